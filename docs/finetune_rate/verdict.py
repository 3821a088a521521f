"""rule.md's arithmetic: arms (a learning rate, seeds pooled per object) against each other and the shipped default.

    python docs/finetune_rate/verdict.py [--root data/eval/finetune_rate]

Reads ``{rval,rtest,lib}_{name}/eval.json`` as ``score.sh`` writes them (names ``shipped``, ``lr<LR>_s<SEED>``,
``losses_s<SEED>``, and ``i4k_lr1e-4_s0`` / ``i4k_losses_s0`` for the 4000-step probe).
"""

from __future__ import annotations

import json
import statistics
import sys
from collections import defaultdict
from pathlib import Path

SETS = {"U": ("rval", "rtest"), "L": ("lib",)}
"""U: the user's kind, never trained on (26 real meshes); L: the library's validation objects."""


def per_object(path: Path) -> dict[str, dict[str, float]]:
    """Per object (category/object), the mean over its views of PSNR, SSIM and LPIPS."""
    acc: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for v in json.loads(path.read_text())["views"]:
        for k in ("psnr", "ssim", "lpips"):
            acc[f"{v['category']}/{v['object']}"][k].append(float(v[k]))
    return {o: {k: statistics.fmean(x) for k, x in m.items()} for o, m in acc.items()}


def seeds(root: Path, prefix: str) -> list[str]:
    """The runs named ``prefix`` (``prefix`` itself, or ``prefix_s<SEED>``) scored on every set of U and L."""
    names = None
    for s in (x for g in SETS.values() for x in g):
        here = {d.name[len(s) + 1:] for d in root.glob(f"{s}_{prefix}*") if (d / "eval.json").is_file()}
        here = {n for n in here if n == prefix or n.startswith(f"{prefix}_s")}
        names = here if names is None else names & here
    return sorted(names or ())


def arm(root: Path, prefix: str, group: str) -> dict[str, dict[str, float]] | None:
    """Per object of group U or L: the metrics of every run named ``prefix`` (one or several seeds) averaged."""
    runs = seeds(root, prefix)
    if not runs:
        return None
    out = {}
    for s in SETS[group]:
        per_run = [per_object(root / f"{s}_{r}" / "eval.json") for r in runs]
        for o in per_run[0]:
            out[f"{s}:{o}"] = {k: statistics.fmean(m[o][k] for m in per_run) for k in ("psnr", "ssim", "lpips")}
    return out


def paired(a: dict, b: dict, k: str) -> tuple[float, float, float]:
    """(mean of a - b over objects, its SE, share of objects where a is better)."""
    d = [a[o][k] - b[o][k] for o in a]
    better = sum((x < 0) if k == "lpips" else (x > 0) for x in d) / len(d)
    return statistics.fmean(d), statistics.stdev(d) / len(d) ** 0.5, better


def main(argv: list[str]) -> int:
    root = Path(argv[argv.index("--root") + 1]) if "--root" in argv else Path("data/eval/finetune_rate")
    names = ["shipped"] + [f"lr{lr}" for lr in ("1e-4", "3e-4", "1e-3")] + ["losses"]
    names += ["lr1e-4_s0", "losses_s0", "i4k_lr1e-4", "i4k_losses"]  # the 4000-step probe (seed 0) and its seed at 2000
    arms = {n: {g: arm(root, n, g) for g in SETS} for n in names}
    arms = {n: a for n, a in arms.items() if all(a.values())}
    print("| model | seeds | U (26 real meshes): PSNR / SSIM / LPIPS | L (library val): PSNR / SSIM / LPIPS |")
    print("|---|---:|---|---|")
    for n, a in arms.items():
        cells = [" / ".join(f"{statistics.fmean(m[k] for m in a[g].values()):.{3 if k != 'psnr' else 2}f}"
                            for k in ("psnr", "ssim", "lpips")) for g in SETS]
        print(f"| {n} | {len(seeds(root, n)) if n != 'shipped' else '-'} | {cells[0]} | {cells[1]} |")
    pairs = [(n, "shipped") for n in arms if n != "shipped"]
    if "lr1e-3" in arms and "lr1e-4" in arms:
        pairs.append(("lr1e-3", "lr1e-4"))
    for other in ("lr3e-4", "losses"):
        if other in arms and "lr1e-4" in arms:
            pairs.append((other, "lr1e-4"))
    for a, b in (("i4k_losses", "i4k_lr1e-4"), ("i4k_lr1e-4", "lr1e-4_s0"), ("i4k_losses", "losses_s0")):
        if a in arms and b in arms:  # the 4000-step probe (one seed): against each other and their 2000 steps
            pairs.append((a, b))
    print("\n| difference | U: d PSNR (SE), objects better | U: d LPIPS (SE) | L: d PSNR (SE), objects better | "
          "L: d LPIPS (SE) |")
    print("|---|---|---|---|---|")
    res = {}
    for a, b in pairs:
        row = []
        for g in SETS:
            p = paired(arms[a][g], arms[b][g], "psnr")
            lp = paired(arms[a][g], arms[b][g], "lpips")
            res[(a, b, g)] = (p, lp)
            row += [f"{p[0]:+.3f} ({p[1]:.3f}), {p[2]:.0%}", f"{lp[0]:+.4f} ({lp[1]:.4f})"]
        print(f"| {a} - {b} | " + " | ".join(row) + " |")
    if ("lr1e-3", "lr1e-4", "U") in res:
        (p, se, _), (lp, _, _) = res[("lr1e-3", "lr1e-4", "U")]
        lib = res[("lr1e-3", "lr1e-4", "L")][0][0]
        change = p >= 0.10 and p >= 2 * se and lp <= 0 and lib >= -0.30
        print(f"\nrule.md step 1: U d PSNR {p:+.3f} (SE {se:.3f}), d LPIPS {lp:+.4f}, L d PSNR {lib:+.3f}: "
              + ("FINETUNE['lr'] becomes 1e-3" if change else "FINETUNE['lr'] stays 1e-4"))
    if ("losses", "lr1e-4", "U") in res:
        (p, _, _), (lp, lse, _) = res[("losses", "lr1e-4", "U")]
        keep = lp <= -0.005 and lp <= -2 * lse and p >= -0.10
        print(f"rule.md question 2: U d LPIPS {lp:+.4f} (SE {lse:.4f}), d PSNR {p:+.3f}: "
              + ("the policy keeps the checkpoint's losses" if keep else "the policy's losses stay as they are"))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
