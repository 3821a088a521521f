"""Which shipped model renders a view better, by where its cameras sit: the measurement behind
``models.pretrained.auto_model`` (the ``shipped:auto`` rule).

Reads two ``eval`` results on the same views (the default model and the any-view model on a sphere-rig
validation split) and the dataset's cameras, and bins the per-view differences by how far the view's cameras
(its references and itself) sit from the default model's training turntable (``pretrained.turntable_offsets``:
elevation offset from 30 degrees, the narrower field of view's offset from 40, and the framing outside the
turntable's).

    python scripts/viewpoint_rule.py data/sphere64_train data/eval/auto/sphere_val_{nerformer_mrvm,mrvm_anyview}

Prints one markdown table a feature (views, mean PSNR and LPIPS difference any-view minus default, and the
share of views where the any-view model has the higher PSNR) and the threshold sweep of the elevation rule.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np


def per_view(data: Path, a: dict, b: dict) -> list[dict]:
    """Per scored view: the largest offset of its cameras (references and itself) from the turntable
    (``pretrained.turntable_offsets``: elevation, field of view, framing, azimuth) and b minus a in PSNR and
    LPIPS."""
    from blender_mrvm.datasets import format as F
    from blender_mrvm.models.pretrained import turntable_offsets

    inputs = a["protocol"]["input_views"]
    bv = {(v["object"], int(v["view"])): v for v in b["views"]}
    rows, objs = [], {}
    for v in a["views"]:
        if v["object"] not in objs:
            ov = F.read_object(data / v["category"] / v["object"])
            intr = ov.intrinsics_per_view or [ov.intrinsics] * len(ov.c2w_opencv)
            objs[v["object"]] = turntable_offsets(ov.c2w_opencv, intr, ov.meta["bbox"])
        off = objs[v["object"]][[*inputs, int(v["view"])]].max(axis=0)
        w = bv[(v["object"], int(v["view"]))]
        rows.append({"el": off[0], "fov": off[1], "frame": off[2], "az": off[3], "psnr_a": v["psnr"],
                     "d_psnr": w["psnr"] - v["psnr"], "d_lpips": w["lpips"] - v["lpips"]})
    return rows


def table(rows: list[dict], feat: str, edges: list[float], unit: str) -> str:
    out = [f"| {feat} ({unit}) | views | PSNR any-view minus default | LPIPS | any-view higher PSNR |",
           "|---|---:|---:|---:|---:|"]
    x = np.array([r[feat] for r in rows])
    for lo, hi in zip(edges[:-1], edges[1:]):
        m = (x >= lo) & (x < hi)
        if not m.any():
            continue
        dp = np.array([r["d_psnr"] for r, k in zip(rows, m) if k])
        dl = np.array([r["d_lpips"] for r, k in zip(rows, m) if k])
        se = dp.std(ddof=1) / np.sqrt(len(dp)) if len(dp) > 1 else float("nan")
        out.append(f"| {lo:g}-{hi:g} | {m.sum()} | {dp.mean():+.2f} (SE {se:.2f}) | {dl.mean():+.3f} | "
                   f"{(dp > 0).mean():.0%} |")
    return "\n".join(out)


def fit(rows: list[dict]) -> tuple[np.ndarray, np.ndarray]:
    """Least squares of the any-view model's PSNR gain on the four largest offsets: (coefficients [intercept,
    per degree of elevation, per degree of field of view, per unit of framing log-distance, per degree of
    azimuth], their standard errors)."""
    x = np.array([[1.0, r["el"], r["fov"], r["frame"], r["az"]] for r in rows])
    y = np.array([r["d_psnr"] for r in rows])
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    cov = np.linalg.inv(x.T @ x) * (resid @ resid) / max(len(y) - x.shape[1], 1)
    return coef, np.sqrt(np.diag(cov))


def main(argv: list[str]) -> None:
    if len(argv) % 3 or not argv:
        raise SystemExit("usage: viewpoint_rule.py DATA EVAL_DEFAULT EVAL_ANYVIEW [DATA EVAL_DEFAULT EVAL_ANYVIEW ...]")
    rows = []
    for i in range(0, len(argv), 3):
        data, ea, eb = Path(argv[i]), Path(argv[i + 1]), Path(argv[i + 2])
        a = json.loads((ea / "eval.json").read_text())
        b = json.loads((eb / "eval.json").read_text())
        part = per_view(data, a, b)
        dp = np.array([r["d_psnr"] for r in part])
        print(f"{data}: {len(part)} views, any-view minus default {dp.mean():+.2f} dB (SE "
              f"{dp.std(ddof=1) / np.sqrt(len(dp)):.2f}); {a['checkpoint']['path']} against {b['checkpoint']['path']}")
        rows += part
    print()
    el, fov, frame = [0, 1e-9, 5, 10, 15, 20, 25, 30, 45, 60, 90, 181], [0, 1e-9, 2, 4, 6, 8, 10, 12, 15, 20, 41], [
        0, 1e-9, 0.05, 0.1, 0.2, 0.4, 2]
    print(table(rows, "el", el, "largest elevation offset from 30, degrees") + "\n")
    print(table(rows, "fov", fov, "largest field-of-view offset from 40, degrees") + "\n")
    print(table(rows, "frame", frame, "largest framing log-distance outside the turntable's") + "\n")
    print(table(rows, "az", [0, 1e-9, 1, 2, 3, 4, 6, 7.6], "largest azimuth offset from the 15-degree grid") + "\n")
    from blender_mrvm.models.pretrained import TURNTABLE_TOLERANCE

    tol = np.asarray(TURNTABLE_TOLERANCE)
    keys = ("el", "fov", "frame", "az")
    inside = [r for r in rows if all(r[k] <= t for k, t in zip(keys, tol))]
    outside = [r for r in rows if not all(r[k] <= t for k, t in zip(keys, tol))]
    for what, part in (("inside", inside), ("outside", outside)):
        if part:
            dp = np.array([r["d_psnr"] for r in part])
            se = dp.std(ddof=1) / np.sqrt(len(dp)) if len(dp) > 1 else float("nan")
            print(f"views {what} TURNTABLE_TOLERANCE {tuple(tol)}: {len(part)}, any-view minus default "
                  f"{dp.mean():+.2f} dB (SE {se:.2f}), any-view higher on {(dp > 0).mean():.0%}")
    for s in range(1, 7):  # one band for all four offsets: where does the default stop winning?
        band = [r for r in rows if r["el"] <= s and r["fov"] <= s and r["frame"] <= 0.01 and r["az"] <= s]
        if band:
            dp = np.array([r["d_psnr"] for r in band])
            print(f"every offset within {s} degrees (framing inside): {len(band)} views, {dp.mean():+.2f} dB")
    print()
    for lim in (5.0, 10.0):
        near = [r for r in rows if r["el"] < lim and max(r["el"], r["fov"], r["az"], 100 * r["frame"]) > 1e-3]
        if near:
            print(f"views whose cameras are all off the turntable but within {lim:g} degrees of its elevation:\n")
            print(table(near, "fov", fov, "largest field-of-view offset from 40, degrees") + "\n")
            print(table(near, "frame", frame, "largest framing log-distance outside the turntable's") + "\n")
    coef, se = fit(rows)
    names = ["intercept (dB)", "per degree of elevation", "per degree of field of view", "per unit of framing",
             "per degree of azimuth"]
    print("| any-view minus default, least squares on the largest offsets | coefficient | SE |\n|---|---:|---:|")
    for n, c, e in zip(names, coef, se):
        print(f"| {n} | {c:+.3f} | {e:.3f} |")



if __name__ == "__main__":
    main(sys.argv[1:])
