"""The room GPNR (``shipped:gpnr_captures``) scored in fp32 and int8 on held-out capture-like rooms.

``bench tradeoff`` scores a model from references spread around the object; rooms are rendered from each target's
nearest photos, as ``synthesize`` does for a capture, so this scores every target view of each room from its 2
nearest other views (the bench's ``nearest`` point) at each precision, and writes one CSV row per precision.

    .venv/bin/python -m blender_mrvm make-captures --scenes 6 --views 24 --resolution 64 --seed 9000 --out /tmp/caps6
    PYTHONPATH=$PWD .venv/bin/python docs/bench_int8/score_rooms.py --data /tmp/caps6 --out docs/bench_int8/rooms.csv
"""

from __future__ import annotations

import argparse
import sys


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--targets", type=int, default=8, help="target views per room")
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    from blender_mrvm import threads
    from blender_mrvm.bench import write_csv

    threads.apply_malloc_defaults()
    import torch

    torch.set_num_threads(1)
    from blender_mrvm.bench.tradeoff import Point, measure_quality
    from blender_mrvm.datasets.loaders import list_objects, load_object
    from blender_mrvm.models.metrics import LPIPS
    from blender_mrvm.models.precision import for_precision
    from blender_mrvm.models.pretrained import resolve_checkpoint
    from blender_mrvm.synthesis import load_checkpoint

    model = load_checkpoint(resolve_checkpoint("shipped:gpnr_captures"), "cpu")[0]
    scenes = [load_object(f, p, s) for s in ("train", "val", "test") for f, p in list_objects(args.data, None, s)]
    lpips = LPIPS()
    rows = []
    for prec in ("fp32", "int8"):
        q = measure_quality(for_precision(model, prec), scenes, Point("nearest", "2 nearest", nearest=2,
                                                                       precision=prec), args.targets, lpips, "cpu")
        rows.append({"checkpoint": "shipped:gpnr_captures", "data": args.data, "rooms": len(scenes),
                     "targets_per_room": args.targets, "references": "2 nearest", "precision": prec, **q,
                     "torch": torch.__version__})
        print(rows[-1], flush=True)
    write_csv(args.out, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
