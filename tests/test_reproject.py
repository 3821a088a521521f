"""Reference colours carried into a view through a depth map (`models/reproject.py`, `eval --reproject`):
exact on a textured plane with exact depth, nothing through an occluder or from outside a reference's frame,
the blend's opacity ramp, and the eval report's paired figures."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.geometry import cameras
from blender_mrvm.models import reproject as rp
from blender_mrvm.training.synthetic import make_sphere_dataset

from test_synthesize import tiny_checkpoint

torch.set_num_threads(1)


def look_at(eye, target=(0.0, 0.0, 0.0)):
    """OpenCV camera-to-world pose at ``eye`` looking at ``target`` (world z up)."""
    eye = np.asarray(eye, np.float64)
    f = np.asarray(target, np.float64) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([r, d, f], 1)
    pose[:3, 3] = eye
    return pose


def plane_colour(x):
    """A smooth colour on the ground plane z = 0."""
    return np.stack([0.5 + 0.4 * np.sin(2 * x[..., 0]), 0.5 + 0.4 * np.cos(3 * x[..., 1]),
                     0.5 + 0.4 * np.tanh(x[..., 0] * x[..., 1])], -1)


def plane_view(pose, intr):
    """(image, distance along each ray, hit mask) of the plane z = 0 seen from ``pose``."""
    o, d = cameras.rays_opencv(intr, pose)
    t = -o[..., 2] / np.where(np.abs(d[..., 2]) > 1e-12, d[..., 2], -1e-12)
    hit = t > 0
    x = o + d * t[..., None]
    img = np.where(hit[..., None], plane_colour(x), 1.0)
    return img.astype(np.float32), np.where(hit, t, 0.0), hit


def intr64():
    f = 32 / np.tan(np.radians(25))
    return cameras.Intrinsics(fx=f, fy=f, cx=32.0, cy=32.0, width=64, height=64)


def test_exact_depth_carries_the_reference_colour():
    intr = intr64()
    ref, tgt = look_at([0.3, -2.0, 1.5]), look_at([-0.8, -1.8, 1.2])
    ref_img, ref_d, ref_hit = plane_view(ref, intr)
    true, depth, hit = plane_view(tgt, intr)
    alike = rp.ReprojectConfig(angle_scale=0.0)
    col, w = rp.reference_colours(depth, tgt, intr, ref_img[None], [ref], [intr], ref_d[None], ref_hit[None], alike)
    # where the target's surface point lies well inside the reference's frame, the colour is the surface's own
    o, d = cameras.rays_opencv(intr, tgt)
    x = o + d * depth[..., None]
    pc = (x - ref[:3, 3]) @ ref[:3, :3]
    uv = (pc @ intr.K.T)[..., :2] / pc[..., 2:]
    inner = hit & np.all((uv > 1.5) & (uv < 62.5), -1)
    assert inner.mean() > 0.5
    inner &= np.all(np.abs(x[..., :2]) < 1.0, -1)  # near the middle, where both views sample the texture finely
    assert inner.sum() > 500
    assert np.all(w[inner] == 1.0)
    assert np.abs(col[inner] - true[inner]).max() < 0.01  # bilinear reads of a smooth texture
    outside = hit & ~np.all((uv >= 0) & (uv < 64), -1)
    assert np.all(w[outside] == 0) and np.all(w[~hit] == 0)  # no depth, or outside the frame: nothing


def test_occluded_points_take_nothing_and_keep_the_model_colour():
    intr = intr64()
    ref, tgt = look_at([0.3, -2.0, 1.5]), look_at([-0.8, -1.8, 1.2])
    ref_img, ref_d, ref_hit = plane_view(ref, intr)
    _, depth, hit = plane_view(tgt, intr)
    blocked = ref_d.copy()
    blocked[:, :32] *= 0.5  # something nearer in front of the reference's left half
    col, w = rp.reference_colours(depth, tgt, intr, ref_img[None], [ref], [intr], blocked[None], ref_hit[None],
                                  rp.ReprojectConfig(tau=0.03))
    _, w_open = rp.reference_colours(depth, tgt, intr, ref_img[None], [ref], [intr], ref_d[None], ref_hit[None])
    assert (w_open > 0).sum() > (w > 0).sum() > 0  # the occluded half lost its weight, the other half kept it
    model = np.full(depth.shape + (3,), 0.25, np.float32)
    out, share = rp.blend(model, np.ones(depth.shape), col, w)
    assert np.array_equal(out[w == 0], model[w == 0]) and np.all(share[w == 0] == 0)


def test_blend_follows_the_opacity_ramp_and_angle_weights():
    cfg = rp.ReprojectConfig(acc_lo=0.5, acc_hi=0.8)
    model = np.zeros((1, 3, 3), np.float32)
    ref = np.ones((1, 3, 3), np.float32)
    out, share = rp.blend(model, np.array([[0.4, 0.65, 0.9]]), ref, np.ones((1, 3)), cfg)
    assert out[0, :, 0] == pytest.approx([0.0, 0.5, 1.0]) and share[0] == pytest.approx([0.0, 0.5, 1.0])
    # two references seeing the same plane: with angle weighting, the one whose ray is nearer the view's dominates
    intr = intr64()
    tgt = look_at([-0.8, -1.8, 1.2])
    near, far = look_at([-0.6, -1.9, 1.3]), look_at([1.5, -1.0, 1.6])
    _, depth, _ = plane_view(tgt, intr)
    views = [plane_view(p, intr) for p in (near, far)]
    red = np.zeros((64, 64, 3), np.float32)
    red[..., 0] = 1
    blue = np.zeros((64, 64, 3), np.float32)
    blue[..., 2] = 1
    args = (depth, tgt, intr, np.stack([red, blue]), [near, far], [intr] * 2, np.stack([v[1] for v in views]),
            np.stack([v[2] for v in views]))
    col_eq, w_eq = rp.reference_colours(*args, rp.ReprojectConfig(angle_scale=0.0))
    col_ang, _ = rp.reference_colours(*args, rp.ReprojectConfig(angle_scale=0.05))
    both = (w_eq == 1) & (col_eq[..., 0] > 0.4) & (col_eq[..., 2] > 0.4)
    assert both.sum() > 100
    assert col_eq[both][:, 0] == pytest.approx(0.5, abs=1e-5)
    assert np.all(col_ang[both][:, 0] > 0.7)


@pytest.mark.parametrize("kw, needle", [({"tau": -0.1}, "tolerance"), ({"tau": float("nan")}, "tolerance"),
                                        ({"angle_scale": -1}, "angle"), ({"acc_lo": 0.9, "acc_hi": 0.5}, "ramp")])
def test_bad_settings_are_refused(kw, needle):
    from blender_mrvm.errors import InputError

    with pytest.raises(InputError, match=needle):
        rp.ReprojectConfig(**kw).check()


@pytest.fixture(scope="module")
def sphere_set(tmp_path_factory):
    root = tmp_path_factory.mktemp("rpset")
    make_sphere_dataset(root, n_objects=2, n_views=6, resolution=16, seed=3, category="c")
    return root


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    return tiny_checkpoint(tmp_path_factory.mktemp("rprun"))


def test_eval_reproject_reports_the_paired_gain(sphere_set, checkpoint, tmp_path, capsys):
    base = ["eval", "--checkpoint", str(checkpoint), "--data", str(sphere_set), "--split", "train",
            "--input-views", "0,3", "--no-lpips", "--threads", "1"]
    assert main(base + ["--out", str(tmp_path / "gt"), "--reproject", "gt", "--reproject-angle", "0"]) == 0
    rep = json.loads((tmp_path / "gt" / "eval.json").read_text())
    assert rep["protocol"]["reproject"]["depth"] == "gt"
    v = rep["views"][0]
    assert set(v["model_only"]) >= {"psnr", "ssim"} and 0 < v["reference_share"] <= 1
    gain = rep["reprojection_minus_model"]
    # an untrained model and exact geometry: the references' colours are far better than its output
    assert gain["views"] == len(rep["views"]) and gain["psnr"]["diff"] > 3 and "depth_abs_rel" not in gain
    assert rep["overall"]["psnr"] == pytest.approx(rep["overall"]["model_only"]["psnr"] + gain["psnr"]["diff"])
    assert "eval --reproject" in (tmp_path / "gt" / "eval.md").read_text()
    assert main(base + ["--out", str(tmp_path / "model"), "--reproject", "model"]) == 0
    rep_m = json.loads((tmp_path / "model" / "eval.json").read_text())
    assert rep_m["overall"]["model_only"]["psnr"] == pytest.approx(rep["overall"]["model_only"]["psnr"])
    # without depth maps, "gt" is refused before anything renders or is written
    nodepth = tmp_path / "nodepth"
    shutil.copytree(sphere_set, nodepth)
    for f in nodepth.rglob("depth"):
        shutil.rmtree(f)
    out = tmp_path / "nd"
    assert main(base[:4] + [str(nodepth)] + base[5:] + ["--out", str(out), "--reproject", "gt"]) == 2
    err = capsys.readouterr().err
    assert "--reproject gt needs the data's depth maps" in err and not out.exists()


def test_ray_distances_match_the_unprojected_points():
    intr = intr64()
    pose = look_at([0.3, -2.0, 1.5])
    z = np.random.default_rng(0).uniform(0.5, 3.0, (64, 64))
    z[:8] = 0  # no surface
    dist = cameras.ray_distances(z, intr)
    pts = cameras.unproject_depth(intr, pose, z)
    want = np.linalg.norm(pts - pose[:3, 3], axis=-1)
    assert np.all(dist[:8] == 0) and dist[8:] == pytest.approx(want[8:], rel=1e-12)


def test_synthesis_config_refuses_an_unknown_reproject_mode(tmp_path):
    from blender_mrvm.errors import InputError
    from blender_mrvm.synthesis import SynthesisConfig

    with pytest.raises(InputError, match="synthesis.reproject"):
        SynthesisConfig(tmp_path, tmp_path / "targets.json", tmp_path / "out", reproject="always")
