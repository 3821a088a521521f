"""Training: a 2-step CPU run whose loss falls, checkpoint round trip, exact resume, DDP with 2 CPU processes."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm.datasets.loaders import load_dataset
from blender_mrvm.models.config import model_config
from blender_mrvm.progress import run_to_end
from blender_mrvm.training import checkpoint as ckpt
from blender_mrvm.training.config import TrainConfig, load_run_config, replace, run_config_dict
from blender_mrvm.training.synthetic import make_sphere_dataset
from blender_mrvm.training.trainer import RayBatcher, lr_at, train

torch.set_num_threads(1)
ROOT = Path(__file__).resolve().parents[1]
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 16, "n_heads": 2},
        "sampler": {"n_coarse": 8, "n_fine": 4}}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    root = make_sphere_dataset(tmp_path_factory.mktemp("spheres"), n_objects=3, n_views=5, resolution=16, seed=1)
    return root, load_dataset(root, "train")


def _cfgs(tmp, data_root, **kw):
    mcfg = model_config("fast", TINY)
    base = dict(data=str(data_root), out_dir=str(tmp), iterations=2, objects_per_step=2, rays_per_object=64,
                max_ref_views=2, lr=3e-3, lr_warmup=0, log_every=1, ckpt_every=2, threads=1, pretrain_frac=1.0,
                bbox_sampling_frac=0.5)
    base.update(kw)
    return mcfg, TrainConfig(**base)


def _fixed_batch_mse(model, scenes, mcfg, tcfg):
    b = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=123)
    err = []
    torch.manual_seed(0)
    with torch.no_grad():
        for _ in range(4):
            d = b.draw(False)
            ctx = model.encode(d["images"], d["cams"])
            pred = torch.ones_like(d["gt"])
            idx = torch.nonzero(d["rays"].hit).flatten()
            pred[idx] = model.render_rays(ctx, d["rays"].select(idx))["fine"]["color"]
            err.append(((pred - d["gt"]) ** 2).mean())
    return float(torch.stack(err).mean())


def test_two_step_training_loss_falls(tmp_path, data):
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "run", root)
    torch.manual_seed(tcfg.seed)
    from blender_mrvm.models.model import GeneralizableNeRF

    before = _fixed_batch_mse(GeneralizableNeRF(mcfg), scenes, mcfg, tcfg)
    summary = run_to_end(train(mcfg, tcfg, scenes=scenes))
    model, cfg2, meta = ckpt.load_model(tmp_path / "run")
    after = _fixed_batch_mse(model.eval(), scenes, mcfg, tcfg)
    print("fixed-batch MSE before/after 2 steps", before, after)
    assert after < before * 0.97, (before, after)
    lines = [json.loads(l) for l in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [l["step"] for l in lines] == [1, 2] and all(np.isfinite(l["loss"]) for l in lines)
    assert lines[0]["masking"] and lines[0]["lambda"] == 0.0  # MRVM warm-up: masked, weight 0
    assert summary["step"] == 2 and cfg2 == mcfg
    assert meta["format_version"] == str(ckpt.FORMAT_VERSION)


def test_checkpoint_round_trip_and_bad_files(tmp_path, data):
    mcfg = model_config("fast", TINY)
    from blender_mrvm.errors import InputError
    from blender_mrvm.models.model import GeneralizableNeRF

    torch.manual_seed(5)
    m = GeneralizableNeRF(mcfg)
    path = ckpt.save_checkpoint(tmp_path, 7, m, mcfg, None)
    assert (tmp_path / "checkpoints" / "latest").read_text().strip() == "step_0000007"
    m2, cfg2, meta = ckpt.load_model(tmp_path)
    assert cfg2 == mcfg and meta["step"] == "7"
    for (k, a), (_, b) in zip(m.state_dict().items(), m2.state_dict().items()):
        assert torch.equal(a, b), k
    assert not list((tmp_path / "checkpoints").glob(".step_*"))  # no temp folders left
    umask = os.umask(0)
    os.umask(umask)
    for f in [path, path / ckpt.MODEL_FILE, tmp_path / "checkpoints" / "latest"]:  # not owner-only (tempfile's)
        assert (f.stat().st_mode & 0o777) == ((0o777 if f.is_dir() else 0o666) & ~umask), f
    with pytest.raises(InputError, match="no checkpoint"):
        ckpt.load_model(tmp_path / "nothing")
    from safetensors.torch import save_file
    save_file({"x": torch.zeros(1)}, str(tmp_path / "other.safetensors"))
    with pytest.raises(InputError, match="not a blender_mrvm"):
        ckpt.load_model(tmp_path / "other.safetensors")


def test_exact_resume(tmp_path, data):
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "a", root, iterations=4, pretrain_frac=0.5)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    # same run interrupted after the step-2 checkpoint, then resumed
    mcfg, tcfg_b = _cfgs(tmp_path / "b", root, iterations=4, pretrain_frac=0.5)
    gen = train(mcfg, tcfg_b, scenes=scenes)
    next(gen), next(gen)
    gen.close()
    assert (tmp_path / "b" / "checkpoints" / "latest").read_text().strip() == "step_0000002"
    summary = run_to_end(train(mcfg, tcfg_b, scenes=scenes))
    assert summary["resumed_from"] == 2
    a, _, _ = ckpt.load_model(tmp_path / "a")
    b, _, _ = ckpt.load_model(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), k
    sa = ckpt.load_trainer_state(ckpt.find_checkpoint(tmp_path / "a"))
    sb = ckpt.load_trainer_state(ckpt.find_checkpoint(tmp_path / "b"))
    assert sa["rng"][0]["numpy"] == sb["rng"][0]["numpy"]


def test_a_resume_keeps_the_fp16_loss_scale(tmp_path, data, monkeypatch):
    """fp16 training's loss scaler (a GPU's) found its scale over the run; a resume started again from the default
    and skipped steps until it found it again. Its state is saved with the optimizer's and restored (a stand-in
    scaler here: this machine has no GPU)."""
    from blender_mrvm.training import trainer as T

    class Scaler:  # GradScaler's interface; halves its scale each step, as after overflows
        made: list = []

        def __init__(self):
            self.scale_value, self.steps = 65536.0, 0
            Scaler.made.append(self)

        def scale(self, loss):
            return loss

        def unscale_(self, opt):
            pass

        def step(self, opt):
            opt.step()

        def update(self):
            self.scale_value, self.steps = self.scale_value / 2, self.steps + 1

        def state_dict(self):
            return {"scale": self.scale_value, "steps": self.steps}

        def load_state_dict(self, st):
            self.scale_value, self.steps = st["scale"], st["steps"]

    monkeypatch.setattr(T, "_grad_scaler", lambda cfg, device: Scaler())
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "b", root, iterations=4, pretrain_frac=0.5)
    gen = train(mcfg, tcfg, scenes=scenes)
    next(gen), next(gen)
    gen.close()
    assert ckpt.load_trainer_state(ckpt.find_checkpoint(tmp_path / "b"))["grad_scaler"] == {"scale": 16384.0,
                                                                                             "steps": 2}
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert (Scaler.made[-1].scale_value, Scaler.made[-1].steps) == (4096.0, 4), "resumed from the saved scale"


def test_init_checkpoint_finetunes_from_given_weights(tmp_path, data):
    """Fine-tuning starts from a checkpoint's weights (lr 0: they come back unchanged), takes the
    checkpoint's model config when the run config names none, refuses another architecture, and a
    run folder's own checkpoint still wins (resume)."""
    from blender_mrvm.errors import InputError

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "a", root)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    a, _, meta = ckpt.load_model(tmp_path / "a")
    assert meta["train_image_size"] == "16"  # synthesis resizes larger references to this
    # the config comes from the checkpoint when the run config has no model section
    p = tmp_path / "ft.json"
    p.write_text(json.dumps({"train": {"init_checkpoint": str(tmp_path / "a")}}))
    m2, t2 = load_run_config(p)
    assert m2 == mcfg and t2.init_checkpoint == str(tmp_path / "a")
    _, tb = _cfgs(tmp_path / "b", root, iterations=1, lr=0.0, pretrain_frac=0.0, ckpt_every=1,
                  init_checkpoint=str(tmp_path / "a" / "checkpoints"), seed=9)
    s = run_to_end(train(m2, tb, scenes=scenes))
    assert s["initialized_from"].endswith("model.safetensors") and s["resumed_from"] == 0
    b, _, _ = ckpt.load_model(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), k
    # without init_checkpoint the same seed-9 run starts elsewhere
    _, tc = _cfgs(tmp_path / "c", root, iterations=1, lr=0.0, pretrain_frac=0.0, ckpt_every=1, seed=9)
    run_to_end(train(mcfg, tc, scenes=scenes))
    c, _, _ = ckpt.load_model(tmp_path / "c")
    assert not all(torch.equal(x, y) for x, y in zip(a.state_dict().values(), c.state_dict().values()))
    # the run folder's own checkpoint wins over init_checkpoint
    s = run_to_end(train(m2, replace(tb, iterations=2), scenes=scenes))
    assert s["resumed_from"] == 1 and s["initialized_from"] is None
    # another architecture, a missing path, the shipped alias
    other = model_config("fast", {**TINY, "nerformer": {"d_model": 24, "n_heads": 2}})
    with pytest.raises(InputError, match="do not fit"):
        run_to_end(train(other, replace(tb, out_dir=str(tmp_path / "d")), scenes=scenes))
    with pytest.raises(InputError, match="does not exist"):
        run_to_end(train(mcfg, replace(tb, out_dir=str(tmp_path / "e"), init_checkpoint=str(tmp_path / "nope")),
                         scenes=scenes))
    assert not (tmp_path / "d").exists() and not (tmp_path / "e").exists()  # nothing written on refusal
    from blender_mrvm.training.config import resolve_init_checkpoint
    from blender_mrvm.models.pretrained import default_checkpoint
    assert resolve_init_checkpoint("shipped") == default_checkpoint()


@pytest.mark.parametrize("arch", ["legacy", "nerformer"])
def test_init_checkpoint_grows_a_deeper_copy(tmp_path, data, arch, capsys):
    """A run config naming more transformer blocks than its init checkpoint's model (same widths) grows it: the
    file's blocks fill the first places, the added ones start as the identity (the deeper model renders exactly
    what the file's did) and then learn; a shallower model, or another width, is refused."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.models import registry

    root, scenes = data
    legacy = {"mrvm": {"target": "rerun", "view_masking": "prob"}} if arch == "legacy" else {}

    def cfg(d_model, n_layers):
        return model_config("fast", {**TINY, **legacy, "nerformer": {"arch": arch, "d_model": d_model, "n_heads": 2,
                                                                     "n_layers": n_layers}})

    shallow, deep = cfg(16, 1), cfg(16, 3)
    _, ta = _cfgs(tmp_path / "a", root, iterations=1, ckpt_every=1)
    run_to_end(train(shallow, ta, scenes=scenes))
    model_file = ckpt.find_checkpoint(tmp_path / "a") / ckpt.MODEL_FILE
    a, _, _ = ckpt.load_model(tmp_path / "a")
    grown = registry.build_model(deep, load_pretrained=False)
    added = ckpt.load_weights_deepened(grown, model_file)
    assert sorted(added) == sorted(f"{b}.{s}.{i}" for b in ("coarse", "fine") for s in ("view_blocks", "ray_blocks")
                                   for i in (1, 2))
    assert _fixed_batch_mse(grown, scenes, deep, ta) == _fixed_batch_mse(a, scenes, shallow, ta)
    # through the trainer: the grown blocks learn (their zeroed output layers move)
    _, tb = _cfgs(tmp_path / "b", root, iterations=1, ckpt_every=1, pretrain_frac=0.0, init_checkpoint=str(model_file))
    s = run_to_end(train(deep, tb, scenes=scenes))
    assert s["initialized_from"] == str(model_file)
    assert "init: 8 transformer blocks added" in capsys.readouterr().err  # the log says what grew
    b, bcfg, _ = ckpt.load_model(tmp_path / "b")
    assert bcfg.nerformer.n_layers == 3 and float(b.coarse.view_blocks[2].attn.out.weight.detach().abs().sum()) > 0
    # the other way round (fewer blocks than the file) and another width: refused, nothing written
    with pytest.raises(ckpt.WeightsMismatch, match="not in the model"):
        ckpt.load_weights_deepened(registry.build_model(shallow, load_pretrained=False),
                                   ckpt.find_checkpoint(tmp_path / "b") / ckpt.MODEL_FILE)
    wide = cfg(24, 3)
    with pytest.raises(InputError, match="only more transformer blocks"):
        run_to_end(train(wide, replace(tb, out_dir=str(tmp_path / "c")), scenes=scenes))
    assert not (tmp_path / "c").exists()


def test_lr_schedule_and_config_file(tmp_path):
    c = TrainConfig(lr=1e-3, lr_warmup=10, iterations=111, lr_final_frac=0.1)
    assert lr_at(0, c) == pytest.approx(1e-4) and lr_at(9, c) == pytest.approx(1e-3)
    assert lr_at(60, c) == pytest.approx(1e-3 * (0.1 + 0.9 * 0.5)) and lr_at(110, c) == pytest.approx(1e-4)
    p = tmp_path / "run.json"
    p.write_text(json.dumps({"model": {"preset": "fast", "overrides": {"mrvm": {"lambda_max": 0.2}}},
                             "train": {"iterations": 5, "amp": "bf16"}}))
    m, t = load_run_config(p, {"out_dir": "x"})
    assert m.mrvm.lambda_max == 0.2 and t.iterations == 5 and t.amp == "bf16" and t.out_dir == "x"
    from blender_mrvm.errors import InputError
    p.write_text(json.dumps({"train": {"iters": 5}}))
    with pytest.raises(InputError, match="unknown"):
        load_run_config(p)


def test_a_run_shorter_than_its_warmup_says_so(tmp_path, data, capsys):
    """The default warmup (200 steps) on a 2-step run never reaches train.lr (session 28's GPU MRVM runs, 180
    steps, were such runs unnoticed): train says so on stderr; a run past its warmup says nothing."""
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "a", root, lr_warmup=200)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    err = capsys.readouterr().err
    assert "train.lr_warmup (200) is not below iterations (2)" in err and "to 1% of train.lr (0.003)" in err
    mcfg, tcfg = _cfgs(tmp_path / "b", root, lr_warmup=1)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert "lr_warmup" not in capsys.readouterr().err


def test_bf16_autocast_training_step_finite(tmp_path, data):
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "bf", root, iterations=1, amp="bf16", objects_per_step=1)
    s = run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert np.isfinite(s["last"]["loss"]) and np.isfinite(s["last"]["grad_norm"])


@pytest.mark.slow
def test_ddp_two_cpu_processes(tmp_path, data):
    root, _ = data
    cfg = {"model": {"preset": "fast", "overrides": TINY},
           "train": {"data": str(root), "out_dir": str(tmp_path / "ddp"), "iterations": 2, "objects_per_step": 1,
                     "rays_per_object": 32, "max_ref_views": 2, "lr_warmup": 0, "threads": 1, "ckpt_every": 2}}
    (tmp_path / "cfg.json").write_text(json.dumps(cfg))
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "TQDM_DISABLE": "1"}
    r = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                        "-m", "blender_mrvm", "train", "--config", str(tmp_path / "cfg.json")],
                       env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-3000:]
    sums = [json.loads((tmp_path / "ddp" / f"summary_rank{i}.json").read_text()) for i in range(2)]
    assert sums[0]["world_size"] == 2 and sums[0]["param_digest"] == sums[1]["param_digest"]  # ranks in sync
    state = ckpt.load_trainer_state(ckpt.find_checkpoint(tmp_path / "ddp"))
    assert state["world_size"] == 2 and len(state["rng"]) == 2
    assert state["rng"][0]["numpy"] != state["rng"][1]["numpy"]  # each rank drew its own batches
    # the losses logged are the mean over the ranks' batches (metrics.jsonl had rank 0's alone): every rank's
    # summary holds the same mean, and rank 0 logged it
    lines = [json.loads(x) for x in (tmp_path / "ddp" / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in lines] == [1, 2]
    for k in ("loss", "mse_fine", "hit", "psnr_fine"):
        assert sums[0]["last"][k] == sums[1]["last"][k] == lines[-1][k], k


def test_cli_init_flag(tmp_path, data, capsys):
    """`train --init` reaches the trainer: a missing checkpoint is a one-line error, a good one fine-tunes;
    `--seed` overrides the config's seed (a negative one is refused before anything is written)."""
    from blender_mrvm.cli import main

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "a", root, iterations=1, ckpt_every=1)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert main(["train", "--init", str(tmp_path / "nope"), "--data", str(root), "--out", str(tmp_path / "b")]) == 2
    assert "init_checkpoint" in capsys.readouterr().err and not (tmp_path / "b").exists()
    cfg = tmp_path / "ft.json"
    cfg.write_text(json.dumps({"train": {"iterations": 1, "rays_per_object": 16, "objects_per_step": 1, "threads": 1,
                                         "max_ref_views": 2, "lr": 0.0}}))
    assert main(["train", "--config", str(cfg), "--seed", "-1", "--data", str(root), "--out", str(tmp_path / "d")]) == 2
    assert "train.seed" in capsys.readouterr().err and not (tmp_path / "d").exists()
    assert main(["train", "--config", str(cfg), "--init", str(tmp_path / "a"), "--data", str(root),
                 "--out", str(tmp_path / "c"), "--seed", "7"]) == 0
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["initialized_from"].endswith("model.safetensors") and line["step"] == 1
    assert json.loads((tmp_path / "c" / "config.json").read_text())["train"]["seed"] == 7
    assert json.loads((tmp_path / "c" / "config.json").read_text())["model"]["config"] == \
        json.loads((tmp_path / "a" / "config.json").read_text())["model"]["config"]


def test_opacity_loss_and_masks(tmp_path, data):
    """Our loader reads object masks; the opacity BCE is ~0 when opacity equals the mask, log 2 at one half,
    and training with it lowers the opacity error on a fixed batch; without masks it is refused."""
    import dataclasses
    import math

    from blender_mrvm.errors import InputError
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training.trainer import opacity_loss

    root, scenes = data
    s = scenes[0]
    assert s.masks is not None and s.masks.shape == s.images.shape[:3]
    assert np.array_equal(s.masks, (s.images < 0.999).any(-1))  # spheres over white: object = non-white
    m = torch.tensor([1.0, 0.0, 1.0, 0.0])
    hit = torch.tensor([True, True, True, False])
    assert float(opacity_loss(torch.tensor([1.0, 0.0, 1.0]), m, hit)) < 1e-3
    assert float(opacity_loss(torch.full((3,), 0.5), m, hit)) == pytest.approx(3 * math.log(2) / 4, rel=1e-4)
    assert float(opacity_loss(torch.tensor([1.0, 0.0]), m, torch.tensor([True, True, False, False]))) > 2.0  # object outside the box

    # The loss pulls each ray's opacity toward its mask: down for background rays, up for object rays.
    acc = torch.full((3,), 0.5, requires_grad=True)
    opacity_loss(acc, m, hit).backward()
    assert acc.grad[1] > 0 and acc.grad[0] < 0 and acc.grad[2] < 0
    # Through the model: one plain gradient step lowers it.
    mcfg, tcfg = _cfgs(tmp_path / "o", root, iterations=2, opacity_weight=1.0, pretrain_frac=0.0)
    torch.manual_seed(3)
    model = GeneralizableNeRF(mcfg).eval()
    d = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=7).draw(False)
    idx = torch.nonzero(d["rays"].hit).flatten()
    assert 0 < float(d["mask"][d["rays"].hit].mean()) < 1

    def loss_of():
        torch.manual_seed(0)
        a = model.render_rays(model.encode(d["images"], d["cams"]), d["rays"].select(idx))["fine"]["acc"]
        return opacity_loss(a, d["mask"], d["rays"].hit)

    l0 = loss_of()
    params = [p for p in model.parameters() if p.requires_grad]
    grads = torch.autograd.grad(l0, params, allow_unused=True)
    gnorm = sum(float((g ** 2).sum()) for g in grads if g is not None) ** 0.5
    with torch.no_grad():
        for p, g in zip(params, grads):
            if g is not None:
                p -= 0.05 * g / gnorm  # a fixed-length step: gradient sizes differ between archs
        assert float(loss_of()) < float(l0) - 1e-3
    # The trainer adds it and logs it.
    s2 = run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert s2["last"]["opacity"] > 0 and np.isfinite(s2["last"]["loss"])
    bare = [dataclasses.replace(x, masks=None) for x in scenes]
    with pytest.raises(InputError, match="opacity_weight needs object masks"):
        run_to_end(train(mcfg, replace(tcfg, out_dir=str(tmp_path / "p")), scenes=bare))


def test_several_datasets_pooled(tmp_path, data):
    """`train --data A --data B` pools both datasets' objects (at most max_objects of each), stores the list
    in config.json, resumes from it, and a config's list is replaced, not split, by one --data."""
    from blender_mrvm.cli import main
    from blender_mrvm.errors import InputError
    from blender_mrvm.training.trainer import load_training_scenes

    root, scenes = data
    other = make_sphere_dataset(tmp_path / "other", n_objects=4, n_views=5, resolution=16, seed=7)
    theirs = load_dataset(other, "train")
    assert len(scenes) >= 2 and len(theirs) >= 2
    tcfg = TrainConfig(data=[str(root), str(other)])  # a JSON list
    assert tcfg.data == (str(root), str(other))
    pooled = load_training_scenes(tcfg)
    assert len(pooled) == len(scenes) + len(theirs)
    assert np.array_equal(pooled[len(scenes)].images, theirs[0].images)  # in the order given
    assert len(load_training_scenes(replace(tcfg, max_objects=1))) == 2
    with pytest.raises(InputError, match="twice"):
        TrainConfig(data=[str(root), str(root) + "/"])
    with pytest.raises(InputError, match="empty dataset root"):
        TrainConfig(data=[str(root), " "])
    with pytest.raises(InputError, match="train.data must be a string"):
        TrainConfig(data=[str(root), 3])
    cfg = tmp_path / "run.json"
    cfg.write_text(json.dumps({"model": {"preset": "fast", "overrides": TINY},
                               "train": {"rays_per_object": 16, "objects_per_step": 1, "threads": 1,
                                         "max_ref_views": 2, "ckpt_every": 1}}))
    out = tmp_path / "run"
    assert main(["train", "--config", str(cfg), "--data", str(root), "--data", str(other), "--out", str(out),
                 "--iterations", "1"]) == 0
    assert json.loads((out / "config.json").read_text())["train"]["data"] == [str(root), str(other)]
    assert main(["train", "--config", str(out / "config.json"), "--iterations", "2"]) == 0
    assert json.loads((out / "summary_rank0.json").read_text())["resumed_from"] == 1
    _, one = load_run_config(out / "config.json", {"data": str(other)})
    assert one.data == str(other)


def test_dataset_weights_set_each_datasets_share_of_draws(data, tmp_path):
    """train.data_weights: dataset k is drawn with share w_k / sum(w) whatever its size; without weights every
    object is alike; bad weights are refused."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.training.trainer import RayBatcher, load_training_sets, object_weights

    root, _ = data
    other = make_sphere_dataset(tmp_path / "other", n_objects=6, n_views=5, resolution=16, seed=7)
    tcfg = TrainConfig(data=[str(root), str(other)], data_weights=(3.0, 1.0), min_ref_views=1, max_ref_views=2,
                       rays_per_object=4)
    sets = load_training_sets(tcfg)
    counts = [len(s) for s in sets]
    assert counts[0] != counts[1]  # sizes differ: the weights, not the sizes, decide
    w = object_weights(tcfg.data_weights, counts)
    assert np.isclose(w[:counts[0]].sum(), 0.75) and np.isclose(w.sum(), 1.0)
    assert object_weights((), counts) is None
    scenes = [s for objs in sets for s in objs]
    b = RayBatcher(scenes, tcfg, 0.05, seed=0, weights=w)
    first = {id(s) for s in sets[0]}
    share = np.mean([id(b.scenes[int(b.rng.choice(len(scenes), p=w))]) in first for _ in range(4000)])
    assert abs(share - 0.75) < 0.03
    assert b.draw(False)["images"].shape[0] in (1, 2)  # a weighted draw gives a batch
    for bad, match in [((1.0,), "1 weight"), ((1.0, 0.0), "positive"), ((1.0, float("nan")), "data_weights")]:
        with pytest.raises(InputError, match=match):
            TrainConfig(data=[str(root), str(other)], data_weights=bad)


def test_lpips_patch_training(tmp_path, data):
    """lpips_weight > 0: each object's rays are one P x P patch whose ground truth is the photo read at the
    patch's pixel positions (at scale 1 and P = image side, exactly the photo); LPIPS is 0 for the photo
    itself, has gradients toward it, and the trainer adds and logs it; bad patch settings are refused."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.models.metrics import LPIPS
    from blender_mrvm.training.patches import lpips_loss

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "l", root, lpips_weight=0.5, patch_size=16, patch_scale_min=1.0,
                       pretrain_frac=0.0)
    d = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=5).draw(False)
    assert d["patch"] == 16 and d["gt"].shape == (256, 3) and d["rays"].hit.shape == (256,)
    img = d["gt"].numpy().reshape(16, 16, 3)
    assert any(np.allclose(img, v, atol=1e-6) for s in scenes for v in s.images)  # the whole view, pixel centres
    assert d["mask"].shape == (256,)
    # a half-size patch (scale 0.5) reads the photo between pixels: bilinear, inside [0, 1]
    d2 = RayBatcher(scenes, replace(tcfg, patch_scale_min=0.5), 0.05, seed=6).draw(False)
    assert d2["gt"].shape == (256, 3) and 0 <= float(d2["gt"].min()) and float(d2["gt"].max()) <= 1

    lp = LPIPS()
    gt = torch.from_numpy(img).permute(2, 0, 1)[None]
    assert float(lpips_loss(lp, gt, gt)) == pytest.approx(0.0, abs=1e-6)
    pred = torch.full_like(gt, 0.5).requires_grad_()
    lv = lpips_loss(lp, pred, gt)
    lv.backward()
    assert float(lv.detach()) > 0.05 and float(pred.grad.abs().sum()) > 0
    with torch.no_grad():  # a small step down the gradient lowers it
        stepped = pred - 0.02 * pred.grad / pred.grad.abs().max()
    assert float(lpips_loss(lp, stepped, gt)) < float(lv)

    s = run_to_end(train(mcfg, replace(tcfg, patch_scale_min=0.25), scenes=scenes))
    assert s["last"]["lpips"] > 0 and np.isfinite(s["last"]["loss"])
    with pytest.raises(InputError, match="patch_size >= 16"):
        replace(tcfg, patch_size=8)
    with pytest.raises(InputError, match="patch_scale_min"):
        replace(tcfg, patch_scale_min=0.0)
    with pytest.raises(InputError, match="lpips_weight"):
        replace(tcfg, lpips_weight=-1.0)


def test_step_patches_scored_as_one_batch_match_one_at_a_time(tmp_path, data):
    """With the LPIPS patch loss the trainer scores a step's patches as one VGG batch after the last object
    (``patch_lpips``) and backpropagates the step once: the same losses and gradients, up to float rounding, as
    each object's LPIPS computed and backpropagated on its own, and the logged parts too."""
    from blender_mrvm.models import registry
    from blender_mrvm.models.metrics import LPIPS
    from blender_mrvm.training.trainer import object_loss, patch_lpips

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "p", root, lpips_weight=0.7, patch_size=16, patch_scale_min=0.5,
                       pretrain_frac=0.0, opacity_weight=0.1)
    torch.manual_seed(0)
    model = registry.build_model(mcfg)
    model.train()
    phase = model.train_phase(5, tcfg)
    batcher = RayBatcher(scenes, tcfg, mcfg.sampler.box_padding, seed=3)
    batches = [batcher.draw(False) for _ in range(3)]
    lp = LPIPS()

    def grads(deferred: bool):
        model.zero_grad(set_to_none=True)
        gen = torch.Generator().manual_seed(9)
        patches, total, lpips_logged = ([] if deferred else None), [], 0.0
        for b in batches:
            b = dict(b, cams=copy.deepcopy(b["cams"]))
            loss, parts = object_loss(model, b, tcfg, phase, gen, "cpu", lp, patches)
            total.append(loss)
            lpips_logged += parts.get("lpips", 0.0)
        if deferred:
            lpv = patch_lpips(lp, patches)
            assert lpv.shape == (3,)
            total.append(tcfg.lpips_weight * lpv.sum())
            lpips_logged = float(lpv.detach().sum())
        loss = torch.stack(total).sum()
        loss.backward()
        return float(loss.detach()), lpips_logged, [p.grad.clone() for p in model.parameters() if p.grad is not None]

    l1, lp1, g1 = grads(False)
    l2, lp2, g2 = grads(True)
    assert lp1 > 0.01 and l1 == pytest.approx(l2, rel=1e-5) and lp1 == pytest.approx(lp2, rel=1e-5)
    assert len(g1) == len(g2) > 0
    for a, b in zip(g1, g2):
        assert torch.allclose(a, b, rtol=1e-4, atol=1e-7)


def test_lpips_groups_of_objects_give_the_same_step(tmp_path, data, monkeypatch):
    """A step of 3 objects with the LPIPS patch loss: scored one object at a time (LPIPS_GROUP 1), in a group of 2
    and then 1, or all together, the step's loss, LPIPS and gradient norm agree (every patch scored once, every
    graph backpropagated once)."""
    from blender_mrvm.training import trainer as T

    root, scenes = data
    logs = []
    for group in (1, 2, 8):
        monkeypatch.setattr(T, "LPIPS_GROUP", group)
        mcfg, tcfg = _cfgs(tmp_path / f"g{group}", root, lpips_weight=0.7, patch_size=16, patch_scale_min=0.5,
                           pretrain_frac=0.0, iterations=1, objects_per_step=3, ckpt_every=1)
        run_to_end(train(mcfg, tcfg, scenes=scenes))
        logs.append(json.loads((tmp_path / f"g{group}" / "metrics.jsonl").read_text().splitlines()[0]))
    for k in ("loss", "lpips", "grad_norm", "mse_fine"):
        assert logs[0][k] > 0
        assert logs[1][k] == pytest.approx(logs[0][k], rel=1e-4) and logs[2][k] == pytest.approx(logs[0][k], rel=1e-4)


def test_distortion_loss(tmp_path, data):
    """Mip-NeRF 360's distortion loss: the brute-force double sum, 0 for an empty ray, lower for weight in one
    short interval than for the same weight in two layers apart, independent of the box's scale; the trainer
    adds and logs it for density models and refuses it for GPNR, which has no density."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.models import registry
    from blender_mrvm.training.trainer import distortion_loss

    g = torch.Generator().manual_seed(0)
    t = torch.sort(torch.rand(3, 6, generator=g) * 2, -1).values
    far = torch.tensor([2.0, 2.5, 3.0])
    w = torch.rand(3, 6, generator=g) / 6
    ref = []
    for r in range(3):
        e = list((t[r] / far[r]).tolist()) + [1.0]
        mid = [(e[i] + e[i + 1]) / 2 for i in range(6)]
        ln = [e[i + 1] - e[i] for i in range(6)]
        ref.append(sum(w[r, i] * w[r, j] * abs(mid[i] - mid[j]) for i in range(6) for j in range(6))
                   + sum(w[r, i] ** 2 * ln[i] for i in range(6)) / 3)
    assert float(distortion_loss(w, t, far)) == pytest.approx(float(sum(ref) / 3), rel=1e-5)
    assert float(distortion_loss(w, 10 * t, 10 * far)) == pytest.approx(float(distortion_loss(w, t, far)), rel=1e-5)
    assert float(distortion_loss(torch.zeros(3, 6), t, far)) == 0.0
    ts = torch.linspace(0, 0.9, 10)[None]
    one = torch.zeros(1, 10)
    one[0, 4] = 0.9
    two = torch.zeros(1, 10)
    two[0, 1] = two[0, 8] = 0.45
    assert float(distortion_loss(one, ts, torch.ones(1))) < float(distortion_loss(two, ts, torch.ones(1)))

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "d", root, distortion_weight=0.01, pretrain_frac=0.0)
    s = run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert s["last"]["distortion"] > 0 and np.isfinite(s["last"]["loss"])
    with pytest.raises(InputError, match="distortion_weight"):
        replace(tcfg, distortion_weight=-1.0)
    with pytest.raises(InputError, match="density field"):
        run_to_end(train(registry.build_config("gpnr", "fast"), replace(tcfg, out_dir=str(tmp_path / "g")),
                         scenes=scenes))
    assert not (tmp_path / "g").exists()


def test_opacity_loss_by_default_on_our_renders(tmp_path, data):
    """A run config that names no opacity_weight gets the opacity loss on our renders (they have masks), none on
    another format; a run folder that holds a run keeps what its config.json recorded; a named value wins."""
    from blender_mrvm.training.config import OPACITY_WEIGHT

    root, _ = data
    cfg = tmp_path / "run.json"
    cfg.write_text(json.dumps({"train": {"iterations": 2}}))
    _, t = load_run_config(cfg, {"data": str(root), "out_dir": str(tmp_path / "new")})
    assert t.opacity_weight == OPACITY_WEIGHT == 0.1
    _, t = load_run_config(cfg, {"data": str(tmp_path / "srn_like"), "out_dir": str(tmp_path / "new")})
    assert t.opacity_weight == 0.0  # not our format: no masks to learn from
    old = _holds_run(tmp_path / "old", {"opacity_weight": 0.0})
    _, t = load_run_config(cfg, {"data": str(root), "out_dir": str(old)})
    assert t.opacity_weight == 0.0  # resumes as it began
    cfg.write_text(json.dumps({"train": {"iterations": 2, "opacity_weight": 0.5}}))
    _, t = load_run_config(cfg, {"data": str(root), "out_dir": str(tmp_path / "new")})
    assert t.opacity_weight == 0.5


def test_compile_flag_compiles_the_networks_after_the_weights_load(tmp_path, data, monkeypatch):
    """`train --compile` sets train.compile: the trainer compiles the networks (not the encoder) once its
    weights are in place, and the checkpoint is what an uncompiled run writes (same keys, loadable). Compiling is
    recorded here instead (minutes on this CPU; session 20 measured it on a GPU and `bench train --compile`)."""
    from blender_mrvm.cli import main

    root, _ = data
    seen = []
    monkeypatch.setattr(torch.nn.Module, "compile", lambda m, **kw: seen.append((type(m).__name__, kw)))
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"model": {"preset": "fast", "overrides": TINY},
                               "train": {"iterations": 1, "rays_per_object": 16, "objects_per_step": 1,
                                         "threads": 1, "max_ref_views": 2, "ckpt_every": 1}}))
    assert main(["train", "--config", str(cfg), "--data", str(root), "--out", str(tmp_path / "a"), "--compile"]) == 0
    assert [n for n, _ in seen] == ["StreamBranch", "StreamBranch", "MRVMHead"]
    assert all(kw == {"dynamic": True} for _, kw in seen)
    assert json.loads((tmp_path / "a" / "config.json").read_text())["train"]["compile"] is True
    seen.clear()
    assert main(["train", "--config", str(cfg), "--data", str(root), "--out", str(tmp_path / "b")]) == 0
    assert not seen and json.loads((tmp_path / "b" / "config.json").read_text())["train"]["compile"] is False
    from safetensors.torch import load_file

    ka = load_file(str(ckpt.find_checkpoint(tmp_path / "a") / ckpt.MODEL_FILE))
    kb = load_file(str(ckpt.find_checkpoint(tmp_path / "b") / ckpt.MODEL_FILE))
    assert sorted(ka) == sorted(kb) and not any("_orig_mod" in k for k in ka)


def test_average_of_two_runs_is_their_mean_and_refuses_other_models(tmp_path, data):
    """scripts/average_checkpoints.py (a model soup): the weights are the mean of the runs', the config and
    metadata the first's (with averaged_from), the file loads as a model; another model config, or one file, is
    a one-line error and writes nothing."""
    import importlib.util

    from safetensors.torch import load_file

    root, scenes = data
    for name, seed in (("a", 0), ("b", 1)):
        mcfg, tcfg = _cfgs(tmp_path / name, root, iterations=1, ckpt_every=1, seed=seed)
        run_to_end(train(mcfg, tcfg, scenes=scenes))
    spec = importlib.util.spec_from_file_location("avg", ROOT / "scripts" / "average_checkpoints.py")
    avg = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(avg)
    out = tmp_path / "soup.safetensors"
    assert avg.main([str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out)]) == 0
    fa, fb = (ckpt.find_checkpoint(tmp_path / n) / ckpt.MODEL_FILE for n in "ab")
    wa, wb, ws = load_file(str(fa)), load_file(str(fb)), load_file(str(out))
    differ = [k for k in wa if wa[k].is_floating_point() and not torch.equal(wa[k], wb[k])]
    assert differ  # two seeds: the runs' weights differ, so the test can tell a mean from a copy
    for k in wa:
        assert torch.allclose(ws[k], (wa[k].double() + wb[k].double()).div(2).to(wa[k].dtype), atol=1e-7)
    meta = ckpt.read_meta(out)
    assert json.loads(meta["averaged_from"]) == ["step_0000001/model.safetensors"] * 2
    assert meta["model_config"] == ckpt.read_meta(fa)["model_config"]
    model, _, _ = ckpt.load_model(out)
    assert sum(p.numel() for p in model.parameters()) > 0
    mcfg, tcfg = _cfgs(tmp_path / "c", root, iterations=1, ckpt_every=1)
    other = model_config("fast", {**TINY, "nerformer": {"d_model": 8, "n_heads": 2}})
    run_to_end(train(other, tcfg, scenes=scenes))
    bad = tmp_path / "bad.safetensors"
    assert avg.main([str(tmp_path / "a"), str(tmp_path / "c"), "--out", str(bad)]) == 2
    assert avg.main([str(tmp_path / "a"), "--out", str(bad)]) == 2
    assert not bad.exists()


def test_a_run_closed_between_checkpoints_keeps_its_steps(tmp_path, data):
    """Closing the run (Ctrl-C, the panel's Esc) after a step that is no checkpoint step saves that step, and
    the resumed run ends with the weights of a run never stopped."""
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "a", root, iterations=4, ckpt_every=4, pretrain_frac=0.5)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    mcfg, tcfg_b = _cfgs(tmp_path / "b", root, iterations=4, ckpt_every=4, pretrain_frac=0.5)
    gen = train(mcfg, tcfg_b, scenes=scenes)
    for _ in range(3):
        next(gen)
    gen.close()
    assert (tmp_path / "b" / "checkpoints" / "latest").read_text().strip() == "step_0000003"
    assert run_to_end(train(mcfg, tcfg_b, scenes=scenes))["resumed_from"] == 3
    a, _, _ = ckpt.load_model(tmp_path / "a")
    b, _, _ = ckpt.load_model(tmp_path / "b")
    for (k, x), (_, y) in zip(a.state_dict().items(), b.state_dict().items()):
        assert torch.equal(x, y), k


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to a child process")
def test_ctrl_c_in_the_cli_saves_the_step_in_progress(tmp_path, data):
    """`train` from a terminal or a log: Ctrl-C lets the step finish, saves it, says where, exits 130 with one
    `error:` line; the same command resumes from that step."""
    import signal
    import time

    root, _ = data
    mcfg, tcfg = _cfgs(tmp_path / "run", root, iterations=100000, ckpt_every=100000)
    cfg = tmp_path / "run.json"
    cfg.write_text(json.dumps(run_config_dict(mcfg, tcfg)))
    cmd = [sys.executable, "-m", "blender_mrvm", "train", "--config", str(cfg)]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    metrics = tmp_path / "run" / "metrics.jsonl"
    t0 = time.monotonic()
    while not (metrics.is_file() and len(metrics.read_text().splitlines()) >= 2):
        assert proc.poll() is None and time.monotonic() - t0 < 120, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    step = int((tmp_path / "run" / "checkpoints" / "latest").read_text().strip().split("_")[1])
    assert step >= 2
    assert f"stopped after step {step} of 100000" in err and "the same command resumes" in err
    assert "Ctrl-C again to stop at once" in err
    assert [l for l in err.splitlines() if l.startswith("error:")] == [
        "error: interrupted; the run's checkpoints are kept (the first Ctrl-C saves the step in progress); the "
        "same command goes on from the newest"]
    done = subprocess.run(cmd + ["--iterations", str(step + 1)], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1])["resumed_from"] == step


def test_a_fine_tune_can_keep_the_losses_its_checkpoint_was_trained_with(tmp_path):
    """The shipped default was trained with LPIPS patches (weight 1) and the depth loss (0.1); fine-tuned without
    them its views got blurrier by LPIPS as their PSNR rose (RECIPE.md "Fine-tuning the shipped model on your
    objects"). ``keep_init_losses`` (``train --keep-losses``, the panel's "Keep its losses") takes them from the
    checkpoint: depth only where the data have depth maps (our renders), a setting the run config names wins, and
    a run folder that holds a run keeps what it recorded. Off, the policy's losses are the defaults."""
    from blender_mrvm.datasets.format import ROOT_MANIFEST
    from blender_mrvm.models.checkpoint_files import checked_header
    from blender_mrvm.models.pretrained import default_checkpoint
    from blender_mrvm.errors import InputError
    from blender_mrvm.training.config import FINETUNE_KEEPS_LOSSES, finetune_policy

    rec = json.loads(checked_header(default_checkpoint())[1]["train_config"])
    assert rec["lpips_weight"] == 1.0 and rec["depth_weight"] == 0.1
    ours, other = tmp_path / "ours", tmp_path / "other"
    ours.mkdir()
    other.mkdir()
    (ours / ROOT_MANIFEST).write_text("{}")

    def cfg(data, named=None, out="run", keep=True):
        return load_run_config(None, {"data": str(data), "out_dir": str(tmp_path / out), "iterations": 100,
                                      "init_checkpoint": "shipped", "keep_init_losses": keep or None,
                                      **(named or {})})[1]

    t = cfg(ours, keep=False)
    assert t.lpips_weight == 0.0 and t.depth_weight == 0.0 and t.lr == 1e-4  # the policy as before
    t = cfg(ours)
    assert {k: getattr(t, k) for k in FINETUNE_KEEPS_LOSSES} == {k: rec[k] for k in FINETUNE_KEEPS_LOSSES}
    assert t.lr == 1e-4 and t.pretrain_frac == 0.0 and t.keep_init_losses  # the rest of the policy as before
    t = cfg(other)  # no depth maps there: no depth loss, the LPIPS loss still
    assert t.depth_weight == 0.0 and t.lpips_weight == 1.0 and t.opacity_weight == 0.0
    assert cfg(ours, {"lpips_weight": 0.0}).lpips_weight == 0.0  # named on the command line: it wins
    (tmp_path / "own.json").write_text(json.dumps({"train": {"depth_weight": 0.0, "init_checkpoint": "shipped",
                                                             "keep_init_losses": True, "data": str(ours)}}))
    own = load_run_config(tmp_path / "own.json")[1]
    assert own.depth_weight == 0.0 and own.lpips_weight == 1.0
    # a run folder begun without them (its config.json) resumes as it began
    _holds_run(tmp_path / "old", {"lpips_weight": 0.0, "depth_weight": 0.0})
    t = cfg(ours, out="old")
    assert t.lpips_weight == 0.0 and t.depth_weight == 0.0
    # a new run has no checkpoint to keep the losses of; a checkpoint that cannot be read gives nothing
    with pytest.raises(InputError, match=r"keep_init_losses \(--keep-losses\) keeps the losses of the checkpoint"):
        load_run_config(None, {"data": str(ours), "out_dir": str(tmp_path / "new"), "keep_init_losses": True})
    gone = TrainConfig(data=str(ours), init_checkpoint=str(tmp_path / "missing.safetensors"), iterations=100,
                       keep_init_losses=True)
    assert finetune_policy(gone).lpips_weight == 0.0  # (load_run_config refuses it, naming the file)
    (tmp_path / "bad.json").write_text(json.dumps({"train": {"keep_init_losses": "yes"}}))
    with pytest.raises(InputError, match="keep_init_losses"):
        load_run_config(tmp_path / "bad.json")


def _holds_run(folder: Path, train: dict) -> Path:
    """A run folder that holds a run (metrics) whose config.json recorded ``train``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "config.json").write_text(json.dumps({"model": {}, "train": train}))
    (folder / "metrics.jsonl").write_text(json.dumps({"step": 1, "loss": 0.5}) + "\n")
    return folder


def test_a_run_started_over_takes_nothing_from_the_run_it_replaces(tmp_path, data):
    """`train --no-resume --force` (the panel's "Replace the run") starts a new run: its opacity and kept losses are
    a new run's (the default, the checkpoint's), never those the replaced run recorded; a folder that holds no run
    (a config.json alone) gives nothing either. Resuming keeps what the run recorded."""
    from blender_mrvm.cli import main
    from blender_mrvm.training.config import OPACITY_WEIGHT

    root, _ = data
    old = _holds_run(tmp_path / "old", {"opacity_weight": 0.0, "lpips_weight": 0.0, "depth_weight": 0.0})
    over = {"data": str(root), "out_dir": str(old)}
    assert load_run_config(None, over)[1].opacity_weight == 0.0  # resumes as it began
    assert load_run_config(None, over, resume=False)[1].opacity_weight == OPACITY_WEIGHT
    keep = {**over, "init_checkpoint": "shipped", "keep_init_losses": True, "iterations": 100}
    t = load_run_config(None, keep)[1]
    assert t.lpips_weight == 0.0 and t.depth_weight == 0.0  # the run's own
    t = load_run_config(None, keep, resume=False)[1]
    assert t.lpips_weight == 1.0 and t.depth_weight == 0.1  # the shipped checkpoint's
    (old / "metrics.jsonl").unlink()  # a config.json alone: no run to continue
    assert load_run_config(None, over)[1].opacity_weight == OPACITY_WEIGHT
    # through the command line: a run begun without the opacity loss, started over with a config naming none
    cfg = tmp_path / "c.json"
    tiny = {"preset": "fast", "overrides": TINY}
    small = {"iterations": 1, "rays_per_object": 16, "objects_per_step": 1, "threads": 1, "max_ref_views": 2}
    cfg.write_text(json.dumps({"model": tiny, "train": {**small, "opacity_weight": 0.0}}))
    run = ["train", "--data", str(root), "--out", str(tmp_path / "a")]
    assert main([*run, "--config", str(cfg)]) == 0
    cfg.write_text(json.dumps({"model": tiny, "train": small}))
    assert main([*run, "--config", str(cfg), "--no-resume", "--force"]) == 0
    assert json.loads((tmp_path / "a" / "config.json").read_text())["train"]["opacity_weight"] == OPACITY_WEIGHT


def test_a_resume_with_a_damaged_config_json_keeps_the_losses_it_began_with(tmp_path, data, monkeypatch):
    """config.json is written atomically; when it is damaged or gone anyway, a resumed run takes what it began with
    from its newest checkpoint's train_config (never 0 for the opacity loss, nor the kept losses dropped); with
    neither readable, the defaults of a new run."""
    from blender_mrvm.cli import main
    from blender_mrvm.models.model import GeneralizableNeRF
    from blender_mrvm.training import trainer
    from blender_mrvm.training.config import OPACITY_WEIGHT

    root, _ = data
    run = tmp_path / "run"
    began = {"opacity_weight": 0.3, "lpips_weight": 0.0, "depth_weight": 0.05}
    mcfg = model_config("fast", TINY)
    ckpt.save_checkpoint(run, 1, GeneralizableNeRF(mcfg), mcfg, None, {"train_config": json.dumps(began)})
    _holds_run(run, began)
    keep = {"data": str(root), "out_dir": str(run), "init_checkpoint": "shipped", "keep_init_losses": True}
    for damage in ("", "{\"model\": {}, \"tr", None):
        if damage is None:
            (run / "config.json").unlink()
        else:
            (run / "config.json").write_text(damage)
        t = load_run_config(None, keep)[1]
        assert (t.opacity_weight, t.lpips_weight, t.depth_weight) == (0.3, 0.0, 0.05), damage
    (run / "config.json").write_text("")
    for ck in (run / "checkpoints").glob("step_*"):
        (ck / ckpt.MODEL_FILE).write_bytes(b"torn")
    t = load_run_config(None, keep)[1]
    assert t.opacity_weight == OPACITY_WEIGHT and t.lpips_weight == 1.0  # a new run's: the default, the shipped's
    # end to end: 1 step, config.json emptied, resumed to 2: the opacity loss is still trained
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"model": {"preset": "fast", "overrides": TINY},
                               "train": {"rays_per_object": 16, "objects_per_step": 1, "threads": 1,
                                         "max_ref_views": 2, "log_every": 1}}))
    written = []
    real = trainer.atomic_write_text
    monkeypatch.setattr(trainer, "atomic_write_text", lambda p, text: (written.append(Path(p).name), real(p, text)))
    e = ["train", "--config", str(cfg), "--data", str(root), "--out", str(tmp_path / "e")]
    assert main([*e, "--iterations", "1"]) == 0
    assert written == ["config.json"]  # never a torn file
    (tmp_path / "e" / "config.json").write_text("")
    assert main([*e, "--iterations", "2"]) == 0
    assert json.loads((tmp_path / "e" / "config.json").read_text())["train"]["opacity_weight"] == OPACITY_WEIGHT
    lines = [json.loads(x) for x in (tmp_path / "e" / "metrics.jsonl").read_text().splitlines()]
    assert [x["step"] for x in lines] == [1, 2] and lines[1]["opacity"] > 0


def test_model_kind_with_init_fine_tunes_the_checkpoints_own_model(tmp_path, data):
    """`--model gpnr --init X` (or a model section naming only its kind and overrides) fine-tunes X's own model
    config, as without --model, not the kind's default preset; a kind that is not the checkpoint's is an
    InputError naming it."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.models import registry

    root, _ = data
    own = registry.build_config("gpnr", "balanced", {"n_samples": 12, "depth_spacing": "linear"})
    ckpt.save_checkpoint(tmp_path / "gb", 1, registry.build_model(own, load_pretrained=False), own, None)
    over = {"data": str(root), "out_dir": str(tmp_path / "ft"), "init_checkpoint": str(tmp_path / "gb")}
    assert load_run_config(None, over)[0] == own
    assert load_run_config(None, over, kind="gpnr")[0] == own
    assert load_run_config(None, over, kind="GPNR")[0] == own  # (an alias or another spelling of the kind)
    p = tmp_path / "run.json"
    p.write_text(json.dumps({"model": {"kind": "gpnr", "overrides": {"near": 0.3}}}))
    m = load_run_config(p, over)[0]
    assert m == replace(own, near=0.3)
    with pytest.raises(InputError, match=r"--model nerformer_mrvm names a nerformer_mrvm model, but init_checkpoint "
                                         r".* holds a gpnr model; drop --model"):
        load_run_config(None, over, kind="nerformer_mrvm")
    p.write_text(json.dumps({"model": {"kind": "nerformer_mrvm"}}))
    with pytest.raises(InputError, match="the config's model section .* holds a gpnr model"):
        load_run_config(p, over)
    # a preset named beside it: the checkpoint's own (its weights fit no other preset), or refused
    assert load_run_config(None, over, kind="gpnr", preset="balanced")[0] == own
    with pytest.raises(InputError, match=r"--preset fast builds a new gpnr model, but --init .* holds a gpnr model "
                                         r"\(preset balanced\)"):
        load_run_config(None, over, kind="gpnr", preset="fast")


def test_min_ref_views_above_an_objects_views_is_refused_before_training(tmp_path, data):
    """An object with no more views than train.min_ref_views cannot give that many references and a target: the run
    is refused naming it (not numpy's 'low >= high' at the first draw, after config.json and metrics.jsonl were
    written). train.ref_views_per 'step' documents that such an object takes what it has."""
    from blender_mrvm.errors import InputError

    root, scenes = data  # 5 views an object
    _, tcfg = _cfgs(tmp_path / "run", root, min_ref_views=4, max_ref_views=4)
    RayBatcher(scenes, tcfg, 0.05, seed=0).draw(False)  # 4 references and a target
    bad = replace(tcfg, min_ref_views=5, max_ref_views=6)
    with pytest.raises(InputError, match=r"train.min_ref_views is 5: every training object needs at least 6 views "
                                         r"\(the references and a target\), and 2 have fewer: spheres/obj000 \(5 views\), "):
        run_to_end(train(model_config("fast", TINY), bad, scenes=scenes))
    assert not (tmp_path / "run").exists()
    step = RayBatcher(scenes, replace(bad, ref_views_per="step"), 0.05, seed=0)
    assert step.draw(False, 5)["n_refs"] == 4


def test_a_resume_below_its_step_is_refused_and_a_finished_run_reports_its_step(tmp_path, data):
    """A run resumed with fewer iterations than its checkpoint's step is refused before anything is written (it
    had reported that step count and recorded it in config.json though the model is further on); with exactly its
    step it trains nothing and reports the step it is at."""
    from blender_mrvm.errors import InputError

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "run", root, iterations=2, ckpt_every=2)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    before = {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir() if p.is_file()}
    with pytest.raises(InputError, match=r"is at step 2 \(step_0000002\), past train.iterations \(1\): raise it"):
        run_to_end(train(mcfg, replace(tcfg, iterations=1), scenes=scenes))
    assert {p.name: p.read_bytes() for p in (tmp_path / "run").iterdir() if p.is_file()} == before
    s = run_to_end(train(mcfg, tcfg, scenes=scenes))
    # the checkpoint it is at (a null one failed `eval --checkpoint "$ck"` in a script)
    assert s["step"] == 2 and s["resumed_from"] == 2 and s["checkpoint"].endswith("step_0000002")


def test_a_resume_with_more_iterations_says_the_schedule_changes(tmp_path, data, capsys):
    """A run extended by resuming with a larger --iterations follows the longer schedule from the resume step: the
    learning rate jumps back up and the masking phase moves. Legal, but not what one run of either length does,
    so it is said."""
    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "run", root, iterations=2, ckpt_every=2, pretrain_frac=0.5)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    capsys.readouterr()
    run_to_end(train(mcfg, replace(tcfg, iterations=4), scenes=scenes))
    err = capsys.readouterr().err
    assert "started with 2 iterations and resumes at step 2 with 4" in err
    assert "masked pretraining ends at step 2 (was 1)" in err
    run_to_end(train(mcfg, replace(tcfg, iterations=4), scenes=scenes))
    assert "resumes at step" not in capsys.readouterr().err, "the same length again: nothing to say"


@pytest.mark.parametrize("poison", ["huge", "nan"])
def test_a_diverged_update_is_never_saved(tmp_path, data, monkeypatch, poison):
    """The loss check sees step N's loss, computed with the weights before update N: the diverged weights update N
    leaves (1e30 from a learning rate too high, or NaN) had been saved as step N's checkpoint (the final one too,
    exit 0) while the message said that checkpoint was kept. They are now checked before any save."""
    from blender_mrvm.errors import TrainingStopped

    root, scenes = data
    real_step = torch.optim.AdamW.step
    calls = []

    def step(self, *a, **kw):  # update 2 diverges
        out = real_step(self, *a, **kw)
        calls.append(1)
        if len(calls) == 2:
            with torch.no_grad():
                for g in self.param_groups:
                    for p in g["params"]:
                        p.mul_(1e30) if poison == "huge" else p.fill_(float("nan"))
        return out

    monkeypatch.setattr(torch.optim.AdamW, "step", step)
    run = tmp_path / "run"
    mcfg, tcfg = _cfgs(run, root, iterations=2, ckpt_every=1, keep_checkpoints=1, objects_per_step=1)
    with pytest.raises(TrainingStopped, match=r"training stopped at step 2: its update left NaN, infinite or "
                                              r"diverged weights .*; the last checkpoint \(step_0000001\) is kept"):
        run_to_end(train(mcfg, tcfg, scenes=scenes))
    cks = sorted(p.name for p in (run / "checkpoints").iterdir() if p.is_dir())
    assert cks == ["step_0000001"], cks  # step 2 (the final one) not written; keep 1 did not drop the good one
    assert (run / "checkpoints" / "latest").read_text().strip() == "step_0000001"
    model, _, _ = ckpt.load_model(run)  # finite, loads
    assert not ckpt.nonfinite_weights(model, ckpt.DIVERGED_WEIGHT)
    # diverging at the first update: nothing is saved, with a one-line stop (it had ended with exit 0)
    calls.clear()
    calls.append(1)
    with pytest.raises(TrainingStopped, match="training stopped at step 1: .*no checkpoint was written"):
        run_to_end(train(mcfg, replace(tcfg, out_dir=str(tmp_path / "run1"), iterations=1), scenes=scenes))
    assert not (tmp_path / "run1" / "checkpoints").exists()


def test_training_refuses_boxes_no_camera_looks_at(tmp_path, data, capsys):
    """A bbox away from where the cameras look (a wrong meta.json bbox): every ray missed ('hit 0' every step) and
    the run trained nothing without a word. All such objects: refused up front; some: a warning naming them."""
    from blender_mrvm.errors import InputError

    root, scenes = data
    _, tcfg = _cfgs(tmp_path, root)
    away = [copy.copy(s) for s in scenes]
    away[0].bbox = (np.full(3, 100.0), np.full(3, 101.0))
    assert len(away) >= 2
    RayBatcher(scenes, tcfg, 0.1, seed=0)
    assert "warning" not in capsys.readouterr().err
    RayBatcher(away, tcfg, 0.1, seed=0)
    err = capsys.readouterr().err
    assert err.count("warning:") == 1 and f"{away[0].category}/{away[0].name}" in err and f"1 of the {len(away)}" in err
    with pytest.raises(InputError, match="looks at its box .* the run would learn nothing"):
        RayBatcher(away[:1], tcfg, 0.1, seed=0)


def test_init_into_a_folder_holding_another_run_is_refused(tmp_path, data):
    """``train --init X --out <a folder holding a run>`` went on from the run's own step (X never loaded) while
    config.json took X's settings (a reviewer's GPNR run turned from depth_spacing auto to linear midway, lr 5e-4 to
    1e-4); with another architecture the message blamed the intact checkpoint ("does not match its model config").
    Both are refused in one line before anything is written; the same --init as the run began with (a fine-tune run
    again after Ctrl-C) continues it."""
    from blender_mrvm.errors import InputError

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "a", root, iterations=2, ckpt_every=2)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    ck = str(tmp_path / "a")
    run_b = tmp_path / "b"
    mcfg_b, tcfg_b = _cfgs(run_b, root, iterations=2, ckpt_every=2)
    run_to_end(train(mcfg_b, tcfg_b, scenes=scenes))  # a run from a random start
    before = {p.name: p.read_bytes() for p in run_b.iterdir() if p.is_file()}
    with pytest.raises(InputError, match=r"began from a random initialisation, not --init .*continue the run without"):
        run_to_end(train(mcfg_b, replace(tcfg_b, init_checkpoint=ck, iterations=4), scenes=scenes))
    assert {p.name: p.read_bytes() for p in run_b.iterdir() if p.is_file()} == before
    # another architecture, no --init: the message names both models, not a broken checkpoint
    wide = model_config("fast", {**TINY, "nerformer": {"d_model": 32, "n_heads": 2}})
    with pytest.raises(InputError, match=r"trains a nerformer_mrvm model.*this start asks for .*--no-resume --force"):
        run_to_end(train(wide, replace(tcfg_b, iterations=4), scenes=scenes))
    # a fine-tune run continued with its own --init
    run_c = tmp_path / "c"
    mcfg_c, tcfg_c = _cfgs(run_c, root, iterations=2, ckpt_every=2, init_checkpoint=ck)
    run_to_end(train(mcfg_c, tcfg_c, scenes=scenes))
    s = run_to_end(train(mcfg_c, replace(tcfg_c, iterations=4), scenes=scenes))
    assert s["resumed_from"] == 2 and s["step"] == 4


def test_preset_beside_init_fine_tunes_that_model_or_is_refused_clearly(tmp_path):
    """``train --preset fast --init shipped:gpnr`` said "the run config a nerformer_mrvm model; leave the run config's
    model section out" to a user who gave no run config (--preset quietly meant a new NeRFormer). A preset that names
    the checkpoint's own model fine-tunes it; another is refused naming --preset and both models."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.models import registry

    over = {"init_checkpoint": "shipped:gpnr", "data": "x", "out_dir": str(tmp_path / "run")}
    m, _ = load_run_config(None, over, preset="fast")
    assert registry.kind_of(m) == "gpnr" and m.name == "fast"
    with pytest.raises(InputError, match=r"--preset balanced builds a new nerformer_mrvm model, but --init "
                                         r"shipped:gpnr holds a gpnr model \(preset fast\).*drop --preset"):
        load_run_config(None, over, preset="balanced")
    with pytest.raises(InputError, match=r"--preset fast builds a new nerformer_mrvm model.*holds a gpnr"):
        load_run_config(None, over, preset="fast", kind="nerformer_mrvm")


def test_a_rerun_of_a_finished_run_keeps_its_summary_and_reports_its_checkpoint(tmp_path, data, capsys):
    """Rerunning a finished `train` printed "checkpoint": null and rewrote summary_rank0.json with an empty "last",
    losing the run's final loss: the rerun reports the checkpoint it found and leaves the record alone."""
    from blender_mrvm.cli import main

    root, _ = data
    cfg = tmp_path / "cfg.json"
    cfg.write_text(json.dumps({"model": {"preset": "fast", "overrides": TINY},
                               "train": {"iterations": 2, "rays_per_object": 16, "objects_per_step": 1, "threads": 1,
                                         "max_ref_views": 2, "lr_warmup": 0, "ckpt_every": 2}}))
    args = ["train", "--config", str(cfg), "--data", str(root), "--out", str(tmp_path / "run")]
    assert main(args) == 0
    first = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    record = (tmp_path / "run" / "summary_rank0.json").read_text()
    assert main(args) == 0
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert again["checkpoint"] == first["checkpoint"] and again["checkpoint"].endswith("step_0000002")
    assert (tmp_path / "run" / "summary_rank0.json").read_text() == record


def test_the_gradient_norm_is_logged_without_clipping_and_direct_calls_check_reference_counts(tmp_path, data):
    """grad_clip 0 logged a grad_norm of 0.0 at every step (the norm was only measured by the clipping); it is the
    gradient's norm now. A run started by train() itself (the panel, scripts: not through load_run_config) drawing
    more references than its model takes is refused as the CLI refuses it."""
    from blender_mrvm.errors import InputError

    root, scenes = data
    mcfg, tcfg = _cfgs(tmp_path / "run", root, grad_clip=0.0)
    run_to_end(train(mcfg, tcfg, scenes=scenes))
    lines = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert all(x["grad_norm"] > 0 and np.isfinite(x["grad_norm"]) for x in lines), lines
    mcfg, tcfg = _cfgs(tmp_path / "run2", root, max_ref_views=mcfg.max_ref_views + 1)
    with pytest.raises(InputError, match=r"train\.max_ref_views \(\d+\) is above the model's max_ref_views"):
        run_to_end(train(mcfg, tcfg, scenes=scenes))
    assert not (tmp_path / "run2").exists()
