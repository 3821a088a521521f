"""Silhouettes of meshes from a camera, rasterized in numpy (no renderer), and their IoU.

Used to *measure* the variety of the procedural library: a pixel is inside when its centre
(i + 0.5, j + 0.5) lies in a projected triangle. Projection goes through ``geometry/cameras.py``.
"""

from __future__ import annotations

import numpy as np

from ...geometry import cameras as C


def rasterize(verts: np.ndarray, tris: np.ndarray, intr: C.Intrinsics, c2w_opencv: np.ndarray) -> np.ndarray:
    """Boolean (H, W) coverage of triangles ``tris`` (T, 3) over ``verts`` (N, 3) seen by the camera.

    Each triangle is tested only against the pixel centres inside its bounding box (all boxes are
    expanded into one candidate list and tested at once), so the cost follows the covered area.
    """
    W, H = intr.width, intr.height
    uv, z = C.project(intr.K, C.invert_pose(c2w_opencv), verts)
    if np.any(z <= 0):
        raise ValueError("mesh crosses the camera plane")
    tri = uv[np.asarray(tris, np.int64)]  # (T, 3, 2)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    # pixel (i, j) has its centre at (i + 0.5, j + 0.5): candidates i in [ceil(min - 0.5), floor(max - 0.5)]
    lo = np.ceil(tri.min(1) - 0.5).astype(np.int64)
    hi = np.floor(tri.max(1) - 0.5).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [W - 1, H - 1])
    nx, ny = hi[:, 0] - lo[:, 0] + 1, hi[:, 1] - lo[:, 1] + 1
    keep = (np.abs(area) > 1e-12) & (nx > 0) & (ny > 0)
    a, b, c, area, lo, nx, ny = a[keep], b[keep], c[keep], area[keep], lo[keep], nx[keep], ny[keep]
    out = np.zeros((H, W), bool)
    if len(a) == 0:
        return out
    counts = nx * ny
    t = np.repeat(np.arange(len(a)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    i = lo[t, 0] + k % nx[t]
    j = lo[t, 1] + k // nx[t]
    px, py = i + 0.5, j + 0.5
    sgn = np.sign(area)[t]

    def edge(p, q):
        return ((q[t, 0] - p[t, 0]) * (py - p[t, 1]) - (q[t, 1] - p[t, 1]) * (px - p[t, 0])) * sgn

    inside = (edge(a, b) >= 0) & (edge(b, c) >= 0) & (edge(c, a) >= 0)
    out[j[inside], i[inside]] = True
    return out


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / union) if union else 1.0


def iou_matrix(masks_a: np.ndarray, masks_b: np.ndarray | None = None) -> np.ndarray:
    """Pairwise IoU between two stacks of (H, W) masks (one stack: with itself)."""
    fa = masks_a.reshape(len(masks_a), -1).astype(np.float64)
    fb = fa if masks_b is None else masks_b.reshape(len(masks_b), -1).astype(np.float64)
    inter = fa @ fb.T
    union = fa.sum(1)[:, None] + fb.sum(1)[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1), 1.0)


def mean_pairwise_iou(masks: np.ndarray) -> float:
    """Mean IoU over distinct pairs of one stack."""
    m = iou_matrix(masks)
    n = len(masks)
    return float((m.sum() - np.trace(m)) / (n * (n - 1)))


def mesh_silhouette(obj, intr: C.Intrinsics, c2w_opencv: np.ndarray) -> np.ndarray:
    """Silhouette of a Blender mesh object (world space) by :func:`rasterize`."""
    me = obj.data
    me.calc_loop_triangles()
    co = np.zeros(len(me.vertices) * 3, np.float64)
    me.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    mw = np.array(obj.matrix_world)
    co = co @ mw[:3, :3].T + mw[:3, 3]
    tris = np.zeros(len(me.loop_triangles) * 3, np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    return rasterize(co, tris.reshape(-1, 3), intr, c2w_opencv)
