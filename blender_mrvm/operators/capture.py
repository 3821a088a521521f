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
from ._modal import ProgressOperator


def config_from_props(context):
    from ..capture.config import CaptureConfig

    p = context.scene.mrvm_capture
    if not p.images_dir.strip():
        raise MRVMError("choose a folder of photos or a video")
    out = p.output_dir.strip()
    if not out:
        raise MRVMError("choose an output folder")
    if out.startswith("//") and not bpy.data.filepath:
        raise MRVMError("save the .blend first or choose an absolute output folder (// is relative to the .blend)")
    cfg = CaptureConfig(camera_model=p.camera_model, matcher=p.matcher, max_num_features=p.max_features,
                        upsample_below=p.upsample_below, single_camera=p.single_camera,
                        estimate_focal=p.estimate_focal, allow_pair=p.allow_pair, video_frames=p.video_frames,
                        force=p.force).validate()
    return Path(bpy.path.abspath(p.images_dir)), Path(bpy.path.abspath(out)), cfg


def _import(context, result) -> str:
    from ..scene.capture import import_capture

    made = import_capture(result.out_dir, context.scene, collection_name=f"Capture {Path(result.out_dir).name}")
    n = len(made["cameras"])
    return (f"Recovered {len(result.registered)}/{result.total} photos into {result.out_dir}; {n} cameras and "
            f"{result.num_points} points in collection {made['collection'].name!r}")


class MRVM_OT_recover_poses(ProgressOperator, bpy.types.Operator):
    """Recover the camera poses of a folder of photos (pycolmap) and add them as cameras with the photos as backgrounds and the sparse points as a mesh"""

    bl_idname = "mrvm.recover_poses"
    bl_label = "Recover Poses"
    bl_options = {"REGISTER", "UNDO"}

    props_attr = "mrvm_capture"
    job_name = "Pose recovery"
    cancel_hint = "finished stages are kept in the output's colmap/"
    timer_interval = 0.05

    def start(self, context):
        from ..capture.sfm import recover_poses

        images, out, cfg = config_from_props(context)
        return recover_poses(images, out, cfg)

    def on_result(self, context, result) -> str:
        return _import(context, result)


classes = (MRVM_OT_recover_poses,)
