"""Evaluate a checkpoint with the SRN protocol: fixed input view ids, every other view scored.

Writes <out>/eval.json (PSNR, SSIM, LPIPS-VGG per category and overall, with the nearest-reference
and mean-colour baselines) and <out>/eval_grid.png. LPIPS needs the offline weights
(`python -m blender_mrvm fetch-weights`); --no-lpips skips it explicitly.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--checkpoint", type=Path, required=True, help="run folder, checkpoint folder or model.safetensors")
    p.add_argument("--data", type=Path, required=True, help="dataset root (ours, SRN, NMR/DVR, NeRF-synthetic)")
    p.add_argument("--split", default="test", help="split to evaluate (default test)")
    p.add_argument("--format", dest="fmt", default=None, help="dataset format (default: detect)")
    p.add_argument("--input-views", default="0", help="comma-separated input view ids, e.g. 64 or 64,104 (SRN)")
    p.add_argument("--max-objects", type=int, default=0, help="evaluate at most this many objects (0 = all)")
    p.add_argument("--max-targets", type=int, default=0, help="score at most this many views per object (0 = all)")
    p.add_argument("--out", type=Path, default=Path("eval_out"), help="output folder")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (otherwise the offline weights are required)")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = default)")


def run(args) -> int:
    import torch

    from ..datasets.loaders import load_dataset
    from ..errors import InputError
    from ..progress import run_with_tqdm
    from ..training.checkpoint import load_model
    from ..training.evaluate import evaluate

    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        views = [int(v) for v in str(args.input_views).split(",") if v.strip()]
    except ValueError as e:
        raise InputError(f"--input-views must be comma-separated integers, got {args.input_views!r}") from e
    if not views:
        raise InputError("--input-views is empty")
    model, _, meta = load_model(args.checkpoint)
    lpips = None
    if not args.no_lpips:
        from ..models.metrics import LPIPS

        lpips = LPIPS()
    scenes = load_dataset(args.data, args.split, args.fmt, args.max_objects or None)
    report = run_with_tqdm(evaluate(model, scenes, views, lpips, args.max_targets, args.out), desc="eval", unit="view")
    report["checkpoint"] = {"path": str(args.checkpoint), "step": meta.get("step")}
    print(json.dumps({"overall": report["overall"], "out": str(args.out)}, indent=2))
    return 0
