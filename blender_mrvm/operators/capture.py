"""Operator: Recover poses (photos folder or video in, cameras + points out).

pycolmap runs in the worker Python (``worker.run_worker``: ``python -m blender_mrvm recover-poses --images DIR
--out OUT ...``, the panel's settings as :func:`commands.recover_poses.cli_args`), as synthesis does: Blender's
own Python has no pycolmap (nor PyAV, pillow-heif) unless someone installed them there, and the worker Python
(the add-on preferences, else a project ``.venv``) has them. ``invoke`` (the UI) runs modal, a timer reading the
worker's progress; Esc interrupts it, and the stages it finished stay in ``<output>/colmap`` (a rerun resumes them).
When the worker ends, the capture folder is imported on the main thread (``scene.capture.import_capture``): one
camera per registered photo with its intrinsics, the photo as camera background, the sparse points as a mesh with
vertex colours, all in a new collection. ``execute`` (scripts) runs everything in one call.
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
    from ._paths import blend_path

    return blend_path(p.images_dir, "the photos"), Path(bpy.path.abspath(out)), cfg


WORKER_NEEDS = ("pycolmap", "PIL", "numpy")
"""What the worker Python must have for pose recovery (HEIC photos and videos name what they need themselves)."""


def run_capture(context, images: Path, out: Path, cfg):
    """Progress generator: ``recover-poses`` in the worker Python; returns the capture folder."""
    from .. import prefs as P
    from ..commands.recover_poses import cli_args
    from ..worker import choose_interpreter, require, run_worker

    pr = P.get(context)
    interp = choose_interpreter(pr.python_path if pr else "", WORKER_NEEDS)
    require(interp, WORKER_NEEDS)
    yield from run_worker("recover-poses", cli_args(images, out, cfg), interp.path)
    return out


def _import(context, out: Path) -> tuple[str, str | None]:
    """Import the capture; its message, and the check's warning (None when the poses look right)."""
    import json

    from ..capture.check import warning
    from ..scene.capture import import_capture

    meta = json.loads((out / "meta.json").read_text())
    made = import_capture(out, context.scene, collection_name=f"Capture {out.name}")
    n = len(made["cameras"])
    what = "video frames" if meta.get("video") else "photos"
    message = (f"Recovered {meta['registered']}/{meta['total']} {what} into {out}; {n} cameras and "
               f"{meta['num_points']} points in collection {made['collection'].name!r}")
    return message, warning(meta.get("pose_check") or {})


class MRVM_OT_recover_poses(ProgressOperator, bpy.types.Operator):
    """Recover the camera poses of a folder of photos (pycolmap) and add them as cameras with the photos as backgrounds and the sparse points as a mesh"""

    bl_idname = "mrvm.recover_poses"
    bl_label = "Recover Poses"
    bl_options = {"REGISTER", "UNDO"}

    props_attr = "mrvm_capture"
    job_name = "Pose recovery"
    panel_names = {"--force": "Overwrite", "--frames": "Video frames", "--camera-model": "Camera model",
                   "--matcher": "Matching", "--max-features": "Features", "--upsample-below": "Upsample below",
                   "--single-camera": "Shared camera", "--no-focal-from-views": "Focal from views",
                   "--pair": "Stereo pair", "--out": "Output", "--images": "Photos"}
    stops_softly = True  # a worker job: Esc lets it save its step in progress without blocking the UI
    cancel_hint = "finished stages are kept in the output's colmap/"
    timer_interval = 0.05

    @classmethod
    def blocked(cls, context) -> str:
        from ._modal import SAVE_FIRST, unsaved_relative

        p = context.scene.mrvm_capture
        if not p.images_dir.strip():
            return "Choose the Photos: a folder of photos or a video"
        if not p.output_dir.strip():
            return "Choose an Output folder"
        for name, value in (("Photos", p.images_dir), ("Output", p.output_dir)):
            if unsaved_relative(value):
                return SAVE_FIRST.format(what=name)
        return ""

    def start(self, context):
        images, out, cfg = config_from_props(context)
        return run_capture(context, images, out, cfg)

    def on_result(self, context, out: Path) -> str:
        message, warned = _import(context, out)
        if warned:  # in the Info log as a warning, and in the panel's status line
            self.report({"WARNING"}, warned)
            message += f"; warning: {warned}"
        return message


classes = (MRVM_OT_recover_poses,)
