"""Point samplers along box-clipped rays: stratified (coarse) and hierarchical inverse-CDF (fine).

Distances are measured from the box entry point (``RayBundle.origins``), so every ray's samples lie
in [0, far]. Rays that miss have far = 0 and are never passed here by the model, but the functions
stay finite for them anyway.
"""

from __future__ import annotations

import torch


def stratified(far: torch.Tensor, n: int, perturb: bool, generator: torch.Generator | None = None) -> torch.Tensor:
    """(R,) box lengths -> (R, n) sorted sample distances, one per equal bin (bin centres if not perturbed)."""
    far = far.float().clamp_min(0.0)
    edges = torch.linspace(0.0, 1.0, n + 1, device=far.device)
    lo, hi = edges[:-1], edges[1:]
    if perturb:
        u = torch.rand((far.shape[0], n), device=far.device, generator=generator)
    else:
        u = torch.full((far.shape[0], n), 0.5, device=far.device)
    return (lo + (hi - lo) * u) * far[:, None]


def bin_edges(t: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """(R, S) sample distances -> (R, S + 1) bin edges (midpoints, clamped to [0, far])."""
    mid = 0.5 * (t[..., 1:] + t[..., :-1])
    return torch.cat([torch.zeros_like(t[..., :1]), mid, far.float()[:, None]], dim=-1)


def sample_pdf(edges: torch.Tensor, weights: torch.Tensor, n: int, deterministic: bool,
               eps: float = 1e-5, generator: torch.Generator | None = None) -> torch.Tensor:
    """Inverse-CDF samples (R, n) from piecewise-constant weights (R, B) on bins ``edges`` (R, B + 1).

    ``eps`` is added to every weight, so all-zero (or NaN-free but tiny) weights give uniform samples;
    zero-width bins are handled without dividing by zero. Gradients do not flow through the samples.
    """
    edges = edges.detach().float()
    w = torch.nan_to_num(weights.detach().float(), nan=0.0, posinf=0.0).clamp_min(0.0) + eps
    pdf = w / w.sum(-1, keepdim=True)
    cdf = torch.cumsum(pdf, -1)
    cdf = torch.cat([torch.zeros_like(cdf[..., :1]), cdf], -1)  # (R, B + 1)
    cdf[..., -1] = 1.0
    R = edges.shape[0]
    if deterministic:
        u = torch.linspace(0.0, 1.0, n + 2, device=edges.device)[1:-1].expand(R, n).contiguous()
    else:
        u = torch.rand((R, n), device=edges.device, generator=generator)
    idx = torch.searchsorted(cdf, u, right=True)
    below = (idx - 1).clamp(0, cdf.shape[-1] - 1)
    above = idx.clamp(0, cdf.shape[-1] - 1)
    c0, c1 = torch.gather(cdf, -1, below), torch.gather(cdf, -1, above)
    b0, b1 = torch.gather(edges, -1, below), torch.gather(edges, -1, above)
    denom = c1 - c0
    frac = torch.where(denom > 0, (u - c0) / torch.where(denom > 0, denom, torch.ones_like(denom)),
                       torch.zeros_like(denom))
    out = b0 + frac.clamp(0.0, 1.0) * (b1 - b0)
    return torch.sort(out, dim=-1).values
