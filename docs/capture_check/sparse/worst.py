"""Worst-pair statistics of each global model (g2_guess, g2_vg) against its error."""
import json, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.capture.check import pair_pose_check
from blender_mrvm.geometry import cameras as C
pycolmap.logging.minloglevel = 2
scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
with open(out, "w") as fh:
    for sd in sorted(work.glob("scene*")):
        tj = json.loads((scenes / sd.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        for start in ("guess", "vg"):
            d = sd / f"ring12/g2_{start}"
            ms = sorted((d / "sparse").iterdir()) if (d / "sparse").is_dir() else []
            if not ms: continue
            recs = [pycolmap.Reconstruction(str(m)) for m in ms]
            rec = max(recs, key=lambda r: r.num_reg_images()); ids = list(rec.reg_image_ids())
            if len(ids) < 3: continue
            rot = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids], [truth[rec.images[i].name] for i in ids]).median_rotation_deg
            c = pair_pose_check(rec, d / "db.db")
            w = c.get("worst") or []
            row = {"scene": sd.name, "start": start, "placed": len(ids), "rot": round(rot, 2), "pairs": c["pairs"],
                   "rmed": c["median_disagreement_deg"], "tmed": c["median_direction_deg"], "suspect": c["suspect"],
                   "worst": w, "share5": c.get("share_over_5_deg")}
            print(json.dumps(row), flush=True); fh.write(json.dumps(row) + "\n")
