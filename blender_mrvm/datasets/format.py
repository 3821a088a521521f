"""Our on-disk dataset format: writers and a reader, bpy-free. See ``shared/DESIGN.md``.

::

    <root>/mrvm_dataset.json                 what produced the set (guards against mixing sets)
    <root>/<category>/<object_id>/
      rgb/000000.png        8-bit sRGB, composited on white (or RGBA, flag in meta.json; straight alpha, mixed
                            in linear light: :func:`composite_on_white`)
      depth/000000.exr      float32 planar z-depth, channel "Y"; 0 where the ray hits nothing
      normal/000000.exr     float32 world-space unit normals, channels "R", "G", "B"; 0 on background
      mask/000000.png       uint8 part ids, 0 = background (labels in meta.json)
      pose/000000.txt       4x4 camera-to-world, OpenCV axes, one line of 16 numbers (SRN)
      intrinsics.txt        SRN: "f cx cy 0", "0. 0. 0.", "1.", "H W"
      transforms.json       nerfstudio / NeRF format, OpenGL camera axes
      meta.json             category, source, normalization, bounds, labels, render settings
    <root>/splits/{train,val,test}.lst

A view counts as finished only when all five of its files exist; each file is written to a
temporary name and renamed, and the pose (written last) is the view's commit point.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import InputError
from ..geometry.cameras import Intrinsics, as_pose, opencv_from_opengl, opengl_from_opencv

FORMAT_VERSION = 1
ROOT_MANIFEST = "mrvm_dataset.json"
VIEW_DIRS = ("rgb", "depth", "normal", "mask", "pose")
VIEW_EXT = {"rgb": ".png", "depth": ".exr", "normal": ".exr", "mask": ".png", "pose": ".txt"}
SPLITS = ("train", "val", "test")


def view_name(index: int) -> str:
    return f"{index:06d}"


def view_paths(obj_dir: Path, index: int) -> dict[str, Path]:
    """The files of view ``index`` of an object folder."""
    n = view_name(index)
    return {k: Path(obj_dir) / k / f"{n}{VIEW_EXT[k]}" for k in VIEW_DIRS}


def view_complete(obj_dir: Path, index: int) -> bool:
    return all(p.is_file() and p.stat().st_size > 0 for p in view_paths(obj_dir, index).values())


# --------------------------------------------------------------------------------------------
# Atomic file writing
# --------------------------------------------------------------------------------------------

def _current_umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


def ordinary_permissions(path: Path) -> None:
    """Give a file, or a folder and everything in it, the permissions a plain create would (umask
    applied): tempfile's mkstemp/mkdtemp make them owner-only, which other users (a render farm, a
    shared checkpoint folder) then cannot read."""
    path = Path(path)
    items = [path, *path.rglob("*")] if path.is_dir() else [path]
    for p in items:
        os.chmod(p, (0o777 if p.is_dir() else 0o666) & ~_UMASK)


_WINDOWS = os.name == "nt"
_REPLACE_WAITS_S = (0.05, 0.1, 0.2, 0.4, 0.8)
"""Windows: the pauses between tries of :func:`replace_file` (about 1.5 s in all)."""


def replace_file(src, dst) -> None:
    """``os.replace(src, dst)``. Windows refuses it (PermissionError) while another program has ``dst`` open without
    sharing its deletion: a virus scanner, the search indexer or a sync client (OneDrive, Dropbox) for a moment just
    after the file was written, an image viewer for as long as it shows it. There it is tried again for about 1.5 s,
    then refused naming ``dst`` (not the temporary file) and what to do."""
    import time

    for wait in (*(_REPLACE_WAITS_S if _WINDOWS else ()), None):
        try:
            os.replace(src, dst)
            return
        except PermissionError as e:
            if not _WINDOWS:
                raise
            if wait is None:
                raise PermissionError(e.errno, "cannot replace a file another program has open (an image viewer, a "
                                      "sync client, a virus scanner): close it there and run again", str(dst)) from e
            time.sleep(wait)


def move_into(tmp: Path, out: Path) -> None:
    """Move a finished temporary folder into ``out`` (files replace files of the same name; ``out`` is
    created when missing) with the permissions of ordinary new files; ``tmp`` is removed."""
    import shutil

    tmp, out = Path(tmp), Path(out)
    ordinary_permissions(tmp)
    if not out.exists():
        out.parent.mkdir(parents=True, exist_ok=True)
        os.replace(tmp, out)
        return
    for p in sorted(tmp.rglob("*")):
        if p.is_file():
            dst = out / p.relative_to(tmp)
            dst.parent.mkdir(parents=True, exist_ok=True)
            replace_file(p, dst)
    shutil.rmtree(tmp, ignore_errors=True)


def disk_full_error(e: BaseException, path: Path) -> OSError | None:
    """An ``OSError(ENOSPC)`` for an error a writer raised as something else (torch.save's RuntimeError
    'unexpected pos' / 'iostream error', OpenEXR's 'No space left on device') when the disk of ``path`` is
    full, so the CLI reports it in one line (``cli.os_error_message``); None otherwise."""
    import errno

    full = "no space" in str(e).lower()
    if not full:
        try:
            p = Path(path)
            while not p.exists() and p.parent != p:
                p = p.parent
            full = os.statvfs(p).f_bavail == 0
        except (OSError, AttributeError):  # (no statvfs on Windows)
            full = False
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path)) if full else None


def atomic_write(path: Path, write: Callable[[str], None], suffix: str | None = None) -> None:
    """Write a file through ``write(tmp_path)`` then rename it into place (never half-written)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # the temporary name is bounded: a long but legal name must not overflow the file system's 255 bytes
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name[:40]}.", suffix=(suffix or path.suffix)[:16], dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        ordinary_permissions(Path(tmp))
        replace_file(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def remove_entries(folder: Path, names) -> None:
    """Remove the files and folders ``names`` of ``folder`` that exist (only those: what a command wrote)."""
    import shutil

    for name in names:
        p = Path(folder) / name
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        elif p.exists() or p.is_symlink():
            p.unlink()


def atomic_write_text(path: Path, text: str) -> None:
    def w(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    atomic_write(path, w)


def atomic_write_json(path: Path, obj: Any) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=False) + "\n")


# --------------------------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------------------------

def linear_to_srgb(x: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB transfer function (what Blender's 'Standard' view transform applies)."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4))


def to_uint8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.round(np.asarray(x) * 255.0), 0, 255).astype(np.uint8)


def unit_pixels(a: np.ndarray) -> np.ndarray:
    """uint8 / uint16 / float pixels (what :func:`colour_pixels` returns) as float32 in [0, 1]: 8 bits over 255,
    16 bits over 65535, a float image as it is (its range is [0, 1])."""
    a = np.asarray(a)
    if a.dtype == np.uint8:
        return a.astype(np.float32) / 255.0
    if a.dtype == np.uint16:
        return a.astype(np.float32) / 65535.0
    return a.astype(np.float32)


# Straight alpha, one convention (the dataset format's, Blender's): an RGBA image holds sRGB-encoded straight colour
# s and alpha a, and it shows over a background b as the mix in linear light, lin(s) a + lin(b) (1 - a). Blender
# mixes so (image planes, the compositor) and renders so (a view rendered on white is the --rgba one mixed so), not
# in the sRGB numbers (s a + b (1 - a): a soft edge over white comes out darker).

def _soft_alpha(colour: np.ndarray, alpha) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    c = np.asarray(colour, dtype=np.float64)
    a = np.broadcast_to(np.clip(np.asarray(alpha, dtype=np.float64), 0.0, 1.0), c.shape)
    return c, a, (a > 0.0) & (a < 1.0)


def composite_on_white(colour: np.ndarray, alpha) -> np.ndarray:
    """Straight sRGB colour in [0, 1] (..., C) with alpha (..., 1) over white, mixed in linear light; float64.

    Opaque pixels keep their colour exactly and empty ones are white; only the soft ones (0 < a < 1) are mixed."""
    c, a, soft = _soft_alpha(colour, alpha)
    out = np.where(a >= 1.0, c, 1.0)
    out[soft] = linear_to_srgb(srgb_to_linear(c[soft]) * a[soft] + (1.0 - a[soft]))
    return out


def uncomposite(colour: np.ndarray, alpha, background: float = 1.0) -> np.ndarray:
    """The straight sRGB colour whose linear-light mix with alpha over ``background`` (1 white, 0 black) is
    ``colour``, the sRGB colour a model rendered on that background: lin(s) = (lin(c) - b (1 - a)) / a, clipped to
    [0, 1] (a colour darker than the background allows at that alpha has no straight colour); float64.

    Where alpha is 0 the colour is kept as it is (the background); where it is 1 it is the colour."""
    c, a, soft = _soft_alpha(np.clip(np.asarray(colour, dtype=np.float64), 0.0, 1.0), alpha)
    out = c.copy()
    lin = (srgb_to_linear(c[soft]) - float(background) * (1.0 - a[soft])) / a[soft]
    out[soft] = linear_to_srgb(np.clip(lin, 0.0, 1.0))
    return out


def straight_rgba(colour: np.ndarray, alpha: np.ndarray, background: float = 1.0) -> np.ndarray:
    """uint8 RGBA (H, W, 4) of a model's colour on ``background`` (1 white, 0 black; (H, W, 3)) and its opacity
    (H, W), such that mixing the file over the background in linear light gives the colour back to within its 8-bit
    rounding: the straight colour is :func:`uncomposite` with the alpha as stored (8 bits).

    A model's colour and opacity need not agree: over white a colour darker than the white its opacity lets through
    (lin(c) < 1 - a: 5% of the shipped model's pixels, soft edges) has no straight colour, and clipping one showed
    those pixels up to 31/255 lighter than the model drew them. There the alpha is raised to the least that shows the
    colour (over black: lin(c) <= a), so the file over its background is the model's output."""
    c = np.clip(np.asarray(colour, dtype=np.float64), 0.0, 1.0)
    a = np.clip(np.asarray(alpha, dtype=np.float64), 0.0, 1.0)
    lin = srgb_to_linear(c)
    need = 1.0 - lin.min(-1) if background >= 0.5 else lin.max(-1)  # the least alpha that can show the colour
    a8 = np.where(need > a, np.ceil(np.clip(need, 0.0, 1.0) * 255.0 - 1e-9), np.round(a * 255.0))
    a8 = np.clip(a8, 0, 255).astype(np.uint8)
    straight = uncomposite(c, a8[..., None].astype(np.float64) / 255.0, background)
    return np.concatenate([to_uint8(straight), a8[..., None]], axis=-1)


def png_writer(arr: np.ndarray, compress_level: int = 6) -> Callable[[str], None]:
    """A function that writes a uint8 (H, W), (H, W, 3) or (H, W, 4) array as PNG to the path it is given
    (``compress_level``: zlib's, 0-9; 1 writes a 1080p photo 5x faster than the default 6, 20 % larger)."""
    from PIL import Image

    arr = np.ascontiguousarray(arr)
    if arr.dtype != np.uint8:
        raise TypeError(f"write_png expects uint8, got {arr.dtype}")
    return lambda tmp: Image.fromarray(arr).save(tmp, format="PNG", compress_level=compress_level)


def write_png(path: Path, arr: np.ndarray, compress_level: int = 6) -> None:
    """Write a uint8 (H, W), (H, W, 3) or (H, W, 4) array as PNG, atomically."""
    atomic_write(path, png_writer(arr, compress_level))


def read_png(path: Path, colour: bool = False) -> np.ndarray:
    """A PNG's (or JPEG's) pixels; InputError naming the file when it is missing, truncated or not an image.

    ``colour``: the colours the image shows (:func:`colour_pixels`: a palette image's colours, not its indices;
    CMYK as RGB), for photos and renders. Without it the stored values come back as they are: a mask's part ids
    (a palette mask gives its indices; ``models/sem2nerf/render.read_mask_png`` reads its grey entries)."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            return colour_pixels(im, path) if colour else np.asarray(im).copy()
    except FileNotFoundError:
        raise InputError(f"image {path} does not exist") from None
    except (OSError, ValueError, SyntaxError) as e:  # PIL: truncated, not a PNG, decompression bomb
        raise InputError(f"cannot read image {path}: {e}") from None


COLOUR_MODES_KEPT = ("RGB", "RGBA", "L", "LA")
"""PIL modes whose pixels :func:`colour_pixels` returns as they are (uint8)."""


def colour_pixels(im, where: Path | str) -> np.ndarray:
    """An open PIL image's colours as a uint8 (H, W), (H, W, 2), (H, W, 3) or (H, W, 4) array, uint16 for
    16-bit grey and for 16-bit RGB(A) PNGs (:func:`_png_16bit_colour`), float32 in [0, 1] for a float image: a palette image (P, PA: what pngquant and optipng write)
    decodes to RGB, or RGBA where its palette is transparent, never to its indices; CMYK, YCbCr, LAB and HSV to
    RGB; bilevel to grey. A 32-bit integer image (I) is 16-bit grey when its values fit, a float image (F)
    must hold values in [0, 1]: InputError otherwise."""
    mode = im.mode
    if mode in ("RGB", "RGBA"):
        wide = _png_16bit_colour(im)
        if wide is not None:
            return wide
    if mode in COLOUR_MODES_KEPT:
        return np.asarray(im).copy()
    if mode.startswith("I;16"):
        return np.asarray(im).astype(np.uint16)
    if mode == "I":
        a = np.asarray(im)
        if a.size and (a.min() < 0 or a.max() > 65535):
            raise InputError(f"image {where} is a 32-bit integer image with values outside 0..65535: not a colour "
                             "image this tool reads (save it as 8- or 16-bit PNG)")
        return a.astype(np.uint16)
    if mode == "F":
        a = np.asarray(im, dtype=np.float32)
        if a.size and (not np.isfinite(a).all() or a.min() < 0.0 or a.max() > 1.0):
            raise InputError(f"image {where} is a float image with values outside [0, 1]: not a colour image this "
                             "tool reads (save it as 8- or 16-bit PNG)")
        return a.copy()
    if mode == "P":
        transparent = "transparency" in im.info or getattr(im.palette, "mode", "RGB") == "RGBA"
        return np.asarray(im.convert("RGBA" if transparent else "RGB")).copy()
    if mode in ("PA", "RGBa", "RGBX"):
        return np.asarray(im.convert("RGBA" if mode != "RGBX" else "RGB")).copy()
    if mode in ("1", "La"):
        return np.asarray(im.convert("L" if mode == "1" else "LA")).copy()
    return np.asarray(im.convert("RGB")).copy()  # CMYK, YCbCr, LAB, HSV


PNG_16BIT_RAWMODES = {"RGB;16B": "RGB;16L", "RGBA;16B": "RGBA;16L"}


def _png_16bit_colour(im) -> np.ndarray | None:
    """A 16-bit RGB(A) PNG's colours at 16 bits (uint16), None for any other image.

    Pillow has no 16-bit RGB mode: it decodes such a PNG to 8 bits by dropping each sample's low byte (up to 1/255
    low, 0.5/255 on average, where 16-bit grey keeps its bits). Its unpacker for little-endian samples, given the
    PNG's big-endian ones, takes the low bytes instead; the PNG's filters act on bytes before unpacking, so the same
    decode gives them exactly. An image whose decode cannot be set up so (already loaded without a file name,
    another Pillow) is read at 8 bits as before."""
    if im.format != "PNG" or not getattr(im, "filename", ""):
        return None
    tiles = list(getattr(im, "tile", None) or [])
    if not tiles:  # loaded already: its header says whether it is 16-bit
        if png_bit_depth(Path(im.filename)) != 16:
            return None
    elif len(tiles) != 1 or tiles[0][3] not in PNG_16BIT_RAWMODES:
        return None
    from PIL import Image

    try:
        with Image.open(im.filename) as lo_im:  # the high bytes are ``im``'s own decode: only the low ones are read again
            (tile,) = lo_im.tile
            low = PNG_16BIT_RAWMODES.get(tile[3])
            if low is None:
                return None
            lo_im.tile = [tile._replace(args=low) if hasattr(tile, "_replace") else (*tile[:3], low)]
            lo = np.asarray(lo_im)
        hi = np.asarray(im)
    except (OSError, ValueError, TypeError):  # (a Pillow without that unpacker: 8 bits as before)
        return None
    if hi.shape != lo.shape or hi.dtype != np.uint8 or lo.dtype != np.uint8:
        return None
    return (hi.astype(np.uint16) << 8) | lo


def png_bit_depth(path: Path) -> int | None:
    """A PNG file's bit depth per channel from its header (IHDR), or None when it is not a PNG."""
    with open(path, "rb") as f:
        head = f.read(25)
    return head[24] if len(head) == 25 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR" else None


def exr_writer(channels: dict[str, np.ndarray]) -> Callable[[str], None]:
    """A function that writes float32 channels (each (H, W)) as a single-part scanline EXR,
    ZIP-compressed, to the path it is given."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    chans = {k: np.ascontiguousarray(v, dtype=np.float32) for k, v in channels.items()}

    def w(tmp: str) -> None:
        try:
            with OpenEXR.File(header, chans) as f:
                f.write(tmp)
        except RuntimeError as e:  # a full disk: "... No space left on device"
            raise disk_full_error(e, Path(tmp)) or e
    return w


def write_exr(path: Path, channels: dict[str, np.ndarray]) -> None:
    """Write float32 channels (each (H, W)) to a single-part scanline EXR, ZIP-compressed, atomically."""
    atomic_write(path, exr_writer(channels))


def read_exr(path: Path) -> dict[str, np.ndarray]:
    """Channels of the first part of an EXR file, by name, as float32 (H, W) arrays."""
    import OpenEXR

    try:
        f = OpenEXR.File(str(path), separate_channels=True)
    except Exception as e:  # OpenEXR raises plain exceptions for unreadable files
        raise InputError(f"cannot read EXR file {path}: {e}") from e
    return {k: np.asarray(v.pixels, dtype=np.float32) for k, v in f.channels().items()}


def read_exr_parts(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """All parts of a (multi-part) EXR: ``{part name: {channel name: (H, W) array}}``."""
    import OpenEXR

    f = OpenEXR.File(str(path), separate_channels=True)
    return {p.name(): {k: np.asarray(v.pixels) for k, v in p.channels.items()} for p in f.parts}


def write_depth(path: Path, depth: np.ndarray) -> None:
    write_exr(path, {"Y": depth})


def read_depth(path: Path) -> np.ndarray:
    ch = read_exr(path)
    for name in ("Y", "Z", "R", "V"):
        if name in ch:
            return ch[name]
    raise InputError(f"no depth channel (Y, Z, R or V) in {path}")


def write_normals(path: Path, normals: np.ndarray) -> None:
    write_exr(path, {"R": normals[..., 0], "G": normals[..., 1], "B": normals[..., 2]})


def read_normals(path: Path) -> np.ndarray:
    ch = read_exr(path)
    return np.stack([ch["R"], ch["G"], ch["B"]], axis=-1)


# --------------------------------------------------------------------------------------------
# Cameras: SRN and transforms.json
# --------------------------------------------------------------------------------------------

def format_pose(c2w_opencv: np.ndarray) -> str:
    return " ".join(f"{v:.9g}" for v in as_pose(c2w_opencv).reshape(-1)) + "\n"


def write_srn_pose(path: Path, c2w_opencv: np.ndarray) -> None:
    atomic_write_text(path, format_pose(c2w_opencv))


def read_srn_pose(path: Path) -> np.ndarray:
    """SRN pose file (one line of 16 numbers, or 4 lines of 4) -> OpenCV camera-to-world."""
    try:
        vals = np.array(Path(path).read_text().split(), dtype=np.float64)
    except (ValueError, UnicodeDecodeError):
        raise InputError(f"{path}: a pose file holds 16 numbers, found text that is not numbers") from None
    if vals.size != 16:
        raise InputError(f"{path}: a pose file holds 16 numbers, found {vals.size}")
    pose = vals.reshape(4, 4)
    check_pose(pose, path)
    return pose


def check_pose(c2w: np.ndarray, where: Path | str) -> None:
    """InputError unless ``c2w`` is a finite rigid camera-to-world pose (rotation part orthonormal with
    determinant +1 to 1e-3, last row 0 0 0 1): a NaN or singular pose gives NaN images downstream."""
    c2w = np.asarray(c2w, dtype=np.float64)
    if not np.all(np.isfinite(c2w)):
        raise InputError(f"{where}: the pose holds NaN or infinite numbers")
    r = c2w[:3, :3]
    if (np.abs(r.T @ r - np.eye(3)).max() > 1e-3 or abs(np.linalg.det(r) - 1.0) > 1e-3
            or np.abs(c2w[3] - [0, 0, 0, 1]).max() > 1e-6):
        raise InputError(f"{where}: not a camera pose (its rotation is singular or not orthonormal)")


def format_srn_intrinsics(intr: Intrinsics) -> str:
    # SRN stores one focal length; fx is authoritative (our renders use square pixels).
    return (f"{intr.fx:.9g} {intr.cx:.9g} {intr.cy:.9g} 0.\n0. 0. 0.\n1.\n{intr.height} {intr.width}\n")


def read_srn_intrinsics(path: Path) -> Intrinsics:
    """SRN ``intrinsics.txt``: 'f cx cy 0' / '0. 0. 0.' / '1.' / 'H W' (pixelNeRF's reading: the first line and the
    last). InputError for another layout (a one-line file read its 'f cx' as 'H W': a camera 6 to 9 pixels off; a
    3x3 or 4x4 K matrix divided by zero), a focal length that is not positive, or a size that is not: our own object
    folders, the SRN loader and Sem2NeRF's --intrinsics read it here."""
    layout = "'f cx cy 0' / '0. 0. 0.' / '1.' / 'H W', pixelNeRF's SRN layout"
    try:
        rows = [ln.split() for ln in Path(path).read_text().splitlines() if ln.strip()]
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not an SRN intrinsics file ({layout}): {e}") from None
    if len(rows) < 2 or len(rows[0]) < 3 or len(rows[-1]) != 2:
        kind = ("a K matrix" if len(rows) in (3, 4) and all(len(r) == len(rows) for r in rows) else
                f"{len(rows)} line(s), the last of {len(rows[-1]) if rows else 0} value(s)")
        raise InputError(f"{path}: not an SRN intrinsics file: it holds {kind}, not {layout}")
    try:
        f, cx, cy = map(float, rows[0][:3])
        h, w = (float(v) for v in rows[-1])
    except ValueError as e:
        raise InputError(f"{path}: not an SRN intrinsics file ({e})") from None
    if not (math.isfinite(f) and f > 0 and math.isfinite(cx) and math.isfinite(cy)):
        raise InputError(f"{path}: the focal length must be a positive number and cx, cy numbers, got "
                         f"f={f} cx={cx} cy={cy}")
    if not (math.isfinite(h) and math.isfinite(w) and int(w) >= 1 and int(h) >= 1):
        raise InputError(f"{path}: the image size on its last line ('H W') must be positive, got {rows[-1][0]} "
                         f"{rows[-1][1]}")
    return Intrinsics(f, f, cx, cy, int(w), int(h))


def transforms_dict(intr: Intrinsics, frames: list[dict[str, Any]], extra: dict[str, Any] | None = None) -> dict:
    """nerfstudio ``transforms.json`` content; each frame has ``file_path`` and ``c2w_opencv``."""
    out: dict[str, Any] = {
        "camera_model": "OPENCV",
        "fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx, "cy": intr.cy,
        "w": intr.width, "h": intr.height,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "camera_angle_x": intr.fov_x,
    }
    if extra:
        out.update(extra)
    fr = []
    for f in frames:
        f = dict(f)
        c2w = f.pop("c2w_opencv")
        f["transform_matrix"] = opengl_from_opencv(c2w).tolist()
        fr.append(f)
    out["frames"] = fr
    return out


@dataclass
class TransformsFrame:
    file_path: str
    c2w_opencv: np.ndarray
    intrinsics: Intrinsics
    extra: dict[str, Any] = field(default_factory=dict)


DISTORTION_KEYS = ("k1", "k2", "k3", "k4", "k5", "k6", "p1", "p2")
"""Lens distortion coefficients of a transforms.json (nerfstudio's OPENCV, instant-ngp's colmap2nerf): a non-zero one
is refused, as every reader here casts pinhole rays (the images read as pinhole ones bend every ray off the pixel
it lit); our own transforms.json writes them as 0."""
PINHOLE_MODELS = ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "FULL_OPENCV")
"""``camera_model`` values that are pinhole cameras once their distortion is 0 (nerfstudio's, COLMAP's names);
another (OPENCV_FISHEYE, EQUIRECTANGULAR) is refused whatever its coefficients."""

def json_number(g: dict, key: str, where: str, positive: bool = False) -> float:
    """``g[key]`` as a finite float (and > 0 if ``positive``); InputError naming it otherwise (a string, null or NaN
    went through float() into a traceback or NaN rays)."""
    v = g[key]
    try:
        x = float(v) if not isinstance(v, bool) else float("nan")
    except (TypeError, ValueError):
        x = float("nan")
    if not math.isfinite(x) or (positive and x <= 0):
        raise InputError(f"{where}: {key} must be a {'positive ' if positive else ''}number, got {v!r}")
    return x


def transforms_intrinsics(g: dict, w: int, h: int, where: str) -> tuple[Intrinsics, bool]:
    """(intrinsics, whether they were scaled) of a transforms.json frame (``g``: the file's keys updated by the
    frame's) whose image is ``w`` x ``h``, read as instant-ngp reads them: fx from ``fl_x`` or ``camera_angle_x``,
    fy from ``fl_y`` or ``camera_angle_y`` (either missing: the other, square pixels), ``cx``/``cy`` (default: the
    centre); in pixels of the file's ``w`` x ``h`` where given, scaled to the image when it was resized (same aspect).

    InputError for lens distortion or a camera that is not a pinhole (:data:`DISTORTION_KEYS`,
    :data:`PINHOLE_MODELS`), a missing or unusable focal length, or a size of another aspect ratio."""
    model = g.get("camera_model")
    if (model is not None and str(model).upper() not in PINHOLE_MODELS) or g.get("is_fisheye"):
        raise InputError(f"{where}: {'camera_model ' + str(model) if model is not None else 'is_fisheye'}: not a "
                         "pinhole camera (this tool casts pinhole rays); undistort the images to a pinhole camera "
                         "first")
    bent = [f"{k}={g[k]}" for k in DISTORTION_KEYS if k in g and json_number(g, k, where) != 0.0]
    if bent:
        raise InputError(f"{where}: lens distortion {', '.join(bent)}: this tool reads pinhole cameras and would "
                         "cast every ray off the pixel it lit; undistort the images first (COLMAP's image_undistorter, "
                         "or OpenCV's undistort) and write their pinhole camera with the coefficients 0")
    fw = json_number(g, "w", where, True) if "w" in g else None
    fh = json_number(g, "h", where, True) if "h" in g else None
    fw, fh = fw or (fh * w / h if fh else w), fh or (fw * h / w if fw else h)  # the size the numbers are for
    if abs(fw * h - fh * w) > max(fw, fh):
        raise InputError(f"{where}: its camera is for {fw:g}x{fh:g} images (w, h), the image is {w}x{h}: another "
                         "aspect ratio, not the same camera at another resolution")

    def focal(fl: str, angle: str, size: float) -> float | None:
        if fl in g:
            return json_number(g, fl, where, True)
        if angle in g:
            a = json_number(g, angle, where, True)
            if a >= math.pi:
                raise InputError(f"{where}: {angle} is a field of view in radians, below pi, got {a!r}")
            return 0.5 * size / math.tan(0.5 * a)
        return None

    fx, fy = focal("fl_x", "camera_angle_x", fw), focal("fl_y", "camera_angle_y", fh)
    if fx is None and fy is None:
        raise InputError(f"{where}: no focal length (camera_angle_x, NeRF-synthetic's, or fl_x, nerfstudio's)")
    fx, fy = fx or fy, fy or fx
    cx = json_number(g, "cx", where) if "cx" in g else fw / 2.0
    cy = json_number(g, "cy", where) if "cy" in g else fh / 2.0
    scaled = (fw, fh) != (w, h)
    sx, sy = w / fw, h / fh
    return Intrinsics(fx * sx, fy * sy, cx * sx, cy * sy, w, h), scaled


def read_transforms(path: Path) -> list[TransformsFrame]:
    """Read a nerfstudio / NeRF-synthetic ``transforms.json`` into OpenCV poses + intrinsics.

    Per-frame intrinsics override global ones (nerfstudio); the camera of each frame is read as the loaders read a
    transforms.json (:func:`transforms_intrinsics`: ``camera_angle_x``/``_y`` or ``fl_x``/``fl_y``, ``cx``/``cy``),
    at the frame's ``w`` x ``h``. InputError, one line, for what cannot be read: not JSON (a truncated file was a
    JSONDecodeError traceback from eval and the panel's capture import), a frame without ``file_path`` or a 4x4
    finite ``transform_matrix``, lens distortion or a camera that is not a pinhole (nerfstudio's OPENCV with
    non-zero coefficients: its cameras were placed as pinhole ones, every ray off the pixel it lit).
    """
    try:
        d = json.loads(Path(path).read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"{path} is not valid JSON ({e})") from None
    if not isinstance(d, dict) or not isinstance(d.get("frames", []), list):
        raise InputError(f"{path}: not a transforms.json (an object with a list of frames)")
    frames = []
    for i, fr in enumerate(d.get("frames", [])):
        where = f"{path} frame {i}"
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise InputError(f"{where}: a frame needs file_path and transform_matrix")
        g = {**d, **fr}
        if not ("w" in g and "h" in g):
            raise InputError(f"{where}: image size (w, h) missing")
        w, h = json_number(g, "w", where, True), json_number(g, "h", where, True)
        intr, _ = transforms_intrinsics(g, int(w), int(h), where)
        try:
            m = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            m = np.full(1, np.nan)
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise InputError(f"{where}: transform_matrix must be a 4x4 matrix of finite numbers")
        c2w = opencv_from_opengl(m)
        extra = {k: v for k, v in fr.items() if k not in ("file_path", "transform_matrix")}
        frames.append(TransformsFrame(str(fr["file_path"]), c2w, intr, extra))
    return frames


# --------------------------------------------------------------------------------------------
# Splits and the object reader
# --------------------------------------------------------------------------------------------

def write_split(root: Path, split: str, entries: list[str]) -> None:
    atomic_write_text(Path(root) / "splits" / f"{split}.lst", "".join(e + "\n" for e in entries))


def read_split(root: Path, split: str) -> list[str]:
    p = Path(root) / "splits" / f"{split}.lst"
    return [ln.strip() for ln in p.read_text().splitlines() if ln.strip()] if p.exists() else []


@dataclass
class ObjectViews:
    """One object folder of our format (a render or a recovered capture), read back."""

    path: Path
    meta: dict[str, Any]
    intrinsics: Intrinsics
    """The object's intrinsics (``intrinsics.txt``; the first view's when they differ per view)."""
    c2w_opencv: list[np.ndarray]
    indices: list[int]
    intrinsics_per_view: list[Intrinsics] = field(default_factory=list)
    """Intrinsics of each view (from ``transforms.json`` frames when they carry their own)."""

    def _path(self, kind: str, i: int) -> Path:
        return view_paths(self.path, self.indices[i])[kind]

    def has(self, kind: str) -> bool:
        """Whether every view has a ``kind`` file (captures have rgb and pose only)."""
        return all(view_paths(self.path, k)[kind].is_file() for k in self.indices)

    def rgb(self, i: int) -> np.ndarray:
        return read_png(self._path("rgb", i), colour=True)

    def depth(self, i: int) -> np.ndarray:
        return read_depth(self._path("depth", i))

    def normals(self, i: int) -> np.ndarray:
        return read_normals(self._path("normal", i))

    def mask(self, i: int) -> np.ndarray:
        return read_png(self._path("mask", i))


LAYOUT_NAMES = {"srn": "an SRN object", "nmr": "an NMR/DVR object", "nerf": "a NeRF-synthetic scene"}


def _other_layout(folder: Path) -> str:
    """The clause naming another tool's layout that ``folder`` holds ('' for none): synthesize given a NeRF-synthetic
    scene or an SRN object had said only "not an object folder (no meta.json)", as if the folder were broken."""
    from .loaders import detect_format  # (loaders imports this module)

    try:
        fmt = detect_format(folder)
    except InputError:
        return ""
    if fmt not in LAYOUT_NAMES or not folder.is_dir():
        return ""
    return (f": it holds {LAYOUT_NAMES[fmt]}, a layout eval and train read (eval --format {fmt}); the other commands "
            f"and the panel read the object folders render-dataset and recover-poses write")


def read_object(obj_dir: Path) -> ObjectViews:
    """Read an object folder written by ``render-dataset`` or ``recover-poses``.

    A view is read when its RGB image and pose exist (renders also have depth, normals and a mask;
    captures do not). Intrinsics come from ``transforms.json`` (per view when frames carry their
    own), else from the SRN ``intrinsics.txt``.
    """
    obj_dir = Path(obj_dir)
    meta_path = obj_dir / "meta.json"
    if not meta_path.is_file():
        raise InputError(f"{obj_dir} is not an object folder (no meta.json){_other_layout(obj_dir)}")
    try:
        meta = json.loads(meta_path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"{meta_path} is not valid JSON ({e})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{meta_path} is not a JSON object")
    tf = obj_dir / "transforms.json"
    by_view: dict[int, Intrinsics] = {}
    if tf.is_file():
        for fr in read_transforms(tf):
            stem = Path(fr.file_path).stem
            if stem.isdigit():
                by_view[int(stem)] = fr.intrinsics
    if (obj_dir / "intrinsics.txt").is_file():
        intr = read_srn_intrinsics(obj_dir / "intrinsics.txt")
        m = meta.get("intrinsics", {})
        if "fl_y" in m:  # SRN holds one focal length; meta.json keeps both
            intr = Intrinsics(m["fl_x"], m["fl_y"], m["cx"], m["cy"], m["w"], m["h"])
    elif by_view:
        intr = by_view[min(by_view)]
    else:
        raise InputError(f"{obj_dir}: no intrinsics.txt or transforms.json")
    idx = sorted(int(p.stem) for p in (obj_dir / "pose").glob("*.txt") if p.stem.isdigit())
    idx = [i for i in idx if view_paths(obj_dir, i)["rgb"].is_file()]
    lost = [i for i in idx if i not in by_view] if meta.get("per_view_intrinsics") else []
    if lost:
        # intrinsics.txt holds one camera: falling back to it would silently give most views a wrong field of
        # view (a GPU session's slimmed copy without transforms.json trained on such views, session 18)
        raise InputError(f"{obj_dir}: its views have their own intrinsics (meta.json per_view_intrinsics), kept in "
                         f"transforms.json, which {'lacks view ' + str(lost[0]) if tf.is_file() else 'is missing'}; "
                         "restore it from the rendered set or the capture (render-dataset and recover-poses write it)")
    poses = [read_srn_pose(view_paths(obj_dir, i)["pose"]) for i in idx]
    per_view = [by_view.get(i, intr) for i in idx]
    return ObjectViews(obj_dir, meta, intr, poses, idx, per_view)


# ---------------------------------------------------------------------------------------------------------------
# What makes two renders of an object one dataset (render-dataset's resume and overwrite checks, the loaders)
# ---------------------------------------------------------------------------------------------------------------

SETTINGS_ADDED_LATER = ("scene_cameras",)
"""Settings that newer versions record: a dataset rendered before one was kept (its settings lack it) still resumes."""


def same_json(a, b, rel_tol: float = 1e-6, abs_tol: float = 1e-5) -> bool:
    """Equal JSON values (dicts, lists, numbers), numbers to float rounding: settings (the panel's angles are float32:
    40 degrees reads 39.99999883637168; a scene camera's pose read again moves by ~1e-7) and records built again in
    another process (``scene.capture_scenes.same_scene``, with tighter tolerances)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_json(a[k], b[k], rel_tol, abs_tol) for k in a)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(same_json(x, y, rel_tol, abs_tol) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return (isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool)
                and not isinstance(b, bool) and math.isclose(a, b, rel_tol=rel_tol, abs_tol=abs_tol))
    return a == b



def differing_settings(old: dict, new: dict) -> list[str]:
    """The keys whose values differ between a dataset's recorded settings and this run's (:func:`settings_match`)."""
    return [k for k in sorted(set(old) | set(new))
            if not (k in SETTINGS_ADDED_LATER and k not in old) and not same_json(old.get(k), new.get(k))]


def settings_match(old, new: dict) -> bool:
    """Whether views rendered with the recorded settings ``old`` belong with this run's ``new`` ones."""
    return isinstance(old, dict) and not differing_settings(old, new)


# ---------------------------------------------------------------------------------------------
# make-shapenet's plan (the objects every shard of a folder renders, per split)
# ---------------------------------------------------------------------------------------------

PLAN_FILE = "plan.json"
"""In ``<root>/splits/``: the plan every make-shapenet shard of the folder renders (``commands/make_shapenet.py``)."""


def plan_path(root) -> Path:
    return Path(root) / "splits" / PLAN_FILE


def read_plan(root) -> dict | None:
    """The plan recorded in a dataset root (None: none recorded, a dataset made before plans were; {}: unreadable)."""
    path = plan_path(root)
    try:
        rec = json.loads(path.read_text())
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return {}
    return rec if isinstance(rec, dict) else {}


def planned_but_unlisted(root, split: str) -> tuple[list[str], int] | None:
    """(objects the recorded plan puts in ``split`` that its list lacks, the plan's count there); None: no plan.

    For readers of the set (train, eval): a list that holds part of its plan is a set whose other shards have not
    finished (bpy-free)."""
    rec = read_plan(root)
    if not rec or not isinstance(rec.get("objects"), dict):
        return None
    planned = list(rec["objects"].get(split) or [])
    lst = Path(root) / "splits" / f"{split}.lst"
    listed = set(lst.read_text().split()) if lst.exists() else set()
    return [k for k in planned if k not in listed], len(planned)
