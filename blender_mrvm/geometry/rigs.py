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


def parse_range(text: str, name: str, lo: float, hi: float, inclusive_lo: bool = False) -> tuple[float, float]:
    """``"a,b"`` (or a single number) -> (a, b) with ``lo < a <= b <= hi`` (``lo <= a`` when inclusive);
    InputError naming ``name`` otherwise."""
    try:
        vals = [float(v) for v in str(text).split(",")]
    except ValueError:
        raise InputError(f"{name} must be 'min,max' (two numbers), got {text!r}") from None
    if len(vals) == 1:
        vals = vals * 2
    if len(vals) != 2 or not all(math.isfinite(v) for v in vals):
        raise InputError(f"{name} must be 'min,max' (two finite numbers), got {text!r}")
    a, b = vals
    if a > b:
        raise InputError(f"{name} min {a:g} exceeds its max {b:g}")
    if (a < lo if inclusive_lo else a <= lo) or b > hi:
        raise InputError(f"{name} must lie within {'[' if inclusive_lo else '('}{lo:g}, {hi:g}], got {text!r}")
    return a, b


VARIED_RIGS = ("sphere", "hemisphere")
"""Rigs that :func:`varied_cameras` draws (per-view distance and field of view)."""
FOV_RANGE_DEG = (30.0, 60.0)
"""Default horizontal field of view range of :func:`varied_cameras`, degrees (phone main cameras: ~65)."""
DISTANCE_RANGE = (0.85, 1.6)
"""Default distance range of :func:`varied_cameras`, as multiples of the distance at which the object's
bounding sphere just fills that view's narrower field of view (below 1 crops a little of the sphere,
rarely of the object, which is smaller than its sphere)."""


def check_elevation_range(rig: str, elevation_range_deg: tuple[float, float]) -> None:
    """InputError unless ``elevation_range_deg`` is a band within [-90, 90] degrees that ``rig`` can have (the
    hemisphere none below the horizon). The one owner of the rule (render configs check through it)."""
    e0, e1 = elevation_range_deg
    if not -90.0 <= e0 <= e1 <= 90.0:
        raise InputError(f"elevation range must lie within [-90, 90] degrees, got {e0:g},{e1:g}")
    if rig == "hemisphere" and e0 < 0.0:
        raise InputError(f"the hemisphere rig has no cameras below the horizon; elevation range {e0:g},{e1:g}")


def varied_cameras(rig: str, n: int, bound_radius: float, width: int, height: int,
                   fov_range_deg: tuple[float, float] = FOV_RANGE_DEG,
                   distance_range: tuple[float, float] = DISTANCE_RANGE,
                   seed: int = 0, elevation_range_deg: tuple[float, float] | None = None,
                   ) -> tuple[list[np.ndarray], list, list[dict]]:
    """``n`` cameras on ``rig`` (sphere or hemisphere) with a field of view and a distance drawn per view.

    Directions are uniform on the sphere (or the upper half), seeded; each view's horizontal field of
    view is uniform in ``fov_range_deg``; its distance from the origin is the framing distance of the
    bounding sphere at that view's narrower field of view (:func:`framing_distance`) times a factor
    uniform in ``distance_range``. ``elevation_range_deg`` keeps the directions to a band of elevations
    (uniform over the band's solid angle: azimuth uniform, sine of the elevation uniform), for cameras near a
    turntable's height; None = the whole sphere (or upper half). Every camera looks at the origin (world z up).
    Returns (OpenCV
    camera-to-world poses, :class:`Intrinsics` per view, one record per view: fov_x_deg, distance,
    distance_factor), all exactly what the views are rendered with.
    """
    from .cameras import intrinsics_from_fov

    if rig not in VARIED_RIGS:
        raise InputError(f"varied cameras need the sphere or hemisphere rig, got {rig!r}")
    if n <= 0:
        raise InputError(f"number of views must be positive, got {n}")
    if not bound_radius > 0:
        raise InputError(f"object radius must be positive, got {bound_radius}")
    f0, f1 = fov_range_deg
    d0, d1 = distance_range
    if not 0.0 < f0 <= f1 < 180.0:
        raise InputError(f"field of view range must lie within (0, 180) degrees, got {f0:g}..{f1:g}")
    if not 0.0 < d0 <= d1:
        raise InputError(f"distance range must be positive multiples, got {d0:g}..{d1:g}")
    if elevation_range_deg is not None:
        check_elevation_range(rig, elevation_range_deg)
    rng = np.random.default_rng([int(seed), 7])
    if elevation_range_deg is None:
        dirs = rng.normal(size=(n, 3))
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        if rig == "hemisphere":
            dirs[:, 2] = np.abs(dirs[:, 2])
    else:
        az = rng.uniform(0.0, 2.0 * math.pi, n)
        z = rng.uniform(*np.sin(np.radians(np.asarray(elevation_range_deg, np.float64))), n)
        ring = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
        dirs = np.stack([ring * np.cos(az), ring * np.sin(az), z], axis=1)
    fovs = rng.uniform(f0, f1, n)
    factors = rng.uniform(d0, d1, n)
    poses, intrs, records = [], [], []
    for d, fov, k in zip(dirs, fovs, factors):
        intr = intrinsics_from_fov(math.radians(float(fov)), width, height)
        dist = framing_distance(bound_radius, min(intr.fov_x, intr.fov_y), margin=1.0) * float(k)
        poses.append(look_at_opencv(d * dist))
        intrs.append(intr)
        records.append({"fov_x_deg": float(fov), "distance": float(dist), "distance_factor": float(k)})
    return poses, intrs, records


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
