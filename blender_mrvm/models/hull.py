"""Empty-space skipping inside the object's box: a conservative visual hull of the reference masks.

Box clipping already makes rays that miss the object's box free. Inside the box most of the volume
is still empty; the reference views' object masks say where: a point can only be on the object if it
projects onto the object in every reference view that sees it. :func:`build_hull` carves a voxel grid
over the normalised box with that rule, conservatively:

- a voxel is kept in a view when the view's mask has an object pixel within the voxel's projected
  radius (its half-diagonal at the voxel's depth) plus ``margin_px`` of the voxel centre's projection
  (a Euclidean distance transform of the mask answers that for every voxel at once);
- a view with an empty mask carves nothing (an object out of frame must not empty the box);
- a view that does not see a voxel (behind the camera, or projecting outside the image by more than
  that radius) carves nothing there;
- the kept grid is grown by one voxel, so a ray that only grazes a kept voxel between two march
  points is still caught.

:func:`clip_rays` then marches every ray through the grid (``steps_per_voxel`` points per voxel
edge), and either drops the rays that meet no kept voxel (``mode="cull"``: they are background, as
box misses are) or also shortens the others to the kept span (``mode="tighten"``: the model's samples
concentrate where the object can be). Both are exact when the masks are right and the object is
inside the box; the bench (``bench tradeoff``) measures the share of rays and samples skipped, the
time saved and the PSNR at each mode. Without masks nothing is skipped.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import torch

from .projection import RefCameras
from .rays import RayBundle

MODES = ("off", "cull", "tighten")
"""Empty-space skipping modes (``off``: box clipping only)."""
GPU_BLOCK = 16384  # rays marched at once on a GPU: ~7 M points at 64^3, a few hundred MB


def footprint_pays(device: torch.device) -> bool:
    """Whether a view's :func:`footprint` is worth making before :func:`clip_rays` marches its rays on ``device``.

    On the CPU it is: it drops most box rays before the march. On a GPU it is not: it is a splat and a distance
    transform on the host, and the device marches every box ray in one pass faster than the host makes the
    footprint. Session 29, H100, 24-view orbit at 256 px, 2 references (docs/bench_gpu/session29/): ``balanced``
    0.0647 s a view without it against 0.0798 with it (0.0733 with no skipping at all), ``quality`` 0.289
    against 0.293. The rays kept are the same either way (the footprint is conservative; tests compare them)."""
    return torch.device(device).type == "cpu"


@dataclass
class Hull:
    """Occupancy grid over the normalised cube [-box, box]^3 (index order x, y, z)."""

    occupied: torch.Tensor
    """(G, G, G) bool."""
    box: float

    @property
    def resolution(self) -> int:
        return int(self.occupied.shape[0])

    def to(self, device) -> "Hull":
        """The hull on ``device`` (itself when it is there already)."""
        device = torch.device(device)
        return self if self.occupied.device == device else Hull(self.occupied.to(device), self.box)

    @property
    def fraction(self) -> float:
        """Share of the box's volume kept."""
        return float(self.occupied.float().mean())


def build_hull(masks: np.ndarray | torch.Tensor, cams: RefCameras, box: float, resolution: int = 64,
               margin_px: float = 1.5) -> Hull:
    """Visual hull of ``masks`` (V, H, W) bool (True = object) seen by ``cams`` (normalised frame)."""
    from scipy.ndimage import distance_transform_edt

    masks = np.asarray(masks.cpu() if isinstance(masks, torch.Tensor) else masks).astype(bool)
    if masks.ndim != 3 or masks.shape[0] != len(cams):
        raise ValueError(f"hull: need one mask per reference view, got {masks.shape} for {len(cams)} views")
    if masks.shape[1:] != (cams.height, cams.width):
        raise ValueError(f"hull: masks are {masks.shape[2]}x{masks.shape[1]}, references {cams.width}x{cams.height}")
    G = int(resolution)
    h = box / G
    pts = _centres(G, box)
    keep = torch.ones(pts.shape[0], dtype=torch.bool)
    w2c = cams.w2c.float().cpu()
    K = cams.K.float().cpu()
    radius_world = h * np.sqrt(3.0)
    W, H = cams.width, cams.height
    for v in range(len(cams)):
        if not masks[v].any():
            continue  # the object is not in this view (or its mask is missing): no information, carve nothing
        p = torch.addmm(w2c[v, :3, 3], pts, w2c[v, :3, :3].T)
        z = p[:, 2]
        front = z > radius_world  # the whole voxel lies in front of the camera
        zs = torch.where(front, z, torch.ones_like(z))
        u = (K[v, 0, 0] * p[:, 0] + K[v, 0, 1] * p[:, 1]) / zs + K[v, 0, 2]
        w = K[v, 1, 1] * p[:, 1] / zs + K[v, 1, 2]
        r_px = radius_world * torch.maximum(K[v, 0, 0], K[v, 1, 1]) / zs * 1.05 + margin_px
        seen = front & (u >= -r_px) & (u <= W + r_px) & (w >= -r_px) & (w <= H + r_px)
        dist = torch.from_numpy(distance_transform_edt(~masks[v]).astype(np.float32))  # pixels to the object
        iu = u.long().clamp_(0, W - 1)
        iv = w.long().clamp_(0, H - 1)
        near_obj = dist.reshape(-1)[iv * W + iu] <= r_px + 1.0  # +1: pixel centre vs. the point inside the pixel
        keep &= ~seen | near_obj
    occ = keep.view(G, G, G)
    occ = torch.nn.functional.max_pool3d(occ[None, None].float(), 3, stride=1, padding=1)[0, 0] > 0
    return Hull(occ, float(box))


@functools.lru_cache(maxsize=4)
def _centres(G: int, box: float) -> torch.Tensor:
    """(G^3, 3) float32 voxel centres of the cube [-box, box]^3, x-major."""
    h = box / G
    c = torch.linspace(-box + h, box - h, G, dtype=torch.float64)
    X, Y, Z = torch.meshgrid(c, c, c, indexing="ij")
    return torch.stack([X, Y, Z], -1).reshape(-1, 3).float()


def footprint(hull: Hull, intr, c2w_norm: np.ndarray) -> torch.Tensor:
    """(H * W,) bool, row-major: the pixels of a camera (normalised frame) whose rays can meet a kept voxel.

    Every kept voxel is splatted as a disc of its projected radius (half-diagonal at its depth, +5 %)
    around its centre's projection; a pixel is kept when its centre lies within the largest radius of a
    marked pixel (conservative: discs only grow). A camera inside or touching the hull keeps every pixel.
    """
    from scipy.ndimage import distance_transform_edt

    from ..geometry import cameras

    W, H = int(intr.width), int(intr.height)
    G = hull.resolution
    h = hull.box / G
    ii = torch.nonzero(hull.occupied.cpu().reshape(-1)).flatten()
    if ii.numel() == 0:
        return torch.zeros(H * W, dtype=torch.bool)
    pts = _centres(G, hull.box)[ii].double()
    w2c = torch.from_numpy(cameras.invert_pose(c2w_norm))
    p = pts @ w2c[:3, :3].T + w2c[:3, 3]
    z = p[:, 2]
    radius_world = h * np.sqrt(3.0)
    if bool((z <= 2 * radius_world).any()):
        return torch.ones(H * W, dtype=torch.bool)
    K = torch.from_numpy(np.asarray(intr.K, np.float64))
    u = (K[0, 0] * p[:, 0] + K[0, 1] * p[:, 1]) / z + K[0, 2]
    v = K[1, 1] * p[:, 1] / z + K[1, 2]
    r = radius_world * float(max(K[0, 0], K[1, 1])) / z * 1.05
    near = (u >= -r) & (u <= W + r) & (v >= -r) & (v <= H + r)
    if not bool(near.any()):
        return torch.zeros(H * W, dtype=torch.bool)
    marks = np.zeros((H, W), bool)
    marks[v[near].floor().long().clamp(0, H - 1).numpy(), u[near].floor().long().clamp(0, W - 1).numpy()] = True
    dist = distance_transform_edt(~marks)
    return torch.from_numpy(dist <= float(r[near].max()) + 1.5).reshape(-1)


def clip_rays(rays: RayBundle, hull: Hull, mode: str = "cull", keep: torch.Tensor | None = None,
              steps_per_voxel: int = 2, block: int | None = None, workers: int = 1) -> RayBundle:
    """Rays after empty-space skipping (see the module doc). Rays already missing stay misses.

    ``keep``: the view's :func:`footprint` when known (rays outside it are dropped without marching).
    The remaining rays are marched ``block`` at a time (memory ~ block x 450 points at 64^3; default 2048 on
    the CPU, :data:`GPU_BLOCK` on a GPU), ``workers`` blocks side by side on threads."""
    if mode == "off":
        return rays
    if mode not in MODES:
        raise ValueError(f"empty-space skipping mode must be one of {', '.join(MODES)}, got {mode!r}")
    if keep is not None:
        rays = RayBundle(rays.origins, rays.dirs, torch.where(keep, rays.far, torch.zeros_like(rays.far)),
                         rays.hit & keep, rays.depth_offset, rays.up)
    if block is None:
        block = 2048 if rays.origins.device.type == "cpu" else GPU_BLOCK
    live = torch.nonzero(rays.hit).flatten()
    starts = range(0, live.numel(), block)

    def part(s):
        return _clip(rays.select(live[s:s + block]), hull, mode, steps_per_voxel)

    if workers > 1 and len(starts) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(min(workers, len(starts))) as pool:
            parts = list(pool.map(part, starts))
    else:
        parts = [part(s) for s in starts]
    out = RayBundle(rays.origins.clone(), rays.dirs, rays.far.clone(), rays.hit.clone(), rays.depth_offset.clone(), rays.up)
    for s, p in zip(starts, parts):
        sel = live[s:s + block]
        out.origins[sel], out.far[sel], out.hit[sel], out.depth_offset[sel] = p.origins, p.far, p.hit, p.depth_offset
    return out


def _voxel(pts: torch.Tensor, hull: Hull) -> torch.Tensor:
    """Flat (x-major) index of the hull voxel holding each point (points outside the box clamp to its edge)."""
    G = hull.resolution
    ijk = ((pts + hull.box) * (G / (2 * hull.box))).long().clamp_(0, G - 1)
    return (ijk[..., 0] * G + ijk[..., 1]) * G + ijk[..., 2]


def _meets_hull(rays: RayBundle, hull: Hull, ts: torch.Tensor, far: torch.Tensor, group: int | None = None) -> torch.Tensor:
    """(R,) bool: whether a march point of each ray (at the distances ``ts``, those up to its ``far``) lies in
    a kept voxel. The same points and voxels as marching every ray to the end, ``group`` steps at a time,
    dropping rays once they meet a voxel or run out of box (``cull`` needs no more; ~10x faster on the CPU).
    On a GPU (``group`` None there) every step is taken at once: each group's dropping costs a host sync,
    and with them ``synthesize`` at 256 px was 3.4x slower with the hull than without it (session 28, H100);
    marching all the steps in one pass gives the same points and the same answer."""
    occ_flat = hull.occupied.reshape(-1).to(rays.origins.device)
    origins, dirs = rays.origins.float(), rays.dirs.float()
    if group is None:
        group = 16 if rays.origins.device.type == "cpu" else len(ts)
    if group >= len(ts):
        pts = origins[:, None, :] + ts.float()[None, :, None] * dirs[:, None, :]
        lin = _voxel(pts, hull)
        return rays.hit & (occ_flat[lin] & (ts[None, :] <= far[:, None] + 1e-9)).any(-1)
    met = torch.zeros(len(rays), dtype=torch.bool, device=rays.origins.device)
    live = torch.nonzero(rays.hit).flatten()
    for s0 in range(0, len(ts), group):
        if live.numel() == 0:
            break
        t = ts[s0:s0 + group]
        pts = origins[live, None, :] + t.float()[None, :, None] * dirs[live, None, :]
        lin = _voxel(pts, hull)
        f = far[live]
        now = (occ_flat[lin] & (t[None, :] <= f[:, None] + 1e-9)).any(-1)
        met[live[now]] = True
        live = live[~now & (f + 1e-9 >= float(ts[min(s0 + group, len(ts) - 1)]))]
    return met


def _clip(rays: RayBundle, hull: Hull, mode: str, steps_per_voxel: int) -> RayBundle:
    G = hull.resolution
    far = rays.far.double()
    step = hull.box / (G * steps_per_voxel)  # march spacing: 1 / steps_per_voxel of a half voxel edge
    n = int(np.ceil(float(far.max()) / step)) + 1 if len(rays) else 1
    ts = torch.arange(n, dtype=torch.float64, device=far.device) * step
    if mode == "cull":
        hit = rays.hit & _meets_hull(rays, hull, ts, far)
        far_new = torch.where(hit, far, torch.zeros_like(far))
        return RayBundle(rays.origins, rays.dirs, far_new.to(rays.far.dtype), hit, rays.depth_offset, rays.up)
    pts = rays.origins.float()[:, None, :] + ts.float()[None, :, None] * rays.dirs.float()[:, None, :]  # (R, n, 3)
    inside = ts[None, :] <= far[:, None] + 1e-9
    lin = _voxel(pts, hull)
    occ = hull.occupied.reshape(-1).to(lin.device)[lin] & inside & rays.hit[:, None]
    any_occ = occ.any(-1)
    hit = rays.hit & any_occ
    first = torch.where(any_occ, occ.float().argmax(-1), torch.zeros_like(any_occ, dtype=torch.long))
    last = torch.where(any_occ, n - 1 - occ.flip(-1).float().argmax(-1), torch.zeros_like(first))
    t0 = (ts[first] - step).clamp_min(0.0)
    t1 = torch.minimum(ts[last] + step, far)
    t0 = torch.where(hit, t0, torch.zeros_like(t0))
    span = torch.where(hit, (t1 - t0).clamp_min(0.0), torch.zeros_like(t0))
    origins = rays.origins.double() + t0[:, None] * rays.dirs.double()
    return RayBundle(origins.to(rays.origins.dtype), rays.dirs, span.to(rays.far.dtype), hit,
                     (rays.depth_offset.double() + t0).to(rays.depth_offset.dtype), rays.up)
