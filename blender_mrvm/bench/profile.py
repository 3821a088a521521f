"""Where a novel view's time goes: encoder, ray set-up, sampling, feature gathering, the networks, compositing.

A model of each requested preset renders one view of the ``bench model`` set-up (random weights: time
does not depend on them) with timers around each stage, after a warm-up render:

- every direct child module of the model (NeRFormer+MRVM: ``encoder``, ``coarse`` / ``fine`` transformer
  branches; GPNR: its patch embedding and transformers), through forward hooks;
- the free functions the model module calls, where it has them: ``rays_in_cameras`` and
  ``project_samples`` (projection), ``sample_maps`` (bilinear feature / colour gathering),
  ``stratified`` / ``sample_pdf`` (sampling), ``volume_render`` (compositing);
- ``other``: the rest of the render (ray generation and box clipping, concatenations, Python).

Writes ``<out>/bench_profile.csv`` (preset, stage, seconds, share of the view, the load average). Usage::

    python -m blender_mrvm bench profile --presets balanced,gpnr:fast --out docs --threads 1
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import defaultdict
from pathlib import Path

from . import write_csv

RESULTS = ("bench_profile.csv",)
"""What the bench writes into ``--out`` (``bench.check_results``)."""

FUNCTIONS = {"rays_in_cameras": "projection", "project_samples": "projection", "sample_maps": "gathering",
             "stratified": "sampling", "sample_pdf": "sampling", "volume_render": "compositing"}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_profile.csv")
    p.add_argument("--presets", default="balanced,gpnr:fast", help="comma-separated presets (KIND:PRESET)")
    p.add_argument("--size", type=int, default=128, help="view side in pixels")
    p.add_argument("--views", type=int, default=2, help="reference views")
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")


def profile_view(model, render) -> dict[str, float]:
    """Seconds per stage of one ``render()`` call (see the module doc)."""
    import torch

    stages: dict[str, float] = defaultdict(float)
    depth = [0]

    def timed(name, fn):
        def wrapper(*a, **k):
            depth[0] += 1
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                depth[0] -= 1
                if depth[0] == 0:  # nested stages count once, in the outermost
                    stages[name] += time.perf_counter() - t
        return wrapper

    mod = sys.modules[type(model).__module__]
    patched = []
    for fname, stage in FUNCTIONS.items():
        targets = [m for m in (mod, sys.modules.get(f"{mod.__name__.rsplit('.', 1)[0]}.samplers")) if m is not None]
        for m in targets:
            if hasattr(m, fname) and callable(getattr(m, fname)):
                patched.append((m, fname, getattr(m, fname)))
                setattr(m, fname, timed(stage, getattr(m, fname)))
    hooks = []
    units = []
    for name, child in model.named_children():
        if isinstance(child, (torch.nn.ModuleList, torch.nn.ModuleDict)):  # iterated, never called: hook its items
            units += [(name, c) for c in child.children()]
        else:
            units.append((name, child))
    for name, child in units:
        t0 = {}

        def pre(_m, _i, name=name, t0=t0):
            depth[0] += 1
            t0["t"] = time.perf_counter()

        def post(_m, _i, _o, name=name, t0=t0):
            depth[0] -= 1
            if depth[0] == 0:
                stages[f"{name} (network)"] += time.perf_counter() - t0["t"]

        hooks += [child.register_forward_pre_hook(pre), child.register_forward_hook(post)]
    try:
        t = time.perf_counter()
        render()
        total = time.perf_counter() - t
    finally:
        for h in hooks:
            h.remove()
        for m, fname, fn in patched:
            setattr(m, fname, fn)
    stages["other"] = max(0.0, total - sum(stages.values()))
    stages["total"] = total
    return dict(stages)


def run(args) -> int:
    import numpy as np
    import torch

    from ..geometry import cameras
    from ..models import registry
    from . import at_least, names, start_results
    from .model import ref_eyes

    at_least(args, size=1, views=1, threads=1)
    presets = []
    for preset in names(args.presets, "--presets"):  # empty: an IndexError in write_csv after it emptied the CSV
        kind, _, name = preset.rpartition(":")
        presets.append((preset, name, registry.build_config(kind or None, name)))  # unknown names fail now
    out = start_results(Path(args.out), RESULTS, args.force)
    torch.set_num_threads(args.threads)
    rows = []
    eyes = [np.array(e, float) / np.linalg.norm(e) * 1.3 for e in ([1, 0.2, 0.4], [-0.2, 1, 0.3], [0.6, -0.7, 0.5])]
    bbox = (np.full(3, -0.4), np.full(3, 0.4))
    size = args.size
    intr = cameras.Intrinsics(131.25 * size / 128, 131.25 * size / 128, size / 2, size / 2, size, size)
    for preset, name, cfg in presets:
        torch.manual_seed(0)
        model = registry.build_model(cfg).eval()
        refs = np.random.default_rng(0).random((args.views, size, size, 3)).astype(np.float32)
        poses = [cameras.look_at_opencv(e) for e in ref_eyes(eyes, args.views)]
        target = cameras.look_at_opencv(eyes[0])

        def render():
            model.synthesize(refs, poses, [intr] * args.views, bbox, target, intr)

        render()  # warm-up
        load = round(os.getloadavg()[0], 2) if hasattr(os, "getloadavg") else ""  # (a busy machine moves the shares)
        st = profile_view(model, render)
        total = st.pop("total")
        for stage, sec in sorted(st.items(), key=lambda kv: -kv[1]):
            rows.append({"kind": registry.kind_of(model.cfg), "preset": name, "size": size, "ref_views": args.views,
                         "threads": args.threads, "stage": stage, "seconds": round(sec, 4),
                         "share_pct": round(100 * sec / total, 1), "view_seconds": round(total, 4),
                         "load_1min": load})
            print(f"{preset:12s} {stage:28s} {sec:7.3f} s  {100 * sec / total:5.1f} %")
    write_csv(out / "bench_profile.csv", rows)
    return 0
