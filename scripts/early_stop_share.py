"""How much early ray termination skips for a NeRFormer+MRVM checkpoint, and what it changes (issue 13).

    python scripts/early_stop_share.py CHECKPOINT DATA OUT.csv [--thresholds 0,1e-3,1e-2,0.1]

Renders 3 target views (0, 7, 11) of one held-out object per category of DATA's test split from 2
references (3 and 15), with hull culling as ``synthesize`` does, once per ``render.stop_transmittance``
threshold (0 = off, the reference), and writes one CSV row per threshold: points the model evaluated, the
share skipped, PSNR against ground truth, and the largest and RMS change of a pixel against the threshold-0
images. ``bench tradeoff --axes stop`` times the same knob on one view; this counts it over many.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from blender_mrvm.datasets.loaders import list_objects, load_object  # noqa: E402
from blender_mrvm.models.config import merge  # noqa: E402
from blender_mrvm.models.pretrained import resolve_checkpoint  # noqa: E402
from blender_mrvm.synthesis import load_checkpoint  # noqa: E402

REFS, TARGETS = (3, 15), (0, 7, 11)


def main(argv: list[str]) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint")
    p.add_argument("data", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--thresholds", default="0,1e-3,1e-2,0.1")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    model, cfg0, _, _ = load_checkpoint(resolve_checkpoint(a.checkpoint))
    first: dict[str, tuple] = {}
    for f, path in list_objects(a.data, None, "test"):
        first.setdefault(Path(path).parent.name, (f, path))
    scenes = [load_object(f, path, "test") for f, path in first.values()]
    rows, base = [], None
    for st in [float(x) for x in a.thresholds.split(",")]:
        model.cfg = merge(cfg0, {"render": {"stop_transmittance": st}})
        n, imgs, gts = 0, [], []
        for sc in scenes:
            for t in TARGETS:
                r = model.synthesize(np.stack([sc.images[i] for i in REFS]), [sc.c2w[i] for i in REFS],
                                     [sc.intrinsics[i] for i in REFS], sc.bbox, sc.c2w[t], sc.intrinsics[t],
                                     ref_masks=np.stack([sc.masks[i] for i in REFS]), skip="cull")
                n += r["samples"]
                imgs.append(r["color"].numpy())
                gts.append(np.asarray(sc.images[t], np.float32))
        imgs, gts = np.stack(imgs), np.stack(gts)
        if base is None:
            base = (n, imgs)
        d = imgs - base[1]
        psnr = float(np.mean([-10 * np.log10(max(((i - g) ** 2).mean(), 1e-10)) for i, g in zip(imgs, gts)]))
        rows.append({"checkpoint": a.checkpoint, "stop_transmittance": st, "views": len(imgs), "samples": n,
                     "skipped_share": round(1 - n / base[0], 5), "psnr": round(psnr, 4),
                     "max_abs_change": round(float(np.abs(d).max()), 4),
                     "rms_change": round(float(np.sqrt((d ** 2).mean())), 5)})
        print(rows[-1], flush=True)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    with open(a.out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
