"""Milliseconds per training step of a run config (its model and train sections, e.g. a shipped recipe's sidecar),
and optionally the step's operator table; for A/B timing of trainer changes:

    PYTHONPATH=<tree> python scripts/time_train_step.py data/cfg/long_j.json 30 [--profile]

run once per code tree, alternating (docs/bench_train_cpu/README.md). The recipe as written (its batch, losses and
threads) through ``bench train``'s timing (``bench.train.measure_config``): 5 warm-up steps, then STEPS timed (and 4
profiled with ``--profile``), from scratch in a temporary folder (the init checkpoint is left out: only the time is
wanted); prints ``<ms> ms/step``."""

import dataclasses
import json
import sys
import tempfile
from pathlib import Path

from blender_mrvm.bench.train import measure_config
from blender_mrvm.models import registry
from blender_mrvm.training.config import TrainConfig
from blender_mrvm.training.trainer import load_training_scenes


def main(argv: list[str]) -> int:
    cfg = json.load(open(argv[0]))
    steps, profile = int(argv[1]), 4 if "--profile" in argv else 0
    model_cfg = registry.config_from_dict(cfg["model"]["kind"], cfg["model"]["config"])
    names = {f.name for f in dataclasses.fields(TrainConfig)}
    tcfg = TrainConfig(**{k: v for k, v in cfg["train"].items() if k in names})
    r = measure_config(model_cfg, tcfg, load_training_scenes(tcfg), steps, 5,
                       Path(tempfile.mkdtemp(prefix="time_train_step_")) / "run", profile)
    print(f"{r['seconds'] / steps * 1000:.1f} ms/step", flush=True)
    if profile:
        print({k: v for k, v in r.items() if k != "profile_table"})
        print(r["profile_table"])
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
