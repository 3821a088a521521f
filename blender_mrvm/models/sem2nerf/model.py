"""Sem2NeRF model: mask encoder -> FiLM codes of a pi-GAN-style SIREN field with part logits.

- :class:`MaskEncoder`: (B, C + 2, S, S) one-hot + contour + distance inputs -> FiLM frequencies
  and phases of every trunk layer (the *mask code*). Backbone: ImageNet VGG16 ``features`` (offline
  weights) whose first convolution is widened to C + 2 channels (the RGB kernel's mean, repeated
  and rescaled so the activations keep their ImageNet scale).
- :class:`MappingNetwork`: z -> *style code* (FiLM frequency and phase of the colour layer), pi-GAN's
  mapping network; the default style is the mean of its outputs over 10,000 random z, kept in the
  buffer ``style_mean`` (:meth:`Sem2NeRF.update_style_mean`).
- :class:`SirenField`: FiLM-SIREN trunk (mask code) -> density and per-point part logits; a FiLM
  colour layer (style code, view direction) -> RGB. Geometry and parts depend on the mask only,
  appearance on both, so mask edits and style changes act on separate things.
- pixel-aligned conditioning (``cfg.pixel_aligned``): :meth:`Sem2NeRF.encode` then returns a
  :class:`MaskCode` that also holds the mask inputs, a projected backbone feature map and the input
  camera; every sample point is projected into the input view and the mask channels and features
  there (plus its depth in that camera) go through a small MLP whose output adds to the density and
  part logits and feeds the colour layer; the sampled one-hot label adds ``label_gain`` to its logit.
  Along a ray of the input view every point sees the same input pixel, so the rendered input-view
  semantic map follows the input mask (the global codes alone gave category-average shapes).
- :meth:`Sem2NeRF.render_rays`: box-clipped rays (``models/rays.py``), stratified + importance
  samples (``models/samplers.py``), ``models/renderer.volume_render``; the semantic map is the
  weight-composited part probabilities plus the background for the transmitted remainder, returned as
  log-probabilities (one logit per known label).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn

from .. import renderer, samplers
from .config import Sem2NeRFConfig

CAMERA_FEATURES = 12
"""Camera features of the encoder head: the 3x3 rotation and the centre (in scene-box units)."""
VGG_CHANNELS = {4: 64, 9: 128, 16: 256, 23: 512}


# ------------------------------------------------------------------------------------------- codes

class MaskCode:
    """What a pixel-aligned encoder gives per input mask (batch-indexable like a tensor).

    code (B, D) global FiLM codes; fmap (B, L, S, S) local feature map (a 1x1 convolution of the
    builder channels and the upsampled backbone features: linear, so sampling it equals sampling its
    inputs and projecting, at a fraction of the channels); index (B, 1, S, S) label index of each
    input pixel (float); K (B, 3, 3) input intrinsics at S px; w2c (B, 4, 4) input camera,
    world-to-camera in the normalised frame (OpenCV axes)."""

    def __init__(self, code, fmap, index, K, w2c):
        self.code, self.fmap, self.index, self.K, self.w2c = code, fmap, index, K, w2c

    def __getitem__(self, idx) -> "MaskCode":
        return MaskCode(self.code[idx], self.fmap[idx], self.index[idx], self.K[idx], self.w2c[idx])

    @property
    def device(self):
        return self.code.device

    @property
    def shape(self):
        return self.code.shape


def _global(mask_code) -> torch.Tensor:
    return mask_code.code if isinstance(mask_code, MaskCode) else mask_code


def project_to_input(pts: torch.Tensor, mc: MaskCode) -> tuple[torch.Tensor, torch.Tensor]:
    """Points (B, N, 3) in the normalised frame -> (grid (B, N, 2) in grid_sample's [-1, 1] units,
    camera depth z (B, N)) in the input view (pixel-centre convention, align_corners=False)."""
    R, t = mc.w2c[:, :3, :3].to(pts), mc.w2c[:, :3, 3].to(pts)
    cam = torch.einsum("bij,bnj->bni", R, pts) + t[:, None]
    z = cam[..., 2]
    zs = torch.where(z.abs() < 1e-6, torch.full_like(z, 1e-6), z)
    K = mc.K.to(pts)
    u = (K[:, None, 0, 0] * cam[..., 0] + K[:, None, 0, 1] * cam[..., 1]) / zs + K[:, None, 0, 2]
    v = K[:, None, 1, 1] * cam[..., 1] / zs + K[:, None, 1, 2]
    S = mc.fmap.shape[-1]
    grid = torch.stack([u / S * 2 - 1, v / S * 2 - 1], -1)
    return grid, z


def local_features(pts: torch.Tensor, mc: MaskCode) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """At each point's projection into the input view: features (B, N, L + 2) (the local map, the
    point's depth in that camera, whether it projects inside the image in front of the camera; zeros
    elsewhere), the input label index (B, N) (nearest pixel; 0 = background outside) and inside (B, N)."""
    grid, z = project_to_input(pts, mc)
    inside = ((grid.abs() <= 1).all(-1) & (z > 1e-3)).to(pts.dtype)
    grid = torch.where(inside[..., None] > 0, grid, torch.full_like(grid, 2.0)).clamp(-2, 2)
    g = grid[:, :, None]  # (B, N, 1, 2)
    a = F.grid_sample(mc.fmap.to(pts), g, mode="bilinear", padding_mode="zeros", align_corners=False)
    idx = F.grid_sample(mc.index.to(pts), g, mode="nearest", padding_mode="zeros", align_corners=False)
    feat = torch.cat([a[..., 0].transpose(1, 2), (z * inside)[..., None], inside[..., None]], -1)
    return feat, idx[:, 0, :, 0].round().long(), inside


def silhouette_cone(bundle, mc: MaskCode, n_check: int = 64, dilate_px: int = 2) -> torch.Tensor:
    """(R,) bool: rays (normalised frame, :class:`..rays.RayBundle`) that pass through the input mask's
    silhouette cone. The input mask is the object's silhouette from that camera and the object lies inside the
    input view (as in every training image), so a ray that stays outside the cone meets only empty space: a
    visual hull of one view (``models/hull.py`` does the same with several references). Checked at ``n_check``
    points evenly along each ray against the foreground dilated by ``dilate_px`` pixels (thin parts between the
    points, the model's soft edges); points behind the input camera or outside its image are outside the cone."""
    R = len(bundle)
    dev = mc.device
    t = torch.linspace(0.0, 1.0, n_check, device=dev)[None, :] * bundle.far.to(dev).float()[:, None]
    pts = bundle.origins.to(dev).float()[:, None] + t[..., None] * bundle.dirs.to(dev).float()[:, None]
    grid, z = project_to_input(pts.reshape(1, -1, 3), mc)
    fg = (mc.index > 0).float()
    if dilate_px > 0:
        fg = F.max_pool2d(fg, 2 * dilate_px + 1, stride=1, padding=dilate_px)
    on = F.grid_sample(fg, grid[:, :, None], mode="nearest", padding_mode="zeros", align_corners=False)[0, 0, :, 0]
    on = (on > 0) & (z[0] > 1e-3)
    return on.view(R, n_check).any(-1).to(bundle.hit.device)


# ------------------------------------------------------------------------------------------- SIREN

def _frequency_init(layer: nn.Linear, freq: float = 25.0) -> None:
    with torch.no_grad():
        n = layer.weight.shape[-1]
        bound = math.sqrt(6.0 / n) / freq
        layer.weight.uniform_(-bound, bound)


def _first_layer_init(layer: nn.Linear) -> None:
    with torch.no_grad():
        n = layer.weight.shape[-1]
        layer.weight.uniform_(-1.0 / n, 1.0 / n)


class FiLMLayer(nn.Module):
    """sin(freq * (W x + b) + phase), freq and phase per sample (pi-GAN)."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.layer = nn.Linear(cin, cout)

    def forward(self, x: torch.Tensor, freq: torch.Tensor, phase: torch.Tensor) -> torch.Tensor:
        # x (B, N, cin); freq, phase (B, cout)
        return torch.sin(freq[:, None] * self.layer(x) + phase[:, None])


class SirenField(nn.Module):
    """Points (B, N, 3) in [-1, 1]^3 + codes -> raw density (B, N), part logits (B, N, C), rgb (B, N, 3)."""

    def __init__(self, cfg: Sem2NeRFConfig):
        super().__init__()
        self.cfg = cfg
        h = cfg.hidden
        self.trunk = nn.ModuleList([FiLMLayer(3 if i == 0 else h, h) for i in range(cfg.n_layers)])
        self.sigma = nn.Linear(h, 1)
        self.parts = nn.Linear(h, cfg.n_labels)
        lh = cfg.local_hidden if cfg.pixel_aligned else 0
        self.color_film = FiLMLayer(h + 3 + lh, h)
        self.color_out = nn.Linear(h, 3)
        if cfg.style_part_colours:  # style -> an RGB logit offset per part label, zero at the start
            self.style_part_rgb = nn.Linear(2 * h, cfg.n_labels * 3)
            nn.init.zeros_(self.style_part_rgb.weight)
            nn.init.zeros_(self.style_part_rgb.bias)
        for m in [*self.trunk[1:], self.color_film]:
            _frequency_init(m.layer)
        for m in (self.sigma, self.parts):  # color_out keeps the default init (colours vary from the start)
            _frequency_init(m)
        _first_layer_init(self.trunk[0].layer)
        if cfg.pixel_aligned:
            self.local = nn.Sequential(nn.Linear(cfg.local_channels + 2 + h, lh), nn.ReLU(), nn.Linear(lh, lh), nn.ReLU())
            self.local_sigma = nn.Linear(lh, 1)
            self.local_parts = nn.Linear(lh, cfg.n_labels)
            self.label_gain = nn.Parameter(torch.tensor(4.0))
            with torch.no_grad():
                for m in (self.local_sigma, self.local_parts):
                    m.weight.mul_(0.1)
                    m.bias.zero_()

    def forward(self, pts: torch.Tensor, dirs: torch.Tensor, mask_code, style_code: torch.Tensor, local=None):
        cfg = self.cfg
        h = cfg.hidden
        g = _global(mask_code)
        freqs = g[:, : cfg.n_layers * h].view(-1, cfg.n_layers, h) * cfg.freq_scale + cfg.freq_bias
        phases = g[:, cfg.n_layers * h:].view(-1, cfg.n_layers, h)
        x = pts
        for i, layer in enumerate(self.trunk):
            x = layer(x, freqs[:, i], phases[:, i])
        raw_sigma = self.sigma(x)[..., 0]
        logits = self.parts(x)
        feats = [dirs, x]
        if cfg.pixel_aligned:
            if local is None:
                raise ValueError("a pixel-aligned Sem2NeRF field needs the points' local features")
            feat, idx, inside = local
            lf = self.local(torch.cat([feat, x], -1))
            raw_sigma = raw_sigma + self.local_sigma(lf)[..., 0]
            gain = (self.label_gain * inside)[..., None]
            logits = logits + self.local_parts(lf)  # (under autocast the gain, a parameter, is cast alike)
            logits = logits.scatter_add(-1, idx[..., None], gain.to(logits.dtype))
            feats.append(lf)
        s_freq = style_code[:, :h] * cfg.freq_scale + cfg.freq_bias
        s_phase = style_code[:, h:]
        c = self.color_film(torch.cat(feats, -1), s_freq, s_phase)
        rgb_logit = self.color_out(c)
        if cfg.style_part_colours:
            offsets = self.style_part_rgb(style_code).view(-1, cfg.n_labels, 3)  # (B, C, 3)
            probs = torch.softmax(logits.detach(), -1)  # the colour loss does not reshape the parts
            rgb_logit = rgb_logit + torch.einsum("bnc,bck->bnk", probs, offsets)
        rgb = torch.sigmoid(rgb_logit)
        return raw_sigma, logits, rgb


# ----------------------------------------------------------------------------------------- mapping

class MappingNetwork(nn.Module):
    """z (B, z_dim) -> style code (B, 2 * hidden): pi-GAN's 3-hidden-layer LeakyReLU MLP."""

    def __init__(self, cfg: Sem2NeRFConfig):
        super().__init__()
        w = cfg.mapping_hidden
        self.net = nn.Sequential(nn.Linear(cfg.z_dim, w), nn.LeakyReLU(0.2), nn.Linear(w, w), nn.LeakyReLU(0.2),
                                 nn.Linear(w, w), nn.LeakyReLU(0.2), nn.Linear(w, 2 * cfg.hidden))
        with torch.no_grad():
            self.net[-1].weight.mul_(0.25)

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.net(z)


# ----------------------------------------------------------------------------------------- encoder

class MaskEncoder(nn.Module):
    """(B, C + 2, S, S) mask inputs -> mask code (B, 2 * n_layers * hidden): FiLM frequencies, phases."""

    def __init__(self, cfg: Sem2NeRFConfig):
        super().__init__()
        from ..vgg import load_vgg16_features, vgg16_features

        self.cfg = cfg
        vgg = load_vgg16_features(cfg.vgg_layers) if cfg.pretrained else vgg16_features(cfg.vgg_layers)
        conv0 = vgg[0]
        first = nn.Conv2d(cfg.in_channels, conv0.out_channels, 3, padding=1)
        with torch.no_grad():
            # ImageNet RGB kernel averaged over colour, spread over the C + 2 input channels: a one-hot
            # input (sum 1 over labels) then sees the grey kernel's response scale.
            w = conv0.weight.mean(1, keepdim=True)  # (64, 1, 3, 3)
            first.weight.copy_(w.expand(-1, cfg.in_channels, -1, -1) * (3.0 / cfg.in_channels))
            first.bias.copy_(conv0.bias)
        vgg[0] = first
        self.backbone = vgg
        ch = VGG_CHANNELS[cfg.vgg_layers]
        self.pool = nn.AdaptiveAvgPool2d(cfg.encoder_grid)
        out = 2 * cfg.n_layers * cfg.hidden
        n_cam = CAMERA_FEATURES if cfg.pose_conditioning else 0
        self.head = nn.Sequential(nn.Linear(ch * cfg.encoder_grid ** 2 + n_cam, cfg.encoder_hidden),
                                  nn.LeakyReLU(0.2), nn.Linear(cfg.encoder_hidden, out))
        with torch.no_grad():
            self.head[-1].weight.mul_(0.25)
            self.head[-1].bias.zero_()
        if cfg.pixel_aligned:
            self.local_proj = nn.Conv2d(ch + cfg.in_channels, cfg.local_channels, 1)

    def forward(self, x: torch.Tensor, cam: torch.Tensor | None = None, return_map: bool = False):
        inputs = x
        x = x * 2.0 - 1.0  # channels in [0, 1] -> [-1, 1], centred like normalised ImageNet input
        fmap = self.backbone(x)
        f = self.pool(fmap).flatten(1)
        if self.cfg.pose_conditioning:
            if cam is None:
                raise ValueError("this Sem2NeRF encoder needs the input camera (pose_conditioning)")
            f = torch.cat([f, cam.to(f)], 1)
        code = self.head(f)
        if return_map:
            up = F.interpolate(fmap, size=inputs.shape[-2:], mode="bilinear", align_corners=False)
            return code, self.local_proj(torch.cat([inputs, up], 1))
        return code


# ------------------------------------------------------------------------------------------- model

class Sem2NeRF(nn.Module):
    """Mask encoder + mapping network + FiLM-SIREN field, with volume rendering of RGB and parts."""

    kind = "sem2nerf"

    def __init__(self, cfg: Sem2NeRFConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = MaskEncoder(cfg)
        self.mapping = MappingNetwork(cfg)
        self.field = SirenField(cfg)
        self.register_buffer("style_mean", torch.zeros(2 * cfg.hidden))
        self.update_style_mean()

    # -- codes
    def camera_features(self, c2w) -> torch.Tensor:
        """(B, 4, 4) world camera-to-world (OpenCV) -> (B, 12): rotation and centre / scene_box."""
        c = torch.as_tensor(c2w, dtype=torch.float64).reshape(-1, 4, 4)
        return torch.cat([c[:, :3, :3].reshape(-1, 9), c[:, :3, 3] / self.cfg.scene_box], 1).float()

    def encode(self, inputs: torch.Tensor, c2w=None, intr=None):
        """(B, C + 2, S, S) builder outputs (+ (B, 4, 4) world c2w of the mask's camera, + its
        intrinsics: one or a list of B, any resolution of the same aspect) -> (B, 2 * n_layers * hidden)
        mask codes, or with ``cfg.pixel_aligned`` a :class:`MaskCode` (which needs c2w and intr)."""
        cam = self.camera_features(c2w).to(inputs.device) if c2w is not None else None
        if not self.cfg.pixel_aligned:
            return self.encoder(inputs, cam)
        if c2w is None or intr is None:
            raise ValueError("a pixel-aligned Sem2NeRF needs the input camera's pose and intrinsics")
        code, fmap = self.encoder(inputs, cam, return_map=True)
        K, w2c = self.input_cameras(c2w, intr, inputs.shape[-1])
        index = inputs[:, : self.cfg.n_labels].argmax(1, keepdim=True).float()
        return MaskCode(code, fmap, index, K.to(inputs.device), w2c.to(inputs.device))

    def input_cameras(self, c2w, intr, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(K (B, 3, 3) at ``size`` px, w2c (B, 4, 4) in the normalised frame) of the input cameras."""
        import numpy as np

        from ..rays import normalize_pose

        c = np.asarray(c2w, np.float64).reshape(-1, 4, 4)
        intrs = list(intr) if isinstance(intr, (list, tuple)) else [intr] * len(c)
        if len(intrs) != len(c):
            raise ValueError(f"{len(intrs)} intrinsics for {len(c)} input cameras")
        Ks, w2cs = [], []
        for m, it in zip(c, intrs):
            if it.width != size:
                it = it.scaled(size / it.width)
            Ks.append([[it.fx, it.skew, it.cx], [0.0, it.fy, it.cy], [0.0, 0.0, 1.0]])
            w2cs.append(np.linalg.inv(normalize_pose(m, np.zeros(3), self.cfg.scene_box)))
        return torch.tensor(np.array(Ks), dtype=torch.float32), torch.tensor(np.array(w2cs), dtype=torch.float32)

    def style(self, z: torch.Tensor) -> torch.Tensor:
        """(B, z_dim) random codes -> (B, 2 * hidden) style codes."""
        return self.mapping(z)

    @torch.no_grad()
    def update_style_mean(self, seed: int = 0) -> torch.Tensor:
        """Set the default style: the mean mapping output over ``style_mean_samples`` random z."""
        g = torch.Generator().manual_seed(seed)
        z = torch.randn(self.cfg.style_mean_samples, self.cfg.z_dim, generator=g).to(self.style_mean.device)
        self.style_mean.copy_(self.mapping(z).mean(0))
        return self.style_mean

    def default_style(self, batch: int = 1) -> torch.Tensor:
        return self.style_mean[None].expand(batch, -1)

    def style_from_seed(self, seed: int) -> torch.Tensor:
        """(1, 2 * hidden) style of the random code drawn with ``seed``."""
        g = torch.Generator().manual_seed(int(seed))
        z = torch.randn(1, self.cfg.z_dim, generator=g).to(self.style_mean.device)
        return self.style(z)

    # -- field
    def query(self, pts: torch.Tensor, dirs: torch.Tensor, mask_code, style_code: torch.Tensor):
        """Points (B, N, 3) (normalised frame), unit dirs (B, N, 3) -> sigma (B, N), logits (B, N, C), rgb (B, N, 3)."""
        local = local_features(pts, mask_code) if isinstance(mask_code, MaskCode) else None
        raw, logits, rgb = self.field(pts, dirs, mask_code, style_code, local)
        sigma = F.softplus(raw * self.cfg.density_scale + self.cfg.density_bias)
        return sigma, logits, rgb

    def _render_hit(self, o, d, far, mask_code, style_code, perturb: bool, generator=None):
        """o, d (B, R, 3) float32, far (B, R): render rays that cross the box."""
        cfg = self.cfg
        B, R = far.shape
        flat_far = far.reshape(-1)
        t = samplers.stratified(flat_far, cfg.n_coarse, perturb, generator)  # (B*R, S)

        def query_at(tt: torch.Tensor):
            """The field at distances ``tt`` (B*R, S) along the rays: sigma (B*R, S), logits (B*R, S, C), rgb."""
            S = tt.shape[-1]
            pts = o.reshape(-1, 1, 3) + tt[..., None] * d.reshape(-1, 1, 3)
            dirs = d.reshape(-1, 1, 3).expand(-1, S, -1)
            sig, lg, col = self.query(pts.reshape(B, R * S, 3), dirs.reshape(B, R * S, 3), mask_code, style_code)
            return sig.view(B * R, S), lg.view(B * R, S, -1), col.view(B * R, S, 3)

        if cfg.n_fine > 0:
            # At inference the coarse points' values are kept and only the fine points are evaluated: every
            # point's value depends on that point alone, so this renders the same view as evaluating all of them
            # again (40 % fewer field queries with 16 + 8 samples). Training evaluates them again, with gradients.
            reuse = not torch.is_grad_enabled()
            with torch.no_grad():
                coarse = query_at(t)
                w, _ = renderer.render_weights(coarse[0], renderer.deltas_from_t(t, flat_far - t[:, -1]))
                edges = samplers.bin_edges(t, flat_far)
                tf = samplers.sample_pdf(edges, w, cfg.n_fine, deterministic=not perturb, generator=generator)
            if reuse:
                t, order = torch.sort(torch.cat([t, tf], -1), -1)

                def merged(c: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
                    x = torch.cat([c, f], 1)
                    return torch.gather(x, 1, order if x.dim() == 2 else order[..., None].expand(-1, -1, x.shape[-1]))

                sigma, logits, rgb = (merged(c, f) for c, f in zip(coarse, query_at(tf)))
            else:
                t = torch.sort(torch.cat([t, tf], -1), -1).values
                sigma, logits, rgb = query_at(t)
        else:
            sigma, logits, rgb = query_at(t)
        out = renderer.volume_render(sigma, rgb, t, cfg.white_background,
                                     last_delta=(flat_far - t[:, -1]).clamp_min(0.0))
        probs = torch.softmax(logits.float(), -1)
        sem = (out["weights"][..., None] * probs).sum(-2)
        sem = torch.cat([sem[:, :1] + (1.0 - out["acc"]).clamp_min(0.0)[:, None], sem[:, 1:]], -1)
        return (out["color"].view(B, R, 3), out["acc"].view(B, R), sem.view(B, R, -1))

    def render_rays(self, origins: torch.Tensor, dirs: torch.Tensor, far: torch.Tensor, hit: torch.Tensor,
                    mask_code: torch.Tensor, style_code: torch.Tensor, perturb: bool = False,
                    generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
        """Render B ray sets of R rays each (normalised frame, origins at the box entry, as
        :class:`..rays.RayBundle` gives them): origins/dirs (B, R, 3), far/hit (B, R).

        Returns rgb (B, R, 3), acc (B, R), semantic (B, R, C) log-probabilities. Rays that miss the box
        are background (white, acc 0, background label) and are not evaluated.
        """
        B, R = far.shape
        C = self.cfg.n_labels
        dev = mask_code.device
        bg = torch.ones(3, device=dev) if self.cfg.white_background else torch.zeros(3, device=dev)
        rgb = bg.expand(B, R, 3).clone()
        acc = torch.zeros(B, R, device=dev)
        sem = torch.zeros(B, R, C, device=dev)
        sem[..., 0] = 1.0
        hit = hit.to(dev).bool() & (far.to(dev) > 0)
        if hit.any():
            # Same number of rays per batch item: render all rays of items with any hit, then keep the hits.
            o = origins.to(dev).float()
            d = dirs.to(dev).float()
            f = torch.where(hit, far.to(dev).float(), torch.zeros_like(far, dtype=torch.float32, device=dev))
            c, a, s = self._render_hit(o, d, f, mask_code, style_code, perturb, generator)
            keep = hit[..., None]
            rgb = torch.where(keep, c, rgb)
            acc = torch.where(hit, a, acc)
            sem = torch.where(keep, s, sem)
        return {"rgb": rgb, "acc": acc, "semantic": torch.log(sem.clamp_min(1e-6))}

    @torch.no_grad()
    def render_image(self, intr, c2w_world, mask_code: torch.Tensor, style_code: torch.Tensor,
                     chunk: int | None = None) -> dict[str, torch.Tensor]:
        """A full view (H, W) of one object: rgb (H, W, 3), acc (H, W), semantic (H, W, C) log-probs. ``chunk``: rays
        per forward pass (default the config's ``chunk_rays``, at least ``models.base.GPU_CHUNK_RAYS`` on a GPU)."""
        from .. import base
        from ..rays import make_rays, normalize_pose, pixel_rows
        import numpy as np

        dev = mask_code.device
        pixels = None if base.rays_on_host(dev) else pixel_rows(0, int(intr.height), int(intr.width), dev)
        bundle = make_rays(intr, normalize_pose(c2w_world, np.zeros(3), self.cfg.scene_box), pixels, box=1.0)
        need = bundle.hit.bool() & (bundle.far > 0)
        box = int(need.sum())
        if self.cfg.cull_cone and isinstance(mask_code, MaskCode):
            need &= silhouette_cone(bundle, mask_code[:1])
        self.last_render_stats = {"rays": len(bundle), "box": box, "evaluated": int(need.sum())}
        h, w, C = intr.height, intr.width, self.cfg.n_labels
        bg = 1.0 if self.cfg.white_background else 0.0
        out = {"rgb": torch.full((len(bundle), 3), bg, device=dev), "acc": torch.zeros(len(bundle), device=dev),
               "semantic": torch.full((len(bundle), C), math.log(1e-6), device=dev)}
        out["semantic"][:, 0] = 0.0  # what render_rays gives a ray that meets nothing: the background label
        sel = torch.nonzero(need).flatten()
        n = base.inference_chunk(self.cfg.chunk_rays, dev, chunk)
        for i in range(0, len(sel), n):
            idx = sel[i:i + n]
            b = bundle.select(idx)
            o = self.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], mask_code[:1],
                                 style_code[:1])
            for k in out:
                out[k][idx.to(dev)] = o[k][0].to(out[k].dtype)
        base.check_finite_view(self, colour=out["rgb"], opacity=out["acc"], semantics=out["semantic"])
        return {k: v.reshape(h, w) if k == "acc" else v.reshape(h, w, -1) for k, v in out.items()}
