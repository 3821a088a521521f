"""Typed, frozen model configs and the named presets ``fast`` / ``balanced`` / ``accurate`` / ``paper``.

Every field has a one-line docstring. Presets are whole named configs (:data:`PRESETS`), not
defaults scattered through the code; :func:`model_config` builds one and applies overrides.
Configs round-trip through plain dicts (:func:`to_dict` / :func:`from_dict`) so a checkpoint can
carry the exact config it was trained with.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Any, get_type_hints

from ..errors import InputError


@dataclass(frozen=True)
class EncoderConfig:
    """Image encoder giving pixel-aligned multi-scale features."""

    backbone: str = "resnet"
    """'resnet' (small ResNet-like, trained from scratch) or 'vgg16' (ImageNet VGG16 blocks 1-3, offline weights)."""
    widths: tuple[int, ...] = (32, 48, 64)
    """Channels of each scale (strides 2, 4, 8) for the resnet backbone."""
    blocks_per_stage: int = 1
    """Residual blocks per scale for the resnet backbone."""
    out_dim: int = 64
    """Channels of the fused per-point feature after concatenating the sampled scales."""
    pretrained: bool = False
    """For 'vgg16': initialise from the cached ImageNet weights (``fetch-weights``); ignored for 'resnet'."""
    freeze_backbone: bool = False
    """For 'vgg16': keep the backbone's weights fixed (only the 1x1 fusion layer trains); False fine-tunes it."""


@dataclass(frozen=True)
class SamplerConfig:
    """Point sampling along rays clipped to the object's box."""

    n_coarse: int = 16
    """Stratified samples per ray inside the box (coarse branch)."""
    n_fine: int = 16
    """Importance (inverse-CDF) samples per ray (fine branch)."""
    fine_includes_coarse: bool = True
    """Fine branch evaluates coarse + fine samples (NeRF); False evaluates the fine samples only."""
    perturb: bool = True
    """Jitter stratified samples during training (evaluation is always deterministic)."""
    box_padding: float = 0.05
    """Box grown by this fraction of its half-size on each side before clipping rays."""
    pdf_eps: float = 1e-5
    """Weight added to every bin before inverse-CDF sampling (all-zero weights give uniform samples)."""


ARCHS = ("legacy", "nerformer")
"""Implicit-function architectures: 'nerformer' = the paper's per-view token streams, 'legacy' = the first
version (one summary token per point travels along the ray), kept so its checkpoints load unchanged."""


@dataclass(frozen=True)
class NeRFormerConfig:
    """NeRFormer-style implicit function: attention across views, then along the ray."""

    arch: str = "legacy"
    """'nerformer' (per-view token streams, ray and view attention alternating, pooled over views: the paper)
    or 'legacy' (one summary token per point along the ray). Configs that predate the field are 'legacy'."""
    d_model: int = 32
    """Token width."""
    n_heads: int = 2
    """Attention heads (d_model must be divisible by it)."""
    n_layers: int = 1
    """(view attention, ray attention) layer pairs per branch (the coarse branch's, when fine_layers is set)."""
    fine_layers: int = 0
    """Layer pairs of the fine branch ('nerformer' arch; 0 = n_layers). The paper: coarse 4, fine 5."""
    pos_freqs: int = 6
    """Harmonic frequencies of the point's position in the normalised box frame ('nerformer' arch)."""
    color_head: str = "direct"
    """'nerformer' arch colour: 'direct' (regressed from the pooled feature, the paper) or 'blend' (a softmax
    blend of the visible reference colours and a predicted colour, IBRNet-style)."""
    ffn_mult: int = 2
    """Feed-forward hidden width as a multiple of d_model."""
    dir_freqs: int = 2
    """Harmonic frequencies of the target/reference view-direction difference ('legacy') or of the target
    viewing direction ('nerformer')."""
    depth_freqs: int = 4
    """Harmonic frequencies of the normalised sample depth (ray-attention position code)."""
    share_coarse_fine: bool = False
    """Use one network for both branches (MRVM needs separate ones; kept for ablations)."""


@dataclass(frozen=True)
class MRVMConfig:
    """Masked ray-and-view modeling: an auxiliary latent-reconstruction loss on the fine branch."""

    enabled: bool = True
    """Apply masking + the MRVM loss during the pretraining phase."""
    point_mask_ratio: float = 0.5
    """Share of the points of each ray whose features are masked."""
    view_mask_prob: float = 0.5
    """'prob' view masking: each view of a masked point is masked with this probability (at least one always is)."""
    view_masking: str = "prob"
    """How many views of a masked point are masked: 'count' = a uniform number 1..V of random views (the
    official code), 'prob' = each with view_mask_prob."""
    target: str = "rerun"
    """MRVM target: 'coarse' = the coarse branch's features at its own samples, the loss at those positions
    of the fine (masked) pass, which evaluates coarse + fine samples (the paper); 'rerun' = the coarse branch
    re-run on the fine points, the loss at the masked points (the legacy arch's)."""
    lambda_max: float = 0.1
    """Final weight of the MRVM loss."""
    warmup_frac: float = 0.05
    """Share of pretraining iterations with the MRVM loss off (official: 20k of 400k steps)."""
    ramp_end_frac: float = 0.0625
    """Share of pretraining iterations at which the weight reaches lambda_max (linear ramp from warmup_frac;
    official: 25k of 400k), kept there to the end of pretraining."""
    ema_momentum: float = 0.99
    """Momentum of the target projector (EMA of the online projector)."""
    proj_dim: int = 32
    """Width of the projector / predictor output."""
    head: str = "ln_gelu"
    """The projector's and predictor's MLPs: 'ln_gelu' (Linear, LayerNorm, GELU, Linear, the hidden layer 2x the
    input; every shipped model) or 'bn_relu' (Linear, BatchNorm1d, ReLU, Linear as the official code: the projector's
    hidden layer the model's width, the predictor's 2x its input; the BYOL-style head)."""


@dataclass(frozen=True)
class RenderConfig:
    """Volume rendering."""

    white_background: bool = True
    """Composite on white (the datasets' background)."""
    chunk_rays: int = 512
    """Rays per forward pass at inference (bounds memory for large renders)."""
    density_activation: str = "softplus"
    """'softplus' or 'relu' on the raw density."""
    density_bias: float = -1.0
    """Added to the raw density before the activation (starts training mostly empty)."""
    fine_min_acc: float = 0.01
    """Inference only: rays whose coarse opacity is below this skip the fine pass and keep the coarse result
    (empty space the hull did not cull); 0 runs the fine pass on every ray. Training always runs it. The
    shipped `balanced` model on 13 held-out objects x 3 views: PSNR 19.024 / LPIPS 0.291 at 0.01 and
    19.022 / 0.292 with the fine pass everywhere, for 25% less CPU (``bench tradeoff --axes gate``)."""
    stop_transmittance: float = 0.0
    """Inference only: early ray termination in the fine pass. A ray's fine samples behind its first coarse
    sample that less than this share of the light reaches are not evaluated (``samplers.stop_counts``); 0
    evaluates them all. Training always does."""


@dataclass(frozen=True)
class ModelConfig:
    """The whole generalizable NeRF."""

    name: str = "balanced"
    """Preset this config came from (informational)."""
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    """Image encoder."""
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    """Ray sampling."""
    nerformer: NeRFormerConfig = field(default_factory=NeRFormerConfig)
    """Implicit function."""
    mrvm: MRVMConfig = field(default_factory=MRVMConfig)
    """MRVM auxiliary loss."""
    render: RenderConfig = field(default_factory=RenderConfig)
    """Volume rendering."""
    max_ref_views: int = 10
    """Largest number of reference views the model is used with."""


_PAPER_MRVM = dict(view_masking="count", target="coarse")
"""MRVM as published (the masking, the target and its positions; the schedule is MRVMConfig's default)."""

PRESETS: dict[str, ModelConfig] = {
    "fast": ModelConfig(
        name="fast",
        encoder=EncoderConfig(widths=(16, 32, 48), out_dim=32),
        sampler=SamplerConfig(n_coarse=8, n_fine=8, fine_includes_coarse=True),
        nerformer=NeRFormerConfig(arch="nerformer", d_model=24, n_heads=2, n_layers=1, pos_freqs=4,
                                  color_head="blend"),
        mrvm=MRVMConfig(proj_dim=24, **_PAPER_MRVM),
    ),
    "balanced": ModelConfig(
        name="balanced",
        encoder=EncoderConfig(widths=(32, 48, 64), out_dim=48),
        sampler=SamplerConfig(n_coarse=12, n_fine=8, fine_includes_coarse=True),
        nerformer=NeRFormerConfig(arch="nerformer", d_model=32, n_heads=2, n_layers=2, color_head="blend"),
        mrvm=MRVMConfig(**_PAPER_MRVM),
    ),
    "accurate": ModelConfig(
        name="accurate",
        encoder=EncoderConfig(backbone="vgg16", pretrained=True, out_dim=96),
        sampler=SamplerConfig(n_coarse=32, n_fine=16, fine_includes_coarse=True),
        nerformer=NeRFormerConfig(arch="nerformer", d_model=64, n_heads=4, n_layers=2, fine_layers=3,
                                  ffn_mult=4, color_head="blend"),
        mrvm=MRVMConfig(proj_dim=64, **_PAPER_MRVM),
    ),
    "paper": ModelConfig(
        name="paper",
        encoder=EncoderConfig(backbone="vgg16", pretrained=True, out_dim=256),
        sampler=SamplerConfig(n_coarse=64, n_fine=32, fine_includes_coarse=True),
        nerformer=NeRFormerConfig(arch="nerformer", d_model=128, n_heads=4, n_layers=4, fine_layers=5, ffn_mult=4,
                                  color_head="direct"),
        mrvm=MRVMConfig(proj_dim=64, **_PAPER_MRVM),
    ),
}
"""Named model configs."""


def to_dict(cfg: Any) -> Any:
    """A config dataclass -> nested plain dict (JSON-serialisable)."""
    if is_dataclass(cfg):
        return {f.name: to_dict(getattr(cfg, f.name)) for f in fields(cfg)}
    if isinstance(cfg, tuple):
        return [to_dict(v) for v in cfg]
    return cfg


def from_dict(cls: type, data: dict[str, Any]) -> Any:
    """Nested dict -> config dataclass ``cls``; unknown keys are an :class:`InputError`."""
    if not isinstance(data, dict):
        raise InputError(f"{cls.__name__}: expected a mapping, got {type(data).__name__}")
    hints = get_type_hints(cls)
    names = {f.name for f in fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise InputError(f"{cls.__name__}: unknown config field(s) {sorted(unknown)}")
    kw = {}
    for k, v in data.items():
        t = hints[k]
        if is_dataclass(t):
            kw[k] = from_dict(t, v)
        elif getattr(t, "__origin__", None) is tuple:
            kw[k] = tuple(v)
        else:
            kw[k] = v
    return cls(**kw)


def merge(cfg: Any, overrides: dict[str, Any]) -> Any:
    """Return ``cfg`` with nested ``overrides`` (a partial dict) applied."""
    if not overrides:
        return cfg
    if not isinstance(overrides, dict):  # (a run config's "overrides": 5 raised AttributeError)
        raise InputError(f"{type(cfg).__name__}: overrides must be a mapping of its fields, got "
                         f"{type(overrides).__name__}")
    hints = get_type_hints(type(cfg))
    kw = {}
    for k, v in overrides.items():
        if k not in hints:
            raise InputError(f"{type(cfg).__name__}: unknown config field {k!r}")
        cur = getattr(cfg, k)
        if is_dataclass(cur):  # a section takes a mapping of its fields ({"nerformer": 5} raised AttributeError)
            if not isinstance(v, dict):
                raise InputError(f"{type(cfg).__name__}.{k} is a section: override it with a mapping of its fields, "
                                 f"got {v!r}")
            kw[k] = merge(cur, v)
        elif isinstance(cur, tuple) and isinstance(v, (list, tuple)):
            kw[k] = tuple(v)
        else:  # (a string for a tuple field is not split into characters: the field's check judges it)
            kw[k] = v
    return replace(cfg, **kw)


def model_config(preset: str = "balanced", overrides: dict[str, Any] | None = None) -> ModelConfig:
    """The named preset with optional nested overrides."""
    if preset not in PRESETS:
        raise InputError(f"unknown model preset {preset!r}; choose one of {sorted(PRESETS)}")
    cfg = merge(PRESETS[preset], overrides or {})
    validate(cfg)
    return cfg


def validate(cfg: ModelConfig) -> None:
    """Raise :class:`InputError` for configs that cannot work."""
    from ..validation import check_sizes, check_types_deep

    check_types_deep(cfg)  # "abc" for a size is a one-line error, not a TypeError in the model
    check_sizes(cfg)
    n = cfg.nerformer
    if n.n_heads < 1 or n.d_model < 1 or cfg.render.chunk_rays < 1 or cfg.max_ref_views < 1:
        raise InputError("model nerformer.d_model, nerformer.n_heads, render.chunk_rays and max_ref_views must be >= 1")
    if n.d_model % n.n_heads:
        raise InputError(f"nerformer.d_model ({n.d_model}) must be divisible by n_heads ({n.n_heads})")
    if not 0.0 <= cfg.render.fine_min_acc < 1.0:
        raise InputError(f"render.fine_min_acc must be in [0, 1), got {cfg.render.fine_min_acc}")
    if not 0.0 <= cfg.render.stop_transmittance < 1.0:
        raise InputError(f"render.stop_transmittance must be in [0, 1), got {cfg.render.stop_transmittance}")
    if cfg.sampler.n_coarse < 1 or cfg.sampler.n_fine < 0:
        raise InputError("sampler.n_coarse must be >= 1 and n_fine >= 0")
    if cfg.encoder.backbone not in ("resnet", "vgg16"):
        raise InputError(f"encoder.backbone must be 'resnet' or 'vgg16', got {cfg.encoder.backbone!r}")
    m = cfg.mrvm
    if not (0.0 <= m.point_mask_ratio <= 1.0 and 0.0 <= m.view_mask_prob <= 1.0):
        raise InputError("mrvm.point_mask_ratio and view_mask_prob must be in [0, 1]")
    if not (0.0 <= m.warmup_frac <= m.ramp_end_frac <= 1.0):
        raise InputError("mrvm: need 0 <= warmup_frac <= ramp_end_frac <= 1")
    if cfg.render.density_activation not in ("softplus", "relu"):
        raise InputError("render.density_activation must be 'softplus' or 'relu'")
    if n.arch not in ARCHS:
        raise InputError(f"nerformer.arch must be one of {', '.join(ARCHS)}, got {n.arch!r}")
    if n.color_head not in ("direct", "blend"):
        raise InputError(f"nerformer.color_head must be 'direct' or 'blend', got {n.color_head!r}")
    if n.n_layers < 1 or n.fine_layers < 0 or n.pos_freqs < 0 or n.dir_freqs < 0:
        raise InputError("nerformer.n_layers must be >= 1; fine_layers, pos_freqs and dir_freqs >= 0")
    if m.head not in ("ln_gelu", "bn_relu"):
        raise InputError(f"mrvm.head must be 'ln_gelu' or 'bn_relu', got {m.head!r}")
    if m.view_masking not in ("count", "prob") or m.target not in ("coarse", "rerun"):
        raise InputError("mrvm.view_masking must be 'count' or 'prob', mrvm.target 'coarse' or 'rerun'")
    if n.arch == "legacy" and (m.target != "rerun" or m.view_masking != "prob" or n.fine_layers):
        raise InputError("the legacy arch takes mrvm.target 'rerun', view_masking 'prob' and no fine_layers; "
                         "use nerformer.arch 'nerformer' for the paper's settings")
    if m.enabled and m.target == "coarse" and not (cfg.sampler.n_fine > 0 and cfg.sampler.fine_includes_coarse):
        raise InputError("mrvm.target 'coarse' compares the fine pass at the coarse samples: it needs sampler.n_fine "
                         "> 0 and fine_includes_coarse")


__all__ = [n for n in dir() if not n.startswith("_") and n not in ("annotations", "dataclasses", "Any")]
