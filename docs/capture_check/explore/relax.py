# Exploration script of session 49 (docs/capture_check/README.md), kept as run: its paths are the session's /tmp/mapbench
import json, shutil, sys, time
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.geometry import cameras as C
work, scenes, sub = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
variants = {
  "default": {},
  "abs15": {"mapper.abs_pose_min_num_inliers": 15},
  "abs15+2view": {"mapper.abs_pose_min_num_inliers": 15, "triangulation.ignore_two_view_tracks": False},
  "abs10+2view": {"mapper.abs_pose_min_num_inliers": 10, "triangulation.ignore_two_view_tracks": False},
}
def setopt(o, k, v):
    parts = k.split("."); obj = o
    for p in parts[:-1]: obj = getattr(obj, p)
    setattr(obj, parts[-1], v)
for d in sorted(work.glob(f"scene*/{sub}")):
    tj = json.loads((scenes / d.parent.name / "truth.json").read_text())
    truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}; n = len(list((d / "images").glob("*.png")))
    out = []
    for start in ("vg", "guess"):
        for vn, opts in variants.items():
            o = pycolmap.IncrementalPipelineOptions(); o.num_threads = 1; o.random_seed = 0; o.min_model_size = 3
            for k, v in opts.items(): setopt(o, k, v)
            db = d / f"{start}_r.db"; shutil.copy(d / f"{start}.db" if start == "guess" else d / "vg.db", db)
            if start == "guess": shutil.copy(d / "cap/colmap/database.match.db", db)
            sp = d / "relax_sparse"; shutil.rmtree(sp, ignore_errors=True); sp.mkdir()
            recs = pycolmap.incremental_mapping(db, d / "images", sp, o)
            if not recs: out.append(f"{start}/{vn}: 0"); continue
            r = max(recs.values(), key=lambda r: r.num_reg_images())
            ids = list(r.reg_image_ids()); names = [r.images[i].name for i in ids]
            rot = align.pose_errors([C.c2w_opencv_from_w2c(r.images[i].cam_from_world().matrix()) for i in ids], [truth[x] for x in names]).median_rotation_deg if len(ids) >= 3 else float("nan")
            out.append(f"{start}/{vn}: {len(ids)}/{n} {rot:.2f}deg")
    print(d.parent.name, " | ".join(out), flush=True)
