"""Similarity alignment and automatic orientation / scale of recovered cameras (numpy only).

Poses here are OpenCV camera-to-world 4x4 matrices (``geometry.cameras`` convention); a
similarity ``(s, R, t)`` maps world points ``x -> s R x + t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (s, R, t) with ``dst ~ s R src + t`` (Umeyama 1991). src, dst: (N, 3)."""
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise InputError(f"umeyama needs two (N>=3, 3) point sets of one shape, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    e = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        e[2, 2] = -1.0
    r = u @ e @ vt
    var_s = (xs ** 2).sum() / len(src)
    s = float(np.trace(np.diag(d) @ e) / var_s) if with_scale else 1.0
    t = mu_d - s * r @ mu_s
    return s, r, t


def rotation_angle_deg(r: np.ndarray) -> float:
    """Angle of a rotation matrix, degrees."""
    c = (np.trace(r) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def apply_similarity_to_pose(c2w: np.ndarray, s: float, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The camera-to-world pose after the world moves by x -> s R x + t (rotation stays orthonormal)."""
    out = np.eye(4)
    out[:3, :3] = r @ c2w[:3, :3]
    out[:3, 3] = s * r @ c2w[:3, 3] + t
    return out


@dataclass(frozen=True)
class PoseErrors:
    """Errors of estimated cameras against the truth after a similarity alignment of their centres."""

    rotation_deg: np.ndarray
    """Per camera: angle between the aligned estimated and the true orientation, degrees."""
    centre: np.ndarray
    """Per camera: distance between the aligned estimated and the true centre (truth's units)."""
    scale: float
    """Scale of the alignment (truth units per estimated unit)."""

    @property
    def median_rotation_deg(self) -> float:
        return float(np.median(self.rotation_deg))

    @property
    def median_centre(self) -> float:
        return float(np.median(self.centre))


def pose_errors(est_c2w: list[np.ndarray], true_c2w: list[np.ndarray]) -> PoseErrors:
    """Align estimated camera centres to the true ones (Umeyama) and measure the residual errors."""
    est = np.array([np.asarray(p)[:3, 3] for p in est_c2w])
    tru = np.array([np.asarray(p)[:3, 3] for p in true_c2w])
    s, r, t = umeyama(est, tru)
    rot, cen = [], []
    for pe, pt in zip(est_c2w, true_c2w):
        a = apply_similarity_to_pose(np.asarray(pe), s, r, t)
        rot.append(rotation_angle_deg(np.asarray(pt)[:3, :3].T @ a[:3, :3]))
        cen.append(float(np.linalg.norm(a[:3, 3] - np.asarray(pt)[:3, 3])))
    return PoseErrors(np.array(rot), np.array(cen), s)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` to unit vector ``b``."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: rotate pi about any axis orthogonal to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


@dataclass(frozen=True)
class Normalization:
    """The similarity x -> scale * rotation @ (x - centre) applied to the recovered world."""

    rotation: np.ndarray
    """3x3: takes the cameras' mean up vector to +z (Blender's up)."""
    centre: np.ndarray
    """The object of interest's centre in the COLMAP world."""
    scale: float
    """1 / radius of the object of interest, so it fits the unit sphere."""
    method: str
    """How the centre was found: 'optical-axes' (object-centric) or 'points' (forward-facing)."""

    def s_r_t(self) -> tuple[float, np.ndarray, np.ndarray]:
        return self.scale, self.rotation, -self.scale * self.rotation @ self.centre

    def to_json(self) -> dict:
        return {"rotation": self.rotation.tolist(), "centre": self.centre.tolist(), "scale": self.scale,
                "method": self.method, "maps": "x_out = scale * rotation @ (x_colmap - centre)"}


def auto_normalization(c2w: list[np.ndarray], points: np.ndarray,
                       ups_cam: list[np.ndarray] | None = None) -> Normalization:
    """Up from the cameras' up vectors; centre where the optical axes meet; radius from the points.

    - up: the mean of the cameras' up vectors (-y of OpenCV cameras, or ``ups_cam``, each photo's up in its
      camera's axes: a phone held upright stores a portrait photo turned, with an EXIF orientation saying so,
      :func:`capture.sfm.photo_ups`) goes to +z. Photos are taken mostly upright, so this is the gravity
      direction to within a few degrees.
    - centre: the least-squares point nearest to all optical axes (the object the photographer
      circled). When the axes are near parallel (a forward-facing capture, a stereo pair) the
      system is ill-conditioned and the median of the sparse points is used instead.
    - radius: the 90th percentile of the distances from the centre of the points that lie within
      0.6 x the median camera distance (the object, not the background); with fewer than 10 such
      points, half the median camera distance.
    """
    c2w = [np.asarray(p, dtype=np.float64) for p in c2w]
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    ups = np.array([-p[:3, 1] for p in c2w] if ups_cam is None else
                   [p[:3, :3] @ np.asarray(u, dtype=np.float64) for p, u in zip(c2w, ups_cam)])
    up = ups.sum(0)
    if np.linalg.norm(up) < 1e-9:
        up = np.array([0.0, 0.0, 1.0])
    rot = rotation_between(up, np.array([0.0, 0.0, 1.0]))
    centres = np.array([p[:3, 3] for p in c2w])
    dirs = np.array([p[:3, 2] for p in c2w])
    a = np.zeros((3, 3))
    b = np.zeros(3)
    for c, d in zip(centres, dirs):
        m = np.eye(3) - np.outer(d, d)
        a += m
        b += m @ c
    ev = np.linalg.eigvalsh(a)
    method = "optical-axes"
    centre = None
    if ev[0] > 0.05 * ev[-1]:
        centre = np.linalg.solve(a, b)
        # The meeting point must lie in front of most cameras, else it is not an object of interest.
        if np.mean(np.einsum("ij,ij->i", centre - centres, dirs) > 0) < 0.5:
            centre = None
    if centre is None:
        method = "points"
        centre = np.median(pts, axis=0) if len(pts) else centres.mean(0) + dirs.mean(0)
    cam_dist = np.median(np.linalg.norm(centres - centre, axis=1))
    if cam_dist <= 0:
        cam_dist = 1.0
    dist = np.linalg.norm(pts - centre, axis=1) if len(pts) else np.zeros(0)
    near = dist[dist < 0.6 * cam_dist]
    radius = float(np.percentile(near, 90)) if len(near) >= 10 else 0.5 * cam_dist
    radius = max(radius, 1e-6)
    return Normalization(rot, centre, 1.0 / radius, method)


def scene_box(points: np.ndarray, c2w: list[np.ndarray] | None = None, percentile: float = 2.0,
              margin: float = 0.1) -> tuple[np.ndarray, np.ndarray, str]:
    """(min xyz, max xyz, how) of the scene the sparse points show, robust to outliers.

    Per axis, the ``percentile``-th and (100 - ``percentile``)-th percentiles of the points, grown by
    ``margin`` times the box's extent on each side (a few stray triangulations far away move a
    percentile by at most their share of the points, so they cannot blow the box up). An axis the points
    hardly span (a flat wall) is given a tenth of the largest extent. With fewer than 10 points: a cube
    around the cameras' centroid, half-size the largest camera distance from it (or the unit cube).
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(1)]
    if len(pts) >= 10:
        lo = np.percentile(pts, percentile, axis=0)
        hi = np.percentile(pts, 100.0 - percentile, axis=0)
        ext = hi - lo
        big = float(ext.max())
        if big <= 0:
            big = 1.0
        pad = np.maximum(ext, 0.1 * big)
        grow = 0.5 * (pad - ext) + margin * pad
        return lo - grow, hi + grow, (f"sparse points: {percentile:g}th..{100 - percentile:g}th percentile per axis, "
                                      f"+{margin:g} x extent margin")
    if c2w:
        centres = np.array([np.asarray(p, np.float64)[:3, 3] for p in c2w])
        c = centres.mean(0)
        r = float(np.linalg.norm(centres - c, axis=1).max()) or 1.0
        return c - r, c + r, "cameras (fewer than 10 sparse points)"
    return -np.ones(3), np.ones(3), "unit cube (no points, no cameras)"
