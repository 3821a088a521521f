"""Display, lamp, loudspeaker, telephone. Screens and speaker fronts face -y, z up."""

from __future__ import annotations

import math

import numpy as np

from ._registry import category, choice, flag, integer, real
from ._shapes import circle_xy, fillet, rounded_rect


def _pick(rng, options):
    return options[int(rng.integers(len(options)))]


# --------------------------------------------------------------------------------------------
# display
# --------------------------------------------------------------------------------------------

@category("display", (
    choice("style", "monitor", "tv", "crt", "imac", "laptop_panel", weights=(0.35, 0.25, 0.15, 0.15, 0.1)),
    choice("aspect", "16:9", "16:10", "4:3", "21:9", weights=(0.45, 0.2, 0.2, 0.15)),
    real("size", 0.45, 1.2, min=0.05, max=5.0),
    choice("stand", "neck", "feet", "none", weights=(0.55, 0.3, 0.15)),
    real("bezel", 0.008, 0.04, min=0.0, max=0.2),
    flag("curved", 0.12),
))
def display(p, rng, m):
    a, b = (int(x) for x in p.aspect.split(":"))
    if p.style == "crt":
        a, b = 4, 3
    W = p.size
    H = W * b / a
    bz = p.bezel * (2.5 if p.style in ("crt", "imac") else 1.0)
    depth = {"monitor": 0.025, "tv": 0.04, "crt": 0.06, "imac": 0.02, "laptop_panel": 0.008}[p.style] * W / 0.6
    fw, fh = W + 2 * bz, H + 2 * bz
    chin = bz * 3 if p.style == "imac" else 0.0
    stand_h = rng.uniform(0.08, 0.2) * W if p.stand != "none" else 0.0
    z0 = stand_h
    zc = z0 + (fh + chin) / 2
    start = m.n_faces
    m.box("frame", (fw, depth, fh + chin), (0, 0, zc), bevel=min(depth * 0.4, bz + 0.004), segments=3)
    m.box("screen", (W, depth * 0.1 + 0.002, H), (0, -depth / 2 - 0.0005, z0 + chin + bz + H / 2), bevel=0.001)
    if p.curved and p.style in ("monitor", "tv"):
        verts = np.concatenate(m._verts, 0)
        used = sorted({i for f in m._faces[start:] for i in f})
        x = verts[used, 0]
        verts[used, 1] += (x / (fw / 2)) ** 2 * W * 0.06
        m._verts = [verts]
    if p.style == "crt":
        back = depth * rng.uniform(5, 9)
        rings = [np.array([[x, depth / 2, z] for x, z in rounded_rect(fw * s, (fh) * s, 0.03, 3, 0, zc)])
                 for s in (0.98, 0.9)]
        rings[1][:, 1] = depth / 2 + back * 0.5
        r3 = np.array([[x, depth / 2 + back, z] for x, z in rounded_rect(fw * 0.5, fh * 0.5, 0.03, 3, 0, zc)])
        m.loft("frame", rings + [r3])
    elif p.style in ("monitor", "imac", "tv") and rng.uniform() < 0.6:
        m.box("frame", (fw * 0.6, depth * 1.5, fh * 0.55), (0, depth, zc), bevel=depth * 0.5, segments=3)
    if p.stand == "neck" or (p.style == "crt" and p.stand != "none"):
        nw = rng.uniform(0.05, 0.12) * W
        neck_top = z0 + (fh + chin) * rng.uniform(0.3, 0.5)
        # against the frame's back (it stood 0.25 neck widths behind it), leaning about its top so its foot comes
        # forward onto the base and down to the floor (tilted about its middle, its top left the frame)
        ny = depth / 2 + (depth * 3 if p.style == "crt" else nw * 0.15)
        tilt = rng.uniform(0.0, 0.25)
        length = neck_top / math.cos(tilt)
        foot_y = ny - length * math.sin(tilt)
        m.box("stand", (nw, nw * 0.3, length), (0, (ny + foot_y) / 2, neck_top / 2), bevel=nw * 0.1, rot=(-tilt, 0, 0))
        ny = foot_y  # the base goes under the foot
        bs = _pick(rng, ("rect", "round", "v"))
        if bs == "round":
            m.cylinder("base", W * rng.uniform(0.15, 0.22), 0.015, (0, ny - 0.02, 0.0075), segments=32, bevel=0.005)
        elif bs == "rect":
            m.box("base", (W * rng.uniform(0.3, 0.45), W * rng.uniform(0.18, 0.28), 0.015), (0, ny - 0.03, 0.0075),
                  bevel=0.005)
        else:
            for sx in (-1, 1):
                m.box("base", (0.025, W * 0.3, 0.015), (sx * W * 0.08, ny - W * 0.08, 0.0075), rot=(0, 0, sx * 0.6),
                      bevel=0.005)
    elif p.stand == "feet":
        for sx in (-1, 1):
            fx = sx * fw * rng.uniform(0.3, 0.42)
            m.box("stand", (0.02, 0.02, stand_h + 0.02), (fx, 0.0, (stand_h + 0.02) / 2), bevel=0.004)
            m.box("base", (0.04, W * 0.2, 0.012), (fx, 0.0, 0.006), bevel=0.004)
    frame_kind = _pick(rng, ("dark_plastic", "dark_plastic", "metal", "white_paint", "plastic"))
    return {"screen": "screen", "frame": frame_kind, "stand": _pick(rng, (frame_kind, "metal")),
            "base": _pick(rng, (frame_kind, "metal"))}


# --------------------------------------------------------------------------------------------
# lamp
# --------------------------------------------------------------------------------------------

@category("lamp", (
    choice("style", "table", "floor", "desk_arm", "pendant", "globe", weights=(0.3, 0.2, 0.2, 0.15, 0.15)),
    choice("shade", "cone", "drum", "dome", "bell"),
    real("height", 0.35, 1.7, min=0.05, max=4.0),
    real("shade_size", 0.12, 0.25, min=0.01, max=1.0),
    integer("heads", 1, 1, min=1, max=6),
    flag("bulb_visible", 0.4),
))
def lamp(p, rng, m):
    style = p.style
    H = p.height
    if style == "table":
        H = min(H, 0.7)
    elif style == "floor":
        H = max(H, 1.2)
    elif style == "desk_arm":
        H = min(max(H, 0.4), 0.8)
    r = p.shade_size * (1.6 if style == "floor" else 1.0)
    base_r = rng.uniform(0.07, 0.14) * (1.4 if style == "floor" else 1.0)
    if style == "pendant":
        # canopy at the top, cord down, shade at the bottom
        m.cylinder("base", 0.06, 0.03, (0, 0, H - 0.015), segments=20, bevel=0.006)
        drop = H * rng.uniform(0.6, 0.85)
        n = p.heads
        for k in range(n):
            a = 2 * math.pi * k / n
            off = 0.0 if n == 1 else r * 1.3
            cx, cy = off * math.cos(a), off * math.sin(a)
            m.cylinder_between("stem", (0, 0, H - 0.03), (cx, cy, H - drop * (1 - 0.1 * (k % 2))), 0.004, segments=6)
            _shade(m, rng, p.shade, (cx, cy, H - drop * (1 - 0.1 * (k % 2))), r, down=True, bulb=p.bulb_visible)
        return _lamp_kinds(rng)
    # base
    bshape = _pick(rng, ("disc", "square", "vase"))
    if style == "table" and bshape == "vase":
        prof = [0.25, 0.7, 1.0, 0.95, 0.6, 0.3, 0.2]
        vh = H * rng.uniform(0.35, 0.5)
        rings = [circle_xy(base_r * f, vh * i / (len(prof) - 1), 24) for i, f in enumerate(prof)]
        m.loft("base", rings)
        z = vh
    elif bshape == "square":
        m.box("base", (2 * base_r, 2 * base_r, 0.03), (0, 0, 0.015), bevel=0.008)
        z = 0.03
    else:
        m.cylinder("base", base_r, 0.025, (0, 0, 0.0125), radius2=base_r * 0.9, segments=32, bevel=0.008)
        z = 0.025
    if style == "desk_arm":
        seg1 = H * rng.uniform(0.45, 0.6)
        a1 = math.radians(rng.uniform(-25, 15))
        j1 = np.array([0, seg1 * math.sin(a1), z + seg1 * math.cos(a1)])
        seg2 = H * rng.uniform(0.45, 0.65)
        a2 = math.radians(rng.uniform(40, 100))
        j2 = j1 + np.array([0, -seg2 * math.sin(a2), seg2 * math.cos(a2)])
        m.sphere("joint", 0.018, (0, 0, z), segments=10, rings=6)
        m.cylinder_between("stem", (0, 0, z), j1, 0.009, segments=8)
        m.sphere("joint", 0.018, j1, segments=10, rings=6)
        m.cylinder_between("stem", j1, j2, 0.008, segments=8)
        m.sphere("joint", 0.015, j2, segments=10, rings=6)
        rr = r * 0.7
        m.cylinder("shade", rr, rr * 1.4, j2 + np.array([0, -rr * 0.5, -rr * 0.5]), axis=(0, -0.5, -1), radius2=rr * 0.35,
                   segments=20)
        if p.bulb_visible:
            m.sphere("bulb", rr * 0.4, j2 + np.array([0, -rr * 0.9, -rr * 1.2]), segments=10, rings=6)
        return _lamp_kinds(rng)
    top = H - r * 0.6
    if style == "globe":
        m.cylinder("stem", 0.012, top - z, (0, 0, (top + z) / 2), segments=10)
        m.sphere("shade", r * 1.1, (0, 0, top + r * 0.5), segments=20, rings=12)
        return _lamp_kinds(rng)
    curve = style == "floor" and rng.uniform() < 0.4
    if curve:  # arc floor lamp
        reach = H * rng.uniform(0.35, 0.55)
        path = np.array([(0, 0, z), (0, 0, H * 0.75), (0, -reach * 0.6, H), (0, -reach, H * 0.92)])
        m.tube("stem", fillet(path, H * 0.3, 6), 0.012, segments=10)
        _shade(m, rng, p.shade, (0, -reach, H * 0.92 - 0.02), r, down=True, bulb=p.bulb_visible)
        return _lamp_kinds(rng)
    m.cylinder("stem", 0.012 if style == "floor" else rng.uniform(0.01, 0.025), top - z, (0, 0, (top + z) / 2),
               segments=12)
    n = p.heads if style == "floor" else 1
    if n == 1:
        _shade(m, rng, p.shade, (0, 0, top), r, down=False, bulb=p.bulb_visible)
    else:
        for k in range(n):
            a = 2 * math.pi * k / n
            end = np.array([r * 1.6 * math.cos(a), r * 1.6 * math.sin(a), top + r * 0.3])
            m.cylinder_between("stem", (0, 0, top - r * 0.3), end, 0.008, segments=8)
            _shade(m, rng, p.shade, end, r * 0.6, down=False, bulb=p.bulb_visible)
    return _lamp_kinds(rng)


def _lamp_kinds(rng):
    metal = _pick(rng, ("metal", "dark_metal", "white_paint", "wood", "paint"))
    return {"base": metal, "stem": metal, "shade": _pick(rng, ("fabric", "paint", "white_paint", "metal", "glass")),
            "bulb": "light", "joint": metal}


def _shade(m, rng, kind, center, r, down: bool, bulb: bool) -> None:
    """A thin-walled open shade around ``center`` (its middle)."""
    cx, cy, cz = center
    h = r * rng.uniform(0.8, 1.2)
    n = 28
    if kind == "cone":
        radii = [(r, -h / 2), (r * 0.45, h / 2)]
    elif kind == "drum":
        radii = [(r, -h / 2), (r * 0.95, h / 2)]
    elif kind == "dome":
        radii = [(r * math.cos(t), -h / 2 + h * math.sin(t)) for t in np.linspace(0, 1.35, 6)]
    else:  # bell
        radii = [(r, -h / 2), (r * 0.85, -h / 4), (r * 0.55, h / 6), (r * 0.4, h / 2)]
    wall = 0.006
    outer = [circle_xy(rad, cz + z, n, cx, cy) for rad, z in radii]
    inner = [circle_xy(max(rad - wall, wall), cz + z, n, cx, cy) for rad, z in radii[::-1]]
    m.loft("shade", outer + inner, closed=True)
    if bulb:
        m.sphere("bulb", r * 0.25, (cx, cy, cz - h * 0.2), segments=12, rings=6)


# --------------------------------------------------------------------------------------------
# loudspeaker
# --------------------------------------------------------------------------------------------

@category("loudspeaker", (
    choice("style", "bookshelf", "tower", "cylinder", "subwoofer", "pa", weights=(0.3, 0.25, 0.15, 0.15, 0.15)),
    integer("drivers", 2, 3, min=0, max=6),
    real("width", 0.15, 0.35, min=0.02, max=2.0),
    flag("grille", 0.3),
    flag("port", 0.5),
    flag("feet", 0.4),
))
def loudspeaker(p, rng, m):
    W = p.width
    style = p.style
    if style == "tower":
        H, D = W * rng.uniform(3.5, 5.0), W * rng.uniform(1.1, 1.6)
    elif style == "bookshelf":
        H, D = W * rng.uniform(1.4, 1.9), W * rng.uniform(1.0, 1.4)
    elif style == "subwoofer":
        H = D = W * 1.0
        H *= rng.uniform(0.95, 1.1)
    elif style == "pa":
        H, D = W * rng.uniform(1.5, 1.9), W * rng.uniform(1.0, 1.3)
    else:
        H, D = W * rng.uniform(1.2, 2.5), W
    z0 = 0.02 if p.feet else 0.0
    if style == "cylinder":
        m.cylinder("cabinet", W / 2, H, (0, 0, z0 + H / 2), segments=32, bevel=W * 0.08)
        m.cylinder("grille", W / 2 + 0.002, H * 0.7, (0, 0, z0 + H * 0.42), segments=32)
        if rng.uniform() < 0.5:
            m.cylinder("driver", W * 0.3, 0.01, (0, 0, z0 + H + 0.003), segments=24)
        if p.feet:
            m.cylinder("foot", W * 0.4, z0, (0, 0, z0 / 2), segments=24)
        return {"cabinet": _pick(rng, ("dark_plastic", "white_paint", "paint")), "grille": "fabric",
                "driver": "dark_plastic", "foot": "rubber"}
    if style == "pa":  # trapezoid cabinet (wider at the front)
        prof = [(-W / 2, -D / 2), (W / 2, -D / 2), (W * 0.3, D / 2), (-W * 0.3, D / 2)]
        m.profile("cabinet", prof, H, plane="xy", offset=z0 + H / 2, bevel=0.01)
        m.box("cabinet", (W * 0.3, 0.03, 0.02), (0, 0, z0 + H + 0.015), bevel=0.008)  # handle
    else:
        m.box("cabinet", (W, D, H), (0, 0, z0 + H / 2), bevel=W * rng.uniform(0.02, 0.08), segments=3)
    yf = -D / 2
    nd = p.drivers if style != "subwoofer" else 1
    # drivers from the top: tweeter small, then woofers
    sizes = []
    for i in range(nd):
        sizes.append(W * (0.16 if (i == 0 and nd > 1) else rng.uniform(0.32, 0.42)))
    if style == "subwoofer":
        sizes = [W * 0.4]
    total = sum(2 * s for s in sizes) + 0.02 * max(nd - 1, 0)
    if total > 0.88 * H:  # shrink the drivers to fit the front panel
        f = (0.88 * H - 0.02 * max(nd - 1, 0)) / (total - 0.02 * max(nd - 1, 0))
        sizes = [s * f for s in sizes]
        total = 0.88 * H
    free = H - total
    z = z0 + H - max(free * 0.3, W * 0.05)
    if p.grille:
        m.box("grille", (W * 0.94, 0.012, H * 0.94), (0, yf - 0.006, z0 + H / 2), bevel=0.004)
        yf -= 0.012
    for s in sizes:
        zc = z - s
        _driver(m, (0, yf, zc), s)
        z = zc - s - 0.02
    if p.port and style != "cylinder":
        pr = W * 0.06
        pz = z0 + max(pr * 2, (z - z0) / 2)
        m.torus("port", pr, pr * 0.25, (0, yf - 0.002, pz), axis=(0, 1, 0), segments=16, sides=6)
        m.cylinder("port", pr, 0.01, (0, yf + 0.001, pz), axis=(0, 1, 0), segments=16)
    if p.feet:
        for sx in (-1, 1):
            for sy in (-1, 1):
                m.cylinder("foot", 0.012, z0, (sx * (W / 2 - 0.03), sy * (D / 2 - 0.03), z0 / 2), radius2=0.004,
                           segments=10)
    if style == "tower" and rng.uniform() < 0.5:
        m.box("foot", (W * 1.3, D * 1.1, 0.02), (0, 0, 0.01), bevel=0.006)
    return {"cabinet": _pick(rng, ("wood", "dark_plastic", "white_paint", "paint", "dark_plastic")),
            "driver": _pick(rng, ("dark_plastic", "metal", "paint")), "grille": "fabric", "port": "dark_plastic",
            "foot": _pick(rng, ("metal", "rubber"))}


def _driver(m, center, radius) -> None:
    """A speaker cone: a surround torus, a dished cone and a dust cap, facing -y."""
    cx, cy, cz = center
    m.torus("driver", radius * 0.88, radius * 0.1, (cx, cy - radius * 0.02, cz), axis=(0, 1, 0), segments=24, sides=6)
    rings = []
    for f, dy in ((0.86, 0.0), (0.55, radius * 0.12), (0.28, radius * 0.18)):
        ang = np.linspace(0, 2 * np.pi, 20, endpoint=False)
        rings.append(np.stack([cx + radius * f * np.cos(ang), np.full(20, cy + dy), cz + radius * f * np.sin(ang)], 1))
    m.loft("driver", rings)
    m.sphere("driver", radius * 0.22, (cx, cy + radius * 0.12, cz), scale=(1, 0.5, 1), segments=12, rings=6)


# --------------------------------------------------------------------------------------------
# telephone
# --------------------------------------------------------------------------------------------

@category("telephone", (
    choice("style", "smartphone", "feature", "flip", "desk", "cordless", weights=(0.35, 0.2, 0.15, 0.15, 0.15)),
    real("height", 0.12, 0.17, min=0.02, max=1.0),
    real("aspect", 0.42, 0.55, min=0.1, max=1.5),
    real("thickness", 0.007, 0.012, min=0.001, max=0.1),
    integer("cameras", 1, 3, min=0, max=6),
    flag("antenna", 0.2),
))
def telephone(p, rng, m):
    style = p.style
    H, Wd, T = p.height, p.height * p.aspect, p.thickness
    if style == "desk":
        return _desk_phone(m, rng, p)
    if style == "feature":
        T *= 1.8
    if style == "cordless":
        Wd *= 0.75
        T *= 2.2
    corner = Wd * rng.uniform(0.08, 0.2)
    if style == "flip":
        half = H / 2
        T *= 1.3
        # lower half upright, upper half hinged open towards the back
        m.profile("body", rounded_rect(Wd, half, corner, 4), T, plane="xz", offset=0.0, bevel=T * 0.3)
        _shift_last(m, (0, 0, half / 2))
        m.cylinder("body", T * 0.45, Wd * 0.9, (0, 0, half), axis=(1, 0, 0), segments=12)
        ang = math.radians(rng.uniform(10, 30))
        m.profile("body", rounded_rect(Wd, half, corner, 4), T * 0.8, plane="xz", offset=0.0, bevel=T * 0.25)
        _shift_last(m, (0, 0, half * 1.5))
        start = m.n_faces
        m.box("screen", (Wd * 0.8, 0.001, half * 0.65), (0, -T * 0.4 - 0.0005, half * 1.55))
        # rotate the last body block and its screen about the hinge
        n_last = len(m._verts)
        _rot_blocks(m, [n_last - 2, n_last - 1], -ang, (0, 0, half))
        del start
        _keypad(m, rng, Wd, half * 0.75, (0, -T / 2, half * 0.45), rows=4, cols=3)
    else:
        m.profile("body", rounded_rect(Wd, H, corner, 5), T, plane="xz", offset=0.0, bevel=T * 0.35, segments=3)
        _shift_last(m, (0, 0, H / 2))
        if style == "smartphone":
            m.box("screen", (Wd * 0.92, 0.0012, H * 0.9), (0, -T / 2 - 0.0005, H / 2), bevel=0.0004)
        else:
            sh = H * (0.35 if style == "feature" else 0.25)
            m.box("screen", (Wd * 0.75, 0.0012, sh), (0, -T / 2 - 0.0005, H - sh / 2 - H * 0.1), bevel=0.0004)
            _keypad(m, rng, Wd, H * 0.45, (0, -T / 2, H * 0.28), rows=4 if style == "feature" else 5, cols=3)
        # side buttons
        for k in range(int(rng.integers(1, 4))):
            m.box("button", (0.002, 0.004, H * 0.08), (Wd / 2 + 0.0005, 0, H * (0.7 - 0.1 * k)), bevel=0.0008)
        # cameras on the back
        for c in range(p.cameras):
            cam_r = Wd * rng.uniform(0.06, 0.1)
            m.cylinder("camera", cam_r, 0.0015, (-Wd / 2 + Wd * 0.22 + (c % 2) * cam_r * 2.4,
                                                 T / 2 + 0.0007, H * 0.88 - (c // 2) * cam_r * 2.4),
                       axis=(0, 1, 0), segments=16)
    if p.antenna or style == "cordless" and rng.uniform() < 0.5:
        m.cylinder("antenna", 0.003, H * 0.3, (Wd * 0.3, 0, H * (1.15 if style != "flip" else 1.0)), segments=8)
    body = _pick(rng, ("dark_plastic", "metal", "paint", "white_paint", "dark_metal"))
    return {"body": body, "screen": "screen", "button": _pick(rng, (body, "plastic", "dark_plastic")),
            "camera": "glass", "handset": body, "antenna": "dark_plastic"}


def _shift_last(m, offset) -> None:
    m._verts[-1] = m._verts[-1] + np.asarray(offset, float)


def _rot_blocks(m, blocks, angle, pivot) -> None:
    c, s = math.cos(angle), math.sin(angle)
    r = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    piv = np.asarray(pivot, float)
    for b in blocks:
        m._verts[b] = (m._verts[b] - piv) @ r.T + piv


def _keypad(m, rng, width, height, center, rows, cols) -> None:
    cx, cy, cz = center
    bw = width * 0.7 / cols
    bh = height * 0.8 / rows
    for r in range(rows):
        for c in range(cols):
            x = cx + (c - (cols - 1) / 2) * bw * 1.15
            z = cz + ((rows - 1) / 2 - r) * bh * 1.15
            m.box("button", (bw, 0.0015, bh * 0.8), (x, cy - 0.0007, z), bevel=min(bw, bh) * 0.2)


def _desk_phone(m, rng, p):
    W = rng.uniform(0.18, 0.24)
    D = W * rng.uniform(0.8, 1.1)
    hf, hb = 0.03, rng.uniform(0.06, 0.09)
    prof = [(-D / 2, 0.0), (D / 2, 0.0), (D / 2, hb), (-D / 2, hf)]
    m.profile("body", prof, W, plane="yz", bevel=0.008, segments=3)
    # keypad and display lying on the sloped top
    slope = math.atan2(hb - hf, D)

    def on_top(y):
        return hf + (y + D / 2) / D * (hb - hf) + 0.002

    bw, bd = W * 0.08, D * 0.08
    for r in range(4):
        for c in range(3):
            x = W * 0.05 + c * bw * 1.4
            y = -D * 0.35 + r * bd * 1.4
            m.box("button", (bw, bd, 0.004), (x, y, on_top(y)), rot=(slope, 0, 0), bevel=0.001)
    if rng.uniform() < 0.6:
        m.box("screen", (W * 0.3, D * 0.2, 0.003), (W * 0.12, D * 0.28, on_top(D * 0.28)), rot=(slope, 0, 0))
    # handset lying across the top, on the left
    hl = W * rng.uniform(0.95, 1.2)
    hx = -W * 0.28
    z = hb + 0.02
    path = np.array([(hx, -hl / 2, z - 0.005), (hx, -hl * 0.35, z + 0.01), (hx, hl * 0.35, z + 0.01),
                     (hx, hl / 2, z - 0.005)])
    m.tube("handset", fillet(path, 0.03, 3), 0.012, segments=10)
    for sy in (-1, 1):
        m.sphere("handset", 0.025, (hx, sy * hl * 0.42, z - 0.005), scale=(1, 1.3, 0.6), segments=14, rings=7)
    body = _pick(rng, ("dark_plastic", "white_paint", "paint", "plastic"))
    return {"body": body, "screen": "screen", "button": _pick(rng, ("plastic", "dark_plastic", "white_paint")),
            "camera": "glass", "handset": body, "antenna": "dark_plastic"}
