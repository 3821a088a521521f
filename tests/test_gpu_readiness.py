"""Device handling on the CPU, for the GPU sessions' 15 minutes (docs/gpu_session.md): the bpy-free paths a GPU
session runs (train with object_batch and the LPIPS patch loss, synthesis, the Python API) run here under a
*simulated* CUDA device. ``fake_cuda`` keeps every tensor on the CPU but marks those that code put on "cuda"
(``.to("cuda")``, ``device="cuda"``, a module moved there) and follows the mark through every torch operation; an
operation mixing a marked tensor with an unmarked one that is not a 0-dim scalar (what CUDA refuses: "Expected all
tensors to be on the same device"), ``.numpy()`` of a marked tensor, and random draws with a generator of the other
device are reported as errors. ``torch.cuda``'s queries answer as one GPU would."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch.overrides import TorchFunctionMode
from torch.utils._pytree import tree_flatten
from torch.utils.weak import WeakTensorKeyDictionary

REPO = Path(__file__).resolve().parents[1]


class DeviceMismatch(AssertionError):
    pass


_GEN_CUDA: dict[int, bool] = {}
_RealGenerator = torch.Generator


def _fake_generator(device="cpu"):
    g = _RealGenerator()
    _GEN_CUDA[id(g)] = str(device).startswith("cuda")
    return g


def _is_cuda(device) -> bool:
    return device is not None and not isinstance(device, torch.Tensor) and str(device).startswith("cuda")


# indexing a CUDA tensor with CPU indices, and copies across devices, are allowed by CUDA
_MIXED_OK = {torch.Tensor.__getitem__, torch.Tensor.__setitem__, torch.Tensor.index_put_, torch.Tensor.index_put,
             torch.Tensor.copy_, torch.index_put}


# operations that refuse even a 0-dim CPU tensor beside CUDA ones
_NO_CPU_SCALARS = {"cat", "concat", "concatenate", "stack", "hstack", "vstack", "index_add", "index_copy", "index_select",
                   "scatter", "scatter_add", "scatter_reduce", "gather", "matmul", "mm", "bmm", "einsum", "searchsorted",
                   "bucketize", "take_along_dim", "masked_select", "masked_scatter", "embedding", "linear", "conv2d",
                   "grid_sample", "interpolate", "cumsum", "repeat_interleave", "nonzero", "index_fill", "put"}

# what nn.Module.to does on the way (the harness moves modules itself: see the fixture)
_HARNESS_OK = {"_has_compatible_shallow_copy_type", "__set__"}


class FakeCuda(TorchFunctionMode):
    def __init__(self):
        super().__init__()
        self.on = WeakTensorKeyDictionary()
        self.ops = 0  # operations run on the simulated device

    def mark(self, t):
        if isinstance(t, torch.Tensor):
            self.on[t] = True
        return t

    def cuda(self, t) -> bool:
        return isinstance(t, torch.Tensor) and t in self.on

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = dict(kwargs or {})
        name = getattr(func, "__name__", str(func))
        if func == torch.Tensor.device.__get__:
            return torch.device("cuda", 0) if self.cuda(args[0]) else torch.device("cpu")
        if func == torch.Tensor.is_cuda.__get__:
            return self.cuda(args[0])
        if func == torch.Tensor.grad.__get__:
            g = func(*args, **kwargs)
            return self.mark(g) if g is not None and self.cuda(args[0]) else g
        if func in (torch.Tensor.numpy, torch.Tensor.__array__) and self.cuda(args[0]):
            raise DeviceMismatch(f"{name}() of a CUDA tensor (needs .cpu() first)")
        if func is torch.Tensor.cpu:
            return args[0].view_as(args[0]) if self.cuda(args[0]) else args[0]  # a CPU copy: unmarked
        if func is torch.Tensor.cuda:
            return args[0] if self.cuda(args[0]) else self.mark(args[0].view_as(args[0]))
        if func is torch.Tensor.pin_memory:
            raise DeviceMismatch("pin_memory() needs CUDA's runtime (and a CPU tensor)")
        gen = kwargs.get("generator")
        if func in (torch.Tensor.to,):
            target, rest = kwargs.get("device"), list(args[1:])
            if target is not None:
                kwargs["device"] = "cpu"
            elif rest and isinstance(rest[0], (str, torch.device)):
                target, rest[0] = rest[0], "cpu"
            elif rest and isinstance(rest[0], torch.Tensor):
                target, rest[0] = ("cuda" if self.cuda(rest[0]) else "cpu"), rest[0].dtype
            out = func(args[0], *rest, **kwargs)
            cuda = _is_cuda(target) if target is not None else self.cuda(args[0])
            if cuda:
                return self.mark(out) if out is not args[0] or self.cuda(args[0]) else self.mark(out.view_as(out))
            if out is args[0] and self.cuda(args[0]):
                return out.view_as(out)  # a CPU copy: unmarked
            return out
        dev = kwargs.get("device")
        factory = dev is not None
        if factory:
            kwargs["device"] = "cpu"
        flat, _ = tree_flatten((args, kwargs))
        tensors = [t for t in flat if isinstance(t, torch.Tensor)]
        marked = [t for t in tensors if self.cuda(t)]
        if marked and func not in _MIXED_OK and not factory and name not in _HARNESS_OK:
            strict = name.rstrip("_") in _NO_CPU_SCALARS  # (a 0-dim CPU tensor is a scalar to elementwise ops only)
            plain = [t for t in tensors if not self.cuda(t) and (strict or t.dim() > 0)]
            if plain:
                raise DeviceMismatch(f"{name}: CUDA tensors {[tuple(t.shape) for t in marked][:3]} with CPU tensors "
                                     f"{[tuple(t.shape) for t in plain][:3]}")
        if func in _MIXED_OK and func is not torch.Tensor.copy_ and tensors and marked:
            if not self.cuda(args[0]):
                raise DeviceMismatch(f"{name}: a CPU tensor indexed or written with CUDA tensors")
            values = [args[2]] if len(args) > 2 else [kwargs.get("values")]  # (__setitem__, index_put: the values)
            if any(isinstance(v, torch.Tensor) and v.dim() > 0 and not self.cuda(v) for v in values):
                raise DeviceMismatch(f"{name}: a CUDA tensor written with CPU values")
        out = func(*args, **kwargs)
        cuda = _is_cuda(dev) if factory else bool(marked)
        if gen is not None and id(gen) in _GEN_CUDA and _GEN_CUDA[id(gen)] != cuda:
            raise DeviceMismatch(f"{name}: a {'CUDA' if _GEN_CUDA[id(gen)] else 'CPU'} generator drawing "
                                 f"{'CUDA' if cuda else 'CPU'} numbers")
        if cuda:
            self.ops += 1
            for t in tree_flatten(out)[0]:
                if isinstance(t, torch.Tensor):
                    self.mark(t)
        return out


@pytest.fixture
def fake_cuda(monkeypatch):
    """A simulated CUDA device (see the module's doc); yields the mode (``mode.cuda(t)``: is ``t`` on it)."""
    mode = FakeCuda()
    real_to = torch.nn.Module.to

    def module_to(self, *args, **kwargs):
        out = real_to(self, *[("cpu" if _is_cuda(a) else a) for a in args],
                      **{k: ("cpu" if k == "device" and _is_cuda(v) else v) for k, v in kwargs.items()})
        target = kwargs.get("device", next((a for a in args if isinstance(a, (str, torch.device))), None))
        if _is_cuda(target):
            for t in [*self.parameters(), *self.buffers()]:
                mode.mark(t)
        elif target is not None:
            for t in [*self.parameters(), *self.buffers()]:
                mode.on.pop(t, None)
        return out

    monkeypatch.setattr(torch.nn.Module, "to", module_to)
    monkeypatch.setattr(torch.nn.Module, "cuda", lambda self, *a, **k: module_to(self, "cuda"))
    monkeypatch.setattr(torch, "Generator", _fake_generator)
    import safetensors.torch as st

    real_load = st.load_file

    def load_file(path, device="cpu", **kw):  # (safetensors loads to a device itself)
        out = real_load(path, device="cpu", **kw)
        return {k: mode.mark(v) for k, v in out.items()} if _is_cuda(device) else out

    monkeypatch.setattr(st, "load_file", load_file)
    for name, value in {"is_available": lambda: True, "device_count": lambda: 1, "synchronize": lambda *a, **k: None,
                        "set_device": lambda *a, **k: None, "get_device_name": lambda *a, **k: "fake GPU",
                        "empty_cache": lambda: None, "reset_peak_memory_stats": lambda *a, **k: None,
                        "memory_allocated": lambda *a, **k: 0, "max_memory_allocated": lambda *a, **k: 0,
                        "is_bf16_supported": lambda *a, **k: True, "current_device": lambda: 0,
                        "manual_seed_all": lambda *a, **k: None}.items():
        monkeypatch.setattr(torch.cuda, name, value, raising=False)
    with mode:
        yield mode


def test_the_simulated_device_catches_a_mixed_op_numpy_and_a_generator(fake_cuda):
    """The harness itself: what CUDA refuses is refused here."""
    a = torch.ones(3).to("cuda")
    assert fake_cuda.cuda(a) and a.device.type == "cuda" and fake_cuda.cuda(a * 2)
    assert not fake_cuda.cuda(a.cpu()) and fake_cuda.cuda(torch.zeros(2, device=a.device))
    with pytest.raises(DeviceMismatch):
        a + torch.ones(3)
    a + torch.tensor(2.0)  # a 0-dim CPU tensor is allowed, as on CUDA
    with pytest.raises(DeviceMismatch):
        torch.cat([a, torch.tensor([2.0])])
    with pytest.raises(DeviceMismatch):
        torch.stack([a.sum(), torch.tensor(2.0)])
    with pytest.raises(DeviceMismatch):
        torch.ones(3)[a.long()]  # a CPU tensor indexed with CUDA indices
    with pytest.raises(DeviceMismatch):
        a[torch.tensor([0, 1])] = torch.ones(2)  # CPU values written into a CUDA tensor
    a[torch.tensor([0, 1])] = a[:2] * 2  # CPU indices into a CUDA tensor are allowed
    with pytest.raises(DeviceMismatch):
        a.numpy()
    with pytest.raises(DeviceMismatch):
        torch.rand(3, device="cuda", generator=torch.Generator())
    lin = torch.nn.Linear(3, 2).to("cuda")
    assert fake_cuda.cuda(lin(a)) and fake_cuda.cuda(lin.weight)


@pytest.fixture(scope="module")
def sphere_data(tmp_path_factory):
    from blender_mrvm.training.synthetic import make_sphere_dataset

    return [make_sphere_dataset(tmp_path_factory.mktemp(f"data{k}"), n_objects=3, n_views=5, resolution=16, seed=k)
            for k in range(2)]


@pytest.mark.parametrize("config", ["q_lp33b", "q_lp33"])
def test_the_next_slice_trains_on_the_simulated_gpu(tmp_path, sphere_data, fake_cuda, config):
    """The runbook's slice (docs/bench_gpu/runs/q_lp33b.json: `accurate` from the shipped `quality` file, object_batch
    12, LPIPS patches, opacity and depth losses, bf16 on cuda; and its fallback q_lp33.json) for 2 steps at CPU size:
    no operation mixes devices, and its checkpoint is written."""
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training.config import load_run_config
    from blender_mrvm.training.trainer import train

    over = {"data": [str(r) for r in sphere_data], "iterations": 2, "objects_per_step": 4,
            "rays_per_object": 256, "patch_size": 16, "threads": 1, "ckpt_every": 2, "log_every": 1,
            "out_dir": str(tmp_path / "run")}
    if config == "q_lp33b":
        over["object_batch"] = 2
    mcfg, tcfg = load_run_config(REPO / "docs" / "bench_gpu" / "runs" / f"{config}.json", over)
    assert tcfg.device == "cuda" and tcfg.amp == "bf16" and tcfg.lpips_weight > 0 and tcfg.depth_weight > 0
    s = run_to_end(train(mcfg, tcfg))
    assert fake_cuda.ops > 1000  # it ran on the simulated device
    assert np.isfinite(s["last"]["loss"]) and "depth" in s["last"] and "lpips" in s["last"], s["last"]
    assert list((tmp_path / "run" / "checkpoints").glob("step_*/model.safetensors"))
    # a run carried back resumes on the device (the optimizer's state and the generators' from the checkpoint)
    mcfg, tcfg = load_run_config(REPO / "docs" / "bench_gpu" / "runs" / f"{config}.json",
                                 {**over, "iterations": 3, "ckpt_every": 1})
    s = run_to_end(train(mcfg, tcfg))
    assert s["last"]["step"] == 3 and np.isfinite(s["last"]["loss"]), s["last"]


def _cli(*argv) -> None:
    from blender_mrvm.cli import main

    assert main([str(a) for a in argv]) == 0, argv


@pytest.mark.parametrize("model", ["nerformer_mrvm", "mrvm_quality"])
def test_synthesize_on_the_simulated_gpu(tmp_path, sphere_data, fake_cuda, model):
    """`gpu_session.sh synth`'s command (an orbit with empty-space skipping, the GPU's default bf16) and a view
    without skipping: nothing mixes devices and nothing reads a CUDA tensor as numpy."""
    obj = Path(sphere_data[0]) / "spheres" / "obj000"
    for skip in ("cull", "off"):
        _cli("synthesize", "--references", obj, "--views", "0", "2", "--orbit", 2, "--orbit-size", 24,
             "--checkpoint", f"shipped:{model}", "--device", "cuda", "--threads", 1, "--ref-size", -1,
             "--skip-empty", skip, "--out", tmp_path / skip, "--force")
        rep = json.loads((tmp_path / skip / "synthesis.json").read_text())
        assert len(rep["targets"]) == 2
    assert fake_cuda.ops > 100


def test_eval_on_the_simulated_gpu(tmp_path, sphere_data, fake_cuda):
    """`gpu_session.sh score`'s command (eval with LPIPS) on the simulated GPU."""
    _cli("eval", "--checkpoint", "shipped", "--data", sphere_data[0], "--split", "train", "--input-views", "0,2",
         "--max-targets", 2, "--device", "cuda", "--threads", 1, "--force", "--out", tmp_path / "ev")
    rep = json.loads((tmp_path / "ev" / "eval.json").read_text())
    assert fake_cuda.ops > 100 and json.dumps(rep).count("lpips") > 0


def test_api_renders_on_the_simulated_gpu(sphere_data, fake_cuda):
    """The Python API (blender_mrvm.api): load_model on cuda, render_views, scores with LPIPS on the device."""
    from blender_mrvm import api

    obj = Path(sphere_data[0]) / "spheres" / "obj000"
    refs = api.load_references(obj, views=[0, 2])
    target = api.read_object(obj)
    m = api.load_model("shipped", device="cuda")
    views = api.render_views(m, refs, target.c2w[1:2], target.intrinsics[1:2], 16, 16, ref_size=-1)
    assert views and np.isfinite(views[0].rgb).all()
    s = api.scores(views[0].rgb, target.images[1], lpips=api.lpips_metric("cuda"))
    assert np.isfinite(s["psnr"]) and fake_cuda.ops > 100


def test_benches_on_the_simulated_gpu(tmp_path, sphere_data, fake_cuda):
    """`bench model`, `bench train` (object_batch and the LPIPS patch loss, as `gpu_session.sh objbatch` and `slice`
    run it) and `bench tradeoff --axes base,precision` with --device cuda."""
    _cli("bench", "model", "--device", "cuda", "--presets", "fast,accurate", "--views", 2, "--sizes", 16,
         "--precisions", "fp32,bf16", "--repeats", 1, "--ref-size", 16, "--out", tmp_path / "model")
    _cli("bench", "train", "--device", "cuda", "--presets", "fast", "--batches", "4x256", "--object-batches", "1,2",
         "--ref-views-per", "object,step", "--precisions", "bf16", "--lpips-weight", 0.5, "--steps", 1, "--warmup", 1,
         "--data", sphere_data[0], "--out", tmp_path / "train")
    _cli("bench", "tradeoff", "--device", "cuda", "--checkpoints", "shipped", "--axes", "base,precision",
         "--data", sphere_data[0], "--split", "train", "--objects", 1, "--targets", 1, "--size", 16, "--repeats", 1,
         "--no-lpips", "--out", tmp_path / "tradeoff")
    assert fake_cuda.ops > 1000


def test_the_slice_check_runs_on_the_simulated_gpu(fake_cuda, capsys):
    """scripts/check_object_batch.py, the first thing `gpu_session.sh slice` runs on the device (--device cuda
    --amp bf16): it runs through and finds the batched path right."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("check_object_batch", REPO / "scripts" / "check_object_batch.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    assert mod.main(["--device", "cuda", "--amp", "bf16"]) == 0
    out = capsys.readouterr().out
    assert "relative differences" in out and "OVER" not in out and fake_cuda.ops > 1000, out


def test_gpu_carry_says_what_a_call_carries_and_refuses_over_64_mib(tmp_path):
    """scripts/gpu_carry.sh adds up what a call carrying ["gpu_pack"] (and gpu_old/) takes of the 64 MiB: the tree
    (tracked and untracked files git does not ignore) with the pack; over it, exit 3 (the device would refuse the
    call: the tree is 19.5 MiB now, and session 32's 45.3 MiB pack beside it is over)."""
    import os
    import shutil
    import subprocess

    from blender_mrvm.training.synthetic import make_sphere_dataset

    root = tmp_path / "repo"
    (root / "scripts").mkdir(parents=True)
    for s in ("gpu_carry.sh", "carry_weights.py"):
        shutil.copy(REPO / "scripts" / s, root / "scripts")
    (root / "blender_mrvm").symlink_to(REPO / "blender_mrvm")
    subprocess.run(["git", "init", "-q", str(root)], check=True)
    data = make_sphere_dataset(tmp_path / "data" / "set", n_objects=2, n_views=3, resolution=8, data_passes=False)
    env = {**os.environ, "PY": sys.executable, "OMP_NUM_THREADS": "1"}

    def carry():
        return subprocess.run(["bash", "scripts/gpu_carry.sh", str(data)], cwd=root, env=env, capture_output=True,
                              text=True, timeout=300)

    r = carry()
    assert r.returncode == 0 and 'a call carrying ["gpu_pack"]: ' in r.stdout and "of 64 MiB" in r.stdout, r.stdout + r.stderr
    (root / "gpu_old").mkdir()
    (root / "gpu_old" / "x").write_bytes(b"0" * 1000)
    with open(root / ".git" / "info" / "exclude", "a") as f:
        f.write("/gpu_old/\n")
    (root / "big.bin").write_bytes(os.urandom(60 * 2 ** 20))  # untracked, not ignored: it travels with the tree
    r = carry()
    assert r.returncode == 3 and "over the 64 MiB" in r.stderr, r.stdout + r.stderr
    assert 'a call carrying ["gpu_pack", "gpu_old"]: ' in r.stdout
