"""Render capture-like scenes: a procedural library object in a textured room, filmed along a hand-held path.

Each scene: a floor and walls with the library's procedural materials (no checkerboards), one library
object standing at the centre, sun, sky and an area light, all drawn per scene from its seed, and a
camera path like a person walking round the object with a phone (an arc or a loop at a drifting
height and distance, small roll, look-at wander, smooth from view to view). Written in the project's
dataset format (rgb, exact depth / normals / part ids of every surface, poses, transforms.json,
meta.json with ``"background": "scene"`` and the room's box as ``bbox``), with two splits:

- held-out views in between: every ``--holdout-every``-th view of a path is a target, synthesized
  from its neighbours on the path (``splits/eval_views.json``: ``target_inputs_<n>`` for 1 to 6
  inputs, which ``eval --n-inputs N`` follows);
- held-out scenes: the last 20 % of the scenes are the test split (``splits/test.lst``), never trained on
  (of this run's ``--scenes``: more scenes on an existing set re-label the kept ones as a fresh run would, and
  the split lists name this run's scenes only).

Runs: a second run reaching a scene another one is rendering is refused (shards of one set, --shard i/n, render
their own scenes into one folder side by side); Ctrl-C stops after the view in flight (exit 130); a rerun keeps the
finished views of an unfinished scene when it builds the same scene, and goes on from there.

Example: python -m blender_mrvm make-captures --scenes 12 --views 24 --resolution 64 --out data/captures64
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", type=int, default=12, help="number of scenes (default 12)")
    p.add_argument("--views", type=int, default=24, help="views per scene along its camera path (default 24)")
    p.add_argument("--resolution", default="64", help="R or WxH pixels (default 64)")
    p.add_argument("--out", required=True, help="dataset root folder")
    p.add_argument("--holdout-every", type=int, default=4,
                   help="every N-th view of a path is held out as a target between its neighbours (default 4)")
    p.add_argument("--fov-range", default="45,65", metavar="MIN,MAX",
                   help="horizontal field of view per scene, degrees (default 45,65)")
    p.add_argument("--engine", default="CYCLES", type=str.upper, help="CYCLES (default), BLENDER_EEVEE or BLENDER_WORKBENCH")
    p.add_argument("--samples", type=int, default=32, help="samples per pixel (default 32)")
    p.add_argument("--denoise", action="store_true",
                   help="Cycles: denoise each view (OpenImageDenoise), so the images carry no Monte Carlo noise a "
                   "photo would not have; off by default (the recorded capture sets were rendered without)")
    p.add_argument("--seed", type=int, default=0, help="scene k is drawn from seed + k (default 0)")
    p.add_argument("--shard", default="0/1", help="i/n: render only this deterministic share of the scenes")
    p.add_argument("--force", action="store_true", help="write into a folder that holds another dataset")


def config_fields(args) -> dict:
    """The config's fields, parsed (bpy-free: malformed arguments fail before Blender loads)."""
    from pathlib import Path

    from ..geometry.rigs import parse_range
    from .render_dataset import parse_resolution, parse_shard

    return {"out": Path(args.out), "scenes": args.scenes, "views": args.views,
            "resolution": parse_resolution(args.resolution), "engine": args.engine, "samples": args.samples,
            "denoise": args.denoise, "seed": args.seed, "holdout_every": args.holdout_every,
            "fov_range_deg": parse_range(args.fov_range, "--fov-range", 0.0, 179.0),
            "shard": parse_shard(args.shard), "force": args.force}


def run(args) -> int:
    fields = config_fields(args)
    from ..progress import run_with_tqdm
    from ..scene.capture_scenes import CaptureConfig, render_captures

    cfg = CaptureConfig(**fields)
    cfg.validate()
    summary = run_with_tqdm(render_captures(cfg), desc="captures", unit="view")
    print(f"wrote {summary.out}: {len(summary.scenes)} scenes, {summary.views_rendered} views rendered, "
          f"{summary.views_skipped} already done, {summary.seconds:.1f} s")
    return 0
