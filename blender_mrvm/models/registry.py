"""The model kinds and the one protocol that training, evaluation, synthesis, the worker and the panel use.

Several model kinds live side by side (``nerformer_mrvm``: the NeRFormer+MRVM radiance field;
``gpnr``: the GPNR patch-based light-field transformer). Each kind is a config dataclass with named
presets and a torch module implementing the protocol below; a checkpoint records its kind
(``model_kind`` in its metadata), so any checkpoint trains, evaluates, synthesizes and fine-tunes
through the same commands. This module is torch-free at import (the add-on reads it on the main
thread); the model classes are imported only when a model is built.

The protocol (what :class:`..models.base.RayModel` subclasses implement)::

    ctx = model.encode(images (V, 3, H, W) in [0, 1] on white, cams: RefCameras)   # once per reference set
    out = model.render_rays(ctx, rays: RayBundle, train=False, generator=None, **phase.kwargs)
        # rays all hit the object's box (normalised frame); out["color"] (R, 3) on the background,
        # out["acc"] (R,) opacity, out["depth"] (R,) expected distance from the box entry given the ray
        # stops; for training also out["aux_heads"] {name: {"color", "acc"}} (weighted by
        # train.coarse_weight) and out["aux_losses"] {name: scalar tensor}
    phase = model.train_phase(step, train_cfg)   # what a training step does: kwargs, loss weights, logs
    model.after_step(phase)                      # e.g. the MRVM target projector's EMA update

Everything else (box normalisation, ray clipping, chunked images, world-unit depth) is shared in
``models/base.py``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field, is_dataclass
from typing import Any

from ..errors import InputError


@dataclass(frozen=True)
class Kind:
    """One model kind: where its config and model classes live."""

    name: str
    """Registry key, stored in checkpoints as ``model_kind``."""
    title: str
    """Human-readable name (panel, reports)."""
    config: str
    """``module:Class`` of the config dataclass (relative to ``blender_mrvm.models``)."""
    presets: str
    """``module:NAME`` of the dict of named configs."""
    model: str
    """``module:Class`` of the torch module."""
    default_preset: str = "balanced"
    """Preset used when none is named."""
    aliases: tuple[str, ...] = field(default_factory=tuple)
    """Other names accepted on the command line."""


KINDS: dict[str, Kind] = {
    "nerformer_mrvm": Kind("nerformer_mrvm", "NeRFormer + MRVM", "config:ModelConfig", "config:PRESETS",
                           "model:GeneralizableNeRF", aliases=("nerformer", "mrvm")),
    "gpnr": Kind("gpnr", "GPNR", "gpnr.config:GPNRConfig", "gpnr.config:PRESETS", "gpnr.model:GPNR"),
}
"""Every model kind this version knows."""

OTHER_KINDS = {
    "sem2nerf": "a Sem2NeRF generator renders from a semantic part mask, not from reference views: use "
                "`python -m blender_mrvm sem2nerf render` (models/sem2nerf/)",
}
"""Checkpoint kinds of this package that do not take reference views (and what to use instead)."""

DEFAULT_KIND = "nerformer_mrvm"
"""Kind of checkpoints that predate the ``model_kind`` key (and of run configs that name none)."""


def _load(ref: str) -> Any:
    mod, name = ref.split(":")
    return getattr(importlib.import_module(f"{__package__}.{mod}"), name)


def kind(name: str | None) -> Kind:
    """The :class:`Kind` for a name or alias (None / '' = the default); InputError for an unknown one."""
    n = (name or DEFAULT_KIND).strip().lower()
    for k in KINDS.values():
        if n == k.name or n in k.aliases:
            return k
    raise InputError(f"unknown model kind {name!r}; this version knows {', '.join(sorted(KINDS))}")


def config_class(name: str | None) -> type:
    return _load(kind(name).config)


def presets(name: str | None) -> dict[str, Any]:
    return _load(kind(name).presets)


def kind_of(cfg: Any) -> str:
    """The kind whose config class ``cfg`` is an instance of."""
    for k in KINDS.values():
        if type(cfg) is _load(k.config):
            return k.name
    raise TypeError(f"{type(cfg).__name__} is not the config of a known model kind")


QUALITY_LEVELS = ("full", "preview")
"""Inference-time speed/quality levels (:func:`quality_overrides`)."""


def quality_overrides(cfg: Any, level: str) -> dict[str, Any]:
    """Config overrides (for ``config.merge``) of an inference-time speed/quality level, any kind.

    ``full``: as trained. ``preview``: half the samples per ray (NeRFormer: coarse and fine; GPNR: epipolar
    depths; at least 4), a point on the shipped models' Pareto front (``bench tradeoff``, 13 held-out objects
    x 3 views, 1 thread): NeRFormer 1.6x less CPU for -0.17 dB, GPNR 1.6x for -0.34 dB, Sem2NeRF (a
    ``Sem2NeRFConfig``: flat overrides for ``dataclasses.replace``) 1.9x for -0.13 dB at equal LPIPS."""
    if level not in QUALITY_LEVELS:
        raise InputError(f"quality must be one of {', '.join(QUALITY_LEVELS)}, got {level!r}")
    if level == "full":
        return {}
    from .sem2nerf.config import Sem2NeRFConfig

    if isinstance(cfg, Sem2NeRFConfig):
        return {"n_coarse": max(4, int(cfg.n_coarse) // 2), "n_fine": int(cfg.n_fine) // 2}
    if kind_of(cfg) == "gpnr":
        return {"n_samples": max(4, int(cfg.n_samples) // 2)}
    return {"sampler": {"n_coarse": max(4, int(cfg.sampler.n_coarse) // 2), "n_fine": int(cfg.sampler.n_fine) // 2}}


def build_config(name: str | None, preset: str | None = None, overrides: dict[str, Any] | None = None):
    """A validated config of kind ``name``: its preset ``preset`` (default: the kind's) with nested overrides."""
    from .config import merge

    k = kind(name)
    table = presets(k.name)
    p = preset or k.default_preset
    if p not in table:
        raise InputError(f"unknown model preset {p!r} for {k.name}; choose one of {sorted(table)}")
    cfg = merge(table[p], overrides or {})
    validate(cfg)
    return cfg


def config_from_dict(name: str | None, data: dict[str, Any]):
    """A validated config of kind ``name`` from a plain dict (as stored in checkpoints and run configs)."""
    from .config import from_dict

    cls = config_class(name)
    legacy = getattr(importlib.import_module(cls.__module__), "STORED_DEFAULTS", {})
    if isinstance(data, dict) and legacy:  # fields newer than the stored config: what the code did before them
        data = {**{k: v for k, v in legacy.items() if k not in data}, **data}
    cfg = from_dict(cls, data)
    validate(cfg)
    return cfg


def validate(cfg: Any) -> None:
    """Raise InputError for a config that cannot work (each config module has its ``validate``)."""
    if not is_dataclass(cfg):
        raise TypeError(f"not a config: {cfg!r}")
    mod = importlib.import_module(type(cfg).__module__)
    mod.validate(cfg)


def build_model(cfg: Any, load_pretrained: bool = True):
    """A fresh torch module for ``cfg`` (any kind). ``load_pretrained`` False skips loading offline pretrained
    weights (ImageNet encoders) where a checkpoint's weights replace them anyway."""
    import inspect

    from .nerformer import configure_attention

    configure_attention()  # every kind attends with nerformer.Attention: no per-shape cuDNN graphs on a GPU
    cls = _load(kind(kind_of(cfg)).model)
    if not load_pretrained and "load_pretrained" in inspect.signature(cls).parameters:
        return cls(cfg, load_pretrained=False)
    return cls(cfg)


def compile_networks(model, mode: str | None = None) -> list[str]:
    """``torch.compile`` in place (``nn.Module.compile``: the state dict keeps its keys, so checkpoints are
    unchanged) each direct submodule of ``model`` that has weights, but the image encoder (it runs once per
    reference view, not per ray chunk); dynamic shapes, since ray chunks and hit counts differ in length.
    ``mode``: torch.compile's (None = its default). Returns the names compiled. Compilation happens at the
    first call: tens of seconds on a GPU machine, minutes on a 2-core CPU."""
    names = [n for n, m in model.named_children() if n != "encoder" and any(True for _ in m.parameters())]
    for n in names:
        getattr(model, n).compile(dynamic=True, **({"mode": mode} if mode else {}))
    return names


def kind_from_meta(meta: dict[str, str]) -> str:
    """The model kind a checkpoint's metadata records (the default for checkpoints that predate the key);
    InputError for a kind this version does not know."""
    raw = meta.get("model_kind") or DEFAULT_KIND
    if raw in OTHER_KINDS:
        raise InputError(f"the checkpoint holds a {raw} model: {OTHER_KINDS[raw]}")
    if raw not in KINDS:
        raise InputError(f"the checkpoint holds a model of kind {raw!r}, which this version does not know "
                         f"(it knows {', '.join(sorted(KINDS))})")
    return raw
