"""For each scene's photo sets: match once as recover_poses does, then map from the view graph's focal length and
from COLMAP's 1.2 x width guess, each scored against the truth (docs/capture_check/README.md).

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/map_bench.py SCENES WORK OUT.jsonl [THREADS]
"""
import json, shutil, sys, time
from pathlib import Path
import numpy as np
import pycolmap
from blender_mrvm.capture import align, sfm
from blender_mrvm.capture.config import CaptureConfig
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.progress import run_to_end
from photo_sets import SUBSETS, copy_subset  # noqa: E402  (beside this script)

sfm.StageLog.close = lambda self: None  # keep database.match.db
scenes, work, out_csv = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3])
threads = int(sys.argv[4]) if len(sys.argv) > 4 else 1


def mapit(db, imgs, truth, n):
    o = pycolmap.IncrementalPipelineOptions(); o.num_threads = threads; o.random_seed = 0; o.min_model_size = 3
    sp = db.parent / (db.stem + "_sparse"); shutil.rmtree(sp, ignore_errors=True); sp.mkdir()
    t = time.perf_counter()
    recs = pycolmap.incremental_mapping(db, imgs, sp, o)
    dt = time.perf_counter() - t
    if not recs:
        return {"registered": 0, "models": 0, "map_s": dt}
    r = max(recs.values(), key=lambda r: r.num_reg_images())
    names = [r.images[i].name for i in r.reg_image_ids()]
    est = [C.c2w_opencv_from_w2c(r.images[i].cam_from_world().matrix()) for i in r.reg_image_ids()]
    res = {"registered": len(names), "models": len(recs), "map_s": dt, "points": r.num_points3D(),
           "reproj": r.compute_mean_reprojection_error(), "focal": float(list(r.cameras.values())[0].params[0]),
           "obs_per_point": (sum(p.track.length() for p in r.points3D.values()) / max(r.num_points3D(), 1))}
    if len(names) >= 3:
        e = align.pose_errors(est, [truth[nm] for nm in names])
        res.update(rot_med=e.median_rotation_deg, rot_max=float(np.max(e.rotation_deg)))
    return res


rows = []
for sd in sorted(scenes.glob("scene*")):
    tj = json.loads((sd / "truth.json").read_text())
    truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
    f_true = tj["views"][0]["K"][0][0]
    for sub, idx in SUBSETS.items():
        d = copy_subset(sd, work, sub)
        cfg = CaptureConfig(num_threads=threads, single_camera=True)
        try:
            run_to_end(sfm.recover_poses(d / "images", d / "cap", cfg))
        except InputError as e:
            pass
        match_db = d / "cap" / "colmap" / "database.match.db"
        photo_dir = d / "images"
        row = {"scene": sd.name, "subset": sub, "n": len(idx), "f_true": f_true,
               "product": json.loads((d / "cap" / "colmap" / "report.json").read_text()).get("mappings")}
        a = d / "vg.db"; shutil.copy(match_db, a)
        v = pycolmap.ViewGraphCalibrationOptions(); v.random_seed = 0
        pycolmap.calibrate_view_graph(a, v)
        dbh = pycolmap.Database.open(a); row["f_viewgraph"] = float(dbh.read_all_cameras()[0].params[0]); dbh.close()
        row["vg"] = mapit(a, photo_dir, truth, len(idx))
        b = d / "guess.db"; shutil.copy(match_db, b)
        row["guess"] = mapit(b, photo_dir, truth, len(idx))
        rows.append(row)
        print(json.dumps(row), flush=True)
        with open(out_csv, "a") as fh:
            fh.write(json.dumps(row) + "\n")
