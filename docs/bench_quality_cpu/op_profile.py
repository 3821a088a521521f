import sys, numpy as np, torch
from blender_mrvm.geometry import cameras
from blender_mrvm.models import registry
from blender_mrvm.bench.model import ref_eyes
torch.set_num_threads(1)
name = sys.argv[1]; size = int(sys.argv[2])
eyes = [np.array(e, float) / np.linalg.norm(e) * 1.3 for e in ([1, 0.2, 0.4], [-0.2, 1, 0.3], [0.6, -0.7, 0.5])]
bbox = (np.full(3, -0.4), np.full(3, 0.4))
intr = cameras.Intrinsics(131.25 * size / 128, 131.25 * size / 128, size / 2, size / 2, size, size)
torch.manual_seed(0)
model = registry.build_model(registry.build_config(None, name)).eval()
refs = np.random.default_rng(0).random((2, size, size, 3)).astype(np.float32)
poses = [cameras.look_at_opencv(e) for e in ref_eyes(eyes, 2)]
target = cameras.look_at_opencv(eyes[0])
r = lambda: model.synthesize(refs, poses, [intr] * 2, bbox, target, intr)
r()
from torch.profiler import profile, ProfilerActivity
with profile(activities=[ProfilerActivity.CPU]) as p:
    r()
print(p.key_averages().table(sort_by="self_cpu_time_total", row_limit=25))
