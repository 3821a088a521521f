"""Rays clipped to the object's box, built in float64 so far or huge scenes stay exact.

The model works in a *normalised* frame: the object's box centred at the origin with its largest
half-extent 1 (:func:`normalization`). Rays are generated with ``geometry.cameras.rays_opencv``
(the one owner of pixel/axis conventions), intersected with the box in float64, and their origins
moved to the box entry point, so a camera 1e4 units away or an object of size 1e-3 gives the same
well-conditioned float32 numbers as a unit object at unit distance. Rays that miss the box are
flagged and never evaluated: they are background.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..geometry import cameras


def normalization(bbox_min, bbox_max) -> tuple[np.ndarray, float]:
    """(centre, scale) that map the box to [-1, 1] along its longest side: x' = (x - c) / s."""
    lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
    c = 0.5 * (lo + hi)
    s = float(np.max(0.5 * (hi - lo)))
    if not np.isfinite(s) or s <= 0:
        raise ValueError(f"degenerate object box {lo.tolist()} .. {hi.tolist()}")
    return c, s


def normalize_pose(c2w: np.ndarray, centre: np.ndarray, scale: float) -> np.ndarray:
    """Camera-to-world pose in the normalised frame (rotation unchanged, centre moved and scaled)."""
    out = cameras.as_pose(c2w).copy()
    out[:3, 3] = (out[:3, 3] - centre) / scale
    return out


def intersect_box(origins, dirs, bbox_min, bbox_max):
    """Slab test. Returns (t_near, t_far, hit) for rays o + t d, t >= 0.

    Works for numpy float64 or torch tensors of shape (..., 3). Direction components that are exactly
    zero (rays parallel to a face) are handled without 0 * inf: such a ray hits the slab for all t if
    its origin lies inside it, never otherwise. Rays starting inside the box get t_near = 0.
    """
    is_torch = isinstance(origins, torch.Tensor)
    xp = torch if is_torch else np
    if is_torch:
        lo = torch.as_tensor(bbox_min, dtype=origins.dtype, device=origins.device)
        hi = torch.as_tensor(bbox_max, dtype=origins.dtype, device=origins.device)
    else:
        lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
    zero = dirs == 0
    safe = xp.where(zero, xp.ones_like(dirs), dirs)
    if is_torch:
        t0 = (lo - origins) / safe
        t1 = (hi - origins) / safe
    else:
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            t0 = (lo - origins) / safe
            t1 = (hi - origins) / safe
    tmin = xp.minimum(t0, t1)
    tmax = xp.maximum(t0, t1)
    inside = (origins >= lo) & (origins <= hi)
    inf = float("inf")
    tmin = xp.where(zero, xp.where(inside, xp.full_like(tmin, -inf), xp.full_like(tmin, inf)), tmin)
    tmax = xp.where(zero, xp.where(inside, xp.full_like(tmax, inf), xp.full_like(tmax, -inf)), tmax)
    if is_torch:
        t_near = tmin.amax(dim=-1).clamp_min(0.0)
        t_far = tmax.amin(dim=-1)
    else:
        t_near = np.maximum(tmin.max(axis=-1), 0.0)
        t_far = tmax.min(axis=-1)
    hit = t_far > t_near
    return t_near, t_far, hit


@dataclass
class RayBundle:
    """Rays in the normalised frame, origins moved to the box entry (t = 0 there)."""

    origins: torch.Tensor
    """(R, 3) float64 box-entry points."""
    dirs: torch.Tensor
    """(R, 3) float64 unit directions."""
    far: torch.Tensor
    """(R,) float64 distance from the entry to the exit point (0 for misses)."""
    hit: torch.Tensor
    """(R,) bool: the ray crosses the box (others are background and not evaluated)."""
    depth_offset: torch.Tensor
    """(R,) float64 distance from the camera centre to the entry point (to report depth)."""
    up: torch.Tensor | None = None
    """(R, 3) float64 up vector of the camera each ray belongs to (GPNR's canonical frame), or None."""

    def __len__(self) -> int:
        return self.origins.shape[0]

    def select(self, idx) -> "RayBundle":
        return RayBundle(self.origins[idx], self.dirs[idx], self.far[idx], self.hit[idx], self.depth_offset[idx],
                         None if self.up is None else self.up[idx])

    @staticmethod
    def cat(bundles: "list[RayBundle]") -> "RayBundle":
        """Several bundles' rays, one after the other."""
        up = None if any(b.up is None for b in bundles) else torch.cat([b.up for b in bundles])
        return RayBundle(*(torch.cat([getattr(b, k) for b in bundles]) for k in
                           ("origins", "dirs", "far", "hit", "depth_offset")), up)

    def to(self, device) -> "RayBundle":
        """The same rays on ``device``."""
        return RayBundle(self.origins.to(device), self.dirs.to(device), self.far.to(device), self.hit.to(device),
                         self.depth_offset.to(device), None if self.up is None else self.up.to(device))


def make_rays(intr: cameras.Intrinsics, c2w_norm: np.ndarray, pixels: np.ndarray | torch.Tensor | None = None,
              box: float = 1.0) -> RayBundle:
    """Rays through ``pixels`` ((N, 2), default all pixel centres, row-major) of a normalised camera,
    clipped to the cube [-box, box]^3. ``pixels`` as a torch tensor makes the rays on its device (in float64
    there, by the same arithmetic: :func:`pixel_rows` gives a block of rows' pixel centres)."""
    o, d = cameras.rays_opencv(intr, c2w_norm, pixels)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    lo, hi = np.full(3, -box), np.full(3, box)
    tn, tf, hit = intersect_box(o, d, lo, hi)
    up = cameras.camera_up(c2w_norm)
    if isinstance(o, torch.Tensor):
        zero = torch.zeros_like(tn)
        tn = torch.where(hit, tn, zero)
        far = torch.where(hit, tf - tn, zero)
        return RayBundle(o + tn[:, None] * d, d, far, hit, tn, torch.as_tensor(up, device=d.device).expand(d.shape).clone())
    tn = np.where(hit, tn, 0.0)
    far = np.where(hit, tf - tn, 0.0)
    entry = o + tn[:, None] * d
    t = lambda a: torch.from_numpy(np.ascontiguousarray(a))  # noqa: E731
    return RayBundle(t(entry), t(d), t(far), t(hit), t(tn), t(np.broadcast_to(up, d.shape).copy()))


def pixel_rows(r0: int, r1: int, width: int, device=None) -> torch.Tensor:
    """((r1 - r0) * width, 2) float64 pixel centres (u, v) of image rows r0..r1, row-major, on ``device``
    (:func:`make_rays` makes their rays there)."""
    v = torch.arange(r0, r1, dtype=torch.float64, device=device) + 0.5
    u = torch.arange(width, dtype=torch.float64, device=device) + 0.5
    vv, uu = torch.meshgrid(v, u, indexing="ij")
    return torch.stack([uu, vv], -1).reshape(-1, 2)
