"""Furniture: bench, cabinet, chair, sofa, table. Units are metres; front faces -y, z up."""

from __future__ import annotations

import math

import numpy as np

from ._registry import category, choice, flag, integer, real
from ._shapes import fillet, rounded_rect

WOODS_OR_METAL = ("wood", "metal", "dark_metal", "paint")


def _pick(rng, options):
    return options[int(rng.integers(len(options)))]


# --------------------------------------------------------------------------------------------
# chair
# --------------------------------------------------------------------------------------------

@category("chair", (
    choice("base", "four_leg", "swivel", "sled", "cantilever", weights=(0.45, 0.25, 0.15, 0.15)),
    flag("arms", 0.4),
    choice("back", "solid", "round_top", "slats", "ladder", "tall"),
    real("seat_width", 0.40, 0.62, min=0.2, max=1.5),
    real("seat_depth", 0.38, 0.56, min=0.2, max=1.5),
    real("seat_height", 0.36, 0.52, min=0.1, max=1.2),
    real("back_height", 0.25, 0.65, min=0.0, max=1.5),
    real("back_tilt", 0.0, 18.0, min=-10.0, max=45.0),
    real("seat_thickness", 0.025, 0.12, min=0.005, max=0.4),
    real("leg_thickness", 0.022, 0.055, min=0.005, max=0.2),
    choice("leg_shape", "round", "square", "tapered"),
    integer("spokes", 4, 5, min=3, max=8),
))
def chair(p, rng, m):
    w, d, h, t = p.seat_width, p.seat_depth, p.seat_height, p.seat_thickness
    lt = p.leg_thickness
    seat_bevel = t * rng.uniform(0.15, 0.45)
    if p.base == "swivel":
        t = max(t, 0.06)
    m.box("seat", (w, d, t), (0, 0, h - t / 2), bevel=seat_bevel, segments=3)
    ztop = h - t
    # --- base
    if p.base == "four_leg":
        inset = rng.uniform(0.0, 0.06)
        splay = rng.uniform(0.0, 0.05)
        for sx in (-1, 1):
            for sy in (-1, 1):
                top = np.array([sx * (w / 2 - lt / 2 - inset), sy * (d / 2 - lt / 2 - inset), ztop])
                bot = top + np.array([sx * splay, sy * splay, -ztop])
                if p.leg_shape == "square":
                    m.box("leg", (lt, lt, ztop), (bot + top) / 2, bevel=lt * 0.15)
                else:
                    r2 = lt / 2 * (0.55 if p.leg_shape == "tapered" else 1.0)
                    m.cylinder_between("leg", bot, top, r2, lt / 2, segments=12)
        if rng.uniform() < 0.5:  # stretchers
            zs = ztop * rng.uniform(0.2, 0.4)
            for sx in (-1, 1):
                x = sx * (w / 2 - lt / 2 - inset + splay * (1 - zs / ztop))
                m.cylinder_between("leg", (x, -(d / 2 - inset), zs), (x, d / 2 - inset, zs), lt * 0.3, segments=8)
    elif p.base == "swivel":
        zb = 0.06
        m.cylinder("base", 0.035, ztop - zb - 0.02, (0, 0, (ztop + zb) / 2), segments=16)
        m.cylinder("base", 0.08, 0.03, (0, 0, ztop - 0.03), segments=16, bevel=0.008)
        reach = max(w, d) * rng.uniform(0.5, 0.62)
        for k in range(p.spokes):
            a = 2 * math.pi * k / p.spokes + math.pi / 2
            end = np.array([reach * math.cos(a), reach * math.sin(a), zb])
            m.cylinder_between("base", (0, 0, zb + 0.01), end + (0, 0, 0.005), 0.02, 0.014, segments=8)
            m.cylinder("caster", 0.025, 0.02, end + (0, 0, -0.03), axis=(math.cos(a + 1.57), math.sin(a + 1.57), 0),
                       segments=12)
        m.cylinder("base", 0.05, 0.05, (0, 0, zb), segments=16, bevel=0.01)
    elif p.base == "sled":
        r = lt * 0.45
        for sx in (-1, 1):
            x = sx * (w / 2 - lt)
            path = [(x, -d / 2 + 0.03, ztop), (x, -d / 2 - 0.02, r), (x, d / 2 + 0.01, r), (x, d / 2 - 0.04, ztop)]
            m.tube("base", fillet(path, 0.06, 4), r, segments=10, cap=True)
    else:  # cantilever: one continuous tube per side, open at the back
        r = lt * 0.45
        for sx in (-1, 1):
            x = sx * (w / 2 - lt)
            path = [(x, d / 2 - 0.05, ztop - r), (x, -d / 2 + 0.02, ztop - r), (x, -d / 2 - 0.04, r),
                    (x, d / 2 + 0.02, r)]
            m.tube("base", fillet(path, 0.08, 5), r, segments=10, cap=True)
    # --- back
    bh = p.back_height * (1.4 if p.back == "tall" else 1.0)
    bt = max(0.02, min(t, 0.06))
    tilt = math.radians(p.back_tilt)
    y0 = d / 2 - bt / 2
    def back_center(z_along):
        return (0.0, y0 + z_along * math.sin(tilt), h + z_along * math.cos(tilt))
    rot = (-tilt, 0, 0)
    if bh > 0.02:
        if p.back in ("solid", "tall"):
            bw = w * rng.uniform(0.85, 1.0)
            m.box("back", (bw, bt, bh), back_center(bh / 2), bevel=bt * 0.4, rot=rot, segments=3)
        elif p.back == "round_top":
            bw = w * rng.uniform(0.8, 1.0)
            prof = rounded_rect(bw, bh, bw * rng.uniform(0.2, 0.5), 6)
            start = m.n_faces
            m.profile("back", prof, bt, plane="xz", bevel=bt * 0.3)
            _transform_faces(m, start, rot, back_center(bh / 2))
        else:
            post = lt * 0.9
            for sx in (-1, 1):
                m.box("back", (post, post, bh), (sx * (w / 2 - post / 2),) + back_center(bh / 2)[1:],
                      bevel=post * 0.2, rot=rot)
            n = int(rng.integers(2, 5)) if p.back == "ladder" else int(rng.integers(3, 7))
            if p.back == "ladder":
                for k in range(n):
                    zz = bh * (0.35 + 0.6 * k / max(n - 1, 1))
                    m.box("back", (w - post, bt * 0.6, bh * 0.1), back_center(zz), bevel=0.005, rot=rot)
            else:
                m.box("back", (w - post, bt, bh * 0.18), back_center(bh * 0.91), bevel=0.008, rot=rot)
                sw = (w - 2 * post) / (2 * n)
                for k in range(n):
                    x = -w / 2 + post + sw * (2 * k + 1)
                    m.box("back", (sw * 0.8, bt * 0.5, bh * 0.82), (x,) + back_center(bh * 0.41)[1:],
                          bevel=0.003, rot=rot)
    # --- arms
    if p.arms:
        za = h + rng.uniform(0.17, 0.25)
        aw = rng.uniform(0.04, 0.08)
        ay0, ay1 = -d / 2 + rng.uniform(0.0, 0.08), d / 2 - bt
        for sx in (-1, 1):
            x = sx * (w / 2 + aw / 2 * rng.choice([0.0, 1.0]))
            m.box("arm", (aw, ay1 - ay0, 0.03), (x, (ay0 + ay1) / 2, za), bevel=0.012)
            # the post stands on the seat's edge (under an armrest set out beside the seat it stood beside the seat,
            # touching nothing: 24 of 40 chairs)
            m.box("arm", (aw * 0.5, 0.03, za - h + 0.02), (sx * w / 2, ay0 + 0.04, (za + h) / 2 - 0.01), bevel=0.005)
    seat_kind = _pick(rng, ("fabric", "leather", "wood", "plastic"))
    frame_kind = _pick(rng, ("wood", "metal", "dark_metal", "plastic"))
    if p.base in ("swivel", "sled", "cantilever"):
        frame_kind = _pick(rng, ("metal", "dark_metal"))
    return {"seat": seat_kind, "back": seat_kind if rng.uniform() < 0.7 else frame_kind, "leg": frame_kind,
            "arm": _pick(rng, (frame_kind, seat_kind)), "base": frame_kind, "caster": "rubber"}


def _transform_faces(m, start: int, rot, center) -> None:
    """Rotate (XYZ Euler) and move the vertices used by faces added since ``start``."""
    from mathutils import Euler
    r = np.array(Euler(rot, "XYZ").to_matrix())
    verts = np.concatenate(m._verts, 0)
    used = sorted({i for f in m._faces[start:] for i in f})
    verts[used] = verts[used] @ r.T + np.asarray(center, float)
    m._verts = [verts]


# --------------------------------------------------------------------------------------------
# table
# --------------------------------------------------------------------------------------------

@category("table", (
    choice("top_shape", "rect", "round", "oval", "square", weights=(0.45, 0.2, 0.15, 0.2)),
    choice("base", "four_leg", "pedestal", "trestle", "panel", weights=(0.45, 0.25, 0.15, 0.15)),
    real("height", 0.4, 0.78, min=0.1, max=1.5),
    real("length", 0.7, 1.9, min=0.2, max=5.0),
    real("depth_ratio", 0.45, 0.9, min=0.1, max=1.0),
    real("top_thickness", 0.02, 0.07, min=0.005, max=0.3),
    real("leg_thickness", 0.03, 0.08, min=0.005, max=0.3),
    flag("apron", 0.5),
    flag("shelf", 0.25),
    integer("feet", 3, 4, min=3, max=8),
))
def table(p, rng, m):
    L = p.length
    D = L * p.depth_ratio if p.top_shape in ("rect", "oval") else L
    if p.top_shape == "square":
        D = L = min(L, 1.1)
    h, t, lt = p.height, p.top_thickness, p.leg_thickness
    round_top = p.top_shape in ("round", "oval")
    if round_top:
        m.cylinder("top", 1.0, t, (0, 0, h - t / 2), segments=48, bevel=t * 0.3)
        _scale_last(m, "top", (L / 2, D / 2, 1.0), (0, 0, h - t / 2))
    else:
        m.box("top", (L, D, t), (0, 0, h - t / 2), bevel=t * rng.uniform(0.1, 0.45), segments=3)
    zt = h - t
    # leg positions
    inset = rng.uniform(0.03, 0.12) * min(L, D)
    if round_top:
        corners = [((L / 2 - inset) * math.cos(a) * 0.72, (D / 2 - inset) * math.sin(a) * 0.72)
                   for a in np.linspace(math.pi / 4, 2 * math.pi + math.pi / 4, 4, endpoint=False)]
    else:
        corners = [(sx * (L / 2 - inset), sy * (D / 2 - inset)) for sx in (-1, 1) for sy in (-1, 1)]
    if p.base == "four_leg":
        shape = _pick(rng, ("square", "round", "tapered"))
        for x, y in corners:
            if shape == "square":
                m.box("leg", (lt, lt, zt), (x, y, zt / 2), bevel=lt * 0.1)
            else:
                m.cylinder_between("leg", (x, y, 0), (x, y, zt), lt / 2 * (0.55 if shape == "tapered" else 1),
                                   lt / 2, segments=12)
        if p.apron:
            ah = min(0.12, zt * 0.2)
            xs = [c[0] for c in corners]
            ys = [c[1] for c in corners]
            if not round_top:
                for sy in (-1, 1):
                    m.box("apron", (max(xs) - min(xs), lt * 0.4, ah), (0, sy * max(ys), zt - ah / 2), bevel=0.004)
                for sx in (-1, 1):
                    m.box("apron", (lt * 0.4, max(ys) - min(ys), ah), (sx * max(xs), 0, zt - ah / 2), bevel=0.004)
            else:
                m.torus("apron", (L / 2 - inset) * 0.72, lt * 0.3, (0, 0, zt - 0.05), segments=32, sides=6)
                _scale_last(m, "apron", (1.0, D / L, 1.0), (0, 0, zt - 0.05))
        if p.shelf:
            xs = [abs(c[0]) for c in corners]
            ys = [abs(c[1]) for c in corners]
            m.box("shelf", (2 * max(xs) + lt, 2 * max(ys) + lt, t * 0.7), (0, 0, zt * 0.25), bevel=0.004)
    elif p.base == "pedestal":
        col_r = rng.uniform(0.04, 0.1)
        m.cylinder("pedestal", col_r, zt, (0, 0, zt / 2), radius2=col_r * rng.uniform(0.6, 1.0), segments=20)
        if rng.uniform() < 0.5:
            fr = min(L, D) * rng.uniform(0.25, 0.4)
            m.cylinder("pedestal", fr, 0.03, (0, 0, 0.015), radius2=fr * 0.85, segments=32, bevel=0.01)
        else:
            reach = min(L, D) * rng.uniform(0.3, 0.45)
            for k in range(p.feet):
                a = 2 * math.pi * k / p.feet + math.pi / 4
                m.cylinder_between("pedestal", (0, 0, 0.08), (reach * math.cos(a), reach * math.sin(a), 0.015),
                                   0.025, 0.018, segments=10)
        if L > 1.3 and not round_top:  # long tables get two pedestals
            m.cylinder("pedestal", col_r, zt, (L * 0.3, 0, zt / 2), segments=20)
            m.box("pedestal", (0.08, D * 0.6, 0.04), (L * 0.3, 0, 0.02), bevel=0.01)
            m.box("pedestal", (0.08, D * 0.6, 0.04), (0, 0, 0.02), bevel=0.01)
    elif p.base == "trestle":
        xin = L / 2 - inset - 0.05
        for sx in (-1, 1):
            m.box("leg", (lt, D * 0.15, zt), (sx * xin, 0, zt / 2), bevel=lt * 0.2)
            m.box("leg", (lt * 1.2, D * 0.8, 0.05), (sx * xin, 0, 0.025), bevel=0.01)
            m.box("leg", (lt * 1.2, D * 0.7, 0.05), (sx * xin, 0, zt - 0.025), bevel=0.01)
        m.box("apron", (2 * xin, lt * 0.8, 0.06), (0, 0, zt * 0.35), bevel=0.01)
    else:  # panel (desk / waterfall)
        pt = max(t, 0.025)
        for sx in (-1, 1):
            m.box("leg", (pt, D * rng.uniform(0.85, 1.0), zt), (sx * (L / 2 - pt / 2 - inset * 0.3), 0, zt / 2),
                  bevel=pt * 0.2)
        if rng.uniform() < 0.6:
            m.box("apron", (L - 2 * pt, 0.015, zt * 0.45), (0, D * 0.4, zt * 0.7), bevel=0.004)
    top_kind = _pick(rng, ("wood", "wood", "white_paint", "glass", "paint"))
    leg_kind = _pick(rng, ("wood", "metal", "dark_metal", "paint"))
    return {"top": top_kind, "leg": leg_kind, "apron": leg_kind, "pedestal": leg_kind, "shelf": top_kind}


def _scale_last(m, label, scale, center) -> None:
    """Scale the most recently added vertex block about ``center`` (used for ovals)."""
    c = np.asarray(center, float)
    m._verts[-1] = (m._verts[-1] - c) * np.asarray(scale, float) + c


# --------------------------------------------------------------------------------------------
# bench
# --------------------------------------------------------------------------------------------

@category("bench", (
    choice("style", "park", "flat", "slatted_flat", "panel", weights=(0.35, 0.25, 0.2, 0.2)),
    flag("back", 0.5),
    flag("arms", 0.35),
    real("length", 1.0, 2.2, min=0.3, max=6.0),
    real("depth", 0.3, 0.55, min=0.1, max=2.0),
    real("seat_height", 0.38, 0.5, min=0.1, max=1.2),
    integer("slats", 3, 6, min=1, max=12),
    integer("supports", 2, 3, min=2, max=6),
))
def bench(p, rng, m):
    L, D, h = p.length, p.depth, p.seat_height
    back = p.back or p.style == "park"
    t = rng.uniform(0.03, 0.06)
    zt = h - t
    if p.style in ("park", "slatted_flat"):
        gap = rng.uniform(0.01, 0.03)
        n = p.slats
        sw = (D - gap * (n - 1)) / n
        for k in range(n):
            y = -D / 2 + sw / 2 + k * (sw + gap)
            m.box("seat", (L, sw, t), (0, y, h - t / 2), bevel=min(sw, t) * 0.25)
    else:
        m.box("seat", (L, D, t * (1.5 if p.style == "panel" else 1)), (0, 0, h - t / 2), bevel=t * 0.3, segments=3)
    xs = np.linspace(-L / 2 + 0.12, L / 2 - 0.12, p.supports)
    frame_kind = _pick(rng, ("dark_metal", "metal", "wood", "paint"))
    if p.style == "park":  # cast side frames: front leg, seat rail, rear leg rising into the back support
        lt = rng.uniform(0.04, 0.06)
        bh_frame = 0.45 if back else 0.0
        for x in xs:
            poly = [(-D / 2 - 0.02, 0.0), (-D / 2 + 0.06, 0.0), (-D / 2 + 0.08, zt - 0.06), (D / 2 - 0.08, zt - 0.06),
                    (D / 2 - 0.02, 0.0), (D / 2 + 0.06, 0.0), (D / 2 + 0.02, zt), (D / 2 + 0.02 + bh_frame * 0.25,
                                                                               zt + bh_frame),
                    (D / 2 - 0.04 + bh_frame * 0.25, zt + bh_frame), (D / 2 - 0.04, zt), (-D / 2 - 0.02, zt)]
            m.profile("frame", poly, lt, plane="yz", offset=x, bevel=0.01)
    elif p.style == "slatted_flat":
        lt = rng.uniform(0.04, 0.07)
        for x in xs:
            for sy in (-1, 1):
                m.box("leg", (lt, lt, zt), (x, sy * (D / 2 - lt), zt / 2), bevel=lt * 0.15)
            m.box("frame", (lt * 0.8, D, 0.05), (x, 0, zt - 0.025), bevel=0.006)
    elif p.style == "panel":
        for x in (xs[0], xs[-1]):
            m.box("leg", (0.05, D * 0.95, zt), (x, 0, zt / 2), bevel=0.012)
    else:
        r = 0.015
        for x in xs:
            path = [(x, -D / 2 + 0.04, zt), (x, -D / 2 + 0.02, r), (x, D / 2 - 0.02, r), (x, D / 2 - 0.04, zt)]
            if rng.uniform() < 0.5:
                m.tube("leg", fillet(path, 0.05, 3), r, segments=8)
            else:
                m.box("leg", (0.04, 0.04, zt), (x, -D / 2 + 0.06, zt / 2), bevel=0.006)
                m.box("leg", (0.04, 0.04, zt), (x, D / 2 - 0.06, zt / 2), bevel=0.006)
    if back:
        bh = rng.uniform(0.3, 0.5)
        tilt = math.radians(rng.uniform(5, 20))
        nb = max(2, p.slats - 1) if p.style != "flat" else 1
        for k in range(nb):
            z = 0.06 + (bh - 0.08) * (k + 0.5) / nb
            y = D / 2 + z * math.sin(tilt)
            m.box("back", (L, 0.025, (bh - 0.08) / nb * (0.75 if nb > 1 else 1.0)),
                  (0, y, h + z * math.cos(tilt)), bevel=0.006, rot=(-tilt, 0, 0))
        for x in xs:
            m.box("frame", (0.04, 0.04, bh + 0.05), (x, D / 2 + bh / 2 * math.sin(tilt), h + bh / 2 - 0.02),
                  bevel=0.008, rot=(-tilt, 0, 0))
    if p.arms:
        za = h + rng.uniform(0.18, 0.25)
        for sx in (-1, 1):
            x = sx * (L / 2 - 0.03)
            m.box("arm", (0.06, D * 0.95, 0.035), (x, 0, za), bevel=0.012)
            m.box("arm", (0.04, 0.04, za - h), (x, -D / 2 + 0.06, (za + h) / 2), bevel=0.006)
    seat_kind = _pick(rng, ("wood", "wood", "paint", "metal"))
    return {"seat": seat_kind, "back": seat_kind, "leg": frame_kind, "arm": frame_kind, "frame": frame_kind}


# --------------------------------------------------------------------------------------------
# sofa
# --------------------------------------------------------------------------------------------

@category("sofa", (
    choice("layout", "straight", "sectional", "loveseat", "chaise"),
    choice("arm_style", "box", "rolled", "none", "thin", weights=(0.35, 0.25, 0.15, 0.25)),
    integer("seats", 2, 4, min=1, max=8),
    real("seat_depth", 0.55, 0.8, min=0.2, max=2.0),
    real("seat_height", 0.38, 0.48, min=0.1, max=1.0),
    real("back_height", 0.35, 0.55, min=0.0, max=1.5),
    real("leg_height", 0.0, 0.16, min=0.0, max=0.6),
    integer("pillows", 0, 2, min=0, max=8),
))
def sofa(p, rng, m):
    n = 2 if p.layout == "loveseat" else p.seats
    cw = rng.uniform(0.55, 0.75)
    W = n * cw
    D, h, lh = p.seat_depth, p.seat_height, p.leg_height
    bt = rng.uniform(0.15, 0.25)  # back thickness
    aw = {"box": 0.18, "rolled": 0.2, "none": 0.0, "thin": 0.08}[p.arm_style] * rng.uniform(0.8, 1.2)
    ct = rng.uniform(0.1, 0.18)  # cushion thickness
    base_top = h - ct
    total_d = D + bt
    yc = -total_d / 2 + D / 2  # seat centre y
    bev = rng.uniform(0.02, 0.05)
    m.box("frame", (W, total_d, base_top - lh), (0, 0, (base_top + lh) / 2), bevel=bev, segments=3)
    # seat cushions
    for k in range(n):
        x = -W / 2 + cw * (k + 0.5)
        m.box("seat_cushion", (cw - 0.01, D - 0.01, ct), (x, yc, base_top + ct / 2), bevel=ct * 0.35, segments=3)
    # back
    bh = p.back_height
    if bh > 0.02:
        m.box("frame", (W, bt, bh), (0, total_d / 2 - bt / 2, h + bh / 2 - 0.02), bevel=bev, segments=3)
        if rng.uniform() < 0.7:
            for k in range(n):
                x = -W / 2 + cw * (k + 0.5)
                m.box("back_cushion", (cw - 0.015, 0.14, bh * 0.85), (x, total_d / 2 - bt - 0.06, h + bh * 0.45),
                      bevel=0.05, segments=3, rot=(-math.radians(rng.uniform(5, 12)), 0, 0))
    extra_x = 0.0
    if p.layout in ("sectional", "chaise"):
        # an L: extra seat block in front of one end
        side = -1 if rng.uniform() < 0.5 else 1
        ext = rng.uniform(0.5, 0.9)
        ex = side * (W / 2 - cw / 2)
        m.box("frame", (cw, ext, base_top - lh), (ex, -total_d / 2 - ext / 2 + 0.01, (base_top + lh) / 2),
              bevel=bev, segments=3)
        m.box("seat_cushion", (cw - 0.01, ext, ct), (ex, -total_d / 2 - ext / 2 + 0.01, base_top + ct / 2),
              bevel=ct * 0.35, segments=3)
        if p.layout == "sectional" and bh > 0.02:
            # the side back stands on the legs' level, beside the seat and its extension (it began above the frame
            # and floated beside the seat)
            top = h + bh - 0.02
            m.box("frame", (bt, ext + D, top - lh), (side * (W / 2 + bt / 2), -total_d / 2 - ext / 2 + D / 2,
                                                     (top + lh) / 2), bevel=bev, segments=3)
            extra_x = side
    # arms
    if aw > 0:
        ah = h + rng.uniform(0.08, 0.22)
        for sx in (-1, 1):
            if sx == extra_x:
                continue
            x = sx * (W / 2 + aw / 2)
            if p.arm_style == "rolled":
                m.box("arm", (aw, total_d, ah - lh - aw / 2), (x, 0, (ah - aw / 2 + lh) / 2), bevel=0.02)
                m.cylinder("arm", aw * 0.6, total_d, (x + sx * 0.02, 0, ah - aw / 2), axis=(0, 1, 0), segments=20,
                           bevel=0.02)
            else:
                m.box("arm", (aw, total_d, ah - lh), (x, 0, (ah + lh) / 2), bevel=min(aw * 0.3, 0.05), segments=3)
    # legs
    if lh > 0.01:
        style = _pick(rng, ("round", "square", "tapered"))
        # under the arms, or under the seat's end on a sectional's armless side (they stood in the air beyond it)
        spots = [(sx * (W / 2 + (aw if sx != extra_x else 0.0) - 0.06), sy * (total_d / 2 - 0.06))
                 for sx in (-1, 1) for sy in (-1, 1)]
        if p.layout in ("sectional", "chaise"):  # and under the front of the extension
            spots += [(ex + dx * (cw / 2 - 0.06), -total_d / 2 - ext + 0.07) for dx in (-1, 1)]
        for x, y in spots:
            if style == "square":
                m.box("leg", (0.05, 0.05, lh), (x, y, lh / 2), bevel=0.006)
            else:
                m.cylinder("leg", 0.025, lh, (x, y, lh / 2), radius2=0.025 if style == "round" else 0.035,
                           segments=10)
    for k in range(p.pillows):
        x = -W / 2 + cw * 0.5 + (W - cw) * (k / max(p.pillows - 1, 1) if p.pillows > 1 else 0.0)
        m.sphere("pillow", 0.2, (x, total_d / 2 - bt - 0.15, h + 0.17), scale=(1.0, 0.35, 0.9), segments=16,
                 rings=8, rot=(-0.3, 0, 0))
    fabric = _pick(rng, ("fabric", "fabric", "leather"))
    return {"frame": fabric, "seat_cushion": fabric, "back_cushion": fabric, "arm": fabric,
            "leg": _pick(rng, ("wood", "metal", "dark_plastic")), "pillow": "fabric"}


# --------------------------------------------------------------------------------------------
# cabinet
# --------------------------------------------------------------------------------------------

@category("cabinet", (
    choice("style", "doors", "drawers", "mixed", "open", "wardrobe"),
    real("width", 0.4, 1.6, min=0.1, max=4.0),
    real("height", 0.5, 1.9, min=0.1, max=4.0),
    real("depth", 0.3, 0.6, min=0.05, max=2.0),
    integer("columns", 1, 3, min=1, max=6),
    integer("rows", 2, 5, min=1, max=10),
    choice("support", "plinth", "legs", "none"),
    choice("handle", "bar", "knob", "none", weights=(0.45, 0.4, 0.15)),
))
def cabinet(p, rng, m):
    W, H, D = p.width, p.height, p.depth
    if p.style == "wardrobe":
        H = max(H, 1.6)
        W = max(W, 0.9)
    if p.style == "drawers":
        H = min(H, 1.3)
    lift = {"plinth": 0.08, "legs": rng.uniform(0.1, 0.2), "none": 0.0}[p.support]
    wall = rng.uniform(0.015, 0.03)
    z0 = lift
    bh = H - lift
    ft = 0.02  # front panel thickness
    if p.style == "open":
        # carcass from panels, with shelves
        for sx in (-1, 1):
            m.box("body", (wall, D, bh), (sx * (W / 2 - wall / 2), 0, z0 + bh / 2), bevel=0.003)
        m.box("body", (W, D, wall), (0, 0, z0 + bh - wall / 2), bevel=0.003)
        m.box("body", (W, D, wall), (0, 0, z0 + wall / 2), bevel=0.003)
        m.box("body", (W - 2 * wall, wall, bh - 2 * wall), (0, D / 2 - wall / 2, z0 + bh / 2))
        for k in range(1, p.rows):
            m.box("shelf", (W - 2 * wall, D - wall, wall), (0, -wall / 2, z0 + wall + (bh - 2 * wall) * k / p.rows),
                  bevel=0.002)
        for k in range(1, p.columns):
            m.box("body", (wall, D - wall, bh - 2 * wall), (-W / 2 + W * k / p.columns, -wall / 2, z0 + bh / 2))
    else:
        m.box("body", (W, D, bh), (0, 0, z0 + bh / 2), bevel=rng.uniform(0.003, 0.012))
        yf = -D / 2 - ft / 2
        cols = 2 if p.style == "wardrobe" else p.columns
        cw = W / cols
        gap = 0.006
        drawers_col = int(rng.integers(cols)) if p.style == "mixed" else -1
        for c in range(cols):
            x = -W / 2 + cw * (c + 0.5)
            if p.style == "drawers" or c == drawers_col:
                rows = p.rows
                for r in range(rows):
                    zc = z0 + bh * (r + 0.5) / rows
                    m.box("drawer", (cw - gap, ft, bh / rows - gap), (x, yf, zc), bevel=0.004)
                    _handle(m, p.handle, (x, yf - ft / 2, zc + bh / rows * 0.2), cw, horizontal=True)
            else:
                m.box("door", (cw - gap, ft, bh - gap), (x, yf, z0 + bh / 2), bevel=0.004)
                hx = x + (cw / 2 - 0.05) * (1 if c % 2 == 0 else -1) if cols > 1 else x + cw / 2 - 0.05
                _handle(m, p.handle, (hx, yf - ft / 2, z0 + bh * (0.5 if p.style != "wardrobe" else 0.55)),
                        bh, horizontal=False)
        if rng.uniform() < 0.3:
            m.box("body", (W + 0.03, D + 0.04, 0.03), (0, -0.01, z0 + bh + 0.015), bevel=0.006)
    if p.support == "plinth":
        m.box("leg", (W - 0.04, D - 0.04, lift), (0, 0.0, lift / 2))
    elif p.support == "legs":
        for sx in (-1, 1):
            for sy in (-1, 1):
                m.cylinder("leg", 0.02, lift, (sx * (W / 2 - 0.05), sy * (D / 2 - 0.05), lift / 2), radius2=0.03,
                           segments=10)
    body = _pick(rng, ("wood", "wood", "white_paint", "paint"))
    front = body if rng.uniform() < 0.6 else _pick(rng, ("wood", "white_paint", "paint", "glass"))
    return {"body": body, "door": front, "drawer": front, "handle": _pick(rng, ("metal", "dark_metal", "wood")),
            "shelf": body, "leg": _pick(rng, ("wood", "metal", "dark_plastic"))}


def _handle(m, style, pos, span, horizontal) -> None:
    x, y, z = pos
    if style == "knob":
        m.sphere("handle", 0.015, (x, y - 0.012, z), segments=10, rings=6)
    elif style == "bar":
        ln = min(0.25, span * 0.4)
        if horizontal:
            m.cylinder_between("handle", (x - ln / 2, y - 0.02, z), (x + ln / 2, y - 0.02, z), 0.007, segments=8)
        else:
            m.cylinder_between("handle", (x, y - 0.02, z - ln / 2), (x, y - 0.02, z + ln / 2), 0.007, segments=8)
