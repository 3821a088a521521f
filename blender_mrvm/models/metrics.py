"""Image metrics: PSNR, SSIM and LPIPS-VGG (v0.1).

SSIM comes in two conventions. :func:`ssim` is pixelNeRF's (it calls scikit-image's
``structural_similarity`` with its defaults: 7x7 uniform window, sample covariance, data range 1), the
headline figure in reports; :func:`ssim_gauss` is Wang et al.'s Gaussian 11x11 window (sigma 1.5,
population covariance), reported as ``ssim_gauss``. They differ by about 0.02 on typical renders. Both are
computed in float64, as scikit-image computes float64 images: in float32 the variances (E[x^2] - E[x]^2) lost
their digits on the flat backgrounds of renders (the shipped model on the demo's views: up to 2.7e-4 off scikit-image
a view, 8.8e-4 for the flat mean-colour baseline; the means over 88 views moved by 1.6e-4 and 3.3e-4). An image
smaller than the window has no SSIM in either convention (scikit-image refuses it): NaN, which reports write as
null, not the figure of a smaller window.

LPIPS uses the standard ImageNet VGG16 backbone and the LPIPS v0.1 linear layers, both loaded from
the offline weight cache (``python -m blender_mrvm fetch-weights``); a missing cache raises an
error naming that command - LPIPS is never computed with a random backbone.
Images are float tensors in [0, 1], (H, W, 3) or (N, H, W, 3).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


INTEGER_RANGES = {torch.uint8: 255.0, torch.uint16: 65535.0}
"""Integer images are scored as fractions of their type's range: a uint8 pair given to :func:`psnr` had been scored
as values in [0, 1] (-13.9 dB for a pair of 34.2)."""


def _nchw(x) -> torch.Tensor:
    """(H, W, C) or (N, H, W, C) images as float32 (N, C, H, W) in [0, 1]: uint8 and uint16 over their range, floats
    as they are (they are in [0, 1])."""
    x = torch.as_tensor(x)
    if not (x.is_floating_point() or x.dtype in INTEGER_RANGES):
        raise TypeError(f"images must be float in [0, 1], uint8 or uint16, got {x.dtype}")
    x = x.to(torch.float32) / INTEGER_RANGES[x.dtype] if x.dtype in INTEGER_RANGES else x.to(torch.float32)
    if x.ndim == 3:
        x = x[None]
    return x.permute(0, 3, 1, 2)


def psnr(pred, gt) -> torch.Tensor:
    """Per-image PSNR in dB (N,) for images in [0, 1]; identical images give +inf."""
    p, g = _nchw(pred), _nchw(gt)
    mse = ((p - g) ** 2).flatten(1).mean(1)
    return -10.0 * torch.log10(mse)


def _gauss(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    # float64: float32 weights sum to 1 only within 1e-8, which a flat background's variance E[x^2] - E[x]^2
    # turns into -1e-8 against SSIM's c2 = 9e-4 (up to 6.6e-6 off scikit-image on pairs of the demo's images)
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-x ** 2 / (2 * sigma ** 2))
    return g / g.sum()


def ssim(pred, gt, size: int = 7) -> torch.Tensor:
    """Per-image mean SSIM (N,) over RGB channels in scikit-image's default convention (pixelNeRF's):
    uniform ``size`` x ``size`` window, sample covariance (N / (N - 1)), data range 1, the mean over the
    valid region (scikit-image's crop of the padded border)."""
    k = torch.full((size,), 1.0 / size, dtype=torch.float64)
    return _ssim(_nchw(pred), _nchw(gt), k, size * size / (size * size - 1))


def ssim_gauss(pred, gt, size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Per-image mean SSIM (N,) with Wang et al.'s Gaussian window (11x11, sigma 1.5), population
    covariance, valid region, data range 1 (scikit-image's ``gaussian_weights=True``)."""
    return _ssim(_nchw(pred), _nchw(gt), _gauss(size, sigma), 1.0)


def _ssim(p: torch.Tensor, g: torch.Tensor, k: torch.Tensor, cov_norm: float) -> torch.Tensor:
    """Mean SSIM (N,) as float32, computed in float64; NaN for images smaller than the window."""
    size = k.numel()
    if min(p.shape[-2:]) < size:
        return torch.full((p.shape[0],), float("nan"))
    p, g = p.double(), g.double()
    C = p.shape[1]
    # the five local moments filtered as one stack, the window applied along rows then columns (it is separable):
    # float64 conv2d has no fast CPU kernel (both SSIMs of a 64 px image 2.3 -> 63 ms on one core, 0.19 -> 9 s at
    # 512 px); shifted sums take 3.3 ms and 0.6 s
    stats = _window_sums(torch.cat([p, g, p * p, g * g, p * g], 1), k)
    mu_p, mu_g, e_pp, e_gg, e_pg = stats.split(C, 1)
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    s_pp = cov_norm * (e_pp - mu_p ** 2)
    s_gg = cov_norm * (e_gg - mu_g ** 2)
    s_pg = cov_norm * (e_pg - mu_p * mu_g)
    m = ((2 * mu_p * mu_g + c1) * (2 * s_pg + c2)) / ((mu_p ** 2 + mu_g ** 2 + c1) * (s_pp + s_gg + c2))
    return m.flatten(1).mean(1).float()


def _window_sums(x: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
    """(N, M, H, W) ``x`` filtered by the separable window ``k`` (outer product of the 1-D taps), valid region."""
    n, (h, w) = k.numel(), x.shape[-2:]
    rows = sum(float(k[i]) * x[..., i:h - n + 1 + i, :] for i in range(n))
    return sum(float(k[i]) * rows[..., i:w - n + 1 + i] for i in range(n))


class LPIPS(nn.Module):
    """LPIPS v0.1 with the VGG16 backbone (Zhang et al. 2018), weights from the offline cache."""

    SHIFT = (-0.030, -0.088, -0.188)
    SCALE = (0.458, 0.448, 0.450)
    MIN_SIZE = 16
    """Smallest image side VGG's four 2x2 poolings leave a pixel of for relu5_3 (the reference implementation fails
    on smaller images too): below it :meth:`distance` is an InputError, not max_pool2d's RuntimeError."""

    def __init__(self):
        super().__init__()
        from .vgg import LPIPS_TAPS, load_lpips_lin, load_vgg16_features

        self.net = load_vgg16_features(LPIPS_TAPS[-1] + 1).eval()
        self.taps = LPIPS_TAPS
        self.lins = nn.ParameterList([nn.Parameter(w, requires_grad=False) for w in load_lpips_lin()])
        for p in self.net.parameters():
            p.requires_grad_(False)
        for i, layer in enumerate(self.net):  # each 3x3 kernel's centre, for inputs of one pixel (features)
            if isinstance(layer, nn.Conv2d) and layer.kernel_size == (3, 3) and layer.padding == (1, 1):
                self.register_buffer(f"centre{i}", layer.weight[:, :, 1:2, 1:2].detach().clone(), persistent=False)
        self.register_buffer("shift", torch.tensor(self.SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(self.SCALE).view(1, 3, 1, 1), persistent=False)

    def features(self, x01: torch.Tensor) -> list[torch.Tensor]:
        x = (x01 * 2.0 - 1.0 - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.net):
            centre = getattr(self, f"centre{i}", None)
            if centre is not None and x.shape[-2:] == (1, 1):
                # one pixel left (a 16 px patch after four pools): with zero padding only the kernel's centre
                # sees it, so the 3x3 convolution is the 1x1 one of its centre taps (the same numbers up to
                # rounding, a ninth of the weights to read: those reads bound these layers on a CPU, 3.5 ->
                # 0.24 ms for 4 patches at 512 channels)
                x = F.conv2d(x, centre, layer.bias)
            else:
                x = layer(x)
            if i in self.taps:
                out.append(x)
        return out

    def distance(self, pred: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
        """Per-image LPIPS (N,) of (N, 3, H, W) ``pred`` against (N or 1, 3, H, W) ``gt`` in [0, 1], with
        whatever gradients the inputs carry. Both go through VGG as one batch: the deep layers' 3x3 convolutions
        on small images are bound by reading their weights (9.4 MB a layer at 512 channels), so one batch of
        2N costs about what one image does (a 16 px patch pair forward and backward on one core: 22 ms against
        40 ms as two batches; 2 patch pairs 28 against 80 ms)."""
        if min(pred.shape[-2:]) < self.MIN_SIZE:
            from ..errors import InputError

            raise InputError(f"LPIPS-VGG needs images of at least {self.MIN_SIZE} px a side, got "
                             f"{pred.shape[-1]}x{pred.shape[-2]} (skip it: --no-lpips)")
        n = pred.shape[0]
        feats = self.features(torch.cat([pred, gt.to(pred.dtype)]))
        total = 0.0
        for f, w in zip(feats, self.lins):
            f = f / (f.norm(dim=1, keepdim=True) + 1e-10)
            total = total + F.conv2d((f[:n] - f[n:]) ** 2, w).mean(dim=(1, 2, 3))
        return total

    @torch.no_grad()
    def forward(self, pred, gt) -> torch.Tensor:
        """Per-image LPIPS (N,) for (N, H, W, 3) / (H, W, 3) images in [0, 1]."""
        return self.distance(_nchw(pred), _nchw(gt))
