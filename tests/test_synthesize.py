"""`synthesize`: a tiny checkpoint made here renders finite RGBA/depth images of the targets' sizes, the
same numbers as the model's own renderer; bad checkpoints and references give one-line errors and
leave nothing behind; --blend writes a .blend whose planes sit on their cameras' frusta."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from blender_mrvm.datasets.novel_views import Target, write_targets
from blender_mrvm.errors import InputError, OutputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.geometry import rigs
from blender_mrvm.progress import run_to_end
from blender_mrvm import synthesis as S
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
        "sampler": {"n_coarse": 4, "n_fine": 2}}


def tiny_checkpoint(run_dir: Path, overrides: dict | None = None, seed: int = 0) -> Path:
    """An untrained tiny model saved through the checkpoint API (the tests never need a good model)."""
    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training.checkpoint import save_checkpoint

    cfg = model_config("fast", merge_dicts(TINY, overrides or {}))
    torch.manual_seed(seed)
    save_checkpoint(run_dir, 3, GeneralizableNeRF(cfg), cfg, None)
    return run_dir


def merge_dicts(a: dict, b: dict) -> dict:
    out = dict(a)
    for k, v in b.items():
        out[k] = merge_dicts(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    data = make_sphere_dataset(root / "data", n_objects=1, n_views=4, resolution=16, seed=1)
    obj = data / "spheres" / "obj000"
    ck = tiny_checkpoint(root / "run")
    # Targets: two views of the folder (16x16) and one bigger, shifted camera (24x24).
    tg = S.targets_from_views(obj, [2, 3])
    k = tg[0].intrinsics
    tg.append(Target("wide", C.Intrinsics(k.fx * 1.5, k.fy * 1.5, 13.0, 10.0, 24, 24), tg[1].c2w_opencv))
    write_targets(root / "targets.json", tg, depth=True)
    return root, obj, ck, tg


def _args(root, obj, ck, out, *extra):
    return ["synthesize", "--references", str(obj), "--views", "0,1", "--targets", str(root / "targets.json"),
            "--checkpoint", str(ck), "--out", str(out), "--device", "cpu", "--threads", "1", *extra]


def test_cli_writes_finite_rgba_and_depth_of_each_target(setup, capsys):
    root, obj, ck, tg = setup
    out = root / "out"
    assert main(_args(root, obj, ck, out)) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["views"] == 3 and line["bbox_source"] == "meta.json bbox"
    for i, t in enumerate(tg):
        rgba = F.read_png(out / t.rgb_path(i))
        assert rgba.shape == (t.intrinsics.height, t.intrinsics.width, 4) and rgba.dtype == np.uint8
        d = F.read_depth(out / t.depth_path(i))
        assert d.shape == rgba.shape[:2] and np.isfinite(d).all() and (d >= 0).all()
    rep = json.loads((out / "synthesis.json").read_text())
    assert rep["references"]["views"] == [0, 1] and rep["checkpoint_step"] == 3 and rep["model"] == "fast"
    assert [r["name"] for r in rep["targets"]] == ["view 002", "view 003", "wide"]
    assert all(0 < r["evaluated_rays"] <= r["rays"] for r in rep["targets"])
    assert not list(root.glob(".out.partial-*"))
    import os

    umask = os.umask(0)
    os.umask(umask)
    assert (out.stat().st_mode & 0o777) == 0o777 & ~umask  # a new folder, not tempfile's owner-only one
    assert ((out / "rgb").stat().st_mode & 0o777) == 0o777 & ~umask


def test_same_numbers_as_the_models_renderer_and_png_round_trip(setup, tmp_path):
    """Chunked rendering equals GeneralizableNeRF.synthesize; the RGBA PNG over white gives it back."""
    root, obj, ck, tg = setup
    model, mcfg, _, _ = S.load_checkpoint(ck)
    refs = S.load_references(obj, (0, 1))
    ctx, ns = S.encode_references(model, refs, "cpu")
    t = tg[2]
    res = run_to_end(S.render_target(model, ctx, ns, t.intrinsics, t.c2w_opencv, 7, "cpu"))  # odd chunk size
    ref = model.synthesize(refs.images, refs.c2w, refs.intrinsics, refs.bbox, t.c2w_opencv, t.intrinsics)
    assert np.abs(res["color"] - ref["color"].numpy()).max() < 1e-5
    assert np.abs(res["acc"] - ref["acc"].numpy()).max() < 1e-5
    assert 0 < res["evaluated"] < res["rays"] == 24 * 24  # rays that miss the box are not evaluated
    rgba = S.rgba_image(res["color"], res["acc"]).astype(np.float64) / 255.0
    over_white = F.composite_on_white(rgba[..., :3], rgba[..., 3:])  # in linear light, as Blender shows it
    assert np.abs(over_white - res["color"]).max() <= 1.0 / 255.0 + 1e-6
    # the alpha is the model's opacity, raised only where its colour is darker than that opacity lets through
    fits = (F.srgb_to_linear(res["color"]) >= 1.0 - F.to_uint8(res["acc"])[..., None] / 255.0).all(-1)
    assert fits.mean() > 0.5, fits.mean()
    assert np.array_equal(rgba[..., 3][fits], (F.to_uint8(res["acc"]) / 255.0)[fits])
    assert (rgba[..., 3] >= F.to_uint8(res["acc"]) / 255.0).all()


def test_references_shrink_to_the_trained_size_by_default(setup, tmp_path, capsys):
    """--ref-size 0 (auto) shrinks references larger than the checkpoint's train_image_size to it, and refuses
    smaller ones with one line (nothing written); -1 keeps them; N resizes to N; a checkpoint without the key
    keeps them."""
    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training.checkpoint import save_checkpoint

    root, obj, ck, tg = setup
    cfg = model_config("fast", TINY)
    small = save_checkpoint(tmp_path / "small", 1, GeneralizableNeRF(cfg), cfg, None, {"train_image_size": "8"})
    big = save_checkpoint(tmp_path / "big", 1, GeneralizableNeRF(cfg), cfg, None, {"train_image_size": "64"})
    assert S.reference_sizes(0, small) == (0, 8) and S.reference_sizes(0, ck) == (0, 0)
    assert S.reference_sizes(-1, small) == (0, 0) and S.reference_sizes(12, small) == (12, 0)
    assert S.reference_sizes(0, tmp_path / "missing") == (0, 0)  # reported later, when it is loaded
    for c, extra, size in [(small, (), 8), (small, ("--ref-size", "-1"), 16), (small, ("--ref-size", "12"), 12),
                           (big, ("--ref-size", "-1"), 16), (ck, (), 16)]:
        out = tmp_path / f"out_{c.parent.parent.name}_{size}"
        assert main(_args(root, obj, c, out, *extra)) == 0
        js = json.loads((out / "synthesis.json").read_text())
        assert js["references"]["size"] == [size, size], (c, extra)
        assert F.read_png(out / "rgb" / "000002.png").shape == (24, 24, 4)  # targets keep their own size
    refused = tmp_path / "refused"
    capsys.readouterr()
    assert main(_args(root, obj, big, refused)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "smaller than the 64 px" in err[0] and not refused.exists()
    assert "in the panel: Reference size Custom 64, or As they are" in err[0]  # (the panel shows it too)
    refs = S.load_references(obj, (0, 1), 0, None, max_size=8)
    k = S.load_references(obj, (0, 1)).intrinsics[0]
    assert refs.images.shape == (2, 8, 8, 3) and refs.intrinsics[0].fx == pytest.approx(k.fx / 2)
    assert refs.intrinsics[0].cx == pytest.approx(k.cx / 2)  # pixel-centre exact scaling
    capsys.readouterr()


def test_depth_is_planar_z_in_world_units(tmp_path, setup):
    """An opaque model (density bias 30) stops every ray at the box entry: the planar depth unprojects onto
    the padded box's surface, and equals the model's own along-ray depth times the ray's z component."""
    root, obj, _, tg = setup
    ck = tiny_checkpoint(tmp_path / "opaque", {"render": {"density_bias": 30.0}, "sampler": {"n_coarse": 64}})
    model, mcfg, _, _ = S.load_checkpoint(ck)
    refs = S.load_references(obj, (0, 1))
    ctx, ns = S.encode_references(model, refs, "cpu")
    t = tg[2]
    res = run_to_end(S.render_target(model, ctx, ns, t.intrinsics, t.c2w_opencv, 512, "cpu"))
    hit = res["acc"] > 0.999
    assert hit.sum() > 50 and (res["depth_z"][~hit & (res["acc"] < 0.5)] == 0).all()
    pts = C.unproject_depth(t.intrinsics, t.c2w_opencv, res["depth_z"])[hit]
    half = ns.box * ns.scale  # padded half size in world units
    rel = np.abs(pts - ns.centre) / half
    step = 2.0 * np.sqrt(3) / 64  # at most one coarse step behind the entry (normalised units / half size)
    assert (rel.max(axis=1) > 1.0 - step - 1e-6).all() and (rel.max(axis=1) < 1.0 + 1e-6).all()
    ref = model.synthesize(refs.images, refs.c2w, refs.intrinsics, refs.bbox, t.c2w_opencv, t.intrinsics)
    _, d = C.rays_opencv(t.intrinsics, np.eye(4))
    assert np.allclose(res["depth_z"][hit], (ref["depth"].numpy() * d[..., 2])[hit], rtol=1e-4)


def _fails(args, msg, capsys, out: Path):
    rc = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert msg in err[0], err[0]
    assert not out.exists() and not list(out.parent.glob(f".{out.name}.partial-*")), "nothing half-written"
    return err[0]


def test_bad_checkpoints_are_one_line_errors(setup, tmp_path, capsys):
    from safetensors import safe_open
    from safetensors.torch import save_file

    from blender_mrvm.training.checkpoint import MODEL_FILE

    root, obj, ck, _ = setup
    out = tmp_path / "out"
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00garbage" * 10)
    _fails(_args(root, obj, junk, out), "does not load", capsys, out)
    other = tmp_path / "other.safetensors"
    save_file({"w": torch.zeros(2)}, str(other), metadata={"format": "someone.else"})
    _fails(_args(root, obj, other, out), "is not a blender_mrvm model checkpoint (format 'someone.else')", capsys, out)
    # Another model's weights (d_model 16) under the tiny model's config (d_model 8): the strict load refuses.
    big = tiny_checkpoint(tmp_path / "big", {"nerformer": {"d_model": 16}})
    with safe_open(str(next((big / "checkpoints").glob("step_*")) / MODEL_FILE), framework="pt") as f:
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    with safe_open(str(next((ck / "checkpoints").glob("step_*")) / MODEL_FILE), framework="pt") as f:
        meta = dict(f.metadata())
    mixed = tmp_path / "mixed.safetensors"
    save_file(tensors, str(mixed), metadata=meta)
    _fails(_args(root, obj, mixed, out), "does not match its model config", capsys, out)
    meta["format_version"] = "99"
    save_file(tensors, str(mixed), metadata=meta)
    _fails(_args(root, obj, mixed, out), "has format version 99, newer than this code", capsys, out)
    _fails(_args(root, obj, tmp_path / "nope", out), "does not exist", capsys, out)


def test_bad_references_and_targets_are_one_line_errors(setup, tmp_path, capsys):
    import shutil

    root, obj, ck, _ = setup
    out = tmp_path / "out"
    _fails(_args(root, tmp_path / "missing", ck, out), "reference folder", capsys, out)
    _fails(_args(root, obj, ck, out)[:4] + ["0,9"] + _args(root, obj, ck, out)[5:],
           "reference view 9 does not exist", capsys, out)
    nopose = tmp_path / "nopose"
    shutil.copytree(obj, nopose)
    (nopose / "pose" / "000001.txt").unlink()
    _fails(_args(root, nopose, ck, out), "reference view 1 of", capsys, out)
    shutil.rmtree(nopose / "pose")
    _fails(_args(root, nopose, ck, out), "have no poses", capsys, out)
    args = _args(root, obj, ck, out)
    args[args.index("--targets") + 1] = str(tmp_path / "none.json")
    _fails(args, "targets file", capsys, out)
    if not torch.cuda.is_available():
        args = _args(root, obj, ck, out)
        args[args.index("--device") + 1] = "cuda"
        _fails(args, "no CUDA GPU", capsys, out)


def test_cancel_leaves_nothing_and_existing_output_keeps_other_files(setup, tmp_path):
    root, obj, ck, tg = setup
    out = tmp_path / "out"
    cfg = S.SynthesisConfig(obj, root / "targets.json", out, (0, 1), ck, "cpu", chunk_rays=16)
    gen = S.synthesize_views(cfg)
    events = [next(gen) for _ in range(4)]
    assert events[-1].total == 16 * 16 * 2 + 24 * 24 and 0 < events[-1].done < events[-1].total
    gen.close()  # what Esc / SIGINT does
    assert not out.exists() and not list(tmp_path.glob(".out.partial-*"))
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(OutputError, match="already holds files"):  # nothing is written over without force
        run_to_end(S.synthesize_views(cfg))
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    summary = run_to_end(S.synthesize_views(dataclasses.replace(cfg, force=True)))
    assert (out / "keep.txt").read_text() == "mine" and (out / "rgb" / "000002.png").is_file()
    assert len(summary.targets) == 3 and (out / "depth").is_dir()  # depth: as targets.json asks
    with pytest.raises(InputError, match="at most 500 reference views"):
        S.load_references(obj, tuple(range(501)))


@pytest.mark.slow
def test_blend_has_cameras_and_planes_on_their_frusta(setup, tmp_path, addon):
    import bpy

    from blender_mrvm.scene import camera as scam
    from blender_mrvm.scene import image_planes as IP

    root, obj, ck, tg = setup
    blend = tmp_path / "res" / "scene.blend"
    assert main(_args(root, obj, ck, tmp_path / "out", "--blend", str(blend)) + ["--plane-distance", "0.7"]) == 0
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    try:
        scene = bpy.context.scene
        assert scene.view_settings.view_transform == "Standard"
        coll = bpy.data.collections[IP.COLLECTION]
        for t in tg:
            cam = bpy.data.objects[t.name]
            assert cam.name in coll.objects
            (plane,) = IP.planes_of(cam)
            img = bpy.data.images[plane["mrvm_image"]]
            assert img.has_data or img.size[0] > 0
            assert Path(bpy.path.abspath(img.filepath)).is_file()
            assert tuple(img.size) == (t.intrinsics.width, t.intrinsics.height)
            # corners on the target camera's frame corners (the render size is the largest target's)
            intr, c2w = scam.read_camera(cam, scene)
            assert np.allclose(c2w, t.c2w_opencv, atol=1e-5)
            verts = np.array([plane.matrix_world @ v.co for v in plane.data.vertices])[:4]
            uv, z = C.project(t.intrinsics.K, C.invert_pose(t.c2w_opencv), verts)
            corners = np.array([[0, 1], [1, 1], [1, 0], [0, 0]]) * [t.intrinsics.width, t.intrinsics.height]
            assert np.abs(uv - corners).max() < 0.5 and np.allclose(z, 0.7, rtol=1e-5)
        refs = bpy.data.collections["MRVM references"].objects
        assert sorted(o.name for o in refs) == ["MRVM reference 000", "MRVM reference 001"]
        assert all(o.data.background_images[0].image is not None for o in refs)
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)


def _blend_args(root, obj, ck, out, blend, targets=None, *extra):
    args = _args(root, obj, ck, out, "--blend", str(blend), *extra)
    if targets is not None:
        args[args.index("--targets") + 1] = str(targets)
    return args


def test_blend_problems_leave_nothing_written(setup, tmp_path, capsys):
    """--blend's problems are errors with nothing written: targets of two frame shapes before anything is
    synthesized; one found after (no plane distance: the object's centre is behind every camera) before the
    views move into --out. No folder the run created stays."""
    root, obj, ck, tg = setup
    k = tg[0].intrinsics
    mixed = write_targets(tmp_path / "mixed.json", [tg[0], Target("wide", C.Intrinsics(k.fx, k.fy, 12.0, 8.0, 24, 16),
                                                                 tg[1].c2w_opencv)])
    away = tg[0].c2w_opencv.copy()
    away[:3, [0, 2]] *= -1.0  # turned round: looks away from the object
    behind = write_targets(tmp_path / "behind.json", [Target("away", k, away)])
    for targets, msg in ((mixed, "the targets have different frame shapes (24x16 and 16x16)"),
                         (behind, "behind every target camera")):
        assert main(_blend_args(root, obj, ck, tmp_path / "new" / "out", tmp_path / "b" / "s.blend", targets)) == 2
        err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("error:")]
        assert len(err) == 1 and msg in err[0], err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["behind.json", "mixed.json"]


@pytest.mark.slow
def test_blend_takes_the_targets_frame_and_pixel_aspect(setup, tmp_path, capsys, addon, monkeypatch):
    """The .blend renders the targets' frame with their pixel aspect (references with fy = 1.01 fx, as COLMAP
    PINHOLE captures have, and their orbit); reference cameras of another frame shape are left out with a note;
    the reference images are found when the .blend is opened from another folder."""
    import shutil

    import bpy

    from blender_mrvm.scene import camera as scam

    root, obj, ck, tg = setup
    refs = tmp_path / "refs"
    shutil.copytree(obj, refs)
    meta = json.loads((refs / "meta.json").read_text())
    k = F.read_object(obj).intrinsics
    meta["intrinsics"] = {"fl_x": k.fx, "fl_y": 1.01 * k.fx, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height}
    (refs / "meta.json").write_text(json.dumps(meta))
    monkeypatch.chdir(tmp_path)
    base = ["synthesize", "--references", "refs", "--views", "0,1", "--checkpoint", str(ck), "--device", "cpu",
            "--threads", "1"]
    assert main(base + ["--orbit", "2", "--out", "o", "--blend", "a/s.blend"]) == 0
    wide = write_targets(tmp_path / "wide.json", [Target("wide", C.Intrinsics(k.fx, k.fx, 12.0, 8.0, 24, 16),
                                                         tg[0].c2w_opencv)])
    capsys.readouterr()
    assert main(base + ["--targets", str(wide), "--out", "w", "--blend", "b/s.blend"]) == 0
    assert "note: reference views 0, 1 left out of s.blend" in capsys.readouterr().err
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    try:
        bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "a" / "s.blend"))
        scene = bpy.context.scene
        assert np.isclose(scene.render.pixel_aspect_x / scene.render.pixel_aspect_y, 1.01)
        cams = sorted((o for o in scene.objects if o.type == "CAMERA"), key=lambda o: o.name)
        assert [c.name for c in cams] == ["MRVM reference 000", "MRVM reference 001", "orbit 000", "orbit 001"]
        for cam in cams:
            intr, _ = scam.read_camera(cam, scene)
            assert (intr.width, intr.height) == (16, 16) and np.isclose(intr.fy / intr.fx, 1.01, rtol=1e-5)
        for cam in cams[:2]:
            assert Path(bpy.path.abspath(cam.data.background_images[0].image.filepath)).is_file()
        bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "b" / "s.blend"))
        scene = bpy.context.scene
        assert (scene.render.resolution_x, scene.render.resolution_y) == (24, 16)
        assert [o.name for o in scene.objects if o.type == "CAMERA"] == ["wide"]
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)


@pytest.mark.slow
def test_blend_replaces_an_existing_file_only_once_it_is_complete(setup, tmp_path, addon):
    """A .blend that fails (a view missing) leaves the existing file, its images and the folders as they were,
    with no temporary or backup file; --force over it replaces it, a rerun reusing its images' names."""
    import bpy

    from blender_mrvm.scene.novel_views import write_blend

    root, obj, ck, tg = setup
    out = tmp_path / "out"
    assert main(_args(root, obj, ck, out)) == 0
    (out / "rgb" / "000001.png").rename(tmp_path / "kept.png")
    blend = tmp_path / "s.blend"
    blend.write_bytes(b"the user's scene")
    for path in (tmp_path / "new" / "s.blend", blend):
        with pytest.raises(InputError, match="wrote no image for 'view 003'"):
            write_blend(path, out / "targets.json", out, plane_distance=0.7)
    assert blend.read_bytes() == b"the user's scene"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.png", "out", "s.blend"]
    (tmp_path / "kept.png").rename(out / "rgb" / "000001.png")
    try:
        for run in ("o1", "o2"):
            assert main(_args(root, obj, ck, tmp_path / run, "--blend", str(blend), "--force")) == 0
            assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"out", "s.blend", "s_novel_views", "o1", run})
            assert sorted(p.name for p in (tmp_path / "s_novel_views").iterdir()) == [
                "view_002.png", "view_002_depth.exr", "view_003.png", "view_003_depth.exr", "wide.png", "wide_depth.exr"]
        assert bpy.data.filepath == str(blend) and len([o for o in bpy.data.objects if o.type == "CAMERA"]) == 5
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)

def test_orbit_and_target_views_without_a_targets_file(setup, tmp_path, capsys):
    from blender_mrvm.datasets.novel_views import read_targets

    root, obj, ck, _ = setup
    base = ["synthesize", "--references", str(obj), "--views", "0", "1", "--checkpoint", str(ck),
            "--device", "cpu", "--threads", "1"]
    assert main(base + ["--orbit", "3", "--orbit-size", "20", "--orbit-elevation", "35", "--out", str(tmp_path / "o")]) == 0
    targets, _ = read_targets(tmp_path / "o" / "targets.json")
    refs = S.load_references(obj, (0, 1))
    centre = 0.5 * (refs.bbox[0] + refs.bbox[1])
    radius = np.median([np.linalg.norm(c[:3, 3] - centre) for c in refs.c2w])
    assert [t.name for t in targets] == ["orbit 000", "orbit 001", "orbit 002"] and all(t.generated for t in targets)
    for i, t in enumerate(targets):
        eye = t.c2w_opencv[:3, 3] - centre
        assert np.isclose(np.linalg.norm(eye), radius) and np.isclose(np.degrees(np.arcsin(eye[2] / radius)), 35.0)
        assert np.allclose(t.c2w_opencv[:3, 2], -eye / radius)  # looks at the centre
        assert (t.intrinsics.width, t.intrinsics.height) == (20, 20)
        assert np.isclose(t.intrinsics.fov_x, refs.intrinsics[0].fov_x, rtol=1e-3)
        assert F.read_png(tmp_path / "o" / t.rgb_path(i)).shape == (20, 20, 4)
    assert main(base + ["--target-views", "2,3", "--out", str(tmp_path / "v")]) == 0
    targets, _ = read_targets(tmp_path / "v" / "targets.json")
    assert [t.name for t in targets] == ["view 002", "view 003"]
    capsys.readouterr()
    assert main(base + ["--target-views", "7", "--out", str(tmp_path / "w")]) == 2
    assert "view 7 does not exist" in capsys.readouterr().err and not (tmp_path / "w").exists()


def test_orbit_size_scales_both_focal_lengths_alike(setup):
    """--orbit-size on references of another aspect ratio and non-square pixels: one scale for fx and fy (the
    pixels keep their shape), the principal point at the new frame's centre."""
    root, obj, ck, tg = setup
    k = C.Intrinsics(90.0, 90.9, 51.0, 27.0, 100, 56)
    refs = dataclasses.replace(S.load_references(obj, (0, 1)), intrinsics=[k, k])
    (t,) = S.orbit_targets(refs, 1, size=64)
    i = t.intrinsics
    assert (i.width, i.height, i.cx, i.cy) == (64, 36, 32.0, 18.0)
    assert np.isclose(i.fx, 0.64 * k.fx) and np.isclose(i.fy / i.fx, k.fy / k.fx)
    (t,) = S.orbit_targets(refs, 1)  # the references' own size
    assert (t.intrinsics.fx, t.intrinsics.fy, t.intrinsics.cx, t.intrinsics.cy) == (90.0, 90.9, 50.0, 28.0)

def test_gpnr_checkpoint_synthesizes_through_the_same_command(setup, tmp_path, capsys):
    """A GPNR checkpoint goes through ``synthesize`` like any other kind; given more references than it
    uses, each target gets its nearest ones; fewer than it needs is one line, nothing written."""
    from blender_mrvm.models import registry
    from blender_mrvm.training.checkpoint import save_checkpoint

    root, obj, _, tg = setup
    cfg = registry.build_config("gpnr", "fast", {"patch_dim": 4, "n_samples": 6, "d_model": 8, "n_heads": 2,
                                                 "n_blocks": 1, "min_ref_views": 2, "max_ref_views": 2})
    torch.manual_seed(0)
    ck = save_checkpoint(tmp_path / "gpnr", 1, registry.build_model(cfg), cfg, None)
    out = tmp_path / "out"
    args = _args(root, obj, ck, out)
    args[args.index("0,1")] = "0,1,3"
    assert main(args) == 0
    rep = json.loads((out / "synthesis.json").read_text())
    assert rep["model_kind"] == "gpnr"
    for r, t in zip(rep["targets"], tg):
        ref_c2w = [F.read_object(obj).c2w_opencv[F.read_object(obj).indices.index(v)] for v in (0, 1, 3)]
        want = S.nearest_views(ref_c2w, t.c2w_opencv, np.mean(rep["bbox"], 0), 2)
        assert r["reference_views"] == [[0, 1, 3][k] for k in want] and len(r["reference_views"]) == 2
    assert 3 in rep["targets"][1]["reference_views"]  # view 003 is its own nearest reference
    capsys.readouterr()
    args = _args(root, obj, ck, tmp_path / "few")
    args[args.index("0,1")] = "1"
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at least 2 reference views" in err[0] and not (tmp_path / "few").exists()


def test_nearest_views_by_angle_and_distance():
    eye = lambda p: C.look_at_opencv(np.asarray(p, float))  # noqa: E731
    refs = [eye([3, 0, 0]), eye([0, 3, 0]), eye([-3, 0, 0]), eye([30, 0.5, 0]), eye([2.9, 0.3, 0.2])]
    assert S.nearest_views(refs, eye([3, 0.2, 0]), np.zeros(3), 2) == (0, 4)
    assert S.nearest_views(refs, eye([0.2, 3, 0]), np.zeros(3), 1) == (1,)


def test_quality_preview_renders_half_the_samples_of_either_kind(setup, tmp_path, capsys, monkeypatch):
    """--quality preview: the model's samples per ray halved (registry.quality_overrides, what bench tradeoff
    measures), recorded in synthesis.json; the images differ from full quality but stay valid."""
    from blender_mrvm.models import registry

    root, obj, ck, tg = setup
    seen = []
    import blender_mrvm.models.config as MC

    real_merge = MC.merge
    monkeypatch.setattr(MC, "merge", lambda cfg, ov: seen.append(ov) or real_merge(cfg, ov))
    outs = {}
    for q in ("full", "preview"):
        outs[q] = tmp_path / q
        assert main(_args(root, obj, ck, outs[q], "--quality", q)) == 0
        assert json.loads((outs[q] / "synthesis.json").read_text())["quality"] == q
    assert {"sampler": {"n_coarse": 4, "n_fine": 1}} in seen  # TINY has 4 + 2 samples
    a, b = (F.read_png(outs[q] / tg[0].rgb_path(0)) for q in ("full", "preview"))
    assert a.shape == b.shape and not np.array_equal(a, b)
    g = registry.build_config("gpnr", "fast")
    assert registry.quality_overrides(g, "preview") == {"n_samples": max(4, g.n_samples // 2)}
    assert registry.quality_overrides(g, "full") == {}
    with pytest.raises(InputError, match="quality"):
        registry.quality_overrides(g, "draft")


def test_precision_bf16_renders_close_to_fp32_and_fp16_asks_for_a_gpu(setup, tmp_path, capsys):
    """--precision (models/precision.py, one owner with the benches): bf16 autocast reaches the model's forward
    passes (the image changes, a little) and is recorded, with a note that it pays on a GPU only; fp16 on the CPU
    is a one-line error before anything is written."""
    root, obj, ck, tg = setup
    outs = {}
    for p in ("fp32", "bf16", "auto"):
        outs[p] = tmp_path / p
        assert main(_args(root, obj, ck, outs[p], "--precision", p)) == 0
        # auto, the default, is fp32 on the CPU (bf16 on a GPU: models.precision.resolve_precision)
        assert json.loads((outs[p] / "synthesis.json").read_text())["precision"] == ("fp32" if p == "auto" else p)
        err = capsys.readouterr().err
        assert ("note: bf16 on the CPU renders the same views as fp32 but no faster" in err) == (p == "bf16")
    for i in range(len(tg)):
        assert np.array_equal(F.read_png(outs["auto"] / tg[i].rgb_path(i)), F.read_png(outs["fp32"] / tg[i].rgb_path(i)))
        a, b = (F.read_png(outs[p] / tg[i].rgb_path(i)).astype(np.float64) / 255 for p in ("fp32", "bf16"))
        assert a.shape == b.shape
        mse = float(((a - b) ** 2).mean())
        assert 0 < mse < 1e-3, (i, mse)  # bf16 keeps ~3 significant digits: changed, but within ~30 dB
    out = tmp_path / "fp16"
    _fails(_args(root, obj, ck, out, "--precision", "fp16"), "--precision fp16 needs a GPU", capsys, out)
    out = tmp_path / "int8c"
    _fails(_args(root, obj, ck, out, "--precision", "int8", "--compile"), "--precision int8 and --compile do not "
           "combine", capsys, out)


def test_int8_is_auto_on_the_cpu_for_a_wide_model_and_renders_close_to_fp32(setup, tmp_path, capsys):
    """--precision int8 (models.precision.for_precision): the linear layers get int8 weights, so the views change a
    little (within ~30 dB here; a shipped `quality` view stays within ~57 dB of fp32) and it is recorded. ``auto``
    picks it on the CPU for a model whose linear layers are wide enough to repay quantizing their inputs (the
    setup's 8-wide model stays fp32, the test above); a compiled run stays fp32."""
    from blender_mrvm.models.precision import INT8_MIN_WIDTH, linear_width
    from blender_mrvm.synthesis import load_checkpoint

    root, obj, _, tg = setup
    wide = tiny_checkpoint(tmp_path / "wide", {"nerformer": {"d_model": 64}})
    model = load_checkpoint(str(wide), "cpu")[0]
    assert linear_width(model) >= INT8_MIN_WIDTH > linear_width(load_checkpoint(str(setup[2]), "cpu")[0])
    outs = {}
    for p in ("fp32", "int8", "auto"):
        outs[p] = tmp_path / p
        assert main(_args(root, obj, wide, outs[p], "--precision", p)) == 0
        assert json.loads((outs[p] / "synthesis.json").read_text())["precision"] == ("int8" if p == "auto" else p)
    capsys.readouterr()
    changed = 0
    for i in range(len(tg)):
        a, b, c = (F.read_png(outs[p] / tg[i].rgb_path(i)).astype(np.float64) / 255 for p in ("fp32", "int8", "auto"))
        assert np.array_equal(b, c)
        mse = float(((a - b) ** 2).mean())
        assert mse < 1e-3, (i, mse)
        changed += mse > 0
    assert changed, "int8 reached the model's layers"


def test_int8_model_is_a_quantized_copy_and_refuses_a_gpu():
    """for_precision: int8 swaps every linear layer for a dynamically quantized one, on a copy unless inplace; float
    precisions return the model itself (autocast does their work); int8 is refused for a GPU by name."""
    from torch.ao.nn.quantized.dynamic import Linear as QLinear

    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.models.precision import check_precision, for_precision

    m = GeneralizableNeRF(model_config("fast", TINY))
    n_lin = sum(isinstance(x, torch.nn.Linear) for x in m.modules())
    for p in ("fp32", "bf16"):
        assert for_precision(m, p) is m
    q = for_precision(m, "int8")
    assert q is not m and sum(isinstance(x, torch.nn.Linear) for x in m.modules()) == n_lin
    assert sum(isinstance(x, QLinear) for x in q.modules()) == n_lin
    assert not any(type(x) is torch.nn.Linear for x in q.modules())
    with pytest.raises(InputError, match="int8 runs on the CPU only"):
        check_precision("--precision", "int8", "cuda:0")


def test_auto_precision_is_bf16_on_a_gpu_and_fp32_or_int8_on_the_cpu():
    """synthesize's default precision, ``auto``: bf16 on a GPU (every shipped model scored the same there in
    session 32 and renders faster); on the CPU int8 for models wide enough for it to pay, else fp32 (bf16 is no
    faster there); a named one stays as named."""
    import argparse

    from blender_mrvm.commands.synthesize import add_arguments
    from blender_mrvm.models.precision import resolve_precision
    from blender_mrvm.synthesis.views import SynthesisConfig

    from blender_mrvm.models import registry

    assert resolve_precision("auto", "cuda") == resolve_precision("auto", "cuda:0") == "bf16"
    assert resolve_precision("auto", "cpu") == "fp32"
    assert [resolve_precision(p, "cuda") for p in ("fp32", "bf16", "fp16")] == ["fp32", "bf16", "fp16"]
    # On the CPU int8 where the bench found it pays and leaves the views as they are (docs/bench_int8): the wide
    # NeRFormer presets; not the narrow ones, nor GPNR, whose views it moves a little (named, it still runs)
    for kind, preset, want in (("nerformer_mrvm", "fast", "fp32"), ("nerformer_mrvm", "balanced", "fp32"),
                               ("nerformer_mrvm", "accurate", "int8"), ("gpnr", "accurate", "fp32")):
        model = registry.build_model(registry.build_config(kind, preset), load_pretrained=False)
        assert resolve_precision("auto", "cpu", model) == want, (kind, preset)
        assert resolve_precision("auto", "cpu", model, compiled=True) == "fp32"
        assert resolve_precision("auto", "cuda", model) == "bf16"
    assert SynthesisConfig.precision == "auto"
    p = argparse.ArgumentParser()
    add_arguments(p)
    assert p.get_default("precision") == "auto"


def _turntable_cameras(els, fov=40.0, framing=0.99, az=0.0):
    """Cameras around a box of half-diagonal 0.5 at the origin: elevations ``els`` (degrees) at azimuth ``az``,
    square views of ``fov`` degrees, at ``framing`` (pretrained.turntable_offsets' measure; the turntable's are
    0.75-1.05)."""
    intr = C.intrinsics_from_fov(np.radians(fov), 64, 64)
    dist = framing * 0.5 / np.sin(np.radians(fov) / 2.0)
    a = np.radians(az)
    c2ws = [C.look_at_opencv(dist * np.array([np.cos(np.radians(e)) * np.cos(a), np.cos(np.radians(e)) * np.sin(a),
                                              np.sin(np.radians(e))])) for e in els]
    return c2ws, [intr] * len(c2ws), (np.full(3, -0.5 / np.sqrt(3)), np.full(3, 0.5 / np.sqrt(3)))


def test_turntable_offsets_measure_elevation_field_of_view_framing_and_azimuth():
    from blender_mrvm.models import pretrained as P

    c2ws, intrs, box = _turntable_cameras([30, 45, -10])
    off = P.turntable_offsets(c2ws, intrs, box)
    assert np.allclose(off, [[0, 0, 0, 0], [15, 0, 0, 0], [40, 0, 0, 0]], atol=1e-9)
    c2ws, intrs, box = _turntable_cameras([30], fov=55.0, framing=1.05 * np.exp(0.2), az=15.0 * 7 + 4.0)
    assert np.allclose(P.turntable_offsets(c2ws, intrs, box), [[0, 15, 0.2, 4.0]], atol=1e-9)
    c2ws, intrs, box = _turntable_cameras([30], framing=0.75 * np.exp(-0.1), az=-15.0 * 3 - 6.0)
    assert np.allclose(P.turntable_offsets(c2ws, intrs, box), [[0, 0, 0.1, 6.0]], atol=1e-9)
    # The training set's own cameras are all on it (make-shapenet's turntable, any object's bounding sphere).
    for r in (0.72 * 0.5, 0.5):
        d = rigs.framing_distance(r, np.radians(40.0))
        for c in rigs.rig_poses("turntable", 24, d, elevation_deg=30.0):
            assert np.allclose(P.turntable_offsets([c], intrs, box), 0.0, atol=1e-6)


def test_auto_picks_the_model_that_fits_the_cameras(tmp_path, capsys):
    """shipped:auto (synthesize's default): the default model when every camera, reference or target, sits on
    its turntable; when one is off in height, field of view, azimuth or (with a real box) framing, the any-view
    model on the CPU and the quality model on a GPU; references of a whole scene get the capture model;
    each run says which and why, in one line and in synthesis.json. Naming the default model off its turntable
    gives the note that names the others."""
    from blender_mrvm.models import pretrained as P

    if P.shipped_or_none(None) is None or P.shipped_or_none("mrvm_anyview") is None:
        pytest.skip("this copy lacks the default or the any-view model")
    el_tol, fov_tol, frame_tol, az_tol = P.TURNTABLE_TOLERANCE
    near = _turntable_cameras([30, 30 + 0.9 * el_tol, 30 - 0.9 * el_tol])
    assert P.auto_model(*near) == ("nerformer_mrvm", P.auto_model(*near)[1])
    assert "all 3 cameras on the 30-degree turntable" in P.auto_model(*near)[1]
    assert P.auto_model(*_turntable_cameras([30, 30], az=15.0 + 0.9 * az_tol))[0] == "nerformer_mrvm"
    for cams, what in [(_turntable_cameras([30, 30 + 1.2 * el_tol + 1]), "elevations"),
                       (_turntable_cameras([30, 30], fov=40 + 1.2 * fov_tol + 1), "fields of view"),
                       (_turntable_cameras([30, 30], framing=1.05 * np.exp(1.5 * frame_tol + 0.02)), "framed"),
                       (_turntable_cameras([30, 30], az=15.0 + 1.2 * az_tol + 0.5), "azimuths between")]:
        name, why = P.auto_model(*cams)
        assert name == "mrvm_anyview" and what in why and why.startswith("auto: the any-view model")
    off = _turntable_cameras([30, 30 + 1.2 * el_tol + 1])
    if P.shipped_or_none("mrvm_quality") is not None:  # on a GPU the quality model, whose speed is fine there
        name, why = P.auto_model(*off, gpu=True)
        assert name == "mrvm_quality" and why.startswith("auto: the quality model") and "elevations" in why
    assert P.auto_model(*near, gpu=True)[0] == "nerformer_mrvm"  # on the turntable the default, on any device
    if P.shipped_or_none("gpnr_captures") is not None:  # references of a whole scene: the capture model
        name, why = P.auto_model(*near, background="scene")
        assert name == "gpnr_captures" and "whole scene" in why
    far = _turntable_cameras([30, 30], framing=1.05 * np.exp(1.5 * frame_tol + 0.02))
    assert P.auto_model(*far, framing_known=False)[0] == "nerformer_mrvm"  # a guessed box says nothing of framing
    assert P.is_auto("shipped:auto") and P.is_auto(" Shipped:AUTO ") and not P.is_auto("shipped")
    from blender_mrvm.synthesis.views import trained_size

    # synthesize sizes the references by the default model before auto picks: every candidate shares its size
    sizes = {trained_size(P.shipped_or_none(n)) for n in (None, "mrvm_anyview", "mrvm_quality", "gpnr_captures")
             if P.shipped_or_none(n)}
    assert len(sizes) == 1 and sizes.pop() > 0
    with pytest.raises(InputError, match="picks a model from the cameras"):
        P.resolve_checkpoint("shipped:auto")  # eval and the rest name a model
    # The explicit default model's note uses the same rule.
    assert P.viewpoint_note(P.default_checkpoint(), *near) == ""
    note = P.viewpoint_note(P.default_checkpoint(), *_turntable_cameras([30, 75, -40]))
    assert note.startswith("2 of 3 cameras are off the 30-degree turntable") and "elevations -40 to 75 degrees" in note
    assert "shipped:auto" in note and "shipped:mrvm_anyview" in note
    assert P.viewpoint_note(tmp_path / "other.safetensors", *_turntable_cameras([75])) == ""
    assert P.viewpoint_note(P.shipped_or_none("mrvm_anyview"), *_turntable_cameras([75])) == ""
    # The converse: the any-view or quality model named for cameras on the default's turntable, where it is better.
    for name, model in (("mrvm_anyview", "any-view model"), ("mrvm_quality", "quality model")):
        if P.shipped_or_none(name) is None:
            continue
        note = P.viewpoint_note(P.shipped_or_none(name), *near)
        assert note.startswith(f"all {len(near[0])} cameras are on the 30-degree turntable") and model in note
        (p0, l0), (p1, l1) = P.TURNTABLE_HELD_OUT["nerformer_mrvm"], P.TURNTABLE_HELD_OUT[name]
        assert p0 > p1 and l0 < l1 and f"{p0:.1f} dB" in note and "shipped:auto" in note
        assert P.viewpoint_note(P.shipped_or_none(name), *_turntable_cameras([30, 75])) == ""  # one camera off
    # Through the CLI: an analytic sphere-rig object, no --checkpoint (= shipped:auto), then the default named.
    data = make_sphere_dataset(tmp_path / "data", n_objects=1, n_views=6, resolution=16, seed=5, rig="sphere")
    obj = data / "spheres" / "obj000"
    ov = F.read_object(obj)
    assert (P.turntable_offsets(ov.c2w_opencv, [ov.intrinsics] * 6, ov.meta["bbox"]).max(axis=0)
            > np.asarray(P.TURNTABLE_TOLERANCE)).any()  # the rig does leave the turntable
    write_targets(tmp_path / "targets.json", S.targets_from_views(obj, [1, 2, 4, 5]))
    run = ["synthesize", "--references", str(obj), "--views", "0,3", "--targets", str(tmp_path / "targets.json"),
           "--device", "cpu", "--threads", "1", "--ref-size", "-1"]
    assert main([*run, "--out", str(tmp_path / "auto")]) == 0
    rep = json.loads((tmp_path / "auto" / "synthesis.json").read_text())
    assert rep["model_choice"].startswith("auto: the any-view model") and rep["viewpoint_note"] == ""
    assert Path(rep["checkpoint"]).resolve() == P.shipped_or_none("mrvm_anyview").resolve()
    assert f"note: {rep['model_choice']}" in capsys.readouterr().err
    if P.shipped_or_none("gpnr_captures") is not None:  # the same views declared a whole scene: the capture model
        meta = json.loads((obj / "meta.json").read_text())
        (obj / "meta.json").write_text(json.dumps({**meta, "background": "scene"}))
        assert main([*run, "--out", str(tmp_path / "scene")]) == 0
        (obj / "meta.json").write_text(json.dumps(meta))
        rep = json.loads((tmp_path / "scene" / "synthesis.json").read_text())
        assert rep["model_choice"].startswith("auto: GPNR for rooms and captures") and rep["model_kind"] == "gpnr"
        assert Path(rep["checkpoint"]).resolve() == P.shipped_or_none("gpnr_captures").resolve()
        capsys.readouterr()
    assert main([*run, "--out", str(tmp_path / "default"), "--checkpoint", "shipped"]) == 0
    rep = json.loads((tmp_path / "default" / "synthesis.json").read_text())
    assert "shipped:mrvm_anyview" in rep["viewpoint_note"] and rep["model_choice"] == ""
    assert Path(rep["checkpoint"]).resolve() == P.default_checkpoint().resolve()
    assert f"note: {rep['viewpoint_note']}" in capsys.readouterr().err


def test_compile_on_request_compiles_every_network_but_the_encoder(setup, tmp_path, capsys, monkeypatch):
    """`--compile` goes through registry.compile_networks (recorded here instead of compiled: minutes on this
    CPU) for every network of the loaded model but the image encoder, and synthesis.json says so; without it
    nothing is compiled."""
    root, obj, ck, _ = setup
    seen = []
    monkeypatch.setattr(torch.nn.Module, "compile", lambda m, **kw: seen.append((type(m).__name__, kw)))
    assert main(_args(root, obj, ck, tmp_path / "plain")) == 0
    assert seen == [] and json.loads((tmp_path / "plain" / "synthesis.json").read_text())["compiled"] is False
    assert main(_args(root, obj, ck, tmp_path / "compiled", "--compile")) == 0
    from blender_mrvm.synthesis import load_checkpoint

    model = load_checkpoint(ck)[0]
    want = [type(m).__name__ for n, m in model.named_children() if n != "encoder" and any(True for _ in m.parameters())]
    assert want and [name for name, _ in seen] == want and all(kw == {"dynamic": True} for _, kw in seen)
    assert json.loads((tmp_path / "compiled" / "synthesis.json").read_text())["compiled"] is True


def test_depth_flag_reaches_the_targets_file_and_the_blend(setup, tmp_path, capsys):
    """``--depth`` with targets made by the command (``--target-views``, ``--orbit``) wrote the depth maps while
    OUT/targets.json said "depth": false and the .blend had no depth beside its planes: the targets file of the run
    now says what was written, and the .blend follows it."""
    root, obj, ck, tg = setup
    blend = tmp_path / "b" / "s.blend"
    args = ["synthesize", "--references", str(obj), "--views", "0,1", "--target-views", "3", "--checkpoint", str(ck),
            "--out", str(tmp_path / "out"), "--device", "cpu", "--threads", "1", "--depth", "--blend", str(blend)]
    assert main(args) == 0
    assert json.loads((tmp_path / "out" / "targets.json").read_text())["depth"] is True
    assert (tmp_path / "out" / "depth" / "000000.exr").is_file()
    from blender_mrvm.datasets.novel_views import blend_images_folder

    assert list(blend_images_folder(blend).glob("*depth*.exr")), sorted(blend_images_folder(blend).iterdir())


def test_force_replaces_an_earlier_synthesis_as_a_whole(setup, tmp_path):
    """``synthesize --force`` into the folder of an earlier --orbit 6 --depth run kept four of its images and all six
    depth maps beside the two new views (depth/000000.exr of another camera beside the new rgb/000000.png), and
    nothing said which files belonged to which run: the earlier views go; files of other names stay."""
    root, obj, ck, tg = setup
    out = tmp_path / "out"
    base = ["synthesize", "--references", str(obj), "--views", "0,1", "--checkpoint", str(ck), "--out", str(out),
            "--device", "cpu", "--threads", "1"]
    assert main(base + ["--orbit", "6", "--depth"]) == 0
    (out / "notes.txt").write_text("mine")
    assert main(base + ["--target-views", "2,3", "--force"]) == 0
    assert sorted(p.name for p in (out / "rgb").iterdir()) == ["000000.png", "000001.png"]
    assert not list((out / "depth").glob("*.exr")) and (out / "notes.txt").read_text() == "mine"
    assert len(json.loads((out / "targets.json").read_text())["targets"]) == 2


def test_synthesis_gives_the_callers_thread_count_back(setup):
    """synthesize_views sets torch's thread count to 1 while it renders (its chunk workers take the cores): a script
    that called it kept 1 thread for everything after."""
    root, obj, ck, tg = setup
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        assert main(_args(root, obj, ck, root / "threads_out", "--threads", "2")) == 0
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_synthesis_json_records_what_repeating_it_needs(setup):
    """synthesis.json named the checkpoint by path only (a run folder's newest moves on) and recorded no code version,
    libraries or command line; it carries the model file's sha256 and the provenance record eval.json has."""
    import hashlib

    from blender_mrvm import __version__

    root, obj, ck, tg = setup
    out = root / "prov_out"
    assert main(_args(root, obj, ck, out)) == 0
    rec = json.loads((out / "synthesis.json").read_text())
    assert Path(rec["checkpoint_file"]).is_file() and Path(rec["checkpoint_file"]).parent.parent.parent == ck
    assert rec["checkpoint_sha256"] == hashlib.sha256(Path(rec["checkpoint_file"]).read_bytes()).hexdigest()
    prov = rec["provenance"]
    assert prov["blender_mrvm"] == __version__ and prov["torch"] == torch.__version__
    assert isinstance(prov["argv"], list) and "commit" in prov  # (argv is pytest's here; the CLI's in a real run)
    assert "time_utc" not in prov  # reruns compare equal
