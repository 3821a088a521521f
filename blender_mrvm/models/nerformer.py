"""NeRFormer-style implicit function: per 3D point, attention across reference views, then along the ray.

Per point and view the token input is [pixel-aligned feature, reference pixel colour, harmonic code
of (target direction - reference direction), their dot product]. A learned summary token (``cls``)
is prepended to the view sequence: it is never masked, so a point seen by no view (behind every
camera, outside every image) still attends to something and nothing divides by zero. After each
view-attention layer the summary tokens of a ray attend to each other along the ray (with a
harmonic code of the sample distance). Heads: density from the summary token; colour as a softmax
blend of the visible reference colours plus a predicted colour (IBRNet/NeRFormer style).
MRVM replaces chosen (point, view) tokens by a learned mask token before the first layer.
"""

from __future__ import annotations

import math
import os

import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from .config import NeRFormerConfig


CUDNN_ATTENTION_ENV = "MRVM_CUDNN_ATTENTION"
"""Set to 1 to let ``scaled_dot_product_attention`` use cuDNN's kernels on a GPU (off by default: see
:func:`configure_attention`)."""


def configure_attention() -> bool:
    """Keep cuDNN's attention out of ``scaled_dot_product_attention`` (process-wide; flash, memory-efficient
    and math kernels remain), unless ``MRVM_CUDNN_ATTENTION=1``; returns whether cuDNN's is allowed.

    Why: on Hopper GPUs torch prefers cuDNN's attention in bf16 / fp16, which builds a cuDNN graph for each
    new tensor shape (28-35 ms of host time per call in session 20's H200 profile). Our attention batches are shaped by how many rays
    hit the object's box, which changes with every object and view, so a graph was built on nearly every call:
    session 18 measured bf16 training 3-4x slower than fp32 with the GPU idle (`balanced` 8 x 1024: 0.60 against
    2.52 steps/s, 7 % against 32 % utilisation), and only for presets whose head width cuDNN takes (a multiple
    of 8: not `fast`'s 12, whose bf16 slowdown was small). With it off, on an H200, bf16 trained 1.4-2.5x faster
    and `accurate` at 16 x 4096 1.28x faster than fp32 (docs/bench_gpu/session20/). Called whenever a model is built
    (``registry.build_model``); a no-op on a machine without CUDA."""
    allowed = os.environ.get(CUDNN_ATTENTION_ENV, "0") == "1"
    if hasattr(torch.backends.cuda, "enable_cudnn_sdp"):
        torch.backends.cuda.enable_cudnn_sdp(allowed)
    return allowed


SHORT_ATTENTION_ENV = "MRVM_SHORT_ATTENTION"
SHORT_ATTENTION_CUDA = 16
"""At inference on a GPU, sequences of at most this many tokens attend through :func:`short_attention` (the view
attention's 2-3 tokens, and the ray attention of presets with at most 16 samples a pass: `fast`'s 8 + 8, `balanced`'s
12 coarse). Measured on an H100 (session 23, docs/bench_gpu/session23/), `fast` at 256 px: the fused kernel's
64 x 64 tiles over such sequences were a third of the device time; written out, eager 16.9 -> 20.4 FPS and compiled
22.7 -> 40.7 FPS (46.7 with CUDA graphs), device time 34.2 -> 16.3 ms."""


def _short_from_env() -> int | str | None:
    raw = os.environ.get(SHORT_ATTENTION_ENV, "").strip()
    if not raw:
        return None
    try:
        return int(raw)
    except ValueError:
        return raw  # reported (one line, exit 2) when a model first attends, not as a traceback at import


SHORT_ATTENTION_MAX: int | str | None = _short_from_env()
"""``MRVM_SHORT_ATTENTION=N`` forces the written-out form for sequences of at most N tokens everywhere (0 = never);
unset (None), :func:`short_attention_max` decides by device and grad mode."""


def short_attention_max(x: torch.Tensor) -> int:
    """The longest sequence that attends through :func:`short_attention` for input ``x``: ``SHORT_ATTENTION_MAX`` when
    set; else :data:`SHORT_ATTENTION_CUDA` at inference on a GPU, and 0 (the fused kernel) on the CPU, where the
    fused kernel is faster (CPU training 5 % slower written out, session 22), and in training, where the written-out
    form's (B, heads, L, L, d) products cost memory and its speed on a GPU is unmeasured."""
    m = SHORT_ATTENTION_MAX
    if m is not None:
        if isinstance(m, str) or m < 0:
            raise InputError(f"{SHORT_ATTENTION_ENV}={m}: give a whole number of tokens, 0 or more (0 = the fused "
                             "kernel always), or leave it unset")
        return m
    return SHORT_ATTENTION_CUDA if x.is_cuda and not torch.is_grad_enabled() else 0


def short_attention(q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Scaled dot-product attention written out for short sequences: q, k, v (B, h, L, dh), ``mask`` broadcastable
    to (B, h, L, L) bool (True = attend) or None. Elementwise products and sums that torch.compile fuses; the same
    result as ``scaled_dot_product_attention`` (softmax in float32)."""
    s = (q[..., :, None, :] * k[..., None, :, :]).sum(-1).float() * q.shape[-1] ** -0.5  # (B, h, L, L)
    if mask is not None:
        s = s.masked_fill(~mask, float("-inf"))
    w = torch.softmax(s, -1).to(v.dtype)
    return (w[..., None] * v[..., None, :, :]).sum(-2)


def harmonic(x: torch.Tensor, n_freqs: int) -> torch.Tensor:
    """[x, sin(2^k pi x), cos(2^k pi x)] for k < n_freqs along the last axis."""
    if n_freqs == 0:
        return x
    freqs = (2.0 ** torch.arange(n_freqs, device=x.device, dtype=x.dtype)) * math.pi
    xb = (x[..., None] * freqs).flatten(-2)
    return torch.cat([x, torch.sin(xb), torch.cos(xb)], -1)


def harmonic_dim(d: int, n_freqs: int) -> int:
    return d * (1 + 2 * n_freqs)


class Attention(nn.Module):
    """Multi-head self-attention with a key validity mask; a fully masked row gives uniform weights, never NaN."""

    def __init__(self, d: int, heads: int):
        super().__init__()
        self.h = heads
        self.qkv = nn.Linear(d, 3 * d)
        self.out = nn.Linear(d, d)

    def forward(self, x: torch.Tensor, key_valid: torch.Tensor | None = None) -> torch.Tensor:
        B, L, D = x.shape
        q, k, v = self.qkv(x).view(B, L, 3, self.h, D // self.h).permute(2, 0, 3, 1, 4)
        mask = None
        if key_valid is not None:
            # A sequence with no valid key attends uniformly: a zero query scores every key alike.
            any_valid = key_valid.any(-1)
            q = q * any_valid.to(q.dtype)[:, None, None, None]
            mask = (key_valid | ~any_valid[:, None])[:, None, None, :]
        if L <= short_attention_max(x):
            y = short_attention(q, k, v, mask)
        else:
            y = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)  # fused; 2-3x the speed of matmul+softmax on CPU
        return self.out(y.transpose(1, 2).reshape(B, L, D))


class Block(nn.Module):
    """Pre-norm transformer block."""

    def __init__(self, d: int, heads: int, ffn_mult: int):
        super().__init__()
        self.n1, self.n2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.attn = Attention(d, heads)
        self.ffn = nn.Sequential(nn.Linear(d, ffn_mult * d), nn.GELU(), nn.Linear(ffn_mult * d, d))

    def forward(self, x, key_valid=None):
        x = x + self.attn(self.n1(x), key_valid)
        return x + self.ffn(self.n2(x))

    def make_identity(self) -> None:
        """Zero the output layers of both residual branches: the block then passes its input through unchanged
        (a block added to a trained model starts as the identity; it still learns, since those output layers
        receive gradients)."""
        with torch.no_grad():
            for lin in (self.attn.out, self.ffn[-1]):
                lin.weight.zero_()
                lin.bias.zero_()


class NeRFormerBranch(nn.Module):
    """One branch (coarse or fine) of the implicit function."""

    def __init__(self, cfg: NeRFormerConfig, feat_dim: int):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.dir_dim = harmonic_dim(3, cfg.dir_freqs) + 1
        self.in_proj = nn.Sequential(nn.Linear(feat_dim + 3 + self.dir_dim, d), nn.GELU(), nn.Linear(d, d))
        self.cls_token = nn.Parameter(torch.zeros(d))
        self.mask_token = nn.Parameter(torch.randn(d) * 0.02)
        self.depth_proj = nn.Linear(harmonic_dim(1, cfg.depth_freqs), d)
        self.view_blocks = nn.ModuleList(Block(d, cfg.n_heads, cfg.ffn_mult) for _ in range(cfg.n_layers))
        self.ray_blocks = nn.ModuleList(Block(d, cfg.n_heads, cfg.ffn_mult) for _ in range(cfg.n_layers))
        self.norm = nn.LayerNorm(d)
        self.density = nn.Sequential(nn.Linear(d, d), nn.GELU(), nn.Linear(d, 1))
        self.blend = nn.Linear(d, 1)
        self.color = nn.Linear(d, 3)

    def forward(self, inputs: torch.Tensor, valid: torch.Tensor, ref_rgb: torch.Tensor, t: torch.Tensor,
                view_mask: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """inputs (R, S, V, F), valid (R, S, V), ref_rgb (R, S, V, 3), t (R, S), view_mask (R, S, V) or None.

        Returns raw density (R, S), colour (R, S, 3) and the latent per-point feature (R, S, D)."""
        R, S, V, _ = inputs.shape
        d = self.cfg.d_model
        x = self.in_proj(inputs) * valid[..., None].to(inputs.dtype)
        if view_mask is not None:
            x = torch.where(view_mask[..., None], self.mask_token.to(x.dtype).expand_as(x), x)
        cls = self.cls_token.to(x.dtype).expand(R, S, 1, d)
        tok = torch.cat([cls, x], 2).reshape(R * S, V + 1, d)
        key_valid = torch.cat([torch.ones_like(valid[..., :1]), valid], -1).reshape(R * S, V + 1)
        if view_mask is not None:  # a masked token is an input (the mask token) even where the view sees nothing
            key_valid = key_valid | torch.cat([torch.zeros_like(view_mask[..., :1]), view_mask], -1).reshape(R * S, V + 1)
        depth_code = self.depth_proj(harmonic(t[..., None].to(x.dtype), self.cfg.depth_freqs))  # (R, S, d)
        for i, (vb, rb) in enumerate(zip(self.view_blocks, self.ray_blocks)):
            tok = vb(tok, key_valid)
            summary = tok[:, 0].reshape(R, S, d)
            if i == 0:
                summary = summary + depth_code
            summary = rb(summary)
            tok = torch.cat([summary.reshape(R * S, 1, d), tok[:, 1:]], 1)
        tok = self.norm(tok)
        latent = tok[:, 0].reshape(R, S, d)
        sigma_raw = self.density(latent)[..., 0]
        # Colour: blend visible, unmasked reference colours + one predicted colour (always available).
        logits = self.blend(tok).reshape(R, S, V + 1).float()
        blend_ok = valid if view_mask is None else valid & ~view_mask
        ok = torch.cat([torch.ones_like(blend_ok[..., :1]), blend_ok], -1)
        logits = logits.masked_fill(~ok, torch.finfo(logits.dtype).min)
        w = torch.softmax(logits, -1)
        own = torch.sigmoid(self.color(latent).float())
        rgb = w[..., :1] * own + (w[..., 1:, None] * ref_rgb.float()).sum(-2)
        return {"sigma_raw": sigma_raw, "rgb": rgb, "latent": latent}


def activate_density(raw: torch.Tensor, kind: str, bias: float) -> torch.Tensor:
    x = raw.float() + bias
    return F.softplus(x) if kind == "softplus" else F.relu(x)
