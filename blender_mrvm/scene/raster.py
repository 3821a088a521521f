"""Exact pixel-centre data passes (depth, normals, ids) by rasterizing triangles in numpy; no bpy.

``render-dataset`` needs, per view, the planar z-depth, the world normal and the object / part id
of the first surface that the ray through each pixel centre hits (pixel (i, j) is sampled at
(i + 0.5, j + 0.5), the convention of ``geometry/cameras.py``). For a pinhole camera that is what a
z-buffer rasterizer computes when it samples each triangle exactly at pixel centres: the
perspective-correct interpolation ``1/z = sum(b_k / z_k)`` of screen-space barycentrics ``b`` is the
ray/plane intersection, so the depth is exact up to float64 rounding, not an estimate.

It replaces a second, 1-sample Cycles render with a near-zero pixel filter (the same values, at a
fraction of the cost, and free of Cycles' per-render set-up). Cycles conventions are kept:

- both sides of every triangle are visible (no back-face culling);
- the normal is the interpolated shading normal (the mesh's corner normals, so flat, smooth and
  custom-normal faces all match Cycles' Normal pass), flipped towards the camera when the ray hits
  the back of the triangle, as Cycles flips it;
- a hit counts only between the camera's clip distances, measured along the ray.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.cameras import Intrinsics

_MAX_PAIRS = 1 << 21
"""Triangle/pixel candidate pairs processed at once (bounds the memory of one chunk)."""


@dataclass(frozen=True)
class Triangles:
    """World-space triangles of everything a view can see, with what the data passes need."""

    verts: np.ndarray
    """(N, 3, 3) float64 vertex positions, world space."""
    normals: np.ndarray
    """(N, 3, 3) float64 unit corner (shading) normals, world space."""
    geo_normals: np.ndarray
    """(N, 3) float64 geometric normals, world space, oriented as the mesh's own normals."""
    object_id: np.ndarray
    """(N,) int64 object pass index (> 0)."""
    material_id: np.ndarray
    """(N,) int64 material pass index (0 without a material)."""

    def __len__(self) -> int:
        return len(self.verts)


@dataclass
class DataPasses:
    """Per-pixel results of :func:`rasterize`; background pixels are 0 (triangle -1)."""

    depth: np.ndarray
    """(H, W) float64 planar z-depth along the camera axis; 0 = background."""
    normal: np.ndarray
    """(H, W, 3) float64 world-space unit normals; 0 = background."""
    triangle: np.ndarray
    """(H, W) int64 index of the visible triangle; -1 = background."""
    object_id: np.ndarray
    """(H, W) int64 object pass index; 0 = background."""
    material_id: np.ndarray
    """(H, W) int64 material pass index; 0 = background."""


def _world_to_camera(c2w_opencv: np.ndarray) -> np.ndarray:
    """Inverse of a rigid camera-to-world pose (rotation transposed; cheaper than a general inverse)."""
    c2w = np.asarray(c2w_opencv, dtype=np.float64)
    w2c = np.eye(4)
    w2c[:3, :3] = c2w[:3, :3].T
    w2c[:3, 3] = -c2w[:3, :3].T @ c2w[:3, 3]
    return w2c


def concatenate(parts: list[Triangles]) -> Triangles:
    if not parts:
        z3 = np.zeros((0, 3, 3))
        return Triangles(z3, z3, np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64))
    return Triangles(*(np.concatenate([getattr(p, f) for p in parts]) for f in
                       ("verts", "normals", "geo_normals", "object_id", "material_id")))


def _clip_near(cam: np.ndarray, idx: np.ndarray, z_min: float) -> tuple[np.ndarray, np.ndarray]:
    """Clip camera-space triangles against the plane z = z_min (keeps z >= z_min).

    Returns the clipped triangles (M, 3, 3) and, for each, the source triangle index and the
    barycentric weights of its corners in the source triangle (M, 3, 3), so attributes follow."""
    out_v, out_src, out_w = [], [], []
    eye = np.eye(3)
    for t in idx:
        v = cam[t]
        poly = []  # (point, weights)
        for k in range(3):
            a, b = v[k], v[(k + 1) % 3]
            wa, wb = eye[k], eye[(k + 1) % 3]
            ina, inb = a[2] >= z_min, b[2] >= z_min
            if ina:
                poly.append((a, wa))
            if ina != inb:
                s = (z_min - a[2]) / (b[2] - a[2])
                poly.append((a + s * (b - a), wa + s * (wb - wa)))
        for k in range(1, len(poly) - 1):
            tri = (poly[0], poly[k], poly[k + 1])
            out_v.append([p for p, _ in tri])
            out_w.append([w for _, w in tri])
            out_src.append(t)
    if not out_v:
        return np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros((0, 3, 3))
    return np.array(out_v), np.array(out_src, dtype=np.int64), np.array(out_w)


def rasterize(tris: Triangles, intr: Intrinsics, c2w_opencv: np.ndarray,
              clip_start: float = 0.0, clip_end: float = np.inf) -> DataPasses:
    """Depth, normal and ids of the first surface along the ray through every pixel centre."""
    w, h = intr.width, intr.height
    depth = np.zeros(h * w)
    tri_of = np.full(h * w, -1, dtype=np.int64)
    bary = np.zeros((h * w, 3))
    if len(tris):
        w2c = _world_to_camera(c2w_opencv)
        cam = (tris.verts.reshape(-1, 3) @ w2c[:3, :3].T + w2c[:3, 3]).reshape(-1, 3, 3)  # OpenCV: z forward
        z = cam[..., 2]
        # Geometry behind (or at) the camera cannot be projected: clip it at a plane just in front.
        # Hits closer than clip_start are dropped below, so the plane only has to be positive.
        z_min = max(clip_start * 0.5, 1e-9)
        ok = z >= z_min
        front = ok[:, 0] & ok[:, 1] & ok[:, 2]
        crossing = ~front & (ok[:, 0] | ok[:, 1] | ok[:, 2])
        src = np.flatnonzero(front)
        cam_t = cam[src]
        weights = np.broadcast_to(np.eye(3), (len(src), 3, 3))
        if crossing.any():
            cv, cs, cw = _clip_near(cam, np.flatnonzero(crossing), z_min)
            cam_t = np.concatenate([cam_t, cv])
            src = np.concatenate([src, cs])
            weights = np.concatenate([weights, cw])
        best = np.full(h * w, np.inf)
        best_b = np.zeros((h * w, 3))
        best_t = np.full(h * w, -1, dtype=np.int64)
        _raster_into(cam_t, intr, clip_start, clip_end, best, best_t, best_b)
        hit = best_t >= 0
        depth[hit] = best[hit]
        # Map clipped pieces back to source triangles (their corner weights in the source).
        t_local = best_t[hit]
        tri_of[hit] = src[t_local]
        bary[hit] = np.einsum("nk,nkj->nj", best_b[hit], weights[t_local])
    hit = tri_of >= 0
    normal = np.zeros((h * w, 3))
    obj = np.zeros(h * w, dtype=np.int64)
    mat = np.zeros(h * w, dtype=np.int64)
    if hit.any():
        t = tri_of[hit]
        n = np.einsum("nk,nkj->nj", bary[hit], tris.normals[t])
        nn = np.linalg.norm(n, axis=1, keepdims=True)
        ng = tris.geo_normals[t]
        n = np.where(nn > 1e-12, n / np.maximum(nn, 1e-300), ng / np.maximum(np.linalg.norm(ng, axis=1, keepdims=True), 1e-300))
        # Ray directions (world) through the pixel centres that hit.
        pix = np.flatnonzero(hit)
        u, v = pix % w + 0.5, pix // w + 0.5
        yc = (v - intr.cy) / intr.fy
        xc = (u - intr.cx - intr.skew * yc) / intr.fx
        d = np.stack([xc, yc, np.ones_like(xc)], axis=1) @ np.asarray(c2w_opencv, dtype=np.float64)[:3, :3].T
        back = np.einsum("nj,nj->n", ng, d) > 0  # the ray sees the back of the triangle
        n[back] = -n[back]
        normal[hit] = n
        obj[hit] = tris.object_id[t]
        mat[hit] = tris.material_id[t]
    return DataPasses(depth.reshape(h, w), normal.reshape(h, w, 3), tri_of.reshape(h, w),
                      obj.reshape(h, w), mat.reshape(h, w))


def _raster_into(cam: np.ndarray, intr: Intrinsics, clip_start: float, clip_end: float,
                 best: np.ndarray, best_t: np.ndarray, best_b: np.ndarray) -> None:
    """Z-buffer the camera-space triangles ``cam`` (all z > 0) into ``best`` (depth), ``best_t``
    (triangle index into ``cam``) and ``best_b`` (screen-space barycentrics), sampling pixel centres."""
    w, h = intr.width, intr.height
    z = cam[..., 2]
    y = cam[..., 1] / z
    px = intr.fx * (cam[..., 0] / z) + intr.skew * y + intr.cx
    py = intr.fy * y + intr.cy
    # Pixel-centre index ranges covered by each triangle's screen bounding box.
    def lo(a):
        return np.minimum(np.minimum(a[:, 0], a[:, 1]), a[:, 2])

    def hi(a):
        return np.maximum(np.maximum(a[:, 0], a[:, 1]), a[:, 2])

    i0 = np.clip(np.ceil(lo(px) - 0.5), 0, w).astype(np.int64)
    i1 = np.clip(np.floor(hi(px) - 0.5), -1, w - 1).astype(np.int64)
    j0 = np.clip(np.ceil(lo(py) - 0.5), 0, h).astype(np.int64)
    j1 = np.clip(np.floor(hi(py) - 0.5), -1, h - 1).astype(np.int64)
    nx, ny = i1 - i0 + 1, j1 - j0 + 1
    area = (px[:, 1] - px[:, 0]) * (py[:, 2] - py[:, 0]) - (px[:, 2] - px[:, 0]) * (py[:, 1] - py[:, 0])
    keep = np.flatnonzero((nx > 0) & (ny > 0) & (np.abs(area) > 1e-14))
    if not len(keep):
        return
    counts = nx[keep] * ny[keep]
    # Chunks of triangles whose candidate pairs fit the budget.
    ends = np.cumsum(counts)
    start = 0
    while start < len(keep):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + _MAX_PAIRS, side="right")), start + 1)
        _raster_chunk(keep[start:stop], counts[start:stop], cam, px, py, z, area, i0, j0, nx, intr,
                      clip_start, clip_end, best, best_t, best_b)
        start = stop


def _raster_chunk(tri, counts, cam, px, py, z, area, i0, j0, nx, intr, clip_start, clip_end,
                  best, best_t, best_b) -> None:
    w = intr.width
    t = np.repeat(tri, counts)
    k = np.arange(len(t)) - np.repeat(np.cumsum(counts) - counts, counts)  # index within the box
    i = i0[t] + k % nx[t]
    j = j0[t] + k // nx[t]
    qx, qy = i + 0.5, j + 0.5
    x0, x1, x2 = px[t, 0], px[t, 1], px[t, 2]
    y0, y1, y2 = py[t, 0], py[t, 1], py[t, 2]
    inv_a = 1.0 / area[t]
    b0 = ((x1 - qx) * (y2 - qy) - (x2 - qx) * (y1 - qy)) * inv_a
    b1 = ((x2 - qx) * (y0 - qy) - (x0 - qx) * (y2 - qy)) * inv_a
    b2 = 1.0 - b0 - b1
    eps = -1e-9  # a pixel centre on a shared edge belongs to both triangles (no cracks)
    inside = (b0 >= eps) & (b1 >= eps) & (b2 >= eps)
    t, i, j, b0, b1, b2 = t[inside], i[inside], j[inside], b0[inside], b1[inside], b2[inside]
    if not len(t):
        return
    inv_z = b0 / z[t, 0] + b1 / z[t, 1] + b2 / z[t, 2]
    zz = 1.0 / inv_z
    # Distance along the ray (Cycles clips camera rays by distance, not by planar depth).
    yc = (j + 0.5 - intr.cy) / intr.fy
    xc = (i + 0.5 - intr.cx - intr.skew * yc) / intr.fx
    dist = zz * np.sqrt(xc * xc + yc * yc + 1.0)
    ok = (dist >= clip_start) & (dist <= clip_end) & (zz > 0)
    pix = (j * w + i)[ok]
    zz, t = zz[ok], t[ok]
    b = np.stack([b0[ok], b1[ok], b2[ok]], axis=1)
    if not len(pix):
        return
    # Z-test: the nearest candidate per pixel (within this chunk, then against earlier chunks).
    near = np.full(len(best), np.inf)
    np.minimum.at(near, pix, zz)
    win = np.flatnonzero(zz == near[pix])
    p = pix[win]
    closer = zz[win] < best[p]
    p, win = p[closer], win[closer]
    best[p] = zz[win]
    best_t[p] = t[win]
    # Perspective-correct barycentrics of the hit (weights of the triangle's corners).
    bz = b[win] / z[t[win]]
    best_b[p] = bz / bz.sum(axis=1, keepdims=True)


def outline_points(tris: Triangles) -> np.ndarray:
    """The few points whose projection bounds the projection of every triangle: the vertices of
    the convex hull (a perspective projection keeps segments straight for points in front of the
    camera, so image extremes lie at hull vertices). Computed once per object for :func:`pixel_box`."""
    pts = tris.verts.reshape(-1, 3)
    if len(pts) > 64:
        try:
            from scipy.spatial import ConvexHull

            pts = pts[ConvexHull(pts).vertices]
        except Exception:  # flat or degenerate geometry: keep every vertex
            pass
    return pts


def pixel_box(points, intr: Intrinsics, c2w_opencv: np.ndarray, margin: int) -> tuple[int, int, int, int] | None:
    """Inclusive pixel ranges (i0, i1, j0, j1) of the image that the projection of ``points`` (or of
    :class:`Triangles`) can reach, widened by ``margin`` pixels (a pixel filter's reach); None when it
    cannot be bounded (geometry at or behind the camera plane) or is empty: render the whole image."""
    pts = points.verts.reshape(-1, 3) if isinstance(points, Triangles) else np.asarray(points, dtype=np.float64)
    if not len(pts):
        return None
    w2c = _world_to_camera(c2w_opencv)
    cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
    z = cam[:, 2]
    if not (z > 1e-9).all():
        return None
    y = cam[:, 1] / z
    px = intr.fx * (cam[:, 0] / z) + intr.skew * y + intr.cx
    py = intr.fy * y + intr.cy
    w, h = intr.width, intr.height
    i0 = max(int(np.floor(px.min() - 0.5)) - margin, 0)
    i1 = min(int(np.ceil(px.max() - 0.5)) + margin, w - 1)
    j0 = max(int(np.floor(py.min() - 0.5)) - margin, 0)
    j1 = min(int(np.ceil(py.max() - 0.5)) + margin, h - 1)
    if i0 > i1 or j0 > j1:
        return None  # nothing in view: render the (empty) image as it is
    return i0, i1, j0, j1
