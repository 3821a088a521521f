"""Atomic checkpoints: model weights in safetensors (with the config and a format version in its
metadata) plus the trainer state (optimizer, schedule, step, every rank's RNG) loaded with
``torch.load(weights_only=True)``.

::

    <run>/checkpoints/step_0001000/model.safetensors
    <run>/checkpoints/step_0001000/trainer_state.pt
    <run>/checkpoints/latest                 name of the newest complete checkpoint

A checkpoint folder is written under a temporary name and renamed into place, then ``latest`` is
replaced atomically: an interrupted save never leaves a checkpoint that looks complete.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import torch

from ..errors import InputError
from ..models.config import ModelConfig, from_dict, to_dict

FORMAT = "blender_mrvm.generalizable_nerf"
FORMAT_VERSION = 1
MODEL_FILE = "model.safetensors"
STATE_FILE = "trainer_state.pt"


def save_checkpoint(run_dir: Path, step: int, model: torch.nn.Module, model_cfg: ModelConfig,
                    trainer_state: dict[str, Any] | None, extra_meta: dict[str, Any] | None = None,
                    keep: int = 2) -> Path:
    from safetensors.torch import save_model

    ck_root = Path(run_dir) / "checkpoints"
    ck_root.mkdir(parents=True, exist_ok=True)
    name = f"step_{step:07d}"
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=ck_root))
    try:
        meta = {"format": FORMAT, "format_version": str(FORMAT_VERSION), "step": str(step),
                "model_config": json.dumps(to_dict(model_cfg))}
        for k, v in (extra_meta or {}).items():
            meta[k] = v if isinstance(v, str) else json.dumps(v)
        save_model(model, str(tmp / MODEL_FILE), metadata=meta)
        if trainer_state is not None:
            torch.save(trainer_state, tmp / STATE_FILE)
        final = ck_root / name
        if final.exists():
            shutil.rmtree(final)
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    fd, ltmp = tempfile.mkstemp(prefix=".latest.", dir=ck_root)
    with os.fdopen(fd, "w") as f:
        f.write(name + "\n")
    os.replace(ltmp, ck_root / "latest")
    done = sorted(p for p in ck_root.glob("step_*") if p.is_dir())
    for old in done[:-keep] if keep > 0 else []:
        if old.name != name:
            shutil.rmtree(old, ignore_errors=True)
    return final


def find_checkpoint(path: Path) -> Path | None:
    """A checkpoint folder from a run folder, a checkpoints/ folder, a checkpoint folder or a model file."""
    path = Path(path)
    if path.is_file() and path.name.endswith(".safetensors"):
        return path.parent if (path.parent / STATE_FILE).exists() or path.name == MODEL_FILE else path
    for base in (path / "checkpoints", path):
        latest = base / "latest"
        if latest.is_file():
            c = base / latest.read_text().strip()
            if (c / MODEL_FILE).is_file():
                return c
    if (path / MODEL_FILE).is_file():
        return path
    return None


def read_meta(model_file: Path) -> dict[str, str]:
    from safetensors import safe_open

    with safe_open(str(model_file), framework="pt") as f:
        return dict(f.metadata() or {})


def load_model(path: Path, device: str = "cpu"):
    """(model, model_cfg, meta) from a checkpoint (any form :func:`find_checkpoint` accepts)."""
    from safetensors.torch import load_model as st_load

    from ..models.model import GeneralizableNeRF

    path = Path(path)
    ck = find_checkpoint(path)
    model_file = path if path.is_file() else (ck / MODEL_FILE if ck else None)
    if model_file is None or not Path(model_file).is_file():
        raise InputError(f"no checkpoint found at {path}")
    meta = read_meta(model_file)
    if meta.get("format") != FORMAT:
        raise InputError(f"{model_file} is not a blender_mrvm model checkpoint (format {meta.get('format')!r})")
    if int(meta.get("format_version", -1)) > FORMAT_VERSION:
        raise InputError(f"{model_file} has format version {meta['format_version']}, newer than this code ({FORMAT_VERSION})")
    cfg = from_dict(ModelConfig, json.loads(meta["model_config"]))
    model = GeneralizableNeRF(cfg)
    st_load(model, str(model_file), strict=True, device=device)
    return model.to(device), cfg, meta


def load_trainer_state(ck: Path) -> dict[str, Any]:
    return torch.load(Path(ck) / STATE_FILE, map_location="cpu", weights_only=True)
