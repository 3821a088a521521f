"""Render a ShapeNet-style multi-view dataset (RGB, depth, normals, part masks, SRN poses, transforms.json).

Examples:
  python -m blender_mrvm render-dataset --source chair.obj --rig sphere --views 24 --resolution 128 --out data/
  python -m blender_mrvm render-dataset --source ShapeNetCore.v2/03001627 --shard 0/8 --out data/
  python -m blender_mrvm render-dataset --blend scene.blend --source selected --rig scene --out data/
Finished views are skipped when a run is repeated (resume); files are written atomically.
"""

from __future__ import annotations

import argparse
import sys

from ..errors import InputError


def parse_resolution(text: str) -> tuple[int, int]:
    try:
        if "x" in text.lower():
            w, h = text.lower().split("x")
            return int(w), int(h)
        r = int(text)
        return r, r
    except ValueError:
        raise InputError(f"resolution must be R or WxH in pixels, got {text!r}") from None


def parse_shard(text: str) -> tuple[int, int]:
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise InputError(f"shard must be i/n (e.g. 0/4), got {text!r}") from None
    if n < 1 or not 0 <= i < n:
        raise InputError(f"shard must be i/n with 0 <= i < n, got {text!r}")
    return i, n


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", action="append", required=True, metavar="SRC",
                   help="mesh file (obj, ply, stl, glb, gltf, off, fbx, usd/usda/usdc/usdz, abc; with assimp-py "
                        "also dae (COLLADA), ASCII fbx, 3ds, lwo, x, ac, ase, 3mf, ms3d, x3d, amf, dxf), .blend file (what a render "
                        "of its first scene shows), .zip archive of them (a downloaded model with its textures; also "
                        "KMZ and .zae), "
                        "folder of them, ShapeNetCore folder, 'selected', or "
                        "'procedural:<category>:<seed>'; repeat for several (each object is named by its file; "
                        "files of one name in different folders, such as two robots' link1.stl, by their folders "
                        "too: panda_link1, xarm_link1)")
    p.add_argument("--out", required=True, help="dataset root folder")
    p.add_argument("--rig", default="sphere", help="sphere | hemisphere | spiral | turntable | scene (default: sphere)")
    p.add_argument("--views", type=int, default=24, help="views per object (default: 24; --rig scene: one a scene "
                   "camera)")
    p.add_argument("--resolution", default="128", help="R or WxH pixels (default: 128); with --rig scene, R is the longer side of the scene's frame shape "
                        "(its resolution and pixel aspect), so the views show what its cameras frame")
    p.add_argument("--engine", default="CYCLES", type=str.upper,
                   help="CYCLES | BLENDER_EEVEE | BLENDER_WORKBENCH (default: CYCLES, on the CPU)")
    p.add_argument("--samples", type=int, default=32, help="samples per pixel (default: 32)")
    p.add_argument("--rgba", action="store_true", help="write RGBA images instead of compositing on white")
    p.add_argument("--fov", type=float, default=40.0, help="horizontal field of view of generated cameras, degrees "
                   "(default 40; with any of the --*-range options each view draws its own)")
    p.add_argument("--elevation", type=float, default=20.0, help="--rig turntable: its elevation, degrees (default 20)")
    p.add_argument("--fov-range", default=None, metavar="MIN,MAX",
                   help="sphere/hemisphere rigs: draw each view's horizontal field of view from this range, degrees; "
                        "one number fixes it (any of the three ranges turns varied cameras on; one alone takes the "
                        "others' defaults: 30,60 and 0.85,1.6)")
    p.add_argument("--distance-range", default=None, metavar="MIN,MAX",
                   help="sphere/hemisphere rigs: camera distance per view, multiples of the distance at which the "
                        "object's bounding sphere fills the view; one number fixes it")
    p.add_argument("--elevation-range", default=None, metavar="MIN,MAX",
                   help="sphere/hemisphere rigs with varied cameras: keep the directions to this band of elevations, "
                        "degrees (default: the whole rig)")
    p.add_argument("--seed", type=int, default=0, help="seed of random rigs and splits (default 0)")
    p.add_argument("--category", default=None, help="category folder for mesh files / selected objects (default: custom)")
    p.add_argument("--split", default=None, choices=["train", "val", "test"], help="put every object into this split")
    p.add_argument("--shard", default="0/1", help="i/n: render only this shard of the objects (default 0/1)")
    p.add_argument("--blend", default=None, help="open this .blend first (for 'selected' and the scene rig)")
    p.add_argument("--force", action="store_true", help="overwrite an output folder that holds another dataset")
    p.add_argument("--skip-bad-meshes", action="store_true",
                   help="skip a mesh file that cannot be read or is refused (no faces, NaN coordinates) and go on, "
                        "naming each at the end, instead of stopping at the first (for folders of many meshes)")


def config_from_args(args):
    from pathlib import Path

    from ..scene.render import RenderConfig

    from ..geometry import rigs

    fov_range = dist_range = el_range = None
    el = getattr(args, "elevation_range", None)
    if el is not None:
        el_range = rigs.parse_range(el, "--elevation-range", -90.0, 90.0, inclusive_lo=True)
    if args.fov_range is not None or args.distance_range is not None or el_range is not None:
        fov_range = rigs.parse_range(args.fov_range, "--fov-range", 0.0, 179.0) if args.fov_range else rigs.FOV_RANGE_DEG
        dist_range = (rigs.parse_range(args.distance_range, "--distance-range", 0.0, 100.0) if args.distance_range
                      else rigs.DISTANCE_RANGE)
    return RenderConfig(out=Path(args.out), sources=tuple(args.source), rig=args.rig, views=args.views,
                        resolution=parse_resolution(args.resolution), engine=args.engine, samples=args.samples,
                        rgba=args.rgba, fov_deg=args.fov, elevation_deg=args.elevation, seed=args.seed,
                        category=args.category, shard=parse_shard(args.shard), force=args.force, split=args.split,
                        skip_bad_meshes=args.skip_bad_meshes,
                        fov_range_deg=fov_range, distance_range=dist_range, elevation_range_deg=el_range)


def run(args) -> int:
    from pathlib import Path

    cfg = config_from_args(args)
    cfg.validate()  # before importing Blender: bad arguments fail fast
    import bpy

    if not args.blend and not bpy.data.filepath:  # Blender's factory scene (its cube, its camera), not the user's
        wants = [w for w, asked in (("--source selected renders the objects selected", "selected" in cfg.sources),
                                    ("--rig scene looks through the cameras", cfg.rig == "scene")) if asked]
        if wants:
            raise InputError(f"{' and '.join(wants)} in an open .blend file: name it with --blend FILE (without it, "
                             "that is Blender's factory startup scene; a .blend given as --source is rendered, but "
                             "its cameras are not read)")

    from ..progress import run_with_tqdm
    from ..scene.render import render_dataset

    if args.blend:
        if not Path(args.blend).is_file():
            raise InputError(f".blend file not found: {args.blend}")
        from ..scene.objects import quiet_stdout

        with quiet_stdout():  # (Blender's 'Read blend: ...' line on stdout, before the command's summary)
            bpy.ops.wm.open_mainfile(filepath=str(Path(args.blend).resolve()))
    if cfg.rig == "scene" and "x" not in args.resolution.lower():  # R: the scene's frame shape, longer side R
        from dataclasses import replace

        from ..scene.render import scene_frame_size

        cfg = replace(cfg, resolution=scene_frame_size(bpy.context.scene, cfg.resolution[0]))
    summary = run_with_tqdm(render_dataset(cfg), desc="render", unit="view")
    skipped = f", {len(summary.skipped)} meshes skipped as unusable" if summary.skipped else ""
    print(f"{len(summary.objects)} objects, {summary.views_rendered} views rendered, "
          f"{summary.views_skipped} already done{skipped}, {summary.seconds:.1f} s -> {Path(summary.out).resolve()}")
    for w in summary.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0
