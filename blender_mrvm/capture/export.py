"""A recovered capture in our dataset format (bpy-free).

::

    <out>/rgb/000000.png        the (undistorted) photos, 8-bit sRGB RGB (converted from their ICC profile)
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

import functools
import io
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


@functools.lru_cache(maxsize=16)
def _srgb_transform(icc: bytes, mode: str):
    """An lcms transform from the ICC profile ``icc`` of an image of ``mode`` (RGB, L or CMYK) to sRGB, or None when
    none is needed or none can be made: the profile is sRGB (it maps a grid of colours to themselves within one
    level: converting would only round), lcms cannot read it, or it does not fit the mode. Cached: a capture's
    photos share one profile."""
    from PIL import Image, ImageCms

    space = {"RGB": "RGB", "L": "GRAY", "CMYK": "CMYK"}[mode]
    try:
        src = ImageCms.ImageCmsProfile(io.BytesIO(icc))
        if src.profile.xcolor_space.strip() != space:
            return None
        t = ImageCms.buildTransform(src, ImageCms.createProfile("sRGB"), mode, "RGB",
                                    renderingIntent=1)  # ICC relative colorimetric, as viewers show photos
        if mode == "CMYK":
            return t
        levels = np.linspace(0, 255, 18).round().astype(np.uint8)
        grid = np.stack(np.meshgrid(levels, levels, levels), -1).reshape(-1, 1, 3) if mode == "RGB" \
            else levels.reshape(-1, 1)
        got = np.asarray(ImageCms.applyTransform(Image.fromarray(grid, mode), t)).astype(int)
        want = grid if mode == "RGB" else np.repeat(grid[..., None], 3, -1)
        return None if np.abs(got - want).max() <= 1 else t
    except (ImageCms.PyCMSError, OSError, ValueError):
        return None


def srgb_photo(im):
    """The photo converted to sRGB (a PIL RGB image) when it carries an ICC profile other than sRGB, else None.

    A photo's numbers are in its profile's colours: an iPhone's (and many Android phones') are Display P3, a
    camera's may be Adobe RGB. ``rgb/`` holds 8-bit sRGB without a profile, and everything downstream (the loaders,
    the models, Blender's image planes) reads the numbers as sRGB, so kept as they are they would be the wrong
    colours (P3 reds and greens duller). Converted with the relative colorimetric intent, as viewers show them. A
    profile lcms cannot read, or of another colour space than the image's, is ignored: the numbers are taken as
    sRGB, as a viewer that ignores it shows them. 16-bit and float images are not converted (lcms takes 8 bits)."""
    icc = im.info.get("icc_profile")
    if not icc:
        return None
    mode = {"RGB": "RGB", "RGBA": "RGB", "RGBX": "RGB", "RGBa": "RGB", "P": "RGB", "PA": "RGB", "L": "L", "LA": "L",
            "1": "L", "CMYK": "CMYK"}.get(im.mode)
    t = _srgb_transform(bytes(icc), mode) if mode else None
    if t is None:
        return None
    from PIL import ImageCms

    return ImageCms.applyTransform(im if im.mode == mode else im.convert(mode), t)


def photo_rgb8(im, where: Path | str | None = None) -> np.ndarray:
    """A photo's pixels as 8-bit sRGB RGB (what ``rgb/`` holds): converted from its ICC profile (:func:`srgb_photo`),
    else its colours as the loaders read them (``format.colour_pixels``, ``format.unit_pixels``: a palette's colours,
    CMYK as RGB, 16 bits over 257, a float image's [0, 1] times 255; Pillow's own conversion clips 16 bits at 255, a
    white image, and scaling a float image as 16 bits made it black), alpha dropped, grey repeated."""
    srgb = srgb_photo(im)
    if srgb is not None:
        return np.asarray(srgb)
    x = F.colour_pixels(im, where if where is not None else (getattr(im, "filename", "") or "photo"))
    if x.dtype != np.uint8:
        x = F.to_uint8(F.unit_pixels(x))
    if x.ndim == 2:
        x = x[..., None]
    if x.shape[-1] in (2, 4):
        x = x[..., :-1]
    return np.ascontiguousarray(np.repeat(x, 3, -1) if x.shape[-1] == 1 else x)


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
            if im.format == "PNG" and im.mode == "RGB" and F.png_bit_depth(v.image_path) == 8 \
                    and srgb_photo(im) is None:  # what rgb/ holds
                F.atomic_write(dst, lambda tmp, src=v.image_path: shutil.copyfile(src, tmp))
            else:  # (a 16-bit PNG opens as RGB too, but is not 8-bit on disk)
                F.write_png(dst, photo_rgb8(im, v.image_path), compress_level=1)  # photos: 5x faster, 20 % larger
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
