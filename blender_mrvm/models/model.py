"""The generalizable NeRF: encoder + box-clipped samplers + NeRFormer coarse/fine branches + MRVM.

Usage (world units in, world units out)::

    model = GeneralizableNeRF(model_config("balanced"))
    out = model.synthesize(ref_images, ref_c2w, ref_intr, bbox, target_c2w, target_intr)

Internally everything runs in the object's normalised frame (``rays.normalization``): the box is
[-1, 1] on its longest side, rays start at the box entry, rays that miss are background and are not
evaluated, and large renders are evaluated ``render.chunk_rays`` rays at a time (bounded memory).

Two architectures of the branches (``nerformer.arch``): 'nerformer', the paper's per-view token streams
(``models/nerformer_streams.py``, every preset), and 'legacy', one summary token per point along the ray
(``models/nerformer.py``), which configs that predate the field read as (the shipped checkpoint).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from . import samplers
from .config import ModelConfig
from .encoder import ImageEncoder
from .base import NormalizedScene, RayModel, TrainPhase, normalized_scene, ref_cameras  # noqa: F401 (re-exported)
from .mrvm import MRVMHead, coarse_positions, lambda_at, make_mask
from .nerformer import NeRFormerBranch, activate_density, harmonic
from .nerformer_streams import StreamBranch, relative_direction
from .projection import ObjectBatch, ObjectRefs, RefCameras, camera_to_world, project_samples, rays_in_cameras, sample_maps
from .rays import RayBundle
from .renderer import volume_render


@dataclass
class Context(ObjectRefs):
    """Encoded reference views (normalised frame): one object's V views, or B objects' V views each
    (:meth:`RayModel.encode_batch`: rows b*V .. b*V+V-1 are object b's)."""

    feats: torch.Tensor
    """(V, C, h, w) pixel-aligned features ((B * V, ...) for a batch)."""
    images: torch.Tensor
    """(V, 3, H, W) reference colours in [0, 1]."""
    cams: RefCameras
    """Reference cameras."""


class GeneralizableNeRF(RayModel):
    """The NeRFormer+MRVM radiance field (model kind ``nerformer_mrvm``)."""

    kind = "nerformer_mrvm"
    int8_auto = True
    """int8 leaves its views as they are (session 36, docs/bench_int8: the shipped `quality` 20.09 dB / LPIPS 0.214
    on 13 held-out sphere-rig objects in both, a view within 53 dB of its fp32 render)."""

    def __init__(self, cfg: ModelConfig, load_pretrained: bool = True):
        """``load_pretrained`` False skips loading the encoder's ImageNet weights (a checkpoint's come next)."""
        super().__init__()
        self.cfg = cfg
        n = cfg.nerformer
        self.encoder = ImageEncoder(cfg.encoder, load_pretrained=load_pretrained)
        if n.arch == "nerformer":
            self.coarse = StreamBranch(n, cfg.encoder.out_dim, n.n_layers)
            self.fine = self.coarse if n.share_coarse_fine else StreamBranch(n, cfg.encoder.out_dim,
                                                                             n.fine_layers or n.n_layers)
        else:
            self.coarse = NeRFormerBranch(n, cfg.encoder.out_dim)
            self.fine = self.coarse if n.share_coarse_fine else NeRFormerBranch(n, cfg.encoder.out_dim)
        self.mrvm = MRVMHead(n.d_model, cfg.mrvm)

    @property
    def box_padding(self) -> float:
        return self.cfg.sampler.box_padding

    @property
    def white_background(self) -> bool:
        return self.cfg.render.white_background

    @property
    def chunk_rays(self) -> int:
        return self.cfg.render.chunk_rays

    def train_phase(self, step: int, train_cfg) -> TrainPhase:
        """MRVM pretraining (masking, lambda ramp) for the first ``train_cfg.pretrain_frac`` of the run."""
        pretrain_steps = int(round(train_cfg.pretrain_frac * train_cfg.iterations)) if self.cfg.mrvm.enabled else 0
        masking = step < pretrain_steps
        lam = lambda_at(step, pretrain_steps, self.cfg.mrvm)
        return TrainPhase({"mask_views": masking}, {"mrvm": lam}, {"lambda": lam, "masking": masking})

    def after_step(self, phase: TrainPhase) -> None:
        if not phase.kwargs.get("mask_views"):
            return
        # the paper's arch (as the official code) moves the target projector once the MRVM loss is on
        if self.cfg.nerformer.arch == "legacy" or phase.loss_weights.get("mrvm", 0.0) > 0:
            self.mrvm.update_target()

    # -- reference views -------------------------------------------------------------------------

    def encode(self, images: torch.Tensor, cams: RefCameras) -> Context:
        """images (V, 3, H, W) in [0, 1] (white background) -> :class:`Context`."""
        if images.shape[-2:] != (cams.height, cams.width):
            raise ValueError(f"reference images {tuple(images.shape[-2:])} do not match cameras {(cams.height, cams.width)}")
        return Context(self.encoder(images), images, cams)

    supports_object_batch = True

    def _mrvm_loss(self, ctx: Context, fine_rows: torch.Tensor, target_rows: torch.Tensor,
                   ray_of_row: torch.Tensor) -> torch.Tensor:
        """MRVM's loss over the given rows (points) of the fine and target features: their mean, or for a batch of
        objects the mean of each object's mean. ``ray_of_row`` (n,) is each row's ray."""
        if ctx.batch is None or fine_rows.shape[0] == 0:
            return self.mrvm.loss(fine_rows, target_rows)
        per_row = self.mrvm.loss(fine_rows, target_rows, reduce=False)
        obj = ctx.batch.obj[ray_of_row]
        B = ctx.batch.groups
        sums = per_row.new_zeros(B).index_add(0, obj, per_row)
        n = torch.bincount(obj, minlength=B)
        has = n > 0
        return (sums[has] / n[has].to(sums.dtype)).mean()

    # -- points ------------------------------------------------------------------------------------

    def _gather(self, ctx: Context, o_c, d_c, dirs, t, batch: ObjectBatch | None = None):
        """Per (ray, sample, view): token inputs (R, S, V, F), validity (R, S, V), colours (R, S, V, 3); ``batch``
        the rays' object layout (``ctx.batch`` or a subset of it)."""
        uv, valid, p = project_samples(ctx.cams, o_c, d_c, t, batch=batch)
        f = sample_maps(ctx.feats.float(), uv.float(), batch=batch)
        c = sample_maps(ctx.images.float(), uv.float(), batch=batch)
        pn = p / p.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        dref = camera_to_world(ctx.cams, pn, batch)  # camera -> world direction (R^T)
        dt = dirs[None, :, None, :].expand_as(dref)
        enc = torch.cat([harmonic(dt - dref, self.cfg.nerformer.dir_freqs), (dt * dref).sum(-1, keepdim=True)], -1)
        inputs = torch.cat([f, c, enc], -1) * valid[..., None]
        return inputs.permute(1, 2, 0, 3), valid.permute(1, 2, 0), c.permute(1, 2, 0, 3)

    def _branch(self, branch: NeRFormerBranch, gathered, t, far, view_mask=None):
        inputs, valid, rgb = gathered
        return self._rendered(branch(inputs, valid, rgb, t, view_mask), t, far)

    def render_rays(self, ctx: Context, rays: RayBundle, train: bool = False, mask_views: bool = False,
                    generator: torch.Generator | None = None) -> dict:
        """Render rays that hit the box (``rays.hit`` all true). Returns coarse/fine colour, depth (from
        the camera, normalised units), accumulation, and the MRVM loss (or None)."""
        if self.cfg.nerformer.arch == "nerformer":
            return self._render_streams(ctx, rays, train, mask_views, generator)
        sc = self.cfg.sampler
        R = len(rays)
        far = rays.far.float()
        dirs = rays.dirs.float()
        o_c, d_c = rays_in_cameras(ctx.cams, rays.origins, rays.dirs, ctx.batch)
        t_c = samplers.stratified(far, sc.n_coarse, perturb=train and sc.perturb, generator=generator)
        coarse = self._branch(self.coarse, self._gather(ctx, o_c, d_c, dirs, t_c, ctx.batch), t_c, far)
        out = {"coarse": coarse, "fine": coarse, "mrvm_loss": None, "n_masked": 0, "samples": R * t_c.shape[1]}
        sel = self._fine_rays(coarse, train)
        if sel is not None:  # inference: the fine pass only where the coarse pass saw something (if anywhere)

            def fields(rows, t):
                idx = sel[rows]
                inputs, valid, rgb = self._gather(ctx, o_c[:, idx], d_c[:, idx], dirs[idx], t, ctx.rays_of(idx))
                return self.fine(inputs, valid, rgb, t)

            self._fine_at_inference(out, t_c, far, sel, fields)
        elif sc.n_fine > 0:
            t_all, _ = self._fine_samples(coarse["weights"], t_c, far, train, generator)
            g = self._gather(ctx, o_c, d_c, dirs, t_all, ctx.batch)
            point_mask = view_mask = None
            if mask_views:
                point_mask, view_mask = make_mask(R, t_all.shape[1], ctx.views, self.cfg.mrvm, generator,
                                                      device=t_all.device)
            fine = self._branch(self.fine, g, t_all, far, view_mask)
            out["fine"] = fine
            out["samples"] += t_all.numel()
            if mask_views:
                with torch.no_grad():
                    target = self.coarse(g[0], g[1], g[2], t_all)["latent"]
                ray_of_row = torch.nonzero(point_mask)[:, 0]
                out["mrvm_loss"] = self._mrvm_loss(ctx, fine["latent"][point_mask], target[point_mask], ray_of_row)
                out["n_masked"] = int(point_mask.sum())
        return self._finish(out, rays)

    def _fine_rays(self, coarse: dict, train: bool) -> torch.Tensor | None:
        """At inference, the rays (indices) that take the fine pass: those whose coarse opacity reaches
        ``render.fine_min_acc`` (every ray when that is 0; may be empty). None in training, or without a fine
        pass: the fine pass then runs on every ray, at every sample."""
        if train or self.cfg.sampler.n_fine == 0:
            return None
        thr = self.cfg.render.fine_min_acc
        busy = coarse["acc"] >= thr if thr > 0 else torch.ones_like(coarse["acc"], dtype=torch.bool)
        return torch.nonzero(busy).flatten()

    def _fine_at_inference(self, out: dict, t_c, far, sel: torch.Tensor, fields) -> None:
        """The fine pass of rays ``sel`` at inference, into ``out["fine"]`` (the coarse result elsewhere) and
        ``out["samples"]``. ``fields(rows, t)`` is the fine branch's output at samples ``t`` (n, s) of rays
        ``sel[rows]``. When every ray took the whole fine pass, ``out["fine"]`` keeps its per-sample outputs
        (weights, transmittance, latent features), as in training.

        Early ray termination (``render.stop_transmittance`` > 0, :func:`samplers.stop_counts`): a ray's samples
        behind the first coarse sample reached by less light than that are not evaluated and render empty
        (their tiny share of the light goes to the background); rays are evaluated in groups of equal kept
        length (a multiple of an eighth of the samples), so no Python loop runs over rays. Ray attention sees
        only the kept samples, so the fine colour is not bit-identical: ``bench tradeoff --axes stop``
        measures the samples skipped, the time saved and the quality."""
        coarse = out["coarse"]
        if not sel.numel():
            return
        far_s = far[sel]
        sub, _ = self._fine_samples(coarse["weights"][sel], t_c[sel], far_s, False, None)
        n, S = sub.shape
        keep = samplers.stop_counts(t_c[sel], coarse["transmittance"][sel], sub, self.cfg.render.stop_transmittance,
                                    quantum=max(1, S // 8))
        if keep is None:
            fine = self._rendered(fields(torch.arange(n, device=sub.device), sub), sub, far_s)
            out["samples"] += n * S
        else:
            sigma, rgb = sub.new_zeros(n, S), sub.new_zeros(n, S, 3)
            for s in torch.unique(keep).tolist():
                rows = torch.nonzero(keep == s).flatten()
                sg, cl = self._fields(fields(rows, sub[rows, :s]))
                sigma[rows, :s], rgb[rows, :s] = sg.float(), cl.float()
            fine = self._render(sigma, rgb, sub, far_s)
            out["samples"] += int(keep.sum())
        out["fine"] = fine if keep is None and n == len(far) else merge_rays(coarse, fine, sel)

    def _fields(self, branch_out: dict):
        """A branch's activated density and colour."""
        cfg = self.cfg.render
        return activate_density(branch_out["sigma_raw"], cfg.density_activation, cfg.density_bias), branch_out["rgb"]

    def _rendered(self, branch_out: dict, t, far) -> dict:
        """A branch's output at samples ``t`` volume-rendered, with its per-point latent features."""
        ren = self._render(*self._fields(branch_out), t, far)
        ren["latent"] = branch_out["latent"]
        return ren

    def _render(self, sigma, rgb, t, far) -> dict:
        ren = volume_render(sigma, rgb, t, self.cfg.render.white_background, last_delta=(far - t[:, -1]).clamp_min(0))
        ren["t"] = t
        ren["depth_exp"] = (ren["weights"] * t.float()).sum(-1) / ren["acc"].clamp_min(1e-8)
        return ren

    def _fine_samples(self, weights, t_c, far, train: bool, generator):
        """The fine pass's sample distances and their sort order: importance samples of the coarse weights,
        with the coarse samples sorted in when ``sampler.fine_includes_coarse`` (else the order is None)."""
        sc = self.cfg.sampler
        t_f = samplers.sample_pdf(samplers.bin_edges(t_c, far), weights, sc.n_fine,
                                  deterministic=not (train and sc.perturb), eps=sc.pdf_eps, generator=generator)
        if not sc.fine_includes_coarse:
            return t_f, None
        return torch.sort(torch.cat([t_c.detach(), t_f], -1), -1)

    def _finish(self, out: dict, rays: RayBundle) -> dict:
        off = rays.depth_offset.float()
        for k in ("coarse", "fine"):
            out[k]["depth_cam"] = out[k]["depth"] + off
        f = out["fine"]
        out["color"], out["acc"] = f["color"], f["acc"]
        out["depth"] = f["depth_exp"]
        out["aux_heads"] = {"coarse": out["coarse"]} if self.cfg.sampler.n_fine > 0 else {}
        out["aux_losses"] = {"mrvm": out["mrvm_loss"]} if out["mrvm_loss"] is not None else {}
        return out

    # -- the paper's arch ------------------------------------------------------------------------------

    def _gather_streams(self, ctx: Context, o_c, d_c, t, origins, dirs, batch: ObjectBatch | None = None):
        """Per (ray, sample, view) inputs of a :class:`StreamBranch` for samples at distances ``t`` (R, S); ``batch``
        the rays' object layout (``ctx.batch`` or a subset of it)."""
        uv, valid, p = project_samples(ctx.cams, o_c, d_c, t, batch=batch)
        f = sample_maps(ctx.feats.float(), uv.float(), batch=batch)
        c = sample_maps(ctx.images.float(), uv.float(), batch=batch)
        pn = p / p.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        dref = camera_to_world(ctx.cams, pn, batch)  # reference ray direction, world frame (R^T)
        rel = relative_direction(dirs[None, :, None, :].expand_as(dref), dref)
        vf = valid[..., None].to(f.dtype)
        points = origins[:, None, :] + t[..., None] * dirs[:, None, :]
        return {"feats": (f * vf).permute(1, 2, 0, 3), "ref_rgb": (c * vf).permute(1, 2, 0, 3),
                "rel_dir": (rel * vf).permute(1, 2, 0, 3), "valid": valid.permute(1, 2, 0), "points": points,
                "dirs": dirs}

    def _branch_streams(self, branch: StreamBranch, g: dict, t, far, view_mask=None):
        return self._rendered(branch(**g, view_mask=view_mask), t, far)

    def _render_streams(self, ctx: Context, rays: RayBundle, train: bool, mask_views: bool,
                        generator: torch.Generator | None) -> dict:
        """The paper's arch: coarse pass at stratified samples; the fine pass at the sorted union of the coarse
        and importance samples (``sampler.fine_includes_coarse``). MRVM masks the fine pass; its target is the
        coarse pass's feature at its own samples (``mrvm.target`` 'coarse', the paper) or the coarse branch
        re-run on the fine points ('rerun')."""
        sc, mc = self.cfg.sampler, self.cfg.mrvm
        R = len(rays)
        far = rays.far.float()
        dirs = rays.dirs.float()
        origins = rays.origins.float()
        o_c, d_c = rays_in_cameras(ctx.cams, rays.origins, rays.dirs, ctx.batch)
        t_c = samplers.stratified(far, sc.n_coarse, perturb=train and sc.perturb, generator=generator)
        coarse = self._branch_streams(self.coarse, self._gather_streams(ctx, o_c, d_c, t_c, origins, dirs, ctx.batch),
                                      t_c, far)
        out = {"coarse": coarse, "fine": coarse, "mrvm_loss": None, "n_masked": 0, "samples": R * t_c.shape[1]}
        sel = self._fine_rays(coarse, train)
        if sel is not None:  # inference: the fine pass only where the coarse pass saw something (if anywhere)

            def fields(rows, t):
                idx = sel[rows]
                return self.fine(**self._gather_streams(ctx, o_c[:, idx], d_c[:, idx], t, origins[idx], dirs[idx],
                                                        ctx.rays_of(idx)))

            self._fine_at_inference(out, t_c, far, sel, fields)
        elif sc.n_fine > 0:
            t_all, order = self._fine_samples(coarse["weights"], t_c, far, train, generator)
            g = self._gather_streams(ctx, o_c, d_c, t_all, origins, dirs, ctx.batch)
            point_mask = view_mask = None
            if mask_views:
                point_mask, view_mask = make_mask(R, t_all.shape[1], ctx.views, mc, generator, device=t_all.device)
            fine = self._branch_streams(self.fine, g, t_all, far, view_mask)
            out["fine"] = fine
            out["samples"] += t_all.numel()
            if mask_views:
                if mc.target == "coarse":  # validated: the fine pass holds the coarse samples
                    pos = coarse_positions(order, sc.n_coarse)  # (R, n_coarse) index of each coarse sample in t_all
                    online = torch.gather(fine["latent"], 1, pos[..., None].expand(-1, -1, fine["latent"].shape[-1]))
                    ray_of_row = torch.arange(R, device=pos.device).repeat_interleave(pos.shape[1])
                    out["mrvm_loss"] = self._mrvm_loss(ctx, online.reshape(-1, online.shape[-1]),
                                                       coarse["latent"].detach().reshape(-1, online.shape[-1]),
                                                       ray_of_row)
                    out["mrvm_positions"] = pos
                else:
                    with torch.no_grad():
                        target = self.coarse(**g)["latent"]
                    out["mrvm_loss"] = self._mrvm_loss(ctx, fine["latent"][point_mask], target[point_mask],
                                                       torch.nonzero(point_mask)[:, 0])
                out["n_masked"] = int(point_mask.sum())
                out["point_mask"] = point_mask
        return self._finish(out, rays)


def merge_rays(coarse: dict, fine: dict, sel: torch.Tensor) -> dict:
    """The fine result of every ray when the fine pass ran only on rays ``sel``: the coarse one elsewhere
    (per-ray outputs only: colour, depth, opacity; per-sample ones differ in length and are dropped)."""
    out = {}
    for k in ("color", "depth", "acc", "depth_exp"):
        v = coarse[k].clone()
        v[sel] = fine[k].to(v.dtype)
        out[k] = v
    return out
