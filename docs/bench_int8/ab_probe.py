"""Side-by-side timing of fp32 and int8 (``models.precision.for_precision``) on the same view, alternated.

A sweep's points are timed one after another, so a neighbour's load lands on one of them; here each round renders
the same 128 px view at every precision in turn, and the CSV keeps every round (the README reads medians) with
each render's PSNR against the first precision's render of the view (how far int8 moves the image). The
process sets the CLI's glibc malloc thresholds first (``threads.apply_malloc_defaults``), as the commands do.

    PYTHONPATH=$PWD .venv/bin/python docs/bench_int8/ab_probe.py --checkpoint shipped:mrvm_quality \\
        --data data/sphere64_heldout --split train --rounds 5 --workers 2 --out docs/bench_int8/ab_quality_w2.csv
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="train")
    ap.add_argument("--object", type=int, default=0, help="index into the split's objects")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--workers", type=int, default=1, help="ray chunks side by side (synthesize uses one a core)")
    ap.add_argument("--precisions", default="fp32,int8")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()

    from blender_mrvm import threads
    from blender_mrvm.bench import write_csv

    policy = threads.apply_malloc_defaults()
    import torch

    torch.set_num_threads(1)
    import numpy as np

    from blender_mrvm.bench import tradeoff
    from blender_mrvm.bench.tradeoff import Point, measure_speed, ref_views
    from blender_mrvm.datasets.loaders import list_objects, load_object
    from blender_mrvm.models.precision import for_precision
    from blender_mrvm.models.pretrained import resolve_checkpoint
    from blender_mrvm.synthesis import load_checkpoint

    model = load_checkpoint(resolve_checkpoint(args.checkpoint), "cpu")[0]
    f, path = list_objects(args.data, None, args.split)[args.object]
    scene = load_object(f, path, args.split)
    precs = [p.strip() for p in args.precisions.split(",")]
    models = {p: for_precision(model, p) for p in precs}
    pt = Point("base", "as trained")
    rows, last = [], {}
    timed = tradeoff._timed

    def keep(render, *a):  # the bench's own timing, keeping the view it rendered
        res, t = timed(render, *a)
        last["rgb"] = np.asarray(res["color"], np.float64)
        return res, t

    tradeoff._timed = keep
    for r in range(args.rounds):
        first = None
        for p in precs:
            s = measure_speed(models[p], scene, ref_views(len(scene), 2), pt, args.size, 1, "cpu", args.workers)
            first = last["rgb"] if first is None else first
            mse = float(((last["rgb"] - first) ** 2).mean())
            rows.append({"checkpoint": args.checkpoint, "object": str(path), "round": r, "precision": p,
                         "size": args.size, "workers": args.workers, "seconds": s["seconds_per_view"],
                         "cpu_seconds": s["cpu_seconds_per_view"], "rays_evaluated": s["rays_evaluated"],
                         "psnr_vs_" + precs[0]: round(10 * np.log10(1 / mse), 2) if mse > 0 else "identical",
                         "load_1min": round(os.getloadavg()[0], 2), "malloc": policy,
                         "cpu": platform.processor() or platform.machine(), "torch": torch.__version__})
            print(r, p, s["seconds_per_view"], s["cpu_seconds_per_view"], flush=True)
    write_csv(args.out, rows)
    med = {p: statistics.median(x["seconds"] for x in rows if x["precision"] == p) for p in precs}
    print("median s/view", med, "fp32/int8", round(med["fp32"] / med["int8"], 3) if "int8" in med else "")
    return 0


if __name__ == "__main__":
    sys.exit(main())
