"""Sem2NeRF synthesis from one part mask and its camera: free-viewpoint images + semantic maps.

``render_from_mask`` validates everything first (checkpoint header, mask size and labels, edits,
pose, intrinsics) without torch, so bad input is a one-line :class:`InputError` and nothing is
written; then it renders into a temporary folder that is moved into place at the end::

    OUT/rgb/NNNNNN.png             RGBA (alpha = the model's opacity, straight colour: mixed over the model's
                                   background in linear light it is the model's output), view 0 = the input camera
    OUT/semantic/NNNNNN.png        uint8 part ids (argmax of the rendered semantic map)
    OUT/semantic_color/NNNNNN.png  the same, coloured for viewing
    OUT/pose/NNNNNN.txt            OpenCV camera-to-world of each view (SRN format)
    OUT/blend/NNNNNN.png           with --blend: the input view along the style blend
    OUT/mask_input.png             the (edited) input mask the model saw
    OUT/sem2nerf.json              settings, labels, edits, styles

Views orbit the world z axis through the input camera (``views`` of them, evenly spaced), or are the
cameras of a ``targets.json`` (the add-on's selected cameras or its own orbit); view k is written as
``rgb/k``, ``semantic/k``, ... in both cases. The checks (:func:`checkpoint_info`, :func:`check_input_mask`,
:func:`check_pose`, :func:`check_camera_sees_box`, :func:`mask_from_rgba`) are shared with the add-on's
operator, which runs them on Blender's main thread before it starts the worker. bpy-free.

The files and the Python API (``api.render_mask_views``: masks and cameras as arrays, views as arrays) share the
checks (:func:`check_render_options`, :func:`prepare_mask`; :func:`mask_from_array` reads an array as
:func:`read_mask_png` reads a file), the loading (:func:`load_render_model`) and the render
(:func:`render_prepared`); :func:`render_from_mask` adds the files, the thread count and the output folder.
"""

from __future__ import annotations

import json
import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...errors import InputError, OutputError
from ...progress import Progress


@dataclass(frozen=True)
class RenderRequest:
    """One ``sem2nerf render`` call."""

    checkpoint: str
    """Sem2NeRF checkpoint (model file, checkpoint folder or run folder)."""
    mask: str
    """Part-id mask PNG (uint8, single channel, the checkpoint's image size)."""
    pose: str
    """The mask's camera: SRN pose file (4x4 OpenCV camera-to-world)."""
    out: str
    """Output folder."""
    intrinsics: str = ""
    """SRN intrinsics.txt of the camera ('' = the pose's object folder's, else ``fov``)."""
    fov: float = 40.0
    """Horizontal field of view in degrees when no intrinsics file is found."""
    views: int = 8
    """Views on the orbit (view 0 = the input camera)."""
    edits: tuple[str, ...] = ()
    """Label edits 'SRC:DST' (ids or names) applied to the mask in order."""
    style_seed: int | None = None
    """Style of this random code (None = the default: mean style)."""
    blend: int | None = None
    """Also blend from the style above to the style of this seed (input view)."""
    blend_steps: int = 5
    """Images along the blend (ends included)."""
    force: bool = False
    """Write into a non-empty output folder (files of the same name are replaced, an earlier render's files removed:
    :func:`remove_earlier_render`); never into the folder of the mask or pose, or the dataset object holding them
    (:func:`input_folders`)."""
    threads: int = 0
    """torch CPU threads (0 = every core but one, ``threads.auto_threads``)."""
    device: str = "cpu"
    """Torch device."""
    targets: str = ""
    """``targets.json`` (``datasets/novel_views.py``): render these cameras instead of the orbit."""
    mix_seed: int | None = None
    """Blend the style above toward the style of this seed for every view ..."""
    mix: float = 0.0
    """... by this factor in [0, 1] (0 = the style above, 1 = the seed's)."""
    quality: str = "full"
    """``full`` (as trained) or ``preview`` (half the samples per ray: ``models.registry.quality_overrides``)."""


SEED_MAX = 2**64 - 1
"""The largest style seed (``torch.Generator.manual_seed`` takes 64 bits)."""


def palette(label_id: int) -> tuple[int, int, int]:
    """A fixed colour per part id (background white)."""
    if label_id == 0:
        return (255, 255, 255)
    rng = np.random.default_rng(int(label_id) * 7919 + 17)
    c = rng.integers(30, 226, 3)
    return int(c[0]), int(c[1]), int(c[2])


def colorize(ids: np.ndarray) -> np.ndarray:
    lut = np.array([palette(i) for i in range(256)], np.uint8)
    return lut[ids]


def parse_edit(text: str, labels: tuple[int, ...], names: tuple[str, ...]) -> tuple[int, int]:
    """'SRC:DST' (part ids or label names) -> (src id, dst id); InputError for unknown labels."""
    if text.count(":") < 1:
        raise InputError(f"--edit {text!r}: expected SRC:DST (part ids or label names)")
    src, dst = text.rsplit(":", 1) if text.count(":") == 1 else _split_named(text, names)

    def lab(s: str) -> int:
        s = s.strip()
        if s.isdigit():
            v = int(s)
        elif s in names:
            v = labels[names.index(s)]
        else:
            raise InputError(f"--edit {text!r}: {s!r} is not a label of this checkpoint")
        if v not in labels:
            raise InputError(f"--edit {text!r}: label id {v} is not known to this checkpoint "
                             f"(known: {list(labels)})")
        return v

    return lab(src), lab(dst)


def _split_named(text: str, names: tuple[str, ...]) -> tuple[str, str]:
    for i in range(len(text)):
        if text[i] == ":":
            a, b = text[:i], text[i + 1:]
            if (a in names or a.isdigit()) and (b in names or b.isdigit()):
                return a, b
    raise InputError(f"--edit {text!r}: expected SRC:DST (part ids or label names)")


def orbit_poses(c2w: np.ndarray, n: int) -> list[np.ndarray]:
    """``n`` poses rotating ``c2w`` about the world z axis (view 0 = ``c2w``)."""
    out = []
    for k in range(n):
        a = 2 * math.pi * k / n
        R = np.array([[math.cos(a), -math.sin(a), 0, 0], [math.sin(a), math.cos(a), 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        out.append(R @ c2w)
    return out


def read_mask_png(path: Path) -> np.ndarray:
    """A mask PNG's (H, W) uint8 part ids; InputError for a missing or unreadable file, several channels (but an RGB
    image whose three channels are equal: grey, as an editor may save it and as the panel reads it), more than 8
    bits, or a palette image whose colours are not grey (a palette image with grey entries, which an editor may save
    a greyscale mask as, is read as those grey values, never as its palette indices)."""
    from PIL import Image

    from ...datasets import format as DF

    if Path(path).is_dir():  # a folder "did not exist"
        raise InputError(f"mask {path} is a folder, not a PNG file")
    if not Path(path).is_file():
        raise InputError(f"mask {path} does not exist")
    try:
        with Image.open(path) as im:
            mode, pal = im.mode, im.getpalette("RGB") if im.mode == "P" else None
        m = np.asarray(DF.read_png(Path(path)))
    except Exception as e:  # noqa: BLE001 - any decoder failure is the user's file
        raise InputError(f"mask {path} is not a readable PNG: {type(e).__name__}") from None
    if mode == "P":  # np.asarray gives its palette indices; PA (indices + alpha) is refused below as 2 channels
        m = _palette_greys(m, pal, f"mask {path}")
    if m.ndim == 3 and m.shape[-1] == 3 and _is_grey(m):  # grey saved as RGB: the panel reads it so
        m = m[..., 0]
    if m.ndim != 2:
        raise InputError(f"mask {path} has {m.shape[-1]} channels; expected a single-channel part-id image")
    if m.dtype != np.uint8:
        raise InputError(f"mask {path} is {m.dtype}; expected 8-bit part ids")
    return m


def _is_grey(img: np.ndarray) -> bool:
    """Whether every pixel of an (H, W, 3|4) image has three equal colour channels (a part-id image saved as RGB)."""
    return bool((img[..., :3] == img[..., :1]).all())


def mask_from_array(mask, labels: tuple[int, ...], where: str) -> np.ndarray:
    """A mask given as an array (the Python API) -> part ids for :func:`check_input_mask`: (H, W) integer ids as
    they are; an (H, W, 3|4) uint8 image grey as the ids (as :func:`read_mask_png` reads a grey RGB PNG), a
    coloured one as label colours (:func:`mask_from_rgba` ``COLORS``, what ``semantic_color`` shows and the
    add-on's painted masks hold; alpha < 128 is background). InputError for anything else."""
    a = np.asarray(mask)
    if a.ndim == 3 and a.shape[-1] in (3, 4):
        enc = "IDS" if a.dtype == np.uint8 and _is_grey(a) else "COLORS"
        return mask_from_rgba(a, labels, enc, where)
    if a.ndim == 3 and a.shape[-1] == 1:
        a = a[..., 0]
    if a.ndim != 2:
        raise InputError(f"{where}: expected (H, W) part ids or an (H, W, 3|4) label-colour image, got shape "
                         f"{a.shape}")
    if a.dtype.kind not in "biu":
        raise InputError(f"{where}: part ids must be integers in 0..255, got {a.dtype}")
    return a


def _palette_greys(index: np.ndarray, pal: list | None, where: str) -> np.ndarray:
    """The grey values a palette image's pixels show (its part ids); InputError when a used entry is coloured."""
    lut = np.asarray(pal or [], np.int64).reshape(-1, 3)
    used = np.flatnonzero(np.bincount(index.ravel(), minlength=256))
    if used.size and (used[-1] >= len(lut) or (lut[used] != lut[used, :1]).any()):
        raise InputError(f"{where} is a palette image with coloured entries, not part ids; save it as 8-bit "
                         "greyscale (value = part id)")
    return lut[index, 0].astype(np.uint8) if used.size else index.astype(np.uint8)


@dataclass(frozen=True)
class CheckpointInfo:
    """What the checks need from a Sem2NeRF checkpoint's header (read without torch)."""

    model_file: Path
    meta: dict
    labels: tuple
    """Part ids the model knows (background 0 first)."""
    names: tuple
    """Their names."""
    size: int
    """Side of the square masks it takes."""
    scene_box: float = 0.5
    """Half-size of the world cube (about the origin) its objects live in: nothing outside it is rendered."""


def checkpoint_info(path: Path) -> CheckpointInfo:
    """The header of a Sem2NeRF checkpoint; InputError when it is none (torch-free: the add-on calls it)."""
    from .config import read_sem2nerf_header

    model_file, meta = read_sem2nerf_header(Path(path))
    try:
        cfg = json.loads(meta["model_config"])
        labels, names, size = tuple(int(v) for v in cfg["labels"]), tuple(cfg["label_names"]), int(cfg["image_size"])
        box = float(cfg.get("scene_box", 0.5))
    except (KeyError, TypeError, ValueError, AttributeError):
        raise InputError(f"{model_file}: its Sem2NeRF model config is unreadable") from None
    return CheckpointInfo(model_file, meta, labels, names, size, box)


def check_input_mask(mask: np.ndarray, info: CheckpointInfo, where: str,
                     edits: tuple[str, ...] = ()) -> tuple[np.ndarray, list[tuple[int, int]]]:
    """The (edited) uint8 part-id mask the model gets, and the parsed edits; InputError for a mask of
    another size than the checkpoint's, labels it does not know, edits of absent labels, an empty mask."""
    from .inputs import check_mask

    mask = np.asarray(mask)
    if mask.shape != (info.size, info.size):
        h, w = mask.shape[:2] if mask.ndim >= 2 else (0, 0)
        raise InputError(f"{where} is {w}x{h}; this checkpoint takes {info.size}x{info.size} masks")
    parsed = [parse_edit(e, info.labels, info.names) for e in edits]
    mask = mask.copy()
    for src, dst in parsed:
        if not (mask == src).any():
            raise InputError(f"--edit {src}:{dst}: label {src} is not in the mask")
        mask[mask == src] = dst
    mask = check_mask(mask, info.labels, where)
    if not (mask != 0).any():
        raise InputError(f"{where} is empty (background only{' after the edits' if parsed else ''})")
    return mask, parsed


def check_pose(c2w, where: str) -> np.ndarray:
    """A finite rigid 4x4 camera-to-world matrix as float64; InputError otherwise."""
    try:
        m = np.asarray(c2w, np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{where} is not a 4x4 camera-to-world matrix") from None
    if m.shape != (4, 4) or not np.isfinite(m).all():
        raise InputError(f"{where} is not a finite 4x4 camera-to-world matrix")
    r = m[:3, :3]
    if not np.allclose(r.T @ r, np.eye(3), atol=1e-4) or np.linalg.det(r) < 0:
        raise InputError(f"{where} is not a rigid camera pose (its rotation is scaled, sheared or mirrored)")
    return m


MIN_BOX_COVER = 0.9
"""Least share of a mask's part pixels whose rays must cross the model's object box (:func:`check_camera_sees_box`).
Every view of the datasets it trains on has all of them cross it (52 of 52 library views: 100 %)."""


def check_camera_sees_box(mask: np.ndarray, intr, c2w: np.ndarray, scene_box: float, where: str) -> None:
    """InputError when from the mask's camera fewer than :data:`MIN_BOX_COVER` of the mask's part pixels lie over the
    model's object box (the cube of half-size ``scene_box`` about the world origin): the model renders nothing
    outside it, so a camera far from the origin (Blender's default camera is 11 units away; a model's training
    views about 1.5) or aimed elsewhere rendered a blank or cut-off object without a word. Torch-free."""
    from ...geometry import cameras

    fg = np.argwhere(np.asarray(mask) != 0)
    if not len(fg):
        return
    o, d = cameras.rays_opencv(intr, c2w, fg[:, ::-1] + 0.5)
    o = np.broadcast_to(o, d.shape)
    with np.errstate(divide="ignore", invalid="ignore"):  # slab test; a zero direction component gives +-inf or nan
        t0, t1 = (-scene_box - o) / d, (scene_box - o) / d
        near = np.where(d == 0, np.where(np.abs(o) <= scene_box, -np.inf, np.inf), np.minimum(t0, t1)).max(-1)
        far = np.where(d == 0, np.where(np.abs(o) <= scene_box, np.inf, -np.inf), np.maximum(t0, t1)).min(-1)
    share = float((far >= np.maximum(near, 0.0)).mean())
    if share < MIN_BOX_COVER:
        dist = float(np.linalg.norm(np.asarray(c2w)[:3, 3]))
        raise InputError(f"{where}: from this camera ({dist:.3g} units from the origin) only {100 * share:.0f}% of the "
                         f"mask's parts lie over the model's object box (a cube of half-size {scene_box:g} about the "
                         "world origin; nothing outside it is rendered), so the object would be missing or cut off: "
                         "its objects are centred at the origin and seen from about 1.5 units away (make-shapenet's "
                         "views): aim the camera at the origin from nearer")


MASK_ENCODINGS = ("COLORS", "IDS")
"""How an RGB(A) image holds part ids: the label colours of :func:`palette` (what ``semantic_color``
shows; white and black are background) or grey values equal to the ids (a dataset mask)."""

COLOR_TOLERANCE = 24
"""Largest per-channel difference (0..255) between a pixel and the label colour it is read as."""


def mask_from_rgba(rgba: np.ndarray, labels: tuple[int, ...], encoding: str, where: str) -> np.ndarray:
    """(H, W, 3|4) uint8 image -> (H, W) uint8 part ids. Pixels with alpha < 128 are background.

    COLORS: each colour is read as the id (0..255) whose colour (:func:`palette`; white and black for
    background) is nearest, within :data:`COLOR_TOLERANCE`, a known label winning a tie; so a colour of a label
    the checkpoint does not know reads as that label, which the check names, never as a known label whose
    colour is a few steps away. A colour near none is an InputError. IDS: the grey value is the id (the image
    must be grey). Labels are checked by :func:`check_input_mask`.
    """
    img = np.asarray(rgba)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype != np.uint8:
        raise InputError(f"{where}: expected an 8-bit RGB or RGBA image")
    if encoding not in MASK_ENCODINGS:
        raise InputError(f"unknown mask encoding {encoding!r}; choose one of {list(MASK_ENCODINGS)}")
    rgb = img[..., :3].astype(np.int32)
    clear = img[..., 3] < 128 if img.shape[2] == 4 else np.zeros(img.shape[:2], bool)
    if encoding == "IDS":
        grey = (rgb[..., 0] == rgb[..., 1]) & (rgb[..., 1] == rgb[..., 2])
        if not (grey | clear).all():
            raise InputError(f"{where} has coloured pixels; a part-id image is grey (value = id): "
                             "read it as label colours instead")
        return np.where(clear, 0, rgb[..., 0]).astype(np.uint8)
    packed = (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]
    uniq, inv = np.unique(packed, return_inverse=True)
    cols = np.stack([(uniq >> 16) & 255, (uniq >> 8) & 255, uniq & 255], -1)
    ref_ids = np.array([0, 0, *range(1, 256)])
    refs = np.array([(255, 255, 255), (0, 0, 0), *[palette(v) for v in range(1, 256)]], np.int32)
    dist = np.abs(cols[:, None, :] - refs[None]).max(-1)
    # a known label wins a tie: half a step more for the others
    dist2 = 2 * dist + ~np.isin(ref_ids, [0, *labels])[None]
    best = dist2.argmin(1)
    ids = np.where(dist[np.arange(len(uniq)), best] <= COLOR_TOLERANCE, ref_ids[best], -1)
    out = np.where(clear, 0, ids[inv.reshape(packed.shape)])
    own = np.where(clear, 0, dist[np.arange(len(uniq)), best][inv.reshape(packed.shape)])
    ref = np.where(clear[..., None], 255, refs[best][inv.reshape(packed.shape)])
    edges = _blend_edges(rgb, out, own, ref, clear)  # (an edge pixel of two labels: the nearer of the two)
    if edges is not None:
        out = out.copy()
        out[edges[0], edges[1]] = edges[2]
    bad = out < 0
    if bad.any():
        y, x = np.argwhere(bad)[0]
        raise InputError(f"{where}: {int(bad.sum())} pixels have colours of no label, e.g. {tuple(img[y, x, :3])} at "
                         f"x={x}, y={y} (paint with the label colours and a hard brush)")
    return out.astype(np.uint8)


EDGE_REACH = 3
"""How far (pixels, in x and y) :func:`_blend_edges` looks for the labels an edge pixel blends (a 2x Lanczos
downscale rings 3 pixels out from an edge)."""


def _blend_edges(rgb: np.ndarray, ids: np.ndarray, own: np.ndarray, ref: np.ndarray, clear: np.ndarray):
    """The edge pixels of a soft brush, anti-aliasing or a resized semantic map, and the labels to read them as.

    An edge pixel holds no label's colour exactly, and its nearest label is none of the labels held exactly by
    pixels near it (up to :data:`EDGE_REACH` away). The nearest colour read such pixels as some third label (the
    palette is dense: 77 labels in the shipped model, so a car's edge read as 'telephone/button' with no word), or
    as no label (refused: every resized map was). They are read as one of the labels near them: the nearer end of
    the blend of two of them that fits the colour best (or the nearest one's colour), where two labels or more are
    near (an edge between parts; a junction of three blends three colours) or that fit is within
    :data:`COLOR_TOLERANCE`; a colour far from every blend inside one part is a painting mistake and stays refused.
    Pixels of a label's exact colour are never edges (a hard-painted mask's one-pixel parts stay); a mask with no
    exact colour (a JPEG) is read by nearest colour as before. ``ids`` (-1: no label), ``own`` (distance to the
    nearest label's colour) and ``ref`` (that colour) per pixel. None, or (ys, xs, labels)."""
    exact = (own == 0) & ~clear
    cand = (own > 0) & ~clear
    if not exact.any() or not cand.any():
        return None
    r, (h, w) = EDGE_REACH, ids.shape
    ys, xs = np.nonzero(cand)
    me = ids[ys, xs]
    c = rgb[ys, xs].astype(np.float64)
    ends, near_of = [], {}  # (label, its exact colour) as the mask holds them; where each label is near
    for v in np.unique(ids[exact]):
        held = exact & (ids == v)
        pad = np.pad(held, r)
        near = np.zeros((h, w), bool)
        for dy in range(2 * r + 1):
            for dx in range(2 * r + 1):
                near |= pad[dy:dy + h, dx:dx + w]
        near_of[int(v)] = near[ys, xs]
        ends += [(int(v), col.astype(np.float64)) for col in np.unique(ref[held], axis=0)]
    count = sum(near_of.values())
    mine = np.zeros(len(ys), bool)  # its own label is held near it
    for v, near in near_of.items():
        mine |= near & (me == v)
    todo = (count >= 1) & ~mine
    best, nearer = np.full(len(ys), np.inf), np.full(len(ys), -1)
    for v, col in ends:
        d = np.where(todo & near_of[v], np.abs(c - col).max(-1), np.inf)
        better = d < best
        best, nearer = np.where(better, d, best), np.where(better, v, nearer)
    for i, (va, ca) in enumerate(ends):
        for vb, cb in ends[i + 1:]:
            ok = todo & near_of[va] & near_of[vb] & (va != vb)
            if not ok.any():
                continue
            seg = cb - ca
            t = np.clip(((c - ca) @ seg) / max(float(seg @ seg), 1e-9), 0.0, 1.0)
            fit = np.where(ok, np.abs(c - (ca + t[:, None] * seg)).max(-1), np.inf)
            better = fit < best
            best = np.where(better, fit, best)
            nearer = np.where(better, np.where(t < 0.5, va, vb), nearer)
    edge = todo & ((best <= COLOR_TOLERANCE) | (count >= 2))
    return (ys[edge], xs[edge], nearer[edge]) if edge.any() else None


def label_colors(labels: tuple[int, ...], names: tuple[str, ...]) -> list[tuple[int, str, str]]:
    """(id, name, '#rrggbb') of each label: the colours to paint a mask with."""
    return [(int(v), str(n), "#%02x%02x%02x" % palette(int(v))) for v, n in zip(labels, names)]


@dataclass
class Prepared:
    info: CheckpointInfo
    mask: np.ndarray
    edits: list = field(default_factory=list)
    c2w: np.ndarray | None = None
    intr: object = None
    views: list = field(default_factory=list)
    """(intrinsics, OpenCV camera-to-world) of every view to render."""


def input_folders(mask: Path, pose: Path) -> dict[str, Path]:
    """The folders the output must not be: those holding the mask and the pose and, for a dataset object's
    ``mask/NNNNNN.png`` or ``pose/NNNNNN.txt``, the object folder, whose ``rgb/`` and ``pose/`` files the
    render's own would replace."""
    folders = {"mask's": mask.parent, "pose's": pose.parent}
    for what, p, sub in (("mask's object", mask, "mask"), ("pose's object", pose, "pose")):
        if p.parent.name == sub:
            folders[what] = p.parent.parent
    return folders


def check_render_options(views: int, blend_steps: int, mix: float, seeds: dict, quality: str) -> None:
    """The render options' checks (``seeds``: flag -> seed or None); InputError with the CLI's message."""
    if views < 1 or blend_steps < 2:
        raise InputError("--views must be >= 1 and --blend-steps >= 2")
    if not 0.0 <= mix <= 1.0:
        raise InputError("--mix must lie in [0, 1]")
    for flag, seed in seeds.items():
        if seed is not None and not 0 <= seed <= SEED_MAX:
            raise InputError(f"{flag} {seed}: a seed must lie in 0 .. {SEED_MAX}")
    from ..registry import QUALITY_LEVELS

    if quality not in QUALITY_LEVELS:
        raise InputError(f"--quality must be one of {', '.join(QUALITY_LEVELS)}, got {quality!r}")


def prepare_mask(info: CheckpointInfo, mask, edits: tuple[str, ...], c2w: np.ndarray, intr, views: int,
                 mask_where: str, pose_where: str) -> Prepared:
    """The checks of a mask (part ids) and its camera (OpenCV camera-to-world, intrinsics at the mask's size),
    shared by the files (:func:`prepare`) and the arrays (``api.render_mask_views``); the views are the orbit of
    ``views`` about the world z axis (a caller with target cameras replaces them)."""
    mask, parsed = check_input_mask(mask, info, mask_where, edits)
    check_camera_sees_box(mask, intr, c2w, info.scene_box, pose_where)
    return Prepared(info, mask, parsed, c2w, intr, [(intr, c) for c in orbit_poses(c2w, views)])


def prepare(req: RenderRequest) -> Prepared:
    """Every check that needs no torch; InputError / OutputError naming the first problem."""
    from ...guards import check_folder_writable, check_not_input

    out = Path(req.out)
    check_not_input(out, input_folders(Path(req.mask), Path(req.pose)))  # whatever --force says
    # an --out under a file was a FileExistsError traceback after the model loaded; a file as --out said "use --force"
    check_folder_writable(out, "output")
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not req.force)):
        raise OutputError(f"output {out} exists and is not an empty folder (use --force to write into it)")
    check_render_options(req.views, req.blend_steps, req.mix,
                         {"--style-seed": req.style_seed, "--mix-seed": req.mix_seed, "--blend": req.blend},
                         req.quality)
    info = checkpoint_info(Path(req.checkpoint))
    mask = read_mask_png(Path(req.mask))
    c2w, intr = mask_camera_files(Path(req.pose), req.intrinsics, info.size, req.fov)
    p = prepare_mask(info, mask, req.edits, c2w, intr, req.views, f"mask {req.mask}", f"pose {req.pose}")
    if req.targets:
        from ...datasets.novel_views import read_targets

        targets, _ = read_targets(Path(req.targets))
        p.views = [(t.intrinsics, check_pose(t.c2w_opencv, f"target {t.name!r}")) for t in targets]
    return p


def mask_camera_files(pose: Path, intrinsics: str, size: int, fov: float = 40.0):
    """(OpenCV camera-to-world, intrinsics at size x size) of a mask's camera from an SRN pose file and
    intrinsics file ('' = the pose's object folder's ``intrinsics.txt``, else ``fov`` degrees)."""
    from ...datasets import format as DF
    from ...geometry import cameras

    pose = Path(pose)
    if pose.is_dir():  # a folder "did not exist"
        raise InputError(f"pose {pose} is a folder, not a pose file (the mask's camera needs one)")
    if not pose.is_file():
        raise InputError(f"pose {pose} does not exist (the mask's camera needs a pose)")
    try:
        c2w = DF.read_srn_pose(pose)
    except Exception as e:  # noqa: BLE001
        raise InputError(f"pose {pose} is not a 4x4 camera-to-world matrix: {type(e).__name__}") from None
    c2w = check_pose(c2w, f"pose {pose}")
    intr_path = Path(intrinsics) if intrinsics else pose.parent.parent / "intrinsics.txt"
    if intrinsics and not intr_path.is_file():
        raise InputError(f"intrinsics {intr_path} do not exist")
    if intr_path.is_file():
        intr = DF.read_srn_intrinsics(intr_path)
        if (intr.width, intr.height) != (size, size):
            if intr.width != intr.height:
                raise InputError(f"intrinsics {intr_path} are {intr.width}x{intr.height}; the mask is square")
            intr = intr.scaled(size / intr.width)
    else:
        if not 1.0 <= fov <= 170.0:
            raise InputError("--fov must be in [1, 170] degrees")
        intr = cameras.intrinsics_from_fov(math.radians(fov), size, size)
    return c2w, intr


RENDER_FOLDERS = ("rgb", "semantic", "semantic_color", "pose", "blend")
"""The folders of per-view files a render writes (``NNNNNN.png`` / ``NNNNNN.txt``)."""


def remove_earlier_render(out: Path) -> None:
    """Remove the files of an earlier render in ``out`` (the views and blend images its ``sem2nerf.json`` counts):
    with ``--force`` its views beyond this render's count and its ``blend/`` were left beside the new files, and
    ``sem2nerf.json`` then described a folder holding two renders. Only the names it wrote go (other files in
    ``out``, a dataset's views past its count among them, are the user's); called when the new render is complete,
    so an interrupted one leaves the earlier render whole."""
    out = Path(out)
    try:
        earlier = json.loads((out / "sem2nerf.json").read_text())
        views, blends = int(earlier.get("views", 0)), int(earlier.get("blend_steps", 0) or 0)
    except (OSError, ValueError, TypeError, AttributeError):
        return  # none there (or not one of ours): nothing is removed
    names = [(sub, f"{k:06d}.{'txt' if sub == 'pose' else 'png'}") for sub in RENDER_FOLDERS[:4] for k in range(views)]
    names += [("blend", f"{j:06d}.png") for j in range(blends)]
    for sub, name in names:
        (out / sub / name).unlink(missing_ok=True)
    for sub in RENDER_FOLDERS:
        d = out / sub
        if d.is_dir() and not any(d.iterdir()):
            d.rmdir()
    for name in ("mask_input.png", "sem2nerf.json"):
        (out / name).unlink(missing_ok=True)


def mix_styles(a, b, t: float):
    """The linear blend ``(1 - t) a + t b`` of two style codes (the blend sequence and ``--mix``)."""
    return (1 - t) * a + t * b


def load_render_model(model_file: Path, device: str, quality: str = "full"):
    """(model, its saved config) of a Sem2NeRF checkpoint, eval mode, its samples per ray set for ``quality``
    (``models.registry.quality_overrides``): how ``sem2nerf render`` and ``api.load_model`` load one."""
    from dataclasses import replace

    from ...training.sem2nerf import load_sem2nerf
    from ..registry import quality_overrides

    model, cfg, _ = load_sem2nerf(Path(model_file), device)
    model.cfg = replace(cfg, **quality_overrides(cfg, quality))
    return model, cfg


@dataclass
class RenderedView:
    """One view of :func:`render_prepared`: the arrays ``sem2nerf render`` writes for view k."""

    rgb: np.ndarray
    """(H, W, 3) float32 in [0, 1]: the model's colour on its background (white for a white-background model)."""
    alpha: np.ndarray
    """(H, W) float32 in [0, 1]: the model's opacity."""
    rgba: np.ndarray
    """(H, W, 4) uint8 straight RGBA: ``rgb/k.png``."""
    semantic: np.ndarray
    """(H, W) uint8 part ids (argmax of the semantic map): ``semantic/k.png``."""
    semantic_color: np.ndarray
    """(H, W, 3) uint8, the ids in their label colours (:func:`palette`): ``semantic_color/k.png``."""
    c2w: np.ndarray
    """OpenCV camera-to-world: ``pose/k.txt``."""
    intrinsics: object


def render_prepared(model, p: Prepared, style_seed: int | None = None, mix_seed: int | None = None,
                    mix: float = 0.0, blend: int | None = None, blend_steps: int = 5):
    """The render shared by :func:`render_from_mask` (files) and ``api.render_mask_views`` (arrays): a generator of
    ``("view", k, RenderedView)`` for every view of ``p``, then with ``blend`` ``("blend", j, (H, W, 3) float32)``
    for the input view along the style blend (``blend_steps`` images, ends included). Options as
    :class:`RenderRequest`'s. Touches no global torch state (threads, RNG: the styles draw from their own
    generators)."""
    import torch

    from .inputs import build_inputs

    labels = tuple(int(v) for v in p.info.labels)
    device = model.style_mean.device
    labels_t = torch.as_tensor(labels)
    white = bool(model.cfg.white_background)
    with torch.no_grad():
        code = model.encode(torch.from_numpy(build_inputs(p.mask, labels))[None].to(device), p.c2w[None], p.intr)
        style = model.style_from_seed(style_seed) if style_seed is not None else model.default_style()
        if mix_seed is not None and mix > 0:
            style = mix_styles(style, model.style_from_seed(mix_seed), mix)
    from ...datasets import format as DF

    for k, (intr, c2w) in enumerate(p.views):
        img = model.render_image(intr, c2w, code, style)
        rgb, acc = img["rgb"].clamp(0, 1).cpu().numpy(), img["acc"].clamp(0, 1).cpu().numpy()
        # straight colour (the model's is composited on its background), as synthesize writes it
        rgba = DF.straight_rgba(rgb, acc, 1.0 if white else 0.0)
        ids = labels_t[img["semantic"].argmax(-1).cpu()].numpy().astype(np.uint8)
        yield "view", k, RenderedView(rgb.astype(np.float32), acc.astype(np.float32), rgba, ids, colorize(ids),
                                      np.asarray(c2w), intr)
    if blend is not None:
        with torch.no_grad():
            s1 = model.style_from_seed(blend)
        for j, a in enumerate(np.linspace(0.0, 1.0, blend_steps)):
            img = model.render_image(p.intr, p.c2w, code, mix_styles(style, s1, float(a)))
            yield "blend", j, img["rgb"].clamp(0, 1).cpu().numpy().astype(np.float32)


def render_from_mask(req: RenderRequest):
    """Progress generator (events in images); returns the summary dict written to sem2nerf.json."""
    p = prepare(req)
    from ...datasets import format as DF
    from ...threads import set_torch_threads

    set_torch_threads(req.threads)
    from ...synthesis.views import resolve_device

    device = str(resolve_device(req.device))
    model, cfg = load_render_model(p.info.model_file, device, req.quality)
    out = Path(req.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        n = len(p.views)
        total = n + (req.blend_steps if req.blend is not None else 0)
        DF.write_png(tmp / "mask_input.png", p.mask)
        for kind, k, res in render_prepared(model, p, req.style_seed, req.mix_seed, req.mix, req.blend,
                                            req.blend_steps):
            if kind == "view":
                DF.write_png(tmp / "rgb" / f"{k:06d}.png", res.rgba)
                DF.write_png(tmp / "semantic" / f"{k:06d}.png", res.semantic)
                DF.write_png(tmp / "semantic_color" / f"{k:06d}.png", res.semantic_color)
                DF.write_srn_pose(tmp / "pose" / f"{k:06d}.txt", res.c2w)
                yield Progress(k + 1, total, f"view {k + 1}/{n}")
            else:
                DF.write_png(tmp / "blend" / f"{k:06d}.png", DF.to_uint8(res))
                yield Progress(n + k + 1, total, f"blend {k + 1}/{req.blend_steps}")
        summary = {"checkpoint": str(p.info.model_file), "mask": str(req.mask), "pose": str(req.pose),
                   "views": n, "targets": str(req.targets), "image_size": cfg.image_size, "labels": list(cfg.labels),
                   "label_names": list(cfg.label_names), "edits": [list(e) for e in p.edits],
                   "style": "mean" if req.style_seed is None else f"seed {req.style_seed}",
                   "mix_seed": req.mix_seed, "mix": req.mix if req.mix_seed is not None else 0.0,
                   "blend_to_seed": req.blend, "blend_steps": req.blend_steps if req.blend is not None else 0,
                   "quality": req.quality, "samples_per_ray": [model.cfg.n_coarse, model.cfg.n_fine],
                   "intrinsics": {"fx": p.intr.fx, "fy": p.intr.fy, "cx": p.intr.cx, "cy": p.intr.cy}}
        (tmp / "sem2nerf.json").write_text(json.dumps(summary, indent=2) + "\n")
        remove_earlier_render(out)
        DF.move_into(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return summary
