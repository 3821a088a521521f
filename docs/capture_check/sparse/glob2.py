"""ring12: global mapping from the match database (focal guess) and from the view-graph-calibrated copy; each model's
pose check, their agreement, and the error against the truth."""
import json, shutil, sys, time
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.capture.check import pair_pose_check
from blender_mrvm.geometry import cameras as C
pycolmap.logging.minloglevel = 2
scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
def poses(rec):
    return {rec.images[i].name: C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in rec.reg_image_ids()}
with open(out, "w") as fh:
    for sd in sorted(work.glob("scene*")):
        tj = json.loads((scenes / sd.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        base = sd / "ring12/base/cap/colmap"
        src = base / "database.match.db" if (base / "database.match.db").is_file() else base / "database.db"
        imgs = sd / "ring12/base/images"
        if not imgs.is_dir():
            imgs.mkdir(parents=True)
            for i in range(0, 24, 2): shutil.copy(scenes / sd.name / "images" / f"{i:03d}.png", imgs)
        row = {"scene": sd.name}; models = {}
        for start in ("guess", "vg"):
            d = sd / f"ring12/g2_{start}"; shutil.rmtree(d, ignore_errors=True); d.mkdir(parents=True)
            db = d / "db.db"; shutil.copy(src, db)
            if start == "vg":
                v = pycolmap.ViewGraphCalibrationOptions(); v.random_seed = 0
                pycolmap.calibrate_view_graph(db, v)
            o = pycolmap.GlobalPipelineOptions(); o.num_threads = 1; o.random_seed = 0
            sp = d / "sparse"; sp.mkdir()
            t = time.perf_counter()
            try:
                recs = pycolmap.global_mapping(db, imgs, sp, o)
            except Exception as e:
                row[start] = {"error": str(e)[:80]}; continue
            if not recs: row[start] = {"placed": 0}; continue
            rec = max(recs.values(), key=lambda r: r.num_reg_images()); p = poses(rec)
            r = {"placed": len(p), "s": round(time.perf_counter() - t, 2)}
            if len(p) >= 3:
                r["rot_med"] = round(align.pose_errors(list(p.values()), [truth[n] for n in p]).median_rotation_deg, 2)
                c = pair_pose_check(rec, db)
                r.update(suspect=c.get("suspect"), chk_rot=c.get("median_disagreement_deg"), chk_dir=c.get("median_direction_deg"), pairs=c.get("pairs"))
                models[start] = p
            row[start] = r
        if len(models) == 2:
            common = sorted(set(models["guess"]) & set(models["vg"]))
            if len(common) >= 3:
                e = align.pose_errors([models["guess"][n] for n in common], [models["vg"][n] for n in common])
                row["agree_rot_med"] = round(e.median_rotation_deg, 2); row["agree_rot_max"] = round(float(np.max(e.rotation_deg)), 2)
                row["common"] = len(common)
        print(json.dumps(row), flush=True); fh.write(json.dumps(row) + "\n")
