"""Set G through `recover-poses` as users run it (session 51, after RULE.md's fifth rule was judged). VARIANT:
`exif` (default): each photo set as JPEGs with a 35 mm focal length in their EXIF (from the truth, rounded to a whole
millimetre as cameras write it), with `recover-poses`' defaults (one camera a photo, each with its EXIF prior);
`exif_single`: the same JPEGs with one shared camera (`--single-camera`); `png`: the PNGs with the defaults. The error
or warning line, the spacing it names, and the kept model's error against the truth. One JSON line a photo set.

    PYTHONPATH=$PWD .venv/bin/python docs/capture_check/spacing/run_g_exif.py SCENES WORK OUT.jsonl [VARIANT]
"""
import json, re, shutil, sys, time
from pathlib import Path
import numpy as np
import pycolmap
from PIL import Image
from blender_mrvm.capture import align, sfm
from blender_mrvm.capture.check import warning
from blender_mrvm.capture.config import CaptureConfig
from blender_mrvm.errors import InputError
from blender_mrvm.progress import run_to_end

pycolmap.logging.minloglevel = 2
SUBSETS = {"a10": range(10, 20), "a20": range(0, 16, 2), "r30": range(0, 36, 3), "r40": range(0, 36, 4)}
scenes, work, out = Path(sys.argv[1]), Path(sys.argv[2]), sys.argv[3]
variant = sys.argv[4] if len(sys.argv) > 4 else "exif"
cfg = CaptureConfig(num_threads=1, single_camera=variant == "exif_single")
named = re.compile(r"about (\d+) degrees apart")

with open(out, "w") as f:
    for scene in sorted(scenes.glob("scene*")):
        tj = json.loads((scene / "truth.json").read_text())
        truth = {v["name"]: np.array(v["c2w_opencv"]) for v in tj["views"]}
        K = np.array(tj["views"][0]["K"])
        for sub, idx in SUBSETS.items():
            d = work / scene.name / f"{sub}_{variant}"
            shutil.rmtree(d, ignore_errors=True)
            (d / "images").mkdir(parents=True)
            for i in idx:
                if variant == "png":
                    shutil.copy(scene / "images" / f"{i:03d}.png", d / "images")
                    continue
                img = Image.open(scene / "images" / f"{i:03d}.png").convert("RGB")
                ex = Image.Exif()
                ex[0x010F], ex[0x0110] = "TestMake", "TestModel"
                ex.get_ifd(0x8769)[0xA405] = int(round(K[0][0] / max(img.size) * 36))
                img.save(d / "images" / f"{i:03d}.jpg", quality=95, exif=ex)
            t = time.time()
            row = {"scene": scene.name, "subset": sub, "variant": variant, "n": len(idx)}
            try:
                res = run_to_end(sfm.recover_poses(d / "images", d / "cap", cfg))
                err = align.pose_errors(res.c2w_opencv, [truth[n.replace(".jpg", ".png")] for n in res.registered])
                line = warning(res.pose_check) or ""
                row.update({"kept": True, "placed": len(res.registered), "rot": round(err.median_rotation_deg, 2),
                            "suspect": bool(res.pose_check.get("suspect")), "line": line})
            except InputError as e:
                line = str(e)
                row.update({"kept": False, "line": line})
            m = named.search(line)
            row.update({"named_deg": int(m.group(1)) if m else None, "s": round(time.time() - t, 1)})
            f.write(json.dumps(row) + "\n"); f.flush()
