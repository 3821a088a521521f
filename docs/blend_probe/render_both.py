"""Render each object's protocol targets (every second of eval_views.json's target_views_2, from input_views_2)
with several checkpoints and save the views beside the truth (docs/blend_probe/README.md).

    python docs/blend_probe/render_both.py DATA SPLIT PART NPARTS OUT.npz CKPT,CKPT

PART of NPARTS: this process takes objects i with i % NPARTS == PART (run one per core)."""
import sys, json, numpy as np, torch
from blender_mrvm.datasets.loaders import load_dataset
from blender_mrvm.training.checkpoint import load_model
from blender_mrvm.models.pretrained import resolve_checkpoint
torch.set_num_threads(1)
data, split, part, nparts, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
names = sys.argv[6].split(",")
models = {n: load_model(resolve_checkpoint(n))[0].eval() for n in names}
ev = json.load(open(f"{data}/splits/eval_views.json"))
refs = ev["input_views_2"]; tgts = ev["target_views_2"][::2]
objs = load_dataset(data, split)
res = {}
for i, obj in enumerate(objs):
    if i % nparts != part: continue
    preds = {n: [] for n in names}
    for t in tgts:
        for n, m in models.items():
            with torch.inference_mode():
                o = m.synthesize(obj.images[refs], [obj.c2w[k] for k in refs], [obj.intrinsics[k] for k in refs],
                                 obj.bbox, obj.c2w[t], obj.intrinsics[t], ref_masks=obj.masks[refs], skip="cull")
            preds[n].append(np.asarray(o["color"], np.float32))
    res[f"{obj.category}/{obj.name}"] = {"gt": obj.images[tgts].astype(np.float32), **{n: np.stack(v) for n, v in preds.items()}}
    print(obj.name, flush=True)
np.savez_compressed(out, **{f"{k}|{n}": v for k, d in res.items() for n, v in d.items()})
