"""Reproducibility as a researcher needs it (the 2026-11-29 review): the learning-rate schedule's last step, exact
resume of `sem2nerf train` with its LPIPS loss, the seed a resumed run records, and what every run records so
that it can be repeated (code version and commit, libraries, threads, command, data digest)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
import torch

from blender_mrvm.models import vgg
from blender_mrvm.models.checkpoint_files import MODEL_FILE, find_checkpoint, read_header_meta
from blender_mrvm.models.config import model_config
from blender_mrvm.progress import run_to_end
from blender_mrvm.training.config import TrainConfig
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
HAVE_LPIPS = all((vgg.weights_dir() / f).is_file() for f in (vgg.VGG_FILE, vgg.LPIPS_FILE))
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 16, "n_heads": 2},
        "sampler": {"n_coarse": 8, "n_fine": 4}}
TINY_S2N = (("hidden", 16), ("n_layers", 2), ("encoder_hidden", 32), ("vgg_layers", 4), ("n_coarse", 6),
            ("n_fine", 2), ("style_mean_samples", 200), ("z_dim", 8), ("mapping_hidden", 16))


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_sphere_dataset(tmp_path_factory.mktemp("repro") / "d", n_objects=3, n_views=4, resolution=16, seed=1)


def _weights(run: Path) -> dict:
    from safetensors.torch import load_file

    return load_file(str(find_checkpoint(run / "checkpoints") / MODEL_FILE))


def _same_weights(a: Path, b: Path) -> bool:
    wa, wb = _weights(a), _weights(b)
    return wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


def _as_killed_after(run: Path, step: int, copy: Path) -> Path:
    """A copy of ``run`` as a SIGKILL right after its step-``step`` checkpoint leaves it: that checkpoint newest,
    the process state gone (a resume starts from the files alone)."""
    shutil.copytree(run, copy)
    assert (copy / "checkpoints" / f"step_{step:07d}").is_dir()
    for ck in (copy / "checkpoints").glob("step_*"):
        if int(ck.name[5:]) > step:
            shutil.rmtree(ck)
    (copy / "checkpoints" / "latest").write_text(f"step_{step:07d}\n")
    return copy


# ------------------------------------------------------------------------------------------- lr schedule

@pytest.mark.parametrize("iterations, warmup", [(110, 10), (111, 10), (11, 10), (5, 0), (2, 0), (1, 0), (300, 200)])
def test_the_cosine_reaches_its_floor_on_the_last_step(iterations, warmup):
    """`lr_at`'s cosine ended one step short: at step iterations-1 its phase was (N-1-W)/(N-W) < 1, so the last
    step ran above lr * lr_final_frac (a 110-step run with 10 warm-up steps: 1.0022e-4 for 1e-4). Now the last step
    is the floor exactly, the first step after the warm-up is the peak, and the rate never rises."""
    from blender_mrvm.training.trainer import lr_at

    c = TrainConfig(lr=1e-3, lr_warmup=warmup, iterations=iterations, lr_final_frac=0.1)
    rates = [lr_at(s, c) for s in range(iterations)]
    assert rates[-1] == 1e-3 * 0.1
    if iterations - 1 > warmup:
        assert rates[warmup] == 1e-3
    assert all(b <= a for a, b in zip(rates[warmup:], rates[warmup + 1:]))
    assert rates[:warmup] == [pytest.approx(1e-3 * (s + 1) / warmup) for s in range(warmup)]
    if iterations == 111:  # the cosine's middle is the middle of the steps after the warm-up
        assert lr_at(60, c) == pytest.approx(1e-3 * (0.1 + 0.9 * 0.5))


def test_a_resume_with_a_longer_schedule_still_names_both_rates(tmp_path, data, capsys):
    """The resume logic that compares two schedules (`_note_a_longer_schedule`) reads the same `lr_at`: a run of 4
    steps resumed with 8 names the rate of the old and the new schedule at the resume step."""
    from blender_mrvm.training.trainer import lr_at, train

    mcfg = model_config("fast", TINY)
    base = dict(data=str(data), out_dir=str(tmp_path / "run"), objects_per_step=1, rays_per_object=32,
                max_ref_views=2, lr=3e-3, lr_warmup=1, log_every=1, ckpt_every=2, threads=1, pretrain_frac=1.0)
    run_to_end(train(mcfg, TrainConfig(iterations=4, **base)))
    logged = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert logged[-1]["step"] == 4 and logged[-1]["lr"] == 3e-3 * 0.05  # the run's last step at the floor
    capsys.readouterr()
    longer = TrainConfig(iterations=8, **base)
    run_to_end(train(mcfg, longer))
    err = capsys.readouterr().err
    before = lr_at(4, TrainConfig(iterations=4, **base))
    assert before == 3e-3 * 0.05  # (the old schedule's floor: a step past its end)
    assert f"({before:.3g} at this step before, {lr_at(4, longer):.3g} now)" in err


# ------------------------------------------------------------------------------------------- exact resume

def _s2n(data, out, **kw):
    from blender_mrvm.training import sem2nerf as T

    base = dict(data=str(data), out_dir=str(out), preset="fast", model_overrides=TINY_S2N, iterations=3,
                objects_per_step=1, patch_size=16, lpips_weight=0.2, checkpoint_every=1, log_every=1, threads=1,
                seed=3, keep=5)
    return T.train_config(**{**base, **kw})


@pytest.mark.skipif(not HAVE_LPIPS, reason=f"offline weights missing: run `{vgg.FETCH_COMMAND}`")
def test_sem2nerf_resumes_exactly_with_its_lpips_loss_and_keeps_its_seed(tmp_path, data, capsys):
    """`sem2nerf train` with its default LPIPS loss built the LPIPS network after restoring the checkpoint's RNG
    state, and building it draws from torch's generator: a run killed after a checkpoint and resumed sampled
    other points from then on (other weights than the uninterrupted run). And a resume with another --seed
    (which cannot act: the generators come from the checkpoint) recorded that seed in config.json and the
    checkpoints. Now the resumed run ends with the uninterrupted run's weights and records the seed it began with."""
    from blender_mrvm.training import sem2nerf as T

    run_to_end(T.train(_s2n(data, tmp_path / "a")))
    same = _as_killed_after(tmp_path / "a", 1, tmp_path / "same")
    s = run_to_end(T.train(_s2n(data, same)))
    assert s["step"] == 3 and s["resumed_from"].endswith("step_0000001")
    assert _same_weights(tmp_path / "a", same)
    killed = _as_killed_after(tmp_path / "a", 1, tmp_path / "b")
    capsys.readouterr()
    run_to_end(T.train(_s2n(data, killed, seed=8)))
    assert "seed 8 is not used" in capsys.readouterr().err
    assert _same_weights(tmp_path / "a", killed)
    assert json.loads((killed / "config.json").read_text())["train"]["seed"] == 3
    assert json.loads(read_header_meta(find_checkpoint(killed / "checkpoints") / MODEL_FILE)["train_config"])["seed"] == 3
    a = [json.loads(x) for x in (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()]
    b = [json.loads(x) for x in (killed / "metrics.jsonl").read_text().splitlines()]
    drop = ("elapsed_s",)
    assert [{k: v for k, v in r.items() if k not in drop} for r in a] == \
        [{k: v for k, v in r.items() if k not in drop} for r in b]


def test_a_train_resume_with_another_seed_records_the_seed_it_ran_with(tmp_path, data, capsys):
    """`train --seed 5` into a run folder started with seed 3 resumes that run (its generators from the
    checkpoint: the weights are seed 3's, bit for bit), and had written seed 5 into config.json and the following
    checkpoints, so repeating the run as recorded gave other numbers. Now it keeps seed 3 and says so."""
    from blender_mrvm.training.trainer import train

    mcfg = model_config("fast", TINY)
    base = dict(data=str(data), iterations=4, objects_per_step=2, rays_per_object=32, max_ref_views=2, lr=3e-3,
                lr_warmup=1, log_every=1, ckpt_every=2, threads=1, pretrain_frac=0.5, seed=3)
    run_to_end(train(mcfg, TrainConfig(out_dir=str(tmp_path / "a"), **base)))
    killed = _as_killed_after(tmp_path / "a", 2, tmp_path / "b")
    capsys.readouterr()
    s = run_to_end(train(mcfg, TrainConfig(out_dir=str(killed), **{**base, "seed": 5})))
    assert s["resumed_from"] == 2 and "seed 5 is not used" in capsys.readouterr().err
    assert _same_weights(tmp_path / "a", killed)
    assert json.loads((killed / "config.json").read_text())["train"]["seed"] == 3
    meta = read_header_meta(find_checkpoint(killed / "checkpoints") / MODEL_FILE)
    assert json.loads(meta["train_config"])["seed"] == 3
    records = [json.loads(x) for x in (killed / "run_record.jsonl").read_text().splitlines()]
    assert [(r["start_step"], r["seed"], r["train_config"]["seed"]) for r in records] == [(0, 3, 3), (2, 3, 3)]


# ------------------------------------------------------------------------------------------- what a run records

def test_train_and_eval_record_what_repeating_them_needs(tmp_path, data):
    """config.json had the settings alone: no version or commit of the code, no library versions, no thread count
    actually used (threads 0 is every core but one: another number on another machine, and torch's CPU results
    depend on it), no command line and nothing that identifies the data beyond its path. eval.json named the
    checkpoint by a path (a run folder's newest checkpoint moves on). Now `run_record.jsonl` (one line a start),
    every checkpoint's `provenance` and eval.json's record them; two runs of one command give the same metrics,
    weights and eval.json but for its output path."""
    from blender_mrvm import __version__
    from blender_mrvm.cli import main

    cfg = {"model": {"preset": "fast", "overrides": TINY},
           "train": {"iterations": 2, "rays_per_object": 32, "objects_per_step": 2, "max_ref_views": 2,
                     "lr_warmup": 0, "ckpt_every": 1, "threads": 1, "seed": 4}}
    (tmp_path / "run.json").write_text(json.dumps(cfg))
    for r in ("r1", "r2"):
        assert main(["train", "--config", str(tmp_path / "run.json"), "--data", str(data), "--out",
                     str(tmp_path / r)]) == 0
    assert _same_weights(tmp_path / "r1", tmp_path / "r2")
    m1, m2 = ([{k: v for k, v in json.loads(x).items() if k != "time_s"}
               for x in (tmp_path / r / "metrics.jsonl").read_text().splitlines()] for r in ("r1", "r2"))
    assert m1 == m2
    (rec,) = [json.loads(x) for x in (tmp_path / "r1" / "run_record.jsonl").read_text().splitlines()]
    assert rec["blender_mrvm"] == __version__ and "commit" in rec and "modified" in rec
    assert rec["torch"] == torch.__version__ and rec["threads"] == 1 and rec["seed"] == 4
    assert rec["start_step"] == 0 and rec["argv"] and rec["time_utc"]
    assert rec["data"]["roots"] == [str(Path(data).resolve())] and rec["data"]["objects"] == 2
    rec2 = json.loads((tmp_path / "r2" / "run_record.jsonl").read_text())
    assert rec2["data"]["sha256"] == rec["data"]["sha256"] and len(rec["data"]["sha256"]) == 64
    meta = read_header_meta(find_checkpoint(tmp_path / "r1" / "checkpoints") / MODEL_FILE)
    assert json.loads(meta["provenance"])["data"]["sha256"] == rec["data"]["sha256"]
    # a fine-tune records which weights it started from ('shipped' names a file that changes with the package)
    assert main(["train", "--init", str(tmp_path / "r1"), "--data", str(data), "--out", str(tmp_path / "ft"),
                 "--iterations", "1"]) == 0
    from blender_mrvm.training.provenance import file_sha256

    init = json.loads((tmp_path / "ft" / "run_record.jsonl").read_text())["init_checkpoint"]
    start_file = find_checkpoint(tmp_path / "r1" / "checkpoints") / MODEL_FILE
    assert init == {"name": str(tmp_path / "r1"), "file": str(start_file.resolve()), "sha256": file_sha256(start_file)}

    for e in ("e1", "e2"):
        assert main(["eval", "--checkpoint", str(tmp_path / "r1"), "--data", str(data), "--input-views", "0,1",
                     "--no-lpips", "--out", str(tmp_path / e), "--threads", "1"]) == 0
    e1, e2 = (json.loads((tmp_path / e / "eval.json").read_text()) for e in ("e1", "e2"))
    for rep in (e1, e2):  # (the output folder is the one thing told apart)
        rep["provenance"]["argv"] = [a for a in rep["provenance"]["argv"] if not a.endswith(("e1", "e2"))]
        rep["provenance"]["settings"].pop("out")
    assert e1 == e2
    p = e1["provenance"]
    assert p["blender_mrvm"] == __version__ and p["threads"] == 1 and p["render_workers"] == 1
    assert p["settings"]["input_views"] == "0,1" and p["settings"]["no_lpips"] is True
    assert p["data"]["objects"] == 1 and len(p["data"]["sha256"]) == 64
    ck = e1["checkpoint"]
    assert ck["file"].endswith("step_0000002/model.safetensors") and len(ck["sha256"]) == 64


def test_a_run_started_over_drops_the_old_runs_record(tmp_path, data):
    """`--no-resume --force` removes what the old run wrote; its run_record.jsonl too (the new run's first line is
    then the record's first)."""
    from blender_mrvm.training.trainer import train

    mcfg = model_config("fast", TINY)
    base = dict(data=str(data), out_dir=str(tmp_path / "run"), iterations=1, objects_per_step=1, rays_per_object=16,
                max_ref_views=2, lr_warmup=0, threads=1)
    run_to_end(train(mcfg, TrainConfig(**base, seed=1)))
    run_to_end(train(mcfg, TrainConfig(**base, seed=2), resume=False, force=True))
    lines = [json.loads(x) for x in (tmp_path / "run" / "run_record.jsonl").read_text().splitlines()]
    assert [r["seed"] for r in lines] == [2]
