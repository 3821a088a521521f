"""GPNR (models/gpnr/): invariance to rigid motion and scale, epipolar geometry of the patch samples,
masking of samples no view sees, alpha/beta as distributions and the colour as a convex combination of
reference colours, the ablation switches, autocast, and the protocol: training, checkpoints of kind
``gpnr`` through the same commands, and one-line errors for bad input."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.models import registry
from blender_mrvm.models.base import normalized_scene, ref_cameras
from blender_mrvm.models.gpnr.model import canonical_frames, masked_softmax
from blender_mrvm.models.projection import RefCameras
from blender_mrvm.models.rays import RayBundle, make_rays

torch.set_num_threads(1)
TINY = {"patch_dim": 8, "n_samples": 12, "d_model": 16, "n_heads": 2, "n_blocks": 1}
INTR = C.Intrinsics(18.0, 18.0, 8.0, 8.0, 16, 16)
BOX = (np.array([-1.0, -1.0, -1.0]), np.array([1.0, 1.0, 1.0]))


def tiny(**over) -> torch.nn.Module:
    torch.manual_seed(0)
    return registry.build_model(registry.build_config("gpnr", "fast", {**TINY, **over})).eval()


def ring(n: int, radius: float = 3.0, z: float = 1.0, start: float = 0.0) -> list[np.ndarray]:
    return [C.look_at_opencv(np.array([radius * math.cos(a), radius * math.sin(a), z]))
            for a in start + np.linspace(0, 1.2, n)]


def images(n: int, seed: int = 0) -> np.ndarray:
    """Smooth random reference images (bilinear sampling of noise would hide nothing, but smooth is closer to renders)."""
    g = np.random.default_rng(seed).random((n, 4, 4, 3)).astype(np.float32)
    t = torch.nn.functional.interpolate(torch.from_numpy(g).permute(0, 3, 1, 2), size=(16, 16), mode="bilinear",
                                        align_corners=False)
    return t.permute(0, 2, 3, 1).numpy()


def similarity(R: np.ndarray, t: np.ndarray, s: float = 1.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = s * R, t
    return T


def moved(c2w: np.ndarray, T: np.ndarray) -> np.ndarray:
    """A camera pose after the scene moves by the similarity T (the camera keeps a rotation matrix)."""
    s = np.cbrt(np.linalg.det(T[:3, :3]))
    out = np.eye(4)
    out[:3, :3] = (T[:3, :3] / s) @ c2w[:3, :3]
    out[:3, 3] = T[:3, :3] @ c2w[:3, 3] + T[:3, 3]
    return out


def random_rotation(seed: int) -> np.ndarray:
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def core_inputs(T: np.ndarray | None = None):
    """Context and target rays in the normalised frame, optionally after a rigid motion T."""
    poses = ring(4)
    if T is not None:
        poses = [moved(p, T) for p in poses]
    cams = ref_cameras(poses[:3], [INTR] * 3)
    base = make_rays(INTR, ring(4)[3], box=1.05)
    rays = base = base.select(torch.nonzero(base.hit).flatten())
    if T is not None:  # same depths along the same physical rays: entry/far from the unmoved scene
        R_, t_ = torch.from_numpy(T[:3, :3]), torch.from_numpy(T[:3, 3])
        rays = RayBundle(base.origins @ R_.T + t_, base.dirs @ R_.T, base.far, base.hit, base.depth_offset,
                         base.up @ R_.T)
    return cams, rays


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_core_invariant_to_rigid_motion(seed):
    """Any rotation and translation of the whole scene (cameras and rays) leaves the colours, opacity and
    depth unchanged to float tolerance, with canonicalization on; with it off they change (so the test
    can fail)."""
    T = similarity(random_rotation(seed), np.random.default_rng(seed).normal(size=3) * 2.0)
    imgs = torch.from_numpy(images(3)).permute(0, 3, 1, 2).contiguous()
    m = tiny()
    cams0, rays0 = core_inputs()
    cams1, rays1 = core_inputs(T)
    with torch.no_grad():
        a = m.render_rays(m.encode(imgs, cams0), rays0)
        b = m.render_rays(m.encode(imgs, cams1), rays1)
    for k in ("color", "acc", "depth"):
        assert torch.allclose(a[k], b[k], atol=2e-5), (k, float((a[k] - b[k]).abs().max()))
    assert torch.equal(a["valid"], b["valid"])
    for over in ({"canonicalize_coords": False}, {"canonicalize_rays": False}):
        m2 = tiny(**over)
        with torch.no_grad():
            a2 = m2.render_rays(m2.encode(imgs, cams0), rays0)["color"]
            b2 = m2.render_rays(m2.encode(imgs, cams1), rays1)["color"]
        assert float((a2 - b2).abs().max()) > 1e-4, over


def test_synthesis_invariant_to_similarity_in_world_units():
    """End to end in world units: a scene rotated (by a rotation that maps its box to a box), translated
    and uniformly scaled, box included, renders the same image."""
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    T = similarity(R, np.array([4.0, -2.5, 7.0]), s=3.7)
    m = tiny()
    poses = ring(4)
    refs = images(3)
    a = m.synthesize(refs, poses[:3], [INTR] * 3, BOX, poses[3], INTR)
    lo, hi = T[:3, :3] @ BOX[0] + T[:3, 3], T[:3, :3] @ BOX[1] + T[:3, 3]
    box2 = (np.minimum(lo, hi), np.maximum(lo, hi))
    p2 = [moved(p, T) for p in poses]
    b = m.synthesize(refs, p2[:3], [INTR] * 3, box2, p2[3], INTR)
    assert torch.allclose(a["color"], b["color"], atol=3e-5), float((a["color"] - b["color"]).abs().max())
    assert torch.allclose(a["acc"], b["acc"], atol=3e-5)
    assert torch.allclose(a["depth"] * 3.7, b["depth"], rtol=1e-4, atol=1e-4)  # depth in world units scales


def _fundamental(c2w_t: np.ndarray, c2w_r: np.ndarray, K: np.ndarray) -> np.ndarray:
    """F with x_r^T F x_t = 0 (pixel coordinates, homogeneous)."""
    rel = C.invert_pose(c2w_r) @ c2w_t  # target camera -> reference camera
    R, t = rel[:3, :3], rel[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    Ki = np.linalg.inv(K)
    return Ki.T @ tx @ R @ Ki


def test_projections_lie_on_epipolar_lines():
    """Every valid patch centre lies on its target pixel's epipolar line in that reference view within 0.1 px."""
    m = tiny(n_samples=24)
    poses = ring(4)
    ns = normalized_scene(*BOX, m.box_padding)
    np_poses = [ns.pose(p) for p in poses]
    cams = ref_cameras(np_poses[:3], [INTR] * 3)
    pix = np.stack(np.meshgrid(np.arange(16) + 0.5, np.arange(16) + 0.5), -1).reshape(-1, 2)
    rays = make_rays(INTR, np_poses[3], pix, box=ns.box)
    keep = torch.nonzero(rays.hit).flatten()
    out = m.render_rays(m.encode(torch.rand(3, 3, 16, 16), cams), rays.select(keep))
    uv, valid = out["uv"], out["valid"]  # (V, R, M, 2), (R, V, M)
    worst = 0.0
    n = 0
    for v in range(3):
        Fm = _fundamental(np_poses[3], np_poses[v], INTR.K)
        x_t = np.concatenate([pix[keep.numpy()], np.ones((len(keep), 1))], 1)  # (R, 3)
        line = x_t @ Fm.T  # (R, 3): l = F x_t
        u = (uv[v, ..., 0].double().numpy() + 1) * 16 / 2
        w = (uv[v, ..., 1].double().numpy() + 1) * 16 / 2
        dist = np.abs(line[:, None, 0] * u + line[:, None, 1] * w + line[:, None, 2]) / np.hypot(line[:, None, 0], line[:, None, 1])
        ok = valid[:, v].numpy()
        n += ok.sum()
        worst = max(worst, float(dist[ok].max()))
    assert n > 100 and worst < 0.1, (n, worst)


def test_samples_behind_or_outside_are_masked_never_nan():
    """A reference camera looking away sees no sample (beta 0 for it); a ray no view sees is background
    with zero opacity; nothing is NaN."""
    poses = ring(3)
    away = C.look_at_opencv(np.array([3.0, 0.0, 1.0]), target=np.array([6.0, 0.0, 1.0]))
    m = tiny()
    ns = normalized_scene(*BOX, m.box_padding)
    cams = ref_cameras([ns.pose(poses[0]), ns.pose(away)], [INTR] * 2)
    rays = make_rays(INTR, ns.pose(poses[2]), box=ns.box)
    rays = rays.select(torch.nonzero(rays.hit).flatten())
    with torch.no_grad():
        out = m.render_rays(m.encode(torch.rand(2, 3, 16, 16), cams), rays)
    assert not out["valid"][:, 1].any()  # everything is behind the camera that looks away
    assert torch.all(out["beta"][:, 1] == 0) and torch.all(out["alpha"][:, 1] == 0)
    for k in ("color", "acc", "depth", "alpha", "beta"):
        assert torch.isfinite(out[k]).all(), k
    # only the camera that looks away: every ray is unseen -> background, opacity 0
    cams = ref_cameras([ns.pose(away)], [INTR])
    with torch.no_grad():
        out = m.render_rays(m.encode(torch.rand(1, 3, 16, 16), cams), rays)
    assert torch.all(out["color"] == 1.0) and torch.all(out["acc"] == 0.0)
    assert torch.isfinite(out["depth"]).all()


def test_masked_softmax_extremes():
    x = torch.tensor([[1e30, -1e30, 0.0], [0.0, 0.0, 0.0], [float("inf"), 1.0, 2.0]])
    valid = torch.tensor([[True, True, False], [False, False, False], [False, True, True]])
    w = masked_softmax(x, valid, -1)
    assert torch.isfinite(w).all()
    assert torch.allclose(w.sum(-1), torch.tensor([1.0, 0.0, 1.0]))
    assert torch.all(w[~valid] == 0)


def test_canonical_frames_are_rotations_with_ray_as_z():
    d = torch.nn.functional.normalize(torch.randn(64, 3, dtype=torch.float64), dim=-1)
    up = torch.randn(64, 3, dtype=torch.float64)
    up[0] = d[0] * 2.0  # degenerate: up parallel to the ray
    Rf = canonical_frames(torch.zeros_like(d), d, up)
    eye = torch.eye(3, dtype=torch.float64)
    assert torch.allclose(Rf @ Rf.transpose(1, 2), eye.expand(64, 3, 3), atol=1e-12)
    assert torch.allclose(torch.linalg.det(Rf), torch.ones(64, dtype=torch.float64))
    assert torch.allclose(torch.einsum("rij,rj->ri", Rf, d), eye[2].expand(64, 3), atol=1e-12)


@pytest.mark.parametrize("colour_filter", ["bilinear", "bicubic"])
def test_weights_are_distributions_and_colour_is_convex_combination(colour_filter):
    m = tiny(colour_filter=colour_filter)
    poses = ring(4)
    ns = normalized_scene(*BOX, m.box_padding)
    cams = ref_cameras([ns.pose(p) for p in poses[:3]], [INTR] * 3)
    rays = make_rays(INTR, ns.pose(poses[3]), box=ns.box)
    rays = rays.select(torch.nonzero(rays.hit).flatten())
    imgs = torch.from_numpy(images(3, seed=4)).permute(0, 3, 1, 2).contiguous()
    with torch.no_grad():
        out = m.render_rays(m.encode(imgs, cams), rays)
    alpha, beta, valid = out["alpha"], out["beta"], out["valid"]
    seen_v = valid.any(-1)
    assert torch.all(alpha >= 0) and torch.all(beta >= 0)
    assert torch.allclose(alpha.sum(-1)[seen_v], torch.ones(int(seen_v.sum())), atol=1e-5)
    assert torch.all(alpha.sum(-1)[~seen_v] == 0)
    seen = seen_v.any(-1)
    assert seen.all() and torch.allclose(beta.sum(-1), torch.ones(len(rays)), atol=1e-5)
    # colour = sum of weights x reference colours read at the projections
    from blender_mrvm.models.projection import sample_maps

    rgb = sample_maps(imgs, out["uv"].float(), colour_filter).clamp(0, 1)  # (V, R, M, 3)
    recon = torch.einsum("rvm,vrmc->rc", out["weights"], rgb)
    assert torch.allclose(out["color"], recon, atol=1e-5)
    lo = torch.where(valid.permute(1, 0, 2)[..., None], rgb, torch.full_like(rgb, 2.0)).amin((0, 2))
    hi = torch.where(valid.permute(1, 0, 2)[..., None], rgb, torch.full_like(rgb, -1.0)).amax((0, 2))
    assert torch.all(out["color"] >= lo - 1e-5) and torch.all(out["color"] <= hi + 1e-5)
    assert torch.all((out["depth"] >= 0) & (out["depth"] <= rays.far.float() + 1e-5))


def test_bicubic_colour_reads_keep_detail_that_bilinear_reads_blur():
    """The reason for ``colour_filter: bicubic``: at sub-pixel positions a bilinear read of a fine pattern
    loses contrast (a low-pass filter), a bicubic read keeps more of it, and both agree at pixel centres."""
    from blender_mrvm.models.projection import sample_maps

    W = 32
    x = torch.arange(W, dtype=torch.float32)
    img = (0.5 + 0.4 * torch.sin(2 * math.pi * x / 4.0)).expand(1, 1, 8, W).contiguous()  # period 4 px
    u = torch.arange(4, W - 4, dtype=torch.float32) + 0.5  # pixel centres (align_corners=False)
    for shift, cmp in ((0.0, "equal"), (0.25, "sharper"), (0.5, "sharper")):
        gu = 2.0 * (u + shift) / W - 1.0
        uv = torch.stack([gu, torch.zeros_like(gu)], -1).view(1, 1, -1, 2)
        lin = sample_maps(img, uv)[0, 0, :, 0]
        cub = sample_maps(img, uv, "bicubic")[0, 0, :, 0]
        amp = lambda v: float(v.max() - v.min())  # noqa: E731
        if cmp == "equal":
            assert torch.allclose(lin, cub, atol=1e-5)
        else:
            assert amp(cub) > 1.1 * amp(lin)


def test_feature_colour_ablation_and_autocast():
    m = tiny(colour_from="features")
    poses = ring(3)
    out = m.synthesize(images(2), poses[:2], [INTR] * 2, BOX, poses[2], INTR)
    assert torch.all((out["color"] >= 0) & (out["color"] <= 1))
    m = tiny()
    with torch.autocast("cpu", dtype=torch.bfloat16):
        out = m.synthesize(images(2), poses[:2], [INTR] * 2, BOX, poses[2], INTR)
    assert torch.isfinite(out["color"]).all() and torch.isfinite(out["depth"]).all()


def test_presets_and_config_validation():
    sizes = {n: sum(p.numel() for p in registry.build_model(c).parameters()) for n, c in registry.presets("gpnr").items()}
    assert sizes["fast"] < sizes["balanced"] < sizes["accurate"] < sizes["paper"]
    paper = registry.presets("gpnr")["paper"]
    assert paper.n_blocks == 8 and paper.d_model == 256
    for bad in ({"patch_size": 4}, {"d_model": 30, "n_heads": 4}, {"colour_from": "nope"}, {"n_samples": 0},
                {"min_ref_views": 5, "max_ref_views": 2}):
        with pytest.raises(InputError):
            registry.build_config("gpnr", "fast", bad)
    with pytest.raises(InputError, match="unknown model kind"):
        registry.kind("nerf-o-matic")
    from blender_mrvm.models.config import from_dict, to_dict

    for c in registry.presets("gpnr").values():
        assert from_dict(type(c), to_dict(c)) == c


# ---------------------------------------------------------------------------------------------- protocol

@pytest.fixture(scope="module")
def spheres(tmp_path_factory):
    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.training.synthetic import make_sphere_dataset

    root = make_sphere_dataset(tmp_path_factory.mktemp("spheres"), n_objects=3, n_views=5, resolution=16, seed=1)
    return root, load_dataset(root, "train")


def test_gpnr_trains_and_round_trips_through_checkpoints(tmp_path, spheres):
    """The shared trainer trains a GPNR model (loss falls on a fixed batch); its checkpoint records the
    kind, loads through the same loader, fine-tunes (init) and is refused as init for another kind."""
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training import checkpoint as ckpt
    from blender_mrvm.training.config import TrainConfig, load_run_config
    from blender_mrvm.training.trainer import RayBatcher, train

    root, scenes = spheres
    mcfg = registry.build_config("gpnr", "fast", TINY)
    tcfg = TrainConfig(data=str(root), out_dir=str(tmp_path / "run"), iterations=6, objects_per_step=2,
                       rays_per_object=64, max_ref_views=2, lr=3e-3, lr_warmup=0, log_every=1, ckpt_every=6,
                       threads=1, opacity_weight=0.1)

    def fixed_mse(model):
        b = RayBatcher(scenes, tcfg, model.box_padding, seed=5)
        errs = []
        with torch.no_grad():
            for _ in range(4):
                d = b.draw(False)
                ctx = model.encode(d["images"], d["cams"])
                idx = torch.nonzero(d["rays"].hit).flatten()
                pred = torch.ones_like(d["gt"])
                pred[idx] = model.render_rays(ctx, d["rays"].select(idx))["color"]
                errs.append(((pred - d["gt"]) ** 2).mean())
        return float(torch.stack(errs).mean())

    torch.manual_seed(tcfg.seed)
    before = fixed_mse(registry.build_model(mcfg).eval())
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    model, cfg2, meta = ckpt.load_model(tmp_path / "run")
    assert meta["model_kind"] == "gpnr" and cfg2 == mcfg and type(model).__name__ == "GPNR"
    after = fixed_mse(model.eval())
    assert after < before, (before, after)
    lines = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert all(np.isfinite(x["loss"]) and "opacity" in x for x in lines)
    doc = json.loads((tmp_path / "run" / "config.json").read_text())
    assert doc["model"]["kind"] == "gpnr"
    # the run config of a finished run trains again from its config.json (kind kept)
    m2, t2 = load_run_config(tmp_path / "run" / "config.json")
    assert m2 == mcfg
    # fine-tune from it: the checkpoint's own model config, any kind
    m3, t3 = load_run_config(None, {"data": str(root), "init_checkpoint": str(tmp_path / "run")})
    assert m3 == mcfg
    # a NeRFormer run config with a GPNR init checkpoint is refused before anything is written
    from blender_mrvm.models.config import model_config

    bad = TrainConfig(data=str(root), out_dir=str(tmp_path / "bad"), iterations=1, threads=1,
                      init_checkpoint=str(tmp_path / "run"))
    nerf = model_config("fast", {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8}})
    with pytest.raises(InputError, match="gpnr model"):
        run_to_end(train(nerf, bad, scenes=scenes))
    with pytest.raises(InputError, match="conflicts with the config"):
        load_run_config(tmp_path / "run" / "config.json", kind="nerformer_mrvm")


def test_checkpoint_of_unknown_kind_and_reference_counts(tmp_path):
    """A checkpoint whose kind this version does not know, and too few / too many reference views: one-line
    InputErrors; the synthesize CLI writes nothing."""
    from blender_mrvm.synthesis import load_checkpoint
    from blender_mrvm.training.checkpoint import save_checkpoint

    cfg = registry.build_config("gpnr", "fast", {**TINY, "min_ref_views": 2, "max_ref_views": 3})
    m = registry.build_model(cfg)
    ck = save_checkpoint(tmp_path / "run", 1, m, cfg, None)
    model, cfg2, meta, _ = load_checkpoint(ck)
    assert cfg2 == cfg
    with pytest.raises(InputError, match="at least 2 reference views"):
        model.check_reference_count(1)
    with pytest.raises(InputError, match="at most 3"):
        model.check_reference_count(4)
    # rewrite the header with an unknown kind
    from safetensors.torch import load_file, save_file

    f = ck / "model.safetensors"
    from blender_mrvm.models.checkpoint_files import read_header_meta

    meta = read_header_meta(f)
    save_file(load_file(str(f)), str(tmp_path / "weird.safetensors"), metadata={**meta, "model_kind": "hologram"})
    with pytest.raises(InputError) as e:
        load_checkpoint(tmp_path / "weird.safetensors")
    assert "hologram" in str(e.value) and "\n" not in str(e.value)


def test_a_sem2nerf_checkpoint_is_named_not_misread():
    """A checkpoint of the mask-conditioned kind handed to the reference-view commands says what it is."""
    with pytest.raises(InputError, match="sem2nerf render"):
        registry.kind_from_meta({"model_kind": "sem2nerf"})
    assert registry.kind_from_meta({}) == "nerformer_mrvm" and registry.kind_from_meta({"model_kind": "gpnr"}) == "gpnr"


def test_a_deeper_gpnr_grows_from_a_shallower_one(tmp_path):
    """More transformer blocks of the same width grow from a GPNR model file: the added blocks start as the
    identity, so the deeper model renders exactly what the file's did."""
    from safetensors.torch import save_model

    from blender_mrvm.training import checkpoint as ckpt

    shallow, deep = tiny(), tiny(n_blocks=3)
    save_model(shallow, str(tmp_path / "m.safetensors"))
    added = ckpt.load_weights_deepened(deep, tmp_path / "m.safetensors")
    assert added and all(n.endswith((".1", ".2")) for n in added)
    ns = normalized_scene(*BOX, shallow.box_padding)
    poses = [ns.pose(p) for p in ring(3)]
    cams = ref_cameras(poses[:2], [INTR] * 2)
    pix = np.stack(np.meshgrid(np.arange(16) + 0.5, np.arange(16) + 0.5), -1).reshape(-1, 2)
    rays = make_rays(INTR, poses[2], pix, box=ns.box)
    rays = rays.select(torch.nonzero(rays.hit).flatten())
    imgs = torch.from_numpy(images(2)).permute(0, 3, 1, 2)
    with torch.no_grad():
        a = shallow.render_rays(shallow.encode(imgs, cams), rays)["color"]
        b = deep.render_rays(deep.encode(imgs, cams), rays)["color"]
    assert len(a) > 50 and torch.equal(a, b)
