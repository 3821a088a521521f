"""One process at a time in an output folder (guards.output_lock), what killed runs leave, full disks that
surface as other errors, long names, and a checkpoint pruned under a reader.

A second command is tested against a lock this test process holds (not by racing two processes)."""

from __future__ import annotations

import errno
import fcntl
import os
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from tests.test_faults import config, data  # noqa: F401  (the fault tests' tiny run and its data fixture)

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def run(tmp_path_factory, data):
    tmp = tmp_path_factory.mktemp("lock_run")
    r = tmp / "run"
    assert main(["train", "--config", str(config(tmp, data)), "--out", str(r)]) == 0
    return r


@contextmanager
def held(folder: Path):
    """Hold ``folder`` as another process's command would."""
    folder.mkdir(parents=True, exist_ok=True)
    fd = os.open(folder / ".lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.write(fd, b"4242\n")
        yield
    finally:
        os.close(fd)


def error_line(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def refused(capsys, argv: list[str], folder: Path) -> None:
    capsys.readouterr()
    with held(folder):
        code = main(argv)
    line = error_line(capsys.readouterr().err)
    assert code == 2 and "in use by another process (pid 4242)" in line, line


def test_train_into_a_held_run_folder_is_refused(data, run, tmp_path, capsys):
    import shutil

    r = tmp_path / "run"
    shutil.copytree(run, r)
    before = sorted(p.name for p in (r / "checkpoints").iterdir())
    metrics = (r / "metrics.jsonl").read_text()
    refused(capsys, ["train", "--config", str(config(tmp_path, data, iterations=8)), "--out", str(r)], r)
    assert sorted(p.name for p in (r / "checkpoints").iterdir()) == before
    assert (r / "metrics.jsonl").read_text() == metrics
    fresh = tmp_path / "new"
    refused(capsys, ["train", "--config", str(config(tmp_path, data)), "--out", str(fresh)], fresh)
    assert not (fresh / "checkpoints").exists() and not (fresh / "metrics.jsonl").exists()


def test_a_save_killed_half_way_is_swept_when_the_run_starts(data, tmp_path, capsys):
    r = tmp_path / "run"
    stale = r / "checkpoints" / ".step_0000002.k1ll3d"
    stale.mkdir(parents=True)
    (stale / "model.safetensors").write_bytes(b"half")
    assert main(["train", "--config", str(config(tmp_path, data, iterations=2)), "--out", str(r)]) == 0
    assert sorted(p.name for p in (r / "checkpoints").iterdir()) == ["latest", "step_0000002"]
    assert not (r / ".lock").exists()


def test_recover_poses_into_a_held_folder_is_refused(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    out = tmp_path / "cap"
    refused(capsys, ["recover-poses", "--images", str(photos), "--out", str(out), "--threads", "1"], out)
    assert [p.name for p in out.iterdir()] == [".lock"]  # (the test's own)


def test_synthesize_and_eval_into_a_held_folder_are_refused(data, run, tmp_path, capsys):
    ref = next(p for p in sorted(Path(data).rglob("*")) if (p / "meta.json").is_file() or (p / "pose").is_dir())
    syn = ["synthesize", "--references", str(ref), "--views", "0", "1", "--checkpoint", str(run), "--orbit", "2",
           "--orbit-size", "16", "--threads", "1", "--out"]
    out = tmp_path / "syn"
    refused(capsys, [*syn, str(out)], out)
    assert [p.name for p in out.iterdir()] == [".lock"]
    ev = ["eval", "--checkpoint", str(run), "--data", str(data), "--split", "train", "--input-views", "0",
          "--no-lpips", "--threads", "1", "--max-targets", "1", "--out"]
    eo = tmp_path / "ev"
    refused(capsys, [*ev, str(eo)], eo)
    assert [p.name for p in eo.iterdir()] == [".lock"]
    # what a killed synthesis left in its folder goes with the next run; nothing of the lock stays
    (out / ".lock").unlink()
    (out / ".mrvm-partial-k1ll3d").mkdir()
    (out / ".mrvm-partial-k1ll3d" / "000000.png").write_bytes(b"x")
    assert main([*syn, str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["rgb", "synthesis.json", "targets.json"]
    # an --out linked to another file system: the temporary folder is built where the link points
    shm = Path("/dev/shm")
    if shm.is_dir() and os.access(shm, os.W_OK) and shm.stat().st_dev != tmp_path.stat().st_dev:
        import tempfile

        with tempfile.TemporaryDirectory(dir=shm) as target:
            link = tmp_path / "link"
            link.symlink_to(target)
            assert main([*syn, str(link)]) == 0
            assert sorted(p.name for p in Path(target, "rgb").iterdir()) == ["000000.png", "000001.png"]


def test_load_model_picks_again_when_a_training_prunes_its_pick(run, tmp_path, monkeypatch):
    import shutil

    from blender_mrvm.training import checkpoint as ck

    r = tmp_path / "run"
    shutil.copytree(run, r)
    real, calls = ck.checked_header, []

    def pruned_first(path):
        calls.append(path)
        if len(calls) == 1:  # a training's keep_checkpoints prunes the pick before it is opened
            picked = ck.find_checkpoint(path)
            shutil.rmtree(picked)
            return real(picked / ck.MODEL_FILE)
        return real(path)

    monkeypatch.setattr(ck, "checked_header", pruned_first)
    _, _, meta = ck.load_model(r)
    assert meta["step"] == "4" and len(calls) == 2


def test_full_disk_errors_raised_as_other_errors_are_one_line(data, tmp_path, capsys, monkeypatch):
    """torch.save's zip writer on a full disk raises RuntimeError ('unexpected pos'); the EXR writer a
    RuntimeError('... No space left on device'): both are the CLI's one-line disk error, checkpoints whole."""
    real_save, real_statvfs = torch.save, os.statvfs

    def full(obj, f, *a, **k):
        if "step_0000004" in str(f):
            raise RuntimeError("[enforce fail at inline_container.cc:626] . unexpected pos 1088 vs 1010")
        return real_save(obj, f, *a, **k)

    class Full:
        f_bavail = 0

    monkeypatch.setattr(torch, "save", full)
    monkeypatch.setattr(os, "statvfs", lambda p: Full() if "step_0000004" in str(p) else real_statvfs(p))
    r = tmp_path / "run"
    capsys.readouterr()
    code = main(["train", "--config", str(config(tmp_path, data)), "--out", str(r)])
    line = error_line(capsys.readouterr().err)
    assert code == 2 and "No space left on device" in line, line
    assert sorted(p.name for p in (r / "checkpoints").iterdir()) == ["latest", "step_0000002"]

    import numpy as np
    import OpenEXR

    class NoSpace:
        def __init__(self, *a, **k):
            pass

        def __enter__(self):
            return self

        def __exit__(self, *a):
            return False

        def write(self, path):
            raise RuntimeError(f"Cannot write image file \"{path}\". No space left on device")

    monkeypatch.setattr(OpenEXR, "File", NoSpace)
    with pytest.raises(OSError) as e:
        F.write_exr(tmp_path / "d.exr", {"Y": np.zeros((2, 2), np.float32)})
    assert e.value.errno == errno.ENOSPC and not list(tmp_path.glob(".d.exr*"))


def test_long_names(tmp_path, capsys):
    from blender_mrvm.cli import os_error_message

    name = "a" * 250 + ".json"  # legal (255 bytes): its temporary name must be too
    F.atomic_write_text(tmp_path / name, "{}")
    assert (tmp_path / name).read_text() == "{}"
    line = os_error_message(OSError(errno.ENAMETOOLONG, "File name too long", "b" * 300))
    assert line and "shorter name" in line


def test_a_long_blend_name_is_refused_before_any_view(data, run, tmp_path, capsys):
    pytest.importorskip("bpy")
    ref = next(p for p in sorted(Path(data).rglob("*")) if (p / "meta.json").is_file() or (p / "pose").is_dir())
    out = tmp_path / "syn"
    capsys.readouterr()
    code = main(["synthesize", "--references", str(ref), "--views", "0", "1", "--checkpoint", str(run), "--orbit",
                 "2", "--orbit-size", "16", "--threads", "1", "--out", str(out),
                 "--blend", str(tmp_path / ("x" * 246 + ".blend"))])
    line = error_line(capsys.readouterr().err)
    assert code == 2 and "--blend" in line and "255" in line, line
    assert not out.exists()


def test_temporary_blends_of_killed_runs_are_removed(tmp_path):
    pytest.importorskip("bpy")
    from blender_mrvm.scene.novel_views import _remove_dead_partials

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    dead = tmp_path / f".mrvm-partial-{p.pid}.blend"
    dead.write_bytes(b"x")
    Path(str(dead) + "1").write_bytes(b"x")
    alive = tmp_path / f".mrvm-partial-{os.getppid()}.blend"
    alive.write_bytes(b"x")
    _remove_dead_partials(tmp_path)
    assert sorted(q.name for q in tmp_path.iterdir()) == [alive.name]


@pytest.mark.parametrize("exc", [RuntimeError("DefaultCPUAllocator: can't allocate memory: you tried to allocate "
                                              "17179869184 bytes. Error code 12 (Cannot allocate memory)"),
                                 MemoryError("Unable to allocate 16.0 GiB for an array")])
def test_out_of_memory_is_one_line(exc, monkeypatch, capsys):
    """``synthesize --chunk 65536`` of a 256 px orbit on a smaller machine ended in torch's allocator traceback
    (exit 1): running out of memory is one line naming what to lower, exit 2; other errors keep their traceback."""
    from blender_mrvm import cli
    from blender_mrvm.commands import contact_sheet

    def boom(args):
        raise exc

    monkeypatch.setattr(contact_sheet, "run", boom)
    rc = cli.main(["contact-sheet", "--dataset", "d", "--out", "s.png"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("error: out of memory on this machine") and "--chunk" in err[0]
    monkeypatch.setattr(contact_sheet, "run", lambda args: (_ for _ in ()).throw(RuntimeError("a bug")))
    with pytest.raises(RuntimeError, match="a bug"):
        cli.main(["contact-sheet", "--dataset", "d", "--out", "s.png"])


def test_torchrun_ranks_print_a_bad_input_once(monkeypatch, capsys):
    """Under torchrun every rank finds the same bad argument: the error line was printed once a rank (3 times with
    3 ranks), and Ctrl-C said 'finished work is kept' twice though the steps since the last checkpoint are lost
    there. Rank 0 prints them, once, saying what is kept; other errors are printed by the rank that has them."""
    from blender_mrvm import cli
    from blender_mrvm.commands import contact_sheet
    from blender_mrvm.errors import InputError, TrainingStopped

    def raising(exc):
        def run(args):
            raise exc
        return run

    argv = ["contact-sheet", "--dataset", "d", "--out", "s.png"]
    for rank, printed in (("0", 1), ("1", 0)):
        monkeypatch.setenv("RANK", rank)
        monkeypatch.setenv("WORLD_SIZE", "2")
        monkeypatch.setattr(contact_sheet, "run", raising(InputError("no dataset")))
        assert cli.main(argv) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == printed
        monkeypatch.setattr(contact_sheet, "run", raising(KeyboardInterrupt()))
        assert cli.main(argv) == 130
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == printed and (not printed or "steps since the last one are not" in err[0]), err
        monkeypatch.setattr(contact_sheet, "run", raising(TrainingStopped("loss is NaN")))
        cli.main(argv)
        assert len(capsys.readouterr().err.strip().splitlines()) == 1  # (what one rank alone may meet)


def test_out_of_memory_in_train_names_what_train_can_lower(monkeypatch, capsys, tmp_path):
    """train ran out of memory holding an object's 24 views of 4000 px (session 55's review of large inputs) and the
    line named --chunk and 'the reference size', which train does not have: it names what lowers train's memory."""
    from blender_mrvm import cli
    from blender_mrvm.commands import train

    def boom(args):
        raise MemoryError("Unable to allocate 4.29 GiB for an array")

    monkeypatch.setattr(train, "run", boom)
    assert cli.main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "r")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("error: out of memory on this machine") and "--chunk" not in line
    assert "render-dataset --resolution" in line and "train.objects_per_step" in line
