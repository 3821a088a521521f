"""GPNR config (frozen dataclass, one docstring line per field) and its named presets.

Presets run from ``fast`` (a CPU-friendly model) to ``paper`` (the size of Suhail et al.'s appendix:
8 blocks per transformer, 256 wide). Every field round-trips through ``models.config.to_dict`` /
``from_dict`` so checkpoints carry the exact config.
"""

from __future__ import annotations

from dataclasses import dataclass

from ...errors import InputError


@dataclass(frozen=True)
class GPNRConfig:
    """Generalizable patch-based neural rendering: a light-field transformer over epipolar patches."""

    name: str = "balanced"
    """Preset this config came from (informational)."""
    patch_size: int = 5
    """Side of the square reference-image patch around each epipolar projection, pixels (odd)."""
    patch_dim: int = 32
    """Width of the linear patch embedding."""
    n_samples: int = 32
    """Depths sampled along the target ray inside the object's box (M); each is projected into every view."""
    depth_spacing: str = "auto"
    """How the M depths are spread along the target ray: 'linear' (evenly between the box entry and exit, as
    for an object seen from outside its box), 'disparity' (evenly in inverse depth between the near plane and
    the box exit: a room or a real scene seen from inside its box), or 'auto' (per ray: 'disparity' when the
    camera is inside the box, i.e. a scene dataset, else 'linear'). Checkpoints written before this field
    existed read as 'linear' (``STORED_DEFAULTS``)."""
    near: float = 0.2
    """Near plane of the 'disparity' spacing: distance from the target camera, in the normalised frame's
    units (the box's longest half-side is 1; in a 5 m room, 0.2 is 0.5 m). Depths start at the farther of
    the near plane and the box entry."""
    alpha_temperature: float = 1.0
    """Temperature of the epipolar weights' softmax at inference (training always uses 1): below 1 each view's
    colour comes from fewer depths along its epipolar line, i.e. less blur along the line. 1 = the paper."""
    beta_temperature: float = 1.0
    """Temperature of the reference-view weights' softmax at inference (training always uses 1)."""
    colour_filter: str = "bicubic"
    """How reference pixel colours are read at the epipolar projections: 'bicubic' (clamped to [0, 1]) or
    'bilinear' (the paper). A bilinear read is a low-pass filter at sub-pixel positions, so the blended
    colour comes out softer than the references; bicubic reads cut LPIPS on every held-out object and room
    (objects, 5 views: -0.009 at +0.20 dB; rooms: -0.026 at -0.12 dB; RECIPE.md). Only the colours: the patch
    features stay bilinear. Checkpoints written before this field existed read as 'bilinear'."""
    ray_freqs: int = 4
    """Harmonic frequencies of the reference ray's Plücker coordinates (the first positional code)."""
    depth_freqs: int = 6
    """Harmonic frequencies of the sample's position: its depth along the target ray when coordinates
    are canonicalized, else its normalised-frame xyz (the second positional code)."""
    camera_freqs: int = 2
    """Harmonic frequencies of the reference camera's centre in its relative pose (the third code)."""
    d_model: int = 64
    """Token width of the three transformers."""
    n_heads: int = 4
    """Attention heads (d_model must be divisible by it)."""
    n_blocks: int = 2
    """Transformer blocks in each of the three transformers (patch encoder, epipolar and view aggregators)."""
    ffn_mult: int = 2
    """Feed-forward hidden width as a multiple of d_model."""
    colour_from: str = "references"
    """'references': colour = sum_k beta_k sum_m alpha_k^m c_k^m of reference pixel colours (the paper);
    'features': colour predicted from the aggregated features (the paper's ablation)."""
    canonicalize_rays: bool = True
    """Express the Plücker coordinates of the reference rays (and the target ray) in the target ray's frame."""
    canonicalize_coords: bool = True
    """Express sample positions and reference camera poses in the target ray's frame."""
    opacity_head: bool = True
    """Predict an opacity per ray (the image planes' alpha; trained by the opacity loss when masks exist)."""
    box_padding: float = 0.05
    """Box grown by this fraction of its half-size on each side before clipping rays."""
    perturb: bool = True
    """Jitter the depths along the target ray during training (evaluation is deterministic)."""
    white_background: bool = True
    """Rays that miss the box (and rays no reference sees) are this background."""
    chunk_rays: int = 256
    """Rays per forward pass at inference (bounds memory for large renders)."""
    min_ref_views: int = 1
    """Fewest reference views the model is used with."""
    max_ref_views: int = 10
    """Most reference views the model is used with; with more, the nearest ones are picked per target."""


PRESETS: dict[str, GPNRConfig] = {
    "fast": GPNRConfig(name="fast", patch_size=3, patch_dim=16, n_samples=24, d_model=48, n_heads=4, n_blocks=1,
                       ray_freqs=3, depth_freqs=4, chunk_rays=512),
    "balanced": GPNRConfig(name="balanced"),
    "accurate": GPNRConfig(name="accurate", patch_size=7, patch_dim=64, n_samples=48, d_model=128, n_heads=4,
                           n_blocks=4, ffn_mult=4, chunk_rays=256),
    "paper": GPNRConfig(name="paper", patch_size=7, patch_dim=128, n_samples=64, d_model=256, n_heads=8, n_blocks=8,
                        ffn_mult=4, chunk_rays=128),
}
"""Named GPNR configs."""

STORED_DEFAULTS: dict[str, object] = {"depth_spacing": "linear", "colour_filter": "bilinear"}
"""Values of fields a stored config (checkpoint, run config) lacks because it was written before the field
existed: what the code did then, so an old checkpoint renders bit-identically."""

DEPTH_SPACINGS = ("linear", "disparity", "auto")
COLOUR_FILTERS = ("bilinear", "bicubic")


def validate(cfg: GPNRConfig) -> None:
    """Raise :class:`InputError` for configs that cannot work."""
    if cfg.patch_size < 1 or cfg.patch_size % 2 == 0:
        raise InputError(f"gpnr patch_size must be a positive odd number, got {cfg.patch_size}")
    for name in ("patch_dim", "n_samples", "d_model", "n_heads", "n_blocks", "ffn_mult", "chunk_rays",
                 "min_ref_views", "max_ref_views"):
        v = getattr(cfg, name)
        if not isinstance(v, int) or isinstance(v, bool) or v < 1:
            raise InputError(f"gpnr {name} must be a positive integer, got {v!r}")
    for name in ("ray_freqs", "depth_freqs", "camera_freqs"):
        v = getattr(cfg, name)
        if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v <= 16:
            raise InputError(f"gpnr {name} must be an integer in 0..16, got {v!r}")
    if cfg.d_model % cfg.n_heads:
        raise InputError(f"gpnr d_model ({cfg.d_model}) must be divisible by n_heads ({cfg.n_heads})")
    if cfg.colour_from not in ("references", "features"):
        raise InputError(f"gpnr colour_from must be 'references' or 'features', got {cfg.colour_from!r}")
    if cfg.min_ref_views > cfg.max_ref_views:
        raise InputError("gpnr needs min_ref_views <= max_ref_views")
    if cfg.depth_spacing not in DEPTH_SPACINGS:
        raise InputError(f"gpnr depth_spacing must be one of {', '.join(DEPTH_SPACINGS)}, got {cfg.depth_spacing!r}")
    if cfg.colour_filter not in COLOUR_FILTERS:
        raise InputError(f"gpnr colour_filter must be one of {', '.join(COLOUR_FILTERS)}, got {cfg.colour_filter!r}")
    if isinstance(cfg.near, bool) or not isinstance(cfg.near, (int, float)) or not 0.0 < float(cfg.near) < 1e6:
        raise InputError(f"gpnr near must be a positive number (normalised units), got {cfg.near!r}")
    for name in ("alpha_temperature", "beta_temperature"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 1e-3 <= float(v) <= 1e3:
            raise InputError(f"gpnr {name} must be a number in [0.001, 1000], got {v!r}")
    if not 0.0 <= float(cfg.box_padding) <= 1.0:
        raise InputError(f"gpnr box_padding must be in [0, 1], got {cfg.box_padding}")
