"""Sem2NeRF in Blender: the main-thread half of the Sem2NeRF operator (the model runs in the worker).

- :func:`image_rgba`: a ``bpy.types.Image`` (a mask the user painted in the image editor, or loaded)
  as an 8-bit RGBA array, top row first, in the image's stored colours; :func:`new_mask_image` the
  other way (a dataset mask in label colours, to paint on);
- :func:`mask_camera`: a scene camera as the mask's viewpoint (intrinsics at the mask's size, OpenCV
  camera-to-world), through ``scene/camera.read_camera`` and ``geometry/cameras.py``;
- :func:`orbit_targets` / :func:`camera_targets`: the views to generate (an orbit of new cameras, the
  same orbit as ``sem2nerf render``, or chosen scene cameras), as ``datasets.novel_views.Target``;
- :func:`set_show_semantic`: switch every Sem2NeRF plane between its image and its semantic map.

The checks of the mask itself (size, labels, empty) are the CLI's (``models/sem2nerf/render.py``).
"""

from __future__ import annotations

import bpy
import numpy as np

from ..datasets.novel_views import Target
from ..errors import CameraConventionError, InputError
from . import camera as scam
from . import image_planes as IP

COLLECTION = "MRVM Sem2NeRF"
"""Collection of the generated cameras and the image planes."""
CAMERA_PREFIX = "MRVM Sem2NeRF"
"""Name prefix of generated orbit cameras."""


def _srgb_from_linear(x: np.ndarray) -> np.ndarray:
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(np.clip(x, 0.0031308, None), 1 / 2.4) - 0.055)


def image_rgba(img: bpy.types.Image | None) -> np.ndarray:
    """(H, W, 4) uint8, top row first: byte images as stored, float images converted to sRGB unless
    they hold non-colour data. InputError for no image or one without pixels."""
    if img is None:
        raise InputError("choose the mask image (paint one in the image editor, or open a mask PNG)")
    w, h = (int(v) for v in img.size)
    ch = int(img.channels)
    if w * h == 0 or ch == 0:
        raise InputError(f"image {img.name!r} has no pixels (is its file missing?)")
    px = np.empty(w * h * ch, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, ch)[::-1]
    if ch == 1:
        px = np.repeat(px, 3, -1)
    elif ch == 2:
        px = np.concatenate([np.repeat(px[..., :1], 3, -1), px[..., 1:]], -1)
    if ch in (1, 3):
        px = np.concatenate([px, np.ones((h, w, 1), np.float32)], -1)
    if img.is_float and img.colorspace_settings.name not in ("Non-Color", "Raw", "Generic Data"):
        px[..., :3] = _srgb_from_linear(np.clip(px[..., :3], 0.0, 1.0))
    return (np.clip(px, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def new_mask_image(name: str, rgb: np.ndarray) -> bpy.types.Image:
    """A new 8-bit Blender image holding ``rgb`` ((H, W, 3) uint8, top row first), packed so it is
    saved with the .blend: a mask to paint on."""
    h, w = rgb.shape[:2]
    img = bpy.data.images.new(f"MRVM mask {name}", w, h, alpha=True)
    px = np.concatenate([rgb.astype(np.float32) / 255.0, np.ones((h, w, 1), np.float32)], -1)
    img.pixels.foreach_set(px[::-1].ravel())
    img.pack()
    return img


def mask_camera(scene: bpy.types.Scene, cam: bpy.types.Object | None, size: int):
    """(intrinsics at size x size, OpenCV camera-to-world) of the camera the mask is seen from."""
    from ..models.sem2nerf.render import check_pose

    if cam is None:
        raise InputError("choose the camera the mask is seen from (the mask's viewpoint)")
    if cam.type != "CAMERA":
        raise InputError(f"{cam.name!r} is not a camera; the mask's viewpoint must be a camera")
    sv = np.linalg.svd(np.array(cam.matrix_world, np.float64)[:3, :3], compute_uv=False)
    if not np.isfinite(sv).all() or sv.min() <= 1e-9 * max(float(sv.max()), 1e-30):
        raise InputError(f"camera {cam.name!r} has no usable pose: its transform is singular (a zero scale)")
    try:
        intr, c2w = scam.read_camera(cam, scene)
    except (CameraConventionError, ValueError, ZeroDivisionError) as e:
        raise InputError(f"camera {cam.name!r} has no usable pose: {e}") from None
    check_square_frame(scene, f"camera {cam.name!r}")
    c2w = check_pose(c2w, f"camera {cam.name!r}'s pose")
    return intr.resized(size, size), c2w


def check_square_frame(scene: bpy.types.Scene, what: str) -> None:
    """InputError unless the scene renders square pixels in a square frame (a Sem2NeRF mask is square)."""
    w, h = scam.render_size(scene)
    r = scene.render
    if w != h or abs(r.pixel_aspect_x - r.pixel_aspect_y) > 1e-6:
        raise InputError(f"{what}: the scene frames {w}x{h} (pixel aspect {r.pixel_aspect_x:g}:{r.pixel_aspect_y:g}); "
                         "a Sem2NeRF mask is square: set a square resolution with square pixels")


def orbit_targets(scene: bpy.types.Scene, intr, c2w: np.ndarray, count: int) -> list[Target]:
    """``count`` new cameras on ``sem2nerf render``'s orbit about world z through the mask's camera."""
    from ..models.sem2nerf.render import orbit_poses
    from .novel_views import fresh_names

    if count < 1:
        raise InputError("the orbit needs at least one camera")
    check_square_frame(scene, "orbit cameras")
    names = fresh_names(CAMERA_PREFIX, count)
    return [Target(n, intr, p, generated=True) for n, p in zip(names, orbit_poses(c2w, count))]


def camera_targets(scene: bpy.types.Scene, objects, size: int) -> list[Target]:
    """Targets for the camera objects among ``objects``, rendered with ``size`` px on the longer side."""
    from .novel_views import selected_targets

    out = []
    for t in selected_targets(scene, objects):
        k = t.intrinsics
        s = size / max(k.width, k.height)
        out.append(Target(t.name, k.resized(max(1, round(k.width * s)), max(1, round(k.height * s))), t.c2w_opencv))
    return out


def sem2nerf_planes() -> list[bpy.types.Object]:
    """Every image plane in the Sem2NeRF collection that carries a semantic map."""
    coll = bpy.data.collections.get(COLLECTION)
    return [o for o in (coll.all_objects if coll else ()) if IP.SHOW_SEMANTIC in o]


def set_show_semantic(show: bool) -> int:
    """Show the semantic map (or the image) on every Sem2NeRF plane; returns how many planes."""
    planes = sem2nerf_planes()
    for o in planes:
        o[IP.SHOW_SEMANTIC] = int(bool(show))
        o.update_tag()
    return len(planes)
