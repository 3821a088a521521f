"""NeRFormer as published (arch ``nerformer``): per-view token streams, ray and view attention alternating.

Every (ray, sample, reference view) has its own token, so a ray carries one token stream per view,
shaped (R, S, V, d). Token input per view: the pixel-aligned feature, the reference pixel colour, and
the relative direction (unit difference of the target and reference ray directions, and their dot
product); a positional code of the point (harmonic, in the normalised box frame) and of the target
viewing direction, through a small MLP, is added to every view's token. Each layer pair is a view
transformer block (per point, across the views that see it) followed by a ray transformer block (per
view, along the ray's samples). At the end the streams are pooled over the views with softmax weights
from a learned score, and a head maps the pooled feature to density and colour (``direct``, the paper)
or to density and a softmax blend of the visible reference colours and a predicted colour (``blend``).

Views where a point projects behind the camera or outside the image are padding: such a token is no key
of view attention (across views) nor of ray attention (along its view's stream) and takes no part in
pooling, so a view that sees nothing changes nothing. A point that
no view sees takes a learned feature instead of the pool (never a 0/0). MRVM replaces chosen (point,
view) tokens by a learned mask token before the position code is added (as the official code does).
Attention is the fused ``scaled_dot_product_attention``; no Python loop runs over rays, samples or views.
"""

from __future__ import annotations

import torch
from torch import nn

from .config import NeRFormerConfig
from .nerformer import Block, harmonic, harmonic_dim

REL_DIM = 4
"""Relative-direction input per view: unit (target dir - reference dir) and their dot product."""


def relative_direction(d_target: torch.Tensor, d_ref: torch.Tensor) -> torch.Tensor:
    """(..., 3) unit target and reference ray directions -> (..., 4): unit difference and dot product."""
    diff = d_target - d_ref
    unit = diff / diff.norm(dim=-1, keepdim=True).clamp_min(1e-6)
    return torch.cat([unit, (d_target * d_ref).sum(-1, keepdim=True)], -1)


class StreamBranch(nn.Module):
    """One branch (coarse or fine) of the paper's NeRFormer."""

    def __init__(self, cfg: NeRFormerConfig, feat_dim: int, n_layers: int):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.feat_proj = nn.Linear(feat_dim, d)
        self.token_proj = nn.Linear(d + 3 + REL_DIM, d)
        pos_in = harmonic_dim(3, cfg.pos_freqs) + harmonic_dim(3, cfg.dir_freqs)
        self.pos_proj = nn.Sequential(nn.Linear(pos_in, d), nn.ReLU(), nn.Linear(d, d))
        self.mask_token = nn.Parameter(torch.randn(d) * 0.02)
        self.unseen = nn.Parameter(torch.zeros(d))
        self.view_blocks = nn.ModuleList(Block(d, cfg.n_heads, cfg.ffn_mult) for _ in range(n_layers))
        self.ray_blocks = nn.ModuleList(Block(d, cfg.n_heads, cfg.ffn_mult) for _ in range(n_layers))
        self.norm = nn.LayerNorm(d)
        self.view_score = nn.Linear(d, 1)
        self.head = nn.Sequential(nn.Linear(d, d // 2 if d >= 8 else d), nn.ReLU(),
                                  nn.Linear(d // 2 if d >= 8 else d, 4))
        if cfg.color_head == "blend":
            self.blend = nn.Linear(d, 1)

    def forward(self, feats: torch.Tensor, ref_rgb: torch.Tensor, rel_dir: torch.Tensor, valid: torch.Tensor,
                points: torch.Tensor, dirs: torch.Tensor, view_mask: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """feats (R, S, V, F), ref_rgb (R, S, V, 3), rel_dir (R, S, V, 4), valid (R, S, V) bool, points (R, S, 3)
        in the normalised frame, dirs (R, 3) unit target directions, view_mask (R, S, V) bool or None.

        Returns raw density (R, S), colour (R, S, 3) in [0, 1] and the pooled per-point feature (R, S, d)."""
        R, S, V, _ = feats.shape
        d = self.cfg.d_model
        vf = valid[..., None].to(feats.dtype)
        # feats arrives as a permuted view of the sampled maps: a Linear on it does not fold into one matrix
        # product without a grad (torch.matmul broadcasts the weight into a batched product over every point: on an
        # H200, 76 kernels and a fifth of a 256 px view's device time, session 20), so give it rows
        f = self.feat_proj(feats.reshape(R * S * V, feats.shape[-1])).view(R, S, V, d)
        x = self.token_proj(torch.cat([f, ref_rgb, rel_dir], -1)) * vf
        if view_mask is not None:
            x = torch.where(view_mask[..., None], self.mask_token.to(x.dtype).expand_as(x), x)
        code = torch.cat([harmonic(points, self.cfg.pos_freqs),
                          harmonic(dirs, self.cfg.dir_freqs)[:, None, :].expand(R, S, -1)], -1)
        x = x + self.pos_proj(code.to(x.dtype))[:, :, None, :]  # (R, S, V, d)
        view_keys = valid.reshape(R * S, V)
        ray_keys = valid.transpose(1, 2).reshape(R * V, S)
        for vb, rb in zip(self.view_blocks, self.ray_blocks):
            x = vb(x.reshape(R * S, V, d), view_keys).view(R, S, V, d)  # across views, per point
            x = rb(x.transpose(1, 2).reshape(R * V, S, d), ray_keys).view(R, V, S, d).transpose(1, 2)  # along the ray, per view
        x = self.norm(x)
        seen = valid.any(-1)  # (R, S)
        score = self.view_score(x)[..., 0].float().masked_fill(~valid, float("-inf"))
        w = torch.softmax(torch.where(seen[..., None], score, torch.zeros_like(score)), -1) * valid
        pooled = (w.to(x.dtype)[..., None] * x).sum(2)
        latent = torch.where(seen[..., None], pooled, self.unseen.to(pooled.dtype).expand_as(pooled))
        out = self.head(latent)
        sigma_raw = out[..., 3]
        own = torch.sigmoid(out[..., :3].float())
        if self.cfg.color_head == "blend":
            ok = valid if view_mask is None else valid & ~view_mask
            logits = self.blend(x)[..., 0].float().masked_fill(~ok, torch.finfo(torch.float32).min)
            own_logit = torch.zeros_like(logits[..., :1])  # the predicted colour is always available
            bw = torch.softmax(torch.cat([own_logit, logits], -1), -1)
            rgb = bw[..., :1] * own + (bw[..., 1:, None] * ref_rgb.float()).sum(-2)
        else:
            rgb = own
        return {"sigma_raw": sigma_raw, "rgb": rgb, "latent": latent}
