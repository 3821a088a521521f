"""Seeded, plausible materials per part: Principled BSDF + a procedural texture on some kinds.

A generator names a material *kind* per part ("wood", "metal", "fabric", ...); :func:`make_material`
draws colour/roughness/metallic within that kind's range from the object's random generator and
builds a new material (its node tree is embedded, so the material is the only new datablock).
``diffuse_color`` / ``metallic`` / ``roughness`` are also set, so Workbench shows the colour. Colours are drawn as
linear Rec.709 and converted into the open file's working space (ACEScg or Linear Rec.2020 in a Blender 5.0 file
set so: ``objects.rec709_colours_to_working_space``), so an object renders the same colours in every file.
"""

from __future__ import annotations

import colorsys

import bpy
import numpy as np

from .. import compat

# kind -> (hue range, saturation range, value range, roughness range, metallic, texture)
# colours are drawn in HSV (value in display space) and converted to linear for the BSDF.
KINDS: dict[str, tuple] = {
    "wood": ((0.05, 0.11), (0.45, 0.75), (0.25, 0.75), (0.45, 0.75), 0.0, "wave"),
    "metal": ((0.0, 1.0), (0.0, 0.12), (0.45, 0.9), (0.15, 0.45), 1.0, "noise_rough"),
    "dark_metal": ((0.0, 1.0), (0.0, 0.1), (0.12, 0.35), (0.25, 0.55), 1.0, None),
    "plastic": ((0.0, 1.0), (0.0, 0.8), (0.1, 0.95), (0.25, 0.6), 0.0, "voronoi?"),
    "dark_plastic": ((0.0, 1.0), (0.0, 0.25), (0.04, 0.2), (0.3, 0.7), 0.0, None),
    "fabric": ((0.0, 1.0), (0.1, 0.7), (0.2, 0.85), (0.8, 1.0), 0.0, "noise"),
    "leather": ((0.02, 0.1), (0.3, 0.8), (0.1, 0.6), (0.35, 0.6), 0.0, "noise"),
    "paint": ((0.0, 1.0), (0.3, 0.95), (0.2, 0.95), (0.1, 0.3), 0.3, None),
    "white_paint": ((0.0, 1.0), (0.0, 0.08), (0.75, 0.97), (0.2, 0.5), 0.0, None),
    "glass": ((0.5, 0.65), (0.1, 0.4), (0.05, 0.25), (0.02, 0.1), 0.0, None),
    "screen": ((0.55, 0.7), (0.2, 0.6), (0.02, 0.12), (0.05, 0.15), 0.0, None),
    "rubber": ((0.0, 1.0), (0.0, 0.05), (0.03, 0.1), (0.8, 0.95), 0.0, None),
    "light": ((0.1, 0.16), (0.05, 0.4), (0.85, 1.0), (0.1, 0.3), 0.0, None),
    "sail": ((0.08, 0.14), (0.0, 0.2), (0.8, 0.98), (0.7, 0.9), 0.0, "noise"),
}


def _linear(c: float) -> float:
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def draw_color(rng: np.random.Generator, kind: str) -> tuple[float, float, float]:
    """A linear Rec.709 colour of ``kind``."""
    h, s, v = KINDS[kind][:3]
    hsv = (rng.uniform(*h), rng.uniform(*s), rng.uniform(*v))
    return tuple(_linear(c) for c in colorsys.hsv_to_rgb(*hsv))


def make_material(name: str, kind: str, rng: np.random.Generator, pass_index: int,
                  color: tuple[float, float, float] | None = None) -> bpy.types.Material:
    """A new material of ``kind`` whose ``pass_index`` is the part label (``color``: linear Rec.709, as drawn)."""
    if kind not in KINDS:
        raise KeyError(kind)
    _, _, _, rough_r, metallic, texture = KINDS[kind]
    base = draw_color(rng, kind) if color is None else color
    rough = float(rng.uniform(*rough_r))
    tex_roll = float(rng.uniform())
    tex_scale = float(rng.uniform(3.0, 12.0))
    tone = float(rng.uniform(0.55, 0.8))
    if texture == "voronoi?":
        texture = "voronoi" if tex_roll < 0.3 else None

    mat = bpy.data.materials.new(name)
    mat.pass_index = int(pass_index)
    mat.diffuse_color = (*base, 1.0)
    mat.metallic = float(metallic)
    mat.roughness = rough
    nt = compat.node_tree(mat)
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    bsdf.inputs["Base Color"].default_value = (*base, 1.0)
    bsdf.inputs["Roughness"].default_value = rough
    bsdf.inputs["Metallic"].default_value = float(metallic)
    if kind == "glass":
        bsdf.inputs["Coat Weight"].default_value = 1.0
    if texture in ("wave", "noise", "voronoi"):
        dark = tuple(c * tone for c in base)
        if texture == "wave":
            tex = nt.nodes.new("ShaderNodeTexWave")
            tex.wave_type = "RINGS" if tex_roll < 0.5 else "BANDS"
            tex.inputs["Scale"].default_value = tex_scale * 0.5
            tex.inputs["Distortion"].default_value = 4.0 + 6.0 * tex_roll
            fac = tex.outputs["Fac"]
        elif texture == "noise":
            tex = nt.nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = tex_scale * 4.0
            tex.inputs["Detail"].default_value = 6.0
            fac = tex.outputs["Fac"]
        else:
            tex = nt.nodes.new("ShaderNodeTexVoronoi")
            tex.inputs["Scale"].default_value = tex_scale * 3.0
            fac = tex.outputs["Distance"]
        ramp = nt.nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (*dark, 1.0)
        ramp.color_ramp.elements[1].color = (*base, 1.0)
        if texture == "noise":
            ramp.color_ramp.elements[0].position = 0.3
            ramp.color_ramp.elements[1].position = 0.7
        nt.links.new(fac, ramp.inputs["Fac"])
        nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    elif texture == "noise_rough":
        tex = nt.nodes.new("ShaderNodeTexNoise")
        tex.inputs["Scale"].default_value = tex_scale * 8.0
        ramp = nt.nodes.new("ShaderNodeMapRange")
        ramp.inputs["To Min"].default_value = max(rough - 0.1, 0.02)
        ramp.inputs["To Max"].default_value = min(rough + 0.15, 1.0)
        nt.links.new(tex.outputs["Fac"], ramp.inputs["Value"])
        nt.links.new(ramp.outputs["Result"], bsdf.inputs["Roughness"])
    from ..objects import rec709_colours_to_working_space

    rec709_colours_to_working_space([mat])  # the numbers above are linear Rec.709
    return mat
