"""Milliseconds per training step of a run config (its model and train sections, e.g. a shipped recipe), on the
CPU with one torch thread, and optionally the step's operator table; for A/B timing of trainer changes:

    PYTHONPATH=<tree> python scripts/time_train_step.py data/cfg/long_j.json 30 [--profile]

run once per code tree, alternating (docs/bench_train_cpu/README.md). Trains ``5 + STEPS (+ 4 profiled) + 1``
steps from scratch in a temporary folder (the config's init checkpoint is ignored: only the time is wanted) and
prints ``<ms> ms/step`` for the STEPS after the 5 warm-up steps."""

import dataclasses
import json
import sys
import tempfile
import time

import torch

from blender_mrvm.bench.train import profile_counts, profile_table
from blender_mrvm.models import registry
from blender_mrvm.progress import Progress
from blender_mrvm.training.config import TrainConfig
from blender_mrvm.training.trainer import train


def main(argv: list[str]) -> int:
    cfg = json.load(open(argv[0]))
    steps, profile = int(argv[1]), 4 if "--profile" in argv else 0
    warm = 5
    model_cfg = registry.config_from_dict(cfg["model"]["kind"], cfg["model"]["config"])
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    t = {k: v for k, v in cfg["train"].items() if k in names}
    total = warm + steps + profile + 1
    t.update(out_dir=tempfile.mkdtemp(prefix="time_train_step_"), iterations=total, log_every=total,
             ckpt_every=total, keep_checkpoints=1, init_checkpoint="", threads=1)
    t0, prof = None, None
    gen = train(model_cfg, TrainConfig(**t), resume=False, force=True)
    for ev in gen:
        if not isinstance(ev, Progress):
            continue
        if ev.done == warm:
            t0 = time.perf_counter()
        elif ev.done == warm + steps:
            print(f"{(time.perf_counter() - t0) / steps * 1000:.1f} ms/step", flush=True)
            if not profile:
                break
            prof = torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU])
            prof.__enter__()
        elif prof is not None and ev.done == warm + steps + profile:
            prof.__exit__(None, None, None)
            events = prof.key_averages()
            print(profile_counts(events, profile))
            print(profile_table(events, "cpu", 40))
            break
    gen.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
