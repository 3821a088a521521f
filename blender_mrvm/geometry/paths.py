"""Hand-held camera paths around an object: what a person walking round it with a phone records. bpy-free.

A path is an arc (or a whole loop) around the object at a height and distance that drift smoothly,
with the small roll and look-at wander of a hand-held camera. Every irregular component is a sum of a
few low-frequency sinusoids with seeded phases (at most a few cycles over the path), so consecutive
cameras stay close whatever the number of views; the azimuth advances monotonically at a speed that
varies (a person slows down and speeds up). All in world units, world z up, OpenCV camera-to-world.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import InputError
from .cameras import look_at_opencv


@dataclass(frozen=True)
class PathSpec:
    """The drawn parameters of one hand-held path (recorded in the dataset's meta.json)."""

    start_azimuth_deg: float
    """Azimuth of the first camera (0 = +x, counter-clockwise seen from above)."""
    span_deg: float
    """Azimuth swept from the first to the last camera (360 = a closed loop)."""
    distance: float
    """Mean horizontal distance from the target, world units."""
    height: float
    """Mean camera height above the target, world units."""
    distance_jitter: float
    """Smooth distance change, as a fraction of ``distance`` (peak)."""
    height_jitter: float
    """Smooth height change, world units (peak)."""
    roll_deg: float
    """Smooth roll about the optical axis, degrees (peak)."""
    look_jitter: float
    """Smooth wander of the look-at point around the target, world units (peak, per axis)."""
    speed_variation: float
    """How much the walking speed varies along the path (0 = constant; < 1 keeps it moving forward)."""
    seed: int
    """Seed of the phases and frequencies of the smooth components."""

    def record(self) -> dict:
        return asdict(self)


def draw_path(rng: np.random.Generator, distance_range=(1.5, 2.3), height_range=(0.1, 1.1),
              span_range_deg=(200.0, 360.0)) -> PathSpec:
    """A path's parameters drawn from ``rng`` (distances/heights for an object of diagonal 1)."""
    span = float(rng.uniform(*span_range_deg))
    if span > 330.0:
        span = 360.0  # a closed loop round the object
    return PathSpec(start_azimuth_deg=float(rng.uniform(0.0, 360.0)), span_deg=span,
                    distance=float(rng.uniform(*distance_range)), height=float(rng.uniform(*height_range)),
                    distance_jitter=float(rng.uniform(0.04, 0.12)), height_jitter=float(rng.uniform(0.05, 0.2)),
                    roll_deg=float(rng.uniform(1.0, 4.0)), look_jitter=float(rng.uniform(0.02, 0.08)),
                    speed_variation=float(rng.uniform(0.1, 0.4)), seed=int(rng.integers(2**31)))


def _smooth(rng: np.random.Generator, s: np.ndarray, closed: bool, cycles=(1, 2)) -> np.ndarray:
    """A smooth signal in [-1, 1] over path parameter ``s`` in [0, 1): a few sinusoids of low frequency
    (``cycles`` per path, amplitude 1 / cycles).

    On a closed loop the frequencies are whole numbers of cycles so the path joins up; on an arc each
    is drawn within half a cycle of its nominal number."""
    out = np.zeros_like(s)
    total = 0.0
    for c in cycles:
        f = float(c) if closed else float(rng.uniform(c - 0.5, c + 0.5))
        a = 1.0 / c  # lower frequencies carry more of the motion
        out += a * np.sin(2.0 * math.pi * f * s + rng.uniform(0.0, 2.0 * math.pi))
        total += a
    return out / total


def _roll(c2w: np.ndarray, angle: float) -> np.ndarray:
    """The same camera rotated by ``angle`` (radians) about its optical axis (+z in OpenCV)."""
    c, s = math.cos(angle), math.sin(angle)
    rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    out = c2w.copy()
    out[:3, :3] = c2w[:3, :3] @ rz
    return out


def handheld_poses(spec: PathSpec, n: int, target=(0.0, 0.0, 0.0)) -> list[np.ndarray]:
    """``n`` OpenCV camera-to-world poses along the path ``spec`` around ``target``."""
    if n < 2:
        raise InputError(f"a camera path needs at least 2 views, got {n}")
    if not (spec.distance > 0 and 0 <= spec.speed_variation < 1):
        raise InputError("a camera path needs a positive distance and a speed variation below 1")
    rng = np.random.default_rng([spec.seed, 5])
    closed = spec.span_deg >= 360.0
    s = np.arange(n) / (n if closed else n - 1)  # a loop does not repeat its first camera
    # monotonic progress with a varying speed: u(s) = s + v * sin(2 pi s k + p) / (2 pi k), derivative >= 1 - v
    k = 1.0 if closed else float(rng.uniform(0.7, 1.5))
    p = float(rng.uniform(0.0, 2.0 * math.pi))
    u = s + spec.speed_variation * (np.sin(2.0 * math.pi * k * s + p) - math.sin(p)) / (2.0 * math.pi * k)
    if not closed:
        u = (u - u[0]) / (u[-1] - u[0])
    az = math.radians(spec.start_azimuth_deg) + math.radians(spec.span_deg) * u
    dist = spec.distance * (1.0 + spec.distance_jitter * _smooth(rng, s, closed))
    height = spec.height + spec.height_jitter * _smooth(rng, s, closed)
    roll = math.radians(spec.roll_deg) * _smooth(rng, s, closed, (1, 2, 3))
    look = spec.look_jitter * np.stack([_smooth(rng, s, closed, (1, 2, 3)) for _ in range(3)], axis=1)
    t = np.asarray(target, np.float64).reshape(3)
    eyes = np.stack([t[0] + dist * np.cos(az), t[1] + dist * np.sin(az), t[2] + height], axis=1)
    return [_roll(look_at_opencv(e, t + lk), r) for e, lk, r in zip(eyes, look, roll)]


def neighbour_inputs(views: int, targets: list[int], n_inputs: int) -> dict[int, list[int]]:
    """Each target's ``n_inputs`` nearest non-target views along the path (by index offset: -1, +1, -2,
    +2, ...), sorted; the held-out-views protocol of ``make-captures``."""
    held = set(targets)
    out = {}
    for t in targets:
        cands = [t + d * sgn for d in range(1, views) for sgn in (-1, 1)]
        refs = [c for c in cands if 0 <= c < views and c not in held][:n_inputs]
        if len(refs) < n_inputs:
            raise InputError(f"view {t} has only {len(refs)} non-held-out views for {n_inputs} inputs")
        out[t] = sorted(refs)
    return out
