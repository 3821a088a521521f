"""Two probes of one NeRFormer layer pair (view attention across 2 views, then ray attention along 48 samples, 2048
rays, d_model 64, 4 heads) on the CPU, 1 thread (docs/bench_quality_cpu/README.md). Neither is in the models.

    python docs/bench_quality_cpu/layer_pair_probes.py

- layout: tokens kept in (ray, view, sample) order so ray attention needs no transposed copy, and attention across
  2 views written as a sigmoid of one score difference (the same outputs to ~1e-6);
- bf16: the layer pair with its weights and activations in bf16 (LayerNorm included), against autocast."""
import copy
import time

import torch

from blender_mrvm.models.nerformer import Block

torch.set_num_threads(1)
torch.manual_seed(0)
R, S, V, d = 2048, 48, 2, 64
vb, rb = Block(d, 4, 4).eval(), Block(d, 4, 4).eval()
x0 = torch.randn(R, S, V, d)
valid = torch.rand(R, S, V) > 0.1
view_keys = valid.reshape(R * S, V)
ray_keys = valid.transpose(1, 2).reshape(R * V, S)


def layer_pair(vb, rb, x):
    """As models/nerformer_streams.py runs it: (R, S, V, d) in and out, two transposed copies."""
    x = vb(x.reshape(R * S, V, d), view_keys).view(R, S, V, d)
    return rb(x.transpose(1, 2).reshape(R * V, S, d), ray_keys).view(R, V, S, d).transpose(1, 2)


def view_attention_2(blk, x, keys):
    """Attention across dim 1 (V == 2) of x (R, V, S, d): the softmax of two scores is a sigmoid of their difference;
    a missing key gets weight 0, a point with none attends uniformly (as models/nerformer.Attention)."""
    a, h = blk.attn, blk.attn.h
    q, k, v = a.qkv(x).view(*x.shape[:-1], 3, h, d // h).unbind(-3)  # (R, V, S, h, dh)
    q = q * keys.any(1, keepdim=True)[..., None, None].to(q.dtype)
    z = (q * (k[:, 1] - k[:, 0])[:, None]).sum(-1) * (d // h) ** -0.5  # (R, V, S, h): s_i1 - s_i0
    k0, k1 = keys[:, 0][:, None, :, None], keys[:, 1][:, None, :, None]
    inf = torch.full_like(z, float("inf"))
    z = torch.where(k0 & k1, z, torch.where(k1, inf, torch.where(k0, -inf, torch.zeros_like(z))))
    y = v[:, 0:1] + torch.sigmoid(z)[..., None] * (v[:, 1:2] - v[:, 0:1])
    return a.out(y.reshape(*x.shape))


def layer_pair_no_transposes(xt, keys_t):
    """The same layer pair on (R, V, S, d) tokens."""
    xt = xt + view_attention_2(vb, vb.n1(xt), keys_t)
    xt = xt + vb.ffn(vb.n2(xt))
    return rb(xt.view(R * V, S, d), ray_keys).view(R, V, S, d)


def timed(f, n=3):
    f()
    t0 = time.perf_counter()
    for _ in range(n):
        f()
    return (time.perf_counter() - t0) / n


with torch.inference_mode():
    xt0, keys_t = x0.transpose(1, 2).contiguous(), valid.transpose(1, 2)
    ref = layer_pair(vb, rb, x0)
    print("layout: max difference", (ref - layer_pair_no_transposes(xt0, keys_t).transpose(1, 2)).abs().max().item())
    print(f"layout: {timed(lambda: layer_pair(vb, rb, x0)):.3f} s -> "
          f"{timed(lambda: layer_pair_no_transposes(xt0, keys_t)):.3f} s")
    vb16, rb16, x16 = copy.deepcopy(vb).bfloat16(), copy.deepcopy(rb).bfloat16(), x0.bfloat16()
    print("bf16: relative error", ((ref - layer_pair(vb16, rb16, x16).float()).norm() / ref.norm()).item())
    with torch.autocast("cpu", dtype=torch.bfloat16):
        auto = timed(lambda: layer_pair(vb, rb, x0))
    print(f"bf16: fp32 {timed(lambda: layer_pair(vb, rb, x0)):.3f} s, autocast {auto:.3f} s, "
          f"pure bf16 {timed(lambda: layer_pair(vb16, rb16, x16)):.3f} s")
