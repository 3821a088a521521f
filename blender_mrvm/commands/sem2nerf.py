"""Sem2NeRF: one part mask + its camera -> a radiance field with semantic maps (train, render, eval, bench).

  python -m blender_mrvm sem2nerf train --data data/shapenet13_all --out runs/s2n --preset fast --iterations 5000
  python -m blender_mrvm sem2nerf render --checkpoint runs/s2n --mask obj/mask/000000.png --pose obj/pose/000000.txt \\
      --out s2n_out [--views 8 | --targets targets.json] [--edit 2:0] [--style-seed 3] [--mix-seed 5 --mix 0.3] [--blend 7]
  python -m blender_mrvm sem2nerf eval --checkpoint runs/s2n --data data/shapenet13_all --holdout 3 --out eval/s2n
  python -m blender_mrvm sem2nerf bench --out docs --force  # -> docs/bench_sem2nerf_inputs.csv

train resumes the run in --out as it is (its objects, its --preset and --model, the --init it began from, an
--iterations not below its step) or refuses in one line before anything is written; it holds the run folder
(.lock) while it runs, and removes the half-saved checkpoints a killed run left.

render writes OUT/rgb, OUT/semantic (uint8 part ids), OUT/semantic_color, OUT/pose and sem2nerf.json;
bad input (labels the checkpoint does not know, an empty mask, a mask of another size, a missing
pose, a camera from which under 90% of the mask lies over the model's object box about the origin) is one
line `error: ...` and nothing is written. --force over an earlier render removes that render's files once the new
one is complete; Ctrl-C writes nothing.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="sem2nerf_command", metavar="ACTION")
    sub.required = True
    t = sub.add_parser("train", help="train a Sem2NeRF model on a dataset with part masks")
    t.add_argument("--data", required=True, help="dataset root (our format, mask/*.png part ids)")
    t.add_argument("--out", required=True, help="run folder (resumed from its latest checkpoint, on the same objects "
                   "with the same --preset and --model; a second training into it is refused while one runs)")
    t.add_argument("--preset", default="balanced", help="model preset: fast or balanced (default balanced; a resumed "
                   "run must name its own)")
    t.add_argument("--split", default="train", help="split to train on (default train)")
    t.add_argument("--holdout", type=int, default=0, help="leave out the last N objects of every category")
    t.add_argument("--max-objects", type=int, default=0, help="use at most this many objects (0 = all)")
    t.add_argument("--iterations", type=int, default=5000, help="optimizer steps (default 5000)")
    t.add_argument("--objects-per-step", type=int, default=2, help="objects per step (default 2)")
    t.add_argument("--other-views", type=int, default=1, help="views besides the input view per object (default 1)")
    t.add_argument("--patch-size", type=int, default=16, help="rays per patch side (default 16)")
    t.add_argument("--lpips-weight", type=float, default=0.2, help="LPIPS loss weight (default 0.2)")
    t.add_argument("--ce-weight", type=float, default=0.1, help="semantic cross-entropy weight (default 0.1)")
    t.add_argument("--gan-weight", type=float, default=0.0, help="patch discriminator weight (default 0 = off)")
    t.add_argument("--input-weight", type=float, default=1.0,
                   help="weight of the input view's losses relative to each other view's (default 1)")
    t.add_argument("--lr", type=float, default=2e-4, help="generator + mapping learning rate (default 2e-4)")
    t.add_argument("--encoder-lr", type=float, default=1e-4, help="mask encoder learning rate (default 1e-4)")
    t.add_argument("--init", default="", metavar="CHECKPOINT",
                   help="fine-tune from this Sem2NeRF checkpoint (its config with the --model overrides; heads they "
                        "add, e.g. style_part_colours=true, start at zero)")
    t.add_argument("--code-lr", type=float, default=None,
                   help="learning rate of the per-object style codes (default 1e-3); each code moves only when its "
                        "object is drawn")
    t.add_argument("--lr-end-factor", type=float, default=1.0,
                   help="learning rates decay exponentially to this factor at the last step (default 1 = constant)")
    t.add_argument("--model", action="append", default=[], metavar="FIELD=VALUE",
                   help="override a field of the model preset (e.g. n_coarse=16, pixel_aligned=false); repeatable")
    t.add_argument("--scale-anneal-steps", type=float, default=2000.0, help="e-folding steps of the patch scale bound")
    t.add_argument("--checkpoint-every", type=int, default=500, help="steps between checkpoints (default 500)")
    t.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    t.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = every core but one)")
    t.add_argument("--device", default="cpu", help="auto (CUDA when available), cpu or cuda[:N] (default cpu)")
    t.add_argument("--no-resume", action="store_true", help="start from scratch; a run folder that holds a run "
                   "needs --force too (its checkpoints and metrics are then removed)")
    t.add_argument("--force", action="store_true", help="with --no-resume: start over in a run folder that holds a run")

    r = sub.add_parser("render", help="free-viewpoint images + semantic maps from one part mask and its camera")
    r.add_argument("--checkpoint", required=True,
                   help="Sem2NeRF model file, checkpoint folder or run folder, or shipped:sem2nerf")
    r.add_argument("--mask", required=True, help="part-id mask PNG (uint8, the checkpoint's image size)")
    r.add_argument("--pose", required=True, help="the mask's camera: SRN pose .txt (4x4 OpenCV camera-to-world)")
    r.add_argument("--intrinsics", default="", help="SRN intrinsics.txt (default: the pose's object folder's)")
    r.add_argument("--fov", type=float, default=40.0, help="horizontal FOV in degrees when no intrinsics are found")
    r.add_argument("--out", required=True, help="output folder (must be empty or new unless --force)")
    r.add_argument("--views", type=int, default=None, help="views on the orbit about world z (view 0 = input camera; "
                   "default 8; not with --targets)")
    r.add_argument("--edit", action="append", default=[], metavar="SRC:DST",
                   help="relabel part SRC as DST (ids or label names) before rendering; repeatable")
    r.add_argument("--style-seed", type=int, default=None, help="style of this random code (default: the mean style)")
    r.add_argument("--blend", type=int, default=None, metavar="SEED",
                   help="also render the input view along a linear blend to the style of SEED")
    r.add_argument("--blend-steps", type=int, default=None, help="with --blend: images along the blend, ends included "
                   "(default 5)")
    r.add_argument("--mix-seed", type=int, default=None, metavar="SEED",
                   help="render every view with the style blended toward the style of SEED ...")
    r.add_argument("--mix", type=float, default=None, help="with --mix-seed: the blend factor in [0, 1] (default 0.5)")
    r.add_argument("--targets", default="",
                   help="targets.json (the add-on's format) of the cameras to render instead of the orbit")
    r.add_argument("--force", action="store_true", help="write into a non-empty output folder (an earlier render's "
                   "files there are removed once this one is complete)")
    r.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = every core but one)")
    r.add_argument("--device", default="cpu", help="auto (CUDA when available), cpu or cuda[:N] (default cpu)")
    r.add_argument("--quality", default="full", choices=("full", "preview"), help="full (as trained) or preview: half the samples per ray, about "
                   "1.9x faster for -0.13 dB at equal LPIPS (bench tradeoff, docs/guide/speed.md)")

    e = sub.add_parser("eval", help="PSNR/SSIM/LPIPS and mIoU on held-out objects vs the category-mean baseline")
    e.add_argument("--checkpoint", required=True, help="Sem2NeRF checkpoint, or shipped:sem2nerf")
    e.add_argument("--data", required=True, help="dataset root")
    e.add_argument("--split", default="train", help="split the objects come from (default train)")
    e.add_argument("--holdout", type=int, default=0,
                   help="evaluate the last N objects of every category of --split (those training held out); "
                        "0 = every object of --split")
    e.add_argument("--max-objects", type=int, default=0, help="evaluate at most this many objects (0 = all)")
    e.add_argument("--input-view", type=int, default=0, help="view whose mask is the input (default 0)")
    e.add_argument("--views-every", type=int, default=3,
                   help="score the input view and every N-th other view (default 3)")
    e.add_argument("--blend-objects", type=int, default=3,
                   help="objects whose input view is rendered along a 5-step style blend (default 3)")
    e.add_argument("--out", required=True, help="output folder for eval.json and eval_grid.png (a folder holding "
                   "other files needs --force)")
    e.add_argument("--force", action="store_true", help="write into an output folder that holds other files")
    e.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = every core but one)")

    b = sub.add_parser("bench", help="time the input builders (512 px by default) -> CSV")
    b.add_argument("--out", default="bench_out", help="output folder (default bench_out)")
    b.add_argument("--size", type=int, default=512, help="mask size in pixels (default 512)")
    b.add_argument("--repeats", type=int, default=50, help="timed repeats per builder (default 50)")
    b.add_argument("--force", action="store_true", help="replace this bench's earlier results in --out")


def parse_model_overrides(items: list[str]) -> dict:
    """['n_coarse=16', 'pixel_aligned=false'] -> {'n_coarse': 16, 'pixel_aligned': False}; InputError for
    fields the model config lacks or values of the wrong type."""
    from dataclasses import fields

    from ..errors import InputError
    from ..models.sem2nerf.config import Sem2NeRFConfig

    types = {f.name: f.type for f in fields(Sem2NeRFConfig)}
    out = {}
    for item in items:
        key, sep, val = item.partition("=")
        key = key.strip()
        if not sep or key not in types or key in ("labels", "label_names", "image_size", "name"):
            raise InputError(f"--model {item!r}: expected FIELD=VALUE with a field of the model config")
        t = str(types[key])
        try:
            if t == "bool":
                if val.strip().lower() not in ("true", "false", "1", "0"):
                    raise ValueError(val)
                out[key] = val.strip().lower() in ("true", "1")
            else:
                out[key] = int(val) if t == "int" else float(val)
        except ValueError:
            raise InputError(f"--model {item!r}: {val!r} is not a valid {t}") from None
    return out


def run(args) -> int:
    from ..progress import run_with_tqdm

    from .. import validation as V

    cmd = args.sem2nerf_command
    for flag in ("holdout", "max_objects", "threads", "input_view", "blend_objects"):  # negative ones were taken
        if getattr(args, flag, None) is not None:
            V.check_count(f"--{flag.replace('_', '-')}", getattr(args, flag), 0)
    if getattr(args, "views_every", None) is not None:
        V.check_count("--views-every", args.views_every, 1)
    if cmd in ("train", "render"):
        V.check_device_name("--device", args.device)
        if args.device.strip().lower() != "cpu":  # auto and cuda resolved now: a traceback in training before
            from ..synthesis.views import resolve_device

            args.device = str(resolve_device(args.device))
    if cmd == "train":
        from ..guards import check_folder_writable
        from ..training import sem2nerf as T

        check_folder_writable(Path(args.out), "run folder")  # a file there had raised FileExistsError
        cfg = T.train_config(data=args.data, out_dir=args.out, preset=args.preset, split=args.split,
                             holdout=args.holdout, max_objects=args.max_objects, iterations=args.iterations,
                             objects_per_step=args.objects_per_step, other_views=args.other_views,
                             patch_size=args.patch_size, lpips_weight=args.lpips_weight, ce_weight=args.ce_weight,
                             gan_weight=args.gan_weight, scale_anneal_steps=args.scale_anneal_steps,
                             input_weight=args.input_weight, lr=args.lr, encoder_lr=args.encoder_lr,
                             lr_end_factor=args.lr_end_factor, model_overrides=parse_model_overrides(args.model),
                             checkpoint_every=args.checkpoint_every, seed=args.seed, threads=args.threads,
                             device=args.device, init_checkpoint=args.init,
                             **({"code_lr": args.code_lr} if args.code_lr is not None else {}))
        summary = run_with_tqdm(T.train(cfg, resume=not args.no_resume, force=args.force), desc="sem2nerf train",
                                unit="step", between_units=True)
        print(json.dumps(summary))
        return 0
    if cmd == "render":
        from ..errors import InputError
        from ..models.sem2nerf.render import RenderRequest, render_from_mask

        # --mix without --mix-seed (or --blend-steps without --blend) was ignored: the images came out in the
        # unblended style with no word
        for flag, value, needs, given in (("--mix", args.mix, "--mix-seed", args.mix_seed),
                                          ("--blend-steps", args.blend_steps, "--blend", args.blend)):
            if value is not None and given is None:
                raise InputError(f"{flag} needs {needs} SEED (the style to blend toward)")
        if args.views is not None and args.targets:  # the targets' cameras were rendered, --views ignored
            raise InputError("--views is the orbit's count; with --targets the targets' cameras are rendered: "
                             "give one of them")
        req = RenderRequest(checkpoint=args.checkpoint, mask=args.mask, pose=args.pose, out=args.out,
                            intrinsics=args.intrinsics, fov=args.fov, views=8 if args.views is None else args.views,
                            edits=tuple(args.edit),
                            style_seed=args.style_seed, blend=args.blend,
                            blend_steps=5 if args.blend_steps is None else args.blend_steps,
                            force=args.force, threads=args.threads, device=args.device, targets=args.targets,
                            mix_seed=args.mix_seed,
                            mix=(0.5 if args.mix is None else args.mix) if args.mix_seed is not None else 0.0,
                            quality=args.quality)
        try:
            summary = run_with_tqdm(render_from_mask(req), desc="sem2nerf render", unit="img")
        except KeyboardInterrupt:  # the CLI's own line says "finished work is kept": a render keeps nothing
            print(f"error: interrupted; nothing was written ({args.out} is as it was)", file=sys.stderr)
            return 130
        print(json.dumps({"out": args.out, "views": summary["views"], "edits": summary["edits"]}))
        return 0
    if cmd == "eval":
        from ..guards import check_not_input, check_output_folder
        from ..training import sem2nerf as T

        # checked before the evaluation, not found when it writes at the end (as `eval` does)
        check_not_input(Path(args.out), {"dataset": Path(args.data)})
        check_output_folder(Path(args.out), args.force, "eval output folder", ours=T.EVAL_FILES)
        res = run_with_tqdm(T.evaluate(Path(args.checkpoint), Path(args.data), Path(args.out), split=args.split,
                                       holdout=args.holdout, max_objects=args.max_objects,
                                       input_view=args.input_view, views_every=args.views_every,
                                       threads=args.threads, blend_objects=args.blend_objects),
                            desc="sem2nerf eval", unit="obj")
        print(json.dumps(res["overall"]))
        return 0
    if cmd == "bench":
        from ..bench import at_least, start_results
        from ..guards import check_folder_writable
        from ..models.sem2nerf.inputs import BENCH_RESULTS, bench

        at_least(args, size=1, repeats=1)
        check_folder_writable(Path(args.out), "bench output folder")
        out = start_results(Path(args.out), BENCH_RESULTS, args.force)
        res = bench(out, size=args.size, repeats=args.repeats)
        print(json.dumps({k: round(v, 3) for k, v in res.items()}))
        return 0
    raise AssertionError(cmd)
