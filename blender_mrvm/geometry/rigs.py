"""Camera rigs around an object at the origin (world z up). bpy-free.

Every rig returns OpenCV camera-to-world poses looking at the origin. The ``scene`` rig (cameras
already in a Blender scene) lives in ``scene/`` because it reads bpy objects.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import InputError
from .cameras import look_at_opencv

RIGS = ("sphere", "hemisphere", "spiral", "turntable", "scene")
"""Rig names accepted by ``--rig``."""


def sphere_positions(n: int, radius: float, seed: int, upper_only: bool = False) -> np.ndarray:
    """``n`` camera centres uniformly distributed on a sphere (or its upper half), seeded."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    if upper_only:
        v[:, 2] = np.abs(v[:, 2])
    return v * radius


def spiral_positions(n: int, radius: float, turns: float | None = None) -> np.ndarray:
    """Archimedean spiral over the upper hemisphere, the SRN test-set layout.

    SRN's ``get_archimedean_spiral`` sweeps the polar angle from the equator to the pole while the
    azimuth advances by one radian per step of ``i`` (20 radians in all, about 3.2 turns). We keep
    that shape for any ``n``.
    """
    a = 40.0
    i = np.linspace(a / 2.0, a, n, endpoint=False)
    theta = i / a * math.pi  # from pi/2 (equator) to pi
    azimuth = -i if turns is None else -np.linspace(0.0, 2.0 * math.pi * turns, n, endpoint=False)
    elev_up = -np.cos(theta)  # 0 .. 1 (height fraction)
    ring = np.sin(theta)
    return np.stack([radius * ring * np.cos(azimuth), radius * ring * np.sin(azimuth), radius * elev_up], axis=1)


def turntable_positions(n: int, radius: float, elevation_deg: float = 20.0) -> np.ndarray:
    """``n`` cameras evenly spaced in azimuth at a fixed elevation."""
    el = math.radians(elevation_deg)
    az = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.stack([radius * math.cos(el) * np.cos(az), radius * math.cos(el) * np.sin(az),
                     np.full(n, radius * math.sin(el))], axis=1)


def rig_poses(rig: str, n: int, radius: float, seed: int = 0, elevation_deg: float = 20.0) -> list[np.ndarray]:
    """OpenCV camera-to-world poses of ``n`` cameras on ``rig``, all looking at the origin."""
    if n <= 0:
        raise InputError(f"number of views must be positive, got {n}")
    if not radius > 0:
        raise InputError(f"camera distance must be positive, got {radius}")
    if rig == "sphere":
        pos = sphere_positions(n, radius, seed)
    elif rig == "hemisphere":
        pos = sphere_positions(n, radius, seed, upper_only=True)
    elif rig == "spiral":
        pos = spiral_positions(n, radius)
    elif rig == "turntable":
        pos = turntable_positions(n, radius, elevation_deg)
    elif rig == "scene":
        raise InputError("the 'scene' rig uses the cameras in the Blender scene; it has no generated positions")
    else:
        raise InputError(f"unknown rig {rig!r}; choose one of {', '.join(RIGS)}")
    return [look_at_opencv(p) for p in pos]


def framing_distance(bound_radius: float, fov_min: float, margin: float = 1.05) -> float:
    """Camera distance at which a sphere of ``bound_radius`` just fills the narrower field of view."""
    if not 0 < fov_min < math.pi:
        raise InputError(f"field of view must be between 0 and 180 degrees, got {math.degrees(fov_min):g}")
    return margin * bound_radius / math.sin(fov_min / 2.0)


def near_far(c2w_list: list[np.ndarray], bound_radius: float, center=(0.0, 0.0, 0.0)) -> tuple[float, float]:
    """Near/far planes that enclose a bounding sphere from every camera (over all views)."""
    c = np.asarray(center, dtype=np.float64)
    d = np.array([np.linalg.norm(p[:3, 3] - c) for p in c2w_list])
    near = max(float(d.min() - bound_radius), 1e-3 * bound_radius)
    far = float(d.max() + bound_radius)
    return near, far


def orbit_poses(count: int, radius: float, elevation_deg: float = 20.0, center=(0.0, 0.0, 0.0),
                start_azimuth_deg: float = 0.0) -> list[np.ndarray]:
    """OpenCV camera-to-world poses of ``count`` cameras evenly spaced on a circle around ``center``.

    The circle lies at ``elevation_deg`` above the horizontal plane through ``center`` (world z up),
    at distance ``radius``; the first camera sits at azimuth ``start_azimuth_deg`` (0 = +x), the
    others follow counter-clockwise seen from above; every camera looks at ``center``.
    """
    if count <= 0:
        raise InputError(f"orbit needs at least one camera, got {count}")
    if not (math.isfinite(radius) and radius > 0):
        raise InputError(f"orbit radius must be positive, got {radius}")
    if not -90.0 <= elevation_deg <= 90.0:
        raise InputError(f"orbit elevation must be within -90..90 degrees, got {elevation_deg:g}")
    c = np.asarray(center, dtype=np.float64).reshape(3)
    el = math.radians(elevation_deg)
    az = math.radians(start_azimuth_deg) + np.linspace(0.0, 2.0 * math.pi, count, endpoint=False)
    pos = np.stack([radius * math.cos(el) * np.cos(az), radius * math.cos(el) * np.sin(az),
                    np.full(count, radius * math.sin(el))], axis=1) + c
    return [look_at_opencv(p, c) for p in pos]
