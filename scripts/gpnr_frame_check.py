"""Does a model's rendering depend on the world frame the scene is written in? (issue 10: canonicalization)

    python scripts/gpnr_frame_check.py DATA SPLIT RUN [RUN ...]

Renders every protocol target of DATA (``eval``'s per-target references, 2 of them) with each RUN twice more:
with the whole scene (cameras and box) turned upside down (180 degrees about x, as a y-down SfM frame before
``recover-poses`` levels it) and turned 90 degrees about z (the azimuth a levelled capture is left with). Both
keep an axis-aligned box axis-aligned, so a model invariant to rigid motions renders the same images; prints
PSNR / LPIPS per frame and the largest per-view change.
"""

from __future__ import annotations

import sys
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


def main(argv: list[str]) -> int:
    from blender_mrvm.datasets.loaders import detect_format, list_objects, load_object
    from blender_mrvm.models import background as bgrule
    from blender_mrvm.models.metrics import LPIPS, psnr
    from blender_mrvm.training.checkpoint import load_model
    from blender_mrvm.training.evaluate import protocol_target_inputs

    torch.set_num_threads(1)
    data, split, runs = Path(argv[0]), argv[1], argv[2:]
    scenes = [load_object(f, p, split) for f, p in list_objects(data, detect_format(data), split)]
    per_target = protocol_target_inputs(data, 2)
    if per_target is None:
        raise SystemExit(f"error: {data} names no per-target references (a make-captures dataset does)")
    lpips = LPIPS()
    for run in runs:
        model, _, _ = load_model(run)
        model.eval()
        bgrule.for_rendering(model, bgrule.of_scenes(scenes))
        rows = []
        for s in scenes:
            pos = {v: k for k, v in enumerate(s.view_ids)}
            for v in sorted(per_target):
                if v not in pos:
                    continue
                refs, t = [pos[r] for r in per_target[v]], pos[v]
                gt, ims = torch.from_numpy(s.images[t]), np.stack([s.images[r] for r in refs])
                row = []
                for W in [np.eye(4), *FRAMES.values()]:
                    out = model.synthesize(ims, [W @ s.c2w[r] for r in refs], [s.intrinsics[r] for r in refs],
                                           moved_box(s.bbox, W), W @ s.c2w[t], s.intrinsics[t])["color"].clamp(0, 1)
                    row += [float(psnr(out, gt)[0]), float(lpips(out, gt)[0])]
                rows.append(row)
        a = np.array(rows)
        line = [f"{run}: {len(a)} views; as written {a[:, 0].mean():.2f} dB / LPIPS {a[:, 1].mean():.4f}"]
        for i, name in enumerate(FRAMES, start=1):
            d = a[:, 2 * i] - a[:, 0]
            line.append(f"{name} {a[:, 2 * i].mean():.2f} / {a[:, 2 * i + 1].mean():.4f} "
                        f"({d.mean():+.2f} dB, largest per-view change {np.abs(d).max():.2f} dB)")
        print("; ".join(line), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
