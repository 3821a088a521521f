"""Pair the evaluations that `gpu_session.sh score` brought back (score.tgz) and print one markdown row per set:
each candidate's PSNR / SSIM / LPIPS and its paired difference against the base checkpoint on the same views
(mean over objects, SE over objects, share of objects better; `training.evaluate.compare_reports`).

    python scripts/score_table.py score.tgz [score2.tgz ...] BASE [CANDIDATE ...] [--pool NAME=SET,SET ...]

BASE and CANDIDATE are the names the verb tagged its folders with (a checkpoint file's name without
`.safetensors`, or `shipped`); with no candidate, every other name in the archive. Each ``--pool`` adds a row per
model for the named sets taken as one (their objects together: the difference is the mean over all their
objects, its SE over all of them), e.g. a set's two halves that a rule reads as one (sessions 31 and 32 pooled
``sphere64_val_train`` and ``sphere64_val_test`` by hand)."""

from __future__ import annotations

import json
import sys
import tarfile
from collections import defaultdict

import numpy as np

from blender_mrvm.training.evaluate import compare_reports


def pooled(parts: dict[str, dict]) -> dict:
    """One report of several sets' reports (``set -> eval.json``): their views together, each object named with
    its set (two sets may hold objects of one name), and the overall means over all the views."""
    views = [{**v, "object": f"{s}/{v['object']}"} for s, rep in parts.items() for v in rep["views"]]
    overall = {"n": len(views)}
    for m in ("psnr", "ssim", "lpips"):
        x = [v[m] for v in views if v.get(m) is not None]
        overall[m] = float(np.mean(x)) if x else float("nan")
    return {"views": views, "overall": overall}


def main(argv: list[str]) -> int:
    pools: dict[str, list[str]] = {}
    args: list[str] = []
    it = iter(argv)
    for a in it:
        if a == "--pool":
            spec = next(it, "")
            name, _, sets = spec.partition("=")
            if not name or not sets:
                print(f"error: --pool needs NAME=SET,SET, got {spec!r}", file=sys.stderr)
                return 2
            pools[name] = sets.split(",")
        else:
            args.append(a)
    archives = [a for a in args if a.endswith((".tgz", ".tar.gz"))]
    rest = [a for a in args if a not in archives]
    if not archives or not rest:
        print(__doc__, file=sys.stderr)
        return 2
    reports: dict[str, dict[str, dict]] = defaultdict(dict)  # set -> name -> eval.json
    for path in archives:
        with tarfile.open(path) as t:
            for m in t.getmembers():
                if m.name.endswith("/eval.json"):
                    name, _, data = m.name.split("/")[-2].partition("__")
                    reports[data][name] = json.load(t.extractfile(m))
    for pool, sets in pools.items():
        missing = [s for s in sets if s not in reports]
        if missing:
            print(f"error: --pool {pool}: no set {missing[0]!r} in the archives (sets: {', '.join(sorted(reports))})",
                  file=sys.stderr)
            return 2
        names = set.intersection(*(set(reports[s]) for s in sets))
        reports[pool] = {n: pooled({s: reports[s][n] for s in sets}) for n in names}
    base = rest[0]
    names = rest[1:] or sorted({n for r in reports.values() for n in r} - {base})
    print("| set | model | views | PSNR / SSIM / LPIPS | d PSNR (SE), objects better | d LPIPS (SE), objects better |")
    print("|---|---|---:|---|---|---|")
    for data in [*sorted(d for d in reports if d not in pools), *pools]:
        r = reports[data]
        for name in [base, *names]:
            if name not in r:
                print(f"| {data} | {name} | missing | | | |")
                continue
            o = r[name]["overall"]
            row = f"| {data} | {name} | {o['n']} | {o['psnr']:.2f} / {o['ssim']:.3f} / {o['lpips']:.4f} |"
            if name == base or base not in r:
                print(row + " | |")
                continue
            c = compare_reports(r[name], r[base])["overall"]
            p, lp = c["psnr"], c["lpips"]
            print(row + f" {p['diff']:+.3f} ({p['se_objects']:.3f}), {p['wins'] * p['objects']:.0f} of {p['objects']} |"
                  f" {lp['diff']:+.4f} ({lp['se_objects']:.4f}), {lp['wins'] * lp['objects']:.0f} of {lp['objects']} |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
