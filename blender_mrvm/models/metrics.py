"""Image metrics: PSNR, SSIM and LPIPS-VGG (v0.1).

SSIM comes in two conventions. :func:`ssim` is pixelNeRF's (it calls scikit-image's
``structural_similarity`` with its defaults: 7x7 uniform window, sample covariance, data range 1), the
headline figure in reports; :func:`ssim_gauss` is Wang et al.'s Gaussian 11x11 window (sigma 1.5,
population covariance), reported as ``ssim_gauss``. They differ by about 0.02 on typical renders.

LPIPS uses the standard ImageNet VGG16 backbone and the LPIPS v0.1 linear layers, both loaded from
the offline weight cache (``python -m blender_mrvm fetch-weights``); a missing cache raises an
error naming that command - LPIPS is never computed with a random backbone.
Images are float tensors in [0, 1], (H, W, 3) or (N, H, W, 3).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


def _nchw(x: torch.Tensor) -> torch.Tensor:
    x = torch.as_tensor(x, dtype=torch.float32)
    if x.ndim == 3:
        x = x[None]
    return x.permute(0, 3, 1, 2)


def psnr(pred, gt) -> torch.Tensor:
    """Per-image PSNR in dB (N,) for images in [0, 1]; identical images give +inf."""
    p, g = _nchw(pred), _nchw(gt)
    mse = ((p - g) ** 2).flatten(1).mean(1)
    return -10.0 * torch.log10(mse)


def _gauss(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float32) - (size - 1) / 2
    g = torch.exp(-x ** 2 / (2 * sigma ** 2))
    return g / g.sum()


def ssim(pred, gt, size: int = 7) -> torch.Tensor:
    """Per-image mean SSIM (N,) over RGB channels in scikit-image's default convention (pixelNeRF's):
    uniform ``size`` x ``size`` window, sample covariance (N / (N - 1)), data range 1, the mean over the
    valid region (scikit-image's crop of the padded border)."""
    p = _nchw(pred)
    size = min(size, p.shape[-1], p.shape[-2])
    k = torch.full((size,), 1.0 / size)
    return _ssim(p, _nchw(gt), k, size * size / max(size * size - 1, 1))


def ssim_gauss(pred, gt, size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Per-image mean SSIM (N,) with Wang et al.'s Gaussian window (11x11, sigma 1.5), population
    covariance, valid region, data range 1."""
    p = _nchw(pred)
    size = min(size, p.shape[-1], p.shape[-2])
    return _ssim(p, _nchw(gt), _gauss(size, sigma), 1.0)


def _ssim(p: torch.Tensor, g: torch.Tensor, k: torch.Tensor, cov_norm: float) -> torch.Tensor:
    C = p.shape[1]
    size = k.numel()
    win = (k[:, None] * k[None, :]).expand(C, 1, size, size).contiguous()

    def filt(x):
        return F.conv2d(x, win, groups=C)

    c1, c2 = 0.01 ** 2, 0.03 ** 2
    mu_p, mu_g = filt(p), filt(g)
    s_pp = cov_norm * (filt(p * p) - mu_p ** 2)
    s_gg = cov_norm * (filt(g * g) - mu_g ** 2)
    s_pg = cov_norm * (filt(p * g) - mu_p * mu_g)
    m = ((2 * mu_p * mu_g + c1) * (2 * s_pg + c2)) / ((mu_p ** 2 + mu_g ** 2 + c1) * (s_pp + s_gg + c2))
    return m.flatten(1).mean(1)


class LPIPS(nn.Module):
    """LPIPS v0.1 with the VGG16 backbone (Zhang et al. 2018), weights from the offline cache."""

    SHIFT = (-0.030, -0.088, -0.188)
    SCALE = (0.458, 0.448, 0.450)

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
