"""Score pixel blends (1 - w) * A + w * B of two checkpoints' saved views (render_both.py) against the truth:
PSNR, SSIM (pixelNeRF's), LPIPS, each paired against A (w = 0) with the SE over objects.

    python docs/blend_probe/score_blends.py A B OUT_0.npz [OUT_1.npz ...]"""
import sys, numpy as np, torch
from collections import defaultdict
from blender_mrvm.training.evaluate import scores_against
from blender_mrvm.models.metrics import LPIPS
torch.set_num_threads(2)
a_name, b_name = sys.argv[1], sys.argv[2]
files = sys.argv[3:]
d = {}
for f in files:
    z = np.load(f)
    for k in z.files:
        obj, n = k.split("|"); d.setdefault(obj, {})[n] = z[k]
lp = LPIPS()
ws = [0.0, 0.25, 0.4, 0.5, 0.75, 1.0]
per_obj = defaultdict(lambda: defaultdict(list))
for obj, v in d.items():
    for i in range(len(v["gt"])):
        cands = {f"w{w}": (1 - w) * v[a_name][i] + w * v[b_name][i] for w in ws}
        sc = scores_against(v["gt"][i], cands, lp)
        for k, s in sc.items():
            for m in ("psnr", "ssim", "lpips"):
                per_obj[(k, m)][obj].append(s[m])
objs = sorted(d)
print(f"{len(objs)} objects, {sum(len(d[o]['gt']) for o in objs)} views; w = weight of {b_name}")
base = {m: np.array([np.mean(per_obj[('w0.0', m)][o]) for o in objs]) for m in ("psnr", "ssim", "lpips")}
for w in ws:
    row = []
    for m in ("psnr", "ssim", "lpips"):
        x = np.array([np.mean(per_obj[(f"w{w}", m)][o]) for o in objs])
        diff = x - base[m]
        row.append(f"{m} {x.mean():.3f} ({diff.mean():+.3f}, SE {diff.std(ddof=1)/np.sqrt(len(objs)):.3f})")
    print(f"w={w}: " + "  ".join(row))
