"""The one owner of camera conventions. Nothing else in the project flips axes.

Frames (camera axes):

======================  ==============================  =====================================
name                    axes                            where
======================  ==============================  =====================================
Blender                 x right, y up, looks down -z    ``Object.matrix_world`` (world z up)
OpenGL / NeRF           same as Blender                 ``transforms.json`` ``transform_matrix``
OpenCV                  x right, y down, looks down +z  SRN ``pose/*.txt`` (camera-to-world),
                                                        COLMAP (world-to-camera), ``K``
======================  ==============================  =====================================

All poses are 4x4 ``float64`` numpy arrays; ``c2w`` maps camera coordinates to world coordinates.
The world frame is the same everywhere (Blender's, z up); only camera axes differ.

Pixel coordinates follow COLMAP and SRN: the centre of the top-left pixel is (0.5, 0.5), so an
unshifted Blender camera has ``cx = W/2, cy = H/2`` and the ray through pixel (i, j) (column i,
row j) passes through (i + 0.5, j + 0.5).

Intrinsics <-> Blender camera follows Blender's own ``BKE_camera_params_compute_viewplane``:
sensor fit (AUTO / HORIZONTAL / VERTICAL), lens shift (in units of the fitted image side) and
non-square pixels (``pixel_aspect_x/y``). What Blender cannot express (skew, non-positive focal,
pixel aspect or shift out of Blender's range) raises :class:`CameraConventionError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..errors import CameraConventionError

# Flips camera y and z: OpenGL/Blender camera axes <-> OpenCV camera axes (its own inverse).
_FLIP_YZ = np.diag([1.0, -1.0, -1.0, 1.0])

BLENDER_PIXEL_ASPECT_MAX = 200.0
BLENDER_SHIFT_MAX = 10.0
BLENDER_LENS_MIN = 1.0  # mm


# --------------------------------------------------------------------------------------------
# Poses
# --------------------------------------------------------------------------------------------

def as_pose(m) -> np.ndarray:
    """Return ``m`` as a 4x4 float64 array (accepts 3x4, 4x4 and mathutils matrices)."""
    a = np.asarray([list(row) for row in m] if not isinstance(m, np.ndarray) else m, dtype=np.float64)
    if a.shape == (3, 4):
        a = np.vstack([a, [0.0, 0.0, 0.0, 1.0]])
    if a.shape != (4, 4):
        raise CameraConventionError(f"a pose must be 4x4 or 3x4, got shape {a.shape}")
    return a


def inverse_3x3(r: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by its adjugate (no LAPACK call: ``np.linalg.inv`` took ~1.5 ms a call while other
    processes kept the cores busy, most of the 130 ms of drawing a 32-object training step, 31 ms with this;
    session 32). A singular matrix raises :class:`CameraConventionError`."""
    a = np.asarray(r, np.float64)
    adj = np.cross(a[[1, 2, 0]], a[[2, 0, 1]]).T  # columns: cross products of row pairs = adjugate
    det = float(a[0] @ adj[:, 0])
    if not np.isfinite(det) or abs(det) < 1e-300:
        raise CameraConventionError(f"a pose's 3x3 part is singular (determinant {det:g})")
    return adj / det


def invert_pose(m: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (or similarity) 4x4 transform."""
    m = as_pose(m)
    r, t = m[:3, :3], m[:3, 3]
    rinv = inverse_3x3(r)
    out = np.eye(4)
    out[:3, :3] = rinv
    out[:3, 3] = -rinv @ t
    return out


def opencv_from_blender(c2w_blender: np.ndarray) -> np.ndarray:
    """Camera-to-world: Blender/OpenGL camera axes -> OpenCV camera axes (same world)."""
    return as_pose(c2w_blender) @ _FLIP_YZ


def blender_from_opencv(c2w_opencv: np.ndarray) -> np.ndarray:
    """Camera-to-world: OpenCV camera axes -> Blender/OpenGL camera axes (same world)."""
    return as_pose(c2w_opencv) @ _FLIP_YZ


def blender_from_opencv_camera_points(pts: np.ndarray) -> np.ndarray:
    """Points in OpenCV camera coordinates (..., 3) -> the same points in Blender camera coordinates."""
    return np.asarray(pts, dtype=np.float64) @ _FLIP_YZ[:3, :3]


# OpenGL/NeRF camera axes are Blender's: the names say which file format a pose is for.
opengl_from_opencv = blender_from_opencv
opencv_from_opengl = opencv_from_blender


SHEAR_TOLERANCE = 1e-4
"""Largest cosine between two axes of a camera matrix taken as perpendicular (float32 matrices of rotated,
scaled cameras reach about 1e-7)."""


def remove_scale(c2w: np.ndarray) -> np.ndarray:
    """Orthonormalize the rotation of a camera matrix (Blender objects may carry scale); a mirrored matrix, or a
    sheared one (a camera under a parent scaled unevenly and rotated: Blender renders its axes as they are, skewed,
    which no pinhole pose and intrinsics can express), raises :class:`CameraConventionError`."""
    c2w = as_pose(c2w).copy()
    axes = c2w[:3, :3] / np.maximum(np.linalg.norm(c2w[:3, :3], axis=0), 1e-300)
    cos = np.abs(axes.T @ axes - np.eye(3)).max()
    if cos > SHEAR_TOLERANCE:
        raise CameraConventionError(
            f"camera matrix is sheared (its axes are {np.degrees(np.arcsin(min(cos, 1.0))):.2g} degrees off "
            "perpendicular: a parent scaled unevenly and rotated), which Blender renders skewed and no camera pose "
            "can express; give the camera a parent with uniform scale, or apply the parent's scale")
    u, _, vt = np.linalg.svd(c2w[:3, :3])
    r = u @ vt
    if np.linalg.det(r) < 0:
        raise CameraConventionError("camera matrix is mirrored (negative scale); cameras must be proper rotations")
    c2w[:3, :3] = r
    return c2w


def rotmat_to_qvec(r: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion (w, x, y, z), COLMAP's order, with w >= 0."""
    r = np.asarray(r, dtype=np.float64)
    # Shepperd's method via the symmetric 4x4 matrix (robust for all rotations).
    k = np.array([
        [r[0, 0] - r[1, 1] - r[2, 2], r[1, 0] + r[0, 1], r[2, 0] + r[0, 2], r[2, 1] - r[1, 2]],
        [r[1, 0] + r[0, 1], r[1, 1] - r[0, 0] - r[2, 2], r[2, 1] + r[1, 2], r[0, 2] - r[2, 0]],
        [r[2, 0] + r[0, 2], r[2, 1] + r[1, 2], r[2, 2] - r[0, 0] - r[1, 1], r[1, 0] - r[0, 1]],
        [r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1], r[0, 0] + r[1, 1] + r[2, 2]],
    ]) / 3.0
    w, v = np.linalg.eigh(k)
    q = v[[3, 0, 1, 2], np.argmax(w)]
    return q if q[0] >= 0 else -q


def qvec_to_rotmat(q) -> np.ndarray:
    """Quaternion (w, x, y, z) -> rotation matrix (normalizes q)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def colmap_from_c2w_opencv(c2w_opencv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV camera-to-world -> COLMAP world-to-camera (qvec wxyz, tvec)."""
    w2c = invert_pose(c2w_opencv)
    return rotmat_to_qvec(w2c[:3, :3]), w2c[:3, 3].copy()


def c2w_opencv_from_colmap(qvec, tvec) -> np.ndarray:
    """COLMAP world-to-camera (qvec wxyz, tvec) -> OpenCV camera-to-world."""
    w2c = np.eye(4)
    w2c[:3, :3] = qvec_to_rotmat(qvec)
    w2c[:3, 3] = np.asarray(tvec, dtype=np.float64)
    return invert_pose(w2c)


def c2w_opencv_from_w2c(w2c) -> np.ndarray:
    """A 3x4 or 4x4 world-to-camera matrix (OpenCV axes, as pycolmap's ``cam_from_world``) -> c2w."""
    return invert_pose(as_pose(w2c))


def look_at_opencv(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """OpenCV camera-to-world for a camera at ``eye`` looking at ``target`` with world ``up``.

    When the viewing direction is (anti)parallel to ``up`` (a camera at a pole), the image "up" is
    taken from the world y axis instead, so the result is always a proper rotation.
    """
    eye = np.asarray(eye, dtype=np.float64)
    fwd = np.asarray(target, dtype=np.float64) - eye
    n = np.linalg.norm(fwd)
    if n == 0:
        raise CameraConventionError("camera position equals its target; the view direction is undefined")
    fwd /= n
    up = np.asarray(up, dtype=np.float64)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9 * max(1.0, np.linalg.norm(up)):
        right = np.cross(fwd, np.array([0.0, 1.0, 0.0]))
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
    return c2w


# --------------------------------------------------------------------------------------------
# Intrinsics
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels, pixel-centre convention (top-left pixel centre = 0.5, 0.5)."""

    fx: float
    """Focal length along image x, pixels."""
    fy: float
    """Focal length along image y, pixels."""
    cx: float
    """Principal point x, pixels from the image's left edge."""
    cy: float
    """Principal point y, pixels from the image's top edge."""
    width: int
    """Image width, pixels."""
    height: int
    """Image height, pixels."""
    skew: float = 0.0
    """K[0, 1]; Blender cannot express a non-zero skew."""

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_K(cls, K, width: int, height: int) -> "Intrinsics":
        K = np.asarray(K, dtype=np.float64)
        if K.shape != (3, 3) or not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise CameraConventionError(f"not a pinhole intrinsic matrix: {K.tolist()}")
        return cls(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), int(width), int(height),
                   float(K[0, 1]))

    @property
    def fov_x(self) -> float:
        """Horizontal field of view in radians (for an unshifted camera)."""
        return 2.0 * math.atan(self.width / (2.0 * self.fx))

    @property
    def fov_y(self) -> float:
        return 2.0 * math.atan(self.height / (2.0 * self.fy))

    def scaled(self, factor: float) -> "Intrinsics":
        """Intrinsics of the same camera at ``factor`` times the resolution (pixel-centre exact)."""
        return self.resized(round(self.width * factor), round(self.height * factor))

    def resized(self, width: int, height: int) -> "Intrinsics":
        """The same camera at ``width`` x ``height`` pixels: every pixel coordinate scales with the size
        (pixel-centre exact; x and y scale separately, so a changed aspect ratio stretches the image)."""
        w, h = int(width), int(height)
        if w < 1 or h < 1:
            raise CameraConventionError(f"image size must be positive, got {w}x{h}")
        if (w, h) == (self.width, self.height):
            return self
        sx, sy = w / self.width, h / self.height
        return replace(self, fx=self.fx * sx, fy=self.fy * sy, cx=self.cx * sx, cy=self.cy * sy,
                       skew=self.skew * sx, width=w, height=h)


@dataclass(frozen=True)
class BlenderCamera:
    """The Blender camera + render settings that determine intrinsics (a perspective camera)."""

    lens: float
    """Focal length, mm (``Camera.lens``)."""
    sensor_width: float = 36.0
    """``Camera.sensor_width``, mm."""
    sensor_height: float = 24.0
    """``Camera.sensor_height``, mm (used only with sensor_fit VERTICAL)."""
    sensor_fit: str = "AUTO"
    """``Camera.sensor_fit``: AUTO, HORIZONTAL or VERTICAL."""
    shift_x: float = 0.0
    """``Camera.shift_x``, in units of the fitted image side."""
    shift_y: float = 0.0
    """``Camera.shift_y``."""
    resolution_x: int = 128
    """Effective render width (resolution_x * percentage / 100)."""
    resolution_y: int = 128
    """Effective render height."""
    pixel_aspect_x: float = 1.0
    """``RenderSettings.pixel_aspect_x`` (>= 1)."""
    pixel_aspect_y: float = 1.0
    """``RenderSettings.pixel_aspect_y`` (>= 1)."""


def _fit_and_viewfac(cam: BlenderCamera) -> tuple[str, float, float, float]:
    """Blender's sensor fit resolution: (fit, sensor_size_mm, viewfac, ycor)."""
    w, h = cam.resolution_x, cam.resolution_y
    ax, ay = cam.pixel_aspect_x, cam.pixel_aspect_y
    ycor = ay / ax
    if cam.sensor_fit not in ("AUTO", "HORIZONTAL", "VERTICAL"):
        raise CameraConventionError(f"unknown sensor fit {cam.sensor_fit!r}")
    # BKE_camera_sensor_size: VERTICAL uses sensor_height, AUTO and HORIZONTAL sensor_width.
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    fit = cam.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if ax * w >= ay * h else "VERTICAL"
    viewfac = float(w) if fit == "HORIZONTAL" else ycor * h
    return fit, sensor, viewfac, ycor


def intrinsics_from_blender(cam: BlenderCamera) -> Intrinsics:
    """Pixel intrinsics of a Blender perspective camera (exactly as Blender projects)."""
    if cam.lens <= 0 or cam.resolution_x <= 0 or cam.resolution_y <= 0:
        raise CameraConventionError("lens and resolution must be positive")
    _, sensor, viewfac, ycor = _fit_and_viewfac(cam)
    fx = cam.lens / sensor * viewfac
    fy = fx / ycor
    cx = cam.resolution_x / 2.0 - cam.shift_x * viewfac
    cy = cam.resolution_y / 2.0 + cam.shift_y * viewfac / ycor
    return Intrinsics(fx, fy, cx, cy, cam.resolution_x, cam.resolution_y)


def blender_from_intrinsics(intr: Intrinsics, sensor_width: float = 36.0, tol: float = 1e-9) -> BlenderCamera:
    """The Blender camera (sensor fit to the longer side) that projects exactly like ``intr``.

    Raises :class:`CameraConventionError` for what Blender cannot express: skew, non-positive
    focal lengths or sizes, a pixel aspect above 200, a shift beyond +-10 or a lens under 1 mm.
    """
    if abs(intr.skew) > tol * max(abs(intr.fx), 1.0):
        raise CameraConventionError(f"Blender cameras have no skew (K[0,1] = {intr.skew:g})")
    if not (intr.fx > 0 and intr.fy > 0):
        raise CameraConventionError(f"focal lengths must be positive (fx={intr.fx:g}, fy={intr.fy:g})")
    if intr.width <= 0 or intr.height <= 0:
        raise CameraConventionError(f"image size must be positive ({intr.width}x{intr.height})")
    if sensor_width <= 0:
        raise CameraConventionError("sensor width must be positive")
    ycor = intr.fx / intr.fy  # = pixel_aspect_y / pixel_aspect_x
    if ycor >= 1.0:
        ax, ay = 1.0, ycor
    else:
        ax, ay = 1.0 / ycor, 1.0
    if max(ax, ay) > BLENDER_PIXEL_ASPECT_MAX:
        raise CameraConventionError(f"pixel aspect {max(ax, ay):g} exceeds Blender's limit of {BLENDER_PIXEL_ASPECT_MAX:g}")
    # Fit the sensor to the longer (aspect-corrected) side, as Blender's AUTO does, so shifts stay
    # in units of the longer side; the sensor size is the same mm value on either side.
    horizontal = ax * intr.width >= ay * intr.height
    viewfac = float(intr.width) if horizontal else ycor * intr.height
    lens = intr.fx * sensor_width / viewfac
    shift_x = (intr.width / 2.0 - intr.cx) / viewfac
    shift_y = (intr.cy - intr.height / 2.0) * ycor / viewfac
    if abs(shift_x) > BLENDER_SHIFT_MAX or abs(shift_y) > BLENDER_SHIFT_MAX:
        raise CameraConventionError(f"principal point too far off-centre for Blender (shift {shift_x:g}, {shift_y:g})")
    if lens < BLENDER_LENS_MIN:
        # Very wide fields of view: only lens / sensor matters, so grow the sensor instead.
        sensor_width *= BLENDER_LENS_MIN / lens
        lens = BLENDER_LENS_MIN
    return BlenderCamera(lens=lens, sensor_width=sensor_width, sensor_height=sensor_width,
                         sensor_fit="HORIZONTAL" if horizontal else "VERTICAL", shift_x=shift_x, shift_y=shift_y,
                         resolution_x=int(intr.width), resolution_y=int(intr.height),
                         pixel_aspect_x=ax, pixel_aspect_y=ay)


def intrinsics_from_fov(fov_x: float, width: int, height: int) -> Intrinsics:
    """Square-pixel, centred intrinsics with horizontal field of view ``fov_x`` (radians)."""
    f = width / (2.0 * math.tan(fov_x / 2.0))
    return Intrinsics(f, f, width / 2.0, height / 2.0, width, height)


# --------------------------------------------------------------------------------------------
# Projection and rays
# --------------------------------------------------------------------------------------------

def project(K: np.ndarray, w2c_opencv: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (N, 3) -> pixels (N, 2) and camera depth z (N,) (OpenCV axes)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cam = pts @ w2c_opencv[:3, :3].T + w2c_opencv[:3, 3]
    z = cam[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uvw = cam @ np.asarray(K, dtype=np.float64).T
        uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, z


def pixel_centers(width: int, height: int) -> np.ndarray:
    """(H, W, 2) pixel-centre coordinates (i + 0.5, j + 0.5)."""
    i, j = np.meshgrid(np.arange(width, dtype=np.float64) + 0.5, np.arange(height, dtype=np.float64) + 0.5)
    return np.stack([i, j], axis=-1)


def camera_up(c2w_opencv: np.ndarray) -> np.ndarray:
    """The world-space up vector of an OpenCV camera (its image's up: minus the camera's y axis)."""
    return -as_pose(c2w_opencv)[:3, 1].copy()


def rays_opencv(intr: Intrinsics, c2w_opencv: np.ndarray, pixels: np.ndarray | None = None,
                normalize: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """World-space ray origins and directions through ``pixels`` (default: every pixel centre).

    With ``normalize=False`` the direction has unit z in camera space, so ``origin + z * dir`` is the
    point at planar depth z (what a z-depth map stores).

    ``pixels`` may also be a float64 torch tensor (on any device): the rays are then torch tensors on its
    device, by the same arithmetic (a GPU view makes its rays where it renders them).
    """
    c2w = as_pose(c2w_opencv)
    if pixels is not None and not isinstance(pixels, np.ndarray) and hasattr(pixels, "device"):
        import torch

        px = pixels.to(torch.float64)
        rot = torch.as_tensor(c2w[:3, :3], device=px.device)
        xp = torch
    else:
        px = pixel_centers(intr.width, intr.height) if pixels is None else np.asarray(pixels, dtype=np.float64)
        rot, xp = c2w[:3, :3], np
    u, v = px[..., 0], px[..., 1]
    y = (v - intr.cy) / intr.fy
    x = (u - intr.cx - intr.skew * y) / intr.fx
    d_cam = xp.stack([x, y, xp.ones_like(x)], -1)
    d = d_cam @ rot.T
    if normalize:
        d = d / xp.linalg.norm(d, axis=-1, keepdims=True) if xp is np else d / d.norm(dim=-1, keepdim=True)
    if xp is np:
        return np.broadcast_to(c2w[:3, 3], d.shape).copy(), d
    return torch.as_tensor(c2w[:3, 3], device=d.device).expand(d.shape).clone(), d


def axis_cosines(intr: Intrinsics, pixels: np.ndarray | None = None) -> np.ndarray:
    """The cosine between the ray through each of ``pixels`` (default: every pixel centre, (H, W)) and the
    optical axis: planar z-depth = distance along the ray x this (the conversion between depth maps and the
    models' distances along their rays)."""
    _, d = rays_opencv(intr, np.eye(4), pixels)
    return d[..., 2]


def ray_distances(z: np.ndarray, intr: Intrinsics) -> np.ndarray:
    """A planar z-depth map (H, W) as distances along each pixel's ray; 0 where it sees no surface (z <= 0)."""
    z = np.asarray(z, np.float64)
    return np.where(z > 0, z / axis_cosines(intr), 0.0)


def unproject_depth(intr: Intrinsics, c2w_opencv: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """World points (H, W, 3) from a planar z-depth map (H, W)."""
    o, d = rays_opencv(intr, c2w_opencv, normalize=False)
    return o + d * np.asarray(depth, dtype=np.float64)[..., None]
