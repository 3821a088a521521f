"""datasets/format.py round trips and geometry/rigs.py layouts (no Blender needed)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.geometry import rigs


def test_exr_round_trip_with_openexr(tmp_path):
    import OpenEXR

    rng = np.random.default_rng(0)
    depth = rng.uniform(0.1, 1e4, size=(7, 11)).astype(np.float32)
    depth[0, 0] = 0.0
    F.write_depth(tmp_path / "d.exr", depth)
    f = OpenEXR.File(str(tmp_path / "d.exr"), separate_channels=True)
    assert list(f.channels()) == ["Y"]
    assert np.array_equal(f.channels()["Y"].pixels, depth)
    assert np.array_equal(F.read_depth(tmp_path / "d.exr"), depth)
    n = rng.normal(size=(5, 6, 3)).astype(np.float32)
    F.write_normals(tmp_path / "n.exr", n)
    assert np.array_equal(F.read_normals(tmp_path / "n.exr"), n)
    (tmp_path / "bad.exr").write_bytes(b"not an exr")
    with pytest.raises(InputError, match="cannot read EXR"):
        F.read_exr(tmp_path / "bad.exr")


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    def boom(tmp):
        open(tmp, "w").write("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        F.atomic_write(tmp_path / "x.png", boom)
    assert list(tmp_path.iterdir()) == []


def test_atomic_files_get_ordinary_permissions(tmp_path):
    import os
    import stat

    F.atomic_write_text(tmp_path / "a.txt", "x")
    mask = os.umask(0)
    os.umask(mask)
    assert stat.S_IMODE((tmp_path / "a.txt").stat().st_mode) == 0o666 & ~mask


def test_srn_files_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    c2w = C.look_at_opencv(rng.normal(size=3) * 2)
    F.write_srn_pose(tmp_path / "p.txt", c2w)
    assert len((tmp_path / "p.txt").read_text().splitlines()) == 1
    assert np.allclose(F.read_srn_pose(tmp_path / "p.txt"), c2w, atol=1e-8)
    (tmp_path / "p4.txt").write_text("\n".join(" ".join(map(str, r)) for r in c2w) + "\n")  # 4-line variant
    assert np.allclose(F.read_srn_pose(tmp_path / "p4.txt"), c2w)
    intr = C.Intrinsics(131.25, 131.25, 64.0, 48.0, 128, 96)
    (tmp_path / "intrinsics.txt").write_text(F.format_srn_intrinsics(intr))
    lines = (tmp_path / "intrinsics.txt").read_text().splitlines()
    assert lines[0].split()[:3] == ["131.25", "64", "48"] and lines[-1] == "96 128"  # "H W"
    assert F.read_srn_intrinsics(tmp_path / "intrinsics.txt") == intr


def test_transforms_json_matches_nerf_conventions(tmp_path):
    """A frame written from an OpenCV pose reads back identically, and holds the OpenGL pose."""
    intr = C.Intrinsics(100.0, 100.0, 32.0, 24.0, 64, 48)
    c2w = C.look_at_opencv((0.0, -3.0, 1.0))
    d = F.transforms_dict(intr, [{"file_path": "rgb/000000.png", "c2w_opencv": c2w}])
    (tmp_path / "transforms.json").write_text(json.dumps(d))
    fr = F.read_transforms(tmp_path / "transforms.json")[0]
    assert np.allclose(fr.c2w_opencv, c2w) and fr.intrinsics == intr
    gl = np.array(d["frames"][0]["transform_matrix"])
    # OpenGL camera looks down -z: -z axis points from the camera to the origin
    fwd = -gl[:3, 2]
    assert np.allclose(fwd, -c2w[:3, 3] / np.linalg.norm(c2w[:3, 3]))
    assert gl[2, 1] > 0, "camera +y is up in OpenGL"
    assert math.isclose(d["camera_angle_x"], 2 * math.atan(32 / 100))


def test_nerf_synthetic_style_transforms(tmp_path):
    d = {"camera_angle_x": 0.6911112070083618, "w": 800, "h": 800,
         "frames": [{"file_path": "./train/r_0", "transform_matrix": np.eye(4).tolist()}]}
    (tmp_path / "t.json").write_text(json.dumps(d))
    fr = F.read_transforms(tmp_path / "t.json")[0]
    assert math.isclose(fr.intrinsics.fx, 400 / math.tan(0.6911112070083618 / 2))
    assert (fr.intrinsics.cx, fr.intrinsics.cy) == (400, 400)


def test_srgb_transfer():
    x = np.linspace(0, 1, 101)
    assert np.allclose(F.srgb_to_linear(F.linear_to_srgb(x)), x, atol=1e-12)
    assert math.isclose(float(F.linear_to_srgb(0.18)), 0.4613561, rel_tol=1e-6)  # mid grey


@pytest.mark.parametrize("rig", ["sphere", "hemisphere", "spiral", "turntable"])
def test_rigs_look_at_origin_from_radius(rig):
    poses = rigs.rig_poses(rig, 50, 2.5, seed=4)
    assert len(poses) == 50
    for p in poses:
        assert math.isclose(np.linalg.norm(p[:3, 3]), 2.5, rel_tol=1e-9)
        assert np.allclose(p[:3, 2], -p[:3, 3] / 2.5, atol=1e-9)  # optical axis at the origin
        assert math.isclose(np.linalg.det(p[:3, :3]), 1.0, rel_tol=1e-9)
    z = np.array([p[2, 3] for p in poses])
    if rig in ("hemisphere", "spiral"):
        assert (z >= -1e-9).all()
    if rig == "sphere":
        assert (z < 0).any() and (z > 0).any()
    if rig == "turntable":
        assert np.allclose(z, 2.5 * math.sin(math.radians(20)))


def test_rigs_are_seeded_and_spiral_climbs():
    a, b = rigs.rig_poses("sphere", 10, 1.0, seed=1), rigs.rig_poses("sphere", 10, 1.0, seed=1)
    c = rigs.rig_poses("sphere", 10, 1.0, seed=2)
    assert all(np.array_equal(x, y) for x, y in zip(a, b)) and not np.allclose(a[0], c[0])
    z = [p[2, 3] for p in rigs.rig_poses("spiral", 40, 1.0)]
    assert z[0] == pytest.approx(0.0, abs=1e-9) and all(np.diff(z) > 0)


def test_framing_fills_the_frame():
    r, fov = 0.5, math.radians(40)
    d = rigs.framing_distance(r, fov, margin=1.0)
    # the bounding sphere is tangent to the frustum: its angular radius equals half the fov
    assert math.isclose(math.asin(r / d), fov / 2)
    near, far = rigs.near_far(rigs.rig_poses("sphere", 5, d), r)
    assert math.isclose(near, d - r) and math.isclose(far, d + r)
    with pytest.raises(InputError):
        rigs.rig_poses("cube", 3, 1.0)
    with pytest.raises(InputError):
        rigs.rig_poses("sphere", 0, 1.0)


def test_read_object_capture_layout_with_per_view_intrinsics(tmp_path):
    """A recovered capture has rgb + pose only and per-frame intrinsics in transforms.json."""
    obj = tmp_path / "cap"
    ks = [C.Intrinsics(50.0 + k, 50.0 + k, 16.0, 12.0, 32, 24) for k in range(3)]
    poses = [C.look_at_opencv((2.0, k - 1.0, 1.0)) for k in range(3)]
    frames = []
    for k in range(3):
        F.write_png(obj / "rgb" / f"{k:06d}.png", np.full((24, 32, 3), 40 * k, np.uint8))
        F.write_srn_pose(obj / "pose" / f"{k:06d}.txt", poses[k])
        frames.append({"file_path": f"rgb/{k:06d}.png", "c2w_opencv": poses[k], "fl_x": ks[k].fx, "fl_y": ks[k].fy,
                       "cx": ks[k].cx, "cy": ks[k].cy})
    F.atomic_write_json(obj / "transforms.json", F.transforms_dict(ks[0], frames))
    F.atomic_write_json(obj / "meta.json", {"category": "capture"})
    ov = F.read_object(obj)
    assert ov.indices == [0, 1, 2] and ov.intrinsics_per_view == ks
    assert ov.has("rgb") and not ov.has("depth")
    assert all(np.allclose(a, b) for a, b in zip(ov.c2w_opencv, poses))
    assert ov.rgb(2)[0, 0, 0] == 80
