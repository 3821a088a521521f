"""Sem2NeRF training on the library's (part mask, image, pose) triples, checkpoints and evaluation.

Each step draws objects; for each, one *input view* whose part mask is encoded (one-hot + contour +
distance field, ``models/sem2nerf/inputs.py``) and ``other_views`` further views of the same object.
Every view (the input one included) is supervised on a P x P patch of rays:

- *region-aware, random-scale patches* (Sem2NeRF): a patch covers ``scale`` of the image side,
  ``scale ~ U[lo, 1]`` with ``lo`` starting at 0.9 and annealing exponentially toward 0.06, so early
  steps see whole objects and later ones fine detail; with probability ``fg_patch_prob`` the patch is
  centred on a random object pixel.
- losses: L2 on colour, LPIPS-VGG (offline weights, with gradients) on the patch, cross-entropy of the
  rendered semantic map against the true part mask, and optionally a non-saturating patch
  discriminator (``gan_weight > 0``).
- appearance: every training object owns a latent z (on the sphere of radius sqrt(z_dim), where
  random normal codes live) mapped to its style code, so the mapping network learns the library's
  appearances and random codes give plausible styles (GLO-style auto-decoding; the paper froze a
  pretrained pi-GAN instead, which we do not have).

Checkpoints are atomic (temporary folder renamed into place, then ``latest``) safetensors files whose
metadata records the format, ``model_kind: sem2nerf``, the config and ``train_image_size``; the
trainer state (optimizers, per-object codes, step, RNG) is a ``torch.load(weights_only=True)`` file.
bpy-free.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import InputError
from ..models.sem2nerf.config import MODEL_KIND, read_sem2nerf_header  # noqa: F401 (torch-free owner)
from ..progress import Progress
from .patches import bilinear, lpips_loss, sample_patch  # noqa: F401 (sample_patch: tests)


@dataclass(frozen=True)
class Sem2NeRFTrainConfig:
    """One Sem2NeRF training run."""

    data: str = ""
    """Dataset root of our format (part masks in mask/*.png, labels in meta.json)."""
    split: str = "train"
    """Split to train on."""
    max_objects: int = 0
    """Use at most this many objects (0 = all)."""
    holdout: int = 0
    """Leave out the last this-many objects of every category (held out for evaluation)."""
    out_dir: str = "runs/sem2nerf"
    """Run folder: metrics.jsonl, checkpoints/."""
    preset: str = "balanced"
    """Model preset (``fast``, ``balanced``)."""
    model_overrides: tuple[tuple[str, Any], ...] = ()
    """(field, value) overrides of the model preset."""
    seed: int = 0
    """Seed for initialisation and sampling."""
    iterations: int = 5000
    """Optimizer steps."""
    objects_per_step: int = 2
    """Objects (each with its own input mask) per step."""
    other_views: int = 1
    """Views besides the input view supervised per object and step."""
    patch_size: int = 16
    """Rays per patch side (P x P rays per supervised view)."""
    scale_start: float = 0.9
    """Initial lower bound of the patch scale range (the range starts at [scale_start, 1])."""
    scale_end: float = 0.06
    """Value the lower bound anneals toward."""
    scale_anneal_steps: float = 2000.0
    """e-folding steps of the lower bound: lo = end + (start - end) * exp(-step / this)."""
    fg_patch_prob: float = 0.8
    """Probability that a patch is centred on an object pixel (region-aware sampling)."""
    lr: float = 2e-4
    """Adam learning rate of the generator and mapping network."""
    encoder_lr: float = 1e-4
    """Adam learning rate of the mask encoder."""
    code_lr: float = 1e-3
    """Adam learning rate of the per-object latent codes."""
    l2_weight: float = 1.0
    """Weight of the colour L2 loss."""
    lpips_weight: float = 0.2
    """Weight of the LPIPS-VGG loss (0 = off; needs the offline weights)."""
    ce_weight: float = 0.1
    """Weight of the semantic cross-entropy loss."""
    input_weight: float = 1.0
    """Weight of the input view's losses relative to each other view's (items are weight-averaged)."""
    lr_end_factor: float = 1.0
    """Learning rates decay exponentially to this factor of their value at the last step (1 = constant)."""
    gan_weight: float = 0.0
    """Weight of the non-saturating patch-discriminator loss (0 = no discriminator)."""
    disc_lr: float = 2e-4
    """Adam learning rate of the patch discriminator."""
    grad_clip: float = 1.0
    """Global gradient-norm clip (0 = off)."""
    checkpoint_every: int = 500
    """Write a checkpoint every this many steps (and at the end)."""
    log_every: int = 25
    """Append a metrics.jsonl line every this many steps."""
    keep: int = 2
    """Checkpoints kept."""
    threads: int = 0
    """torch CPU threads (0 = every core but one, ``threads.auto_threads``)."""
    device: str = "cpu"
    """Torch device ('cpu', 'cuda')."""
    init_checkpoint: str = ""
    """Fine-tune: start from this Sem2NeRF checkpoint's weights (and the per-object codes it learned for the
    objects this run trains too, matched by name) with ``model_overrides`` applied to its config, instead of the
    preset at random; the optimizer starts afresh. A run folder with a checkpoint resumes from it instead: an ``init_checkpoint`` other
    than the one its run began from is then refused (it would not be used), as ``train`` refuses it."""


MAX_LR = 1.0
"""The largest learning rate a run accepts (``train.lr``'s cap too, ``training.config.MAX_LR``)."""


def train_config(**kw) -> Sem2NeRFTrainConfig:
    """A validated :class:`Sem2NeRFTrainConfig` (InputError for bad values)."""
    if "model_overrides" in kw and isinstance(kw["model_overrides"], dict):
        kw["model_overrides"] = tuple(sorted(kw["model_overrides"].items()))
    cfg = Sem2NeRFTrainConfig(**kw)
    if cfg.iterations < 1 or cfg.objects_per_step < 1 or cfg.other_views < 0 or cfg.patch_size < 2:
        raise InputError("sem2nerf: iterations >= 1, objects_per_step >= 1, other_views >= 0, patch_size >= 2")
    if not (0 < cfg.scale_end <= cfg.scale_start <= 1):
        raise InputError("sem2nerf: need 0 < scale_end <= scale_start <= 1")
    if cfg.lpips_weight > 0 and cfg.patch_size < 16:
        raise InputError("sem2nerf: LPIPS needs patch_size >= 16 (or lpips_weight 0)")
    # learning rates above 1 only diverge (1e39 is not even a float32: Adam's step crashed on it)
    for name in ("lr", "encoder_lr", "code_lr", "disc_lr"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and 0 <= v <= MAX_LR):
            raise InputError(f"sem2nerf: --{name.replace('_', '-')} must be a number between 0 and {MAX_LR:g}, "
                             f"got {v!r}")
    v = cfg.lr_end_factor
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and 0 < v <= 1):
        raise InputError(f"sem2nerf: --lr-end-factor must be a number above 0 and at most 1, got {v!r}")
    # a negative weight trained away from its target (--ce-weight -1: a loss of -0.53, exit 0), or a NaN at step 1
    # blamed on the learning rate (--input-weight -1)
    for name in ("l2_weight", "lpips_weight", "ce_weight", "input_weight", "gan_weight", "grad_clip"):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
            raise InputError(f"sem2nerf: --{name.replace('_', '-')} must be a number of 0 or more, got {v!r}")
    # checkpoint_every 0 divided by zero after config.json and metrics.jsonl were written; a negative seed was
    # numpy's traceback
    for name, low in (("checkpoint_every", 1), ("log_every", 1), ("seed", 0), ("keep", 0)):
        v = getattr(cfg, name)
        if isinstance(v, bool) or not isinstance(v, int) or v < low:
            raise InputError(f"sem2nerf: --{name.replace('_', '-')} must be a whole number of {low} or more, got {v!r}")
    return cfg


def scale_lower_bound(step: int, cfg: Sem2NeRFTrainConfig) -> float:
    """Lower bound of the patch scale range at ``step`` (exponential annealing toward scale_end)."""
    return cfg.scale_end + (cfg.scale_start - cfg.scale_end) * math.exp(-step / max(cfg.scale_anneal_steps, 1e-9))


# ------------------------------------------------------------------------------------------- data

@dataclass
class MaskedObject:
    """One object: views with images, part masks and poses."""

    name: str
    category: str
    images: np.ndarray
    """(N, H, W, 3) float32 in [0, 1] on white."""
    masks: np.ndarray
    """(N, H, W) uint8 part ids."""
    c2w: np.ndarray
    """(N, 4, 4) OpenCV camera-to-world."""
    intrinsics: list
    labels: dict
    """part id -> name (meta.json ``labels``)."""


def load_masked_object(obj_dir: Path) -> MaskedObject:
    from ..datasets import format as DF
    from ..datasets.loaders import load_ours

    scene = load_ours(obj_dir)
    ov = DF.read_object(Path(obj_dir))
    if not ov.has("mask"):
        raise InputError(f"{obj_dir}: views lack mask/*.png part masks (Sem2NeRF needs them)")
    masks = np.stack([np.asarray(ov.mask(i)) for i in range(len(ov.indices))])
    if masks.ndim != 3 or masks.shape != scene.images.shape[:3]:
        raise InputError(f"{obj_dir}: masks {masks.shape} do not match images {scene.images.shape[:3]}")
    labels = {int(k): str(v) for k, v in (ov.meta.get("labels") or {}).items()}
    labels.setdefault(0, "background")
    return MaskedObject(scene.name, scene.category, scene.images, masks.astype(np.uint8), scene.c2w,
                        scene.intrinsics, labels)


def split_holdout(dirs: list[Path], holdout: int) -> tuple[list[Path], list[Path]]:
    """(kept, held out): the last ``holdout`` object folders of every category (sorted) are held out."""
    if holdout <= 0:
        return list(dirs), []
    by_cat: dict[str, list[Path]] = {}
    for d in sorted(dirs):
        by_cat.setdefault(d.parent.name, []).append(d)
    keep, held = [], []
    for ds in by_cat.values():
        n = max(len(ds) - holdout, 1 if len(ds) > 1 else len(ds))
        keep += ds[:n]
        held += ds[n:]
    return keep, held


def load_masked_dataset(root: Path, split: str = "train", limit: int = 0, holdout: int = 0,
                        held_out: bool = False) -> list[MaskedObject]:
    from ..datasets.loaders import _check_split_name, list_ours

    root = Path(root)
    if not root.is_dir():
        raise InputError(f"dataset {root} does not exist")
    has_split = (root / "splits" / f"{split}.lst").is_file()
    if not has_split:  # a misspelt split trained (or scored) on every object, test objects included, with exit 0
        _check_split_name(root, split)
    dirs = list_ours(root, split if has_split else None)
    if not dirs:
        raise InputError(f"{root}: no objects of our format for split {split!r}")
    keep, held = split_holdout(dirs, holdout)
    dirs = held if held_out else keep
    dirs = dirs[:limit] if limit else dirs
    if not dirs:
        raise InputError(f"{root}: no objects left for split {split!r} (holdout {holdout})")
    return [load_masked_object(d) for d in dirs]


def label_table(objects: list[MaskedObject]) -> tuple[tuple[int, ...], tuple[str, ...]]:
    """Known labels (background first) and names from the objects' meta and their masks."""
    names: dict[int, str] = {0: "background"}
    for o in objects:
        for k, v in o.labels.items():
            names.setdefault(k, v)
        for k in np.unique(o.masks):
            names.setdefault(int(k), f"part_{int(k)}")
    ids = (0,) + tuple(sorted(k for k in names if k != 0))
    return ids, tuple(names[k] for k in ids)


# ------------------------------------------------------------------------------------------- patches

def gather_patch(image: np.ndarray, mask_idx: np.ndarray, px: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Bilinear colour (N, 3) and nearest part index (N,) at continuous pixel coordinates ``px``."""
    h, w = mask_idx.shape
    xi = np.clip(np.floor(px[:, 0]).astype(np.int64), 0, w - 1)
    yi = np.clip(np.floor(px[:, 1]).astype(np.int64), 0, h - 1)
    return bilinear(image, px), torch.from_numpy(mask_idx[yi, xi])


# ------------------------------------------------------------------------------------------- losses

class PatchDiscriminator(nn.Module):
    """Small conv discriminator on (B, 3, P, P) patches -> (B,) logits (LeakyReLU, no normalisation)."""

    def __init__(self, width: int = 32):
        super().__init__()
        self.net = nn.Sequential(nn.Conv2d(3, width, 3, 1, 1), nn.LeakyReLU(0.2),
                                 nn.Conv2d(width, 2 * width, 4, 2, 1), nn.LeakyReLU(0.2),
                                 nn.Conv2d(2 * width, 4 * width, 4, 2, 1), nn.LeakyReLU(0.2),
                                 nn.Conv2d(4 * width, 1, 3, 1, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x * 2 - 1).mean(dim=(1, 2, 3))


# ------------------------------------------------------------------------------------------- checkpoints

def save_checkpoint(run_dir: Path, step: int, model, train_image_size: int, trainer_state: dict | None,
                    extra_meta: dict | None = None, keep: int = 2) -> Path:
    """Atomic checkpoint ``<run>/checkpoints/step_NNNNNNN/`` (+ ``latest``) through the shared writer; returns its folder."""
    from . import checkpoint as ckpt

    meta = {"train_image_size": str(int(train_image_size)), **(extra_meta or {})}
    return ckpt.save_checkpoint(run_dir, step, model, model.cfg, trainer_state, meta, keep=keep, kind=MODEL_KIND)


def _unloaded_model(cfg):
    """A model of ``cfg`` whose weights will come from a file (no ImageNet load, no 10,000-code style mean)."""
    from ..models.sem2nerf.model import Sem2NeRF

    model = Sem2NeRF(replace(cfg, pretrained=False, style_mean_samples=1))
    model.cfg = model.field.cfg = cfg
    return model


def load_sem2nerf(path: Path, device: str = "cpu"):
    """(model, config, metadata) from a Sem2NeRF checkpoint (run folder, checkpoint folder or model file)."""
    from safetensors.torch import load_model as st_load

    from ..models.config import from_dict
    from ..models.sem2nerf.config import Sem2NeRFConfig, validate

    model_file, meta = read_sem2nerf_header(path)
    cfg = validate(from_dict(Sem2NeRFConfig, json.loads(meta["model_config"])))
    model = _unloaded_model(cfg)
    try:
        st_load(model, str(model_file), strict=True, device=device)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"checkpoint {model_file} does not match its config: {first[:300]}") from None
    from .checkpoint import _check_finite

    _check_finite(model, model_file)  # (the style mean too: a buffer)
    model.checkpoint_file = model_file  # named when its renders come out NaN (models.base.check_finite_view)
    return model.to(device).eval(), cfg, meta


# ------------------------------------------------------------------------------------------- training

def code_styles(model, codes: torch.Tensor) -> torch.Tensor:
    """Style codes of training objects' latent codes (B, z_dim): each projected onto the sphere of radius
    sqrt(z_dim), where random normal codes live, then through the mapping network."""
    zs = codes / codes.norm(dim=-1, keepdim=True).clamp_min(1e-8) * math.sqrt(model.cfg.z_dim)
    return model.style(zs)


NEW_HEADS = ("field.style_part_rgb.",)
"""Parameters a fine-tuning run may add to an older checkpoint's model (zero-initialised heads)."""


def init_model(path, overrides: dict[str, Any], device: str = "cpu", objects: list[str] | None = None):
    """(model, config, codes or None) to fine-tune from a Sem2NeRF checkpoint: its config with ``overrides``
    applied (e.g. ``style_part_colours=true``), its weights, and heads the overrides add (:data:`NEW_HEADS`)
    at their zero start; the per-object codes of its trainer state when it has one. InputError when the
    overrides change the shape of a weight it has.

    With ``objects`` (the fine-tuning run's ``category/name`` list) the codes are a list, one entry per object:
    the code the checkpoint learned for that object, or None for an object it did not train (matched by the
    names its trainer state records, :func:`object_names`; a state that records none is matched by position
    when the counts agree), so no object takes another's style."""
    from safetensors.torch import load_file

    from ..models.checkpoint_files import STATE_FILE
    from ..models.config import from_dict, merge
    from ..models.sem2nerf.config import Sem2NeRFConfig, validate

    model_file, meta = read_sem2nerf_header(Path(path))
    cfg = validate(merge(from_dict(Sem2NeRFConfig, json.loads(meta["model_config"])), overrides))
    model = _unloaded_model(cfg)
    try:
        res = model.load_state_dict(load_file(str(model_file), device="cpu"), strict=False)
    except RuntimeError as e:
        first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(f"init checkpoint {model_file} does not fit the overridden model: {first[:300]}") from None
    lost = [k for k in res.missing_keys if not k.startswith(NEW_HEADS)] + list(res.unexpected_keys)
    if lost:
        raise InputError(f"init checkpoint {model_file} does not fit the overridden model (weights {lost[:3]})")
    state = model_file.parent / STATE_FILE
    st = torch.load(state, map_location="cpu", weights_only=True) if state.is_file() else None
    codes = st["codes"] if st is not None else None
    if objects is not None and codes is not None:
        theirs = st.get("objects")
        if theirs is None:  # an older state: by position, only when the counts agree
            theirs = [str(i) for i in range(len(codes))] if len(codes) == len(objects) else []
            objects = [str(i) for i in range(len(objects))]
        at = {str(n): i for i, n in enumerate(theirs)}
        codes = [codes[at[n]] if n in at else None for n in objects]
    return model.to(device), cfg, codes


def object_names(objects: list[MaskedObject]) -> list[str]:
    """``category/name`` of each training object, in the order of its style code (recorded in the trainer state:
    a resume or a fine-tune gives every learned code back to its own object)."""
    return [f"{o.category}/{o.name}" for o in objects]


def _check_same_objects(out: Path, ck: Path, recorded: list | None, names: list[str], n_codes: int) -> None:
    """InputError when a resume's objects are not those the run in ``out`` learned its per-object style codes
    for (the same count of other objects took them silently, each the code of the object at its place before)."""
    if recorded is None:  # a state from before the names were recorded: the count at least
        if n_codes != len(names):
            raise InputError(f"run {out} was trained on {n_codes} objects, this data has {len(names)}")
        return
    recorded = [str(n) for n in recorded]
    if recorded == names:
        return
    i = next((i for i, (a, b) in enumerate(zip(recorded, names)) if a != b), min(len(recorded), len(names)))
    if i < len(recorded) and i < len(names):
        what = f"its object {i + 1} is {recorded[i]}, this data's is {names[i]}"
    elif i < len(recorded):
        what = f"this data has only {len(names)}, not its object {i + 1} ({recorded[i]})"
    else:
        what = f"this data has {len(names) - len(recorded)} more, the first {names[i]}"
    raise InputError(f"the run in {out} ({ck.name}) learned style codes for its {len(recorded)} objects, but {what}: "
                     "resume it on the same objects (its --data, --split, --holdout, --max-objects), start over with "
                     "--no-resume --force, or give another --out")


IGNORED_MODEL_FIELDS = ("name", "labels", "label_names", "image_size")
"""Model config fields a resume does not compare with its options: the preset's name (informational) and what the
data decide (checked on their own)."""


def _model_flags(mcfg) -> str:
    """'--preset fast --model n_coarse=6 ...': the options that build ``mcfg`` (for messages)."""
    from ..models.config import to_dict
    from ..models.sem2nerf.config import PRESETS

    base = PRESETS.get(mcfg.name)
    if base is None:
        return "the --preset and --model it began with"
    have, ref = to_dict(mcfg), to_dict(base)
    return " ".join([f"--preset {mcfg.name}"] + [_model_flag(k, v) for k, v in have.items()
                                                 if k not in IGNORED_MODEL_FIELDS and v != ref.get(k)])


def _model_flag(key: str, value) -> str:
    return f"--model {key}={_word(value)}"


def _word(value) -> str:
    """A config value as ``--model`` takes it (``true``, not ``True``)."""
    return str(value).lower() if isinstance(value, bool) else str(value)


def _check_same_model(out: Path, ck: Path, mcfg, cfg: Sem2NeRFTrainConfig, from_init: bool) -> None:
    """InputError when a resume asks for another model than the run in ``out`` trains (``--preset``, ``--model``):
    the run goes on as its checkpoint's model, so config.json would have recorded options that were not used (as
    ``train`` refuses a resume whose model does not fit the run's). A run fine-tuned from a checkpoint (``from_init``)
    is its checkpoint's model: only its ``--model`` overrides are compared."""
    from ..models.config import merge, to_dict
    from ..models.sem2nerf.config import sem2nerf_config, validate

    overrides = dict(cfg.model_overrides)
    if from_init:
        want = validate(merge(mcfg, overrides))
        asked, how = "--model", "without --model"
    else:
        want = sem2nerf_config(cfg.preset, overrides, image_size=mcfg.image_size, labels=mcfg.labels,
                               label_names=mcfg.label_names)
        asked = " ".join([f"--preset {cfg.preset}"] + [_model_flag(k, v) for k, v in overrides.items()])
        how = _model_flags(mcfg)
    have, got = to_dict(mcfg), to_dict(want)
    diff = [(k, have[k], got.get(k)) for k in have if k not in IGNORED_MODEL_FIELDS and have[k] != got.get(k)]
    if not from_init and cfg.preset != mcfg.name:  # (also when --model overrides make the two presets alike)
        diff.insert(0, ("preset", mcfg.name, cfg.preset))
    if diff:
        k, a, b = diff[0]
        more = f" and {len(diff) - 1} more setting(s)" if len(diff) > 1 else ""
        raise InputError(f"the run in {out} ({ck.name}) trains a sem2nerf model with {k}={_word(a)}; this start "
                         f"({asked}) asks for {k}={_word(b)}{more}, which would not be used: continue it with its own "
                         f"model ({how}), start over with --no-resume --force, or give another --out")


def _normalized_rays(intr, c2w, px: np.ndarray, box: float):
    from ..models.rays import make_rays, normalize_pose

    return make_rays(intr, normalize_pose(c2w, np.zeros(3), box), px, box=1.0)


def train(cfg: Sem2NeRFTrainConfig, resume: bool = True, objects: list[MaskedObject] | None = None,
          force: bool = False):
    """Progress generator: trains, writes checkpoints and metrics.jsonl; returns a summary dict.

    ``resume``: continue from the run folder's newest checkpoint (its metrics past that step are dropped). A
    resume must continue that run as it is: the same objects (their learned style codes), the same model
    (``--preset``, ``--model``), the ``--init`` it began from or none, and ``iterations`` not below its step;
    anything else is refused before anything is written. Without it, a run folder that holds a run is refused
    unless ``force``, which removes that run first (``run_folder.resume_point``, as ``train --no-resume --force``).

    The run folder is held (``guards.output_lock``) from before its state is read until the run ends, as ``train``
    holds it: a second training into it is refused instead of both writing checkpoints and metrics; the
    temporary folders of checkpoint saves a killed run left half-way are removed under it."""
    from ..guards import output_lock, sweep_partials

    with output_lock(Path(cfg.out_dir), "run folder"):
        sweep_partials(Path(cfg.out_dir) / "checkpoints", ".step_*")
        return (yield from _train(cfg, resume, objects, force))


def _train(cfg: Sem2NeRFTrainConfig, resume: bool, objects: list[MaskedObject] | None, force: bool):
    from ..models.checkpoint_files import STATE_FILE, find_checkpoint
    from ..models.sem2nerf.config import sem2nerf_config
    from ..models.sem2nerf.inputs import build_inputs, to_index
    from ..models.sem2nerf.model import Sem2NeRF
    from ..threads import set_torch_threads

    threads = set_torch_threads(cfg.threads)
    dev = torch.device(cfg.device)
    out = Path(cfg.out_dir)
    if objects is None:
        if not cfg.data:
            raise InputError("no dataset: give --data")
        objects = load_masked_dataset(Path(cfg.data), cfg.split, cfg.max_objects, cfg.holdout)
    sizes = {o.images.shape[1:3] for o in objects}
    if len(sizes) != 1:
        raise InputError(f"objects have different image sizes {sorted(sizes)}")
    (h, w), = sizes
    if h != w:
        raise InputError(f"Sem2NeRF trains on square images; these are {w}x{h}")
    labels, names = label_table(objects)
    obj_names = object_names(objects)

    ck = find_checkpoint(out) if resume and out.exists() else None
    torch.manual_seed(cfg.seed)
    init_codes = None
    st = None
    if ck is not None:  # a resume continues the run as it is, or is refused before anything is written
        from . import run_folder
        from .config import recorded_train
        from .trainer import _check_continues, _keep_recorded_seed

        _check_continues(out, ck, cfg, None)  # an --init it did not begin from would not be used
        cfg = _keep_recorded_seed(out, Path(ck), cfg, True)  # (its generators resume from the checkpoint)
        began = (recorded_train(out) or {}).get("init_checkpoint") or ""
        if began and not cfg.init_checkpoint:  # config.json keeps what the run began from
            cfg = replace(cfg, init_checkpoint=str(began))
        st = torch.load(Path(ck) / STATE_FILE, map_location="cpu", weights_only=True)
        _check_same_objects(out, ck, st.get("objects"), obj_names, st["codes"].shape[0])
        run_folder.check_not_past(out, ck, int(st["step"]), cfg.iterations, "--iterations")
    if ck is not None or cfg.init_checkpoint:
        if ck is not None:
            model, mcfg, _ = load_sem2nerf(ck, cfg.device)
            _check_same_model(out, ck, mcfg, cfg, from_init=bool(cfg.init_checkpoint))
        else:
            model, mcfg, init_codes = init_model(cfg.init_checkpoint, dict(cfg.model_overrides), cfg.device,
                                                 objects=obj_names)
        src = f"run {out}" if ck is not None else f"init checkpoint {cfg.init_checkpoint}"
        if mcfg.image_size != h:
            raise InputError(f"{src} was trained at {mcfg.image_size} px; this data is {h} px")
        missing = set(labels) - set(mcfg.labels)
        if missing:
            raise InputError(f"{src} does not know label id(s) {sorted(missing)} of this data")
        labels, names = mcfg.labels, mcfg.label_names
    else:
        overrides = dict(cfg.model_overrides)
        mcfg = sem2nerf_config(cfg.preset, overrides, image_size=h, labels=labels, label_names=names)
        model = Sem2NeRF(mcfg).to(dev)
    model.train()
    n_obj = len(objects)
    codes = nn.Parameter(torch.randn(n_obj, mcfg.z_dim, device=dev))
    gen_params = list(model.field.parameters()) + list(model.mapping.parameters())
    opt = torch.optim.Adam([{"params": gen_params, "lr": cfg.lr},
                            {"params": model.encoder.parameters(), "lr": cfg.encoder_lr},
                            {"params": [codes], "lr": cfg.code_lr}], betas=(0.0 if cfg.gan_weight > 0 else 0.9, 0.999))
    disc = d_opt = None
    if cfg.gan_weight > 0:
        disc = PatchDiscriminator().to(dev)
        d_opt = torch.optim.Adam(disc.parameters(), lr=cfg.disc_lr, betas=(0.0, 0.99))
    start = 0
    rng = np.random.default_rng(cfg.seed)
    if init_codes is not None:  # the objects it trained keep their styles (by name: never another object's)
        with torch.no_grad():
            for i, c in enumerate(init_codes):
                if c is not None and c.shape == codes[i].shape:
                    codes[i] = c.to(dev)
    lp = None
    if cfg.lpips_weight > 0:  # before the resumed RNG state is set: building its layers draws from torch's generator
        # (built after it, a resumed run's draws differed from the uninterrupted run's from the first step on)
        from ..models.metrics import LPIPS

        lp = LPIPS().to(dev)
    if st is not None:
        with torch.no_grad():
            codes.copy_(st["codes"].to(dev))
        opt.load_state_dict(st["opt"])
        for group, lr in zip(opt.param_groups, (cfg.lr, cfg.encoder_lr, cfg.code_lr)):
            group["lr"] = lr  # the run config's learning rates apply to a resumed run
        if disc is not None and "disc" in st:
            disc.load_state_dict(st["disc"])
            d_opt.load_state_dict(st["d_opt"])
        start = int(st["step"])
        rng.bit_generator.state = json.loads(st["rng"])
        torch.set_rng_state(st["torch_rng"])
    from . import run_folder

    if resume:  # the metrics a killed run wrote past its checkpoint are written again below
        run_folder.trim_metrics(out / "metrics.jsonl", start)
    else:  # never mixed with an old run's checkpoints and metrics: refused, or (force) removed first
        run_folder.resume_point(out, resume=False, force=force)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps({"train": {k: v for k, v in cfg.__dict__.items()},
                                                 "labels": list(labels), "label_names": list(names)},
                                                indent=2, default=list) + "\n")
    from .provenance import append_record, environment, init_record, scenes_digest

    record = {"start_step": start, "resumed_from": str(ck) if ck else None, "init_checkpoint": init_record(cfg.init_checkpoint),
              "seed": cfg.seed, "iterations": cfg.iterations,
              "data": {"root": str(Path(cfg.data).expanduser().resolve()) if cfg.data else None, "split": cfg.split,
                       "holdout": cfg.holdout, "max_objects": cfg.max_objects, **scenes_digest(objects)},
              "train_config": dict(cfg.__dict__),  # this start's (config.json holds the latest start's only)
              **environment(threads, str(dev))}
    append_record(out, record)  # what repeating the run needs and config.json does not say (training/provenance.py)
    index_cache: dict[tuple[int, int], np.ndarray] = {}
    input_cache: dict[tuple[int, int], torch.Tensor] = {}

    def idx_of(o: int, v: int) -> np.ndarray:
        if (o, v) not in index_cache:
            index_cache[(o, v)] = to_index(objects[o].masks[v], labels, f"{objects[o].name} view {v}")
        return index_cache[(o, v)]

    def inputs_of(o: int, v: int) -> torch.Tensor:
        if (o, v) not in input_cache:
            input_cache[(o, v)] = torch.from_numpy(build_inputs(objects[o].masks[v], labels))
        return input_cache[(o, v)]

    def trained(done: int) -> None:  # TrainingStopped when the update left diverged weights (never saved)
        run_folder.check_weights(model, done, last_ck or ck, {"codes": codes, **({} if disc is None else {
            f"disc.{k}": v for k, v in disc.state_dict().items()})})

    def save(done: int) -> Path:
        model.update_style_mean()
        trained(done)  # (the style mean too: the mean of the mapping network's outputs)
        state = {"step": done, "codes": codes.detach().cpu(), "opt": opt.state_dict(),
                 "rng": json.dumps(rng.bit_generator.state), "torch_rng": torch.get_rng_state(),
                 "objects": obj_names}
        if disc is not None:
            state["disc"] = disc.state_dict()
            state["d_opt"] = d_opt.state_dict()
        # train_config: the whole train record (config.json's), under the key the other kinds' checkpoints use, so a
        # run whose config.json is lost still knows the --init it began from (training.config.recorded_train);
        # `train` (the four fields checkpoints recorded before) is kept for whoever reads it
        return save_checkpoint(out, done, model, h, state, keep=cfg.keep,
                               extra_meta={"train": {"data": cfg.data, "split": cfg.split,
                                                     "iterations": cfg.iterations, "gan_weight": cfg.gan_weight},
                                           "train_config": json.dumps(dict(cfg.__dict__), default=list),
                                           "provenance": json.dumps(record, default=str)})

    P = cfg.patch_size
    last_ck = None
    saved_at = start  # the step of the newest checkpoint on disk
    t0 = time.time()
    metrics_f = open(out / "metrics.jsonl", "a")
    try:
        for step in range(start, cfg.iterations):
            lo = scale_lower_bound(step, cfg)
            obj_ids = rng.choice(n_obj, size=cfg.objects_per_step, replace=n_obj < cfg.objects_per_step)
            enc_intr, enc_cam, enc_in, item_obj, item_w, o_list, d_list, f_list, h_list, gt_rgb, gt_idx = ([] for _ in range(11))
            for j, o in enumerate(obj_ids):
                ob = objects[o]
                nv = len(ob.images)
                vin = int(rng.integers(nv))
                enc_in.append(inputs_of(o, vin))
                enc_cam.append(ob.c2w[vin])
                enc_intr.append(ob.intrinsics[vin])
                others = [v for v in range(nv) if v != vin]
                pick = list(rng.choice(others, size=min(cfg.other_views, len(others)), replace=False)) if others else []
                for v in [vin] + [int(x) for x in pick]:
                    scale = float(rng.uniform(lo, 1.0))
                    px = sample_patch(rng, ob.masks[v], P, scale, cfg.fg_patch_prob)
                    b = _normalized_rays(ob.intrinsics[v], ob.c2w[v], px, mcfg.scene_box)
                    rgb, idx = gather_patch(ob.images[v], idx_of(o, v), px)
                    item_obj.append(j)
                    item_w.append(cfg.input_weight if v == vin else 1.0)
                    o_list.append(b.origins)
                    d_list.append(b.dirs)
                    f_list.append(b.far)
                    h_list.append(b.hit)
                    gt_rgb.append(rgb)
                    gt_idx.append(idx)
            enc = torch.stack(enc_in).to(dev)
            mask_code = model.encode(enc, np.stack(enc_cam), enc_intr)
            style = code_styles(model, codes[torch.as_tensor(obj_ids, device=dev)])
            sel = torch.as_tensor(item_obj, device=dev)
            res = model.render_rays(torch.stack(o_list), torch.stack(d_list), torch.stack(f_list), torch.stack(h_list),
                                    mask_code[sel], style[sel], perturb=True)
            B = len(item_obj)
            gt = torch.stack(gt_rgb).to(dev)
            gi = torch.stack(gt_idx).to(dev)
            wts = torch.as_tensor(item_w, dtype=torch.float32, device=dev)
            wts = wts / wts.sum()
            l2 = (((res["rgb"] - gt) ** 2).mean(dim=(1, 2)) * wts).sum()
            ce = (F.nll_loss(res["semantic"].reshape(-1, mcfg.n_labels), gi.reshape(-1), reduction="none")
                  .view(B, -1).mean(1) * wts).sum()
            loss = cfg.l2_weight * l2 + cfg.ce_weight * ce
            pred_img = res["rgb"].view(B, P, P, 3).permute(0, 3, 1, 2)
            gt_img = gt.view(B, P, P, 3).permute(0, 3, 1, 2)
            lpv = torch.zeros(())
            if lp is not None:
                lpv = lpips_loss(lp, pred_img, gt_img)
                loss = loss + cfg.lpips_weight * lpv
            g_adv = d_loss = torch.zeros(())
            if disc is not None:
                g_adv = F.softplus(-disc(pred_img)).mean()
                loss = loss + cfg.gan_weight * g_adv
            # before the updates: a NaN never reaches the weights (steps counted from 1, as `train` counts them)
            run_folder.check_loss(float(loss.detach()), step + 1, last_ck or ck)
            decay = cfg.lr_end_factor ** (step / max(cfg.iterations - 1, 1))
            for group, lr in zip(opt.param_groups, (cfg.lr, cfg.encoder_lr, cfg.code_lr)):
                group["lr"] = lr * decay
            opt.zero_grad(set_to_none=True)
            loss.backward()
            if cfg.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(list(model.parameters()) + [codes], cfg.grad_clip)
            opt.step()
            if disc is not None:
                d_opt.zero_grad(set_to_none=True)
                d_loss = F.softplus(-disc(gt_img)).mean() + F.softplus(disc(pred_img.detach())).mean()
                d_loss.backward()
                d_opt.step()
            done = step + 1
            trained(done)
            if done % cfg.log_every == 0 or done == cfg.iterations:
                psnr = float(-10 * torch.log10(l2.detach().clamp_min(1e-10)))
                rec = {"step": done, "loss": float(loss.detach()), "l2": float(l2.detach()), "psnr": psnr,
                       "lpips": float(lpv.detach()), "ce": float(ce.detach()), "g_adv": float(g_adv.detach()),
                       "d_loss": float(d_loss.detach()), "scale_lo": lo,
                       "elapsed_s": round(time.time() - t0, 1)}
                metrics_f.write(json.dumps(rec) + "\n")
                metrics_f.flush()
            if done % cfg.checkpoint_every == 0 or done == cfg.iterations:
                last_ck, saved_at = save(done), done
            try:
                yield Progress(done, cfg.iterations, f"loss {loss.item():.4f} l2 {l2.item():.4f} ce {ce.item():.3f}")
            except GeneratorExit:  # closed between steps (Ctrl-C, Esc): the finished steps are kept
                if saved_at != done:
                    last_ck = save(done)
                    print(f"sem2nerf train: stopped after step {done} of {cfg.iterations}; checkpoint {last_ck} "
                          "(the same command resumes from it)", file=sys.stderr, flush=True)
                raise
    finally:
        metrics_f.close()
    newest = last_ck if last_ck else ck  # (a rerun of a finished run saves nothing: the checkpoint it found)
    return {"step": cfg.iterations, "checkpoint": str(newest) if newest else None,
            "resumed_from": str(ck) if ck else None, "labels": list(labels), "objects": n_obj}


# ------------------------------------------------------------------------------------------- evaluation

def category_mean_images(objects: list[MaskedObject]) -> dict[str, np.ndarray]:
    """Per category: the per-pixel mean object colour over every view of every object ((H, W, 3);
    pixels no object covers get the category's overall mean object colour)."""
    acc: dict[str, list] = {}
    for o in objects:
        fg = (o.masks > 0)[..., None].astype(np.float64)
        s = (o.images * fg).sum(0)
        n = fg.sum(0)
        if o.category in acc:
            acc[o.category][0] += s
            acc[o.category][1] += n
        else:
            acc[o.category] = [s, n]
    out = {}
    for cat, (s, n) in acc.items():
        overall = s.reshape(-1, 3).sum(0) / max(n.sum(), 1.0)
        out[cat] = np.where(n > 0, s / np.maximum(n, 1.0), overall).astype(np.float32)
    return out


def category_mean_photos(objects: list[MaskedObject]) -> dict[str, np.ndarray]:
    """Per category: the per-pixel mean of every view of every object, background included ((H, W, 3)): the
    baseline that knows nothing of the object it is shown (no mask, no pose)."""
    acc: dict[str, list] = {}
    for o in objects:
        s = acc.setdefault(o.category, [0.0, 0])
        s[0] = s[0] + o.images.astype(np.float64).sum(0)
        s[1] += len(o.images)
    return {cat: (s / n).astype(np.float32) for cat, (s, n) in acc.items()}


def miou(gt: np.ndarray, pred: np.ndarray) -> float:
    """Mean IoU over the labels present in either map (background included)."""
    ious = []
    for lab in np.union1d(np.unique(gt), np.unique(pred)):
        a, b = gt == lab, pred == lab
        ious.append((a & b).sum() / max((a | b).sum(), 1))
    return float(np.mean(ious)) if ious else 1.0


def _edit_locality(model, cfg, ob: MaskedObject, v_in: int, code: torch.Tensor) -> dict:
    """Remove the smallest part of the input mask (relabel it background) and measure how much the
    rendered input view changes near the edited region (within r = size / 16 px) and far from it."""
    from scipy import ndimage

    from ..models.sem2nerf.inputs import build_inputs

    m = ob.masks[v_in]
    parts, counts = np.unique(m[m > 0], return_counts=True)
    if len(parts) < 2:
        return {"object": f"{ob.category}/{ob.name}", "edited": None}
    src = int(parts[np.argmin(counts)])
    edited = np.where(m == src, 0, m).astype(np.uint8)
    style = model.default_style()
    with torch.no_grad():
        code_e = model.encode(torch.from_numpy(build_inputs(edited, cfg.labels))[None], ob.c2w[v_in][None],
                              ob.intrinsics[v_in])
    a = model.render_image(ob.intrinsics[v_in], ob.c2w[v_in], code, style)["rgb"].numpy()
    b = model.render_image(ob.intrinsics[v_in], ob.c2w[v_in], code_e, style)["rgb"].numpy()
    r = max(2, cfg.image_size // 16)
    near = ndimage.distance_transform_edt(m != src) <= r
    change = np.abs(a - b).mean(-1)
    return {"object": f"{ob.category}/{ob.name}", "edited": src, "edited_px": int((m == src).sum()), "radius_px": r,
            "near_change": float(change[near].mean()), "far_change": float(change[~near].mean()) if (~near).any() else 0.0}


def _style_blend(model, ob: MaskedObject, v_in: int, code, steps: int = 5, seeds: tuple[int, int] = (1, 2)) -> dict:
    """Render the input view along the linear blend between the styles of two seeds: the images should
    move monotonically away from the first end and toward the second (mean absolute differences)."""
    with torch.no_grad():
        s0, s1 = model.style_from_seed(seeds[0]), model.style_from_seed(seeds[1])
    imgs = [model.render_image(ob.intrinsics[v_in], ob.c2w[v_in], code, (1 - a) * s0 + a * s1)["rgb"].numpy()
            for a in np.linspace(0.0, 1.0, steps)]
    d0 = [float(np.abs(im - imgs[0]).mean()) for im in imgs]
    d1 = [float(np.abs(im - imgs[-1]).mean()) for im in imgs]
    mono = all(x < y for x, y in zip(d0, d0[1:])) and all(x > y for x, y in zip(d1, d1[1:]))
    return {"object": f"{ob.category}/{ob.name}", "seeds": list(seeds), "from_start": d0, "to_end": d1,
            "monotonic": bool(mono)}


def _summarise_edits(rows: list[dict]) -> dict:
    rows = [r for r in rows if r.get("edited") is not None]
    if not rows:
        return {"n_objects": 0}
    near = float(np.mean([r["near_change"] for r in rows]))
    far = float(np.mean([r["far_change"] for r in rows]))
    return {"n_objects": len(rows), "edit": "smallest part of the input mask -> background",
            "near_change": near, "far_change": far, "far_over_near": far / near if near > 0 else None}


EVAL_FILES = ("eval_grid.png",)
"""What :func:`evaluate` writes into its output folder that a rerun may replace without --force (not an earlier
``eval.json``, as with ``eval``)."""


def evaluate(checkpoint: Path, data: Path, out: Path, split: str = "train", holdout: int = 0, max_objects: int = 0,
             input_view: int = 0, views_every: int = 3, threads: int = 0, blend_objects: int = 3):
    """Progress generator over objects; writes ``out/eval.json`` and returns its dict.

    For every evaluated object the mask of ``input_view`` is encoded and the input view plus every
    ``views_every``-th other view are rendered with the mean style. Scored per view: PSNR, SSIM,
    LPIPS-VGG against the rendered ground truth, the same for the baseline (the category's mean
    object image, masked by the true mask of that view: in novel views it knows the true silhouette, which
    the model must infer) and for the category's mean photo (``base_free_*``: no mask, no pose), and the mIoU between the true part mask and
    the rendered semantic map (in the input view: the input mask itself). ``eval_grid.png`` shows, per
    object (first 16): input mask | true, rendered and semantic input view | the same for the first
    novel view. Also: editing locality (every object) and style-blend monotonicity (the first
    ``blend_objects`` objects)."""
    from ..models import metrics as M
    from .evaluate import scores_against
    from ..models.sem2nerf.inputs import build_inputs

    if views_every < 1:
        raise InputError("--views-every must be >= 1")
    from ..threads import set_torch_threads

    n_threads = set_torch_threads(threads)
    model, cfg, meta = load_sem2nerf(checkpoint)
    if holdout > 0:
        evals = load_masked_dataset(Path(data), split, max_objects, holdout, held_out=True)
        base_objs = load_masked_dataset(Path(data), split, 0, holdout)
    else:
        evals = load_masked_dataset(Path(data), split, max_objects)
        base_objs = load_masked_dataset(Path(data), "train", 0)
    short = [ob.name for ob in evals if input_view >= len(ob.images)]
    if short:  # it read view input_view % n, while eval.json recorded input_view
        raise InputError(f"--input-view {input_view}: {short[0]} has only {len(next(o for o in evals if o.name == short[0]).images)} "
                         f"views{f' ({len(short) - 1} more objects too)' if len(short) > 1 else ''}")
    means = category_mean_images(base_objs)
    photos = category_mean_photos(base_objs)
    lp = M.LPIPS()
    labels_t = torch.as_tensor(cfg.labels)
    per_view = []
    edit_rows = []
    blend_rows: list[dict] = []
    grid_rows: list[np.ndarray] = []
    t0 = time.time()
    for k, ob in enumerate(evals):
        if ob.images.shape[1:3] != (cfg.image_size, cfg.image_size):
            raise InputError(f"{ob.name}: images are not {cfg.image_size} px like the checkpoint's training images")
        v_in = input_view
        with torch.no_grad():
            code = model.encode(torch.from_numpy(build_inputs(ob.masks[v_in], cfg.labels))[None], ob.c2w[v_in][None],
                                ob.intrinsics[v_in])
        views = [v_in] + [v for v in range(len(ob.images)) if v != v_in and (v - v_in) % views_every == 0]
        row: list[np.ndarray] = []
        for v in views:
            img = model.render_image(ob.intrinsics[v], ob.c2w[v], code, model.default_style())
            pred = img["rgb"].clamp(0, 1).numpy()
            gt = ob.images[v]
            fg = ob.masks[v] > 0
            base = np.where(fg[..., None], means.get(ob.category, np.full_like(gt, 0.5)), 1.0).astype(np.float32)
            sem = labels_t[img["semantic"].argmax(-1)].numpy()
            sc = scores_against(gt, {"": pred, "base_": base,
                                     "base_free_": photos.get(ob.category, np.full_like(gt, 1.0))}, lp)
            per_view.append({
                "object": f"{ob.category}/{ob.name}", "category": ob.category, "view": int(v), "input_view": v == v_in,
                **{f"{k}{m}": sc[k][m] for k in ("", "base_", "base_free_") for m in ("psnr", "ssim", "lpips")},
                "miou": miou(ob.masks[v], sem),
                "fg_iou": float((fg & (sem > 0)).sum() / max((fg | (sem > 0)).sum(), 1))})
            if len(grid_rows) < 16 and (v == v_in or len(row) < 6):
                from ..models.sem2nerf.render import colorize

                row += ([colorize(ob.masks[v])] if v == v_in else []) + [
                    (gt * 255).round().astype(np.uint8), (pred * 255).round().astype(np.uint8),
                    colorize(sem.astype(np.uint8))]
        if row:
            grid_rows.append(np.concatenate(row[:7], 1))
        edit_rows.append(_edit_locality(model, cfg, ob, v_in, code))
        if k < blend_objects:
            blend_rows.append(_style_blend(model, ob, v_in, code))
        yield Progress(k + 1, len(evals), ob.name)

    def summarise(rows):
        keys = ("psnr", "ssim", "lpips", "base_psnr", "base_ssim", "base_lpips", "base_free_psnr", "base_free_ssim",
                "base_free_lpips", "miou", "fg_iou")
        return {"n_views": len(rows), **{key: float(np.mean([r[key] for r in rows])) for key in keys}} if rows else {}

    res = {"checkpoint": str(checkpoint), "step": meta.get("step"), "data": str(data), "split": split,
           "holdout": holdout, "objects": len(evals), "input_view": input_view, "views_every": views_every,
           "style": "mean", "elapsed_s": round(time.time() - t0, 1),
           "overall": {"input_view": summarise([r for r in per_view if r["input_view"]]),
                       "novel_views": summarise([r for r in per_view if not r["input_view"]])},
           "per_category": {c: {"input_view": summarise([r for r in per_view if r["category"] == c and r["input_view"]]),
                                "novel_views": summarise([r for r in per_view if r["category"] == c and not r["input_view"]])}
                            for c in sorted({r["category"] for r in per_view})},
           "edit_locality": _summarise_edits(edit_rows),
           "style_blend": {"n_objects": len(blend_rows), "steps": 5,
                           "monotonic": sum(r["monotonic"] for r in blend_rows),
                           "end_to_end_change": float(np.mean([r["from_start"][-1] for r in blend_rows]))
                           if blend_rows else None, "per_object": blend_rows},
           "per_view": per_view, "per_object_edits": edit_rows}
    from .provenance import environment, file_sha256, scenes_digest

    model_file = read_sem2nerf_header(checkpoint)[0]
    res["provenance"] = {**environment(n_threads, "cpu", when=False), "data": scenes_digest(evals),
                         "checkpoint": {"file": str(Path(model_file).resolve()), "sha256": file_sha256(model_file)}}
    Path(out).mkdir(parents=True, exist_ok=True)
    from ..datasets.format import atomic_write_text
    from .evaluate import report_json

    atomic_write_text(Path(out) / "eval.json", report_json(res) + "\n")  # (valid JSON: null, never NaN)
    if grid_rows:
        from ..datasets.format import write_png

        width = max(r.shape[1] for r in grid_rows)
        grid = np.concatenate([np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0)), constant_values=255)
                               for r in grid_rows], 0)
        write_png(Path(out) / "eval_grid.png", grid)
    return res
