"""Multi-view object loaders: our format, SRN (pixelNeRF), NMR/DVR and NeRF-synthetic.

Every loader returns :class:`ObjectScene` objects with OpenCV camera-to-world poses (checked rigid:
``format.check_pose``) and :class:`~..geometry.cameras.Intrinsics` (conversions go through
``geometry/cameras.py``), images as float32 RGB in [0, 1] composited on white (straight alpha mixed in linear light,
as Blender does: :func:`to_float_rgb`; palette, CMYK and 16-bit files decoded to their colours:
``format.read_png(colour=True)``), object masks where the format has them,
and an object box (from ``meta.json`` where the format has one, else the format's documented bounds).
Image suffixes match in any case (.PNG, .JPG). bpy-free.

Layouts read::

    ours     <root>/<category>/<object>/{rgb,pose}/NNNNNN.*, intrinsics.txt, meta.json (bbox)
    srn      <root>/<cat>_<split>/<object>/{rgb/*.png, pose/*.txt, intrinsics.txt}   (pixelNeRF's SRN layout;
             also <root>/<split>/<object>, a folder of objects, or one object)
    nmr      <root>/<category>/<object>/{image/*.png|jpg, mask/*.png, cameras.npz},
             <root>/<category>/softras_<split>.lst (pixelNeRF's NMR benchmark; preferred) or <split>.lst (DVR's)
    nerf     <root>/<scene>/transforms_{train,val,test}.json + image files (RGBA: alpha is the mask); nerfstudio's
             and instant-ngp's keys too (per-frame fl_x fl_y cx cy, w h of resized images, camera_angle_y,
             instant-ngp's scale and offset, nerfstudio's unnormalised poses); lens distortion, fisheyes and EXR
             images are refused by name

A camera that sees none of its format's box (SRN, NeRF-synthetic) is refused: poses of the other axis convention
turn every camera away from the object and loaded silently.
"""

from __future__ import annotations

import json
import math
import sys
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..geometry import cameras
from . import format as F
from .format import DISTORTION_KEYS, PINHOLE_MODELS, transforms_intrinsics  # noqa: F401  (read here too)
from .format import json_number as _number

SRN_BOX = 0.5
"""SRN (ShapeNet, pixelNeRF): objects lie within a sphere of radius ~0.5 around the origin (near 0.8, far 1.8 at distance 1.3)."""
NMR_BOX = 0.5
"""NMR/DVR: ShapeNet objects normalised into the unit cube [-0.5, 0.5]^3."""
NERF_SYNTHETIC_BOX = 1.5
"""NeRF-synthetic scenes fit in [-1.5, 1.5]^3 (near 2, far 6 at distance 4)."""
FORMATS = ("ours", "srn", "nmr", "nerf")


@dataclass
class ObjectScene:
    """One object seen from several posed views."""

    name: str
    """Object id."""
    category: str
    """Category (synset or name; '' when unknown)."""
    images: np.ndarray
    """(N, H, W, 3) float32 RGB in [0, 1], composited on white."""
    c2w: np.ndarray
    """(N, 4, 4) float64 camera-to-world, OpenCV axes."""
    intrinsics: list
    """N :class:`Intrinsics`, one per view."""
    bbox: tuple
    """(min xyz, max xyz) float64 of the object."""
    view_ids: list = field(default_factory=list)
    """Index of each view in its source (file number)."""
    masks: np.ndarray | None = None
    """(N, H, W) bool object masks (True = object) when the source has them for every view (our
    renders' mask/ part ids > 0), else None."""
    background: str = "white"
    """What the views show behind the object: "white" (object sets: composited on white, ``bbox`` is the
    object's box) or "scene" (capture-like renders, meta.json ``background``: a whole room, ``bbox`` is the
    room's box, masks cover every surface, sky excepted)."""
    depths: np.ndarray | None = None
    """(N, H, W) float32 planar z-depth in world units (0 where the pixel sees nothing) when asked for
    (``load_dataset(..., depth=True)``) and the source has it for every view (our renders' depth/ EXRs),
    else None. Training reads it for ``train.depth_weight``; nothing else needs it."""
    split_list: str | None = None
    """The split list naming this object ('<category>/softras_test.lst' for NMR/DVR), where the format has one."""

    def __len__(self) -> int:
        return self.images.shape[0]

    def foreground_boxes(self, thresh: float = 0.99) -> np.ndarray:
        """(N, 4) [x0, y0, x1, y1) pixel boxes of the non-white pixels (whole image when none, and
        always for a scene background, whose bright walls are not empty space)."""
        out = np.zeros((len(self), 4), np.int64)
        for i, im in enumerate(self.images):
            if self.background == "scene":
                out[i] = (0, 0, im.shape[1], im.shape[0])
                continue
            fg = (im < thresh).any(-1)
            ys, xs = np.nonzero(fg)
            h, w = fg.shape
            out[i] = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) if xs.size else (0, 0, w, h)
        return out


def to_float_rgb(arr: np.ndarray, linear_alpha: bool = True) -> np.ndarray:
    """uint8 / uint16 / float image (H, W[, C]) -> float32 RGB in [0, 1], alpha composited on white.

    Straight alpha is mixed in linear light (``format.composite_on_white``), as Blender renders it on white and
    shows it over white: an ``--rgba`` dataset loads as the dataset rendered on white. ``linear_alpha=False`` mixes
    the sRGB numbers (c a + 1 - a), the NeRF-synthetic benchmark's own protocol (NeRF, nerfstudio), kept for its
    scenes so that scores stay comparable with published ones."""
    x = F.unit_pixels(arr)
    if x.ndim == 2:
        x = x[..., None]
    if x.shape[-1] in (2, 4):  # grey + alpha, RGBA
        c, alpha = x[..., :-1], x[..., -1:]
        x = F.composite_on_white(c, alpha) if linear_alpha else c * alpha + (1.0 - alpha)
    if x.shape[-1] == 1:
        x = np.repeat(x, 3, -1)
    return np.clip(x[..., :3], 0.0, 1.0).astype(np.float32)


def read_colour(path: Path) -> np.ndarray:
    """An image file's colours as float32 RGB in [0, 1] on white (palette, CMYK, 16-bit: their colours)."""
    return to_float_rgb(F.read_png(path, colour=True))


def read_binary_mask(path: Path) -> np.ndarray:
    """(H, W) bool object mask of a mask image (DVR/NMR ``mask/*.png``): object where it is brighter than one half
    (> 127 of 255), whatever its mode (grey, palette, RGB: the brightest colour channel)."""
    x = F.unit_pixels(F.read_png(path, colour=True))
    if x.ndim == 3:
        x = x[..., :3].max(-1) if x.shape[-1] >= 3 else x[..., 0]
    return x > 0.5


IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def _files(folder: Path, suffixes: Sequence[str]) -> list[Path]:
    """The files of ``folder`` whose suffix is one of ``suffixes`` in any case (.png, .PNG), sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in suffixes and p.is_file())


def _note(msg: str) -> None:
    print(f"note: {msg}", file=sys.stderr)


class _Stack:
    """The (N, H, W, 3) float32 images of an object, filled view by view as they are read: each view is copied into
    one array allocated at the first (``N`` views), so an object's pixels are held once, plus the view being read.
    ``np.stack(list).astype(np.float32)`` held them three times at its peak (the list, the stack and its copy): 24
    views of 4000 px (4.6 GB as float) ran out of memory in ``train``. The values are those of the stack (float32
    throughout). A view of another size is not kept; :meth:`result` then names every size, as before."""

    def __init__(self, n: int, where: Path):
        self.n, self.where, self.k = int(n), where, 0
        self.out: np.ndarray | None = None
        self.shapes: set = set()

    def add(self, image: np.ndarray) -> None:
        self.shapes.add(image.shape)
        if self.out is None:
            self.out = np.empty((self.n, *image.shape), np.float32)
        if len(self.shapes) == 1:
            self.out[self.k] = image
        self.k += 1

    def result(self) -> np.ndarray:
        if len(self.shapes) > 1:
            raise InputError(f"{self.where}: views have different image sizes {sorted(self.shapes)}")
        if self.out is None or self.k != self.n:
            raise ValueError(f"{self.where}: {self.k} views read of {self.n}")
        return self.out


def _stack(images, where: Path, n: int | None = None) -> np.ndarray:
    """(N, H, W, 3) float32 of ``images`` (a sequence, or an iterator of ``n`` views read as it is consumed: only
    one view is held outside the result at a time; :class:`_Stack`)."""
    st = _Stack(len(images) if n is None else n, where)
    for im in images:
        st.add(im)
    return st.result()


# --------------------------------------------------------------------------------------------- ours

def load_ours(obj_dir: Path, depth: bool = False) -> ObjectScene:
    """An object folder of our format; ``depth``: read the depth/ EXRs too (:attr:`ObjectScene.depths`)."""
    ov = F.read_object(Path(obj_dir))
    if not ov.indices:
        raise InputError(f"{obj_dir}: no finished views")
    meta = ov.meta
    if "bbox" in meta:
        b = meta["bbox"]
        lo, hi = (b["min"], b["max"]) if isinstance(b, dict) else (b[0], b[1])
    elif "bound_radius" in meta:
        r = float(meta["bound_radius"])
        lo, hi = [-r] * 3, [r] * 3
    else:
        raise InputError(f"{obj_dir}/meta.json has no 'bbox' (object bounds)")
    images = _stack((to_float_rgb(ov.rgb(i)) for i in range(len(ov.indices))), obj_dir, len(ov.indices))
    h, w = images.shape[1:3]
    intrs = list(getattr(ov, "intrinsics_per_view", None) or []) or [ov.intrinsics] * len(ov.indices)
    for intr in intrs:
        if (intr.width, intr.height) != (w, h):
            raise InputError(f"{obj_dir}: intrinsics say {intr.width}x{intr.height}, images are {w}x{h}")
    masks = None
    if all(F.view_paths(obj_dir, v)["mask"].is_file() for v in ov.indices):
        masks = np.stack([np.asarray(ov.mask(i)) > 0 for i in range(len(ov.indices))])
        if masks.shape != images.shape[:3]:
            raise InputError(f"{obj_dir}: masks are {masks.shape[2]}x{masks.shape[1]}, images {w}x{h}")
    depths = None
    if depth and all(F.view_paths(obj_dir, v)["depth"].is_file() for v in ov.indices):
        depths = np.stack([np.asarray(ov.depth(i), np.float32) for i in range(len(ov.indices))])
        if depths.shape != images.shape[:3]:
            raise InputError(f"{obj_dir}: depth maps are {depths.shape[2]}x{depths.shape[1]}, images {w}x{h}")
        if not np.isfinite(depths).all() or (depths < 0).any():
            raise InputError(f"{obj_dir}: a depth map holds negative or non-finite values (0 marks no surface)")
    return ObjectScene(str(meta.get("object_id", Path(obj_dir).name)), str(meta.get("category", Path(obj_dir).parent.name)),
                       images, np.stack(ov.c2w_opencv), intrs,
                       (np.asarray(lo, np.float64), np.asarray(hi, np.float64)), list(ov.indices), masks,
                       "scene" if meta.get("background") == "scene" else "white", depths)


def list_ours(root: Path, split: str | None = None) -> list[Path]:
    """Object folders of our format (those in ``splits/<split>.lst`` if given; entries 'cat/id' or 'id')."""
    root = Path(root)
    dirs = sorted(p.parent for p in root.glob("*/*/meta.json"))
    if split:
        entries = F.read_split(root, split)
        if not entries:
            raise InputError(f"{root}/splits/{split}.lst is missing or empty")
        keep = set(entries)
        dirs = [d for d in dirs if f"{d.parent.name}/{d.name}" in keep or d.name in keep]
    return dirs


# --------------------------------------------------------------------------------------------- SRN

def srn_category(obj_dir: Path) -> str:
    """The category of an SRN object folder: 'cars' of cars_test/<object> (pixelNeRF's <cat>_<split>), the set's
    folder name of <set>/test/<object>, else the parent folder's name."""
    obj_dir = Path(obj_dir).absolute()
    name = obj_dir.parent.name
    base, _, split = name.rpartition("_")
    if base and split in F.SPLITS:
        return base
    return obj_dir.parent.parent.name if name in F.SPLITS else name


def load_srn(obj_dir: Path) -> ObjectScene:
    """pixelNeRF SRN layout: rgb/*.png, pose/*.txt (OpenCV c2w), intrinsics.txt (f cx cy / ... / H W)."""
    obj_dir = Path(obj_dir)
    rgbs = _files(obj_dir / "rgb", (".png",))
    if not rgbs:
        raise InputError(f"{obj_dir}: no rgb/*.png (not an SRN object folder)")
    if not (obj_dir / "intrinsics.txt").is_file():
        raise InputError(f"{obj_dir}: SRN object without intrinsics.txt (its camera: 'f cx cy 0' / ... / 'H W'); "
                         "restore it from the data set, or leave the object out")
    images, poses, ids = _Stack(len(rgbs), obj_dir), [], []
    for p in rgbs:
        pose = obj_dir / "pose" / f"{p.stem}.txt"
        if not pose.is_file():
            raise InputError(f"{obj_dir}: {p.name} has no pose/{pose.name}")
        images.add(read_colour(p))
        poses.append(F.read_srn_pose(pose))
        ids.append(int(p.stem) if p.stem.isdigit() else len(ids))
    images = images.result()
    h, w = images.shape[1:3]
    intr = srn_intrinsics(obj_dir / "intrinsics.txt", w, h)
    box = (np.full(3, -SRN_BOX), np.full(3, SRN_BOX))
    for c2w, p in zip(poses, rgbs):
        check_faces_box(c2w, box, f"{obj_dir}/pose/{p.stem}.txt", "SRN poses are OpenCV camera-to-world (x right, "
                        "y down, looking down +z) around the origin")
    return ObjectScene(obj_dir.name, srn_category(obj_dir), images, np.stack(poses), [intr] * len(ids), box, ids)


def srn_intrinsics(path: Path, w: int, h: int) -> cameras.Intrinsics:
    """The camera of an SRN ``intrinsics.txt`` ('f cx cy 0' / '0. 0. 0.' / '1.' / 'H W', pixelNeRF's reading: the
    first line and the last) for the object's ``w`` x ``h`` images: given at another resolution of the same aspect
    (SRN's own sets), it is scaled to them. InputError for another layout (a one-line file read its 'f cx' as 'H W':
    a camera 6 to 9 pixels off; a 3x3 or 4x4 K matrix divided by zero), a focal length that is not positive, or
    another aspect ratio (the height was left as the file's, not the images')."""
    intr = F.read_srn_intrinsics(path)  # (its layout and values checked there)
    if (intr.width, intr.height) != (w, h):  # SRN intrinsics may be given at another resolution
        if abs(intr.width * h - intr.height * w) > max(intr.width, intr.height):
            raise InputError(f"{path} is for {intr.width}x{intr.height} images ('H W' = '{intr.height} "
                             f"{intr.width}'), the object's are {w}x{h}: another aspect ratio, not the same camera "
                             "at another resolution")
        intr = intr.resized(w, h)
    return intr


def check_faces_box(c2w: np.ndarray, box, where: str, convention: str) -> None:
    """InputError when the camera ``c2w`` (OpenCV) sees none of ``box`` (every corner behind it): poses of the other
    convention (OpenGL read as OpenCV or the reverse turns each camera around) load silently otherwise, every view
    looking away from the object."""
    lo, hi = (np.asarray(b, np.float64) for b in box)
    corners = np.array([[(lo, hi)[(i >> a) & 1][a] for a in range(3)] for i in range(8)])
    z = (corners - c2w[:3, 3]) @ c2w[:3, 2]
    if (z <= 0).all():
        raise InputError(f"{where}: the camera looks away from the scene box {lo.tolist()} to {hi.tolist()} (all of "
                         f"it is behind the camera): {convention}; are these poses in the other convention?")


# --------------------------------------------------------------------------------------------- NMR/DVR

RIGID_TOL = 1e-3
"""How far from orthonormal (max |R^T R - I|) a DVR ``world_mat``'s rotation part may be to be read as a rigid pose
(``format.check_pose``'s tolerance)."""


def decompose_projection(P: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(K with K[2, 2] = 1 and a positive diagonal, rotation R (det +1), t) of a 3x4 projection P = lambda K [R | t]
    (RQ decomposition, as OpenCV's decomposeProjectionMatrix that pixelNeRF and IDR call); InputError when its
    3x3 part is singular."""
    P = np.asarray(P, np.float64)[:3, :4]
    M = P[:, :3]
    det = np.linalg.det(M)
    if not np.isfinite(det) or abs(det) <= 1e-12 * max(np.abs(M).max(), 1e-300) ** 3:
        raise InputError(f"{where}: its 3x3 part is singular (not a camera)")
    if det < 0:  # P and -P are the same projection; the one with det > 0 puts the scene in front (lambda > 0)
        P, M = -P, -M
    J = np.eye(3)[::-1]
    q, r = np.linalg.qr((J @ M).T)  # M = (J r^T J)(J q^T): upper triangular times orthogonal
    K, R = J @ r.T @ J, J @ q.T
    D = np.diag(np.sign(np.diag(K)))
    K, R = K @ D, D @ R
    t = np.linalg.solve(K, P[:, 3])
    return K / K[2, 2], R, t


def dvr_camera(world_mat, camera_mat, scale_mat, w: int, h: int, where: str) -> tuple[np.ndarray, cameras.Intrinsics]:
    """(OpenCV camera-to-world, intrinsics) of one DVR/NMR view of a ``w`` x ``h`` image.

    ``world_mat`` (3x4 or 4x4) is either the rigid world-to-camera [R | t] of DVR's ShapeNet renders (NMR), with
    ``camera_mat`` mapping camera coordinates to NDC in [-1, 1] (pixelNeRF: fx_px = camera_mat[0, 0] * W / 2,
    principal point at the image centre plus camera_mat[:2, 2] * size / 2), or the projection K [R | t] of DVR's
    multi-view data (DTU: K in pixels), RQ-decomposed into K, R and t as pixelNeRF's DVR loader does (the
    ``camera_mat`` is then not read, as there). ``scale_mat`` (or None): DVR's normalisation, world = scale_mat @
    normalised coordinates, a uniform scale and a translation; the cameras come back in normalised coordinates
    (where the unit-cube box :data:`NMR_BOX` holds), as pixelNeRF's loader returns them. InputError for anything
    else (a scaled rotation, a skewed or degenerate camera, a non-uniform scale)."""
    wm = np.asarray(world_mat, np.float64)
    if wm.shape not in ((3, 4), (4, 4)) or not np.isfinite(wm).all():
        raise InputError(f"{where}: world_mat must be a finite 3x4 or 4x4 matrix, got shape {wm.shape}")
    if wm.shape == (4, 4) and np.abs(wm[3] - [0, 0, 0, 1]).max() > 1e-6:
        raise InputError(f"{where}: world_mat's last row is {wm[3].tolist()}, not 0 0 0 1")
    m = wm[:3, :3]
    mtm = m.T @ m
    s2 = np.trace(mtm) / 3.0
    neither = (f"{where}: world_mat is neither a rigid world-to-camera pose [R | t] (rotation part orthonormal, "
               "determinant +1: DVR's ShapeNet/NMR renders) nor a projection K [R | t] with K in pixels (DVR's "
               "multi-view/DTU data: a pixel camera, no skew)")
    if np.abs(mtm - np.eye(3)).max() <= RIGID_TOL and np.linalg.det(m) > 0:
        c2w = cameras.c2w_opencv_from_w2c(wm[:3, :4])
        if camera_mat is None:
            raise InputError(f"{where}: a rigid world_mat needs its camera_mat (the intrinsics, in NDC)")
        cmat = np.asarray(camera_mat, np.float64)
        if cmat.shape not in ((3, 3), (3, 4), (4, 4)) or not np.isfinite(cmat).all() or cmat[0, 0] <= 0 or cmat[1, 1] <= 0:
            raise InputError(f"{where}: camera_mat is not an NDC intrinsics matrix (positive focal lengths): {cmat.tolist()}")
        fx, fy = cmat[0, 0] * w / 2.0, cmat[1, 1] * h / 2.0
        cx, cy = w / 2.0 + cmat[0, 2] * w / 2.0, h / 2.0 + cmat[1, 2] * h / 2.0
        intr = cameras.Intrinsics(fx, fy, cx, cy, w, h)
    elif s2 > 0 and np.abs(mtm / s2 - np.eye(3)).max() <= RIGID_TOL:  # orthonormal up to scale: K would be I
        raise InputError(f"{neither}: its 3x3 part is a {'mirrored' if np.linalg.det(m) < 0 else 'scaled'} rotation "
                         f"(scale {math.sqrt(s2):.4g}); a scaled world goes in scale_mat")
    else:
        try:
            K, R, t = decompose_projection(wm, where)
        except InputError as e:
            raise InputError(f"{neither}: {e}") from None
        if abs(K[0, 1]) > 1e-3 * K[0, 0]:
            raise InputError(f"{neither}: read as a projection its K has skew {K[0, 1]:.4g}")
        c2w = np.eye(4)
        c2w[:3, :3] = R.T
        c2w[:3, 3] = -R.T @ t
        intr = cameras.Intrinsics(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), w, h)
    F.check_pose(c2w, where)
    if scale_mat is not None:
        S = cameras.as_pose(np.asarray(scale_mat, np.float64)) if np.shape(scale_mat) in ((3, 4), (4, 4)) else None
        sc = S[0, 0] if S is not None else float("nan")
        if (S is None or not np.isfinite(S).all() or not sc > 0 or np.abs(S[3] - [0, 0, 0, 1]).max() > 1e-6
                or np.abs(S[:3, :3] - sc * np.eye(3)).max() > 1e-6 * sc):
            raise InputError(f"{where}: scale_mat must be a uniform scale and a translation (DVR: world = scale_mat "
                             f"@ normalised coordinates), got {np.asarray(scale_mat).tolist()}")
        c2w = c2w.copy()
        c2w[:3, 3] = (c2w[:3, 3] - S[:3, 3]) / sc  # the camera centre in normalised coordinates; axes unchanged
    return c2w, intr


def load_nmr(obj_dir: Path, split: str | None = None) -> ObjectScene:
    """DVR/NMR: image/*.png (or .jpg) + cameras.npz with world_mat_i, camera_mat_i and scale_mat_i
    (:func:`dvr_camera`), and mask/*.png of the same names where the object has them (object > 127).
    ``split``: record the split list (:func:`nmr_split_list`) that names the object."""
    obj_dir = Path(obj_dir)
    imgs = _files(obj_dir / "image", (".png",)) or _files(obj_dir / "image", (".jpg", ".jpeg"))
    cam_file = obj_dir / "cameras.npz"
    if not imgs or not cam_file.is_file():
        raise InputError(f"{obj_dir}: need image/*.png and cameras.npz (NMR/DVR layout)")
    try:
        cams = dict(np.load(cam_file))
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as e:  # (a truncated or empty file)
        raise InputError(f"cannot read {cam_file}: {e or type(e).__name__}") from None
    masks_by_stem = {p.stem: p for p in _files(obj_dir / "mask", (".png",))}
    images, poses, intrs, ids, masks = _Stack(len(imgs), obj_dir), [], [], [], []
    for k, p in enumerate(imgs):
        i = int(p.stem) if p.stem.isdigit() else k
        wm, cm, sm = f"world_mat_{i}", f"camera_mat_{i}", f"scale_mat_{i}"
        if wm not in cams:
            raise InputError(f"{cam_file}: missing {wm} (for {p.name})")
        im = read_colour(p)
        h, w = im.shape[:2]
        c2w, intr = dvr_camera(*(_numbers(cams, key, cam_file) for key in (wm, cm, sm)), w, h, f"{cam_file} view {i}")
        images.add(im)
        del im
        poses.append(c2w)
        intrs.append(intr)
        ids.append(i)
        if masks_by_stem:
            mp = masks_by_stem.get(p.stem)
            masks.append(None if mp is None else read_binary_mask(mp))
    images = images.result()
    mask_arr = None
    if masks:
        lacking = [imgs[k].name for k, m in enumerate(masks) if m is None]
        if lacking:
            _note(f"{obj_dir}/mask has no mask for {', '.join(lacking[:3])}{', ...' if lacking[3:] else ''}: the "
                  "object is read without masks (no empty-space skipping for it)")
        else:
            mask_arr = np.stack(masks) if len({m.shape for m in masks}) == 1 else None
            if mask_arr is None or mask_arr.shape != images.shape[:3]:
                raise InputError(f"{obj_dir}: mask/ images are not the size of the views (image/ are "
                                 f"{images.shape[2]}x{images.shape[1]})")
    lst = nmr_split_list(obj_dir.parent, split) if split else None
    listed = None
    if lst is not None and obj_dir.name in _read_lst(lst):
        listed = f"{obj_dir.parent.name}/{lst.name}"
    return ObjectScene(obj_dir.name, obj_dir.parent.name, images, np.stack(poses), intrs,
                       (np.full(3, -NMR_BOX), np.full(3, NMR_BOX)), ids, mask_arr, split_list=listed)


def _numbers(cams: dict, key: str, cam_file: Path) -> np.ndarray | None:
    """``cams[key]`` as float64 (None when absent); InputError when it is not numbers (a traceback before)."""
    if key not in cams:
        return None
    try:
        return np.asarray(cams[key], np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{cam_file}: {key} is not a matrix of numbers (it holds {cams[key].dtype} values)") from None


NMR_LIST_PREFIXES = ("softras_", "")
"""Split lists of a NMR/DVR category, by preference: pixelNeRF's NMR benchmark (``softras_<split>.lst``, the
SoftRas split the published NMR figures use), then DVR's own (``<split>.lst``)."""


def nmr_split_list(category_dir: Path, split: str) -> Path | None:
    """The split list of a NMR/DVR category folder (:data:`NMR_LIST_PREFIXES`), None when it has neither."""
    for prefix in NMR_LIST_PREFIXES:
        p = Path(category_dir) / f"{prefix}{split}.lst"
        if p.is_file():
            return p
    return None


def _read_lst(path: Path) -> list[str]:
    return [ln.strip() for ln in Path(path).read_text().splitlines() if ln.strip()]


def list_nmr(root: Path, split: str) -> list[Path]:
    """NMR/DVR object folders listed in each ``<root>/<category>/softras_<split>.lst`` (pixelNeRF's NMR
    benchmark), or ``<split>.lst`` (DVR's) where a category has no softras list. InputError naming the lists
    there when no category has either, or when a list names a folder that is not there."""
    root = Path(root)
    out, lists = [], []
    for cat in sorted(d for d in root.iterdir() if d.is_dir()) if root.is_dir() else []:
        lst = nmr_split_list(cat, split)
        if lst is None:
            continue
        lists.append(lst)
        for name in _read_lst(lst):
            if not (cat / name).is_dir():
                raise InputError(f"{lst} lists {name!r}, which is not a folder of {cat}: the data set is incomplete "
                                 "(restore the object, or remove it from the list)")
            out.append(cat / name)
    if not lists:
        present = sorted(str(p.relative_to(root)) for p in root.glob("*/*.lst"))
        raise InputError(f"{root}: no NMR/DVR split list for split {split!r}: looked for "
                         f"<category>/softras_{split}.lst (pixelNeRF's NMR benchmark) and <category>/{split}.lst "
                         f"(DVR's); " + (f"the lists there: {', '.join(present[:6])}{', ...' if present[6:] else ''}"
                                         if present else "there are no .lst files"))
    return out


# --------------------------------------------------------------------------------------------- NeRF-synthetic

UNREAD_IMAGE_SUFFIXES = (".exr", ".hdr")
"""Linear, high-dynamic-range images (instant-ngp reads them): refused by name, not read as sRGB pixels."""
NGP_SCALE, NGP_OFFSET = 0.33, 0.5
"""instant-ngp's defaults for a transforms.json's ``scale`` and ``offset``: it maps a position p of the file to
p * scale + offset, where the scene's unit cube is [0, 1]^3."""


def _frame_image(scene_dir: Path, file_path: str) -> Path:
    """A NeRF-synthetic frame's image: ``file_path`` as written, else with .png (the release leaves the suffix
    out) or another image suffix, in any case (an EXR too, so that it is refused by name)."""
    p = Path(scene_dir) / file_path
    if p.suffix.lower() in IMAGE_SUFFIXES + UNREAD_IMAGE_SUFFIXES and p.is_file():
        return p
    stem = p if p.suffix.lower() not in IMAGE_SUFFIXES else p.with_suffix("")
    for ext in IMAGE_SUFFIXES + UNREAD_IMAGE_SUFFIXES:
        for e in (ext, ext.upper()):
            q = stem.with_name(stem.name + e)
            if q.is_file():
                return q
    return p if p.suffix else p.with_suffix(".png")  # missing: read_png names it


def transforms_box(d: dict, positions: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The scene box of a transforms.json whose cameras sit at ``positions`` (N, 3): where instant-ngp's ``scale``
    and ``offset`` put its unit cube (p * scale + offset in [0, 1]^3; ``aabb_scale`` grows it for the background
    only, and colmap2nerf writes 32 for every scene); for a nerfstudio file (``camera_model`` or
    ``applied_transform``: its poses are not normalised, nerfstudio's loader centres and scales the cameras into its
    box at load) the cameras' region; else NeRF-synthetic's [-1.5, 1.5]^3. The fixed box was used for all three:
    a scene scaled or moved for instant-ngp, or in COLMAP's units, was sampled where it is not."""
    if "scale" in d or "offset" in d:
        scale = _number(d, "scale", where, True) if "scale" in d else NGP_SCALE
        off = d.get("offset", NGP_OFFSET)
        off = off if isinstance(off, list) else [off] * 3
        if len(off) != 3:
            raise InputError(f"{where}: offset must be three numbers (or one), got {d['offset']!r}")
        off = np.array([_number({"offset": v}, "offset", where) for v in off])
        return (0.0 - off) / scale, (1.0 - off) / scale
    if "camera_model" in d or "applied_transform" in d:
        centre = positions.mean(0)
        r = max(float(np.linalg.norm(positions - centre, axis=1).max()), 1e-6)
        _note(f"{where}: a nerfstudio file (poses not normalised): the scene box is the cameras' region, as "
              f"nerfstudio's loader takes it: {np.round(centre - r, 4).tolist()} to {np.round(centre + r, 4).tolist()}")
        return centre - r, centre + r
    return np.full(3, -NERF_SYNTHETIC_BOX), np.full(3, NERF_SYNTHETIC_BOX)


def _lone_transforms(folder: Path) -> str:
    """A hint for a folder (or a folder of scenes) that holds a transforms.json (nerfstudio, instant-ngp) but no
    transforms_<split>.json ('' when it has none)."""
    folder = Path(folder)
    if not (folder / "transforms.json").is_file() and not any(folder.glob("*/transforms.json")):
        return ""
    return ("; it holds a transforms.json (nerfstudio / instant-ngp: every frame, no split), which is read once it "
            "is named for a split: copy it to transforms_test.json to evaluate on the scene, or to "
            "transforms_train.json to train on it")


def load_nerf_synthetic(scene_dir: Path, split: str = "train") -> ObjectScene:
    """NeRF-synthetic: transforms_<split>.json (OpenGL c2w, camera_angle_x) + RGBA PNGs (on white); the alpha
    (> 0.5) is the object mask where every frame has one. The category is the scene's name. nerfstudio's and
    instant-ngp's keys are read too (:func:`transforms_intrinsics`, :func:`transforms_box`); nerfstudio's
    ``applied_transform`` is informative (the poses already hold it). Frames naming one image twice are refused (a
    view that is both a reference and a target scores itself), as is a camera that sees none of the scene box."""
    scene_dir = Path(scene_dir)
    tf = scene_dir / f"transforms_{split}.json"
    if not tf.is_file():
        raise InputError(f"{scene_dir}: no transforms_{split}.json" + _lone_transforms(scene_dir))
    try:
        d = json.loads(tf.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"{tf} is not valid JSON ({e})") from None
    if not isinstance(d, dict) or not isinstance(d.get("frames"), list):
        raise InputError(f"{tf}: not a transforms file (a JSON object with a 'frames' list)")
    images, poses, intrs, masks, seen, scaled = _Stack(len(d["frames"]), scene_dir), [], [], [], {}, set()
    for k, fr in enumerate(d["frames"]):
        if not isinstance(fr, dict) or not isinstance(fr.get("file_path"), str) or "transform_matrix" not in fr:
            raise InputError(f"{tf}: frame {k} is not an object with a 'file_path' (text) and a 'transform_matrix'")
        where = f"{tf}: frame {k} ({fr['file_path']})"
        p = _frame_image(scene_dir, fr["file_path"])
        if p.resolve() in seen:
            raise InputError(f"{tf}: frames {seen[p.resolve()]} and {k} are both {p.name}: one view twice (as a "
                             "reference and a target it scores itself); remove one")
        seen[p.resolve()] = k
        if p.suffix.lower() in UNREAD_IMAGE_SUFFIXES:
            raise InputError(f"{where}: {p.name} is a linear high-dynamic-range image; this tool reads 8- or 16-bit "
                             "sRGB PNG and JPEG images: convert it (the colours as displayed) to PNG")
        raw = F.read_png(p, colour=True)
        im = to_float_rgb(raw, linear_alpha=False)
        h, w = im.shape[:2]
        intr, resized = transforms_intrinsics({**d, **fr}, w, h, where)
        if resized:
            scaled.add((w, h))
        try:
            c2w = cameras.opencv_from_opengl(cameras.as_pose(np.asarray(fr["transform_matrix"], np.float64)))
        except (ValueError, TypeError, cameras.CameraConventionError) as e:
            raise InputError(f"{where}: transform_matrix is not a 4x4 matrix ({e})") from None
        F.check_pose(c2w, f"{where} transform_matrix")
        images.add(im)
        del im
        poses.append(c2w)
        intrs.append(intr)
        masks.append(F.unit_pixels(raw[..., -1]) > 0.5 if raw.ndim == 3 and raw.shape[-1] in (2, 4) else None)
    if not poses:
        raise InputError(f"{tf}: no frames")
    box = transforms_box(d, np.stack(poses)[:, :3, 3], str(tf))
    for k, c2w in enumerate(poses):
        check_faces_box(c2w, box, f"{tf}: frame {k} ({d['frames'][k]['file_path']}) transform_matrix",
                        "transforms.json poses are OpenGL camera-to-world (x right, y up, looking down -z), as NeRF, "
                        "nerfstudio and instant-ngp write them, and the box is NeRF-synthetic's unless the file has "
                        "instant-ngp's scale and offset")
    if scaled:
        _note(f"{tf}: its cameras are for images of another size (w, h), the images are "
              f"{', '.join(f'{w}x{h}' for w, h in sorted(scaled))}: the cameras are scaled to them")
    images = images.result()
    mask_arr = np.stack(masks) if all(m is not None for m in masks) else None
    return ObjectScene(scene_dir.name, scene_dir.name, images, np.stack(poses), intrs, box, list(range(len(images))),
                       mask_arr)


# --------------------------------------------------------------------------------------------- dispatch

def _is_capture(meta_path: Path) -> bool:
    """Whether ``meta.json`` is a recovered capture's (``recover-poses``)."""
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("kind") == "capture"


def detect_format(root: Path) -> str:
    """Guess the layout of a dataset root (or a single object folder)."""
    root = Path(root)
    if (root / F.ROOT_MANIFEST).is_file() or any(root.glob("*/*/meta.json")) or (root / "meta.json").is_file():
        return "ours"
    captures = sorted(p.parent.name for p in root.glob("*/meta.json") if _is_capture(p))
    if captures:  # side by side (each also holds an SRN intrinsics.txt: read as SRN they lost box, cameras, background)
        raise InputError(f"{root} holds recovered captures one level down ({', '.join(captures[:3])}"
                         f"{', ...' if len(captures) > 3 else ''}): give one of them, or lay them out as "
                         "<category>/<capture> folders")
    if any(root.glob("transforms_*.json")) or any(root.glob("*/transforms_*.json")):
        return "nerf"
    if any(root.glob("*/*/cameras.npz")) or (root / "cameras.npz").is_file():
        return "nmr"
    if (root / "intrinsics.txt").is_file() or any(root.glob("*/intrinsics.txt")) or any(root.glob("*/*/intrinsics.txt")):
        return "srn"
    raise InputError(f"{root}: not a dataset this tool reads (ours, SRN, NMR/DVR or NeRF-synthetic)"
                     + _lone_transforms(root))


def list_objects(root: Path, fmt: str | None = None, split: str = "train") -> list[tuple[str, Path]]:
    """(format, path) of every object of ``split`` under ``root``."""
    root = Path(root)
    fmt = fmt or detect_format(root)
    if fmt == "ours":
        if (root / "meta.json").is_file():
            return [("ours", root)]
        has_split = (root / "splits" / f"{split}.lst").is_file()
        if not has_split:
            _check_split_name(root, split)
        return [("ours", p) for p in list_ours(root, split if has_split else None)]
    if fmt == "srn":
        # pixelNeRF: <root>/<cat>_<split>/<object>/ or a folder of objects
        if (root / "intrinsics.txt").is_file() or (root / "rgb").is_dir():
            return [("srn", root)]
        cands = _srn_objects(root, f"*_{split}/*") or _srn_objects(root, f"{split}/*")
        if cands:
            return [("srn", p) for p in cands]
        # a folder of objects: one split of a set (cars_train, or a plain test/), or objects without one
        named = root.name.rsplit("_", 1)[-1]
        if named in F.SPLITS and named != split:
            raise InputError(f"{root} is the {named!r} split of an SRN set, not {split!r}: give --split {named}, or "
                             f"the set's folder ({root.parent}) to choose its splits")
        return [("srn", p) for p in _srn_objects(root, "*")]
    if fmt == "nmr":
        if (root / "cameras.npz").is_file():
            return [("nmr", root)]
        return [("nmr", p) for p in list_nmr(root, split)]
    if fmt == "nerf":
        if any(root.glob("transforms_*.json")):
            return [("nerf", root)]
        scenes = sorted(p.parent for p in root.glob(f"*/transforms_{split}.json"))
        if not scenes:
            have = sorted({p.stem.split("_", 1)[1] for p in root.glob("*/transforms_*.json")})
            raise InputError(f"{root}: no NeRF-synthetic scene has transforms_{split}.json"
                             + (f" (the scenes have split(s) {', '.join(have)})" if have else "")
                             + _lone_transforms(root))
        return [("nerf", p) for p in scenes]
    raise InputError(f"unknown dataset format {fmt!r}; choose one of {FORMATS}")


def object_category(fmt: str, path: Path) -> str:
    """The category :func:`load_object` gives the object at ``path``, without loading it (our format: its folder's
    parent, as meta.json records it; SRN: :func:`srn_category`; NeRF-synthetic: the scene)."""
    path = Path(path)
    if fmt == "srn":
        return srn_category(path)
    if fmt == "nerf":
        return path.name
    return path.parent.name


def load_object(fmt: str, path: Path, split: str = "train", depth: bool = False, image_size: int = 0,
                what: str = "train.image_size", shrink_only: bool = False) -> ObjectScene:
    """One object; ``depth``: with its depth maps where the format has them (ours only). ``image_size`` (0: as
    rendered): every view at that many pixels on its longer side, whatever the format (:func:`resize_scene`;
    ``what`` names the setting in its refusal of upsampling, ``shrink_only`` keeps smaller views instead). The
    object is read at its own size first: one object's full-size pixels are held at a time."""
    if fmt == "ours":
        scene = load_ours(path, depth)
    elif fmt == "srn":
        scene = load_srn(path)
    elif fmt == "nmr":
        scene = load_nmr(path, split)
    elif fmt == "nerf":
        scene = load_nerf_synthetic(path, split)
    else:
        raise InputError(f"unknown dataset format {fmt!r}; choose one of {FORMATS}")
    return resize_scene(scene, image_size, what, shrink_only)


def _srn_objects(root: Path, pattern: str) -> list[Path]:
    """SRN object folders matching ``pattern`` under ``root``: those with an intrinsics.txt or an rgb/ folder (one
    without intrinsics.txt is then refused by :func:`load_srn`, not skipped)."""
    found = {p.parent for p in Path(root).glob(f"{pattern}/intrinsics.txt")}
    found |= {p.parent for p in Path(root).glob(f"{pattern}/rgb") if p.is_dir()}
    return sorted(found)


def _check_split_name(root: Path, split: str) -> None:
    """A split our dataset does not have is a typo, not 'every object' (training objects included)."""
    lists = sorted(p.stem for p in (root / "splits").glob("*.lst")) if (root / "splits").is_dir() else []
    if lists:
        raise InputError(f"{root} has no split {split!r} (it has {', '.join(lists)})")
    if split not in F.SPLITS:
        raise InputError(f"unknown split {split!r}; choose one of {', '.join(F.SPLITS)}")


def unfinished_objects(root: Path, split: str) -> tuple[list[str], int]:
    """(objects of ``split`` that are listed but missing or not completely rendered, objects in all) of a
    dataset root of our format; ([], n) for a finished one."""
    root = Path(root)
    if not (root / F.ROOT_MANIFEST).is_file():
        return [], 0
    entries = F.read_split(root, split)
    dirs = {f"{p.parent.parent.name}/{p.parent.name}": p.parent for p in root.glob("*/*/meta.json")}
    names = entries or sorted(dirs)
    if entries:  # objects of this split started after the lists were written (an interrupted run, a failed shard)
        try:
            settings = json.loads((root / F.ROOT_MANIFEST).read_text()).get("settings")
        except (OSError, ValueError, AttributeError):
            settings = None
        listed = set(entries)
        for key, d in sorted(dirs.items()):
            if key in listed:
                continue
            try:
                meta = json.loads((d / "meta.json").read_text())
            except (OSError, ValueError):
                continue
            if (isinstance(meta, dict) and meta.get("split") == split and meta.get("complete") is False
                    and F.settings_match(meta.get("settings"), settings or {})):
                names = [*names, key]
    bad = []
    for e in names:
        d = dirs.get(e) or next((v for k, v in dirs.items() if k.split("/")[1] == e), None)
        if d is None:
            bad.append(e)
            continue
        try:
            complete = json.loads((d / "meta.json").read_text()).get("complete", True)
        except (ValueError, OSError, AttributeError):
            complete = False
        if complete is False:
            bad.append(e)
    return bad, len(names)


def load_dataset(root: Path, split: str = "train", fmt: str | None = None, limit: int | None = None,
                 depth: bool = False, image_size: int = 0) -> list[ObjectScene]:
    """The objects of ``split`` for training; InputError when the dataset is half-rendered (some objects of
    the split missing or unfinished: training would quietly use the others). ``depth``: read depth maps too;
    ``image_size``: each view's longer side in pixels (0 = as rendered; :func:`resize_scene`)."""
    objs = list_objects(root, fmt, split)
    check_finished(root, split, objs)
    return [load_object(f, p, split, depth, image_size) for f, p in objs[:limit]]


def check_finished(root: Path, split: str, objs: list) -> None:
    """InputError when ``objs`` (from :func:`list_objects`) is empty, or our dataset is half-rendered (some
    objects of the split missing or unfinished: training or evaluation would quietly use the others)."""
    if not objs:
        raise InputError(f"{root}: no objects for split {split!r}")
    if objs[0][0] == "ours":
        bad, total = unfinished_objects(Path(root), split)
        if bad:
            raise InputError(f"{root} is half-rendered: {len(bad)} of {total} objects of split {split!r} are missing "
                             f"or unfinished (e.g. {bad[0]}); finish it with render-dataset (a rerun resumes)")
        left = F.planned_but_unlisted(Path(root), split)  # a make-shapenet set whose other shards have not run
        if left and left[0]:
            raise InputError(f"{root} is half-rendered: {len(left[0])} of {left[1]} objects make-shapenet planned for "
                             f"split {split!r} are not finished (e.g. {left[0][0]}); run its other shards (a rerun "
                             "of any shard names them)")


# --------------------------------------------------------------------------------------------- resizing on loading

def scaled_size(w: int, h: int, size: int) -> tuple[int, int]:
    """(width, height) with the longer side ``size`` pixels and the shorter rounded to keep the aspect ratio (as
    ``synthesis.reference_shape``)."""
    s = size / max(w, h)
    return max(1, round(w * s)), max(1, round(h * s))


def _area_axis(x: np.ndarray, n_out: int, axis: int) -> np.ndarray:
    """``x`` (float) averaged over each output pixel's footprint along ``axis`` (box filtering, exact areas: a
    partly covered input pixel counts by its covered share). Through the running sum, linear between pixels."""
    n_in = x.shape[axis]
    x = np.moveaxis(np.asarray(x, np.float64), axis, 0)
    c = np.concatenate([np.zeros((1, *x.shape[1:])), np.cumsum(x, 0)])
    e = np.arange(n_out + 1, dtype=np.int64) * n_in
    kk = np.minimum(e // n_out, n_in - 1)
    frac = ((e - kk * n_out) / n_out).reshape(-1, *([1] * (x.ndim - 1)))  # (k, 0) or (n_in - 1, 1) at the end
    at = c[kk] + frac * x[kk]
    out = (at[1:] - at[:-1]) * (n_out / n_in)
    return np.moveaxis(out, 0, axis)


def resize_colour(image: np.ndarray, w: int, h: int) -> np.ndarray:
    """An (H, W, C) float image at ``w`` x ``h`` by area (box) filtering: each pixel the mean of its footprint, a
    partly covered source pixel weighted by its share (the sRGB values, as PIL's BOX and OpenCV's INTER_AREA)."""
    if image.shape[:2] == (h, w):
        return image
    H, W = image.shape[:2]
    if H % h == 0 and W % w == 0:  # whole footprints (1024 to 128 px): the same means, without the running sums
        out = image.reshape(h, H // h, w, W // w, -1).mean((1, 3), dtype=np.float64)
    else:
        out = _area_axis(_area_axis(image, h, 0), w, 1)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def _overlap_ranges(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray]:
    """(first, last + 1) input pixel each output pixel's footprint overlaps (by a positive length)."""
    i = np.arange(n_out + 1, dtype=np.int64) * n_in
    lo = i[:-1] // n_out
    hi = -((-i[1:]) // n_out)  # ceil
    return lo, hi


def resize_object_mask(mask: np.ndarray, w: int, h: int) -> np.ndarray:
    """A bool (H, W) object mask at ``w`` x ``h``, conservatively (``synthesis.views.resize_mask``'s rule, with
    exact footprints at any scale): a pixel is object when any object pixel overlaps it."""
    m = np.asarray(mask, bool)
    if m.shape == (h, w):
        return m
    H, W = m.shape
    c = np.zeros((H + 1, W + 1), np.int64)
    c[1:, 1:] = np.cumsum(np.cumsum(m, 0, dtype=np.int64), 1)
    y0, y1 = _overlap_ranges(H, h)
    x0, x1 = _overlap_ranges(W, w)
    count = c[y1][:, x1] - c[y0][:, x1] - c[y1][:, x0] + c[y0][:, x0]
    return count > 0


def resize_depth(depth: np.ndarray, w: int, h: int) -> np.ndarray:
    """A (H, W) depth map (0 = no surface) at ``w`` x ``h``: each pixel takes the valid sample (> 0) nearest its
    centre among the source pixels its footprint overlaps (the nearer surface among equally near ones), 0 when none
    is valid. The depth loss pulls the light of the ray through the pixel's centre onto the surface it hits: the
    nearest sample is that surface, to half a source pixel; a mean invents a surface between two that nothing lies
    on, and a min-pool gives the front surface to rays that pass behind it at its outline. A pixel has a depth where
    any overlapping source pixel has one, as the conservative masks (:func:`resize_object_mask`) mark it object."""
    d = np.asarray(depth, np.float32)
    if d.shape == (h, w):
        return d
    H, W = d.shape

    def axis(n_in, n_out):
        lo, hi = _overlap_ranges(n_in, n_out)
        kmax = int((hi - lo).max())
        idx = lo[:, None] + np.arange(kmax)[None]
        pad = idx < hi[:, None]
        idx = np.minimum(idx, n_in - 1)
        dist = (idx + 0.5) - (np.arange(n_out)[:, None] + 0.5) * (n_in / n_out)
        return idx, pad, dist ** 2

    iy, py, dy = axis(H, h)
    ix, px, dx = axis(W, w)
    out = np.zeros((h, w), np.float32)
    for i in range(h):
        cand = d[iy[i]][:, ix]  # (Ky, w, Kx)
        ok = (cand > 0) & py[i][:, None, None] & px[None]
        d2 = np.where(ok, dy[i][:, None, None] + dx[None], np.inf)
        d2 = d2.transpose(1, 0, 2).reshape(w, -1)
        cand = cand.transpose(1, 0, 2).reshape(w, -1)
        best = d2.min(1, keepdims=True)
        pick = np.where(np.isfinite(best) & (d2 <= best + 1e-9), cand, np.inf).min(1)
        out[i] = np.where(np.isfinite(pick), pick, 0.0)
    return out


def resize_scene(scene: ObjectScene, size: int, what: str = "train.image_size", shrink_only: bool = False) -> ObjectScene:
    """``scene`` with every view's longer side ``size`` pixels (0: unchanged): colours by area, masks
    conservatively, depth maps by the nearest valid sample, the cameras by ``Intrinsics.resized`` (a point projects
    where it did, scaled). A ``size`` above the views' is refused (upsampling adds nothing), or with
    ``shrink_only`` leaves them as they are."""
    if not size or not len(scene):
        return scene
    n, H, W = scene.images.shape[:3]
    if size > max(W, H):
        if shrink_only:
            return scene
        raise InputError(f"{what} {size} is larger than the views of {scene.category}/{scene.name} ({W}x{H} px): "
                         f"upsampling adds nothing; give at most {max(W, H)}, or 0 to use them as rendered")
    w, h = scaled_size(W, H, size)
    if (w, h) == (W, H):
        return scene
    images = np.empty((n, h, w, scene.images.shape[3]), np.float32)
    for k in range(n):
        images[k] = resize_colour(scene.images[k], w, h)
    masks = None if scene.masks is None else np.stack([resize_object_mask(m, w, h) for m in scene.masks])
    depths = None if scene.depths is None else np.stack([resize_depth(d, w, h) for d in scene.depths])
    intrs = [intr.resized(w, h) for intr in scene.intrinsics]
    from dataclasses import replace

    return replace(scene, images=images, intrinsics=intrs, masks=masks, depths=depths)
