"""ring12 (12 photos 30 degrees apart) through recover-poses with SIFT / matching variants; placed, error, check."""
import json, shutil, sys, time
from pathlib import Path
import numpy as np
import pycolmap
from blender_mrvm.capture import align, sfm
from blender_mrvm.capture.config import CaptureConfig
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.progress import run_to_end

scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
variants = sys.argv[4].split(",")
subset = sys.argv[5] if len(sys.argv) > 5 else "ring12"
SUB = {"ring12": range(0, 24, 2), "ring8": range(0, 24, 3), "arc6w": range(0, 12, 2)}[subset]
_FE, _FM = pycolmap.FeatureExtractionOptions, pycolmap.FeatureMatchingOptions
V = set()

def fe():
    o = _FE()
    if "affine" in V: o.sift.estimate_affine_shape = True
    if "dsp" in V: o.sift.domain_size_pooling = True
    if "feat8k" in V: o.sift.max_num_features = 8192
    if "peak" in V: o.sift.peak_threshold = 0.004
    return o

def fm():
    o = _FM()
    if "ratio9" in V: o.sift.max_ratio = 0.9
    if "guided" in V: o.guided_matching = True
    if "nocross" in V: o.sift.cross_check = False
    return o

pycolmap.FeatureExtractionOptions, pycolmap.FeatureMatchingOptions = fe, fm
_orig_sift_max = None
for sd in sorted(scenes.glob("scene*")):
    tj = json.loads((sd / "truth.json").read_text())
    truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
    for var in variants:
        V.clear(); V.update(var.split("+"))
        d = work / sd.name / subset / var
        shutil.rmtree(d, ignore_errors=True)
        (d / "images").mkdir(parents=True)
        for i in SUB:
            if "jpeg" in V or "exif" in V:
                from PIL import Image
                img = Image.open(sd / "images" / f"{i:03d}.png").convert("RGB")
                ex = Image.Exif()
                if "exif" in V:
                    K = np.array(tj["views"][0]["K"])
                    ex[0x010F], ex[0x0110] = "TestMake", "TestModel"
                    ex.get_ifd(0x8769)[0xA405] = int(round(K[0][0] / max(img.size) * 36))
                img.save(d / "images" / f"{i:03d}.jpg", quality=95, exif=ex)
            else:
                shutil.copy(sd / "images" / f"{i:03d}.png", d / "images")
        kw = {}
        if "feat8k" in V: kw["max_num_features"] = 8192
        cfg = CaptureConfig(num_threads=1, single_camera=True, **kw)
        t = time.perf_counter(); err = None
        try:
            run_to_end(sfm.recover_poses(d / "images", d / "cap", cfg))
        except InputError as e:
            err = str(e)[:120]
        row = {"scene": sd.name, "variant": var, "mappings": (json.loads((d / "cap" / "colmap" / "report.json").read_text()).get("mappings") if (d / "cap" / "colmap" / "report.json").is_file() else None), "n": len(SUB), "s": round(time.perf_counter() - t, 1), "error": err}
        # adjacent-pair inliers from the match database
        db = pycolmap.Database.open(str(d / "cap" / "colmap" / "database.db"))
        names = {im.image_id: im.name for im in db.read_all_images()}
        pids, geoms = db.read_two_view_geometries(); db.close()
        order = sorted(names.values())
        cam = pycolmap.Database.open(str(d / "cap" / "colmap" / "database.db")).read_all_cameras()[0]
        adj = []
        for pid, g in zip(pids, geoms):
            a, b = sfm._pair_to_ids(pid)
            ia, ib = order.index(names[a]), order.index(names[b])
            if (ib - ia) % len(order) in (1, len(order) - 1):
                adj.append(len(g.inlier_matches) if g.config not in (pycolmap.TwoViewGeometryConfiguration.UNDEFINED, pycolmap.TwoViewGeometryConfiguration.DEGENERATE) else 0)
        adj += [0] * (len(order) - len(adj))
        row["adj_inliers"] = sorted(adj)
        row["verified_pairs"] = sum(1 for g in geoms if len(g.inlier_matches) >= 15)
        meta = d / "cap" / "meta.json"
        if meta.is_file():
            m = json.loads(meta.read_text())
            rec = pycolmap.Reconstruction(str(d / "cap" / m["colmap_model"]))
            ids = list(rec.reg_image_ids())
            e = align.pose_errors([C.c2w_opencv_from_w2c(rec.images[i].cam_from_world().matrix()) for i in ids],
                                  [truth[rec.images[i].name.replace(".jpg", ".png")] for i in ids])
            pc = m.get("pose_check", {})
            row.update(placed=len(ids), rot_med=round(e.median_rotation_deg, 2), rot_max=round(float(np.max(e.rotation_deg)), 1),
                       suspect=pc.get("suspect"), chk_rot=pc.get("median_disagreement_deg"), chk_dir=pc.get("median_direction_deg"))
        print(json.dumps(row), flush=True)
        with open(out, "a") as fh:
            fh.write(json.dumps(row) + "\n")
        shutil.rmtree(d / "images"); 
