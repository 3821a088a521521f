"""The paper's NeRFormer (arch 'nerformer'), MRVM as published, the pretrained encoder and the two-run schedule.

Tiny shapes on the CPU: per-view token streams, invariance to the order of the reference views,
padding views changing nothing, the fine pass over the coarse + fine samples, the MRVM target and its
positions, the lambda schedule, the legacy arch for old configs, and a short training run whose
loss falls.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras
from blender_mrvm.models import config as C
from blender_mrvm.models.model import GeneralizableNeRF, normalized_scene, ref_cameras
from blender_mrvm.models.mrvm import coarse_positions, lambda_at, make_mask
from blender_mrvm.models.nerformer import NeRFormerBranch
from blender_mrvm.models.nerformer_streams import StreamBranch
from blender_mrvm.models.projection import RefCameras
from blender_mrvm.models.rays import make_rays

torch.set_num_threads(1)

TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8},
        "nerformer": {"arch": "nerformer", "d_model": 8, "n_heads": 2, "n_layers": 1, "fine_layers": 2, "pos_freqs": 2},
        "sampler": {"n_coarse": 6, "n_fine": 4, "fine_includes_coarse": True}, "mrvm": {"proj_dim": 8}}
EYES = [[2.0, 0.3, 0.5], [0.2, 2.0, 0.4], [-1.0, -1.5, 1.0], [1.5, -1.5, 0.2]]


def _model(seed=0, **over):
    torch.manual_seed(seed)
    o = json.loads(json.dumps(TINY))
    for k, v in over.items():
        o.setdefault(k, {}).update(v)
    return GeneralizableNeRF(C.model_config("fast", o))


def _scene(m, V=2, n_rays=24, ref_fov=45.0):
    intr = cameras.intrinsics_from_fov(math.radians(45), 16, 16)
    ref_intr = cameras.intrinsics_from_fov(math.radians(ref_fov), 16, 16)
    ns = normalized_scene(np.full(3, -0.5), np.full(3, 0.5), 0.05)
    poses = [ns.pose(cameras.look_at_opencv(e)) for e in EYES]
    g = torch.Generator().manual_seed(3)
    imgs = torch.rand(V, 3, 16, 16, generator=g)
    ctx = m.encode(imgs, ref_cameras(poses[:V], [ref_intr] * V))
    rays = make_rays(intr, poses[-1], box=ns.box)
    rays = rays.select(torch.nonzero(rays.hit).flatten()[:n_rays])
    return ctx, rays


def _sub_ctx(m, ctx, idx):
    """The context of the reference views ``idx`` (in that order) of ``ctx``."""
    cams = RefCameras(ctx.cams.w2c[idx], ctx.cams.K[idx], ctx.cams.width, ctx.cams.height)
    return m.encode(ctx.images[idx], cams)


def _facing_away(ctx):
    """The same cameras turned 180 degrees about their own y axis: the object is behind every one."""
    w2c = torch.diag(torch.tensor([-1.0, 1.0, -1.0, 1.0], dtype=torch.float64)) @ ctx.cams.w2c
    return RefCameras(w2c, ctx.cams.K, ctx.cams.width, ctx.cams.height)


def test_presets_use_the_papers_arch_and_paper_is_paper_sized():
    p = C.PRESETS["paper"]
    n, s = p.nerformer, p.sampler
    assert (n.arch, n.d_model, n.n_heads, n.ffn_mult, n.n_layers, n.fine_layers) == ("nerformer", 128, 4, 4, 4, 5)
    assert (s.n_coarse, s.n_fine, s.fine_includes_coarse) == (64, 32, True)
    for name in ("accurate", "paper"):
        e = C.PRESETS[name].encoder
        assert e.backbone == "vgg16" and e.pretrained
    for cfg in C.PRESETS.values():
        assert cfg.nerformer.arch == "nerformer" and cfg.mrvm.target == "coarse" and cfg.mrvm.view_masking == "count"
    m = GeneralizableNeRF(p, load_pretrained=False)
    assert isinstance(m.coarse, StreamBranch) and len(m.coarse.view_blocks) == 4 and len(m.fine.ray_blocks) == 5


def test_legacy_config_reads_as_legacy_arch():
    old = C.to_dict(C.PRESETS["balanced"])
    for k in ("arch", "fine_layers", "pos_freqs", "color_head"):
        old["nerformer"].pop(k)
    for k in ("view_masking", "target"):
        old["mrvm"].pop(k)
    old["encoder"].pop("freeze_backbone")
    old["sampler"]["fine_includes_coarse"] = False
    cfg = C.from_dict(C.ModelConfig, old)
    C.validate(cfg)
    assert cfg.nerformer.arch == "legacy" and cfg.mrvm.target == "rerun" and cfg.mrvm.view_masking == "prob"
    m = GeneralizableNeRF(cfg)
    assert isinstance(m.coarse, NeRFormerBranch) and isinstance(m.fine, NeRFormerBranch)
    with pytest.raises(InputError, match="arch"):
        C.model_config("fast", {"nerformer": {"arch": "transformer"}})
    with pytest.raises(InputError, match="legacy arch"):
        C.model_config("fast", {"nerformer": {"arch": "legacy"}})  # the paper's MRVM target needs the new arch
    with pytest.raises(InputError, match="fine_includes_coarse"):
        C.model_config("fast", {"sampler": {"fine_includes_coarse": False}})


def test_shapes_and_fine_pass_holds_coarse_plus_fine_samples():
    m = _model()
    ctx, rays = _scene(m)
    R = len(rays)
    out = m.render_rays(ctx, rays, train=True, mask_views=True, generator=torch.Generator().manual_seed(0))
    assert out["coarse"]["weights"].shape == (R, 6) and out["fine"]["weights"].shape == (R, 10)
    assert out["color"].shape == (R, 3) and out["acc"].shape == (R,) and out["depth"].shape == (R,)
    assert out["fine"]["latent"].shape == (R, 10, 8)
    t_c, t_all = out["coarse"]["t"], out["fine"]["t"]
    assert (t_all[:, 1:] >= t_all[:, :-1]).all()  # sorted union
    pos = out["mrvm_positions"]
    assert torch.equal(torch.gather(t_all, 1, pos), t_c)  # every coarse sample is evaluated again by the fine pass
    assert set(out["aux_losses"]) == {"mrvm"} and torch.isfinite(out["mrvm_loss"])


def test_coarse_positions_inverts_the_sort():
    t_c = torch.tensor([[0.1, 0.5, 0.9]])
    t_f = torch.tensor([[0.05, 0.6]])
    t_all, order = torch.sort(torch.cat([t_c, t_f], -1), -1)
    pos = coarse_positions(order, 3)
    assert pos.tolist() == [[1, 2, 4]] and torch.equal(t_all.gather(1, pos), t_c)


def test_view_permutation_invariance():
    m = _model().eval()
    ctx, rays = _scene(m, V=3)
    with torch.no_grad():
        a = m.render_rays(ctx, rays)
        b = m.render_rays(_sub_ctx(m, ctx, [2, 0, 1]), rays)
    for k in ("color", "acc", "depth"):
        assert torch.allclose(a[k], b[k], atol=1e-5), k
    assert torch.allclose(a["fine"]["latent"], b["fine"]["latent"], atol=1e-5)


@pytest.mark.parametrize("head", ["direct", "blend"])
def test_a_view_that_sees_nothing_changes_nothing(head):
    m = _model(nerformer={"color_head": head}).eval()
    ctx, rays = _scene(m, V=3, n_rays=64, ref_fov=20.0)  # narrow references: some points are seen by none
    two = _sub_ctx(m, ctx, [0, 1])
    from blender_mrvm.models.projection import project_samples, rays_in_cameras

    o_c, d_c = rays_in_cameras(two.cams, rays.origins, rays.dirs)
    seen = project_samples(two.cams, o_c, d_c, m.render_rays(two, rays)["fine"]["t"])[1].any(0)
    assert seen.any() and not seen.all()
    blind = _facing_away(_sub_ctx(m, ctx, [2]))  # a third camera with the object behind it
    cams = RefCameras(torch.cat([two.cams.w2c, blind.w2c]), torch.cat([two.cams.K, blind.K]), 16, 16)
    three = m.encode(ctx.images, cams)
    with torch.no_grad():
        a = m.render_rays(two, rays)
        b = m.render_rays(three, rays)
    for k in ("color", "acc", "depth"):
        assert torch.allclose(a[k], b[k], atol=1e-6), k


def test_point_seen_by_no_view_is_finite_and_ignores_references():
    m = _model()
    ctx, rays = _scene(m, V=2)
    away = m.encode(ctx.images, _facing_away(ctx))
    out = m.render_rays(away, rays, train=True, mask_views=True, generator=torch.Generator().manual_seed(1))
    for k in ("color", "acc", "depth"):
        assert torch.isfinite(out[k]).all(), k
    (out["color"].sum() + out["mrvm_loss"]).backward()
    assert all(torch.isfinite(p.grad).all() for p in m.parameters() if p.grad is not None)
    with torch.no_grad():
        other = m.encode(torch.zeros_like(ctx.images), _facing_away(ctx))
        assert torch.allclose(m.render_rays(away, rays)["color"], m.render_rays(other, rays)["color"])


def test_gradients_reach_encoder_and_both_transformers():
    m = _model()
    ctx, rays = _scene(m)
    out = m.render_rays(ctx, rays, train=True, generator=torch.Generator().manual_seed(2))
    (out["color"].sum() + out["aux_heads"]["coarse"]["color"].sum()).backward()
    for name, mod in (("encoder", m.encoder), ("coarse", m.coarse), ("fine", m.fine)):
        g = sum(float(p.grad.abs().sum()) for p in mod.parameters() if p.grad is not None)
        assert g > 0, name
    for blk in (m.fine.view_blocks[0], m.fine.ray_blocks[-1], m.coarse.pos_proj, m.fine.view_score):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in blk.parameters())


def test_mrvm_loss_is_fine_at_coarse_positions_against_detached_coarse():
    m = _model()
    ctx, rays = _scene(m)
    out = m.render_rays(ctx, rays, train=True, mask_views=True, generator=torch.Generator().manual_seed(4))
    pos = out["mrvm_positions"]
    fl, cl = out["fine"]["latent"], out["coarse"]["latent"]
    online = torch.gather(fl, 1, pos[..., None].expand(-1, -1, fl.shape[-1]))
    expect = m.mrvm.loss(online.reshape(-1, fl.shape[-1]), cl.reshape(-1, fl.shape[-1]))
    assert torch.allclose(out["mrvm_loss"], expect)
    assert out["n_masked"] == len(rays) * 5 and out["point_mask"].shape == (len(rays), 10)
    out["mrvm_loss"].backward()
    # the coarse pass is only the target: no gradient reaches it (nor the target projector) from this loss
    assert all(p.grad is None or p.grad.abs().max() == 0 for p in m.coarse.parameters())
    assert all(p.grad is None for p in m.mrvm.target_projector.parameters())
    assert m.fine.mask_token.grad is not None and m.fine.mask_token.grad.abs().sum() > 0
    assert m.mrvm.predictor[0].weight.grad.abs().sum() > 0


def test_count_view_masking_masks_one_to_all_views():
    cfg = C.MRVMConfig(point_mask_ratio=0.5, view_masking="count")
    point, views = make_mask(400, 10, 4, cfg, torch.Generator().manual_seed(0))
    assert (point.sum(1) == 5).all() and (views.any(-1) == point).all()
    counts = views.sum(-1)[point]
    assert counts.min() == 1 and counts.max() == 4
    hist = torch.bincount(counts, minlength=5)[1:].float() / counts.numel()
    assert (hist - 0.25).abs().max() < 0.05  # a uniform number of views, 1..V


def test_lambda_schedule_reaches_a_tenth_early_and_stays():
    cfg = C.MRVMConfig()  # official: 0 until 5% of pretraining, 0.1 from 6.25% on
    n = 1000
    assert lambda_at(0, n, cfg) == 0.0
    assert lambda_at(49, n, cfg) == 0.0 and 0.0 < lambda_at(56, n, cfg) < 0.1
    assert lambda_at(100, n, cfg) == pytest.approx(0.1)  # 10%
    assert lambda_at(500, n, cfg) == pytest.approx(0.1)  # 50%
    assert lambda_at(n - 1, n, cfg) == pytest.approx(0.1)  # the last pretraining step
    assert lambda_at(n, n, cfg) == 0.0  # finetuning


def test_two_runs_pretrain_then_finetune_policy():
    from blender_mrvm.training.config import FINETUNE, TrainConfig, finetune_policy

    t = TrainConfig()
    assert t.pretrain_frac == 1.0 and t.bbox_sampling_frac == 0.75  # one pretraining run, mostly bbox sampling
    ft = finetune_policy(TrainConfig(init_checkpoint="x", iterations=1000))
    assert ft.pretrain_frac == 0.0 and ft.bbox_sampling_frac == 0.0 and ft.lr == FINETUNE["lr"]
    assert ft.lr_warmup == FINETUNE["lr_warmup"]  # the schedule restarts


def test_vgg_encoder_pretrained_frozen_and_missing_weights(tmp_path, monkeypatch):
    from blender_mrvm.models.encoder import ImageEncoder
    from blender_mrvm.models.vgg import weights_dir

    if not (weights_dir() / "vgg16_imagenet_features.safetensors").is_file():
        pytest.skip("offline VGG16 weights not fetched (python -m blender_mrvm fetch-weights)")
    enc = ImageEncoder(C.EncoderConfig(backbone="vgg16", pretrained=True, freeze_backbone=True, out_dim=8))
    rnd = ImageEncoder(C.EncoderConfig(backbone="vgg16", pretrained=True, out_dim=8), load_pretrained=False)
    assert not torch.equal(enc.vgg[0].weight, rnd.vgg[0].weight)  # ImageNet weights, not the random start
    assert not any(p.requires_grad for p in enc.vgg.parameters()) and enc.fuse.weight.requires_grad
    enc(torch.rand(1, 3, 16, 16)).sum().backward()
    assert enc.fuse.weight.grad is not None and all(p.grad is None for p in enc.vgg.parameters())
    tuned = ImageEncoder(C.EncoderConfig(backbone="vgg16", pretrained=True, out_dim=8))
    assert all(p.requires_grad for p in tuned.vgg.parameters())
    monkeypatch.setenv("MRVM_WEIGHTS_DIR", str(tmp_path))
    with pytest.raises(InputError, match="python -m blender_mrvm fetch-weights"):
        GeneralizableNeRF(C.model_config("accurate", {"encoder": {"out_dim": 8}}))
    # a checkpoint of such a model loads without the cache: its own weights replace ImageNet's
    from blender_mrvm.models import registry

    assert registry.build_model(C.model_config("accurate"), load_pretrained=False) is not None


def test_short_training_run_reduces_the_loss(tmp_path):
    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training import checkpoint as ckpt
    from blender_mrvm.training.config import TrainConfig
    from blender_mrvm.training.synthetic import make_sphere_dataset
    from blender_mrvm.training.trainer import RayBatcher, train

    root = make_sphere_dataset(tmp_path / "data", n_objects=2, n_views=5, resolution=16, seed=1)
    scenes = load_dataset(root, "train")
    mcfg = C.model_config("fast", {**TINY, "nerformer": {**TINY["nerformer"], "d_model": 16}})
    tcfg = TrainConfig(data=str(root), out_dir=str(tmp_path / "run"), iterations=30, objects_per_step=2,
                       rays_per_object=64, max_ref_views=2, lr=3e-3, lr_warmup=0, log_every=1, ckpt_every=30,
                       threads=1)

    def mse(model):
        b = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=123)
        err = []
        with torch.no_grad():
            for _ in range(4):
                d = b.draw(False)
                ctx = model.encode(d["images"], d["cams"])
                pred = torch.ones_like(d["gt"])
                idx = torch.nonzero(d["rays"].hit).flatten()
                pred[idx] = model.render_rays(ctx, d["rays"].select(idx))["color"]
                err.append(((pred - d["gt"]) ** 2).mean())
        return float(torch.stack(err).mean())

    torch.manual_seed(tcfg.seed)
    before = mse(GeneralizableNeRF(mcfg).eval())
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    model, cfg2, _ = ckpt.load_model(tmp_path / "run")
    after = mse(model.eval())
    assert cfg2 == mcfg and cfg2.nerformer.arch == "nerformer"
    assert after < before * 0.8, (before, after)
    lines = [json.loads(l) for l in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert all(l["masking"] for l in lines) and lines[-1]["lambda"] == pytest.approx(0.1)  # a pretraining run
    assert all(np.isfinite(l["loss"]) for l in lines) and "mrvm" in lines[-1]
