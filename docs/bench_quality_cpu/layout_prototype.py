import torch, time, torch.nn.functional as F
from blender_mrvm.models.nerformer import Block
torch.set_num_threads(1); torch.manual_seed(0)
R,S,V,d=2048,48,2,64
vb, rb = Block(d,4,4).eval(), Block(d,4,4).eval()
x0 = torch.randn(R,S,V,d)
valid = torch.rand(R,S,V) > 0.1
view_keys = valid.reshape(R*S,V); ray_keys = valid.transpose(1,2).reshape(R*V,S)
def cur(x):
    x = vb(x.reshape(R*S,V,d), view_keys).view(R,S,V,d)
    x = rb(x.transpose(1,2).reshape(R*V,S,d), ray_keys).view(R,V,S,d).transpose(1,2)
    return x
def view_attn2(blk, x, keys):  # x (R,V,S,d) layout, attention across dim 1 (V == 2)
    a = blk.attn; h = a.h; B = x.shape
    qkv = a.qkv(x).view(*x.shape[:-1], 3, h, d//h)
    q, k, v = qkv.unbind(-3)  # (R,V,S,h,dh)
    kv = keys  # (R,V,S) bool
    any_valid = kv.any(1, keepdim=True)
    q = q * any_valid[..., None, None].to(q.dtype)
    scale = (d//h) ** -0.5
    dk = (k[:,1] - k[:,0])  # (R,S,h,dh)
    z = (q * dk[:, None]).sum(-1) * scale  # (R,V,S,h): s_i1 - s_i0
    both = (kv[:,0] & kv[:,1])[:, None, :, None]
    only1 = (kv[:,1] & ~kv[:,0])[:, None, :, None]
    only0 = (kv[:,0] & ~kv[:,1])[:, None, :, None]
    z = torch.where(both, z, torch.where(only1, torch.full_like(z, float('inf')), torch.where(only0, torch.full_like(z, float('-inf')), torch.zeros_like(z))))
    w = torch.sigmoid(z)[..., None]
    v0, v1 = v[:,0:1], v[:,1:2]
    y = v0 + w * (v1 - v0)
    return a.out(y.reshape(*x.shape))
def new(xt, keys_t, ray_keys):
    n = vb.n1(xt)
    xt = xt + view_attn2(vb, n, keys_t)
    xt = xt + vb.ffn(vb.n2(xt))
    xt = rb(xt.view(R*V,S,d), ray_keys).view(R,V,S,d)
    return xt
xt0 = x0.transpose(1,2).contiguous()
keys_t = valid.transpose(1,2)
def t(f,n=3):
    f(); t0=time.perf_counter()
    for _ in range(n): f()
    return (time.perf_counter()-t0)/n
with torch.inference_mode():
    a = cur(x0); b = new(xt0, keys_t, ray_keys).transpose(1,2)
    print("maxdiff", (a-b).abs().max().item())
    print("cur", t(lambda: cur(x0)), "new", t(lambda: new(xt0, keys_t, ray_keys)))
