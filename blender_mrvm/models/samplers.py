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


def disparity(far: torch.Tensor, offset: torch.Tensor, near: float, n: int, perturb: bool,
              generator: torch.Generator | None = None) -> torch.Tensor:
    """(R,) box lengths and (R,) camera-to-box-entry distances -> (R, n) sorted sample distances from the
    box entry, one per equal bin of *inverse depth* (disparity) between the near plane and the box exit.

    Depth is measured from the camera: the samples run from ``max(near, offset)`` (the near plane, or the
    box entry when the camera is farther than ``near`` from the box) to ``offset + far`` (the exit), with
    their reciprocals evenly spaced (bin centres if not perturbed), so they are evenly spaced along the
    epipolar line of a reference camera near the target camera (as the light-field / LLFF code samples real
    scenes between the data's near and far bounds). A near plane beyond the exit falls back to the entry.
    Returned distances are from the box entry (``t - offset``), in [0, far], float32 like :func:`stratified`.
    """
    far = far.double().clamp_min(0.0)
    off = offset.double().clamp_min(0.0)
    t1 = off + far
    t0 = torch.maximum(off, torch.full_like(off, float(near)))
    t0 = torch.where(t0 < t1, t0, off)
    ok = t0 > 0  # a ray starting at the camera with no near plane cannot be spaced in disparity: linear
    d0 = 1.0 / torch.where(ok, t0, torch.ones_like(t0))
    d1 = 1.0 / torch.where(ok, t1, torch.ones_like(t1)).clamp_min(1e-300)
    edges = torch.linspace(0.0, 1.0, n + 1, device=far.device, dtype=torch.float64)
    lo, hi = edges[:-1], edges[1:]
    if perturb:
        u = torch.rand((far.shape[0], n), device=far.device, generator=generator).double()
    else:
        u = torch.full((far.shape[0], n), 0.5, device=far.device, dtype=torch.float64)
    s = lo + (hi - lo) * u  # (R, n) in [0, 1], increasing
    disp = d0[:, None] + s * (d1 - d0)[:, None]
    t = 1.0 / disp - off[:, None]
    lin = s * far[:, None]
    t = torch.where(ok[:, None], t, lin)
    t = torch.minimum(t.clamp_min(0.0), far[:, None])
    return t.float()


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


def stop_counts(t_coarse: torch.Tensor, trans_coarse: torch.Tensor, t_fine: torch.Tensor, min_trans: float,
                quantum: int = 1) -> torch.Tensor | None:
    """Early ray termination: how many of each ray's sorted fine-pass samples to evaluate.

    ``trans_coarse`` (R, Sc) is the coarse pass's transmittance at its samples ``t_coarse`` (R, Sc) (the light
    that reaches each one). A ray stops at its first coarse sample reached by less than ``min_trans``: what
    lies there and beyond adds less than ``min_trans`` to its colour by the coarse pass's account. Returns
    (R,) counts of the fine samples ``t_fine`` (R, S, sorted) in front of that point, rounded up to a multiple
    of ``quantum`` (so rays fall into few groups of equal length), at least one quantum and at most S; None
    when every ray keeps all S (nothing to skip) or ``min_trans`` is 0 (off)."""
    R, S = t_fine.shape
    if min_trans <= 0 or R == 0 or S == 0:
        return None
    stopped = trans_coarse < min_trans
    first = torch.where(stopped.any(-1), stopped.float().argmax(-1), torch.full((R,), -1, device=t_fine.device))
    t_stop = torch.where(first >= 0, torch.gather(t_coarse, 1, first.clamp_min(0)[:, None])[:, 0],
                         torch.full((R,), float("inf"), device=t_fine.device, dtype=t_coarse.dtype))
    keep = (t_fine < t_stop[:, None]).sum(-1)
    q = max(1, int(quantum))
    keep = ((keep + q - 1) // q * q).clamp(min(q, S), S)
    return None if bool((keep == S).all()) else keep
