"""Sets A-F (RULE.md's fifth rule): each photo set's spacing from its match database, with the database's cameras and
with the camera of the model its mapping made (`check.photo_spacing`, `check.spacing_camera`), against the true
spacing (arcs 15 degrees, rings 30). Reads the work folders `map_bench.py` / `sparse/confirm_f.py` left. One JSON line
a photo set.

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/probe.py /tmp/mb OUT.jsonl
"""
import json, sys
from pathlib import Path
import pycolmap
from blender_mrvm.capture.check import photo_spacing, spacing_camera

pycolmap.logging.minloglevel = 2
root, out = Path(sys.argv[1]), sys.argv[2]


def kept_model(colmap: Path):
    recs = []
    for s in ("sparse", "sparse_guess"):
        for d in sorted((colmap / s).glob("*")) if (colmap / s).is_dir() else []:
            try:
                recs.append(pycolmap.Reconstruction(d))
            except Exception:
                pass
    return max(recs, key=lambda r: r.num_reg_images()) if recs else None


with open(out, "w") as f:
    for s in "abcdef":
        for scene in sorted((root / f"work_{s}").glob("scene*")):
            for sub in ("arc8", "arc10", "arc14", "ring12"):
                colmap = scene / sub / "cap" / "colmap"
                if not (colmap / "database.db").exists():
                    continue
                rec = kept_model(colmap)
                db_cams = photo_spacing(colmap / "database.db")
                model = photo_spacing(colmap / "database.db", spacing_camera(rec))
                row = {"set": s.upper(), "scene": scene.name, "subset": sub, "true_deg": 30 if sub == "ring12" else 15,
                       "model_photos": rec.num_reg_images() if rec else 0, "spacing_db": db_cams["spacing_deg"],
                       "spacing": model["spacing_deg"], "focal_from": model["focal_from"],
                       "unmatched": len(model["unmatched"])}
                f.write(json.dumps(row) + "\n")
