"""The model shipped with the add-on: where it lives and how the CLI finds it (bpy-free).

The default checkpoint was trained by our own ``train`` command on the procedural ShapeNet-13
``all`` setting; its recipe and evaluation table are in ``assets/checkpoints/RECIPE.md``. It is a
plain model file (safetensors with the model config and format version in its metadata), loaded
with ``training.checkpoint.load_model`` like any other checkpoint.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

ASSET_DIR = Path(__file__).resolve().parents[1] / "assets" / "checkpoints"
"""Folder of the shipped checkpoints (inside the package, so the extension zip carries it)."""
DEFAULT_NAME = "mrvm_shapenet13_all"
"""Stem of the default checkpoint: ``<stem>.safetensors`` (weights + config) and ``<stem>.json`` (run config)."""


def default_checkpoint() -> Path:
    """Path of the shipped default model file; :class:`InputError` if this copy of the package lacks it."""
    p = ASSET_DIR / f"{DEFAULT_NAME}.safetensors"
    if not p.is_file():
        raise InputError(f"the shipped default checkpoint {p} is missing (a partial install?); "
                         f"pass --checkpoint or train one with `python -m blender_mrvm train`")
    return p


def default_run_config() -> Path:
    """The run config (model + train sections) the default checkpoint was trained with."""
    return ASSET_DIR / f"{DEFAULT_NAME}.json"


def resolve_checkpoint(path) -> Path:
    """The one fallback rule for a checkpoint argument: None, '' or 'shipped' = the shipped default model
    (:func:`default_checkpoint`); anything else is that path, which must exist. InputError otherwise."""
    if path is None or str(path).strip() == "" or str(path).strip().lower() == "shipped":
        return default_checkpoint()
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"checkpoint {p} does not exist")
    return p
