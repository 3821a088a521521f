"""Speed against accuracy: one-knob-at-a-time sweeps of every trained model kind, with the Pareto front.

Each checkpoint (``--checkpoints``, default the shipped NeRFormer+MRVM and GPNR models) is swept from its
own setting one knob at a time, at inference (the weights stay; every point is a real measurement):

- ``samples``: points per ray (NeRFormer: coarse and fine; GPNR: epipolar depths);
- ``refs``: number of reference views (1, 2, 5), spread evenly around each object;
- ``nearest``: a dense capture: each target rendered from its K nearest other views (2, 3, 5, 10;
  ``synthesize --nearest``), timed on view 0 from its K nearest;
- ``ref_size``: reference resolution (the references resized before encoding);
- ``precision``: fp32, bf16 autocast (and fp16 on a GPU; int8 linear layers on the CPU);
- ``gate``: NeRFormer's fine pass skipped on rays whose coarse opacity is below ``render.fine_min_acc``
  (off, a tenth of the default and 10x it);
- ``stop``: NeRFormer's early ray termination (``render.stop_transmittance`` 1e-3, 1e-2, 0.1): the fine pass
  skips a ray's samples behind the point the coarse pass says almost no light reaches;
- ``skip``: box clipping only, visual-hull culling (``models/hull.py``), hull tightening;
- ``chunk``: rays per forward pass (time and memory only: the numbers are the same).

Sem2NeRF (``shipped:sem2nerf`` or a ``sem2nerf train`` checkpoint; one part mask in, views out) has its own
knobs: ``samples`` (coarse + fine points per ray: half, no fine pass, double), ``skip`` (the input mask's
silhouette-cone culling on or off), ``precision`` and ``chunk``; its
quality is scored on novel views rendered from each object's view-0 mask (mean style), with their part mIoU,
and its time is one view's render with the mask already encoded (a user encodes a mask once, then renders views).

Width and depth are training-time choices: each trained model given in ``--checkpoints`` (its kind and
preset) is a point of its own. For every point:

- quality on held-out objects (``--data``, split ``--split``, ``--objects`` of them, one per category
  first, ``--targets`` target views each): PSNR, SSIM (pixelNeRF's convention), LPIPS-VGG;
- speed: median seconds per ``--size`` x ``--size`` view (wall and process CPU seconds; the CPU seconds
  are the steadier figure on a shared machine) over ``--repeats`` renders of a held-out object, rays per
  second, and the peak extra resident memory of one more (untimed) render, the allocator's freed memory
  handed back to the system first (Linux ``VmHWM`` reset through ``/proc/self/clear_refs``; on CUDA
  ``torch.cuda.max_memory_allocated``; an empty cell where it cannot be measured).

Writes ``<out>/bench_tradeoff.csv`` (one row per point, with the machine, threads and load) and
``<out>/bench_tradeoff.png`` (seconds per view against LPIPS and against PSNR, log time axis, the Pareto
front of each kind drawn as a line, the points on it listed in ``<out>/bench_tradeoff_front.md``).

Usage (about 30 minutes on one core)::

    python -m blender_mrvm bench tradeoff --data data/shapenet13_all --out docs/bench_tradeoff --threads 1
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..models.precision import autocast, for_precision
from . import PeakMemory, mib_cell, write_csv

RESULTS = ("bench_tradeoff.csv", "bench_tradeoff.png", "bench_tradeoff_front.md")
"""What the bench writes into ``--out`` (``bench.check_results``)."""
AXES = ("base", "samples", "gate", "stop", "filter", "refs", "nearest", "ref_size", "precision", "skip", "chunk")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, required=True, help="rendered dataset with held-out objects (make-shapenet)")
    p.add_argument("--split", default="test", help="held-out split (default test)")
    p.add_argument("--checkpoints", default="shipped:nerformer_mrvm,shipped:gpnr,shipped:sem2nerf",
                   help="comma-separated checkpoints (files, run folders or shipped:<kind>, shipped:sem2nerf); "
                        "each is swept")
    p.add_argument("--axes", default=",".join(AXES), help=f"comma-separated knobs to sweep ({', '.join(AXES)}); "
                   "the model as trained (base) is always measured too: each point is read against it")
    p.add_argument("--objects", type=int, default=13, help="held-out objects scored (one per category first)")
    p.add_argument("--targets", type=int, default=3, help="target views scored per object")
    p.add_argument("--size", type=int, default=128, help="timed view's side in pixels (default 128)")
    p.add_argument("--repeats", type=int, default=3, help="timed renders per point (median reported)")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    p.add_argument("--workers", type=int, default=1,
                   help="ray chunks rendered side by side on threads (threads.render_workers; torch threads then 1)")
    p.add_argument("--device", default="cpu", help="cpu, cuda[:N] or auto (CUDA when available); default cpu")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (the front then uses PSNR only)")
    p.add_argument("--out", type=Path, default=Path("bench_out"), help="folder for the CSV, PNG and front")


@dataclass
class Point:
    """One setting of one checkpoint."""

    axis: str
    label: str
    overrides: dict[str, Any] = field(default_factory=dict)
    refs: int = 2
    nearest: int = 0
    """> 0: each target from its ``nearest`` nearest other views (the targets stay those of ``refs`` spread ones)."""
    ref_size: int = 0
    precision: str = "fp32"
    skip: str = "cull"
    chunk: int = 0
    quality: bool = True
    """False: numbers are the base point's by construction (chunking), only speed is measured."""


def parse_axes(text: str) -> list[str]:
    """``--axes``: the knobs named, with ``base`` always first (session 32's `--axes precision` on a GPU came back
    without an fp32 point to read bf16 against, and the device time to rerun it was gone)."""
    from ..errors import InputError

    axes = [a.strip() for a in text.split(",") if a.strip()]
    bad = [a for a in axes if a not in AXES]
    if bad:
        raise InputError(f"--axes: unknown knob(s) {bad}; choose from {', '.join(AXES)}")
    return ["base", *[a for a in axes if a != "base"]]


def sweep(kind: str, cfg, axes: list[str], device: str) -> list[Point]:
    """The points of one checkpoint: its own setting, then each knob moved alone."""
    pts = [Point("base", "as trained")] if "base" in axes else []
    if "samples" in axes:
        from ..models.registry import quality_overrides

        half = quality_overrides(cfg, "preview")  # what `synthesize --quality preview` renders
        if kind == "gpnr":
            n = int(cfg.n_samples)
            for s in sorted({half["n_samples"], n * 2} - {n}):
                pts.append(Point("samples", f"{s} depths", {"n_samples": s}))
        else:
            c, f = int(cfg.sampler.n_coarse), int(cfg.sampler.n_fine)
            h = half["sampler"]
            for cc, ff in [(h["n_coarse"], h["n_fine"]), (c, 0), (c * 2, f * 2)]:
                if (cc, ff) != (c, f):
                    pts.append(Point("samples", f"{cc}+{ff} samples", {"sampler": {"n_coarse": cc, "n_fine": ff}}))
    if "gate" in axes and kind != "gpnr":
        g = float(cfg.render.fine_min_acc)
        for v in sorted({0.0, g / 10 if g > 0 else 1e-3, 10 * g if g > 0 else 1e-2} - {g}):
            pts.append(Point("gate", f"fine gate {v:g}" if v else "fine pass everywhere",
                             {"render": {"fine_min_acc": v}}))
    if "stop" in axes and kind != "gpnr":
        st = float(cfg.render.stop_transmittance)
        for v in sorted({0.0, 1e-3, 1e-2, 0.1} - {st}):
            pts.append(Point("stop", f"stop at T {v:g}" if v else "no early stop", {"render": {"stop_transmittance": v}}))
    if "filter" in axes and kind == "gpnr":  # how reference colours are read (GPNR's colour is a blend of them)
        other = "bilinear" if cfg.colour_filter == "bicubic" else "bicubic"
        pts.append(Point("filter", f"{other} colour reads", {"colour_filter": other}))
    if "refs" in axes:
        pts += [Point("refs", f"{r} refs", refs=r) for r in (1, 5)]
    if "nearest" in axes:
        pts += [Point("nearest", f"{k} nearest", nearest=k) for k in (2, 3, 5, 10)
                if k <= int(getattr(cfg, "max_ref_views", 10))]
    if "ref_size" in axes:
        pts.append(Point("ref_size", "refs at 32 px", ref_size=32))
    if "precision" in axes:
        pts += [Point("precision", p, precision=p) for p in precision_points(device)]
    if "skip" in axes:
        pts += [Point("skip", "box only", skip="off"), Point("skip", "hull tighten", skip="tighten")]
    if "chunk" in axes:
        pts += [Point("chunk", f"chunk {c}", chunk=c, quality=False) for c in (256, 4096)]
    return pts


def ref_views(n_views: int, k: int) -> list[int]:
    """``k`` reference view ids spread evenly over an object's ``n_views`` (turntable: evenly in azimuth)."""
    return [int(round(i * n_views / k + 3)) % n_views for i in range(k)]


def speed_refs(scene, pt: Point) -> list[int]:
    """The references of the timed view: ``pt.refs`` spread ones, or with ``pt.nearest`` view 0's nearest
    others (:func:`measure_speed` times the first view that is not a reference)."""
    if not pt.nearest:
        return ref_views(len(scene), pt.refs)
    from ..training.evaluate import nearest_of

    return nearest_of(scene, list(range(1, len(scene))), 0, pt.nearest)


def _timed(render, precision: str, repeats: int, device: str) -> tuple[Any, dict]:
    """(the last result, median wall / CPU seconds and peak extra MiB) of ``render()``: one warm-up call, then
    ``repeats`` timed ones, then one more for the memory (``PeakMemory(release=True)``: the allocator's freed
    memory handed back first, which the timed renders must not pay for; measured inside the timed renders, the
    peak had left out what the warm-up freed and the allocator kept, up to 256 MiB)."""
    import torch

    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    with autocast(precision, device):
        render()  # warm-up
        walls, cpus = [], []
        for _ in range(repeats):
            sync()
            w0, c0 = time.perf_counter(), time.process_time()
            res = render()
            sync()
            walls.append(time.perf_counter() - w0)
            cpus.append(time.process_time() - c0)
        with PeakMemory(device, release=True) as pm:
            render()
    return res, {"seconds_per_view": round(statistics.median(walls), 4),
                 "cpu_seconds_per_view": round(statistics.median(cpus), 4), "peak_extra_mib": mib_cell([pm.mib])}


def measure_speed(model, scene, refs: list[int], pt: Point, size: int, repeats: int, device: str,
                  workers: int = 1) -> dict:
    """Median wall / CPU seconds of one ``size`` x ``size`` view, rays, and peak extra memory (MiB)."""
    from ..synthesis import reference_shape, resize_mask, resize_view

    w, h = reference_shape(scene.intrinsics[refs[0]], pt.ref_size)
    mr = [resize_view(scene.images[r], scene.intrinsics[r], w, h) for r in refs]
    masks = None if scene.masks is None else np.stack([resize_mask(scene.masks[r], w, h) for r in refs])
    tgt = [v for v in range(len(scene)) if v not in refs][0]
    intr = scene.intrinsics[tgt].resized(size, size)
    args = (np.stack([im for im, _ in mr]), [scene.c2w[r] for r in refs], [k for _, k in mr], scene.bbox,
            scene.c2w[tgt], intr)
    kw = dict(chunk=pt.chunk or None, ref_masks=masks, skip=pt.skip, workers=workers)
    res, t = _timed(lambda: model.synthesize(*args, **kw), pt.precision, repeats, device)
    sec = t["seconds_per_view"]
    return {**t, "rays_total": res["rays"], "rays_box": res["box_rays"], "rays_evaluated": res["evaluated"],
            "rays_per_s": round(res["evaluated"] / sec, 1),
            "samples_per_ray": round(res.get("samples", 0) / max(1, res["evaluated"]), 2) if res.get("samples") else ""}


def measure_quality(model, scenes, pt: Point, targets: int, lpips, device: str, workers: int = 1) -> dict:
    from ..progress import run_to_end
    from ..training.evaluate import evaluate

    gen = evaluate(model, scenes, ref_views(len(scenes[0]), pt.refs), lpips,
                   max_targets=targets, chunk=pt.chunk or None, ref_size=pt.ref_size, skip=pt.skip, workers=workers,
                   nearest=pt.nearest)
    with autocast(pt.precision, device):
        rep = run_to_end(gen)
    o = rep["overall"]
    return {k: round(float(o[k]), 4) for k in ("psnr", "ssim", "lpips") if o.get(k) is not None}


def sem2nerf_file(spec: str):
    """The model file of ``spec`` when it is a Sem2NeRF checkpoint, else None."""
    from ..models.checkpoint_files import checked_header
    from ..models.pretrained import resolve_checkpoint
    from ..models.sem2nerf.config import MODEL_KIND

    f, meta = checked_header(resolve_checkpoint(spec))
    return f if meta.get("model_kind") == MODEL_KIND else None


def precision_points(device: str) -> tuple[str, ...]:
    """The precision axis's points beside fp32 (the base): bf16 and fp16 autocast on a GPU; bf16 and int8 weights
    on the CPU (``models/precision.py``)."""
    return ("bf16", "fp16") if device.startswith("cuda") else ("bf16", "int8")


def sem2nerf_sweep(cfg, axes: list[str], device: str) -> list[Point]:
    """A Sem2NeRF checkpoint's points: its own setting, then each of its knobs moved alone."""
    pts = [Point("base", "as trained", refs=1)] if "base" in axes else []
    if "samples" in axes:
        from ..models.registry import quality_overrides

        c, f = int(cfg.n_coarse), int(cfg.n_fine)
        half = quality_overrides(cfg, "preview")  # what `sem2nerf render --quality preview` renders
        for cc, ff in [(half["n_coarse"], half["n_fine"]), (c, 0), (c * 2, f * 2)]:
            if (cc, ff) != (c, f):
                pts.append(Point("samples", f"{cc}+{ff} samples", {"n_coarse": cc, "n_fine": ff}, refs=1))
    if "skip" in axes:
        on = not cfg.cull_cone
        pts.append(Point("skip", "cone culling" if on else "no cone culling", {"cull_cone": on}, refs=1))
    if "precision" in axes:
        pts += [Point("precision", p, precision=p, refs=1) for p in precision_points(device)]
    if "chunk" in axes:
        sizes = (256, 4096, 16384, 65536) if device.startswith("cuda") else (256, 4096)  # a GPU wants large ones
        pts += [Point("chunk", f"chunk {c}", chunk=c, refs=1, quality=False) for c in sizes]
    return pts


def sem2nerf_targets(n_views: int, k: int) -> list[int]:
    """``k`` novel views spread evenly over an object's ``n_views``, away from the input view 0."""
    return sorted({(i + 1) * n_views // (k + 1) for i in range(k)} - {0})


def _sem2nerf_code(model, ob, device: str):
    import torch

    from ..models.sem2nerf.inputs import build_inputs

    with torch.no_grad():
        x = torch.from_numpy(build_inputs(ob.masks[0], model.cfg.labels))[None].to(device)
        return model.encode(x, ob.c2w[0][None], ob.intrinsics[0])


def measure_sem2nerf_speed(model, ob, pt: Point, size: int, repeats: int, device: str) -> dict:
    """Median wall / CPU seconds of one ``size`` x ``size`` novel view of ``ob`` (mask encoded beforehand)."""
    code, style = _sem2nerf_code(model, ob, device), model.default_style()
    v = sem2nerf_targets(len(ob.images), 1)[0]
    intr = ob.intrinsics[v].resized(size, size)
    _, t = _timed(lambda: model.render_image(intr, ob.c2w[v], code, style, chunk=pt.chunk or None), pt.precision,
                  repeats, device)
    st = model.last_render_stats  # (the rays render_image made and evaluated)
    return {**t, "rays_total": st["rays"], "rays_box": st["box"], "rays_evaluated": st["evaluated"],
            "rays_per_s": round(st["evaluated"] / t["seconds_per_view"], 1),
            "samples_per_ray": int(model.cfg.n_coarse + model.cfg.n_fine)}


def measure_sem2nerf_quality(model, objects, pt: Point, targets: int, lpips, device: str) -> dict:
    """Mean PSNR / SSIM / LPIPS and part mIoU of ``targets`` novel views per object, rendered at the data's
    size from the object's view-0 mask with the mean style."""
    import torch

    from ..training.evaluate import scores_against
    from ..training.sem2nerf import miou

    labels = torch.as_tensor(model.cfg.labels)
    rows = []
    with autocast(pt.precision, device):
        for ob in objects:
            code = _sem2nerf_code(model, ob, device)
            for v in sem2nerf_targets(len(ob.images), targets):
                img = model.render_image(ob.intrinsics[v], ob.c2w[v], code, model.default_style())
                pred = img["rgb"].float().clamp(0, 1).cpu()
                gt = torch.from_numpy(ob.images[v])
                sc = scores_against(gt, {"view": pred}, lpips)["view"]
                rows.append({**{k: sc[k] for k in ("psnr", "ssim", "lpips") if k in sc},
                             "miou": miou(ob.masks[v], labels[img["semantic"].float().argmax(-1).cpu()].numpy())})
    return {k: round(float(np.mean([r[k] for r in rows])), 4) for k in rows[0]}


def scored(r: dict, key: str) -> float | None:
    """``r[key]`` as a finite number, None when it is missing, empty, NaN or infinite (a CSV's 'nan')."""
    v = r.get(key)
    if v is None or v == "":
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        return None
    return v if np.isfinite(v) else None


def pareto(rows: list[dict], cost: str, loss: str) -> list[dict]:
    """Rows that no other row dominates (as cheap or cheaper and as good or better, and strictly one of the two),
    sorted by cost, then loss; points with the same cost and loss are all on it. Rows without a finite cost and
    loss are on no front (a NaN cost had sorted anywhere and put itself on the front, hiding real points)."""
    ok = [(c, l, r) for r in rows for c, l in [(scored(r, cost), scored(r, loss))] if c is not None and l is not None]
    ok.sort(key=lambda t: (t[0], t[1]))
    front, best, last = [], float("inf"), None
    for c, l, r in ok:
        if l < best or (c, l) == last:  # (c, l) == last: a tie with the point just kept, which does not dominate it
            front.append(r)
            best, last = l, (c, l)
    return front


def fits(pt: Point, n_views: int) -> bool:
    """Whether objects of ``n_views`` views can make the point: its references leave a view to render (``refs``)
    and a view has that many others to take the nearest from (``nearest``)."""
    return pt.refs < n_views and pt.nearest <= n_views - 1


def candidate_points(axes: list[str]) -> list[Point]:
    """The references (``refs``, ``nearest``) the points of ``axes`` can have whatever the checkpoint: what
    :func:`fits` needs to know before a model is loaded (the other knobs keep the base point's 2 references)."""
    pts = [Point(a, a) for a in axes if a not in ("refs", "nearest")]
    if "refs" in axes:
        pts += [Point("refs", "", refs=r) for r in (1, 5)]
    if "nearest" in axes:
        pts += [Point("nearest", "", nearest=k) for k in (2, 3, 5, 10)]
    return pts


def run(args) -> int:
    import torch

    from .. import threads
    from ..datasets.loaders import list_objects, load_object
    from ..errors import InputError
    from ..models import registry
    from ..models.config import merge
    from ..synthesis import load_checkpoint, resolve_device
    from ..models.pretrained import resolve_checkpoint
    from . import at_least, names, start_results

    at_least(args, objects=1, targets=1, size=1, repeats=1, threads=1, workers=1)
    args.device = str(resolve_device(args.device))  # 'gpu', or cuda on a CPU build: one line, not a traceback
    torch.set_num_threads(1 if args.workers > 1 else args.threads)
    axes = parse_axes(args.axes)
    # every checkpoint resolved and its header checked now, not when its turn comes after the others' sweeps
    specs = names(args.checkpoints, "--checkpoints")
    s2n_files = {spec: sem2nerf_file(spec) for spec in specs}
    lpips = None
    if not args.no_lpips:
        from ..models.metrics import LPIPS

        lpips = LPIPS()
    objs = list_objects(args.data, None, args.split)
    by_cat: dict[str, list] = {}
    for o in objs:
        by_cat.setdefault(Path(o[1]).parent.name, []).append(o)
    order = [c[i] for i in range(max(map(len, by_cat.values()), default=0)) for c in by_cat.values() if i < len(c)]
    scenes = [load_object(f, p, args.split) for f, p in order[:args.objects]]
    if not scenes:
        raise InputError(f"{args.data}: no objects in split {args.split!r}")
    n_views = min(len(sc) for sc in scenes)
    if all(f is None for f in s2n_files.values()) and not any(fits(pt, n_views) for pt in candidate_points(axes)):
        # before --out is touched: it had made the folder (and with --force removed the earlier results), loaded
        # every model, then said only "nothing was measured: no rows to write"
        raise InputError(f"no point of --axes {','.join(axes)} can be measured: the objects of {args.data} "
                         f"(split {args.split}) have {n_views} view(s), and every point needs a target view beside "
                         "its references (2 references by default: 3 views; --axes refs has 1 reference: 2 views)")
    # Sem2NeRF checkpoints loaded and their objects' masks checked before --out is touched: a set rendered at another
    # size had been refused after --force removed the earlier results
    s2n_models, masked = {}, None
    for spec in specs:
        if s2n_files[spec] is not None:
            from ..training.sem2nerf import load_masked_object, load_sem2nerf

            model, cfg0, _ = load_sem2nerf(s2n_files[spec], args.device)
            s2n_models[spec] = (model, cfg0)
            if masked is None:
                masked = [load_masked_object(path) for _, path in order[:args.objects]]
            for ob in masked:  # the encoder takes masks of its training size (as `sem2nerf eval` checks)
                if ob.masks.shape[1:] != (cfg0.image_size, cfg0.image_size):
                    raise InputError(f"{ob.category}/{ob.name}: masks are {ob.masks.shape[2]}x{ob.masks.shape[1]} px, "
                                     f"{spec} takes {cfg0.image_size} px masks (render the set at that resolution)")
    out = start_results(Path(args.out), RESULTS, args.force)
    load0 = os.getloadavg()[0]
    rows = []
    def add(kind: str, spec: str, cfg, n_params: int, pt: Point, speed: dict, quality: dict, n_objects: int,
            t0: float) -> None:
        row = {"kind": kind, "checkpoint": spec, "preset": getattr(cfg, "name", ""), "params": n_params,
               "axis": pt.axis, "point": pt.label, "refs": pt.nearest or pt.refs, "ref_size": pt.ref_size or "native",
               "precision": pt.precision, "skip_empty": pt.skip if kind != "sem2nerf" else "",
               "chunk": pt.chunk or pt.overrides.get("chunk_rays") or "model", "size": args.size, **speed,
               "psnr": quality.get("psnr", ""), "ssim": quality.get("ssim", ""), "lpips": quality.get("lpips", ""),
               "miou": quality.get("miou", ""),
               "quality": "measured" if pt.quality else "same numbers as 'as trained' (chunking only)",
               "objects": n_objects, "targets_per_object": args.targets,
               "threads": 1 if args.workers > 1 else args.threads, "workers": args.workers,
               "device": args.device, "malloc": threads.malloc_policy, "load_1min": round(os.getloadavg()[0], 2),
               "cpu": platform.processor() or platform.machine(), "torch": torch.__version__}
        rows.append(row)
        print(f"{kind:15s} {pt.axis:9s} {pt.label:16s} {speed['seconds_per_view']:7.3f} s/view "
              f"(cpu {speed['cpu_seconds_per_view']:.3f})  psnr {row['psnr']}  lpips {row['lpips']}  "
              f"[{time.perf_counter() - t0:.0f} s]", flush=True)
        write_csv(out / "bench_tradeoff.csv", rows, quiet=True)  # after every point: a stopped sweep keeps its rows

    for spec in specs:
        s2n = s2n_files[spec]
        if s2n is not None:
            from dataclasses import replace

            model, cfg0 = s2n_models.pop(spec)
            n_params = sum(p.numel() for p in model.parameters())
            for pt in sem2nerf_sweep(cfg0, axes, args.device):
                model.cfg = replace(cfg0, **pt.overrides)
                m = for_precision(model, pt.precision)  # int8: a copy with int8 linear layers
                t0 = time.perf_counter()
                speed = measure_sem2nerf_speed(m, masked[0], pt, args.size, args.repeats, args.device)
                quality = (measure_sem2nerf_quality(m, masked, pt, args.targets, lpips, args.device)
                           if pt.quality else {})
                add("sem2nerf", spec, cfg0, n_params, pt, speed, quality, len(masked), t0)
            model.cfg = cfg0
            continue
        ck = resolve_checkpoint(spec)
        model, cfg0, _, _ = load_checkpoint(ck, args.device)
        kind = registry.kind_of(cfg0)
        n_params = sum(p.numel() for p in model.parameters())
        for pt in sweep(kind, cfg0, axes, args.device):
            if not fits(pt, n_views):
                print(f"note: {kind} {pt.axis} point '{pt.label}' skipped: the objects have {n_views} views, too few "
                      "to leave a target beside its references", flush=True)
                continue
            model.cfg = merge(cfg0, pt.overrides) if pt.overrides else cfg0
            m = for_precision(model, pt.precision)  # int8: a copy with int8 linear layers
            t0 = time.perf_counter()
            speed = measure_speed(m, scenes[0], speed_refs(scenes[0], pt), pt, args.size, args.repeats,
                                  args.device, args.workers)
            quality = (measure_quality(m, scenes, pt, args.targets, lpips, args.device, args.workers)
                       if pt.quality else {})
            add(kind, spec, cfg0, n_params, pt, speed, quality, len(scenes), t0)
        model.cfg = cfg0
    write_csv(out / "bench_tradeoff.csv", rows)
    write_front(rows, out, load0)
    return 0


def model_name(r: dict) -> str:
    """A point's model in the fronts: its preset and checkpoint (several trained models of one kind share a
    front, e.g. `fast` and `balanced` at the same budget)."""
    return f"{r.get('preset', '')} ({Path(str(r.get('checkpoint', ''))).name})"


def point_name(r: dict, rows: list[dict]) -> str:
    """The point's label, prefixed by its model (:func:`model_name`) when its kind has points of several
    checkpoints."""
    several = len({x.get("checkpoint") for x in rows if x["kind"] == r["kind"]}) > 1
    return f"{model_name(r)}: {r['point']}" if several else r["point"]


def unscored_points(rows: list[dict]) -> list[dict]:
    """Measured points whose CPU seconds or a score they were given (PSNR, LPIPS) is not a finite number."""
    return [r for r in rows if r.get("quality") == "measured"
            and (scored(r, "cpu_seconds_per_view") is None or scored(r, "psnr") is None
                 or (r.get("lpips") not in (None, "") and scored(r, "lpips") is None))]


def write_front(rows: list[dict], out: Path, load0: float) -> None:
    """The Pareto fronts (markdown) and the plot (PNG)."""
    lines = ["# Pareto fronts (CPU seconds per view against LPIPS / PSNR)", "",
             f"Load average at the start: {load0:.2f}. Rows: `bench_tradeoff.csv`.", ""]
    for kind in sorted({r["kind"] for r in rows}):
        kr = [r for r in rows if r["kind"] == kind and r["quality"] == "measured"]
        for loss, lab in (("lpips", "LPIPS"), ("neg_psnr", "PSNR")):
            for r in kr:
                r["neg_psnr"] = -float(r["psnr"]) if r["psnr"] != "" else ""
            front = pareto(kr, "cpu_seconds_per_view", loss)
            lines += [f"## {kind}: seconds against {lab}", "", "| model | point | s/view (cpu) | PSNR | SSIM | LPIPS |",
                      "|---|---|---|---|---|---|"]
            lines += [f"| {model_name(r)} | {r['point']} | {r['cpu_seconds_per_view']:.3f} | {r['psnr']} | {r['ssim']} | {r['lpips']} |"
                      for r in front]
            lines.append("")
            for r in kr:
                r.pop("neg_psnr", None)
    unscored = unscored_points(rows)
    if unscored:  # a NaN score is on no front and in no plot: say which, not leave them out silently
        lines += ["## Left out (no finite CPU seconds, PSNR or LPIPS)", "",
                  *[f"- {r['kind']} {model_name(r)}: {r['point']} (cpu s {r.get('cpu_seconds_per_view')}, PSNR "
                    f"{r.get('psnr')}, LPIPS {r.get('lpips')})" for r in unscored], ""]
        print(f"warning: {len(unscored)} point(s) have no finite CPU seconds, PSNR or LPIPS and are on no front: "
              + "; ".join(f"{r['kind']} {r['point']}" for r in unscored), flush=True)
    (out / "bench_tradeoff_front.md").write_text("\n".join(lines))
    plot(rows, out / "bench_tradeoff.png")
    print(f"wrote {out / 'bench_tradeoff_front.md'} and {out / 'bench_tradeoff.png'}")


COLOURS = [(31, 119, 180), (214, 39, 40), (44, 160, 44), (148, 103, 189), (255, 127, 14)]


def plot(rows: list[dict], path: Path, w: int = 1100, h: int = 460) -> None:
    """Two panels (CPU seconds per view, log axis, against LPIPS and PSNR), drawn with PIL."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (w, h), "white")
    d = ImageDraw.Draw(img)
    kinds = sorted({r["kind"] for r in rows})
    meas = [r for r in rows if r["quality"] == "measured" and scored(r, "psnr") is not None
            and scored(r, "cpu_seconds_per_view") is not None and float(r["cpu_seconds_per_view"]) > 0]
    if not meas:
        img.save(path)
        return
    secs = [float(r["cpu_seconds_per_view"]) for r in meas]
    lx0, lx1 = np.log10(min(secs)) - 0.1, np.log10(max(secs)) + 0.1
    panels = [("lpips", "LPIPS (lower is better)", True), ("psnr", "PSNR dB (higher is better)", False)]
    pw = (w - 60) // 2
    for pi, (key, title, lower) in enumerate(panels):
        vals = [float(r[key]) for r in meas if scored(r, key) is not None]
        ox, oy, pwid, phei = 60 + pi * (pw + 20), 40, pw - 70, h - 110
        if not vals:  # (--no-lpips): say so, not leave half the image blank
            d.text((ox, 12), f"{title}: not measured", fill="black")
            continue
        v0, v1 = min(vals), max(vals)
        pad = 0.08 * (v1 - v0 or 1.0)
        v0, v1 = v0 - pad, v1 + pad
        d.rectangle([ox, oy, ox + pwid, oy + phei], outline="black")
        d.text((ox, 12), f"seconds per {rows[0]['size']}px view (CPU, log) vs {title}", fill="black")

        def xy(r, ox=ox, oy=oy, pwid=pwid, phei=phei, key=key, v0=v0, v1=v1):
            x = ox + (np.log10(float(r["cpu_seconds_per_view"])) - lx0) / (lx1 - lx0) * pwid
            y = oy + (1 - (float(r[key]) - v0) / (v1 - v0)) * phei
            return x, y

        for e in range(int(np.floor(lx0)), int(np.ceil(lx1)) + 1):
            for m in (1, 2, 5):
                lv = e + np.log10(m)
                if lx0 <= lv <= lx1:
                    x = ox + (lv - lx0) / (lx1 - lx0) * pwid
                    d.line([x, oy + phei, x, oy + phei + 4], fill="black")
                    d.text((x - 10, oy + phei + 6), f"{10 ** lv:g}", fill="black")
        d.text((ox + pwid - 190, oy + phei + 36), "CPU seconds per view (log scale)", fill="black")
        for k in range(5):
            v = v0 + (v1 - v0) * k / 4
            y = oy + (1 - k / 4) * phei
            d.line([ox - 4, y, ox, y], fill="black")
            d.text((ox - 44, y - 6), f"{v:.3f}" if key == "lpips" else f"{v:.2f}", fill="black")
        for ki, kind in enumerate(kinds):
            col = COLOURS[ki % len(COLOURS)]
            kr = [r for r in meas if r["kind"] == kind and scored(r, key) is not None]
            for r in kr:
                r["_loss"] = float(r[key]) if lower else -float(r[key])
            front = pareto(kr, "cpu_seconds_per_view", "_loss")
            if len(front) > 1:
                d.line([xy(r) for r in front], fill=col, width=2)
            for r in kr:
                x, y = xy(r)
                on = r in front
                d.ellipse([x - 4, y - 4, x + 4, y + 4], fill=col if on else "white", outline=col)
                if on:
                    d.text((x + 5, y - 12), point_name(r, rows), fill=col)
            for r in kr:
                r.pop("_loss", None)
            d.text((ox + 8 + 170 * ki, oy + phei + 24), f"o {kind}", fill=col)
    d.text((60, h - 22), "filled: on the kind's Pareto front (no other point of that kind is as fast and as good, "
           "and faster or better)", fill="black")
    img.save(path)
