"""GPNR (model kind ``gpnr``): a target ray's colour straight from patches on its epipolar lines.

For a target ray, M depths t_m between the object's box entry and exit (linear, or even in inverse
depth from a near plane when the camera is inside the box, e.g. a room: ``cfg.depth_spacing``) are
projected into each of the K reference views (``models/projection.py``, float64-exact camera frames,
points behind a camera or outside its image masked). Around every projection a patch is read through a linear patch embedding
(a p x p convolution of the reference image, computed once per reference set and read bilinearly at
the projection, which equals embedding the bilinearly resampled patch). Each patch token is

    f0 = [patch embedding || reference colour || ray code || position code || camera code]

- ray code: harmonic code of the Plücker coordinates (d, c x d) of the reference ray through the patch;
- position code: the depth t_m along the target ray (or, without coordinate canonicalization, the
  sample's xyz);
- camera code: the reference camera's pose (rotation, harmonic code of its centre).

With canonicalization (the default) all of these are expressed in the target ray's frame: origin at
the target camera centre, z along the ray, y from the target camera's up vector. A rigid motion of the
whole scene then changes none of the inputs, so the rendering is invariant to it; uniform scale is
removed by the box normalisation every kind shares. The target ray itself becomes the same ray for
every pixel, so its token is a learned query.

Three transformers (Suhail et al., appendix): a patch-feature encoder (attention across the views at
the same depth), an epipolar aggregator (attention along each view's line, with the query token;
softmax weights alpha_k^m over depths) and a reference-view aggregator (attention across views, with
the query; softmax weights beta_k). Colour = sum_k beta_k sum_m alpha_k^m c_k^m, a convex combination
of reference pixel colours (or, for the ablation, predicted from the aggregated feature). The same
weights give an expected depth; an opacity head (our addition, trained by the opacity loss when masks
exist) gives the image planes' alpha. A sample no view sees has alpha 0; a view with no valid sample
has beta 0; a ray no view sees is background, never NaN.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from .. import samplers
from ..base import RayModel
from ..encoder import IMAGENET_MEAN, IMAGENET_STD, per_view
from ..nerformer import Block, harmonic, harmonic_dim
from ..projection import ObjectRefs, RefCameras, project_samples, rays_in_cameras, sample_maps
from ..rays import RayBundle
from .config import GPNRConfig


@dataclass
class GPNRContext(ObjectRefs):
    """Encoded reference views (normalised frame); B objects' in turn for a batch (``RayModel.encode_batch``)."""

    patches: torch.Tensor
    """(V, patch_dim, H, W) linear patch embedding at every pixel."""
    images: torch.Tensor
    """(V, 3, H, W) reference colours in [0, 1]."""
    cams: RefCameras
    """Reference cameras."""


def masked_softmax(logits: torch.Tensor, valid: torch.Tensor, dim: int) -> torch.Tensor:
    """Softmax over ``dim`` of the valid entries; invalid entries get 0, and a slice with no valid entry
    is all 0 (never NaN)."""
    x = logits.float().masked_fill(~valid, float("-inf"))
    m = x.amax(dim, keepdim=True)
    m = torch.where(torch.isfinite(m), m, torch.zeros_like(m))
    e = torch.exp(x - m) * valid
    return e / e.sum(dim, keepdim=True).clamp_min(1e-30)


def canonical_frames(origins: torch.Tensor, dirs: torch.Tensor, up: torch.Tensor | None) -> torch.Tensor:
    """(R, 3, 3) rotations whose rows are the target ray's frame axes (x, y, z = the ray direction, y from
    the camera's up vector), so ``R @ (p - origin)`` is p in that frame. Degenerate up vectors (parallel
    to the ray) fall back to a fixed axis."""
    d = dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    if up is None:
        up = torch.zeros_like(d)
        up[:, 2] = 1.0
    u = up - (up * d).sum(-1, keepdim=True) * d
    n = u.norm(dim=-1, keepdim=True)
    alt = torch.zeros_like(d)
    alt[torch.arange(d.shape[0]), d.abs().argmin(-1)] = 1.0
    alt = alt - (alt * d).sum(-1, keepdim=True) * d
    u = torch.where(n > 1e-6, u, alt)
    y = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x = torch.cross(y, d, dim=-1)
    return torch.stack([x, y, d], dim=1)


class GPNR(RayModel):
    """The light-field transformer; see the module doc."""

    kind = "gpnr"
    int8_auto = False
    """int8 moves its views a little (session 36, docs/bench_int8: the room model's view 30 dB from its fp32 render,
    -0.04 dB and LPIPS +0.0007 on 6 held-out rooms, for 1.19x), so ``auto`` keeps fp32; ``--precision int8`` asks."""
    supports_object_batch = True
    blends_references = True
    """Colour is a blend of reference pixels: the background only fills rays no reference sees
    (``models/background.py``)."""

    def __init__(self, cfg: GPNRConfig):
        super().__init__()
        self.cfg = cfg
        d = cfg.d_model
        self.patch_embed = nn.Conv2d(3, cfg.patch_dim, cfg.patch_size, padding=cfg.patch_size // 2,
                                     padding_mode="replicate")
        self.ray_dim = harmonic_dim(6, cfg.ray_freqs)
        self.pos_dim = harmonic_dim(1 if cfg.canonicalize_coords else 3, cfg.depth_freqs)
        self.cam_dim = 9 + harmonic_dim(3, cfg.camera_freqs)
        self.token_in = nn.Sequential(nn.Linear(cfg.patch_dim + 3 + self.ray_dim + self.pos_dim + self.cam_dim, d),
                                      nn.GELU(), nn.Linear(d, d))
        self.query = nn.Parameter(torch.randn(d) * 0.02)
        self.query_in = None if cfg.canonicalize_rays else nn.Linear(harmonic_dim(6, cfg.ray_freqs), d)
        blocks = lambda: nn.ModuleList(Block(d, cfg.n_heads, cfg.ffn_mult) for _ in range(cfg.n_blocks))  # noqa: E731
        self.patch_encoder = blocks()
        self.epipolar = blocks()
        self.view_agg = blocks()
        self.norm_e, self.norm_v = nn.LayerNorm(d), nn.LayerNorm(d)
        self.alpha_head = nn.Linear(2 * d, 1)
        self.beta_head = nn.Linear(2 * d, 1)
        self.view_in = nn.Linear(d, d)
        self.rgb_head = nn.Linear(d, 3) if cfg.colour_from == "features" else None
        self.opacity = nn.Sequential(nn.Linear(d, d), nn.GELU(), nn.Linear(d, 1)) if cfg.opacity_head else None
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)

    # -- protocol -----------------------------------------------------------------------------------

    @property
    def box_padding(self) -> float:
        return self.cfg.box_padding

    @property
    def white_background(self) -> bool:
        return self.cfg.white_background

    @property
    def chunk_rays(self) -> int:
        return self.cfg.chunk_rays

    def encode(self, images: torch.Tensor, cams: RefCameras) -> GPNRContext:
        """images (V, 3, H, W) in [0, 1] -> :class:`GPNRContext` (the patch embedding of every pixel)."""
        if images.shape[-2:] != (cams.height, cams.width):
            raise ValueError(f"reference images {tuple(images.shape[-2:])} do not match cameras {(cams.height, cams.width)}")
        return GPNRContext(per_view(self._embed, images), images, cams)  # one view at a time without gradients

    def _embed(self, images: torch.Tensor) -> torch.Tensor:
        """(V, 3, H, W) in [0, 1] -> (V, patch_dim, H, W) patch embedding (each view on its own)."""
        return self.patch_embed((images - self.mean.to(images.dtype)) / self.std.to(images.dtype))

    def sample_depths(self, rays: RayBundle, train: bool = False,
                      generator: torch.Generator | None = None) -> torch.Tensor:
        """(R, M) depths from the box entry (``cfg.depth_spacing``): linear between entry and exit, or even
        in inverse depth from the near plane to the exit ('auto': the latter for rays whose camera is inside
        the box, i.e. starts at its entry)."""
        cfg = self.cfg
        perturb = train and cfg.perturb
        far = rays.far.float()
        if cfg.depth_spacing == "linear":
            return samplers.stratified(far, cfg.n_samples, perturb=perturb, generator=generator)
        if cfg.depth_spacing == "auto":
            inside = rays.depth_offset <= 0
            if not bool(inside.any()):
                return samplers.stratified(far, cfg.n_samples, perturb=perturb, generator=generator)
            if not bool(inside.all()):
                lin = samplers.stratified(far, cfg.n_samples, perturb=perturb, generator=generator)
                disp = samplers.disparity(rays.far, rays.depth_offset, cfg.near, cfg.n_samples, perturb, generator)
                return torch.where(inside[:, None].to(lin.device), disp, lin)
        return samplers.disparity(rays.far, rays.depth_offset, cfg.near, cfg.n_samples, perturb, generator)

    def render_rays(self, ctx: GPNRContext, rays: RayBundle, train: bool = False,
                    generator: torch.Generator | None = None) -> dict:
        """Rays that hit the box -> colour (R, 3) on the background, acc (R,), depth (R,) from the box entry,
        and the attention weights alpha (R, V, M), beta (R, V) and the colour weights (R, V, M)."""
        cfg = self.cfg
        R, V, batch = len(rays), ctx.views, ctx.batch
        t = self.sample_depths(rays, train, generator)  # (R, M)
        M = t.shape[1]
        o_c, d_c = rays_in_cameras(ctx.cams, rays.origins, rays.dirs, batch)
        uv, valid, _ = project_samples(ctx.cams, o_c, d_c, t, batch=batch)  # (V, R, M, 2), (V, R, M)
        uvf = uv.float()
        patch = sample_maps(ctx.patches.float(), uvf, batch=batch).permute(1, 2, 0, 3)  # (R, M, V, P)
        rgb = sample_maps(ctx.images.float(), uvf, cfg.colour_filter, batch).permute(1, 2, 0, 3)  # (R, M, V, 3)
        if cfg.colour_filter != "bilinear":
            rgb = rgb.clamp(0.0, 1.0)  # bicubic overshoots at edges; the colour stays a blend of [0, 1] values
        valid = valid.permute(1, 2, 0)  # (R, M, V)

        # Geometry in float64, then the frame the codes are expressed in.
        cam_o = (rays.origins.double() - rays.depth_offset.double()[:, None] * rays.dirs.double())  # camera centres
        t_cam = t.double() + rays.depth_offset.double()[:, None]  # depth from the target camera
        pts = cam_o[:, None, :] + t_cam[..., None] * rays.dirs.double()[:, None, :]  # (R, M, 3)
        Cw = ctx.cams.centres.double()  # (V, 3), each ray's own object's (R, V, 3) for a batch
        Rc2w = ctx.cams.w2c[:, :3, :3].double().transpose(1, 2)  # (V, 3, 3) reference camera-to-world rotations
        Cw = Cw[None] if batch is None else batch.per_ray(Cw).transpose(0, 1)
        Rc2w = Rc2w[None] if batch is None else batch.per_ray(Rc2w).transpose(0, 1)  # (1 or R, V, 3, 3)
        frame = canonical_frames(rays.origins.double(), rays.dirs.double(), rays.up.double() if rays.up is not None else None)
        eye = torch.eye(3, dtype=torch.float64, device=frame.device).expand(R, 3, 3)
        rot_r = frame if cfg.canonicalize_rays else eye
        org_r = cam_o if cfg.canonicalize_rays else torch.zeros_like(cam_o)
        rot_c = frame if cfg.canonicalize_coords else eye
        org_c = cam_o if cfg.canonicalize_coords else torch.zeros_like(cam_o)

        # 1. ray code: Plücker coordinates of the reference ray through each sample.
        C_r = torch.einsum("rij,rvj->rvi", rot_r, Cw - org_r[:, None])  # (R, V, 3)
        P_r = torch.einsum("rij,rmj->rmi", rot_r, pts - org_r[:, None])  # (R, M, 3)
        dref = P_r[:, :, None, :] - C_r[:, None, :, :]  # (R, M, V, 3)
        dref = dref / dref.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        moment = torch.cross(C_r[:, None].expand_as(dref), dref, dim=-1)
        ray_code = harmonic(torch.cat([dref, moment], -1).float(), cfg.ray_freqs)
        # 2. position code: depth along the target ray (canonical) or the sample's xyz.
        if cfg.canonicalize_coords:
            pos = t_cam[..., None].float()
        else:
            pos = pts.float()
        pos_code = harmonic(pos, cfg.depth_freqs)[:, :, None, :].expand(R, M, V, self.pos_dim)
        # 3. camera code: the reference camera's pose in the chosen frame.
        C_c = torch.einsum("rij,rvj->rvi", rot_c, Cw - org_c[:, None])  # (R, V, 3)
        R_c = (torch.einsum("rij,vjk->rvik", rot_c, Rc2w[0]) if batch is None
               else torch.einsum("rij,rvjk->rvik", rot_c, Rc2w)).reshape(R, V, 9)
        cam_code = torch.cat([R_c.float(), harmonic(C_c.float(), cfg.camera_freqs)], -1)[:, None].expand(R, M, V, self.cam_dim)

        vmask = valid[..., None].float()
        tok = self.token_in(torch.cat([patch * vmask, rgb * vmask, ray_code, pos_code, cam_code], -1))  # (R, M, V, d)
        d = tok.shape[-1]
        # Patch-feature encoder: attention across the views at the same depth.
        x = tok.reshape(R * M, V, d)
        kv = valid.reshape(R * M, V)
        for blk in self.patch_encoder:
            x = blk(x, kv)
        x = x.reshape(R, M, V, d).permute(0, 2, 1, 3)  # (R, V, M, d)
        # Epipolar aggregator: along each view's line, with the query token first.
        q = self.query.to(x.dtype).expand(R, d)
        if self.query_in is not None:  # without ray canonicalization the target ray is an input
            q = q + self.query_in(harmonic(torch.cat([rays.dirs, torch.cross(cam_o, rays.dirs.double(), dim=-1)], -1).float(),
                                           cfg.ray_freqs))
        seq = torch.cat([q[:, None, None, :].expand(R, V, 1, d), x], 2).reshape(R * V, M + 1, d)
        valid_vm = valid.permute(0, 2, 1)  # (R, V, M)
        kv = torch.cat([torch.ones_like(valid_vm[..., :1]), valid_vm], -1).reshape(R * V, M + 1)
        for blk in self.epipolar:
            seq = blk(seq, kv)
        seq = self.norm_e(seq).reshape(R, V, M + 1, d)
        q_e, keys = seq[:, :, :1], seq[:, :, 1:]
        a_logit = self.alpha_head(torch.cat([q_e.expand_as(keys), keys], -1))[..., 0]
        if not train and cfg.alpha_temperature != 1.0:
            a_logit = a_logit / cfg.alpha_temperature
        alpha = masked_softmax(a_logit, valid_vm, -1)  # (R, V, M)
        feat_v = (alpha[..., None] * keys).sum(2)  # (R, V, d)
        col_v = (alpha[..., None] * rgb.permute(0, 2, 1, 3)).sum(2)  # (R, V, 3)
        dep_v = (alpha * t[:, None, :]).sum(2)  # (R, V)
        view_ok = valid_vm.any(-1)  # (R, V)
        # Reference-view aggregator: across views, with the query token first.
        seq = torch.cat([q[:, None, :], self.view_in(feat_v)], 1)
        kv = torch.cat([torch.ones_like(view_ok[:, :1]), view_ok], -1)
        for blk in self.view_agg:
            seq = blk(seq, kv)
        seq = self.norm_v(seq)
        q_v, keys_v = seq[:, :1], seq[:, 1:]
        b_logit = self.beta_head(torch.cat([q_v.expand_as(keys_v), keys_v], -1))[..., 0]
        if not train and cfg.beta_temperature != 1.0:
            b_logit = b_logit / cfg.beta_temperature
        beta = masked_softmax(b_logit, view_ok, -1)  # (R, V)
        seen = view_ok.any(-1)  # (R,)
        bg = 1.0 if cfg.white_background else 0.0
        if self.rgb_head is None:
            color = (beta[..., None] * col_v).sum(1)
        else:
            color = torch.sigmoid(self.rgb_head((beta[..., None] * keys_v).sum(1)).float())
        color = torch.where(seen[:, None], color, torch.full_like(color, bg))
        if self.opacity is not None:
            acc = torch.sigmoid(self.opacity(q_v[:, 0]).float()[..., 0])
        else:
            acc = torch.ones(R, device=color.device)
        acc = torch.where(seen, acc, torch.zeros_like(acc))
        depth = (beta * dep_v).sum(1)
        weights = beta[..., None] * alpha
        return {"color": color, "acc": acc, "depth": depth, "alpha": alpha, "beta": beta, "weights": weights,
                "t": t, "valid": valid_vm, "uv": uv, "aux_heads": {}, "aux_losses": {}}
