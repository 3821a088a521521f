"""Session 37: apply rule.md to the candidates' paired scores (data/eval/s37/*/compare.json) and print the table.

    python docs/anyview_s37/summarize.py NAME... [--test] [--dir s38] [--base shipped]

`--dir s38` reads data/eval/s38 (session 38's stage 5, paired against stage 4).

After the rule's table it prints, for information, the off-turntable mean's SE with objects shared between sets
counted once (`sphere64_val` and `near_turntable64` share seeds 3000-3001; the rule's SE treats the sets as
independent). `--base` names the scores the candidates were paired against (score.sh's BASE; default
`shipped`). It needs the per-view lists of each candidate's and the base's `eval.json` (not in evals.tgz).

The scores it read (eval.json without the per-view list, and compare.json) are in evals.tgz beside it:
`tar -xzf docs/anyview_s37/evals.tgz -C data/eval`. Its output: validation.md and test.md.
"""
import json
import math
import sys
from pathlib import Path

EVAL = Path(__file__).resolve().parents[2] / "data" / "eval"


def paired(root, set_name, name, metric):
    """(mean difference, SE over objects, objects, absolute mean) of one set, against the base."""
    c = json.loads((root / f"{set_name}_{name}" / "compare.json").read_text())["overall"][metric]
    ev = json.loads((root / f"{set_name}_{name}" / "eval.json").read_text())
    return c["diff"], c["se_objects"], c["objects"], ev["overall"][metric]


def pooled_halves(root, name, metric, halves):
    """Two halves of one set pooled, weighted by objects (SE: the halves independent)."""
    parts = [paired(root, h, name, metric) for h in halves]
    n = sum(p[2] for p in parts)
    diff = sum(p[0] * p[2] for p in parts) / n
    se = math.sqrt(sum((p[1] * p[2] / n) ** 2 for p in parts))
    return diff, se, n, sum(p[3] * p[2] for p in parts) / n


def object_diffs(root, set_name, name, base):
    """{metric: {object: mean paired difference over its views}} of one set (PSNR and LPIPS), from the per-view
    lists of NAME's and BASE's eval.json (None if absent)."""
    views = {}
    for who in (name, base):
        ev = json.loads((root / f"{set_name}_{who}" / "eval.json").read_text())
        if not ev.get("views"):
            return None
        views[who] = {(v["object"], v["view"]): v for v in ev["views"]}
    out = {}
    for metric in ("psnr", "lpips"):
        per = {}
        for key, v in views[name].items():
            per.setdefault(key[0], []).append(v[metric] - views[base][key][metric])
        out[metric] = {o: sum(d) / len(d) for o, d in per.items()}
    return out


def clustered_off_se(root, name, sets, base):
    """{metric: SE} of the mean over sets of each set's mean object difference, objects in several sets as one
    cluster: each object's contribution is the sum over the sets it is in of its residual / (number of sets x
    objects in that set); the variance is the sum of their squares (x n/(n-1)). Close to the rule's SE when no
    object is shared (it differs by the n/(n-1) factors and by taking V1's two halves' residuals about their
    pooled mean). None without per-view lists."""
    per_set = []
    for halves in sets.values():
        merged = {"psnr": {}, "lpips": {}}
        for h in halves:
            d = object_diffs(root, h, name, base)
            if d is None:
                return None
            for metric in merged:
                merged[metric].update(d[metric])
        per_set.append(merged)
    se = {}
    for metric in ("psnr", "lpips"):
        contrib = {}
        for merged in per_set:
            diffs = merged[metric]
            mean = sum(diffs.values()) / len(diffs)
            for o, d in diffs.items():
                contrib[o] = contrib.get(o, 0.0) + (d - mean) / (len(sets) * len(diffs))
        n = len(contrib)
        se[metric] = math.sqrt(n / (n - 1) * sum(c * c for c in contrib.values()))
    return se


def main(argv):
    root = EVAL / "s37"
    if "--dir" in argv:
        i = argv.index("--dir")
        root = EVAL / argv[i + 1]
        argv = argv[:i] + argv[i + 2:]
    base = "shipped"
    if "--base" in argv:
        i = argv.index("--base")
        base = argv[i + 1]
        argv = argv[:i] + argv[i + 2:]
    test = "--test" in argv
    names = [a for a in argv if not a.startswith("--")]
    if test:
        sets = {"sphere held-out": ["t_sphere"], "near test": ["t_near"], "fine test": ["t_fine"]}
        guards = {"turntable held-out": ["t_turn"], "all test": ["t_all"]}
    else:
        sets = {"V1 sphere val": ["sphval_a", "sphval_b"], "V2 near": ["near"], "V3 fine": ["fine"]}
        guards = {"G turntable val": ["ttval"]}
    rows = []
    for name in names:
        row = {"name": name}
        for metric in ("psnr", "lpips"):
            ds, ses = [], []
            for label, halves in {**sets, **guards}.items():
                d, se, n, v = pooled_halves(root, name, metric, halves)
                row[(label, metric)] = (d, se, v)
                if label in sets:
                    ds.append(d)
                    ses.append(se)
            row[("off", metric)] = (sum(ds) / len(ds), math.sqrt(sum(s * s for s in ses)) / len(ses), None)
        rows.append(row)
    labels = [*sets, *guards]
    print("| candidate | " + " | ".join(f"{l}: PSNR / LPIPS, d PSNR (SE), d LPIPS (SE)" for l in labels)
          + " | off-turntable mean d PSNR (SE), d LPIPS (SE) |")
    print("|---" * (len(labels) + 2) + "|")
    for r in rows:
        cells = []
        for l in labels:
            (dp, sp, vp), (dl, sl, vl) = r[(l, "psnr")], r[(l, "lpips")]
            cells.append(f"{vp:.2f} / {vl:.4f}, {dp:+.2f} ({sp:.2f}), {dl:+.4f} ({sl:.4f})")
        (dp, sp, _), (dl, sl, _) = r[("off", "psnr")], r[("off", "lpips")]
        print(f"| {r['name']} | " + " | ".join(cells) + f" | {dp:+.3f} ({sp:.3f}), {dl:+.4f} ({sl:.4f}) |")
    for r in rows:
        se = clustered_off_se(root, r["name"], sets, base)
        if se is not None:
            print(f"{r['name']}: off-turntable SE with shared objects counted once: PSNR {se['psnr']:.3f} (rule's "
                  f"{r[('off', 'psnr')][1]:.3f}), LPIPS {se['lpips']:.4f} (rule's {r[('off', 'lpips')][1]:.4f})")
    if test:
        for r in rows:
            dp, dl = r[("off", "psnr")][0], r[("off", "lpips")][0]
            veto = dp < 0 or dl > 0.002
            print(f"{r['name']}: off-turntable test mean d PSNR {dp:+.3f}, d LPIPS {dl:+.4f}: "
                  + ("VETO (not shipped)" if veto else "no veto"))
        return 0
    elig = [r for r in rows if r[("off", "lpips")][0] <= 0
            and all(r[(l, "lpips")][0] <= 0.003 for l in sets) and r[("G turntable val", "psnr")][0] >= -0.30]
    print("eligible:", [r["name"] for r in elig])
    if not elig:
        print("pick: none; nothing shipped")
        return 0
    best = max(elig, key=lambda r: r[("off", "psnr")][0])
    dp, sp, _ = best[("off", "psnr")]
    ship = dp >= 0.10 and dp >= 2 * sp
    print(f"pick: {best['name']} (off-turntable d PSNR {dp:+.3f}, SE {sp:.3f}): "
          + ("SHIP (then the test sets, once)" if ship else "not shipped (below +0.10 dB or 2 SE)"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
