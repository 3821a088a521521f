"""Every compared pair of every kept model (RULE.md's sixth rule): the model's error against the truth, and per pair
its rotation and direction disagreement with the model (`check.pair_angles`) and its turn in the model. One JSON line a
kept model: {"set", "scene", "sub", "err", "placed", "pairs": [[rotation, direction, turn, photo a, photo b], ...]}.

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/pairs.py OUT.jsonl SET=SCENES:WORK [SET=SCENES:WORK ...]

e.g. `G=/tmp/mb/scenes_g:/tmp/mb/work_g`. Every photo set folder under WORK/<scene>/ with a `cap/meta.json` counts.
"""
import json, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.capture.align import rotation_angle_deg
from blender_mrvm.capture.check import pair_angles
from blender_mrvm.geometry import cameras as C

pycolmap.logging.minloglevel = 2
with open(sys.argv[1], "w") as out:
    for arg in sys.argv[2:]:
        label, paths = arg.split("=", 1)
        scenes, work = (Path(p) for p in paths.split(":"))
        for scene in sorted(work.glob("scene*")):
            tj = json.loads((scenes / scene.name / "truth.json").read_text())
            truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
            for d in sorted(p for p in scene.iterdir() if (p / "cap" / "meta.json").exists()):
                meta = json.loads((d / "cap" / "meta.json").read_text())
                rec = pycolmap.Reconstruction(str(d / "cap" / meta["colmap_model"]))
                ids = list(rec.reg_image_ids())
                names = [rec.images[i].name for i in ids]
                err = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids],
                                        [truth[n.replace(".jpg", ".png")] for n in names]).median_rotation_deg
                by = {rec.images[i].name: rec.images[i] for i in ids}
                pairs = []
                for r, dd, a, b in pair_angles(rec, d / "cap" / "colmap" / "database.db"):
                    rel = by[b].cam_from_world() * by[a].cam_from_world().inverse()
                    pairs.append([round(r, 3), round(dd, 3), round(rotation_angle_deg(rel.rotation.matrix()), 2), a, b])
                out.write(json.dumps({"set": label, "scene": scene.name, "sub": d.name, "err": round(err, 3),
                                      "placed": len(ids), "pairs": pairs}) + "\n")
