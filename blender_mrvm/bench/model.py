"""Model rendering speed: seconds per novel view for each preset, and the work box clipping saves.

For each preset and reference count, a randomly initialised model (speed does not depend on the
weights) renders a view of an SRN-like set-up (camera 1.3 units from a [-0.4, 0.4]^3 object box,
f = 131.25 px at 128 px: pixelNeRF's SRN cars cameras) after one warm-up render; the median of
``--repeats`` timed renders is reported with the rays evaluated (those that hit the object's box)
against all rays, and the points evaluated against evaluating every ray with the same samples between a fixed near and
far (what pixelNeRF does), with the process CPU seconds (steadier than wall time on a shared machine) and
the peak extra resident memory of one more, untimed render (``bench.PeakMemory``, the allocator's freed memory
handed back first; bounded by ``render.chunk_rays``, not by the image size; an empty cell where it cannot be
measured). Figures go to ``<out>/bench_model.csv`` (one row per preset x views x size).
The issue's target: ``balanced``, 128 x 128, 2 reference views, about 1 s on 2 CPU cores.

``--precisions`` compares fp32 with bf16 autocast and, on the CPU, int8 linear layers (``models/precision.py``).
On a GPU (``--device cuda``) each row also has frames per second and ``--precisions`` compares fp32 with
bf16 / fp16 autocast (the issue's GPU target: 30 FPS for ``fast`` at 256 x 256)::

    python -m blender_mrvm bench model --device cuda --presets fast,balanced,accurate,gpnr:fast \
        --views 2 --sizes 128,256 --precisions fp32,bf16 --repeats 10 --out docs/bench_model_gpu
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

from . import PeakMemory, mib_cell, write_csv

RESULTS = ("bench_model.csv", "bench_model_profile.txt")
"""What the bench writes into ``--out`` (``bench.check_results``)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_model.csv")
    p.add_argument("--presets", default="fast,balanced,accurate",
                   help="comma-separated model presets; KIND:PRESET for another model kind (e.g. gpnr:fast)")
    p.add_argument("--views", default="1,2", help="comma-separated reference-view counts")
    p.add_argument("--sizes", default="128", help="comma-separated square render sizes")
    p.add_argument("--repeats", type=int, default=3, help="timed renders per configuration (median reported)")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    p.add_argument("--workers", type=int, default=1,
                   help="ray chunks rendered side by side on threads (threads.render_workers; torch threads then 1)")
    p.add_argument("--device", default="cpu", help="cpu or cuda[:N] (GPU timings synchronise before reading the clock)")
    p.add_argument("--chunk", type=int, default=0, help="rays per forward pass (0 = the model's; a GPU wants 16384+)")
    p.add_argument("--precisions", default="fp32",
                   help="comma-separated fp32, bf16, fp16 (a GPU only), int8 (linear layers; the CPU only)")
    p.add_argument("--compile", action="store_true",
                   help="torch.compile the model's networks first (every submodule but the image encoder, dynamic "
                   "shapes; the warm-up render pays the compilation): a GPU experiment for the FPS target, minutes "
                   "of compilation on a CPU")
    p.add_argument("--compile-mode", default=None,
                   choices=("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs"),
                   help="torch.compile's mode (implies --compile): reduce-overhead replays CUDA graphs, which the "
                   "bench's fixed view allows (a real orbit changes the ray count every view)")
    p.add_argument("--profile", action="store_true",
                   help="one more render per configuration under torch.profiler (CUDA activities on a GPU), after the "
                   "timed ones: ATen calls, kernel launches, syncs, device allocations and device-busy ms per view in "
                   "the CSV, the profiler's operator table in bench_model_profile.txt")
    p.add_argument("--ref-size", type=int, default=0,
                   help="reference images' side in pixels (default 0: the view's size); synthesis gives a model its "
                   "training size (64 px for the shipped ones), so large views are best measured with --ref-size 64")


def run(args) -> int:
    import numpy as np
    import torch

    from ..errors import InputError
    from ..geometry import cameras
    from ..models import registry
    from ..synthesis.views import resolve_device
    from . import at_least, names, start_results, whole_numbers

    at_least(args, repeats=1, threads=1, workers=1, chunk=0, ref_size=0)
    presets = []
    for preset in names(args.presets, "--presets"):  # an empty list had read "out of memory for every one"
        kind, _, name = preset.rpartition(":")
        presets.append((preset, name, registry.build_config(kind or None, name)))  # unknown names fail now
    sizes, view_counts = whole_numbers(args.sizes, "--sizes"), whole_numbers(args.views, "--views")
    torch.set_num_threads(1 if args.workers > 1 else args.threads)
    device = str(resolve_device(args.device))
    precisions = [s.strip() for s in args.precisions.split(",") if s.strip()]
    from ..models.precision import PRECISIONS, check_precision, for_precision

    if not precisions:
        raise InputError(f"--precisions: none given; choose from {', '.join(PRECISIONS)}")
    for prec in precisions:
        check_precision("--precisions", prec, device)
    if "int8" in precisions and compile_mode(args):
        raise InputError("--precisions int8 and --compile do not combine (torch.compile takes float layers)")
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    out = start_results(Path(args.out), RESULTS, args.force)
    rows = []
    eyes = [np.array(e, float) / np.linalg.norm(e) * 1.3 for e in ([1, 0.2, 0.4], [-0.2, 1, 0.3], [0.6, -0.7, 0.5],
                                                                   [-0.8, -0.5, 0.2])]
    bbox = (np.full(3, -0.4), np.full(3, 0.4))
    for preset, name, cfg in presets:
        torch.manual_seed(0)
        model = registry.build_model(cfg).eval().to(device)
        n_params = sum(p.numel() for p in model.parameters())
        mode = compile_mode(args)
        if mode:
            registry.compile_networks(model, None if mode == "default" else mode)
        nets = {prec: for_precision(model, prec) for prec in precisions}  # int8: one copy with int8 linear layers
        for size in sizes:
            intr = cameras.Intrinsics(131.25 * size / 128, 131.25 * size / 128, size / 2, size / 2, size, size)
            for nv in view_counts:
                rs = args.ref_size or size
                refs = np.random.default_rng(0).random((nv, rs, rs, 3)).astype(np.float32)
                rintr = [intr.resized(rs, rs)] * nv
                ref_poses = [cameras.look_at_opencv(e) for e in ref_eyes(eyes, nv)]
                target = cameras.look_at_opencv(eyes[0])
                for prec in precisions:
                    net = nets[prec]
                    try:
                        times, cpus, peaks, res = _time_renders(args, net, refs, ref_poses, rintr, bbox, target,
                                                                intr, prec, device, sync)
                    except torch.cuda.OutOfMemoryError:  # one configuration too large: the others still run
                        torch.cuda.empty_cache()
                        print(f"{preset:9s} {size}px {nv} ref(s) {prec} {device}: out of memory, skipped", flush=True)
                        continue
                    rows.append(_row(args, cfg, name, size, rs, nv, n_params, prec, device, times, cpus, peaks, res,
                                     model.inference_chunk(args.chunk or None)))
                    if args.profile:
                        counts, table = _profile_render(args, net, refs, ref_poses, rintr, bbox, target, intr, prec,
                                                        device, sync)
                        rows[-1].update(counts)
                        with open(out / "bench_model_profile.txt", "w" if len(rows) == 1 else "a") as f:
                            f.write(f"== {preset} {size}px {nv} ref(s) {prec} {device} compiled={args.compile_mode or bool(args.compile)}: "
                                    + ", ".join(f"{k} {v}" for k, v in counts.items()) + "\n" + table + "\n")
                    peak = rows[-1]["peak_extra_mib"]  # '' where it cannot be measured
                    print(f"{preset:9s} {size}px {nv} ref(s) {prec} {device}: {rows[-1]['seconds_median']:.3f} s/view "
                          f"({rows[-1]['fps']:.1f} FPS), {res['evaluated']}/{res['rays']} rays evaluated, "
                          f"peak +{'?' if peak == '' else peak} MiB", flush=True)
                    write_csv(out / "bench_model.csv", rows, quiet=True)  # a run cut short keeps its rows
    if not rows:
        raise InputError("bench model: no configuration could run (out of memory for every one)")
    write_csv(out / "bench_model.csv", rows)
    return 0


def _time_renders(args, model, refs, ref_poses, rintr, bbox, target, intr, prec, device, sync):
    """One warm-up render, ``args.repeats`` timed ones, then one for the memory (``PeakMemory(release=True)``):
    (wall seconds, process CPU seconds, [peak extra MiB], the last timed render's result)."""
    from ..models.precision import autocast

    with autocast(prec, device):
        model.synthesize(refs, ref_poses, rintr, bbox, target, intr, chunk=args.chunk or None,
                         workers=args.workers)  # warm-up
        sync()
        times, cpus = [], []
        for _ in range(args.repeats):
            t0, c0 = time.perf_counter(), time.process_time()
            res = model.synthesize(refs, ref_poses, rintr, bbox, target, intr,
                                   chunk=args.chunk or None, workers=args.workers)
            sync()
            times.append(time.perf_counter() - t0)
            cpus.append(time.process_time() - c0)
        # the memory on one more, untimed render, the allocator's freed memory handed back first: inside the timed
        # renders the peak had left out what the warm-up freed and the CLI's allocator keeps (up to 256 MiB)
        with PeakMemory(device, release=True) as pm:
            model.synthesize(refs, ref_poses, rintr, bbox, target, intr, chunk=args.chunk or None,
                             workers=args.workers)
            sync()
    return times, cpus, [pm.mib], res


def compile_mode(args) -> str:
    """torch.compile's mode for this bench ('default' for a bare --compile), '' when nothing is compiled."""
    return args.compile_mode or ("default" if args.compile else "")


def _profile_render(args, model, refs, ref_poses, rintr, bbox, target, intr, prec, device, sync):
    """One render under ``torch.profiler``: (per-view counts as CSV columns, the operator table)."""
    import torch

    from .train import profile_counts, profile_table
    from ..models.precision import autocast

    acts = [torch.profiler.ProfilerActivity.CPU]
    if device.startswith("cuda"):
        acts.append(torch.profiler.ProfilerActivity.CUDA)
    with autocast(prec, device), torch.profiler.profile(activities=acts) as prof:
        model.synthesize(refs, ref_poses, rintr, bbox, target, intr, chunk=args.chunk or None, workers=args.workers)
        sync()
    events = prof.key_averages()
    counts = {k.replace("_per_step", "_per_view"): v for k, v in profile_counts(events, 1).items()}
    return counts, profile_table(events, device)


def _row(args, cfg, name, size, rs, nv, n_params, prec, device, times, cpus, peaks, res, chunk_rays) -> dict:
    """One CSV row: a preset x size x reference count x precision."""
    import torch

    from .. import threads
    from ..models import registry

    sec = statistics.median(times)
    pts_ray = points_per_ray(cfg)
    gpu = torch.cuda.get_device_name(torch.device(device)) if device.startswith("cuda") else ""
    return {
        "kind": registry.kind_of(cfg), "preset": name, "size": size, "ref_size": rs, "ref_views": nv,
        "threads": 1 if args.workers > 1 else args.threads, "workers": args.workers, "params": n_params,
        "device": device, "precision": prec, "compiled": bool(compile_mode(args)), "compile_mode": compile_mode(args),
        "seconds_median": round(sec, 4), "seconds_min": round(min(times), 4), "fps": round(1.0 / sec, 2),
        "cpu_seconds_median": round(statistics.median(cpus), 4), "peak_extra_mib": mib_cell(peaks),
        "chunk_rays": chunk_rays, "malloc": threads.malloc_policy, "load_1min": round(os.getloadavg()[0], 2),
        "rays_total": res["rays"], "rays_evaluated": res["evaluated"],
        "rays_skipped_pct": round(100 * (1 - res["evaluated"] / res["rays"]), 1),
        # the points the render evaluated, as it counted them: the fine pass skips rays whose coarse opacity is under
        # render.fine_min_acc (on by default), so evaluated rays x points per ray had overstated it (GPNR counts none)
        "points_evaluated": res.get("samples") or res["evaluated"] * pts_ray,
        "points_fixed_near_far": res["rays"] * pts_ray,
        "rays_per_s": round(res["evaluated"] / sec, 1),
        "cpu": platform.processor() or platform.machine(), "gpu": gpu, "torch": torch.__version__,
    }


def points_per_ray(cfg) -> int:
    """Samples each evaluated ray costs: coarse + fine (+ coarse again) for NeRFormer, the epipolar depths
    for GPNR (each projected into every reference view)."""
    if hasattr(cfg, "sampler"):
        sc = cfg.sampler
        return sc.n_coarse + sc.n_fine + (sc.n_coarse if sc.fine_includes_coarse else 0)
    return int(cfg.n_samples)


def ref_eyes(eyes, n: int):
    """``n`` reference camera positions: the fixed ones after the target's, then more on a ring at the same
    distance (1.3 units) around the object."""
    import numpy as np

    out = list(eyes[1:1 + n])
    k = 0
    while len(out) < n:
        a = 2 * np.pi * k / max(1, n) + 0.3
        out.append(np.array([np.cos(a), np.sin(a), 0.35]) / np.linalg.norm([1.0, 0.35]) * 1.3)
        k += 1
    return out
