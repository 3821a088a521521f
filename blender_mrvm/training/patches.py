"""Random-scale image patches and the differentiable LPIPS loss on them, shared by the trainers.

A per-pixel loss (MSE) on scattered rays is minimised by the mean of what the model cannot tell apart:
a blur. A perceptual loss needs neighbouring pixels, so a trainer that uses one renders its rays as a
P x P patch: ``sample_patch`` places the patch (region-aware: with probability ``fg_prob`` centred on an
object pixel; its side ``scale`` of the image side, so scale 1 is the whole image at P x P and small
scales are full-resolution detail), ``bilinear`` reads the ground truth at the patch's continuous pixel
coordinates, and ``lpips_loss`` is LPIPS-VGG v0.1 (the offline weights) with gradients to the
prediction. Used by Sem2NeRF (the paper's recipe) and by the ray models' ``lpips_weight``. bpy-free.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F


def sample_patch(rng: np.random.Generator, mask: np.ndarray, patch: int, scale: float, fg_prob: float) -> np.ndarray:
    """(P*P, 2) continuous pixel coordinates (x, y), row-major, of a P x P patch covering ``scale`` of the
    image side.

    Sample spacing is scale * side / P; with probability ``fg_prob`` the patch is centred on a random
    object pixel of ``mask`` (clamped so it stays inside the image)."""
    h, w = mask.shape
    side_x, side_y = scale * w, scale * h
    fg = np.flatnonzero(mask.ravel() > 0)
    if fg.size and rng.random() < fg_prob:
        k = fg[rng.integers(fg.size)]
        cy, cx = k // w + 0.5, k % w + 0.5
        x0 = float(np.clip(cx - side_x / 2, 0, w - side_x))
        y0 = float(np.clip(cy - side_y / 2, 0, h - side_y))
    else:
        x0 = float(rng.uniform(0, w - side_x)) if w > side_x else 0.0
        y0 = float(rng.uniform(0, h - side_y)) if h > side_y else 0.0
    g = (np.arange(patch) + 0.5) / patch
    xs, ys = x0 + g * side_x, y0 + g * side_y
    X, Y = np.meshgrid(xs, ys)
    return np.stack([X.ravel(), Y.ravel()], -1)


def bilinear(image: np.ndarray, px: np.ndarray) -> torch.Tensor:
    """(N, C) float values of an (H, W, C) or (H, W) image at continuous pixel coordinates ``px`` (N, 2),
    pixel centres at +0.5, borders clamped."""
    a = np.asarray(image, np.float32)
    if a.ndim == 2:
        a = a[..., None]
    h, w = a.shape[:2]
    img = torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None]
    grid = torch.from_numpy(np.stack([px[:, 0] / w * 2 - 1, px[:, 1] / h * 2 - 1], -1)).float()[None, None]
    return F.grid_sample(img, grid, mode="bilinear", padding_mode="border", align_corners=False)[0, :, 0].T


def lpips_loss(lp, pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """Mean LPIPS-VGG (v0.1) of (B, 3, P, P) patches in [0, 1], differentiable w.r.t. ``pred``
    (``lp`` a :class:`models.metrics.LPIPS`; its ``forward`` is for evaluation, without gradients)."""
    return lp.distance(pred, gt).mean()
