"""Dataset rendering speed: views/second of ``render-dataset`` against a naive per-view loop.

The naive loop is what the usual scripts do: one ``bpy.ops.render.render(write_still=True)`` per
view with Blender writing a PNG (RGB only), in the same scene (object, light, world, engine,
samples, resolution) as ours. ``render-dataset`` writes RGB, depth, normals, part mask and pose per view (two
renders: colour + 1-sample data passes). Figures go to ``<out>/bench_render.csv``.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from . import write_csv


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_render.csv")
    p.add_argument("--views", type=int, default=24, help="views per measurement (Cycles, Workbench)")
    p.add_argument("--eevee-views", type=int, default=3, help="views per measurement for EEVEE (slow on software GL)")
    p.add_argument("--resolutions", default="64,128")
    p.add_argument("--engines", default="CYCLES,BLENDER_WORKBENCH,BLENDER_EEVEE")
    p.add_argument("--samples", type=int, default=16)


def _mesh(folder: Path) -> Path:
    import trimesh

    box = trimesh.creation.box(extents=(0.8, 0.5, 0.4))
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.22)
    ball.apply_translation((0.35, 0.2, 0.3))
    m = trimesh.util.concatenate([box, ball, trimesh.creation.torus(0.3, 0.08)])
    path = folder / "bench_object.ply"
    m.export(path)
    return path


def naive_loop(mesh: Path, out: Path, engine: str, res: int, views: int, samples: int) -> float:
    """Seconds for ``views`` renders the usual way: the same scene (object, light, world, engine
    settings) as ``render-dataset``, but one plain render per view with Blender writing an RGB PNG."""
    import bpy

    from ..geometry import cameras as C
    from ..geometry import rigs
    from ..scene import objects as O
    from ..scene.camera import apply_intrinsics, apply_pose
    from ..scene.render import RenderConfig, RenderSession

    bpy.ops.wm.read_homefile(use_empty=True)
    cfg = RenderConfig(out=out, sources=(str(mesh),), views=views, resolution=(res, res), engine=engine,
                       samples=samples)
    session = RenderSession(cfg, out)
    try:
        objs = O.load_into(O.resolve_sources(cfg.sources)[0], session.coll)
        vl = session.scene.view_layers[0]
        O.apply_world_transform(objs, O.normalization_matrix(O.mesh_vertices_world(objs, vl)), vl)
        intr = C.intrinsics_from_fov(math.radians(cfg.fov_deg), res, res)
        scene = session.scene
        apply_intrinsics(session.camera, scene, intr)
        s = scene.render.image_settings
        s.media_type, s.file_format, s.color_depth = "IMAGE", "PNG", "8"
        scene.render.use_file_extension = True
        poses = rigs.rig_poses("sphere", views, rigs.framing_distance(0.5, intr.fov_x), seed=0)
        t0 = time.perf_counter()
        for i, p in enumerate(poses):
            apply_pose(session.camera, p)
            scene.render.filepath = str(out / f"{i:06d}")
            with O.quiet_stdout():
                bpy.ops.render.render(write_still=True, scene=scene.name)
        return time.perf_counter() - t0
    finally:
        session.close()


def ours(mesh: Path, out: Path, engine: str, res: int, views: int, samples: int) -> float:
    import bpy

    from ..progress import run_to_end
    from ..scene.render import RenderConfig, render_dataset

    bpy.ops.wm.read_homefile(use_empty=True)
    cfg = RenderConfig(out=out, sources=(str(mesh),), views=views, resolution=(res, res), engine=engine,
                       samples=samples)
    t0 = time.perf_counter()
    summary = run_to_end(render_dataset(cfg))
    assert summary.views_rendered == views
    return time.perf_counter() - t0


def run(args) -> int:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        mesh = _mesh(tmp)
        for engine in [e.strip().upper() for e in args.engines.split(",") if e.strip()]:
            views = args.eevee_views if engine == "BLENDER_EEVEE" else args.views
            for res in [int(r) for r in args.resolutions.split(",")]:
                for method, fn, outputs in (("naive_loop", naive_loop, "rgb png"),
                                            ("render_dataset", ours, "rgb png, depth+normal exr, mask png, pose")):
                    d = tmp / f"{engine}_{res}_{method}"
                    d.mkdir()
                    sec = fn(mesh, d, engine, res, views, args.samples)
                    row = {"engine": engine, "resolution": res, "method": method, "views": views,
                           "samples": args.samples, "seconds": round(sec, 3),
                           "views_per_second": round(views / sec, 3), "outputs": outputs}
                    rows.append(row)
                    print(f"{engine:18s} {res:4d}px {method:15s} {views:3d} views {sec:7.2f} s "
                          f"{views / sec:7.2f} views/s", flush=True)
    write_csv(out / "bench_render.csv", rows)
    return 0
