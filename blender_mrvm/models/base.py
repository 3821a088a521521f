"""What every model kind shares: the object's normalised frame, reference cameras, and images rendered
ray chunk by ray chunk from a kind's ``render_rays`` (the protocol in ``models/registry.py``).

Usage (world units in, world units out), for any kind::

    model = registry.build_model(registry.build_config("gpnr", "fast"))
    out = model.synthesize(ref_images, ref_c2w, ref_intr, bbox, target_c2w, target_intr)

Internally everything runs in the object's normalised frame: the box is [-1, 1] on its longest side,
rays start at the box entry, rays that miss are background and are not evaluated, and large renders
are evaluated ``chunk_rays`` rays at a time (bounded memory).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from itertools import islice
from typing import Any, Sequence

import numpy as np
import torch
from torch import nn

from ..geometry import cameras
from .projection import ObjectBatch, ObjectRefs, RefCameras  # noqa: F401 (ObjectRefs re-exported)
from .rays import RayBundle, make_rays, normalization, normalize_pose, pixel_rows


GPU_CHUNK_RAYS = 1 << 14
"""Rays per forward pass at inference on a GPU, at the least (:meth:`RayModel.inference_chunk`): the configs' chunks
(512 for the NeRFormer presets) are sized for a 2-core CPU, where they bound memory at no cost, but on a GPU a
256 px view then takes ~100 forward passes, each a round of launches and host syncs. 16 384 rays of `accurate`
(the largest shipped preset) hold ~4.5 GB at 256 px (bench model: +18 GB at 65 536 rays); `fast` ~0.4 GB."""

RAY_BLOCK = 1 << 16
"""Pixels whose rays are made at once in :meth:`RayModel.image_chunks` (with ``chunk_rays`` rays per forward
pass, this bounds a view's memory whatever its size; only the output images grow with it)."""


def inference_chunk(chunk_rays: int, device: torch.device, chunk: int | None = None) -> int:
    """Rays per forward pass at inference for a model whose config says ``chunk_rays``, on ``device``: ``chunk`` when
    given (> 0), else ``chunk_rays``, raised to :data:`GPU_CHUNK_RAYS` on a GPU (every model kind's one policy)."""
    if chunk:
        return int(chunk)
    return max(int(chunk_rays), GPU_CHUNK_RAYS) if torch.device(device).type == "cuda" else int(chunk_rays)


def rays_on_host(device: torch.device) -> bool:
    """Whether a view's rays are made in numpy (on the CPU, where numpy is as fast as torch) rather than by torch
    on ``device`` (a GPU: :meth:`RayModel.image_chunks`). Both give the same rays (tests compare them)."""
    return device.type == "cpu"


def check_finite_view(model, **parts: torch.Tensor) -> None:
    """InputError when a rendered view's ``parts`` (colour, opacity, depth, ...) hold NaN or infinite values: a
    model with diverged weights renders nothing but NaN, which an image would store as black (NaN casts to 0) and
    eval.json as NaN. Names the checkpoint the model was loaded from (``model.checkpoint_file``) as probably
    broken. One host sync."""
    if bool(torch.stack([torch.isfinite(v).all() for v in parts.values()]).all()):
        return
    from ..errors import InputError

    bad = [k for k, v in parts.items() if not bool(torch.isfinite(v).all())]
    src = getattr(model, "checkpoint_file", None)
    what = f"checkpoint {src} is" if src else "model's weights are"
    raise InputError(f"the rendered view holds NaN or infinite values ({', '.join(bad)}): the {what} probably "
                     "broken (a training run whose learning rate diverged?); retrain it or use another checkpoint")


@dataclass
class NormalizedScene:
    """A scene moved into the model's frame: box centred, longest half-side 1."""

    centre: np.ndarray
    scale: float
    box: float
    """Half-size of the (padded) cube rays are clipped to, in normalised units."""

    def pose(self, c2w: np.ndarray) -> np.ndarray:
        return normalize_pose(c2w, self.centre, self.scale)


def normalized_scene(bbox_min, bbox_max, padding: float) -> NormalizedScene:
    c, s = normalization(bbox_min, bbox_max)
    return NormalizedScene(c, s, 1.0 + padding)


def ref_cameras(c2w_norm: Sequence[np.ndarray], intr: Sequence[cameras.Intrinsics]) -> RefCameras:
    w2c = np.stack([cameras.invert_pose(c) for c in c2w_norm])
    K = np.stack([i.K for i in intr])
    return RefCameras(torch.from_numpy(w2c), torch.from_numpy(K), int(intr[0].width), int(intr[0].height))


@dataclass
class TrainPhase:
    """What one training step of a model does (from ``model.train_phase``)."""

    kwargs: dict[str, Any] = field(default_factory=dict)
    """Keyword arguments for ``render_rays`` (e.g. MRVM's ``mask_views``)."""
    loss_weights: dict[str, float] = field(default_factory=dict)
    """Weight of each of ``render_rays``' ``aux_losses``."""
    logs: dict[str, Any] = field(default_factory=dict)
    """Values written to metrics.jsonl."""


def rays_to(rays: RayBundle, device) -> RayBundle:
    """The same rays on ``device``."""
    return rays.to(device)


class RayModel(nn.Module):
    """Base class of every model kind: the shared, kind-independent half of the protocol."""

    kind: str = ""
    """Registry key (``models/registry.py``)."""

    # -- what the shared code needs to know of a kind (subclasses map these onto their config) --------

    @property
    def box_padding(self) -> float:
        """The box is grown by this fraction of its half-size on each side before clipping rays."""
        raise NotImplementedError

    @property
    def white_background(self) -> bool:
        return True

    @property
    def chunk_rays(self) -> int:
        """Rays per forward pass at inference."""
        return 512

    def inference_chunk(self, chunk: int | None = None) -> int:
        """Rays per forward pass at inference on this model's device (:func:`inference_chunk`)."""
        return inference_chunk(self.chunk_rays, self.device, chunk)

    @property
    def max_ref_views(self) -> int:
        return int(getattr(self.cfg, "max_ref_views", 10))

    @property
    def min_ref_views(self) -> int:
        return int(getattr(self.cfg, "min_ref_views", 1))

    @property
    def device(self) -> torch.device:
        p = next(self.parameters(), None)
        return p.device if p is not None else torch.device("cpu")

    # -- the per-kind protocol -------------------------------------------------------------------------

    def encode(self, images: torch.Tensor, cams: RefCameras):
        raise NotImplementedError

    def render_rays(self, ctx, rays: RayBundle, train: bool = False, generator: torch.Generator | None = None,
                    **phase) -> dict:
        raise NotImplementedError

    int8_auto = False
    """Whether ``--precision auto`` may give this kind int8 linear layers on the CPU when they are wide enough
    (``models.precision.resolve_precision``): only kinds whose views int8 leaves as they are. Named, int8 runs for
    any kind."""

    supports_object_batch = False
    """Whether training may render several objects' rays in one pass (:meth:`encode_batch`, :meth:`render_rays_batch`,
    ``train.object_batch``): a kind whose context is an :class:`ObjectRefs` and whose ``render_rays`` reads each ray's
    object from ``ctx.batch`` (projection.py's functions take it). Kinds without it train one object at a time."""

    def encode_batch(self, images: list[torch.Tensor], cams: list[RefCameras]):
        """B objects' reference views, each (V, 3, H, W) with the same V and image size, encoded in one pass: the
        context's rows b*V .. b*V+V-1 are object b's (``ctx.groups`` B)."""
        V, (H, W) = len(cams[0]), (cams[0].height, cams[0].width)
        if any(len(c) != V or (c.height, c.width) != (H, W) for c in cams):
            raise ValueError("objects batched in one pass need the same number of reference views and image size")
        merged = RefCameras(torch.cat([c.w2c for c in cams]), torch.cat([c.K for c in cams]), W, H)
        return replace(self.encode(torch.cat(images), merged), groups=len(cams))

    def render_rays_batch(self, ctx, rays: RayBundle, counts: list[int], train: bool = False,
                          generator: torch.Generator | None = None, **phase) -> dict:
        """:meth:`render_rays` of B objects at once: ``ctx`` from :meth:`encode_batch`, ``rays`` object after object,
        ``counts[b]`` of object b (all hit the box). Per-ray outputs are laid out as ``rays``; a kind's auxiliary
        losses weigh each object as in a pass of its own (MRVM's: the mean of the objects' own means)."""
        if len(counts) != ctx.groups or sum(counts) != len(rays):
            raise ValueError(f"{len(counts)} objects with {sum(counts)} rays do not match the context's {ctx.groups} "
                             f"objects and {len(rays)} rays")
        batch = ObjectBatch.from_counts(counts, ctx.views, device=rays.origins.device)
        return self.render_rays(replace(ctx, batch=batch), rays, train=train, generator=generator, **phase)

    def train_phase(self, step: int, train_cfg) -> TrainPhase:
        return TrainPhase()

    def after_step(self, phase: TrainPhase) -> None:
        pass

    # -- shared: reference sets and images ---------------------------------------------------------------

    def check_reference_count(self, n: int) -> None:
        """InputError when ``n`` reference views are fewer or more than this model takes."""
        from ..errors import InputError

        if n < self.min_ref_views:
            raise InputError(f"this {self.kind} model needs at least {self.min_ref_views} reference views, got {n}")
        if n > self.max_ref_views:
            raise InputError(f"this {self.kind} model takes at most {self.max_ref_views} reference views, got {n}")

    def encode_world(self, ref_images: np.ndarray, ref_c2w: Sequence[np.ndarray],
                     ref_intr: Sequence[cameras.Intrinsics], bbox: tuple):
        """(context, normalised scene) for references in world units: ref_images (V, H, W, 3) float in
        [0, 1] on white; OpenCV c2w poses; bbox = (min xyz, max xyz) of the object."""
        ns = normalized_scene(bbox[0], bbox[1], self.box_padding)
        cams = ref_cameras([ns.pose(c) for c in ref_c2w], ref_intr)
        dev = self.device
        cams.w2c, cams.K = cams.w2c.to(dev), cams.K.to(dev)
        imgs = torch.as_tensor(np.asarray(ref_images, np.float32)).permute(0, 3, 1, 2).contiguous().to(dev)
        with torch.no_grad():
            ctx = self.encode(imgs, cams)
        return ctx, ns

    @torch.no_grad()
    def image_chunks(self, ctx, intr: cameras.Intrinsics, c2w_norm: np.ndarray, box: float, chunk: int | None = None,
                     hull=None, skip: str = "off", workers: int = 1):
        """Generator over one view in the normalised frame: yields the rays finished so far in each step
        (misses first, then every chunk), returns dict(color (H, W, 3) on the background, acc (H, W),
        depth (H, W) distance from the camera along the ray to the expected surface (0 where acc = 0),
        rays, box_rays (rays that cross the box), evaluated (rays the model rendered), span (mean
        share of each evaluated ray's box length left to sample), samples (points the model evaluated, where
        its ``render_rays`` counts them in ``"samples"``; 0 otherwise)).

        ``hull`` (:class:`models.hull.Hull`) with ``skip`` "cull" or "tighten": empty-space skipping
        inside the box (``models/hull.py``).

        ``workers`` > 1 renders that many chunks at once on threads (CPU: each chunk's ops on one core,
        ``threads.render_workers``); results are written and yielded in chunk order all the same."""
        from .hull import clip_rays, footprint, footprint_pays

        H, W = int(intr.height), int(intr.width)
        n = H * W
        # On a GPU the rays are made, rendered and gathered there, and the view crosses to the host once at the
        # end: made on the host in numpy, a 256 px view's rays took longer than the model's whole render (session
        # 20's FPS profile spent half of a view outside device work). The hull's marching runs there too (on the
        # host until session 26); the footprint (a splat and distance transform of the view's pixels, on the host)
        # is made on the CPU only: on a GPU marching every box ray is faster (hull.footprint_pays).
        dev = self.device
        skipping = hull is not None and skip != "off"
        keep = None
        if skipping:
            hull = hull.to(dev)  # the model's own hulls are built there
            if footprint_pays(dev):
                keep = footprint(hull, intr, c2w_norm).to(dev)
        bg = 1.0 if self.white_background else 0.0
        color = torch.full((n, 3), bg, device=dev)
        depth = torch.zeros(n, device=dev)
        acc = torch.zeros(n, device=dev)
        chunk = self.inference_chunk(chunk)
        evaluated = samples = 0
        box_rays = torch.zeros((), dtype=torch.int64, device=dev)
        span = torch.zeros((), dtype=torch.float64, device=dev)
        rows = max(1, RAY_BLOCK // W)  # rays are made a block of rows at a time: memory does not grow with the view
        workers = int(workers) if self.device.type == "cpu" else 1  # a GPU takes one chunk at a time
        for r0 in range(0, H, rows):
            r1 = min(H, r0 + rows)
            pixels = pixel_rows(r0, r1, W, None if rays_on_host(dev) else dev)
            rays = make_rays(intr, c2w_norm, pixels.numpy() if rays_on_host(dev) else pixels, box=box)
            base = r0 * W
            box_rays += rays.hit.sum()
            box_far = rays.far
            if skipping:
                rays = clip_rays(rays, hull, skip, keep=None if keep is None else keep[base:base + len(rays)],
                                 workers=workers)
            idx = torch.nonzero(rays.hit).flatten()
            yield len(rays) - idx.numel()
            sels = [idx[s:s + chunk] for s in range(0, idx.numel(), chunk)]
            for sel, sub, o in self._chunk_results(ctx, rays, sels, workers):
                a = o["acc"].float()
                out = sel.to(dev) + base
                color[out] = o["color"].float().to(dev)
                acc[out] = a.to(dev)
                depth[out] = torch.where(a > 0, o["depth"].float() + sub.depth_offset.float(), torch.zeros_like(a)).to(dev)
                samples += int(o.get("samples", 0))
                yield sel.numel()
            evaluated += int(idx.numel())
            span += (rays.far[idx] / box_far[idx].clamp_min(1e-12)).sum()
        span = float(span) / evaluated if evaluated else 0.0
        check_finite_view(self, colour=color, opacity=acc, depth=depth)
        return {"color": color.view(H, W, 3).clamp(0, 1).cpu(), "depth": depth.view(H, W).cpu(),
                "acc": acc.view(H, W).clamp(0, 1).cpu(), "rays": n, "box_rays": int(box_rays), "evaluated": evaluated,
                "span": span, "samples": samples}

    def _chunk_results(self, ctx, rays: RayBundle, sels: list, workers: int):
        """(sel, rays, outputs) of each chunk of ray indices in ``sels``, in order. With ``workers`` > 1 they
        render on a thread pool, up to twice as many chunks in flight as workers (torch's ops release the
        GIL, so they run side by side); a caller that stops early (Esc) waits only for those."""
        dev = self.device
        # grad mode and autocast are per thread: a worker takes the caller's (bf16 on the CPU ran the networks in
        # fp32 on every thread but the caller's: the views depended on --threads)
        cast = torch.is_autocast_enabled(dev.type)
        cast_dtype = torch.get_autocast_dtype(dev.type) if cast else None

        def one(sel):
            sub = rays_to(rays.select(sel), dev)
            with torch.no_grad(), torch.autocast(dev.type, dtype=cast_dtype, enabled=cast):
                return sub, self.render_rays(ctx, sub)

        if workers <= 1:
            for sel in sels:
                yield (sel, *one(sel))
            return
        todo = iter(sels)
        with ThreadPoolExecutor(workers, thread_name_prefix="mrvm-chunk") as pool:
            pending = deque((sel, pool.submit(one, sel)) for sel in islice(todo, 2 * workers))
            while pending:
                sel, fut = pending.popleft()
                sub, o = fut.result()
                nxt = next(todo, None)
                if nxt is not None:
                    pending.append((nxt, pool.submit(one, nxt)))
                yield sel, sub, o

    def hull(self, ctx, ref_masks: np.ndarray, box: float):
        """The references' visual hull (``models/hull.py``) for ``ctx`` (which holds the cameras), on the model's
        device."""
        from .hull import build_hull

        return build_hull(ref_masks, ctx.cams, box).to(self.device)

    def world_hull(self, masks: np.ndarray, c2w: Sequence[np.ndarray], intr: Sequence[cameras.Intrinsics],
                   bbox: tuple):
        """The visual hull of any posed views' object ``masks`` (V, H, W) bool, one size, in this model's frame
        for the box ``bbox`` (world units): views need not be the encoded references, and every mask given only
        tightens it (a dense capture carves with all its photos while a view is rendered from its nearest)."""
        from .hull import build_hull

        ns = normalized_scene(bbox[0], bbox[1], self.box_padding)
        return build_hull(masks, ref_cameras([ns.pose(c) for c in c2w], intr), ns.box).to(self.device)

    @torch.no_grad()
    def render_image(self, ctx, intr: cameras.Intrinsics, c2w_norm: np.ndarray, box: float,
                     chunk: int | None = None, hull=None, skip: str = "off", workers: int = 1) -> dict:
        """A full view (normalised frame), chunk by chunk; misses are background, not evaluated."""
        gen = self.image_chunks(ctx, intr, c2w_norm, box, chunk, hull, skip, workers)
        while True:
            try:
                next(gen)
            except StopIteration as stop:
                return stop.value

    @torch.no_grad()
    def synthesize(self, ref_images: np.ndarray, ref_c2w: Sequence[np.ndarray], ref_intr: Sequence[cameras.Intrinsics],
                   bbox: tuple, target_c2w: np.ndarray, target_intr: cameras.Intrinsics, chunk: int | None = None,
                   ref_masks: np.ndarray | None = None, skip: str = "off", workers: int = 1, hull=None) -> dict:
        """Novel view in world units (see :meth:`encode_world`). Depth is along the ray, world units.

        ``ref_masks`` (V, H, W) bool object masks of the references with ``skip`` "cull" or "tighten":
        empty-space skipping inside the box through their visual hull (``models/hull.py``); ``hull`` (from
        :meth:`world_hull`) is used instead when given. ``workers``: chunks rendered at once
        (:meth:`image_chunks`)."""
        ctx, ns = self.encode_world(ref_images, ref_c2w, ref_intr, bbox)
        if skip == "off":
            hull = None
        elif hull is None and ref_masks is not None:
            hull = self.hull(ctx, ref_masks, ns.box)
        out = self.render_image(ctx, target_intr, ns.pose(target_c2w), ns.box, chunk, hull, skip, workers)
        out["depth"] = out["depth"] * ns.scale
        return out
