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
        self.color_film = FiLMLayer(h + 3, h)
        self.color_out = nn.Linear(h, 3)
        for m in [*self.trunk[1:], self.color_film]:
            _frequency_init(m.layer)
        for m in (self.sigma, self.parts):  # color_out keeps the default init (colours vary from the start)
            _frequency_init(m)
        _first_layer_init(self.trunk[0].layer)

    def forward(self, pts: torch.Tensor, dirs: torch.Tensor, mask_code: torch.Tensor, style_code: torch.Tensor):
        cfg = self.cfg
        h = cfg.hidden
        freqs = mask_code[:, : cfg.n_layers * h].view(-1, cfg.n_layers, h) * cfg.freq_scale + cfg.freq_bias
        phases = mask_code[:, cfg.n_layers * h:].view(-1, cfg.n_layers, h)
        x = pts
        for i, layer in enumerate(self.trunk):
            x = layer(x, freqs[:, i], phases[:, i])
        raw_sigma = self.sigma(x)[..., 0]
        logits = self.parts(x)
        s_freq = style_code[:, :h] * cfg.freq_scale + cfg.freq_bias
        s_phase = style_code[:, h:]
        c = self.color_film(torch.cat([dirs, x], -1), s_freq, s_phase)
        rgb = torch.sigmoid(self.color_out(c))
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

    def forward(self, x: torch.Tensor, cam: torch.Tensor | None = None) -> torch.Tensor:
        x = x * 2.0 - 1.0  # channels in [0, 1] -> [-1, 1], centred like normalised ImageNet input
        f = self.pool(self.backbone(x)).flatten(1)
        if self.cfg.pose_conditioning:
            if cam is None:
                raise ValueError("this Sem2NeRF encoder needs the input camera (pose_conditioning)")
            f = torch.cat([f, cam.to(f)], 1)
        return self.head(f)


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

    def encode(self, inputs: torch.Tensor, c2w=None) -> torch.Tensor:
        """(B, C + 2, S, S) builder outputs (+ (B, 4, 4) world c2w of the mask's camera) -> (B, 2 * n_layers * hidden) mask codes."""
        cam = self.camera_features(c2w).to(inputs.device) if c2w is not None else None
        return self.encoder(inputs, cam)

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
    def query(self, pts: torch.Tensor, dirs: torch.Tensor, mask_code: torch.Tensor, style_code: torch.Tensor):
        """Points (B, N, 3) (normalised frame), unit dirs (B, N, 3) -> sigma (B, N), logits (B, N, C), rgb (B, N, 3)."""
        raw, logits, rgb = self.field(pts, dirs, mask_code, style_code)
        sigma = F.softplus(raw * self.cfg.density_scale + self.cfg.density_bias)
        return sigma, logits, rgb

    def _render_hit(self, o, d, far, mask_code, style_code, perturb: bool, generator=None):
        """o, d (B, R, 3) float32, far (B, R): render rays that cross the box."""
        cfg = self.cfg
        B, R = far.shape
        flat_far = far.reshape(-1)
        t = samplers.stratified(flat_far, cfg.n_coarse, perturb, generator)  # (B*R, S)
        if cfg.n_fine > 0:
            with torch.no_grad():
                pts = o.reshape(-1, 1, 3) + t[..., None] * d.reshape(-1, 1, 3)
                sig, _, _ = self.query(pts.view(B, -1, 3), d.reshape(-1, 1, 3).expand_as(pts).reshape(B, -1, 3),
                                       mask_code, style_code)
                w, _ = renderer.render_weights(sig.view(B * R, -1), renderer.deltas_from_t(t, flat_far - t[:, -1]))
                edges = samplers.bin_edges(t, flat_far)
                tf = samplers.sample_pdf(edges, w, cfg.n_fine, deterministic=not perturb, generator=generator)
            t = torch.sort(torch.cat([t, tf], -1), -1).values
        S = t.shape[-1]
        pts = o.reshape(-1, 1, 3) + t[..., None] * d.reshape(-1, 1, 3)
        dirs = d.reshape(-1, 1, 3).expand(-1, S, -1)
        sigma, logits, rgb = self.query(pts.reshape(B, R * S, 3), dirs.reshape(B, R * S, 3), mask_code, style_code)
        out = renderer.volume_render(sigma.view(B * R, S), rgb.view(B * R, S, 3), t, cfg.white_background,
                                     last_delta=(flat_far - t[:, -1]).clamp_min(0.0))
        probs = torch.softmax(logits.float().view(B * R, S, -1), -1)
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
    def render_image(self, intr, c2w_world, mask_code: torch.Tensor, style_code: torch.Tensor) -> dict[str, torch.Tensor]:
        """A full view (H, W) of one object: rgb (H, W, 3), acc (H, W), semantic (H, W, C) log-probs."""
        from ..rays import make_rays, normalize_pose
        import numpy as np

        bundle = make_rays(intr, normalize_pose(c2w_world, np.zeros(3), self.cfg.scene_box), None, box=1.0)
        outs = []
        n = self.cfg.chunk_rays
        for i in range(0, len(bundle), n):
            b = bundle.select(slice(i, i + n))
            outs.append(self.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], mask_code[:1],
                                         style_code[:1]))
        h, w = intr.height, intr.width
        return {k: torch.cat([o[k][0] for o in outs], 0).reshape(h, w, -1).squeeze(-1) if k == "acc"
                else torch.cat([o[k][0] for o in outs], 0).reshape(h, w, -1) for k in outs[0]}
