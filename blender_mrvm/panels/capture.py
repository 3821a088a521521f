"""The "Capture" section of the MRVM sidebar tab: Recover poses of a photo folder."""

from __future__ import annotations

import bpy

from .main import MRVMPanel, draw_job


class MRVM_PT_capture(MRVMPanel, bpy.types.Panel):
    bl_label = "Capture"
    bl_idname = "MRVM_PT_capture"
    bl_parent_id = "MRVM_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return hasattr(context.scene, "mrvm_capture")

    def draw(self, context):
        p = context.scene.mrvm_capture
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.enabled = not p.running
        col.prop(p, "images_dir")
        sub = col.column()
        sub.active = is_video_path(p.images_dir)
        sub.prop(p, "video_frames")
        col.prop(p, "output_dir")
        col.prop(p, "camera_model")
        col.prop(p, "matcher")
        col.prop(p, "max_features")
        col.prop(p, "upsample_below")
        col.prop(p, "single_camera")
        sub = col.column()
        sub.active = shares_camera(p)  # the focal estimate is for a shared camera only
        sub.prop(p, "estimate_focal")
        col.prop(p, "allow_pair")
        col.prop(p, "force")
        draw_job(layout, p, "mrvm.recover_poses", "CAMERA_DATA", "Recovering poses...")


def is_video_path(path: str) -> bool:
    from pathlib import Path

    from ..capture.video import VIDEO_EXTENSIONS

    return Path(bpy.path.abspath(path.strip())).suffix.lower() in VIDEO_EXTENSIONS if path.strip() else False


def shares_camera(p) -> bool:
    """Whether these settings give the photos one shared camera (``CaptureConfig.shared_camera``)."""
    from ..capture.config import CaptureConfig

    return CaptureConfig(camera_model=p.camera_model, single_camera=p.single_camera,
                         allow_pair=p.allow_pair).shared_camera


classes = (MRVM_PT_capture,)
