"""Vehicles and long objects: airplane, car, rifle, watercraft. Front (nose, muzzle, bow) faces -y."""

from __future__ import annotations

import math

import numpy as np

from ._registry import category, choice, flag, integer, real
from ._shapes import ellipse, fillet, superellipse


def _pick(rng, options):
    return options[int(rng.integers(len(options)))]


def _rotate_block_since(m, start_face: int, rot_axis: str, angle: float, pivot) -> None:
    """Rotate the vertices used by faces added since ``start_face`` about an axis through ``pivot``."""
    c, s = math.cos(angle), math.sin(angle)
    r = {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
         "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
         "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[rot_axis]
    verts = np.concatenate(m._verts, 0)
    used = sorted({i for f in m._faces[start_face:] for i in f})
    piv = np.asarray(pivot, float)
    verts[used] = (verts[used] - piv) @ r.T + piv
    m._verts = [verts]


# --------------------------------------------------------------------------------------------
# car
# --------------------------------------------------------------------------------------------

# style -> (windshield base u, roof start u, roof end u, rear glass end u, roof height, body height, clearance)
_CAR = {
    "sedan": (0.30, 0.45, 0.68, 0.83, 0.42, 0.62, 0.16),
    "hatchback": (0.30, 0.45, 0.86, 0.985, 0.46, 0.62, 0.16),
    "suv": (0.27, 0.38, 0.93, 0.985, 0.55, 0.78, 0.24),
    "pickup": (0.27, 0.36, 0.53, 0.56, 0.52, 0.78, 0.26),
    "sports": (0.38, 0.55, 0.63, 0.88, 0.32, 0.55, 0.12),
    "van": (0.03, 0.18, 0.95, 0.985, 0.9, 0.75, 0.18),
    "convertible": (0.36, 0.46, 0.47, 0.48, 0.3, 0.58, 0.14),
    "racer": (0.4, 0.5, 0.55, 0.6, 0.18, 0.3, 0.05),
}


@category("car", (
    choice("style", *_CAR, weights=(0.2, 0.14, 0.17, 0.1, 0.12, 0.1, 0.09, 0.08)),
    real("length", 3.8, 5.2, min=1.0, max=20.0),
    real("width_ratio", 0.34, 0.47, min=0.2, max=0.8),
    real("wheel_radius", 0.28, 0.44, min=0.1, max=1.0),
    real("roof_scale", 0.75, 1.3, min=0.3, max=2.0),
    real("wheelbase_ratio", 0.58, 0.66, min=0.3, max=0.9),
))
def car(p, rng, m):
    ua, ub, uc, ud, roof, hb, clr = _CAR[p.style]
    L = p.length
    W = L * p.width_ratio
    roof *= p.roof_scale
    R = p.wheel_radius
    hb *= rng.uniform(0.82, 1.2)
    clr *= rng.uniform(0.8, 1.3)
    front_drop = rng.uniform(0.1, 0.25) * hb
    rear_drop = rng.uniform(0.0, 0.15) * hb
    belt = clr + hb
    us = np.concatenate([[0.0, 0.02, 0.06], np.linspace(0.1, 0.9, 13), [0.94, 0.98, 1.0]])

    def top(u):
        z = np.interp(u, [0, 0.12, ua, ud, 1.0], [belt - front_drop, belt - front_drop * 0.5, belt, belt,
                                                    belt - rear_drop])
        return z

    body_w = 0.42 if p.style == "racer" else 1.0

    def half_w(u):
        if p.style == "racer":
            return W / 2 * body_w * np.interp(u, [0, 0.15, 0.35, 0.75, 1.0], [0.35, 0.45, 1.0, 1.0, 0.7])
        return W / 2 * np.interp(u, [0, 0.08, 0.9, 1.0], [0.82, 0.97, 0.98, 0.9])

    def bottom(u):
        return clr + np.interp(u, [0, 0.06, 0.94, 1.0], [0.12, 0.0, 0.0, 0.08])

    sq = superellipse(1.0, 1.0, rng.uniform(3.5, 6.0), 20)
    rings = []
    for u in us:
        y = -L / 2 + u * L
        zb, zt = bottom(u), top(u)
        hw = half_w(u)
        # ends of the car are slightly inset to round the plan view
        rings.append(np.stack([sq[:, 0] * hw, np.full(len(sq), y), (zb + zt) / 2 + sq[:, 1] * (zt - zb) / 2], 1))
    m.loft("body", rings)

    # cabin (greenhouse): half superellipse rings over the belt line; sides are glass
    ns, nr = 3, 4
    t = np.concatenate([np.linspace(0, 1, ns + 1)[:-1], np.ones(nr + 1), np.linspace(1, 0, ns + 1)[1:]])
    xs = np.concatenate([np.ones(ns), np.linspace(1, -1, nr + 1), -np.ones(ns)])
    k = len(t)
    cu = np.concatenate([np.linspace(ua, ub, 4), np.linspace(ub, uc, 5)[1:], np.linspace(uc, ud, 4)[1:]])
    tumble = rng.uniform(0.7, 0.85)
    crings = []
    for u in cu:
        y = -L / 2 + u * L
        hgt = roof * (np.interp(u, [ua, ub, uc, ud], [0.04, 1, 1, 0.04]))
        hw = half_w(u) * 0.93
        width = hw * (1 - (1 - tumble) * t)
        x = xs * width
        # round the roof edge a little
        z = belt - 0.02 + hgt * np.where(np.abs(xs) < 1, 1 - 0.08 * xs ** 2, t)
        crings.append(np.stack([x, np.full(k, y), z], 1))
    labels = []
    pillar = 4 + int(rng.integers(0, 3))  # B-pillar gap in the roof span
    for i in range(len(cu) - 1):
        for j in range(k):
            side = j < ns or (ns + nr) <= j < k - 1
            roof_seg = ns <= j < ns + nr
            bottom_seg = j == k - 1
            glass_slope = i < 3 or i >= len(cu) - 4
            if bottom_seg:
                labels.append("body")
            elif glass_slope:
                labels.append("window" if (roof_seg or side) else "body")
            elif roof_seg:
                labels.append("body")
            else:
                labels.append("body" if i == pillar else "window")
    labels += ["window", "window"]  # end caps
    m.loft(labels, crings)

    if p.style == "convertible":
        for sx in (-1, 1):
            m.box("body", (W * 0.3, 0.12, roof * 1.3), (sx * W * 0.2, -L / 2 + L * 0.62, belt + roof * 0.4),
                  bevel=0.04, rot=(-0.25, 0, 0))
    if p.style == "racer":
        m.box("body", (W * 0.95, 0.25, 0.03), (0, -L / 2 + 0.15, clr + 0.12), bevel=0.01)  # front wing
        for sx in (-1, 1):
            m.box("body", (0.03, 0.3, 0.3), (sx * W * 0.38, L / 2 - 0.2, belt + 0.2), bevel=0.01)
        m.box("body", (W * 0.8, 0.3, 0.03), (0, L / 2 - 0.2, belt + 0.35), bevel=0.01)  # rear wing
        m.tube("body", fillet([(-0.15, L * 0.08, belt), (0, L * 0.08, belt + 0.3), (0.15, L * 0.08, belt)], 0.1, 4),
               0.025, segments=8)  # roll hoop
    if p.style == "pickup":
        y0, y1 = -L / 2 + (ud + 0.02) * L, L / 2 - 0.08
        zr = belt + 0.03
        for sx in (-1, 1):
            m.box("body", (0.06, y1 - y0, 0.08), (sx * (half_w(0.8) - 0.03), (y0 + y1) / 2, zr), bevel=0.015)
        m.box("body", (2 * half_w(0.8), 0.06, 0.08), (0, y1, zr), bevel=0.015)

    # wheels
    wb = L * p.wheelbase_ratio
    yc = rng.uniform(-0.03, 0.03) * L
    tw = rng.uniform(0.18, 0.26)
    for sy in (-1, 1):
        for sx in (-1, 1):
            c = (sx * (W / 2 - tw / 2 + 0.03), yc + sy * wb / 2, R)
            if p.style == "racer":
                c = (sx * (W / 2 - tw / 2), yc + sy * wb / 2, R)
                m.cylinder_between("body", (sx * half_w(0.5 + sy * 0.3) * 0.8, c[1], clr + 0.1), c, 0.02, segments=6)
            m.cylinder("wheel", R, tw, c, axis=(1, 0, 0), segments=24, bevel=0.04)
            m.cylinder("hubcap", R * rng.uniform(0.55, 0.7), 0.02, (c[0] + sx * tw / 2, c[1], c[2]), axis=(1, 0, 0),
                       segments=16, bevel=0.005)
    # lights
    zl = top(0.0) - 0.1
    for sx in (-1, 1):
        m.sphere("light", 0.1, (sx * half_w(0.0) * 0.7, -L / 2 + 0.03, zl), scale=(1.3, 0.35, 0.6),
                 segments=12, rings=6)
        m.box("light", (0.25, 0.04, 0.09), (sx * half_w(1.0) * 0.72, L / 2 - 0.01, top(1.0) - 0.12), bevel=0.015)
    # bumpers
    for sy, u in ((-1, 0.0), (1, 1.0)):
        m.box("bumper", (2 * half_w(u) * 1.02, 0.12, 0.14), (0, sy * (L / 2 - 0.03), bottom(u) + 0.1), bevel=0.04,
              segments=3)
    return {"body": "paint", "wheel": "rubber", "window": "glass", "light": "light",
            "bumper": _pick(rng, ("dark_plastic", "metal", "paint")), "hubcap": "metal"}


# --------------------------------------------------------------------------------------------
# airplane
# --------------------------------------------------------------------------------------------

@category("airplane", (
    choice("style", "airliner", "fighter", "prop", "glider", "bizjet", weights=(0.3, 0.2, 0.2, 0.12, 0.18)),
    real("span_ratio", 0.7, 1.1, min=0.2, max=3.0),
    real("fuselage_radius", 0.045, 0.07, min=0.01, max=0.3),
    real("sweep", 0.0, 35.0, min=-20.0, max=70.0),
    real("taper", 0.25, 0.6, min=0.05, max=1.0),
    choice("wing_position", "low", "mid", "high"),
    choice("tail", "conventional", "t_tail", "twin"),
    integer("engines_per_wing", 0, 2, min=0, max=4),
    flag("landing_gear", 0.4),
))
def airplane(p, rng, m):
    L = 1.0
    R = p.fuselage_radius
    span = p.span_ratio * L
    sweep = p.sweep
    taper = p.taper
    style = p.style
    engines = p.engines_per_wing
    tail = p.tail
    wing_pos = p.wing_position
    if style == "fighter":
        sweep = max(sweep, 35.0) + 10 * rng.uniform()
        span = min(span, 0.65)
        taper = min(taper, 0.3)
        R *= 1.2
    elif style == "glider":
        span = max(span, 1.3)
        sweep, taper = min(sweep, 5.0), max(taper, 0.4)
        R *= 0.7
        engines = 0
        wing_pos = "high"
    elif style == "prop":
        sweep = min(sweep, 8.0)
        span = max(span, 0.9)
    elif style == "bizjet":
        tail = "t_tail"
    # fuselage
    us = np.concatenate([[0.006, 0.02, 0.04, 0.07, 0.1, 0.14], np.linspace(0.2, 0.65, 6), np.linspace(0.7, 0.99, 7)])
    nose = rng.uniform(0.1, 0.18) if style != "fighter" else 0.25
    prof = np.interp(us, [0, nose, 0.68, 1.0], [0.0, 1.0, 1.0, 0.18])
    prof = np.where(us < nose, np.sqrt(np.clip(us / nose, 0, 1)), prof)
    rise = np.interp(us, [0, 0.68, 1.0], [0.0, 0.0, R * 0.8])
    circ = ellipse(1.0, 1.0 if style != "fighter" else 0.8, 16)
    rings = [np.stack([circ[:, 0] * R * pr, np.full(16, -L / 2 + u * L), rz + circ[:, 1] * R * pr], 1)
             for u, pr, rz in zip(us, prof, rise)]
    m.loft("fuselage", rings, tip_start=(0, -L / 2, 0), cap_end=True)

    # wings
    root_c = L * (rng.uniform(0.16, 0.24) if style != "fighter" else 0.45)
    if style == "glider":
        root_c = L * 0.1
    y_le = -L / 2 + L * (rng.uniform(0.35, 0.45) if style != "fighter" else 0.35)
    wz = {"low": -R * 0.6, "mid": 0.0, "high": R * 0.75}[wing_pos]
    thick = max(R * 0.25, 0.009)
    half = span / 2
    tip_y = y_le + half * math.tan(math.radians(sweep))
    planform = [(0.0, y_le + root_c), (half, tip_y + root_c * taper), (half, tip_y), (0.0, y_le)]
    start = m.n_faces
    m.profile("wing", planform, thick, plane="xy", offset=wz, bevel=thick * 0.3)
    if style not in ("fighter",):
        _rotate_block_since(m, start, "y", -math.radians(rng.uniform(0, 6)), (0, 0, wz))
    # engines on this half
    eng_x = [half * f for f in ((0.35,), (0.3, 0.58), (0.25, 0.45, 0.65), (0.2, 0.35, 0.5, 0.65))[engines - 1]] \
        if engines > 0 and style in ("airliner", "prop") else []
    for ex in eng_x:
        ly = y_le + ex * math.tan(math.radians(sweep))
        if style == "prop":
            m.cylinder("engine", R * 0.45, root_c * 0.9, (ex, ly + root_c * 0.2, wz), axis=(0, 1, 0), radius2=R * 0.3,
                       segments=14, bevel=R * 0.1)
            _propeller(m, rng, (ex, ly - root_c * 0.27, wz), R * 2.2)
        else:
            m.cylinder("engine", R * 0.45, root_c * 0.7, (ex, ly - root_c * 0.15, wz - R * 0.55), axis=(0, 1, 0),
                       radius2=R * 0.38, segments=16, bevel=R * 0.1)
    if p.landing_gear:
        gx = half * 0.15 if style != "fighter" else half * 0.3
        for sx_ in (1,):
            m.cylinder_between("landing_gear", (gx, y_le + root_c * 0.6, wz), (gx, y_le + root_c * 0.6, -R - 0.06),
                               R * 0.08, segments=8)
            m.cylinder("landing_gear", R * 0.35, R * 0.25, (gx, y_le + root_c * 0.6, -R - 0.06), axis=(1, 0, 0),
                       segments=12)
    # horizontal stabilizer (this half)
    st_c = root_c * (0.5 if style != "fighter" else 0.35)
    st_half = half * rng.uniform(0.28, 0.38) if style != "fighter" else half * 0.45
    st_le = L / 2 - st_c * 1.3
    st_z = R * 0.6
    fin_h = R * rng.uniform(2.2, 3.2) if style != "glider" else R * 3.5
    if tail == "t_tail":
        st_z = R * 0.6 + fin_h
    st_tip = st_le + st_half * math.tan(math.radians(max(sweep, 10) + 5))
    stab = [(0.0, st_le + st_c), (st_half, st_tip + st_c * 0.5), (st_half, st_tip), (0.0, st_le)]
    if tail == "t_tail":
        stab = [(0.0, st_le + st_c + fin_h * 0.5), (st_half, st_tip + st_c * 0.5 + fin_h * 0.5),
                (st_half, st_tip + fin_h * 0.5), (0.0, st_le + fin_h * 0.5)]
    m.profile("tail", stab, thick * 0.8, plane="xy", offset=st_z, bevel=thick * 0.2)
    # engines on the rear fuselage (bizjet)
    if style == "bizjet" or (style == "airliner" and engines == 0):
        m.cylinder("engine", R * 0.4, L * 0.12, (R * 1.35, L * 0.22, R * 0.5), axis=(0, 1, 0), radius2=R * 0.33,
                   segments=14, bevel=R * 0.08)
        m.cylinder_between("engine", (R * 0.5, L * 0.22, R * 0.5), (R * 1.1, L * 0.22, R * 0.5), R * 0.1, segments=8)
    m.mirrored_x(start)

    # vertical fin(s)
    fin_root = root_c * 0.6 if style != "fighter" else root_c * 0.35
    fin_le = L / 2 - fin_root * 1.15
    fin_sw = fin_h * math.tan(math.radians(rng.uniform(30, 50)))
    # a sweep of at most 1.6 root chords keeps the top chord (root - sweep / 2) positive: with a short root and a
    # steep sweep (glider, bizjet) the outline crossed itself (an inside-out, pinched fin under a T-tail that
    # floated above it)
    fin_sw = min(fin_sw, fin_root * 1.6)
    fin = [(fin_le, R * 0.4), (fin_le + fin_root, R * 0.6), (fin_le + fin_root + fin_sw * 0.5, R * 0.6 + fin_h),
           (fin_le + fin_sw, R * 0.6 + fin_h)]
    if tail == "twin":
        for sx in (-1, 1):
            start_f = m.n_faces
            m.profile("tail", fin, thick * 0.8, plane="yz", offset=sx * R * 0.9, bevel=thick * 0.2)
            _rotate_block_since(m, start_f, "y", sx * math.radians(15), (sx * R * 0.9, 0, R * 0.5))
    else:
        m.profile("tail", fin, thick * 0.8, plane="yz", offset=0.0, bevel=thick * 0.2)
    # canopy / cockpit and nose propeller
    if style in ("fighter", "glider", "prop"):
        m.sphere("window", R * 0.8, (0, -L / 2 + L * (0.22 if style != "prop" else 0.28), R * 0.7),
                 scale=(0.8, 2.4, 0.7), segments=16, rings=8)
    if style == "prop" and not eng_x:
        _propeller(m, rng, (0, -L / 2 - 0.005, 0), R * 3.0)
    if p.landing_gear:
        m.cylinder_between("landing_gear", (0, -L / 2 + 0.12, -R * 0.5), (0, -L / 2 + 0.12, -R - 0.06), R * 0.07,
                           segments=8)
        m.cylinder("landing_gear", R * 0.3, R * 0.2, (0, -L / 2 + 0.12, -R - 0.06), axis=(1, 0, 0), segments=12)
    body = _pick(rng, ("white_paint", "white_paint", "metal", "paint"))
    return {"fuselage": body, "wing": body if rng.uniform() < 0.7 else "metal", "tail": _pick(rng, (body, "paint")),
            "engine": _pick(rng, ("metal", "dark_metal", body)), "propeller": "dark_metal",
            "landing_gear": "rubber", "window": "glass"}


def _propeller(m, rng, hub, diameter) -> None:
    m.cylinder("propeller", diameter * 0.08, diameter * 0.18, hub, axis=(0, -1, 0), radius2=diameter * 0.01,
               segments=12)
    blades = int(rng.integers(2, 5))
    a0 = rng.uniform(0, math.pi)
    for b in range(blades):
        a = a0 + 2 * math.pi * b / blades
        c = (hub[0] + math.cos(a) * diameter / 4, hub[1] + diameter * 0.04, hub[2] + math.sin(a) * diameter / 4)
        m.box("propeller", (diameter / 2, diameter * 0.015, diameter * 0.07), c, rot=(0.4, -a, 0), bevel=0.002)


# --------------------------------------------------------------------------------------------
# watercraft
# --------------------------------------------------------------------------------------------

@category("watercraft", (
    choice("style", "sailboat", "motorboat", "yacht", "ship", "submarine", weights=(0.25, 0.2, 0.2, 0.25, 0.1)),
    real("beam_ratio", 0.22, 0.36, min=0.05, max=1.0),
    real("depth_ratio", 0.08, 0.16, min=0.02, max=0.6),
    real("fullness", 1.0, 3.0, min=1.0, max=6.0),
    real("sheer", 0.0, 0.06, min=0.0, max=0.3),
    integer("masts", 1, 2, min=0, max=5),
    integer("funnels", 1, 2, min=0, max=6),
))
def watercraft(p, rng, m):
    L = 1.0
    B = L * p.beam_ratio
    Dd = L * p.depth_ratio
    style = p.style
    if style == "ship":
        B = min(B, 0.2)
    if style == "submarine":
        _submarine(m, rng, B * 0.5)
        return {"hull": _pick(rng, ("dark_metal", "dark_plastic")), "cabin": "dark_metal", "mast": "metal"}
    freeboard = Dd * rng.uniform(0.6, 0.9)
    keel = Dd - freeboard
    us = np.concatenate([[0.02, 0.05, 0.1, 0.16, 0.24], np.linspace(0.32, 0.92, 7), [1.0]])
    half_b = B / 2 * np.clip(1 - ((0.55 - us) / 0.55).clip(0) ** 1.7, 0.05, 1.0)
    half_b = np.where(us > 0.8, half_b * np.interp(us, [0.8, 1.0], [1.0, 0.85]), half_b)
    deck = freeboard + p.sheer * (1 - us) ** 2
    n = 6
    ts = np.linspace(1, 0, n + 1)  # deck edge -> keel
    q = p.fullness
    rings = []
    for u, hb, dz in zip(us, half_b, deck):
        y = -L / 2 + u * L
        kz = -keel * np.interp(u, [0, 0.1, 0.85, 1.0], [0.3, 1.0, 1.0, 0.6])
        x_r = hb * (1 - (1 - ts) ** q)
        z_r = kz + (dz - kz) * ts
        x = np.concatenate([x_r, -x_r[::-1][1:]])
        z = np.concatenate([z_r, z_r[::-1][1:]])
        rings.append(np.stack([x, np.full(len(x), y), z], 1))
    k = len(rings[0])
    seg = ["hull"] * (k - 1) + ["deck"]  # the closing segment of each ring spans the deck
    labels = seg * (len(rings) - 1) + seg + ["hull"]  # gaps, bow fan, transom cap
    m.loft(labels, rings, tip_start=(0, -L / 2, freeboard + p.sheer * 1.1), cap_end=True)
    zdeck = freeboard
    if style == "sailboat":
        masts = max(p.masts, 1)
        mh = L * rng.uniform(0.8, 1.2)
        for i in range(masts):
            my = -L * 0.12 + i * L * 0.3
            m.cylinder("mast", 0.008, mh * (1 - 0.25 * i), (0, my, zdeck + mh * (1 - 0.25 * i) / 2), segments=8)
            hgt = mh * (1 - 0.25 * i)
            main = [(my + 0.01, zdeck + 0.06), (my + L * rng.uniform(0.3, 0.42), zdeck + 0.06), (my + 0.01, zdeck + hgt * 0.95)]
            m.profile("sail", main, 0.003, plane="yz")
            m.cylinder_between("mast", (0, my, zdeck + 0.06), (0, main[1][0], zdeck + 0.06), 0.006, segments=6)
        jib = [(-L / 2 + 0.06, zdeck + 0.04), (-L * 0.13, zdeck + 0.04), (-L * 0.13, zdeck + mh * 0.85)]
        m.profile("sail", jib, 0.003, plane="yz")
        m.box("cabin", (B * 0.45, L * 0.2, 0.04), (0, L * 0.12, zdeck + 0.02), bevel=0.01)
    elif style in ("motorboat", "yacht"):
        tiers = 1 if style == "motorboat" else int(rng.integers(2, 4))
        y0 = -L * rng.uniform(0.1, 0.2)
        cl = L * rng.uniform(0.3, 0.45)
        w = B * 0.7
        z = zdeck
        for t_ in range(tiers):
            th = L * rng.uniform(0.05, 0.07)
            m.box("cabin", (w, cl, th), (0, y0 + cl / 2, z + th / 2), bevel=0.012, segments=2)
            m.box("window", (w * 1.01, cl * 0.8, th * 0.35), (0, y0 + cl * 0.55, z + th * 0.55), bevel=0.003)
            z += th
            y0 += cl * 0.15
            cl *= 0.7
            w *= 0.85
        if style == "motorboat":
            m.box("window", (B * 0.55, 0.01, L * 0.05), (0, -L * 0.17, zdeck + L * 0.05), rot=(-0.6, 0, 0), bevel=0.003)
        if rng.uniform() < 0.6:
            m.cylinder("mast", 0.006, L * 0.12, (0, y0 + cl * 0.5, z + L * 0.06), segments=8)
    else:  # ship
        y0 = L * rng.uniform(-0.05, 0.25)
        tiers = int(rng.integers(2, 5))
        w, cl, z = B * 0.85, L * rng.uniform(0.12, 0.3), zdeck
        for t_ in range(tiers):
            th = L * 0.035
            m.box("cabin", (w, cl, th), (0, y0, z + th / 2), bevel=0.004)
            m.box("window", (w * 1.01, cl * 0.9, th * 0.25), (0, y0, z + th * 0.6), bevel=0.001)
            z += th
            cl *= 0.8
            w *= 0.9
        for f in range(p.funnels):
            fy = y0 + cl * 0.5 + L * 0.06 * (f + 1)
            m.cylinder("funnel", B * 0.12, L * 0.09, (0, fy, z + L * 0.03), radius2=B * 0.1, segments=16,
                       bevel=0.003)
            _scale_block(m, (1.0, 1.4, 1.0), (0, fy, z))
        m.cylinder("mast", 0.005, L * 0.12, (0, y0 - cl * 0.3, z + L * 0.06), segments=8)
        if rng.uniform() < 0.5:  # cargo containers forward
            for c in range(int(rng.integers(2, 5))):
                m.box("deck", (B * 0.7, L * 0.06, L * 0.04), (0, -L * 0.3 + c * L * 0.07, zdeck + L * 0.02),
                      bevel=0.002)
    hull = _pick(rng, ("white_paint", "paint", "wood", "dark_metal"))
    return {"hull": hull, "deck": _pick(rng, ("wood", "white_paint", "dark_plastic")),
            "cabin": _pick(rng, ("white_paint", "paint", "wood")), "mast": _pick(rng, ("metal", "wood")),
            "sail": "sail", "funnel": _pick(rng, ("paint", "dark_metal")), "window": "glass"}


def _scale_block(m, scale, center) -> None:
    c = np.asarray(center, float)
    m._verts[-1] = (m._verts[-1] - c) * np.asarray(scale, float) + c


def _submarine(m, rng, R) -> None:
    L = 1.0
    us = np.concatenate([[0.01, 0.04, 0.08, 0.14], np.linspace(0.2, 0.7, 5), np.linspace(0.76, 0.98, 5)])
    prof = np.where(us < 0.18, np.sqrt(us / 0.18), np.interp(us, [0.18, 0.7, 1.0], [1.0, 1.0, 0.1]))
    circ = ellipse(1.0, 1.0, 16)
    rings = [np.stack([circ[:, 0] * R * pr, np.full(16, -L / 2 + u * L), circ[:, 1] * R * pr], 1) for u, pr in zip(us, prof)]
    m.loft("hull", rings, tip_start=(0, -L / 2, 0), cap_end=True)
    sl = L * rng.uniform(0.1, 0.16)
    sy = -L * rng.uniform(0.1, 0.2)
    m.box("cabin", (R * 0.5, sl, R * 1.4), (0, sy, R * 1.3), bevel=R * 0.2, segments=3)
    m.cylinder("mast", R * 0.05, R * 0.8, (0, sy, R * 2.2), segments=8)
    fin = 0.9 * R
    m.profile("hull", [(L * 0.41, -fin), (L * 0.47, -fin), (L * 0.47, fin), (L * 0.41, fin)], R * 0.06,
              plane="yz", bevel=R * 0.02)
    m.profile("hull", [(-fin, L * 0.41), (fin, L * 0.41), (fin, L * 0.47), (-fin, L * 0.47)], R * 0.06,
              plane="xy", bevel=R * 0.02)


# --------------------------------------------------------------------------------------------
# rifle
# --------------------------------------------------------------------------------------------

@category("rifle", (
    choice("style", "bolt", "assault", "sniper", "shotgun", "smg"),
    real("barrel_length", 0.35, 0.7, min=0.05, max=2.0),
    choice("magazine", "box", "curved", "none", weights=(0.45, 0.3, 0.25)),
    choice("stock", "solid", "skeleton", "thumbhole", "none", weights=(0.45, 0.25, 0.2, 0.1)),
    flag("scope", 0.45),
    flag("bipod", 0.2),
))
def rifle(p, rng, m):
    style = p.style
    bl = p.barrel_length * (0.5 if style == "smg" else 1.0)
    rec_l = rng.uniform(0.2, 0.32)
    rec_h = rng.uniform(0.05, 0.075)
    zb = rec_h * 0.65  # barrel axis height
    wood = style in ("bolt", "shotgun") or (style == "sniper" and rng.uniform() < 0.5)
    # receiver (side profile, y back, z up)
    rec = [(0.0, 0.0), (rec_l, 0.0), (rec_l, rec_h), (rec_l * 0.1, rec_h), (0.0, rec_h * 0.8)]
    m.profile("receiver", rec, 0.035, plane="yz", bevel=0.004)
    # barrel
    br = rng.uniform(0.008, 0.013)
    m.cylinder("barrel", br, bl, (0, -bl / 2 + 0.01, zb), axis=(0, 1, 0), segments=12, bevel=0.002)
    if rng.uniform() < 0.5:
        m.cylinder("barrel", br * 1.6, 0.05, (0, -bl + 0.02, zb), axis=(0, 1, 0), segments=12, bevel=0.003)
    # handguard / fore-end
    hl = bl * rng.uniform(0.35, 0.65)
    if wood:
        fore = [(-hl, zb - 0.01), (0.02, zb - 0.012), (0.02, -0.03), (-hl * 0.8, -0.025), (-hl, zb - 0.025)]
        m.profile("handguard", fore, 0.04, plane="yz", bevel=0.006)
    else:
        m.box("handguard", (0.045, hl, 0.05), (0, -hl / 2, zb - 0.005), bevel=0.01)
    if style == "shotgun":
        m.cylinder("magazine", br * 1.1, bl * 0.8, (0, -bl * 0.4, zb - br * 2.8), axis=(0, 1, 0), segments=10)
    # pistol grip (not on classic bolt / shotgun stocks)
    if style not in ("bolt", "shotgun"):
        ang = rng.uniform(0.25, 0.45)
        gl = rng.uniform(0.1, 0.13)
        gy = rec_l * 0.72
        grip = [(gy, 0.005), (gy + 0.04, 0.005), (gy + 0.04 + gl * math.sin(ang), -gl),
                (gy + gl * math.sin(ang) - 0.005, -gl)]
        m.profile("grip", grip, 0.03, plane="yz", bevel=0.006)
        m.box("receiver", (0.006, 0.06, 0.006), (0, gy - 0.03, -0.03), bevel=0.002)  # trigger guard
    # magazine
    if p.magazine != "none" and style != "shotgun":
        my = rec_l * 0.25
        mw = 0.04
        if p.magazine == "curved":
            arc = np.linspace(0, 1, 6)
            depth = rng.uniform(0.14, 0.22)
            bend = 0.25 * depth
            front = [(my - bend * a ** 2, 0.005 - depth * a) for a in arc]
            back = [(my + mw - bend * a ** 2 - 0.015 * a, 0.005 - depth * a) for a in arc[::-1]]
            m.profile("magazine", front + back, 0.028, plane="yz", bevel=0.004)
        else:
            depth = rng.uniform(0.06, 0.16)
            m.box("magazine", (0.028, mw + 0.01, depth), (0, my + mw / 2, -depth / 2 + 0.005), bevel=0.004)
    # stock
    sl = rng.uniform(0.22, 0.34)
    if p.stock != "none":
        drop = rng.uniform(0.02, 0.06)
        y0 = rec_l - 0.01
        if p.stock == "solid":
            poly = [(y0, rec_h), (y0 + sl, rec_h - drop), (y0 + sl, rec_h - drop - 0.13), (y0 + 0.1, -0.04),
                    (y0, -0.01)]
            if style in ("bolt", "shotgun"):  # classic wrist
                poly = [(y0, rec_h), (y0 + sl, rec_h - drop), (y0 + sl, rec_h - drop - 0.14),
                        (y0 + 0.12, -0.015), (y0 + 0.04, -0.04), (y0, -0.01)]
            m.profile("stock", poly, 0.04, plane="yz", bevel=0.008)
        elif p.stock == "thumbhole":
            top = [(y0, rec_h * 0.8), (y0 + sl, rec_h - drop), (y0 + sl, rec_h - drop - 0.12), (y0 + sl - 0.03, rec_h - drop - 0.12), (y0 + sl - 0.03, rec_h - drop - 0.02), (y0, rec_h * 0.4)]
            m.profile("stock", top, 0.035, plane="yz", bevel=0.005)
            m.profile("stock", [(y0, 0.0), (y0 + sl - 0.03, rec_h - drop - 0.12), (y0 + sl - 0.03, rec_h - drop - 0.09),
                                (y0, 0.025)], 0.03, plane="yz", bevel=0.005)
        else:  # skeleton: tubes
            m.cylinder_between("stock", (0, y0, zb), (0, y0 + sl, zb - drop), 0.01, segments=8)
            m.cylinder_between("stock", (0, y0, 0.005), (0, y0 + sl, zb - drop - 0.1), 0.008, segments=8)
            m.box("stock", (0.035, 0.025, 0.13), (0, y0 + sl, zb - drop - 0.05), bevel=0.006)
    # scope
    if p.scope or style == "sniper":
        sl_ = rng.uniform(0.2, 0.32)
        sr = rng.uniform(0.014, 0.02)
        zs = rec_h + 0.035
        ys = rec_l * 0.45
        m.cylinder("scope", sr, sl_ * 0.6, (0, ys, zs), axis=(0, 1, 0), segments=14)
        m.cylinder("scope", sr * 1.6, sl_ * 0.2, (0, ys - sl_ * 0.38, zs), axis=(0, 1, 0), radius2=sr,
                   segments=14)
        m.cylinder("scope", sr * 1.3, sl_ * 0.15, (0, ys + sl_ * 0.36, zs), axis=(0, -1, 0), radius2=sr,
                   segments=14)
        for dy in (-0.06, 0.06):
            m.box("scope", (0.012, 0.015, 0.035), (0, ys + dy, rec_h + 0.01), bevel=0.002)
    elif style in ("assault", "smg") and rng.uniform() < 0.6:
        m.box("receiver", (0.02, 0.12, 0.03), (0, rec_l * 0.5, rec_h + 0.012), bevel=0.004)  # carry handle / rail
    if p.bipod or style == "sniper" and rng.uniform() < 0.5:
        by = -hl * 0.85
        for sx in (-1, 1):
            m.cylinder_between("bipod", (0, by, zb - 0.02), (sx * 0.06, by - 0.05, -0.16), 0.005, segments=6)
    wood_kind = "wood" if wood else _pick(rng, ("dark_plastic", "dark_metal", "paint"))
    return {"barrel": "dark_metal", "receiver": "dark_metal", "stock": wood_kind, "grip": wood_kind,
            "magazine": _pick(rng, ("dark_metal", "dark_plastic")), "scope": "dark_metal", "handguard": wood_kind,
            "bipod": "dark_metal"}
