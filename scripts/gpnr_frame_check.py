"""Does a model's rendering depend on the world frame the scene is written in? (issue 10: canonicalization)

    python scripts/gpnr_frame_check.py DATA SPLIT RUN [RUN ...]

Renders every protocol target of DATA (``eval``'s per-target references, 2 of them) with each RUN twice more:
with the whole scene (cameras and box) turned upside down (180 degrees about x, as a y-down SfM frame before
``recover-poses`` levels it) and turned 90 degrees about z (the azimuth a levelled capture is left with). Both
keep an axis-aligned box axis-aligned, so a model invariant to rigid motions renders the same images; prints
PSNR / LPIPS per frame and the largest per-view change.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

FRAMES = {
    "upside down": np.diag([1.0, -1.0, -1.0, 1.0]),
    "90 degrees about z": np.array([[0.0, -1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]),
}


def moved_box(box, W: np.ndarray):
    """The axis-aligned box after the rotation ``W`` (a signed axis permutation, so the box stays exact)."""
    corners = np.array([[x, y, z] for x in (box[0][0], box[1][0]) for y in (box[0][1], box[1][1])
                        for z in (box[0][2], box[1][2])], np.float64) @ W[:3, :3].T
    return corners.min(0), corners.max(0)


def moved_scene(s, W: np.ndarray):
    """The object scene with every camera and its box rewritten in the frame rotated by ``W``."""
    return dataclasses.replace(s, c2w=np.einsum("ij,njk->nik", W, np.asarray(s.c2w)), bbox=moved_box(s.bbox, W))


def main(argv: list[str]) -> int:
    from blender_mrvm.datasets.loaders import detect_format, list_objects, load_object
    from blender_mrvm.models import background as bgrule
    from blender_mrvm.models.metrics import LPIPS
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training.checkpoint import load_model
    from blender_mrvm.training.evaluate import evaluate, protocol_target_inputs

    torch.set_num_threads(1)
    data, split, runs = Path(argv[0]), argv[1], argv[2:]
    scenes = [load_object(f, p, split) for f, p in list_objects(data, detect_format(data), split)]
    per_target = protocol_target_inputs(data, 2)
    if per_target is None:
        raise SystemExit(f"error: {data} names no per-target references (a make-captures dataset does)")
    lpips = LPIPS()
    for run in runs:
        model, _, _ = load_model(run)
        bgrule.for_rendering(model, bgrule.of_scenes(scenes))
        views = {}
        for name, W in [("as written", np.eye(4)), *FRAMES.items()]:
            with tempfile.TemporaryDirectory() as tmp:  # evaluate keeps the per-view scores in its eval.json
                run_to_end(evaluate(model, [moved_scene(s, W) for s in scenes], [], lpips, out_dir=Path(tmp),
                                    grid_objects=0, target_inputs=per_target))
                views[name] = json.loads((Path(tmp) / "eval.json").read_text())["views"]
        base = np.array([v["psnr"] for v in views["as written"]])
        line = [f"{run}: {len(base)} views"]
        for name, recs in views.items():
            p = np.array([v["psnr"] for v in recs])
            line.append(f"{name} {p.mean():.2f} dB / LPIPS {np.mean([v['lpips'] for v in recs]):.4f}"
                        + ("" if name == "as written" else
                           f" ({(p - base).mean():+.2f} dB, largest per-view change {np.abs(p - base).max():.2f} dB)"))
        print("; ".join(line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
