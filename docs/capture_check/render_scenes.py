"""Render N textured ring scenes with known poses (scene<S>..scene<S+N-1>, seeds 100+S...) for the benchmark, each
with VIEWS views round the ring (default 24, 15 degrees apart; set G: 36, 10 degrees apart).

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/render_scenes.py OUT N [S [VIEWS]]
"""
import json, sys, time
from pathlib import Path
import bpy  # noqa
from blender_mrvm.scene.capture import render_textured_ring

out = Path(sys.argv[1]); n = int(sys.argv[2])
fovs = [45, 55, 65, 75]
s0 = int(sys.argv[3]) if len(sys.argv) > 3 else 0
views = int(sys.argv[4]) if len(sys.argv) > 4 else 24
for s in range(s0, s0 + n):
    d = out / f"scene{s:02d}"
    if (d / "truth.json").exists():
        continue
    portrait = s % 2 == 1
    w, h = (240, 320) if portrait else (320, 240)
    fov = fovs[s % 4] if not portrait else fovs[(s // 2) % 4]
    radius = 3.5 + 0.1 * (s % 7)
    height = 1.0 + 0.2 * (s % 6)
    t = time.time()
    render_textured_ring(d, n_views=views, width=w, height=h, radius=radius, cam_height=height, fov_x_deg=fov,
                         samples=4, seed=100 + s, threads=2)
    (d / "params.json").write_text(json.dumps({"seed": 100 + s, "width": w, "height": h, "fov_x_deg": fov,
                                               "radius": radius, "cam_height": height, "views": views}))
    print(s, w, h, fov, radius, height, f"{time.time()-t:.1f}s", flush=True)
