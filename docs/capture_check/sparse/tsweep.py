import json, sys
from pathlib import Path
import numpy as np, pycolmap
from blender_mrvm.capture.check import pair_angles, _pieces
pycolmap.logging.minloglevel = 2
res = {}
for s in "abcdf":
    for line in open(f"/tmp/mb/confirm_{s}.jsonl"):
        r = json.loads(line); k = r["kept"]
        if "rot" not in k: continue
        d = Path(f"/tmp/mb/work_{s}") / r["scene"] / r["subset"] / "cap"
        m = json.loads((d / "meta.json").read_text())
        rec = pycolmap.Reconstruction(str(d / m["colmap_model"]))
        ang = pair_angles(rec, d / "colmap/database.db")
        names = [rec.images[i].name for i in rec.reg_image_ids()]
        med = k["pairs"] >= 3 and ((k["rmed"] or 0) > 1.5 or (k["tmed"] or 0) > 1.5)
        for T in (3, 5, 7.5, 10, 15):
            split = _pieces(names, [(a, b) for x, y, a, b in ang if max(x, y) <= T]) - _pieces(names, [(a, b) for _, _, a, b in ang])
            flag = med or (k["pairs"] >= 3 and split > 0)
            cls = "right" if k["rot"] < 1 else ("far" if k["rot"] > 10 else "mid")
            res.setdefault((T, cls), []).append(flag)
        res.setdefault(("med", "right" if k["rot"] < 1 else ("far" if k["rot"] > 10 else "mid")), []).append(med)
for key in sorted(res, key=str):
    v = res[key]; print(key, f"{sum(v)} of {len(v)}")
