"""Tables of the real-mesh evaluation (session 40): each shipped object model on the real-mesh sets beside the
procedural held-out sets with the same cameras and protocol, and the real objects one by one.

    python docs/real_meshes/summarize.py [--eval data/eval/real] > docs/real_meshes/results.md

Reads ``<eval>/<set>_<model>/eval.json`` as ``score.sh`` writes them. Margins are per object (the mean over its
views), SE over objects."""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

SETS = [("turntable", "real_turntable64", "turntable64_heldout"), ("sphere rig", "real_sphere64", "sphere64_heldout")]
MODELS = ["default", "anyview", "quality", "gpnr", "auto"]
NAMES = {"default": "default (`shipped`)", "anyview": "any-view", "quality": "quality (int8)",
         "gpnr": "GPNR (`shipped:gpnr`)", "auto": "Auto"}


def per_object(ev: dict) -> dict[str, dict[str, float]]:
    """Per object: the mean over its views of PSNR, LPIPS and the nearest view's PSNR and LPIPS."""
    acc: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for v in ev["views"]:
        a = acc[v["object"]]
        a["psnr"].append(v["psnr"])
        a["lpips"].append(v["lpips"])
        a["ssim"].append(v["ssim"])
        a["n_psnr"].append(v["baseline_nearest"]["psnr"])
        a["n_lpips"].append(v["baseline_nearest"]["lpips"])
        a["m_psnr"].append(v["baseline_mean"]["psnr"])
    return {o: {k: float(np.mean(x)) for k, x in a.items()} for o, a in acc.items()}


def mean_se(x) -> tuple[float, float]:
    x = np.asarray(x, float)
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(len(x))) if len(x) > 1 else 0.0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--eval", default="data/eval/real")
    args = ap.parse_args()
    root = Path(args.eval)
    evs = {}
    for d in root.iterdir():
        if (d / "eval.json").is_file():
            evs[d.name] = json.loads((d / "eval.json").read_text())

    print("| cameras | objects | model | PSNR / SSIM / LPIPS | nearest view PSNR / LPIPS | over the better baseline: "
          "PSNR (SE) | LPIPS minus the nearest view's (SE) | objects better than the nearest view (PSNR, LPIPS) |")
    print("|---|---|---|---|---|---|---|---|")
    for rig, real, proc in SETS:
        for m in MODELS:
            for label, s in (("real", real), ("procedural", proc)):
                ev = evs.get(f"{s}_{m}")
                if ev is None:
                    continue
                o = ev["overall"]
                objs = per_object(ev).values()
                gain = mean_se([p["psnr"] - max(p["n_psnr"], p["m_psnr"]) for p in objs])
                dl = mean_se([p["lpips"] - p["n_lpips"] for p in objs])
                bp = np.mean([p["psnr"] > p["n_psnr"] for p in objs])
                bl = np.mean([p["lpips"] < p["n_lpips"] for p in objs])
                n = o["baseline_nearest"]
                print(f"| {rig} | {label} | {NAMES[m]} | {o['psnr']:.2f} / {o['ssim']:.3f} / {o['lpips']:.3f} | "
                      f"{n['psnr']:.2f} / {n['lpips']:.3f} | {gain[0]:+.2f} ({gain[1]:.2f}) | {dl[0]:+.3f} ({dl[1]:.3f}) | "
                      f"{bp:.0%}, {bl:.0%} |")
    for rig, real, _ in SETS:
        have = [m for m in MODELS if f"{real}_{m}" in evs and m != "auto"]
        if not have:
            continue
        print(f"\nReal meshes one by one, {rig} (PSNR / LPIPS per model; the nearest reference view last):\n")
        print("| object | " + " | ".join(NAMES[m] for m in have) + " | nearest view |")
        print("|---|" + "---|" * (len(have) + 1))
        po = {m: per_object(evs[f"{real}_{m}"]) for m in have}
        objs = sorted(po[have[0]])
        for ob in objs:
            cells = [f"{po[m][ob]['psnr']:.2f} / {po[m][ob]['lpips']:.3f}" for m in have]
            n = po[have[0]][ob]
            print(f"| {ob.split('/')[-1]} | " + " | ".join(cells) + f" | {n['n_psnr']:.2f} / {n['n_lpips']:.3f} |")


if __name__ == "__main__":
    main()
