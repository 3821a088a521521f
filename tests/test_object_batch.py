"""Several objects' rays in one forward pass (``train.object_batch``): the projection helpers with an
``ObjectBatch``, ``GeneralizableNeRF.render_rays_batch`` and ``trainer.batch_loss`` give what one pass per object
gives, for both branch archs, in training and at inference, with MRVM's loss weighting each object as its own."""

from __future__ import annotations

import copy
import json
import math

import numpy as np
import pytest
import torch

from blender_mrvm.datasets.loaders import load_dataset
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras
from blender_mrvm.models import config as C
from blender_mrvm.models import registry
from blender_mrvm.models.model import GeneralizableNeRF, normalized_scene, ref_cameras
from blender_mrvm.models.projection import (ObjectBatch, RefCameras, camera_to_world, project_samples,
                                            rays_in_cameras, sample_maps)
from blender_mrvm.models.rays import RayBundle, make_rays
from blender_mrvm.progress import run_to_end
from blender_mrvm.training.config import TrainConfig
from blender_mrvm.training.synthetic import make_sphere_dataset
from blender_mrvm.training.trainer import RayBatcher, batch_loss, object_groups, object_loss, train

torch.set_num_threads(1)

PAPER = {"encoder": {"widths": [8, 8, 8], "out_dim": 8},
         "nerformer": {"arch": "nerformer", "d_model": 8, "n_heads": 2, "n_layers": 1, "fine_layers": 2, "pos_freqs": 2},
         "sampler": {"n_coarse": 6, "n_fine": 4, "fine_includes_coarse": True, "perturb": False},
         "mrvm": {"proj_dim": 8}}
LEGACY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8},
          "nerformer": {"arch": "legacy", "d_model": 8, "n_heads": 2, "n_layers": 1, "pos_freqs": 2},
          "sampler": {"n_coarse": 6, "n_fine": 4, "fine_includes_coarse": False, "perturb": False},
          "mrvm": {"proj_dim": 8, "target": "rerun", "view_masking": "prob"}}
GPNR_TINY = {"d_model": 16, "n_heads": 2, "n_blocks": 1, "patch_dim": 8, "n_samples": 6}
RAYS = (20, 7, 13)  # an object's rays: unequal, so the padded layout is exercised


def _model(over, seed=0):
    torch.manual_seed(seed)
    return GeneralizableNeRF(C.model_config("fast", json.loads(json.dumps(over))))


def _objects(V=2, rays=RAYS, seed=0):
    """Objects each with V reference views (own cameras, field of view and images) and a target's rays."""
    rng = np.random.default_rng(seed)
    g = torch.Generator().manual_seed(seed)
    out = []
    for b, n in enumerate(rays):
        intr = cameras.intrinsics_from_fov(math.radians(40 + 5 * b), 16, 16)
        ns = normalized_scene(np.full(3, -0.5), np.full(3, 0.5), 0.05)
        eyes = [2.5 * e / np.linalg.norm(e) for e in rng.normal(size=(V + 1, 3))]
        poses = [ns.pose(cameras.look_at_opencv(e)) for e in eyes]
        rays_b = make_rays(intr, poses[V], box=ns.box)
        rays_b = rays_b.select(torch.nonzero(rays_b.hit).flatten()[:n])
        assert len(rays_b) == n
        out.append((torch.rand(V, 3, 16, 16, generator=g), ref_cameras(poses[:V], [intr] * V), rays_b))
    return out


def test_projection_with_a_batch_is_each_objects_own():
    objs = _objects(V=3)
    batch = ObjectBatch.from_counts([len(r) for *_, r in objs], 3)
    assert batch.obj.tolist() == [0] * 20 + [1] * 7 + [2] * 13 and batch.slots == 20
    assert batch.pos.tolist() == list(range(20)) + list(range(7)) + list(range(13))
    cams = RefCameras(torch.cat([c.w2c for _, c, _ in objs]), torch.cat([c.K for _, c, _ in objs]), 16, 16)
    rays = RayBundle.cat([r for *_, r in objs])
    t = torch.rand(len(rays), 5, generator=torch.Generator().manual_seed(1)) * 2
    maps = torch.rand(9, 4, 8, 8, generator=torch.Generator().manual_seed(2))
    o_c, d_c = rays_in_cameras(cams, rays.origins, rays.dirs, batch)
    uv, valid, p = project_samples(cams, o_c, d_c, t, batch=batch)
    assert valid.any() and not valid.all()
    start = 0
    for b, (_, cam, r) in enumerate(objs):
        rows = slice(start, start + len(r))
        start += len(r)
        o1, d1 = rays_in_cameras(cam, r.origins, r.dirs)
        assert torch.allclose(o_c[:, rows], o1, atol=1e-6) and torch.allclose(d_c[:, rows], d1, atol=1e-6)
        uv1, valid1, p1 = project_samples(cam, o1, d1, t[rows])
        assert torch.equal(valid[:, rows], valid1) and torch.allclose(uv[:, rows], uv1, atol=1e-5)
        assert torch.allclose(camera_to_world(cams, p, batch)[:, rows], camera_to_world(cam, p1), atol=1e-5)
        for mode in ("bilinear", "bicubic"):
            # the same grid_sample arithmetic per map: equal bit for bit on the same coordinates
            assert torch.equal(sample_maps(maps, uv, mode, batch)[:, rows], sample_maps(maps[3 * b:3 * b + 3], uv[:, rows], mode))
    sub = batch.select(torch.tensor([25, 3, 39]))
    assert sub.obj.tolist() == [1, 0, 2] and sub.pos.tolist() == [5, 3, 12] and sub.slots == 20


def _deterministic_mask(R, S, V, cfg, generator=None, device=None):
    """An MRVM mask that depends on the sample and view only (so one pass and a batch draw the same one)."""
    point = (torch.arange(S, device=device) % 2 == 0).expand(R, S).clone()
    views = (torch.arange(V, device=device) == 0).expand(R, S, V) & point[..., None]
    return point, views


@pytest.mark.parametrize("arch", ["paper", "legacy"])
def test_render_rays_batch_is_each_object_on_its_own(arch, monkeypatch):
    """Colours, opacity and depth of three objects rendered in one pass equal three passes; MRVM's loss is the mean
    of the objects' own losses (not of their points: the objects hold 20, 7 and 13 rays); at inference (the fine
    pass only where the coarse one is busy) too."""
    from blender_mrvm.models import model as M

    monkeypatch.setattr(M, "make_mask", _deterministic_mask)
    m = _model(PAPER if arch == "paper" else LEGACY)
    objs = _objects()
    counts = [len(r) for *_, r in objs]
    rays = RayBundle.cat([r for *_, r in objs])
    for train_mode in (True, False):
        seq = [m.render_rays(m.encode(i, c), r, train=train_mode, mask_views=train_mode) for i, c, r in objs]
        ctx = m.encode_batch([i for i, _, _ in objs], [c for _, c, _ in objs])
        assert ctx.feats.shape[0] == 6 and ctx.views == 2 and ctx.groups == 3
        out = m.render_rays_batch(ctx, rays, counts, train=train_mode, mask_views=train_mode)
        for k in ("color", "acc", "depth"):
            assert torch.allclose(out[k], torch.cat([s[k] for s in seq]), atol=2e-6), k
        if train_mode:
            losses = [float(s["mrvm_loss"]) for s in seq]
            assert len(set(np.round(losses, 4))) == 3  # the objects differ, so the weighting matters
            assert float(out["mrvm_loss"]) == pytest.approx(np.mean(losses), rel=1e-5)
            assert out["n_masked"] == sum(s["n_masked"] for s in seq)
        else:
            assert out["mrvm_loss"] is None


@pytest.mark.parametrize("over", [{}, {"canonicalize_rays": False, "canonicalize_coords": False,
                                       "colour_from": "features"}])
def test_gpnr_render_rays_batch_is_each_object_on_its_own(over):
    """GPNR's colour, opacity and depth of three objects in one pass equal three passes: each ray's Plücker, position
    and camera codes are taken against its own object's reference cameras (canonical frames or not)."""
    torch.manual_seed(0)
    m = registry.build_model(registry.build_config("gpnr", "fast", {**GPNR_TINY, "perturb": False, **over}))
    objs = _objects()
    counts = [len(r) for *_, r in objs]
    for train_mode in (True, False):
        m.train(train_mode)
        seq = [m.render_rays(m.encode(i, c), r, train=train_mode) for i, c, r in objs]
        ctx = m.encode_batch([i for i, _, _ in objs], [c for _, c, _ in objs])
        out = m.render_rays_batch(ctx, RayBundle.cat([r for *_, r in objs]), counts, train=train_mode)
        for k in ("color", "acc", "depth", "beta"):
            assert torch.allclose(out[k], torch.cat([s[k] for s in seq]), atol=2e-6), k


def test_render_rays_batch_refuses_mismatched_inputs():
    m = _model(PAPER)
    objs = _objects()
    ctx = m.encode_batch([i for i, _, _ in objs], [c for _, c, _ in objs])
    rays = RayBundle.cat([r for *_, r in objs])
    with pytest.raises(ValueError, match="do not match"):
        m.render_rays_batch(ctx, rays, [20, 7, 12])
    with pytest.raises(ValueError, match="do not match"):
        m.render_rays_batch(ctx, rays, [20, 20])
    with pytest.raises(ValueError, match="same number of reference views"):
        m.encode_batch([objs[0][0], objs[1][0][:1]], [objs[0][1], ref_cameras([np.eye(4)], [cameras.intrinsics_from_fov(1.0, 16, 16)])])


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = make_sphere_dataset(tmp_path_factory.mktemp("spheres"), n_objects=4, n_views=5, resolution=16, seed=2)
    return root, load_dataset(root, "train", None, None, True)  # with the depth maps


def _tcfg(root, tmp, **kw):
    base = dict(data=str(root), out_dir=str(tmp), iterations=2, objects_per_step=4, rays_per_object=48,
                min_ref_views=2, max_ref_views=2, lr=3e-3, lr_warmup=0, log_every=1, ckpt_every=2, threads=1,
                pretrain_frac=0.0, bbox_sampling_frac=0.5)
    base.update(kw)
    return TrainConfig(**base)


@pytest.mark.parametrize("lpips,seed,odd", [(False, 0, False), (True, 0, False), (True, 1, False), (False, 2, True),
                                            (True, 3, True)])
def test_batch_loss_equals_the_objects_losses_and_gradients(tmp_path, data, lpips, seed, odd):
    """The trainer's loss of four objects in one pass (``batch_loss``) and its gradient equal the sum of their
    ``object_loss`` (deterministic samples), with the opacity, depth, distortion and (patch) LPIPS terms, and each
    object's logged parts; ``odd``: one object's rays all miss the box and another is a scene (a capture)."""
    from blender_mrvm.models.metrics import LPIPS
    from blender_mrvm.training.trainer import patch_lpips

    root, scenes = data
    extra = dict(lpips_weight=0.5, patch_size=16, patch_scale_min=0.5) if lpips else {}
    tcfg = _tcfg(root, tmp_path, opacity_weight=0.1, depth_weight=0.2, distortion_weight=0.05, **extra)
    mcfg = C.model_config("fast", json.loads(json.dumps(PAPER)))
    torch.manual_seed(seed)
    model = registry.build_model(mcfg)
    model.train()
    phase = model.train_phase(0, tcfg)
    batcher = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=5)
    bs = [batcher.draw(True) for _ in range(4)]
    assert all(b["surface"] is not None and torch.isfinite(b["surface"]).any() for b in bs)
    if odd:
        r = bs[2]["rays"]
        bs[2] = dict(bs[2], rays=RayBundle(r.origins, r.dirs, r.far, torch.zeros_like(r.hit), r.depth_offset, r.up))
        bs[1] = dict(bs[1], scene=True)
    lp = LPIPS() if lpips else None

    def run(batched: bool):
        model.zero_grad(set_to_none=True)
        gen = torch.Generator().manual_seed(1)
        patches = [] if lpips else None
        copies = [dict(b, cams=copy.deepcopy(b["cams"])) for b in bs]
        if batched:
            loss, parts = batch_loss(model, copies, tcfg, phase, gen, "cpu", lp, patches)
        else:
            pairs = [object_loss(model, b, tcfg, phase, gen, "cpu", lp, patches) for b in copies]
            loss, parts = sum(p[0] for p in pairs), [p[1] for p in pairs]
        if lpips:
            loss = loss + tcfg.lpips_weight * patch_lpips(lp, patches).sum()
        loss.backward()
        return float(loss), parts, [p.grad.clone() for p in model.parameters() if p.grad is not None]

    l1, parts1, g1 = run(False)
    l2, parts2, g2 = run(True)
    assert l1 > 0 and l2 == pytest.approx(l1, rel=1e-5)
    assert len(parts1) == len(parts2) == 4
    for a, b in zip(parts1, parts2):
        assert a.keys() == b.keys() and all(b[k] == pytest.approx(a[k], rel=1e-4, abs=1e-7) for k in a)
    assert {"depth", "distortion", "opacity", "mse_coarse"} <= parts1[0].keys()
    if odd:
        assert parts1[2].keys() == {"hit", "mse_fine"} and parts1[2]["hit"] == 0
    assert len(g1) == len(g2) > 0
    for a, b in zip(g1, g2):  # float32 sums in another order: each gradient within 1e-4 of its own size
        assert float((a - b).norm()) <= 1e-4 * float(a.norm()) + 1e-7  # (some are 0 in exact arithmetic)


def test_object_groups_keep_the_draws_and_group_by_reference_count(data):
    """Grouped, a step draws the same objects, views and rays as one pass per object; a group holds one reference
    count and at most ``size`` objects, and covers the step's objects once."""
    root, scenes = data
    tcfg = _tcfg(root, "unused", min_ref_views=1, max_ref_views=3)

    def step(size):
        batcher = RayBatcher(scenes, tcfg, 0.05, seed=11)
        return list(object_groups(batcher, False, 9, size))

    one = [g[0] for g in step(1)]
    assert all(len(g) == 1 for g in step(1))
    groups = step(4)
    assert all(1 <= len(g) <= 4 and len({b["n_refs"] for b in g}) == 1 for g in groups)
    flat = [b for g in groups for b in g]
    key = lambda b: (b["target_view"], tuple(b["ref_views"]), float(b["gt"].sum()))  # noqa: E731
    assert sorted(map(key, flat)) == sorted(map(key, one)) and len(flat) == 9
    assert len({b["n_refs"] for b in one}) > 1  # the step mixes counts, so grouping did something


def test_training_with_object_batch(tmp_path, data, capsys, monkeypatch):
    """A run with ``object_batch`` trains (MRVM masking on, mixed reference counts) and records it in config.json; 0 is
    refused; GPNR trains batched too; a model kind that cannot batch objects says so and trains one at a time."""
    root, scenes = data
    mcfg = C.model_config("fast", json.loads(json.dumps(PAPER)))
    tcfg = _tcfg(root, tmp_path / "run", object_batch=3, min_ref_views=1, max_ref_views=2, pretrain_frac=1.0,
                 iterations=3, ckpt_every=1)
    s = run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert np.isfinite(s["last"]["loss"]) and s["last"]["loss"] > 0 and s["last"]["mrvm"] > 0
    assert json.loads((tmp_path / "run" / "config.json").read_text())["train"]["object_batch"] == 3
    with pytest.raises(InputError, match="object_batch"):
        _tcfg(root, tmp_path / "bad", object_batch=0)
    from blender_mrvm.models.gpnr.model import GPNR

    gcfg = registry.build_config("gpnr", "fast", GPNR_TINY)
    capsys.readouterr()
    s = run_to_end(train(gcfg, _tcfg(root, tmp_path / "gpnr", object_batch=2, iterations=1, ckpt_every=1,
                                     rays_per_object=16), scenes=scenes))
    assert np.isfinite(s["last"]["loss"]) and "one object at a time" not in capsys.readouterr().err
    monkeypatch.setattr(GPNR, "supports_object_batch", False)
    s = run_to_end(train(gcfg, _tcfg(root, tmp_path / "gpnr1", object_batch=2, iterations=1, ckpt_every=1,
                                     rays_per_object=16), scenes=scenes))
    assert np.isfinite(s["last"]["loss"])
    assert "trains one object at a time" in capsys.readouterr().err


def test_object_loss_is_the_documented_sum_of_terms(tmp_path, data):
    """One object's loss, assembled here from the render and the public term functions as ``object_loss`` documents
    it: MSE over all drawn rays (misses show white) + coarse_weight x the coarse head's + opacity (both heads) +
    distortion + depth (the mean over the rays with a surface, times their share of the drawn rays) + MRVM."""
    from blender_mrvm.training.trainer import distortion_loss, opacity_loss, surface_loss

    root, scenes = data
    tcfg = _tcfg(root, tmp_path, opacity_weight=0.1, depth_weight=0.2, distortion_weight=0.05, coarse_weight=0.3,
                 pretrain_frac=1.0)
    mcfg = C.model_config("fast", json.loads(json.dumps(PAPER)))
    torch.manual_seed(0)
    model = registry.build_model(mcfg)
    phase = model.train_phase(int(0.5 * tcfg.iterations), tcfg)
    assert phase.kwargs["mask_views"] and phase.loss_weights["mrvm"] > 0
    b = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=5).draw(False)
    hit = b["rays"].hit
    assert 0 < int(hit.sum()) < len(hit)
    loss, parts = object_loss(model, dict(b, cams=copy.deepcopy(b["cams"])), tcfg, phase,
                              torch.Generator().manual_seed(1), "cpu")
    sel = torch.nonzero(hit).flatten()
    out = model.render_rays(model.encode(b["images"], b["cams"]), b["rays"].select(sel), train=True,
                            generator=torch.Generator().manual_seed(1), **phase.kwargs)
    gt, n = b["gt"], len(b["gt"])

    def mse(color):
        full = torch.ones_like(gt)
        full[sel] = color
        return ((full - gt) ** 2).sum() / (3 * n)

    coarse = out["aux_heads"]["coarse"]
    far = b["rays"].far[sel].float()
    t_star = b["surface"][sel]
    ok = torch.isfinite(t_star)
    assert 0 < int(ok.sum()) < len(ok)
    depth = (surface_loss(out["fine"]["weights"][ok], out["fine"]["t"][ok], far[ok], t_star[ok])
             + 0.3 * surface_loss(coarse["weights"][ok], coarse["t"][ok], far[ok], t_star[ok]))
    expect = (mse(out["color"]) + 0.3 * mse(coarse["color"])
              + 0.1 * (opacity_loss(out["acc"], b["mask"], hit) + 0.3 * opacity_loss(coarse["acc"], b["mask"], hit))
              + 0.05 * distortion_loss(out["fine"]["weights"], out["fine"]["t"], far)
              + 0.2 * depth * int(ok.sum()) / n + phase.loss_weights["mrvm"] * out["aux_losses"]["mrvm"])
    assert float(loss) == pytest.approx(float(expect), rel=1e-5)
    assert parts["depth"] == pytest.approx(float(depth), rel=1e-5)
    assert parts["mse_fine"] == pytest.approx(float(mse(out["color"])), rel=1e-5)
    assert parts["hit"] == pytest.approx(float(hit.float().mean()))


def test_one_reference_count_a_step(data):
    """``ref_views_per`` 'step': every object of a step takes the step's count (so a batched step is one pass), the
    counts still cover min..max over steps, and anything but 'object' or 'step' is refused."""
    root, scenes = data
    tcfg = _tcfg(root, "unused", min_ref_views=1, max_ref_views=3, ref_views_per="step")
    batcher = RayBatcher(scenes, tcfg, 0.05, seed=11)
    seen = set()
    for _ in range(12):
        groups = list(object_groups(batcher, False, 6, 8))
        assert len(groups) == 1 and len(groups[0]) == 6
        counts = {b["n_refs"] for b in groups[0]}
        assert len(counts) == 1 and all(len(b["ref_views"]) == b["n_refs"] for b in groups[0])
        seen |= counts
    assert seen == {1, 2, 3}
    with pytest.raises(InputError, match="ref_views_per"):
        _tcfg(root, "unused", ref_views_per="batch")
