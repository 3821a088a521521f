"""Issue 14 fault tests: training resume after a damaged `latest`, a truncated checkpoint or trainer
state, a full disk (simulated ENOSPC), a NaN loss; metrics.jsonl without repeated steps; --no-resume
into a run; outputs a command owns; recover-poses continuing a failed run; plain progress lines in
logs; the panel never probing the worker from draw()."""

from __future__ import annotations

import errno
import hashlib
import io
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from blender_mrvm.training.synthetic import make_sphere_dataset
from tests.helpers import pycolmap_stages_in_this_process

torch.set_num_threads(1)

TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
        "sampler": {"n_coarse": 4, "n_fine": 2}}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_sphere_dataset(tmp_path_factory.mktemp("fault_ds"), n_objects=2, n_views=4, resolution=16, seed=3)


def config(tmp: Path, data: Path, **train) -> Path:
    doc = {"model": {"preset": "fast", "overrides": TINY},
           "train": {"data": str(data), "iterations": 6, "rays_per_object": 16, "max_ref_views": 2, "threads": 1,
                     "ckpt_every": 2, "log_every": 1, "keep_checkpoints": 3, "lr_warmup": 0, **train}}
    p = tmp / "run.json"
    p.write_text(json.dumps(doc))
    return p


def train(capsys, cfg: Path, run: Path, *extra) -> tuple[int, dict | None, str]:
    capsys.readouterr()
    code = main(["train", "--config", str(cfg), "--out", str(run), *map(str, extra)])
    cap = capsys.readouterr()
    lines = [ln for ln in cap.out.splitlines() if ln.startswith("{")]
    return code, (json.loads(lines[-1]) if lines else None), cap.err


def steps(run: Path) -> list[int]:
    return [json.loads(ln)["step"] for ln in (run / "metrics.jsonl").read_text().splitlines()]


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def finished(tmp_path_factory, data):
    """A finished 6-step run (checkpoints at 2, 4, 6) and the summary of the uninterrupted run."""
    tmp = tmp_path_factory.mktemp("fault_run")
    cfg = config(tmp, data)
    run = tmp / "run"
    assert main(["train", "--config", str(cfg), "--out", str(run)]) == 0
    summary = json.loads((run / "summary_rank0.json").read_text())
    return cfg, run, summary


def resumed_copy(finished, tmp_path, damage) -> tuple[Path, Path]:
    """A copy of the finished run cut back to step 6's predecessors by ``damage``, then resumed."""
    cfg, run, _ = finished
    r = tmp_path / "run"
    shutil.copytree(run, r)
    damage(r / "checkpoints")
    return cfg, r


@pytest.mark.parametrize("latest", ["", "\x00\x00garbage", "step_0099999\n", None])
def test_resume_ignores_a_damaged_latest(finished, tmp_path, capsys, latest):
    """`latest` empty, garbage, naming a deleted step or missing: the run resumes from its newest complete
    checkpoint (step 4 after step 6 is removed), never from step 0, and ends with the same weights."""
    def damage(ck):
        shutil.rmtree(ck / "step_0000006")
        if latest is None:
            (ck / "latest").unlink()
        else:
            (ck / "latest").write_text(latest)
    cfg, r = resumed_copy(finished, tmp_path, damage)
    before = digest(r / "checkpoints" / "step_0000004" / "model.safetensors")
    code, out, err = train(capsys, cfg, r)
    assert code == 0, err
    assert out["resumed_from"] == 4
    assert json.loads((r / "summary_rank0.json").read_text())["param_digest"] == finished[2]["param_digest"]
    assert digest(r / "checkpoints" / "step_0000004" / "model.safetensors") == before  # not rewritten
    assert steps(r) == [1, 2, 3, 4, 5, 6]  # no repeated steps after the resume


@pytest.mark.parametrize("what", ["model", "state", "state_garbage", "state_missing"])
def test_resume_skips_a_truncated_checkpoint(finished, tmp_path, capsys, what):
    """The newest checkpoint truncated (a full disk, a bad copy): a warning names it, training resumes
    from the one before it (step 4), and the uninterrupted run's weights come out."""
    def damage(ck):
        newest = ck / "step_0000006"
        if what == "model":
            p = newest / "model.safetensors"
            p.write_bytes(p.read_bytes()[:5000])
        elif what == "state":
            p = newest / "trainer_state.pt"
            p.write_bytes(p.read_bytes()[:300])
        elif what == "state_garbage":
            (newest / "trainer_state.pt").write_bytes(b"\x80\x04garbage" * 10)
        else:
            (newest / "trainer_state.pt").unlink()
    cfg, r = resumed_copy(finished, tmp_path, damage)
    code, out, err = train(capsys, cfg, r)
    assert code == 0, err
    assert "warning: skipped damaged checkpoint(s) step_0000006" in err and "resuming from step_0000004" in err
    assert out["resumed_from"] == 4
    assert json.loads((r / "summary_rank0.json").read_text())["param_digest"] == finished[2]["param_digest"]


def test_all_checkpoints_damaged_refuses_then_force_starts_over(finished, tmp_path, capsys):
    def damage(ck):
        for p in ck.glob("step_*/trainer_state.pt"):
            p.write_bytes(b"")
    cfg, r = resumed_copy(finished, tmp_path, damage)
    hashes = {p: digest(p) for p in r.rglob("*") if p.is_file()}
    code, out, err = train(capsys, cfg, r)
    assert code == 2 and "has no complete checkpoint to resume from" in error_line(err)
    assert {p: digest(p) for p in r.rglob("*") if p.is_file()} == hashes  # nothing overwritten
    code, out, err = train(capsys, cfg, r, "--no-resume", "--force")
    assert code == 0 and out["resumed_from"] == 0, err
    assert steps(r) == [1, 2, 3, 4, 5, 6]


def test_no_resume_into_a_run_needs_force(finished, tmp_path, capsys):
    cfg, run, _ = finished
    r = tmp_path / "run"
    shutil.copytree(run, r)
    (r / "notes.txt").write_text("the user's")
    hashes = {p: digest(p) for p in r.rglob("*") if p.is_file()}
    code, _, err = train(capsys, cfg, r, "--no-resume")
    assert code == 2 and "holds a run (checkpoints up to step 6)" in error_line(err)
    assert {p: digest(p) for p in r.rglob("*") if p.is_file()} == hashes
    cfg2 = config(tmp_path, Path(json.loads(cfg.read_text())["train"]["data"]), iterations=2)
    code, out, err = train(capsys, cfg2, r, "--no-resume", "--force")
    assert code == 0, err
    # the old run is gone (no step_4/step_6 beside the new run's step 2), the user's file stays
    assert sorted(p.name for p in (r / "checkpoints").glob("step_*")) == ["step_0000002"]
    assert (r / "notes.txt").read_text() == "the user's" and steps(r) == [1, 2]


def test_full_disk_during_training(data, tmp_path, capsys, monkeypatch):
    """ENOSPC while writing the step-4 checkpoint: one error line, exit 2, step 2 intact, no temporary
    folder left; a torn metrics line is dropped on resume, which then ends like an uninterrupted run."""
    import safetensors.torch as st

    cfg = config(tmp_path, data)
    run = tmp_path / "run"
    real = st.save_model

    def full_disk(model, filename, metadata=None):
        if "step_0000004" in filename:
            raise OSError(errno.ENOSPC, "No space left on device", filename)
        return real(model, filename, metadata=metadata)

    monkeypatch.setattr(st, "save_model", full_disk)
    code, _, err = train(capsys, cfg, run)
    line = error_line(err)
    assert code == 2 and "No space left on device" in line and "what was finished before is kept" in line
    names = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert names == ["latest", "step_0000002"], names
    with open(run / "metrics.jsonl", "a") as f:
        f.write('{"step": 5, "loss": 0.')  # a torn line, as a full disk leaves
    monkeypatch.setattr(st, "save_model", real)
    code, out, err = train(capsys, cfg, run)
    assert code == 0 and out["resumed_from"] == 2, err
    assert steps(run) == [1, 2, 3, 4, 5, 6]


def test_nan_loss_stops_naming_the_step(data, tmp_path, capsys, monkeypatch):
    from blender_mrvm.training import trainer

    real = trainer.RayBatcher.draw
    calls = {"n": 0}

    def draw(self, bbox_phase, n_refs=None):
        b = real(self, bbox_phase, n_refs)
        calls["n"] += 1
        if calls["n"] > 6:  # steps 1-3 are fine (2 objects per step), step 4 sees NaN images
            b["gt"] = torch.full_like(b["gt"], float("nan"))
        return b

    monkeypatch.setattr(trainer.RayBatcher, "draw", draw)
    run = tmp_path / "run"
    code, _, err = train(capsys, config(tmp_path, data), run)
    line = error_line(err)
    assert code == 2 and "training stopped at step 4: the loss is nan" in line
    assert "the last checkpoint (step_0000002) is kept" in line
    assert sorted(p.name for p in (run / "checkpoints").glob("step_*")) == ["step_0000002"]


def test_half_rendered_dataset_is_refused_and_split_typos(data, tmp_path, capsys):
    half = tmp_path / "half"
    shutil.copytree(data, half)
    meta = half / "spheres" / "obj000" / "meta.json"
    meta.write_text(json.dumps({**json.loads(meta.read_text()), "complete": False}))
    code, _, err = train(capsys, config(tmp_path, half), tmp_path / "run")
    assert code == 2 and "half-rendered: 1 of 1 objects of split 'train'" in error_line(err)
    assert not (tmp_path / "run").exists()
    # evaluation refuses it too, before loading a model or writing anything
    from blender_mrvm.cli import main

    capsys.readouterr()
    code = main(["eval", "--data", str(half), "--split", "train", "--input-views", "0", "--no-lpips",
                 "--out", str(tmp_path / "ev"), "--threads", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "half-rendered" in error_line(err) and not (tmp_path / "ev").exists()


# ------------------------------------------------------------------------------------------ outputs

def test_demo_reruns_into_its_own_folder_but_never_over_a_users_file(tmp_path):
    from blender_mrvm.commands.demo import demo_folder
    from blender_mrvm.errors import OutputError

    out = tmp_path / "demo_out"
    f = demo_folder(out)
    f.check()  # new folder
    f.claim()
    (out / "contact_sheet.png").write_bytes(b"sheet v1")
    f.wrote("contact_sheet.png")
    (out / "dataset").mkdir()
    demo_folder(out).check()  # a rerun: only the demo's own, unchanged files
    (out / "scene.blend").write_bytes(b"the user's scene")  # not written by the demo
    with pytest.raises(OutputError, match="was changed since|did not write"):
        demo_folder(out).check()
    (out / "scene.blend").unlink()
    (out / "contact_sheet.png").write_bytes(b"edited")
    with pytest.raises(OutputError, match="changed since this command wrote it"):
        demo_folder(out).check()
    demo_folder(out).check(force=True)


def test_contact_sheet_force_replaces_and_plain_run_writes(tmp_path, data, capsys):
    out = tmp_path / "sheet.png"
    assert main(["contact-sheet", "--dataset", str(data), "--out", str(out)]) == 0
    first = digest(out)
    capsys.readouterr()
    assert main(["contact-sheet", "--dataset", str(data), "--out", str(out), "--views", "2"]) == 2
    assert "already exists; pass --force" in error_line(capsys.readouterr().err) and digest(out) == first
    assert main(["contact-sheet", "--dataset", str(data), "--out", str(out), "--views", "2", "--force"]) == 0
    assert digest(out) != first


def test_recover_poses_continues_an_unfinished_run(tmp_path):
    """A failed or killed run leaves colmap/ (no meta.json): the rerun goes on without --force; a folder
    holding a finished capture or anything else still needs it. (The stages themselves:
    test_recover_poses_resumes_finished_stages.)"""
    from blender_mrvm.capture.sfm import prepare_output
    from blender_mrvm.errors import OutputError

    photos = tmp_path / "photos"
    photos.mkdir()
    out = tmp_path / "cap"
    (out / "colmap").mkdir(parents=True)
    (out / "colmap" / "database.db").write_bytes(b"partial")
    (out / "rgb").mkdir()
    with pytest.raises(OutputError, match=r"already holds files \(colmap, rgb\)"):
        prepare_output(out, photos, force=False)  # files of our names alone are not a run of ours (session 52)
    from blender_mrvm.capture.export import RUN_MARKER

    (out / RUN_MARKER).write_text("")  # what a run writes first
    prepare_output(out, photos, force=False)  # continues: colmap/ is left to the stage log, the rest redone
    assert (out / "colmap" / "database.db").is_file() and not (out / "rgb").exists()
    from blender_mrvm.capture.sfm import StageLog

    StageLog(out / "colmap", {"any": "stamp"})  # no log of finished stages: colmap/ starts afresh
    assert sorted(p.name for p in (out / "colmap").iterdir()) == ["stages.json"]
    (out / "rgb").mkdir()
    (out / "meta.json").write_text("{}")
    with pytest.raises(OutputError, match="already holds files"):
        prepare_output(out, photos, force=False)
    (out / "meta.json").unlink()
    (out / "mine.txt").write_text("x")
    with pytest.raises(OutputError, match="already holds files"):
        prepare_output(out, photos, force=False)
    assert (out / "mine.txt").read_text() == "x"


# ------------------------------------------------------------------------------------------ progress

def test_plain_progress_lines_when_output_is_not_a_terminal(monkeypatch):
    """tqdm prints nothing to a file or a pipe; there the CLI prints plain lines (an eval run of 13
    minutes left an empty log before)."""
    import sys

    from blender_mrvm import progress as P

    def gen():
        for i in range(40):
            yield P.Progress(i + 1, 40, f"view {i + 1}")
        return "result"

    buf = io.StringIO()
    monkeypatch.setattr(sys, "stderr", buf)
    monkeypatch.delenv("TQDM_DISABLE", raising=False)
    monkeypatch.delenv(P.PROGRESS_ENV, raising=False)
    assert P.run_with_tqdm(gen(), desc="eval", unit="view") == "result"
    lines = buf.getvalue().splitlines()
    assert lines[0].startswith("eval: 1/40 view (2%) view 1")
    assert 10 <= len(lines) <= 13 and lines[-1].startswith("eval: 40/40 view (100%)") and lines[-1].endswith("(done)")
    buf.truncate(0)
    monkeypatch.setenv("TQDM_DISABLE", "1")
    assert P.run_with_tqdm(gen(), desc="eval") == "result" and buf.getvalue() == ""


# ------------------------------------------------------------------------------------------ panel

def test_panels_never_probe_the_worker_from_draw(empty_scene, monkeypatch):
    """draw() reads the cached dependency report; the probe (a subprocess, up to 30 s) runs at register
    time, on a preference change and from Check Again only."""
    import subprocess

    import bpy

    from blender_mrvm import prefs as P
    from blender_mrvm import worker as W
    from blender_mrvm.panels.novel_views import MRVM_PT_model, MRVM_PT_novel_views

    def no_process(*a, **k):
        raise AssertionError("draw() started a process")

    import threading

    for th in threading.enumerate():  # the register-time probe, if it is still running
        if th.name == "mrvm-dependency-probe":
            th.join(60)
    P._status.clear()
    W.clear_probe_cache()
    monkeypatch.setattr(subprocess, "run", no_process)
    monkeypatch.setattr(subprocess, "Popen", no_process)
    import types

    from tests.test_novel_views import _draw

    ctx = bpy.context
    for cls in (MRVM_PT_model, MRVM_PT_novel_views):
        _draw(cls)
    _draw(P.MRVM_AddonPreferences, types.SimpleNamespace(device="AUTO", checkpoint_dir=""))
    rep = P.dependency_status(ctx, cached=True)
    assert rep.pending and rep.lines() == [("Checking the worker Python...", True)]
    monkeypatch.undo()
    P.refresh_dependency_status(ctx)  # what Check Again does
    assert not P.dependency_status(ctx, cached=True).pending


def test_recover_poses_resumes_finished_stages(ring, tmp_path, monkeypatch, capsys):
    """A run killed after matching: the rerun (no --force) restores the database as matching left it
    and goes on from mapping, with the result of an uninterrupted run; other settings start afresh."""
    import pycolmap

    from blender_mrvm.capture import sfm
    from blender_mrvm.capture.config import CaptureConfig

    photos = tmp_path / "photos"
    photos.mkdir()
    for p in sorted(ring[0].iterdir())[:8]:
        shutil.copy(p, photos / p.name)
    cfg = CaptureConfig(num_threads=2, single_camera=True)
    out = tmp_path / "cap"
    gen = sfm.recover_poses(photos, out, cfg)
    for ev in gen:  # killed once matching is done
        if ev.done >= sfm._STAGE_END["match"]:
            break
    gen.close()
    log = json.loads((out / "colmap" / "stages.json").read_text())
    assert log["done"] == ["extract", "match"] and not (out / "meta.json").exists()

    def not_again(*a, **k):
        raise AssertionError("a finished stage ran again")

    pycolmap_stages_in_this_process(monkeypatch)  # (where the patch below reaches matching)
    for name in ("extract_features", "match_exhaustive", "match_sequential"):
        monkeypatch.setattr(pycolmap, name, not_again)
    capsys.readouterr()
    assert main(["recover-poses", "--images", str(photos), "--out", str(out), "--threads", "2",
                 "--single-camera"]) == 0, capsys.readouterr().err
    resumed = json.loads((out / "meta.json").read_text())
    assert resumed["registered"] == 8 and not list((out / "colmap").glob("database.*.db"))
    monkeypatch.undo()
    # As accurate as an uninterrupted run (test_capture.py's bound; COLMAP's multi-threaded mapping is not
    # bit-identical from run to run, so the poses are compared with the truth, not with another run).
    from blender_mrvm.capture import align

    frames = json.loads((out / "transforms.json").read_text())["frames"]
    truth = {v["name"]: np.array(v["c2w_opencv"]) for v in ring[1]["views"]}
    got = [F.read_srn_pose(out / "pose" / f"{i:06d}.txt") for i in range(len(frames))]
    err = align.pose_errors(got, [truth[f["original_name"]] for f in frames])
    assert err.median_rotation_deg < 0.5 and err.median_centre < 0.01 * ring[1]["radius"]
    # Other settings: the stages are not reused (the log's stamp differs), colmap/ starts afresh.
    st = sfm.StageLog(out / "colmap", sfm.run_stamp(photos, sorted(p.name for p in photos.iterdir()),
                                                    CaptureConfig(max_num_features=1024)))
    assert st.done == set() and sorted(p.name for p in (out / "colmap").iterdir()) == ["stages.json"]

