"""Issue 10: GPNR inside rooms and real scenes - depth spacing, the background rule, a recovered capture's box.

- ``depth_spacing`` 'disparity': samples even in inverse depth between the near plane and the box exit,
  monotone, inside the box; 'auto' = disparity for cameras inside the box, today's linear spacing outside
  (bit-identical); configs stored before the field existed (every old checkpoint) read as 'linear'.
- ``models/background.py``: the data decides the background in training, evaluation and synthesis.
- ``capture.align.scene_box``: the box of a recovered capture from its sparse points, robust to outliers.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from blender_mrvm.capture import align
from blender_mrvm.errors import InputError
from blender_mrvm.models import background as bgrule
from blender_mrvm.models import registry, samplers
from blender_mrvm.models.config import to_dict
from blender_mrvm.models.rays import make_rays
from blender_mrvm.geometry import cameras as C

torch.set_num_threads(1)


# ------------------------------------------------------------------------------------ depth spacing

def test_disparity_spacing_exact_monotone_and_inside():
    far = torch.tensor([2.0, 1.0, 3.0, 0.5], dtype=torch.float64)
    off = torch.tensor([0.0, 0.0, 0.7, 0.0], dtype=torch.float64)
    near, n = 0.2, 16
    t = samplers.disparity(far, off, near, n, perturb=False).double()
    assert t.shape == (4, n) and t.dtype == torch.float64
    # Bin centres: 1 / (t + offset) evenly spaced from 1/max(near, offset) to 1/(offset + far).
    for r in range(4):
        t0, t1 = max(near, float(off[r])), float(off[r] + far[r])
        s = (torch.arange(n, dtype=torch.float64) + 0.5) / n
        want = 1.0 / (1.0 / t0 + s * (1.0 / t1 - 1.0 / t0)) - float(off[r])
        torch.testing.assert_close(t[r], want, rtol=1e-6, atol=1e-6)
        inv = 1.0 / (t[r] + off[r])
        steps = inv[1:] - inv[:-1]
        torch.testing.assert_close(steps, torch.full_like(steps, float(steps.mean())), rtol=1e-4, atol=1e-6)
    # Perturbed: sorted, within [near plane, exit] of each ray, one sample per disparity bin.
    g = torch.Generator().manual_seed(0)
    for _ in range(20):
        t = samplers.disparity(far, off, near, n, perturb=True, generator=g).double()
        assert (t[:, 1:] >= t[:, :-1]).all()
        assert (t >= torch.clamp(near - off, min=0)[:, None] - 1e-6).all() and (t <= far[:, None] + 1e-6).all()


def test_disparity_degenerate_rays_stay_finite():
    # The near plane beyond the exit, a zero-length ray, a camera on the box face with no room for a near plane.
    far = torch.tensor([0.1, 0.0, 1.0])
    off = torch.tensor([0.0, 0.0, 0.0])
    t = samplers.disparity(far, off, 0.2, 8, perturb=True, generator=torch.Generator().manual_seed(1))
    assert torch.isfinite(t).all() and (t >= 0).all() and (t <= far[:, None] + 1e-6).all()
    assert (t[0, 1:] >= t[0, :-1]).all()


def _gpnr(**over):
    torch.manual_seed(0)
    cfg = registry.build_config("gpnr", "fast", over)
    return registry.build_model(cfg).eval(), cfg


def _rays(inside: bool, dist: float = 3.0):
    intr = C.Intrinsics.from_fov(8, 8, 60.0) if hasattr(C.Intrinsics, "from_fov") else \
        C.Intrinsics.from_K(np.array([[7.0, 0, 4], [0, 7.0, 4], [0, 0, 1]]), 8, 8)
    c2w = np.eye(4)
    c2w[:3, 3] = [0.0, 0.0, -0.3 if inside else -dist]
    return make_rays(intr, c2w, box=1.05)


def test_auto_spacing_is_linear_outside_the_box_and_disparity_inside():
    model, _ = _gpnr(depth_spacing="auto")
    out = _rays(inside=False)
    assert (out.depth_offset > 0).all()
    g1, g2 = torch.Generator().manual_seed(3), torch.Generator().manual_seed(3)
    got = model.sample_depths(out, train=True, generator=g1)
    want = samplers.stratified(out.far.float(), model.cfg.n_samples, perturb=True, generator=g2)
    assert torch.equal(got, want)  # object-on-white keeps today's spacing, bit for bit
    ins = _rays(inside=True)
    assert (ins.depth_offset == 0).all()
    got = model.sample_depths(ins)
    want = samplers.disparity(ins.far, ins.depth_offset, model.cfg.near, model.cfg.n_samples, False)
    assert torch.equal(got, want)
    assert not torch.equal(got, samplers.stratified(ins.far.float(), model.cfg.n_samples, perturb=False))


def test_old_configs_read_as_linear_and_render_bit_identically():
    model, cfg = _gpnr(depth_spacing="linear")
    stored = to_dict(cfg)
    stored.pop("depth_spacing")
    stored.pop("near")  # a config written before the fields existed
    stored.pop("colour_filter")
    old = registry.config_from_dict("gpnr", stored)
    assert old.depth_spacing == "linear" and old.colour_filter == "bilinear"  # the colour reads of then
    assert registry.build_config("gpnr", "fast").colour_filter == "bicubic"  # new models read bicubic
    assert registry.config_from_dict("gpnr", to_dict(registry.build_config("gpnr", "fast"))).depth_spacing == "auto"
    # The shipped library model (written before the field) reads as linear.
    from blender_mrvm.training.config import init_model_config

    assert init_model_config("shipped:gpnr").depth_spacing == "linear"
    # Linear spacing is today's sampler, for cameras inside the box too.
    ins = _rays(inside=True)
    assert torch.equal(model.sample_depths(ins), samplers.stratified(ins.far.float(), cfg.n_samples, perturb=False))


def test_finetune_overrides_keep_the_checkpoint_model(tmp_path):
    import json

    from blender_mrvm.training.config import load_run_config

    p = tmp_path / "run.json"
    p.write_text(json.dumps({"model": {"overrides": {"depth_spacing": "disparity", "near": 0.3}},
                             "train": {"init_checkpoint": "shipped:gpnr", "data": "x", "out_dir": str(tmp_path / "o")}}))
    mcfg, _ = load_run_config(p)
    assert registry.kind_of(mcfg) == "gpnr" and mcfg.depth_spacing == "disparity" and mcfg.near == 0.3
    assert mcfg.n_samples == 24  # the rest is the checkpoint's own model


# ------------------------------------------------------------------------------------ background rule

class _S:
    def __init__(self, bg, name="a"):
        self.background, self.category, self.name = bg, "c", name


def test_background_rule():
    assert bgrule.of_meta({"background": "scene"}) == "scene" and bgrule.of_meta({}) == "white"
    assert bgrule.of_scenes([_S("scene"), _S("scene", "b")]) == "scene"
    with pytest.raises(InputError, match="mixes objects on white"):
        bgrule.of_scenes([_S("white"), _S("scene", "b")])
    # Training: the data decides, both ways; the config records it.
    g = registry.build_config("gpnr", "fast")
    cfg, note = bgrule.for_training(g, "scene")
    assert cfg.white_background is False and "white_background=False" in note
    assert bgrule.for_training(cfg, "white")[0].white_background is True
    assert bgrule.for_training(g, "white") == (g, None)
    n = registry.build_config("nerformer_mrvm", "fast")
    assert bgrule.config_white(bgrule.for_training(n, "scene")[0]) is False
    # Rendering: GPNR follows the data; a volume model keeps its background and says so.
    model, _ = _gpnr()
    assert model.white_background is True
    note = bgrule.for_rendering(model, "scene")
    assert model.white_background is False and "blends reference pixels" in note
    assert bgrule.for_rendering(model, "scene") is None

    class Vol:
        kind = "nerformer_mrvm"
        cfg = n

    v = Vol()
    note = bgrule.for_rendering(v, "scene")
    assert bgrule.config_white(v.cfg) is True and "composites on white" in note


def test_scene_batches_do_not_score_rays_outside_the_box():
    from blender_mrvm.models.base import ref_cameras
    from blender_mrvm.training.config import TrainConfig
    from blender_mrvm.training.trainer import object_loss
    from blender_mrvm.models.base import TrainPhase

    model, cfg = _gpnr(depth_spacing="auto", white_background=False)
    intr = C.Intrinsics.from_K(np.array([[7.0, 0, 4], [0, 7.0, 4], [0, 0, 1]]), 8, 8)
    poses = []
    for x in (-0.2, 0.2):
        p = np.eye(4)
        p[:3, 3] = [x, 0.0, -3.0]
        poses.append(p)
    cams = ref_cameras(poses, [intr, intr])
    images = torch.rand(2, 3, 8, 8)
    rays = _rays(inside=False, dist=6.0)
    assert (~rays.hit).any() and rays.hit.any()
    gt = torch.rand(len(rays), 3)
    tc = TrainConfig(opacity_weight=0.0)
    b = {"images": images, "cams": cams, "rays": rays, "gt": gt, "mask": None}
    gen = lambda: torch.Generator().manual_seed(0)  # noqa: E731
    _, white_parts = object_loss(model, dict(b), tc, TrainPhase(), gen(), "cpu")
    loss, scene_parts = object_loss(model, dict(b, scene=True), tc, TrainPhase(), gen(), "cpu")
    out = model.render_rays(model.encode(images, cams), rays.select(torch.nonzero(rays.hit).flatten()), train=True,
                            generator=gen())
    want = float(((out["color"].detach() - gt[rays.hit]) ** 2).mean())
    assert abs(scene_parts["mse_fine"] - want) < 1e-6
    assert white_parts["mse_fine"] != pytest.approx(want)


# ------------------------------------------------------------------------------------ recovered scene box

def test_scene_box_from_sparse_points_is_robust_to_outliers():
    rng = np.random.default_rng(0)
    pts = rng.uniform([-2, -1, 0], [2, 1, 3], size=(2000, 3))
    lo, hi, how = align.scene_box(pts)
    assert "percentile" in how
    ext = np.array([4.0, 2.0, 3.0])
    assert np.all(lo < [-2, -1, 0] + 0.1 * ext) and np.all(hi > [2, 1, 3] - 0.1 * ext)
    assert np.all(lo > [-2, -1, 0] - 0.25 * ext) and np.all(hi < [2, 1, 3] + 0.25 * ext)
    # 1 % of stray triangulations a thousand units away do not move it.
    bad = np.concatenate([pts, rng.normal(0, 1, (20, 3)) * 1000 + 5000])
    lo2, hi2, _ = align.scene_box(bad)
    assert np.abs(lo2 - lo).max() < 0.1 * ext.max() and np.abs(hi2 - hi).max() < 0.1 * ext.max()
    # A flat wall still gives a box with volume; NaN points are ignored.
    flat = pts.copy()
    flat[:, 2] = 1.0
    flat[0] = np.nan
    lo3, hi3, _ = align.scene_box(flat)
    assert np.all(np.isfinite(lo3)) and (hi3 - lo3)[2] >= 0.1 * 4.0
    # Too few points: a cube around the cameras.
    cams = [np.eye(4) for _ in range(3)]
    for i, c in enumerate(cams):
        c[:3, 3] = [i, 0, 0]
    lo4, hi4, how4 = align.scene_box(pts[:5], cams)
    assert "cameras" in how4 and np.all(hi4 > lo4)


def test_inference_temperatures_sharpen_the_weights_and_default_to_the_paper():
    from blender_mrvm.models.base import ref_cameras

    stored = to_dict(registry.build_config("gpnr", "fast"))
    for k in ("alpha_temperature", "beta_temperature"):
        stored.pop(k)
    assert registry.config_from_dict("gpnr", stored).alpha_temperature == 1.0
    intr = C.Intrinsics.from_K(np.array([[7.0, 0, 4], [0, 7.0, 4], [0, 0, 1]]), 8, 8)
    poses = []
    for x in (-0.3, 0.3):
        p = np.eye(4)
        p[:3, 3] = [x, 0.0, -3.0]
        poses.append(p)
    cams = ref_cameras(poses, [intr, intr])
    torch.manual_seed(1)
    images = torch.rand(2, 3, 8, 8)
    rays = _rays(inside=False)
    outs = {}
    for t in (1.0, 0.2):
        model, _ = _gpnr(alpha_temperature=t, beta_temperature=t)
        with torch.no_grad():
            outs[t] = model.render_rays(model.encode(images, cams), rays)
            train_out = model.render_rays(model.encode(images, cams), rays, train=True,
                                          generator=torch.Generator().manual_seed(0))
        if t != 1.0:  # training ignores the temperatures
            ref, _ = _gpnr()
            with torch.no_grad():
                want = ref.render_rays(ref.encode(images, cams), rays, train=True, generator=torch.Generator().manual_seed(0))
            assert torch.equal(train_out["color"], want["color"])
    ent = lambda a: float(-(a.clamp_min(1e-12).log() * a).sum(-1).mean())  # noqa: E731
    assert ent(outs[0.2]["alpha"]) < ent(outs[1.0]["alpha"]) and ent(outs[0.2]["beta"]) < ent(outs[1.0]["beta"])
    s = outs[0.2]["alpha"].sum(-1)
    assert (((s - 1).abs() < 1e-5) | (s == 0)).all()
