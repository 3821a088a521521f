"""Test data made here (nothing downloaded): small asymmetric meshes in every supported format."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def asymmetric_mesh():
    """A box with a sphere on one corner and a bar on another: no symmetry hides a flipped axis."""
    import trimesh

    box = trimesh.creation.box(extents=(0.8, 0.5, 0.4))
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.22)
    ball.apply_translation((0.35, 0.2, 0.3))
    bar = trimesh.creation.box(extents=(0.15, 0.15, 0.7))
    bar.apply_translation((-0.35, -0.2, 0.3))
    return trimesh.util.concatenate([box, ball, bar])


def write_mesh(path: Path, mesh=None) -> Path:
    mesh = mesh if mesh is not None else asymmetric_mesh()
    path.parent.mkdir(parents=True, exist_ok=True)
    mesh.export(path)
    return path


def depth_consistency(ov, a: int, b: int, occlusion: float = 0.02) -> np.ndarray:
    """Relative z errors of view a's depth unprojected and reprojected into view b.

    B's depth is sampled bilinearly where all four neighbours are foreground. Points that land
    more than ``occlusion`` (relative) behind B's surface are hidden in B and skipped; points in
    front of it are kept, so a wrong pose or depth scale still shows.
    """
    from blender_mrvm.geometry import cameras as C

    da, db = ov.depth(a), ov.depth(b)
    per_view = getattr(ov, "intrinsics_per_view", None) or [ov.intrinsics] * len(ov.indices)
    pts = C.unproject_depth(per_view[a], ov.c2w_opencv[a], da)[da > 0]  # each view with its own intrinsics
    uv, z = C.project(per_view[b].K, C.invert_pose(ov.c2w_opencv[b]), pts)
    x, y = uv[:, 0] - 0.5, uv[:, 1] - 0.5  # pixel-centre convention -> array coordinates
    h, w = db.shape
    ok = (x >= 0) & (x < w - 1) & (y >= 0) & (y < h - 1) & (z > 0)
    x, y, z = x[ok], y[ok], z[ok]
    i, j = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - i, y - j
    q = np.stack([db[j, i], db[j, i + 1], db[j + 1, i], db[j + 1, i + 1]])
    fg = (q > 0).all(axis=0)
    dbv = (q[0] * (1 - fx) * (1 - fy) + q[1] * fx * (1 - fy) + q[2] * (1 - fx) * fy + q[3] * fx * fy)[fg]
    z = z[fg]
    rel = (z - dbv) / dbv
    return np.abs(rel[rel < occlusion])
