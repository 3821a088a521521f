# Exploration script of session 49 (docs/capture_check/README.md), kept as run: its paths are the session's /tmp/mapbench
import json, shutil, sys, time
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.capture.check import pair_pose_check
from blender_mrvm.geometry import cameras as C
pycolmap.logging.minloglevel = 2
subs = sys.argv[1].split(",")
for work, scenes in [("work", "scenes"), ("work_b", "scenes_b")]:
    for d in sorted(Path("/tmp/mapbench", work).glob("scene*/*")):
        if d.name not in subs: continue
        tj = json.loads((Path("/tmp/mapbench", scenes) / d.parent.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        n = len(list((d / "images").glob("*.png")))
        res = []
        for start in ("vg", "guess"):
            db = d / f"glob_{start}.db"
            shutil.copy(d / "vg.db" if start == "vg" else d / "cap/colmap/database.match.db", db)
            sp = d / f"glob_{start}_sparse"; shutil.rmtree(sp, ignore_errors=True); sp.mkdir()
            o = pycolmap.GlobalPipelineOptions(); o.num_threads = 1; o.random_seed = 0
            t = time.perf_counter()
            try:
                recs = pycolmap.global_mapping(db, d / "images", sp, o)
            except Exception as e:
                res.append(f"{start}: err {e}"[:80]); continue
            dt = time.perf_counter() - t
            if not recs: res.append(f"{start}: 0"); continue
            rec = max(recs.values(), key=lambda r: r.num_reg_images()); ids = list(rec.reg_image_ids())
            rot = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids], [truth[rec.images[i].name] for i in ids]).median_rotation_deg if len(ids) >= 3 else float("nan")
            c = pair_pose_check(rec, db)
            res.append(f"{start}: {len(ids)}/{n} {rot:.2f}deg chk {c['median_disagreement_deg']} {dt:.1f}s")
        print(d.parent.name, d.name, " | ".join(res), flush=True)
