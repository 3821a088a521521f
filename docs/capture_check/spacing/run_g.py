"""Set G (RULE.md's fifth rule): each photo set through `recover-poses` (shared camera, 1 thread), then the spacing
with the mapping's own model camera (`check.photo_spacing`), the error line if refused, the kept model's error
against the truth and its pose check. One JSON line a photo set.

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/run_g.py SCENES WORK OUT.jsonl
"""
import json, shutil, sys, time
from pathlib import Path
import numpy as np
import pycolmap
from blender_mrvm.capture import align, sfm
from blender_mrvm.capture.check import SPARSE_SPACING_DEG, photo_spacing, spacing_camera
from blender_mrvm.capture.config import CaptureConfig
from blender_mrvm.errors import InputError
from blender_mrvm.progress import run_to_end

pycolmap.logging.minloglevel = 2
SUBSETS = {"a10": range(10, 20), "a20": range(0, 16, 2), "r30": range(0, 36, 3), "r40": range(0, 36, 4)}
TRUE_DEG = {"a10": 10, "a20": 20, "r30": 30, "r40": 40}
scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
cfg = CaptureConfig(num_threads=1, single_camera=True)


def largest(sparse: Path):
    best = None
    for d in sorted(sparse.glob("*")):
        try:
            r = pycolmap.Reconstruction(d)
        except Exception:
            continue
        if best is None or r.num_reg_images() > best.num_reg_images():
            best = r
    return best


with open(out, "w") as f:
    for scene in sorted(scenes.glob("scene*")):
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in json.loads((scene / "truth.json").read_text())["views"]}
        for sub, idx in SUBSETS.items():
            d = work / scene.name / sub
            shutil.rmtree(d, ignore_errors=True)
            (d / "images").mkdir(parents=True)
            for i in idx:
                shutil.copy(scene / "images" / f"{i:03d}.png", d / "images")
            t = time.time()
            row = {"scene": scene.name, "subset": sub, "true_deg": TRUE_DEG[sub], "n": len(idx)}
            try:
                res = run_to_end(sfm.recover_poses(d / "images", d / "cap", cfg))
                err = align.pose_errors(res.c2w_opencv, [np.array(truth[n]) for n in res.registered])
                row.update({"kept": True, "placed": len(res.registered), "rot": round(err.median_rotation_deg, 2),
                            "suspect": bool(res.pose_check.get("suspect")),
                            "warning_spacing": res.pose_check.get("photo_spacing_deg")})
            except InputError as e:
                row.update({"kept": False, "error": str(e)})
            colmap = d / "cap" / "colmap"
            # the model the mapping kept: the one placing more of its two tries (sfm.recover_poses)
            tries = [largest(colmap / s) for s in ("sparse", "sparse_guess") if (colmap / s).is_dir()]
            tries = [r for r in tries if r is not None]
            rec = max(tries, key=lambda r: r.num_reg_images()) if tries else None
            cam = spacing_camera(rec)
            sp = photo_spacing(colmap / "database.db", cam)
            row.update({"model_photos": rec.num_reg_images() if rec else 0, "spacing": sp["spacing_deg"],
                        "focal_from": sp["focal_from"], "unmatched": len(sp["unmatched"]),
                        "advice_in_error": "degrees apart" in row.get("error", ""),
                        "s": round(time.time() - t, 1), "threshold": SPARSE_SPACING_DEG})
            f.write(json.dumps(row) + "\n"); f.flush()
            print(json.dumps(row)[:220], flush=True)
