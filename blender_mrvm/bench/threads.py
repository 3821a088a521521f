"""The thread-count cliff: seconds per view at 1..N threads, OpenMP policies and chunk workers.

Seconds per view at 1..N torch threads, OpenMP's default wait policy against
``OMP_WAIT_POLICY=PASSIVE`` (``threads.py``), and 1..N ray chunks rendered side by side on threads with
one torch thread each (``threads.render_workers``, what synthesis and eval use), the last also with glibc's
own malloc thresholds (``threads.apply_malloc_defaults`` off), on a quiet machine and beside a competing process.

Each setting runs ``bench model`` in a fresh process (libgomp reads its policy when torch is imported).
``--competitors K`` busy processes (a pure-Python spin loop each, like Blender or a second job holding a
core) run beside the "busy" settings (``--competitors 0``: the quiet settings alone). Writes
``<out>/bench_threads.csv``: policy, threads, competitors, median seconds per view and ``ratio_to_first``, the
ratio to the first of ``--threads`` (1 thread by default) under the same policy and load.

Usage::

    python -m blender_mrvm bench threads --out docs --preset balanced --size 128
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from . import write_csv

RESULTS = ("bench_threads.csv",)
"""What the bench writes into ``--out`` (``bench.check_results``)."""

SPIN = "import time\nwhile True:\n    pass\n"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_threads.csv")
    p.add_argument("--preset", default="balanced", help="model preset (KIND:PRESET for another kind)")
    p.add_argument("--size", type=int, default=128, help="view side in pixels")
    p.add_argument("--views", type=int, default=2, help="reference views")
    p.add_argument("--threads", default="1,2", help="comma-separated thread counts (torch threads, or chunk workers)")
    p.add_argument("--competitors", type=int, default=1, help="busy processes beside the 'busy' settings")
    p.add_argument("--repeats", type=int, default=3, help="timed renders per setting (median)")


POLICIES = ("openmp default", "PASSIVE", "chunk workers (ours)", "chunk workers, glibc malloc")
"""The last one is ours with glibc's own malloc thresholds (``threads.apply_malloc_defaults`` skipped): the
page faults of freed and re-mapped chunk tensors."""


def _one(policy: str, threads: int, args) -> float:
    from ..threads import KEEP_ENV, KEEP_MALLOC_ENV

    env = dict(os.environ)
    env.pop("OMP_WAIT_POLICY", None)
    env.pop(KEEP_ENV, None)
    env.pop(KEEP_MALLOC_ENV, None)
    if policy == "openmp default":
        env[KEEP_ENV] = "1"
    if policy.endswith("glibc malloc"):
        env[KEEP_MALLOC_ENV] = "1"
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "blender_mrvm", "bench", "model", "--presets", args.preset, "--views",
               str(args.views), "--sizes", str(args.size), "--repeats", str(args.repeats), "--out", tmp]
        cmd += ["--threads", "1", "--workers", str(threads)] if policy.startswith("chunk") else ["--threads", str(threads)]
        done = subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        if done.returncode != 0:  # the child's own error line, not a CalledProcessError traceback
            from ..errors import MRVMError

            lines = [ln for ln in done.stderr.splitlines() if ln.strip()]
            why = next((ln for ln in reversed(lines) if ln.startswith("error:")), lines[-1] if lines else "")
            raise MRVMError(f"bench model ({policy}, {threads} thread(s)) failed with exit code {done.returncode}: "
                            f"{why.removeprefix('error: ')}")
        with open(Path(tmp) / "bench_model.csv") as f:
            return float(next(csv.DictReader(f))["seconds_median"])


def run(args) -> int:
    from ..models import registry
    from . import at_least, start_results, whole_numbers

    at_least(args, size=1, views=1, competitors=0, repeats=1)
    threads = whole_numbers(args.threads, "--threads")
    kind, _, name = str(args.preset).strip().rpartition(":")
    registry.build_config(kind or None, name)  # an unknown preset: one line now, not a failed child process later
    out = start_results(Path(args.out), RESULTS, args.force)
    rows = []
    for busy in dict.fromkeys((0, args.competitors)):  # --competitors 0: the quiet settings once, not twice
        procs = [subprocess.Popen([sys.executable, "-c", SPIN]) for _ in range(busy)]
        try:
            for policy in POLICIES:
                base = None
                for t in threads:
                    sec = _one(policy, t, args)
                    base = sec if base is None else base
                    rows.append({"policy": policy, "threads": t, "competing_processes": busy, "preset": args.preset,
                                 "size": args.size, "ref_views": args.views, "seconds_median": round(sec, 3),
                                 "ratio_to_first": round(sec / base, 2), "cpus": os.cpu_count(),
                                 "load_1min": round(os.getloadavg()[0], 2)})
                    print(f"{policy:15s} threads={t} competitors={busy}: {sec:.3f} s/view", flush=True)
        finally:
            for p in procs:
                p.kill()
                p.wait()
    write_csv(out / "bench_threads.csv", rows)
    return 0
