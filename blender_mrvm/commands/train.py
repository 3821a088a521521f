"""Train a model of any kind (NeRFormer+MRVM: an MRVM pretraining run, then a finetuning run; GPNR) from a JSON run config.

Single process:  python -m blender_mrvm train --config run.json
Data-parallel:   torchrun --nproc_per_node N -m blender_mrvm train --config run.json
Fine-tune:       python -m blender_mrvm train --init runs/pretrain --data my_dataset --out runs/ft  (or --init shipped)
Several datasets: --data turntable_set --data sphere_set  (objects pooled; train.data as a JSON list)
Resumes from the run folder's newest complete checkpoint unless --no-resume (which refuses a run folder
holding a run unless --force). Ctrl-C (or SIGINT, e.g. `timeout -s INT`) finishes the step in progress and saves
it as a checkpoint before stopping (one process; under torchrun it stops at once); a second Ctrl-C stops at once.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, default=None, help="run config JSON ({'model': ..., 'train': ...})")
    p.add_argument("--model", dest="kind", default=None,
                   help="model kind when the config names none: nerformer_mrvm (default) or gpnr (with --init: "
                        "the checkpoint's own model, which must be of this kind)")
    p.add_argument("--preset", default=None,
                   help="model preset (fast, balanced, accurate or paper) when the config names none")
    p.add_argument("--data", action="append", default=None, metavar="ROOT",
                   help="dataset root (overrides train.data); repeat to pool the objects of several datasets, "
                        "e.g. a turntable and a sphere-rig rendering")
    p.add_argument("--data-weights", type=float, nargs="+", default=None, metavar="W",
                   help="each --data dataset's share of the objects drawn, e.g. 2 1 (overrides train.data_weights; "
                        "default: every object alike)")
    p.add_argument("--out", dest="out_dir", default=None, help="run folder (overrides train.out_dir)")
    p.add_argument("--iterations", type=int, default=None, help="overrides train.iterations")
    p.add_argument("--seed", type=int, default=None,
                   help="overrides train.seed (initialisation and all sampling), e.g. a second seed of an ablation")
    p.add_argument("--init", dest="init_checkpoint", default=None,
                   help="fine-tune: start from this checkpoint's weights ('shipped' = the default model) "
                        "instead of a random initialisation (overrides train.init_checkpoint)")
    p.add_argument("--keep-losses", dest="keep_init_losses", action="store_true", default=None,
                   help="with --init: fine-tune with the losses that checkpoint was trained with (the shipped default: "
                        "LPIPS patches and depth) instead of the defaults: sharper views (LPIPS -0.02 on new objects "
                        "of your kind), 0.2 dB lower PSNR, about 1.2x the time a step on a CPU (sets "
                        "train.keep_init_losses; RECIPE.md)")
    p.add_argument("--lpips-weight", type=float, default=None, metavar="W",
                   help="perceptual loss: rays drawn as 16x16 patches with LPIPS-VGG at this weight besides MSE "
                        "(overrides train.lpips_weight; 0 = off, the default; sharper views, see RECIPE.md)")
    p.add_argument("--depth-weight", type=float, default=None, metavar="W",
                   help="depth loss at this weight: each ray's light pulled onto the surface the training view's depth "
                        "map saw (overrides train.depth_weight; 0 = off, the default; needs depth maps, as our renders "
                        "have; NeRFormer+MRVM only; RECIPE.md)")
    p.add_argument("--image-size", type=int, default=None, metavar="N",
                   help="train at N pixels on each view's longer side, each view resized when loaded (overrides "
                        "train.image_size; 0 = as rendered, the default): a 1024 px dataset trains at 128 px without "
                        "re-rendering; larger than the views is refused; a resume must keep it")
    p.add_argument("--compile", action="store_true", default=None,
                   help="torch.compile the networks before training (sets train.compile; worth it on a GPU, where "
                        "small models wait on kernel launches; minutes of compilation on a CPU)")
    p.add_argument("--no-resume", action="store_true", help="start from scratch; a run folder that holds a run "
                   "needs --force too (its checkpoints and metrics are then removed)")
    p.add_argument("--force", action="store_true", help="with --no-resume: start over in a run folder that holds a run")


def run(args) -> int:
    from ..errors import InputError
    from ..guards import check_folder_writable
    from ..progress import run_with_tqdm
    from ..training.config import load_run_config
    from ..training.trainer import train

    data = args.data if args.data is None or len(args.data) > 1 else args.data[0]  # one root stays a string
    mcfg, tcfg = load_run_config(args.config, {"data": data, "data_weights": args.data_weights, "out_dir": args.out_dir,
                                               "iterations": args.iterations, "seed": args.seed,
                                               "init_checkpoint": args.init_checkpoint,
                                               "lpips_weight": args.lpips_weight, "depth_weight": args.depth_weight,
                                               "keep_init_losses": args.keep_init_losses,
                                               "compile": args.compile, "image_size": args.image_size},
                                  kind=args.kind, preset=args.preset, resume=not args.no_resume)
    from ..training.config import data_roots

    if not data_roots(tcfg):
        raise InputError("no dataset: give --data or train.data in the config")
    check_folder_writable(Path(tcfg.out_dir), "run folder")  # a file there had raised FileExistsError
    import os

    rank = int(os.environ.get("RANK", "0"))
    # Ctrl-C lets the step in progress finish; the trainer then saves it (a second Ctrl-C stops at once). Not under
    # torchrun: its ranks could stop a step apart and wait on each other's gradients, so they stop at once as before
    single = int(os.environ.get("WORLD_SIZE", "1")) <= 1
    summary = run_with_tqdm(train(mcfg, tcfg, resume=not args.no_resume, force=args.force), desc="train", unit="step",
                            disable=True if rank else None, between_units=single)
    out = Path(tcfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    record = out / f"summary_rank{summary['rank']}.json"
    if summary["resumed_from"] < summary["step"] or not record.exists():  # (a rerun that trained nothing keeps it)
        record.write_text(json.dumps(summary, indent=2) + "\n")
    if rank == 0:
        print(json.dumps({k: summary[k] for k in ("step", "checkpoint", "resumed_from", "initialized_from", "world_size")}))
    return 0
