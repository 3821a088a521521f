"""MRVM: masked ray-and-view modeling (the auxiliary loss) and its schedule.

During pretraining, a share of the points of each ray in the *fine* branch (default 50%) is chosen;
for each chosen point a random non-empty subset of the views is replaced by a learned mask token
(``view_masking`` 'count': a uniform number 1..V of random views, as the official code; 'prob': each
view with ``view_mask_prob``). The fine branch's latent features go through an online projector and a
predictor; the target, without gradient, goes through a target projector that is an exponential
moving average of the online projector. Loss: 2 - 2 cos(prediction, target), averaged.

Targets (``target``): 'coarse' (the paper) - the coarse pass's own features at its own samples; the
fine pass evaluates the sorted union of coarse and fine samples, and the loss compares them at every
coarse sample's position in that union (masked or not: the official code averages over all of them).
'rerun' (the legacy arch) - the coarse branch re-run, unmasked, on the fine points; the loss at the
masked points.

Weight: 0 for the first ``warmup_frac`` of pretraining iterations, then a linear ramp to
``lambda_max`` at ``ramp_end_frac``, kept to the end of pretraining (official: 0 until 20k of 400k
steps, 0.1 from 25k on); 0 while finetuning.
"""

from __future__ import annotations

import copy

import torch
import torch.nn.functional as F
from torch import nn

from .config import MRVMConfig


def make_mask(R: int, S: int, V: int, cfg: MRVMConfig, generator: torch.Generator | None = None,
              device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """Random mask: (point_mask (R, S) bool, view_mask (R, S, V) bool).

    Exactly round(point_mask_ratio * S) points per ray are masked; each masked point masks a uniform
    number 1..V of its views ('count') or every view with probability view_mask_prob and always at least
    one ('prob'); unmasked points mask no view."""
    k = int(round(cfg.point_mask_ratio * S))
    scores = torch.rand((R, S), generator=generator, device=device)
    point = torch.zeros((R, S), dtype=torch.bool, device=device)
    if k > 0:
        point.scatter_(1, scores.topk(k, dim=1).indices, True)
    if cfg.view_masking == "count":  # a uniform number 1..V of the views, chosen at random
        rank = torch.rand((R, S, V), generator=generator, device=device).argsort(-1).argsort(-1)
        n = torch.randint(0, V, (R, S), generator=generator, device=device)
        return point, (rank <= n[..., None]) & point[..., None]
    views = torch.rand((R, S, V), generator=generator, device=device) < cfg.view_mask_prob
    forced = torch.randint(0, V, (R, S), generator=generator, device=device)
    views |= F.one_hot(forced, V).bool()
    return point, views & point[..., None]


def coarse_positions(order: torch.Tensor, n_coarse: int) -> torch.Tensor:
    """Where the coarse samples went: ``order`` (R, S) is the argsort that sorted ``cat([t_coarse, t_fine])``;
    returns (R, n_coarse), the index in the sorted union of each coarse sample, in coarse order."""
    return order.argsort(-1)[:, :n_coarse]


def lambda_at(step: int, pretrain_steps: int, cfg: MRVMConfig) -> float:
    """MRVM loss weight at ``step`` of a pretraining phase of ``pretrain_steps`` (0 after it)."""
    if not cfg.enabled or pretrain_steps <= 0 or step >= pretrain_steps:
        return 0.0
    frac = step / pretrain_steps
    if frac < cfg.warmup_frac:
        return 0.0
    span = cfg.ramp_end_frac - cfg.warmup_frac
    if span <= 0:
        return cfg.lambda_max
    return cfg.lambda_max * min(1.0, (frac - cfg.warmup_frac) / span)


def normalized_l2(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """2 - 2 cos(pred, target) per row (= squared distance of the unit vectors)."""
    return 2.0 - 2.0 * F.cosine_similarity(pred.float(), target.float(), dim=-1, eps=1e-6)


def _mlp(d_in: int, d_out: int, head: str = "ln_gelu", hidden: int = 0) -> nn.Sequential:
    """The head's MLP (``MRVMConfig.head``): 'ln_gelu' with a hidden layer 2x ``d_in``; 'bn_relu' with ``hidden``."""
    if head == "bn_relu":
        return nn.Sequential(nn.Linear(d_in, hidden), nn.BatchNorm1d(hidden), nn.ReLU(), nn.Linear(hidden, d_out))
    return nn.Sequential(nn.Linear(d_in, 2 * d_in), nn.LayerNorm(2 * d_in), nn.GELU(), nn.Linear(2 * d_in, d_out))


class MRVMHead(nn.Module):
    """Online projector + predictor (fine branch) and the EMA target projector (coarse branch)."""

    def __init__(self, d_model: int, cfg: MRVMConfig):
        super().__init__()
        self.cfg = cfg
        self.projector = _mlp(d_model, cfg.proj_dim, cfg.head, d_model)  # official: MLP(d, d, proj)
        self.predictor = _mlp(cfg.proj_dim, cfg.proj_dim, cfg.head, 2 * cfg.proj_dim)  # MLP(proj, 2 proj, proj)
        self.target_projector = copy.deepcopy(self.projector)
        for p in self.target_projector.parameters():
            p.requires_grad_(False)

    @torch.no_grad()
    def update_target(self, momentum: float | None = None) -> None:
        m = self.cfg.ema_momentum if momentum is None else momentum
        for pt, po in zip(self.target_projector.parameters(), self.projector.parameters()):
            pt.mul_(m).add_(po.detach(), alpha=1.0 - m)
        for bt, bo in zip(self.target_projector.buffers(), self.projector.buffers()):  # BatchNorm's statistics
            if bt.dtype.is_floating_point:
                bt.mul_(m).add_(bo.detach(), alpha=1.0 - m)

    def loss(self, fine_latent: torch.Tensor, coarse_latent: torch.Tensor, reduce: bool = True) -> torch.Tensor:
        """Mean 2 - 2cos over the given (masked) points; both (N, D). 0 (with grad) when N == 0. ``reduce`` False:
        the (N,) values of the points."""
        if fine_latent.shape[0] == 0:
            return fine_latent.sum() * 0.0 if reduce else fine_latent.sum(-1) * 0.0
        pred = self.predictor(self.projector(fine_latent))
        with torch.no_grad():
            target = self.target_projector(coarse_latent.detach())
        per_point = normalized_l2(pred, target.detach())
        return per_point.mean() if reduce else per_point
