"""Model components: configs, shapes, MRVM masks, stop-gradient on the target branch, lambda schedule."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras
from blender_mrvm.models import config as C
from blender_mrvm.models.encoder import ImageEncoder
from blender_mrvm.models.model import GeneralizableNeRF, normalized_scene, ref_cameras
from blender_mrvm.models.mrvm import lambda_at, make_mask, normalized_l2
from blender_mrvm.models.rays import make_rays

torch.set_num_threads(1)

TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8, "n_heads": 2},
        "sampler": {"n_coarse": 6, "n_fine": 4, "fine_includes_coarse": True}}


def test_presets_are_named_valid_and_round_trip():
    assert set(C.PRESETS) == {"fast", "balanced", "accurate", "paper"}
    for name, cfg in C.PRESETS.items():
        C.validate(cfg)
        assert cfg.name == name
        assert C.from_dict(C.ModelConfig, C.to_dict(cfg)) == cfg
    sizes = [sum(p.numel() for p in GeneralizableNeRF(C.PRESETS[n], load_pretrained=False).parameters())
             for n in ("fast", "balanced", "accurate", "paper")]
    assert sizes[0] < sizes[1] < sizes[2] < sizes[3]
    assert C.model_config("balanced", {"mrvm": {"lambda_max": 0.2}}).mrvm.lambda_max == 0.2
    with pytest.raises(InputError, match="unknown"):
        C.model_config("balanced", {"mrvm": {"lambda": 0.2}})
    with pytest.raises(InputError, match="preset"):
        C.model_config("huge")
    with pytest.raises(InputError, match="divisible"):
        C.model_config("fast", {"nerformer": {"d_model": 7}})


def test_every_config_field_has_a_docstring():
    import inspect

    for cls in (C.EncoderConfig, C.SamplerConfig, C.NeRFormerConfig, C.MRVMConfig, C.RenderConfig, C.ModelConfig):
        src = inspect.getsource(cls)
        for f in C.fields(cls):
            after = src.split(f"    {f.name}:", 1)[1].splitlines()[1].strip()
            assert after.startswith('"""'), (cls.__name__, f.name)


def test_encoder_shapes_multi_scale():
    enc = ImageEncoder(C.EncoderConfig(widths=(8, 12, 16), out_dim=10))
    f = enc(torch.rand(3, 3, 32, 24))
    assert f.shape == (3, 10, 16, 12)


def test_mrvm_mask_counts_and_views():
    cfg = C.MRVMConfig(point_mask_ratio=0.5, view_mask_prob=0.3)
    g = torch.Generator().manual_seed(0)
    point, views = make_mask(50, 10, 4, cfg, g)
    assert point.shape == (50, 10) and views.shape == (50, 10, 4)
    assert (point.sum(1) == 5).all()
    assert (views.any(-1) == point).all()  # masked points mask >= 1 view, others none
    frac = views[point].float().mean().item()
    assert 0.3 < frac < 0.6  # 0.3 each plus the forced one: 1 - 0.7 * 0.75 = 0.475
    all_views = make_mask(4, 6, 3, C.MRVMConfig(point_mask_ratio=1.0, view_mask_prob=1.0), g)[1]
    assert all_views.all()


def test_lambda_schedule():
    cfg = C.MRVMConfig(lambda_max=0.1, warmup_frac=0.1, ramp_end_frac=1.0)
    assert lambda_at(0, 1000, cfg) == 0.0 and lambda_at(99, 1000, cfg) == 0.0
    assert lambda_at(100, 1000, cfg) == pytest.approx(0.0)
    assert lambda_at(550, 1000, cfg) == pytest.approx(0.05)
    assert lambda_at(999, 1000, cfg) == pytest.approx(0.1 * 899 / 900)
    assert lambda_at(1000, 1000, cfg) == 0.0  # finetuning: off
    assert lambda_at(500, 1000, C.MRVMConfig(enabled=False)) == 0.0
    assert lambda_at(300, 1000, C.MRVMConfig(warmup_frac=0.1, ramp_end_frac=0.2)) == pytest.approx(0.1)


def test_normalized_l2_is_two_minus_two_cos():
    a = torch.tensor([[1.0, 0.0], [1.0, 0.0], [2.0, 2.0]])
    b = torch.tensor([[3.0, 0.0], [-1.0, 0.0], [0.0, 5.0]])
    assert torch.allclose(normalized_l2(a, b), torch.tensor([0.0, 4.0, 2 - 2 * math.cos(math.pi / 4)]))


def _setup(seed=0, V=2, mrvm=None):
    torch.manual_seed(seed)
    over = dict(TINY)
    if mrvm:
        over = {**over, "mrvm": mrvm}
    m = GeneralizableNeRF(C.model_config("fast", over))
    intr = cameras.intrinsics_from_fov(math.radians(45), 16, 16)
    ns = normalized_scene(np.full(3, -0.5), np.full(3, 0.5), 0.05)
    eyes = [[2.0, 0.3, 0.5], [0.2, 2.0, 0.4], [-1.0, -1.5, 1.0], [1.5, -1.5, 0.2]]
    poses = [ns.pose(cameras.look_at_opencv(e)) for e in eyes]
    ctx = m.encode(torch.rand(V, 3, 16, 16), ref_cameras(poses[:V], [intr] * V))
    rays = make_rays(intr, poses[-1], box=ns.box)
    rays = rays.select(torch.nonzero(rays.hit).flatten()[:32])
    return m, ctx, rays


def test_render_rays_shapes_and_mrvm_loss():
    m, ctx, rays = _setup()
    out = m.render_rays(ctx, rays, train=True, mask_views=True, generator=torch.Generator().manual_seed(0))
    R = len(rays)
    assert out["coarse"]["color"].shape == (R, 3) and out["fine"]["color"].shape == (R, 3)
    assert out["coarse"]["weights"].shape == (R, 6) and out["fine"]["weights"].shape == (R, 10)
    assert out["n_masked"] == R * 5
    assert out["mrvm_loss"].ndim == 0 and 0.0 <= out["mrvm_loss"].item() <= 4.0
    out2 = m.render_rays(ctx, rays, train=True, mask_views=False)
    assert out2["mrvm_loss"] is None


def test_target_branch_gets_no_gradient_from_mrvm():
    m, ctx, rays = _setup()
    out = m.render_rays(ctx, rays, train=True, mask_views=True, generator=torch.Generator().manual_seed(1))
    out["mrvm_loss"].backward()
    assert all(p.grad is None for p in m.mrvm.target_projector.parameters())
    assert all(not p.requires_grad for p in m.mrvm.target_projector.parameters())
    # the coarse branch is only the target here: its parameters get no gradient from this loss
    assert all(p.grad is None or p.grad.abs().max() == 0 for p in m.coarse.parameters())
    assert m.fine.mask_token.grad is not None and m.fine.mask_token.grad.abs().sum() > 0
    assert m.mrvm.predictor[0].weight.grad.abs().sum() > 0


def test_ema_update_moves_target_towards_online():
    m, _, _ = _setup()
    with torch.no_grad():
        for p in m.mrvm.projector.parameters():
            p.add_(1.0)
    before = [p.clone() for p in m.mrvm.target_projector.parameters()]
    m.mrvm.update_target(0.9)
    for b, t, o in zip(before, m.mrvm.target_projector.parameters(), m.mrvm.projector.parameters()):
        assert torch.allclose(t, 0.9 * b + 0.1 * o)


def test_official_bn_relu_head_trains_and_its_target_tracks_the_statistics():
    """mrvm.head 'bn_relu' (the official code's projector and predictor: BatchNorm1d, ReLU, the projector's hidden
    layer the model's width): the MRVM loss is finite and reaches the predictor and the fine pass's mask token, the
    target gets no gradient, and the EMA moves the target's BatchNorm statistics as well as its weights."""
    from torch import nn

    m, ctx, rays = _setup(mrvm={"head": "bn_relu"})
    d = m.cfg.nerformer.d_model
    assert isinstance(m.mrvm.projector[1], nn.BatchNorm1d) and m.mrvm.projector[0].out_features == d
    assert m.mrvm.predictor[0].out_features == 2 * m.cfg.mrvm.proj_dim
    m.train()
    out = m.render_rays(ctx, rays, train=True, mask_views=True)
    assert torch.isfinite(out["mrvm_loss"]) and out["mrvm_loss"] > 0
    out["mrvm_loss"].backward()
    assert m.mrvm.predictor[0].weight.grad.abs().sum() > 0 and m.fine.mask_token.grad.abs().sum() > 0
    assert all(p.grad is None for p in m.mrvm.target_projector.parameters())
    bn_o, bn_t = m.mrvm.projector[1], m.mrvm.target_projector[1]
    assert not torch.equal(bn_o.running_mean, torch.zeros_like(bn_o.running_mean))  # the forward updated it
    before = bn_t.running_mean.clone()
    m.mrvm.update_target(0.9)
    assert torch.allclose(bn_t.running_mean, 0.9 * before + 0.1 * bn_o.running_mean)
    with pytest.raises(Exception, match="mrvm.head"):
        C.model_config("fast", {**TINY, "mrvm": {"head": "bn"}})


def test_all_views_masked_and_single_view_finite():
    m, ctx, rays = _setup(mrvm={"point_mask_ratio": 1.0, "view_mask_prob": 1.0})
    out = m.render_rays(ctx, rays, train=True, mask_views=True)
    assert torch.isfinite(out["fine"]["color"]).all() and torch.isfinite(out["mrvm_loss"])
    out["mrvm_loss"].backward()
    m1, ctx1, rays1 = _setup(V=1)
    out = m1.render_rays(ctx1, rays1, train=True, mask_views=True)
    assert torch.isfinite(out["fine"]["color"]).all()


def test_invisible_point_colour_ignores_reference_pixels():
    """A point seen by no reference view cannot take colour from any reference pixel."""
    m, ctx, rays = _setup()
    with torch.no_grad():
        a = m.render_rays(ctx, rays)["fine"]["color"]
        ctx.images.fill_(0.5)  # only reference colours change; features are kept
        b = m.render_rays(ctx, rays)["fine"]["color"]
        # cameras facing away: nothing visible -> colours independent of the references
        # turn every camera 180 degrees about its own y axis (same centre): the object is behind it
        ctx.cams.w2c = torch.diag(torch.tensor([-1.0, 1.0, -1.0, 1.0], dtype=torch.float64)) @ ctx.cams.w2c
        c = m.render_rays(ctx, rays)["fine"]["color"]
        ctx.images.fill_(0.0)
        d = m.render_rays(ctx, rays)["fine"]["color"]
    assert not torch.allclose(a, b)
    assert torch.allclose(c, d)
