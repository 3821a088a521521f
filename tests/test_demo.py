"""`demo` (what `make demo` runs): held-out renders, synthesis from the protocol's 2 references, scores
against the ground truth, scene.blend with planes in place, contact sheet; without a model, the
dataset-only fallback. A tiny untrained checkpoint made here stands in for the shipped one: the test
checks the plumbing and the numbers' consistency, never the model's quality."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.models import vgg

torch.set_num_threads(1)
HAVE_WEIGHTS = (vgg.weights_dir() / vgg.VGG_FILE).is_file()


def _tiny_checkpoint(run_dir: Path, extra_meta: dict | None = None) -> Path:
    from blender_mrvm.models.config import model_config
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training.checkpoint import save_checkpoint

    cfg = model_config("fast", {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
                                "sampler": {"n_coarse": 4, "n_fine": 2}})
    torch.manual_seed(0)
    save_checkpoint(run_dir, 5, GeneralizableNeRF(cfg), cfg, None, extra_meta)
    return run_dir


@pytest.mark.slow
def test_demo_with_a_model(tmp_path, addon, capsys):
    import bpy

    from blender_mrvm.datasets import format as F
    from blender_mrvm.datasets.loaders import to_float_rgb
    from blender_mrvm.models.metrics import psnr
    from blender_mrvm.scene import image_planes as IP

    ck = _tiny_checkpoint(tmp_path / "run")
    out = tmp_path / "demo_out"
    args = ["demo", "--out", str(out), "--checkpoint", str(ck), "--objects", "1", "--views", "8", "--resolution", "24",
            "--scene-resolution", "24", "--threads", "1", "--no-picture"]
    if not HAVE_WEIGHTS:
        args.append("--no-lpips")
    assert main(args) == 0
    text = capsys.readouterr().out
    assert "chair" in text and "over the better trivial baseline" in text
    from blender_mrvm.commands.demo import demo_folder

    assert (out / "scene_novel_views").is_dir()
    demo_folder(out).check()  # `make demo` again writes over its own outputs (the .blend's images folder included)
    rep = json.loads((out / "metrics.json").read_text())
    assert rep["protocol"]["input_views"] == [1, 5] and rep["objects"] == ["procedural:chair:1000"]
    assert rep["overall"]["n"] == 6 and [v["view"] for v in rep["views"]] == [0, 2, 3, 4, 6, 7]
    assert rep["checkpoint_step"] == "5" and rep["model"] == "fast"
    # The printed PSNR is the written PNG (over white) against the rendered ground truth.
    obj = out / "dataset" / "chair" / "chair_001000"
    v = rep["views"][2]
    pred = to_float_rgb(F.read_png(out / "novel" / "chair" / "out" / "rgb" / "000002.png"))
    gt = to_float_rgb(F.read_png(obj / "rgb" / "000003.png"))
    assert v["view"] == 3 and abs(float(psnr(torch.from_numpy(pred), torch.from_numpy(gt))[0]) - v["psnr"]) < 1e-4
    assert 0 < v["ssim"] <= 1 and 3 < v["psnr"] < 60 and (not HAVE_WEIGHTS or 0 <= v["lpips"] < 1.5)
    a = v["alpha"]  # the written alpha against the rendered mask
    alpha = F.read_png(out / "novel" / "chair" / "out" / "rgb" / "000002.png")[..., 3] / 255.0
    mask = F.read_png(obj / "mask" / "000003.png") > 0
    assert a["background"] == pytest.approx(float(alpha[~mask].mean())) and 0 <= a["iou"] <= 1
    assert "alpha (opacity) vs object masks" in text
    o = rep["overall"]
    assert abs(o["psnr_gain_over_best_baseline"]
               - (o["psnr"] - max(o["baseline_nearest"]["psnr"], o["baseline_mean"]["psnr"]))) < 1e-9
    sheet = F.read_png(out / "contact_sheet.png")
    assert sheet.shape[1] == 112 + 4 * (128 + 4) + 4 and sheet.shape[0] == 18 + 3 * (128 + 4) + 4
    # scene.blend: the object, 2 reference cameras, 6 target cameras with planes, the overview camera.
    bpy.ops.wm.open_mainfile(filepath=str(out / "scene.blend"))
    try:
        sc = bpy.context.scene
        assert sc.view_settings.view_transform == "Standard" and sc.camera.name == "MRVM overview"
        planes = [o for o in sc.objects if o.get(IP.PLANE_TAG)]
        assert len(planes) == 6
        for pl in planes:
            img = bpy.data.images[pl["mrvm_image"]]
            assert tuple(img.size) == (24, 24) and Path(bpy.path.abspath(img.filepath)).is_file()
        assert len(bpy.data.collections["MRVM references"].objects) == 2
        meshes = [o for o in bpy.data.collections["MRVM demo object"].all_objects if o.type == "MESH"]
        assert meshes, "the object is in the scene"
        lo = np.min([np.array(o.matrix_world) @ np.append(np.array(c), 1.0) for o in meshes for c in o.bound_box], axis=0)
        hi = np.max([np.array(o.matrix_world) @ np.append(np.array(c), 1.0) for o in meshes for c in o.bound_box], axis=0)
        meta = json.loads((obj / "meta.json").read_text())
        assert np.allclose(lo[:3], meta["bbox"][0], atol=1e-3) and np.allclose(hi[:3], meta["bbox"][1], atol=1e-3)
        # Seen through target camera "MRVM view 00" (planes hidden), the object covers the pixels the
        # dataset's part mask of view 0 marks: object, cameras and planes share one frame.
        for o in sc.objects:
            if o.get(IP.PLANE_TAG) or o.name.startswith("MRVM frame"):
                o.hide_render = True
        sc.camera = bpy.data.objects["MRVM view 00"]
        r = sc.render
        r.engine, r.film_transparent, r.filepath = "CYCLES", True, str(tmp_path / "view00.png")
        sc.cycles.samples, sc.cycles.device = 4, "CPU"
        r.image_settings.file_format, r.image_settings.color_mode = "PNG", "RGBA"
        bpy.ops.render.render(write_still=True)
        sil = F.read_png(tmp_path / "view00.png")[..., 3] > 127
        mask = F.read_png(obj / "mask" / "000000.png") > 0
        iou = (sil & mask).sum() / (sil | mask).sum()
        assert mask.sum() > 20 and iou > 0.85, iou
    finally:
        bpy.ops.wm.read_homefile(use_empty=True)


def test_demo_without_a_model_renders_the_dataset(tmp_path, addon, monkeypatch, capsys):
    from blender_mrvm.commands import demo
    from blender_mrvm.errors import InputError
    from blender_mrvm.models import pretrained

    def missing():
        raise InputError("the shipped default checkpoint X is missing")

    monkeypatch.setattr(pretrained, "default_checkpoint", missing)
    monkeypatch.setattr(demo, "DATASET_ONLY_OBJECTS", ("procedural:chair:0",))
    monkeypatch.setattr(demo, "DATASET_ONLY_VIEWS", 3)  # the demo's least --views, now checked here too
    monkeypatch.setattr(demo, "DATASET_ONLY_RESOLUTION", 16)
    assert main(["demo", "--out", str(tmp_path / "d")]) == 0
    cap = capsys.readouterr()
    text = cap.err
    assert "note: the shipped default checkpoint X is missing" in text and "renders the dataset" in text
    assert "note:" not in cap.out
    assert (tmp_path / "d" / "contact_sheet.png").is_file()
    assert len(list((tmp_path / "d" / "dataset").glob("*/*/rgb/*.png"))) == 3


def test_demo_without_a_model_honours_objects_views_and_resolution(tmp_path, addon, monkeypatch, capsys):
    """Without a model the demo rendered its fixed 4 objects x 12 views at 128 px whatever --objects, --views and
    --resolution said, and printed its notes on stdout; now it renders what was asked and notes on stderr."""
    from PIL import Image

    from blender_mrvm.commands import demo
    from blender_mrvm.errors import InputError
    from blender_mrvm.models import pretrained

    def missing():
        raise InputError("the shipped default checkpoint X is missing")

    monkeypatch.setattr(pretrained, "default_checkpoint", missing)
    out = tmp_path / "d"
    assert main(["demo", "--out", str(out), "--objects", "1", "--views", "3", "--resolution", "16",
                 "--no-lpips", "--no-picture"]) == 0
    cap = capsys.readouterr()
    assert "note:" not in cap.out, cap.out
    err = [ln for ln in cap.err.splitlines() if ln.startswith("note:")]
    assert err == ["note: the shipped default checkpoint X is missing",
                   "note: without a model the demo renders the dataset and its contact sheet only"]
    pngs = sorted((out / "dataset").glob("*/*/rgb/*.png"))
    assert len(pngs) == 3 and {p.parent.parent.name for p in pngs} == {"chair_000000"}
    assert Image.open(pngs[0]).size == (16, 16)
    assert (out / "contact_sheet.png").is_file()
    # more objects than the dataset-only list: the other categories' held-out ones
    assert demo.dataset_only_sources(6)[:4] == demo.DATASET_ONLY_OBJECTS
    assert demo.dataset_only_sources(6)[4:] == ("procedural:sofa:1004", "procedural:table:1005")


def test_references_the_model_would_refuse_are_refused_before_rendering(tmp_path, capsys):
    """--resolution below the model's training size with the default --ref-size: synthesis would refuse the
    rendered references after the dataset was rendered; the demo says so first, and writes nothing."""
    ck = _tiny_checkpoint(tmp_path / "run", {"train_image_size": "24"})
    out = tmp_path / "demo a"
    args = ["demo", "--out", str(out), "--checkpoint", str(ck), "--objects", "1", "--views", "3", "--resolution",
            "16", "--scene-resolution", "16", "--no-lpips", "--no-picture", "--threads", "1"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --resolution 16 renders references smaller than the 24 px")
    assert "--ref-size 24" in err[0] and not out.exists()


def test_scene_blend_synthesizes_with_the_ref_size_given(tmp_path, monkeypatch):
    """scene.blend's views come from the references at --ref-size, as the scored views do (before, build_scene
    left it out and failed after the scores on references smaller than the model's training size)."""
    from types import SimpleNamespace

    from blender_mrvm import synthesis
    from blender_mrvm.commands.demo import build_scene
    from blender_mrvm.training.synthetic import make_sphere_dataset

    data = make_sphere_dataset(tmp_path / "d", n_objects=1, n_views=4, resolution=16)
    obj = sorted((data / "spheres").glob("obj*"))[0]
    seen = []

    def synthesize_views(cfg):
        seen.append(cfg)
        raise RuntimeError("stop here")
        yield

    monkeypatch.setattr(synthesis, "synthesize_views", synthesize_views)
    args = SimpleNamespace(resolution=16, scene_resolution=16, ref_size=64, device="cpu", threads=1)
    with pytest.raises(RuntimeError, match="stop here"):
        build_scene(args, obj, "procedural:chair:0", [0, 2], tmp_path / "ck", tmp_path / "out", render_picture=False)
    assert [c.ref_size for c in seen] == [64]
