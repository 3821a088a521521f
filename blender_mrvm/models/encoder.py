"""Image encoder: pixel-aligned multi-scale features for the reference views.

``resnet``: a small ResNet-like network trained from scratch (GroupNorm, so batches of 1 view
work), features at strides 2, 4 and 8. ``vgg16``: ImageNet VGG16 blocks 1-3 (strides 1, 2, 4) from
the offline cache (``pretrained``; a missing cache is a one-line error naming ``fetch-weights``),
frozen (``freeze_backbone``) or fine-tuned. Either way every scale is upsampled to the finest scale kept (stride 2) and fused
by a 1x1 convolution into one (V, out_dim, H/2, W/2) map, computed once per reference set, so each
3D point needs a single bilinear lookup per view.

Without gradients (synthesis, eval) the views are encoded one at a time into the preallocated map
(:func:`per_view`): the network's intermediate maps are one view's, whatever the number of views (two 8000 px
references at ``--ref-size 4096`` asked for one 4.8 GB allocation when encoded together). Every layer works on each
view alone (GroupNorm normalises per view), so the features are those of one batched pass, to float rounding.
References over :data:`LEAN_FUSE_PIXELS` are also fused scale by scale (:meth:`ImageEncoder._fuse_lean`). Peak
memory of encoding one view, measured (CPU, float32): 1.45 GiB at 2048 px and 5.5 GiB at 4096 px for the shipped
``balanced`` encoder before, 0.51 GiB and 2.0 GiB now (0.19 GiB and 0.75 GiB of it the features kept per view).
"""

from __future__ import annotations

from contextlib import nullcontext

import torch
import torch.nn.functional as F
from torch import nn

from .config import EncoderConfig

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
MIN_SIDE = 16
"""Reference images smaller than this are resampled up before encoding (GroupNorm needs spatial extent)."""


LEAN_FUSE_PIXELS = 1024 * 1024
"""References of more pixels than this are fused scale by scale without gradients (:meth:`ImageEncoder._fuse_lean`);
smaller ones (every size the models were trained and are tested at) keep the concatenated form's exact arithmetic."""


def per_view(encode, images: torch.Tensor) -> torch.Tensor:
    """``encode(images)`` for (V, C, H, W) images whose views are encoded independently of each other. Without
    gradients, one view at a time, written into one preallocated (V, ...) output: the peak is one view's
    intermediate maps plus the output, not V views'.
    With gradients (training, adaptation), one pass over all views as before."""
    V = images.shape[0]
    if V <= 1 or torch.is_grad_enabled():
        return encode(images)
    first = encode(images[:1])
    out = first.new_empty((V, *first.shape[1:]))
    out[:1] = first
    del first
    for i in range(1, V):
        out[i:i + 1] = encode(images[i:i + 1])
    return out


def _gn(c: int) -> nn.GroupNorm:
    import math

    return nn.GroupNorm(math.gcd(8, c), c)


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.n1 = _gn(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.n2 = _gn(cout)
        self.skip = None
        if stride != 1 or cin != cout:
            self.skip = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), _gn(cout))

    def forward(self, x):
        y = F.relu(self.n1(self.conv1(x)))
        y = self.n2(self.conv2(y))
        return F.relu(y + (x if self.skip is None else self.skip(x)))


class ImageEncoder(nn.Module):
    """(V, 3, H, W) images in [0, 1] -> (V, out_dim, ceil(H/2), ceil(W/2)) pixel-aligned features."""

    def __init__(self, cfg: EncoderConfig, load_pretrained: bool = True):
        """``load_pretrained`` False leaves a 'vgg16, pretrained' backbone random (a checkpoint's weights follow)."""
        super().__init__()
        self.cfg = cfg
        self.register_buffer("mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False)
        if cfg.backbone == "vgg16":
            from .vgg import load_vgg16_features, vgg16_features

            # Up to relu3_3 (index 15): strides 1, 2, 4 with 64, 128, 256 channels.
            self.vgg = load_vgg16_features(16) if cfg.pretrained and load_pretrained else vgg16_features(16)
            if cfg.freeze_backbone:
                for p in self.vgg.parameters():
                    p.requires_grad_(False)
            self.taps = (3, 8, 15)
            chans = (64, 128, 256)
        else:
            w = cfg.widths
            self.stem = nn.Sequential(nn.Conv2d(3, w[0], 3, 2, 1, bias=False), _gn(w[0]), nn.ReLU())
            stages = []
            cin = w[0]
            for i, c in enumerate(w):
                blocks = [BasicBlock(cin, c, 1 if i == 0 else 2)]
                blocks += [BasicBlock(c, c, 1) for _ in range(cfg.blocks_per_stage - 1)]
                stages.append(nn.Sequential(*blocks))
                cin = c
            self.stages = nn.ModuleList(stages)
            chans = tuple(w)
        self.fuse = nn.Conv2d(sum(chans), cfg.out_dim, 1)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return per_view(self._encode, images)

    def _encode(self, images: torch.Tensor) -> torch.Tensor:
        x = (images - self.mean) / self.std
        h, w = x.shape[-2:]
        if min(h, w) < MIN_SIDE:  # tiny references (down to 1x1): resample up; features stay pixel-aligned
            f = MIN_SIDE / min(h, w)
            x = F.interpolate(x, size=(max(MIN_SIDE, round(h * f)), max(MIN_SIDE, round(w * f))), mode="bilinear",
                              align_corners=False)
        feats = []
        if self.cfg.backbone == "vgg16":
            with torch.no_grad() if self.cfg.freeze_backbone else nullcontext():
                for i, layer in enumerate(self.vgg):
                    x = layer(x)
                    if i in self.taps:
                        feats.append(x)
            feats[0] = F.avg_pool2d(feats[0], 2, ceil_mode=True)  # stride 1 -> 2
        else:
            x = self.stem(x)
            for st in self.stages:
                x = st(x)
                feats.append(x)
        del x
        size = feats[0].shape[-2:]
        if h * w > LEAN_FUSE_PIXELS and not torch.is_grad_enabled():
            return self._fuse_lean(feats, size)
        up = [feats[0]] + [F.interpolate(f, size=size, mode="bilinear", align_corners=False) for f in feats[1:]]
        return self.fuse(torch.cat(up, 1))

    def _fuse_lean(self, feats: list, size) -> torch.Tensor:
        """``fuse(cat(feats[0], up(feats[1]), up(feats[2])))`` without the upsampled maps or their concatenation:
        the 1x1 convolution is linear per pixel and bilinear upsampling per channel, so each scale is fused at its
        own resolution (``fuse``'s columns of its channels) and then upsampled, out_dim channels instead of its own,
        and summed into the output. Equal to the concatenated form but for float rounding (~1e-6 relative); the
        peak is the backbone's and the output's maps, not the concatenation of every scale at the finest (at 4096 px
        the shipped encoder peaked at 5.5 GiB a view, now 2.0 GiB)."""
        W, b = self.fuse.weight, self.fuse.bias
        lo = 0
        out = None
        for k in range(len(feats)):
            f, feats[k] = feats[k], None  # (each scale's map released once fused)
            part = F.conv2d(f, W[:, lo:lo + f.shape[1]], b if k == 0 else None)
            lo += f.shape[1]
            del f
            if k == 0:
                out = part
            else:
                out += F.interpolate(part, size=size, mode="bilinear", align_corners=False)
            del part
        return out
