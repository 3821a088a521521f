"""Blender camera objects <-> the conventions of ``geometry/cameras.py`` (no axis logic here)."""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..geometry import cameras as C


def render_size(scene: bpy.types.Scene) -> tuple[int, int]:
    r = scene.render
    return (round(r.resolution_x * r.resolution_percentage / 100),
            round(r.resolution_y * r.resolution_percentage / 100))


def blender_camera_of(cam_obj: bpy.types.Object, scene: bpy.types.Scene) -> C.BlenderCamera:
    cam = cam_obj.data
    if cam.type != "PERSP":
        raise C.CameraConventionError(f"camera {cam_obj.name!r} is {cam.type.lower()}; only perspective cameras are supported")
    w, h = render_size(scene)
    return C.BlenderCamera(lens=cam.lens, sensor_width=cam.sensor_width, sensor_height=cam.sensor_height,
                           sensor_fit=cam.sensor_fit, shift_x=cam.shift_x, shift_y=cam.shift_y,
                           resolution_x=w, resolution_y=h,
                           pixel_aspect_x=scene.render.pixel_aspect_x, pixel_aspect_y=scene.render.pixel_aspect_y)


def read_camera(cam_obj: bpy.types.Object, scene: bpy.types.Scene) -> tuple[C.Intrinsics, np.ndarray]:
    """Intrinsics and OpenCV camera-to-world of a Blender camera object as ``scene`` renders it."""
    intr = C.intrinsics_from_blender(blender_camera_of(cam_obj, scene))
    try:
        c2w = C.opencv_from_blender(C.remove_scale(C.as_pose(cam_obj.matrix_world)))
    except C.CameraConventionError as e:  # (which of a scene's cameras)
        raise C.CameraConventionError(f"camera {cam_obj.name!r}: {e}") from None
    return intr, c2w


def apply_intrinsics(cam_obj: bpy.types.Object, scene: bpy.types.Scene, intr: C.Intrinsics) -> None:
    """Set the camera data and the scene's resolution / pixel aspect so Blender projects like ``intr``."""
    bc = C.blender_from_intrinsics(intr)
    cam = cam_obj.data
    cam.type = "PERSP"
    cam.sensor_fit = bc.sensor_fit
    cam.sensor_width = bc.sensor_width
    cam.sensor_height = bc.sensor_height
    cam.lens_unit = "MILLIMETERS"
    cam.lens = bc.lens
    cam.shift_x, cam.shift_y = bc.shift_x, bc.shift_y
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = bc.resolution_x, bc.resolution_y, 100
    r.pixel_aspect_x, r.pixel_aspect_y = bc.pixel_aspect_x, bc.pixel_aspect_y


def apply_pose(cam_obj: bpy.types.Object, c2w_opencv: np.ndarray) -> None:
    cam_obj.matrix_world = Matrix(C.blender_from_opencv(c2w_opencv).tolist())


def set_clip(cam_obj: bpy.types.Object, near: float, far: float) -> None:
    cam_obj.data.clip_start = max(near * 0.5, 1e-6)
    cam_obj.data.clip_end = far * 2.0


def new_camera(name: str, collection: bpy.types.Collection) -> bpy.types.Object:
    data = bpy.data.cameras.new(name)
    obj = bpy.data.objects.new(name, data)
    collection.objects.link(obj)
    return obj
