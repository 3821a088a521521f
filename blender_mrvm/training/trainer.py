"""The trainer: AdamW + warm-up/cosine schedule, gradient clipping, optional autocast, MRVM pretraining
then finetuning, JSONL metrics, atomic checkpoints and exact resume; data-parallel under ``torchrun``.

Per step and process: ``objects_per_step`` objects, each with a random 1..K reference set and one
target view; ``rays_per_object`` target pixels drawn inside the object's 2D box during the first
``bbox_sampling_frac`` of training (pixelNeRF) and over the whole image afterwards. Rays that miss
the object's 3D box are background: they are scored (prediction = white) but never evaluated; on
scene data (``background: scene``) they are not scored, and the model is set up for the data's
background before it is built (``models/background.py``).
On capture-like data (``background: scene``) the references are the target's k nearest views.

Distributed: under ``torchrun`` (``WORLD_SIZE > 1``) each rank draws its own batch (seed + rank),
parameters start identical (broadcast from rank 0) and gradients are averaged with one all-reduce
per step (gloo on CPU, nccl on GPU) - the same update as DistributedDataParallel, without requiring
every parameter to be used in every phase (the MRVM head is idle while finetuning). Rank 0 writes
logs (each loss the mean over the ranks' batches) and checkpoints; every rank's RNG state is stored, so
resume is exact on any world size that matches the saved one.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from contextlib import nullcontext
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..datasets.format import atomic_write_text
from ..datasets.loaders import ObjectScene, load_dataset
from ..errors import InputError
from ..geometry.cameras import axis_cosines, rays_opencv
from ..models import registry
from ..models.base import RayModel, TrainPhase, normalized_scene, ref_cameras, rays_to
from ..models.rays import RayBundle, intersect_box, make_rays
from ..progress import Progress
from .patches import bilinear, sample_patch
from ..synthesis import nearest_views
from . import checkpoint as ckpt
from .config import TrainConfig, data_roots, run_config_dict


# ------------------------------------------------------------------------------------------- distributed

@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        return self.rank == 0


def init_distributed(device: str) -> Dist:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Dist()
    import torch.distributed as dist

    if not dist.is_initialized():
        dist.init_process_group(backend="nccl" if device.startswith("cuda") else "gloo")
    return Dist(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", "0")))


def _broadcast_params(model: torch.nn.Module) -> None:
    import torch.distributed as dist

    with torch.no_grad():
        for t in list(model.parameters()) + list(model.buffers()):
            dist.broadcast(t.data, 0)


def _allreduce_grads(params: list[torch.nn.Parameter], world: int) -> None:
    import torch.distributed as dist

    grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in params]
    flat = torch.cat([g.reshape(-1) for g in grads])
    dist.all_reduce(flat)
    flat /= world
    off = 0
    for p in params:
        n = p.numel()
        p.grad = flat[off:off + n].view_as(p).clone()
        off += n


def _mean_over_ranks(parts: dict[str, float], world: int) -> dict[str, float]:
    """A step's logged losses as the mean over the ranks of a torchrun job: each rank's are of its own batch only,
    and metrics.jsonl (written by rank 0) had held rank 0's alone while the update is of every rank's mean gradient. One
    gather at logging steps only (training steps are unchanged); a gather of the dicts, not an all-reduce of a
    tensor, because a part can be missing on a rank (no object of its batch had depth, or rays to render): it
    counts 0 there, as it does for such an object within a rank's step."""
    import torch.distributed as dist

    every: list[Any] = [None] * world
    dist.all_gather_object(every, parts)
    names = list(dict.fromkeys(k for d in every for k in d))
    return {k: sum(float(d.get(k, 0.0)) for d in every) / world for k in names}


# ------------------------------------------------------------------------------------------- data

def lr_at(step: int, cfg: TrainConfig) -> float:
    """Linear warm-up to ``lr`` then cosine decay to ``lr * lr_final_frac``: the first step after the warm-up
    runs at ``lr`` and the run's last step (``iterations - 1``) at ``lr * lr_final_frac`` exactly. (Until
    2026-11-29 the cosine spanned ``iterations - lr_warmup`` steps and the last step ended one step short of
    the floor; every step's rate has moved by up to ``lr * (1 - lr_final_frac) * pi / (2 (iterations -
    lr_warmup))`` since, so a run resumed from a checkpoint of before is not bit for bit the uninterrupted one.)"""
    if step < cfg.lr_warmup:
        return cfg.lr * (step + 1) / cfg.lr_warmup
    span = cfg.iterations - 1 - cfg.lr_warmup
    p = 1.0 if span <= 0 else min(1.0, (step - cfg.lr_warmup) / span)
    return cfg.lr * (cfg.lr_final_frac + (1 - cfg.lr_final_frac) * 0.5 * (1 + math.cos(math.pi * p)))


class RayBatcher:
    """Draws (reference set, target rays) per object from a list of scenes with one numpy generator."""

    def __init__(self, scenes: list[ObjectScene], cfg: TrainConfig, box_padding: float, seed: int,
                 weights: np.ndarray | None = None, nearest: bool = False):
        """``weights``: per scene, its probability of being drawn (:func:`object_weights`); None = uniform.
        ``nearest``: the target's nearest views are its references for objects too (always for captures)."""
        if not scenes:
            raise InputError("no training objects")
        for s in scenes:
            if len(s) < 2:
                raise InputError(f"object {s.category}/{s.name} has {len(s)} view(s); training needs >= 2")
        few = [s for s in scenes if len(s) <= cfg.min_ref_views]
        if few and cfg.ref_views_per == "object":  # ('step': an object with fewer views takes what it has)
            named = ", ".join(f"{s.category}/{s.name} ({len(s)} views)" for s in few[:3]) + (", ..." if few[3:] else "")
            raise InputError(f"train.min_ref_views is {cfg.min_ref_views}: every training object needs at least "
                             f"{cfg.min_ref_views + 1} views (the references and a target), and {len(few)} "
                             f"{'has' if len(few) == 1 else 'have'} fewer: {named}; lower train.min_ref_views or "
                             "leave those objects out")
        unseen = [s for s in scenes if box_unseen(s, box_padding)]
        if unseen:  # every ray of theirs misses the box: they would train nothing, at 'hit 0' every step
            named = ", ".join(f"{s.category}/{s.name}" for s in unseen[:3]) + (", ..." if unseen[3:] else "")
            lo, hi = (np.round(np.asarray(b, np.float64), 4).tolist() for b in unseen[0].bbox)
            what = (f"no view of {len(unseen)} of the {len(scenes)} training object(s) ({named}) looks at its box "
                    f"(the first's: {lo} to {hi}): every ray of theirs misses it")
            if len(unseen) == len(scenes):
                raise InputError(f"{what}, so the run would learn nothing; check the objects' bbox (meta.json) "
                                 "against their cameras")
            print(f"warning: {what} and trains nothing; check their bbox (meta.json) against their cameras",
                  file=sys.stderr)
        self.scenes = scenes
        self.weights = weights
        self.nearest = bool(nearest)
        self.cfg = cfg
        self.padding = float(box_padding)
        self.rng = np.random.default_rng(seed)
        self._boxes = [s.foreground_boxes() for s in scenes]
        for weight, field, what, files in (("opacity_weight", "masks", "object masks", ""),
                                           ("depth_weight", "depths", "depth maps", " (depth/*.exr)")):
            bare = [f"{s.category}/{s.name}" for s in scenes if getattr(s, field) is None]
            if getattr(cfg, weight) > 0 and bare:
                raise InputError(f"{weight} needs {what}, and {len(bare)} training object(s) have none (e.g. "
                                 f"{bare[0]}); our rendered datasets have them{files}, or set {weight} to 0")

    def draw(self, bbox_phase: bool, n_refs: int | None = None) -> dict[str, Any]:
        """One object's batch; ``n_refs`` the step's reference count (``train.ref_views_per`` 'step'; at most the
        object's views but one), else the object draws its own."""
        c, rng = self.cfg, self.rng
        j = int(rng.integers(len(self.scenes))) if self.weights is None else int(rng.choice(len(self.scenes), p=self.weights))
        s = self.scenes[j]
        if n_refs is None:
            k = int(rng.integers(c.min_ref_views, min(c.max_ref_views, len(s) - 1) + 1))
        else:
            k = min(int(n_refs), len(s) - 1)
        perm = rng.permutation(len(s))
        refs, tgt = perm[:k], int(perm[k])
        if s.background == "scene" or self.nearest:
            # A capture: the target's nearest views are its references, as eval and synthesis give them
            # (random views of a walk round a room rarely see what the target sees); adapting to a dense
            # set of references whose views each take their nearest few, too.
            others = [int(v) for v in perm[k:] if v != tgt] + [int(v) for v in perm[:k]]
            centre = 0.5 * (np.asarray(s.bbox[0], np.float64) + np.asarray(s.bbox[1], np.float64))
            near = nearest_views([s.c2w[v] for v in others], s.c2w[tgt], centre, k)
            refs = np.array([others[i] for i in near])
        ns = normalized_scene(s.bbox[0], s.bbox[1], self.padding)
        cams = ref_cameras([ns.pose(s.c2w[i]) for i in refs], [s.intrinsics[i] for i in refs])
        images = torch.from_numpy(np.ascontiguousarray(s.images[refs])).permute(0, 3, 1, 2).contiguous()
        intr = s.intrinsics[tgt]
        patch = 0
        if c.lpips_weight > 0:  # one P x P patch at a random scale, region-aware (training/patches.py)
            patch = c.patch_size
            px = sample_patch(rng, self._foreground(s, tgt), patch, float(rng.uniform(c.patch_scale_min, 1.0)),
                              c.patch_fg_prob)
            gt = bilinear(s.images[tgt], px)
            mask = bilinear(s.masks[tgt], px)[:, 0] if s.masks is not None else None
            z = None
            if c.depth_weight > 0:  # interpolated only where all four pixels around see a surface
                z = bilinear(s.depths[tgt], px)[:, 0].numpy().astype(np.float64)
                z[bilinear(s.depths[tgt] > 0, px)[:, 0].numpy() < 0.999] = 0.0
        else:
            x0, y0, x1, y1 = self._boxes[j][tgt] if bbox_phase else (0, 0, intr.width, intr.height)
            ix = rng.integers(x0, x1, c.rays_per_object)
            iy = rng.integers(y0, y1, c.rays_per_object)
            px = np.stack([ix + 0.5, iy + 0.5], -1)
            gt = torch.from_numpy(s.images[tgt][iy, ix].astype(np.float32))
            mask = torch.from_numpy(s.masks[tgt][iy, ix].astype(np.float32)) if s.masks is not None else None
            z = s.depths[tgt][iy, ix].astype(np.float64) if c.depth_weight > 0 else None
        rays = make_rays(intr, ns.pose(s.c2w[tgt]), px, box=ns.box)
        return {"images": images, "cams": cams, "rays": rays, "gt": gt, "mask": mask, "n_refs": k,
                "scene": s.background == "scene", "patch": patch,
                "surface": None if z is None else surface_distance(rays, axis_cosines(intr, px), z / ns.scale),
                "ref_views": [int(v) for v in refs], "target_view": tgt}

    @staticmethod
    def _foreground(s: ObjectScene, view: int) -> np.ndarray:
        """Where a region-aware patch may be centred: the object mask, else the non-white pixels (an
        empty mask lets ``sample_patch`` place the patch anywhere)."""
        if s.masks is not None:
            return s.masks[view]
        if s.background == "scene":
            return np.zeros(s.images.shape[1:3], bool)
        return (s.images[view] < 0.99).any(-1)


def box_unseen(s: ObjectScene, box_padding: float, grid: int = 32) -> bool:
    """Whether no ray through a ``grid`` x ``grid`` lattice of pixels of any view of ``s`` crosses its (padded) box:
    a bbox that is not where the cameras look (a wrong meta.json bbox) makes every training ray miss. A view that
    sees the box ends the search (the first one, for sound data)."""
    ns = normalized_scene(s.bbox[0], s.bbox[1], box_padding)
    lo, hi = np.full(3, -ns.box), np.full(3, ns.box)
    for c2w, intr in zip(s.c2w, s.intrinsics):
        u = (np.arange(grid) + 0.5) * intr.width / grid
        v = (np.arange(grid) + 0.5) * intr.height / grid
        o, d = rays_opencv(intr, ns.pose(c2w), np.stack(np.meshgrid(u, v), -1).reshape(-1, 2))
        if intersect_box(o.reshape(-1, 3), d.reshape(-1, 3), lo, hi)[2].any():
            return False
    return True


def surface_distance(rays, cos: np.ndarray, z: np.ndarray) -> torch.Tensor:
    """(R,) float32 distance along each ray from its box entry (the ``t`` of the model's samples) to the surface
    a depth map saw there: ``z`` (R,) planar z-depth in the normalised frame's units (0 = no surface), turned
    into a distance along the ray by ``cos``, the rays' cosines to the optical axis (``cameras.axis_cosines``).
    NaN where there is no surface, the ray misses the box, or the surface lies outside the box's stretch of the
    ray (a depth map of another object): those rays carry no depth loss."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where((z > 0) & (cos > 1e-6), z / cos, np.nan) - rays.depth_offset.numpy()
    far = rays.far.numpy()
    ok = rays.hit.numpy() & (t >= -1e-6 * np.maximum(far, 1.0)) & (t <= far * (1 + 1e-6))
    return torch.from_numpy(np.where(ok, np.clip(t, 0.0, far), np.nan).astype(np.float32))


# ------------------------------------------------------------------------------------------- training

def _autocast(cfg: TrainConfig, device: str):
    if cfg.amp == "none":
        return nullcontext()
    dtype = torch.bfloat16 if cfg.amp == "bf16" else torch.float16
    return torch.autocast(device_type="cuda" if device.startswith("cuda") else "cpu", dtype=dtype)


def _rng_state(batcher: RayBatcher, gen: torch.Generator) -> dict[str, Any]:
    return {"numpy": batcher.rng.bit_generator.state, "torch_gen": gen.get_state(), "torch_global": torch.get_rng_state()}


def _set_rng_state(batcher: RayBatcher, gen: torch.Generator, st: dict[str, Any]) -> None:
    batcher.rng.bit_generator.state = st["numpy"]
    gen.set_state(st["torch_gen"])
    torch.set_rng_state(st["torch_global"])


def train(model_cfg: Any, cfg: TrainConfig, resume: bool = True, scenes: list[ObjectScene] | None = None,
          force: bool = False):
    """Progress generator; returns a summary dict (final step, last losses, checkpoint path).
    ``force`` lets a run without ``resume`` replace the run folder's old run (``run_folder.resume_point``).

    The run folder is held (``guards.output_lock``) from before its state is read until the run ends: a second
    training into it is refused instead of both writing checkpoints and metrics (rank 0 holds it under torchrun)."""
    from ..guards import output_lock, sweep_partials

    main = int(os.environ.get("RANK", "0")) == 0
    with output_lock(Path(cfg.out_dir), "run folder") if main else nullcontext():
        if main:  # the temporary folders of saves a killed run left half-way (only this process writes there)
            sweep_partials(Path(cfg.out_dir) / "checkpoints", ".step_*")
        return (yield from _train(model_cfg, cfg, resume, scenes, force))


def _train(model_cfg: Any, cfg: TrainConfig, resume: bool, scenes: list[ObjectScene] | None, force: bool):
    from . import run_folder

    device = cfg.device
    run_folder.check_device(device)
    from .config import check_reference_range

    check_reference_range(model_cfg, cfg)  # (the panel and direct callers do not come through load_run_config)
    dd = init_distributed(device)
    if device.startswith("cuda") and dd.world > 1:
        device = f"cuda:{dd.local_rank}"
        torch.cuda.set_device(device)
    from ..threads import set_torch_threads

    threads = set_torch_threads(cfg.threads)
    run_dir = Path(cfg.out_dir)
    weights = None
    if scenes is None:
        sets = load_training_sets(cfg)
        scenes = [s for objs in sets for s in objs]
        weights = object_weights(cfg.data_weights, [len(objs) for objs in sets])
    elif cfg.image_size:  # objects a caller loaded: at the size the run trains at, as loading would give them
        from ..datasets.loaders import resize_scene

        scenes = [resize_scene(s, cfg.image_size) for s in scenes]
    from ..models import background as bgrule

    data_bg = bgrule.of_scenes(scenes)
    model_cfg, note = bgrule.for_training(model_cfg, data_bg)  # the data decides what the images sit on
    if note and dd.main:
        print(f"note: {note}", file=sys.stderr)
    if cfg.lr_warmup >= cfg.iterations and cfg.lr > 0 and dd.main:
        # a short run with the default warmup (200 steps) never reaches train.lr and never decays: legal (a smoke
        # run) but rarely meant (session 28's first GPU MRVM runs were such runs), so say so
        print(f"note: train.lr_warmup ({cfg.lr_warmup}) is not below iterations ({cfg.iterations}): the learning "
              f"rate only ramps up, to {cfg.iterations / max(1, cfg.lr_warmup):.0%} of train.lr "
              f"({cfg.lr:g}), and never decays; set train.lr_warmup to a fraction of the run", file=sys.stderr)
    for name in ("distortion_weight", "depth_weight"):
        if getattr(cfg, name) > 0 and registry.kind_of(model_cfg) != "nerformer_mrvm":
            raise InputError(f"{name} needs a density field (a nerformer_mrvm model); this run trains a "
                             f"{registry.kind_of(model_cfg)} model: set it to 0")
    torch.manual_seed(cfg.seed)
    model = registry.build_model(model_cfg).to(device)
    params = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=cfg.weight_decay)
    scaler = _grad_scaler(cfg, device)
    batcher = RayBatcher(scenes, cfg, model.box_padding, cfg.seed * 7919 + dd.rank, weights)
    lp = None
    if cfg.lpips_weight > 0:
        from ..models.metrics import LPIPS

        lp = LPIPS().to(device)  # frozen VGG16 + linear heads from the offline weights (fetch-weights);
        # loaded before the run folder is touched, so missing weights write nothing
    # The sampling generator lives where the model samples (a CPU generator cannot feed CUDA tensors).
    gen = torch.Generator(device=torch.device(device)).manual_seed(cfg.seed * 104729 + dd.rank)
    torch.manual_seed(cfg.seed + dd.rank)
    start = 0
    init_from = None
    found, state = run_folder.resume_point(run_dir, resume, force, dd.main)
    if found is not None:
        _check_continues(run_dir, found, cfg, model_cfg)
        _check_same_image_size(run_dir, found, cfg)
        try:
            ckpt.load_weights(model, found / ckpt.MODEL_FILE, device)
        except ckpt.WeightsMismatch:  # the checkpoint is fine: this start asked for another model
            raise InputError(f"the run in {run_dir} trains {_model_words(ckpt.read_model_config(found / ckpt.MODEL_FILE))}"
                             f" ({found.name}); this start asks for {_model_words(model_cfg)}: continue the run with "
                             "its own model (no --preset, --model or config model section), start over with "
                             "--no-resume --force, or give another --out") from None
        if state.get("world_size", 1) != dd.world:
            raise InputError(f"checkpoint {found} was written by {state.get('world_size')} process(es); "
                             f"resume with the same number (got {dd.world}), or start over with --no-resume --force")
        start = int(state["step"])
        cfg = _keep_recorded_seed(run_dir, found, cfg, dd.main)
        run_folder.check_not_past(run_dir, found, start, cfg.iterations, "train.iterations",
                                  " (--iterations, the panel's Iterations)")
        _note_a_longer_schedule(found, start, cfg, dd.main)
        opt.load_state_dict(state["optimizer"])
        if scaler is not None and state.get("grad_scaler"):  # fp16: its loss scale and growth count, found so far
            scaler.load_state_dict(state["grad_scaler"])
        _set_rng_state(batcher, gen, state["rng"][dd.rank])
    else:
        if cfg.init_checkpoint:
            init_from, added = init_weights(model, model_cfg, cfg.init_checkpoint, device)
            if added and dd.main:
                print(f"init: {len(added)} transformer blocks added to {init_from.name}'s model, starting as the "
                      f"identity ({', '.join(added)})", file=sys.stderr, flush=True)
        if dd.world > 1:
            _broadcast_params(model)
        if dd.main:
            _note_linear_depths_inside(model_cfg, cfg, scenes, model.box_padding)
    if cfg.compile:
        registry.compile_networks(model)  # after the weights are in place (compiling keeps the state dict's keys)
    if dd.main:
        run_dir.mkdir(parents=True, exist_ok=True)
        # atomic: a torn config.json would lose what the run began with (training.config.recorded_train)
        atomic_write_text(run_dir / "config.json", json.dumps(run_config_dict(model_cfg, cfg), indent=2) + "\n")
    record = None
    if dd.main:  # what repeating the run needs and config.json does not say (training/provenance.py)
        record = start_record(cfg, scenes, start, found, threads, device, dd.world)
        from .provenance import append_record

        append_record(run_dir, record)
    image_size = train_image_size(scenes)
    bbox_steps = int(round(cfg.bbox_sampling_frac * cfg.iterations))
    object_batch = cfg.object_batch if model.supports_object_batch else 1
    if cfg.object_batch > 1 and object_batch == 1 and dd.main:
        print(f"note: a {model.kind} model trains one object at a time; train.object_batch "
              f"({cfg.object_batch}) is not used", file=sys.stderr)
    log = open(run_dir / "metrics.jsonl", "a", encoding="utf-8") if dd.main else None
    last: dict[str, float] = {}
    saved = None
    saved_at = start  # the step of the newest checkpoint on disk (the one resumed from, if any)
    try:
        t0 = time.perf_counter()
        for step in range(start, cfg.iterations):
            model.train()
            lr = lr_at(step, cfg)
            for g in opt.param_groups:
                g["lr"] = lr
            phase = model.train_phase(step, cfg)
            opt.zero_grad(set_to_none=True)
            tot = {"loss": 0.0, "mse_fine": 0.0, "opacity": 0.0, "hit": 0.0,
                   **{k: 0.0 for k in phase.loss_weights}}
            # Each object's loss is backpropagated on its own (only one object's graph is held), except with the
            # LPIPS patch loss: then up to LPIPS_GROUP objects' patches are scored as one VGG batch
            # (``patch_lpips``) and their graphs go back together (patches are small: P x P rays each). With
            # ``object_batch`` each group of objects rendered together goes back together (its patches one VGG batch).
            patches: list | None = [] if lp is not None else None
            held: list[torch.Tensor] = []

            def backward_held():
                if patches:
                    with _autocast(cfg, device):
                        lpv = patch_lpips(lp, patches)
                    lpips_part = lpv.sum() * (cfg.lpips_weight / cfg.objects_per_step)
                    tot["lpips"] = tot.get("lpips", 0.0) + float(lpv.detach().sum()) / cfg.objects_per_step
                    tot["loss"] += float(lpips_part.detach())
                    held.append(lpips_part)
                    patches.clear()
                if held:
                    total = held[0] if len(held) == 1 else torch.stack([x.float() for x in held]).sum()
                    (scaler.scale(total) if scaler else total).backward()
                    held.clear()

            for group in object_groups(batcher, step < bbox_steps, cfg.objects_per_step, object_batch):
                with _autocast(cfg, device):
                    loss, group_parts = batch_loss(model, group, cfg, phase, gen, device, lp, patches)
                for parts in group_parts:
                    for k, v in parts.items():
                        tot[k] = tot.get(k, 0.0) + v / cfg.objects_per_step
                loss = loss / cfg.objects_per_step
                tot["loss"] += float(loss.detach())
                if loss.requires_grad:  # (a batch whose rays all miss the box has nothing to learn)
                    held.append(loss)
                # (batched, a group's graphs go back together: at most ``object_batch`` objects' are held at once)
                if patches is None or object_batch > 1 or sum(len(a) for a, _ in patches) >= LPIPS_GROUP:
                    backward_held()
            backward_held()
            if dd.world > 1:
                _allreduce_grads(params, dd.world)
            if scaler:
                scaler.unscale_(opt)
            # the norm is measured without clipping too (grad_clip 0 logged a grad_norm of 0.0 every step)
            gnorm = torch.nn.utils.clip_grad_norm_(params, cfg.grad_clip if cfg.grad_clip > 0 else float("inf"))
            # before the update: a NaN never reaches the weights (under torchrun the all-reduced gradient
            # norm, the same on every rank, so all stop together; fp16's scaler skips inf steps itself)
            by_norm = dd.world > 1 and scaler is None
            run_folder.check_loss(float(gnorm) if by_norm else tot["loss"], step + 1, saved or found,
                                  "gradient norm" if by_norm else "loss")
            if scaler:
                scaler.step(opt)
                scaler.update()
            else:
                opt.step()
            model.after_step(phase)
            done = step + 1
            logged = done % cfg.log_every == 0 or done == cfg.iterations or done == start + 1
            if logged and dd.world > 1:  # the same steps on every rank: the collective is met by all
                tot = _mean_over_ranks(tot, dd.world)
            last = {"step": done, "lr": lr, **phase.logs, "grad_norm": float(gnorm),
                    "psnr_fine": -10 * math.log10(max(tot["mse_fine"], 1e-10)), **tot,
                    "time_s": time.perf_counter() - t0}
            if log and logged:
                log.write(json.dumps(last) + "\n")
                log.flush()
            if done % cfg.ckpt_every == 0 or done == cfg.iterations:
                # the loss above was computed with the weights before this update, and a diverging step (a learning
                # rate too high) leaves NaN or huge weights: checked before every save, never saved (between saves
                # the next step's loss check stops such a run; checking after every step added a few ops per
                # weight tensor to every step)
                run_folder.check_weights(model, done, saved or found)
                saved = _save(run_dir, done, model, model_cfg, cfg, opt, batcher, gen, dd, image_size, scaler, record)
                saved_at = done
            try:
                yield Progress(done, cfg.iterations, f"loss {tot['loss']:.4f} psnr {last['psnr_fine']:.2f}")
            except GeneratorExit:
                # Closed between steps (Ctrl-C, the panel's Esc, `timeout -s INT`): the finished steps are kept
                # as a checkpoint the next run resumes from, not lost back to the last ckpt_every. One process
                # only: the ranks of a torchrun job stop at different steps, and saving is collective.
                if dd.world == 1 and saved_at != done:
                    run_folder.check_weights(model, done, saved or found)
                    saved = _save(run_dir, done, model, model_cfg, cfg, opt, batcher, gen, dd, image_size, scaler, record)
                    print(f"train: stopped after step {done} of {cfg.iterations}; checkpoint {saved} "
                          "(the same command resumes from it)", file=sys.stderr, flush=True)
                raise
    finally:
        if log:
            log.close()
    # the model's step: a resume past train.iterations was refused above
    # a rerun of a finished run trains nothing and saves nothing: its checkpoint is the one it found (it printed null,
    # and `eval --checkpoint "$ck"` in a script then failed)
    newest = saved if saved else found
    return {"step": cfg.iterations, "last": last, "checkpoint": str(newest) if newest else None,
            "resumed_from": start, "initialized_from": str(init_from) if init_from else None,
            "world_size": dd.world, "rank": dd.rank, "param_digest": param_digest(model)}


def object_groups(batcher: RayBatcher, bbox_phase: bool, n: int, size: int):
    """A step's ``n`` objects, drawn in the order one pass per object draws them (the same draws), in groups of at
    most ``size`` that can share a forward pass: the same number of reference views and reference image size, in
    the order each kind first appears. ``size`` 1 yields each object as it is drawn. With ``train.ref_views_per``
    'step' the step's reference count is drawn first, for all its objects."""
    c = batcher.cfg
    k = int(batcher.rng.integers(c.min_ref_views, c.max_ref_views + 1)) if c.ref_views_per == "step" else None
    if size <= 1:
        for _ in range(n):
            yield [batcher.draw(bbox_phase, k)]
        return
    kinds: dict[tuple, list] = {}
    for _ in range(n):
        b = batcher.draw(bbox_phase, k)
        kinds.setdefault((b["n_refs"], tuple(b["images"].shape[-2:])), []).append(b)
    for same in kinds.values():
        for i in range(0, len(same), size):
            yield same[i:i + size]


def load_training_sets(cfg: TrainConfig) -> list[list[ObjectScene]]:
    """The training objects of each dataset ``train.data`` names, in the order given (each read with
    ``data_format`` and ``split``, at most ``max_objects`` from each); every root is loaded, and so
    checked, before the run folder is touched; with their depth maps for ``depth_weight``; every view at
    ``image_size`` pixels on its longer side when it is not 0)."""
    roots = data_roots(cfg)
    if not roots:
        raise InputError("no dataset: give --data or train.data in the config")
    return [load_dataset(Path(root), cfg.split, cfg.data_format or None, cfg.max_objects or None, cfg.depth_weight > 0,
                         cfg.image_size) for root in roots]


def load_training_scenes(cfg: TrainConfig) -> list[ObjectScene]:
    """Every dataset's training objects pooled (:func:`load_training_sets`)."""
    return [s for objs in load_training_sets(cfg) for s in objs]


def object_weights(data_weights, counts: list[int]) -> np.ndarray | None:
    """Per pooled object, the probability of being drawn when dataset k (``counts[k]`` objects) gets the share
    ``data_weights[k]`` (normalised) of the draws; None (uniform over objects) without weights."""
    if not data_weights:
        return None
    w = np.concatenate([np.full(n, float(dw) / n) for dw, n in zip(data_weights, counts) if n])
    return w / w.sum()


def object_loss(model: RayModel, b: dict[str, Any], cfg: TrainConfig, phase: TrainPhase,
                gen: torch.Generator, device, lp=None,
                patches: list | None = None) -> tuple[torch.Tensor, dict[str, float]]:
    """The loss of one object's batch and its parts, for any model kind.

    Photometric MSE over all drawn rays (rays that miss the box are predicted as the background and
    cost nothing to evaluate), the same for each auxiliary head (``coarse_weight``), the opacity BCE
    against the object mask when ``opacity_weight`` > 0, LPIPS of the final colour's patch when the
    batch is a patch and ``lp`` (:class:`models.metrics.LPIPS`) is given (``lpips_weight``), and the
    model's auxiliary losses with the weights of its training phase (e.g. MRVM's lambda).

    With a ``patches`` list the LPIPS term is left to the caller: the (predicted, true) (1, 3, P, P) patch
    pair is appended to it instead (:func:`patch_lpips` scores a step's patches as one VGG batch)."""
    cams = _cams_to(b["cams"], device)
    ctx = model.encode(b["images"].to(device), cams)
    out = None
    if bool(b["rays"].hit.any()):
        sel = torch.nonzero(b["rays"].hit).flatten()
        out = model.render_rays(ctx, rays_to(b["rays"].select(sel), device), train=True, generator=gen, **phase.kwargs)
    loss, (parts,) = _group_terms(model, [b], out, cfg, phase, device, lp, patches)
    return loss, parts


def batch_loss(model: RayModel, bs: list[dict[str, Any]], cfg: TrainConfig, phase: TrainPhase,
               gen: torch.Generator, device, lp=None,
               patches: list | None = None) -> tuple[torch.Tensor, list[dict[str, float]]]:
    """The summed loss of several objects' batches and each one's parts (:func:`object_loss`'s), their rays rendered
    in one forward pass (``model.render_rays_batch``): the objects need the same number of reference views and
    image size. Each object's terms are those of a pass of its own; the model's auxiliary losses (MRVM's) are the
    batch's mean of each object's own (so their sum over the objects is the same). The random draws of sampling
    and masking differ from one pass per object, so the two are equal in distribution, not bit for bit."""
    if len(bs) == 1:
        loss, parts = object_loss(model, bs[0], cfg, phase, gen, device, lp, patches)
        return loss, [parts]
    ctx = model.encode_batch([b["images"].to(device) for b in bs], [_cams_to(b["cams"], device) for b in bs])
    sels = [torch.nonzero(b["rays"].hit).flatten() for b in bs]
    counts = [len(x) for x in sels]
    out = None
    if sum(counts):
        rays = RayBundle.cat([b["rays"].select(x) for b, x in zip(bs, sels)])
        out = model.render_rays_batch(ctx, rays_to(rays, device), counts, train=True, generator=gen, **phase.kwargs)
    return _group_terms(model, bs, out, cfg, phase, device, lp, patches)


def _cams_to(cams, device):
    cams.w2c, cams.K = cams.w2c.to(device), cams.K.to(device)
    return cams


def _group_terms(model: RayModel, bs: list[dict[str, Any]], out: dict | None, cfg: TrainConfig, phase: TrainPhase,
                 device, lp=None, patches: list | None = None) -> tuple[torch.Tensor, list[dict[str, float]]]:
    """The summed loss of objects ``bs`` and each one's parts, from ``out``: the render of their rays that hit the box,
    object after object (None: none does). Every term is computed for all the objects at once (sums per object over
    their rays), so a group costs the kernels of one object, and the parts reach the host in one transfer.

    Per object, as :func:`object_loss` documents: the photometric MSE over all its drawn rays (a ray that misses the
    box shows the background; in a scene, the photo itself, and only the hits count), the same for each auxiliary head
    (``coarse_weight``), the opacity BCE, distortion, depth and LPIPS terms, and the model's auxiliary losses (the
    batch's own value, added for each object with rays to render). An object none of whose rays hit the box adds
    nothing but its logged MSE."""
    B = len(bs)
    sizes = [len(b["gt"]) for b in bs]
    hit_cpu = torch.cat([b["rays"].hit for b in bs])
    nhit = [int(b["rays"].hit.sum()) for b in bs]
    scene = [bool(b.get("scene")) for b in bs]
    n = torch.tensor([max(1, h) if sc else sz for h, sc, sz in zip(nhit, scene, sizes)], dtype=torch.float32,
                     device=device)
    gt = torch.cat([b["gt"] for b in bs]).to(device).float()
    obj_cpu = torch.repeat_interleave(torch.arange(B), torch.tensor(sizes))
    obj = obj_cpu.to(device)
    hit_idx = torch.nonzero(hit_cpu).flatten().to(device)
    obj_hit = obj_cpu[hit_cpu].to(device)
    bg = 1.0 if model.white_background else 0.0
    shown = gt.clone() if all(scene) else torch.full_like(gt, bg)  # what a ray that misses the box shows
    if any(scene) and not all(scene):
        shown = torch.where(torch.tensor([scene[k] for k in obj_cpu.tolist()], device=device)[:, None], gt, shown)

    def per_object(v: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
        return v.new_zeros(B).index_add(0, idx, v)

    def mse(color: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:  # (B,) per object, and every ray's colour
        full = shown if color is None else shown.index_put((hit_idx,), color.float())
        return per_object(((full - gt) ** 2).sum(-1), obj) / (3 * n), full

    vals: dict[str, torch.Tensor] = {}
    mse_fine, full = mse(None if out is None else out["color"])
    vals["mse_fine"] = mse_fine
    parts = [{"hit": h / max(1, sz)} for h, sz in zip(nhit, sizes)]
    if out is None:
        return torch.zeros((), device=device), _with_values(parts, vals, has=None)
    loss = mse_fine
    heads = out.get("aux_heads", {})
    for name, head in heads.items():
        vals[f"mse_{name}"] = mse(head["color"])[0]
        loss = loss + cfg.coarse_weight * vals[f"mse_{name}"]
    if cfg.opacity_weight > 0:
        mask, hit = torch.cat([b["mask"] for b in bs]).to(device).float(), hit_cpu.to(device)
        size = torch.tensor(sizes, dtype=torch.float32, device=device)

        def opacity(acc: torch.Tensor) -> torch.Tensor:
            return per_object(opacity_per_ray(torch.zeros_like(mask).index_put((hit_idx,), acc.float()), mask, hit),
                              obj) / size

        opa = opacity(out["acc"])
        for head in heads.values():
            opa = opa + cfg.coarse_weight * opacity(head["acc"])
        vals["opacity"] = opa
        loss = loss + cfg.opacity_weight * opa
    far = None
    if cfg.distortion_weight > 0 or cfg.depth_weight > 0:
        far = torch.cat([b["rays"].far[b["rays"].hit] for b in bs]).to(device)
        hits = torch.tensor(nhit, dtype=torch.float32, device=device).clamp_min(1)
    if cfg.distortion_weight > 0:
        fine = out["fine"]
        vals["distortion"] = per_object(distortion_per_ray(fine["weights"], fine["t"], far), obj_hit) / hits
        loss = loss + cfg.distortion_weight * vals["distortion"]
    depth_objects = None
    if cfg.depth_weight > 0 and any(b.get("surface") is not None for b in bs):
        t_star = torch.cat([b["surface"][b["rays"].hit] if b.get("surface") is not None
                            else torch.full((h,), float("nan")) for b, h in zip(bs, nhit)])
        ok_cpu = torch.isfinite(t_star)
        ok_count = [int(x) for x in torch.zeros(B, dtype=torch.int64).index_add(0, obj_cpu[hit_cpu], ok_cpu.long())]
        depth_objects = [c > 0 for c in ok_count]
        if any(depth_objects):
            ok = torch.nonzero(ok_cpu).flatten().to(device)
            ts, fk, ob = t_star.to(device)[ok], far[ok], obj_hit[ok]
            per_ray = sum((1.0 if h is out["fine"] else cfg.coarse_weight)
                          * surface_per_ray(h["weights"][ok], h["t"][ok], fk, ts) for h in [out["fine"], *heads.values()])
            sums = per_object(per_ray, ob)
            vals["depth"] = sums / torch.tensor(ok_count, dtype=torch.float32, device=device).clamp_min(1)
            loss = loss + cfg.depth_weight * sums / n  # the mean over its ok rays x their share of the object's rays
    if lp is not None and any(b.get("patch") for b in bs) and any(nhit):
        keep = [k for k in range(B) if nhit[k] and bs[k].get("patch")]
        p = bs[keep[0]]["patch"]
        if any(bs[k]["patch"] != p or sizes[k] != p * p for k in keep):
            raise ValueError("objects scored together by LPIPS need patches of one size")
        start = torch.cumsum(torch.tensor([0] + sizes[:-1]), 0)
        rows = (start[keep][:, None] + torch.arange(p * p)[None]).to(device)  # (k, P*P) each patch's rays
        pair = full[rows].transpose(1, 2).reshape(-1, 3, p, p), gt[rows].transpose(1, 2).reshape(-1, 3, p, p)
        if patches is not None:
            patches.append(pair)
        else:
            lpv = lp.distance(*pair)
            vals["lpips"] = torch.zeros(B, device=device).index_put((torch.tensor(keep, device=device),), lpv.float())
            loss = loss + cfg.lpips_weight * vals["lpips"]
    aux = {name: v for name, v in out.get("aux_losses", {}).items() if v is not None}
    for name, value in aux.items():
        loss = loss + phase.loss_weights.get(name, 0.0) * value
        vals[name] = value.expand(B)
    if B == 1:
        return loss[0], _with_values(parts, vals, has=nhit, depth_objects=depth_objects)
    has = torch.tensor([h > 0 for h in nhit], device=device)  # an object with no rays to render adds no loss
    total = torch.where(has, loss, torch.zeros_like(loss)).sum()
    return total, _with_values(parts, vals, has=nhit, depth_objects=depth_objects)


def _with_values(parts: list[dict[str, float]], vals: dict[str, torch.Tensor], has: list[int] | None,
                 depth_objects: list[bool] | None = None) -> list[dict[str, float]]:
    """Each object's parts with the (B,) values ``vals`` (one transfer to the host): an object without rays to
    render (``has[k]`` 0) logs only its MSE; 'depth' only where the object had depth to compare with."""
    names = list(vals)
    table = torch.stack([vals[k].detach().float() for k in names]).cpu().tolist() if names else []
    for k, part in enumerate(parts):
        for name, row in zip(names, table):
            if name == "mse_fine" or (has is not None and has[k] and (name != "depth" or depth_objects[k])):
                part[name] = row[k]
    return parts


LPIPS_GROUP = 8
"""With the LPIPS patch loss, objects whose patches are scored as one VGG batch and whose graphs are held until
then (more objects a step go in groups of this many: memory stays bounded on a GPU step of many objects)."""


def patch_lpips(lp, patches: list[tuple[torch.Tensor, torch.Tensor]]) -> torch.Tensor:
    """LPIPS (K,) of a step's K (predicted, true) (1, 3, P, P) patch pairs, scored as one VGG batch (one pair
    at a time costs about K times as much on a CPU: ``models.metrics.LPIPS.distance``)."""
    return lp.distance(torch.cat([a for a, _ in patches]), torch.cat([b for _, b in patches]))


def interval_shares(t: torch.Tensor, far: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(lengths, midpoints) (R, S) of the intervals the samples at distances ``t`` (R, S, sorted) stand for along
    rays of box length ``far`` (R,), as shares of that length: sample i's interval is [t_i, t_{i+1}], the last one
    ends at far (the renderer's steps)."""
    s = torch.cat([t.float(), far.float()[:, None]], -1) / far.float().clamp_min(1e-8)[:, None]
    return (s[:, 1:] - s[:, :-1]).clamp_min(0.0), 0.5 * (s[:, 1:] + s[:, :-1])


def distortion_loss(weights: torch.Tensor, t: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """Mip-NeRF 360's distortion loss, mean over rays: weights (R, S) of samples at distances t (R, S, sorted)
    along rays of length far (R,); sample i stands for the interval [t_i, t_{i+1}] (the last one ends at
    far), as the renderer's steps do. Distances are shares of the ray's length, so the loss does not depend
    on the box's size. sum_ij w_i w_j |m_i - m_j| (m the interval midpoints) + 1/3 sum_i w_i^2 len_i: 0 for
    an empty ray, smallest when the weight sits in one short interval."""
    return distortion_per_ray(weights, t, far).mean()


def distortion_per_ray(weights: torch.Tensor, t: torch.Tensor, far: torch.Tensor) -> torch.Tensor:
    """(R,) :func:`distortion_loss` of each ray."""
    w = weights.float()
    length, mid = interval_shares(t, far)
    inter = (w[:, :, None] * w[:, None, :] * (mid[:, :, None] - mid[:, None, :]).abs()).sum((-1, -2))
    intra = (w * w * length).sum(-1) / 3.0
    return inter + intra


def surface_loss(weights: torch.Tensor, t: torch.Tensor, far: torch.Tensor, t_star: torch.Tensor) -> torch.Tensor:
    """Mean over rays of the expected distance between where the light stops and the surface at ``t_star`` (R,),
    as a share of the ray's box length ``far`` (R,): sample i (weight ``weights`` (R, S) at distance ``t`` (R, S),
    sorted) stops its light in [t_i, t_{i+1}] (the last one ends at far), counted at the interval's midpoint;
    the light no sample stops (1 - sum of the weights) leaves at the far end. 0 only when all the light stops
    at the surface; a translucent ghost spread along the ray, or a surface too far in front or behind, costs
    its distance. Unlike a loss on the expected depth, two layers whose mean sits on the surface still cost."""
    return surface_per_ray(weights, t, far, t_star).mean()


def surface_per_ray(weights: torch.Tensor, t: torch.Tensor, far: torch.Tensor, t_star: torch.Tensor) -> torch.Tensor:
    """(R,) :func:`surface_loss` of each ray."""
    w = weights.float()
    _, mid = interval_shares(t, far)
    ss = (t_star.float() / far.float().clamp_min(1e-8))[:, None]
    leave = (1.0 - w.sum(-1)).clamp_min(0.0) * (1.0 - ss[:, 0]).abs()
    return (w * (mid - ss).abs()).sum(-1) + leave


def opacity_loss(acc: torch.Tensor, mask: torch.Tensor, hit: torch.Tensor) -> torch.Tensor:
    """Binary cross-entropy of the accumulated opacity of the rays that hit the box (``acc``, one per
    True in ``hit``) against the object mask of all rays (``mask``); averaged over all rays, since a ray
    that misses the box has opacity 0 and no loss when the mask agrees (else the constant log(eps))."""
    acc_all = torch.zeros_like(mask, dtype=acc.dtype).index_put((torch.nonzero(hit).flatten(),), acc)
    return opacity_per_ray(acc_all, mask, hit).sum() / mask.numel()


def opacity_per_ray(acc: torch.Tensor, mask: torch.Tensor, hit: torch.Tensor) -> torch.Tensor:
    """(R,) :func:`opacity_loss` of each drawn ray before the mean: ``acc`` (R,) is read where ``hit``; a ray that
    misses the box costs the constant -log(eps) where the mask says object (box too small), else nothing."""
    eps = 1e-4
    a = acc.float().clamp(eps, 1 - eps)
    m = mask.float()
    bce = -(m * torch.log(a) + (1 - m) * torch.log1p(-a))
    return torch.where(hit, bce, m * -math.log(eps))


def init_weights(model: torch.nn.Module, model_cfg: Any, name: str, device: str) -> tuple[Path, list[str]]:
    """Load the weights ``init_checkpoint`` names into a fresh model (fine-tuning); its model file and the
    transformer blocks added when the run config names a deeper copy of its model
    (:func:`checkpoint.load_weights_deepened`). InputError, naming both models, when the checkpoint holds
    another architecture."""
    from .config import resolve_init_checkpoint

    model_file = resolve_init_checkpoint(name)
    theirs = ckpt.read_model_config(model_file)
    if registry.kind_of(theirs) != registry.kind_of(model_cfg):
        raise InputError(f"init_checkpoint {model_file} holds a {registry.kind_of(theirs)} model, the run config a "
                         f"{registry.kind_of(model_cfg)} model; leave the run config's model section out to use the "
                         "checkpoint's own")
    try:
        ckpt.load_weights(model, model_file, device)
    except ckpt.WeightsMismatch:
        try:  # the run config names a deeper copy of the checkpoint's model: grow it
            return model_file, ckpt.load_weights_deepened(model, model_file, device)
        except ckpt.WeightsMismatch:
            raise InputError(f"init_checkpoint {model_file} holds a {theirs.name!r} model whose weights do not fit "
                             f"the run config's {model_cfg.name!r} model (only more transformer blocks of the same "
                             "width can be grown from it); leave the run config's model section out to use the "
                             "checkpoint's own") from None
    return model_file, []


def train_image_size(scenes: list[ObjectScene]) -> int:
    """Median longer image side of the training views as loaded (``train.image_size`` when it is set: every view
    is resized to it when loaded), recorded in checkpoints: synthesis and eval resize larger references to it."""
    sides = [max(s.intrinsics[0].width, s.intrinsics[0].height) for s in scenes if len(s)]
    return int(np.median(sides)) if sides else 0


def param_digest(model: torch.nn.Module) -> str:
    """sha256 of all parameters and buffers (ranks of a data-parallel run must agree)."""
    import hashlib

    h = hashlib.sha256()
    for k, v in model.state_dict().items():
        h.update(k.encode())
        h.update(v.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def _model_words(model_cfg) -> str:
    """'a gpnr model (preset fast)': what a run or a start trains, for messages."""
    name = getattr(model_cfg, "name", None)
    return f"a {registry.kind_of(model_cfg)} model" + (f" (preset {name})" if name else "")


def _same_checkpoint(a: str | None, b: str | None) -> bool:
    if not a or not b:
        return a == b
    return a == b or (not a.startswith("shipped") and Path(a).expanduser().resolve() == Path(b).expanduser().resolve())


def _check_continues(run_dir: Path, found: Path, cfg: TrainConfig, model_cfg) -> None:
    """A start that continues the run in ``run_dir`` must not name another checkpoint to start from: ``--init X``
    into a folder holding a run was not used (the run went on from its own step) while config.json took X's
    settings (a reviewer's GPNR run turned from depth_spacing auto to linear midway, lr 5e-4 to 1e-4). The same
    --init as the run began with (a fine-tune run again after Ctrl-C) continues it."""
    from .config import recorded_train

    if not cfg.init_checkpoint:
        return
    began = (recorded_train(run_dir) or {}).get("init_checkpoint")
    if not _same_checkpoint(str(cfg.init_checkpoint), str(began) if began else None):
        raise InputError(f"the run in {run_dir} (at {found.name}) began from "
                         f"{began if began else 'a random initialisation'}, not --init {cfg.init_checkpoint}, which "
                         "would not be used: continue the run without --init, fine-tune into another --out, or start "
                         "over here with --no-resume --force")


def _check_same_image_size(run_dir: Path, found: Path, cfg: TrainConfig) -> None:
    """A start that continues the run in ``run_dir`` must train at the image size the run began with
    (``train.image_size``; a run recorded before the field trained at 0, the data's own size): the model's weights,
    its checkpoints' ``train_image_size`` and what the loss compares would change size midway."""
    from .config import recorded_train

    began = (recorded_train(run_dir) or {}).get("image_size", 0)
    if isinstance(began, int) and not isinstance(began, bool) and began != cfg.image_size:
        def words(n):
            return f"--image-size {n}" if n else "the views as rendered (--image-size 0)"

        raise InputError(f"the run in {run_dir} (at {found.name}) trains at {words(began)}, not {words(cfg.image_size)}: "
                         f"continue it with --image-size {began}, train at another size into another --out, or start "
                         "over here with --no-resume --force")


def _keep_recorded_seed(run_dir: Path, found: Path, cfg: TrainConfig, main: bool) -> TrainConfig:
    """``cfg`` with the seed the run in ``run_dir`` was started with, when a resume names another: a resume
    restores every generator from its checkpoint, so the seed it names is not used, and config.json and the next
    checkpoints had recorded it all the same (a run seeded 3 and resumed with --seed 5 recorded seed 5 while its
    weights were seed 3's, bit for bit: repeating it with --seed 5 gave other numbers). Said on stderr."""
    from ..models.checkpoint_files import read_header_meta
    from .config import recorded_train

    try:
        rec = json.loads(read_header_meta(found / ckpt.MODEL_FILE).get("train_config") or "{}")
    except (TypeError, ValueError, OSError, InputError):
        rec = {}
    if not isinstance(rec, dict) or "seed" not in rec:
        rec = recorded_train(run_dir) or {}
    seed = rec.get("seed")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0 or seed == cfg.seed:
        return cfg
    if main:
        print(f"note: the run in {run_dir} was started with seed {seed}; it resumes with the random state its checkpoint "
              f"({found.name}) saved, so seed {cfg.seed} is not used: config.json keeps seed {seed} (a run with seed "
              f"{cfg.seed} needs another --out, or --no-resume --force here)", file=sys.stderr)
    return replace(cfg, seed=seed)


def start_record(cfg: TrainConfig, scenes: list[ObjectScene], start: int, found: Path | None, threads: int,
                 device: str, world: int) -> dict[str, Any]:
    """One start's line of the run folder's ``run_record.jsonl`` (also every checkpoint's ``provenance``): where
    it began (step, checkpoint), the seed, the data it trained on (roots, split and the digest of the objects as
    loaded) and :func:`provenance.environment` (version, commit, libraries, threads, command line)."""
    from .provenance import environment, init_record, scenes_digest

    try:
        roots = [str(Path(r).expanduser().resolve()) for r in data_roots(cfg)]
    except InputError:
        roots = []
    return {"start_step": start, "resumed_from": str(found) if found is not None else None,
            "init_checkpoint": init_record(cfg.init_checkpoint), "seed": cfg.seed, "iterations": cfg.iterations,
            "world_size": world,
            "data": {"roots": roots, "split": cfg.split, "format": cfg.data_format or "detected",
                     "weights": list(cfg.data_weights) if cfg.data_weights else None, **scenes_digest(scenes)},
            # this start's settings: config.json holds the latest start's only (a resume may change lr, iterations)
            "train_config": _train_dict(cfg),
            **environment(threads, device)}


def _train_dict(cfg: TrainConfig) -> dict[str, Any]:
    from ..models.config import to_dict

    return to_dict(cfg)


def _note_a_longer_schedule(found: Path, step: int, cfg: TrainConfig, main: bool) -> None:
    """Say so when a run is resumed with another length than it was started with: the learning rate and the
    masking phase follow the new length from the resume step on, so the resumed run is not the one a single
    run of either length would have been (exact resume holds at the same settings)."""
    from ..models.checkpoint_files import read_header_meta

    if not main:
        return
    try:
        rec = json.loads(read_header_meta(found / ckpt.MODEL_FILE).get("train_config") or "{}")
        before = int(rec["iterations"])
    except (KeyError, TypeError, ValueError, OSError, InputError):
        return  # an older checkpoint that did not record it
    if before == cfg.iterations:
        return
    was = replace(cfg, iterations=before)
    print(f"note: the run was started with {before} iterations and resumes at step {step} with {cfg.iterations}: "
          f"the learning rate follows the {cfg.iterations}-step schedule from here ({lr_at(step, was):.3g} at this "
          f"step before, {lr_at(step, cfg):.3g} now)" + (
              f", and masked pretraining ends at step {int(cfg.pretrain_frac * cfg.iterations)} (was "
              f"{int(cfg.pretrain_frac * before)})" if 0 < cfg.pretrain_frac < 1 else ""), file=sys.stderr)


def _cameras_inside_box(scenes: list[ObjectScene], padding: float) -> tuple[int, int]:
    """(views whose camera is inside the box rays are clipped to, i.e. its scene's box as a model pads it, all views):
    a room or a scene filmed from within, where GPNR's depth spacing matters (``models/gpnr``: 'auto')."""
    inside = total = 0
    for s in scenes:
        ns = normalized_scene(s.bbox[0], s.bbox[1], padding)
        off = np.abs((np.asarray(s.c2w)[:, :3, 3] - ns.centre) / ns.scale).max(axis=1)
        inside += int((off <= ns.box).sum())
        total += len(off)
    return inside, total


def _note_linear_depths_inside(model_cfg, cfg: TrainConfig, scenes: list[ObjectScene], padding: float) -> None:
    """Warn when a new GPNR run samples depths 'linear' while its cameras are inside the box (rooms): such a run
    works, but 'auto' (even in inverse depth there) is what room models use, 0.5-0.8 dB better on held-out rooms at
    the same budget (docs/gpnr_rooms.md); the object model (shipped:gpnr) is 'linear', and --init keeps its model, so
    a room fine-tune from it had kept 'linear' silently. Not refused: the weights fit either spacing and a run may
    keep it on purpose (a comparison); a resume keeps the run's model, so only a new start is told."""
    if registry.kind_of(model_cfg) != "gpnr" or getattr(model_cfg, "depth_spacing", None) != "linear":
        return
    inside, total = _cameras_inside_box(scenes, padding)
    if not inside:
        return  # (cameras outside the box: 'auto' is 'linear' there, bit for bit)
    came = f"kept from --init {cfg.init_checkpoint}" if cfg.init_checkpoint else "the model config's"
    print(f"warning: gpnr depth_spacing is 'linear' ({came}), but {inside} of {total} training views have their camera "
          "inside the box (a room): room models use 'auto' (depths even in inverse depth from the camera; +0.5 to "
          "+0.8 dB on held-out rooms, docs/gpnr_rooms.md); to use it, train with a --config holding "
          '{"model": {"overrides": {"depth_spacing": "auto"}}} (the weights fit either)', file=sys.stderr, flush=True)


def _grad_scaler(cfg: TrainConfig, device: str):
    """fp16 autocast's loss scaler (on a GPU only), else None."""
    return torch.amp.GradScaler("cuda") if cfg.amp == "fp16" and device.startswith("cuda") else None


def _save(run_dir, step, model, model_cfg, cfg, opt, batcher, gen, dd: Dist, image_size: int = 0, scaler=None,
          record: dict | None = None):
    my = _rng_state(batcher, gen)
    if dd.world > 1:
        import torch.distributed as dist

        states: list[Any] = [None] * dd.world
        dist.all_gather_object(states, my)
    else:
        states = [my]
    path = None
    if dd.main:
        state = {"step": step, "optimizer": opt.state_dict(), "rng": states, "world_size": dd.world,
                 # fp16: a resume starting again from 65536 would skip steps (inf gradients) until it found its scale
                 **({"grad_scaler": scaler.state_dict()} if scaler is not None else {})}
        path = ckpt.save_checkpoint(run_dir, step, model, model_cfg, state,
                                    {"train_config": json.dumps(run_config_dict(model_cfg, cfg)["train"]),
                                     "train_image_size": str(image_size),
                                     **({"provenance": json.dumps(record, default=str)} if record else {})},
                                    keep=cfg.keep_checkpoints)
    if dd.world > 1:
        import torch.distributed as dist

        dist.barrier()
    return path
