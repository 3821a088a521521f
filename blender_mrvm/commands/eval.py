"""Evaluate a checkpoint with the SRN protocol: fixed input view ids, every other view scored.

The input views default to the dataset's own protocol (``splits/eval_views.json`` from
``make-shapenet``: ``--n-inputs 1`` or ``2``; ``make-captures`` names each held-out view's own inputs,
its neighbours on the camera path), or pixelNeRF's ids for SRN folders; ``--input-views`` overrides
them. The checkpoint defaults to the shipped model. Writes <out>/eval.json (PSNR, SSIM,
LPIPS-VGG per category and overall, with the nearest-reference and mean-colour baselines and the
margin over the better one), <out>/eval.md and <out>/eval_grid.png; --compare-to adds paired differences
against another checkpoint's eval.json (<out>/compare.json). LPIPS needs the offline weights
(`python -m blender_mrvm fetch-weights`); --no-lpips skips it explicitly.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..models.precision import SYNTH_PRECISIONS

    p.add_argument("--checkpoint", type=Path, default=None,
                   help="run folder, checkpoint folder or .safetensors file of any model kind, or shipped:<kind> such as shipped:gpnr, shipped:gpnr_captures for rooms and photo captures, shipped:mrvm_anyview for cameras off the turntable, or shipped:mrvm_quality (GPU-trained, best for cameras anywhere, slow on a CPU) (default: the shipped NeRFormer+MRVM model)")
    p.add_argument("--data", type=Path, required=True, help="dataset root (ours, SRN, NMR/DVR, NeRF-synthetic)")
    p.add_argument("--split", default="test", help="split to evaluate (default test)")
    p.add_argument("--format", dest="fmt", default=None, help="dataset format (default: detect)")
    p.add_argument("--n-inputs", type=int, default=2, help="number of input views of the dataset's protocol "
                   "(splits/eval_views.json input_views_N; default 2)")
    p.add_argument("--input-views", default=None, help="comma-separated input view ids overriding the protocol, "
                   "e.g. 64 or 64,104 (then every other view is scored)")
    p.add_argument("--nearest", type=int, default=0, metavar="K",
                   help="render each target from its K nearest other views (a dense capture: every other photo "
                   "at hand; with --input-views, the nearest K of those) instead of the protocol's fixed inputs; the "
                   "protocol still picks the targets (0 = off, the default)")
    p.add_argument("--max-objects", type=int, default=0, help="evaluate at most this many objects (0 = all)")
    p.add_argument("--max-objects-per-category", type=int, default=0,
                   help="evaluate the first N objects of each category of the split (0 = all)")
    p.add_argument("--max-targets", type=int, default=0, help="score at most this many views per object (0 = all)")
    p.add_argument("--out", type=Path, default=Path("eval_out"), help="output folder")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (otherwise the offline weights are required)")
    p.add_argument("--device", default="auto", help="auto (CUDA when available), cpu or cuda[:N]: where the model "
                   "renders (default auto); references, rays and the hull are moved to it, scores are computed on the CPU")
    p.add_argument("--threads", type=int, default=0, help="CPU threads (0 = every core): views render that many ray chunks side by side, one core each")
    p.add_argument("--skip-empty", choices=("cull", "tighten", "off"), default="cull",
                   help="empty-space skipping through the references' visual hull where the dataset has masks "
                   "(as synthesize; default cull)")
    p.add_argument("--ref-size", type=int, default=0, help="references' longer side for the model, as in synthesize: "
                   "0 (default) shrinks references larger than the model's training images to that size, -1 keeps "
                   "them, N pixels (baselines and ground truth stay at the size the views are loaded at: --image-size)")
    p.add_argument("--image-size", type=int, default=None, metavar="N",
                   help="score at N pixels on each view's longer side: every view (references, targets, masks, depth "
                   "maps) resized when loaded, as train --image-size does (0 = the dataset's size); default: the size "
                   "a checkpoint trained with train.image_size trained at (larger views shrunk to it, not smaller "
                   "ones grown), else the dataset's size")
    from ..training.adapt import add_arguments as add_adapt_arguments

    add_adapt_arguments(p)
    p.add_argument("--reproject", choices=("auto", "off", "model", "gt"), default="auto",
                   help="lay the references' own colours over each view where they see its surface: through the "
                   "model's depth ('model'; its renders of the view and of each reference) or the data's depth maps "
                   "('gt': the ceiling with exact geometry); each view also keeps the model's own scores and the "
                   "report the paired difference. auto (default): 'model' where synthesis does it (--nearest, a "
                   "model that predicts its colours), else off (models/reproject.py)")
    from ..models.reproject import ReprojectConfig

    rp = ReprojectConfig()
    p.add_argument("--reproject-tau", type=float, default=rp.tau,
                   help=f"with --reproject: a reference sees a point at most (1 + tau) x its own depth there away "
                   f"(default {rp.tau}, as synthesis)")
    p.add_argument("--reproject-angle", type=float, default=rp.angle_scale,
                   help=f"with --reproject: weight references by exp((cos angle - 1) / this) between their ray and "
                   f"the view's (0 = alike; default {rp.angle_scale}, as synthesis)")
    p.add_argument("--reproject-opacity", default=f"{rp.acc_lo},{rp.acc_hi}", metavar="LO,HI",
                   help=f"with --reproject: the photos' colours are trusted from the view's opacity LO, fully from HI "
                   f"(default {rp.acc_lo},{rp.acc_hi}, as synthesis)")
    p.add_argument("--reproject-refs", type=int, default=rp.max_refs,
                   help=f"with --reproject: the view's nearest this many references lend their colours (default "
                   f"{rp.max_refs}, as synthesis)")
    p.add_argument("--precision", default="fp32", choices=SYNTH_PRECISIONS,
                   help="the model's precision (models/precision.py): fp32 (default, the protocol's), bf16 or fp16 "
                   "autocast (fp16 on a GPU), int8 linear layers (the CPU), or auto (what synthesize uses: bf16 on a "
                   "GPU, int8 on the CPU where it pays); the metrics are float32 whatever it is; eval.json records it")
    p.add_argument("--force", action="store_true", help="write into an output folder that holds other files")
    p.add_argument("--compare-to", type=Path, default=None, help="eval.json of another checkpoint on the same views: "
                   "also write <out>/compare.json (paired differences this - other, standard errors over objects); "
                   "refused when it is of another data root, split or format, or a common view had other inputs; a "
                   "note names the views only one of them scored and the rendering settings they differ in")


def check_args(args) -> None:
    """Every number and the output folder, before the checkpoint or the data is read."""
    from .. import validation as V
    from ..guards import check_output_folder

    V.check_device_name("--device", args.device)
    V.check_count("--threads", args.threads, 0, 4096)
    V.check_count("--max-objects", args.max_objects, 0)
    V.check_count("--max-objects-per-category", args.max_objects_per_category, 0)
    V.check_count("--max-targets", args.max_targets, 0)
    V.check_count("--n-inputs", args.n_inputs, 1, 10)
    from ..datasets.novel_views import MAX_REFERENCES

    V.check_count("--nearest", args.nearest, 0, MAX_REFERENCES)
    V.check_ref_size("--ref-size", args.ref_size)
    if getattr(args, "image_size", None) is not None:
        V.check_count("--image-size", args.image_size, 0)
    from ..training.adapt import from_args as adapt_from_args

    from ..errors import InputError
    from ..models.precision import check_precision

    adapt = adapt_from_args(args)  # checked here, before anything is read
    check_precision("--precision", args.precision, auto=True)
    if args.precision == "int8" and adapt.on:
        raise InputError("--precision int8 and --adapt-steps do not combine (adapting trains float weights); "
                         "leave one out")
    reproject_from_args(args)
    # an earlier evaluation (eval.json) is kept unless --force: the default folder is shared by every run, and a
    # second checkpoint's scores had replaced the first's without a word (session 29); the rest is derived from it
    check_output_folder(args.out, args.force, "eval output folder", ours=("eval.md", "eval_grid.png", "compare.json"))


def reproject_from_args(args):
    """The checked :class:`models.reproject.ReprojectConfig` of ``--reproject-*`` (an InputError when bad)."""
    from ..models.reproject import ReprojectConfig

    from ..errors import InputError

    try:
        lo, hi = (float(v) for v in str(args.reproject_opacity).split(","))
    except ValueError as e:
        raise InputError(f"--reproject-opacity must be two numbers LO,HI, got {args.reproject_opacity!r}") from e
    cfg = ReprojectConfig(tau=args.reproject_tau, angle_scale=args.reproject_angle, max_refs=args.reproject_refs,
                          acc_lo=lo, acc_hi=hi)
    cfg.check()
    return cfg


def read_compare_to(path: Path) -> dict:
    """Another run's eval.json (``--compare-to``); InputError when it is missing or not one."""
    from ..errors import InputError

    if not path.is_file():
        raise InputError(f"--compare-to {path} does not exist")
    try:
        other = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise InputError(f"--compare-to {path} is not valid JSON ({e})") from None
    views = other.get("views") if isinstance(other, dict) else None
    if not isinstance(views, list) or not all(isinstance(r, dict) and {"category", "object", "view"} <= set(r)
                                              for r in views):
        raise InputError(f"--compare-to {path} is not an eval.json written by `eval` (no per-view 'views' list)")
    return other


def run(args) -> int:
    """The output folder is held for the run (``guards.output_lock``): a second evaluation into it is refused, so
    its check holds and eval.json, eval.md, eval_grid.png and compare.json come from one run."""
    from ..guards import check_name_length, output_lock

    check_name_length(args.out, "--out")
    with output_lock(args.out, "eval output folder"):
        return _run(args)


def _run(args) -> int:
    from ..datasets.loaders import check_finished, detect_format, list_objects, load_object, object_category
    from ..errors import InputError
    from ..progress import run_with_tqdm
    from ..training.checkpoint import load_model
    from ..training.evaluate import evaluate, per_category, report_json, protocol_target_inputs, protocol_views

    from ..threads import render_workers
    from ..training.adapt import from_args as adapt_from_args

    check_args(args)
    workers = render_workers(args.threads)
    other = None
    if args.compare_to is not None:
        other = read_compare_to(args.compare_to)
    if not args.data.exists():
        raise InputError(f"dataset {args.data} does not exist")
    fmt = args.fmt or detect_format(args.data)
    data_rec = {"root": str(args.data.expanduser().resolve()), "split": args.split, "format": fmt}
    if other is not None:  # another data set or split: refused before anything is scored (the views come later)
        compare_to(args, {"data": data_rec}, other, check_only=True)
    if args.input_views is not None:
        try:
            views = [int(v) for v in str(args.input_views).split(",") if v.strip()]
        except ValueError as e:
            raise InputError(f"--input-views must be comma-separated integers, got {args.input_views!r}") from e
        if not views:
            raise InputError("--input-views is empty")
        targets, source, per_target = None, "--input-views", None
    else:
        if args.n_inputs < 1:
            raise InputError(f"--n-inputs must be at least 1, got {args.n_inputs}")
        views, targets, source = protocol_views(args.data, args.n_inputs, fmt)
        per_target = protocol_target_inputs(args.data, args.n_inputs)  # captures: each target's own neighbours
    from ..models.pretrained import resolve_checkpoint

    args.checkpoint = resolve_checkpoint(args.checkpoint)
    from ..synthesis import resolve_device

    device = resolve_device(args.device)
    from ..models.precision import autocast, check_precision, for_precision, resolve_precision

    check_precision("--precision", args.precision, device.type, auto=True)
    model, _, meta = load_model(args.checkpoint, str(device))
    from ..models.checkpoint_files import model_file_of
    from ..training.provenance import file_sha256

    model_file = getattr(model, "checkpoint_file", None) or model_file_of(args.checkpoint)  # the file it loaded
    model_sha = file_sha256(model_file)
    precision = resolve_precision(args.precision, device.type, model)
    if precision == "int8" and adapt_from_args(args).on:  # auto picked it: adapting needs the float weights
        precision = "fp32"
    model = for_precision(model, precision, inplace=True)
    from ..synthesis import reference_sizes

    ref_size, max_ref_size = reference_sizes(args.ref_size, args.checkpoint)
    lpips = None
    if not args.no_lpips:
        from ..models.metrics import LPIPS

        lpips = LPIPS()
    objs = list_objects(args.data, fmt, args.split)
    check_finished(args.data, args.split, objs)
    # grouped by the category the loaders give (every NeRF-synthetic scene fell in one group, the root's; SRN's
    # groups were cars_test)
    objs = per_category(objs, lambda o: object_category(*o), args.max_objects_per_category)
    objs = objs[:args.max_objects or None]
    if not objs:
        raise InputError(f"{args.data}: no objects for split {args.split!r}")
    image_size, shrink_only = scoring_size(args.image_size, meta)
    # depth maps, where they exist, are scored; every view at image_size px on its longer side (0: as rendered)
    scenes = [load_object(f, p, args.split, depth=True, image_size=image_size, what="--image-size",
                          shrink_only=shrink_only) for f, p in objs]
    _note_larger_views(scenes, image_size, ref_size, max_ref_size)
    from ..models import background as bgrule

    reproject = args.reproject
    if reproject == "auto":  # as synthesis: each view from its nearest of more, and not GPNR
        reproject = "model" if args.nearest and not bgrule.blends_references(model) else "off"
    data_bg = bgrule.of_scenes(scenes)
    bg_note = bgrule.for_rendering(model, data_bg)  # the data decides; a mismatch is said, never silent
    if bg_note:
        print(f"note: {bg_note}", file=sys.stderr)
    from ..training.provenance import environment, scenes_digest

    extra = {"checkpoint": {"path": str(args.checkpoint), "step": int(meta["step"]) if meta.get("step") else None,
                            # which weights: a run folder's path names its newest checkpoint, which moves on
                            "file": str(Path(model_file).resolve()), "sha256": model_sha},
             # what repeating it needs (training/provenance.py): code, libraries, threads, the command, the data
             "provenance": {**environment(device=str(device), when=False), "render_workers": workers,
                            "data": scenes_digest(scenes),
                            "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in sorted(vars(args).items())
                                         if k not in ("func",) and isinstance(v, (str, int, float, bool, Path, type(None)))}},
             "device": str(device), "precision": precision,
             "background": {"data": data_bg, "white_background": model.white_background, "note": bg_note},
             "image_size": {"asked": args.image_size, "used": image_size,
                            "rule": "the dataset's size" if not image_size else
                            "the checkpoint's train.image_size (shrinking only)" if shrink_only else "--image-size"},
             "data": {**data_rec, "protocol_source": source, "max_objects_per_category": args.max_objects_per_category,
                      "n_inputs": None if source == "--input-views" else args.n_inputs}}
    with autocast(precision, device.type):
        report = run_with_tqdm(evaluate(model, scenes, views, lpips, args.max_targets, args.out, target_views=targets,
                                        extra=extra, ref_size=ref_size, max_ref_size=max_ref_size,
                                        skip=args.skip_empty, target_inputs=per_target, workers=workers,
                                        adapt=adapt_from_args(args), nearest=args.nearest,
                                        pool=views if args.nearest and source == "--input-views" else None,
                                        reproject=reproject, reproject_cfg=reproject_from_args(args)),
                               desc="eval", unit="view")
    result = {"overall": report["overall"], "out": str(args.out)}
    (args.out / "compare.json").unlink(missing_ok=True)  # an earlier run's (--force): not of this eval.json
    if other is not None:
        from ..datasets.format import atomic_write_json

        this = json.loads((args.out / "eval.json").read_text())
        cmp = {"this": str(args.checkpoint), "other": other.get("checkpoint", {}).get("path"),
               **compare_to(args, this, other)}
        atomic_write_json(args.out / "compare.json", cmp)
        result["compare"] = {"file": str(args.out / "compare.json"), "this": cmp["this"], "other": cmp["other"],
                             "this_minus_other": cmp["overall"], "unpaired": cmp["unpaired"],
                             "settings_differ": cmp["settings_differ"]}
        up = cmp["unpaired"]
        if up["this"] or up["other"]:  # other objects or --max-targets: the figures are of the common views alone
            print(f"note: --compare-to pairs the {cmp['overall']['views']} views both scored; left out: {up['this']} "
                  f"scored only here, {up['other']} only in {args.compare_to}", file=sys.stderr)
        if cmp["settings_differ"]:  # the difference is then the setting's as much as the checkpoint's
            print("note: --compare-to: the two evaluations rendered with other settings: " + "; ".join(
                f"{k} {x} against {y}" for k, (x, y) in cmp["settings_differ"].items()), file=sys.stderr)
    # one JSON line, last on stdout (as synthesize, train and sem2nerf): `json.load` or `tail -n1 | jq` reads it
    print(report_json(result, indent=None))
    return 0


def checkpoint_image_size(meta: dict) -> int:
    """The ``train.image_size`` a checkpoint's run trained at (its ``train_config``; 0 when it trained at its
    data's own size, or recorded none)."""
    try:
        n = json.loads(meta.get("train_config") or "{}").get("image_size", 0)
    except (ValueError, TypeError, AttributeError):
        return 0
    return n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else 0


def scoring_size(asked: int | None, meta: dict) -> tuple[int, bool]:
    """(the longer side every view is loaded at, 0 = as rendered; whether smaller views stay as they are) for
    ``--image-size`` ``asked`` (None: the checkpoint's ``train.image_size``, shrinking only)."""
    if asked is None:
        return checkpoint_image_size(meta), True
    return int(asked), False


def _note_larger_views(scenes, image_size: int, ref_size: int, max_ref_size: int) -> None:
    """Say so when the targets render at a larger size than the references the model sees (a dataset rendered
    larger than the model trained at, scored at its own size: slow, and not what the model was trained for)."""
    if image_size or ref_size or not max_ref_size:
        return
    big = [s for s in scenes if len(s) and max(s.images.shape[1:3]) > max_ref_size]
    if big:
        side = max(big[0].images.shape[1:3])
        print(f"note: the views are {side} px on their longer side, the model trained at {max_ref_size}: the "
              f"references are shrunk to {max_ref_size} and the targets rendered and scored at {side} px; "
              f"--image-size {max_ref_size} scores at the training size", file=sys.stderr)


def compare_to(args, this: dict, other: dict, check_only: bool = False) -> dict | None:
    """``training.evaluate.compare_reports(this, other)`` (or with ``check_only`` its check alone), its refusal
    (other data, split or references: ``check_comparable``) named as --compare-to's."""
    from ..errors import InputError
    from ..training.evaluate import check_comparable, compare_reports

    try:
        if check_only:
            check_comparable(this, other)
            return None
        return compare_reports(this, other)
    except InputError as e:
        done = "" if check_only else f" ({args.out / 'eval.json'} is written, compare.json is not)"
        raise InputError(f"--compare-to {args.compare_to}: {e}{done}") from None
