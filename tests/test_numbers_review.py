"""The numbers researchers read, checked as a researcher would: SSIM against scikit-image on render-like images,
metrics at the sizes where they stop being defined, identical views in the means, the pairing's ties and unpaired
views, and the points bench model counts."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from blender_mrvm.models import vgg
from blender_mrvm.models.config import model_config
from blender_mrvm.models.metrics import ssim, ssim_gauss
from blender_mrvm.models.model import GeneralizableNeRF
from blender_mrvm.training.checkpoint import save_checkpoint
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
HAVE_WEIGHTS = (vgg.weights_dir() / vgg.VGG_FILE).is_file() and (vgg.weights_dir() / vgg.LPIPS_FILE).is_file()
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
        "sampler": {"n_coarse": 4, "n_fine": 2}}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    cfg = model_config("fast", TINY)
    return save_checkpoint(tmp_path_factory.mktemp("run"), 3, GeneralizableNeRF(cfg), cfg, None)


def _render_like(rng, size=64):
    """A white background with a shaded disc and a few faint speckles: the flat regions where float32 variances
    (E[x^2] - E[x]^2) lose their digits."""
    y, x = np.mgrid[:size, :size] / size
    img = np.ones((size, size, 3))
    disc = (x - 0.5) ** 2 + (y - 0.5) ** 2 < 0.08
    img[disc] = np.stack([0.6 * x, 0.4 + 0.2 * y, 0.3 + 0 * x], -1)[disc]
    spots = rng.random((size, size)) < 0.1
    return np.clip(img + 0.01 * rng.normal(size=img.shape) * spots[..., None], 0, 1)


def test_ssim_matches_scikit_image_within_1e6_on_renders_and_random_images():
    """SSIM in float32 had been up to 4e-5 (uniform) and 5e-5 (Gaussian) off scikit-image on the demo's views:
    flat backgrounds, where E[x^2] - E[x]^2 cancels, and a float32 Gaussian that sums to 1 within 1e-8 only."""
    from skimage.metrics import structural_similarity as sk

    rng = np.random.default_rng(0)
    pairs = [(_render_like(rng), _render_like(rng)) for _ in range(3)]
    pairs += [(rng.random((40, 57, 3)), rng.random((40, 57, 3)))]
    for a, b in pairs:
        a32, b32 = torch.from_numpy(a.astype(np.float32)), torch.from_numpy(b.astype(np.float32))
        a, b = a32.double().numpy(), b32.double().numpy()  # the very numbers scored
        assert ssim(a32, b32).item() == pytest.approx(sk(a, b, channel_axis=-1, data_range=1.0), abs=1e-6)
        ref = sk(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5, use_sample_covariance=False)
        assert ssim_gauss(a32, b32).item() == pytest.approx(ref, abs=1e-6)


def test_ssim_of_images_smaller_than_its_window_is_nan_as_scikit_image_refuses_them():
    """A 6 px image had an SSIM of a 6x6 window (2x2 at 2 px), reported under "7x7 uniform window"; scikit-image
    refuses such images. NaN, written null in eval.json and "-" in eval.md."""
    from skimage.metrics import structural_similarity as sk

    rng = np.random.default_rng(1)
    for side, plain, gauss in ((2, False, False), (6, False, False), (7, True, False), (10, True, False),
                               (11, True, True)):
        a, b = rng.random((side, side, 3)).astype(np.float32), rng.random((side, side, 3)).astype(np.float32)
        got = ssim(torch.from_numpy(a), torch.from_numpy(b)).item()
        got_g = ssim_gauss(torch.from_numpy(a), torch.from_numpy(b)).item()
        assert np.isfinite(got) == plain and np.isfinite(got_g) == gauss, side
        if not plain:
            with pytest.raises(ValueError):
                sk(a, b, channel_axis=-1, data_range=1.0)


@pytest.mark.skipif(not HAVE_WEIGHTS, reason=f"offline weights missing: run `{vgg.FETCH_COMMAND}`")
def test_eval_refuses_lpips_on_images_under_16_px_before_rendering(checkpoint, tmp_path, capsys):
    """LPIPS-VGG of an 8 px view had been max_pool2d's RuntimeError traceback after the first render: refused up
    front in one line naming --no-lpips; without LPIPS the evaluation runs, its Gaussian SSIM null (under its
    window)."""
    from blender_mrvm.models.metrics import LPIPS

    root = tmp_path / "d"
    make_sphere_dataset(root, n_objects=1, n_views=4, resolution=8, seed=1, category="red")
    F.write_split(root, "test", ["red/obj000"])
    base = ["eval", "--checkpoint", str(checkpoint), "--data", str(root), "--input-views", "0", "--threads", "1"]
    capsys.readouterr()
    assert main([*base, "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at least 16 px" in err[0] and "--no-lpips" in err[0], err
    assert not (tmp_path / "e").exists()
    from blender_mrvm.errors import InputError

    with pytest.raises(InputError, match="16 px"):
        LPIPS()(torch.rand(8, 8, 3), torch.rand(8, 8, 3))
    assert main([*base, "--no-lpips", "--out", str(tmp_path / "f")]) == 0
    o = json.loads((tmp_path / "f" / "eval.json").read_text())["overall"]
    assert o["ssim_gauss"] is None and o["ssim"] is not None and o["psnr"] is not None  # 8 px: 7x7 fits, 11x11 not


def _one_object(tmp_path):
    """A dataset of one 6-view sphere (16 px) listed as the test split: (its root, its object folder)."""
    root = tmp_path / "d"
    make_sphere_dataset(root, n_objects=1, n_views=6, resolution=16, seed=1, category="red")
    F.write_split(root, "test", ["red/obj000"])
    return root, root / "red" / "obj000"


def _eval(checkpoint, root, out) -> dict:
    """eval.json of views 0 and 1 as references, the others targets (no LPIPS)."""
    assert main(["eval", "--checkpoint", str(checkpoint), "--data", str(root), "--input-views", "0,1", "--threads", "1",
                 "--no-lpips", "--out", str(out)]) == 0
    return json.loads((out / "eval.json").read_text())


def test_views_equal_to_the_truth_are_counted_where_psnr_leaves_them_out(checkpoint, tmp_path, capsys):
    """A target identical to a reference (a repeated pose) has PSNR +inf for the nearest-view baseline: the mean had
    left it out without a word (eval.md's "views 4" over a baseline mean of 3). Now counted in eval.json and said in
    eval.md; a NaN PSNR no longer drops out of the mean alone (its mean is null, as every other score's)."""
    from blender_mrvm.training.evaluate import summarize

    root, obj = _one_object(tmp_path)
    for sub in (p for p in obj.iterdir() if p.is_dir()):  # view 5 := view 0 (pose, image, depth, mask)
        for f in [f for f in sub.iterdir() if f.stem == "000000"]:
            shutil.copy(f, sub / f"000005{f.suffix}")
    out = tmp_path / "e"
    rep = _eval(checkpoint, root, out)
    near = {v["view"]: v["baseline_nearest"]["psnr"] for v in rep["views"]}
    assert near[5] is None and all(near[v] is not None for v in (2, 3, 4))
    o = rep["overall"]
    assert o["n"] == 4 and o["baseline_nearest"]["psnr_identical_views"] == 1
    assert o["baseline_nearest"]["psnr"] == pytest.approx(np.mean([near[v] for v in (2, 3, 4)]))
    assert "psnr_identical_views" not in o and "psnr_identical_views" not in o["baseline_mean"]
    assert "nearest view 1 of 4" in (out / "eval.md").read_text()
    recs = [{"category": "c", "object": "o", "view": i, "psnr": p, "baseline_nearest": {}, "baseline_mean": {}}
            for i, p in enumerate((20.0, float("nan")))]
    assert not np.isfinite(summarize(recs)["overall"]["psnr"])


def test_compare_counts_ties_and_unpaired_views(checkpoint, tmp_path, capsys):
    """`wins` 0.0 had read "worse on every object" where the two were equal (an eval against itself, a depth score
    no setting moves); views scored by one side only were left out, and other rendering settings (--ref-size,
    --skip-empty, --precision) paired, without a word."""
    from blender_mrvm.training.evaluate import compare_reports

    def rep(objs, **protocol):
        return {"precision": "fp32", "protocol": {"empty_space_skipping": "cull", **protocol},
                "views": [{"category": "c", "object": o, "view": 0, "psnr": 20.0} for o in objs]}

    c = compare_reports(rep(["a", "b", "x"]), rep(["a", "b"]))
    assert c["overall"]["psnr"]["wins"] == 0.0 and c["overall"]["psnr"]["ties"] == 1.0
    assert c["unpaired"] == {"this": 1, "other": 0} and c["settings_differ"] == {}
    c = compare_reports(rep(["a"], reference_sizes=[[32, 32]]), rep(["a"], reference_sizes=[[64, 64]],
                                                                   empty_space_skipping="off"))
    assert c["settings_differ"] == {"protocol.empty_space_skipping": ["cull", "off"],
                                    "protocol.reference_sizes": [[[32, 32]], [[64, 64]]]}

    root = tmp_path / "d"
    make_sphere_dataset(root, n_objects=2, n_views=4, resolution=16, seed=1, category="red")
    F.write_split(root, "test", ["red/obj000", "red/obj001"])
    base = ["eval", "--checkpoint", str(checkpoint), "--data", str(root), "--input-views", "0", "--threads", "1",
            "--no-lpips", "--max-targets", "1"]
    assert main([*base, "--out", str(tmp_path / "a")]) == 0
    capsys.readouterr()
    assert main([*base, "--max-objects", "1", "--skip-empty", "off", "--out", str(tmp_path / "b"),
                 "--compare-to", str(tmp_path / "a" / "eval.json")]) == 0
    cap = capsys.readouterr()
    line = json.loads(cap.out.strip().splitlines()[-1])
    assert line["compare"]["unpaired"] == {"this": 0, "other": 1}
    assert "pairs the 1 views both scored; left out: 0 scored only here, 1 only in" in cap.err
    assert "other settings: protocol.empty_space_skipping off against cull" in cap.err


def test_bench_model_points_evaluated_are_the_points_the_render_counted(tmp_path):
    """points_evaluated had been evaluated rays x (coarse + fine + coarse) although the fine pass skips rays whose
    coarse opacity is under render.fine_min_acc (on by default): 76224 against the 75728 the render evaluated."""
    from blender_mrvm.bench.model import points_per_ray
    from blender_mrvm.models import registry

    assert main(["bench", "model", "--presets", "fast", "--views", "2", "--sizes", "64", "--repeats", "1",
                 "--threads", "1", "--out", str(tmp_path)]) == 0
    row = next(csv.DictReader(open(tmp_path / "bench_model.csv")))
    every = int(row["rays_evaluated"]) * points_per_ray(registry.build_config(None, "fast"))
    assert 0 < int(row["points_evaluated"]) < every


def test_opacity_on_object_pixels_leaves_out_views_without_any(checkpoint, tmp_path):
    """A target whose mask holds no object pixel (the object out of frame) had scored opacity 0.0 "on object
    pixels", pulling the mean over views down (0.337 against 0.449 over the three views that have some): now null
    for that view and left out of the mean."""
    from PIL import Image

    from blender_mrvm.training.evaluate import alpha_scores

    root, obj_dir = _one_object(tmp_path)
    Image.fromarray(np.zeros((16, 16), np.uint8)).save(obj_dir / "mask" / "000003.png")
    rep = _eval(checkpoint, root, tmp_path / "e")
    obj = {v["view"]: v["alpha"]["object"] for v in rep["views"]}
    assert obj[3] is None and all(obj[v] > 0 for v in (2, 4, 5))
    assert rep["overall"]["alpha"]["object"] == pytest.approx(np.mean([obj[v] for v in (2, 4, 5)]))
    assert alpha_scores(np.full((2, 2), 0.3), np.ones((2, 2), bool))["background"] is None


def test_the_demo_table_prints_an_opacity_without_object_pixels_as_a_dash(capsys):
    """eval's opacity on object pixels is None where no view has any (it counted 0.0 before); the demo's table
    formatted it with :.3f, a TypeError after the run."""
    from blender_mrvm.commands.demo import _print_table

    block = {"psnr": 20.0, "ssim": 0.8, "lpips": 0.2, "baseline_nearest": {"psnr": 18.0}, "baseline_mean": {"psnr": 15.0}}
    report = {"per_category": {"chair": block},
              "overall": {**block, "n": 4, "psnr_gain_over_best_baseline": 2.0,
                          "alpha": {"background": 0.01, "object": None, "iou": None}}}
    _print_table(report, with_lpips=True)
    assert "0.010 mean on background, - on the object, IoU -" in capsys.readouterr().out
