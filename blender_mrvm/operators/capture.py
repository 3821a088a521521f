"""Operator: Recover poses (photos folder in, cameras + points out).

``invoke`` (the UI) runs modal: each pycolmap stage runs in a worker thread inside the core
generator (``capture.sfm.recover_poses``), and a timer advances the generator, which waits at most
0.1 s per step, so the UI stays responsive; Esc cancels the running stage through pycolmap's
cancellation token (what finished stays in ``<output>/colmap``). When the generator ends, the
capture folder is imported on the main thread (``scene.capture.import_capture``): one camera per
registered photo with its intrinsics, the photo as camera background, the sparse points as a mesh
with vertex colours, all in a new collection. ``execute`` (scripts) runs everything in one call.
"""

from __future__ import annotations

from pathlib import Path

import bpy

from ..errors import MRVMError


def config_from_props(context):
    from ..capture.config import CaptureConfig

    p = context.scene.mrvm_capture
    if not p.images_dir.strip():
        raise MRVMError("choose a folder of photos")
    out = p.output_dir.strip()
    if not out:
        raise MRVMError("choose an output folder")
    if out.startswith("//") and not bpy.data.filepath:
        raise MRVMError("save the .blend first or choose an absolute output folder (// is relative to the .blend)")
    cfg = CaptureConfig(camera_model=p.camera_model, matcher=p.matcher, max_num_features=p.max_features,
                        allow_pair=p.allow_pair, force=p.force).validate()
    return Path(bpy.path.abspath(p.images_dir)), Path(bpy.path.abspath(out)), cfg


def _import(context, result) -> str:
    from ..scene.capture import import_capture

    made = import_capture(result.out_dir, context.scene, collection_name=f"Capture {Path(result.out_dir).name}")
    n = len(made["cameras"])
    return (f"Recovered {len(result.registered)}/{result.total} photos into {result.out_dir}; {n} cameras and "
            f"{result.num_points} points in collection {made['collection'].name!r}")


class MRVM_OT_recover_poses(bpy.types.Operator):
    """Recover the camera poses of a folder of photos (pycolmap) and add them as cameras with the photos as backgrounds and the sparse points as a mesh"""

    bl_idname = "mrvm.recover_poses"
    bl_label = "Recover Poses"
    bl_options = {"REGISTER", "UNDO"}

    _gen = None
    _timer = None

    def _start(self, context):
        from ..capture.sfm import recover_poses

        images, out, cfg = config_from_props(context)
        gen = recover_poses(images, out, cfg)
        first = next(gen)  # scans and checks the photos and the output folder before any work
        return gen, first

    def execute(self, context):
        from ..progress import run_to_end

        props = context.scene.mrvm_capture
        try:
            gen, _ = self._start(context)
            result = run_to_end(gen)
            msg = _import(context, result)
        except MRVMError as e:
            props.status = str(e)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        props.status = msg
        self.report({"INFO"}, msg)
        return {"FINISHED"}

    def invoke(self, context, event):
        props = context.scene.mrvm_capture
        if props.running:
            self.report({"WARNING"}, "Pose recovery is already running")
            return {"CANCELLED"}
        try:
            self._gen, first = self._start(context)
        except MRVMError as e:
            props.status = str(e)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        props.running, props.progress, props.status = True, first.fraction, first.message
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.05, window=context.window)
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
        props = context.scene.mrvm_capture
        props.running = False
        props.status = message
        self.report({level}, message)
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        return {"CANCELLED"} if cancelled else {"FINISHED"}

    def cancel(self, context):  # Blender closing the operator (file load, quit)
        if self._gen is not None:
            self._gen.close()
        self._finish(context, True, "Pose recovery cancelled", "WARNING")

    def modal(self, context, event):
        if event.type == "ESC":
            self._gen.close()
            return self._finish(context, True, "Pose recovery cancelled; finished stages are kept in the output's colmap/",
                                "WARNING")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            ev = next(self._gen)
        except StopIteration as stop:
            try:
                msg = _import(context, stop.value)
            except MRVMError as e:
                return self._finish(context, True, str(e), "ERROR")
            return self._finish(context, False, msg)
        except MRVMError as e:
            return self._finish(context, True, str(e), "ERROR")
        props = context.scene.mrvm_capture
        props.progress, props.status = ev.fraction, f"{ev.message} (Esc to cancel)"
        context.window_manager.progress_update(ev.done)
        if context.workspace:
            context.workspace.status_text_set(f"MRVM: {props.status}")
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        return {"RUNNING_MODAL"}


classes = (MRVM_OT_recover_poses,)
