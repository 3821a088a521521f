import torch, time
from blender_mrvm.models.nerformer import Block
torch.set_num_threads(1); torch.manual_seed(0)
R,S,V,d=2048,48,2,64
vb, rb = Block(d,4,4).eval(), Block(d,4,4).eval()
x0 = torch.randn(R,S,V,d)
valid = torch.rand(R,S,V) > 0.1
view_keys = valid.reshape(R*S,V); ray_keys = valid.transpose(1,2).reshape(R*V,S)
def cur(vb, rb, x):
    x = vb(x.reshape(R*S,V,d), view_keys).view(R,S,V,d)
    x = rb(x.transpose(1,2).reshape(R*V,S,d), ray_keys).view(R,V,S,d).transpose(1,2)
    return x
def t(f,n=3):
    f(); t0=time.perf_counter()
    for _ in range(n): f()
    return (time.perf_counter()-t0)/n
import copy
vb16, rb16 = copy.deepcopy(vb).bfloat16(), copy.deepcopy(rb).bfloat16()
x16 = x0.bfloat16()
with torch.inference_mode():
    a = cur(vb, rb, x0); b = cur(vb16, rb16, x16).float()
    print("rel err", ((a-b).norm()/a.norm()).item())
    print("fp32", t(lambda: cur(vb, rb, x0)))
    print("pure bf16", t(lambda: cur(vb16, rb16, x16)))
    with torch.autocast("cpu", dtype=torch.bfloat16):
        print("autocast", t(lambda: cur(vb, rb, x0)))
