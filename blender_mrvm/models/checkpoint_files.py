"""Where a checkpoint's files are and what its header says, without torch (bpy-free, torch-free).

The add-on's main thread uses this to check a checkpoint the user picked (is it ours, which model)
before a worker with torch is started; ``training/checkpoint.py`` builds on the same names.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

from ..errors import InputError

FORMAT = "blender_mrvm.generalizable_nerf"
FORMAT_VERSION = 1
MODEL_FILE = "model.safetensors"
STATE_FILE = "trainer_state.pt"
MAX_HEADER = 100 * 1024 * 1024
"""safetensors caps its JSON header at 100 MB; a larger length means the file is not one."""


def step_of(ck: Path) -> int:
    """The step a checkpoint folder's name gives (``step_0001000`` -> 1000), -1 for other names."""
    name = Path(ck).name
    return int(name[5:]) if name.startswith("step_") and name[5:].isdigit() else -1


def checkpoint_folders(base: Path) -> list[Path]:
    """The ``step_*`` checkpoint folders under ``base`` (a checkpoints/ folder), newest first, damaged ones
    included (temporary ``.step_*`` folders of an interrupted save are not checkpoints)."""
    base = Path(base)
    if not base.is_dir():
        return []
    return sorted((p for p in base.iterdir() if p.is_dir() and step_of(p) >= 0), key=step_of, reverse=True)


def model_file_problem(model_file: Path) -> str:
    """Why ``model_file`` is not a whole safetensors file ('' when it is): missing, empty, a header that
    does not parse, or fewer bytes than its header's tensors need (a truncated copy or a full disk)."""
    model_file = Path(model_file)
    try:
        size = model_file.stat().st_size
        with open(model_file, "rb") as f:
            head = f.read(8)
            if len(head) < 8:
                return "file too short"
            (n,) = struct.unpack("<Q", head)
            if n > MAX_HEADER or 8 + n > size:
                return "truncated or not a safetensors file (header length beyond the end)"
            header = json.loads(f.read(n).decode("utf-8"))
    except FileNotFoundError:
        return "missing"
    except (OSError, ValueError, UnicodeDecodeError) as e:
        return f"unreadable header ({e})"
    if not isinstance(header, dict):
        return "not a safetensors header"
    end = 0
    for k, v in header.items():
        if k == "__metadata__":
            continue
        try:
            end = max(end, int(v["data_offsets"][1]))
        except (TypeError, KeyError, IndexError, ValueError):
            return f"tensor {k!r} has no data offsets"
    if size < 8 + n + end:
        return f"truncated: {size} bytes, its tensors need {8 + n + end}"
    return ""


def checkpoint_problem(ck: Path, need_state: bool = True) -> str:
    """Why a checkpoint folder cannot be resumed from ('' when its files are whole; the trainer state is
    only looked at here, torch reads it)."""
    ck = Path(ck)
    why = model_file_problem(ck / MODEL_FILE)
    if why:
        return f"{MODEL_FILE}: {why}"
    if need_state:
        st = ck / STATE_FILE
        if not st.is_file():
            return f"{STATE_FILE}: missing"
        if st.stat().st_size == 0:
            return f"{STATE_FILE}: empty"
    return ""


def find_checkpoint(path: Path) -> Path | None:
    """A checkpoint folder from a run folder, a checkpoints/ folder, a checkpoint folder or a model file.

    In a run folder the newest complete ``step_*`` checkpoint wins: the ``latest`` file is only a hint
    (it may be empty, damaged or name a deleted step), used for folders without ``step_*`` names."""
    path = Path(path)
    if path.is_file() and path.name.endswith(".safetensors"):
        return path.parent if (path.parent / STATE_FILE).exists() or path.name == MODEL_FILE else path
    for base in (path / "checkpoints", path):
        for ck in checkpoint_folders(base):
            if not checkpoint_problem(ck, need_state=False):
                return ck
    for base in (path / "checkpoints", path):
        latest = base / "latest"
        if latest.is_file():
            try:
                c = base / latest.read_text(errors="replace").strip()
            except OSError:
                continue
            if latest.read_text(errors="replace").strip() and (c / MODEL_FILE).is_file():
                return c
    if (path / MODEL_FILE).is_file():
        return path
    return None


def model_file_of(path: Path) -> Path:
    """The model file of a checkpoint (any form :func:`find_checkpoint` accepts); InputError if none."""
    path = Path(path)
    ck = find_checkpoint(path)
    model_file = path if path.is_file() else (ck / MODEL_FILE if ck else None)
    if model_file is None or not Path(model_file).is_file():
        damaged = [c for base in (path / "checkpoints", path) for c in checkpoint_folders(base)]
        if damaged:
            raise InputError(f"no complete checkpoint at {path}: {damaged[0].name} is damaged "
                             f"({checkpoint_problem(damaged[0], need_state=False)})")
        raise InputError(f"no checkpoint found at {path}")
    return Path(model_file)


def read_header_meta(model_file: Path) -> dict[str, str]:
    """The ``__metadata__`` of a safetensors file, read from its header (8-byte length + JSON)."""
    model_file = Path(model_file)
    try:
        with open(model_file, "rb") as f:
            head = f.read(8)
            if len(head) < 8:
                raise ValueError("file too short")
            (n,) = struct.unpack("<Q", head)
            if n > MAX_HEADER:
                raise ValueError("header too large")
            raw = f.read(n)
            if len(raw) < n:
                raise ValueError("truncated header")
        header = json.loads(raw.decode("utf-8"))
    except (OSError, ValueError, UnicodeDecodeError) as e:
        raise InputError(f"checkpoint {model_file} does not load: {e}") from None
    meta = header.get("__metadata__") if isinstance(header, dict) else None
    return dict(meta) if isinstance(meta, dict) else {}


def checked_header(path: Path) -> tuple[Path, dict[str, str]]:
    """(model file, metadata) of a checkpoint after checking it is a blender_mrvm model of a format
    version this code reads; InputError naming what is wrong."""
    model_file = model_file_of(path)
    meta = read_header_meta(model_file)
    why = model_file_problem(model_file)
    if why:
        raise InputError(f"checkpoint {model_file} does not load: {why}")
    if meta.get("format") != FORMAT:
        raise InputError(f"{model_file} is not a blender_mrvm model checkpoint (format {meta.get('format')!r})")
    try:
        version = int(meta.get("format_version", -1))
    except ValueError:
        version = -1
    if version > FORMAT_VERSION:
        raise InputError(f"{model_file} has format version {meta['format_version']}, newer than this code ({FORMAT_VERSION})")
    return model_file, meta


def model_kind(meta: dict[str, str]) -> str:
    """The model kind recorded in a checkpoint's metadata (checkpoints without one are NeRFormer+MRVM)."""
    from .registry import DEFAULT_KIND

    return str(meta.get("model_kind") or DEFAULT_KIND)


def model_name(meta: dict[str, str]) -> str:
    """The model preset name recorded in a checkpoint's metadata ('' when unreadable)."""
    try:
        return str(json.loads(meta["model_config"])["name"])
    except (KeyError, ValueError, TypeError):
        return ""
