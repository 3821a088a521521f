"""2D/3D curve helpers for the generators (numpy only)."""

from __future__ import annotations

import numpy as np


def rounded_rect(w: float, h: float, r: float, n: int = 4, cx: float = 0.0, cy: float = 0.0) -> np.ndarray:
    """Counter-clockwise rounded rectangle (w x h, corner radius r, n segments per corner)."""
    r = min(r, 0.49 * w, 0.49 * h)
    pts = []
    corners = [(w / 2 - r, h / 2 - r, 0.0), (-w / 2 + r, h / 2 - r, 0.5 * np.pi),
               (-w / 2 + r, -h / 2 + r, np.pi), (w / 2 - r, -h / 2 + r, 1.5 * np.pi)]
    for x, y, a0 in corners:
        for t in np.linspace(a0, a0 + 0.5 * np.pi, n + 1):
            pts.append((cx + x + r * np.cos(t), cy + y + r * np.sin(t)))
    return np.array(pts)


def ellipse(rx: float, ry: float, n: int = 24, cx: float = 0.0, cy: float = 0.0) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([cx + rx * np.cos(t), cy + ry * np.sin(t)], 1)


def superellipse(rx: float, rz: float, exponent: float, n: int = 24) -> np.ndarray:
    """Counter-clockwise superellipse points (x, z) (exponent 2 = ellipse, large = rectangle)."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False) + np.pi / n
    c, s = np.cos(t), np.sin(t)
    e = 2.0 / exponent
    return np.stack([rx * np.sign(c) * np.abs(c) ** e, rz * np.sign(s) * np.abs(s) ** e], 1)


def fillet(points, radius: float, n: int = 4) -> np.ndarray:
    """A polyline (3D) with its interior corners rounded by circular-ish arcs of ``radius``."""
    p = np.asarray(points, float)
    out = [p[0]]
    for i in range(1, len(p) - 1):
        a, b, c = p[i - 1], p[i], p[i + 1]
        da, dc = a - b, c - b
        la, lc = np.linalg.norm(da), np.linalg.norm(dc)
        r = min(radius, 0.45 * la, 0.45 * lc)
        s0, s1 = b + da / la * r, b + dc / lc * r
        for t in np.linspace(0, 1, n + 1):
            # quadratic Bezier through the corner
            out.append((1 - t) ** 2 * s0 + 2 * (1 - t) * t * b + t ** 2 * s1)
    out.append(p[-1])
    return np.array(out)


def ring_xz(pts2d, y: float, x0: float = 0.0, z0: float = 0.0) -> np.ndarray:
    """2D (x, z) points placed in the plane at ``y`` (a cross-section for lofts along y)."""
    pts2d = np.asarray(pts2d, float)
    return np.stack([x0 + pts2d[:, 0], np.full(len(pts2d), y), z0 + pts2d[:, 1]], 1)


def ring_xy(pts2d, z: float) -> np.ndarray:
    pts2d = np.asarray(pts2d, float)
    return np.stack([pts2d[:, 0], pts2d[:, 1], np.full(len(pts2d), z)], 1)


def circle_xy(r: float, z: float, n: int = 24, cx: float = 0.0, cy: float = 0.0) -> np.ndarray:
    return ring_xy(ellipse(r, r, n, cx, cy), z)
