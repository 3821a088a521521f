"""The files between the add-on and the synthesis worker (bpy-free).

The add-on writes ``targets.json``; the worker (``python -m blender_mrvm synthesize --references DIR
--views 0 1 --targets targets.json --checkpoint CKPT --out OUT``) reads it and writes, for target i,
``OUT/rgb/<i:06d>.png`` (RGBA, alpha 0 = background) and, when asked, ``OUT/depth/<i:06d>.exr``
(planar z-depth, channel "Y"): the paths each target names. References are an object folder of our
dataset format (a render, a recovered capture, or scene cameras exported by the add-on).

::

    {"format": "blender_mrvm.targets", "version": 1, "depth": false,
     "targets": [{"name": "Camera", "generated": false, "c2w_opencv": [[4x4]],
                  "fl_x": .., "fl_y": .., "cx": .., "cy": .., "w": .., "h": ..,
                  "rgb": "rgb/000000.png", "depth": "depth/000000.exr"}]}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.cameras import Intrinsics, as_pose
from ..validation import check_image_side
from .format import atomic_write_json


def blend_images_folder(blend_path: Path) -> Path:
    """Where ``scene.novel_views.write_blend`` puts the images a .blend's image planes show: beside it,
    ``<stem>_novel_views/`` (the demo owns it as one of its folders)."""
    return Path(blend_path).parent / f"{Path(blend_path).stem}_novel_views"


TARGETS_FORMAT = "blender_mrvm.targets"
TARGETS_VERSION = 1
MAX_REFERENCES = 10
"""The most reference views one target is rendered from (the models' ``max_ref_views`` cap)."""
MAX_POOL = 500
"""The most reference views a synthesis may be given: with more than a target uses, each target takes its
nearest ones (a dense capture)."""


@dataclass(frozen=True)
class Target:
    """One view to synthesize."""

    name: str
    """Name of the Blender camera (existing, or to create when ``generated``)."""
    intrinsics: Intrinsics
    """Pixel intrinsics (pixel-centre convention) at the size the image is synthesized."""
    c2w_opencv: np.ndarray
    """4x4 camera-to-world, OpenCV axes."""
    generated: bool = False
    """The camera does not exist yet: the add-on creates it with the result (an orbit camera)."""

    def rgb_path(self, index: int) -> str:
        return f"rgb/{index:06d}.png"

    def depth_path(self, index: int) -> str:
        return f"depth/{index:06d}.exr"

    def semantic_path(self, index: int) -> str:
        """The coloured semantic map ``sem2nerf render --targets`` writes for this target."""
        return f"semantic_color/{index:06d}.png"


def parse_views(text: str, max_views: int = MAX_POOL) -> tuple[int, ...]:
    """Reference view indices from '0 1', '0,1' or '0, 3, 5'; 1..max_views distinct, non-negative; 'all'
    gives () (every view of the folder)."""
    if text.strip().lower() == "all":
        return ()
    parts = [p for p in text.replace(",", " ").split() if p]
    try:
        views = tuple(int(p) for p in parts)
    except ValueError:
        raise InputError(f"reference views must be view numbers like '0 1', got {text!r}") from None
    if not views:
        raise InputError("choose at least one reference view")
    if len(views) > max_views:
        raise InputError(f"at most {max_views} reference views, got {len(views)}")
    if min(views) < 0 or len(set(views)) != len(views):
        raise InputError(f"reference views must be distinct and non-negative, got {text!r}")
    return views


def write_targets(path: Path, targets: list[Target], depth: bool = False) -> Path:
    """Write ``targets.json`` (atomically)."""
    if not targets:
        raise InputError("no target views")
    names = [t.name for t in targets]
    if len(set(names)) != len(names):
        raise InputError("target names must be unique")
    rows = []
    for i, t in enumerate(targets):
        k = t.intrinsics
        rows.append({"name": t.name, "generated": bool(t.generated), "c2w_opencv": as_pose(t.c2w_opencv).tolist(),
                     "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy, "w": k.width, "h": k.height,
                     "rgb": t.rgb_path(i), "depth": t.depth_path(i)})
    atomic_write_json(Path(path), {"format": TARGETS_FORMAT, "version": TARGETS_VERSION, "depth": bool(depth),
                                   "targets": rows})
    return Path(path)


def read_targets(path: Path) -> tuple[list[Target], bool]:
    """``(targets, depth wanted)`` from ``targets.json``; InputError naming what is wrong (the target and
    the field): sizes of 1 to ``validation.MAX_IMAGE_SIDE`` pixels, finite positive focal lengths, a finite
    principal point and a rigid pose (not scaled, sheared or mirrored), names unique (each names one Blender camera)."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"targets file {path} does not exist") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read targets file {path}: {e}") from None
    except ValueError as e:
        raise InputError(f"{path} is not JSON: {e}") from None
    version = d.get("version", 0) if isinstance(d, dict) else None
    if (not isinstance(d, dict) or d.get("format") != TARGETS_FORMAT or isinstance(version, bool)
            or not isinstance(version, int) or version > TARGETS_VERSION):
        raise InputError(f"{path} is not a targets file of version <= {TARGETS_VERSION}")
    rows = d.get("targets", [])
    if not isinstance(rows, list):
        raise InputError(f"{path}: 'targets' must be a list of targets")
    out: list[Target] = []
    for i, r in enumerate(rows):
        t = _target_of_row(path, i, r)
        if any(o.name == t.name for o in out):
            raise InputError(f"{path}: two targets are named {t.name!r}; target names must be unique "
                             "(each names one Blender camera)")
        out.append(t)
    if not out:
        raise InputError(f"{path} lists no targets")
    return out, bool(d.get("depth", False))


def _target_of_row(path: Path, i: int, r) -> Target:
    """Target ``i`` of a targets file, each value checked; InputError naming the target and the field."""
    if not isinstance(r, dict):
        raise InputError(f"{path}: target {i} is malformed (not an object)")
    name = r.get("name")
    if not isinstance(name, str) or not name.strip():
        raise InputError(f"{path}: target {i} is malformed (its name must be a non-empty text)")
    what = f"{path}: target {i} ({name!r})"
    try:
        for key in ("w", "h"):
            check_image_side(f"{what}: {key}", r[key])
        vals = {}
        for key in ("fl_x", "fl_y", "cx", "cy"):
            v = r[key]
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise InputError(f"{what}: {key} must be a finite number, got {v!r}")
            if key.startswith("fl_") and v <= 0:
                raise InputError(f"{what}: {key} must be a positive focal length in pixels, got {v!r}")
            vals[key] = float(v)
        try:
            pose = np.asarray(r["c2w_opencv"], dtype=np.float64)
        except (TypeError, ValueError):
            pose = None
        if pose is None or pose.shape not in ((4, 4), (3, 4)) or not np.isfinite(pose).all() or (
                pose.shape == (4, 4) and not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0])):
            raise InputError(f"{what}: c2w_opencv must be a finite 4x4 (or 3x4) camera-to-world matrix")
        from ..models.sem2nerf.render import check_pose  # (torch-free) the check `sem2nerf render` makes

        check_pose(as_pose(pose), f"{what}: c2w_opencv")  # a mirrored pose rendered an empty view without a word
        generated = r.get("generated", False)
        if not isinstance(generated, bool):
            raise InputError(f"{what}: generated must be true or false, got {generated!r}")
    except KeyError as e:
        raise InputError(f"{path}: target {i} is malformed ({name!r} has no {e.args[0]!r})") from None
    k = Intrinsics(vals["fl_x"], vals["fl_y"], vals["cx"], vals["cy"], r["w"], r["h"])
    return Target(name, k, as_pose(pose), generated)
