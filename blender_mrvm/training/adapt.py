"""Adapting a trained model to one scene's references before it renders (test-time fine-tuning).

A generalizable model renders a new object from what it learnt on others; a few optimizer steps on the
object's own references can fit what it got wrong about this one (IBRNet and GeoNeRF fine-tune per scene;
with few references there is no held-out view, so each step holds one reference out: it is the target
and the others are the inputs, leave one out). Only the references are used, never the views to render,
so an evaluation with adaptation is still a few-shot evaluation.

The steps are the trainer's own (``trainer.RayBatcher`` over a scene made of the references, with the
reference count fixed at N - 1, and ``trainer.object_loss``), on a copy of the model: the caller's model
is never changed. Any model kind; a scene needs at least two references.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from ..errors import InputError
from ..progress import Progress


PAYS_FROM = 5
"""Fewest references with which adaptation was measured to pay (``docs/adapt.md``: 13 held-out objects, 100
steps): with 2 it lost 0.6 dB, with 3 and 4 it moved nothing beyond noise, with 5 it gained 0.4 dB and with 10
1.1 dB (each step renders one reference from the others: the fewer there are, the less that task is like the
render)."""


def few_references_note(n_refs: int) -> str:
    """A note for a user adapting to fewer than :data:`PAYS_FROM` references ('' otherwise)."""
    if n_refs >= PAYS_FROM:
        return ""
    return (f"adapting to {n_refs} references: each step renders one of them from the other{'s' if n_refs > 2 else ''}; "
            f"measured on held-out objects it lost 0.6 dB with 2 references and changed nothing beyond noise with 3 "
            f"or 4, while it gained with {PAYS_FROM} or more (docs/adapt.md); consider --adapt-steps 0")


MAX_LR = 1e-2
"""The largest ``--adapt-lr``: measured from 5e-5 to 2e-4 (``docs/adapt.md``; 2e-4 already lost 1.5 dB with two
references), and at 1 a few steps wiped the view (opacity collapsed at a finite loss): 0.01 leaves room to try
higher rates without accepting ones that only destroy the model."""


@dataclass(frozen=True)
class AdaptConfig:
    """How a model adapts to a scene's references (``steps`` 0 = it does not)."""

    steps: int = 0
    """Optimizer steps (each: one reference held out as the target, the others as inputs)."""
    lr: float = 5e-5
    """Peak AdamW learning rate (a short linear warm-up, then cosine decay to a twentieth)."""
    rays: int = 512
    """Target rays per step (ignored with ``lpips_weight``: then one 16 x 16 patch)."""
    opacity_weight: float = 0.1
    """Opacity loss against the references' object masks, where there are masks (0 = off)."""
    lpips_weight: float = 0.0
    """LPIPS patch loss (needs the offline LPIPS weights; 0 = off)."""
    seed: int = 0
    """Seed of the drawn rays (the same references and seed give the same adapted model)."""

    def __post_init__(self) -> None:
        from .. import validation as V

        V.check_count("--adapt-steps", self.steps, 0, 100000)
        V.check_count("--adapt-rays", self.rays, 1, 1 << 20)
        for name, v, hi in (("--adapt-lr", self.lr, MAX_LR), ("adaptation opacity weight", self.opacity_weight, 100.0),
                            ("--adapt-lpips", self.lpips_weight, 100.0)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and 0 <= v <= hi):
                raise InputError(f"{name} must be a number between 0 and {hi:g}, got {v!r}")
        if self.lr == 0 and self.steps:
            raise InputError("--adapt-lr must be above 0 when --adapt-steps is")

    @property
    def on(self) -> bool:
        return self.steps > 0


def _train_config(acfg: AdaptConfig, inputs: int, has_masks: bool):
    """The trainer's settings for adaptation steps with ``inputs`` references each."""
    from .config import TrainConfig

    return TrainConfig(iterations=acfg.steps, pretrain_frac=0.0, objects_per_step=1, rays_per_object=acfg.rays,
                       min_ref_views=inputs, max_ref_views=inputs, bbox_sampling_frac=0.0, lr=acfg.lr,
                       lr_warmup=max(1, min(20, acfg.steps // 10)), seed=acfg.seed,
                       opacity_weight=acfg.opacity_weight if has_masks else 0.0, lpips_weight=acfg.lpips_weight)


def adapt(model, images: np.ndarray, c2w: Sequence[np.ndarray], intr: Sequence, bbox,
          acfg: AdaptConfig, masks: np.ndarray | None = None, background: str = "white", lpips=None,
          max_refs: int = 0):
    """Progress generator; returns a copy of ``model`` fine-tuned on the references (in eval mode).

    ``images`` (N, H, W, 3) float in [0, 1], ``c2w`` / ``intr`` per reference, ``bbox`` the scene's box (as
    ``model.synthesize`` takes them), ``masks`` (N, H, W) object masks or None, ``background`` the data's
    ("white" objects or a "scene"); ``lpips``: a :class:`models.metrics.LPIPS` when ``acfg.lpips_weight`` > 0
    (built here otherwise); ``max_refs``: each step renders its held-out reference from at most this many
    others, its nearest when there are more (0 = as many as the model takes; synthesis passes the count each
    target is rendered from).
    ``acfg.steps`` 0 returns the model itself."""
    from ..datasets.loaders import ObjectScene
    from . import trainer

    if not acfg.on:
        return model
    n = len(images)
    if n < 2:
        raise InputError(f"adapting to the references holds one out as the target and needs at least 2 references "
                         f"(got {n}); set the adaptation steps to 0")
    images = np.ascontiguousarray(np.asarray(images, np.float32)[..., :3])
    scene = ObjectScene(name="references", category="", images=images,
                        c2w=np.stack([np.asarray(c, np.float64) for c in c2w]), intrinsics=list(intr),
                        bbox=(np.asarray(bbox[0], np.float64), np.asarray(bbox[1], np.float64)),
                        view_ids=list(range(n)), masks=None if masks is None else np.asarray(masks, bool),
                        background=background)
    inputs = min(n - 1, max_refs or model.max_ref_views)
    cfg = _train_config(acfg, inputs, masks is not None)
    if cfg.lpips_weight > 0 and lpips is None:
        from ..models.metrics import LPIPS

        lpips = LPIPS()
    device = model.device
    if lpips is not None:
        lpips = lpips.to(device)
    m = copy.deepcopy(model)
    params = [p for p in m.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(params, lr=cfg.lr, weight_decay=0.0)
    # Fewer inputs than the others: each step's held-out reference takes its nearest, as views then render.
    batcher = trainer.RayBatcher([scene], cfg, m.box_padding, acfg.seed * 7919 + 17, nearest=inputs < n - 1)
    gen = torch.Generator(device=device).manual_seed(acfg.seed * 104729 + 17)
    fork = torch.random.fork_rng(devices=[device.index or 0] if device.type == "cuda" else [])
    with fork:  # the caller's global RNG is left as it was
        torch.manual_seed(acfg.seed)
        for step in range(cfg.iterations):
            m.train()
            for g in opt.param_groups:
                g["lr"] = trainer.lr_at(step, cfg)
            phase = m.train_phase(step, cfg)
            opt.zero_grad(set_to_none=True)
            loss, _ = trainer.object_loss(m, batcher.draw(False), cfg, phase, gen, device,
                                          lpips if cfg.lpips_weight > 0 else None)
            if not torch.isfinite(loss.detach()):
                raise InputError(f"adapting to the references diverged at step {step + 1} (loss {float(loss.detach())}); "
                                 "lower the adaptation learning rate")
            if loss.requires_grad:
                loss.backward()
                torch.nn.utils.clip_grad_norm_(params, 1.0)
                opt.step()
            yield Progress(step + 1, cfg.iterations, f"adapting: loss {float(loss.detach()):.4f}")
    m.eval()
    for p in m.parameters():
        p.requires_grad_(False)
    return m


def add_arguments(p) -> None:
    """The ``--adapt-*`` command-line arguments (eval and synthesize)."""
    d = AdaptConfig()
    p.add_argument("--adapt-steps", type=int, default=d.steps,
                   help="fine-tune a copy of the model on the references alone before rendering, this many steps "
                   "(each holds one reference out as the target; needs 2+ references, pays with 5+; 0 = off, the "
                   "default; training/adapt.py)")
    p.add_argument("--adapt-lr", type=float, default=d.lr,
                   help=f"peak learning rate of --adapt-steps (default {d.lr:g}; measured from 5e-5 to 2e-4, "
                        f"docs/adapt.md; at most {MAX_LR:g}: higher rates wipe the view)")
    p.add_argument("--adapt-rays", type=int, default=d.rays, help=f"target rays per adaptation step (default {d.rays})")
    p.add_argument("--adapt-lpips", type=float, default=d.lpips_weight,
                   help="LPIPS patch loss weight while adapting (0 = off, the default; needs the offline weights)")


def from_args(args) -> AdaptConfig:
    """The :class:`AdaptConfig` of the ``--adapt-*`` arguments (checked: a bad value is an InputError)."""
    return AdaptConfig(steps=args.adapt_steps, lr=args.adapt_lr, rays=args.adapt_rays, lpips_weight=args.adapt_lpips)
