"""`train` and `eval` commands end to end on a tiny analytic set (SRN protocol, JSON + PNG grid)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.models import vgg
from blender_mrvm.training.evaluate import make_grid, summarize
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
HAVE_WEIGHTS = (vgg.weights_dir() / vgg.VGG_FILE).is_file()


def test_summarize_per_category_and_overall():
    recs = [{"category": "a", "psnr": 20.0, "ssim": 0.8, "lpips": 0.2, "baseline_mean": {"psnr": 10.0, "ssim": 0.5, "lpips": 0.5}},
            {"category": "a", "psnr": 22.0, "ssim": 0.9, "lpips": 0.1, "baseline_mean": {"psnr": 12.0, "ssim": 0.5, "lpips": 0.5}},
            {"category": "b", "psnr": 30.0, "ssim": 1.0, "lpips": 0.0, "baseline_mean": {"psnr": 14.0, "ssim": 0.5, "lpips": 0.5}}]
    r = summarize(recs)
    assert r["per_category"]["a"]["psnr"] == 21.0 and r["per_category"]["b"]["n"] == 1
    assert r["overall"]["psnr"] == pytest.approx(24.0) and r["overall"]["baseline_mean"]["psnr"] == pytest.approx(12.0)
    assert r["overall"]["baseline_nearest"]["psnr"] is None
    g = make_grid([[np.zeros((4, 4, 3)), np.ones((4, 4, 3)), np.full((4, 4, 3), 0.5)]], pad=1)
    assert g.shape == (6, 16, 3) and g.dtype == np.uint8 and g[1, 1, 0] == 0 and g[1, 6, 0] == 255


def test_alpha_scores():
    from blender_mrvm.training.evaluate import alpha_scores

    mask = np.zeros((4, 4), bool)
    mask[1:3, 1:3] = True
    assert alpha_scores(mask.astype(float), mask) == {"background": 0.0, "object": 1.0, "iou": 1.0}
    haze = np.where(mask, 0.9, 0.2)
    a = alpha_scores(haze, mask)
    assert a["background"] == pytest.approx(0.2) and a["object"] == pytest.approx(0.9) and a["iou"] == 1.0
    a = alpha_scores(np.full((4, 4), 0.6), mask)  # everything opaque: IoU = object share
    assert a["iou"] == pytest.approx(4 / 16)


def test_train_then_eval_commands(tmp_path, capsys):
    data = make_sphere_dataset(tmp_path / "data", n_objects=2, n_views=4, resolution=16, seed=2)
    cfg = {"model": {"preset": "fast", "overrides": {"encoder": {"widths": [8, 8, 8], "out_dim": 8},
                                                     "nerformer": {"d_model": 8}, "sampler": {"n_coarse": 4, "n_fine": 2}}},
           "train": {"iterations": 2, "rays_per_object": 32, "objects_per_step": 1, "threads": 1}}
    (tmp_path / "run.json").write_text(json.dumps(cfg))
    assert main(["train", "--config", str(tmp_path / "run.json"), "--data", str(data), "--out", str(tmp_path / "run")]) == 0
    args = ["eval", "--checkpoint", str(tmp_path / "run"), "--data", str(data), "--input-views", "0,1",
            "--out", str(tmp_path / "ev"), "--threads", "1"]
    if not HAVE_WEIGHTS:
        args.append("--no-lpips")
    assert main(args) == 0
    rep = json.loads((tmp_path / "ev" / "eval.json").read_text())
    assert rep["protocol"]["input_views"] == [0, 1] and rep["protocol"]["scored_views"] == 2  # test object: views 2, 3
    assert set(rep["per_category"]) == {"spheres"}
    o = rep["overall"]
    assert 5 < o["psnr"] < 60 and 0 < o["ssim"] <= 1 and o["baseline_nearest"]["psnr"] is not None
    if HAVE_WEIGHTS:
        assert 0 <= o["lpips"] < 1
    assert {v["view"] for v in rep["views"]} == {2, 3}
    a = o["alpha"]  # the sphere set has masks: opacity against them
    assert 0 <= a["background"] <= 1 and 0 <= a["object"] <= 1 and 0 <= a["iou"] <= 1
    assert "Opacity (the image planes' alpha)" in (tmp_path / "ev" / "eval.md").read_text()
    assert 0 <= o["depth_abs_rel"] and all(0 <= v["depth_abs_rel"] for v in rep["views"])  # the set has depth maps
    assert 0 <= o["depth_missing"] <= 1 and o["depth_abs_rel"] >= o["depth_missing"]
    assert "mean absolute relative error" in (tmp_path / "ev" / "eval.md").read_text()
    # References as synthesis gives them: trained at 16 px, so 16 px references stay; --ref-size 8 halves them
    # for the model only (baselines stay at the dataset's size).
    assert rep["protocol"]["reference_sizes"] == [[16, 16]]
    assert main(["eval", "--checkpoint", str(tmp_path / "run"), "--data", str(data), "--input-views", "0,1",
                 "--no-lpips", "--ref-size", "8", "--out", str(tmp_path / "ev8"), "--threads", "1"]) == 0
    rep8 = json.loads((tmp_path / "ev8" / "eval.json").read_text())
    assert rep8["protocol"]["reference_sizes"] == [[8, 8]]
    assert rep8["overall"]["baseline_nearest"]["psnr"] == pytest.approx(o["baseline_nearest"]["psnr"])
    assert rep8["overall"]["psnr"] != pytest.approx(o["psnr"], abs=1e-6)
    from blender_mrvm.datasets.format import read_png

    grid = read_png(tmp_path / "ev" / "eval_grid.png")
    assert grid.shape[0] == 16 + 4 and grid.shape[1] == 4 * 16 + 5 * 2
    assert main(["eval", "--checkpoint", str(tmp_path / "run"), "--data", str(data), "--input-views", "7",
                 "--no-lpips", "--out", str(tmp_path / "ev2")]) == 2
    assert "no view(s) [7]" in capsys.readouterr().err


def test_compare_reports_says_which_mean_it_reports():
    """compare.json's ``diff`` is the mean over objects of each object's mean difference (the unit of its standard
    error, as published); ``diff_views`` the mean over the common views: they differ when objects have different
    numbers of views."""
    from blender_mrvm.training.evaluate import compare_reports

    def rep(rows):
        return {"views": [{"category": "c", "object": o, "view": v, "psnr": p, "ssim": 0.5, "lpips": 0.1}
                          for o, v, p in rows]}

    a = rep([("o1", 0, 21.0), ("o1", 1, 21.0), ("o1", 2, 21.0), ("o2", 0, 17.0)])
    b = rep([("o1", 0, 20.0), ("o1", 1, 20.0), ("o1", 2, 20.0), ("o2", 0, 20.0)])
    psnr = compare_reports(a, b)["overall"]["psnr"]
    assert psnr["diff"] == pytest.approx((1.0 - 3.0) / 2)  # per object: o1 +1, o2 -3
    assert psnr["diff_views"] == pytest.approx((3 * 1.0 - 3.0) / 4)
    assert psnr["objects"] == 2 and compare_reports(a, b)["overall"]["views"] == 4
    doc = compare_reports.__doc__
    assert "mean over objects of each object's mean difference" in doc and "``diff_views``" in doc
