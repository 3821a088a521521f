"""Numerical stability of the renderer, samplers, ray clipping and projection at the extremes (issue 4)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings, strategies as st

from blender_mrvm.geometry import cameras
from blender_mrvm.models import samplers
from blender_mrvm.models.config import model_config
from blender_mrvm.models.model import GeneralizableNeRF, normalized_scene, ref_cameras
from blender_mrvm.models.projection import RefCameras, project_samples, rays_in_cameras
from blender_mrvm.models.rays import intersect_box, make_rays
from blender_mrvm.models.renderer import deltas_from_t, render_weights, volume_render

torch.set_num_threads(1)


def _render(sigma, t, rgb=None, last=float("inf")):
    sigma = torch.as_tensor(sigma, dtype=torch.float32)
    t = torch.as_tensor(t, dtype=torch.float32)
    if rgb is None:
        rgb = torch.zeros(sigma.shape + (3,))
    return volume_render(sigma, rgb, t, white_background=True, last_delta=last)


# ---------------------------------------------------------------------------------------- renderer

def test_empty_ray_is_pure_background():
    out = _render(torch.zeros(2, 8), torch.linspace(0, 1, 8).expand(2, 8))
    assert torch.equal(out["weights"], torch.zeros(2, 8))
    assert torch.equal(out["transmittance"], torch.ones(2, 8))
    assert torch.equal(out["acc"], torch.zeros(2))
    assert torch.equal(out["color"], torch.ones(2, 3))  # white background, black samples unseen


def test_infinite_density_stops_at_first_sample():
    sigma = torch.tensor([[0.0, 1e10, 1e10, 0.0]])
    out = _render(sigma, torch.tensor([[0.0, 0.1, 0.2, 0.3]]))
    assert torch.allclose(out["weights"], torch.tensor([[0.0, 1.0, 0.0, 0.0]]))
    assert torch.equal(out["color"], torch.zeros(1, 3))  # black sample, opaque
    assert abs(out["depth"].item() - 0.1) < 1e-6


def test_infinite_last_step_and_zero_density_no_nan():
    # sigma = 0 with an infinite last step must not give 0 * inf = NaN; sigma > 0 there is opaque.
    w, trans = render_weights(torch.tensor([[0.0, 0.0]]), deltas_from_t(torch.tensor([[0.0, 1.0]])))
    assert torch.equal(w, torch.zeros(1, 2)) and torch.equal(trans, torch.ones(1, 2))
    w, _ = render_weights(torch.tensor([[0.0, 1e-3]]), deltas_from_t(torch.tensor([[0.0, 1.0]])))
    assert torch.allclose(w, torch.tensor([[0.0, 1.0]]))


def test_tiny_step_alpha_is_exact():
    # alpha = -expm1(-sigma * delta) keeps precision where 1 - exp() would round to 0 in float32.
    w, _ = render_weights(torch.tensor([[1.0, 0.0]]), torch.tensor([[1e-10, 1.0]]))
    assert w[0, 0].item() == pytest.approx(1e-10, rel=1e-4)
    assert (1.0 - torch.exp(torch.tensor(-1e-10))).item() == 0.0  # what the naive formula would give


def test_weights_sum_to_one_minus_transmittance():
    g = torch.Generator().manual_seed(0)
    sigma = torch.rand(64, 16, generator=g) * 20
    t = torch.sort(torch.rand(64, 16, generator=g), -1).values
    out = _render(sigma, t, last=0.5)
    trans_end = torch.exp(-(sigma * deltas_from_t(t, 0.5)).sum(-1))
    assert torch.allclose(out["acc"] + trans_end, torch.ones(64), atol=1e-5)


def test_no_samples_is_background():
    out = _render(torch.zeros(3, 0), torch.zeros(3, 0))
    assert torch.equal(out["color"], torch.ones(3, 3)) and torch.equal(out["acc"], torch.zeros(3))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 1e10, allow_nan=False), min_size=1, max_size=12),
       st.floats(1e-10, 10.0), st.booleans())
def test_renderer_property_finite_and_bounded(sigmas, step, infinite_last):
    sigma = torch.tensor([sigmas], dtype=torch.float32)
    t = torch.arange(len(sigmas), dtype=torch.float32)[None] * step
    out = _render(sigma, t, rgb=torch.rand(1, len(sigmas), 3), last=float("inf") if infinite_last else step)
    for k in ("color", "depth", "acc", "weights"):
        assert torch.isfinite(out[k]).all(), k
    assert -1e-6 <= out["acc"].item() <= 1 + 1e-6
    assert ((out["color"] >= -1e-6) & (out["color"] <= 1 + 1e-6)).all()


def test_bf16_autocast_render_finite():
    sigma = torch.tensor([[0.0, 1e10, 3.0]], dtype=torch.bfloat16)
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = _render(sigma, torch.tensor([[0.0, 0.5, 1.0]]))
    assert out["color"].dtype == torch.float32 and torch.isfinite(out["color"]).all()
    assert out["acc"].item() == pytest.approx(1.0)


# ----------------------------------------------------------------------------------------- samplers

def test_inverse_cdf_all_zero_weights_gives_uniform_samples():
    edges = torch.linspace(0, 2, 9).expand(4, 9)
    s = samplers.sample_pdf(edges, torch.zeros(4, 8), 7, deterministic=True)
    assert torch.isfinite(s).all()
    assert torch.allclose(s, torch.linspace(0, 2, 9)[1:-1].expand(4, 7), atol=1e-4)


def test_inverse_cdf_concentrates_on_heavy_bin_and_zero_width_bins():
    edges = torch.tensor([[0.0, 0.0, 0.0, 1.0, 2.0, 2.0]])  # zero-width bins
    w = torch.tensor([[0.0, 5.0, 0.0, 1.0, 0.0]])
    s = samplers.sample_pdf(edges, w, 64, deterministic=False, generator=torch.Generator().manual_seed(1))
    assert torch.isfinite(s).all() and (s >= 0).all() and (s <= 2).all()
    w = torch.tensor([[0.0, 0.0, 0.0, 1.0, 0.0]])
    s = samplers.sample_pdf(edges, w, 64, deterministic=True)
    assert ((s >= 1.0) & (s <= 2.0)).float().mean() > 0.99


def test_stratified_within_bins():
    far = torch.tensor([0.0, 1.0, 3.0])
    t = samplers.stratified(far, 5, perturb=True, generator=torch.Generator().manual_seed(0))
    assert (t >= 0).all() and (t <= far[:, None]).all() and torch.equal(t[0], torch.zeros(5))
    assert (torch.diff(t, dim=-1) >= 0).all()


# ----------------------------------------------------------------------------------------- box

def test_box_rays_parallel_inside_and_missing():
    lo, hi = np.full(3, -1.0), np.full(3, 1.0)
    o = np.array([[-5.0, 0.0, 0.0],   # along +x, parallel to four faces: hits
                  [-5.0, 1.0, 0.0],   # grazing the y = 1 face exactly: degenerate, no NaN
                  [-5.0, 2.0, 0.0],   # parallel, outside the slab: misses
                  [0.0, 0.0, 0.0],    # inside the box: starts at 0
                  [5.0, 0.0, 0.0]])   # pointing away: misses
    d = np.array([[1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0, 0, 1.0], [1.0, 0, 0]])
    tn, tf, hit = intersect_box(o, d, lo, hi)
    assert not np.any(np.isnan(tn)) and not np.any(np.isnan(tf))
    assert np.all(np.isfinite(tn[hit])) and np.all(np.isfinite(tf[hit]))
    assert hit.tolist() == [True, True, False, True, False]
    assert (tn[0], tf[0]) == (4.0, 6.0) and (tn[3], tf[3]) == (0.0, 1.0)
    tn2, tf2, hit2 = intersect_box(torch.from_numpy(o), torch.from_numpy(d), lo, hi)
    assert hit2.tolist() == hit.tolist() and torch.allclose(tn2[hit2], torch.from_numpy(tn[hit]))


@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=3, max_size=3), st.lists(st.floats(-1, 1), min_size=3, max_size=3))
def test_box_property_entry_and_exit_on_surface(o, d):
    d = np.asarray(d)
    if np.linalg.norm(d) < 1e-6:
        return
    d = d / np.linalg.norm(d)
    o = np.asarray(o)[None]
    tn, tf, hit = intersect_box(o, d[None], -np.ones(3), np.ones(3))
    if hit[0]:
        for tv in (tn[0], tf[0]):
            p = o[0] + tv * d
            assert np.max(np.abs(p)) <= 1 + 1e-9
        if np.max(np.abs(o)) > 1:
            assert abs(np.max(np.abs(o[0] + tn[0] * d)) - 1) < 1e-9
    else:  # a missed ray has no point inside the box at any t >= 0 (sampled densely)
        ts = np.linspace(0, 40, 4001)
        p = o[0] + ts[:, None] * d
        assert not np.any(np.max(np.abs(p), axis=1) < 1 - 1e-3)


# ----------------------------------------------------------------------------------------- projection

def _cams(c2ws, intr):
    return ref_cameras(c2ws, [intr] * len(c2ws))


def test_points_behind_or_on_camera_plane_are_masked_never_nan():
    intr = cameras.intrinsics_from_fov(math.radians(60), 32, 32)
    cam = _cams([np.eye(4)], intr)  # camera at origin looking down +z
    o = torch.tensor([[0.0, 0.0, -1.0], [0.5, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    t = torch.tensor([[0.0, 1.0, 2.0]] * 3)
    o_c, d_c = rays_in_cameras(cam, o, d)
    uv, valid, _ = project_samples(cam, o_c, d_c, t)
    assert torch.isfinite(uv).all()
    # ray 0: z = -1 (behind), 0 (camera centre, on the plane), +1 (in front, centre of image)
    assert valid[0, 0].tolist() == [False, False, True]
    assert torch.allclose(uv[0, 0, 2], torch.zeros(2), atol=1e-6)
    assert not valid[0, 1].any()  # ray 1 lies in the camera plane z = 0
    assert valid[0, 2].tolist() == [False, True, True]


def test_projection_matches_cameras_project():
    rng = np.random.default_rng(0)
    intr = cameras.Intrinsics(40.0, 44.0, 15.0, 17.0, 32, 30)
    c2w = cameras.look_at_opencv([2.0, -1.0, 1.0])
    cam = _cams([c2w], intr)
    o = torch.from_numpy(rng.uniform(-0.3, 0.3, (5, 3)))
    d = torch.nn.functional.normalize(torch.from_numpy(rng.normal(size=(5, 3))), dim=-1)
    t = torch.rand(5, 4, dtype=torch.float32) * 0.2
    o_c, d_c = rays_in_cameras(cam, o, d)
    uv, valid, _ = project_samples(cam, o_c, d_c, t)
    pts = (o[:, None] + t.double()[..., None] * d[:, None]).reshape(-1, 3).numpy()
    px, z = cameras.project(intr.K, cameras.invert_pose(c2w), pts)
    expect = np.stack([2 * px[:, 0] / 32 - 1, 2 * px[:, 1] / 30 - 1], -1)
    assert np.allclose(uv[0].reshape(-1, 2).numpy(), expect, atol=1e-5)


# ----------------------------------------------------------------------------------------- whole model

@pytest.fixture(scope="module")
def tiny_model():
    torch.manual_seed(0)
    cfg = model_config("fast", {"encoder": {"widths": [8, 8, 8], "out_dim": 8},
                                "nerformer": {"d_model": 8, "n_heads": 2},
                                "sampler": {"n_coarse": 4, "n_fine": 4}, "render": {"density_bias": 2.0}})
    return GeneralizableNeRF(cfg).eval()


def _view(model, fov_deg, size, dist, res=(8, 8), chunk=None):
    intr = cameras.intrinsics_from_fov(math.radians(fov_deg), *res)
    eyes = [np.array(e) / np.linalg.norm(e) * dist for e in ([1, 0.2, 0.3], [-0.3, 1, 0.2], [0.5, -0.8, 0.6])]
    poses = [cameras.look_at_opencv(e) for e in eyes]
    bbox = (np.full(3, -size / 2), np.full(3, size / 2))
    rng = np.random.default_rng(0)
    refs = rng.random((2, res[1], res[0], 3)).astype(np.float32)
    return model.synthesize(refs, poses[:2], [intr, intr], bbox, poses[2], intr, chunk=chunk)


@pytest.mark.parametrize("fov,size,dist", [(1.0, 1.0, 200.0), (170.0, 1.0, 1.5), (50.0, 1e-3, 2e-3),
                                           (50.0, 1e3, 2e3), (0.02, 1.0, 1e4), (50.0, 1e-3, 1e4)])
def test_model_extremes_finite(tiny_model, fov, size, dist):
    out = _view(tiny_model, fov, size, dist)
    assert torch.isfinite(out["color"]).all() and torch.isfinite(out["depth"]).all()
    assert ((out["color"] >= 0) & (out["color"] <= 1)).all()
    if out["evaluated"]:
        hit = out["acc"] > 0.5
        if hit.any():  # depth in world units lies near the object, wherever the camera is
            dd = out["depth"][hit]
            assert ((dd > dist - size * 2) & (dd < dist + size * 2)).all()


def test_model_1x1_and_missing_rays_are_background(tiny_model):
    out = _view(tiny_model, 50, 1.0, 3.0, res=(1, 1))
    assert out["color"].shape == (1, 1, 3) and out["evaluated"] == 1
    # camera looking away from the object: nothing evaluated, pure white
    intr = cameras.intrinsics_from_fov(math.radians(30), 4, 4)
    away = cameras.look_at_opencv([0, 0, 5.0], target=[0, 0, 10.0], up=[0, 1, 0])
    refs = np.ones((1, 4, 4, 3), np.float32)
    out = tiny_model.synthesize(refs, [cameras.look_at_opencv([3.0, 0, 0])], [intr],
                                (-np.ones(3), np.ones(3)), away, intr)
    assert out["evaluated"] == 0 and torch.equal(out["color"], torch.ones(4, 4, 3))


def test_large_render_chunked_matches_unchunked(tiny_model):
    a = _view(tiny_model, 40, 1.0, 3.0, res=(24, 20), chunk=7)
    b = _view(tiny_model, 40, 1.0, 3.0, res=(24, 20), chunk=100000)
    assert torch.allclose(a["color"], b["color"], atol=1e-5)


@pytest.mark.slow
def test_2048_render_memory_bounded_by_chunking(tiny_model):
    import resource

    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    intr = cameras.intrinsics_from_fov(math.radians(2.0), 2048, 2048)  # from 300 units the box covers ~1% of it
    poses = [cameras.look_at_opencv(np.array(e)) for e in ([3.0, 0, 0], [0, 3.0, 0], [180.0, 180.0, 150.0])]
    refs = np.ones((2, 8, 8, 3), np.float32)
    ref_intr = cameras.intrinsics_from_fov(math.radians(50), 8, 8)
    ns = normalized_scene(np.full(3, -0.5), np.full(3, 0.5), 0.0)
    ctx = tiny_model.encode(torch.from_numpy(refs).permute(0, 3, 1, 2), ref_cameras([ns.pose(p) for p in poses[:2]],
                                                                                      [ref_intr] * 2))
    out = tiny_model.render_image(ctx, intr, ns.pose(poses[2]), ns.box, chunk=256)
    grown_mb = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
    assert out["color"].shape == (2048, 2048, 3) and torch.isfinite(out["color"]).all()
    assert 0 < out["evaluated"] < out["rays"]
    assert grown_mb < 1500, grown_mb  # ray arrays of 4M rays are ~400 MB; per-chunk work is small


def test_model_bf16_autocast_finite(tiny_model):
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = _view(tiny_model, 50, 1.0, 3.0)
    assert torch.isfinite(out["color"]).all() and out["color"].dtype == torch.float32


@settings(max_examples=15, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(-1.4, 1.4), st.floats(1.3, 50.0), st.floats(5.0, 150.0))
def test_model_property_random_poses(az, el, dist, fov):
    model = test_model_property_random_poses.model
    eye = dist * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    intr = cameras.intrinsics_from_fov(math.radians(fov), 6, 5)
    poses = [cameras.look_at_opencv(eye), cameras.look_at_opencv([2.0, 0.5, 0.3]), cameras.look_at_opencv([-0.4, 0.1, 3.0])]
    out = model.synthesize(np.random.default_rng(0).random((2, 5, 6, 3)), poses[1:], [intr, intr],
                           (-np.ones(3) * 0.5, np.ones(3) * 0.5), poses[0], intr)
    assert torch.isfinite(out["color"]).all() and torch.isfinite(out["depth"]).all()


test_model_property_random_poses.model = GeneralizableNeRF(model_config(
    "fast", {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
             "sampler": {"n_coarse": 4, "n_fine": 2}})).eval()


def test_short_attention_matches_the_fused_kernel(monkeypatch):
    """The written-out attention for short sequences (the GPU default at inference, MRVM_SHORT_ATTENTION) gives what the fused
    kernel gives, masks and a sequence with no valid key included, and a model renders the same through it."""
    import numpy as np

    from blender_mrvm.geometry import cameras
    from blender_mrvm.models import nerformer, registry

    torch.manual_seed(0)
    att = nerformer.Attention(24, 2)
    x = torch.randn(50, 3, 24)
    valid = torch.rand(50, 3) > 0.4
    valid[0] = False  # nothing to attend to: uniform weights, never NaN
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 0)
    ref = att(x, valid)
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 4)
    got = att(x, valid)
    assert torch.isfinite(got).all() and torch.allclose(got, ref, atol=1e-5)
    x16 = torch.randn(40, 16, 24)  # the ray attention's 8 + 8 samples of `fast`'s fine pass
    valid16 = torch.rand(40, 16) > 0.3
    valid16[3] = False
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 0)
    ref16 = att(x16, valid16)
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 16)
    assert torch.allclose(att(x16, valid16), ref16, atol=1e-5)
    model = registry.build_model(registry.build_config(None, "fast"), load_pretrained=False).eval()
    intr = cameras.Intrinsics(30.0, 30.0, 8.0, 8.0, 16, 16)
    eyes = [np.array(e, float) / np.linalg.norm(e) * 1.3 for e in ([1, 0.2, 0.4], [-0.2, 1, 0.3], [0.6, -0.7, 0.5])]
    refs = np.random.default_rng(0).random((2, 16, 16, 3)).astype(np.float32)
    args = (refs, [cameras.look_at_opencv(e) for e in eyes[1:]], [intr] * 2, (np.full(3, -0.4), np.full(3, 0.4)),
            cameras.look_at_opencv(eyes[0]), intr)
    short = model.synthesize(*args)  # SHORT_ATTENTION_MAX 16: view and ray attention written out
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 0)
    fused = model.synthesize(*args)
    assert np.allclose(np.asarray(short["color"]), np.asarray(fused["color"]), atol=1e-5)


def test_short_attention_default_policy(monkeypatch):
    """Unset, the written-out attention is used at inference on a GPU only (measured there: session 23), never on the
    CPU or in training; MRVM_SHORT_ATTENTION overrides both ways."""
    from types import SimpleNamespace

    from blender_mrvm.models import nerformer

    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", None)
    gpu, cpu = SimpleNamespace(is_cuda=True), torch.zeros(1)
    with torch.no_grad():
        assert nerformer.short_attention_max(gpu) == nerformer.SHORT_ATTENTION_CUDA == 16
        assert nerformer.short_attention_max(cpu) == 0
    with torch.enable_grad():
        assert nerformer.short_attention_max(gpu) == 0
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 0)
    with torch.no_grad():
        assert nerformer.short_attention_max(gpu) == 0
    monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", 4)
    assert nerformer.short_attention_max(cpu) == 4
    from blender_mrvm.errors import InputError

    for bad in ("yes", -1):  # a one-line error when a model first attends, not a traceback at import
        monkeypatch.setattr(nerformer, "SHORT_ATTENTION_MAX", bad)
        with pytest.raises(InputError, match="MRVM_SHORT_ATTENTION"):
            nerformer.short_attention_max(cpu)


def test_a_nan_render_is_an_error_naming_the_checkpoint(tmp_path):
    """Finite weights of 1e30 (a diverged training step; loading refuses only NaN) render NaN, which had been written
    as black images (NaN casts to 0) and into eval.json as NaN (not JSON)."""
    import json

    from blender_mrvm.errors import InputError
    from blender_mrvm.training import checkpoint as ckpt
    from blender_mrvm.training.evaluate import report_json

    cfg = model_config("fast", {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
                                "sampler": {"n_coarse": 4, "n_fine": 2}})
    torch.manual_seed(0)
    model = GeneralizableNeRF(cfg)
    with torch.no_grad():
        for p in model.parameters():
            p.fill_(1e30)
    ck = ckpt.save_checkpoint(tmp_path / "run", 1, model, cfg, None)
    model, _, _ = ckpt.load_model(tmp_path / "run")  # finite: it loads
    intr = cameras.intrinsics_from_fov(math.radians(40), 16, 16)
    c2w = [cameras.look_at_opencv(np.array([2.0, 0.3 * i, 1.0])) for i in range(2)]
    bbox = (np.full(3, -0.5), np.full(3, 0.5))
    with pytest.raises(InputError, match=f"NaN or infinite values .*the checkpoint {ck / 'model.safetensors'} is "
                                         "probably broken"):
        model.synthesize(np.ones((2, 16, 16, 3), np.float32), c2w, [intr, intr], bbox, c2w[0], intr)
    text = report_json({"overall": {"psnr": None, "ssim": float("nan"), "lpips": np.float32("inf")}, "n": [1.0]})
    assert json.loads(text) == {"overall": {"psnr": None, "ssim": None, "lpips": None}, "n": [1.0]}
    assert "NaN" not in text and "Infinity" not in text
