"""Paired differences of eval.json reports, per scored view and per object (issue 10's capture tables).

    python scripts/paired_vs_baselines.py data/eval/A/eval.json [data/eval/B/eval.json ...]
    python scripts/paired_vs_baselines.py data/eval/A1/eval.json+data/eval/A2/eval.json  # pooled: one report

For each report: the model minus its nearest-photo baseline and minus the mean of its references
(``baseline_blend``), and each further report's model minus the first's, for PSNR, SSIM and LPIPS:
mean difference, its standard error over the scored views and over the objects (object means), and the
share of views where the first term is better. The reports must score the same views.
"""

from __future__ import annotations

import json
import sys

import numpy as np

KEYS = ("psnr", "ssim", "lpips")


def _rows(rep):
    return {(v["object"], v["view"]): v for v in rep["views"]}


def paired(a: dict, b: dict, key: str) -> dict:
    """a - b over the views both hold (dicts view -> record)."""
    ks = sorted(set(a) & set(b))
    d = np.array([a[k][key] - b[k][key] for k in ks])
    objs = sorted({k[0] for k in ks})
    om = np.array([np.mean([d[i] for i, k in enumerate(ks) if k[0] == o]) for o in objs])
    better = (d < 0) if key == "lpips" else (d > 0)
    se = lambda x: float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else float("nan")  # noqa: E731
    return {"diff": float(d.mean()), "se_views": se(d), "se_objects": se(om), "views": len(ks),
            "objects": len(objs), "better_share": float(better.mean())}


def _load(arg: str) -> dict:
    """One report, or the views of several joined with '+' (other splits or sets scored by one model)."""
    views = []
    for p in arg.split("+"):
        views += json.loads(open(p).read())["views"]
    return {"views": views}


def main(paths: list[str]) -> None:
    reps = [_load(p) for p in paths]
    first = _rows(reps[0])
    for p, rep in zip(paths, reps):
        rows = _rows(rep)
        for base in ("baseline_nearest", "baseline_blend"):
            b = {k: v[base] for k, v in rows.items()}
            print(f"{p}: model - {base}: " + "; ".join(
                f"{k} {r['diff']:+.3f} (SE {r['se_views']:.3f} views / {r['se_objects']:.3f} objects, better on "
                f"{100 * r['better_share']:.0f}% of {r['views']})" for k in KEYS for r in [paired(rows, b, k)]))
    for p, rep in zip(paths[1:], reps[1:]):
        rows = _rows(rep)
        print(f"{p} - {paths[0]}: " + "; ".join(
            f"{k} {r['diff']:+.3f} (SE {r['se_views']:.3f} views / {r['se_objects']:.3f} objects, better on "
            f"{100 * r['better_share']:.0f}% of {r['views']})" for k in KEYS for r in [paired(rows, first, k)]))


if __name__ == "__main__":
    main(sys.argv[1:])
