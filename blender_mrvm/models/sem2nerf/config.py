"""Typed frozen config of the Sem2NeRF model and its named presets ``fast`` / ``balanced``.

Every field has a one-line docstring. The label table (which part ids the model knows) is part of
the config: it is fixed when training starts (from the dataset's ``meta.json`` labels) and travels
with the checkpoint, so a mask with other ids is refused before any work.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ...errors import InputError
from ..config import from_dict, merge, to_dict  # noqa: F401 (re-exported: generic dataclass <-> dict)

MODEL_KIND = "sem2nerf"
"""The ``model_kind`` a Sem2NeRF checkpoint records."""


@dataclass(frozen=True)
class Sem2NeRFConfig:
    """Mask encoder + FiLM-SIREN radiance/semantic generator + style mapping network."""

    name: str = "balanced"
    """Preset this config came from (informational)."""
    labels: tuple[int, ...] = (0, 1)
    """Part ids the model knows, background (0) first; one input channel and one output logit each."""
    label_names: tuple[str, ...] = ("background", "part")
    """Name of each label (same order as ``labels``)."""
    image_size: int = 64
    """Side of the square masks the encoder takes (the training image size)."""
    vgg_layers: int = 16
    """Modules of ImageNet VGG16 ``features`` used by the encoder (9 = up to relu2_2, 16 = relu3_3)."""
    pretrained: bool = True
    """Initialise the encoder's VGG16 from the offline ImageNet weights (``fetch-weights``)."""
    encoder_grid: int = 4
    """The VGG feature map is average-pooled to grid x grid cells before the code head."""
    encoder_hidden: int = 256
    """Width of the code head's hidden layer."""
    pose_conditioning: bool = True
    """The code head also sees the input camera (rotation + centre): the mask's viewpoint is known."""
    pixel_aligned: bool = False
    """Every sample point also sees the mask inputs and backbone features at its projection into the
    input view (pixelNeRF-style local conditioning beside the global FiLM codes): the rendered input
    view then follows the input mask pixel for pixel. False = global codes only (the paper's design;
    older checkpoints)."""
    local_channels: int = 32
    """Backbone feature channels sampled per point (a 1x1 projection of the VGG map) when pixel_aligned."""
    local_hidden: int = 64
    """Width of the per-point local-feature MLP when pixel_aligned."""
    style_part_colours: bool = False
    """The style code also gives every part label an RGB offset (added to the colour logits, weighted by the
    point's part probabilities). The style's FiLM of the one colour layer alone could barely recolour a part
    (fitting the style vector itself to a recoloured chair: 18.5 -> 19.9 dB), so random styles all looked
    alike; this head starts at zero, so a model trained without it renders the same. False = older
    checkpoints."""
    hidden: int = 64
    """Width of the SIREN layers."""
    n_layers: int = 4
    """FiLM-SIREN layers of the trunk (conditioned by the mask code)."""
    z_dim: int = 32
    """Dimension of the random style code z fed to the mapping network."""
    mapping_hidden: int = 64
    """Width of the mapping network (3 hidden LeakyReLU layers, as pi-GAN's)."""
    style_mean_samples: int = 10000
    """Random z averaged through the mapping network for the default style (the paper's 10,000)."""
    freq_scale: float = 15.0
    """FiLM frequencies are ``freq_scale * code + freq_bias`` (pi-GAN: 15, 30)."""
    freq_bias: float = 30.0
    """See ``freq_scale``."""
    scene_box: float = 0.5
    """Half-size of the world cube the field lives in (ShapeNet-normalised objects fit in 0.5)."""
    n_coarse: int = 24
    """Stratified samples per ray inside the cube."""
    n_fine: int = 12
    """Importance samples per ray (same network, merged with the coarse ones); 0 = none."""
    density_scale: float = 10.0
    """Raw density is multiplied by this before the softplus (sharper surfaces)."""
    density_bias: float = -2.0
    """Added to the scaled raw density before the softplus (starts mostly empty)."""
    chunk_rays: int = 1024
    """Rays per forward pass at inference."""
    cull_cone: bool = False
    """At inference, rays that stay outside the input mask's silhouette cone are background and cost nothing
    (``model.silhouette_cone``; pixel-aligned models, which carry the input camera). Off: measured (``bench
    tradeoff --axes skip``, 13 held-out objects x 3 novel views) it skips 18 % of a 128 px view's rays but
    worsens LPIPS by 0.005 at equal PSNR: the shipped model's haze outside the cone (opacity up to 0.1-0.27)
    is part of its soft silhouettes, and cutting it leaves hard edges."""
    white_background: bool = True
    """Composite on white (the datasets' background)."""

    @property
    def n_labels(self) -> int:
        return len(self.labels)

    @property
    def in_channels(self) -> int:
        """One-hot channels + contour map + distance field."""
        return len(self.labels) + 2


PRESETS: dict[str, Sem2NeRFConfig] = {
    "fast": Sem2NeRFConfig(name="fast", vgg_layers=9, encoder_hidden=128, hidden=32, n_layers=3, z_dim=16,
                           mapping_hidden=32, n_coarse=16, n_fine=8, pixel_aligned=True, style_part_colours=True),
    "balanced": Sem2NeRFConfig(name="balanced", pixel_aligned=True, style_part_colours=True),
}
"""Named Sem2NeRF configs."""


def validate(cfg: Sem2NeRFConfig) -> Sem2NeRFConfig:
    """Raise :class:`InputError` for configs that cannot work; returns ``cfg``."""
    if len(cfg.labels) < 1 or len(set(cfg.labels)) != len(cfg.labels):
        raise InputError("sem2nerf labels must be distinct part ids")
    if any(not 0 <= int(v) <= 255 for v in cfg.labels):
        raise InputError("sem2nerf labels must lie in 0..255 (masks are uint8)")
    if len(cfg.label_names) != len(cfg.labels):
        raise InputError("sem2nerf label_names must name every label")
    if cfg.labels[0] != 0:
        raise InputError("sem2nerf labels must start with the background id 0")
    if cfg.vgg_layers not in (4, 9, 16, 23):
        raise InputError("sem2nerf vgg_layers must be 4, 9, 16 or 23 (ends of VGG16 blocks before pooling)")
    if cfg.image_size < 8 or cfg.hidden < 4 or cfg.n_layers < 1 or cfg.z_dim < 1:
        raise InputError("sem2nerf image_size >= 8, hidden >= 4, n_layers >= 1, z_dim >= 1")
    if cfg.pixel_aligned and (cfg.local_channels < 1 or cfg.local_hidden < 1):
        raise InputError("sem2nerf local_channels >= 1 and local_hidden >= 1 with pixel_aligned")
    if cfg.n_coarse < 2 or cfg.n_fine < 0 or cfg.scene_box <= 0 or cfg.style_mean_samples < 1:
        raise InputError("sem2nerf n_coarse >= 2, n_fine >= 0, scene_box > 0, style_mean_samples >= 1")
    return cfg


def sem2nerf_config(preset: str = "balanced", overrides: dict[str, Any] | None = None, **kw) -> Sem2NeRFConfig:
    """The named preset with optional nested overrides (and keyword overrides)."""
    if preset not in PRESETS:
        raise InputError(f"unknown sem2nerf preset {preset!r}; choose one of {sorted(PRESETS)}")
    cfg = merge(PRESETS[preset], overrides or {})
    if kw:
        cfg = replace(cfg, **{k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()})
    return validate(cfg)


def resolve_sem2nerf_checkpoint(path) -> Path:
    """'' / 'shipped' / 'shipped:sem2nerf' -> the shipped Sem2NeRF model file (InputError when this copy
    lacks it); anything else is that path."""
    raw = "" if path is None else str(path).strip()
    if raw.lower() in ("", "shipped", "shipped:sem2nerf"):
        from ..pretrained import shipped_checkpoint

        return shipped_checkpoint("sem2nerf")
    return Path(path)


def read_sem2nerf_header(path: Path) -> tuple[Path, dict[str, str]]:
    """(model file, metadata) of a Sem2NeRF checkpoint (model file, checkpoint or run folder, or
    ``shipped:sem2nerf``); InputError if it is none. Torch-free: the add-on checks a picked file on
    Blender's main thread."""
    from ..checkpoint_files import checked_header

    model_file, meta = checked_header(resolve_sem2nerf_checkpoint(path))
    if meta.get("model_kind") != MODEL_KIND:
        raise InputError(f"{model_file} is not a Sem2NeRF checkpoint (model kind {meta.get('model_kind', 'mrvm')!r})")
    return model_file, meta
