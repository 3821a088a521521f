"""Agreeing-pair connectivity: does the graph of pairs that agree with the model (both angles <= T) connect every
placed photo? For each kept incremental model (ring_opts variants) and each global model (g2_*), beside its error."""
import json, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture import align
from blender_mrvm.capture.check import pair_angles, pair_pose_check
from blender_mrvm.geometry import cameras as C
pycolmap.logging.minloglevel = 2
scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
TS = (2.0, 3.0, 5.0)
def components(nodes, edges):
    parent = {n: n for n in nodes}
    def f(x):
        while parent[x] != x: parent[x] = parent[parent[x]]; x = parent[x]
        return x
    for a, b in edges: parent[f(a)] = f(b)
    sizes = {}
    for n in nodes: sizes[f(n)] = sizes.get(f(n), 0) + 1
    return sorted(sizes.values(), reverse=True)
def evaluate(rec, db, truth, label):
    ids = list(rec.reg_image_ids()); names = [rec.images[i].name for i in ids]
    if len(ids) < 3: return None
    key = lambda n: n.replace(".jpg", ".png")
    rot = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids], [truth[key(n)] for n in names]).median_rotation_deg
    ang = pair_angles(rec, db)
    c = pair_pose_check(rec, db)
    row = {"model": label, "placed": len(ids), "rot": round(rot, 2), "pairs": len(ang), "suspect": c["suspect"],
           "rmed": c["median_disagreement_deg"], "tmed": c["median_direction_deg"]}
    cover = components(names, [(a, b) for r, d, a, b in ang])
    row["cover_components"] = len(cover)
    for T in TS:
        comp = components(names, [(a, b) for r, d, a, b in ang if max(r, d) <= T])
        row[f"largest_{T:g}"] = round(comp[0] / len(ids), 3)
        row[f"split_{T:g}"] = len(comp) - len(cover)
    return row
with open(out, "w") as fh:
    for sd in sorted(work.glob("scene*")):
        tj = json.loads((scenes / sd.name / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        cands = []
        for vd in sorted((sd / "ring12").iterdir()):
            meta = vd / "cap" / "meta.json"
            if meta.is_file():
                m = json.loads(meta.read_text())
                cands.append((f"inc:{vd.name}", vd / "cap" / m["colmap_model"], vd / "cap/colmap/database.db"))
            if vd.name.startswith("g2_") and (vd / "sparse").is_dir():
                ms = sorted((vd / "sparse").iterdir())
                if ms:
                    best = max(ms, key=lambda p: pycolmap.Reconstruction(str(p)).num_reg_images())
                    cands.append((f"glob:{vd.name[3:]}", best, vd / "db.db"))
        for label, model, db in cands:
            r = evaluate(pycolmap.Reconstruction(str(model)), db, truth, label)
            if r:
                r["scene"] = sd.name; print(json.dumps(r), flush=True); fh.write(json.dumps(r) + "\n")
