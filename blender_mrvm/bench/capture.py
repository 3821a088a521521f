"""Pose recovery speed and accuracy: our defaults against pycolmap's defaults (exhaustive matching).

A procedurally textured scene is rendered (Cycles, emission shading) from a ring of 40 known cameras
at 960x540 (9 degrees apart). For each size n (10, 20, 40) the same n photos go to every method:
``--subset arc`` (default) takes n consecutive ring views, so neighbours stay 9 degrees apart at every
n; ``--subset spread`` takes n evenly spaced views (36 degrees apart at n=10, where no method
registers every view). Methods:

- ``ours``: ``capture.sfm.recover_poses`` with the default :class:`CaptureConfig` (SIFT from the
  photo's own resolution above ``upsample_below`` px, at most 2048 features, exhaustive matching up to
  30 photos and sequential matching for more numbered frames, SIMPLE_PINHOLE per photo), including
  the photo checks (scan) and the export of the capture folder;
- ``ours_exhaustive``: the same with ``matcher="exhaustive"``: what an unordered photo set (names that
  are not numbered frames) gets;
- ``pycolmap_default``: ``extract_features`` / ``match_exhaustive`` / ``incremental_mapping`` with
  pycolmap's default options (SIFT on the 2x-upsampled photo, 8192 features, SIMPLE_RADIAL, every
  pair), largest model kept.

Every method gets the same photos and ``--threads``. Each (n, method) runs ``--repeats`` times; the
order of the methods rotates from one repeat to the next (no method always runs first or on a warm
cache). Wall and CPU seconds (``time.process_time``: this process, all threads) are taken per stage;
on a shared machine the CPU seconds are the steadier figure, so both are reported with the 1-minute
load average. Accuracy: Umeyama similarity alignment of the recovered camera centres to the truth,
then the median rotation error (degrees) and median centre error (% of the ring radius);
``accurate`` = every photo registered, rotation < 0.5 deg and centre < 1 % in every repeat.

Writes ``<out>/bench_capture_runs.csv`` (every run) and ``<out>/bench_capture.csv`` (medians per
method and size, with the time ratio to ``pycolmap_default``).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import statistics
import time
from pathlib import Path

import numpy as np

from . import write_csv

RESULTS = ("bench_capture.csv", "bench_capture_runs.csv")
"""What the bench writes into ``--out`` (``bench.check_results``); the rendered rings cached there
(``capture_ring_*``) are reused by later runs of the same render settings."""

STAGES = ("scan", "extract", "match", "map", "check", "undistort", "export")
METHODS = ("ours", "ours_exhaustive", "pycolmap_default")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for the CSVs and the cached renders")
    p.add_argument("--sizes", default="10,20,40", help="numbers of images to recover")
    p.add_argument("--views", type=int, default=40, help="views rendered on the ring (subsets are taken)")
    p.add_argument("--width", type=int, default=960, help="rendered photo width, pixels")
    p.add_argument("--height", type=int, default=540, help="rendered photo height, pixels")
    p.add_argument("--samples", type=int, default=4, help="Cycles samples per pixel of the rendered photos")
    p.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, of {', '.join(METHODS)}")
    p.add_argument("--threads", type=int, default=-1, help="CPU threads for every method (0 or -1 = all; default all)")
    p.add_argument("--repeats", type=int, default=3, help="runs per method and size (medians are reported)")
    p.add_argument("--subset", choices=("arc", "spread"), default="arc",
                   help="arc: n consecutive ring views; spread: n evenly spaced views")


def ring_folder(out: Path, args) -> Path:
    """The cached ring of these render settings under ``out``: every setting is in the name (a ring rendered at
    other --samples had been reused as if it were this one)."""
    return out / f"capture_ring_{args.views}_{args.width}x{args.height}_s{args.samples}"


def _render(out: Path, args) -> dict:
    ring = ring_folder(out, args)
    truth_path = ring / "truth.json"
    if not truth_path.is_file():
        import bpy  # noqa: F401  (the renderer lives in the scene layer)

        from ..scene.capture import render_textured_ring

        render_textured_ring(ring, n_views=args.views, width=args.width, height=args.height, samples=args.samples)
    return json.loads(truth_path.read_text()) | {"dir": str(ring)}


def subset_names(truth: dict, n: int, how: str = "arc") -> list[str]:
    """The photos given to every method: n consecutive ring views (arc) or n evenly spaced ones (spread)."""
    views = truth["views"]
    if n > len(views):
        raise ValueError(f"asked for {n} images from a ring of {len(views)} views")
    if how == "arc":
        return [v["name"] for v in views[:n]]
    step = len(views) / n
    return [views[int(round(i * step)) % len(views)]["name"] for i in range(n)]


def _subset(truth: dict, n: int, dst: Path, how: str) -> list[str]:
    names = subset_names(truth, n, how)
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


def run_ours(images: Path, work: Path, threads: int, **overrides) -> dict:
    from ..capture.config import CaptureConfig
    from ..capture.sfm import recover_poses
    from ..errors import MRVMError
    from ..progress import run_to_end

    cfg = CaptureConfig(num_threads=threads, force=True, **overrides)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        res = run_to_end(recover_poses(images, work, cfg))
    except MRVMError as e:  # a failed recovery is a result too (registered 0, errors NaN)
        return {"timings": {}, "cpu": {}, "total": time.perf_counter() - t0, "total_cpu": time.process_time() - c0,
                "names": [], "c2w": [], "matcher": cfg.matcher, "features": cfg.max_num_features,
                "first_octave": "", "error": str(e)}
    total, total_cpu = time.perf_counter() - t0, time.process_time() - c0
    meta = json.loads((work / "meta.json").read_text())
    return {"timings": res.timings, "cpu": res.cpu_timings, "total": total, "total_cpu": total_cpu,
            "names": res.registered, "c2w": res.c2w_opencv, "matcher": res.matcher,
            "features": cfg.max_num_features, "first_octave": meta["sift_first_octave"], "error": ""}


def run_ours_exhaustive(images: Path, work: Path, threads: int) -> dict:
    return run_ours(images, work, threads, matcher="exhaustive")


def run_pycolmap_default(images: Path, work: Path, threads: int) -> dict:
    import pycolmap

    from ..geometry import cameras as C

    pycolmap.logging.minloglevel = 2
    if work.exists():
        shutil.rmtree(work)
    (work / "sparse").mkdir(parents=True)
    db = work / "database.db"
    tm, cpu = {}, {}
    t0, c0 = time.perf_counter(), time.process_time()
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = threads
    pycolmap.extract_features(db, images, extraction_options=ext, device=pycolmap.Device.cpu)
    tm["extract"], cpu["extract"] = time.perf_counter() - t0, time.process_time() - c0
    t, c = time.perf_counter(), time.process_time()
    mo = pycolmap.FeatureMatchingOptions()
    mo.num_threads = threads
    pycolmap.match_exhaustive(db, matching_options=mo, device=pycolmap.Device.cpu)
    tm["match"], cpu["match"] = time.perf_counter() - t, time.process_time() - c
    t, c = time.perf_counter(), time.process_time()
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = threads
    recs = pycolmap.incremental_mapping(db, images, work / "sparse", opts)
    tm["map"], cpu["map"] = time.perf_counter() - t, time.process_time() - c
    total, total_cpu = time.perf_counter() - t0, time.process_time() - c0
    names, c2ws = [], []
    if recs:
        rec = max(recs.values(), key=lambda r: r.num_reg_images())
        for i in sorted(rec.reg_image_ids()):
            im = rec.images[i]
            names.append(im.name)
            c2ws.append(C.c2w_opencv_from_w2c(im.cam_from_world().matrix()))
    return {"timings": tm, "cpu": cpu, "total": total, "total_cpu": total_cpu, "names": names, "c2w": c2ws,
            "matcher": "exhaustive", "features": ext.sift.max_num_features, "first_octave": ext.sift.first_octave,
            "error": ""}


RUNNERS = {"ours": run_ours, "ours_exhaustive": run_ours_exhaustive, "pycolmap_default": run_pycolmap_default}
RUN_FIELDS = ["method", "images", "repeat", "width", "height", "subset", "matcher", "max_features", "sift_first_octave",
              *[f"{s}_s" for s in STAGES], "total_s", *[f"{s}_cpu_s" for s in STAGES], "total_cpu_s",
              "registered", "median_rot_deg", "median_centre_pct_radius", "load_1min", "error"]
SUMMARY_FIELDS = ["method", "images", "repeats", "width", "height", "subset", "matcher", "max_features",
                  "sift_first_octave", *[f"{s}_s" for s in STAGES], "total_s", "total_cpu_s", "time_ratio",
                  "cpu_ratio", "registered", "median_rot_deg", "median_centre_pct_radius", "accurate", "load_1min"]


def _accurate(row: dict) -> bool:
    reg, n = (int(x) for x in row["registered"].split("/"))
    rot, cen = row["median_rot_deg"], row["median_centre_pct_radius"]
    return reg == n and rot != "" and cen != "" and rot < 0.5 and cen < 1.0


def median_worst_last(values, digits: int) -> float | str:
    """The median of per-run errors where a run that registered too few photos to be scored (NaN, or '') counts as
    worse than any scored run; '' when the median falls on such a run. ``statistics.median`` over NaN had
    depended on the runs' order (the same three runs gave NaN or 0.3)."""
    v = sorted((float(x) if x not in ("", None) and math.isfinite(float(x)) else math.inf) for x in values)
    m = statistics.median(v)
    return round(m, digits) if math.isfinite(m) else ""


def _num(v) -> str:
    return "-" if v == "" else f"{v:.3f}"


def summarize(runs: list[dict]) -> list[dict]:
    """Medians per (method, images) (the errors: :func:`median_worst_last`); ratios against pycolmap_default's
    medians of the same size."""
    med = statistics.median
    out = []
    for key in dict.fromkeys((r["method"], r["images"]) for r in runs):
        rs = [r for r in runs if (r["method"], r["images"]) == key]
        first = rs[0]
        row = {k: first[k] for k in ("method", "images", "width", "height", "subset", "matcher", "max_features",
                                     "sift_first_octave")}
        row["repeats"] = len(rs)
        for s in STAGES:
            row[f"{s}_s"] = round(med(r[f"{s}_s"] for r in rs), 3)
        row["total_s"] = round(med(r["total_s"] for r in rs), 3)
        row["total_cpu_s"] = round(med(r["total_cpu_s"] for r in rs), 3)
        regs = sorted({r["registered"] for r in rs})
        row["registered"] = regs[0] if len(regs) == 1 else "|".join(regs)
        row["median_rot_deg"] = median_worst_last([r["median_rot_deg"] for r in rs], 4)
        row["median_centre_pct_radius"] = median_worst_last([r["median_centre_pct_radius"] for r in rs], 4)
        row["accurate"] = all(_accurate(r) for r in rs)
        row["load_1min"] = round(med(r["load_1min"] for r in rs), 2)
        out.append(row)
    for row in out:
        base = [b for b in out if b["method"] == "pycolmap_default" and b["images"] == row["images"]]
        row["time_ratio"] = round(row["total_s"] / base[0]["total_s"], 3) if base else ""
        row["cpu_ratio"] = round(row["total_cpu_s"] / base[0]["total_cpu_s"], 3) if base else ""
    return out


def run(args) -> int:
    from ..errors import InputError
    from . import at_least, start_results, whole_numbers

    at_least(args, views=3, width=16, height=16, samples=1, repeats=1)
    if args.threads == 0:  # 0 = all, as in synthesize, eval and recover-poses
        args.threads = -1
    if args.threads != -1 and args.threads < 1:
        raise InputError(f"--threads must be 0 or -1 (all) or at least 1 (got {args.threads})")
    sizes = whole_numbers(args.sizes, "--sizes", minimum=3, maximum=args.views)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in RUNNERS]
    if unknown or not methods:
        raise InputError(f"--methods: unknown or none ({', '.join(unknown)}); choose from {', '.join(RUNNERS)}")
    out = start_results(Path(args.out), RESULTS, args.force)
    t = time.perf_counter()
    truth = _render(out, args)
    print(f"ring of {args.views} views at {args.width}x{args.height} ready ({time.perf_counter() - t:.0f}s)")
    runs: list[dict] = []
    runs_path, summary_path = out / "bench_capture_runs.csv", out / "bench_capture.csv"
    for n in sizes:
        images = out / "capture_subsets" / f"{args.subset}{n}"
        _subset(truth, n, images, args.subset)
        for rep in range(args.repeats):
            k = rep % len(methods)
            for m in methods[k:] + methods[:k]:  # rotate the order from one repeat to the next
                load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
                r = RUNNERS[m](images, out / "capture_work" / f"{m}_n{n}", args.threads)
                rot, cen = _errors(r["names"], r["c2w"], truth)
                row = {"method": m, "images": n, "repeat": rep, "width": args.width, "height": args.height,
                       "subset": args.subset, "matcher": r["matcher"], "max_features": r["features"],
                       "sift_first_octave": r["first_octave"],
                       **{f"{s}_s": round(r["timings"].get(s, 0.0), 3) for s in STAGES},
                       "total_s": round(r["total"], 3),
                       **{f"{s}_cpu_s": round(r["cpu"].get(s, 0.0), 3) for s in STAGES},
                       "total_cpu_s": round(r["total_cpu"], 3), "registered": f"{len(r['names'])}/{n}",
                       # '' where too few photos registered to align (registered and error say so), not NaN
                       "median_rot_deg": round(rot, 4) if math.isfinite(rot) else "",
                       "median_centre_pct_radius": round(cen, 4) if math.isfinite(cen) else "",
                       "load_1min": round(load, 2), "error": r["error"]}
                runs.append(row)
                print(f"{m} n={n} rep {rep}: total {row['total_s']:.1f}s (cpu {row['total_cpu_s']:.1f}s) "
                      + " ".join(f"{s} {row[f'{s}_s']:.1f}" for s in ("extract", "match", "map"))
                      + f", {row['registered']} registered, rot {rot:.3f} deg, centre {cen:.3f}% R, load {load:.1f}"
                      + (f", error: {r['error']}" if r["error"] else ""), flush=True)
                write_csv(runs_path, runs, RUN_FIELDS)
                write_csv(summary_path, summarize(runs), SUMMARY_FIELDS)
    print(f"\nmedians over {args.repeats} repeats ({args.subset} subsets, threads {args.threads}):")
    for row in summarize(runs):
        print(f"  {row['method']:17s} n={row['images']:3d}  total {row['total_s']:6.1f}s  "
              f"cpu {row['total_cpu_s']:6.1f}s  extract {row['extract_s']:5.1f}  match {row['match_s']:5.1f}  "
              f"map {row['map_s']:5.1f}  ratio {row['time_ratio']} (cpu {row['cpu_ratio']})  {row['registered']}  "
              f"rot {_num(row['median_rot_deg'])}  centre {_num(row['median_centre_pct_radius'])}%  "
              f"accurate {row['accurate']}  load {row['load_1min']}")
    print(f"wrote {summary_path} and {runs_path}")
    return 0
