"""Train / fine-tune from the panel: the operator runs `train` in the worker on a tiny analytic set,
writes checkpoints that Synthesize novel views then uses, continues a run, refuses settings that
cannot work, and Esc stops the worker (modal path with synthetic events)."""

from __future__ import annotations

import json
import re
import time
import types
from pathlib import Path

import pytest


@pytest.fixture
def train_ready(empty_scene, tmp_path, addon):
    import bpy

    from blender_mrvm.training.synthetic import make_sphere_dataset

    pr = bpy.context.preferences.addons["blender_mrvm"].preferences
    saved = (pr.python_path, pr.checkpoint_dir, pr.device)
    pr.python_path, pr.checkpoint_dir, pr.device = "", "", "CPU"
    data = make_sphere_dataset(tmp_path / "data", n_objects=2, n_views=4, resolution=16, seed=3)
    p = empty_scene.mrvm_train
    p.data_dir, p.run_dir, p.preset, p.start_from = str(data), str(tmp_path / "run"), "fast", "NEW"
    p.iterations, p.checkpoint_every, p.rays_per_object = 2, 1, 32
    yield empty_scene
    pr.python_path, pr.checkpoint_dir, pr.device = saved


def test_panel_draws_the_model_section(train_ready):
    from test_novel_views import _draw  # the FakeLayout helper

    from blender_mrvm.panels.novel_views import MRVM_PT_model

    log = _draw(MRVM_PT_model)
    props = {e[1] for e in log if e[0] == "prop"}
    assert {"data_dir", "run_dir", "start_from", "preset", "iterations", "checkpoint_every", "resume",
            "use_for_synthesis"} <= props
    assert ("operator", "mrvm.train") in log
    train_ready.mrvm_train.start_from = "CHECKPOINT"  # the size comes from the checkpoint: no preset
    props = {e[1] for e in _draw(MRVM_PT_model) if e[0] == "prop"}
    assert "init_checkpoint" in props and "preset" not in props


def test_train_writes_checkpoints_that_synthesis_picks_and_continues(train_ready, tmp_path):
    import bpy

    from blender_mrvm.operators import synthesize as S
    from blender_mrvm.training.checkpoint import find_checkpoint, load_model

    p = train_ready.mrvm_train
    assert bpy.ops.mrvm.train() == {"FINISHED"}
    assert re.match(r"Trained to step 2 in \d+ s; checkpoint .*step_0000002 \(picked for novel views\)$", p.status), p.status
    run = tmp_path / "run"
    assert find_checkpoint(run).name == "step_0000002"
    model, cfg, meta = load_model(run)
    assert cfg.name == "fast" and meta["step"] == "2"
    assert json.loads((run / "config.json").read_text())["train"]["ckpt_every"] == 1
    nv = train_ready.mrvm_novel_views
    assert nv.checkpoint == str(run)
    # Synthesis now takes that run (its latest checkpoint) as the model.
    assert S._checkpoint(bpy.context, nv) == run
    # A run folder given relative to the .blend is picked as the folder trained, even when the .blend is saved
    # elsewhere before the job ends (the setting's text then named another folder)
    from blender_mrvm.operators import train as T

    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    assert T._as_setting(run) == bpy.path.relpath(str(run)) and Path(bpy.path.abspath(T._as_setting(run))) == run
    # Fine-tune: continue the same run to step 3.
    p.iterations = 3
    assert bpy.ops.mrvm.train() == {"FINISHED"}
    assert "Trained to step 3" in p.status and "(continued from step 2)" in p.status
    assert find_checkpoint(run).name == "step_0000003"
    # Already there: a clear message, not a silent success.
    with pytest.raises(RuntimeError, match="already at step 3; raise Iterations"):
        bpy.ops.mrvm.train()


def test_fine_tune_the_shipped_model_then_continue(train_ready, tmp_path):
    """Start from the shipped model: its config and weights, no masking phase, the fine-tuning learning
    rate; continuing the run keeps that schedule."""
    import bpy
    import torch

    from blender_mrvm.models.pretrained import default_checkpoint
    from blender_mrvm.training.checkpoint import load_model

    p = train_ready.mrvm_train
    p.start_from, p.iterations = "SHIPPED", 1
    assert bpy.ops.mrvm.train() == {"FINISHED"}
    assert re.match(r"Trained to step 1 in \d+ s \(fine-tuned mrvm_shapenet13_all.safetensors\); checkpoint ", p.status), p.status
    run = tmp_path / "run"
    doc = json.loads((run / "config.json").read_text())
    assert doc["train"]["init_checkpoint"] == str(default_checkpoint())
    assert doc["train"]["pretrain_frac"] == 0.0 and doc["train"]["lr"] == 1e-4
    assert doc["train"]["opacity_weight"] == 0.1  # our renders have masks: keep the alpha clean
    tuned, cfg, _ = load_model(run)
    shipped, cfg0, _ = load_model(default_checkpoint())
    assert cfg == cfg0  # the shipped model's own config, not the "fast" preset chosen for new runs
    diff = max(float((a - b).abs().max()) for a, b in zip(tuned.state_dict().values(), shipped.state_dict().values()))
    assert 0 < diff < 1e-3, diff  # one small AdamW step away from the shipped weights
    p.iterations = 2  # continue: same model and schedule, from step 1
    assert bpy.ops.mrvm.train() == {"FINISHED"}
    assert "(continued from step 1)" in p.status
    doc = json.loads((run / "config.json").read_text())
    assert doc["train"]["lr"] == 1e-4 and doc["train"]["pretrain_frac"] == 0.0
    assert torch.is_tensor(next(iter(load_model(run)[0].state_dict().values())))


def test_fine_tune_bad_checkpoints(train_ready, tmp_path):
    import bpy

    p = train_ready.mrvm_train
    p.start_from = "CHECKPOINT"
    p.init_checkpoint = ""
    with pytest.raises(RuntimeError, match="choose the checkpoint to fine-tune"):
        bpy.ops.mrvm.train()
    p.init_checkpoint = str(tmp_path / "missing.safetensors")
    with pytest.raises(RuntimeError, match="the checkpoint to fine-tune does not exist"):
        bpy.ops.mrvm.train()
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x05" * 40)
    p.init_checkpoint = str(junk)
    with pytest.raises(RuntimeError, match="junk.safetensors does not load"):
        bpy.ops.mrvm.train()
    assert not (tmp_path / "run").exists()  # nothing started


def test_train_bad_settings(train_ready, tmp_path):
    import bpy

    p = train_ready.mrvm_train
    p.data_dir = str(tmp_path / "nothing")
    with pytest.raises(RuntimeError, match="dataset folder .*nothing does not exist"):
        bpy.ops.mrvm.train()
    assert "does not exist" in p.status
    p.data_dir = str(tmp_path)  # a folder without a dataset: the worker's one-line error
    with pytest.raises(RuntimeError, match="not a dataset this tool reads") as e:
        bpy.ops.mrvm.train()
    assert "\n" not in str(e.value).strip() and "not a dataset this tool reads" in p.status
    run = tmp_path / "run"
    run.mkdir(exist_ok=True)
    (run / "config.json").write_text(json.dumps({"model": {"config": {"name": "balanced"}}}))
    p.data_dir = str(tmp_path / "data")
    with pytest.raises(RuntimeError, match="the run folder holds a nerformer_mrvm 'balanced' model"):
        bpy.ops.mrvm.train()


def test_train_modal_escape_stops_the_worker(train_ready, tmp_path, monkeypatch):
    import bpy

    from blender_mrvm import worker as Wk
    from blender_mrvm.operators._modal import ProgressOperator
    from blender_mrvm.operators.train import MRVM_OT_train as Op
    from test_novel_views import _FakeWM

    procs = []
    real = Wk.run_worker
    monkeypatch.setattr(Wk, "run_worker", lambda *a, **k: real(*a, on_start=procs.append, **k))
    train_ready.mrvm_train.iterations = 100000
    train_ready.mrvm_train.checkpoint_every = 100000  # Esc's checkpoint is the only one

    class Driver(ProgressOperator):
        props_attr, job_name, cancel_hint = Op.props_attr, Op.job_name, Op.cancel_hint
        start, on_result = Op.start, Op.on_result
        reports: list = []

        def report(self, level, msg):
            self.reports.append((next(iter(level)), msg))

    ctx = types.SimpleNamespace(scene=bpy.context.scene, preferences=bpy.context.preferences, window=None,
                                window_manager=_FakeWM(), screen=None,
                                workspace=types.SimpleNamespace(status_text_set=lambda t: None))
    op = Driver()
    assert op.invoke(ctx, None) == {"RUNNING_MODAL"}
    assert op.modal(ctx, types.SimpleNamespace(type="TIMER")) == {"RUNNING_MODAL"}
    assert procs and procs[0].poll() is None
    metrics = tmp_path / "run" / "metrics.jsonl"
    t0 = time.monotonic()
    while not (metrics.is_file() and metrics.read_text().strip()):  # a step or more done
        assert procs[0].poll() is None and time.monotonic() - t0 < 120
        assert op.modal(ctx, types.SimpleNamespace(type="TIMER")) == {"RUNNING_MODAL"}
    assert op.modal(ctx, types.SimpleNamespace(type="ESC")) == {"CANCELLED"}
    assert procs[0].poll() is not None
    assert op.reports[-1] == ("WARNING", "Training cancelled; the step in progress finishes and is saved as a "
                                         "checkpoint (train again to continue)")
    assert not train_ready.mrvm_train.running
    # the worker finished its step and saved it: training again continues from there
    step = int((tmp_path / "run" / "checkpoints" / "latest").read_text().strip().split("_")[1])
    assert step >= 1


def test_write_job_opacity_loss_only_with_masks(train_ready, tmp_path):
    """New runs add the opacity loss on our renders (manifest: masks present), not on other formats;
    a continued run keeps whatever it was started with."""
    import bpy

    from blender_mrvm.operators import train as T
    from blender_mrvm.training.config import OPACITY_WEIGHT

    job = T.plan_from_props(bpy.context)
    doc = lambda d: json.loads((d / "train.json").read_text())["train"]  # noqa: E731
    for d in "abc":
        (tmp_path / d).mkdir()
    T.write_job(job, tmp_path / "a")
    assert doc(tmp_path / "a")["opacity_weight"] == OPACITY_WEIGHT
    srn = tmp_path / "srn"
    srn.mkdir()
    T.write_job(T.TrainJob(**{**job.__dict__, "data": srn}), tmp_path / "b")
    assert doc(tmp_path / "b")["opacity_weight"] == 0.0
    T.write_job(T.TrainJob(**{**job.__dict__, "continued": {"opacity_weight": 0.0, "lr": 5e-4}}), tmp_path / "c")
    assert doc(tmp_path / "c")["opacity_weight"] == 0.0 and doc(tmp_path / "c")["lr"] == 5e-4
    import dataclasses

    from blender_mrvm.training.config import TrainConfig

    losses = {f.name for f in dataclasses.fields(TrainConfig) if f.name.endswith("_weight")}
    assert losses <= set(T.CONTINUED_SETTINGS)  # a continued run trains with the losses it started with


def test_cli_and_panel_fine_tune_with_one_policy(train_ready, tmp_path):
    """The panel's "Start from: shipped" job and the CLI's ``train --init shipped`` give the same train
    settings: the one fine-tuning policy (training.config.FINETUNE), not a copy in the operator."""
    import bpy

    from blender_mrvm.models.pretrained import default_checkpoint
    from blender_mrvm.operators import train as T
    from blender_mrvm.training.config import FINETUNE, FINETUNE_KEEPS_LOSSES, load_run_config

    p = train_ready.mrvm_train
    p.start_from, p.iterations = "SHIPPED", 40
    for keep in (False, True):  # "Keep its losses" and --keep-losses
        p.keep_losses = keep
        job = T.plan_from_props(bpy.context)
        T.write_job(job, tmp_path)
        m_panel, t_panel = load_run_config(tmp_path / "train.json")
        m_cli, t_cli = load_run_config(None, {"data": p.data_dir, "out_dir": str(tmp_path / "run"), "iterations": 40,
                                              "init_checkpoint": "shipped", "keep_init_losses": keep or None})
        assert m_panel == m_cli
        for k in (*FINETUNE, *FINETUNE_KEEPS_LOSSES):
            assert getattr(t_panel, k) == getattr(t_cli, k), (keep, k)
        assert t_cli.lpips_weight == (1.0 if keep else 0.0)  # the shipped model's own loss, or the default
    p.keep_losses = False
    assert t_cli.pretrain_frac == 0.0 and t_cli.lr == FINETUNE["lr"] and t_cli.lr_warmup == 4  # a tenth of 40
    assert t_panel.init_checkpoint == str(default_checkpoint())
    # a run config that names its own learning rate keeps it
    (tmp_path / "own.json").write_text(json.dumps({"train": {"lr": 3e-4, "init_checkpoint": "shipped"}}))
    assert load_run_config(tmp_path / "own.json")[1].lr == 3e-4


def test_panel_new_gpnr_run_and_shipped_model_choice(train_ready, tmp_path):
    """The Model section trains a new model of the chosen kind; a size the kind lacks is one clear error;
    the Novel views section offers the shipped models."""
    import bpy

    from blender_mrvm.operators import train as T
    from blender_mrvm.panels.novel_views import MRVM_PT_model
    from test_novel_views import _draw

    p = train_ready.mrvm_train
    p.model_kind, p.preset = "gpnr", "fast"
    job = T.plan_from_props(bpy.context)
    assert job.model == {"kind": "gpnr", "preset": "fast"}
    T.write_job(job, tmp_path)
    from blender_mrvm.training.config import load_run_config

    mcfg, _ = load_run_config(tmp_path / "train.json")
    assert type(mcfg).__name__ == "GPNRConfig" and mcfg.name == "fast"
    assert "model_kind" in {e[1] for e in _draw(MRVM_PT_model) if e[0] == "prop"}
    p.model_kind, p.preset = "nerformer_mrvm", "paper"  # the paper's NeRFormer size exists since session 4
    assert T.plan_from_props(bpy.context).model == {"kind": "nerformer_mrvm", "preset": "paper"}
    from blender_mrvm.models import registry

    real = registry.presets
    try:  # a size the kind lacks is one clear error
        registry.presets = lambda k: {n: c for n, c in real(k).items() if n != "paper"}
        with pytest.raises(Exception, match="has no 'paper' size"):
            T.plan_from_props(bpy.context)
    finally:
        registry.presets = real
