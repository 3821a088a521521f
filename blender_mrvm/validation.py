"""Checks shared by the frozen config dataclasses (bpy-free, torch-free).

Configs are validated once, where they are built: each dataclass's ``__post_init__`` calls
:func:`check_types` (every field has the type its annotation names: a JSON ``"abc"`` for an int is
an :class:`InputError`, not a TypeError deep in training) and then its own range checks with the
helpers below. ``from_dict``, ``merge``/``replace`` and the CLI all build configs through the
constructor, so they all get the same checks and the same one-line messages.
"""

from __future__ import annotations

import math
import numbers
import types
import typing
from dataclasses import fields
from pathlib import Path
from typing import Any

from .errors import InputError

MAX_IMAGE_SIDE = 8192
"""Largest image side any command makes (render-dataset's limit too)."""
MAX_REFERENCE_SIDE = 4096
"""Largest side references are resized to, or kept at (``--ref-size -1``). The image encoder runs one view at a time
(``models.encoder.per_view``), so its peak is one view's plus the features kept of each, measured on the CPU in
float32 at 4096 px (GiB): the shipped NeRFormer encoders (``shipped``, ``shipped:mrvm_anyview``) 2.0 for the first
view and 0.94 for each more (0.75 features, 0.19 pixels); GPNR's 2.4 and 1.2; the quality model's VGG16 3.0 and 0.42
at 2048 px, so about 12 and 1.7 at 4096 (every figure scales with the pixels: a quarter at 2048 px). Encoded all at
once, one view took 5.5 and two 6.3 in the shipped encoder (``synthesize`` peaked at 12.1 GiB with two 8000 px photos
at ``--ref-size 4096``, 4.2 now). Kept at 4096: the default models fit a 16 GB machine there with several
references; no model gains from references larger than it was trained on (64-128 px; docs/guide/novel_views.md)."""
MAX_REFERENCE_BYTES = 4 << 30
"""Most memory a synthesis's references may take as float32 RGB pixels (views x width x height x 12 bytes), checked
after the first is read, before the others: 50 photos of 4000x4000 kept at their size (``--ref-size -1``) need
9.6 GB, and a 6 GiB cap failed at the 28th after 16 s with a message blaming that photo."""


def _name(obj: Any, field: str) -> str:
    """How a field is named in messages: ``<label>.<field>``, the label being the class attribute
    ``config_label`` (e.g. "train", as in a run config) or the class name."""
    return f"{getattr(type(obj), 'config_label', type(obj).__name__)}.{field}"


def _coerce(value: Any, hint: Any, label: str) -> Any:
    """``value`` as the type ``hint`` names, or InputError. Accepts int for float and integral floats
    for int (JSON numbers); never bool for a number or a string for anything but str/Path."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, label)
            except InputError as e:
                errors.append(str(e))
        raise InputError(errors[0] if errors else f"{label}: bad value {value!r}")
    if origin is tuple or hint is tuple:
        if isinstance(value, (str, bytes)) or not hasattr(value, "__iter__"):
            raise InputError(f"{label} must be a list, got {value!r}")
        args = typing.get_args(hint)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], label) for v in value)
        return tuple(value)
    if hint is bool:
        if not isinstance(value, bool):
            raise InputError(f"{label} must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise InputError(f"{label} must be an integer, got {value!r}")
        if not isinstance(value, numbers.Integral):
            if not math.isfinite(value) or value != int(value):
                raise InputError(f"{label} must be an integer, got {value!r}")
        return value if type(value) is int else int(value)  # numpy integers and 3.0 become int
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            raise InputError(f"{label} must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise InputError(f"{label} must be a finite number, got {value!r}")
        return value
    if hint is str:
        if not isinstance(value, str):
            raise InputError(f"{label} must be a string, got {value!r}")
        return value
    if hint is Path:
        if not isinstance(value, (str, Path)):
            raise InputError(f"{label} must be a path, got {value!r}")
        return Path(value)
    return value  # nested dataclasses and other types: their own __post_init__ checks them


def check_types(obj: Any) -> None:
    """Check (and coerce, e.g. 1 -> 1.0 for a float field) every field of a frozen dataclass against
    its annotation; InputError naming the field."""
    hints = typing.get_type_hints(type(obj))
    for f in fields(obj):
        value = getattr(obj, f.name)
        new = _coerce(value, hints.get(f.name, Any), _name(obj, f.name))
        if new is not value:
            object.__setattr__(obj, f.name, new)


def at_least(obj: Any, field: str, low: float) -> None:
    v = getattr(obj, field)
    if v < low:
        raise InputError(f"{_name(obj, field)} must be at least {low}, got {v}")


def in_range(obj: Any, field: str, low: float, high: float) -> None:
    v = getattr(obj, field)
    if not low <= v <= high:
        raise InputError(f"{_name(obj, field)} must be between {low} and {high}, got {v}")


def one_of(obj: Any, field: str, choices: tuple) -> None:
    v = getattr(obj, field)
    if v not in choices:
        raise InputError(f"{_name(obj, field)} must be one of {', '.join(map(repr, choices))}, got {v!r}")


def check_device_name(label: str, name: str, allow_auto: bool = True) -> None:
    """'cpu', 'cuda', 'cuda:N' (and 'auto'): the spelling only; whether CUDA exists is checked when the
    device is opened."""
    n = (name or "").strip().lower()
    ok = n in (("auto",) if allow_auto else ()) + ("cpu", "cuda")
    if n.startswith("cuda:"):
        ok = n[5:].isdigit()
    if not ok:
        choices = "auto, cpu or cuda[:N]" if allow_auto else "cpu or cuda[:N]"
        raise InputError(f"{label}: unknown device {name!r}; choose {choices}")


def check_image_side(label: str, value: int, low: int = 1, high: int = MAX_IMAGE_SIDE) -> None:
    """A pixel size given on the command line (``--orbit-size``, ``--ref-size``, ...)."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise InputError(f"{label} must be a whole number of pixels, got {value!r}")
    if not low <= value <= high:
        raise InputError(f"{label} must be between {low} and {high} pixels, got {value}")


# The references' size: one rule (their longer side at most MAX_REFERENCE_SIDE, all of them at most
# MAX_REFERENCE_BYTES), checked when the size is known: up front for --ref-size N (check_ref_size), after the first
# image is read when the references keep their own size (--ref-size -1: check_reference_memory).

def check_ref_size(label: str, value: int) -> None:
    """``--ref-size``: 0 (the model's training size), -1 (the first reference's own) or a longer side in pixels, at
    most :data:`MAX_REFERENCE_SIDE` (for -1, :func:`check_reference_memory` checks the size read)."""
    if value in (0, -1) and not isinstance(value, bool):
        return
    try:
        check_image_side(label, value, 1, MAX_REFERENCE_SIDE)
    except InputError:  # (say that 0 and -1 are legal too)
        raise InputError(f"{label} must be 0 (the model's size), -1 (the first reference's size) or 1 to "
                         f"{MAX_REFERENCE_SIDE} pixels, got {value!r}") from None


def check_reference_memory(count: int, w: int, h: int, side_limit: int = 0) -> None:
    """InputError when references at ``w`` x ``h`` are larger than ``side_limit`` (0 = no limit; synthesis passes
    :data:`MAX_REFERENCE_SIDE`) on the longer side, or ``count`` of them would take more than
    :data:`MAX_REFERENCE_BYTES` as float pixels; the message names the --ref-size that fits (and --views). Two
    8000x8000 photos kept at their size (``--ref-size -1``) ran out of an 8 GiB cap in the image encoder after
    13 s."""
    if side_limit and max(w, h) > side_limit:
        raise InputError(f"the reference views would be {w}x{h}, over the {side_limit} px limit for references "
                         "(the image encoder's memory grows with their pixels); pass --ref-size "
                         f"{side_limit} or smaller (their longer side in pixels; in the panel: Reference size Custom)")
    need = count * w * h * 12
    if need <= MAX_REFERENCE_BYTES:
        return
    fits = int(max(w, h) * (MAX_REFERENCE_BYTES / need) ** 0.5)
    raise InputError(f"{count} reference views at {w}x{h} take {need / 2**30:.1f} GiB of memory, over the "
                     f"{MAX_REFERENCE_BYTES / 2**30:.0f} GiB limit for references; pass --ref-size {fits} or "
                     "smaller (their longer side in pixels; in the panel: Reference size Custom), or choose fewer "
                     "with --views")


def check_count(label: str, value: int, low: int = 0, high: int | None = None) -> None:
    """A count given on the command line (``--views``, ``--objects``, ``--chunk``, ``--threads``)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low or (high is not None and value > high):
        rng = f"at least {low}" if high is None else f"between {low} and {high}"
        raise InputError(f"{label} must be {rng}, got {value!r}")


def check_types_deep(obj: Any) -> None:
    """:func:`check_types` on a dataclass and every dataclass nested in it."""
    from dataclasses import is_dataclass

    check_types(obj)
    for f in fields(obj):
        v = getattr(obj, f.name)
        if is_dataclass(v) and not isinstance(v, type):
            check_types_deep(v)


def check_sizes(obj: Any, label: str = "") -> None:
    """Every int field of a (nested) config dataclass is >= 0 (sizes and counts), every int in an int
    tuple >= 1 (layer widths); InputError naming the first that is not."""
    from dataclasses import is_dataclass

    for f in fields(obj):
        v = getattr(obj, f.name)
        name = f"{label}{f.name}"
        if is_dataclass(v) and not isinstance(v, type):
            check_sizes(v, name + ".")
        elif isinstance(v, int) and not isinstance(v, bool) and v < 0:
            raise InputError(f"model {name} must be at least 0, got {v}")
        elif isinstance(v, tuple) and v and all(isinstance(x, int) and not isinstance(x, bool) for x in v) \
                and min(v) < 1:
            raise InputError(f"model {name} must hold sizes of at least 1, got {list(v)}")
