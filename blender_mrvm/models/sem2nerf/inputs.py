"""Sem2NeRF input builders (paper supplement): one-hot mask, contour map, contour distance field.

Given a part-id mask (H, W) of uint8 ids (0 = background) and the table of known label ids:

- :func:`one_hot`: (C, H, W) float32, one channel per known label (background included).
- :func:`contour_map`: (H, W) float32 in {0, 1}: the *external* contours of every non-background
  label region (holes of a region are not outlined), drawn ``3 px`` thick at 512 px, the thickness
  scaled with the resolution (:func:`contour_thickness`). Sem2NeRF draws them with OpenCV's
  ``findContours(RETR_EXTERNAL)`` + ``drawContours(thickness=3)``; here the contour pixels are the
  border pixels of each hole-filled region (a 4-neighbour outside it, or the image edge), dilated
  by a square of side ``thickness`` (centred like OpenCV's thick lines).
- :func:`distance_field`: (H, W) float32 in [0, 1]: the unsigned Euclidean distance of every pixel
  to the nearest contour pixel, divided by its maximum (0 on the contour; all ones when there is no
  contour, i.e. an empty mask). Exact up to 128 px; larger maps go through a 128 px grid, within
  ``(2 f - 1) / sqrt(2)`` px of exact for a reduction ``f`` (<= 4.95 px at 512 px, see the function).

Everything is numpy (+ scipy for the distance transform), bpy-free and torch-free.
:func:`build_inputs` stacks the three into the encoder's (C + 2, H, W) input. :func:`bench` times
each builder at 512 px and writes a CSV.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from ...errors import InputError

REFERENCE_SIZE = 512
"""Resolution at which the supplement's 3 px contour thickness is given."""
REFERENCE_THICKNESS = 3
"""Contour thickness (px) at :data:`REFERENCE_SIZE`."""


def contour_thickness(height: int, width: int) -> int:
    """Contour thickness in pixels for an image of this size (3 px at 512 px, at least 1)."""
    return max(1, int(round(REFERENCE_THICKNESS * max(height, width) / REFERENCE_SIZE)))


def label_lookup(labels: Sequence[int]) -> np.ndarray:
    """(256,) int64 table: part id -> channel index, -1 for ids not in ``labels``."""
    lut = np.full(256, -1, np.int64)
    for i, lab in enumerate(labels):
        if not 0 <= int(lab) <= 255:
            raise InputError(f"label id {lab} is outside 0..255 (masks are uint8)")
        lut[int(lab)] = i
    return lut


def to_index(mask: np.ndarray, labels: Sequence[int], where: str = "mask") -> np.ndarray:
    """(H, W) part ids -> (H, W) int64 channel indices; InputError naming ids not in ``labels``."""
    m = check_mask(mask, labels, where)
    return label_lookup(labels)[m]


def check_mask(mask: np.ndarray, labels: Sequence[int], where: str = "mask") -> np.ndarray:
    """The mask as (H, W) uint8 part ids; InputError if it is not one or holds ids not in ``labels``."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise InputError(f"{where}: expected a single-channel part-id mask, got shape {m.shape}")
    if m.dtype != np.uint8:
        if m.size and (m.min() < 0 or m.max() > 255 or not np.all(np.equal(np.mod(m, 1), 0))):
            raise InputError(f"{where}: part ids must be integers in 0..255")
        m = m.astype(np.uint8)
    present = np.flatnonzero(np.bincount(m.ravel(), minlength=256))
    bad = sorted(set(int(v) for v in present) - set(int(v) for v in labels))
    if bad:
        raise InputError(f"{where}: label id(s) {bad} are not known (known: {sorted(int(v) for v in labels)})")
    return m


def one_hot(mask: np.ndarray, labels: Sequence[int]) -> np.ndarray:
    """(H, W) part ids -> (C, H, W) float32 one-hot over ``labels`` (C = len(labels))."""
    m = check_mask(mask, labels)
    lab = np.asarray(labels, np.uint8)
    return (m[None] == lab[:, None, None]).view(np.uint8).astype(np.float32)


def _fill_holes(region: np.ndarray) -> np.ndarray:
    """``region`` (bool, cropped with a 1-px free border) with its holes filled: the complement's
    components that do not reach the border become part of the region."""
    from scipy import ndimage

    # A hole pixel has region pixels on its left, right, above and below; without such pixels there
    # is no hole and the (costlier) labelling is skipped.
    out = ~region
    enclosed = out & np.logical_or.accumulate(region, 1) & np.logical_or.accumulate(region[:, ::-1], 1)[:, ::-1]
    if not enclosed.any():
        return region
    enclosed &= np.logical_or.accumulate(region, 0) & np.logical_or.accumulate(region[::-1], 0)[::-1]
    if not enclosed.any():
        return region
    comp, n = ndimage.label(out)
    if n <= 1:  # the free border ring joins all outside pixels: one component = no holes
        return region
    outside = np.zeros(n + 1, bool)
    edge = np.concatenate([comp[0], comp[-1], comp[:, 0], comp[:, -1]])
    outside[edge] = True
    outside[0] = True  # label 0 = the region itself
    return region | ~outside[comp]


def _borders(region: np.ndarray) -> np.ndarray:
    """Pixels of ``region`` with a 4-neighbour outside it (the array edge counts as outside)."""
    inner = region.copy()
    inner[1:] &= region[:-1]
    inner[:-1] &= region[1:]
    inner[:, 1:] &= region[:, :-1]
    inner[:, :-1] &= region[:, 1:]
    inner[0] = inner[-1] = False
    inner[:, 0] = inner[:, -1] = False
    return region & ~inner


def _dilate_square(x: np.ndarray, size: int) -> np.ndarray:
    """Binary dilation by a size x size square (centred; even sizes extend one more px up/left)."""
    if size <= 1:
        return x
    lo, hi = size // 2, (size - 1) // 2

    def along(a: np.ndarray, axis: int) -> np.ndarray:
        out = a.copy()
        n = a.shape[axis]
        for s in range(1, max(lo, hi) + 1):
            src = [slice(None)] * 2
            dst = [slice(None)] * 2
            if s <= hi:  # from the pixel s before -> pixels shifted forward
                src[axis], dst[axis] = slice(0, n - s), slice(s, n)
                out[tuple(dst)] |= a[tuple(src)]
            if s <= lo:
                src[axis], dst[axis] = slice(s, n), slice(0, n - s)
                out[tuple(dst)] |= a[tuple(src)]
        return out

    return along(along(x, 0), 1)


def contour_map(mask: np.ndarray, thickness: int | None = None) -> np.ndarray:
    """(H, W) part ids -> (H, W) float32 contour map in {0, 1} (external contours of each non-zero label)."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise InputError(f"expected a single-channel part-id mask, got shape {m.shape}")
    if m.dtype != np.uint8:
        m = m.astype(np.uint8)
    h, w = m.shape
    t = contour_thickness(h, w) if thickness is None else int(thickness)
    thin = np.zeros((h, w), bool)
    present = np.flatnonzero(np.bincount(m.ravel(), minlength=256))
    # Per label, on its bounding box with a 1-px free ring (so the image edge counts as outside and
    # the cost follows the region's size): border pixels of the hole-filled region.
    for lab in present[present > 0]:
        eq = m == lab
        rows, cols = np.flatnonzero(eq.any(1)), np.flatnonzero(eq.any(0))
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        crop = np.zeros((y1 - y0 + 2, x1 - x0 + 2), bool)
        crop[1:-1, 1:-1] = eq[y0:y1, x0:x1]
        thin[y0:y1, x0:x1] |= _borders(_fill_holes(crop))[1:-1, 1:-1]
    return _dilate_square(thin, t).astype(np.float32)


EXACT_MAX_SIDE = 128
"""Contour maps up to this side get the exact EDT; larger ones are reduced to at most this side
first (see :func:`distance_field`)."""


def distance_field(contour: np.ndarray, exact_max_side: int = EXACT_MAX_SIDE) -> np.ndarray:
    """(H, W) contour map -> (H, W) float32 unsigned Euclidean distance to the contour, scaled to [0, 1].

    Exact (scipy's EDT) when ``max(H, W) <= exact_max_side`` (the training and encoder sizes, e.g. 64
    and 128 px). Larger maps are reduced by ``f = ceil(max(H, W) / exact_max_side)`` (a f x f block is
    contour when any of its pixels is), the exact EDT of that grid (times ``f``) is interpolated
    bilinearly back to every pixel, and pixels off the contour are clamped to at least 1 px (their
    true distance). Before the normalisation the result then differs from the exact distance by at
    most ``(2 f - 1) / sqrt(2)`` px: each contour pixel is within ``(f - 1) / sqrt(2)`` of its block's
    centre, and bilinear interpolation of a 1-Lipschitz function between centres ``f`` apart adds at
    most ``f / sqrt(2)``. At 512 px (f = 4) that is <= 4.95 px (4.3 px measured on the benchmark and
    random masks, against a largest distance of about 170 px); OpenCV's ``distanceTransform(DIST_L2,
    3)`` that Sem2NeRF uses is a 3x3 chamfer whose relative error of up to ~4.5% is larger. It stays
    exactly 0 on the contour and positive elsewhere; all ones when there is no contour (empty mask).
    """
    from scipy import ndimage

    c = np.asarray(contour) > 0.5
    if not c.any():
        return np.ones(c.shape, np.float32)
    h, w = c.shape
    f = max(1, -(-max(h, w) // max(1, int(exact_max_side))))
    if f == 1:
        dist = ndimage.distance_transform_edt(~c).astype(np.float32)
    else:
        dist = _coarse_distance(c, f)
    mx = float(dist.max())
    return dist / mx if mx > 0 else dist


def _coarse_distance(c: np.ndarray, f: int) -> np.ndarray:
    """Approximate distance to the True pixels of ``c`` (bool (H, W)) through the exact EDT of its
    f x f block maxima, interpolated bilinearly (block centres at pixel ``f * I + (f - 1) / 2``)."""
    from scipy import ndimage

    h, w = c.shape
    H, W = -(-h // f), -(-w // f)
    if (H * f, W * f) != (h, w):
        pad = np.zeros((H * f, W * f), bool)
        pad[:h, :w] = c
    else:
        pad = c
    rows = pad[0::f].copy()  # OR of each block's rows, then of its columns (contiguous-row ops)
    for r in range(1, f):
        rows |= pad[r::f]
    coarse = rows[:, 0::f].copy()
    for r in range(1, f):
        coarse |= rows[:, r::f]
    d = ndimage.distance_transform_edt(~coarse).astype(np.float32) * np.float32(f)
    dp = np.pad(d, 1, mode="edge")  # extrapolation at the image edge repeats the outermost centre
    # Fine pixel f*I + r lies o = (r + 0.5) / f - 0.5 coarse pixels from centre I: columns on the small
    # array first (strided writes), then rows (each a contiguous run).
    cols = np.empty((H + 2, W * f), np.float32)
    out = np.empty((H * f, W * f), np.float32)
    for r in range(f):
        o = (r + 0.5) / f - 0.5
        lo = int(np.floor(o))
        a = np.float32(o - lo)
        left, right = dp[:, 1 + lo:1 + lo + W], dp[:, 2 + lo:2 + lo + W]
        cols[:, r::f] = left + a * (right - left)
    for r in range(f):
        o = (r + 0.5) / f - 0.5
        lo = int(np.floor(o))
        a = np.float32(o - lo)
        top, bottom = cols[1 + lo:1 + lo + H], cols[2 + lo:2 + lo + H]
        np.subtract(bottom, top, out=out[r::f])
        out[r::f] *= a
        out[r::f] += top
    out = out[:h, :w]
    np.maximum(out, 1.0, out=out)  # a pixel off the contour is at least 1 px from it
    np.putmask(out, c, 0.0)
    return out


def build_inputs(mask: np.ndarray, labels: Sequence[int]) -> np.ndarray:
    """(H, W) part ids -> (C + 2, H, W) float32: one-hot over ``labels``, contour map, distance field."""
    oh = one_hot(mask, labels)
    c = contour_map(mask)
    return np.concatenate([oh, c[None], distance_field(c)[None]], 0)


# ----------------------------------------------------------------------------------------- reference

def contour_map_reference(mask: np.ndarray, thickness: int | None = None) -> np.ndarray:
    """Plain per-label reference of :func:`contour_map` (full-image hole filling), for tests."""
    from scipy import ndimage

    m = np.asarray(mask)
    h, w = m.shape
    t = contour_thickness(h, w) if thickness is None else int(thickness)
    thin = np.zeros((h, w), bool)
    for lab in np.unique(m):
        if lab == 0:
            continue
        region = np.pad(m == lab, 1)
        filled = ndimage.binary_fill_holes(region)
        inner = ndimage.binary_erosion(filled, structure=ndimage.generate_binary_structure(2, 1), border_value=0)
        thin |= (filled & ~inner)[1:-1, 1:-1]
    return _dilate_square(thin, t).astype(np.float32)


# ----------------------------------------------------------------------------------------- benchmark

def synthetic_mask(size: int = 512, seed: int = 0) -> np.ndarray:
    """A chair-like part mask (seat, back with a hole, legs, a handle) of ``size`` px for benchmarks."""
    rng = np.random.default_rng(seed)
    m = np.zeros((size, size), np.uint8)
    s = size / 512
    yy, xx = np.mgrid[:size, :size]

    def box(y0, y1, x0, x1, v):
        m[int(y0 * s):int(y1 * s), int(x0 * s):int(x1 * s)] = v

    box(80, 260, 150, 360, 2)     # back
    box(130, 210, 200, 310, 0)    # a hole in the back
    box(260, 310, 130, 380, 1)    # seat
    for x in (140, 350):          # legs
        box(310, 470, x, x + 22, 3)
    r = (yy - 285 * s) ** 2 + (xx - 255 * s) ** 2 < (18 * s) ** 2
    m[r] = 4                      # a knob on the seat
    noise = rng.random((size, size)) < 0.0  # deterministic shape; seed kept for variants
    m[noise] = 0
    return m


BENCH_RESULTS = ("bench_sem2nerf_inputs.csv",)
"""What :func:`bench` writes into its folder (``bench.check_results``)."""


def bench(out_dir: Path, size: int = 512, repeats: int = 50, n_labels: int = 6) -> dict[str, float]:
    """Time each builder on a ``size`` px mask and write ``bench_sem2nerf_inputs.csv`` (wall-clock median,
    min, 90th percentile and the median process CPU time, which a loaded machine disturbs less);
    returns the wall-clock medians.

    ``python -m blender_mrvm sem2nerf bench --out docs --repeats 400`` wrote ``docs/bench_sem2nerf_inputs.csv``
    (512 px; 2 CPU cores shared with other jobs, load average 8 to 10, so wall-clock medians are 2-3x
    the CPU times; min / median CPU time): the distance field 1.6 / 2.8 ms (``distance_field``; the
    exact scipy EDT it replaced at this size, ``distance_field_exact``, 12.5 / 18.3 ms), contour +
    distance 4.8 / 7.0 ms, the whole input build 8.2 / 12.4 ms. Rows: one_hot, contour_map, distance_field,
    contour_and_distance, build_inputs, contour_map_reference, distance_field_exact."""
    import time

    mask = synthetic_mask(size)
    labels = list(range(n_labels))
    contour = contour_map(mask)
    jobs = {
        "one_hot": lambda: one_hot(mask, labels),
        "contour_map": lambda: contour_map(mask),
        "distance_field": lambda: distance_field(contour),
        "contour_and_distance": lambda: distance_field(contour_map(mask)),
        "build_inputs": lambda: build_inputs(mask, labels),
        "contour_map_reference": lambda: contour_map_reference(mask),
        "distance_field_exact": lambda: distance_field(contour, exact_max_side=1 << 30),
    }
    times: dict[str, list[float]] = {name: [] for name in jobs}
    cpus: dict[str, list[float]] = {name: [] for name in jobs}
    for fn in jobs.values():
        fn()  # warm-up
    for _ in range(repeats):  # round robin: a load that comes and goes disturbs every builder alike
        for name, fn in jobs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            times[name].append(time.perf_counter() - t0)
            cpus[name].append(time.process_time() - c0)
    out: dict[str, float] = {}
    rows = []
    for name in jobs:
        ts, cs = np.asarray(times[name]) * 1e3, np.asarray(cpus[name]) * 1e3
        out[name] = float(np.median(ts))
        rows.append({"builder": name, "size": size, "repeats": repeats, "median_ms": f"{np.median(ts):.3f}",
                     "min_ms": f"{ts.min():.3f}", "p90_ms": f"{np.percentile(ts, 90):.3f}",
                     "cpu_median_ms": f"{np.median(cs):.3f}"})
    from ...bench import write_csv

    write_csv(Path(out_dir) / BENCH_RESULTS[0], rows, quiet=True)  # (with the provenance columns every bench CSV has)
    return out
