"""Set F: each photo set through recover-poses (the models it keeps) and, for rings, global mapping on its database;
each model's error against the truth, the shipped medians' verdict and the fourth rule's split (RULE.md).

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/sparse/confirm_f.py SCENES WORK OUT.jsonl
"""
import json, shutil, sys, time
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align, sfm
from blender_mrvm.capture.check import pair_angles, pair_pose_check
from blender_mrvm.capture.config import CaptureConfig
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.progress import run_to_end

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from photo_sets import SUBSETS, copy_subset  # noqa: E402  (docs/capture_check/)
pycolmap.logging.minloglevel = 2
scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
T = 5.0


def pieces(nodes, edges):
    parent = {n: n for n in nodes}
    def find(x):
        while parent[x] != x:
            parent[x] = parent[parent[x]]; x = parent[x]
        return x
    for a, b in edges:
        parent[find(a)] = find(b)
    return len({find(n) for n in nodes})


def judge(rec, db, truth):
    ids = list(rec.reg_image_ids()); names = [rec.images[i].name for i in ids]
    rot = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids],
                            [truth[n] for n in names]).median_rotation_deg
    c = pair_pose_check(rec, db, split_check=False)  # the medians alone; the split is computed here
    ang = pair_angles(rec, db)
    split = pieces(names, [(a, b) for r, d, a, b in ang if max(r, d) <= T]) - pieces(names, [(a, b) for r, d, a, b in ang])
    return {"placed": len(ids), "rot": round(rot, 2), "pairs": c["pairs"], "rmed": c["median_disagreement_deg"],
            "tmed": c["median_direction_deg"], "medians_suspect": c["suspect"], "split": split,
            "rule4_suspect": bool(c["suspect"] or (c["pairs"] >= 3 and split > 0))}


with open(out, "w") as fh:
    for sd in sorted(scenes.glob("scene*")):
        tj = json.loads((sd / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        for sub, idx in SUBSETS.items():
            d = copy_subset(sd, work, sub)
            row = {"scene": sd.name, "subset": sub, "n": len(idx)}
            t = time.perf_counter()
            try:
                run_to_end(sfm.recover_poses(d / "images", d / "cap", CaptureConfig(num_threads=1, single_camera=True)))
                meta = json.loads((d / "cap" / "meta.json").read_text())
                row["kept"] = judge(pycolmap.Reconstruction(str(d / "cap" / meta["colmap_model"])),
                                    d / "cap/colmap/database.db", truth)
            except InputError as e:
                row["kept"] = {"error": str(e)[:100]}
            row["s"] = round(time.perf_counter() - t, 1)
            if sub == "ring12":
                g = d / "glob"; g.mkdir()
                shutil.copy(d / "cap/colmap/database.db", g / "db.db")
                o = pycolmap.GlobalPipelineOptions(); o.num_threads = 1; o.random_seed = 0
                (g / "sparse").mkdir()
                try:
                    recs = pycolmap.global_mapping(g / "db.db", d / "images", g / "sparse", o)
                except Exception as e:  # noqa: BLE001  (exploration: any failure is a row)
                    recs, row["global"] = {}, {"error": str(e)[:100]}
                if recs:
                    rec = max(recs.values(), key=lambda r: r.num_reg_images())
                    row["global"] = judge(rec, g / "db.db", truth) if rec.num_reg_images() >= 3 else {"placed": rec.num_reg_images()}
            print(json.dumps(row), flush=True)
            fh.write(json.dumps(row) + "\n")
