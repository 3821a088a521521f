"""Inference-time savings (issue 13): the fine pass skipped where the coarse pass saw nothing
(``render.fine_min_acc``), ray chunks rendered side by side on threads (``image_chunks(workers=)``,
``threads.render_workers``). Each must leave what the model renders unchanged where it promises to. bpy-free."""

from __future__ import annotations

import threading

import pytest
import torch

from blender_mrvm import threads
from blender_mrvm.errors import InputError
from blender_mrvm.models import registry
from blender_mrvm.models.config import merge, validate
from blender_mrvm.models.rays import make_rays

from test_hull import SIZE, model_and_scene


def _rays_and_context(model, imgs, poses, intr, bbox, target):
    ctx, ns = model.encode_world(imgs, poses, [intr] * 2, bbox)
    rays = make_rays(intr, ns.pose(target), box=ns.box)
    return ctx, rays.select(torch.nonzero(rays.hit).flatten())


@pytest.mark.parametrize("arch", ["legacy", "nerformer"])
def test_fine_pass_skipped_only_where_the_coarse_pass_is_empty(arch):
    model, imgs, poses, intr, _, bbox, target = model_and_scene()
    base = merge(model.cfg, {"nerformer": {"arch": arch}, "render": {"fine_min_acc": 0.0}})
    torch.manual_seed(0)
    model = registry.build_model(base).eval()
    ctx, rays = _rays_and_context(model, imgs, poses, intr, bbox, target)
    with torch.no_grad():
        full = model.render_rays(ctx, rays)
        thr = float(full["coarse"]["acc"].median())  # half the rays below: both paths are exercised
        model.cfg = merge(base, {"render": {"fine_min_acc": thr}})
        gated = model.render_rays(ctx, rays)
    busy = full["coarse"]["acc"] >= thr
    assert 0 < int(busy.sum()) < len(busy)
    for k in ("color", "acc", "depth"):  # rays the gate keeps: the fine pass, unchanged
        assert torch.allclose(gated[k][busy], full[k][busy], atol=1e-5), k
    for k, ck in (("color", "color"), ("acc", "acc")):  # the others: the coarse pass's own result
        assert torch.equal(gated[k][~busy], full["coarse"][ck][~busy]), k
    # training never skips: every ray's fine pass runs (its per-sample outputs are there)
    model.train()
    tr = model.render_rays(ctx, rays, train=True, generator=torch.Generator().manual_seed(0))
    assert tr["fine"]["weights"].shape[0] == len(rays)


def test_fine_pass_gate_with_nothing_busy_and_bad_values():
    model, imgs, poses, intr, _, bbox, target = model_and_scene()
    ctx, rays = _rays_and_context(model, imgs, poses, intr, bbox, target)
    model.cfg = merge(model.cfg, {"render": {"fine_min_acc": 0.999999}})
    with torch.no_grad():
        out = model.render_rays(ctx, rays)
    assert torch.equal(out["color"], out["coarse"]["color"])  # no ray busy enough: the coarse image
    for bad in (-0.1, 1.0):
        with pytest.raises(InputError, match="fine_min_acc"):
            validate(merge(model.cfg, {"render": {"fine_min_acc": bad}}))


@pytest.mark.parametrize("kind", ["nerformer_mrvm", "gpnr"])
def test_chunk_workers_give_the_same_image_in_the_same_order(kind):
    model, imgs, poses, intr, masks, bbox, target = model_and_scene()
    if kind == "gpnr":
        torch.manual_seed(0)
        model = registry.build_model(registry.build_config("gpnr", "fast")).eval()
    one = model.synthesize(imgs, poses, [intr] * 2, bbox, target, intr, chunk=97, ref_masks=masks, skip="cull")
    two = model.synthesize(imgs, poses, [intr] * 2, bbox, target, intr, chunk=97, ref_masks=masks, skip="cull",
                           workers=3)
    for k in ("color", "acc", "depth"):
        assert torch.equal(one[k], two[k]), k
    ctx, ns = model.encode_world(imgs, poses, [intr] * 2, bbox)
    gen = model.image_chunks(ctx, intr, ns.pose(target), ns.box, chunk=97, workers=2)
    steps = [next(gen) for _ in range(4)]  # stop in the middle (Esc): the pool is shut down, nothing hangs
    gen.close()
    assert sum(steps) <= SIZE * SIZE and all(s > 0 for s in steps[1:])
    assert not any(t.name.startswith("mrvm-chunk") and t.is_alive() for t in threading.enumerate())


def test_chunk_workers_render_in_the_callers_precision():
    """Autocast is per thread: the chunk workers ran the networks in fp32 under the caller's bf16, so a bf16 view
    depended on --threads and synthesis.json said bf16 of fp32 networks."""
    model, imgs, poses, intr, masks, bbox, target = model_and_scene()
    views = {}
    for precision, workers in (("bf16", 1), ("bf16", 3), ("fp32", 3)):
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=precision == "bf16"):
            views[precision, workers] = model.synthesize(imgs, poses, [intr] * 2, bbox, target, intr, chunk=97,
                                                         ref_masks=masks, skip="cull", workers=workers)["color"]
    assert torch.equal(views["bf16", 1], views["bf16", 3])
    assert not torch.equal(views["bf16", 3], views["fp32", 3])  # the workers did run in bf16


def test_render_workers_use_every_core_with_one_torch_thread_each():
    before = torch.get_num_threads()
    try:
        assert threads.render_workers(3) == 3 and torch.get_num_threads() == 1
        assert threads.render_workers(0) == threads.usable_cores() >= 1
    finally:
        torch.set_num_threads(before)


def test_stop_counts_cut_each_ray_where_the_coarse_light_runs_out():
    from blender_mrvm.models.samplers import stop_counts

    t_c = torch.tensor([[0.0, 1.0, 2.0, 3.0]] * 3)
    trans = torch.tensor([[1.0, 0.5, 1e-4, 1e-6],   # stops at the coarse sample at 2.0
                          [1.0, 0.9, 0.8, 0.7],      # never stops
                          [1e-4, 1e-5, 1e-6, 1e-7]])  # stops at once: still one quantum evaluated
    t_f = torch.linspace(0.0, 3.5, 8).expand(3, 8)  # 0, 0.5, ..., 3.5
    keep = stop_counts(t_c, trans, t_f, 1e-3)
    assert keep.tolist() == [4, 8, 1]  # 0, 0.5, 1.0, 1.5 lie in front of 2.0
    assert stop_counts(t_c, trans, t_f, 1e-3, quantum=3).tolist() == [6, 8, 3]  # rounded up, at most all
    assert stop_counts(t_c, trans, t_f, 0.0) is None  # off
    assert stop_counts(t_c[1:2], trans[1:2], t_f[1:2], 1e-3) is None  # nothing to skip


@pytest.mark.parametrize("arch", ["legacy", "nerformer"])
def test_early_stop_skips_the_samples_behind_an_opaque_coarse_pass(arch):
    """With ray attention made the identity (no coupling along the ray), early termination must give exactly
    the full fine pass with the skipped samples emptied: the kept samples' fields unchanged, the skipped ones
    a suffix of each ray behind its coarse stop point, and the sample count what was evaluated."""
    model, imgs, poses, intr, _, bbox, target = model_and_scene()
    base = merge(model.cfg, {"nerformer": {"arch": arch}, "render": {"fine_min_acc": 0.0, "density_bias": 8.0},
                             "sampler": {"n_coarse": 8, "n_fine": 8, "fine_includes_coarse": True}})
    torch.manual_seed(0)
    model = registry.build_model(base).eval()
    with torch.no_grad():
        for br in (model.coarse, model.fine):
            for rb in br.ray_blocks:  # a residual block with zero outputs is the identity
                for lin in (rb.attn.out, rb.ffn[2]):
                    lin.weight.zero_()
                    lin.bias.zero_()
    ctx, rays = _rays_and_context(model, imgs, poses, intr, bbox, target)
    seen = []
    render = model._render
    model._render = lambda sigma, rgb, t, far: seen.append((sigma.clone(), t)) or render(sigma, rgb, t, far)
    with torch.no_grad():
        full = model.render_rays(ctx, rays)
        sig_full, t_full = seen[-1]
        model.cfg = merge(base, {"render": {"stop_transmittance": 1e-3}})
        cut = model.render_rays(ctx, rays)
        sig_cut, t_cut = seen[-1]
    R, S = t_full.shape
    assert torch.equal(t_cut, t_full)
    kept = sig_cut > 0
    n_kept = kept.sum(-1)
    assert cut["samples"] == R * 8 + int(n_kept.sum()) < full["samples"] == R * (8 + S)
    assert (n_kept < S).float().mean() > 0.3, "the test scene should stop many rays"
    assert torch.equal(kept, torch.arange(S)[None] < n_kept[:, None]), "skipped samples are a suffix of each ray"
    assert torch.allclose(sig_cut[kept], sig_full[kept], rtol=1e-5, atol=1e-5)
    trans = full["coarse"]["transmittance"]
    stopped = n_kept < S
    t_stop = torch.gather(full["coarse"]["t"], 1, (trans < 1e-3).float().argmax(-1, keepdim=True))[:, 0]
    assert (t_full[stopped, :][~kept[stopped]] >= t_stop[stopped, None].expand(-1, S)[~kept[stopped]]).all()
    # what is lost is the light behind the stop point, which the fine pass too sees as (almost) none
    assert (cut["color"] - full["color"]).abs().max() < 0.02
    # training never stops early
    model.train()
    tr = model.render_rays(ctx, rays, train=True, generator=torch.Generator().manual_seed(0))
    assert tr["samples"] == R * (8 + S)


def test_stop_transmittance_bad_values():
    model = model_and_scene()[0]
    for bad in (-1e-3, 1.0):
        with pytest.raises(InputError, match="stop_transmittance"):
            validate(merge(model.cfg, {"render": {"stop_transmittance": bad}}))


@pytest.mark.parametrize("preset", ["fast", "balanced", "gpnr:fast"])
def test_every_linear_layer_is_one_matrix_product_at_inference(preset):
    """Without a grad, torch.matmul does not fold a Linear's input that is a permuted view into rows: it broadcasts
    the weight into a batched product over every point, which on a GPU is one launch per 65 535 points (session 20,
    H200: 76 kernels, a fifth of a 256 px `fast` view's device time). No layer of a preset may get such an input."""
    import numpy as np

    from blender_mrvm.geometry import cameras

    kind, _, name = preset.rpartition(":")
    torch.manual_seed(0)
    model = registry.build_model(registry.build_config(kind or None, name), load_pretrained=False).eval()
    size = 24
    intr = cameras.Intrinsics(30.0, 30.0, size / 2, size / 2, size, size)
    eyes = [np.array(e, float) / np.linalg.norm(e) * 1.3 for e in ([1, 0.2, 0.4], [-0.2, 1, 0.3], [0.6, -0.7, 0.5])]
    refs = np.random.default_rng(0).random((2, size, size, 3)).astype(np.float32)
    with torch.profiler.profile(record_shapes=True) as prof:
        model.synthesize(refs, [cameras.look_at_opencv(e) for e in eyes[1:]], [intr] * 2,
                         (np.full(3, -0.4), np.full(3, 0.4)), cameras.look_at_opencv(eyes[0]), intr)
    linear_inputs = [e.input_shapes for e in prof.key_averages(group_by_input_shape=True) if e.key == "aten::linear"]
    broadcast = [e.input_shapes for e in prof.key_averages(group_by_input_shape=True)
                 if e.key == "aten::matmul" and len(e.input_shapes[0]) >= 3 and len(e.input_shapes[1]) == 2]
    assert linear_inputs and not broadcast, broadcast


def test_rays_made_by_torch_equal_the_numpy_rays():
    """A GPU view makes its rays on the device (``make_rays`` with torch pixels, ``rays.pixel_rows``): the same
    float64 rays as the host's numpy path, skew, rows and misses included."""
    import numpy as np

    from blender_mrvm.geometry import cameras
    from blender_mrvm.models.rays import pixel_rows

    intr = cameras.Intrinsics(41.0, 39.5, 17.2, 12.9, 33, 27, skew=0.7)
    c2w = cameras.look_at_opencv(np.array([4.2, -2.6, 1.8]))
    vv, uu = np.meshgrid(np.arange(5, 19) + 0.5, np.arange(33) + 0.5, indexing="ij")
    a = make_rays(intr, c2w, np.stack([uu, vv], -1).reshape(-1, 2), box=1.1)
    b = make_rays(intr, c2w, pixel_rows(5, 19, 33), box=1.1)
    assert 0 < int(a.hit.sum()) < len(a)
    assert torch.equal(a.hit, b.hit)
    for k in ("origins", "dirs", "far", "depth_offset", "up"):
        x, y = getattr(a, k), getattr(b, k)
        assert x.dtype == y.dtype == torch.float64 and x.shape == y.shape, k
        assert torch.allclose(x, y, rtol=0, atol=1e-12), k


@pytest.mark.parametrize("kind", ["nerformer_mrvm", "gpnr"])
def test_a_view_rendered_through_device_side_rays_is_the_same(kind, monkeypatch):
    """``image_chunks``' device path (rays made by torch, the view gathered where it renders, one copy to the host at
    the end: what a GPU runs) gives the host path's image, counts and span; forced here on the CPU."""
    from blender_mrvm.models import base

    model, imgs, poses, intr, masks, bbox, target = model_and_scene()
    if kind == "gpnr":
        torch.manual_seed(0)
        model = registry.build_model(registry.build_config("gpnr", "fast")).eval()
    host = model.synthesize(imgs, poses, [intr] * 2, bbox, target, intr, chunk=97)
    monkeypatch.setattr(base, "rays_on_host", lambda device: False)
    dev = model.synthesize(imgs, poses, [intr] * 2, bbox, target, intr, chunk=97)
    for k in ("color", "acc", "depth"):
        assert torch.allclose(host[k], dev[k], rtol=0, atol=1e-5), k
    for k in ("rays", "box_rays", "evaluated", "samples"):
        assert host[k] == dev[k], k
    assert host["span"] == pytest.approx(dev["span"], abs=1e-9)


def test_inference_chunk_is_the_configs_on_the_cpu_and_large_on_a_gpu(monkeypatch):
    """A GPU renders at least models.base.GPU_CHUNK_RAYS rays a forward pass (the configs' 512 are sized for a
    2-core CPU); a chunk asked for is kept as it is, on either device."""
    from blender_mrvm.models import base

    model, *_ = model_and_scene()
    assert model.inference_chunk() == model.chunk_rays == 512
    assert model.inference_chunk(97) == 97
    monkeypatch.setattr(type(model), "device", property(lambda self: torch.device("cuda")))
    assert model.inference_chunk() == base.GPU_CHUNK_RAYS == 16384
    assert model.inference_chunk(97) == 97
    # the one policy every kind uses (Sem2NeRF's render_image too): a config's larger chunk stays
    assert base.inference_chunk(1024, "cuda") == 16384 and base.inference_chunk(1 << 20, "cuda") == 1 << 20
    assert base.inference_chunk(1024, "cpu") == 1024 and base.inference_chunk(1024, "cuda", 5) == 5
