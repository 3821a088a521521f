"""What the artist does while a panel job runs: undo and redo (the sections' status is saved in every undo step, and
undo frees the Blender data a job holds), saving the file, renaming or deleting the cameras a job will place its
results at, and a second job, in another scene, into the same folder or taking the names the first chose. Driven
headless as tests/test_modal_operator.py does (a fake window manager; ``bpy.ops.ed.undo`` needs an undo stack, which
background Blender starts at the first ``undo_push``)."""

from __future__ import annotations

import pytest
from test_modal_operator import TIMER, Job, make_context
from test_novel_views import _camera, _modal_driver, _png, prefs, ready  # noqa: F401  (prefs, ready: fixtures)
from test_sem2nerf_cli import trained  # noqa: F401  (fixture: a 1-step tiny Sem2NeRF run)
from test_sem2nerf_ui import s2n  # noqa: F401  (fixture)

from blender_mrvm.datasets import format as DF


def _undo_steps(*names):
    import bpy

    for n in names:
        bpy.ops.ed.undo_push(message=n)


def _job_on(scene, n=5, attr="mrvm_train"):
    ctx, op = make_context(), Job(n=n)
    op.props_attr, ctx.scene = attr, scene
    return ctx, op


def _run_out(op, ctx):
    res = {"RUNNING_MODAL"}
    for _ in range(1000):
        res = op.modal(ctx, TIMER)
        if res != {"RUNNING_MODAL"}:
            return res
    raise AssertionError("the job never ended")


def test_undo_while_a_job_runs_keeps_its_section_running(empty_scene):
    """Ctrl-Z while Train ran loaded the step saved before it started: its section read idle, the panel showed the
    Train button (and its settings) again, and a second press started a second job beside the first, into the same
    run folder. The section stays running, a second job is refused, and the job still ends its section."""
    import bpy

    p = empty_scene.mrvm_train
    p.iterations = 10
    _undo_steps("original", "before the job")
    ctx, op = _job_on(empty_scene)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    assert bpy.ops.ed.undo() == {"FINISHED"}
    scene = ctx.scene = bpy.context.scene
    assert scene.mrvm_train.running, "the job runs: its section says so"
    ctx2, second = _job_on(scene)
    assert second.invoke(ctx2, None) == {"CANCELLED"}
    assert second.reports[-1] == ("WARNING", "Test job is already running")
    assert _run_out(op, ctx) == {"FINISHED"} and not scene.mrvm_train.running
    assert scene.mrvm_train.status == "done with result"
    assert bpy.ops.ed.redo() == {"FINISHED"} and not bpy.context.scene.mrvm_train.running


def test_undoing_to_a_step_saved_while_a_job_ran_shows_no_job(empty_scene):
    """The artist edits while Synthesize runs (undo steps saved with the section "running"), then undoes the result:
    the section came back with a progress bar and "Esc to cancel" and refused every run ("already running") until
    the file was opened again. Undo now sets it idle: no job runs."""
    import bpy

    _undo_steps("original", "before the job")
    ctx, op = _job_on(empty_scene, n=3, attr="mrvm_novel_views")
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    _undo_steps("an edit while it ran", "another edit while it ran")
    assert _run_out(op, ctx) == {"FINISHED"}
    _undo_steps("Synthesize Novel Views")
    assert bpy.ops.ed.undo() == {"FINISHED"}
    p = bpy.context.scene.mrvm_novel_views
    assert not p.running and "Esc to cancel" not in p.status, (p.running, p.status)
    ctx, again = _job_on(bpy.context.scene, attr="mrvm_novel_views")
    assert again.invoke(ctx, None) == {"RUNNING_MODAL"}, again.reports
    assert _run_out(again, ctx) == {"FINISHED"}


def test_undo_during_render_dataset_stops_it_with_what_happened_and_a_rerun_resumes(empty_scene, tmp_path):
    """Render Dataset renders in Blender, in a scene of its own that undo frees: Ctrl-Z during a render ended it
    with "unexpected error, a bug (ReferenceError: StructRNA of type Object has been removed)". It now says the undo
    removed what it was rendering with and that finished views are kept, and a rerun resumes them. (The step undone
    to was saved during the render: the copy of its render scene that step holds is removed too.)"""
    import bpy

    from blender_mrvm.operators.dataset import MRVM_OT_render_dataset

    p = empty_scene.mrvm_dataset
    p.source, p.library_category, p.library_count = "LIBRARY", "table", 1
    p.views, p.resolution, p.engine, p.output_dir = 3, 32, "BLENDER_WORKBENCH", str(tmp_path / "ds")
    _undo_steps("original", "before the render")
    op, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}  # view 1 done
    _undo_steps("an edit while it rendered", "another edit while it rendered")
    assert bpy.ops.ed.undo() == {"FINISHED"}
    ctx.scene = bpy.context.scene
    assert op.modal(ctx, TIMER) == {"CANCELLED"}
    level, msg = op.reports[-1]
    assert level == "ERROR" and "bug" not in msg and "undo" in msg and "finished views are kept" in msg, msg
    assert not ctx.scene.mrvm_dataset.running and ctx.scene.mrvm_dataset.status == msg
    assert [s.name for s in bpy.data.scenes] == [ctx.scene.name]
    op, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and _run_out(op, ctx) == {"FINISHED"}
    assert "2 views rendered, 1 already done" in op.reports[-1][1], op.reports


def _finished_run(job, tmp_path):
    """A synthesis run of ``job`` as the worker leaves it (an image per target)."""
    from blender_mrvm.operators.synthesize import SynthesisRun

    for i, t in enumerate(job.targets):
        _png(tmp_path / "job" / "out" / t.rgb_path(i), seed=i)
    return SynthesisRun(job, tmp_path / "job", 1.0)


def test_a_target_camera_renamed_while_synthesizing_gets_its_plane(ready, tmp_path):
    """Renaming a selected target camera while the worker ran threw the synthesized views away ("target camera
    'Target' was removed while synthesizing"); the plane now goes to the camera under its new name."""
    import bpy

    from blender_mrvm.operators import synthesize as S
    from blender_mrvm.scene import image_planes as IP

    job = S.plan_from_props(bpy.context)
    run = _finished_run(job, tmp_path)
    bpy.data.objects["Target"].name = "Hero shot"
    msg = S.import_run(bpy.context, run)
    assert msg.startswith("1 novel view in collection"), msg
    assert len(IP.planes_of(bpy.data.objects["Hero shot"])) == 1


def test_a_target_camera_deleted_while_synthesizing_does_not_give_its_plane_to_another_of_its_name(ready, tmp_path):
    """The target camera deleted while the worker ran and another camera made under its name (Blender names the next
    new camera as the one deleted): the view synthesized for the deleted camera was placed on the new one, at
    another place. The import is refused, naming the camera deleted."""
    import bpy

    from blender_mrvm.errors import InputError
    from blender_mrvm.operators import synthesize as S
    from blender_mrvm.scene import image_planes as IP

    job = S.plan_from_props(bpy.context)
    run = _finished_run(job, tmp_path)
    bpy.data.objects.remove(bpy.data.objects["Target"])
    other = _camera(ready, "Target", (0.0, -3.0, 2.0))
    with pytest.raises(InputError, match="'Target' was deleted while the job ran"):
        S.import_run(bpy.context, run)
    assert not IP.planes_of(other)


def test_orbit_camera_names_taken_while_synthesizing_are_chosen_again(ready, tmp_path):
    """Synthesize (orbit) in two scenes at once: both chose the free names "MRVM orbit 000", ... at their start, and
    the second to finish threw its views away ("an object named 'MRVM orbit 000' already exists"). Its cameras now
    take names free when the results arrive."""
    import bpy

    from blender_mrvm.operators import synthesize as S
    from blender_mrvm.scene import image_planes as IP

    p = ready.mrvm_novel_views
    p.target_source, p.orbit_count = "ORBIT", 2
    job = S.plan_from_props(bpy.context)
    run = _finished_run(job, tmp_path)
    other = bpy.data.scenes.new("Other")
    for t in job.targets:  # the other scene's synthesis finished first
        other.collection.objects.link(bpy.data.objects.new(t.name, bpy.data.cameras.new(t.name)))
    msg = S.import_run(bpy.context, run)
    assert msg.startswith("2 novel views in collection") and "(2 new cameras)" in msg, msg
    mine = [o for o in ready.objects if o.type == "CAMERA" and o.name.startswith("MRVM orbit")]
    assert len(mine) == 2 and all(len(IP.planes_of(o)) == 1 for o in mine)
    assert not any(IP.planes_of(o) for o in other.objects)


def test_a_sem2nerf_target_camera_renamed_while_it_ran_gets_its_plane(s2n, tmp_path):
    """Sem2NeRF's selected cameras, one renamed while the worker ran: the views were thrown away as for Synthesize."""
    import bpy

    from blender_mrvm.operators import sem2nerf as OS
    from blender_mrvm.scene import image_planes as IP
    from test_sem2nerf_ui import _camera as s2n_camera

    intr = DF.read_srn_intrinsics(s2n.obj / "intrinsics.txt")
    cams = [s2n_camera(s2n.scene, f"T{i}", DF.read_srn_pose(s2n.obj / "pose" / f"{i:06d}.txt"), intr) for i in (1, 2)]
    for o in s2n.scene.objects:
        o.select_set(o in cams)
    s2n.props.target_source = "SELECTED"
    job = OS.plan_from_props(bpy.context)
    for i, t in enumerate(job.targets):
        _png(tmp_path / "job" / "out" / t.rgb_path(i), t.intrinsics.width, t.intrinsics.height, seed=i)
        _png(tmp_path / "job" / "out" / t.semantic_path(i), t.intrinsics.width, t.intrinsics.height, seed=9)
    cams[0].name = "Renamed"
    msg = OS.import_run(bpy.context, OS.Sem2NeRFRun(job, tmp_path / "job", 1.0))
    assert msg.startswith("2 Sem2NeRF views"), msg
    assert all(len(IP.planes_of(c)) == 1 for c in cams) and cams[0].name == "Renamed"


def test_render_dataset_in_two_scenes_into_one_folder_is_refused_with_the_other_scene_named(empty_scene, tmp_path):
    """Render Dataset started in a second scene into the folder the first scene's job renders into: the two rendered
    the same views twice, turn about on Blender's one main thread. The second is refused, naming the first's scene;
    once it is done, the second starts (and finds everything done)."""
    import bpy

    from blender_mrvm.operators.dataset import MRVM_OT_render_dataset

    other = bpy.data.scenes.new("Other")
    for sc in (empty_scene, other):
        p = sc.mrvm_dataset
        p.source, p.library_category, p.library_count = "LIBRARY", "table", 1
        p.views, p.resolution, p.engine, p.output_dir = 2, 32, "BLENDER_WORKBENCH", str(tmp_path / "ds")
    first, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert first.invoke(ctx, None) == {"RUNNING_MODAL"}
    second, ctx2 = _modal_driver(MRVM_OT_render_dataset)
    ctx2.scene = other
    assert second.invoke(ctx2, None) == {"CANCELLED"}
    assert second.reports[-1] == ("ERROR", f"the Dataset section of scene {empty_scene.name!r} is rendering into "
                                           f"{tmp_path / 'ds'}; wait for it to finish or choose another output folder")
    assert other.mrvm_dataset.status == second.reports[-1][1] and not other.mrvm_dataset.running
    assert _run_out(first, ctx) == {"FINISHED"}
    assert second.invoke(ctx2, None) == {"RUNNING_MODAL"} and _run_out(second, ctx2) == {"FINISHED"}
    assert "0 views rendered, 2 already done" in second.reports[-1][1], second.reports


def _names():
    import bpy

    return {k: sorted(d.name for d in getattr(bpy.data, k))
            for k in ("scenes", "objects", "collections", "meshes", "materials", "cameras", "lights", "worlds")}


def test_saving_while_render_dataset_runs_keeps_its_render_scene_out_of_the_file(empty_scene, tmp_path):
    """Ctrl-S while Render Dataset ran saved its own render scene into the artist's .blend: a scene "MRVM_render"
    with the object being rendered, a camera, a sun, a world and materials, there each time the file was opened.
    The file now holds the artist's data only (a new object made during the render among them), and the render
    goes on to the end."""
    import bpy

    from blender_mrvm.operators.dataset import MRVM_OT_render_dataset

    p = empty_scene.mrvm_dataset
    p.source, p.library_category, p.library_count = "LIBRARY", "table", 1
    p.views, p.resolution, p.engine, p.output_dir = 2, 32, "BLENDER_WORKBENCH", str(tmp_path / "ds")
    artist = _names()
    op, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    assert "MRVM_render" in bpy.data.scenes  # rendering
    empty_scene.collection.objects.link(bpy.data.objects.new("Mine", bpy.data.meshes.new("Mine")))
    artist["objects"].append("Mine")
    artist["meshes"].append("Mine")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    assert _run_out(op, ctx) == {"FINISHED"} and "2 views rendered" in op.reports[-1][1], op.reports
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "scene.blend"))
    assert _names() == {k: sorted(v) for k, v in artist.items()}


def test_undo_after_render_dataset_brings_back_no_render_scene(empty_scene, tmp_path):
    """The artist works while Render Dataset runs (undo steps saved then hold its render scene), then undoes an edit
    once the render is done: the render scene "MRVM_render" came back with the object rendered, its camera, sun,
    world and materials, and stayed in the file. The state undone to is the artist's alone; the edit is undone."""
    import bpy

    from blender_mrvm.operators.dataset import MRVM_OT_render_dataset

    p = empty_scene.mrvm_dataset
    p.source, p.library_category, p.library_count = "LIBRARY", "table", 1
    p.views, p.resolution, p.engine, p.output_dir = 2, 32, "BLENDER_WORKBENCH", str(tmp_path / "ds")
    _undo_steps("original", "before the render")
    artist = _names()
    op, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    empty_scene.frame_current = 5
    _undo_steps("an edit while it rendered")
    empty_scene.frame_current = 6
    _undo_steps("another edit while it rendered")
    assert _run_out(op, ctx) == {"FINISHED"} and _names() == artist
    assert bpy.ops.ed.undo() == {"FINISHED"}
    assert bpy.context.scene.frame_current == 5 and _names() == artist
    assert bpy.ops.ed.undo() == {"FINISHED"} and _names() == artist
    assert bpy.ops.ed.redo() == {"FINISHED"} and _names() == artist


def _two_selected_cubes(scene, tmp_path):
    import bpy

    for name, x in (("A", -1.0), ("B", 1.0)):
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([(x + dx, dy, dz) for dx in (0, .5) for dy in (0, .5) for dz in (0, .5)], [],
                         [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)])
        ob = bpy.data.objects.new(name, mesh)
        scene.collection.objects.link(ob)
        ob.select_set(True)
    p = scene.mrvm_dataset
    p.source = "SELECTED"
    p.views, p.resolution, p.engine, p.output_dir = 2, 16, "BLENDER_WORKBENCH", str(tmp_path / "ds")


def test_a_selected_object_renamed_before_its_turn_is_rendered_under_its_first_name(empty_scene, tmp_path):
    """Render Dataset of the selected objects: renaming one not rendered yet stopped the render ("object 'B' no
    longer exists") and the objects after it were not rendered. It is found by its Blender ID and rendered into the
    folder named when the render began; one deleted is refused in one line, also when another took its name."""
    import bpy

    from blender_mrvm.operators.dataset import MRVM_OT_render_dataset

    _two_selected_cubes(empty_scene, tmp_path)
    op, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}  # A's first view
    bpy.data.objects["B"].name = "B renamed"
    assert _run_out(op, ctx) == {"FINISHED"}, op.reports
    ds = tmp_path / "ds" / "custom"
    assert sorted(p.name for p in ds.iterdir()) == ["A", "B"]
    assert len(list((ds / "B" / "rgb").glob("*.png"))) == 2
    # deleted, and another object given its name: not rendered into its folder
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    _two_selected_cubes(scene, tmp_path / "2")
    op, ctx = _modal_driver(MRVM_OT_render_dataset)
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    bpy.data.objects.remove(bpy.data.objects["B"])
    bpy.data.objects["A"].copy().name = "B"
    assert _run_out(op, ctx) == {"CANCELLED"}
    assert op.reports[-1][0] == "ERROR" and "object 'B' was deleted while the render ran" in op.reports[-1][1]
    assert not (tmp_path / "2" / "ds" / "custom" / "B" / "rgb").is_dir()
