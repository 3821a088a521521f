"""Contact sheet of the procedural library: several seeds of every category, rendered by Blender.

One row per category, one column per seed, all from the same fixed three-quarter front view
(the view :func:`view_pose` also gives the silhouette tests). Workbench (fast, flat studio light,
material colours) or Cycles at a few samples; ``parts=True`` colours faces by part label instead.
"""

from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import bpy
import numpy as np

from ...errors import InputError
from ...geometry import cameras as C
from ...progress import Progress
from .. import camera as scam
from .. import compat
from . import CATEGORIES, PART_LABELS, build

VIEW_AZIMUTH_DEG = -35.0
"""Fixed preview/silhouette view: azimuth from the front (-y) towards +x, degrees."""
VIEW_ELEVATION_DEG = 25.0
"""Fixed preview/silhouette view: elevation above the ground plane, degrees."""
VIEW_FOV_DEG = 40.0
"""Field of view of the fixed view, degrees."""


def view_pose(distance: float | None = None) -> np.ndarray:
    """OpenCV camera-to-world of the fixed three-quarter front view (objects have bbox diagonal 1)."""
    az, el = math.radians(VIEW_AZIMUTH_DEG), math.radians(VIEW_ELEVATION_DEG)
    d = distance or 1.05 * 0.5 / math.sin(math.radians(VIEW_FOV_DEG) / 2)
    eye = d * np.array([-math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])
    return C.look_at_opencv(eye)


def view_intrinsics(size: int) -> C.Intrinsics:
    return C.intrinsics_from_fov(math.radians(VIEW_FOV_DEG), size, size)


def part_color(label: int) -> tuple[float, float, float]:
    """A stable, distinct colour per global part label (golden-ratio hues)."""
    import colorsys
    h = (label * 0.618033988749895) % 1.0
    return colorsys.hsv_to_rgb(h, 0.65, 0.95)


def _setup_scene(scene, engine: str, size: int, samples: int):
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    compat.set_file_format(scene.render.image_settings, "PNG")
    scene.render.image_settings.color_mode = "RGB"
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("mrvm_preview_world")
    world.color = (1.0, 1.0, 1.0)
    scene.world = world
    if engine == "WORKBENCH":
        scene.render.engine = "BLENDER_WORKBENCH"
        sh = scene.display.shading
        sh.light = "STUDIO"
        sh.color_type = "MATERIAL"
        sh.show_cavity = True
        sh.cavity_type = "WORLD"
        sh.background_type = "WORLD"
        scene.display.render_aa = "8"
    elif engine == "CYCLES":
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        bg = compat.node_tree(world).nodes.get("Background")
        if bg is not None:
            bg.inputs["Color"].default_value = (1, 1, 1, 1)
            bg.inputs["Strength"].default_value = 1.0
        sun = bpy.data.lights.new("mrvm_preview_sun", "SUN")
        sun.energy = 3.0
        so = bpy.data.objects.new("mrvm_preview_sun", sun)
        so.rotation_euler = (math.radians(40), math.radians(10), math.radians(-30))
        scene.collection.objects.link(so)
    else:
        raise InputError(f"unknown preview engine {engine!r}; choose WORKBENCH or CYCLES")
    cam = scam.new_camera("mrvm_preview_cam", scene.collection)
    scam.apply_intrinsics(cam, scene, view_intrinsics(size))
    scam.apply_pose(cam, view_pose())
    scam.set_clip(cam, 0.5, 3.0)
    scene.camera = cam


def render_object_png(scene, obj, path: Path) -> None:
    """Render the tile to ``path``; Blender's own log lines (``render | Saved: '/tmp/...png'``) kept off stdout."""
    from ..objects import quiet_stdout

    scene.render.filepath = str(path)
    with quiet_stdout():
        bpy.ops.render.render(write_still=True)


def _flat_part_colour(mat, rgb) -> None:
    """Colour ``mat`` by its part alone, in every engine: Workbench draws ``diffuse_color``, Cycles and EEVEE the
    node tree (a plain diffuse surface of that colour, replacing the part's textures and metal)."""
    from .. import compat

    mat.diffuse_color = (*rgb, 1.0)
    nt = compat.node_tree(mat)
    if nt is None:
        return
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfDiffuse")
    bsdf.inputs["Color"].default_value = (*rgb, 1.0)
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])


def contact_sheet(out: Path, categories=CATEGORIES, seeds=(0, 1, 2, 3, 4, 5), size: int = 160,
                  engine: str = "WORKBENCH", samples: int = 16, parts: bool = False):
    """Render ``seeds`` of every category into one PNG at ``out``; a progress generator returning the path."""
    from PIL import Image, ImageDraw

    if size < 16 or size > 2048:
        raise InputError(f"tile size must be between 16 and 2048 pixels, got {size}")
    for c in categories:
        if c not in CATEGORIES:
            raise InputError(f"unknown category {c!r}; choose from {', '.join(CATEGORIES)}")
    if not seeds:
        raise InputError("at least one seed is needed")
    out = Path(out)
    if out.parent and not out.parent.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(out.parent, os.W_OK):
        raise InputError(f"cannot write to {out.parent}")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    _setup_scene(scene, engine.upper(), size, samples)
    label_w = 110
    sheet = Image.new("RGB", (label_w + size * len(seeds), size * len(categories)), "white")
    draw = ImageDraw.Draw(sheet)
    total = len(categories) * len(seeds)
    done = 0
    with tempfile.TemporaryDirectory() as tmp:
        for r, cat in enumerate(categories):
            draw.text((6, r * size + size // 2 - 6), cat, fill=(0, 0, 0))
            for c, seed in enumerate(seeds):
                obj = build(cat, int(seed), scene.collection)
                if parts:
                    for mat in obj.data.materials:
                        _flat_part_colour(mat, part_color(mat.pass_index))
                png = Path(tmp) / f"{cat}_{seed}.png"
                render_object_png(scene, obj, png)
                tile = Image.open(png).convert("RGB")
                sheet.paste(tile, (label_w + c * size, r * size))
                draw.text((label_w + c * size + 4, r * size + 3), f"seed {seed}", fill=(90, 90, 90))
                mesh, mats = obj.data, list(obj.data.materials)
                bpy.data.objects.remove(obj)
                bpy.data.meshes.remove(mesh)
                for mat in mats:
                    bpy.data.materials.remove(mat)
                done += 1
                yield Progress(done, total, f"{cat} seed {seed}")
    tmp_out = out.with_name(out.name + ".tmp.png")
    sheet.save(tmp_out)
    os.replace(tmp_out, out)
    return out


__all__ = ["contact_sheet", "view_pose", "view_intrinsics", "part_color", "PART_LABELS"]
