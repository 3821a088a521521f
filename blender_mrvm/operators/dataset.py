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


def config_from_props(context) -> "RenderConfig":  # noqa: F821
    from ..scene.render import RenderConfig

    p = context.scene.mrvm_dataset
    if p.source == "SELECTED":
        sources = ("selected",)
    else:
        if not p.source_path.strip():
            raise MRVMError("choose a mesh file or folder to render")
        sources = (bpy.path.abspath(p.source_path),)
    out = p.output_dir.strip()
    if not out:
        raise MRVMError("choose an output folder")
    if out.startswith("//") and not bpy.data.filepath:
        raise MRVMError("save the .blend first or choose an absolute output folder (// is relative to the .blend)")
    return RenderConfig(out=Path(bpy.path.abspath(out)), sources=sources, rig=p.rig, views=p.views,
                        resolution=(p.resolution, p.resolution), engine=p.engine, samples=p.samples,
                        rgba=p.rgba, fov_deg=math.degrees(p.fov), elevation_deg=math.degrees(p.elevation),
                        seed=p.seed, force=p.force)


class MRVM_OT_render_dataset(bpy.types.Operator):
    """Render a ShapeNet-style multi-view dataset (RGB, depth, normals, part masks, poses) of the chosen objects"""

    bl_idname = "mrvm.render_dataset"
    bl_label = "Render Dataset"
    bl_options = {"REGISTER"}

    _gen = None
    _timer = None

    def _start(self, context):
        from ..scene.render import render_dataset

        cfg = config_from_props(context)
        gen = render_dataset(cfg)
        first = next(gen)  # validates input and the output folder before any rendering
        return gen, first

    def execute(self, context):
        from ..progress import run_to_end

        props = context.scene.mrvm_dataset
        try:
            gen, _ = self._start(context)
            summary = run_to_end(gen)
        except MRVMError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        props.status = f"{summary.views_rendered} views rendered, {summary.views_skipped} already done"
        self.report({"INFO"}, f"Dataset written to {summary.out}: {props.status}")
        return {"FINISHED"}

    def invoke(self, context, event):
        props = context.scene.mrvm_dataset
        if props.running:
            self.report({"WARNING"}, "A dataset render is already running")
            return {"CANCELLED"}
        try:
            self._gen, first = self._start(context)
        except MRVMError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        props.running, props.progress, props.status = True, 0.0, first.message
        wm = context.window_manager
        wm.progress_begin(0, max(first.total, 1))
        self._timer = wm.event_timer_add(0.01, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _finish(self, context, cancelled: bool, message: str, level: str = "INFO"):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace:
            context.workspace.status_text_set(None)
        props = context.scene.mrvm_dataset
        props.running = False
        props.status = message
        self.report({level}, message)
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        return {"CANCELLED"} if cancelled else {"FINISHED"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._gen.close()
            return self._finish(context, True, "Dataset render cancelled; finished views are kept (rerun to resume)",
                                "WARNING")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            ev = next(self._gen)
        except StopIteration as stop:
            s = stop.value
            return self._finish(context, False, f"Dataset written to {s.out}: {s.views_rendered} views rendered, "
                                                f"{s.views_skipped} already done ({s.seconds:.1f} s)")
        except MRVMError as e:
            return self._finish(context, True, str(e), "ERROR")
        props = context.scene.mrvm_dataset
        props.progress, props.status = ev.fraction, f"{ev.message}  ({ev.done}/{ev.total}, Esc to cancel)"
        context.window_manager.progress_update(ev.done)
        if context.workspace:
            context.workspace.status_text_set(f"MRVM: {props.status}")
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        return {"RUNNING_MODAL"}


classes = (MRVM_OT_render_dataset,)
