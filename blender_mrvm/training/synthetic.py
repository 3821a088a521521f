"""A tiny analytic multi-view set in our on-disk format (no Blender): shaded coloured spheres.

Each object is 1-3 spheres with random colours inside the unit box; views are ray-traced exactly
with ``geometry.cameras.rays_opencv`` (pixel centres, OpenCV axes) and written with the
``datasets.format`` writers, so the set exercises the same reader as a Blender-rendered one. Used by
tests, the benchmark and smoke runs of ``train``/``eval``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..datasets import format as F
from ..geometry import cameras, rigs


def _trace(intr, c2w, centres, radii, colours):
    o, d = cameras.rays_opencv(intr, c2w)
    H, W = intr.height, intr.width
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    best = np.full(o.shape[0], np.inf)
    ids = np.zeros(o.shape[0], np.int64)
    for k, (c, r) in enumerate(zip(centres, radii)):
        oc = o - c
        b = (oc * d).sum(-1)
        disc = b * b - ((oc * oc).sum(-1) - r * r)
        t = -b - np.sqrt(np.maximum(disc, 0.0))
        ok = (disc > 0) & (t > 0) & (t < best)
        best = np.where(ok, t, best)
        ids = np.where(ok, k + 1, ids)
    hit = np.isfinite(best)
    p = o + np.where(hit, best, 0.0)[:, None] * d
    n = np.zeros_like(p)
    rgb = np.ones_like(p)
    light = np.array([0.4, -0.3, 0.85]) / np.linalg.norm([0.4, -0.3, 0.85])
    for k in range(len(centres)):
        m = ids == k + 1
        n[m] = (p[m] - centres[k]) / radii[k]
        shade = 0.35 + 0.65 * np.clip(n[m] @ light, 0.0, 1.0)
        rgb[m] = colours[k] * shade[:, None]
    z_axis = c2w[:3, 2]
    depth = np.where(hit, ((p - c2w[:3, 3]) @ z_axis), 0.0)
    return rgb.reshape(H, W, 3), depth.reshape(H, W), n.reshape(H, W, 3), ids.reshape(H, W)


def make_sphere_dataset(root: Path, n_objects: int = 4, n_views: int = 8, resolution: int = 32, seed: int = 0,
                        category: str = "spheres", fov_deg: float = 45.0, rig: str = "sphere",
                        data_passes: bool = True) -> Path:
    """Write ``n_objects`` objects with ``n_views`` views each under ``root`` (our format); returns root.
    ``data_passes`` False leaves out the depth and normal EXRs (OpenEXR is then not needed: the GPU machine
    has none; training without the depth loss never reads them).

    All but the last ``max(1, n_objects // 4)`` objects are listed in ``splits/train.lst``, the rest in ``test.lst``."""
    root = Path(root)
    rng = np.random.default_rng(seed)
    intr = cameras.intrinsics_from_fov(math.radians(fov_deg), resolution, resolution)
    dist = rigs.framing_distance(0.8, math.radians(fov_deg))
    names = []
    for j in range(n_objects):
        k = int(rng.integers(1, 4))
        radii = rng.uniform(0.2, 0.45, k)
        centres = rng.uniform(-0.45, 0.45, (k, 3)) * (1 - radii[:, None])
        colours = rng.uniform(0.1, 0.9, (k, 3))
        lo = (centres - radii[:, None]).min(0)
        hi = (centres + radii[:, None]).max(0)
        obj = f"obj{j:03d}"
        obj_dir = root / category / obj
        poses = rigs.rig_poses(rig, n_views, dist, seed=seed * 1000 + j)
        for i, c2w in enumerate(poses):
            rgb, depth, normal, ids = _trace(intr, c2w, centres, radii, colours)
            vp = F.view_paths(obj_dir, i)
            F.write_png(vp["rgb"], F.to_uint8(rgb))
            if data_passes:
                F.write_depth(vp["depth"], depth.astype(np.float32))
                F.write_normals(vp["normal"], normal.astype(np.float32))
            F.write_png(vp["mask"], ids.astype(np.uint8))
            F.write_srn_pose(vp["pose"], c2w)
        F.atomic_write_text(obj_dir / "intrinsics.txt", F.format_srn_intrinsics(intr))
        F.atomic_write_json(obj_dir / "meta.json", {
            "format_version": F.FORMAT_VERSION, "generator": "blender_mrvm synthetic spheres", "category": category,
            "object_id": obj, "bbox": [lo.tolist(), hi.tolist()], "n_views": n_views, "complete": True,
            "labels": {str(i + 1): f"sphere{i + 1}" for i in range(k)}, "background": "white"})
        names.append(f"{category}/{obj}")
    n_train = n_objects - max(1, n_objects // 4) if n_objects > 1 else 1
    F.write_split(root, "train", names[:n_train])
    F.write_split(root, "test", names[n_train:] or names[:1])
    F.write_split(root, "val", names[n_train:] or names[:1])
    F.atomic_write_json(root / F.ROOT_MANIFEST, {"format_version": F.FORMAT_VERSION,
                                                 "generator": "blender_mrvm synthetic spheres", "seed": seed})
    return root
