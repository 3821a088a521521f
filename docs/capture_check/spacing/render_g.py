"""Set G (RULE.md's fifth rule): N textured ring scenes with 36 views (10 degrees apart), seeds 100+S..., the same
scene parameters as `render_scenes.py` (field of view, portrait photos, radius, camera height by the scene number).

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/render_g.py OUT N S
"""
import json, sys, time
from pathlib import Path
import bpy  # noqa
from blender_mrvm.scene.capture import render_textured_ring

out, n, s0 = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
fovs = [45, 55, 65, 75]
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
    render_textured_ring(d, n_views=36, width=w, height=h, radius=radius, cam_height=height, fov_x_deg=fov,
                         samples=4, seed=100 + s, threads=2)
    (d / "params.json").write_text(json.dumps({"seed": 100 + s, "width": w, "height": h, "fov_x_deg": fov,
                                               "radius": radius, "cam_height": height, "views": 36}))
    print(s, w, h, fov, radius, height, f"{time.time()-t:.1f}s", flush=True)
