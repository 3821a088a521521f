"""Numerically safe volume rendering (white background by default).

Per sample i with density sigma_i and step delta_i (the last step is infinite):

- optical depth   tau_i = sigma_i * delta_i, defined as 0 where sigma_i == 0 (no 0 * inf)
- alpha           alpha_i = -expm1(-tau_i)            (exact for tiny tau, 1 for tau = inf)
- transmittance   T_i = exp(-sum_{j<i} tau_j)         (exclusive cumulative sum in log space)
- weight          w_i = T_i * alpha_i

The sums run in float32 even under autocast. An empty ray (all densities 0) has weights 0,
accumulation 0 and colour = background; a ray with no samples is background too.
"""

from __future__ import annotations

import torch


def deltas_from_t(t: torch.Tensor, last=float("inf")) -> torch.Tensor:
    """(..., S) sample distances -> (..., S) steps; the last one is ``last`` (a float, infinite by
    default, or a (...,) tensor such as the distance to the box exit)."""
    d = t[..., 1:] - t[..., :-1]
    if isinstance(last, torch.Tensor):
        tail = last.to(t.dtype).reshape(t.shape[:-1] + (1,))
    else:
        tail = torch.full_like(t[..., :1], last)
    return torch.cat([d, tail], dim=-1).clamp_min(0.0)


def render_weights(sigma: torch.Tensor, deltas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Weights w (..., S) and transmittance T (..., S) from densities and steps."""
    sigma = sigma.float().clamp_min(0.0)
    deltas = deltas.float()
    tau = torch.where(sigma > 0, sigma * deltas, torch.zeros_like(sigma))
    tau = torch.nan_to_num(tau, nan=0.0, posinf=float("inf"))
    alpha = -torch.expm1(-tau)
    # Exclusive cumulative sum by shifting (never inf - inf).
    excl = torch.cumsum(torch.cat([torch.zeros_like(tau[..., :1]), tau[..., :-1]], dim=-1), dim=-1)
    trans = torch.exp(-excl)
    return trans * alpha, trans


def composite(weights: torch.Tensor, rgb: torch.Tensor, t: torch.Tensor, white_background: bool = True):
    """Colour (..., 3), expected depth (...,) and accumulation (...,) from weights (..., S).

    Depth of an empty ray is the last sample distance (0 when there are no samples)."""
    weights = weights.float()
    acc = weights.sum(-1)
    color = (weights[..., None] * rgb.float()).sum(-2)
    if white_background:
        color = color + (1.0 - acc)[..., None]
    if t.shape[-1] == 0:
        depth = torch.zeros_like(acc)
    else:
        depth = (weights * t.float()).sum(-1) + (1.0 - acc).clamp_min(0.0) * t[..., -1].float()
    return color, depth, acc


def volume_render(sigma: torch.Tensor, rgb: torch.Tensor, t: torch.Tensor, white_background: bool = True,
                  last_delta=float("inf")):
    """Full rendering: returns dict(color, depth, acc, weights, transmittance)."""
    w, trans = render_weights(sigma, deltas_from_t(t.float(), last_delta))
    color, depth, acc = composite(w, rgb, t, white_background)
    return {"color": color, "depth": depth, "acc": acc, "weights": w, "transmittance": trans}
