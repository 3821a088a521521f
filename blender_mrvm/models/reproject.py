"""Reference colours carried into a novel view through a depth map (image-based rendering on top of a model).

A NeRFormer view is a volume rendering of predicted colours: at this project's CPU scale, a blur. Where the
view's depth is right, the reference photos hold the true, sharp colour of the same surface point: project the
point into each reference, keep the references that see it (its distance from the reference camera agrees
with the reference's own depth map within ``tau``, relatively, and the reference shows the object there),
and read their colour (bilinear), each weighted by how close its ray is to the view's: the references' colour
replaces the model's in proportion to the best of those weights, so it takes over only where a reference looks
from nearly the view's own direction (where an error in depth moves the colour least). The view keeps the model's
colour wherever no reference sees the point or the model is unsure there is a surface (opacity below
``acc_lo``, fully trusted from ``acc_hi``).

Everything is in world units: depths are distances from the camera along each pixel's ray (as
``RayModel.synthesize`` returns them; 0 where nothing was rendered), poses OpenCV camera-to-world, pixel
centres at +0.5 (``geometry.cameras``). The depth can be the model's own (its renders of the target and of
each reference) or the data's (``eval --reproject gt``: the ceiling this reaches with exact geometry).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..geometry import cameras


@dataclass(frozen=True)
class ReprojectConfig:
    tau: float = 0.1
    """A reference sees the point when its distance from that camera is at most (1 + tau) x the reference's
    depth at the projection."""
    angle_scale: float = 0.05
    """Weight of a reference exp((cos(angle between the rays) - 1) / angle_scale): 1 at the view's own angle, 0.5
    at 15 degrees, 0.07 at 30 (with 0.05); 0 = every seeing reference alike. The defaults were chosen on training
    objects with each view's 5 nearest references (RECIPE.md "The references' own colours through depth")."""
    max_refs: int = 2
    """Only the view's nearest ``max_refs`` references (by direction and distance, ``synthesis.nearest_views``) lend
    their colours, so only those are rendered for their depth (time); the farther ones weigh little anyway."""
    acc_lo: float = 0.2
    acc_hi: float = 0.5
    """The reference colour is trusted not at all below the view's opacity ``acc_lo`` and fully from ``acc_hi``
    (chosen on training objects: the CPU models draw their objects at opacity ~0.7, and 0.5 / 0.8 gave +0.31 dB
    where 0.2 / 0.5 gave +0.49)."""

    def check(self) -> None:
        from ..errors import InputError

        if not (np.isfinite(self.tau) and self.tau >= 0):
            raise InputError(f"reprojection tolerance (--reproject-tau) must be a number >= 0, got {self.tau}")
        if not (np.isfinite(self.angle_scale) and self.angle_scale >= 0):
            raise InputError(f"reprojection angle scale (--reproject-angle) must be a number >= 0, got {self.angle_scale}")
        if not (isinstance(self.max_refs, int) and self.max_refs >= 1):
            raise InputError(f"reprojection needs max_refs >= 1 (--reproject-refs), got {self.max_refs}")
        if not (0 <= self.acc_lo < self.acc_hi <= 1):
            raise InputError(f"reprojection opacity ramp (--reproject-opacity) needs 0 <= low < high <= 1, got "
                             f"{self.acc_lo}, {self.acc_hi}")


def _bilinear(img: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(N, C) values of ``img`` (H, W, C) at pixel coordinates ``uv`` (N, 2), pixel centres at +0.5, clamped to
    the border."""
    H, W = img.shape[:2]
    x = np.clip(uv[:, 0] - 0.5, 0, W - 1)
    y = np.clip(uv[:, 1] - 0.5, 0, H - 1)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, W - 1), np.minimum(y0 + 1, H - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bot = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bot * fy


def reference_colours(depth: np.ndarray, c2w: np.ndarray, intr: cameras.Intrinsics, ref_images: np.ndarray,
                      ref_c2w: Sequence[np.ndarray], ref_intr: Sequence[cameras.Intrinsics],
                      ref_depths: np.ndarray, ref_object: np.ndarray, cfg: ReprojectConfig = ReprojectConfig()):
    """(colour (H, W, 3), weight (H, W) in [0, 1]) the references give the view's surface points.

    ``depth`` (H, W): the view's distance along each ray (0 = no surface: weight 0). ``ref_images`` (V, h, w, 3),
    ``ref_depths`` (V, h, w) distances along the references' rays and ``ref_object`` (V, h, w) bool, where each
    reference shows the object. ``weight`` is the largest single reference's weight (1 where a reference at the
    same angle, or any reference with ``angle_scale`` 0, sees the point)."""
    H, W = depth.shape
    o, d = cameras.rays_opencv(intr, c2w)
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    dep = np.asarray(depth, np.float64).reshape(-1)
    x = o + d * dep[:, None]
    surface = dep > 0
    num = np.zeros((H * W, 3))
    den = np.zeros(H * W)
    best = np.zeros(H * W)
    for img, pose, k, rdep, robj in zip(ref_images, ref_c2w, ref_intr, ref_depths, ref_object):
        pose = cameras.as_pose(pose)
        C = pose[:3, 3]
        pc = (x - C) @ pose[:3, :3]  # camera frame (R^T (x - C))
        z = pc[:, 2]
        h, w = rdep.shape
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = (pc @ np.asarray(k.K, np.float64).T)[:, :2] / z[:, None]
        inside = surface & (z > 1e-9) & np.all(np.isfinite(uv), 1)
        inside &= (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
        uv = np.where(inside[:, None], uv, 0.0)
        iu, iv = uv[:, 0].astype(np.int64).clip(0, w - 1), uv[:, 1].astype(np.int64).clip(0, h - 1)
        dist = np.linalg.norm(x - C, axis=1)
        ref_d = np.asarray(rdep, np.float64)[iv, iu]
        seen = inside & np.asarray(robj, bool)[iv, iu] & (ref_d > 0) & (dist <= ref_d * (1 + cfg.tau))
        wgt = seen.astype(np.float64)
        if cfg.angle_scale > 0:
            cos = np.sum(d * (x - C), 1) / np.maximum(dist, 1e-12)
            wgt *= np.exp((cos - 1) / cfg.angle_scale)
        num += wgt[:, None] * _bilinear(np.asarray(img, np.float64), uv)
        den += wgt
        best = np.maximum(best, wgt)
    col = num / np.maximum(den, 1e-12)[:, None]
    return col.reshape(H, W, 3).astype(np.float32), best.reshape(H, W).astype(np.float32)


def blend(color: np.ndarray, acc: np.ndarray, ref_colour: np.ndarray, ref_weight: np.ndarray,
          cfg: ReprojectConfig = ReprojectConfig()) -> tuple[np.ndarray, np.ndarray]:
    """(the model's ``color`` (H, W, 3) with the references' colour laid over where they see the surface and the
    model's opacity says there is one (see the module), the share (H, W) in [0, 1] taken from the references)."""
    ramp = np.clip((np.asarray(acc, np.float64) - cfg.acc_lo) / (cfg.acc_hi - cfg.acc_lo), 0, 1)
    g = ramp * np.asarray(ref_weight, np.float64)
    out = np.asarray(color, np.float64) * (1 - g[..., None]) + np.asarray(ref_colour, np.float64) * g[..., None]
    return out.astype(np.float32), g.astype(np.float32)


def lay_over(color: np.ndarray, acc: np.ndarray, depth: np.ndarray, c2w: np.ndarray, intr: cameras.Intrinsics,
             ref_images: np.ndarray, ref_c2w: Sequence[np.ndarray], ref_intr: Sequence[cameras.Intrinsics],
             geometry: Sequence[tuple], cfg: ReprojectConfig = ReprojectConfig()) -> tuple[np.ndarray, float]:
    """(the view ``color`` with the references' colours laid over, share of its pixels taken at least half from
    them): :func:`reference_colours` then :func:`blend`; ``geometry`` holds each reference's (distances along its
    rays, where it shows the object)."""
    col, wgt = reference_colours(depth, c2w, intr, ref_images, ref_c2w, ref_intr, np.stack([g[0] for g in geometry]),
                                 np.stack([g[1] for g in geometry]), cfg)
    out, share = blend(color, acc, col, wgt, cfg)
    return out, float(np.mean(share >= 0.5))
