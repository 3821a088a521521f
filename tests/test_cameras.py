"""geometry/cameras.py: conventions, round trips and errors (no Blender needed)."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from blender_mrvm.errors import CameraConventionError
from blender_mrvm.geometry import cameras as C


def random_rotation(rng):
    q = rng.normal(size=4)
    return C.qvec_to_rotmat(q)


def random_pose(rng, scale=3.0):
    p = np.eye(4)
    p[:3, :3] = random_rotation(rng)
    p[:3, 3] = rng.normal(size=3) * scale
    return p


def test_flip_is_involution_and_axes():
    rng = np.random.default_rng(0)
    p = random_pose(rng)
    assert np.allclose(C.blender_from_opencv(C.opencv_from_blender(p)), p)
    # A Blender camera looks down its -z; the OpenCV camera of the same pose looks down +z.
    cv = C.opencv_from_blender(p)
    assert np.allclose(cv[:3, 2], -p[:3, 2])
    assert np.allclose(cv[:3, 1], -p[:3, 1])
    assert np.allclose(cv[:3, 0], p[:3, 0])


@given(st.integers(0, 10_000))
@settings(max_examples=60, deadline=None)
def test_colmap_round_trip(seed):
    rng = np.random.default_rng(seed)
    p = random_pose(rng)
    q, t = C.colmap_from_c2w_opencv(p)
    assert q[0] >= 0 and abs(np.linalg.norm(q) - 1) < 1e-12
    assert np.allclose(C.c2w_opencv_from_colmap(q, t), p, atol=1e-10)


def test_quaternion_near_180_degrees():
    r = np.diag([1.0, -1.0, -1.0])  # 180 deg about x: w = 0
    q = C.rotmat_to_qvec(r)
    assert np.allclose(np.abs(q), [0, 1, 0, 0])
    assert np.allclose(C.qvec_to_rotmat(q), r)


def test_look_at_points_camera_at_target_and_handles_poles():
    for eye in [(3, 0, 0), (0, 0, 5), (0, 0, -2), (1, 2, 3)]:
        c2w = C.look_at_opencv(eye)
        assert np.isclose(np.linalg.det(c2w[:3, :3]), 1.0)
        uv, z = C.project(np.eye(3), C.invert_pose(c2w), np.zeros((1, 3)))
        assert np.allclose(uv, 0, atol=1e-12) and z[0] > 0
    # image "down" points to world -z for a camera on the equator (world z up)
    c2w = C.look_at_opencv((3, 0, 0))
    assert c2w[2, 1] < -0.99
    with pytest.raises(CameraConventionError):
        C.look_at_opencv((0, 0, 0))


def test_unshifted_blender_camera_centre_is_half_resolution():
    k = C.intrinsics_from_blender(C.BlenderCamera(lens=50, resolution_x=640, resolution_y=480))
    assert (k.cx, k.cy) == (320.0, 240.0)
    assert math.isclose(k.fx, 50 / 36 * 640) and k.fx == k.fy


def test_sensor_fit_auto_portrait_uses_sensor_width_on_height():
    # AUTO fit with a portrait image: the sensor width spans the (longer) vertical side.
    k = C.intrinsics_from_blender(C.BlenderCamera(lens=50, resolution_x=480, resolution_y=640))
    assert math.isclose(k.fy, 50 / 36 * 640)
    k = C.intrinsics_from_blender(C.BlenderCamera(lens=50, sensor_fit="VERTICAL", sensor_height=24,
                                                  resolution_x=640, resolution_y=480))
    assert math.isclose(k.fy, 50 / 24 * 480)


@given(
    lens=st.floats(5, 300), sw=st.floats(5, 60), sh=st.floats(5, 60),
    fit=st.sampled_from(["AUTO", "HORIZONTAL", "VERTICAL"]),
    sx=st.floats(-1, 1), sy=st.floats(-1, 1),
    w=st.integers(1, 4096), h=st.integers(1, 4096),
    ax=st.floats(1, 4), ay=st.floats(1, 4),
)
@settings(max_examples=200, deadline=None)
def test_blender_intrinsics_round_trip(lens, sw, sh, fit, sx, sy, w, h, ax, ay):
    cam = C.BlenderCamera(lens, sw, sh, fit, sx, sy, w, h, ax, ay)
    k = C.intrinsics_from_blender(cam)
    back = C.blender_from_intrinsics(k)
    k2 = C.intrinsics_from_blender(back)
    for a, b in [(k.fx, k2.fx), (k.fy, k2.fy), (k.cx, k2.cx), (k.cy, k2.cy)]:
        assert math.isclose(a, b, rel_tol=1e-9, abs_tol=1e-9)
    assert (k2.width, k2.height) == (w, h)
    # non-square pixels: fx / fy equals the pixel aspect ratio ay / ax
    assert math.isclose(k.fx / k.fy, ay / ax, rel_tol=1e-9)


def test_blender_cannot_express():
    good = C.Intrinsics(100, 100, 32, 32, 64, 64)
    C.blender_from_intrinsics(good)
    with pytest.raises(CameraConventionError, match="skew"):
        C.blender_from_intrinsics(C.Intrinsics(100, 100, 32, 32, 64, 64, skew=2.0))
    with pytest.raises(CameraConventionError, match="positive"):
        C.blender_from_intrinsics(C.Intrinsics(-100, 100, 32, 32, 64, 64))
    with pytest.raises(CameraConventionError, match="pixel aspect"):
        C.blender_from_intrinsics(C.Intrinsics(100, 0.1, 32, 32, 64, 64))
    with pytest.raises(CameraConventionError, match="off-centre"):
        C.blender_from_intrinsics(C.Intrinsics(100, 100, 32 + 64 * 11, 32, 64, 64))
    # a 170-degree field of view is expressible: the sensor grows instead of the lens going under 1 mm
    wide = C.intrinsics_from_fov(math.radians(170), 64, 64)
    bc = C.blender_from_intrinsics(wide, sensor_width=1.0)
    assert bc.lens >= 1.0 and math.isclose(C.intrinsics_from_blender(bc).fx, wide.fx)


def test_rays_go_through_pixel_centres():
    k = C.Intrinsics(80.0, 90.0, 31.0, 17.5, 64, 40)
    rng = np.random.default_rng(3)
    c2w = random_pose(rng)
    o, d = C.rays_opencv(k, c2w, normalize=False)
    pts = o + 2.5 * d
    uv, z = C.project(k.K, C.invert_pose(c2w), pts.reshape(-1, 3))
    assert np.allclose(z, 2.5)
    assert np.allclose(uv, C.pixel_centers(64, 40).reshape(-1, 2), atol=1e-9)
    assert np.allclose(C.pixel_centers(64, 40)[0, 0], [0.5, 0.5])


def test_scaled_intrinsics_keep_pixel_centre_convention():
    k = C.Intrinsics(100, 100, 64, 48, 128, 96)
    k2 = k.scaled(0.5)
    assert (k2.cx, k2.cy, k2.width, k2.height) == (32, 24, 64, 48)


def test_inverse_3x3_is_the_inverse_without_lapack():
    """``cameras.inverse_3x3`` (the pose inverse's 3x3 part by its adjugate; ``np.linalg.inv`` cost ~1.5 ms a call
    on a busy machine): the same as LAPACK's inverse for rotations, similarities and general matrices, the pose
    inverse undoes the pose, and a singular matrix is refused by name."""
    rng = np.random.default_rng(0)
    for _ in range(200):
        q, _r = np.linalg.qr(rng.normal(size=(3, 3)))
        for a in (q, q * rng.uniform(1e-3, 1e3), rng.normal(size=(3, 3))):
            inv = np.linalg.inv(a)
            np.testing.assert_allclose(C.inverse_3x3(a), inv, rtol=1e-8, atol=1e-10 * np.abs(inv).max())
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = q * 2.5, rng.normal(size=3)
    np.testing.assert_allclose(C.invert_pose(pose) @ pose, np.eye(4), atol=1e-12)
    with pytest.raises(C.CameraConventionError, match="singular"):
        C.inverse_3x3(np.array([[1.0, 2, 3], [2, 4, 6], [0, 0, 1]]))
