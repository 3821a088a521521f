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
import shutil
import tempfile
from pathlib import Path
from typing import Any

import torch

from ..datasets.format import atomic_write_text, disk_full_error, ordinary_permissions, replace_file
from ..errors import InputError
from ..models.checkpoint_files import (FORMAT, FORMAT_VERSION, MODEL_FILE, STATE_FILE, checked_header,
                                       checkpoint_folders, find_checkpoint, model_file_of,
                                       read_header_meta)  # noqa: F401 (re-exported)
from ..models import registry
from ..models.config import to_dict


def save_checkpoint(run_dir: Path, step: int, model: torch.nn.Module, model_cfg: Any,
                    trainer_state: dict[str, Any] | None, extra_meta: dict[str, Any] | None = None,
                    keep: int = 2, kind: str | None = None) -> Path:
    """Atomic checkpoint ``<run>/checkpoints/step_NNNNNNN/`` (+ ``latest``) of any model kind (``kind``: the
    registry's for ``model_cfg`` when None); returns its folder."""
    from safetensors.torch import save_model

    ck_root = Path(run_dir) / "checkpoints"
    ck_root.mkdir(parents=True, exist_ok=True)
    name = f"step_{step:07d}"
    tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", dir=ck_root))
    try:
        meta = {"format": FORMAT, "format_version": str(FORMAT_VERSION), "step": str(step),
                "model_kind": kind or registry.kind_of(model_cfg), "model_config": json.dumps(to_dict(model_cfg))}
        for k, v in (extra_meta or {}).items():
            meta[k] = v if isinstance(v, str) else json.dumps(v)
        try:
            save_model(model, str(tmp / MODEL_FILE), metadata=meta)
            if trainer_state is not None:
                torch.save(trainer_state, tmp / STATE_FILE)
        except RuntimeError as e:  # a full disk: torch's zip writer says 'unexpected pos' or 'iostream error'
            raise disk_full_error(e, tmp) or e
        ordinary_permissions(tmp)
        final = ck_root / name
        if final.exists():
            shutil.rmtree(final)
        replace_file(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    atomic_write_text(ck_root / "latest", name + "\n")
    # oldest first by step, as checkpoint_folders orders them: by name, step_10000000 sorted before step_9999000,
    # so from the ten-millionth step on every new checkpoint but the current was pruned and the old ones kept
    done = checkpoint_folders(ck_root)[::-1]
    for old in done[:-keep] if keep > 0 else []:
        if old.name != name:
            shutil.rmtree(old, ignore_errors=True)
    return final


read_meta = read_header_meta
"""A model file's safetensors metadata (unchecked)."""


def config_from_meta(meta: dict[str, str], where: Path | str) -> Any:
    """The model config (of the recorded kind) in a checkpoint's metadata; one-line InputError when it
    is missing, not JSON, or not a valid config of that kind."""
    kind = registry.kind_from_meta(meta)
    try:
        data = json.loads(meta["model_config"])
    except KeyError:
        raise InputError(f"checkpoint {where} has no model config in its metadata") from None
    except ValueError as e:
        raise InputError(f"checkpoint {where} has an unreadable model config ({e})") from None
    try:
        return registry.config_from_dict(kind, data)
    except (TypeError, ValueError) as e:
        raise InputError(f"checkpoint {where} has an unreadable {kind} model config ({e})") from None


def read_model_config(model_file: Path) -> Any:
    """The model config (of any kind) stored in a model file."""
    model_file, meta = checked_header(model_file)
    return config_from_meta(meta, model_file)


class WeightsMismatch(InputError):
    """A model file's weights do not fit the model they are loaded into (another architecture)."""


def load_weights(model: torch.nn.Module, model_file: Path, device: str = "cpu") -> None:
    """Load a model file's weights into ``model``; InputError naming the mismatch when they do not fit."""
    from safetensors.torch import load_model as st_load

    try:
        st_load(model, str(model_file), strict=True, device=device)
    except RuntimeError as e:
        raise WeightsMismatch(f"checkpoint {model_file} does not match its model config: {_first_line(e)}") from None
    except Exception as e:  # safetensors' own errors: a damaged file
        raise InputError(f"checkpoint {model_file} does not load: {_first_line(e)}") from None
    _check_finite(model, model_file)


def _first_line(e: Exception) -> str:
    return (str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__)[:300]


DIVERGED_WEIGHT = 1e8
"""Largest absolute weight a training run saves (:func:`nonfinite_weights`' ``limit``): trained models' weights stay
within a few units (the shipped ones' largest is 5), while a step with a diverging learning rate leaves finite
weights of 1e30 that render nothing but NaN (float32 overflows a layer or two later)."""


def nonfinite_weights(model: torch.nn.Module | dict[str, torch.Tensor], limit: float | None = None) -> list[str]:
    """The names of ``model``'s floating-point parameters and buffers (or of a dict's tensors) that hold NaN or
    infinite values, or with ``limit`` values larger than it in magnitude (one host sync when none does: a
    diverged training step is caught before it is saved)."""
    tensors = model.state_dict() if isinstance(model, torch.nn.Module) else model
    floats = [(k, v.detach()) for k, v in tensors.items() if v.is_floating_point() and v.numel()]
    if not floats:
        return []
    peaks = torch.stack([v.abs().max().float() for _, v in floats])  # (NaN stays NaN: max propagates it)
    ok = torch.isfinite(peaks) if limit is None else peaks <= limit
    if bool(ok.all()):
        return []
    return [k for (k, _), good in zip(floats, ok.tolist()) if not good]


def _check_finite(model: torch.nn.Module, model_file: Path) -> None:
    bad = nonfinite_weights(model)
    if bad:
        raise InputError(f"checkpoint {model_file} holds NaN or infinite weights ({bad[0]}"
                         f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''})")


def load_weights_deepened(model: torch.nn.Module, model_file: Path, device: str = "cpu") -> list[str]:
    """Load a model file into a deeper copy of its model: the same widths, more transformer blocks in some
    stacks. The file's blocks fill the first places of each stack and the added blocks start as the identity
    (``make_identity``), so the deeper model computes exactly what the file's did and training goes on from
    there (capacity grown from a trained model instead of a random start). Returns the added blocks' names;
    :class:`WeightsMismatch` unless the two models differ by exactly such whole blocks."""
    from safetensors.torch import load_file

    try:
        theirs = load_file(str(model_file), device=device)
    except Exception as e:  # safetensors' own errors: a damaged file
        raise InputError(f"checkpoint {model_file} does not load: {_first_line(e)}") from None
    own = model.state_dict()
    shape = [k for k in theirs if k in own and tuple(theirs[k].shape) != tuple(own[k].shape)]
    extra = sorted(set(theirs) - set(own))
    missing = set(own) - set(theirs)
    added = [n for n, m in model.named_modules() if hasattr(m, "make_identity")
             and {f"{n}.{k}" for k in m.state_dict()} <= missing]
    covered = {f"{n}.{k}" for n in added for k in model.get_submodule(n).state_dict()}
    if shape or extra or missing - covered or not added:
        what = (f"{shape[0]} has another shape" if shape else f"{extra[0]} is not in the model" if extra
                else f"{sorted(missing - covered)[0]} is not in the file" if missing - covered
                else "the file's model is not shallower")
        raise WeightsMismatch(f"checkpoint {model_file} is not a shallower copy of this model: {what}")
    model.load_state_dict(theirs, strict=False)
    for n in added:
        model.get_submodule(n).make_identity()
    _check_finite(model, model_file)
    return added


def load_model(path: Path, device: str = "cpu"):
    """(model, model_cfg, meta) from a checkpoint of any kind (any form :func:`find_checkpoint` accepts).

    A run folder that a training is writing may lose the checkpoint picked (pruned, ``keep_checkpoints``) before
    it is read: then the newest is picked again (twice at most)."""
    for tries in range(3):
        picked = find_checkpoint(path)
        try:
            return _load_model(path, device)
        except (InputError, FileNotFoundError):
            if tries == 2 or picked is None or picked.exists() or Path(path).is_file():
                raise
    raise AssertionError("unreachable")


def _load_model(path: Path, device: str = "cpu"):
    model_file, meta = checked_header(path)
    cfg = config_from_meta(meta, model_file)
    model = registry.build_model(cfg, load_pretrained=False)  # the checkpoint holds every weight
    load_weights(model, model_file, device)
    model.checkpoint_file = model_file  # named when its renders come out NaN (models.base.check_finite_view)
    return model.to(device), cfg, meta


def load_trainer_state(ck: Path) -> dict[str, Any]:
    return torch.load(Path(ck) / STATE_FILE, map_location="cpu", weights_only=True)


def _read_tensors(model_file: Path) -> tuple[dict[str, str], dict[str, torch.Tensor]]:
    """A model file's metadata and tensors."""
    from safetensors import safe_open

    with safe_open(str(model_file), "pt") as f:
        return f.metadata() or {}, {k: f.get_tensor(k) for k in f.keys()}


_ST_DTYPES = {torch.float64: "F64", torch.float32: "F32", torch.float16: "F16", torch.bfloat16: "BF16",
              torch.int64: "I64", torch.int32: "I32", torch.int16: "I16", torch.int8: "I8", torch.uint8: "U8",
              torch.bool: "BOOL"}


def safetensors_bytes(tensors: dict[str, torch.Tensor], meta: dict[str, str]) -> list[bytes]:
    """The safetensors file of ``tensors`` and ``meta``, as byte blocks in file order, the same bytes in every
    process. (``safetensors.save_file`` writes the metadata map in a per-process hash order, so one model halved
    twice gave two sha256s and a shipped file's hash could not be checked by re-making it.) The layout is the
    format's: a little-endian u64 header length, the JSON header padded with spaces to 8 bytes, then the tensors'
    bytes back to back; metadata keys sorted, tensors by element size (largest first, so each starts aligned)
    then name."""
    import struct

    header: dict[str, Any] = {"__metadata__": {k: str(meta[k]) for k in sorted(meta)}} if meta else {}
    blobs, offset = [], 0
    for name in sorted(tensors, key=lambda k: (-tensors[k].element_size(), k)):
        t = tensors[name].detach().to("cpu").contiguous()
        if t.dtype not in _ST_DTYPES:
            raise TypeError(f"tensor {name!r} has dtype {t.dtype}, which model files do not store")
        b = t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b""
        header[name] = {"dtype": _ST_DTYPES[t.dtype], "shape": list(t.shape), "data_offsets": [offset, offset + len(b)]}
        blobs.append(b)
        offset += len(b)
    h = json.dumps(header, separators=(",", ":"), ensure_ascii=False).encode()
    h += b" " * (-len(h) % 8)
    return [struct.pack("<Q", len(h)), h, *blobs]


def _write_tensors(tensors: dict[str, torch.Tensor], meta: dict[str, str], out: Path) -> Path:
    """Write a model file atomically and byte-stably (:func:`safetensors_bytes`), with ordinary permissions."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    with open(tmp, "wb") as f:
        for block in safetensors_bytes(tensors, meta):
            f.write(block)
    ordinary_permissions(tmp)
    replace_file(tmp, out)
    return out


def half_copy(model_file: Path, out: Path) -> Path:
    """A copy of a model file with its floating-point tensors stored in fp16 (half the bytes; they load into the
    model's fp32 layers, ~1e-3 relative rounding) and the same metadata: how shipped and GPU-trained models
    travel (at most 16 MiB a file comes back from the GPU machine; 25 MB a shipped model). Written atomically."""
    meta, tensors = _read_tensors(Path(model_file))
    return _write_tensors({k: t.half() if t.is_floating_point() else t for k, t in tensors.items()}, meta, Path(out))


def average_model_files(model_files: list[Path], out: Path) -> Path:
    """The mean of the weights of models fine-tuned from one starting point ("model soup", Wortsman et al. 2022:
    runs that share a start usually sit in one basin, and their mean often generalises better than each, at no
    cost at inference). The files must hold the same model config and tensors; the first one's metadata is kept,
    with ``averaged_from`` (the files' names) added. Floats are averaged in float64 and stored in the first
    file's dtype. InputError for fewer than two files, a different config, or different tensors."""
    files = [Path(f) for f in model_files]
    if len(files) < 2:
        raise InputError(f"averaging needs at least two model files, got {len(files)}")
    meta, acc = _read_tensors(files[0])
    dtypes = {k: t.dtype for k, t in acc.items()}
    acc = {k: t.double() if t.is_floating_point() else t for k, t in acc.items()}
    for f in files[1:]:
        m, ts = _read_tensors(f)
        if m.get("model_config") != meta.get("model_config") or m.get("model_kind") != meta.get("model_kind"):
            raise InputError(f"{f} holds another model than {files[0]} (model config differs): only runs of one "
                             "model can be averaged")
        if set(ts) != set(acc) or any(ts[k].shape != acc[k].shape for k in acc):
            raise InputError(f"{f} holds other tensors than {files[0]}")
        for k, t in ts.items():
            if t.is_floating_point():
                acc[k] += t.double()
            elif not torch.equal(t, acc[k]):
                raise InputError(f"{f}: non-float tensor {k} differs from {files[0]}'s")
    n = len(files)
    mean = {k: (t / n).to(dtypes[k]) if t.is_floating_point() else t for k, t in acc.items()}
    if not all(torch.isfinite(t).all() for t in mean.values() if t.is_floating_point()):
        raise InputError("the average holds non-finite weights: one of the files is broken")
    return _write_tensors(mean, {**meta, "averaged_from": json.dumps([f"{f.parent.name}/{f.name}" for f in files])},
                          Path(out))
