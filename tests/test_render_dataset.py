"""Rendering a dataset end to end: files, formats, multi-view consistency, resume, shards, sources."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.progress import run_to_end
from tests.helpers import depth_consistency, write_mesh

pytestmark = pytest.mark.slow


def _render(**kw):
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    kw.setdefault("resolution", (64, 64))
    kw.setdefault("samples", 8)
    return run_to_end(render_dataset(RenderConfig(**kw)))


def _material(name: str):
    """A new material with its node tree, in any Blender (before 5.0 a new material has none)."""
    import bpy

    from blender_mrvm.scene import compat

    mat = bpy.data.materials.new(name)
    compat.node_tree(mat)
    return mat


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True)
    tmp = tmp_path_factory.mktemp("ds")
    mesh = write_mesh(tmp / "meshes" / "widget.ply")
    summary = _render(out=tmp / "data", sources=(str(mesh),), views=8, rig="sphere", resolution=(96, 80), seed=3)
    return tmp / "data", summary, mesh


def test_layout_and_meta(dataset):
    root, summary, _ = dataset
    assert summary.views_rendered == 8 and summary.objects == ["custom/widget"]
    obj = root / "custom" / "widget"
    for k in F.VIEW_DIRS:
        assert len(list((obj / k).iterdir())) == 8, k
    meta = json.loads((obj / "meta.json").read_text())
    assert meta["complete"] and meta["n_views"] == 8 and meta["labels"] == {"0": "background", "1": "custom"}
    assert 0 < meta["near"] < meta["far"]
    # ShapeNet normalization: bbox centred on the origin with unit diagonal
    lo, hi = np.array(meta["bbox"])
    assert np.allclose((lo + hi) / 2, 0, atol=1e-6) and np.isclose(np.linalg.norm(hi - lo), 1.0, atol=1e-6)
    assert (root / "splits" / "train.lst").exists()
    entries = sum((F.read_split(root, s) for s in F.SPLITS), [])
    assert entries == ["custom/widget"]
    assert json.loads((root / F.ROOT_MANIFEST).read_text())["settings"]["views"] == 8


def test_images_masks_depth_agree(dataset):
    root, _, _ = dataset
    ov = F.read_object(root / "custom" / "widget")
    for i in range(len(ov.indices)):
        rgb, mask, depth, nrm = ov.rgb(i), ov.mask(i), ov.depth(i), ov.normals(i)
        assert rgb.shape == (80, 96, 3) and rgb.dtype == np.uint8
        assert mask.shape == (80, 96) and depth.dtype == np.float32
        fg = mask > 0
        assert 0.05 < fg.mean() < 0.95, "object should fill a good part of the frame"
        assert ((depth > 0) == fg).all()
        from scipy.ndimage import binary_dilation

        far_bg = ~binary_dilation(fg, iterations=2)  # anti-aliased edges aside
        assert (rgb[far_bg] == 255).all(), "background is white"
        assert (rgb[fg].mean(axis=-1) < 250).mean() > 0.95, "the grey object is not white"
        n = np.linalg.norm(nrm[fg], axis=-1)
        assert np.allclose(n, 1, atol=1e-3) and (nrm[~fg] == 0).all()
        # the object stays inside near/far
        assert depth[fg].min() >= ov.meta["near"] - 1e-4 and depth[fg].max() <= ov.meta["far"] + 1e-4
        # world normals face the camera on visible surfaces
        o, d = C.rays_opencv(ov.intrinsics, ov.c2w_opencv[i])
        assert (np.einsum("...k,...k", nrm, d)[fg] < 0.2).mean() > 0.97


def test_multiview_depth_consistency(dataset):
    root, _, _ = dataset
    ov = F.read_object(root / "custom" / "widget")
    centres = np.array([p[:3, 3] for p in ov.c2w_opencv])
    errs = []
    for a in range(len(centres)):
        d = np.linalg.norm(centres - centres[a], axis=1)
        d[a] = np.inf
        b = int(np.argmin(d))
        e = depth_consistency(ov, a, b)
        assert len(e) > 100
        errs.append(np.median(e))
    assert max(errs) < 0.005, f"median relative depth error per pair: {np.round(errs, 5)}"


def test_srn_and_transforms_give_same_rays(dataset):
    root, _, _ = dataset
    obj = root / "custom" / "widget"
    intr_srn = F.read_srn_intrinsics(obj / "intrinsics.txt")
    frames = F.read_transforms(obj / "transforms.json")
    assert len(frames) == 8
    for i, fr in enumerate(frames):
        pose = F.read_srn_pose(obj / "pose" / f"{i:06d}.txt")
        o1, d1 = C.rays_opencv(intr_srn, pose)
        o2, d2 = C.rays_opencv(fr.intrinsics, fr.c2w_opencv)
        assert np.allclose(o1, o2, atol=1e-6) and np.allclose(d1, d2, atol=1e-6)
        assert (obj / fr.file_path).is_file()
    # transforms.json uses OpenGL camera axes: the camera looks down its -z towards the object
    raw = json.loads((obj / "transforms.json").read_text())
    m = np.array(raw["frames"][0]["transform_matrix"])
    assert np.dot(-m[:3, 2], -m[:3, 3]) > 0.99 * np.linalg.norm(m[:3, 3])


def test_resume_skips_finished_views_and_redoes_missing(dataset, tmp_path):
    root, _, mesh = dataset
    work = tmp_path / "copy"
    shutil.copytree(root, work)
    obj = work / "custom" / "widget"
    kw = dict(out=work, sources=(str(mesh),), views=8, rig="sphere", resolution=(96, 80), seed=3)
    s = _render(**kw)
    assert (s.views_rendered, s.views_skipped) == (0, 8)
    before = (obj / "rgb" / "000002.png").read_bytes()
    (obj / "rgb" / "000005.png").unlink()
    meta = json.loads((obj / "meta.json").read_text())
    meta["complete"] = False
    (obj / "meta.json").write_text(json.dumps(meta))
    s = _render(**kw)
    assert (s.views_rendered, s.views_skipped) == (1, 7)
    assert (obj / "rgb" / "000005.png").is_file() and (obj / "rgb" / "000002.png").read_bytes() == before


def test_cancel_keeps_finished_views_and_resumes(tmp_path, bpy_empty):
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    import bpy

    mesh = write_mesh(tmp_path / "m.stl")
    n_obj = len(bpy.data.objects)
    cfg = RenderConfig(out=tmp_path / "d", sources=(str(mesh),), views=5, resolution=(32, 32), samples=4)
    gen = render_dataset(cfg)
    for _ in range(3):  # start + 2 views
        next(gen)
    gen.close()
    obj = tmp_path / "d" / "custom" / "m"
    assert not json.loads((obj / "meta.json").read_text())["complete"]
    assert sorted(p.name for p in (obj / "pose").iterdir()) == ["000000.txt", "000001.txt"]
    assert not list(obj.rglob(".*")), "no temporary files left behind"
    assert len(bpy.data.objects) == n_obj and len(bpy.data.scenes) == 1, "private scene cleaned up"
    s = run_to_end(render_dataset(cfg))
    assert (s.views_rendered, s.views_skipped) == (3, 2)
    assert json.loads((obj / "meta.json").read_text())["complete"]


def test_shards_partition_objects(tmp_path, bpy_empty):
    meshes = [write_mesh(tmp_path / "m" / f"o{i}.ply") for i in range(3)]
    done = []
    for i in range(2):
        s = _render(out=tmp_path / "d", sources=(str(tmp_path / "m"),), views=1, resolution=(16, 16),
                    samples=1, shard=(i, 2))
        done.append(s.objects)
    assert sorted(done[0] + done[1]) == [f"custom/o{i}" for i in range(3)]
    assert not set(done[0]) & set(done[1]) and len(meshes) == 3
    assert sorted(sum((F.read_split(tmp_path / "d", s) for s in F.SPLITS), [])) == sorted(done[0] + done[1])


def test_the_procedural_fingerprint_is_the_same_in_another_process(bpy_empty):
    """The built object's hash must not change from one process to the next for the same library: bmesh's bevel
    is not bit-exact across processes (a few vertices a float32 step apart, in another order), and hashing its raw
    vertices made a plain rerun of make-shapenet refuse a rifle or a telephone as 'changed' most of the time."""
    import subprocess
    import sys

    from blender_mrvm.scene import objects as O

    specs = [("rifle", s) for s in range(6)] + [("telephone", s) for s in range(6)] + [("chair", 3), ("bench", 1)]
    code = ("import bpy, json; from blender_mrvm.scene import objects as O; bpy.ops.wm.read_homefile(use_empty=True);"
            f"print(json.dumps([O.appearance_fingerprint(O.ObjectSpec(kind='procedural', category=c, object_id='x', "
            f"seed=s)) for c, s in {specs!r}]))")
    there = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                      env={**os.environ, "OMP_NUM_THREADS": "1"}).stdout.strip().splitlines()[-1])
    here = [O.appearance_fingerprint(O.ObjectSpec(kind="procedural", category=c, object_id="x", seed=s))
            for c, s in specs]
    assert here == there
    assert len(set(here)) == len(here)


def test_a_shard_finishing_while_another_writes_the_lists_is_not_left_out(tmp_path, bpy_empty, monkeypatch):
    """Shard A reads the folder, shard B finishes its last object and writes the lists, then A writes its own
    (read before B's object was finished): B's object was missing from the lists although it is on disk."""
    from blender_mrvm.scene import render as R

    meshes = [write_mesh(tmp_path / "m" / f"o{i}.ply") for i in range(2)]
    out = tmp_path / "d"
    _render(out=out, sources=(str(tmp_path / "m"),), views=1, resolution=(16, 16), samples=1)
    b_meta = out / "custom" / "o1" / "meta.json"
    finished = json.loads(b_meta.read_text())
    b_meta.write_text(json.dumps({**finished, "complete": False}))  # B is still rendering o1 when A reads

    real_write = F.write_split
    b_done = []

    def write_split(root, split, entries):  # between A's reading and A's writing, B finishes and writes
        if not b_done:
            b_done.append(1)
            b_meta.write_text(json.dumps(finished))
            b_sees = {sp: [] for sp in F.SPLITS}  # what B's lists hold: both objects
            for o in ("o0", "o1"):
                b_sees[json.loads((out / "custom" / o / "meta.json").read_text())["split"]].append(f"custom/{o}")
            for sp, lst in b_sees.items():
                real_write(root, sp, lst)
        real_write(root, split, entries)

    monkeypatch.setattr(F, "write_split", write_split)
    R.write_splits(out)
    listed = sorted(sum((F.read_split(out, sp) for sp in F.SPLITS), []))
    assert b_done and listed == ["custom/o0", "custom/o1"] and len(meshes) == 2


@pytest.mark.parametrize("ext", [".obj", ".ply", ".stl", ".glb", ".off"])
def test_every_mesh_format_loads_and_normalizes(tmp_path, bpy_empty, ext):
    mesh = write_mesh(tmp_path / f"thing{ext}")
    _render(out=tmp_path / "d", sources=(str(mesh),), views=1, resolution=(24, 24), samples=1)
    meta = json.loads((tmp_path / "d" / "custom" / "thing" / "meta.json").read_text())
    lo, hi = np.array(meta["bbox"])
    assert np.isclose(np.linalg.norm(hi - lo), 1.0, atol=1e-5)
    assert F.read_png(tmp_path / "d" / "custom" / "thing" / "mask" / "000000.png").max() == 1


@pytest.mark.parametrize("version,model_file", [("v2", "models/model_normalized.obj"),
                                                ("v1", "model.obj")])  # v1: the NMR renders' source
def test_shapenet_folder_layout(tmp_path, bpy_empty, version, model_file):
    root = tmp_path / f"ShapeNetCore.{version}"
    for synset, model in (("03001627", "abc123"), ("04379243", "def456")):
        write_mesh(root / synset / model / model_file)
    s = _render(out=tmp_path / "d", sources=(str(root),), views=1, resolution=(16, 16), samples=1)
    assert sorted(s.objects) == ["chair/abc123", "table/def456"]
    s = _render(out=tmp_path / "d2", sources=(str(root / "03001627"),), views=1, resolution=(16, 16), samples=1)
    assert s.objects == ["chair/abc123"]


def test_selected_objects_and_scene_rig_leave_user_scene_untouched(tmp_path, bpy_empty):
    import bpy
    from mathutils import Matrix

    from blender_mrvm.scene.camera import apply_pose, new_camera

    scene = bpy_empty
    bpy.ops.mesh.primitive_monkey_add(location=(2.0, 1.0, 0.5), rotation=(0.3, 0.2, 0.1))
    monkey = bpy.context.active_object
    monkey.scale = (2.0, 2.0, 2.0)
    bpy.ops.mesh.primitive_cube_add(location=(-3, 0, 0))
    cube = bpy.context.active_object
    cube.select_set(False)
    monkey.select_set(True)
    cams = []
    for k, eye in enumerate([(8, 1, 3), (2, 9, 1), (-5, 5, 4)]):
        cam = new_camera(f"Cam{k}", scene.collection)
        cam.data.lens = 35 + 10 * k
        apply_pose(cam, C.look_at_opencv(eye, target=(2.0, 1.0, 0.5)))
        cams.append(cam)
    before = [Matrix(o.matrix_world) for o in (monkey, cube)]
    n_data = (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.materials), len(bpy.data.scenes))
    _render(out=tmp_path / "d", sources=("selected",), rig="scene", resolution=(48, 40), samples=2)
    assert [Matrix(o.matrix_world) for o in (monkey, cube)] == before
    assert (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.materials), len(bpy.data.scenes)) == n_data
    ov = F.read_object(tmp_path / "d" / "custom" / "Suzanne")
    assert len(ov.indices) == 3 and ov.meta["scene_cameras"] == ["Cam0", "Cam1", "Cam2"]
    assert ov.meta["per_view_intrinsics"]
    norm = np.array(ov.meta["normalization"]["matrix"])
    frames = F.read_transforms(tmp_path / "d" / "custom" / "Suzanne" / "transforms.json")
    for k, cam in enumerate(cams):
        # the written pose is the scene camera mapped into the normalized frame
        c2w = C.opencv_from_blender(np.array(cam.matrix_world))
        assert np.allclose(ov.c2w_opencv[k][:3, :3], c2w[:3, :3], atol=1e-6)
        assert np.allclose(ov.c2w_opencv[k][:3, 3], norm[:3, :3] @ c2w[:3, 3] + norm[:3, 3], atol=1e-5)
        assert np.isclose(frames[k].intrinsics.fx, cam.data.lens / 36 * 48)
        assert ov.mask(k).any(), "the monkey is in view of every camera"


def test_what_the_user_makes_while_views_render_is_theirs(tmp_path, bpy_empty):
    """The panel renders one view a step, modally: what the user (or another job) made between the steps was
    removed with the session's own data when the object finished (a new object, material, scene, image)."""
    import bpy

    from blender_mrvm.scene.render import RenderConfig, render_dataset

    mesh = write_mesh(tmp_path / "m.ply")
    before = {k: len(getattr(bpy.data, k)) for k in ("objects", "meshes", "materials", "scenes", "cameras", "worlds")}
    gen = render_dataset(RenderConfig(out=tmp_path / "d", sources=(str(mesh), "procedural:chair:0"), views=2,
                                      resolution=(16, 16), samples=1))
    next(gen), next(gen)  # started, first view of the first object
    me = bpy.data.meshes.new("UserMesh")
    user = bpy.data.objects.new("UserCube", me)
    bpy.context.scene.collection.objects.link(user)
    bpy.data.materials.new("UserMaterial")
    bpy.data.scenes.new("UserScene")
    bpy.data.images.new("UserImage", 4, 4)
    run_to_end(gen)
    for name, kind in (("UserCube", "objects"), ("UserMesh", "meshes"), ("UserMaterial", "materials"),
                       ("UserScene", "scenes"), ("UserImage", "images")):
        assert name in getattr(bpy.data, kind), name
    after = {k: len(getattr(bpy.data, k)) for k in before}
    assert after == {k: v + (k in ("objects", "meshes", "materials", "scenes")) for k, v in before.items()}


def test_rgba_and_workbench(tmp_path, bpy_empty):
    mesh = write_mesh(tmp_path / "w.ply")
    _render(out=tmp_path / "d", sources=(str(mesh),), views=2, resolution=(48, 48), samples=2, rgba=True,
            engine="BLENDER_WORKBENCH")
    obj = tmp_path / "d" / "custom" / "w"
    rgba = F.read_png(obj / "rgb" / "000000.png")
    mask = F.read_png(obj / "mask" / "000000.png")
    assert rgba.shape == (48, 48, 4)
    from scipy.ndimage import binary_erosion

    inner, outer = binary_erosion(mask > 0, iterations=2), binary_erosion(mask == 0, iterations=2)  # AA edges aside
    # opaque inside: 255, or 254 under Blender 4.5, whose Workbench leaves its film's alpha a hair under 1
    assert inner.sum() > 20 and (rgba[..., 3][outer] == 0).all() and (rgba[..., 3][inner] >= 254).all()
    assert (F.read_depth(obj / "depth" / "000000.exr") > 0).sum() == (mask > 0).sum()


# --------------------------------------------------------------------------------------------
# Nothing lost, one clear line (issue 14)
# --------------------------------------------------------------------------------------------

def test_ctrl_c_stops_between_views_and_keeps_finished_ones(tmp_path, bpy_empty):
    """SIGINT to a headless render-dataset stops it after the view in flight (Cycles used to
    swallow the KeyboardInterrupt and render to the end); the finished views resume."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from blender_mrvm.scene.render import RenderConfig, render_dataset, view_intact

    root = Path(__file__).resolve().parents[1]
    mesh = write_mesh(tmp_path / "m.ply")
    out = tmp_path / "d"
    args = ["--source", str(mesh), "--views", "30", "--resolution", "64", "--samples", "32", "--out", str(out)]
    env = dict(os.environ, PYTHONPATH=str(root), TQDM_DISABLE="1")
    proc = subprocess.Popen([sys.executable, "-m", "blender_mrvm", "render-dataset", *args], cwd=root, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    poses = out / "custom" / "m" / "pose"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if poses.is_dir() and len(list(poses.glob("*.txt"))) >= 2:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the render ended before it could be interrupted"
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err[-2000:]
    assert [line for line in err.splitlines() if line.startswith("error:")] == \
        ["error: interrupted; the views finished so far are kept; the same command goes on from them"]
    obj = out / "custom" / "m"
    kept = sorted(p.name for p in poses.iterdir())
    assert 2 <= len(kept) < 30, kept
    assert kept == [f"{i:06d}.txt" for i in range(len(kept))]
    assert all(view_intact(obj, i) for i in range(len(kept)))
    assert not json.loads((obj / "meta.json").read_text())["complete"]
    assert not list(obj.rglob(".*")), "no temporary files left behind"
    s = run_to_end(render_dataset(RenderConfig(out=out, sources=(str(mesh),), views=30, resolution=(64, 64),
                                               samples=32)))
    assert (s.views_rendered, s.views_skipped) == (30 - len(kept), len(kept))


def test_resume_renders_a_truncated_view_again(dataset, tmp_path):
    root, _, mesh = dataset
    work = tmp_path / "copy"
    shutil.copytree(root, work)
    obj = work / "custom" / "widget"
    kw = dict(out=work, sources=(str(mesh),), views=8, rig="sphere", resolution=(96, 80), seed=3)
    png = obj / "rgb" / "000003.png"
    whole = png.read_bytes()
    png.write_bytes(whole[: len(whole) // 2])  # a damaged copy: the file exists and is not empty
    exr = obj / "depth" / "000006.exr"
    exr.write_bytes(exr.read_bytes()[:-200])
    s = _render(**kw)
    assert (s.views_rendered, s.views_skipped) == (2, 6)
    assert F.read_png(png).shape == (80, 96, 3) and F.read_depth(exr).shape == (80, 96)
    assert json.loads((obj / "meta.json").read_text())["complete"]


def test_resume_refuses_views_of_a_changed_source(tmp_path, bpy_empty):
    from blender_mrvm.errors import OutputError
    from tests.helpers import asymmetric_mesh

    mesh = write_mesh(tmp_path / "thing.ply")
    kw = dict(out=tmp_path / "d", sources=(str(mesh),), views=2, resolution=(16, 16), samples=1)
    _render(**kw)
    meta_path = tmp_path / "d" / "custom" / "thing" / "meta.json"
    first = json.loads(meta_path.read_text())["source_hash"]
    assert first.startswith("sha256:")
    s = _render(**kw)
    assert (s.views_rendered, s.views_skipped) == (0, 2), "same file: resumed"
    changed = asymmetric_mesh()
    changed.apply_scale((1.0, 1.5, 1.0))
    write_mesh(mesh, changed)  # the same path, other content
    with pytest.raises(OutputError, match="changed"):
        _render(**kw)
    s = _render(**kw, force=True)
    assert s.views_rendered == 2 and json.loads(meta_path.read_text())["source_hash"] != first
    # a dataset rendered before source hashes were kept still resumes
    meta = json.loads(meta_path.read_text())
    del meta["source_hash"]
    meta_path.write_text(json.dumps(meta))
    assert _render(**kw).views_skipped == 2


def test_a_resume_follows_the_run_where_no_pixel_changes(tmp_path, bpy_empty):
    """The split, the spelling of the mesh's path and float rounding of the settings change no pixel: a finished
    object resumes (it was refused, and --force deleted its views), and its record follows the run."""
    from blender_mrvm.datasets.loaders import load_dataset

    mesh = write_mesh(tmp_path / "m" / "thing.ply")
    kw = dict(out=tmp_path / "d", views=2, resolution=(16, 16), samples=1, fov_deg=40.0)
    _render(sources=(str(mesh),), split="train", **kw)
    meta_path = tmp_path / "d" / "custom" / "thing" / "meta.json"
    respelled = str(tmp_path / "m" / ".." / "m" / "thing.ply")
    s = _render(sources=(respelled,), split="test", **{**kw, "fov_deg": 39.99999883637168})  # the panel's 40
    assert (s.views_rendered, s.views_skipped) == (0, 2)
    meta = json.loads(meta_path.read_text())
    assert meta["source"] == respelled and meta["split"] == "test"
    assert F.read_split(tmp_path / "d", "test") == ["custom/thing"] and F.read_split(tmp_path / "d", "train") == []
    assert any("now in 'test'" in w for w in s.warnings)
    # an object of the split started after the lists were written (an interrupted run, a failed shard) is found
    other = tmp_path / "d" / "custom" / "other"
    shutil.copytree(meta_path.parent, other)
    (other / "meta.json").write_text(json.dumps({**meta, "object_id": "other", "complete": False}))
    with pytest.raises(InputError, match="half-rendered.*custom/other"):
        load_dataset(tmp_path / "d", "test")


def test_scene_cameras_and_selected_materials_are_part_of_what_views_were_rendered_from(tmp_path, bpy_empty):
    """Another set of scene cameras is another dataset, and a selected object's changed material makes its views
    stale: both resumed before, mixing views of the two (or keeping the old ones whole)."""
    import bpy

    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.camera import apply_pose, new_camera

    scene = bpy_empty
    bpy.ops.mesh.primitive_monkey_add()
    monkey = bpy.context.active_object
    mat = _material("paint")
    monkey.data.materials.append(mat)
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.8, 0.1, 0.1, 1.0)
    cams = []
    for k, eye in enumerate([(6, 1, 2), (1, 6, 1)]):
        cams.append(new_camera(f"Cam{k}", scene.collection))
        apply_pose(cams[-1], C.look_at_opencv(eye, target=(0.0, 0.0, 0.0)))
    kw = dict(out=tmp_path / "d", sources=("selected",), rig="scene", resolution=(16, 16), samples=1)
    _render(**kw)
    assert _render(**kw).views_skipped == 2, "nothing changed: resumed"
    apply_pose(cams[1], C.look_at_opencv((1, 6, 3), target=(0.0, 0.0, 0.0)))
    with pytest.raises(OutputError, match="other settings.*scene_cameras"):
        _render(**kw)
    apply_pose(cams[1], C.look_at_opencv((1, 6, 1), target=(0.0, 0.0, 0.0)))
    assert _render(**kw).views_skipped == 2, "the same cameras again"
    bsdf.inputs["Base Color"].default_value = (0.1, 0.1, 0.8, 1.0)
    with pytest.raises(OutputError, match="materials"):
        _render(**kw)
    s = _render(**kw, force=True)
    assert s.views_rendered == 2
    # a dataset rendered before either was kept still resumes
    root, obj = tmp_path / "d" / F.ROOT_MANIFEST, tmp_path / "d" / "custom" / "Suzanne" / "meta.json"
    for path in (root, obj):
        rec = json.loads(path.read_text())
        del rec["settings"]["scene_cameras"]
        rec.pop("appearance_hash", None)
        path.write_text(json.dumps(rec))
    assert _render(**kw).views_skipped == 2


def test_an_unfinished_object_framed_by_other_bounds_is_not_resumed(tmp_path, bpy_empty):
    """An object interrupted under a version that framed it by other bounds (before session 52: vertices no face
    uses, collection instances left out) would mix views of two normalizations: refused, --force renders it."""
    from blender_mrvm.errors import OutputError

    mesh = write_mesh(tmp_path / "thing.ply")
    kw = dict(out=tmp_path / "d", sources=(str(mesh),), views=2, resolution=(16, 16), samples=1)
    _render(**kw)
    obj = tmp_path / "d" / "custom" / "thing"
    meta = json.loads((obj / "meta.json").read_text())
    meta["complete"] = False
    meta["normalization"]["matrix"] = (2.0 * np.array(meta["normalization"]["matrix"])).tolist()
    (obj / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(OutputError, match="normalized to other bounds"):
        _render(**kw)
    assert _render(**kw, force=True).views_rendered == 2


def test_a_procedural_object_built_otherwise_by_a_later_library_is_not_resumed(tmp_path, bpy_empty, monkeypatch):
    """An object's generator parameters can stay the same while a later version of the library builds other geometry
    from them: an object interrupted under one version and resumed under the other would mix the two. The built
    object is hashed (meta.json's appearance_hash); a dataset rendered before that was kept still resumes."""
    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.procedural import _registry

    kw = dict(out=tmp_path / "d", sources=("procedural:table:3",), views=2, resolution=(16, 16), samples=1)
    _render(**kw)
    meta_path = next((tmp_path / "d").glob("*/*/meta.json"))
    meta = json.loads(meta_path.read_text())
    assert meta["appearance_hash"].startswith("sha256:")
    meta["complete"] = False  # interrupted after its views
    meta_path.write_text(json.dumps(meta))
    assert _render(**kw).views_skipped == 2, "the same library: resumed"

    gen = _registry.GENERATORS["table"]

    def with_a_spike(p, rng, m):  # the same parameters, other geometry: what a library change looks like
        kinds = gen.fn(p, rng, m)
        m._verts[0] = m._verts[0] * np.array([1.0, 1.0, 1.3])
        return kinds

    monkeypatch.setitem(_registry.GENERATORS, "table", dataclasses.replace(gen, fn=with_a_spike))
    with pytest.raises(OutputError, match="as it was before it changed"):
        _render(**kw)
    assert _render(**kw, force=True).views_rendered == 2
    monkeypatch.undo()
    meta = json.loads(meta_path.read_text())
    meta.pop("appearance_hash")  # rendered before the built object was hashed
    meta_path.write_text(json.dumps(meta))
    assert _render(**kw).views_skipped == 2, "finished: its views are of one version, kept"
    meta["complete"] = False  # interrupted under that version: resumed, it mixed two chairs (an upgrade review)
    meta_path.write_text(json.dumps(meta))
    with pytest.raises(OutputError, match="unfinished views of .* from a version that did not record the object"):
        _render(**kw)
    assert _render(**kw, force=True).views_rendered == 2


def test_shards_starting_into_one_new_folder_do_not_refuse_each_other(tmp_path):
    """The other shard's write probe or half-written manifest in a new folder is not 'another dataset's files'."""
    from blender_mrvm.scene.render import RenderConfig, prepare_output

    out = tmp_path / "d"
    out.mkdir()
    (out / ".write-test-abc123").write_text("")
    (out / f".{F.ROOT_MANIFEST}.x1y2.json").write_text("{")
    prepare_output(RenderConfig(out=out, sources=("procedural:chair:0",), shard=(1, 2)))
    assert (out / F.ROOT_MANIFEST).is_file()


@pytest.mark.parametrize("value", ["nan", "inf", "1e30"])
@pytest.mark.parametrize("ext", [".obj", ".ply", ".off"])
def test_mesh_with_broken_vertices_is_refused(tmp_path, bpy_empty, capsys, value, ext):
    from blender_mrvm.cli import main
    from tests.helpers import asymmetric_mesh

    m = asymmetric_mesh()
    v = m.vertices.copy()
    v[5, 0] = float(value)
    path = tmp_path / f"bad{ext}"
    import trimesh

    write_mesh(path, trimesh.Trimesh(v, m.faces, process=False))
    out = tmp_path / "d"
    rc = main(["render-dataset", "--source", str(path), "--views", "2", "--resolution", "16", "--samples", "1",
               "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("error: ") and "bad" + ext in err[0], err
    assert not list(out.glob("*/*/meta.json")), "no dataset recorded"


def test_views_have_a_limit(tmp_path, capsys):
    from blender_mrvm.cli import main

    rc = main(["render-dataset", "--source", "procedural:chair:0", "--views", "100000", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "views" in err[0] and "10000" in err[0], err
    assert not (tmp_path / "d").exists()


def test_skip_bad_meshes_goes_on_past_a_refused_mesh(tmp_path, bpy_empty, capsys):
    """A folder of meshes with one bad file (NaN vertices, an empty file): by default the run stops at it (exit 2),
    naming --skip-bad-meshes; with it the others are rendered and each bad one is named in a warning line."""
    import trimesh

    from blender_mrvm.cli import main
    from tests.helpers import asymmetric_mesh

    src = tmp_path / "meshes"
    m = asymmetric_mesh()
    v = m.vertices.copy()
    v[5, 0] = float("nan")
    write_mesh(src / "a_bad.obj", trimesh.Trimesh(v, m.faces, process=False))
    (src / "b_empty.ply").write_bytes(b"")
    write_mesh(src / "c_good.obj")
    args = ["render-dataset", "--source", str(src), "--views", "2", "--resolution", "16", "--samples", "1"]
    assert main(args + ["--out", str(tmp_path / "strict")]) == 2
    err = capsys.readouterr().err
    assert "a_bad.obj" in err and "the other 2 object(s) without it: --skip-bad-meshes" in err, err
    assert main(args + ["--out", str(tmp_path / "d"), "--skip-bad-meshes"]) == 0
    out, err = capsys.readouterr()
    warn = [ln for ln in err.splitlines() if ln.startswith("warning: ")]
    assert len(warn) == 2 and "a_bad" in warn[0] and "b_empty" in warn[1], err
    assert "1 objects, 2 views rendered, 0 already done, 2 meshes skipped as unusable" in out, out  # in the summary too
    assert [p.parent.name for p in (tmp_path / "d").glob("*/*/meta.json")] == ["c_good"]
    assert F.read_split(tmp_path / "d", "train") + F.read_split(tmp_path / "d", "val") + \
        F.read_split(tmp_path / "d", "test") == ["custom/c_good"]
    # every mesh bad: an empty dataset with exit 0 before; now one error line, and nothing left behind
    (src / "c_good.obj").unlink()
    assert main(args + ["--out", str(tmp_path / "e"), "--skip-bad-meshes"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: every mesh was skipped as unusable (2: ") and not (tmp_path / "e").exists(), err


def _export_in_every_format(folder: Path) -> list[str]:
    """The asymmetric test mesh in a red material, with a point light and a camera beside it, exported by
    Blender in every format render-dataset reads that Blender writes; returns the file names."""
    import addon_utils
    import bpy

    addon_utils.enable("io_scene_fbx", default_set=False)
    bpy.ops.wm.read_homefile(use_empty=True)
    ply = write_mesh(folder / "src.ply")
    bpy.ops.wm.ply_import(filepath=str(ply))
    ply.unlink()
    obj = bpy.context.selected_objects[0]
    mat = _material("red")
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.8, 0.05, 0.05, 1.0)
    obj.data.materials.append(mat)
    bpy.ops.object.light_add(type="POINT", location=(2, -2, 2))
    bpy.context.object.data.energy = 2000.0  # would brighten the object if it were kept
    bpy.ops.object.camera_add(location=(0, -3, 0))
    bpy.ops.object.select_all(action="SELECT")
    bpy.ops.wm.obj_export(filepath=str(folder / "m_obj.obj"))
    bpy.ops.export_scene.fbx(filepath=str(folder / "m_fbx.fbx"))
    bpy.ops.export_scene.gltf(filepath=str(folder / "m_glb.glb"), export_lights=True, export_cameras=True)
    for ext in ("usda", "usdc", "usdz"):
        bpy.ops.wm.usd_export(filepath=str(folder / f"m_{ext}.{ext}"))
    bpy.ops.wm.alembic_export(filepath=str(folder / "m_abc.abc"))
    bpy.ops.wm.read_homefile(use_empty=True)
    return sorted(f.name for f in folder.iterdir() if f.suffix != ".mtl")


def test_every_format_renders_the_same_object(tmp_path, bpy_empty):
    """OBJ, FBX, GLB, USDA/USDC/USDZ and Alembic exports of one object render the same silhouette and bounds;
    the files' own light and camera are dropped (Blender 5.0.1's FBX importer fails on a light unless helped); a
    SketchUp file in the folder is named in a warning, and alone is refused with what to do."""
    from blender_mrvm.errors import InputError

    src = tmp_path / "src"
    src.mkdir()
    names = _export_in_every_format(src)
    assert len(names) == 7, names
    (src / "cone.skp").write_bytes(b"SketchUp Model")
    s = _render(out=tmp_path / "d", sources=(str(src),), views=3, rig="sphere", resolution=(40, 40), samples=2)
    stems = sorted(Path(n).stem for n in names)
    assert sorted(o.split("/")[1] for o in s.objects) == stems
    assert len(s.warnings) == 1 and "cone.skp" in s.warnings[0] and "export it as glTF" in s.warnings[0], s.warnings
    root = tmp_path / "d" / "custom"
    ref = F.read_object(root / "m_obj")
    ref_rgb = np.stack([ref.rgb(i)[..., :3] for i in range(3)]).astype(np.float32) / 255
    ref_mask = np.stack([ref.mask(i) > 0 for i in range(3)])
    assert ref_mask.mean() > 0.1
    for stem in stems:
        ov = F.read_object(root / stem)
        mask = np.stack([ov.mask(i) > 0 for i in range(3)])
        iou = (mask & ref_mask).sum() / (mask | ref_mask).sum()
        assert iou > 0.99, (stem, iou)
        meta = json.loads((root / stem / "meta.json").read_text())
        assert np.allclose(meta["bbox"], json.loads((root / "m_obj" / "meta.json").read_text())["bbox"], atol=1e-4)
        rgb = np.stack([ov.rgb(i)[..., :3] for i in range(3)]).astype(np.float32) / 255
        r, g, b = np.median(rgb[mask], axis=0)
        if stem == "m_abc":  # Alembic carries no materials: the default grey
            assert abs(r - g) < 0.03 and abs(r - b) < 0.03, (stem, r, g, b)
        else:  # red as the OBJ's, at the same brightness (the file's light is not rendered)
            assert r - g > 0.4 and r - b > 0.4, (stem, r, g, b)
            assert np.abs(rgb - ref_rgb)[mask & ref_mask].mean() < 0.03, stem
    only = tmp_path / "only"
    only.mkdir()
    shutil.copy(src / "cone.skp", only / "cone.skp")
    with pytest.raises(InputError, match="export it as glTF"):
        _render(out=tmp_path / "e", sources=(str(only),), views=2)
    with pytest.raises(InputError, match="export it as glTF"):
        _render(out=tmp_path / "e", sources=(str(only / "cone.skp"),), views=2)


def _textured_cube(tex: Path, grouped: bool):
    """A selected cube whose material reads the image file ``tex`` (blue), inside a node group if ``grouped``."""
    import bpy

    F.write_png(tex, np.full((8, 8, 3), (30, 60, 200), np.uint8))
    bpy.ops.mesh.primitive_cube_add()
    mat = _material("paint")
    tree = bpy.data.node_groups.new("paint_group", "ShaderNodeTree") if grouped else mat.node_tree
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = bpy.data.images.load(str(tex))
    colour = node.outputs["Color"]
    if grouped:
        tree.interface.new_socket("Color", in_out="OUTPUT", socket_type="NodeSocketColor")
        tree.links.new(colour, tree.nodes.new("NodeGroupOutput").inputs[0])
        gnode = mat.node_tree.nodes.new("ShaderNodeGroup")
        gnode.node_tree = tree
        colour = gnode.outputs[0]
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    mat.node_tree.links.new(colour, bsdf.inputs["Base Color"])
    bpy.context.active_object.data.materials.append(mat)


def test_images_the_render_reads_are_part_of_what_its_views_were_rendered_from(tmp_path, bpy_empty):
    """The image files the rendered materials read (here a selected object's, through a node group; for files,
    those an importer found by itself) are hashed into meta.json after loading: a resume that would add views
    rendered with another image is refused, a finished object is skipped without loading it. A USD text layer's
    asset paths (its exported texture here) are among its linked files."""
    import bpy

    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.objects import linked_files

    tex = tmp_path / "paint.png"
    _textured_cube(tex, grouped=True)
    kw = dict(out=tmp_path / "d", sources=("selected",), views=3, resolution=(24, 24), samples=1)
    _render(**kw)
    obj = tmp_path / "d" / "custom" / "Cube"
    meta = json.loads((obj / "meta.json").read_text())
    assert meta["rendered_images_hash"].startswith("sha256:")
    rgb = F.read_png(obj / "rgb" / "000000.png")[..., :3].astype(float)
    inside = F.read_png(obj / "mask" / "000000.png") > 0
    assert rgb[inside][:, 2].mean() > rgb[inside][:, 0].mean() + 20, "the image is what colours it"
    F.write_png(tex, np.full((8, 8, 3), (200, 60, 30), np.uint8))
    assert _render(**kw).views_skipped == 3, "a finished object is kept as it was rendered"
    (obj / "rgb" / "000002.png").unlink()  # unfinished: the missing view would be red among blue ones
    with pytest.raises(OutputError, match="other images than its materials read now"):
        _render(**kw)
    assert (obj / "rgb" / "000001.png").is_file(), "nothing is removed without --force"
    assert _render(**kw, force=True).views_skipped == 0
    assert json.loads((obj / "meta.json").read_text())["rendered_images_hash"] != meta["rendered_images_hash"]

    src = tmp_path / "usd"
    src.mkdir()
    bpy.ops.wm.read_homefile(use_empty=True)
    _textured_cube(tex, grouped=False)  # Blender's USD export writes an image read by the BSDF itself
    bpy.ops.wm.usd_export(filepath=str(src / "cube.usda"), selected_objects_only=True, export_materials=True)
    assert linked_files(src / "cube.usda") == [("./textures/paint.png", src / "textures" / "paint.png")]
    bpy.ops.wm.read_homefile(use_empty=True)
    kw = dict(out=tmp_path / "u", sources=(str(src / "cube.usda"),), views=2, resolution=(24, 24), samples=1)
    _render(**kw)
    assert json.loads((tmp_path / "u" / "custom" / "cube" / "meta.json").read_text())["rendered_images_hash"]
    F.write_png(src / "textures" / "paint.png", np.full((8, 8, 3), (30, 200, 30), np.uint8))
    with pytest.raises(OutputError, match="texture"):
        _render(**kw)


def test_formats_blender_cannot_import_are_read_with_assimp(tmp_path, bpy_empty):
    """COLLADA (Z_UP and Y_UP, the object under a rotated, scaled and moved node), ASCII FBX (Y-up and Z-up), a
    textured COLLADA, AC3D, 3MF, DirectX, 3DS, X3D (under a rotated, scaled Transform), AMF and DXF, which Blender
    5 has no importer for, are read with assimp: the
    same silhouettes and bounds as the mesh itself read by Blender, in their materials' colour or texture; a folder
    takes them; a broken one is refused with one line. A COLLADA, AC3D, X3D and DXF file that also draw edges as
    lines (which assimp-py cannot hand over) are read without them: the same silhouettes and bounds."""
    from blender_mrvm.errors import InputError
    from tests.helpers import (write_3ds, write_3mf, write_ac3d, write_amf, write_ascii_fbx, write_collada,
                               write_directx, write_dxf, write_x3d)

    src = tmp_path / "src"
    src.mkdir()
    write_mesh(src / "m_ply.ply")
    write_collada(src / "m_zup.dae", "Z_UP")
    write_collada(src / "m_yup.dae", "Y_UP")
    write_ascii_fbx(src / "m_ascii.fbx")
    write_ascii_fbx(src / "m_ascii_zup.fbx", up="Z")  # 3ds Max's axes, named in the file's GlobalSettings
    write_ac3d(src / "m_ac.ac")  # Y-up as the format is
    write_3mf(src / "m_3mf.3mf")  # Z-up as the format is, kept as written by assimp's loader
    write_directx(src / "m_x.x")  # Y-up and left-handed: mirrored unless its handedness is turned
    write_3ds(src / "m_3ds.3ds")  # Z-up as the format is, turned Y-up by assimp's loader
    F.write_png(src / "blue.png", np.full((8, 8, 3), (20, 40, 220), np.uint8))
    write_collada(src / "m_tex.dae", "Y_UP", texture="blue.png")
    write_collada(src / "m_edges.dae", "Z_UP", edges=True)  # SketchUp's edges: <lines>, and <linestrips> alone
    write_ac3d(src / "m_ac_edges.ac", edges=True)  # a closed line among the faces, and an object of a line alone
    write_x3d(src / "m_x3d.x3d", edges=True)  # Y-up, under a rotated, scaled, moved Transform; a line set beside
    write_amf(src / "m_amf.amf")  # Z-up as the format is, kept as written by assimp's loader
    write_dxf(src / "m_dxf.dxf", edges=True)  # Z-up 3DFACEs, turned Y-up by assimp's loader; a LINE among them
    s = _render(out=tmp_path / "d", sources=(str(src),), views=3, rig="sphere", resolution=(40, 40), samples=2)
    assert sorted(o.split("/")[1] for o in s.objects) == ["m_3ds", "m_3mf", "m_ac", "m_ac_edges", "m_amf", "m_ascii",
                                                          "m_ascii_zup", "m_dxf", "m_edges", "m_ply", "m_tex", "m_x",
                                                          "m_x3d", "m_yup", "m_zup"]
    assert not s.warnings, s.warnings
    root = tmp_path / "d" / "custom"
    ref = F.read_object(root / "m_ply")
    ref_mask = np.stack([ref.mask(i) > 0 for i in range(3)])
    assert ref_mask.mean() > 0.1
    ref_bbox = json.loads((root / "m_ply" / "meta.json").read_text())["bbox"]
    for stem in ("m_zup", "m_yup", "m_ascii", "m_ascii_zup", "m_tex", "m_ac", "m_3mf", "m_x", "m_3ds", "m_edges",
                 "m_ac_edges", "m_x3d", "m_amf", "m_dxf"):
        ov = F.read_object(root / stem)
        mask = np.stack([ov.mask(i) > 0 for i in range(3)])
        iou = (mask & ref_mask).sum() / (mask | ref_mask).sum()
        assert iou > 0.99, (stem, iou)
        assert np.allclose(json.loads((root / stem / "meta.json").read_text())["bbox"], ref_bbox, atol=1e-4), stem
        rgb = np.stack([ov.rgb(i)[..., :3] for i in range(3)]).astype(np.float32) / 255
        r, g, b = np.median(rgb[mask], axis=0)
        if stem == "m_tex":
            assert b - r > 0.3 and b - g > 0.3, (stem, r, g, b)
        elif stem in ("m_3mf", "m_x", "m_3ds", "m_amf", "m_dxf"):  # no material in the file: a grey
            assert abs(r - g) < 0.03 and abs(r - b) < 0.03, (stem, r, g, b)
        else:
            assert r - g > 0.3 and r - b > 0.3, (stem, r, g, b)
    assert json.loads((root / "m_tex" / "meta.json").read_text())["rendered_images_hash"]

    (src / "broken.dae").write_text("<COLLADA><library_geometries>")
    with pytest.raises(InputError, match=r"^cannot read mesh file .*broken.dae: .+"):
        _render(out=tmp_path / "e", sources=(str(src / "broken.dae"),), views=2)


def test_assimp_materials_uv_tiling_is_rendered(tmp_path, bpy_empty):
    """A 3ds Max ASE square whose diffuse map repeats 2x2 checker squares once, and the same with the map's own UVW
    tiling at 2: seen from above, the second shows twice as many squares along a row (the tiling baked into the
    UVs), not the same picture."""
    from tests.helpers import write_ase_quad

    src = tmp_path / "src"
    src.mkdir()
    checker = np.zeros((32, 32, 3), np.uint8)
    checker[:16, :16] = checker[16:, 16:] = (220, 20, 20)
    checker[:16, 16:] = checker[16:, :16] = (20, 20, 220)
    F.write_png(src / "checker.png", checker)
    write_ase_quad(src / "once.ase", "checker.png", 1.0)
    write_ase_quad(src / "twice.ase", "checker.png", 2.0)
    s = _render(out=tmp_path / "d", sources=(str(src),), views=1, rig="turntable", elevation_deg=89.0,
                resolution=(64, 64), samples=4)
    assert not s.warnings, s.warnings
    changes = {}
    for stem in ("once", "twice"):
        ov = F.read_object(tmp_path / "d" / "custom" / stem)
        rgb, mask = ov.rgb(0)[..., :3].astype(int), ov.mask(0) > 0
        row = rgb[32][mask[32]]
        red = row[:, 0] > row[:, 2]
        changes[stem] = int((red[1:] != red[:-1]).sum())  # red/blue boundaries crossed along the middle row
    assert changes == {"once": 1, "twice": 3}, changes


def test_obj_material_libraries_are_found_as_the_obj_names_them(tmp_path, bpy_empty):
    """An OBJ's `mtllib` may name several libraries on one line (the OBJ specification), a Windows path or another
    letter case; Blender's importer reads each such line as one name as written and renders every material grey
    without a word. Each is found and read (red and green faces); a library that is nowhere is named in a warning
    and in meta.json."""
    mesh = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nusemtl red\nf 1 2 3\nf 1 2 4\nusemtl green\nf 1 3 4\n"
            "f 2 3 4\n")
    src = tmp_path / "src"
    (src / "mats").mkdir(parents=True)
    (src / "red.mtl").write_text("newmtl red\nKd 1 0 0\n")
    (src / "mats" / "green.mtl").write_text("newmtl green\nKd 0 1 0\n")
    for name, lines in {"one_line": "mtllib red.mtl mats/green.mtl", "windows": "mtllib .\\RED.MTL\r\nmtllib mats\\Green.mtl",
                        "gone": "mtllib red.mtl gone.mtl"}.items():
        (src / f"{name}.obj").write_text(lines + "\n" + mesh)
    s = _render(out=tmp_path / "d", sources=(str(src),), views=4, rig="sphere", resolution=(32, 32), samples=2)
    assert len(s.warnings) == 1 and "gone.mtl" in s.warnings[0] and "default grey" in s.warnings[0], "\n".join(s.warnings)
    for name, colours in {"one_line": ("red", "green"), "windows": ("red", "green"), "gone": ("red",)}.items():
        ov = F.read_object(tmp_path / "d" / "custom" / name)
        px = np.concatenate([ov.rgb(i)[..., :3][ov.mask(i) > 0].astype(int) for i in range(4)])
        red = ((px[:, 0] > 150) & (px[:, 1] < 80)).sum()
        green = ((px[:, 1] > 150) & (px[:, 0] < 80)).sum()
        assert red > 20 and (green > 20) == ("green" in colours), (name, red, green)
    meta = json.loads((tmp_path / "d" / "custom" / "gone" / "meta.json").read_text())
    assert meta["missing_material_libraries"] == ["gone.mtl"]


def test_vertex_colours_are_a_meshs_colour(tmp_path, bpy_empty):
    """A scan's colour is its vertex colours (PLY, OBJ's `v x y z r g b`): a ball red on one side and blue on the
    other renders so, in both formats, not in the default grey of a mesh without materials."""
    import trimesh

    ball = trimesh.creation.icosphere(subdivisions=3)
    rgba = np.full((len(ball.vertices), 4), 255, np.uint8)
    rgba[:, :3] = np.where(ball.vertices[:, :1] > 0, (230, 10, 10), (10, 10, 230))
    ball.visual.vertex_colors = rgba
    src = tmp_path / "src"
    src.mkdir()
    ball.export(src / "ply_ball.ply")
    (src / "obj_ball.obj").write_text(
        "".join(f"v {x} {y} {z} {r / 255} {g / 255} {b / 255}\n" for (x, y, z), (r, g, b, _) in zip(ball.vertices, rgba))
        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in ball.faces))
    _render(out=tmp_path / "d", sources=(str(src),), views=4, rig="sphere", resolution=(32, 32), samples=2)
    for stem in ("ply_ball", "obj_ball"):
        ov = F.read_object(tmp_path / "d" / "custom" / stem)
        px = np.concatenate([ov.rgb(i)[..., :3][ov.mask(i) > 0].astype(int) for i in range(4)])
        red = ((px[:, 0] > 120) & (px[:, 2] < 80)).mean()
        blue = ((px[:, 2] > 120) & (px[:, 0] < 80)).mean()
        assert red > 0.2 and blue > 0.2 and red + blue > 0.7, (stem, red, blue)  # grey before: both 0


def test_meshes_of_one_name_in_an_archive_are_told_apart_by_their_folders(tmp_path):
    import zipfile

    from blender_mrvm.scene.objects import resolve_sources

    with zipfile.ZipFile(tmp_path / "pack.zip", "w") as z:
        for folder in ("chairs", "tables"):
            z.writestr(f"{folder}/model.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    specs = resolve_sources((str(tmp_path / "pack.zip"),))
    assert [(s.object_id, s.member) for s in specs] == [("pack_chairs_model", "chairs/model.obj"),
                                                       ("pack_tables_model", "tables/model.obj")]


def test_mesh_files_of_one_name_in_different_folders_are_told_apart_by_their_folders(tmp_path):
    """Robots' parts share file names (``link1.stl`` in every arm's folder): they were refused as one object
    folder; now each is named by the first folder below the ones they share, or every folder below it where those
    are alike too. One object in two formats in one folder is still refused, naming both files."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.scene.objects import resolve_sources

    tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    files = ["panda/meshes/visual/link1.obj", "xarm/desc/meshes/visual/link1.stl", "a1/meshes/hip.obj",
             "legs/front/hip.obj", "legs/rear/hip.obj", "hip.obj", "duck.obj"]
    for f in files:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text(tri)
    specs = resolve_sources(tuple(str(tmp_path / f) for f in files), category="real")
    assert [s.key for s in specs] == ["real/panda_link1", "real/xarm_link1", "real/a1_hip",
                                      "real/legs_front_hip", "real/legs_rear_hip", "real/hip", "real/duck"]
    assert [s.path for s in specs] == [str(tmp_path / f) for f in files]
    # a file named twice (by two spellings of its path) is one object; one object in two formats is one object
    # folder, which is refused
    twice = resolve_sources((str(tmp_path / "a1/meshes/hip.obj"), str(tmp_path / "a1/../a1/meshes/hip.obj")), "real")
    assert [(s.key, s.path) for s in twice] == [("real/hip", str(tmp_path / "a1/meshes/hip.obj"))]
    (tmp_path / "a1/meshes/hip.stl").write_text("solid x\nendsolid x\n")
    with pytest.raises(InputError, match=r"same object folder: real/hip \(.*hip\.obj and .*hip\.stl; rename one\)"):
        resolve_sources(tuple(str(tmp_path / f) for f in ("a1/meshes/hip.obj", "a1/meshes/hip.stl")), category="real")


def test_folders_are_read_as_the_user_sees_them(tmp_path):
    """A folder is ShapeNetCore only where its layout is: a loose mesh beside a subfolder's model.obj, and Google
    Scanned Objects' <name>/meshes/model.obj, are folders of meshes (they were taken for ShapeNet v1, dropping the
    loose file without a word and making every object a category); a ShapeNet tree names what it leaves out.
    Hidden files (macOS's ._chair.obj) are no meshes; names in other scripts get ids of their own (they were all
    'object'), ASCII names keep theirs; a source named twice is one object, and an archive that cannot be read is
    said to be so."""
    import unicodedata
    import zipfile

    from blender_mrvm.errors import InputError
    from blender_mrvm.scene.objects import resolve_sources, safe_id

    tri = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"

    def folder(name, files):
        for f in files:
            (tmp_path / name / f).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / name / f).write_text(tri)
        return str(tmp_path / name)

    def keys(*sources, warnings=None):
        return [s.key for s in resolve_sources(sources, None, warnings)]

    assert keys(folder("mixed", ["a.obj", "b/model.obj"])) == ["custom/a", "custom/model"]
    assert keys(folder("gso", ["Bowl/meshes/model.obj", "Mug/meshes/model.obj", "Mug/materials/textures/t.png"])) \
        == ["custom/Bowl_model", "custom/Mug_model"]
    said: list[str] = []
    assert keys(folder("sn", ["03001627/abc/model.obj", "04379243/def/model.obj", "notes/x.obj"]), warnings=said) \
        == ["chair/abc", "table/def"]
    assert len(said) == 1 and "1 file(s) outside ShapeNetCore's" in said[0] and "notes/x.obj" in said[0], said
    assert keys(str(tmp_path / "sn" / "03001627")) == ["chair/abc"]
    # hidden files and folders: a resource fork is no mesh (its bytes are no OBJ)
    mac = folder("mac", ["chair.obj", ".git/old.obj", "__MACOSX/chair.obj"])
    (tmp_path / "mac" / "._chair.obj").write_bytes(b"\0\5\26\7 resource fork")
    (tmp_path / "mac" / ".chair.obj").write_text(tri)
    assert keys(mac) == ["custom/chair"]
    # names in other scripts: distinct, stable ids; ASCII ids as they were
    assert keys(folder("cjk", ["椅子.obj", "桌子.obj"])) == [f"custom/{safe_id('桌子')}", f"custom/{safe_id('椅子')}"]
    assert safe_id("椅子") != safe_id("桌子") and safe_id("椅子").startswith("object_") and len(safe_id("椅子")) == 13
    assert safe_id("café") == safe_id(unicodedata.normalize("NFD", "café")) and safe_id("café").startswith("cafe_")
    assert [safe_id(n) for n in ("chair", "my chair", "..x..", "")] == ["chair", "my_chair", "x", "object"]
    # one source named twice is one object (two sources for one object folder: the test above)
    chair = str(tmp_path / "mac" / "chair.obj")
    assert keys(chair, str(tmp_path / "mac" / ".." / "mac" / "chair.obj"), mac) == ["custom/chair"]
    assert keys("procedural:chair:1", "procedural:chair:01") == ["chair/chair_000001"]
    # an archive that cannot be read is not one "with no mesh file inside"
    zipped = folder("zips", ["a.obj"])
    with zipfile.ZipFile(tmp_path / "zips" / "b.zip", "w") as z:
        z.writestr("b.obj", tri * 50)
    (tmp_path / "zips" / "c.zip").write_bytes((tmp_path / "zips" / "b.zip").read_bytes()[:60])
    said = []
    assert keys(zipped, warnings=said) == ["custom/b", "custom/a"]
    assert len(said) == 1 and "cannot be read" in said[0] and "c.zip" in said[0], said
    (tmp_path / "zips" / "a.obj").unlink(), (tmp_path / "zips" / "b.zip").unlink()
    with pytest.raises(InputError, match=r"no mesh files .* c\.zip cannot be read"):
        keys(zipped)


@pytest.mark.parametrize("source,needle", [("procedural:chiar:1", "unknown category 'chiar'"),
                                           (f"procedural:chair:{2 ** 63}", r"below 2\*\*63")])
def test_procedural_sources_are_checked_before_anything_renders(tmp_path, source, needle):
    from blender_mrvm.scene.objects import resolve_sources

    with pytest.raises(InputError, match=needle):
        resolve_sources(("procedural:chair:0", source))


def test_zip_archives_are_read_with_the_files_around_their_meshes(tmp_path, bpy_empty):
    """A downloaded model as a zip: a textured glTF (.gltf, .bin and its image in a subfolder, beside a licence
    and a macOS resource fork) renders in its texture's colour, named by the archive, and so does a KMZ's textured
    COLLADA (read with assimp, its image found where the archive is unpacked); an archive of two meshes
    (one an Alembic cache, read from the unpacked file during the render) gives an object each; a resume skips
    them, a changed archive refuses it; a folder takes archives and names the ones without meshes; a broken
    archive and one without meshes are refused with one line."""
    import zipfile

    import bpy

    from blender_mrvm.errors import InputError, OutputError

    model = tmp_path / "export"
    (model / "textures").mkdir(parents=True)
    _textured_cube(model / "textures" / "paint.png", grouped=False)
    bpy.ops.export_scene.gltf(filepath=str(model / "scene.gltf"), export_format="GLTF_SEPARATE", use_selection=True)
    bpy.ops.wm.alembic_export(filepath=str(model / "cube.abc"), selected=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    gltf_files = [f for f in sorted(model.rglob("*")) if f.is_file() and f.suffix != ".abc"]
    assert {f.suffix for f in gltf_files} >= {".gltf", ".bin", ".png"}, gltf_files
    src = tmp_path / "downloads"
    src.mkdir()
    with zipfile.ZipFile(src / "blue_cube.zip", "w") as z:
        for f in gltf_files:
            z.write(f, "model/" + str(f.relative_to(model)))
        z.writestr("license.txt", "CC-BY")
        z.writestr("__MACOSX/model/._scene.gltf", b"\0\5\26\7")
    with zipfile.ZipFile(src / "two.zip", "w") as z:
        for f in gltf_files:
            z.write(f, str(f.relative_to(model)))
        z.write(model / "cube.abc", "cube.abc")
    with zipfile.ZipFile(src / "readme.zip", "w") as z:
        z.writestr("readme.txt", "no mesh here")
    from tests.helpers import write_collada

    write_collada(model / "thing.dae", "Z_UP", texture="paint.png")  # Google Earth's KMZ: COLLADA and its images
    shutil.copy(model / "textures" / "paint.png", model / "paint.png")
    with zipfile.ZipFile(src / "earth.kmz", "w") as z:
        z.writestr("doc.kml", "<kml/>")
        z.write(model / "thing.dae", "models/thing.dae")
        z.write(model / "paint.png", "models/paint.png")

    kw = dict(out=tmp_path / "d", sources=(str(src),), views=2, rig="sphere", resolution=(24, 24), samples=1)
    s = _render(**kw)
    assert sorted(s.objects) == ["custom/blue_cube", "custom/earth", "custom/two_cube", "custom/two_scene"]
    assert len(s.warnings) == 1 and "readme.zip" in s.warnings[0] and "no mesh file inside" in s.warnings[0]
    root = tmp_path / "d" / "custom"
    meta = json.loads((root / "blue_cube" / "meta.json").read_text())
    assert meta["source"] == f"{src / 'blue_cube.zip'}!/model/scene.gltf"
    assert "missing_textures" not in meta
    for obj in ("blue_cube", "two_scene", "two_cube", "earth"):
        ov = F.read_object(root / obj)
        mask = ov.mask(0) > 0
        assert mask.mean() > 0.05, obj
        if obj != "two_cube":  # Alembic carries no materials
            r, g, b = np.median(ov.rgb(0)[..., :3][mask].astype(float), axis=0)
            assert b > r + 40 and b > g + 40, (obj, r, g, b)
    assert np.allclose(json.loads((root / "two_cube" / "meta.json").read_text())["bbox"], meta["bbox"], atol=1e-4)
    assert _render(**kw).views_skipped == 8, "resumed: the archives unchanged, their images hashed the same"

    (root / "blue_cube" / "rgb" / "000001.png").unlink()
    with zipfile.ZipFile(src / "blue_cube.zip", "a") as z:
        z.writestr("notes.txt", "changed")
    with pytest.raises(OutputError, match="as it was before it changed"):
        _render(**kw)

    with pytest.raises(InputError, match=r"no mesh files .* in archive .*readme.zip"):
        _render(out=tmp_path / "e", sources=(str(src / "readme.zip"),), views=2)
    (src / "broken.zip").write_bytes(b"PK\3\4 not really")
    with pytest.raises(InputError, match=r"cannot read archive .*broken.zip"):
        _render(out=tmp_path / "e", sources=(str(src / "broken.zip"),), views=2)


def test_see_through_objects_are_named_and_misread_fbx_opacity_is_made_opaque(tmp_path, bpy_empty):
    """Masks and depth are rasterized from the geometry; the colour is Cycles'. A user's object in a nearly
    transparent material (kept as it is) renders images that show through the surface the masks show: named in a
    warning and in meta.json. The same object exported to FBX at alpha 0 reads back at alpha 0 (Blender's FBX
    importer's guess, which 3ds Max files get wrong): rendered opaque, with a warning."""
    import addon_utils
    import bpy

    bpy.ops.mesh.primitive_monkey_add()
    monkey = bpy.context.active_object
    mat = _material("glassy")
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Alpha"].default_value = 0.05
    bsdf.inputs["Base Color"].default_value = (0.1, 0.02, 0.02, 1.0)  # dark: the white background shows apart
    monkey.data.materials.append(mat)
    s = _render(out=tmp_path / "d", sources=("selected",), views=3, resolution=(32, 32), samples=2)
    assert len(s.warnings) == 1 and "show through" in s.warnings[0], s.warnings
    meta = json.loads((tmp_path / "d" / "custom" / "Suzanne" / "meta.json").read_text())
    assert meta["see_through"]["median_opacity_over_mask"] < 0.2
    assert bsdf.inputs["Alpha"].default_value == pytest.approx(0.05), "the user's material is not changed"

    bsdf.inputs["Alpha"].default_value = 0.0
    addon_utils.enable("io_scene_fbx", default_set=False)
    bpy.ops.export_scene.fbx(filepath=str(tmp_path / "monkey.fbx"), use_selection=True)
    s = _render(out=tmp_path / "e", sources=(str(tmp_path / "monkey.fbx"),), views=3, resolution=(32, 32),
                samples=2)
    assert len(s.warnings) == 1 and "rendered opaque" in s.warnings[0] and "glassy" in s.warnings[0], s.warnings
    meta = json.loads((tmp_path / "e" / "custom" / "monkey" / "meta.json").read_text())
    assert meta["made_opaque"][0].startswith("glassy") and "see_through" not in meta  # the user's own is "glassy"
    ov = F.read_object(tmp_path / "e" / "custom" / "monkey")
    rgb = np.stack([ov.rgb(i)[..., :3] for i in range(3)])
    mask = np.stack([ov.mask(i) > 0 for i in range(3)])
    assert rgb[mask].mean() < 120, "the object is drawn, not the white background through it"


def test_surfaces_the_mesh_does_not_hold_are_named(tmp_path, bpy_empty):
    """Cycles' true displacement draws a sphere a third larger than its mesh, whose masks and depth the exact data
    passes rasterize: the images draw what the passes do not have, and the render says so."""
    import bpy

    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0)
    ball = bpy.context.active_object
    mat = _material("bumpy")
    tree = mat.node_tree
    disp = tree.nodes.new("ShaderNodeDisplacement")
    disp.inputs["Height"].default_value = 1.0
    disp.inputs["Scale"].default_value = 0.35
    out = next(n for n in tree.nodes if n.type == "OUTPUT_MATERIAL")
    tree.links.new(disp.outputs["Displacement"], out.inputs["Displacement"])
    mat.displacement_method = "DISPLACEMENT"
    ball.data.materials.append(mat)
    s = _render(out=tmp_path / "d", sources=("selected",), views=3, resolution=(32, 32), samples=2)
    assert len(s.warnings) == 1 and "do not have" in s.warnings[0], s.warnings
    meta = json.loads((tmp_path / "d" / "custom" / "Sphere" / "meta.json").read_text())
    assert meta["unmasked"]["median_opaque_outside_mask"] > 0.1 and "see_through" not in meta
    mat.displacement_method = "BUMP"  # shading only: the silhouette is the mesh's
    s = _render(out=tmp_path / "e", sources=("selected",), views=3, resolution=(32, 32), samples=2)
    assert not s.warnings, s.warnings


def test_blend_file_renders_what_its_render_shows(tmp_path, bpy_empty):
    """A .blend as a source: what a render of its scene shows (a cube cut in half by a boolean whose cutter is
    hidden from renders, and a text object, made a mesh so its masks and depth exist), not what is hidden from
    renders (an object, an excluded collection) nor its light and camera; the open file itself is refused."""
    import bpy

    from blender_mrvm.errors import InputError

    scene = bpy_empty
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    cube = bpy.context.active_object
    cube.name = "Block"
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(1.5, 0, 0))
    cutter = bpy.context.active_object
    cutter.name = "Cutter"
    cutter.hide_render = True
    mod = cube.modifiers.new("cut", "BOOLEAN")
    mod.operation, mod.object = "DIFFERENCE", cutter  # leaves x in [-1, 0.5]
    bpy.ops.object.text_add(location=(-1.0, 0, 1.2))  # small, above the block's kept part
    bpy.context.active_object.name = "Label"
    bpy.context.active_object.data.size = 0.3
    bpy.ops.mesh.primitive_uv_sphere_add(location=(5, 0, 0))
    bpy.context.active_object.name = "HiddenBall"
    bpy.context.active_object.hide_render = True
    extra = bpy.data.collections.new("Excluded")
    scene.collection.children.link(extra)
    bpy.ops.mesh.primitive_monkey_add(location=(0, 6, 0))
    monkey = bpy.context.active_object
    for c in list(monkey.users_collection):
        c.objects.unlink(monkey)
    extra.objects.link(monkey)
    bpy.context.view_layer.layer_collection.children["Excluded"].exclude = True
    bpy.ops.object.light_add(type="POINT", location=(0, 0, 3))
    bpy.ops.object.camera_add(location=(0, -5, 0))
    path = tmp_path / "asset.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "open.blend"))
    with pytest.raises(InputError, match="selected"):
        _render(out=tmp_path / "o", sources=(str(tmp_path / "open.blend"),), views=1)
    bpy.ops.wm.read_homefile(use_empty=True)
    n_objects = len(bpy.data.objects)
    s = _render(out=tmp_path / "d", sources=(str(path),), views=2, resolution=(32, 32), samples=2)
    assert s.objects == ["custom/asset"] and not s.warnings, s.warnings
    meta = json.loads((tmp_path / "d" / "custom" / "asset" / "meta.json").read_text())
    assert sorted(meta["labels"].values()) == ["Block", "Label_mesh", "background"]
    lo, hi = np.array(meta["bbox"])
    ext = hi - lo  # the block is 1.5 x 2 x 2 (2 x 2 x 2 uncut), the text above its kept part
    assert ext[0] < 0.85 * ext[1], ext  # the boolean cut (the hidden cutter still cuts)
    assert len(bpy.data.objects) == n_objects, "nothing of the .blend is left in the open file"


def test_blend_file_collection_instances_are_rendered(tmp_path, bpy_empty):
    """A .blend whose scene shows an asset collection (excluded from the view layer) only through collection
    instances: one plain, one rotated and scaled, one inside another instanced collection; the asset is a red cube
    cut by a boolean whose cutter is hidden from renders, its collection's instance offset set. Every instance is
    rendered, in colour, masks and normalization, as Blender places it (it was left out: the file was refused as
    having no faces), and nothing is left in the open file."""
    import math

    import bpy

    scene = bpy_empty
    asset, pair = bpy.data.collections.new("Asset"), bpy.data.collections.new("Pair")
    asset.instance_offset = (0, 0, -1)
    bpy.ops.mesh.primitive_cube_add(size=2.0)
    block = bpy.context.active_object
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(-1.5, 0, 0))
    cutter = bpy.context.active_object
    cutter.hide_render = True
    mod = block.modifiers.new("cut", "BOOLEAN")
    mod.operation, mod.object = "DIFFERENCE", cutter  # leaves x in [-0.5, 1]
    mat = _material("red")
    next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED").inputs["Base Color"].default_value = \
        (0.8, 0.02, 0.02, 1.0)
    block.data.materials.append(mat)
    for o in (block, cutter):
        scene.collection.objects.unlink(o)
        asset.objects.link(o)

    def instance(coll, where, into, turn=0.0, scale=1.0):
        e = bpy.data.objects.new(f"{coll.name}_instance", None)
        e.instance_type, e.instance_collection = "COLLECTION", coll
        e.location, e.rotation_euler, e.scale = where, (0, 0, turn), (scale,) * 3  # its saved matrix: identity
        into.objects.link(e)

    for coll in (asset, pair):
        scene.collection.children.link(coll)
        bpy.context.view_layer.layer_collection.children[coll.name].exclude = True
    instance(asset, (0, 0, 0), scene.collection)  # x [-0.5, 1], y [-1, 1], z [0, 2]
    instance(asset, (10, 0, 0), scene.collection, turn=math.pi / 2, scale=0.5)  # x [9.5, 10.5], z [0, 1]
    instance(asset, (0, 5, 0), pair)
    instance(pair, (0, 0, 10), scene.collection)  # y [4, 6], z [10, 12]
    path = tmp_path / "kit.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    n_objects = len(bpy.data.objects)
    s = _render(out=tmp_path / "d", sources=(str(path),), views=2, resolution=(32, 32), samples=1)
    assert s.objects == ["custom/kit"] and not s.warnings, s.warnings
    meta = json.loads((tmp_path / "d" / "custom" / "kit" / "meta.json").read_text())
    assert len(meta["labels"]) == 4, meta["labels"]  # background and three cubes
    norm = np.array(meta["normalization"]["matrix"])  # the bounds: x [-0.5, 10.5], y [-1, 6], z [0, 12]
    assert np.isclose(1 / norm[0, 0], math.sqrt(11 ** 2 + 7 ** 2 + 12 ** 2), rtol=1e-4)
    assert np.allclose(-norm[:3, 3] / norm[0, 0], (5, 2.5, 6), atol=1e-4)
    ov = F.read_object(tmp_path / "d" / "custom" / "kit")
    px = np.concatenate([ov.rgb(i)[..., :3][ov.mask(i) > 0].astype(float) for i in range(2)])
    assert len(px) > 10 and np.median(px[:, 0]) > np.median(px[:, 1]) + 60, np.median(px, axis=0)
    assert len(bpy.data.objects) == n_objects, "nothing of the .blend is left in the open file"


def test_vertices_no_face_uses_are_left_out_of_the_bounds_and_named(tmp_path, bpy_empty):
    """A scan's PLY with a stray vertex 100 units away (used by no face) is normalized and framed by its faces, as
    the same triangle without it is (it rendered as nothing: its scale came from the stray point), and a warning and
    meta.json say so; a selected object's loose vertex too; a loose vertex inside the bounds is no news."""
    import bpy

    tri = "0 0 0\n1 0 0\n0 0 1\n"
    for name, extra in (("scan", "100 0 0\n"), ("clean", ""), ("inside", "0.5 0 0.2\n")):
        n = 3 + bool(extra)
        (tmp_path / f"{name}.ply").write_text(
            f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
            f"element face 1\nproperty list uchar int vertex_indices\nend_header\n{tri}{extra}3 0 1 2\n")
    me = bpy.data.meshes.new("tet")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1), (40, 0, 0)], [], [(0, 1, 2), (0, 1, 3), (0, 2, 3),
                                                                                 (1, 2, 3)])
    ob = bpy.data.objects.new("Tet", me)
    bpy_empty.collection.objects.link(ob)
    ob.select_set(True)
    s = _render(out=tmp_path / "d", sources=(*(str(tmp_path / f"{n}.ply") for n in ("scan", "clean", "inside")),
                                              "selected"), views=2, resolution=(16, 16), samples=1)
    assert sorted(w.split(":")[0] for w in s.warnings) == ["custom/Tet", "custom/scan"], s.warnings
    assert all("1 vertices that no face of some area uses" in w for w in s.warnings), s.warnings
    meta = {n: json.loads((tmp_path / "d" / "custom" / n / "meta.json").read_text())
            for n in ("scan", "clean", "inside", "Tet")}
    assert meta["scan"]["normalization"] == meta["clean"]["normalization"] == meta["inside"]["normalization"]
    assert np.isclose(meta["Tet"]["normalization"]["scale"], 1 / np.sqrt(3))
    assert meta["scan"]["loose_vertices"] == {"count": 1, "bbox_with_them": [[0, 0, 0], [100, 0, 1]]}
    assert "loose_vertices" not in meta["inside"] and meta["Tet"]["loose_vertices"]["count"] == 1
    for n in ("scan", "Tet"):  # a dot at most before
        assert sum((F.read_png(tmp_path / "d" / "custom" / n / "mask" / f"00000{i}.png") > 0).sum()
                   for i in range(2)) > 10, n


def test_blend_file_images_are_part_of_what_its_views_were_rendered_from(tmp_path, bpy_empty):
    """A .blend whose material reads an image beside it (relative path, not packed): the image is one of its linked
    files, and a resume after the image changed is refused; a packed image is in the .blend's own bytes."""
    import bpy

    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.objects import linked_files

    tex = tmp_path / "tex" / "wood.png"
    tex.parent.mkdir()
    F.write_png(tex, np.full((8, 8, 3), (150, 90, 40), np.uint8))
    bpy.ops.mesh.primitive_cube_add()
    mat = _material("wood")
    node = mat.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = bpy.data.images.load(str(tex))
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    bpy.context.active_object.data.materials.append(mat)
    packed = bpy.data.images.new("packed", 4, 4)
    packed.pack()
    path = tmp_path / "asset.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True, relative_remap=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    n_images = len(bpy.data.images)
    assert linked_files(path) == [("tex/wood.png", tex)]
    assert len(bpy.data.images) == n_images, "reading the paths leaves nothing behind"
    kw = dict(out=tmp_path / "d", sources=(str(path),), views=2, resolution=(24, 24), samples=1)
    _render(**kw)
    assert _render(**kw).views_skipped == 2
    F.write_png(tex, np.full((8, 8, 3), (20, 200, 40), np.uint8))
    with pytest.raises(OutputError, match="texture"):
        _render(**kw)


def test_blend_file_linked_libraries_are_part_of_what_its_views_were_rendered_from(tmp_path, bpy_empty):
    """A .blend whose scene links an object from a library (another .blend), whose material reads an image from a
    second library in another folder: both libraries and the image are its linked files, the views show the
    linked object, and a resume after the library's object or the image changed (the .blend's own bytes did not)
    is refused; with the library gone, the file is refused before any view is written."""
    import bpy

    from blender_mrvm.errors import InputError, OutputError
    from blender_mrvm.scene.objects import linked_files

    lib_dir, tex_dir = tmp_path / "lib", tmp_path / "shared"
    lib_dir.mkdir(), tex_dir.mkdir()
    tex = tex_dir / "paint.png"
    F.write_png(tex, np.full((8, 8, 3), (30, 60, 200), np.uint8))
    mat = _material("paint")  # the second library: a material reading the image
    node = mat.node_tree.nodes.new("ShaderNodeTexImage")
    node.image = bpy.data.images.load(str(tex))
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    mat.use_fake_user = True
    materials = tex_dir / "materials.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(materials), copy=True, relative_remap=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(str(materials), link=True, relative=True) as (src, dst):
        dst.materials = ["paint"]
    bpy.ops.mesh.primitive_monkey_add()  # the first library: an object using the linked material
    bpy.context.active_object.name = "Suzanne"
    bpy.context.active_object.data.materials.append(dst.materials[0])
    parts = lib_dir / "parts.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(parts), copy=True, relative_remap=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    with bpy.data.libraries.load(str(parts), link=True, relative=True) as (src, dst):
        dst.objects = ["Suzanne"]
    bpy.context.scene.collection.objects.link(dst.objects[0])
    path = tmp_path / "shot.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True, relative_remap=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    n = (len(bpy.data.libraries), len(bpy.data.objects), len(bpy.data.images), len(bpy.data.scenes))

    assert linked_files(path) == [("lib/parts.blend", parts), ("shared/materials.blend", materials),
                                  ("shared/paint.png", tex)]
    assert (len(bpy.data.libraries), len(bpy.data.objects), len(bpy.data.images), len(bpy.data.scenes)) == n, \
        "reading the libraries leaves nothing behind"
    kw = dict(out=tmp_path / "d", sources=(str(path),), views=2, resolution=(24, 24), samples=1)
    _render(**kw)
    obj = tmp_path / "d" / "custom" / "shot"
    rgb = F.read_png(obj / "rgb" / "000000.png")[..., :3].astype(float)
    inside = F.read_png(obj / "mask" / "000000.png") > 0
    assert inside.mean() > 0.05, "the linked object is rendered"
    assert rgb[inside][:, 2].mean() > rgb[inside][:, 0].mean() + 20, "in the second library's image's colour"
    assert _render(**kw).views_skipped == 2

    bpy.ops.wm.open_mainfile(filepath=str(parts))  # the object changes in its library; shot.blend does not
    bpy.data.objects["Suzanne"].scale = (1.0, 1.0, 0.3)
    bpy.ops.wm.save_mainfile()
    bpy.ops.wm.read_homefile(use_empty=True)
    with pytest.raises(OutputError, match="linked .blend"):
        _render(**kw)
    assert _render(**kw, force=True).views_skipped == 0
    F.write_png(tex, np.full((8, 8, 3), (200, 60, 30), np.uint8))  # the second library's image changes
    with pytest.raises(OutputError, match="linked .blend"):
        _render(**kw)

    parts.rename(tmp_path / "moved.blend")  # the library is gone: Blender would render the scene without it
    with pytest.raises(InputError, match=r"1 object of its scene \(Suzanne\) is linked from another .blend and "
                                         r"missing: the linked file .*parts.blend cannot be read"):
        _render(**{**kw, "out": tmp_path / "d2"})
    assert not (tmp_path / "d2" / "custom").exists()


def test_faces_of_no_area_far_away_do_not_frame_the_object(tmp_path, bpy_empty):
    """A box OBJ with one zero-area face 20 units away (three vertices at one point, or a sliver on a line) was framed
    by that face: scale 0.049 instead of 0.86, one mask pixel a view, no word. Faces of no area render nothing and
    are left out of the bounds, as loose vertices are, and named."""
    import trimesh

    box = trimesh.creation.box(extents=(1.0, 0.5, 0.3))
    v, f = box.vertices.tolist(), box.faces.tolist()
    for name, extra_v in (("point", [[20, 0, 0]] * 3), ("sliver", [[0.5, 0, 0], [10, 0, 0], [20, 0, 0]])):
        n = len(v)
        lines = [f"v {x} {y} {z}" for x, y, z in v + extra_v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
        lines.append(f"f {n + 1} {n + 2} {n + 3}")
        (tmp_path / f"{name}.obj").write_text("\n".join(lines) + "\n")
    (tmp_path / "clean.obj").write_text("\n".join([f"v {x} {y} {z}" for x, y, z in v]
                                                  + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]) + "\n")
    s = _render(out=tmp_path / "d", sources=tuple(str(tmp_path / f"{n}.obj") for n in ("point", "sliver", "clean")),
                views=2, resolution=(16, 16), samples=1)
    meta = {n: json.loads((tmp_path / "d" / "custom" / n / "meta.json").read_text()) for n in ("point", "sliver", "clean")}
    assert meta["point"]["normalization"]["scale"] == pytest.approx(meta["clean"]["normalization"]["scale"], rel=1e-6)
    assert meta["sliver"]["normalization"]["scale"] == pytest.approx(meta["clean"]["normalization"]["scale"], rel=1e-6)
    assert sorted(w.split(":")[0] for w in s.warnings if "no face of some area" in w) == ["custom/point", "custom/sliver"]


def test_vertices_stored_far_from_the_origin_and_objects_that_cover_no_pixel_are_said(tmp_path, bpy_empty):
    """A scan in UTM coordinates (5.3e6 units away) snapped to Blender's float32 grid of half a unit: its sphere came
    out blocky and the colour 1-5 px off the masks, without a word; a 1e-5 x 1e-5 x 1 needle rendered views with empty
    masks, 'complete'. Both are named in a warning; the same box near the origin is no news."""
    import trimesh

    box = trimesh.creation.box(extents=(4.0, 3.0, 2.0))
    box.export(tmp_path / "near.ply")
    far = box.copy()
    far.apply_translation((452000.0, 5300000.0, 310.0))
    (tmp_path / "far.ply").write_bytes(trimesh.exchange.ply.export_ply(far, encoding="ascii"))
    trimesh.creation.box(extents=(1e-5, 1e-5, 1.0)).export(tmp_path / "needle.ply")
    s = _render(out=tmp_path / "d", sources=tuple(str(tmp_path / f"{n}.ply") for n in ("near", "far", "needle")),
                views=2, resolution=(16, 16), samples=1)
    said = {w.split(":")[0]: w for w in s.warnings}
    assert "float32" in said.get("custom/far", "") and "custom/near" not in said, s.warnings
    assert "covers no pixel in any of the 2 views" in said.get("custom/needle", ""), s.warnings


def test_names_that_are_not_utf8(tmp_path, bpy_empty, capsys):
    """A mesh named with Latin-1 bytes (ch\\xe9ir.obj, from an old archive) crashed render-dataset with a
    UnicodeEncodeError traceback while hashing its name; an --out of such bytes failed in the EXR writer with a
    half-written object. The mesh renders; the folder is refused up front in one line."""
    import os

    from blender_mrvm.cli import main

    src = tmp_path / os.fsdecode(b"ch\xe9ir.obj")
    write_mesh(src)
    base = ["render-dataset", "--source", str(src), "--views", "1", "--resolution", "16", "--samples", "1"]
    assert main(base + ["--out", str(tmp_path / "d")]) == 0
    assert len(list((tmp_path / "d").glob("custom/*/meta.json"))) == 1
    capsys.readouterr()
    bad = tmp_path / os.fsdecode(b"o\xe9ut")
    assert main(base + ["--out", str(bad)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not UTF-8 text" in err[0] and not bad.exists(), err
