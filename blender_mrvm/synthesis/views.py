"""Novel views from posed reference images with a trained checkpoint (bpy-free).

The core of ``python -m blender_mrvm synthesize`` and of the add-on's Synthesize operator (which
runs that command in the worker process). :func:`synthesize_views` is a progress generator:

1. checks everything before writing anything: the targets file (``datasets/novel_views.py``), the
   reference folder (our dataset format: a rendered object, a recovered capture, or scene cameras
   exported by the add-on; every chosen view needs an image and a pose), the checkpoint (it must
   load, be a ``blender_mrvm`` model of a format version this code reads, and match its config;
   none given, or ``shipped:auto``: the shipped model that fits the cameras and the device,
   ``models.pretrained.auto_model``), and the device;
2. encodes the references once and renders every target in chunks of rays (one progress event per
   chunk, so a cancel lands within a chunk), rays that miss the object's box are background and
   are not evaluated;
3. writes, for target i, ``rgb/<i:06d>.png`` (RGBA: straight colour, alpha = the model's
   accumulated opacity, so compositing over white gives back the model's output) and, when asked,
   ``depth/<i:06d>.exr`` (planar z-depth in scene units along the camera axis, channel "Y", 0 where
   the accumulated opacity is below one half), plus ``synthesis.json`` (what was run) and a copy of
   ``targets.json`` (the cameras). Everything is
   written into a temporary folder beside ``out`` and moved into place at the end: an error or a
   cancel leaves ``out`` as it was, and no folder the run created.

The object's box (the model clips rays to it and works in the box's normalised frame) comes from
the reference folder: ``meta.json`` ``bbox`` (renders; a recovered capture's scene box from its sparse points),
``bound_radius``, a normalised capture without a box (its object of interest fits the unit sphere), else where the
reference cameras' optical axes meet (radius half the camera distance). ``bbox`` in the config overrides all of
them. An orbit looks at the capture's object (``object_bbox``), not at its scene box's centre.
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..datasets import format as F
from ..datasets.novel_views import MAX_POOL, MAX_REFERENCES, Target, read_targets, write_targets
from ..errors import InputError
from ..geometry import cameras as C
from ..progress import Progress, ProgressGen, as_step_of

ALPHA_DEPTH_THRESHOLD = 0.5
"""Depth is written where the accumulated opacity reaches this (0 = background elsewhere)."""
REPROJECT_MODES = ("auto", "on", "off")


@dataclass(frozen=True)
class SynthesisConfig:
    """One synthesis run."""

    references: Path
    """Object folder of our dataset format (render, recovered capture, or exported scene cameras)."""
    targets: Path
    """``targets.json`` naming the views to synthesize (``datasets/novel_views.py``)."""
    out: Path
    """Output folder: rgb/, depth/ and synthesis.json."""
    views: tuple[int, ...] = ()
    """Reference view indices; empty = every view of the folder (at most ``MAX_POOL``)."""
    checkpoint: Path | None = None
    """Model checkpoint (file, checkpoint folder or run folder, or ``shipped:<name>``); None = ``shipped:auto``,
    the shipped object model that fits the cameras (``models.pretrained.auto_model``)."""
    device: str = "auto"
    """auto (CUDA when available), cpu or cuda[:N]."""
    depth: bool | None = None
    """Write depth maps; None = as the targets file asks."""
    chunk_rays: int = 0
    """Rays per forward pass (0 = the model config's ``render.chunk_rays``, at least ``models.base.GPU_CHUNK_RAYS`` on a GPU)."""
    ref_size: int = 0
    """Reference size: N > 0 resizes them so their longer side has N pixels; 0 (auto) shrinks references
    larger than the images the model was trained on (the checkpoint's ``train_image_size``) to that
    size, since its convolutional features are tuned to that scale; -1 keeps the first view's size."""
    bbox: tuple | None = None
    """Object box ((min x, y, z), (max x, y, z)) in world units; None = from the references."""
    threads: int = 0
    """CPU threads (0 = every core): ray chunks rendered side by side, one core each (``threads.render_workers``)."""
    quality: str = "full"
    """Speed/quality level (``registry.quality_overrides``): ``full`` renders as the model was trained,
    ``preview`` with half the samples per ray (~1.6x faster, a few tenths of a dB less)."""
    precision: str = "auto"
    """``auto`` (bf16 on a GPU; on the CPU int8 for models wide enough for it to pay, else fp32), fp32, ``bf16`` /
    ``fp16`` autocast for the model's forward passes, or ``int8`` linear layers (the CPU only;
    ``models/precision.py``): on an H100 every shipped model scores the same in bf16 and `quality` renders 1.21x
    faster; fp16 needs a GPU; on the CPU bf16 is no faster (a note says so) and int8 renders `quality` 1.3x faster
    at the same scores. synthesis.json records the precision it ran at."""
    skip_empty: str = "cull"
    """Empty-space skipping inside the object's box (``models/hull.py``) when the references have object
    masks (``mask/*.png``): ``cull`` (default: rays that cannot meet the references' visual hull are
    background, not evaluated; same images to < 1/255, except under int8: ``models/precision.py``), ``tighten``
    (also shorten the rays to the hull:
    faster sampling, but models trained on box-length rays lose PSNR), ``off``."""
    force: bool = False
    """Write into an output folder that already holds files (same-named files are replaced)."""
    adapt: Any = None
    """A :class:`training.adapt.AdaptConfig`: before rendering, fine-tune a copy of the model on the references
    alone (leave one out); None or 0 steps = off."""
    nearest: int = 0
    """References per target: each target is rendered from its ``nearest`` nearest references (by camera
    direction and distance, :func:`nearest_views`); 0 = every reference when there are at most
    :data:`DENSE_NEAREST` (5), else each view's 5 nearest. A speed/accuracy knob (docs/guide/novel_views.md,
    "Many references")."""
    reproject: str = "auto"
    """Lay the references' own colours over each view where they see its surface, through the model's depth
    (``models/reproject.py``; each reference used is rendered once more for its depth): ``on``, ``off``, or
    ``auto`` (the default): on when each view is rendered from its nearest of more references (a dense capture,
    where a reference sits close to every view) by a model that predicts its colours at ``quality`` full, off
    otherwise, for GPNR, whose colour already is a blend of the references', and at ``preview`` (it about doubles
    the time of a view: docs/guide/novel_views.md, "Many references")."""

    compile: bool = False
    """``torch.compile`` the model's networks (not the image encoder; ``models.registry.compile_networks``) once
    loaded and adapted. Experimental: `bench model` renders `fast` at 256 px at 41-47 views/s compiled against 20
    eager on an H100 (docs/bench_gpu/session23), but timed through synthesis (session 26, same GPU, the shipped
    `balanced`, a 24-view orbit at 256 px, empty-space skipping on) a view took 0.40 s compiled against 0.24 s
    eager, after a first view of 33 s (docs/bench_gpu/session26). That run still marched the hull on the host;
    it runs on the device since, untimed there. On a 2-core CPU compiling takes minutes for ~15 % less time a
    view."""

    config_label = "synthesis"  # not a field: how messages name the fields

    def __post_init__(self) -> None:
        _validate_config(self)


def _validate_config(c: SynthesisConfig) -> None:
    """One-line InputError for a value that cannot work, before anything is read or written."""
    from .. import validation as V

    V.check_types(c)
    if any(v < 0 for v in c.views):
        raise InputError(f"reference views must be view numbers >= 0, got {list(c.views)}")
    V.check_device_name("synthesis.device", c.device)
    from ..models.precision import check_precision

    check_precision("--precision (synthesis.precision)", c.precision, auto=True)
    if c.precision == "int8" and c.compile:
        raise InputError("--precision int8 and --compile do not combine (torch.compile takes float layers); "
                         "leave one out")
    V.check_ref_size("--ref-size (synthesis.ref_size)", c.ref_size)
    V.check_count("--chunk (synthesis.chunk_rays)", c.chunk_rays, 0, 1 << 22)
    V.check_count("--nearest (synthesis.nearest)", c.nearest, 0, MAX_REFERENCES)
    V.check_count("--threads (synthesis.threads)", c.threads, 0, 4096)
    from ..models.hull import MODES

    from ..models.registry import QUALITY_LEVELS

    if c.quality not in QUALITY_LEVELS:
        raise InputError(f"--quality (synthesis.quality) must be one of {', '.join(QUALITY_LEVELS)}, got {c.quality!r}")
    if c.reproject not in REPROJECT_MODES:
        raise InputError(f"--reproject (synthesis.reproject) must be one of {', '.join(REPROJECT_MODES)}, "
                         f"got {c.reproject!r}")
    if c.skip_empty not in MODES:
        raise InputError(f"--skip-empty (synthesis.skip_empty) must be one of {', '.join(MODES)}, got {c.skip_empty!r}")
    from ..training.adapt import AdaptConfig

    if c.adapt is not None and not isinstance(c.adapt, AdaptConfig):
        raise InputError(f"synthesis.adapt must be an AdaptConfig or None, got {type(c.adapt).__name__}")


@dataclass
class References:
    """Reference views ready for the model."""

    folder: Path
    views: tuple[int, ...]
    """View indices in the folder."""
    images: np.ndarray
    """(V, H, W, 3) float32 in [0, 1], composited on white."""
    c2w: list
    """V OpenCV camera-to-world poses."""
    intrinsics: list
    """V intrinsics at the images' (common) size."""
    bbox: tuple
    """(min xyz, max xyz) float64."""
    bbox_source: str
    """Where the box came from."""
    masks: np.ndarray | None = None
    """(V, H, W) bool object masks at the images' size when every reference has one (``mask/``), else None."""
    background: str = "white"
    """What the views show (meta.json ``background``): 'white' (an object on white) or 'scene'."""
    subject: tuple | None = None
    """(min xyz, max xyz) of what the photos are of, where it is not ``bbox``: a recovered capture's ``bbox`` is the
    scene's (the sparse points: what models clip rays to), its ``object_bbox`` the unit sphere of the normalization
    round the object the cameras circle. None: ``bbox``."""

    def subject_centre(self) -> np.ndarray:
        """The point new views (an orbit) look at: the centre of :attr:`subject`, or of ``bbox``."""
        lo, hi = self.subject if self.subject is not None else self.bbox
        return 0.5 * (np.asarray(lo, np.float64) + np.asarray(hi, np.float64))

    def subset(self, keep: Sequence[int]) -> "References":
        """The references at positions ``keep``."""
        keep = list(keep)
        return References(self.folder, tuple(self.views[k] for k in keep), self.images[keep],
                          [self.c2w[k] for k in keep], [self.intrinsics[k] for k in keep], self.bbox, self.bbox_source,
                          None if self.masks is None else self.masks[keep], self.background, self.subject)


def nearest_views(ref_c2w: Sequence[np.ndarray], target_c2w: np.ndarray, centre, k: int) -> tuple[int, ...]:
    """Positions (sorted) of the ``k`` reference cameras nearest the target: by the angle between their
    directions from the object's centre, plus the log-ratio of their distances to it (a view from the
    same side at the same distance is nearest)."""
    c = np.asarray(centre, np.float64)
    tv = C.as_pose(target_c2w)[:3, 3] - c
    td = np.linalg.norm(tv)
    scores = []
    for i, p in enumerate(ref_c2w):
        rv = C.as_pose(p)[:3, 3] - c
        rd = np.linalg.norm(rv)
        cos = float(np.clip(rv @ tv / max(rd * td, 1e-12), -1.0, 1.0))
        scores.append((np.arccos(cos) + abs(np.log(max(rd, 1e-12) / max(td, 1e-12))), i))
    return tuple(sorted(i for _, i in sorted(scores)[:k]))


# ---------------------------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------------------------

def colour_lenders(ref_c2w: Sequence[np.ndarray], target_c2w: np.ndarray, centre, cfg) -> tuple[int, ...]:
    """Positions of the references whose colours a view takes (``models/reproject.py``): its ``cfg.max_refs``
    nearest (:func:`nearest_views`)."""
    return nearest_views(ref_c2w, target_c2w, centre, min(cfg.max_refs, len(ref_c2w)))


def resolve_device(name: str):
    """A torch device from auto / cpu / cuda[:N]; InputError when CUDA is asked for but absent."""
    import torch

    n = (name or "auto").strip().lower()
    if n == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if n == "cpu":
        return torch.device("cpu")
    if n == "cuda" or n.startswith("cuda:"):
        if not torch.cuda.is_available():
            raise InputError("device cuda was asked for, but torch sees no CUDA GPU here (use --device cpu or auto)")
        dev = torch.device(n)
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise InputError(f"device {n}: torch sees only {torch.cuda.device_count()} CUDA GPU(s)")
        return dev
    raise InputError(f"unknown device {name!r}; choose auto, cpu or cuda")


def load_checkpoint(path: Path | None, device="cpu"):
    """(model in eval mode, model config, metadata, path) from a checkpoint; one-line InputError when it
    does not load, is not a blender_mrvm model, has a newer format version, or does not match its config."""
    from ..models.pretrained import resolve_checkpoint
    from ..training.checkpoint import load_model

    path = resolve_checkpoint(path)
    try:
        model, cfg, meta = load_model(path, "cpu")
    except InputError:
        raise
    except (KeyError, TypeError, ValueError) as e:  # metadata that is not a model config
        raise InputError(f"checkpoint {path} has an unreadable model config ({type(e).__name__}: {e})") from None
    except RuntimeError as e:  # strict load: weights do not match the config they were saved with
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"checkpoint {path} does not match its model config: {first}") from None
    except Exception as e:  # safetensors: not a safetensors file, truncated, ...
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"checkpoint {path} does not load: {first}") from None
    model = model.to(device).eval()
    return model, cfg, meta, path


def parse_bbox(values: Sequence[float]) -> tuple:
    """(min, max) from six numbers; InputError for a wrong count or an empty box."""
    v = np.asarray(list(values), dtype=np.float64)
    if v.shape != (6,) or not np.all(np.isfinite(v)):
        raise InputError(f"a box is six finite numbers (min x y z, max x y z), got {list(values)}")
    lo, hi = v[:3], v[3:]
    if np.any(hi <= lo):
        raise InputError(f"box max {hi.tolist()} must exceed its min {lo.tolist()} on every axis")
    return lo, hi


FRAMING_BOXES = ("meta.json bbox", "meta.json bound_radius", "given")
"""The reference boxes (:func:`object_box`'s sources) that bound the object itself, so that a camera's framing
of it means something (``pretrained.auto_model``); the others are guessed from the cameras."""


def object_box(meta: dict, c2w: Sequence[np.ndarray]) -> tuple[tuple, str]:
    """((min, max), source) of the object the references show (see the module doc)."""
    b = meta.get("bbox")
    if b is not None:
        lo, hi = (b["min"], b["max"]) if isinstance(b, dict) else (b[0], b[1])
        return parse_bbox([*lo, *hi]), "meta.json bbox"
    if meta.get("bound_radius"):
        r = float(meta["bound_radius"])
        return parse_bbox([-r, -r, -r, r, r, r]), "meta.json bound_radius"
    if meta.get("kind") == "capture" and meta.get("normalization"):
        return parse_bbox([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]), "normalised capture (unit sphere)"
    from ..capture.align import auto_normalization

    norm = auto_normalization(list(c2w), np.zeros((0, 3)))
    r = 1.0 / norm.scale
    c = norm.centre
    return parse_bbox([*(c - r), *(c + r)]), f"reference cameras ({norm.method}, radius half the camera distance)"


def _resize(img: np.ndarray, w: int, h: int) -> np.ndarray:
    """Anti-aliased bilinear resize of a float (H, W, 3) image."""
    if img.shape[1] == w and img.shape[0] == h:
        return img
    import torch
    import torch.nn.functional as Fn

    t = torch.from_numpy(np.ascontiguousarray(img)).permute(2, 0, 1)[None]
    down = w < img.shape[1] or h < img.shape[0]
    out = Fn.interpolate(t, size=(h, w), mode="bilinear", align_corners=False, antialias=down)
    return out[0].permute(1, 2, 0).clamp(0, 1).numpy()


def trained_size(checkpoint: Path | None) -> int:
    """The longer image side a checkpoint was trained on (its ``train_image_size``), 0 when unknown."""
    from ..models.checkpoint_files import read_header_meta, model_file_of

    from ..models.pretrained import resolve_checkpoint

    try:
        return max(0, int(read_header_meta(model_file_of(resolve_checkpoint(checkpoint))).get("train_image_size", 0)))
    except (InputError, ValueError, OSError):
        return 0  # a bad checkpoint is reported when it is loaded


def reference_sizes(ref_size: int, checkpoint: Path | None) -> tuple[int, int]:
    """``(ref_size, max_size)`` for :func:`load_references` from a :class:`SynthesisConfig` ``ref_size``."""
    if ref_size > 0:
        return int(ref_size), 0
    if ref_size == 0:
        return 0, trained_size(checkpoint)
    return 0, 0


def check_reference_folder(folder: Path, views: Sequence[int] = ()) -> tuple[Any, tuple[int, ...]]:
    """(the folder read by ``datasets.format.read_object``, the chosen view indices) after checking an
    object folder (render, recovered capture or exported scene cameras): it exists, every chosen view
    has an image and a pose, the views are distinct and at most ``MAX_POOL``; no view given = every view
    of the folder. Reads no image. The one owner of these rules (the add-on's panel checks through it
    too)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"reference folder {folder} does not exist")
    ov = F.read_object(folder)
    if not ov.indices:
        rgbs = sorted((folder / "rgb").glob("*.png"))
        if rgbs:
            raise InputError(f"the reference images in {folder} have no poses (no pose/*.txt beside rgb/)")
        raise InputError(f"{folder} holds no reference views (rgb/*.png with pose/*.txt)")
    if not views:
        if len(ov.indices) > MAX_POOL:
            raise InputError(f"{folder} has {len(ov.indices)} views; choose at most {MAX_POOL} "
                             f"reference views (e.g. --views 0,1)")
        views = tuple(ov.indices)
    views = tuple(int(v) for v in views)
    if len(views) > MAX_POOL:
        raise InputError(f"at most {MAX_POOL} reference views, got {len(views)}")
    if len(set(views)) != len(views):
        raise InputError(f"reference views must be distinct, got {list(views)}")
    have = set(ov.indices)
    for v in views:
        if v in have:
            continue
        paths = F.view_paths(folder, v)
        if paths["rgb"].is_file():
            raise InputError(f"reference view {v} of {folder} has no pose ({paths['pose'].name} missing)")
        shown = ", ".join(map(str, ov.indices[:12])) + (" ..." if len(ov.indices) > 12 else "")
        raise InputError(f"reference view {v} does not exist in {folder} (it has views {shown})")
    return ov, views


def load_references(folder: Path, views: Sequence[int] = (), ref_size: int = 0, bbox: tuple | None = None,
                    max_size: int = 0, side_limit: int = 0, first_camera_size: int | None = None) -> References:
    """Read the chosen views of an object folder (see :class:`References`); InputError naming what is wrong.

    All references take one size: the first view's, or ``ref_size`` pixels on the longer side when it is
    given, or at most ``max_size`` pixels on the longer side (shrinking only). Each view is resized as it is
    read: 50 photos of 4000x4000 held at full size before resizing took 9.6 GB of float32 pixels (a 6 GiB cap
    failed at the 28th), to be shrunk to 64 px; now one full-size photo is held at a time. Once the first is read,
    InputError when the references would be larger than ``side_limit`` pixels on the longer side (0 = no limit) or
    take more than ``validation.MAX_REFERENCE_BYTES`` (``validation.check_reference_memory``).

    ``first_camera_size`` (None: off): the first view's camera is returned at that size (0 = its image's own,
    ``reference_shape``), its pixels at the others' size: an orbit takes its camera from the first reference
    and only the poses from the rest (:func:`orbit_references`), and each image is read once."""
    from .. import validation as V
    from ..datasets.loaders import to_float_rgb

    folder = Path(folder)
    ov, views = check_reference_folder(folder, views)
    pos = {v: k for k, v in enumerate(ov.indices)}
    imgs, intrs, poses = [], [], []
    first = None  # (view, its intrinsics at its image's size, the common (w, h))
    for v in views:
        k = pos[v]
        path = F.view_paths(folder, v)["rgb"]
        try:
            img = to_float_rgb(ov.rgb(k))
        except MemoryError:
            raise InputError(f"reference image {path} does not fit in memory at its size; shrink the photos "
                             "before synthesizing") from None
        except Exception as e:
            raise InputError(f"cannot read reference image {path}: {e}") from None
        intr = ov.intrinsics_per_view[k] if ov.intrinsics_per_view else ov.intrinsics
        if (img.shape[1], img.shape[0]) != (intr.width, intr.height):
            if abs(img.shape[0] - intr.height * img.shape[1] / intr.width) > 1.0:
                raise InputError(f"reference view {v}: image is {img.shape[1]}x{img.shape[0]} but its camera is "
                                 f"{intr.width}x{intr.height} (different aspect ratio)")
            intr = intr.resized(img.shape[1], img.shape[0])
        # One size for all references: the first view's, or the longer side ref_size.
        if first is None:
            first = (v, intr, reference_shape(intr, ref_size, max_size))
            if first_camera_size is not None:  # the camera as a read at first_camera_size would give it
                s0 = reference_shape(intr, first_camera_size)
                V.check_reference_memory(1, *s0)
                first_camera = intr if (intr.width, intr.height) == s0 else intr.resized(*s0)
            V.check_reference_memory(len(views), *first[2], side_limit)
        w0, h0 = first[2]
        if (intr.width, intr.height) != (w0, h0):
            if abs(intr.height * w0 / intr.width - h0) > 1.0:
                raise InputError(f"reference views {first[0]} and {v} have different aspect ratios "
                                 f"({first[1].width}x{first[1].height} and {intr.width}x{intr.height})")
            img, intr = resize_view(img, intr, w0, h0)
        imgs.append(img)
        intrs.append(intr)
        poses.append(C.as_pose(ov.c2w_opencv[k]))
    w0, h0 = first[2]
    subject = None
    if bbox is not None:
        box, src = parse_bbox([*bbox[0], *bbox[1]]), "given"
    else:
        box, src = object_box(ov.meta, poses)
        ob = ov.meta.get("object_bbox")  # a capture's object, inside its scene box
        if ob is not None:
            try:
                subject = parse_bbox([*ob[0], *ob[1]])
            except (InputError, TypeError, ValueError, IndexError):
                subject = None
    from ..models.background import of_meta

    if first_camera_size is not None:
        intrs[0] = first_camera
    images = np.empty((len(imgs), h0, w0, 3), np.float32)  # (each view copied in: not stacked, then cast again)
    for k in range(len(imgs)):
        images[k] = imgs[k]
        imgs[k] = None
    return References(folder, views, images, poses, intrs, box, src,
                      _reference_masks(folder, ov, [pos[v] for v in views], w0, h0), of_meta(ov.meta), subject)


def _reference_masks(folder: Path, ov, ks: Sequence[int], w: int, h: int) -> np.ndarray | None:
    """Object masks of views ``ks`` at ``w`` x ``h`` (nearest resampling) when every one has a readable
    ``mask/`` image, else None (empty-space skipping is then off; nothing else needs masks)."""
    out = []
    for k in ks:
        path = F.view_paths(folder, ov.indices[k])["mask"]
        if not path.is_file():
            return None
        try:
            m = np.asarray(ov.mask(k))
        except Exception:
            return None
        m = resize_mask((m[..., 0] if m.ndim == 3 else m) > 0, w, h)
        if not m.any():
            return None
        out.append(m)
    return np.stack(out)


def orbit_references(folder: Path, views: Sequence[int], ref_size: int = 0, bbox: tuple | None = None,
                     pose_size: int = 16) -> References:
    """What an orbit (:func:`orbit_targets`) needs of the references, each image read once: every view at
    ``pose_size`` pixels on the longer side (only the poses and the box count), but the first view's camera at
    ``ref_size`` (0 or -1: its image's own size), whose field of view and size the orbit takes. Reading the first
    view twice, at its size and at ``pose_size``, decoded the largest image twice."""
    return load_references(folder, views, pose_size, bbox, first_camera_size=max(0, int(ref_size)))


def resize_mask(mask: np.ndarray, w: int, h: int) -> np.ndarray:
    """A bool object mask at ``w`` x ``h``, conservatively: a pixel is object when any object pixel of the mask
    overlaps it (unchanged when already that size).

    The masks carve the references' visual hull, which must not lose the object: nearest sampling dropped thin
    parts (a chair leg one pixel wide at 64 px falls between the samples at 16 px), and the hull then culled the
    rays through them."""
    from PIL import Image

    mask = np.asarray(mask, bool)
    if mask.shape == (h, w):
        return mask
    area = Image.fromarray(mask.astype(np.float32)).resize((w, h), Image.BOX)  # each pixel: its footprint's mean
    return np.asarray(area) > 1e-6


def reference_shape(intr: C.Intrinsics, ref_size: int = 0, max_size: int = 0) -> tuple[int, int]:
    """(width, height) the references take: ``intr``'s size, or ``ref_size`` pixels on the longer side
    when given, or at most ``max_size`` pixels on the longer side (shrinking only)."""
    w, h = intr.width, intr.height
    if not (ref_size and ref_size > 0) and max_size and max_size > 0 and max(w, h) > max_size:
        ref_size = max_size
    if ref_size and ref_size > 0:
        s = ref_size / max(w, h)
        w, h = max(1, round(w * s)), max(1, round(h * s))
    return int(w), int(h)


def resize_view(img: np.ndarray, intr: C.Intrinsics, w: int, h: int) -> tuple[np.ndarray, C.Intrinsics]:
    """An image and its camera at ``w`` x ``h`` (unchanged when already that size)."""
    if (intr.width, intr.height) == (w, h):
        return img, intr
    return _resize(img, w, h), intr.resized(w, h)


# ---------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------

def encode_references(model, refs: References, device=None):
    """(context, normalised scene) for ``refs``: the references encoded once for every target (on the
    model's device)."""
    return model.encode_world(refs.images, refs.c2w, refs.intrinsics, refs.bbox)


def reference_hull(model, ctx, ns, refs: References, skip: str):
    """The references' visual hull (``models/hull.py``) when ``skip`` is not "off" and every reference has
    a mask, else None (no empty-space skipping)."""
    return model.hull(ctx, refs.masks, ns.box) if refs.masks is not None and skip != "off" else None


def render_target(model, ctx, ns, intr: C.Intrinsics, c2w: np.ndarray, chunk: int, device=None, hull=None,
                  skip: str = "off", workers: int = 1):
    """Progress generator over one view: yields rays finished, returns dict(color (H, W, 3) on white,
    acc (H, W), depth_z (H, W) planar z-depth in world units where acc reaches ALPHA_DEPTH_THRESHOLD (0 elsewhere),
    depth (H, W) the distance along each ray in world units wherever anything was rendered, evaluated rays).

    ``model.image_chunks`` of any model kind (box-clipped rays, misses are background), chunk by chunk
    so a caller can report progress and stop between chunks."""
    import torch

    res = yield from model.image_chunks(ctx, intr, ns.pose(c2w), ns.box, chunk, hull, skip, workers)
    # Distance along the ray (normalised units) -> planar z in world units: z = dist * scale * d_cam.z.
    zdir = torch.from_numpy(C.axis_cosines(intr).astype(np.float32))
    acc = res["acc"]
    depth_z = torch.where(acc >= ALPHA_DEPTH_THRESHOLD, res["depth"] * float(ns.scale) * zdir, torch.zeros_like(acc))
    return {"color": res["color"].numpy(), "acc": acc.numpy(), "depth_z": depth_z.numpy(),
            "depth": (res["depth"] * float(ns.scale)).numpy(),
            "evaluated": res["evaluated"], "rays": res["rays"], "box_rays": res["box_rays"]}


def rgba_image(color_on_white: np.ndarray, acc: np.ndarray, scene: bool = False) -> np.ndarray:
    """uint8 RGBA with straight colour such that compositing over white gives ``color_on_white``.

    ``scene``: the view shows a whole scene (``background: scene``): the colour as it is, opaque.

    Compositing is the dataset format's and Blender's, in linear light (``format.uncomposite``): the straight
    colour s of the model's colour c on white with opacity a has lin(s) = (lin(c) - (1 - a)) / a, so an image plane
    of the file over white in Blender, and the loaders, give back the model's output (with the sRGB numbers'
    (c - (1 - a)) / a, soft edges came out lighter there). It is computed with the 8-bit alpha that is stored, so
    the round trip is exact to within the 8-bit rounding of the colour; where alpha rounds to 0 the colour is kept.
    """
    if scene:
        rgb8 = F.to_uint8(np.clip(color_on_white, 0.0, 1.0))
        return np.concatenate([rgb8, np.full(rgb8.shape[:-1] + (1,), 255, np.uint8)], axis=-1)
    return F.straight_rgba(color_on_white, acc)


# ---------------------------------------------------------------------------------------------
# The run
# ---------------------------------------------------------------------------------------------

@dataclass
class SynthesisSummary:
    """What a run did (also written to ``out/synthesis.json``)."""

    out: Path
    targets: list = field(default_factory=list)
    """Per target: name, files, size, rays evaluated, seconds."""
    seconds: float = 0.0
    device: str = "cpu"
    checkpoint: str = ""
    checkpoint_file: str = ""
    """The model file ``checkpoint`` (a run folder, a name) resolved to: the weights that rendered."""
    bbox: list = field(default_factory=list)
    bbox_source: str = ""
    references: list = field(default_factory=list)
    reference_size: list = field(default_factory=list)
    """[width, height] of the references as the model saw them."""
    background: dict = field(default_factory=dict)
    """What the references show and what the model rendered on (``models/background.py``)."""
    viewpoint_note: str = ""
    """A shipped model named for cameras it does not fit: the default off its training turntable, the any-view or
    quality model on it (``pretrained.viewpoint_note``)."""
    model_choice: str = ""
    """``shipped:auto``'s choice and why (``pretrained.auto_model``); '' for a named checkpoint."""
    reference_colours: dict | None = None
    """The references' colours laid over the views (``models/reproject.py``): the mode, settings and how many
    references were rendered for their depth; None when off."""
    adaptation: dict | None = None
    """The adaptation to the references (``training/adapt.py``), its seconds and a note for the user ('' or
    :func:`training.adapt.few_references_note`); None without."""


def _check_out(out: Path, cfg: SynthesisConfig | None = None) -> None:
    from ..guards import check_folder_writable, check_not_input, check_output_folder, same_path

    ours: tuple[str, ...] = ()
    if cfg is not None:
        check_not_input(out, {"reference": Path(cfg.references)})
        if same_path(Path(cfg.targets), out / "targets.json"):
            ours = ("targets.json",)  # the targets file the run reads may sit in the output folder
    check_output_folder(out, force=bool(cfg and cfg.force), ours=ours)
    check_folder_writable(out)


def _stale_views(out: Path, new: Path) -> list[Path]:
    """The views (``rgb/NNNNNN.png``, ``depth/NNNNNN.exr``) an earlier synthesis left in ``out`` that this one,
    finished in ``new``, does not write: ``--force`` replaces a run's outputs as a whole (an --orbit 6 --depth run
    overwritten by --target-views 2,3 kept four old images and six old depth maps beside the new views, and nothing
    said which belonged to which run). Files of other names are left alone."""
    stale = []
    for sub, suffix in (("rgb", ".png"), ("depth", ".exr")):
        for f in sorted((Path(out) / sub).glob(f"[0-9][0-9][0-9][0-9][0-9][0-9]{suffix}")):
            if not (Path(new) / sub / f.name).exists():
                stale.append(f)
    return stale


def make_folder(path: Path) -> list[Path]:
    """Create the folder ``path`` with its missing parents; return the folders this call created (outermost
    first) for :func:`remove_new_folders` to take back when the command fails."""
    path = Path(path)
    missing, p = [], path
    while not p.exists() and p.parent != p:
        missing.append(p)
        p = p.parent
    path.mkdir(parents=True, exist_ok=True)
    return missing[::-1]


def remove_new_folders(folders: Sequence[Path]) -> None:
    """Remove the folders :func:`make_folder` created, innermost first, those that are empty (a failed
    command leaves no empty folder behind; what anyone put there since stays)."""
    for p in reversed(list(folders)):
        try:
            p.rmdir()
        except OSError:
            return


def synthesize_views(cfg: SynthesisConfig, before_move: Callable[[Path, SynthesisSummary], None] | None = None
                     ) -> ProgressGen:
    """Progress generator (events in rays); returns a :class:`SynthesisSummary`. See the module doc.

    ``before_move(folder, summary)`` runs when every file is written into the temporary folder, before it
    moves into ``out`` (``synthesize --blend`` builds its .blend there): an error it raises leaves ``out``
    as it was, like any other.

    ``out`` is held for the run (``guards.output_lock``; a second synthesis into it is refused, so its checks
    hold until the views are in); the temporary folder is built inside it (one file system, whatever ``out``
    links to; a short name) and what a killed run left there is removed first. Torch's thread count is 1 while it
    renders (``threads.render_workers``) and the caller's again when it ends (a script's had stayed at 1)."""
    import torch

    from ..guards import output_lock, sweep_partials

    threads = torch.get_num_threads()  # (render_workers sets 1: the caller's own count comes back at the end)
    try:
        with output_lock(Path(cfg.out)) as out:
            sweep_partials(out)
            return (yield from _synthesize_views(cfg, before_move))
    finally:
        torch.set_num_threads(threads)


def _synthesize_views(cfg: SynthesisConfig, before_move) -> ProgressGen:
    from ..guards import PARTIAL_PREFIX, same_path
    from ..threads import render_workers

    t0 = time.perf_counter()
    workers = render_workers(cfg.threads)
    out = Path(cfg.out)
    _check_out(out, cfg)
    targets, depth_wanted = read_targets(Path(cfg.targets))
    depth = depth_wanted if cfg.depth is None else bool(cfg.depth)
    from ..models.pretrained import auto_model, default_checkpoint, is_auto, viewpoint_note

    auto = cfg.checkpoint is None or is_auto(cfg.checkpoint)  # its candidates share the default's training size
    size, max_size = reference_sizes(cfg.ref_size, default_checkpoint() if auto else cfg.checkpoint)
    from .. import validation as V

    refs = load_references(Path(cfg.references), tuple(cfg.views), size, cfg.bbox, max_size, V.MAX_REFERENCE_SIDE)
    side = max(refs.intrinsics[0].width, refs.intrinsics[0].height)
    if cfg.ref_size == 0 and max_size and side < max_size:
        raise InputError(f"the reference images are {refs.intrinsics[0].width}x{refs.intrinsics[0].height}, smaller than "
                         f"the {max_size} px this model was trained on; pass --ref-size {max_size} to upsample them "
                         "or --ref-size -1 to use them as they are (in the panel: Reference size Custom "
                         f"{max_size}, or As they are)")
    device = resolve_device(cfg.device)
    from ..models.precision import CPU_BF16_NOTE, check_precision, for_precision, resolve_precision

    check_precision("--precision", cfg.precision, device.type, auto=True)
    cams = ([*refs.c2w, *[t.c2w_opencv for t in targets]], [*refs.intrinsics, *[t.intrinsics for t in targets]],
            refs.bbox, refs.bbox_source in FRAMING_BOXES)
    checkpoint, model_note = cfg.checkpoint, ""
    if auto:
        name, model_note = auto_model(*cams, gpu=device.type == "cuda", background=refs.background)
        checkpoint = f"shipped:{name}"
        print(f"note: {model_note}", file=sys.stderr)
    model, mcfg, meta, ck_path = load_checkpoint(checkpoint, device)
    cfg = replace(cfg, precision=resolve_precision(cfg.precision, device.type, model, compiled=cfg.compile))
    if cfg.precision == "bf16" and device.type == "cpu":
        print(f"note: {CPU_BF16_NOTE}", file=sys.stderr)
    from ..models.background import SCENE, for_rendering
    from ..models.config import merge
    from ..models.registry import quality_overrides

    model.cfg = merge(model.cfg, quality_overrides(model.cfg, cfg.quality))
    bg_note = for_rendering(model, refs.background)  # the data decides; a mismatch is said, never silent
    if bg_note:
        print(f"note: {bg_note}", file=sys.stderr)
    view_note = "" if auto else viewpoint_note(ck_path, *cams)
    if view_note:
        print(f"note: {view_note}", file=sys.stderr)
    per_view = references_per_target(model, len(refs.views), cfg.nearest)
    total = sum(t.intrinsics.width * t.intrinsics.height for t in targets)
    adapt_seconds, adapt_note = None, ""
    if cfg.adapt is not None and cfg.adapt.on:
        from ..training.adapt import few_references_note

        adapt_note = few_references_note(len(refs.views))
        if adapt_note:
            print(f"note: {adapt_note}", file=sys.stderr)
        ta = time.perf_counter()
        model = yield from adapt_to_references(model, refs, cfg.adapt, total, per_view)
        adapt_seconds = time.perf_counter() - ta
    model = for_precision(model, cfg.precision, inplace=True)  # int8: after adaptation, which trains float weights
    if cfg.compile:
        from ..models.registry import compile_networks

        compile_networks(model)  # after adaptation (it trains a copy), before the first view compiles it
    chunk = model.inference_chunk(cfg.chunk_rays if cfg.chunk_rays and cfg.chunk_rays > 0 else None)
    summary = SynthesisSummary(out, device=str(device), checkpoint=str(ck_path),
                               checkpoint_file=str(getattr(model, "checkpoint_file", ck_path)),
                               bbox=[np.asarray(refs.bbox[0]).tolist(), np.asarray(refs.bbox[1]).tolist()],
                               bbox_source=refs.bbox_source, references=[str(refs.folder), list(refs.views)],
                               reference_size=[refs.intrinsics[0].width, refs.intrinsics[0].height],
                               background={"data": refs.background, "white_background": model.white_background,
                                           "note": bg_note}, viewpoint_note=view_note, model_choice=model_note,
                               adaptation=None if adapt_seconds is None else {
                                   **asdict(cfg.adapt), "seconds": round(adapt_seconds, 3), "note": adapt_note})

    renderer = TargetRenderer(model, refs, per_view, cfg.skip_empty, cfg.precision, chunk, device, workers)

    def lenders(c2w) -> list[int]:
        """The references whose colours a view at ``c2w`` takes (:func:`colour_lenders` of those it uses)."""
        used = renderer.refs_for(c2w)
        return [used[i] for i in colour_lenders([refs.c2w[k] for k in used], c2w, renderer.centre, rp_cfg)]

    from ..models.background import blends_references

    rp_cfg = None
    if cfg.reproject == "on" or (cfg.reproject == "auto" and renderer.per_target and not blends_references(model)
                                 and cfg.quality == "full"):
        from ..models.reproject import ReprojectConfig

        rp_cfg = ReprojectConfig()
        needed = sorted(set().union(*(lenders(t.c2w_opencv) for t in targets)))
        total += sum(refs.intrinsics[k].width * refs.intrinsics[k].height for k in needed)
        summary.reference_colours = {"mode": cfg.reproject, **asdict(rp_cfg), "reference_renders": len(needed)}
    yield Progress(0, total, f"encoding {len(refs.views)} reference view{'s' if len(refs.views) != 1 else ''}")

    def render(intr, c2w, msg):
        """Progress generator over one view (:meth:`TargetRenderer.render`): returns (render_target's dict, the
        references used, the hull)."""
        nonlocal done
        gen = renderer.render(intr, c2w)
        while True:
            try:
                done += next(gen)
            except StopIteration as stop:
                return stop.value
            yield Progress(done, total, msg)

    geometry: dict[int, tuple] = {}  # reference -> (distances along its rays, where it shows the object)

    def reference_geometry(k):
        """Progress generator: the model's depth of reference ``k`` (rendered once, from its own nearest)."""
        if k not in geometry:
            res, _, _ = yield from render(refs.intrinsics[k], refs.c2w[k], f"reference {refs.views[k]}: depth")
            seen = refs.masks[k] if refs.masks is not None else res["acc"] >= ALPHA_DEPTH_THRESHOLD
            geometry[k] = C.ray_distances(res["depth_z"], refs.intrinsics[k]).astype(np.float32), seen
        return geometry[k]

    tmp = None
    done = 0
    try:
        tmp = Path(tempfile.mkdtemp(prefix=PARTIAL_PREFIX, dir=out))  # (out is held: output_lock made it)
        for i, t in enumerate(targets):
            ts = time.perf_counter()
            geo, lend = [], []
            if rp_cfg is not None:
                lend = lenders(t.c2w_opencv)
                for k in lend:
                    geo.append((yield from reference_geometry(k)))
            res, used, hull = yield from render(t.intrinsics, t.c2w_opencv, f"view {i + 1}/{len(targets)} ({t.name})")
            extra = {}
            if rp_cfg is not None:
                from ..models import reproject as rp

                res["color"], share = rp.lay_over(res["color"], res["acc"], res["depth"],
                                                  t.c2w_opencv, t.intrinsics, refs.images[lend],
                                                  [refs.c2w[k] for k in lend], [refs.intrinsics[k] for k in lend], geo,
                                                  rp_cfg)
                extra["reference_share"] = round(share, 4)
                extra["colour_views"] = [int(refs.views[k]) for k in lend]
            F.write_png(tmp / t.rgb_path(i), rgba_image(res["color"], res["acc"], refs.background == SCENE))
            files = {"rgb": t.rgb_path(i)}
            if depth:
                F.write_depth(tmp / t.depth_path(i), res["depth_z"].astype(np.float32))
                files["depth"] = t.depth_path(i)
            summary.targets.append({"name": t.name, **files, "width": t.intrinsics.width,
                                    "height": t.intrinsics.height, "rays": res["rays"],
                                    "box_rays": res["box_rays"], "evaluated_rays": res["evaluated"],
                                    "empty_space_skipping": cfg.skip_empty if hull is not None else "off", "seconds": time.perf_counter() - ts,
                                    "reference_views": [int(refs.views[k]) for k in used], **extra})
        summary.seconds = time.perf_counter() - t0
        F.atomic_write_json(tmp / "synthesis.json", _summary_json(summary, meta, mcfg, cfg))
        if not same_path(Path(cfg.targets), out / "targets.json") or depth != depth_wanted:
            # the cameras beside their images, saying whether depth maps were written (--depth over the file's word)
            write_targets(tmp / "targets.json", targets, depth=depth)
        if before_move is not None:
            before_move(tmp, summary)
        if cfg.force:  # views of an earlier synthesis there that this one does not replace would sit beside its own
            for stale in _stale_views(out, tmp):
                stale.unlink()
        F.move_into(tmp, out)
    finally:
        if tmp is not None and tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
        # failed or cancelled: output_lock removes the folder (and parents) it made when they stay empty
    yield Progress(total, total, f"{len(targets)} view{'s' if len(targets) != 1 else ''} written")
    return summary


class TargetRenderer:
    """Views of ``refs`` rendered one target camera at a time, each from the references it uses: all of them, or its
    ``per_view`` nearest when there are more (:func:`nearest_views`); the encoded references of the last set used
    are kept for the next view. The per-view loop of ``synthesize`` and of ``api.render_views`` (one owner: the API's
    views are the CLI's, byte for byte)."""

    def __init__(self, model, refs: References, per_view: int, skip_empty: str, precision: str, chunk: int, device,
                 workers: int = 1):
        self.model, self.refs, self.per_view, self.skip_empty = model, refs, int(per_view), skip_empty
        self.precision, self.chunk, self.device, self.workers = precision, chunk, device, max(1, int(workers))
        self.per_target = len(refs.views) > self.per_view  # more references than a view uses: its nearest
        self.centre = 0.5 * (np.asarray(refs.bbox[0], np.float64) + np.asarray(refs.bbox[1], np.float64))
        # Each view takes its nearest references, but every reference's mask carves the hull (only tighter).
        self.pool_hull = (model.world_hull(refs.masks, refs.c2w, refs.intrinsics, refs.bbox)
                          if self.per_target and refs.masks is not None and skip_empty != "off" else None)
        self._encoded: dict[tuple[int, ...], Any] = {}

    def refs_for(self, c2w) -> tuple[int, ...]:
        """Positions of the references a view at ``c2w`` is rendered from."""
        if self.per_target:
            return nearest_views(self.refs.c2w, c2w, self.centre, self.per_view)
        return tuple(range(len(self.refs.views)))

    def context_for(self, keep: tuple[int, ...]):
        """(encoded references, their count, the hull) of the references ``keep``."""
        from ..models.precision import autocast

        if keep not in self._encoded:
            self._encoded.clear()
            sub = self.refs.subset(keep)
            with autocast(self.precision, self.device.type):
                ctx, ns = encode_references(self.model, sub)
                self._encoded[keep] = ctx, ns, (self.pool_hull if self.pool_hull is not None
                                                else reference_hull(self.model, ctx, ns, sub, self.skip_empty))
        return self._encoded[keep]

    def render(self, intr: C.Intrinsics, c2w: np.ndarray):
        """Generator over one view at ``c2w`` / ``intr``, yielding the rays each step finished (the caller runs
        between steps); returns (:func:`render_target`'s dict, the references used, the hull)."""
        from ..models.precision import autocast

        keep = self.refs_for(c2w)
        ctx, ns, hull = self.context_for(keep)
        gen = render_target(self.model, ctx, ns, intr, c2w, self.chunk, self.device, hull, self.skip_empty,
                            self.workers)
        while True:
            try:
                with autocast(self.precision, self.device.type):  # each step
                    n = next(gen)
            except StopIteration as stop:
                return stop.value, keep, hull
            yield n


DENSE_NEAREST = 5
"""References per view when a synthesis is given more than its model takes (a dense capture: ``--views all``)
and no ``--nearest``. Measured with every other view of 24 at hand (``docs/nearest.md``): more nearest views
raise PSNR with diminishing returns while the time grows about linearly, and past 5-6 LPIPS stops improving
(capture rooms, the sphere rig) or gets worse (turntable objects); 5 is within 0.1-0.5 dB of the best count on
the three sets, LPIPS within 0.004, at a little over half the time of 10."""


def references_per_target(model, available: int, nearest: int = 0) -> int:
    """How many references each target is rendered from: ``nearest`` (at most the ``available`` ones), or 0 =
    every reference when there are at most :data:`DENSE_NEAREST`, else each view's :data:`DENSE_NEAREST` nearest;
    InputError when the model cannot take that many.

    Up to session 54 every reference up to the model's 10 was used: 8 photos around a room gave the room model
    21.25 dB (level with the nearest photo), each view's 5 nearest 24.38 (3 nearest 24.96, 6 22.92): references
    from the far side of a room only add wrong colours. On objects the 5 nearest of 6 or 8 around them are level
    or better (default model +0.14 / +0.23 dB, GPNR -0.08 / +0.02; docs/nearest.md)."""
    if nearest:
        k = min(nearest, available)
    else:
        k = min(available, DENSE_NEAREST, model.max_ref_views)
    if nearest > model.max_ref_views:
        raise InputError(f"--nearest {nearest}: this {model.kind} model takes at most {model.max_ref_views} "
                         "reference views per target")
    model.check_reference_count(k)
    return k


def adapt_to_references(model, refs: References, acfg, total: int, per_view: int = 0) -> ProgressGen:
    """Progress generator (at 0 of ``total`` rays, naming the step); returns a copy of ``model`` fine-tuned
    on ``refs`` (``training/adapt.py``), each step rendering one reference from ``per_view`` others (0 = as
    many as the model takes)."""
    from ..training.adapt import adapt

    return (yield from as_step_of(adapt(model, refs.images, refs.c2w, refs.intrinsics, refs.bbox, acfg, refs.masks,
                                        refs.background, max_refs=per_view), 0, total,
                                  lambda p: f"adapting to the references: step {p.done}/{p.total}"))


def _kind(mcfg) -> str:
    from ..models.registry import kind_of

    return kind_of(mcfg)


def _summary_json(s: SynthesisSummary, meta: dict, mcfg, cfg: SynthesisConfig) -> dict[str, Any]:
    from ..training.provenance import environment, file_sha256

    return {"format": "blender_mrvm.synthesis", "version": 1, "checkpoint": s.checkpoint,
            "checkpoint_step": int(meta["step"]) if str(meta.get("step", "")).isdigit() else None,
            "model": mcfg.name, "model_kind": _kind(mcfg), "device": s.device,
            "quality": cfg.quality, "precision": cfg.precision, "skip_empty": cfg.skip_empty, "nearest": cfg.nearest,
            "compiled": cfg.compile,
            "reference_colours": s.reference_colours,
            "adaptation": s.adaptation,
            "references": {"folder": s.references[0], "views": s.references[1], "size": s.reference_size},
            "bbox": s.bbox, "bbox_source": s.bbox_source, "seconds": s.seconds, "targets": s.targets,
            "background": s.background, "viewpoint_note": s.viewpoint_note, "model_choice": s.model_choice,
            "rgb": ("RGBA PNG, opaque: the whole scene" if s.background.get("data") == "scene" else
                    "RGBA PNG, straight colour, alpha = accumulated opacity (over white = the model's output)"),
            "depth": f"planar z-depth along the camera axis, scene units, channel Y; 0 where alpha < {ALPHA_DEPTH_THRESHOLD}",
            # what repeating it needs: the code (version, commit), libraries, the command (training/provenance.py)
            "checkpoint_file": s.checkpoint_file, "checkpoint_sha256": file_sha256(Path(s.checkpoint_file)),
            "provenance": environment(device=s.device, when=False)}


def targets_from_views(folder: Path, views: Sequence[int]) -> list[Target]:
    """Targets at the cameras of ``views`` of an object folder (the demo and tests score them against the
    folder's own images)."""
    ov = F.read_object(Path(folder))
    pos = {v: k for k, v in enumerate(ov.indices)}
    out = []
    for v in views:
        if v not in pos:
            raise InputError(f"view {v} does not exist in {folder}")
        k = pos[v]
        intr = ov.intrinsics_per_view[k] if ov.intrinsics_per_view else ov.intrinsics
        out.append(Target(f"view {v:03d}", intr, C.as_pose(ov.c2w_opencv[k])))
    return out


def orbit_targets(refs: References, count: int, elevation_deg: float = 20.0, radius: float | None = None,
                  size: int = 0) -> list[Target]:
    """``count`` targets on a circle around the object's centre (:meth:`References.subject_centre`: a capture's
    object, not its scene box), looking at it, with the first
    reference's field of view (unshifted) at ``size`` pixels on the longer side (0 = the references' size).
    ``radius`` defaults to the references' median distance from the centre.

    Both focal lengths scale by the one factor ``size / longer side`` (the pixels keep the reference's
    shape even where rounding the sides changes the aspect ratio a little); the principal point is the
    new frame's centre."""
    from ..geometry.rigs import orbit_poses

    centre = refs.subject_centre()
    if radius is None:
        radius = float(np.median([np.linalg.norm(c[:3, 3] - centre) for c in refs.c2w]))
    k = refs.intrinsics[0]
    w, h = reference_shape(k, size)
    s = size / max(k.width, k.height) if size > 0 else 1.0
    intr = C.Intrinsics(k.fx * s, k.fy * s, w / 2.0, h / 2.0, w, h)  # unshifted
    poses = orbit_poses(count, radius, elevation_deg, centre)
    return [Target(f"orbit {i:03d}", intr, p, generated=True) for i, p in enumerate(poses)]


def json_line(summary: SynthesisSummary) -> str:
    return json.dumps({"out": str(summary.out), "views": len(summary.targets), "seconds": round(summary.seconds, 3),
                       "device": summary.device, "bbox_source": summary.bbox_source})
