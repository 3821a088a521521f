"""Contact sheets: one PNG showing a dataset at a glance (bpy-free)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from . import format as F

_PALETTE = np.array([[255, 255, 255]] + [[int(c) for c in np.random.default_rng(k).integers(40, 230, 3)]
                                          for k in range(1, 256)], dtype=np.uint8)


def colorize_mask(mask: np.ndarray) -> np.ndarray:
    return _PALETTE[mask]


def colorize_depth(depth: np.ndarray) -> np.ndarray:
    valid = depth > 0
    out = np.full(depth.shape + (3,), 255, np.uint8)
    if valid.any():
        lo, hi = depth[valid].min(), depth[valid].max()
        t = (depth - lo) / max(hi - lo, 1e-9)
        g = (40 + 200 * (1 - t)).clip(0, 255).astype(np.uint8)
        out[valid] = np.stack([g, g, g], -1)[valid]
    return out


def _rgb(img: np.ndarray) -> np.ndarray:
    """An object folder's image as the 8-bit RGB a sheet shows: RGBA over white mixed in linear light, as the loaders
    read it (``loaders.to_float_rgb``); it had mixed the sRGB numbers (soft edges up to 74/255 darker than the dataset
    the model trains on) and cast 16-bit images to 8 bits (their high bits lost)."""
    from .loaders import to_float_rgb

    return F.to_uint8(to_float_rgb(img))


def finished_objects(root: Path, limit: int | None = None,
                     left_out: list[str] | None = None) -> list[F.ObjectViews]:
    """The finished objects of a dataset root, in name order, at most ``limit``. An object folder whose
    ``meta.json`` says it is not complete (a render stopped by Ctrl-C or a crash; a ``meta.json`` without the key,
    as other writers leave it, counts as complete, as the loaders read it), that holds no view, or whose files
    cannot be read is left out and appended to ``left_out`` as ``category/object (why)``."""
    from ..errors import InputError

    out: list[F.ObjectViews] = []
    skipped = left_out if left_out is not None else []
    for meta_path in sorted(Path(root).glob("*/*/meta.json")):
        if limit is not None and len(out) >= limit:
            break
        obj_dir = meta_path.parent
        name = f"{obj_dir.parent.name}/{obj_dir.name}"
        try:
            ov = F.read_object(obj_dir)
        except InputError as e:
            skipped.append(f"{name} ({'unfinished' if _unfinished(meta_path) else e})")
            continue
        if ov.meta.get("complete", True) is not True:
            skipped.append(f"{name} (unfinished)")
        elif not ov.indices:
            skipped.append(f"{name} (no views)")
        else:
            out.append(ov)
    return out


def _unfinished(meta_path: Path) -> bool:
    """Whether a ``meta.json`` that can be read says its object is not complete."""
    import json

    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError):
        return False
    return isinstance(meta, dict) and meta.get("complete", True) is not True


def dataset_contact_sheet(root: Path, out_png: Path, max_objects: int = 8, views_per_object: int = 4,
                          tile: int = 96, left_out: list[str] | None = None) -> Path:
    """Rows = objects (the first ``max_objects`` finished ones: :func:`finished_objects`, which names the object
    folders it leaves out in ``left_out``); per view: RGB, depth, part mask, normals."""
    from ..errors import InputError

    root = Path(root)
    skipped: list[str] = []
    objs = finished_objects(root, max_objects, skipped)
    if left_out is not None:
        left_out.extend(skipped)
    if not objs:
        if skipped:
            raise InputError(f"no finished objects under {root} to show: {len(skipped)} left out "
                             f"({', '.join(skipped[:3])}{', ...' if len(skipped) > 3 else ''})")
        raise InputError(f"no rendered objects under {root}")
    rows = []
    for ov in objs:
        n = len(ov.indices)
        picks = sorted({round(k * (n - 1) / max(views_per_object - 1, 1)) for k in range(min(views_per_object, n))})
        tiles = []
        for i in picks:
            nrm = ov.normals(i)
            for img in (_rgb(ov.rgb(i)), colorize_depth(ov.depth(i)), colorize_mask(ov.mask(i)),
                        ((nrm * 0.5 + 0.5) * 255 * (np.abs(nrm).sum(-1, keepdims=True) > 0)
                         + 255 * (np.abs(nrm).sum(-1, keepdims=True) == 0)).clip(0, 255).astype(np.uint8)):
                tiles.append(np.asarray(Image.fromarray(img).resize((tile, tile), Image.NEAREST)))
        row = np.concatenate(tiles, axis=1)
        label = np.full((16, row.shape[1], 3), 255, np.uint8)
        im = Image.fromarray(label)
        ImageDraw.Draw(im).text((2, 2), f"{ov.meta['category']}/{ov.meta['object_id']}  "
                                         "(rgb | depth | parts | normals per view)", fill=(0, 0, 0))
        rows.append(np.concatenate([np.asarray(im), row], axis=0))
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    F.write_png(Path(out_png), np.concatenate(rows, axis=0))
    return Path(out_png)
