"""A recovered capture in our dataset format (bpy-free).

::

    <out>/rgb/000000.png        the (undistorted) photos, 8-bit sRGB RGB
    <out>/pose/000000.txt       OpenCV camera-to-world (SRN), in the normalized world
    <out>/intrinsics.txt        SRN intrinsics of the first view (fx; all views share a size)
    <out>/transforms.json       nerfstudio format; each frame names its photo in ``original_name``
                                and carries its own fl_x/fl_y/cx/cy
    <out>/meta.json             kind "capture", registered/total, unregistered photos, timings,
                                camera model, matcher, normalization, intrinsics; colmap_model (the
                                kept model) and colmap_export_model (the one matching rgb/: the
                                undistorted model when the camera model has distortion)
    <out>/points.ply            sparse points (normalized world), binary PLY, xyz float32 + rgb uchar
    <out>/colmap/               database.db, sparse/<k>/ models, undistorted/ (kept for inspection)

A capture has no depth, normal or mask images: it is reference views, not a rendered training set.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..datasets import format as F
from ..errors import InputError
from ..geometry.cameras import Intrinsics

RUN_MARKER = ".recover-poses"
"""The file ``recover-poses`` writes first into its output folder: what tells a run of its own, stopped before
``meta.json`` (written last), from a folder of the user's that only holds files of the same names."""
OUTPUT_ENTRIES = ("rgb", "pose", "intrinsics.txt", "transforms.json", "meta.json", "points.ply", "colmap", "frames",
                  RUN_MARKER)


def open_photo(path: Path):
    """``PIL.Image.open`` for the user's own photos, at any size: Pillow refuses images over 179 megapixels as a
    possible 'decompression bomb', and a 200 MP phone photo is one (pycolmap reads it at ``max_image_size``)."""
    from PIL import Image

    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None
    try:
        return Image.open(path)
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def photo_rgb8(im) -> np.ndarray:
    """A photo's pixels as 8-bit RGB (what ``rgb/`` holds): 16- and 32-bit greyscale scaled down from the 16-bit
    range (Pillow's own conversion clips them at 255: a white image), the rest as Pillow converts them."""
    if im.mode in ("I", "I;16", "I;16L", "I;16B", "I;16N", "F"):
        grey = np.clip(np.asarray(im, dtype=np.float64) / 257.0, 0, 255).round().astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)
    return np.asarray(im.convert("RGB"))


def png_bit_depth(path: Path) -> int | None:
    """A PNG file's bit depth per channel from its header (IHDR), or None when it is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(25)
    return head[24] if len(head) == 25 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" else None


@dataclass
class CaptureView:
    """One registered photo, ready to write."""

    original_name: str
    """File name of the photo in the input folder."""
    image_path: Path
    """The image to copy into rgb/ (undistorted when the camera model had distortion)."""
    intrinsics: Intrinsics
    """Pinhole intrinsics of ``image_path``."""
    c2w_opencv: np.ndarray
    """OpenCV camera-to-world in the output (normalized) world."""


def write_points_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """Binary little-endian PLY with float x, y, z and uchar red, green, blue."""
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    rgb = np.asarray(rgb, dtype=np.uint8).reshape(-1, 3)
    rec = np.empty(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                    ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    rec["x"], rec["y"], rec["z"] = xyz.T
    rec["red"], rec["green"], rec["blue"] = rgb.T
    header = ("ply\nformat binary_little_endian 1.0\ncomment blender_mrvm sparse capture points\n"
              f"element vertex {len(xyz)}\nproperty float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n").encode("ascii")

    def w(tmp: str) -> None:
        with open(tmp, "wb") as f:
            f.write(header)
            f.write(rec.tobytes())
    F.atomic_write(path, w)


def read_points_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Read a PLY written by :func:`write_points_ply` -> (xyz float64 (N, 3), rgb uint8 (N, 3))."""
    data = Path(path).read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply\n") or end < 0:
        raise InputError(f"{path} is not a PLY file")
    header = data[:end].decode("ascii").splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise InputError(f"{path}: only binary little-endian PLY is read here")
    n = next(int(ln.split()[2]) for ln in header if ln.startswith("element vertex"))
    rec = np.frombuffer(data[end + len(b"end_header\n"):], count=n,
                        dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    xyz = np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float64)
    rgb = np.stack([rec["red"], rec["green"], rec["blue"]], axis=1)
    return xyz, rgb


def write_capture(out_dir: Path, views: list[CaptureView], xyz: np.ndarray, rgb: np.ndarray,
                  meta: dict[str, Any]) -> None:
    """Write the capture folder (images, poses, intrinsics, transforms.json, points, meta last)."""
    out_dir = Path(out_dir)
    frames = []
    for i, v in enumerate(views):
        name = F.view_name(i)
        dst = out_dir / "rgb" / f"{name}.png"
        with open_photo(v.image_path) as im:
            if im.size != (v.intrinsics.width, v.intrinsics.height):
                raise InputError(f"{v.image_path}: image is {im.size[0]}x{im.size[1]}, its camera says "
                                 f"{v.intrinsics.width}x{v.intrinsics.height}")
            if im.format == "PNG" and im.mode == "RGB" and png_bit_depth(v.image_path) == 8:  # what rgb/ holds
                F.atomic_write(dst, lambda tmp, src=v.image_path: shutil.copyfile(src, tmp))
            else:  # (a 16-bit PNG opens as RGB too, but is not 8-bit on disk)
                F.write_png(dst, photo_rgb8(im), compress_level=1)  # photos: 5x faster, 20 % larger
        F.write_srn_pose(out_dir / "pose" / f"{name}.txt", v.c2w_opencv)
        k = v.intrinsics
        frames.append({"file_path": f"rgb/{name}.png", "c2w_opencv": v.c2w_opencv, "original_name": v.original_name,
                       "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height})
    first = views[0].intrinsics
    F.atomic_write_text(out_dir / "intrinsics.txt", F.format_srn_intrinsics(first))
    F.atomic_write_json(out_dir / "transforms.json", F.transforms_dict(first, frames, {"mrvm_kind": "capture"}))
    write_points_ply(out_dir / "points.ply", xyz, rgb)
    meta = dict(meta)
    meta.setdefault("intrinsics", {"fl_x": first.fx, "fl_y": first.fy, "cx": first.cx, "cy": first.cy,
                                   "w": first.width, "h": first.height})
    F.atomic_write_json(out_dir / "meta.json", meta)


@dataclass
class CaptureRead:
    """A capture folder read back."""

    meta: dict[str, Any]
    frames: list[F.TransformsFrame] = field(default_factory=list)
    xyz: np.ndarray | None = None
    rgb: np.ndarray | None = None


def read_capture(out_dir: Path) -> CaptureRead:
    out_dir = Path(out_dir)
    if not (out_dir / "transforms.json").is_file():
        raise InputError(f"{out_dir} is not a recovered capture (no transforms.json)")
    import json

    meta = json.loads((out_dir / "meta.json").read_text()) if (out_dir / "meta.json").is_file() else {}
    frames = F.read_transforms(out_dir / "transforms.json")
    xyz = rgb = None
    if (out_dir / "points.ply").is_file():
        xyz, rgb = read_points_ply(out_dir / "points.ply")
    return CaptureRead(meta, frames, xyz, rgb)
