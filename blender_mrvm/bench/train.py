"""Training throughput: optimizer steps and rays per second for each model preset, batch shape and precision.

Each configuration runs the real trainer (``training.trainer.train``: the ray batcher, the model's losses
with MRVM's masking where the preset has it, the backward pass, clipping and the AdamW step) for
``--warmup`` + ``--steps`` + 2 steps and times the ``--steps`` after the warm-up (the next step measures the
memory; the last step, which writes the checkpoint, is not timed). A batch is ``OBJECTSxRAYS``:
``train.objects_per_step`` objects, each with its own 1-3 references, and ``train.rays_per_object`` target rays
each. Data: ``--data`` (a dataset root, its train split), else a small analytic set made in a temporary folder
(``training.synthetic``: 8 objects x 12 views at ``--resolution``).

Each row: steps and rays per second (wall), process CPU seconds per step, the share of the step spent drawing
the batch on the CPU (``RayBatcher.draw``: picking views, making rays; the rest is the model, the loss, the
backward pass and the update), the peak extra memory of one step after the timed ones (``bench.PeakMemory`` with
the allocator's freed memory handed back first; on CUDA the allocator's peak), and on a GPU its mean utilisation over
the timed steps (``torch.cuda.utilization``, else ``nvidia-smi``, sampled every 0.2 s). Written to
``<out>/bench_train.csv``. Issue 11 asks a GPU session for exactly these (steps per second, GPU
utilisation, bf16 against fp32)::

    python -m blender_mrvm bench train --device cuda --presets fast,balanced,accurate,paper,gpnr:fast \
        --batches 2x256,8x1024,16x4096 --precisions fp32,bf16 --data data/shapenet13_all --out docs/bench_train_gpu

``--profile K`` runs K more steps per configuration under ``torch.profiler`` (CPU, and CUDA activities on a
GPU; after the timed steps, so the timing is not the profiler's) and adds to each row the ATen operator calls,
kernel launches, host-device synchronisations and device allocations per step and the device's busy
milliseconds per step (kernels and copies); ``<out>/bench_train_profile.txt`` gets each configuration's
operator table (the profiler's own). Comparing fp32 with bf16 rows says where a slower precision loses: more
launches per step (casts), synchronisations, allocations, or slower kernels.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path

from . import PeakMemory, mib_cell, write_csv

RESULTS = ("bench_train.csv", "bench_train_profile.txt")
"""What the bench writes into ``--out`` (``bench.check_results``)."""

PRECISIONS = {"fp32": "none", "bf16": "bf16", "fp16": "fp16"}
"""Bench precision name -> ``train.amp``."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_train.csv")
    p.add_argument("--presets", default="fast,balanced",
                   help="comma-separated model presets; KIND:PRESET for another model kind (e.g. gpnr:fast)")
    p.add_argument("--batches", default="2x256,2x1024,8x256",
                   help="comma-separated OBJECTSxRAYS: objects per step x target rays per object")
    p.add_argument("--precisions", default="fp32", help="comma-separated fp32, bf16, fp16 (fp16 on a GPU only)")
    p.add_argument("--object-batches", default="1",
                   help="comma-separated train.object_batch values: objects rendered in one forward pass (1 = one "
                   "at a time; model kinds that cannot batch objects train one at a time whatever this says)")
    p.add_argument("--ref-views-per", default="object",
                   help="comma-separated train.ref_views_per values: 'object' (each object draws its reference count) "
                   "or 'step' (one count a step: with --object-batches a step is one forward pass)")
    p.add_argument("--device", default="cpu", help="cpu or cuda[:N] (default cpu)")
    p.add_argument("--steps", type=int, default=20, help="timed steps per configuration")
    p.add_argument("--warmup", type=int, default=3, help="untimed steps first (allocator, autotuning; at least 1)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (train.threads)")
    p.add_argument("--data", default=None, help="dataset root to train on (default: a small analytic set)")
    p.add_argument("--resolution", type=int, default=64, help="image side of the analytic set")
    p.add_argument("--compile", action="store_true",
                   help="train with the networks torch.compiled (train.compile); the warm-up steps pay the compilation")
    p.add_argument("--lpips-weight", type=float, default=0.0,
                   help="train with the LPIPS patch loss at this weight (train.lpips_weight, as the shipped recipe "
                   "does): each object's rays are then one P x P patch, so RAYS must be P*P with P >= 16 (2x256: "
                   "two 16 x 16 patches)")
    p.add_argument("--profile", type=int, default=0,
                   help="steps profiled after the timed ones (torch.profiler; 0 = none): counts per step in the CSV, "
                   "operator tables in bench_train_profile.txt")


def parse_batches(text: str) -> list[tuple[int, int]]:
    """``"2x256,8x1024"`` -> [(2, 256), (8, 1024)]; InputError for anything else."""
    from ..errors import InputError

    out = []
    for part in [s.strip() for s in str(text).split(",") if s.strip()]:
        a, sep, b = part.lower().partition("x")
        if not sep or not a.isdigit() or not b.isdigit() or int(a) < 1 or int(b) < 1:
            raise InputError(f"--batches: {part!r} is not OBJECTSxRAYS (e.g. 2x256)")
        out.append((int(a), int(b)))
    if not out:
        raise InputError("--batches is empty")
    return out


def parse_precisions(text: str, device: str) -> list[str]:
    from ..errors import InputError

    precs = [s.strip() for s in str(text).split(",") if s.strip()]
    bad = [s for s in precs if s not in PRECISIONS or (s == "fp16" and not device.startswith("cuda"))]
    if bad or not precs:
        raise InputError(f"--precisions: {bad or precs} not among fp32, bf16 (and fp16 on a GPU)")
    return precs


class GpuUtilisation:
    """Mean GPU utilisation (percent) over a block, sampled on a thread every ``period`` seconds from
    ``torch.cuda.utilization`` (needs pynvml) or ``nvidia-smi``; ``pct`` stays None where neither answers."""

    def __init__(self, device: str, period: float = 0.2):
        self.device, self.period = str(device), float(period)
        self.samples: list[float] = []
        self.pct: float | None = None
        self._stop = threading.Event()
        self._read = self._reader() if self.device.startswith("cuda") else None

    def _reader(self):
        import torch

        idx = torch.device(self.device).index or 0
        try:
            torch.cuda.utilization(idx)
            return lambda: float(torch.cuda.utilization(idx))
        except Exception:  # no pynvml: ask the driver's tool
            pass
        smi = shutil.which("nvidia-smi")
        if smi is None:
            return None
        cmd = [smi, f"--id={idx}", "--query-gpu=utilization.gpu", "--format=csv,noheader,nounits"]

        def read() -> float:
            return float(subprocess.run(cmd, capture_output=True, text=True, timeout=5).stdout.split()[0])

        try:
            read()
        except Exception:
            return None
        return read

    def _loop(self) -> None:
        while not self._stop.wait(self.period):
            try:
                self.samples.append(self._read())
            except Exception:
                pass

    def __enter__(self) -> "GpuUtilisation":
        if self._read is not None:
            self._thread = threading.Thread(target=self._loop, daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._read is not None:
            self._stop.set()
            self._thread.join()
            self.pct = sum(self.samples) / len(self.samples) if self.samples else None


PROFILE_COUNTS = {
    "kernel_launches": ("cudaLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernel", "cuLaunchKernelEx",
                        "cudaLaunchCooperativeKernel"),
    "syncs": ("cudaStreamSynchronize", "cudaDeviceSynchronize", "cudaEventSynchronize", "cudaMemcpy"),
    "device_allocs": ("cudaMalloc", "cudaFree", "cudaMallocAsync", "cudaFreeAsync"),
}
"""Profile columns (per step) counted from the CUDA runtime calls of these names (0 on the CPU)."""


PROFILE_COLUMNS = ("aten_ops_per_step", *(f"{c}_per_step" for c in PROFILE_COUNTS), "device_ms_per_step")


def profile_counts(events, steps: int) -> dict:
    """Per-step counts from a profiler's ``key_averages()``: ATen operator calls, the :data:`PROFILE_COUNTS`
    runtime calls, and the device's busy milliseconds (the summed time of the events that ran on the device:
    kernels, copies, fills; '' where the profiler has no device time)."""
    from torch.autograd import DeviceType

    out = {"aten_ops_per_step": round(sum(e.count for e in events if e.key.startswith("aten::")) / steps, 1)}
    for col, names in PROFILE_COUNTS.items():
        out[f"{col}_per_step"] = round(sum(e.count for e in events if e.key in names) / steps, 1)
    busy = [getattr(e, "self_device_time_total", getattr(e, "self_cuda_time_total", 0.0)) for e in events
            if getattr(e, "device_type", None) == DeviceType.CUDA]
    out["device_ms_per_step"] = round(sum(busy) / 1000 / steps, 3) if busy else ""
    return out


def profile_table(events, device: str, rows: int = 30) -> str:
    """The profiler's own operator table, by self device time on a GPU (self CPU time otherwise)."""
    keys = ("self_device_time_total", "self_cuda_time_total") if device.startswith("cuda") else ()
    for key in (*keys, "self_cpu_time_total"):
        try:
            return events.table(sort_by=key, row_limit=rows)
        except Exception:  # an older torch names the device column otherwise
            continue
    return ""


def patch_side(rays: int) -> int:
    """P for a batch of ``rays`` target rays per object under the LPIPS patch loss (one P x P patch, P >= 16);
    InputError when ``rays`` is no such square."""
    import math

    from ..errors import InputError

    side = math.isqrt(rays)
    if side * side != rays or side < 16:
        raise InputError(f"--lpips-weight trains on P x P patches: rays per object must be P*P with P >= 16 "
                         f"(256, 576, 1024, ...), got {rays}")
    return side


def parse_object_batches(text: str) -> list[int]:
    """``"1,8"`` -> [1, 8]; InputError for anything but positive integers."""
    from ..errors import InputError

    parts = [s.strip() for s in str(text).split(",") if s.strip()]
    if not parts or not all(p.isdigit() and int(p) >= 1 for p in parts):
        raise InputError(f"--object-batches: {text!r} is not a comma-separated list of integers >= 1")
    return [int(p) for p in parts]


def measure(model_cfg, scenes, objects: int, rays: int, precision: str, device: str, steps: int, warmup: int,
            threads: int, run_dir: Path, profile: int = 0, compile: bool = False, lpips_weight: float = 0.0,
            object_batch: int = 1, ref_views_per: str = "object") -> dict:
    """Train ``model_cfg`` on ``scenes`` for ``warmup + steps + 1 + profile + 1`` steps in ``run_dir`` at the bench's
    batch shape and precision (:func:`measure_config`)."""
    from ..training.config import TrainConfig

    tcfg = TrainConfig(objects_per_step=objects, rays_per_object=rays, amp=PRECISIONS[precision], device=device,
                       threads=threads, seed=0, compile=compile, lpips_weight=lpips_weight,
                       patch_size=patch_side(rays) if lpips_weight > 0 else 16, object_batch=object_batch,
                       ref_views_per=ref_views_per)
    return measure_config(model_cfg, tcfg, scenes, steps, warmup, run_dir, profile)


def measure_config(model_cfg, tcfg, scenes, steps: int, warmup: int, run_dir: Path, profile: int = 0) -> dict:
    """Train ``model_cfg`` with the run settings ``tcfg`` (any recipe; its length, logging, checkpoints and init
    are the bench's) on ``scenes`` for ``warmup + steps + 1 + profile + 1`` steps in ``run_dir``; the timing of
    the ``steps`` after the warm-up (wall, process CPU) and the GPU's utilisation over them, the peak extra memory
    of the step after them (``PeakMemory(release=True)``); with ``profile`` > 0 the next ``profile`` steps under
    ``torch.profiler`` (:func:`profile_counts` and, as ``profile_table``, :func:`profile_table`)."""
    import torch

    from ..progress import Progress
    from ..training.config import replace
    from ..training.trainer import RayBatcher, train

    total = warmup + steps + 1 + profile + 1  # (+1: the step whose memory is measured, after the timed ones)
    tcfg = replace(tcfg, out_dir=str(run_dir), iterations=total, log_every=total, ckpt_every=total,
                   keep_checkpoints=1, init_checkpoint="")
    device = tcfg.device
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    # the memory of one more step, the allocator's freed memory handed back first (which the timed steps must not
    # pay for): measured over the timed steps, the peak had left out what the warm-up freed and the CLI's allocator
    # keeps mapped (up to 256 MiB)
    mem, util = PeakMemory(device, release=True), GpuUtilisation(device)
    t0 = c0 = None
    wall = cpu = 0.0
    drawing = [False, 0.0]  # timing on, seconds in RayBatcher.draw while on
    draw = RayBatcher.draw

    def timed_draw(self, *a, **kw):
        t = time.perf_counter()
        try:
            return draw(self, *a, **kw)
        finally:
            if drawing[0]:
                drawing[1] += time.perf_counter() - t

    RayBatcher.draw = timed_draw
    prof = None
    found: dict = {}
    try:
        gen = train(model_cfg, tcfg, resume=False, scenes=scenes, force=True)
        for ev in gen:
            if not isinstance(ev, Progress):
                continue
            if ev.done == warmup:
                sync()
                util.__enter__()
                t0, c0 = time.perf_counter(), time.process_time()
                drawing[0] = True
            elif ev.done == warmup + steps:
                sync()
                wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                drawing[0] = False
                util.__exit__(None, None, None)
                mem.__enter__()
            elif ev.done == warmup + steps + 1:
                sync()
                mem.__exit__(None, None, None)
            if profile and ev.done == warmup + steps + 1:
                acts = [torch.profiler.ProfilerActivity.CPU]
                if device.startswith("cuda"):
                    acts.append(torch.profiler.ProfilerActivity.CUDA)
                prof = torch.profiler.profile(activities=acts)
                prof.__enter__()
            elif prof is not None and ev.done == warmup + steps + 1 + profile:
                sync()
                prof.__exit__(None, None, None)
                events = prof.key_averages()
                found = {**profile_counts(events, profile), "profile_table": profile_table(events, device)}
                prof = None
        gen.close()
    finally:
        RayBatcher.draw = draw
        if prof is not None:  # stopped early: leave no profiler running
            prof.__exit__(None, None, None)
    return {"seconds": wall, "cpu_seconds": cpu, "draw_share": drawing[1] / wall if wall else float("nan"),
            "peak_extra_mib": mem.mib, "gpu_util_pct": util.pct, **found}


def run(args) -> int:
    import torch

    from ..datasets.loaders import load_dataset
    from ..errors import InputError
    from ..models import registry
    from ..training.run_folder import check_device
    from ..training.synthetic import make_sphere_dataset

    from ..validation import check_device_name

    device = str(args.device).strip().lower()
    check_device_name("--device", device, allow_auto=False)  # before --out is made: 'tpu' left an empty folder
    check_device(device)
    if args.steps < 1 or args.warmup < 1 or args.threads < 1 or args.profile < 0:
        raise InputError("--steps, --warmup and --threads must be at least 1 (the first step carries the set-up: "
                         "it is never timed), --profile at least 0")
    batches = parse_batches(args.batches)
    if not args.lpips_weight >= 0:
        raise InputError(f"--lpips-weight must be >= 0, got {args.lpips_weight}")
    if args.lpips_weight > 0:
        for _, rays in batches:
            patch_side(rays)
    precisions = parse_precisions(args.precisions, device)
    object_batches = parse_object_batches(args.object_batches)
    ref_pers = [s.strip() for s in str(args.ref_views_per).split(",") if s.strip()]
    if not ref_pers or any(r not in ("object", "step") for r in ref_pers):
        raise InputError(f"--ref-views-per: {args.ref_views_per!r} is not a comma-separated list of object, step")
    presets = []
    for preset in [s.strip() for s in args.presets.split(",") if s.strip()]:
        kind, _, name = preset.rpartition(":")
        presets.append((name, registry.build_config(kind or None, name)))  # unknown names fail before any work
    if not presets:
        raise InputError("--presets is empty")
    if args.data and not Path(args.data).exists():
        raise InputError(f"--data {args.data} does not exist")
    from . import start_results

    out = start_results(Path(args.out), RESULTS, args.force)
    rows = []
    with tempfile.TemporaryDirectory(prefix="mrvm_bench_train_") as tmp:
        tmp = Path(tmp)
        if args.data:
            data, source = Path(args.data), str(args.data)
        else:
            data = make_sphere_dataset(tmp / "data", n_objects=8, n_views=12, resolution=args.resolution,
                                       data_passes=False)  # no depth loss here: no OpenEXR needed
            source = f"analytic spheres, 8 objects x 12 views, {args.resolution} px"
        if not data.exists():
            raise InputError(f"--data {data} does not exist")
        scenes = load_dataset(data, "train")
        gpu = torch.cuda.get_device_name(torch.device(device)) if device.startswith("cuda") else ""
        for name, cfg in presets:
            probe = registry.build_model(cfg)
            params, batches_objects = sum(p.numel() for p in probe.parameters()), probe.supports_object_batch
            for (objects, rays), prec, ob, rp in [(b, p, o, r) for b in batches for p in precisions
                                                  for o in object_batches for r in ref_pers]:
                tag = (f"{objects}x{rays} {prec}" + (f" batch {ob}" if len(object_batches) > 1 or ob > 1 else "")
                       + (f" refs per {rp}" if len(ref_pers) > 1 or rp != "object" else ""))
                try:
                    r = measure(cfg, scenes, objects, rays, prec, device, args.steps, args.warmup, args.threads,
                                tmp / f"run_{len(rows)}_{name}_{objects}x{rays}_{prec}_b{ob}_{rp}", args.profile,
                                args.compile, args.lpips_weight, ob, rp)
                except torch.cuda.OutOfMemoryError:  # one configuration too large: the others still run
                    torch.cuda.empty_cache()
                    print(f"{name:9s} {tag} {device}: out of memory, skipped", flush=True)
                    continue
                sps = args.steps / r["seconds"]
                rows.append({
                    "kind": registry.kind_of(cfg), "preset": name, "params": params, "device": device,
                    "precision": prec, "compiled": bool(args.compile), "objects_per_step": objects,
                    "object_batch": ob if batches_objects else 1, "ref_views_per": rp,
                    "rays_per_object": rays,
                    "rays_per_step": objects * rays, "lpips_weight": args.lpips_weight, "steps": args.steps, "seconds": round(r["seconds"], 3),
                    "steps_per_s": round(sps, 3), "rays_per_s": round(sps * objects * rays, 1),
                    "cpu_seconds_per_step": round(r["cpu_seconds"] / args.steps, 4),
                    "draw_share": round(r["draw_share"], 3) if r["draw_share"] == r["draw_share"] else "",
                    "peak_extra_mib": mib_cell([r["peak_extra_mib"]]),
                    "gpu_util_pct": "" if r["gpu_util_pct"] is None else round(r["gpu_util_pct"], 1),
                    **{k: r.get(k, "") for k in PROFILE_COLUMNS if args.profile},
                    "threads": args.threads, "data": source, "load_1min": round(os.getloadavg()[0], 2),
                    "cpu": platform.processor() or platform.machine(), "gpu": gpu, "torch": torch.__version__})
                if args.profile:
                    with open(out / "bench_train_profile.txt", "w" if len(rows) == 1 else "a") as f:
                        f.write(f"== {name} {tag} {device}: {args.profile} step(s) profiled; per "
                                f"step: " + ", ".join(f"{k} {r.get(k, '')}" for k in PROFILE_COLUMNS) + "\n"
                                + r.get("profile_table", "") + "\n")
                util = f", GPU {rows[-1]['gpu_util_pct']}%" if device.startswith("cuda") else ""
                peak = rows[-1]["peak_extra_mib"]  # '' where it cannot be measured
                print(f"{name:9s} {tag} {device}: {sps:.2f} steps/s, "
                      f"{rows[-1]['rays_per_s']:.0f} rays/s, drawing the batch {100 * r['draw_share']:.0f} %, "
                      f"peak +{'?' if peak == '' else peak} MiB{util}", flush=True)
                write_csv(out / "bench_train.csv", rows, quiet=True)  # a run cut short keeps its rows
    if not rows:
        raise InputError("bench train: no configuration could run (out of memory for every one)")
    write_csv(out / "bench_train.csv", rows)
    return 0
