"""Operator: Train / fine-tune the model from the panel (``bpy.ops.mrvm.train()``).

Training runs in the worker process (``python -m blender_mrvm train --config job.json``, the same
command a cluster job runs), driven by ``operators/_modal.ProgressOperator``: modal from the UI with
the step, loss and PSNR in the panel and status bar, Esc interrupts the worker (it finishes the step in
progress and saves it as a checkpoint, and training again continues from there); ``execute`` runs it to the end.

A new run starts from the shipped model (the default), from another checkpoint, or from a random
start ("Start from"). Starting from a checkpoint fine-tunes it: its model config and weights, with
the trainer's fine-tuning policy (``training.config.FINETUNE``: no MRVM masking phase, a lower peak
learning rate), the same as ``train --init`` on the command line. New runs on our rendered datasets (which carry object masks)
add the opacity loss (``training.config.OPACITY_WEIGHT``). With "Continue run" on and a run already in the run folder,
the trainer resumes it instead (weights, optimizer, schedule and random state) and trains up to the
iteration count, on whatever dataset is chosen now. When it finishes, the run folder is picked as
the Synthesize novel views checkpoint (the synthesis loads its latest checkpoint). A job that needs the offline
VGG16 / LPIPS weights (Keep its losses of a model trained with LPIPS, a VGG16 encoder) is refused before it starts
when they are not in the worker's weight cache (``worker.weights_dir``: the preferences' Weights cache, ...).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import bpy

from ..errors import InputError
from ._modal import ProgressOperator

if TYPE_CHECKING:
    from ..progress import ProgressGen

TRAIN_COMMAND = "train"
CONTINUED_SETTINGS = ("init_checkpoint", "pretrain_frac", "lr", "lr_warmup", "lr_final_frac", "weight_decay", "seed",
                      "min_ref_views", "max_ref_views", "objects_per_step", "bbox_sampling_frac", "grad_clip",
                      "coarse_weight", "opacity_weight", "distortion_weight", "depth_weight", "lpips_weight", "patch_size",
                      "patch_scale_min", "patch_fg_prob", "amp", "keep_checkpoints")
"""Train settings a continued run keeps from its config.json (the panel does not set them): its losses too."""


@dataclass(frozen=True)
class TrainJob:
    """One training run, checked and ready to start."""

    data: Path
    """Dataset root."""
    run_dir: Path
    """Run folder (checkpoints/, metrics.jsonl, config.json)."""
    preset: str
    """Model preset name (of the run continued or the checkpoint fine-tuned, when there is one)."""
    model: dict
    """The run config's model section: a preset, a full config (continuing a run), or empty (the
    fine-tuned checkpoint's own)."""
    init_checkpoint: Path | None
    """Fine-tune this model file (None: a random start, or continuing a run)."""
    continued: dict
    """Train settings of the run being continued that the new job keeps (its schedule)."""
    iterations: int
    """Steps in all."""
    checkpoint_every: int
    """Checkpoint interval in steps."""
    rays_per_object: int
    """Target rays per object per step."""
    resume: bool
    """Continue from the run folder's last checkpoint."""
    device: str
    """The add-on preferences' device: cpu, cuda, or auto (the trainer's default, the CPU)."""
    force: bool = False
    """Not resuming: the user confirmed removing the run the folder holds (``train --force``)."""
    keep_losses: bool = False
    """Fine-tuning: train with the losses the checkpoint was trained with (``train.keep_init_losses``)."""


def _abs(p: str, what: str) -> Path:
    from ._paths import blend_path

    return blend_path(p, f"the {what}")


def _as_setting(path: Path) -> str:
    """``path`` as a panel setting: relative to the saved .blend (``//``) when it can be, else absolute."""
    from ..scene.image_planes import blend_relative

    return blend_relative(path)


def run_config(run_dir: Path) -> dict | None:
    """The run config a run folder was trained with (its config.json: model config and train section),
    or None when it holds no run."""
    cfg = Path(run_dir) / "config.json"
    if not cfg.is_file():
        return None
    try:
        doc = json.loads(cfg.read_text())
        str(doc["model"]["config"]["name"])
        if not isinstance(doc.get("train", {}), dict):
            return None
        return doc
    except (ValueError, KeyError, TypeError):
        return None


def run_model_name(run_dir: Path) -> str | None:
    """The model preset a run folder was trained with, or None when it has no run."""
    doc = run_config(run_dir)
    return None if doc is None else str(doc["model"]["config"]["name"])


def init_checkpoint(p) -> tuple[Path, dict]:
    """(model file, metadata) to fine-tune (Start from: shipped model or checkpoint), checked without torch."""
    from ..models.checkpoint_files import checked_header

    if p.start_from == "SHIPPED":
        from ..models.pretrained import shipped_checkpoint

        ck = shipped_checkpoint(p.model_kind)
    else:
        ck = _abs(p.init_checkpoint, "checkpoint to fine-tune")
        if not ck.exists():
            raise InputError(f"the checkpoint to fine-tune does not exist: {ck}")
    return checked_header(ck)


def _vgg_encoder(cfg) -> bool:
    """A model config (dict or dataclass) whose encoder is an ImageNet VGG16 (built from the offline weights)."""
    enc = cfg.get("encoder") if isinstance(cfg, dict) else getattr(cfg, "encoder", None)
    if isinstance(enc, dict):
        return enc.get("backbone") == "vgg16" and bool(enc.get("pretrained"))
    return getattr(enc, "backbone", None) == "vgg16" and bool(getattr(enc, "pretrained", False))


def _recorded(meta: dict, key: str) -> dict:
    """A JSON section of a checkpoint's metadata ({} when it has none or it cannot be read)."""
    try:
        doc = json.loads(meta.get(key) or "{}")
    except ValueError:
        return {}
    return doc if isinstance(doc, dict) else {}


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and v > 0


def require_weights(context, why: str) -> None:
    """InputError naming the folder and the command that fills it when the offline VGG16 / LPIPS weights the
    worker will read (``worker.weights_dir``: the preferences' Weights cache, ...) are missing; before the job
    starts, instead of the worker failing after its start-up."""
    from .. import prefs as P
    from ..worker import FETCH_WEIGHTS, choose_interpreter, missing_weights, weights_dir

    pr = P.get(context)
    folder = weights_dir(choose_interpreter(pr.python_path if pr else "").path)
    if missing_weights(folder):
        raise InputError(f"{why} needs the offline VGG16 / LPIPS weights, which are not in {folder}: run "
                         f'`{FETCH_WEIGHTS} --out "{folder}"` once, or set Weights cache in the add-on preferences '
                         "to the folder it wrote them to")


def plan_from_props(context) -> TrainJob:
    """Check the Model section's settings; no side effects. MRVMError on bad input."""
    from .. import prefs as P

    p = context.scene.mrvm_train
    data = _abs(p.data_dir, "dataset folder")
    if not data.is_dir():
        raise InputError(f"dataset folder {data} does not exist (render one in the Dataset section)")
    run_dir = _abs(p.run_dir, "run folder")
    if run_dir.exists() and not run_dir.is_dir():
        raise InputError(f"run folder {run_dir} is a file")
    from ..training.run_folder import holds_run

    replace_run = not p.resume and holds_run(run_dir)
    if replace_run and not p.overwrite_run:
        raise InputError(f"the run folder {run_dir} holds a run: turn on Continue run, choose a new run folder, "
                         "or tick Replace the run to remove it and start over")
    init, base = None, {}
    running = run_config(run_dir) if p.resume else None
    if running is not None:  # continue the run in the folder: its model and its schedule
        name = str(running["model"]["config"]["name"])
        kind = str(running["model"].get("kind") or "nerformer_mrvm")
        if p.start_from == "NEW" and (name != p.preset or kind != p.model_kind):
            raise InputError(f"the run folder holds a {kind} {name!r} model; choose that model to continue it, "
                             "a new run folder, or turn off Continue run")
        model = {"kind": kind, "config": running["model"]["config"]}
        base = {k: v for k, v in running.get("train", {}).items() if k in CONTINUED_SETTINGS}
        weights = ("continuing a run with the LPIPS loss" if _positive(base.get("lpips_weight")) else
                   "continuing a run of a VGG16-encoder model" if _vgg_encoder(model["config"]) else "")
    elif p.start_from != "NEW":
        from ..models.checkpoint_files import model_name

        init, meta = init_checkpoint(p)  # fine-tune: the checkpoint's own model
        name, model = model_name(meta) or "?", {}
        lpips = p.keep_losses and _positive(_recorded(meta, "train_config").get("lpips_weight"))
        weights = ("Keep its losses (the LPIPS loss)" if lpips else
                   "fine-tuning a VGG16-encoder model" if _vgg_encoder(_recorded(meta, "model_config")) else "")
    else:
        from ..models import registry

        if p.preset not in registry.presets(p.model_kind):
            raise InputError(f"the {registry.kind(p.model_kind).title} model has no {p.preset!r} size; choose one of "
                             f"{', '.join(registry.presets(p.model_kind))}")
        name, model = p.preset, {"kind": p.model_kind, "preset": p.preset}
        vgg = _vgg_encoder(registry.presets(p.model_kind)[p.preset])
        weights = f"the {p.preset} size (a VGG16 encoder)" if vgg else ""
    if weights:
        require_weights(context, weights)
    pr = P.get(context)
    dev = (pr.device if pr else "AUTO").lower()
    return TrainJob(data, run_dir, name, model, init, base, int(p.iterations), int(p.checkpoint_every),
                    int(p.rays_per_object), bool(p.resume), dev, force=replace_run,
                    keep_losses=bool(p.keep_losses) and init is not None)


def prepare(context):
    """The worker's interpreter, after checking it has what training needs."""
    from .. import prefs as P
    from ..worker import choose_interpreter, require

    pr = P.get(context)
    interp = choose_interpreter(pr.python_path if pr else "")
    require(interp, ("torch", "safetensors", "numpy", "PIL"))
    return interp


def write_job(job: TrainJob, job_dir: Path) -> list[str]:
    """Write the run config for ``train --config``; return the worker's arguments."""
    train = {**job.continued, "data": str(job.data), "out_dir": str(job.run_dir), "iterations": job.iterations,
             "ckpt_every": job.checkpoint_every, "rays_per_object": job.rays_per_object,
             "log_every": max(1, min(10, job.checkpoint_every))}
    if job.device != "auto":
        train["device"] = job.device
    if not job.continued:
        from ..training.config import default_opacity_weight

        train["opacity_weight"] = default_opacity_weight([job.data])
    if job.init_checkpoint is not None:  # used only when the run folder has no checkpoint to resume
        train["init_checkpoint"] = str(job.init_checkpoint)  # the trainer's fine-tuning policy applies
        if job.keep_losses:
            train["keep_init_losses"] = True
    doc = {"train": train}
    if job.model:
        doc["model"] = job.model
    cfg = job_dir / "train.json"
    cfg.write_text(json.dumps(doc, indent=2) + "\n")
    args = ["--config", str(cfg)]
    if not job.resume:
        args.append("--no-resume")
        if job.force:
            args.append("--force")
    return args


@dataclass
class TrainRun:
    job: TrainJob
    summary: dict
    """The train command's last JSON line: step, checkpoint, resumed_from, world_size."""
    seconds: float


TRAIN_GRACE_S = 30.0
"""Seconds the interrupted worker gets to finish its step and save it before it is terminated (a step of the
`accurate` preset took ~4 s on the 2-core CPU, its checkpoint ~1 s)."""


def run_job(job: TrainJob, interp) -> "ProgressGen":
    """Progress generator: run the worker; return a :class:`TrainRun`. The job folder is always removed."""
    from ..worker import run_worker

    job_dir = Path(tempfile.mkdtemp(prefix="mrvm_train_"))
    try:
        args = write_job(job, job_dir)
        # Esc interrupts the child, which finishes its step and saves it: give it the time of a slow CPU step
        result = yield from run_worker(TRAIN_COMMAND, args, interp.path, grace_s=TRAIN_GRACE_S)
    finally:
        shutil.rmtree(job_dir, ignore_errors=True)
    summary = {}
    for line in reversed(result.output):
        try:
            summary = json.loads(line)
            break
        except ValueError:
            continue
    return TrainRun(job, summary if isinstance(summary, dict) else {}, result.seconds)


def on_train_result(context, run: TrainRun) -> str:
    """Pick the run for novel views (when asked) and say what was trained."""
    p = context.scene.mrvm_train
    ck = run.summary.get("checkpoint")
    if run.summary.get("resumed_from", 0) >= run.job.iterations:  # (its checkpoint: the one it was already at)
        raise InputError(f"the run in {run.job.run_dir} is already at step {run.summary['resumed_from']}; "
                         "raise Iterations to train further")
    if not ck:
        raise InputError(f"training finished but wrote no checkpoint into {run.job.run_dir}")
    msg = f"Trained to step {run.summary.get('step')} in {run.seconds:.0f} s"
    if run.summary.get("resumed_from"):
        msg += f" (continued from step {run.summary['resumed_from']})"
    elif run.summary.get("initialized_from"):
        msg += f" (fine-tuned {Path(run.summary['initialized_from']).name})"
    msg += f"; checkpoint {ck}"
    nv = getattr(context.scene, "mrvm_novel_views", None)
    if p.use_for_synthesis and nv is not None:
        nv.checkpoint = _as_setting(Path(run.job.run_dir))  # the folder trained, not the setting's text now (a
        # .blend saved elsewhere during the run moved what '//' names)
        msg += " (picked for novel views)"
    return msg


class MRVM_OT_train(ProgressOperator, bpy.types.Operator):
    """Train the novel-view model on a rendered dataset, or continue (fine-tune) a run, in the worker process"""

    bl_idname = "mrvm.train"
    bl_label = "Train / Fine-tune"
    bl_options = {"REGISTER"}

    props_attr = "mrvm_train"
    job_name = "Training"
    panel_names = {"--no-resume --force": "'Continue run' off and 'Replace the run' ticked",
                   "--no-resume": "Continue run", "--force": "Replace the run", "--iterations": "Iterations",
                   "--init": "Start from", "--keep-losses": "Keep its losses", "--out": "Run folder",
                   "--data": "Dataset", "--preset": "Size", "--model": "Model"}
    stops_softly = True  # a worker job: Esc lets it save its step in progress without blocking the UI
    cancel_hint = "the step in progress finishes and is saved as a checkpoint (train again to continue)"
    timer_interval = 0.1

    @classmethod
    def blocked(cls, context) -> str:
        from ._modal import SAVE_FIRST, unsaved_relative

        p = context.scene.mrvm_train
        if not p.data_dir.strip():
            return "Choose the Dataset to train on (render one in the Dataset section)"
        if not p.run_dir.strip():
            return "Choose a Run folder"
        if p.start_from == "CHECKPOINT" and not p.init_checkpoint.strip():
            return "Start from Checkpoint: choose the checkpoint to fine-tune (or start from the Shipped model)"
        for name, value in (("Dataset", p.data_dir), ("Run folder", p.run_dir),
                            ("Checkpoint", p.init_checkpoint if p.start_from == "CHECKPOINT" else "")):
            if unsaved_relative(value):
                return SAVE_FIRST.format(what=name)
        return ""

    def start(self, context):
        job = plan_from_props(context)
        interp = prepare(context)
        return run_job(job, interp)

    def on_result(self, context, run: TrainRun) -> str:
        return on_train_result(context, run)


classes = (MRVM_OT_train,)
