"""Pair the evaluations that `gpu_session.sh score` brought back (score.tgz) and print one markdown row per set:
each candidate's PSNR / SSIM / LPIPS and its paired difference against the base checkpoint on the same views
(mean over objects, SE over objects, share of objects better; `training.evaluate.compare_reports`).

    python scripts/score_table.py score.tgz BASE [CANDIDATE ...]

BASE and CANDIDATE are the names the verb tagged its folders with (a checkpoint file's name without
`.safetensors`, or `shipped`); with no candidate, every other name in the archive."""

from __future__ import annotations

import json
import sys
import tarfile
from collections import defaultdict

from blender_mrvm.training.evaluate import compare_reports


def main(argv: list[str]) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    reports: dict[str, dict[str, dict]] = defaultdict(dict)  # set -> name -> eval.json
    with tarfile.open(argv[0]) as t:
        for m in t.getmembers():
            if m.name.endswith("/eval.json"):
                name, _, data = m.name.split("/")[-2].partition("__")
                reports[data][name] = json.load(t.extractfile(m))
    base = argv[1]
    names = argv[2:] or sorted({n for r in reports.values() for n in r} - {base})
    print("| set | model | views | PSNR / SSIM / LPIPS | d PSNR (SE), objects better | d LPIPS (SE), objects better |")
    print("|---|---|---:|---|---|---|")
    for data in sorted(reports):
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
