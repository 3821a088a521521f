"""Dataset rendering speed: views/second of ``render-dataset`` against a naive per-view loop.

The naive loop is what the usual scripts do: one ``bpy.ops.render.render(write_still=True)`` per
view with Blender writing a PNG (RGB only), in the same scene (object, light, world, engine,
samples, resolution) as ours. ``render-dataset`` writes RGB, depth, normals, part mask and pose per
view plus the per-object files (one colour render per view, limited to the pixels the object can
reach; the pixel-centre data passes rasterized and written on a thread while the next view renders),
and its time includes loading the object. The two run side by side, alternating, ``--repeats``
times; each row records the machine's load average, and ``render_dataset`` rows the ratio to the
naive loop of the same repeat. Figures go to ``<out>/bench_render.csv``.
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

from . import write_csv

RESULTS = ("bench_render.csv",)
"""What the bench writes into ``--out`` (``bench.check_results``)."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="bench_out", help="folder for bench_render.csv")
    p.add_argument("--views", type=int, default=24, help="views per measurement (Cycles, Workbench)")
    p.add_argument("--eevee-views", type=int, default=3, help="views per measurement for EEVEE (slow on software GL)")
    p.add_argument("--resolutions", default="64,128", help="comma-separated square image sizes, pixels")
    p.add_argument("--engines", default="CYCLES,BLENDER_WORKBENCH,BLENDER_EEVEE", help="comma-separated render engines")
    p.add_argument("--samples", type=int, default=16, help="samples per pixel")
    p.add_argument("--repeats", type=int, default=1, help="side-by-side measurements per engine and resolution "
                                                          "(the order alternates to cancel drift)")


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
    from ..scene import compat
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
        compat.set_file_format(s, "PNG")
        s.color_depth = "8"
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
    import os
    import platform

    from ..scene.render import ENGINES
    from . import at_least, names, start_results, whole_numbers

    at_least(args, repeats=1, views=1, eevee_views=1, samples=1)
    resolutions = whole_numbers(args.resolutions, "--resolutions")
    engines = names(str(args.engines).upper(), "--engines", ENGINES)  # FOO had been a TypeError mid-run
    out = start_results(Path(args.out), RESULTS, args.force)
    rows = []
    methods = (("naive_loop", naive_loop, "rgb png"),
               ("render_dataset", ours, "rgb png, depth+normal exr, mask png, pose, intrinsics, transforms.json, meta"))
    machine = f"{platform.machine()} {os.cpu_count()} cpu"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        mesh = _mesh(tmp)
        for engine in engines:
            views = args.eevee_views if engine == "BLENDER_EEVEE" else args.views
            for res in resolutions:
                for rep in range(args.repeats):
                    vps = {}
                    for method, fn, outputs in (methods if rep % 2 == 0 else methods[::-1]):
                        d = tmp / f"{engine}_{res}_{method}_{rep}"
                        d.mkdir()
                        load = os.getloadavg()[0]
                        sec = fn(mesh, d, engine, res, views, args.samples)
                        vps[method] = views / sec
                        row = {"engine": engine, "resolution": res, "method": method, "repeat": rep, "views": views,
                               "samples": args.samples, "seconds": round(sec, 3),
                               "views_per_second": round(views / sec, 3), "ratio_to_naive": "",
                               "load_1min": round(load, 2), "machine": machine, "outputs": outputs}
                        rows.append(row)
                        print(f"{engine:18s} {res:4d}px {method:15s} {views:3d} views {sec:7.2f} s "
                              f"{views / sec:7.2f} views/s  (load {load:.2f})", flush=True)
                    ratio = vps["render_dataset"] / vps["naive_loop"]
                    for row in rows[-2:]:
                        if row["method"] == "render_dataset":
                            row["ratio_to_naive"] = round(ratio, 3)
                    print(f"{'':18s} {res:4d}px ratio render_dataset / naive_loop: {ratio:.2f}x", flush=True)
                    write_csv(out / "bench_render.csv", rows, quiet=True)  # a run cut short keeps its pairs
    write_csv(out / "bench_render.csv", rows)
    return 0
