"""Training run config (frozen dataclass) and the JSON run-config file read by ``train --config``.

A run config file is JSON::

    {"model": {"kind": "nerformer_mrvm", "preset": "balanced", "overrides": {...}},
     "train": {"data": "path/to/dataset", "iterations": 20000, ...}}

``kind`` is a model kind of ``models/registry.py`` (default ``nerformer_mrvm``); instead of a preset
the model section may hold a whole ``config`` (as saved in checkpoints and run folders).
"""

from __future__ import annotations

import math

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..models.config import from_dict, merge, to_dict


@dataclass(frozen=True)
class TrainConfig:
    """One training run (checked when built: a bad value is a one-line InputError naming the field)."""

    config_label = "train"  # not a field: how messages name the fields ("train.lr")

    data: str | tuple[str, ...] = ""
    """Dataset root (ours, SRN, NMR/DVR or NeRF-synthetic), or a list of roots whose objects are pooled
    (e.g. a turntable and a sphere-rig rendering: objects are drawn uniformly from all of them). Every root
    is read with ``data_format`` and ``split``; :func:`data_roots` is the one reader of this field."""
    data_weights: tuple[float, ...] = ()
    """With several roots in ``data``: each dataset's share of the objects drawn (normalised), e.g. (2, 1) for
    two turntable draws per sphere-rig draw; () draws every object alike, so datasets count by their size."""
    data_format: str = ""
    """Dataset format; '' detects it."""
    split: str = "train"
    """Split to train on."""
    max_objects: int = 0
    """Use at most this many objects of each dataset (0 = all)."""
    image_size: int = 0
    """Train at this many pixels on each view's longer side (0 = as rendered): every view is resized when it is
    loaded, whatever the format (``datasets.loaders.resize_scene``: colours by area, object masks conservatively,
    depth maps by the nearest valid sample, the cameras scaled exactly), so a 1024 px dataset trains at 128 px
    without re-rendering. Larger than the views is refused (upsampling adds nothing); the checkpoints'
    ``train_image_size`` is this size; a resume must keep it."""
    out_dir: str = "runs/mrvm"
    """Run folder: metrics.jsonl, checkpoints/, config.json."""
    seed: int = 0
    """Seed for initialisation and all sampling (per rank: seed + rank)."""
    iterations: int = 20000
    """Optimizer steps of this run."""
    pretrain_frac: float = 1.0
    """Share of iterations in the MRVM pretraining phase (masking); the rest trains without it. The paper
    pretrains in one run (1.0) and finetunes in a second that starts from its checkpoint (``init_checkpoint``,
    :data:`FINETUNE`: no masking, the learning-rate schedule restarted). Runs before this field's default
    changed name their own value (0.8)."""
    objects_per_step: int = 2
    """Objects per step per process (each with its own reference set)."""
    object_batch: int = 1
    """Objects of a step rendered in one forward pass, at most (those with the same number of reference views and
    image size go together; each object's loss is as in a pass of its own). 1 renders them one at a time, as every
    recipe before this field. Larger fills a GPU that one object leaves waiting on kernel launches; model kinds
    without it (``RayModel.supports_object_batch``) train one object at a time."""
    rays_per_object: int = 256
    """Target rays sampled per object per step."""
    min_ref_views: int = 1
    """Fewest reference views drawn per object: every training object needs one view more (a target), or the run
    is refused naming it (with ``ref_views_per`` 'step' an object with fewer views takes what it has)."""
    max_ref_views: int = 3
    """Most reference views drawn per object (random 1..K)."""
    ref_views_per: str = "object"
    """Who draws the reference count: 'object' (each object its own, every recipe before this field) or 'step' (one
    count a step for all its objects, as pixelNeRF draws it per batch; an object with fewer views takes what it has):
    with ``object_batch`` the step is then one forward pass instead of one per count. Each object's count has the
    same distribution either way."""
    bbox_sampling_frac: float = 0.75
    """Share of early iterations drawing target rays only inside the object's 2D box (pixelNeRF; the official
    MRVM pretraining: 300k of 400k steps; finetuning: none)."""
    lr: float = 5e-4
    """Peak AdamW learning rate."""
    lr_warmup: int = 200
    """Linear learning-rate warm-up steps."""
    lr_final_frac: float = 0.05
    """Cosine decay ends at lr * lr_final_frac."""
    weight_decay: float = 0.01
    """AdamW weight decay."""
    grad_clip: float = 1.0
    """Global gradient-norm clip (0 = off)."""
    coarse_weight: float = 1.0
    """Weight of the coarse branch's photometric loss."""
    opacity_weight: float = 0.0
    """Weight of a binary cross-entropy between each branch's accumulated opacity and the object mask
    (needs masks: our renders have them). Colour over white alone leaves faint white density in empty
    space, a haze in the alpha of image planes; this loss removes it. 0 = off."""
    distortion_weight: float = 0.0
    """Weight of the distortion loss of Mip-NeRF 360 on the fine pass's weights along each ray (density models
    only): sum_ij w_i w_j |s_i - s_j| + 1/3 sum_i w_i^2 len_i over the samples' intervals, with distances as a
    share of the ray's box length. It pulls each ray's weight into one compact interval: fewer translucent
    layers and floaters. 0 = off."""
    depth_weight: float = 0.0
    """Weight of a depth loss on each branch's weights along the rays that see a surface (density models
    only; needs depth maps in the data: our renders write them): the expected distance between where the
    light stops along the ray (the weights, plus the light that leaves the box at the far end) and the
    rendered surface, as a share of the ray's length in the box. It pulls each ray's weight onto the surface
    the training view saw: the geometry that colour alone learns slowly and blurs into ghosts from two views.
    Training only; the model never sees depth at test time. 0 = off."""
    lpips_weight: float = 0.0
    """Weight of LPIPS-VGG between each object's rendered patch and the photo (0 = off). A per-pixel loss
    on scattered rays is minimised by a blur; with this > 0 each object's rays form one ``patch_size`` x
    ``patch_size`` patch (``training/patches.py``; ``rays_per_object`` is then unused) so a perceptual loss
    can see edges and texture."""
    patch_size: int = 16
    """Patch side in rays when ``lpips_weight`` > 0 (at least 16: LPIPS-VGG pools four times)."""
    patch_scale_min: float = 0.25
    """A patch covers ``scale`` ~ U[patch_scale_min, 1] of the image side: 1 is the whole view at
    patch_size x patch_size, small scales full-resolution detail."""
    patch_fg_prob: float = 0.8
    """Probability that a patch is centred on an object pixel (else anywhere in the image)."""
    amp: str = "none"
    """Autocast: 'none', 'bf16' (CPU/GPU) or 'fp16' (GPU, with a grad scaler)."""
    compile: bool = False
    """torch.compile the model's networks (not the image encoder; ``models.registry.compile_networks``) before
    the first step: fewer, fused kernels on a GPU, where small models wait on kernel launches; the first steps
    pay the compilation (tens of seconds there, minutes on a 2-core CPU). Checkpoints are unchanged."""
    log_every: int = 10
    """Write a metrics line every this many steps."""
    ckpt_every: int = 1000
    """Checkpoint every this many steps (and at the end)."""
    keep_checkpoints: int = 2
    """Checkpoints kept on disk, the newest by step (older ones are removed); 0 keeps every one."""
    threads: int = 0
    """torch CPU threads per process (0 = every core but one, ``threads.auto_threads``: another count on another
    machine, and torch's CPU results depend on it in their last bits; give it for numbers to be repeated)."""
    device: str = "cpu"
    """'cpu' or 'cuda' (under torchrun each rank takes cuda:LOCAL_RANK)."""
    init_checkpoint: str = ""
    """Fine-tune: start from these weights (a model file, checkpoint or run folder, or 'shipped' for the
    add-on's default model) instead of a random initialisation. The optimizer, schedule and step start
    afresh; the model config is the checkpoint's unless the run config names one (it must match, or be a
    deeper copy: more transformer blocks of the same width, the added ones starting as the identity).
    Ignored when the run folder already has a checkpoint to resume from."""
    keep_init_losses: bool = False
    """Fine-tuning: train with the losses ``init_checkpoint`` was trained with (:data:`FINETUNE_KEEPS_LOSSES`;
    the shipped default: LPIPS patches at 1 and depth at 0.1) instead of the defaults. Measured on the shipped
    default fine-tuned on 71 real meshes (RECIPE.md "Fine-tuning the shipped model on your objects"): views of new
    objects of that kind LPIPS 0.022 sharper, 0.18 dB lower PSNR, about 1.2x the time a step on a CPU. Off by
    default (the rule written before measuring allowed at most 0.10 dB)."""

    def __post_init__(self) -> None:
        validate(self)


def load_run_config(path: Path | None, overrides: dict[str, Any] | None = None,
                    kind: str | None = None, preset: str | None = None,
                    resume: bool = True) -> tuple[Any, TrainConfig]:
    """Read a run-config JSON (or none) and apply ``overrides`` to the train section. ``kind`` and
    ``preset`` (the command line's ``--model`` and ``--preset``) choose the model where the config names
    none; naming another kind or preset beside a config that names its own is an InputError. Fine-tuning
    (``init_checkpoint``) with no preset or full model config named trains the checkpoint's own model (with the
    section's overrides); a kind named beside it (``--model``, the section's ``kind``) must be the checkpoint's.
    ``resume`` (False for ``train --no-resume``): whether the run continues the run its folder holds; one that
    starts over takes nothing from the folder's records (:func:`recorded_train`)."""
    data: dict[str, Any] = {}
    if path is not None:
        path = Path(path)
        if not path.is_file():
            raise InputError(f"config file {path} does not exist")
        try:
            data = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise InputError(f"{path}: not valid JSON ({e})") from e
    if not isinstance(data, dict):
        raise InputError(f"{path}: a run config is a JSON object ({{'model': ..., 'train': ...}}), got a "
                         f"{type(data).__name__}")
    unknown = set(data) - {"model", "train"}
    if unknown:
        raise InputError(f"{path}: unknown top-level keys {sorted(unknown)} (expected 'model' and 'train')")
    m = data.get("model", {})
    if not isinstance(m, dict) or not isinstance(data.get("train", {}), dict):
        raise InputError(f"{path}: 'model' and 'train' must be JSON objects")
    check_model_section(m, path)
    if preset:
        full = m.get("config") if isinstance(m.get("config"), dict) else {}
        named = m.get("preset") or full.get("name")
        if m and named != preset:
            raise InputError(f"--preset {preset} conflicts with the config's own model "
                             f"({named or 'a custom model section'}); drop --preset or the config's model section")
        if not m:
            m = {"preset": preset}
    section = data.get("train", {})
    tcfg = from_dict(TrainConfig, section)
    given = {k: v for k, v in (overrides or {}).items() if v is not None}
    if given:
        tcfg = merge(tcfg, given)
    if tcfg.keep_init_losses and not tcfg.init_checkpoint:
        raise InputError("keep_init_losses (--keep-losses) keeps the losses of the checkpoint a run fine-tunes: give "
                         "it one (--init shipped, or train.init_checkpoint), or drop it")
    tcfg = finetune_policy(tcfg, set(section) | set(given), resume)
    tcfg = data_policy(tcfg, set(section) | set(given), resume)
    validate(tcfg)
    from ..models import registry

    if preset and tcfg.init_checkpoint and not data.get("model"):  # --preset beside --init, no model section
        theirs = init_model_config(tcfg.init_checkpoint)
        k_theirs = registry.kind_of(theirs)
        if getattr(theirs, "name", None) != preset or (kind and registry.kind(kind).name != k_theirs):
            made = registry.kind(kind).name if kind else "nerformer_mrvm"
            raise InputError(f"--preset {preset} builds a new {made} model, but --init {tcfg.init_checkpoint} holds a "
                             f"{k_theirs} model (preset {getattr(theirs, 'name', '?')}) whose weights would not fit it: "
                             "drop --preset to fine-tune the checkpoint's own model")
        m = {}  # the checkpoint's own model: what --preset names
    named_kind = registry.kind(m["kind"]).name if m.get("kind") else None
    if kind and named_kind and registry.kind(kind).name != named_kind:
        raise InputError(f"--model {kind} conflicts with the config's own {named_kind} model; drop --model or the "
                         "config's model section")
    k = named_kind or kind
    if "config" in m:  # a full config (as saved in a checkpoint), with the section's overrides on top
        mcfg = registry.config_from_dict(k, m["config"])
        if m.get("overrides"):  # (a copied run's config.json plus an override: it was dropped without a word)
            mcfg = merge(mcfg, m["overrides"])
            registry.validate(mcfg)
    elif set(m) <= {"kind", "overrides"} and tcfg.init_checkpoint:  # fine-tuning: the checkpoint's own model
        mcfg = init_model_config(tcfg.init_checkpoint)
        theirs, want = registry.kind_of(mcfg), named_kind or (registry.kind(kind).name if kind else None)
        if want and want != theirs:
            who = (f"the config's model section (kind {m['kind']!r})" if named_kind else f"--model {kind}")
            raise InputError(f"{who} names a {want} model, but init_checkpoint {tcfg.init_checkpoint} holds a "
                             f"{theirs} model; drop {'it' if named_kind else '--model'} to fine-tune the "
                             f"checkpoint's own model, or start from a {want} checkpoint")
        if m.get("overrides"):  # settings that keep the weights' shapes, or more transformer blocks (grown from it)
            mcfg = merge(mcfg, m["overrides"])
            registry.validate(mcfg)
    else:
        mcfg = registry.build_config(k, m.get("preset", preset), m.get("overrides"))
    check_reference_range(mcfg, tcfg)
    return mcfg, tcfg


MODEL_SECTION_KEYS = ("kind", "preset", "overrides", "config")
"""What a run config's model section may hold."""


def check_model_section(m: dict[str, Any], path: Path | None = None) -> None:
    """InputError for a model section that would be read as something else than it says: an unknown key (a
    misspelt ``overrides`` or ``preset`` was dropped, and the run trained the default model with exit 0), both a
    ``preset`` and a full ``config`` (the preset was dropped), or ``overrides`` that are not a JSON object."""
    where = f"{path}: " if path is not None else ""
    unknown = sorted(set(m) - set(MODEL_SECTION_KEYS))
    if unknown:
        raise InputError(f"{where}unknown key(s) {unknown} in the model section (it takes "
                         f"{', '.join(MODEL_SECTION_KEYS)})")
    if "preset" in m and "config" in m:
        raise InputError(f"{where}the model section names both a preset ({m['preset']!r}) and a full config: give "
                         "one (a preset with overrides, or the config)")
    if "overrides" in m and not isinstance(m["overrides"], dict):
        raise InputError(f"{where}the model section's overrides must be a JSON object of fields, got "
                         f"{type(m['overrides']).__name__}")


def check_reference_range(mcfg: Any, tcfg: TrainConfig) -> None:
    """InputError when the run would train with reference counts its model refuses afterwards: the model's
    ``min_ref_views`` / ``max_ref_views`` (every kind has the latter; 10 for the presets) bound what ``eval`` and
    ``synthesize`` give it, and a run drawing ``train.max_ref_views`` 14 from a model of 10 trained at 14 and then
    refused ``--nearest 12`` ("must be between 0 and 10")."""
    lo, hi = int(getattr(mcfg, "min_ref_views", 1)), int(getattr(mcfg, "max_ref_views", 10))
    if tcfg.max_ref_views > hi:
        raise InputError(f"train.max_ref_views ({tcfg.max_ref_views}) is above the model's max_ref_views ({hi}): the "
                         f"trained model would refuse the reference counts it was trained with; lower "
                         f"train.max_ref_views, or raise the model's (model.overrides {{\"max_ref_views\": "
                         f"{tcfg.max_ref_views}}})")
    if tcfg.min_ref_views < lo:
        raise InputError(f"train.min_ref_views ({tcfg.min_ref_views}) is below the model's min_ref_views ({lo}): the "
                         "trained model would refuse the reference counts it was trained with; raise "
                         "train.min_ref_views, or lower the model's")


FINETUNE = {"pretrain_frac": 0.0, "lr": 1e-4, "lr_warmup": 50, "bbox_sampling_frac": 0.0}
"""The fine-tuning policy: a run that starts from a checkpoint (``init_checkpoint``) has no MRVM masking
phase (the paper pretrains with masking in one run, then finetunes without in a second), restarts the
learning-rate schedule at a lower peak with a short warm-up (at most a tenth of the run), and draws target
rays from the whole image (no bbox sampling, as the official finetuning). Settings a run config names
itself win."""


MRVM_OFFICIAL_FINETUNE = {"lr": 1e-3, "lr_final_frac": 1.0, "lr_warmup": 0}
"""The official MRVM code's finetuning run (``NeRFormer+MRVM/scripts/finetune.sh``): a constant lr 1e-3 with no
warm-up, for twice the pretraining's steps. Not the fine-tuning policy (:data:`FINETUNE`): the MRVM budget study's
second run with ``FT=official`` (``scripts/mrvm_budgets.sh``, ``gpu_session.sh mrvm_scale``), which took MRVM's PSNR
cost away there (RECIPE.md "The official finetune")."""


OPACITY_WEIGHT = 0.1
"""``opacity_weight`` of a new run on our renders whose config names none. Measured (RECIPE.md, "Depth from the
renders' depth maps"): from scratch at equal budget, LPIPS 0.277 against 0.337 without it and background opacity
0.06 against 0.23 (the haze of the image planes' alpha); every shipped model was trained with it."""


def default_opacity_weight(roots) -> float:
    """:data:`OPACITY_WEIGHT` when every dataset root is one of our renders (its manifest: object masks for every
    view), else 0 (other formats have no masks)."""
    from ..datasets.format import ROOT_MANIFEST

    roots = list(roots)
    return OPACITY_WEIGHT if roots and all((Path(r) / ROOT_MANIFEST).is_file() for r in roots) else 0.0


def data_policy(tcfg: TrainConfig, named: set[str] = frozenset(), resume: bool = True) -> TrainConfig:
    """``tcfg`` with the opacity loss its data call for (:func:`default_opacity_weight`) when ``opacity_weight``
    is not in ``named``; a run that continues the run its folder holds (``resume``) keeps the value that run
    recorded (:func:`recorded_train`: runs started before this default resume as they began); a run that starts
    over, or whose records cannot be read, gets the default. The one owner of the rule: the CLI's ``train``
    and the panel's new runs both go through it."""
    if "opacity_weight" in named:
        return tcfg
    rec = recorded_train(tcfg.out_dir, resume)
    if rec:
        w = rec.get("opacity_weight", 0.0)  # (a record without it: a run begun before the field, without the loss)
        if isinstance(w, (int, float)) and not isinstance(w, bool) and math.isfinite(w) and w >= 0:
            return replace(tcfg, opacity_weight=float(w))
    return replace(tcfg, opacity_weight=default_opacity_weight(data_roots(tcfg)))


def recorded_train(out_dir: str | Path, resume: bool = True) -> dict[str, Any] | None:
    """The train section of the run a new start continues, as it recorded it: None when the start begins a run
    (not ``resume``, as ``train --no-resume``, or a folder that holds no run: ``run_folder.holds_run``; a
    ``config.json`` alone is what a run refused at its first step left); else its ``config.json``'s, or, when
    that file is missing or cannot be read (a damaged disk), the ``train_config`` its newest checkpoint recorded;
    {} when neither can be read. The policies keep a continued run as it began (:func:`data_policy`,
    :func:`checkpoint_losses`) and give {} their defaults, as a new run."""
    from .run_folder import holds_run

    if not resume or not holds_run(Path(out_dir)):
        return None
    try:
        rec = json.loads((Path(out_dir) / "config.json").read_text()).get("train")
        if isinstance(rec, dict) and rec:
            return rec
    except (OSError, ValueError, AttributeError):
        pass
    return _checkpoint_train(Path(out_dir))


def _checkpoint_train(run_dir: Path) -> dict[str, Any]:
    """The ``train_config`` the newest whole checkpoint of ``run_dir`` recorded in its metadata; {} when there
    is none or it cannot be read."""
    from ..models.checkpoint_files import MODEL_FILE, find_checkpoint, read_header_meta

    try:
        ck = find_checkpoint(run_dir / "checkpoints")
        rec = json.loads(read_header_meta(ck / MODEL_FILE).get("train_config") or "{}") if ck else {}
    except (InputError, OSError, ValueError):
        return {}
    return rec if isinstance(rec, dict) else {}


FINETUNE_KEEPS_LOSSES = ("lpips_weight", "patch_size", "patch_scale_min", "patch_fg_prob", "depth_weight")
"""Loss settings a fine-tune with ``keep_init_losses`` takes from the checkpoint it starts from (the
``train_config`` it records): a model trained with the LPIPS patch loss and fine-tuned without it gets blurrier
views as their PSNR rises (RECIPE.md "Fine-tuning the shipped model on your objects"). ``depth_weight`` only where
the data are our renders (they have depth maps); settings a run config names itself win."""


def checkpoint_losses(tcfg: TrainConfig, resume: bool = True) -> dict[str, Any]:
    """The :data:`FINETUNE_KEEPS_LOSSES` settings recorded in ``tcfg.init_checkpoint`` (its ``train_config``) that
    this run's data allow, or those of the run it continues (``resume`` into a folder that holds a run: a run
    resumes with the losses it began with; :func:`recorded_train`); {} when there are none or they cannot be read
    (the trainer then says what is wrong). A run that starts over (``--no-resume --force``) takes the checkpoint's,
    never those of the run it replaces."""
    from ..models.checkpoint_files import checked_header

    rec = recorded_train(tcfg.out_dir, resume)  # a run continued keeps the losses it began with
    if not rec:  # a new run, or one whose records are unreadable: the checkpoint it fine-tunes
        try:
            rec = json.loads(checked_header(resolve_init_checkpoint(str(tcfg.init_checkpoint)))[1]
                             .get("train_config") or "{}")
        except (InputError, OSError, ValueError):
            return {}
    if not isinstance(rec, dict):
        return {}
    out: dict[str, Any] = {}
    defaults = TrainConfig()
    for k in FINETUNE_KEEPS_LOSSES:
        v, kind = rec.get(k), type(getattr(defaults, k))
        if isinstance(v, (int, float)) and not isinstance(v, bool) and (kind is float or float(v).is_integer()):
            out[k] = kind(v)
    if out.get("depth_weight", 0.0) > 0 and not default_opacity_weight(data_roots(tcfg)) > 0:
        out.pop("depth_weight")  # other datasets have no depth maps
    return out


def finetune_policy(tcfg: TrainConfig, named: set[str] = frozenset(), resume: bool = True) -> TrainConfig:
    """``tcfg`` with the fine-tuning policy (:data:`FINETUNE`; with ``keep_init_losses``, also the losses the
    checkpoint was trained with: :data:`FINETUNE_KEEPS_LOSSES`, or, continuing a run (``resume``), those it
    began with: :func:`checkpoint_losses`) applied to the settings not in ``named``, when it fine-tunes a
    checkpoint; unchanged otherwise. The one owner of the policy: the CLI's ``train --init`` and the panel's
    "Start from" both go through it."""
    if not tcfg.init_checkpoint:
        return tcfg
    pol = dict(FINETUNE)
    pol["lr_warmup"] = min(FINETUNE["lr_warmup"], max(1, tcfg.iterations // 10))
    if tcfg.keep_init_losses:
        pol.update(checkpoint_losses(tcfg, resume))
    return replace(tcfg, **{k: v for k, v in pol.items() if k not in named})


def resolve_init_checkpoint(name: str) -> Path:
    """The model file ``init_checkpoint`` names ('shipped' = the default model); InputError if none."""
    from ..models.checkpoint_files import model_file_of
    from ..models.pretrained import resolve_checkpoint

    try:
        return model_file_of(resolve_checkpoint(name))
    except InputError as e:
        raise InputError(f"init_checkpoint: {e}") from None


def init_model_config(name: str) -> Any:
    """The model config stored in the checkpoint ``init_checkpoint`` names."""
    from .checkpoint import read_model_config

    return read_model_config(resolve_init_checkpoint(name))


MAX_LR = 1.0
"""The largest ``train.lr`` accepted (``--adapt-lr`` has a lower cap: ``training.adapt``)."""


def validate(c: TrainConfig) -> None:
    """Types, then ranges (``TrainConfig.__post_init__`` runs it; kept callable for old callers)."""
    from .. import validation as V

    V.check_types(c)
    for name in ("iterations", "log_every", "ckpt_every"):
        V.at_least(c, name, 1)
    for name in ("max_objects", "image_size", "seed", "lr_warmup", "keep_checkpoints", "threads"):
        V.at_least(c, name, 0)
    # 0 is a frozen run (tests); NaN/inf are refused by check_types; above 1 a run only diverges (1e39 is not even
    # a float32: AdamW's step crashed on it, after the run folder was started)
    V.in_range(c, "lr", 0.0, MAX_LR)
    V.in_range(c, "lr_final_frac", 0.0, 1.0)
    for name in ("weight_decay", "grad_clip", "coarse_weight"):
        V.at_least(c, name, 0.0)
    V.check_device_name("train.device", c.device, allow_auto=False)
    if c.data_format not in ("", "ours", "srn", "nmr", "nerf"):
        raise InputError(f"train.data_format must be '', ours, srn, nmr or nerf, got {c.data_format!r}")
    roots = data_roots(c)  # no empty or repeated dataset roots
    if c.data_weights and roots:  # a config may name weights and leave the roots to --data
        if len(c.data_weights) != len(roots):
            raise InputError(f"train.data_weights has {len(c.data_weights)} weight(s) for {len(roots)} dataset(s)")
        if not all(math.isfinite(w) and w > 0 for w in c.data_weights):
            raise InputError(f"train.data_weights must be positive numbers, got {list(c.data_weights)}")
    if not c.split.strip():
        raise InputError("train.split is empty")
    if c.iterations < 1:
        raise InputError(f"iterations must be >= 1, got {c.iterations}")
    if not 1 <= c.min_ref_views <= c.max_ref_views:
        raise InputError("need 1 <= min_ref_views <= max_ref_views")
    if c.ref_views_per not in ("object", "step"):
        raise InputError(f"train.ref_views_per must be 'object' or 'step', got {c.ref_views_per!r}")
    if c.amp not in ("none", "bf16", "fp16"):
        raise InputError(f"amp must be none, bf16 or fp16, got {c.amp!r}")
    if not 0.0 <= c.pretrain_frac <= 1.0 or not 0.0 <= c.bbox_sampling_frac <= 1.0:
        raise InputError("pretrain_frac and bbox_sampling_frac must be in [0, 1]")
    if not c.opacity_weight >= 0.0:
        raise InputError(f"opacity_weight must be >= 0, got {c.opacity_weight}")
    if c.rays_per_object < 1 or c.objects_per_step < 1 or c.object_batch < 1:
        raise InputError("rays_per_object, objects_per_step and object_batch must be >= 1")
    if not c.distortion_weight >= 0.0:
        raise InputError(f"distortion_weight must be >= 0, got {c.distortion_weight}")
    if not c.depth_weight >= 0.0:
        raise InputError(f"depth_weight must be >= 0, got {c.depth_weight}")
    if not c.lpips_weight >= 0.0:
        raise InputError(f"lpips_weight must be >= 0, got {c.lpips_weight}")
    if c.lpips_weight > 0 and c.patch_size < 16:
        raise InputError(f"lpips_weight needs patch_size >= 16 (LPIPS-VGG pools four times), got {c.patch_size}")
    V.in_range(c, "patch_scale_min", 1e-3, 1.0)
    V.in_range(c, "patch_fg_prob", 0.0, 1.0)


def data_roots(c: TrainConfig) -> tuple[str, ...]:
    """The dataset roots ``train.data`` names, in order (``()`` when it names none); InputError for an
    empty entry in a list or a root named twice (its objects would be drawn twice as often)."""
    if isinstance(c.data, str):
        return (c.data,) if c.data.strip() else ()
    roots = tuple(c.data)
    seen: dict[str, str] = {}
    for r in roots:
        if not r.strip():
            raise InputError("train.data has an empty dataset root in its list")
        key = str(Path(r).expanduser().resolve())
        if key in seen:
            raise InputError(f"train.data names the dataset {r!r} twice"
                             + (f" (as {seen[key]!r} too)" if seen[key] != r else ""))
        seen[key] = r
    return roots


def run_config_dict(mcfg: Any, tcfg: TrainConfig) -> dict:
    from ..models import registry

    return {"model": {"kind": registry.kind_of(mcfg), "config": to_dict(mcfg)}, "train": to_dict(tcfg)}


__all__ = ["TrainConfig", "data_roots", "load_run_config", "run_config_dict", "validate", "replace"]
