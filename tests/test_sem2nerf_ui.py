"""Sem2NeRF in Blender: operator end to end on a tiny checkpoint (dataset mask and painted image, orbit
and selected cameras), planes with images and semantic maps, Esc leaves nothing, bad input is one line
with nothing created or written."""

from __future__ import annotations

import types

import numpy as np
import pytest
from test_novel_views import ESC, TIMER, _draw, _modal_driver, _state, tiny_checkpoint
from test_sem2nerf_cli import trained  # noqa: F401 (module fixture: a 1-step tiny Sem2NeRF run on 16 px spheres)

from blender_mrvm.datasets import format as DF

def _camera(scene, name, c2w, intr):
    from blender_mrvm.scene import camera as scam

    cam = scam.new_camera(name, scene.collection)
    scam.apply_intrinsics(cam, scene, intr)
    scam.apply_pose(cam, c2w)
    return cam


def _paint(name, ids, encoding="COLORS", float_buffer=False):
    """A Blender image holding the part ids as label colours (or grey ids), as a user would paint it."""
    import bpy

    from blender_mrvm.models.sem2nerf.render import colorize

    h, w = ids.shape
    img = bpy.data.images.new(name, w, h, alpha=True, float_buffer=float_buffer)
    rgb = colorize(ids) if encoding == "COLORS" else np.repeat(ids[..., None], 3, -1)
    px = np.concatenate([rgb.astype(np.float32) / 255.0, np.ones((h, w, 1), np.float32)], -1)
    if float_buffer:  # float images hold linear values
        c = px[..., :3]
        px[..., :3] = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    img.pixels.foreach_set(px[::-1].ravel())  # Blender's rows go bottom-up
    return img


@pytest.fixture
def s2n(empty_scene, trained, tmp_path, monkeypatch):  # noqa: F811
    """A 16 x 16 scene with valid settings (dataset mask and pose, 2 orbit cameras); job folders in tmp_path/jobs."""
    import tempfile

    run, data, obj = trained
    jobs = tmp_path / "jobs"
    jobs.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(jobs))
    scene = empty_scene
    scene.render.resolution_x = scene.render.resolution_y = 16
    scene.render.resolution_percentage = 100
    p = scene.mrvm_sem2nerf
    p.checkpoint, p.mask_source, p.mask_path, p.viewpoint = str(run), "FILE", str(obj / "mask" / "000000.png"), "DATASET"
    p.target_source, p.orbit_count, p.plane_distance = "ORBIT", 2, 1.0
    p.output, p.output_dir, p.device = "FILES", str(tmp_path / "planes"), "CPU"
    return types.SimpleNamespace(scene=scene, props=p, run=run, obj=obj, jobs=jobs, planes=tmp_path / "planes")


def _label_colours(run):
    from blender_mrvm.models.sem2nerf.render import checkpoint_info, palette

    return {palette(v) for v in checkpoint_info(run).labels}


def test_registered_and_panel_draws(empty_scene, trained):  # noqa: F811
    import bpy
    from blender_mrvm.models.sem2nerf.render import checkpoint_info, palette
    from blender_mrvm.panels.sem2nerf import MRVM_PT_sem2nerf

    assert hasattr(bpy.types, "MRVM_OT_sem2nerf") and hasattr(bpy.types, "MRVM_PT_sem2nerf")
    assert MRVM_PT_sem2nerf.bl_parent_id == "MRVM_PT_main"
    p = empty_scene.mrvm_sem2nerf
    p.mask_source, p.style, p.mix, p.checkpoint = "IMAGE", "SEED", 0.5, str(trained[0])
    log = _draw(MRVM_PT_sem2nerf)
    props = {e[1] for e in log if e[0] == "prop"}
    assert {"mask_image", "mask_encoding", "camera", "style_seed", "mix_seed", "show_semantic"} <= props
    assert ("operator", "mrvm.sem2nerf") in log
    labels = [e[1] for e in log if e[0] == "label"]
    info = checkpoint_info(trained[0])
    for v, name in zip(info.labels, info.names):  # the colours to paint with
        assert f"{v} {name}: #%02x%02x%02x" % palette(v) in labels


def test_operator_dataset_mask_orbit_planes_with_semantic_maps(s2n):
    import bpy

    from blender_mrvm.models.sem2nerf.render import orbit_poses
    from blender_mrvm.scene import camera as scam
    from blender_mrvm.scene import image_planes as IP

    assert bpy.ops.mrvm.sem2nerf() == {"FINISHED"}
    p = s2n.props
    assert p.status.startswith("2 Sem2NeRF views of mask") and "(2 new cameras)" in p.status, p.status
    coll = bpy.data.collections["MRVM Sem2NeRF"]
    cams = sorted((o for o in coll.objects if o.type == "CAMERA"), key=lambda o: o.name)
    assert [c.name for c in cams] == ["MRVM Sem2NeRF 000", "MRVM Sem2NeRF 001"]
    want = orbit_poses(DF.read_srn_pose(s2n.obj / "pose" / "000000.txt"), 2)  # the CLI's orbit
    colours = _label_colours(s2n.run)
    for cam, c2w in zip(cams, want):
        intr, got = scam.read_camera(cam, s2n.scene)
        assert np.allclose(got, c2w, atol=1e-5) and (intr.width, intr.height) == (16, 16)
        (plane,) = IP.planes_of(cam)
        img, sem = bpy.data.images[plane["mrvm_image"]], bpy.data.images[plane["mrvm_semantic_image"]]
        assert tuple(img.size) == tuple(sem.size) == (16, 16) and plane[IP.SHOW_SEMANTIC] == 0
        texs = {n.image.name for n in plane.active_material.node_tree.nodes if n.type == "TEX_IMAGE"}
        assert texs == {img.name, sem.name}
        stem = cam.name.replace(" ", "_")
        assert bpy.path.abspath(sem.filepath) == str(s2n.planes / f"{stem}_semantic.png")
        sem_png = DF.read_png(s2n.planes / f"{stem}_semantic.png")
        assert {tuple(c) for c in sem_png.reshape(-1, sem_png.shape[-1])[:, :3]} <= colours
        assert DF.read_png(s2n.planes / f"{stem}.png").shape == (16, 16, 4)
    assert len(list(s2n.planes.iterdir())) == 4
    p.show_semantic = True
    assert all(o[IP.SHOW_SEMANTIC] == 1 for o in coll.objects if IP.SHOW_SEMANTIC in o)
    p.show_semantic = False
    assert all(o[IP.SHOW_SEMANTIC] == 0 for o in coll.objects if IP.SHOW_SEMANTIC in o)
    assert not list(s2n.jobs.iterdir()), "the job folder is removed"
    # With the box ticked, new planes show their semantic maps (they showed images until it was ticked again)
    p.show_semantic = True
    assert bpy.ops.mrvm.sem2nerf() == {"FINISHED"}
    assert all(o[IP.SHOW_SEMANTIC] == 1 for o in coll.objects if IP.SHOW_SEMANTIC in o)


def test_painted_image_reads_back_as_the_mask(empty_scene, trained, tmp_path):  # noqa: F811
    import bpy

    from blender_mrvm.models.sem2nerf.render import checkpoint_info, mask_from_rgba
    from blender_mrvm.scene.sem2nerf import image_rgba

    run, _, obj = trained
    labels = checkpoint_info(run).labels
    m = DF.read_png(obj / "mask" / "000000.png")
    assert len(np.unique(m)) >= 2
    for enc, flt in (("COLORS", False), ("COLORS", True), ("IDS", False)):
        img = _paint(f"m_{enc}_{flt}", m, enc, flt)
        assert np.array_equal(mask_from_rgba(image_rgba(img), labels, enc, "img"), m), (enc, flt)
    # files opened in the image editor: the dataset's grey mask, and a semantic map of a render
    from blender_mrvm.models.sem2nerf.render import colorize

    DF.write_png(tmp_path / "sem.png", colorize(m))
    for path, enc in ((obj / "mask" / "000000.png", "IDS"), (tmp_path / "sem.png", "COLORS")):
        img = bpy.data.images.load(str(path))
        assert np.array_equal(mask_from_rgba(image_rgba(img), labels, enc, "img"), m), path


def test_semantic_planes_replace_and_switch(empty_scene, tmp_path):
    """A plane with a semantic map: both images saved and wired; building again replaces it under
    the same names and removes the old images; the switch flips what the material shows."""
    import bpy

    from blender_mrvm.geometry import cameras as C
    from blender_mrvm.scene import image_planes as IP
    from blender_mrvm.scene.sem2nerf import COLLECTION, set_show_semantic

    scene = empty_scene
    scene.render.resolution_x = scene.render.resolution_y = 8
    cam = _camera(scene, "Cam", np.eye(4), C.intrinsics_from_fov(0.8, 8, 8))
    cfg = IP.PlaneConfig(distance=1.0, folder=str(tmp_path / "p"), collection=COLLECTION)
    rgba = np.zeros((8, 8, 4), np.uint8)
    for k in range(2):
        rgba[..., 3], sem = 255, np.full((8, 8, 3), 40 * (k + 1), np.uint8)
        IP.build_image_planes(scene, [IP.NovelView("Cam", rgba, semantic=sem)], cfg)
    (plane,) = IP.planes_of(cam)
    assert plane.name == "MRVM plane Cam" and plane["mrvm_semantic_image"] == "MRVM semantic Cam"
    assert sorted(i.name for i in bpy.data.images) == ["MRVM Cam", "MRVM semantic Cam"]
    assert DF.read_png(tmp_path / "p" / "Cam_1_semantic.png")[0, 0, 0] == 80  # a new file: a re-run writes over none
    assert DF.read_png(tmp_path / "p" / "Cam_semantic.png")[0, 0, 0] == 40
    assert set_show_semantic(True) == 1 and plane[IP.SHOW_SEMANTIC] == 1
    nodes = plane.active_material.node_tree.nodes
    attr = next(n for n in nodes if n.type == "ATTRIBUTE")
    assert (attr.attribute_type, attr.attribute_name) == ("OBJECT", IP.SHOW_SEMANTIC) and attr.outputs["Fac"].is_linked


@pytest.mark.slow
def test_operator_painted_image_scene_camera_selected_targets_packed(s2n):
    import bpy

    from blender_mrvm.scene import image_planes as IP

    intr = DF.read_srn_intrinsics(s2n.obj / "intrinsics.txt")
    poses = [DF.read_srn_pose(s2n.obj / "pose" / f"{i:06d}.txt") for i in range(3)]
    view = _camera(s2n.scene, "MaskView", poses[0], intr)
    targets = [_camera(s2n.scene, f"T{i}", poses[i], intr) for i in (1, 2)]
    for o in s2n.scene.objects:
        o.select_set(o in targets)
    p = s2n.props
    p.mask_source, p.mask_encoding, p.camera = "IMAGE", "COLORS", view
    p.mask_image = _paint("painted", DF.read_png(s2n.obj / "mask" / "000000.png"))
    p.target_source, p.output, p.style, p.style_seed, p.mix, p.mix_seed = "SELECTED", "PACK", "SEED", 3, 0.5, 4
    assert bpy.ops.mrvm.sem2nerf() == {"FINISHED"}, p.status
    assert p.status.startswith("2 Sem2NeRF views of image 'painted'"), p.status
    for cam in targets:
        (plane,) = IP.planes_of(cam)
        img, sem = bpy.data.images[plane["mrvm_image"]], bpy.data.images[plane["mrvm_semantic_image"]]
        assert img.packed_file is not None and sem.packed_file is not None
    assert not s2n.planes.exists() and not list(s2n.jobs.iterdir())


def test_job_arguments_carry_the_style(s2n, tmp_path):
    import bpy

    from blender_mrvm.datasets.novel_views import read_targets
    from blender_mrvm.operators import sem2nerf as O

    p = s2n.props
    p.style, p.style_seed, p.mix, p.mix_seed, p.quality = "SEED", 7, 0.25, 9, "PREVIEW"
    job = O.plan_from_props(bpy.context)
    before = _state()
    args = O.write_job(job, tmp_path / "job")
    assert _state() == before, "orbit cameras come with the results"
    assert args[:2] == ["render", "--checkpoint"] and args[-6:] == ["--style-seed", "7", "--mix-seed", "9", "--mix", "0.25"]
    assert args[args.index("--quality") + 1] == "preview"
    p.quality = "FULL"
    assert np.array_equal(DF.read_png(tmp_path / "job" / "mask.png"), DF.read_png(s2n.obj / "mask" / "000000.png"))
    targets, _ = read_targets(tmp_path / "job" / "targets.json")
    assert [t.name for t in targets] == ["MRVM Sem2NeRF 000", "MRVM Sem2NeRF 001"] and all(t.generated for t in targets)


def test_open_mask_for_painting_and_relabel(s2n, tmp_path):
    import bpy

    from blender_mrvm.models.sem2nerf.render import checkpoint_info
    from blender_mrvm.operators import sem2nerf as O

    p = s2n.props
    m = DF.read_png(s2n.obj / "mask" / "000000.png")
    assert bpy.ops.mrvm.sem2nerf_paint_mask() == {"FINISHED"}
    assert (p.mask_source, p.mask_encoding) == ("IMAGE", "COLORS") and p.mask_image.packed_file is not None
    p.camera = _camera(s2n.scene, "View", DF.read_srn_pose(s2n.obj / "pose" / "000000.txt"),
                       DF.read_srn_intrinsics(s2n.obj / "intrinsics.txt"))
    assert np.array_equal(O.plan_from_props(bpy.context).mask, m), "the painted image reads back as the mask"
    parts = sorted(int(v) for v in np.unique(m) if v)
    info = checkpoint_info(s2n.run)
    p.edits = f"{parts[0]}:0"
    if len(parts) > 1:  # relabel by name too
        p.edits += f", {info.names[info.labels.index(parts[1])]}:{parts[0]}"
    got = O.plan_from_props(bpy.context).mask
    want = np.where(m == parts[0], 0, m)
    if len(parts) > 1:
        want = np.where(want == parts[1], parts[0], want)
    assert np.array_equal(got, want)
    p.edits = "1:250"
    with pytest.raises(RuntimeError, match="250"):
        bpy.ops.mrvm.sem2nerf()
    p.mask_source, p.mask_path = "FILE", str(tmp_path / "missing.png")
    with pytest.raises(RuntimeError, match="does not exist"):
        bpy.ops.mrvm.sem2nerf_paint_mask()
    # a label the checkpoint does not know is refused, not painted in a colour that reads back as another label
    DF.write_png(tmp_path / "unknown.png", np.where(m > 0, 200, 0).astype(np.uint8))
    p.mask_path, images = str(tmp_path / "unknown.png"), len(bpy.data.images)
    with pytest.raises(RuntimeError, match=r"label id\(s\) \[200\] are not known"):
        bpy.ops.mrvm.sem2nerf_paint_mask()
    assert len(bpy.data.images) == images and p.mask_source == "FILE"


def test_escape_stops_the_worker_and_adds_nothing(s2n, monkeypatch):
    from blender_mrvm import worker as Wk
    from blender_mrvm.operators.sem2nerf import MRVM_OT_sem2nerf

    procs = []
    real = Wk.run_worker
    monkeypatch.setattr(Wk, "run_worker", lambda *a, **k: real(*a, on_start=procs.append, **k))
    (op, ctx), before = _modal_driver(MRVM_OT_sem2nerf), _state()
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and s2n.props.running
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    assert len(procs) == 1 and procs[0].poll() is None, "the worker is running"
    assert op.modal(ctx, ESC) == {"CANCELLED"}
    assert procs[0].poll() is not None, "Esc ended the worker process"
    assert op.reports[-1] == ("WARNING", "Sem2NeRF cancelled; nothing was added")
    assert _state() == before and not s2n.props.running
    assert not list(s2n.jobs.iterdir()) and not s2n.planes.exists()


BAD = ["unknown_label", "empty", "size", "no_dataset_pose", "no_camera", "not_a_camera", "degenerate_camera", "not_square",
       "unknown_colour", "unknown_label_colour", "no_image", "not_sem2nerf", "no_checkpoint"]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_one_line_nothing_created_or_written(s2n, tmp_path, case):
    import bpy

    from blender_mrvm.models.sem2nerf.render import palette

    p, obj = s2n.props, s2n.obj
    m = DF.read_png(obj / "mask" / "000000.png")

    def mask_file(arr):
        path = tmp_path / "in" / "mask" / "000000.png"
        DF.write_png(path, arr)
        p.mask_path, p.viewpoint = str(path), "CAMERA"
        p.camera = _camera(s2n.scene, "View", DF.read_srn_pose(obj / "pose" / "000000.txt"),
                           DF.read_srn_intrinsics(obj / "intrinsics.txt"))

    def painted(arr=None, cam=True):
        p.mask_source, p.viewpoint = "IMAGE", "CAMERA"
        p.mask_image = _paint("painted", m if arr is None else arr)
        if cam:
            p.camera = _camera(s2n.scene, "View", DF.read_srn_pose(obj / "pose" / "000000.txt"),
                               DF.read_srn_intrinsics(obj / "intrinsics.txt"))

    if case == "unknown_label":
        bad = m.copy()
        bad[:2, :2] = 200
        mask_file(bad)
        match = r"label id\(s\) \[200\] are not known"
    elif case == "empty":
        mask_file(np.zeros_like(m))
        match = "is empty"
    elif case == "size":
        mask_file(np.zeros((20, 16), np.uint8))
        match = "is 16x20; this checkpoint takes 16x16 masks"
    elif case == "no_dataset_pose":
        path = tmp_path / "in" / "mask" / "000000.png"
        DF.write_png(path, m)
        p.mask_path = str(path)
        match = "has no pose in its dataset"
    elif case == "no_camera":
        painted(cam=False)
        match = "(?i)choose the camera the mask is seen from"  # the button greyed out (poll), with the reason
    elif case == "degenerate_camera":
        painted()
        p.camera.scale = (1.0, 0.0, 1.0)
        bpy.context.view_layer.update()
        match = "camera 'View' has no usable pose: its transform is singular"
    elif case == "not_a_camera":
        painted(cam=False)
        empty = bpy.data.objects.new("Empty", None)
        s2n.scene.collection.objects.link(empty)
        p.camera = empty  # the panel's picker offers cameras only; a script can set anything
        match = "'Empty' is not a camera"
    elif case == "not_square":
        painted()
        s2n.scene.render.resolution_x = 20
        match = "a Sem2NeRF mask is square"
    elif case == "unknown_colour":
        img = m.copy()
        painted(img)
        px = np.array(p.mask_image.pixels[:], np.float32).reshape(16, 16, 4)
        px[0, 0, :3] = (0.0, 1.0, 0.0)
        p.mask_image.pixels.foreach_set(px.ravel())
        match = "colours of no label"
    elif case == "unknown_label_colour":
        bad = m.copy()
        bad[:3, :3] = 200
        painted(bad)
        assert palette(200) not in _label_colours(s2n.run)
        match = r"label id\(s\) \[200\] are not known"
    elif case == "no_image":
        p.mask_source, p.viewpoint = "IMAGE", "CAMERA"
        match = "(?i)choose the mask image"  # the button greyed out (poll), with the reason
    elif case == "not_sem2nerf":
        p.checkpoint = str(tiny_checkpoint(tmp_path / "nerformer"))
        match = "is not a Sem2NeRF checkpoint"
    else:  # empty = the shipped model when this copy has one (64 px: the 16 px test mask is refused), else none
        from blender_mrvm.models.pretrained import shipped_or_none

        p.checkpoint = ""
        match = "this checkpoint takes 64x64 masks" if shipped_or_none("sem2nerf") else "choose a Sem2NeRF checkpoint"
    before = _state()
    with pytest.raises(RuntimeError, match=match) as ei:
        bpy.ops.mrvm.sem2nerf()
    assert len(str(ei.value).strip().splitlines()) == 1, str(ei.value)
    assert _state() == before, "nothing created"
    assert not s2n.planes.exists() and not list(s2n.jobs.iterdir()), "nothing written"
    assert not p.running and (p.status or "poll()" in str(ei.value))  # poll: the greyed-out button says why


def test_a_file_saved_during_a_job_opens_with_no_job_running(empty_scene, tmp_path):
    """running / progress / status are saved in the .blend (SKIP_SAVE does not keep scene properties out of it): the
    add-on's load_post handler sets every section of every scene idle, so the panel can start a job again."""
    import bpy

    from blender_mrvm.props import SCENE_PROPERTIES

    other = bpy.data.scenes.new("Other")
    for scene in (empty_scene, other):
        for name in SCENE_PROPERTIES:
            g = getattr(scene, name)
            g.running, g.progress, g.status = True, 0.5, "view 1/2, Esc to cancel"
    done = empty_scene.mrvm_dataset
    done.running, done.progress, done.status = False, 0.0, "Dataset written"  # a finished job's message stays
    names = (empty_scene.name, other.name)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "saved.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "saved.blend"))
    for scene in (bpy.data.scenes[n] for n in names):
        for name in SCENE_PROPERTIES:
            g = getattr(scene, name)
            assert not g.running and g.progress == 0.0, (scene.name, name)
            assert g.status in ("", "Dataset written"), (scene.name, name, g.status)
    assert bpy.data.scenes[names[0]].mrvm_dataset.status == "Dataset written"


def test_a_worker_python_without_scipy_is_refused_up_front(s2n, tmp_path, monkeypatch):
    """Sem2NeRF's mask inputs (build_inputs) need scipy: a worker Python lacking it is named with its install
    command before the job starts, not a failure in the worker."""
    import sys

    import bpy

    from blender_mrvm import worker as W

    py = tmp_path / "python"
    mods = {"torch": "2.13.0", "safetensors": "0.4.5", "numpy": "1.26.4", "PIL": "11.0", "scipy": None}
    py.write_text(f"#!{sys.executable}\nimport json\nprint(json.dumps({{'python': '3.11.0', 'modules': {mods!r}}}))\n")
    py.chmod(0o755)
    monkeypatch.setattr(W, "choose_interpreter", lambda *a, **k: W.Interpreter(str(py), "preferences"))
    W.clear_probe_cache()
    before = _state()
    with pytest.raises(RuntimeError, match='scipy missing in the worker Python .*pip install "scipy>=1.11"'):
        bpy.ops.mrvm.sem2nerf()
    assert _state() == before and not list(s2n.jobs.iterdir())
    W.clear_probe_cache()


def test_relabel_examples_work_with_the_shipped_checkpoint(addon):
    """The Relabel examples of the panel's tooltip and of docs/guide/sem2nerf.md name labels of the shipped
    checkpoint (whose names are category/part: 'arm:seat' was refused)."""
    import re
    from pathlib import Path

    import bpy

    from blender_mrvm.models.pretrained import shipped_or_none
    from blender_mrvm.models.sem2nerf.render import checkpoint_info, parse_edit

    ck = shipped_or_none("sem2nerf")
    if ck is None:
        pytest.skip("this copy ships no Sem2NeRF model")
    info = checkpoint_info(ck)
    tip = bpy.types.Scene.bl_rna.properties["mrvm_sem2nerf"].fixed_type.properties["edits"].description
    doc = (Path(__file__).resolve().parents[1] / "docs" / "guide" / "sem2nerf.md").read_text()
    start = doc.index("*Relabel*")
    relabel = doc[start:doc.index("`--edit`", start)]
    examples = re.findall(r"'([^' ]+:[^' ]+)'", tip) + re.findall(r"`([^` ]+:[^` ]+)`", relabel)
    assert len(examples) == 4 and any(not e[0].isdigit() for e in examples), examples
    for e in examples:
        src, dst = parse_edit(e, info.labels, info.names)
        assert src in info.labels and dst in info.labels
