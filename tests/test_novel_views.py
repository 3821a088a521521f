"""Novel views in Blender: panel, preferences' dependency status, scene references exported for the
worker, results imported as cameras + image planes (all or nothing), and the Synthesize operator end
to end through the worker process with a tiny checkpoint made here (execute, and the modal path with
synthetic timer / Esc events), plus its checks (bad input, a checkpoint that does not load, torch
missing), each leaving the scene as it was."""

from __future__ import annotations

import json
import math
import re
import types
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.errors import InputError

W, H = 32, 24


class FakeLayout:
    """Records what a draw() puts on screen (labels, properties, operators)."""

    def __init__(self, log=None):
        self.log = log if log is not None else []
        self.enabled = self.active = True
        self.use_property_split = self.use_property_decorate = False

    def _child(self, *a, **k):
        return FakeLayout(self.log)

    column = row = box = _child

    def label(self, text="", icon="NONE"):
        self.log.append(("label", text, icon))

    def prop(self, data, name, **k):
        self.log.append(("prop", name))

    def operator(self, idname, **k):
        self.log.append(("operator", idname))

    def separator(self, **k):
        pass

    def progress(self, **k):
        self.log.append(("progress", k.get("text")))


def _draw(panel_or_prefs_cls, owner=None):
    import bpy

    layout = FakeLayout()
    me = types.SimpleNamespace(layout=layout)
    if owner is not None:
        me = owner
        me.layout = layout
    panel_or_prefs_cls.draw(me, bpy.context)
    return layout.log


def _labels(log):
    return [e[1] for e in log if e[0] == "label"]


def _scene(scene):
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = W, H, 100
    return scene


def _camera(scene, name, location, target=(0.0, 0.0, 0.0), shift=(0.0, 0.0)):
    from blender_mrvm.geometry import cameras as C
    from blender_mrvm.scene import camera as scam

    cam = scam.new_camera(name, scene.collection)
    cam.data.lens, (cam.data.shift_x, cam.data.shift_y) = 35.0, shift
    scam.apply_pose(cam, C.look_at_opencv(location, target))
    return cam


def _png(path: Path, w=W, h=H, seed=0):
    from PIL import Image

    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    img[..., 3] = 255
    img[: h // 3, : w // 3, 3] = 0
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path)
    return img


def _with_background(cam, path: Path):
    import bpy

    img = bpy.data.images.load(str(path))
    bg = cam.data.background_images.new()
    bg.image = img
    return img


def _state():
    import bpy

    out = {k: sorted(d.name for d in getattr(bpy.data, k))
           for k in ("objects", "meshes", "materials", "images", "collections", "cameras")}
    out["children"] = sorted(c.name for c in bpy.context.scene.collection.children)
    return out


def _corner_error(scene, cam, plane) -> float:
    import bpy
    from bpy_extras.object_utils import world_to_camera_view

    bpy.context.view_layer.update()
    w, h = scene.render.resolution_x, scene.render.resolution_y
    corners = np.array([[0, h], [w, h], [w, 0], [0, 0]], dtype=float)
    got = []
    for v in list(plane.data.vertices)[:4]:
        q = world_to_camera_view(scene, cam, plane.matrix_world @ v.co)
        got.append((q.x * w, (1.0 - q.y) * h))
    return float(np.abs(np.array(got) - corners).max())


def tiny_checkpoint(run_dir: Path) -> Path:
    """An untrained tiny model saved through the checkpoint API (these tests need a model that loads, not a good one)."""
    import torch

    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training.checkpoint import save_checkpoint

    cfg = model_config("fast", {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
                                "sampler": {"n_coarse": 4, "n_fine": 2}})
    torch.manual_seed(0)
    save_checkpoint(run_dir, 1, GeneralizableNeRF(cfg), cfg, None)
    return run_dir


# ---------------------------------------------------------------------------------------------


def test_registered_and_panel_draws_each_mode(empty_scene):
    import bpy

    from blender_mrvm.panels.novel_views import MRVM_PT_novel_views

    assert hasattr(bpy.types, "MRVM_OT_synthesize") and hasattr(bpy.types, "MRVM_PT_novel_views")
    assert MRVM_PT_novel_views.bl_parent_id == "MRVM_PT_main"
    p = empty_scene.mrvm_novel_views
    assert (p.reference_source, p.target_source, p.device, p.output) == ("DATASET", "ORBIT", "AUTO", "FILES")

    log = _draw(MRVM_PT_novel_views)
    props = [e[1] for e in log if e[0] == "prop"]
    assert {"dataset_dir", "reference_views", "orbit_count", "orbit_elevation", "orbit_radius", "checkpoint",
            "device", "reference_sizing", "plane_distance", "output_dir", "save_depth"} <= set(props)
    assert ("operator", "mrvm.synthesize") in log and "reference_size" not in props

    p.reference_source, p.target_source, p.output = "SCENE", "SELECTED", "PACK"
    cam = _camera(empty_scene, "Cam", (3.0, 0.0, 1.0))
    cam.select_set(True)
    log = _draw(MRVM_PT_novel_views)
    assert "0 cameras with a reference image" in _labels(log) and "1 camera selected" in _labels(log)
    assert ("prop", "output_dir") not in log and ("prop", "orbit_count") not in log

    p.running, p.progress, p.status = True, 0.5, "view 2/4"
    log = _draw(MRVM_PT_novel_views)
    assert ("progress", "view 2/4") in log and ("operator", "mrvm.synthesize") not in log
    p.running = False


@pytest.fixture
def bare_python(tmp_path_factory):
    import os
    import venv

    from blender_mrvm import worker as Wk

    d = tmp_path_factory.mktemp("bare") / "venv"
    venv.create(d, with_pip=False, symlinks=os.name != "nt")
    return str(Wk.venv_python(d))


@pytest.fixture
def prefs(addon):
    import bpy

    pr = bpy.context.preferences.addons["blender_mrvm"].preferences
    saved = (pr.python_path, pr.checkpoint_dir)
    yield pr
    pr.python_path, pr.checkpoint_dir = saved


def test_dependency_status_in_preferences(empty_scene, prefs, bare_python):
    import sys

    import bpy

    from blender_mrvm import prefs as P
    from blender_mrvm.panels.novel_views import MRVM_PT_novel_views

    rep = P.dependency_status()
    assert rep.interpreter.path == sys.executable and rep.missing == [] and rep.install_command == ""
    log = _draw(P.MRVM_AddonPreferences, types.SimpleNamespace(device="AUTO", checkpoint_dir=""))
    labels = _labels(log)
    own = f"Worker Python (Blender's own, {sys.version_info.major}.{sys.version_info.minor}"  # 3.13 from 5.1 on
    assert labels[0].startswith(own) and labels[0].endswith(sys.executable)
    assert any(lab.startswith("torch 2.13") for lab in labels)
    assert ("operator", "mrvm.copy_install_command") not in log

    prefs.python_path = bare_python
    rep = P.dependency_status()
    assert rep.interpreter.source == "preferences"
    assert rep.missing == ["torch", "safetensors", "numpy", "PIL", "scipy", "OpenEXR", "pycolmap", "pillow_heif", "av"]
    log = _draw(P.MRVM_AddonPreferences, types.SimpleNamespace(device="AUTO", checkpoint_dir=""))
    labels = _labels(log)
    assert "torch: missing (needed for training and novel-view synthesis)" in labels
    assert "pycolmap: missing (needed for recovering the poses of photos)" in labels
    assert f'Install with: "{bare_python}" -m pip install "torch==2.13.0"' in labels[-1]
    assert ("operator", "mrvm.copy_install_command") in log
    assert bpy.ops.mrvm.check_dependencies() == {"FINISHED"}
    # The Novel views panel warns too.
    assert "torch is missing in the worker Python" in _labels(_draw(MRVM_PT_novel_views))

    prefs.python_path = str(Path(bare_python).parent / "nonexistent")
    assert P.dependency_status().error.startswith("the worker Python set in the add-on preferences does not exist")


def test_scene_references_export_round_trip(empty_scene, tmp_path):
    from blender_mrvm.datasets.format import read_object
    from blender_mrvm.scene import camera as scam
    from blender_mrvm.scene import novel_views as NV

    scene = _scene(empty_scene)
    a = _camera(scene, "RefA", (3.0, -1.0, 1.0), shift=(0.1, -0.05))
    b = _camera(scene, "RefB", (-2.0, 2.5, 1.5))
    _camera(scene, "NoImage", (0.0, -3.0, 1.0))
    img_a = _png(tmp_path / "a.png", 2 * W, 2 * H, seed=1)  # the photo at twice the render size
    img_b = _png(tmp_path / "b.png", seed=2)
    _with_background(a, tmp_path / "a.png")
    _with_background(b, tmp_path / "b.png").pack()
    (tmp_path / "b.png").unlink()  # packed: exported from the .blend's bytes
    assert [c.name for c in NV.reference_cameras(scene)] == ["RefA", "RefB"]

    folder, views = NV.export_scene_references(scene, NV.reference_cameras(scene), tmp_path / "refs")
    assert views == (0, 1)
    ov = read_object(folder)
    assert ov.indices == [0, 1]
    for i, (cam, img, scale) in enumerate(((a, img_a, 2.0), (b, img_b, 1.0))):
        intr, c2w = scam.read_camera(cam, scene)
        assert np.allclose(ov.c2w_opencv[i], c2w, atol=1e-6)
        k = ov.intrinsics_per_view[i]
        assert (k.width, k.height) == (W * scale, H * scale)
        assert np.allclose([k.fx, k.fy, k.cx, k.cy], np.array([intr.fx, intr.fy, intr.cx, intr.cy]) * scale)
        assert np.array_equal(ov.rgb(i), img[..., :3])


def test_import_results_orbit_and_selected(empty_scene, tmp_path):
    import bpy

    from blender_mrvm.datasets.novel_views import write_targets
    from blender_mrvm.scene import camera as scam
    from blender_mrvm.scene import image_planes as IP
    from blender_mrvm.scene import novel_views as NV

    scene = _scene(empty_scene)
    scene.render.pixel_aspect_y = 1.25
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "s.blend"))
    scene = bpy.context.scene
    sel = _camera(scene, "Selected", (0.0, -3.0, 1.0), shift=(0.05, 0.0))
    targets = NV.orbit_targets(scene, 3, 2.5, math.radians(20.0), math.radians(45.0), (0.2, 0.0, 0.1))
    targets += NV.selected_targets(scene, [sel])
    assert [t.name for t in targets] == ["MRVM orbit 000", "MRVM orbit 001", "MRVM orbit 002", "Selected"]
    assert not any(bpy.data.objects.get(t.name) for t in targets[:3]), "orbit cameras exist only with results"
    write_targets(tmp_path / "job" / "targets.json", targets)
    out = tmp_path / "job" / "out"
    imgs = [_png(out / t.rgb_path(i), seed=i) for i, t in enumerate(targets[:3])]  # what a worker would write

    before = _state()
    with pytest.raises(InputError, match="wrote no image for 'Selected'"):
        NV.import_results(scene, targets, out, IP.PlaneConfig(distance=1.0))
    assert _state() == before

    imgs.append(_png(out / targets[3].rgb_path(3), seed=3))
    res = NV.import_results(scene, targets, out, IP.PlaneConfig(distance=1.0))
    assert len(res.planes) == 4 and res.collection.name == "MRVM novel views"
    for i, t in enumerate(targets):
        cam = bpy.data.objects[t.name]
        assert (cam.name in res.collection.objects) == t.generated
        intr, c2w = scam.read_camera(cam, scene)
        assert np.allclose([intr.fx, intr.fy, intr.cx, intr.cy], [t.intrinsics.fx, t.intrinsics.fy,
                                                                  t.intrinsics.cx, t.intrinsics.cy], rtol=1e-6)
        assert np.allclose(c2w, t.c2w_opencv, atol=1e-6)
        (plane,) = IP.planes_of(cam)
        assert _corner_error(scene, cam, plane) < 0.5
        assert (tmp_path / "mrvm_novel_views" / f"{IP.safe_id(t.name)}.png").is_file()
    # A second orbit run keeps the first one's cameras and adds fresh ones.
    more = NV.orbit_targets(scene, 2, 2.5, 0.0, math.radians(45.0))
    assert [t.name for t in more] == ["MRVM orbit 003", "MRVM orbit 004"]


# ---------------------------------------------------------------------------------------------
# The operator's checks


@pytest.fixture
def ready(empty_scene, tmp_path, prefs):
    """A saved scene with valid Novel views settings: references, a selected target, a checkpoint file."""
    import bpy

    from blender_mrvm.scene import novel_views as NV

    scene = _scene(empty_scene)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    scene = bpy.context.scene
    refs = []
    for i, loc in enumerate(((3.0, 0.0, 1.0), (0.0, 3.0, 1.0))):
        cam = _camera(scene, f"Ref{i}", loc)
        _png(tmp_path / f"ref{i}.png", seed=i)
        _with_background(cam, tmp_path / f"ref{i}.png")
        refs.append(cam)
    folder, _ = NV.export_scene_references(scene, refs, tmp_path / "refs")
    target = _camera(scene, "Target", (-3.0, 0.0, 1.0))
    for o in scene.objects:
        o.select_set(o == target)
    ck = tiny_checkpoint(tmp_path / "run")
    p = scene.mrvm_novel_views
    p.reference_source, p.dataset_dir, p.reference_views = "DATASET", str(folder), "0 1"
    p.target_source, p.checkpoint, p.plane_distance = "SELECTED", str(ck), 1.0
    prefs.python_path, prefs.checkpoint_dir = "", ""
    return scene


def test_orbit_cameras_see_planes_nearer_than_a_new_cameras_clip_start(ready, tmp_path):
    """An orbit's plane distance under a new camera's default clip start (0.1): the plan takes it, and the
    cameras created with the results clip nearer still, so the import succeeds and each shows its plane."""
    import bpy

    from blender_mrvm.operators import synthesize as S
    from blender_mrvm.scene import image_planes as IP
    from blender_mrvm.scene import novel_views as NV

    p = ready.mrvm_novel_views
    p.target_source, p.orbit_count, p.plane_distance = "ORBIT", 2, 0.05
    job = S.plan_from_props(bpy.context)
    out = tmp_path / "job" / "out"
    for i, t in enumerate(job.targets):
        _png(out / t.rgb_path(i), seed=i)
    NV.import_results(ready, list(job.targets), out, job.planes)
    for t in job.targets:
        cam = bpy.data.objects[t.name]
        assert cam.data.clip_start < 0.05 < cam.data.clip_end
        (plane,) = IP.planes_of(cam)
        assert _corner_error(ready, cam, plane) < 0.5 and np.isclose(plane["mrvm_distance"], 0.05)


def _fails(msg: str):
    """Run the operator; it must report ``msg`` as its error and leave the scene as it was."""
    import bpy

    before = _state()
    with pytest.raises(RuntimeError, match=msg):
        bpy.ops.mrvm.synthesize()
    assert _state() == before
    assert re.search(msg, bpy.context.scene.mrvm_novel_views.status), "the panel shows the error too"


def _reference_synthesis(job, tmp_path) -> np.ndarray:
    """What the synthesize core writes for ``job`` when run here, in-process (the operator must match it)."""
    from blender_mrvm.datasets.format import read_png
    from blender_mrvm.datasets.novel_views import write_targets
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.synthesis import SynthesisConfig, synthesize_views

    write_targets(tmp_path / "check" / "targets.json", list(job.targets))
    run_to_end(synthesize_views(SynthesisConfig(job.reference_dir, tmp_path / "check" / "targets.json",
                                                tmp_path / "check" / "out", job.views, job.checkpoint, "cpu")))
    return read_png(tmp_path / "check" / "out" / "rgb" / "000000.png")


def test_operator_synthesizes_through_the_worker(ready, tmp_path, monkeypatch):
    """Execute path end to end: worker process, tiny checkpoint, one image plane on the target's frustum
    showing exactly what the synthesize core computes for that camera; the job folder is removed."""
    import tempfile

    import bpy

    from blender_mrvm.datasets.format import read_png
    from blender_mrvm.operators import synthesize as S
    from blender_mrvm.scene import image_planes as IP

    jobs = tmp_path / "jobs"
    jobs.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(jobs))
    assert S.model_available()
    job = S.plan_from_props(bpy.context)
    assert job.views == (0, 1) and [t.name for t in job.targets] == ["Target"] and job.device == "auto"
    ready.view_settings.view_transform = "Standard"  # (under AgX the message adds a note on colour management)
    assert bpy.ops.mrvm.synthesize() == {"FINISHED"}
    status = ready.mrvm_novel_views.status
    assert re.fullmatch(r"1 novel view in collection 'MRVM novel views', synthesized in [0-9.]+ s", status), status
    cam = bpy.data.objects["Target"]
    (plane,) = IP.planes_of(cam)
    assert _corner_error(ready, cam, plane) < 0.5
    png = Path(bpy.path.abspath(bpy.data.images[plane["mrvm_image"]].filepath))
    got = read_png(png)
    assert got.shape == (H, W, 4)
    assert np.array_equal(got, _reference_synthesis(job, tmp_path))
    assert not list(jobs.glob("mrvm_synth_*")), "the job folder is removed"


def test_the_finish_message_carries_the_runs_viewpoint_note(tmp_path):
    """What synthesis.json says about cameras off the default model's turntable, and which model Auto picked,
    reaches the status line."""
    from blender_mrvm.operators import synthesize as S

    assert S.run_note(tmp_path) == ""  # no synthesis.json
    (tmp_path / "synthesis.json").write_text(json.dumps({"viewpoint_note": "use shipped:mrvm_anyview"}))
    assert S.run_note(tmp_path) == "use shipped:mrvm_anyview"
    (tmp_path / "synthesis.json").write_text(json.dumps({"viewpoint_note": "use shipped:mrvm_anyview",
                                                         "adaptation": {"steps": 9, "note": "adapting to 2 references"}}))
    assert S.run_note(tmp_path) == "use shipped:mrvm_anyview; adapting to 2 references"  # and the adaptation's
    (tmp_path / "synthesis.json").write_text(json.dumps({"viewpoint_note": "", "adaptation": None}))
    assert S.run_note(tmp_path) == ""
    (tmp_path / "synthesis.json").write_text(json.dumps({"model_choice": "auto: the any-view model", "viewpoint_note": "",
                                                         "adaptation": {"steps": 9, "note": "adapting"}}))
    assert S.run_note(tmp_path) == "auto: the any-view model; adapting"  # Auto's choice first
    (tmp_path / "synthesis.json").write_text("[1, 2")
    assert S.run_note(tmp_path) == ""


class _FakeWM:
    def __init__(self):
        self.calls = []

    def progress_begin(self, a, b):
        self.calls.append("begin")

    def progress_update(self, v):
        self.calls.append(("update", v))

    def progress_end(self):
        self.calls.append("end")

    def event_timer_add(self, interval, window=None):
        return object()

    def event_timer_remove(self, timer):
        self.calls.append("timer_remove")

    def modal_handler_add(self, op):
        self.calls.append("modal")


def _modal_driver(Op=None):
    """The Synthesize operator's (or ``Op``'s) own start/on_result on the ProgressOperator machinery, with
    a fake window manager (headless Blender has no event loop or window), as tests/test_modal_operator.py does."""
    import bpy

    from blender_mrvm.operators._modal import ProgressOperator
    from blender_mrvm.operators.synthesize import MRVM_OT_synthesize

    Op = Op or MRVM_OT_synthesize

    class Driver(ProgressOperator):
        props_attr, job_name, cancel_hint = Op.props_attr, Op.job_name, Op.cancel_hint
        start, on_result = Op.start, Op.on_result

        def __init__(self):
            self.reports = []

        def report(self, level, msg):
            self.reports.append((next(iter(level)), msg))

    ctx = types.SimpleNamespace(scene=bpy.context.scene, selected_objects=list(bpy.context.selected_objects),
                                preferences=bpy.context.preferences, window_manager=_FakeWM(), window=None,
                                workspace=types.SimpleNamespace(status_text_set=lambda t: None), screen=None)
    return Driver(), ctx


TIMER, ESC = types.SimpleNamespace(type="TIMER"), types.SimpleNamespace(type="ESC")


def test_operator_modal_progress_and_finish(ready, tmp_path):
    import time

    import bpy

    from blender_mrvm.scene import image_planes as IP

    op, ctx = _modal_driver()
    p = ready.mrvm_novel_views
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"} and p.running
    statuses, deadline, res = [], time.monotonic() + 120, {"RUNNING_MODAL"}
    while res == {"RUNNING_MODAL"} and time.monotonic() < deadline:
        res = op.modal(ctx, TIMER)
        statuses.append(p.status)
    assert res == {"FINISHED"} and not p.running, (res, op.reports)
    assert any(s.startswith("view 1/1 (Target)") and s.endswith("Esc to cancel") for s in statuses), statuses[-5:]
    assert p.status.startswith("1 novel view in collection") and op.reports[-1][0] == "INFO"
    assert len(IP.planes_of(bpy.data.objects["Target"])) == 1
    assert ctx.window_manager.calls[-1] == "end"
    # the scene renders through AgX (Blender's default): the message says the planes show tone-mapped
    assert bpy.context.scene.view_settings.view_transform == "AgX"
    assert "view transform AgX" in p.status and "View Transform Standard" in p.status, p.status


def test_colour_management_note_names_what_changes_the_planes(empty_scene):
    """Planes placed by the panel in a scene under AgX (Blender's default since 4.0) rendered the synthesized white
    as 197 of 255 and shifted hues, and nothing said so (``synthesize --blend`` sets Standard for its own file; the
    panel leaves the artist's scene as it is): the success message names what the colour management changes."""
    from blender_mrvm.scene.image_planes import colour_management_note

    vs = empty_scene.view_settings
    vs.view_transform = "Standard"
    assert colour_management_note(empty_scene) == ""
    vs.exposure = 1.5
    assert "exposure 1.5" in colour_management_note(empty_scene)
    vs.exposure, vs.view_transform = 0.0, "Filmic"
    assert "view transform Filmic" in colour_management_note(empty_scene)


def test_operator_modal_escape_stops_the_worker_and_adds_nothing(ready, tmp_path, monkeypatch):
    import tempfile

    from blender_mrvm import worker as Wk

    jobs = tmp_path / "jobs"
    jobs.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(jobs))
    procs = []
    real = Wk.run_worker
    monkeypatch.setattr(Wk, "run_worker", lambda *a, **k: real(*a, on_start=procs.append, **k))
    op, ctx = _modal_driver()
    before = _state()
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"}
    assert op.modal(ctx, TIMER) == {"RUNNING_MODAL"}
    assert len(procs) == 1 and procs[0].poll() is None, "the worker is running"
    assert op.modal(ctx, ESC) == {"CANCELLED"}
    assert procs[0].poll() is not None, "Esc ended the worker process"
    assert op.reports[-1] == ("WARNING", "Synthesis cancelled; nothing was added")
    assert _state() == before and not ready.mrvm_novel_views.running
    assert not list(jobs.glob("mrvm_synth_*")), "the job folder is removed"


def test_operator_writes_the_job_for_the_worker(ready, tmp_path):
    import bpy

    from blender_mrvm.datasets.novel_views import read_targets
    from blender_mrvm.operators import synthesize as S

    p = ready.mrvm_novel_views
    p.reference_source, p.target_source, p.orbit_count, p.save_depth = "SCENE", "ORBIT", 3, True
    job = S.plan_from_props(bpy.context)
    assert job.reference_cameras == ("Ref0", "Ref1") and len(job.targets) == 3
    before = _state()
    args = S.write_job(bpy.context, job, tmp_path / "job")
    assert _state() == before, "writing the job creates nothing in the scene (orbit cameras come with the results)"
    targets, depth = read_targets(tmp_path / "job" / "targets.json")
    assert depth and [t.name for t in targets] == ["MRVM orbit 000", "MRVM orbit 001", "MRVM orbit 002"]
    assert args == ["--references", str(tmp_path / "job" / "references"), "--views", "0", "1",
                    "--targets", str(tmp_path / "job" / "targets.json"), "--checkpoint", p.checkpoint,
                    "--device", "auto", "--ref-size", "0", "--quality", "full", "--adapt-steps", "0",
                    "--nearest", "0", "--reproject", "auto", "--precision", "auto",
                    "--out", str(tmp_path / "job" / "out")]
    p.quality = "PREVIEW"  # the panel's Quality reaches the worker
    assert "preview" == S.write_job(bpy.context, S.plan_from_props(bpy.context), tmp_path / "job_q")[-11]
    p.quality = "FULL"
    p.adapt_steps = 40  # and its Adapt steps
    assert S.write_job(bpy.context, S.plan_from_props(bpy.context), tmp_path / "job_a")[-9] == "40"
    p.nearest = 3  # and its references per view
    assert S.write_job(bpy.context, S.plan_from_props(bpy.context), tmp_path / "job_n")[-7] == "3"
    p.nearest = 0
    p.photo_colours = "OFF"  # and its Photo colours
    assert S.write_job(bpy.context, S.plan_from_props(bpy.context), tmp_path / "job_p")[-5] == "off"
    p.photo_colours = "AUTO"
    p.precision = "BF16"  # and its Precision, with the command's own choices (models.precision.SYNTH_PRECISIONS)
    assert S.write_job(bpy.context, S.plan_from_props(bpy.context), tmp_path / "job_b")[-3] == "bf16"
    p.precision = "AUTO"
    from blender_mrvm.models.precision import SYNTH_PRECISIONS

    assert [i.identifier.lower() for i in p.bl_rna.properties["precision"].enum_items] == list(SYNTH_PRECISIONS)
    p.reference_source, p.reference_views = "DATASET", "all"  # every view of the folder: --views all
    job = S.plan_from_props(bpy.context)
    assert job.views == () and S.write_job(bpy.context, job, tmp_path / "job_all")[2:4] == ["--views", "all"]
    p.adapt_steps = 0
    # Reference size: auto (0, the model's training size for larger references), as they are (-1), custom.
    for sizing, want in [("NATIVE", "-1"), ("CUSTOM", "96")]:
        p.reference_sizing, p.reference_size = sizing, 96
        args = S.write_job(bpy.context, S.plan_from_props(bpy.context), tmp_path / f"job_{sizing}")
        assert args[args.index("--ref-size") + 1] == want
    p.reference_sizing = "AUTO"


def test_operator_bad_input(ready, tmp_path, prefs, bare_python):
    import bpy

    p = ready.mrvm_novel_views
    # No camera selected.
    for o in ready.objects:
        o.select_set(False)
    with pytest.raises(RuntimeError, match=r"poll\(\) Select the target cameras \(or choose Targets: Orbit\)"):
        bpy.ops.mrvm.synthesize()  # the button is greyed out, with the reason
    bpy.data.objects["Target"].select_set(True)
    # References without poses, a view that is not there, a folder that is not a dataset object.
    pose1 = Path(p.dataset_dir) / "pose" / "000001.txt"
    saved = pose1.read_bytes()
    pose1.unlink()
    _fails("reference view 1 of .* has no pose")
    pose1.write_bytes(saved)
    p.reference_views = "0 7"
    _fails("reference view 7 does not exist")
    p.reference_views = "0 1"
    p.dataset_dir = str(tmp_path)
    _fails("is not an object folder")
    # Scene cameras whose image does not exist.
    p.reference_source = "SCENE"
    (tmp_path / "ref1.png").unlink()
    _fails("the reference image of camera 'Ref1' does not exist")
    p.reference_source, p.dataset_dir = "DATASET", str(tmp_path / "refs")
    # Checkpoints: a missing file; none chosen and none shipped.
    p.checkpoint = str(tmp_path / "missing.safetensors")
    _fails("checkpoint .*missing.safetensors does not exist")
    p.checkpoint = ""
    from blender_mrvm.operators.synthesize import default_checkpoint, plan_from_props

    if default_checkpoint() is None:
        _fails("no checkpoint chosen, and this version ships no trained model yet")
    else:  # empty = the shipped model the worker picks by the cameras (auto, the default), or the one chosen
        assert p.shipped_model == "auto" and plan_from_props(bpy.context).checkpoint == "shipped:auto"
        from blender_mrvm.panels.novel_views import MRVM_PT_novel_views as NVP
        from blender_mrvm.models.pretrained import FIGURES as FIG

        assert FIG["auto"] in " ".join(e[1] for e in _draw(NVP) if e[0] == "label")  # over several lines
        p.shipped_model = "nerformer_mrvm"
        assert plan_from_props(bpy.context).checkpoint == default_checkpoint()
    from blender_mrvm.models.pretrained import FIGURES, shipped_or_none
    from blender_mrvm.panels.novel_views import MRVM_PT_novel_views

    from blender_mrvm.models.pretrained import SHIPPED, SHIPPED_NAMED
    from blender_mrvm.props import SHIPPED_MODELS

    assert [e[0] for e in SHIPPED_MODELS] == ["auto", *SHIPPED, *SHIPPED_NAMED]  # the panel offers what is shipped
    for name in [k for k, *_ in SHIPPED_MODELS[2:]]:  # the panel's other shipped models: chosen by name, figures shown
        p.shipped_model = name
        if shipped_or_none(name) is not None:
            assert plan_from_props(bpy.context).checkpoint == shipped_or_none(name)
            assert FIGURES[name] in " ".join(e[1] for e in _draw(MRVM_PT_novel_views) if e[0] == "label")
    p.shipped_model = "nerformer_mrvm"
    p.checkpoint = str(tmp_path / "run")
    # A checkpoint that does not load: the worker's one-line error, nothing added.
    (tmp_path / "junk.safetensors").write_bytes(b"junk" * 8)
    p.checkpoint = str(tmp_path / "junk.safetensors")
    _fails("checkpoint .*junk.safetensors does not load")
    import torch
    from safetensors.torch import save_file

    save_file({"w": torch.zeros(2)}, str(tmp_path / "other.safetensors"), metadata={"format": "someone.else"})
    p.checkpoint = str(tmp_path / "other.safetensors")
    _fails("other.safetensors is not a blender_mrvm model checkpoint")
    p.checkpoint = str(tmp_path / "run")
    # The plane behind the camera's far clip.
    p.plane_distance = 5000.0
    _fails("plane distance 5000 is outside camera 'Target'")
    p.plane_distance = 1.0
    # torch missing in the worker Python.
    prefs.python_path = bare_python
    _fails("torch, safetensors, numpy, PIL, scipy missing in the worker Python")
