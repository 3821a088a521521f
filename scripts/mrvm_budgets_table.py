"""The table of scripts/mrvm_budgets.sh: MRVM minus the identical model without it, per training budget.

    python scripts/mrvm_budgets_table.py [data/eval] [ARM]   (ARM: mrvm, the default, or mrvm_bn)

Reads ``budget_[all_][gpu_][r{RAYS}_]{mrvm,base}_s{SEED}_p{P}_{1,2}v/eval.json`` under the folder (``all_``: the
``all`` setting; ``gpu_``: ``scripts/gpu_session.sh mrvm_scale``'s runs; ``r{RAYS}_``: ``mrvm_budgets.sh`` with
``RAYS``, more rays a step; ``oft_``: ``FT=official``, the official code's finetune; the batch of both is read from the checkpoint), pairs each MRVM evaluation with the baseline's on the same views
(``training.evaluate.compare_reports``: objects are the unit) and prints, per seed, budget and reference count, both models' PSNR / SSIM / LPIPS, the nearest view's, and the paired
difference with its 95% interval over objects (mean +- 1.96 standard errors). A second table gives, per setting,
budget and reference count, the mean paired difference over seeds with its standard error over seeds (the seed's
spread is the larger one here: RECIPE.md "Two more seeds").
"""

from __future__ import annotations

import json
import re
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from blender_mrvm.training.evaluate import compare_reports  # noqa: E402



def run_name(arm: str) -> re.Pattern:
    """The evaluation folders of ``arm`` (mrvm, or mrvm_bn: mrvm.head bn_relu), the arm paired with base."""
    return re.compile(rf"budget_(all_)?(gpu_)?(r\d+_)?(oft_)?{arm}_s(\d+)_p(\d+)_(\d)v$")


def interval(s: dict) -> str:
    if s.get("se_objects") is None:
        return f"{s['diff']:+.3f}"
    h = 1.96 * s["se_objects"]
    return f"{s['diff']:+.3f} [{s['diff'] - h:+.3f}, {s['diff'] + h:+.3f}]"


def order(p: Path, name: re.Pattern) -> list:
    """`unseen` before `all`, then seed, budget and reference count."""
    setting, gpu, rays, oft, *nums = name.search(p.name).groups()
    return [bool(setting), bool(gpu), int((rays or "r0_")[1:-1]), bool(oft), *map(int, nums)]


def batch(report: dict) -> str:
    """``OBJ x RAYS`` rays a step, from the evaluated checkpoint's training config ('' if it cannot be read)."""
    try:
        from blender_mrvm.models.checkpoint_files import checked_header

        t = json.loads(checked_header(Path(report["checkpoint"]["path"]))[1]["train_config"])
        return f"{t['objects_per_step']} x {t['rays_per_object']}"
    except Exception:  # an evaluation whose checkpoint is gone keeps its row
        return ""


def over_seeds(diffs: list[float]) -> str:
    """Mean over seeds, with the standard error over seeds when there are two or more."""
    m = statistics.fmean(diffs)
    if len(diffs) < 2:
        return f"{m:+.3f}"
    return f"{m:+.3f} ({statistics.stdev(diffs) / len(diffs) ** 0.5:.3f})"


def seeds_table(groups: dict) -> str:
    """Per setting, budget and reference count: seeds, then the PSNR / SSIM / LPIPS differences' mean (SE) over them."""
    head = ("| setting | steps (pretrain + finetune) | refs | seeds | PSNR diff, mean (SE) | SSIM diff | LPIPS diff |\n"
            "|---|---|---:|---|---|---|---|\n")
    rows = [f"| {setting} | {steps} | {views} | {', '.join(seeds)} | " + " | ".join(over_seeds(d[k]) for k in
                                                                                   ("psnr", "ssim", "lpips")) + " |"
            for (setting, steps, views), (seeds, d) in groups.items()]
    return head + "\n".join(rows) + "\n"


def main(root: Path, arm: str = "mrvm", seeds: bool = True) -> str:
    """The per-seed table, then (``seeds``) the mean over seeds of each setting, budget and reference count."""
    rows, name, groups = [], run_name(arm), {}
    for d in sorted((p for p in root.glob(f"budget_*{arm}_s*_p*_*v") if name.search(p.name)),
                    key=lambda p: order(p, name)):
        setting, gpu, rays, oft, seed, steps, views = name.search(d.name).groups()
        setting = "all" if setting else "unseen"
        other = root / d.name.replace(f"{arm}_s", "base_s")
        if not (d / "eval.json").is_file() or not (other / "eval.json").is_file():
            continue
        a, b = json.loads((d / "eval.json").read_text()), json.loads((other / "eval.json").read_text())
        c = compare_reports(a, b)["overall"]
        oa, ob = a["overall"], b["overall"]
        finetune = 2 * int(steps) if oft else int(steps) // 3  # scripts/mrvm_budgets.sh: F = P / 3, FT=official 2P
        if gpu:
            setting += f", GPU {batch(a)} rays a step".replace("GPU  rays a step", "GPU")
        elif rays:  # scripts/mrvm_budgets.sh with RAYS: the recipe at more rays a step
            b = batch(a)
            setting += f", {b} rays a step" if b else f", {rays[1:-1]} rays per object a step"
        if oft:  # scripts/mrvm_budgets.sh with FT=official: the official code's finetune
            setting += ", official finetune (2P at lr 1e-3)"
        budget = f"{steps} + {finetune} = {int(steps) + finetune}"
        seen, d = groups.setdefault((setting, budget, views), ([], {"psnr": [], "ssim": [], "lpips": []}))
        seen.append(seed)
        for k in d:
            d[k].append(c[k]["diff"])
        rows.append(f"| {setting} | {seed} | {budget} | {views} | {c['views']} "
                    f"| {oa['psnr']:.2f} / {oa['ssim']:.3f} / {oa['lpips']:.3f} "
                    f"| {ob['psnr']:.2f} / {ob['ssim']:.3f} / {ob['lpips']:.3f} "
                    f"| {oa['baseline_nearest']['psnr']:.2f} / {oa['baseline_nearest']['lpips']:.3f} "
                    f"| {interval(c['psnr'])} | {interval(c['ssim'])} | {interval(c['lpips'])} "
                    f"| {c['psnr']['wins']:.0%} |")
    head = ("| setting | seed | steps (pretrain + finetune) | refs | views | MRVM PSNR / SSIM / LPIPS | without MRVM "
            "| nearest view PSNR / LPIPS | PSNR diff [95%] | SSIM diff [95%] | LPIPS diff [95%] "
            "| objects where MRVM has the higher PSNR |\n|---|---|---|---:|---:|---|---|---|---|---|---|---:|\n")
    out = head + "\n".join(rows) + "\n"
    if seeds and groups:
        out += "\nMRVM minus none, mean over seeds (SE over seeds):\n\n" + seeds_table(groups)
    return out


if __name__ == "__main__":
    print(main(Path(sys.argv[1] if len(sys.argv) > 1 else "data/eval"), sys.argv[2] if len(sys.argv) > 2 else "mrvm"),
          end="")
