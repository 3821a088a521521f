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
    if img.ndim == 2:
        return np.repeat(img[..., None], 3, -1)
    if img.shape[-1] == 4:  # RGBA on white for display
        a = img[..., 3:4] / 255.0
        return (img[..., :3] * a + 255 * (1 - a)).astype(np.uint8)
    return img


def dataset_contact_sheet(root: Path, out_png: Path, max_objects: int = 8, views_per_object: int = 4,
                          tile: int = 96) -> Path:
    """Rows = objects; per view: RGB, depth, part mask, normals."""
    root = Path(root)
    objs = sorted(p.parent for p in root.glob("*/*/meta.json"))[:max_objects]
    if not objs:
        from ..errors import InputError

        raise InputError(f"no rendered objects under {root}")
    rows = []
    for obj_dir in objs:
        ov = F.read_object(obj_dir)
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
