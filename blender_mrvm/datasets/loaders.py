"""Multi-view object loaders: our format, SRN (pixelNeRF), NMR/DVR and NeRF-synthetic.

Every loader returns :class:`ObjectScene` objects with OpenCV camera-to-world poses and
:class:`~..geometry.cameras.Intrinsics` (conversions go through ``geometry/cameras.py``), images as
float32 RGB in [0, 1] composited on white, and an object box (from ``meta.json`` where the format
has one, else the format's documented bounds). bpy-free.

Layouts read::

    ours     <root>/<category>/<object>/{rgb,pose}/NNNNNN.*, intrinsics.txt, meta.json (bbox)
    srn      <root>/<object>/{rgb/*.png, pose/*.txt, intrinsics.txt}   (pixelNeRF's SRN layout)
    nmr      <root>/<category>/<object>/{image/*.png, cameras.npz}, <root>/<category>/<split>.lst
    nerf     <root>/<scene>/transforms_{train,val,test}.json + image files
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from ..geometry import cameras
from . import format as F

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


def to_float_rgb(arr: np.ndarray) -> np.ndarray:
    """uint8 / uint16 / float image (H, W[, C]) -> float32 RGB in [0, 1], alpha composited on white."""
    a = np.asarray(arr)
    if a.dtype == np.uint8:
        x = a.astype(np.float32) / 255.0
    elif a.dtype == np.uint16:
        x = a.astype(np.float32) / 65535.0
    else:
        x = a.astype(np.float32)
    if x.ndim == 2:
        x = np.repeat(x[..., None], 3, -1)
    if x.shape[-1] == 4:
        alpha = x[..., 3:4]
        x = x[..., :3] * alpha + (1.0 - alpha)
    elif x.shape[-1] == 2:  # grey + alpha
        x = np.repeat(x[..., :1] * x[..., 1:] + (1.0 - x[..., 1:]), 3, -1)
    return np.clip(x[..., :3], 0.0, 1.0)


def _stack(images: Sequence[np.ndarray], where: Path) -> np.ndarray:
    shapes = {im.shape for im in images}
    if len(shapes) != 1:
        raise InputError(f"{where}: views have different image sizes {sorted(shapes)}")
    return np.stack(images).astype(np.float32)


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
    images = _stack([to_float_rgb(ov.rgb(i)) for i in range(len(ov.indices))], obj_dir)
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

def load_srn(obj_dir: Path) -> ObjectScene:
    """pixelNeRF SRN layout: rgb/*.png, pose/*.txt (OpenCV c2w), intrinsics.txt (f cx cy / ... / H W)."""
    obj_dir = Path(obj_dir)
    rgbs = sorted((obj_dir / "rgb").glob("*.png"))
    if not rgbs:
        raise InputError(f"{obj_dir}: no rgb/*.png (not an SRN object folder)")
    intr = F.read_srn_intrinsics(obj_dir / "intrinsics.txt")
    images, poses, ids = [], [], []
    for p in rgbs:
        pose = obj_dir / "pose" / f"{p.stem}.txt"
        if not pose.is_file():
            raise InputError(f"{obj_dir}: {p.name} has no pose/{pose.name}")
        images.append(to_float_rgb(F.read_png(p)))
        poses.append(F.read_srn_pose(pose))
        ids.append(int(p.stem) if p.stem.isdigit() else len(ids))
    images = _stack(images, obj_dir)
    h, w = images.shape[1:3]
    if (intr.width, intr.height) != (w, h):  # SRN intrinsics may be given at another resolution
        intr = intr.scaled(w / intr.width)
    return ObjectScene(obj_dir.name, obj_dir.parent.name, images, np.stack(poses), [intr] * len(ids),
                       (np.full(3, -SRN_BOX), np.full(3, SRN_BOX)), ids)


# --------------------------------------------------------------------------------------------- NMR/DVR

def load_nmr(obj_dir: Path) -> ObjectScene:
    """DVR/NMR: image/*.png + cameras.npz with world_mat_i (3x4 or 4x4 K [R|t], projection) and camera_mat_i.

    DVR's ``world_mat`` is the world-to-camera [R | t] in OpenCV axes; ``camera_mat`` maps camera
    coordinates to NDC in [-1, 1] (pixelNeRF: fx_px = camera_mat[0,0] * W / 2, principal point at the
    image centre plus camera_mat[:2, 2] * size / 2)."""
    obj_dir = Path(obj_dir)
    imgs = sorted((obj_dir / "image").glob("*.png")) or sorted((obj_dir / "image").glob("*.jpg"))
    cam_file = obj_dir / "cameras.npz"
    if not imgs or not cam_file.is_file():
        raise InputError(f"{obj_dir}: need image/*.png and cameras.npz (NMR/DVR layout)")
    cams = np.load(cam_file)
    images, poses, intrs, ids = [], [], [], []
    for k, p in enumerate(imgs):
        i = int(p.stem) if p.stem.isdigit() else k
        wm, cm = f"world_mat_{i}", f"camera_mat_{i}"
        if wm not in cams or cm not in cams:
            raise InputError(f"{cam_file}: missing {wm} / {cm}")
        im = to_float_rgb(F.read_png(p))
        h, w = im.shape[:2]
        cmat = np.asarray(cams[cm], np.float64)
        fx, fy = cmat[0, 0] * w / 2.0, cmat[1, 1] * h / 2.0
        cx, cy = w / 2.0 + cmat[0, 2] * w / 2.0, h / 2.0 + cmat[1, 2] * h / 2.0
        w2c = cameras.as_pose(np.asarray(cams[wm], np.float64)[:3, :4])
        images.append(im)
        poses.append(cameras.c2w_opencv_from_w2c(w2c))
        intrs.append(cameras.Intrinsics(fx, fy, cx, cy, w, h))
        ids.append(i)
    return ObjectScene(obj_dir.name, obj_dir.parent.name, _stack(images, obj_dir), np.stack(poses), intrs,
                       (np.full(3, -NMR_BOX), np.full(3, NMR_BOX)), ids)


def list_nmr(root: Path, split: str) -> list[Path]:
    """NMR/DVR object folders listed in ``<root>/<category>/<split>.lst``."""
    out = []
    for lst in sorted(Path(root).glob(f"*/{split}.lst")):
        out += [lst.parent / ln.strip() for ln in lst.read_text().splitlines() if ln.strip()]
    return out


# --------------------------------------------------------------------------------------------- NeRF-synthetic

def load_nerf_synthetic(scene_dir: Path, split: str = "train") -> ObjectScene:
    """NeRF-synthetic: transforms_<split>.json (OpenGL c2w, camera_angle_x) + RGBA PNGs (on white)."""
    scene_dir = Path(scene_dir)
    tf = scene_dir / f"transforms_{split}.json"
    if not tf.is_file():
        raise InputError(f"{scene_dir}: no transforms_{split}.json")
    d = json.loads(tf.read_text())
    images, poses, intrs = [], [], []
    for fr in d.get("frames", []):
        p = scene_dir / fr["file_path"]
        if not p.suffix:
            p = p.with_suffix(".png")
        im = to_float_rgb(F.read_png(p))
        h, w = im.shape[:2]
        if "fl_x" in d or "fl_x" in fr:  # nerfstudio-style intrinsics
            g = {**d, **fr}
            intr = cameras.Intrinsics(float(g["fl_x"]), float(g.get("fl_y", g["fl_x"])), float(g.get("cx", w / 2)),
                                      float(g.get("cy", h / 2)), w, h)
        else:
            intr = cameras.intrinsics_from_fov(float(d["camera_angle_x"]), w, h)
        images.append(im)
        poses.append(cameras.opencv_from_opengl(np.asarray(fr["transform_matrix"], np.float64)))
        intrs.append(intr)
    if not images:
        raise InputError(f"{tf}: no frames")
    return ObjectScene(scene_dir.name, "", _stack(images, scene_dir), np.stack(poses), intrs,
                       (np.full(3, -NERF_SYNTHETIC_BOX), np.full(3, NERF_SYNTHETIC_BOX)), list(range(len(images))))


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
    raise InputError(f"{root}: not a dataset this tool reads (ours, SRN, NMR/DVR or NeRF-synthetic)")


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
        if (root / "intrinsics.txt").is_file():
            return [("srn", root)]
        cands = sorted(p.parent for p in root.glob(f"*_{split}/*/intrinsics.txt"))
        if cands:
            return [("srn", p) for p in cands]
        # a folder of objects: one split of a set (cars_train), or objects without one
        named = root.name.rsplit("_", 1)[1] if "_" in root.name else ""
        if named in F.SPLITS and named != split:
            raise InputError(f"{root} is the {named!r} split of an SRN set, not {split!r}: give --split {named}, or "
                             f"the set's folder ({root.parent}) to choose its splits")
        return [("srn", p) for p in sorted(p.parent for p in root.glob("*/intrinsics.txt"))]
    if fmt == "nmr":
        if (root / "cameras.npz").is_file():
            return [("nmr", root)]
        return [("nmr", p) for p in list_nmr(root, split)]
    if fmt == "nerf":
        scenes = [root] if any(root.glob("transforms_*.json")) else sorted(p.parent for p in root.glob("*/transforms_train.json"))
        return [("nerf", p) for p in scenes]
    raise InputError(f"unknown dataset format {fmt!r}; choose one of {FORMATS}")


def load_object(fmt: str, path: Path, split: str = "train", depth: bool = False) -> ObjectScene:
    """One object; ``depth``: with its depth maps where the format has them (ours only)."""
    if fmt == "ours":
        return load_ours(path, depth)
    if fmt == "srn":
        return load_srn(path)
    if fmt == "nmr":
        return load_nmr(path)
    if fmt == "nerf":
        return load_nerf_synthetic(path, split)
    raise InputError(f"unknown dataset format {fmt!r}; choose one of {FORMATS}")


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
                 depth: bool = False) -> list[ObjectScene]:
    """The objects of ``split`` for training; InputError when the dataset is half-rendered (some objects of
    the split missing or unfinished: training would quietly use the others). ``depth``: read depth maps too."""
    objs = list_objects(root, fmt, split)
    check_finished(root, split, objs)
    return [load_object(f, p, split, depth) for f, p in objs[:limit]]


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
