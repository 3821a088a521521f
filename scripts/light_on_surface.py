"""Where a NeRFormer+MRVM checkpoint stops the light along training rays that see the object (the ghosts).

    python scripts/light_on_surface.py CHECKPOINT DATA [--objects 40] [--batches 12] [--rays 512]

Draws ``--batches`` training batches (1-3 random references, ``--rays`` target rays each) from the first
``--objects`` training objects of DATA (our renders: it needs their depth maps), renders them as training
does (every sample, no fine-pass skipping), and prints per branch, over the rays whose depth map sees a surface:
the light the ray stops (1 = opaque), the depth loss's two parts (the stopped light's expected distance from
the surface, and the light that leaves at the far end times its distance; ``trainer.surface_loss`` is their
sum), the error of the expected stop, and the samples' spacing, all as shares of the ray's length in the box.
RECIPE.md "Depth from the renders' depth maps" quotes it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from blender_mrvm.datasets.loaders import load_dataset  # noqa: E402
from blender_mrvm.training.checkpoint import load_model  # noqa: E402
from blender_mrvm.training.config import TrainConfig  # noqa: E402
from blender_mrvm.training.trainer import RayBatcher, interval_shares, surface_loss  # noqa: E402


def branch_stats(h: dict, far: torch.Tensor, t_star: torch.Tensor) -> list[float]:
    """[light stopped, stopped light's distance, leaving light's distance, |expected stop - surface|, spacing]."""
    w = h["weights"].float()
    length, mid = interval_shares(h["t"], far)
    ss = (t_star.float() / far.float().clamp_min(1e-8))[:, None]
    acc = w.sum(-1)
    leave = (1 - acc).clamp_min(0) * (1 - ss[:, 0]).abs()
    stop = (w * mid).sum(-1) / acc.clamp_min(1e-6)
    return [float(acc.mean()), float(surface_loss(w, h["t"], far, t_star) - leave.mean()), float(leave.mean()),
            float((stop - ss[:, 0]).abs().mean()), float(length.mean())]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("checkpoint")
    ap.add_argument("data")
    ap.add_argument("--objects", type=int, default=40)
    ap.add_argument("--batches", type=int, default=12)
    ap.add_argument("--rays", type=int, default=512)
    a = ap.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(0)  # the training-mode samples are perturbed
    model, _, _ = load_model(a.checkpoint, "cpu")
    model.eval()
    scenes = load_dataset(Path(a.data), "train", limit=a.objects, depth=True)
    batcher = RayBatcher(scenes, TrainConfig(depth_weight=1.0, rays_per_object=a.rays), model.box_padding, seed=1)
    rows: dict[str, list] = {"coarse": [], "fine": []}
    with torch.no_grad():
        for _ in range(a.batches):
            b = batcher.draw(False)
            sel = torch.nonzero(b["rays"].hit).flatten()
            out = model.render_rays(model.encode(b["images"], b["cams"]), b["rays"].select(sel), train=True)
            t_star = b["surface"][sel]
            ok = torch.isfinite(t_star)
            far = b["rays"].far[sel][ok]
            for name in rows:
                h = {k: out[name][k][ok] for k in ("weights", "t")}
                rows[name].append(branch_stats(h, far, t_star[ok]))
    print("branch  light stopped  stopped light's distance  leaving light's distance  |expected stop - surface|  "
          "sample spacing (shares of the ray in the box)")
    for name, r in rows.items():
        m = np.mean(r, 0)
        print(f"{name:7s} {m[0]:13.3f} {m[1]:25.4f} {m[2]:25.4f} {m[3]:26.4f} {m[4]:15.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
