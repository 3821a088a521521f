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


def selected_renderable(context) -> int:
    """How many selected objects Render Dataset's "Selected objects" renders (meshes, curves, surfaces, texts,
    metaballs: ``scene.objects``)."""
    from ..scene.objects import _MESHLIKE

    return sum(1 for o in context.selected_objects or () if o.type in _MESHLIKE)


def _degrees(angle: float) -> float:
    """A float32 angle property in degrees as typed: 40 degrees, not 39.99999883637168 (the dataset's settings read
    the same from the panel and the CLI)."""
    return round(math.degrees(angle), 5)


def rendering_into(out: Path) -> str | None:
    """The name of the scene whose Render Dataset job renders into ``out`` now, or None. Two scenes' jobs into one
    folder rendered the same views twice, turn about (they share Blender's main thread), or the second was refused as
    "in use by another process" naming Blender's own process id."""
    from ._modal import _live

    for job in _live:
        if job.props_attr == "mrvm_dataset" and getattr(job, "_out", None) and _same_folder(job._out, out):
            scene = job._job_scene(None)
            return scene.name if scene is not None else "?"
    return None


def _same_folder(a: Path, b: Path) -> bool:
    from ..guards import same_path

    return same_path(a, b)  # (macOS: Data is data)


def _data_uids() -> frozenset:
    from ..scene.objects import all_id_collections

    return frozenset(d.session_uid for name in all_id_collections() for d in getattr(bpy.data, name))


def private_render_data(before=frozenset()) -> list:
    """The data-blocks made since ``before`` (``session_uid``s) for a Render Dataset job's own render scene: its
    scenes named "MRVM_render", and what was made since that only they use (collection, objects, meshes, materials,
    images, camera, light, world). The artist's own data, new or not, is used by the artist's scenes: never in it."""
    from ..scene.objects import all_id_collections

    new = [d for name in all_id_collections() for d in getattr(bpy.data, name) if d.session_uid not in before]
    private = {d.session_uid for d in new if isinstance(d, bpy.types.Scene) and d.name.startswith("MRVM_render")}
    if not private:
        return []
    users = bpy.data.user_map(subset=new)
    grew = True
    while grew:
        grew = False
        for d in new:
            by = users.get(d, ())
            if d.session_uid not in private and by and all(u.session_uid in private for u in by):
                private.add(d.session_uid)
                grew = True
    return [d for d in new if d.session_uid in private]


def keep_render_scenes_out_of_saves() -> None:
    """Before a save (``save_pre``): the render scene of each Render Dataset job running, and what only it uses, are
    marked runtime data, which Blender does not write. Ctrl-S during a render saved them into the artist's .blend:
    a scene "MRVM_render" with the object being rendered, a camera, a sun and a world, there each time it was
    opened. The render goes on (it removes them when it ends, as always)."""
    from ._modal import _live

    for job in list(_live):
        if job.props_attr == "mrvm_dataset" and getattr(job, "_before", None):
            for d in private_render_data(job._before):
                d.is_runtime_data = True


def remove_render_scenes_undo_brought_back() -> None:
    """After an undo or a redo (``undo_post``, ``redo_post``): remove the render scenes of Render Dataset jobs, and
    what only they use, from the state loaded. An undo step saved while a render ran (the artist went on working)
    holds its render scene: undoing to it after the render had ended brought back a scene "MRVM_render" with the
    object rendered, its camera, sun and world, for good (saved with the file). None is in use: a render running when
    the undo came has lost its data with it (it stops at its next view, its finished views kept)."""
    stale = private_render_data()
    if stale:
        bpy.data.batch_remove(stale)


class MRVM_OT_render_dataset(ProgressOperator, bpy.types.Operator):
    """Render a ShapeNet-style multi-view dataset (RGB, depth, normals, part masks, poses) of the chosen objects"""

    bl_idname = "mrvm.render_dataset"
    bl_label = "Render Dataset"
    bl_options = {"REGISTER"}

    props_attr = "mrvm_dataset"
    job_name = "Dataset render"
    panel_names = {"--force": "Overwrite", "--skip-bad-meshes": "Skip bad meshes", "--views": "Views",
                   "--resolution": "Resolution", "--samples": "Samples", "--rig": "Rig", "--fov": "Field of view",
                   "--elevation": "Elevation", "--seed": "Seed", "--out": "Output", "--source": "Objects",
                   "--rgba": "Transparent background", "--engine": "Engine"}
    cancel_hint = "finished views are kept (render again to resume)"

    _out = None
    """The dataset folder this job renders into (:func:`rendering_into`)."""
    _before = frozenset()
    """``session_uid`` of every data-block when the job started (:func:`private_render_data`)."""

    @classmethod
    def blocked(cls, context) -> str:
        from ._modal import SAVE_FIRST, unsaved_relative

        p = context.scene.mrvm_dataset
        if p.source == "SELECTED" and not selected_renderable(context):
            return ("Select the objects to render (meshes, curves, surfaces, texts or metaballs), or choose another "
                    "Objects source")
        if p.source == "PATH" and not p.source_path.strip():
            return "Choose the mesh file or folder to render (Path)"
        if p.rig == "scene" and not any(o.type == "CAMERA" for o in context.scene.objects):
            return "The Scene cameras rig renders from the scene's cameras: add a camera, or choose another Rig"
        if not p.output_dir.strip():
            return "Choose an Output folder"
        if unsaved_relative(p.output_dir) or (p.source == "PATH" and unsaved_relative(p.source_path)):
            return SAVE_FIRST.format(what="Output" if unsaved_relative(p.output_dir) else "Path")
        return ""

    def start(self, context):
        from ..errors import OutputError
        from ..scene.render import render_dataset

        cfg = config_from_props(context)
        other = rendering_into(cfg.out)
        if other is not None:
            raise OutputError(f"the Dataset section of scene {other!r} is rendering into {cfg.out}; wait for it to "
                              "finish or choose another output folder")
        self._out, self._before = cfg.out, _data_uids()
        return render_dataset(cfg)

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
