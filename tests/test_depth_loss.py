"""The depth loss (``train.depth_weight``): depth maps read on request, the surface distance along each
training ray, the loss's values, and a run with it (and the inputs it refuses)."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
import torch

from blender_mrvm.datasets.loaders import ObjectScene, load_dataset
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras, rigs
from blender_mrvm.models import registry
from blender_mrvm.models.config import model_config
from blender_mrvm.models.rays import normalization
from blender_mrvm.progress import run_to_end
from blender_mrvm.training.config import TrainConfig, replace
from blender_mrvm.training.synthetic import _trace, make_sphere_dataset
from blender_mrvm.training.trainer import RayBatcher, surface_loss, train

torch.set_num_threads(1)
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 16, "n_heads": 2},
        "sampler": {"n_coarse": 8, "n_fine": 4}}


@pytest.fixture(scope="module")
def spheres(tmp_path_factory):
    return make_sphere_dataset(tmp_path_factory.mktemp("spheres"), n_objects=3, n_views=5, resolution=16, seed=1)


def test_depth_maps_are_read_only_when_asked(spheres):
    plain = load_dataset(spheres, "train")
    assert all(s.depths is None for s in plain)
    deep = load_dataset(spheres, "train", depth=True)
    for s in deep:
        assert s.depths.shape == s.images.shape[:3] and s.depths.dtype == np.float32
        assert np.array_equal(s.depths > 0, s.masks)  # 0 marks the background


def _one_sphere(centre, radius, res=24, views=4):
    intr = cameras.intrinsics_from_fov(math.radians(40), res, res)
    poses = rigs.rig_poses("sphere", views, rigs.framing_distance(1.0, math.radians(40)), seed=3)
    rgb, depth, masks = [], [], []
    for c2w in poses:
        im, z, _, ids = _trace(intr, c2w, [np.asarray(centre, float)], [radius], [np.array([0.8, 0.3, 0.2])])
        rgb.append(im)
        depth.append(z)
        masks.append(ids > 0)
    lo, hi = np.asarray(centre) - radius, np.asarray(centre) + radius
    return ObjectScene("ball", "c", np.stack(rgb).astype(np.float32), np.stack(poses), [intr] * views, (lo, hi),
                       list(range(views)), np.stack(masks), "white", np.stack(depth).astype(np.float32))


@pytest.mark.parametrize("patch", [False, True])
def test_surface_distance_lands_on_the_surface(patch):
    """A training ray's surface distance, walked from its box entry, reaches the sphere the depth map saw:
    exactly at pixel centres; within a sliver of the radius for the patches' interpolated depth."""
    centre, radius = np.array([0.3, -0.2, 0.1]), 0.7
    s = _one_sphere(centre, radius)
    cfg = TrainConfig(depth_weight=1.0, rays_per_object=400, lpips_weight=1.0 if patch else 0.0, min_ref_views=1,
                      max_ref_views=1)
    b = RayBatcher([s], cfg, 0.05, seed=0)
    c, scale = normalization(*s.bbox)
    err = []
    for _ in range(6):
        d = b.draw(False)
        t = d["surface"].numpy().astype(np.float64)
        ok = np.isfinite(t)
        rays = d["rays"]
        p = (rays.origins.numpy() + t[:, None] * rays.dirs.numpy())[ok] * scale + c  # world
        err += list(np.abs(np.linalg.norm(p - centre, axis=1) - radius) / radius)
        fg = (d["mask"].numpy() > (0.999 if patch else 0.5)) & rays.hit.numpy()
        assert np.array_equal(ok, fg)  # every ray that sees the sphere (wholly, in a patch) has its distance
    assert len(err) > 100
    if patch:  # depth interpolated between pixel centres: off most near the silhouette, where it is steep
        assert np.median(err) < 5e-3 and max(err) < 4e-2
    else:
        assert max(err) < 1e-5


def test_surface_loss_values():
    t = torch.tensor([[0.0, 0.2, 0.4, 0.6, 0.8]])
    far = torch.tensor([1.0])
    mids = [0.1, 0.3, 0.5, 0.7, 0.9]
    at = torch.zeros(1, 5)
    at[0, 2] = 1.0  # all the light stops in [0.4, 0.6], around the surface at 0.5
    assert float(surface_loss(at, t, far, torch.tensor([0.5]))) == pytest.approx(0.0, abs=1e-7)
    ghost = torch.zeros(1, 5)
    ghost[0, 0] = ghost[0, 4] = 0.5  # two layers whose mean is the surface: a loss on the mean depth is 0 here
    assert float(surface_loss(ghost, t, far, torch.tensor([0.5]))) == pytest.approx(0.4, rel=1e-6)
    empty = torch.zeros(1, 5)  # the light leaves at the far end
    assert float(surface_loss(empty, t, far, torch.tensor([0.25]))) == pytest.approx(0.75, rel=1e-6)
    w = torch.tensor([[0.1, 0.2, 0.3, 0.1, 0.05]])
    ref = sum(float(w[0, i]) * abs(mids[i] - 0.35) for i in range(5)) + (1 - float(w.sum())) * 0.65
    assert float(surface_loss(w, t, far, torch.tensor([0.35]))) == pytest.approx(ref, rel=1e-5)
    # a share of the ray's length: the box's size does not matter
    assert float(surface_loss(w, 7 * t, 7 * far, torch.tensor([7 * 0.35]))) == pytest.approx(ref, rel=1e-5)
    w.requires_grad_(True)
    surface_loss(w, t, far, torch.tensor([0.35])).backward()
    assert w.grad[0, 1] < w.grad[0, 0] and w.grad[0, 2] < w.grad[0, 4]  # light nearer the surface costs less


def _cfgs(tmp, root, **kw):
    base = dict(data=str(root), out_dir=str(tmp), iterations=3, objects_per_step=2, rays_per_object=64,
                max_ref_views=2, lr=3e-3, lr_warmup=0, log_every=1, ckpt_every=3, threads=1, pretrain_frac=0.0,
                bbox_sampling_frac=0.5, depth_weight=0.5)
    base.update(kw)
    return model_config("fast", TINY), TrainConfig(**base)


def test_training_with_the_depth_loss(tmp_path, spheres):
    mcfg, tcfg = _cfgs(tmp_path / "run", spheres)
    s = run_to_end(train(mcfg, tcfg))  # the data loaded from train.data, depth maps with it
    assert s["last"]["depth"] > 0 and np.isfinite(s["last"]["loss"])
    off = run_to_end(train(mcfg, replace(tcfg, out_dir=str(tmp_path / "off"), depth_weight=0.0)))
    assert "depth" not in off["last"]
    # with LPIPS patches too (the depth of a patch is interpolated)
    lp = run_to_end(train(mcfg, replace(tcfg, out_dir=str(tmp_path / "lp"), lpips_weight=1.0),
                          scenes=load_dataset(spheres, "train", depth=True)))
    assert lp["last"]["depth"] > 0 and np.isfinite(lp["last"]["loss"])


def test_depth_loss_refuses_what_it_cannot_use(tmp_path, spheres):
    mcfg, tcfg = _cfgs(tmp_path / "run", spheres)
    with pytest.raises(InputError, match="depth_weight must be >= 0"):
        replace(tcfg, depth_weight=-0.1)
    with pytest.raises(InputError, match="density field"):
        run_to_end(train(registry.build_config("gpnr", "fast"), replace(tcfg, out_dir=str(tmp_path / "g"))))
    assert not (tmp_path / "g").exists()
    bare = tmp_path / "bare"
    shutil.copytree(spheres, bare)
    shutil.rmtree(next(bare.glob("*/*/depth")))  # one object without its depth maps
    with pytest.raises(InputError, match="depth_weight needs depth maps"):
        run_to_end(train(mcfg, replace(tcfg, data=str(bare), out_dir=str(tmp_path / "b"))))
    assert not (tmp_path / "b").exists()


def test_eval_scores_depth_where_the_data_has_it():
    """``depth_abs_rel``: 0 for the true distances along the rays (from planar depth), the relative error of a
    scaled answer, 1 where nothing is rendered; ``depth_missing`` and ``depth_rel_median`` split the two; nothing
    for a view without a surface."""
    from blender_mrvm.training.evaluate import depth_scores

    def depth_abs_rel(*a):
        return depth_scores(*a).get("depth_abs_rel")

    s = _one_sphere(np.zeros(3), 0.6, res=20, views=1)
    intr, c2w = s.intrinsics[0], s.c2w[0]
    o, d = cameras.rays_opencv(intr, c2w)
    z = s.depths[0].astype(np.float64)
    along = np.where(z > 0, z / (d.reshape(20, 20, 3) @ c2w[:3, 2]), 0.0)  # camera to surface, along the ray
    assert depth_abs_rel(along, z, intr) == pytest.approx(0.0, abs=1e-9)
    assert depth_abs_rel(1.1 * along, z, intr) == pytest.approx(0.1, rel=1e-9)
    assert depth_abs_rel(np.zeros_like(z), z, intr) == pytest.approx(1.0)
    assert depth_abs_rel(along, np.zeros_like(z), intr) is None
    half = along.copy()
    fg = np.argwhere(z > 0)
    half[tuple(fg[: len(fg) // 2].T)] = 0  # nothing rendered on half the surface, the rest 20 % too far
    half *= 1.2
    sc = depth_scores(half, z, intr)
    assert sc["depth_missing"] == pytest.approx(1 - (len(fg) - len(fg) // 2) / len(fg))
    assert sc["depth_rel_median"] == pytest.approx(0.2, rel=1e-9)
    assert sc["depth_abs_rel"] == pytest.approx(sc["depth_missing"] + 0.2 * (1 - sc["depth_missing"]), rel=1e-9)
    assert "depth_rel_median" not in depth_scores(np.zeros_like(z), z, intr)
