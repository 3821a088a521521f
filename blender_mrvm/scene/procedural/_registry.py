"""Category registry, named parameters and the global part-label table (no bpy needed here).

Label ids are stable: category ``i`` (its index in :data:`CATEGORIES`) owns ids ``16*i + 1`` to
``16*i + 15``, given to its parts in the order they are declared; new parts are only ever appended.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ...errors import InputError

CATEGORIES: tuple[str, ...] = ("airplane", "bench", "cabinet", "car", "chair", "display", "lamp", "loudspeaker",
                               "rifle", "sofa", "table", "telephone", "watercraft")
"""The ShapeNet-13 categories, in ShapeNet's (alphabetical) order."""

PARTS: dict[str, tuple[str, ...]] = {
    "airplane": ("fuselage", "wing", "tail", "engine", "propeller", "landing_gear", "window"),
    "bench": ("seat", "back", "leg", "arm", "frame"),
    "cabinet": ("body", "door", "drawer", "handle", "shelf", "leg"),
    "car": ("body", "wheel", "window", "light", "bumper", "hubcap"),
    "chair": ("seat", "back", "leg", "arm", "base", "caster"),
    "display": ("screen", "frame", "stand", "base"),
    "lamp": ("base", "stem", "shade", "bulb", "joint"),
    "loudspeaker": ("cabinet", "driver", "grille", "port", "foot"),
    "rifle": ("barrel", "receiver", "stock", "grip", "magazine", "scope", "handguard", "bipod"),
    "sofa": ("frame", "seat_cushion", "back_cushion", "arm", "leg", "pillow"),
    "table": ("top", "leg", "apron", "pedestal", "shelf"),
    "telephone": ("body", "screen", "button", "camera", "handset", "antenna"),
    "watercraft": ("hull", "deck", "cabin", "mast", "sail", "funnel", "window"),
}
"""Part names per category, in id order."""

LABEL_BLOCK = 16


def label_ids(category: str) -> dict[str, int]:
    base = LABEL_BLOCK * CATEGORIES.index(category) + 1
    return {name: base + j for j, name in enumerate(PARTS[category])}


PART_LABELS: dict[int, str] = {i: f"{c}/{name}" for c in CATEGORIES for name, i in label_ids(c).items()}
"""Global part-label table: id -> "category/part"; 0 is the background."""

assert all(0 < i < 256 for i in PART_LABELS) and all(len(p) < LABEL_BLOCK for p in PARTS.values())


# --------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Param:
    """A named generator parameter: sampled from the seed unless the caller sets it."""

    name: str
    """Keyword name passed to build()."""
    kind: str
    """"choice", "bool", "int" or "float"."""
    options: tuple = ()
    """Choices (kind "choice")."""
    lo: float = 0.0
    """Lower end of the sampled range (int/float); bool: probability of True."""
    hi: float = 1.0
    """Upper end of the sampled range (int/float, inclusive for int)."""
    min: float | None = None
    """Smallest value a caller may set (defaults to lo)."""
    max: float | None = None
    """Largest value a caller may set (defaults to hi)."""
    weights: tuple = ()
    """Sampling weights of the choices (uniform when empty)."""

    def sample(self, rng: np.random.Generator) -> Any:
        u = float(rng.uniform())  # exactly one draw per parameter keeps the streams aligned
        if self.kind == "choice":
            w = np.asarray(self.weights or [1.0] * len(self.options), float)
            c = np.cumsum(w / w.sum())
            return self.options[int(min(np.searchsorted(c, u, side="right"), len(self.options) - 1))]
        if self.kind == "bool":
            return u < self.lo
        if self.kind == "int":
            return int(self.lo + math.floor(u * (self.hi - self.lo + 1 - 1e-9)))
        return float(self.lo + u * (self.hi - self.lo))

    def check(self, category: str, value: Any) -> Any:
        where = f"{category} parameter {self.name!r}"
        if self.kind == "choice":
            if value not in self.options:
                raise InputError(f"{where} must be one of {', '.join(map(str, self.options))}, got {value!r}")
            return value
        if self.kind == "bool":
            if not isinstance(value, (bool, np.bool_)):
                raise InputError(f"{where} must be true or false, got {value!r}")
            return bool(value)
        lo = self.lo if self.min is None else self.min
        hi = self.hi if self.max is None else self.max
        if self.kind == "int":
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                raise InputError(f"{where} must be an integer, got {value!r}")
            value = int(value)
        else:
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(float(value)):
                raise InputError(f"{where} must be a finite number, got {value!r}")
            value = float(value)
        if value < lo or value > hi:
            noun = "count" if self.kind == "int" else "value"
            if value < 0 <= lo:
                raise InputError(f"{where} must not be negative, got {value!r} (allowed {lo:g} to {hi:g})")
            raise InputError(f"{where} {noun} {value!r} is out of range ({lo:g} to {hi:g})")
        return value


def choice(name: str, *options, weights=()) -> Param:
    return Param(name, "choice", tuple(options), weights=tuple(weights))


def flag(name: str, p: float) -> Param:
    return Param(name, "bool", lo=p)


def integer(name: str, lo: int, hi: int, min: int | None = None, max: int | None = None) -> Param:
    return Param(name, "int", lo=lo, hi=hi, min=min, max=max)


def real(name: str, lo: float, hi: float, min: float | None = None, max: float | None = None) -> Param:
    return Param(name, "float", lo=lo, hi=hi, min=min, max=max)


class P(dict):
    """Resolved parameters; attribute access for readability in generators."""

    __getattr__ = dict.__getitem__


@dataclass(frozen=True)
class Generator:
    category: str
    params: tuple[Param, ...]
    fn: Callable


GENERATORS: dict[str, Generator] = {}


def category(name: str, params: tuple[Param, ...]):
    """Register ``fn(p: P, rng, m: PartMesh) -> dict[part, material kind]`` for ``name``."""
    def deco(fn):
        GENERATORS[name] = Generator(name, params, fn)
        return fn
    return deco


def check_seed(seed: Any) -> int:
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        raise InputError(f"seed must be an integer, got {seed!r}")
    if seed < 0 or seed >= 2 ** 63:
        raise InputError(f"seed must be a non-negative integer below 2**63, got {seed}")
    return int(seed)


def resolve(category_name: str, seed: Any, params: dict[str, Any]) -> tuple[P, int]:
    """Validate the category, seed and parameters; sample the ones not given."""
    if category_name not in GENERATORS:
        raise InputError(f"unknown category {category_name!r}; choose one of {', '.join(CATEGORIES)}")
    seed = check_seed(seed)
    gen = GENERATORS[category_name]
    names = {p.name for p in gen.params}
    unknown = sorted(set(params) - names)
    if unknown:
        raise InputError(f"unknown {category_name} parameter {unknown[0]!r}; known: {', '.join(sorted(names))}")
    rng = np.random.default_rng([seed, CATEGORIES.index(category_name), 0])
    out = P()
    for p in gen.params:
        v = p.sample(rng)
        out[p.name] = p.check(category_name, params[p.name]) if p.name in params else v
    return out, seed
