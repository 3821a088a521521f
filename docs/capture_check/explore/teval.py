# Exploration script of session 49 (docs/capture_check/README.md), kept as run: its paths are the session's /tmp/mapbench
import json, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.geometry import cameras as C
from blender_mrvm.capture.check import pair_pose_check
out = open(sys.argv[1], "w")
for work, scenes in [("work", "scenes"), ("work_b", "scenes_b"), ("work_c", "scenes_c")]:
    for d in sorted(Path("/tmp/mapbench", work).glob("scene*/*")):
        tj = json.loads((Path("/tmp/mapbench", scenes) / d.parent.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        cands = []
        if (d / "cap/meta.json").is_file():
            meta = json.loads((d / "cap/meta.json").read_text()); cands.append(("kept", d / "cap" / meta["colmap_model"], d / "cap/colmap/database.db"))
        for st in ("vg", "guess"):
            sp = d / f"glob_{st}_sparse"
            if sp.is_dir():
                for m in sp.iterdir(): cands.append((f"glob_{st}", m, d / f"glob_{st}.db")); break
        for kind, model, db in cands:
            rec = pycolmap.Reconstruction(str(model)); ids = list(rec.reg_image_ids())
            if len(ids) < 3: continue
            rot = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids], [truth[rec.images[i].name] for i in ids]).median_rotation_deg
            c = pair_pose_check(rec, db)
            r, t, n = c["median_disagreement_deg"], c["median_direction_deg"], c["pairs"]
            out.write(json.dumps({"scene": d.parent.name, "sub": d.name, "kind": kind, "placed": len(ids), "rot": rot, "rmed": r, "tmed": t, "pairs": n}) + "\n"); out.flush()
