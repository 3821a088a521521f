"""Image encoder: pixel-aligned multi-scale features for the reference views.

``resnet``: a small ResNet-like network trained from scratch (GroupNorm, so batches of 1 view
work), features at strides 2, 4 and 8. ``vgg16``: ImageNet VGG16 blocks 1-3 (strides 1, 2, 4) from
the offline cache (``pretrained``; a missing cache is a one-line error naming ``fetch-weights``),
frozen (``freeze_backbone``) or fine-tuned. Either way every scale is upsampled to the finest scale kept (stride 2) and fused
by a 1x1 convolution into one (V, out_dim, H/2, W/2) map, computed once per reference set, so each
3D point needs a single bilinear lookup per view.
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
        size = feats[0].shape[-2:]
        up = [feats[0]] + [F.interpolate(f, size=size, mode="bilinear", align_corners=False) for f in feats[1:]]
        return self.fuse(torch.cat(up, 1))
