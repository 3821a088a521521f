"""Pose recovery speed and accuracy: our defaults against pycolmap's defaults (exhaustive matching).

A procedurally textured scene is rendered (Cycles, emission shading) from a ring of 40 known cameras
at 960x540; subsets of 10, 20 and 40 evenly spaced views are recovered twice:

- ``ours``: ``capture.sfm.recover_poses`` with the default :class:`CaptureConfig` (2048 SIFT
  features, sequential matching for more than 30 numbered frames, SIMPLE_PINHOLE with intrinsics
  per photo), including the export of the capture folder;
- ``pycolmap_default``: ``extract_features`` / ``match_exhaustive`` / ``incremental_mapping`` with
  pycolmap's default options (8192 features, SIMPLE_RADIAL, every pair), largest model kept.

Accuracy: Umeyama similarity alignment of the recovered camera centres to the truth, then the median
rotation error (degrees) and median centre error (% of the ring radius). Time per stage, total,
registered/total and the errors go to ``<out>/bench_capture.csv``.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import time
from pathlib import Path

import numpy as np

STAGES = ("extract", "match", "map", "undistort", "export")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_capture.csv and the cached renders")
    p.add_argument("--sizes", default="10,20,40", help="numbers of images to recover")
    p.add_argument("--views", type=int, default=40, help="views rendered on the ring (subsets are taken)")
    p.add_argument("--width", type=int, default=960)
    p.add_argument("--height", type=int, default=540)
    p.add_argument("--samples", type=int, default=4)
    p.add_argument("--methods", default="ours,pycolmap_default")
    p.add_argument("--threads", type=int, default=-1, help="CPU threads for both methods (-1 = all)")


def _render(out: Path, args) -> dict:
    ring = out / f"capture_ring_{args.views}_{args.width}x{args.height}"
    truth_path = ring / "truth.json"
    if not truth_path.is_file():
        import bpy  # noqa: F401  (the renderer lives in the scene layer)

        from ..scene.capture import render_textured_ring

        render_textured_ring(ring, n_views=args.views, width=args.width, height=args.height, samples=args.samples)
    return json.loads(truth_path.read_text()) | {"dir": str(ring)}


def _subset(truth: dict, n: int, dst: Path) -> list[str]:
    views = truth["views"]
    step = len(views) / n
    names = [views[int(round(i * step)) % len(views)]["name"] for i in range(n)]
    if dst.exists():
        shutil.rmtree(dst)
    dst.mkdir(parents=True)
    for name in names:
        shutil.copy(Path(truth["dir"]) / "images" / name, dst / name)
    return names


def _errors(names, c2ws, truth) -> tuple[float, float]:
    from ..capture import align

    tr = {v["name"]: np.array(v["c2w_opencv"]) for v in truth["views"]}
    if len(names) < 3:
        return float("nan"), float("nan")
    e = align.pose_errors(c2ws, [tr[n] for n in names])
    return e.median_rotation_deg, 100.0 * e.median_centre / truth["radius"]


def run_ours(images: Path, work: Path, threads: int) -> dict:
    from ..capture.config import CaptureConfig
    from ..capture.sfm import recover_poses
    from ..progress import run_to_end

    t0 = time.perf_counter()
    res = run_to_end(recover_poses(images, work, CaptureConfig(num_threads=threads, force=True)))
    total = time.perf_counter() - t0
    return {"timings": res.timings, "total": total, "names": res.registered, "c2w": res.c2w_opencv,
            "matcher": res.matcher, "features": CaptureConfig().max_num_features}


def run_pycolmap_default(images: Path, work: Path, threads: int) -> dict:
    import pycolmap

    from ..geometry import cameras as C

    pycolmap.logging.minloglevel = 2
    if work.exists():
        shutil.rmtree(work)
    (work / "sparse").mkdir(parents=True)
    db = work / "database.db"
    tm = {}
    t0 = time.perf_counter()
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = threads
    pycolmap.extract_features(db, images, extraction_options=ext, device=pycolmap.Device.cpu)
    tm["extract"] = time.perf_counter() - t0
    t = time.perf_counter()
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = threads
    pycolmap.match_exhaustive(db, matching_options=mo, device=pycolmap.Device.cpu)
    tm["match"] = time.perf_counter() - t
    t = time.perf_counter()
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = threads
    recs = pycolmap.incremental_mapping(db, images, work / "sparse", opts)
    tm["map"] = time.perf_counter() - t
    total = time.perf_counter() - t0
    names, c2ws = [], []
    if recs:
        rec = max(recs.values(), key=lambda r: r.num_reg_images())
        for i in sorted(rec.reg_image_ids()):
            im = rec.images[i]
            names.append(im.name)
            c2ws.append(C.c2w_opencv_from_w2c(im.cam_from_world().matrix()))
    return {"timings": tm, "total": total, "names": names, "c2w": c2ws, "matcher": "exhaustive", "features": 8192}


def run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t = time.perf_counter()
    truth = _render(out, args)
    print(f"ring of {args.views} views at {args.width}x{args.height} ready ({time.perf_counter() - t:.0f}s)")
    rows = []
    csv_path = out / "bench_capture.csv"
    fields = ["method", "images", "width", "height", "matcher", "max_features", *[f"{s}_s" for s in STAGES],
              "total_s", "registered", "median_rot_deg", "median_centre_pct_radius"]
    methods = {"ours": run_ours, "pycolmap_default": run_pycolmap_default}
    for n in (int(s) for s in args.sizes.split(",")):
        images = out / "capture_subsets" / f"n{n}"
        _subset(truth, n, images)
        for m in args.methods.split(","):
            r = methods[m](images, out / "capture_work" / f"{m}_n{n}", args.threads)
            rot, cen = _errors(r["names"], r["c2w"], truth)
            row = {"method": m, "images": n, "width": args.width, "height": args.height, "matcher": r["matcher"],
                   "max_features": r["features"],
                   **{f"{s}_s": round(r["timings"].get(s, 0.0), 3) for s in STAGES},
                   "total_s": round(r["total"], 3), "registered": f"{len(r['names'])}/{n}",
                   "median_rot_deg": round(rot, 4), "median_centre_pct_radius": round(cen, 4)}
            rows.append(row)
            print(", ".join(f"{k}={v}" for k, v in row.items()), flush=True)
            with open(csv_path, "w", newline="") as f:
                w = csv.DictWriter(f, fieldnames=fields)
                w.writeheader()
                w.writerows(rows)
    for n in sorted({r["images"] for r in rows}):
        pair = {r["method"]: r for r in rows if r["images"] == n}
        if len(pair) == 2:
            ratio = pair["ours"]["total_s"] / pair["pycolmap_default"]["total_s"]
            print(f"{n} images: ours {pair['ours']['total_s']:.1f}s vs pycolmap default "
                  f"{pair['pycolmap_default']['total_s']:.1f}s -> {ratio:.2f}x the time")
    print(f"wrote {csv_path}")
    return 0
