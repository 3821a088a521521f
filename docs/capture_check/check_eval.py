"""The product's pose check (blender_mrvm/capture/check.py) on each subset's kept model, beside its error against
the truth. Over every verified pair ("all") and over pairs COLMAP verified as CALIBRATED or UNCALIBRATED
("general", the shipped one); each with the rotations' median and the directions' (between the cameras' centres).

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/check_eval.py WORK SCENES OUT.jsonl
"""
import json
import sys
import time
from pathlib import Path

import numpy as np
import pycolmap

from blender_mrvm.capture import align
from blender_mrvm.capture.check import pair_pose_check
from blender_mrvm.geometry import cameras as C

work, scenes, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
with open(out, "w") as fh:
    for cap in sorted(work.glob("scene*/*/cap")):
        if not (cap / "meta.json").is_file():
            continue  # refused by recover-poses (fewer than half the photos placed)
        meta = json.loads((cap / "meta.json").read_text())
        tj = json.loads((scenes / cap.parent.parent.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        rec = pycolmap.Reconstruction(str(cap / meta["colmap_model"]))
        ids = list(rec.reg_image_ids())
        e = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids],
                              [truth[rec.images[i].name] for i in ids])
        row = {"scene": cap.parent.parent.name, "subset": cap.parent.name, "placed": len(ids), "n": meta["total"],
               "rot_med": round(e.median_rotation_deg, 2)}
        for key, general in (("all", False), ("general", True)):
            t = time.perf_counter()
            c = pair_pose_check(rec, cap / "colmap" / "database.db", general_only=general)
            row[key] = {"pairs": c["pairs"], "median": c["median_disagreement_deg"],
                        "direction": c["median_direction_deg"], "seconds": round(time.perf_counter() - t, 3)}
        fh.write(json.dumps(row) + "\n")
