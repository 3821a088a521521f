"""The worker process runner: JSON progress from the CLI, a real child command streaming events,
cancel (child gone, finished views kept), errors as one line, interpreter choice and dependency probe.
No bpy in this process: the child (render-dataset) imports Blender itself."""

from __future__ import annotations

import json
import os
import sys
import time
import venv
from pathlib import Path

import pytest

from blender_mrvm import worker as W
from blender_mrvm.errors import Cancelled, InputError
from blender_mrvm.progress import Progress, run_with_tqdm

ROOT = Path(__file__).resolve().parents[1]
RENDER = ["--source", "procedural:chair:0", "--resolution", "16", "--engine", "BLENDER_WORKBENCH"]
ENV = {"OMP_NUM_THREADS": "1"}


def _gen(n):
    for i in range(n):
        yield Progress(i + 1, n, f"step {i + 1}")
    return "result"


def test_run_with_tqdm_json_mode(monkeypatch, capsys):
    monkeypatch.setenv("MRVM_PROGRESS", "json")
    assert run_with_tqdm(_gen(3), desc="d") == "result"
    lines = capsys.readouterr().out.splitlines()
    assert [json.loads(ln) for ln in lines] == [
        {"mrvm": "progress", "done": i, "total": 3, "message": f"step {i}", "skipped": 0, "desc": "d"} for i in (1, 2, 3)]
    assert [W.parse_progress(ln) for ln in lines] == [Progress(i, 3, f"step {i}") for i in (1, 2, 3)]
    monkeypatch.delenv("MRVM_PROGRESS")
    assert run_with_tqdm(_gen(3), disable=True) == "result"
    assert capsys.readouterr().out == "", "without the variable nothing goes to stdout (tqdm writes to stderr)"


@pytest.mark.skipif(os.name != "posix", reason="SIGINT to this process")
def test_between_units_ctrl_c_finishes_the_unit_then_a_second_stops_at_once(monkeypatch, capsys):
    """``run_with_tqdm(between_units=True)``: a Ctrl-C during unit 2 lets it finish and closes the work at its
    event (where it can save), announced on stderr; a second Ctrl-C during the next unit stops it there; the
    SIGINT handler is restored afterwards either way."""
    import signal

    monkeypatch.delenv("MRVM_PROGRESS", raising=False)
    # Ctrl-C as a terminal has it: a process started in the background (`cmd &`, as CI may run) inherits SIGINT
    # ignored, and Python then leaves it so; the second Ctrl-C would go back to "ignored" and never stop the work
    inherited = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        _ctrl_c_twice(signal, capsys)
    finally:
        signal.signal(signal.SIGINT, inherited)


def _ctrl_c_twice(signal, capsys):
    before = signal.getsignal(signal.SIGINT)
    log: list = []

    def work(signals_in: dict):
        try:
            for i in range(1, 6):
                for _ in range(signals_in.get(i, 0)):
                    os.kill(os.getpid(), signal.SIGINT)
                log.append(f"unit {i} finished")
                yield Progress(i, 5)
        except GeneratorExit:
            log.append("closed at its event")
            raise

    with pytest.raises(KeyboardInterrupt):
        run_with_tqdm(work({2: 1}), desc="train", unit="step", disable=True, between_units=True)
    assert log == ["unit 1 finished", "unit 2 finished", "closed at its event"]
    assert "train: stopping after the step in progress (Ctrl-C again to stop at once)" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is before
    log.clear()
    with pytest.raises(KeyboardInterrupt):
        run_with_tqdm(work({3: 2}), desc="train", unit="step", disable=True, between_units=True)
    assert log == ["unit 1 finished", "unit 2 finished"]  # unit 3 was cut by the second Ctrl-C
    assert signal.getsignal(signal.SIGINT) is before
    assert run_with_tqdm(work({}), disable=True, between_units=True) is None and len(log) == 7


def test_parse_progress_and_error_lines():
    ev = '{"mrvm": "progress", "done": 2, "total": 5, "message": "m", "skipped": 1, "desc": ""}'
    assert W.parse_progress(ev) == Progress(2, 5, "m", 1)
    assert W.parse_progress("Fra:1 Mem:12M " + ev) == Progress(2, 5, "m", 1)  # Blender's log on the same line
    for other in ("wrote out.png", '{"a": 1}', '{"mrvm": "result"}', '{"mrvm": "progress", "done": "x"}', "{"):
        assert W.parse_progress(other) is None
    py = "/opt/py/bin/python"
    assert W.error_message(2, ["Traceback", "error: first", "noise", "error: the real one"], py) == "the real one"
    msg = W.error_message(1, ["Traceback (most recent call last):", "  ...", "ModuleNotFoundError: No module named 'torch'"], py)
    assert msg == f'torch is missing in the worker Python {py}; install with: "{py}" -m pip install "torch==2.13.0"'
    # a crash (no error: line) had read "worker failed (exit code 1): <the traceback's last line>", its traceback lost
    assert W.error_message(-9, ["", "Killed", ""], py) == (
        "the worker was stopped by SIGKILL (the system may have run out of memory: lower the sizes, or close other "
        "programs); its last output is in the system console (Killed)")
    assert W.error_message(1, ["ValueError: x"], py) == (
        "unexpected error in the worker, a bug (exit code 1: ValueError: x); its last output is in the system console")


def test_child_streams_progress_and_finishes(tmp_path):
    out = tmp_path / "ds"
    events = []
    gen = W.run_worker("render-dataset", [*RENDER, "--views", "3", "--out", out], sys.executable, env=ENV)
    while True:
        try:
            events.append(next(gen))
        except StopIteration as stop:
            res = stop.value
            break
    assert res.returncode == 0 and res.events == 4  # the child's "starting" + one per view
    # Events that arrive within one poll interval are coalesced into the latest (a UI tick shows one).
    seen = [(e.done, e.total) for e in events]
    assert seen[0] == (0, 0) and seen[-1] == (3, 3) and seen == sorted(seen)
    assert all(e.message for e in events)
    assert any("3 views rendered" in ln for ln in res.output)
    assert len(list((out / "chair" / "chair_000000" / "rgb").glob("*.png"))) == 3


def _long_render_past_two_views(out, procs: list, grace_s: float):
    """A worker rendering 400 views, advanced until two are done."""
    gen = W.run_worker("render-dataset", [*RENDER, "--views", "400", "--out", out], sys.executable, env=ENV,
                       on_start=procs.append, grace_s=grace_s)
    t0 = time.monotonic()
    for ev in gen:
        if ev.done >= 2:
            return gen
        assert time.monotonic() - t0 < 60, "no progress from the child"
    raise AssertionError("the child ended before two views")


def test_cancel_stops_the_child_and_keeps_finished_views(tmp_path):
    out = tmp_path / "ds"
    procs = []
    gen = _long_render_past_two_views(out, procs, 10.0)
    t1 = time.monotonic()
    gen.close()
    (proc,) = procs
    assert proc.poll() is not None, "the child still runs after cancel"
    assert time.monotonic() - t1 < 10.0
    assert proc.returncode == 130, "SIGINT: the CLI closed its generator and exited as interrupted (not killed)"
    obj = out / "chair" / "chair_000000"
    done = sorted(p.name for p in (obj / "pose").glob("*.txt"))
    assert 2 <= len(done) < 400, "finished views are kept, the rest was not rendered"
    for i in range(len(done)):  # every committed view is complete, no temp files left behind
        assert all((obj / k / f"{i:06d}{ext}").is_file() for k, ext in
                   (("rgb", ".png"), ("depth", ".exr"), ("normal", ".exr"), ("mask", ".png"), ("pose", ".txt")))
    assert not [p for p in obj.rglob(".*") if p.is_file()]


def test_an_interrupt_sent_in_stops_the_child_without_blocking(tmp_path):
    """Esc on a panel job closed the generator, which waited for the child (up to 37 s for Train: its grace to save
    the step in progress) with Blender's UI frozen. INTERRUPT sent into the generator interrupts the child and
    returns at once; the generator goes on yielding while the child winds down, then raises Cancelled, and the
    child has exited as interrupted, keeping its finished views."""
    out = tmp_path / "ds"
    procs = []
    gen = _long_render_past_two_views(out, procs, 20.0)
    t1 = time.monotonic()
    ev = gen.send(W.INTERRUPT)
    assert time.monotonic() - t1 < 1.0, "the send returned at once"
    (proc,) = procs
    ticks = 0
    with pytest.raises(Cancelled, match="interrupted"):
        while True:
            ev = next(gen)
            ticks += 1
            assert "Esc again stops at once" in ev.message or proc.poll() is not None
            assert time.monotonic() - t1 < 30
    assert proc.returncode == 130, "SIGINT: the CLI closed its work and exited as interrupted (not killed)"
    done = sorted(p.name for p in (out / "chair" / "chair_000000" / "pose").glob("*.txt"))
    assert 2 <= len(done) < 400


def _worker_ignoring_sigint(tmp_path, monkeypatch, grace_s: float):
    """A worker run whose child ignores SIGINT (as one winding down does), started and past its handler's set-up:
    (the generator, [its Popen])."""
    script = tmp_path / "stubborn.py"
    script.write_text("import signal, time\nsignal.signal(signal.SIGINT, signal.SIG_IGN)\nprint('up', flush=True)\n"
                      "time.sleep(60)\n")
    monkeypatch.setattr(W, "worker_argv", lambda python, command, args: [python, str(script)])
    procs = []
    gen = W.run_worker("x", [], sys.executable, env=ENV, on_start=procs.append, grace_s=grace_s)
    next(gen)
    time.sleep(1.5)  # the child has set its signal handler
    return gen, procs


def test_a_child_that_ignores_the_interrupt_is_terminated_after_the_grace(tmp_path, monkeypatch):
    """A worker that does not wind down is terminated past the grace time, still without blocking the caller."""
    gen, (proc,) = _worker_ignoring_sigint(tmp_path, monkeypatch, 0.5)
    t1 = time.monotonic()
    gen.send(W.INTERRUPT)
    assert time.monotonic() - t1 < 1.0
    with pytest.raises((Cancelled, W.WorkerError)):
        for _ in gen:
            assert time.monotonic() - t1 < 15
    assert proc.poll() is not None


def test_esc_again_after_an_interrupt_stops_the_child_at_once(tmp_path, monkeypatch):
    """Esc again (the generator closed after INTERRUPT was sent in: 'Esc again stops at once') sent SIGINT a second
    time and waited the whole grace for it, which a winding-down child ignores (the CLI's sigint_flag), with
    Blender's UI frozen (up to 30 s for Train): it terminates the child at once."""
    gen, procs = _worker_ignoring_sigint(tmp_path, monkeypatch, 20.0)
    gen.send(W.INTERRUPT)
    next(gen)
    t1 = time.monotonic()
    gen.close()
    assert time.monotonic() - t1 < 5.0, "Esc again waited for the grace"
    assert procs[0].poll() is not None


def test_child_error_is_one_line(tmp_path):
    gen = W.run_worker("render-dataset", ["--source", str(tmp_path / "nothing.obj"), "--out", tmp_path / "o"],
                       sys.executable, env=ENV)
    with pytest.raises(W.WorkerError) as ei:
        for _ in gen:
            pass
    assert str(ei.value) == f"mesh file or folder not found: {tmp_path / 'nothing.obj'}"
    assert ei.value.returncode == 2 and "\n" not in str(ei.value)


def test_interrupted_from_outside_is_cancelled(tmp_path):
    procs = []
    gen = W.run_worker("render-dataset", [*RENDER, "--views", "400", "--out", tmp_path / "ds"], sys.executable,
                       env=ENV, on_start=procs.append)
    with pytest.raises(Cancelled, match="interrupted"):
        for ev in gen:
            if ev.done >= 1:
                W._signal(procs[0], __import__("signal").SIGINT)


@pytest.fixture(scope="module")
def bare_python(tmp_path_factory):
    """A real interpreter without the project's dependencies (a fresh venv, no pip)."""
    d = tmp_path_factory.mktemp("bare") / "venv"
    venv.create(d, with_pip=False, symlinks=os.name != "nt")
    return str(W.venv_python(d))


def test_probe_and_install_hint(bare_python):
    W.clear_probe_cache()
    ours = W.probe(sys.executable)["modules"]
    assert all(ours[m] for m, _, _ in W.DEPENDENCIES), ours
    assert ours["torch"].startswith("2.13")
    bare = W.probe(bare_python)["modules"]
    assert not any(bare.values()), bare
    assert W.missing(bare_python, ("torch", "pycolmap")) == ["torch", "pycolmap"]
    assert W.install_hint(bare_python, ["torch", "OpenEXR"]) == f'"{bare_python}" -m pip install "torch==2.13.0" "openexr>=3.3"'
    with pytest.raises(InputError, match="does not exist"):
        W.probe("/nonexistent/python")


@pytest.mark.skipif(os.name == "nt", reason="the fake interpreter is a script with a #! line")
def test_a_package_installed_after_a_probe_is_seen(tmp_path):
    """Installing torch (as the error says) changes no interpreter mtime, the probe cache's key: a cached report
    lacking what is needed is probed again, so the next press no longer says torch is missing; a report that has
    everything needed is reused without starting a process."""
    py = tmp_path / "python"
    py.write_text(f"#!{sys.executable}\nimport json, pathlib\np = pathlib.Path({str(tmp_path)!r})\n"
                  "with open(p / 'runs', 'a') as f:\n    f.write('x')\n"
                  "v = (p / 'torch').read_text() if (p / 'torch').exists() else None\n"
                  "print(json.dumps({'python': '3.11.0', 'modules': {'torch': v, 'numpy': '1.26.4'}}))\n")
    py.chmod(0o755)
    W.clear_probe_cache()
    with pytest.raises(InputError, match="torch missing"):
        W.require(W.Interpreter(str(py), "preferences"), ("torch",))
    (tmp_path / "torch").write_text("2.13.0")  # pip install torch
    W.require(W.Interpreter(str(py), "preferences"), ("torch",))
    runs = (tmp_path / "runs").read_text()
    assert W.missing(str(py), ("torch", "numpy")) == [] and (tmp_path / "runs").read_text() == runs
    W.clear_probe_cache()


def test_missing_dependency_in_the_child_is_one_line(bare_python, tmp_path):
    gen = W.run_worker("render-dataset", [*RENDER, "--out", tmp_path / "o"], bare_python)
    with pytest.raises(W.WorkerError) as ei:
        for _ in gen:
            pass
    msg = str(ei.value)
    assert msg.startswith(f"numpy is missing in the worker Python {bare_python}; install with: \"{bare_python}\" -m pip install")


def test_choose_interpreter(bare_python, tmp_path):
    # The preference wins when set (a venv folder is accepted too); a wrong path is an error.
    assert W.choose_interpreter(bare_python) == W.Interpreter(bare_python, "preferences")
    assert W.choose_interpreter(str(Path(bare_python).parents[1])).path == bare_python
    with pytest.raises(InputError, match="does not exist"):
        W.choose_interpreter(str(tmp_path / "no" / "python"))
    # Empty: this Python has torch, so it runs the worker.
    assert W.choose_interpreter("") == W.Interpreter(sys.executable, "blender")
    with pytest.raises(InputError) as ei:
        W.require(W.Interpreter(bare_python, "preferences"), ("torch",))
    assert "torch missing in the worker Python" in str(ei.value) and '-m pip install "torch==2.13.0"' in str(ei.value)


def test_find_project_venv_through_an_extension_symlink(tmp_path):
    proj = tmp_path / "proj"
    py = W.venv_python(proj / ".venv")
    py.parent.mkdir(parents=True)
    py.write_text("")
    (proj / "blender_mrvm").mkdir()
    ext = tmp_path / "blender" / "extensions" / "user_default"
    ext.mkdir(parents=True)
    (ext / "blender_mrvm").symlink_to(proj / "blender_mrvm")
    assert W.find_project_venv(ext / "blender_mrvm") == py
    assert W.find_project_venv(tmp_path / "blender" / "extensions") is None
    assert W.find_project_venv() == W.venv_python(ROOT / ".venv")


@pytest.mark.skipif(os.name == "nt", reason="the fake interpreters are scripts with a #! line")
def test_a_hanging_python_and_a_folder_without_one_are_named_plainly(tmp_path):
    """A worker Python that hangs is reported as not answering (before: "cannot run: Command '[..., '-c', '<the
    whole multi-line probe script>', ...]' timed out after 30 seconds"); a preference naming a folder that is not a
    venv is "a folder without bin/python" (before: "does not exist", though it exists)."""
    hang = tmp_path / "hang_py"
    hang.write_text("#!/bin/sh\nsleep 30\n")
    hang.chmod(0o755)
    W.clear_probe_cache()
    t0 = time.monotonic()
    with pytest.raises(InputError) as ei:
        W.probe(str(hang), timeout=1)
    assert str(ei.value) == f"worker Python {hang} did not answer within 1 s" and time.monotonic() - t0 < 10
    folder = tmp_path / "not a venv"
    folder.mkdir()
    with pytest.raises(InputError) as ei:
        W.choose_interpreter(str(folder))
    assert "is a folder without bin/python" in str(ei.value) and "does not exist" not in str(ei.value)
    W.clear_probe_cache()


def test_the_worker_reads_the_weights_from_the_cache_folder(tmp_path, monkeypatch):
    """The worker's MRVM_WEIGHTS_DIR (models/vgg.py reads the offline VGG16 / LPIPS weights there): the preferences'
    Weights cache when set, else $MRVM_WEIGHTS_DIR, else the project's .cache/weights beside a venv's Python, else
    the package's default. Before, the worker got none: in the installed extension it looked beside the extension's
    folder, not where `fetch-weights` put them."""
    monkeypatch.delenv("MRVM_WEIGHTS_DIR", raising=False)
    monkeypatch.setattr(W, "preferences_cache_dir", None)
    default = ROOT / ".cache" / "weights"
    assert W.weights_dir() == default
    assert W.worker_env()["MRVM_WEIGHTS_DIR"] == str(default)
    proj = tmp_path / "proj"
    py = W.venv_python(proj / ".venv")
    py.parent.mkdir(parents=True)
    (proj / ".venv" / "pyvenv.cfg").write_text("home = /usr/bin\n")
    assert W.weights_dir(str(py)) == default  # no .cache/weights in that project
    (proj / ".cache" / "weights").mkdir(parents=True)
    assert W.worker_env(python=str(py))["MRVM_WEIGHTS_DIR"] == str(proj / ".cache" / "weights")
    monkeypatch.setenv("MRVM_WEIGHTS_DIR", str(tmp_path / "env"))
    assert W.weights_dir(str(py)) == tmp_path / "env"
    monkeypatch.setattr(W, "preferences_cache_dir", lambda: str(tmp_path / "mine"))
    assert W.worker_env(python=str(py))["MRVM_WEIGHTS_DIR"] == str(tmp_path / "mine")
    # what the child reads: models/vgg.py's folder is the one passed, with the files named as there
    import subprocess

    out = subprocess.run([sys.executable, "-c", "from blender_mrvm.models import vgg; "
                          "print(vgg.weights_dir(), vgg.VGG_FILE, vgg.LPIPS_FILE)"], capture_output=True, text=True,
                         env=W.worker_env(python=str(py)), timeout=120)
    assert out.stdout.split() == [str(tmp_path / "mine"), *W.WEIGHT_FILES], out.stderr


def test_a_crashed_worker_leaves_its_traceback_in_the_console(tmp_path, capsys):
    """A worker that crashed (no error: line) was reported as "worker failed (exit code 1): <last line>" and its
    traceback was kept nowhere: the panel's message calls it a bug, and the last output goes to the system console."""
    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho 'Traceback (most recent call last):' >&2\necho '  File \"x.py\", line 1' >&2\n"
                    "echo 'ValueError: broken' >&2\nexit 1\n")
    fake.chmod(0o755)
    with pytest.raises(W.WorkerError) as ei:
        for _ in W.run_worker("render-dataset", ["--out", tmp_path / "o"], str(fake), env=ENV):
            pass
    assert str(ei.value) == ("unexpected error in the worker, a bug (exit code 1: ValueError: broken); its last output "
                             "is in the system console")
    err = capsys.readouterr().err
    assert "the render-dataset worker ended with exit code 1" in err and '  File "x.py", line 1' in err
