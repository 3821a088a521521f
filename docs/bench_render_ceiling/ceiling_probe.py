"""How fast could `render-dataset` be at the naive loop's image? (issue 13's 1.5x target; session 35)

Per view, in one process, alternating the order between repeats (the bench object and sphere rig of
`bench render`, Cycles CPU, the dataset renderer's scene and settings):

- naive_16spp:      the bench's naive loop (one render + Blender's PNG per view), 16 samples;
- naive_1spp:       the same at 1 sample: the per-render cost that is not path tracing;
- crop_cycles_only: render-dataset's own Cycles renders (cropped to the object's pixel box, colour read
                    back), without the data passes and the five files: its time if they cost nothing;
- render_dataset:   the whole command.

A fresh scene per measurement: with `render.use_persistent_data` Cycles keeps the first render's sample
count for every later render of a scene (seen here in bpy 5.0.1: changing `cycles.samples` between renders
had no effect), so the 1-sample loop gets its own session.

    PYTHONPATH=$PWD .venv/bin/python docs/bench_render_ceiling/ceiling_probe.py --out docs/bench_render_ceiling
"""
from __future__ import annotations

import argparse
import csv
import math
import os
import sys
import tempfile
import time
from pathlib import Path

import bpy

from blender_mrvm.bench.render import _mesh, naive_loop, ours
from blender_mrvm.geometry import cameras as C
from blender_mrvm.geometry import rigs
from blender_mrvm.scene import objects as O
from blender_mrvm.scene import raster
from blender_mrvm.scene.camera import apply_intrinsics, apply_pose
from blender_mrvm.scene.render import RenderConfig, RenderSession


def crop_cycles_only(mesh: Path, out: Path, res: int, views: int, samples: int) -> float:
    """render-dataset's Cycles renders alone: same scene, cameras, crop and EXR read-back, no data passes, no files."""
    bpy.ops.wm.read_homefile(use_empty=True)
    cfg = RenderConfig(out=out, sources=(str(mesh),), views=views, resolution=(res, res), engine="CYCLES",
                       samples=samples)
    session = RenderSession(cfg, out)
    try:
        objs = O.load_into(O.resolve_sources(cfg.sources)[0], session.coll)
        vl = session.view_layer
        O.apply_world_transform(objs, O.normalization_matrix(O.mesh_vertices_world(objs, vl)), vl)
        outline = raster.outline_points(O.mesh_triangles(objs, vl))
        intr = C.intrinsics_from_fov(math.radians(cfg.fov_deg), res, res)
        apply_intrinsics(session.camera, session.scene, intr)
        poses = rigs.rig_poses("sphere", views, rigs.framing_distance(0.5, intr.fov_x), seed=0)
        margin = int(math.ceil(session.scene.cycles.filter_width / 2)) + 1
        t0 = time.perf_counter()
        for p in poses:
            apply_pose(session.camera, p)
            session.render_colour(raster.pixel_box(outline, intr, p, margin))
        return time.perf_counter() - t0
    finally:
        session.close()


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--views", type=int, default=24)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--resolutions", default="64,128")
    a = ap.parse_args()
    methods = [("naive_16spp", lambda m, d, r, v: naive_loop(m, d, "CYCLES", r, v, 16)),
               ("naive_1spp", lambda m, d, r, v: naive_loop(m, d, "CYCLES", r, v, 1)),
               ("crop_cycles_only", lambda m, d, r, v: crop_cycles_only(m, d, r, v, 16)),
               ("render_dataset", lambda m, d, r, v: ours(m, d, "CYCLES", r, v, 16))]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        mesh = _mesh(tmp)
        for res in [int(x) for x in a.resolutions.split(",")]:
            for rep in range(a.repeats):
                order = methods if rep % 2 == 0 else methods[::-1]
                for name, fn in order:
                    d = tmp / f"{res}_{name}_{rep}"
                    d.mkdir()
                    load = os.getloadavg()[0]
                    with O.quiet_stdout():
                        sec = fn(mesh, d, res, a.views)
                    rows.append({"resolution": res, "method": name, "repeat": rep, "views": a.views,
                                 "ms_per_view": round(1000 * sec / a.views, 2), "load_1min": round(load, 2)})
                    sys.stderr.write(f"{res:4d}px {name:17s} rep {rep}: {1000 * sec / a.views:7.2f} ms/view "
                                     f"(load {load:.2f})\n")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "ceiling.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
