"""Loaders for our format, SRN, NMR/DVR and NeRF-synthetic on tiny fixtures written here from known cameras."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from blender_mrvm.datasets import loaders as L
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras
from blender_mrvm.training.synthetic import make_sphere_dataset

W, H = 12, 10
INTR = cameras.Intrinsics(11.0, 11.0, 6.0, 5.0, W, H)
POSES = [cameras.look_at_opencv(e) for e in ([2.0, 0.5, 0.7], [-1.0, 2.0, 0.3], [0.3, -1.5, 1.8])]


def _image(k):
    rgba = np.zeros((H, W, 4), np.uint8)
    rgba[..., k % 3] = 200
    rgba[..., 3] = 255
    rgba[:3, :3, 3] = 0  # transparent corner -> white
    return rgba


def _check_rays(scene, intrs):
    assert len(scene) == 3 and scene.images.shape == (3, H, W, 3) and scene.images.dtype == np.float32
    assert np.allclose(scene.images[0, 0, 0], 1.0)  # alpha composited on white
    assert np.allclose(scene.images[1, 5, 5], [0, 200 / 255, 0], atol=1e-6)
    for i in range(3):
        o1, d1 = cameras.rays_opencv(scene.intrinsics[i], scene.c2w[i])
        o2, d2 = cameras.rays_opencv(intrs[i], POSES[i])
        assert np.allclose(o1, o2, atol=1e-6) and np.allclose(d1, d2, atol=1e-6)


def test_srn(tmp_path):
    obj = tmp_path / "cars_train" / "abc"
    for i, c2w in enumerate(POSES):
        F.write_png(obj / "rgb" / f"{i:06d}.png", _image(i))
        F.write_srn_pose(obj / "pose" / f"{i:06d}.txt", c2w)
    F.atomic_write_text(obj / "intrinsics.txt", F.format_srn_intrinsics(INTR))
    objs = L.list_objects(tmp_path, split="train")
    assert L.detect_format(tmp_path) == "srn" and objs == [("srn", obj)]
    sc = L.load_object(*objs[0])
    _check_rays(sc, [INTR] * 3)
    assert sc.category == "cars" and sc.name == "abc"  # pixelNeRF's <cat>_<split> folder: the category
    assert np.allclose(sc.bbox[1], 0.5)


def test_an_srn_split_folder_is_read_as_its_own_split_and_captures_side_by_side_are_refused(tmp_path):
    """A folder of one SRN split (cars_train) was read whatever --split said (eval --split test scored training
    objects and recorded 'test'); captures side by side were read as SRN (their intrinsics.txt), losing their
    scene box, per-photo cameras and background."""
    obj = tmp_path / "cars_train" / "abc"
    for i, c2w in enumerate(POSES):
        F.write_png(obj / "rgb" / f"{i:06d}.png", _image(i))
        F.write_srn_pose(obj / "pose" / f"{i:06d}.txt", c2w)
    F.atomic_write_text(obj / "intrinsics.txt", F.format_srn_intrinsics(INTR))
    assert L.list_objects(tmp_path / "cars_train", split="train") == [("srn", obj)]
    with pytest.raises(InputError, match=r"the 'train' split of an SRN set, not 'test'"):
        L.list_objects(tmp_path / "cars_train", split="test")
    bare = tmp_path / "objects"
    (bare / "abc").mkdir(parents=True)
    for f in ("rgb", "pose", "intrinsics.txt"):
        (bare / "abc" / f).symlink_to(obj / f)
    assert L.list_objects(bare, split="test") == [("srn", bare / "abc")]  # no split named: every object
    for name in ("a", "b"):
        cap = tmp_path / "caps" / name
        (cap / "rgb").mkdir(parents=True)
        F.atomic_write_text(cap / "intrinsics.txt", F.format_srn_intrinsics(INTR))
        F.atomic_write_json(cap / "meta.json", {"kind": "capture", "background": "scene"})
    with pytest.raises(InputError, match=r"holds recovered captures one level down \(a, b\)"):
        L.detect_format(tmp_path / "caps")


def test_nmr_dvr(tmp_path):
    obj = tmp_path / "02958343" / "xyz"
    cams = {}
    intr = cameras.Intrinsics(13.125, 13.125, W / 2 + 0.6, H / 2 - 0.5, W, H)
    for i, c2w in enumerate(POSES):
        F.write_png(obj / "image" / f"{i:04d}.png", _image(i))
        cams[f"world_mat_{i}"] = cameras.invert_pose(c2w)[:3, :4]
        cm = np.eye(4)
        cm[0, 0], cm[1, 1] = intr.fx / (W / 2), intr.fy / (H / 2)
        cm[0, 2], cm[1, 2] = 0.6 / (W / 2), -0.5 / (H / 2)
        cams[f"camera_mat_{i}"] = cm
    np.savez(obj / "cameras.npz", **cams)
    (tmp_path / "02958343" / "test.lst").write_text("xyz\n")
    objs = L.list_objects(tmp_path, split="test")
    assert L.detect_format(tmp_path) == "nmr" and objs == [("nmr", obj)]
    sc = L.load_object(*objs[0])
    _check_rays(sc, [intr] * 3)
    assert sc.category == "02958343"


def test_nerf_synthetic(tmp_path):
    scene = tmp_path / "lego"
    frames = []
    for i, c2w in enumerate(POSES):
        F.write_png(scene / "train" / f"r_{i}.png", _image(i))
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": cameras.opengl_from_opencv(c2w).tolist()})
    fov = 2 * math.atan(W / (2 * INTR.fx))
    (scene / "transforms_train.json").write_text(json.dumps({"camera_angle_x": fov, "frames": frames}))
    objs = L.list_objects(tmp_path)
    assert objs == [("nerf", scene)]
    sc = L.load_object("nerf", scene, "train")
    _check_rays(sc, [INTR] * 3)
    assert np.allclose(sc.bbox[0], -1.5)


def test_ours_from_writers_and_splits(tmp_path):
    root = make_sphere_dataset(tmp_path / "ds", n_objects=2, n_views=3, resolution=16, seed=3)
    assert L.detect_format(root) == "ours"
    train = L.load_dataset(root, "train")
    test = L.load_dataset(root, "test")
    assert [s.name for s in train] == ["obj000"] and [s.name for s in test] == ["obj001"]
    sc = train[0]
    assert sc.images.shape == (3, 16, 16, 3) and sc.c2w.shape == (3, 4, 4) and sc.category == "spheres"
    meta = json.loads((root / "spheres" / "obj000" / "meta.json").read_text())
    assert np.allclose(sc.bbox[0], meta["bbox"][0])
    # the object is visible, the background white, and the depth map agrees with the box
    ov = F.read_object(root / "spheres" / "obj000")
    fg = ov.depth(0) > 0
    assert 0.05 < fg.mean() < 0.9 and np.allclose(sc.images[0][~fg], 1.0)
    pts = cameras.unproject_depth(sc.intrinsics[0], sc.c2w[0], ov.depth(0))[fg]
    assert np.all(pts >= sc.bbox[0] - 1e-3) and np.all(pts <= sc.bbox[1] + 1e-3)
    boxes = sc.foreground_boxes()
    assert (boxes[:, 2] > boxes[:, 0]).all()


def test_errors(tmp_path):
    with pytest.raises(InputError, match="not a dataset"):
        L.detect_format(tmp_path)
    (tmp_path / "o").mkdir()
    with pytest.raises(InputError, match="rgb"):
        L.load_srn(tmp_path / "o")
    with pytest.raises(InputError, match="unknown dataset format"):
        L.load_object("colmap", tmp_path)
