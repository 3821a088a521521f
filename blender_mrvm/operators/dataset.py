"""Operator: Render dataset (panel button and ``bpy.ops.mrvm.render_dataset()``).

``invoke`` (the UI) runs modal: a timer advances the core generator one view per tick, so the UI
stays responsive, with Blender's progress indicator, a status line and Esc to cancel (finished views
are kept; a rerun resumes). ``execute`` (scripts, ``--background``) runs to the end in one call.
"""

from __future__ import annotations

import math
from pathlib import Path

import bpy

from ..errors import MRVMError
from ._modal import ProgressOperator


def config_from_props(context) -> "RenderConfig":  # noqa: F821
    from ..scene.render import RenderConfig, scene_frame_size

    p = context.scene.mrvm_dataset
    if p.source == "SELECTED":
        sources = ("selected",)
    elif p.source == "LIBRARY":
        from ..scene.procedural import CATEGORIES

        cats = CATEGORIES if p.library_category == "ALL" else (p.library_category,)
        sources = tuple(f"procedural:{c}:{s}" for c in cats
                        for s in range(p.library_seed, p.library_seed + p.library_count))
    else:
        if not p.source_path.strip():
            raise MRVMError("choose a mesh file or folder to render")
        from ._paths import blend_path

        sources = (str(blend_path(p.source_path, "the mesh file or folder")),)
    out = p.output_dir.strip()
    if not out:
        raise MRVMError("choose an output folder")
    if out.startswith("//") and not bpy.data.filepath:
        raise MRVMError("save the .blend first or choose an absolute output folder (// is relative to the .blend)")
    return RenderConfig(out=Path(bpy.path.abspath(out)), sources=sources, rig=p.rig, views=p.views,
                        resolution=(scene_frame_size(context.scene, p.resolution) if p.rig == "scene"
                                    else (p.resolution, p.resolution)), engine=p.engine, samples=p.samples,
                        rgba=p.rgba, fov_deg=_degrees(p.fov), elevation_deg=_degrees(p.elevation),
                        seed=p.seed, force=p.force, skip_bad_meshes=p.source == "PATH" and p.skip_bad_meshes)


def _degrees(angle: float) -> float:
    """A float32 angle property in degrees as typed: 40 degrees, not 39.99999883637168 (the dataset's settings read
    the same from the panel and the CLI)."""
    return round(math.degrees(angle), 5)


class MRVM_OT_render_dataset(ProgressOperator, bpy.types.Operator):
    """Render a ShapeNet-style multi-view dataset (RGB, depth, normals, part masks, poses) of the chosen objects"""

    bl_idname = "mrvm.render_dataset"
    bl_label = "Render Dataset"
    bl_options = {"REGISTER"}

    props_attr = "mrvm_dataset"
    job_name = "Dataset render"
    cancel_hint = "finished views are kept (render again to resume)"

    def start(self, context):
        from ..scene.render import render_dataset

        return render_dataset(config_from_props(context))

    def on_result(self, context, s) -> str:
        for w in s.warnings:  # e.g. a mesh's missing textures: in the Info log, one line each
            self.report({"WARNING"}, w)
        warned = ""
        if s.warnings:
            more = f" (and {len(s.warnings) - 1} more)" if len(s.warnings) > 1 else ""
            warned = f"; warning: {s.warnings[0]}{more}"
        return (f"Dataset written to {s.out}: {s.views_rendered} views rendered, "
                f"{s.views_skipped} already done ({s.seconds:.1f} s){warned}")


classes = (MRVM_OT_render_dataset,)
