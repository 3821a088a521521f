# Exploration script of session 49 (docs/capture_check/README.md), kept as run: its paths are the session's /tmp/mapbench
import json, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.capture.check import pair_pose_check
from blender_mrvm.geometry import cameras as C
out = open(sys.argv[1], "w")
for work, scenes in [("work", "scenes"), ("work_b", "scenes_b"), ("work_c", "scenes_c")]:
    for d in sorted(Path("/tmp/mapbench", work).glob("scene*/*")):
        if not (d / "vg.db").is_file(): continue
        tj = json.loads((Path("/tmp/mapbench", scenes) / d.parent.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        row = {"scene": d.parent.name, "subset": d.name, "n": len(list((d / "images").glob("*.png")))}
        for start in ("vg", "guess"):
            sp = d / f"{start}_sparse"
            models = [p for p in sp.iterdir() if p.is_dir()] if sp.is_dir() else []
            if not models: row[start] = {"placed": 0}; continue
            recs = [pycolmap.Reconstruction(str(m)) for m in models]
            rec = max(recs, key=lambda r: r.num_reg_images())
            ids = list(rec.reg_image_ids())
            rot = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids], [truth[rec.images[i].name] for i in ids]).median_rotation_deg if len(ids) >= 3 else None
            c = pair_pose_check(rec, d / f"{start}.db")
            row[start] = {"placed": len(ids), "rot": rot, "med": c["median_disagreement_deg"], "suspect": c["suspect"]}
        out.write(json.dumps(row) + "\n"); out.flush()
