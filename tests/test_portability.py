"""Windows and macOS behaviour, simulated on Linux: the other platform's API or semantics is faked (``os.name``,
a missing ``fcntl``, ``msvcrt``, ``os.replace`` refusing while another handle has the file open, SIGBREAK) and the
code that an artist's panel or CLI run goes through is checked against it. No bpy, no GPU."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from blender_mrvm import cli
from blender_mrvm import worker as W

posix_only = pytest.mark.skipif(os.name != "posix", reason="simulates Windows with POSIX signals")


# ---------------------------------------------------------------------------------------------
# Esc in the panel on Windows: the worker is interrupted softly (Ctrl-Break), not terminated
# ---------------------------------------------------------------------------------------------

class _FakeWindowsProc:
    """A ``subprocess.Popen`` on Windows as ``worker._signal`` drives it: what it was sent."""

    def __init__(self):
        self.pid, self.calls = 4242, []

    def send_signal(self, sig):
        self.calls.append(("send_signal", sig))

    def terminate(self):
        self.calls.append(("terminate",))

    def kill(self):
        self.calls.append(("kill",))


class _OsAs:
    """``os`` for one module as another platform has it (patching ``os.name`` itself breaks pathlib and pytest)."""

    def __init__(self, name: str):
        self.name = name

    def __getattr__(self, attr):
        return getattr(os, attr)


def test_windows_esc_interrupts_the_worker_with_ctrl_break(monkeypatch):
    """The first Esc (``INTERRUPT`` -> SIGINT) terminated the child on Windows (TerminateProcess): Train lost the
    steps since its last checkpoint and the soft stop ("the step in progress is finished and kept") never happened
    there. It now sends Ctrl-Break to the child's own process group (it is started with CREATE_NEW_PROCESS_GROUP);
    SIGTERM still terminates, SIGKILL kills."""
    monkeypatch.setattr(W, "os", _OsAs("nt"))
    monkeypatch.setattr(signal, "CTRL_BREAK_EVENT", 1, raising=False)
    proc = _FakeWindowsProc()
    W._signal(proc, signal.SIGINT)
    assert proc.calls == [("send_signal", 1)]
    proc.calls.clear()
    W._signal(proc, signal.SIGTERM)
    W._signal(proc, signal.SIGKILL)
    assert proc.calls == [("terminate",), ("kill",)]
    # no console shared with the child (GenerateConsoleCtrlEvent fails): terminated, as before
    proc.calls.clear()

    def refuse(sig):
        raise OSError(6, "The handle is invalid")

    proc.send_signal = refuse
    W._signal(proc, signal.SIGINT)
    assert proc.calls == [("terminate",)]


def _fake_command_parser(run):
    parser = cli.Parser(prog="python -m blender_mrvm")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("fake")
    p.set_defaults(_module=SimpleNamespace(run=run))
    return parser


@posix_only
@pytest.mark.parametrize("soft", [True, False])
def test_cli_takes_ctrl_break_as_ctrl_c(monkeypatch, capsys, soft):
    """What the worker gets on Windows is SIGBREAK, whose default ends the process at once (nothing saved, no
    ``error: interrupted`` line, exit code 0xC000013A rather than 130). The CLI takes it as Ctrl-C: inside
    ``progress.sigint_flag`` (training, rendering: finish the unit in progress) the flag is set; elsewhere it is a
    KeyboardInterrupt, ``error: interrupted`` and exit 130 (which ``run_worker`` reports as cancelled). SIGBREAK is
    simulated by SIGUSR1; "the process ended" by a handler that records the signal unhandled."""
    from blender_mrvm.progress import sigint_flag

    fake_break = signal.SIGUSR1
    monkeypatch.setattr(signal, "SIGBREAK", fake_break, raising=False)
    unhandled = []
    before = signal.signal(fake_break, lambda s, f: unhandled.append(s))  # Windows' default: ExitProcess
    previous_int = signal.signal(signal.SIGINT, signal.default_int_handler)

    def run(args):
        if soft:
            with sigint_flag() as flag:
                os.kill(os.getpid(), fake_break)
                time.sleep(0.05)
                return 7 if flag == [signal.SIGINT] else 0
        os.kill(os.getpid(), fake_break)
        time.sleep(0.05)
        return 0

    monkeypatch.setattr(cli, "build_parser", lambda: _fake_command_parser(run))
    try:
        rc = cli.main(["fake"])
        after = signal.getsignal(fake_break)
    finally:
        signal.signal(fake_break, before)
        signal.signal(signal.SIGINT, previous_int)
    assert unhandled == []
    if soft:
        assert rc == 7, "the unit in progress was not told to finish"
    else:
        assert rc == 130 and "error: interrupted" in capsys.readouterr().err
    assert after is not None and getattr(after, "__name__", "") == "<lambda>", "main left its SIGBREAK handler"


# ---------------------------------------------------------------------------------------------
# Output folders on Windows: one process at a time (no fcntl there)
# ---------------------------------------------------------------------------------------------

@pytest.fixture
def windows_locks(monkeypatch):
    """This process as Windows has it for ``guards.output_lock``: no ``fcntl``, no ``os.pread``/``pwrite``, an
    ``msvcrt`` whose ``locking`` refuses a byte another open handle locked (simulated by ``flock`` on the handle),
    and ``os.unlink`` refusing a file a handle has open."""
    import errno
    import fcntl as real_fcntl

    held: dict[int, str] = {}
    real_open, real_close, real_unlink = os.open, os.close, os.unlink

    def locking(fd, mode, nbytes):
        if mode == fake.LK_UNLCK:
            real_fcntl.flock(fd, real_fcntl.LOCK_UN)
            return
        try:
            real_fcntl.flock(fd, real_fcntl.LOCK_EX | real_fcntl.LOCK_NB)
        except BlockingIOError:
            raise OSError(errno.EACCES, "Permission denied") from None

    fake = SimpleNamespace(LK_UNLCK=0, LK_NBLCK=2, locking=locking)

    def fake_open(path, flags, mode=0o777, *a, **k):
        fd = real_open(path, flags, mode, *a, **k)
        held[fd] = os.path.realpath(path)
        return fd

    def fake_close(fd):
        held.pop(fd, None)
        real_close(fd)

    def fake_unlink(path, *a, **k):
        if os.path.realpath(path) in held.values():
            raise PermissionError(errno.EACCES, "The process cannot access the file because it is being used by "
                                                "another process", str(path))
        real_unlink(path, *a, **k)

    monkeypatch.setitem(sys.modules, "fcntl", None)
    monkeypatch.setitem(sys.modules, "msvcrt", fake)
    monkeypatch.delattr(os, "pread", raising=False)
    monkeypatch.delattr(os, "pwrite", raising=False)
    monkeypatch.setattr(os, "open", fake_open)
    monkeypatch.setattr(os, "close", fake_close)
    monkeypatch.setattr(os, "unlink", fake_unlink)
    return held


def test_windows_output_lock_refuses_a_second_writer(tmp_path, windows_locks):
    """Without ``fcntl`` the folder was not locked at all: on Windows two runs (the panel's Render Dataset and a
    shell's, two Blenders) wrote into one dataset folder at once. Now the second is refused, naming the holder's
    pid; the lock file goes when the first ends, and the folder can be held again."""
    from blender_mrvm.errors import OutputError
    from blender_mrvm.guards import LOCK_FILE, output_lock

    out = tmp_path / "ds"
    with output_lock(out):
        assert (out / LOCK_FILE).is_file()
        with pytest.raises(OutputError, match=rf"in use by another process \(pid {os.getpid()}\)"):
            with output_lock(out):
                pass
    assert not windows_locks, "a handle was left open"
    assert not (out / LOCK_FILE).exists(), "the lock file was left (removed while its handle was open)"
    assert not out.exists(), "the folder it made was left"
    with output_lock(out):
        pass


# ---------------------------------------------------------------------------------------------
# Windows refuses os.replace over a file another program has open
# ---------------------------------------------------------------------------------------------

@pytest.fixture
def open_elsewhere(monkeypatch):
    """Windows' ``os.replace``: PermissionError (WinError 5) while another program holds the destination open
    (``holds[path]`` tries more; -1: for good)."""
    import errno

    from blender_mrvm.datasets import format as F

    monkeypatch.setattr(F, "_WINDOWS", True, raising=False)
    monkeypatch.setattr(F, "_REPLACE_WAITS_S", (0.01,) * 5, raising=False)
    holds: dict[str, int] = {}
    real = os.replace

    def replace(src, dst, *a, **k):
        left = holds.get(str(dst), 0)
        if left:
            holds[str(dst)] = left - 1 if left > 0 else left
            raise PermissionError(errno.EACCES, "Access is denied", str(src), None, str(dst))
        real(src, dst, *a, **k)

    monkeypatch.setattr(os, "replace", replace)
    return holds


def test_windows_atomic_write_waits_out_a_scanner(tmp_path, open_elsewhere):
    """A virus scanner or the indexer opening a file just written made the next atomic write over it (a dataset's
    meta.json, a run's config, a view re-rendered) fail with "Access is denied" naming a temporary file. It is
    tried again; the file is replaced and no temporary file is left."""
    from blender_mrvm.datasets import format as F

    path = tmp_path / "meta.json"
    F.atomic_write_json(path, {"a": 1})
    open_elsewhere[str(path)] = 2
    F.atomic_write_json(path, {"a": 2})
    assert F.json.loads(path.read_text(encoding="utf-8")) == {"a": 2}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["meta.json"]


def test_windows_atomic_write_names_the_file_held_open(tmp_path, open_elsewhere):
    """Held for good (an image viewer showing it): one line through the CLI naming the file and the fix, not the
    temporary name; the old file is as it was and no temporary file is left."""
    from blender_mrvm.datasets import format as F

    path = tmp_path / "000001.png"
    path.write_bytes(b"old")
    open_elsewhere[str(path)] = -1
    with pytest.raises(PermissionError) as ei:
        F.atomic_write(path, lambda tmp: Path(tmp).write_bytes(b"new"))
    msg = cli.os_error_message(ei.value)
    assert msg is not None and str(path) in msg and "another program has open" in msg, msg
    assert path.read_bytes() == b"old" and sorted(p.name for p in tmp_path.iterdir()) == ["000001.png"]


# ---------------------------------------------------------------------------------------------
# Case-insensitive file systems (macOS' default, Windows): Data is data
# ---------------------------------------------------------------------------------------------

@pytest.fixture
def case_insensitive_fs(monkeypatch):
    """``os.stat`` as macOS's default file system (APFS, case-insensitive) answers it: a name in another case finds
    the entry. ``Path.resolve`` keeps the case it was given there, as on macOS (realpath does not fold it)."""
    real_stat = os.stat

    def stat(path, *a, **k):
        try:
            return real_stat(path, *a, **k)
        except FileNotFoundError:
            if isinstance(path, int):
                raise
            p = Path(os.fsdecode(path)).absolute()
            found = Path(p.anchor)
            for part in p.parts[1:]:
                names = {n.casefold(): n for n in os.listdir(found)} if found.is_dir() else {}
                if part.casefold() not in names:
                    raise
                found = found / names[part.casefold()]
            return real_stat(found, *a, **k)

    monkeypatch.setattr(os, "stat", stat)


def test_macos_output_folder_that_is_the_input_in_another_case_is_refused(tmp_path, case_insensitive_fs):
    """``synthesize --references refs/chair --out Refs/Chair`` (or a Sem2NeRF output named as its dataset in another
    case) compared the resolved paths as strings: on macOS they differ while they name one folder, and the
    predictions were written over the reference object's ground truth. Also the panel's check of two Render Dataset
    jobs into one folder (``operators.dataset._same_folder``)."""
    from blender_mrvm.errors import OutputError
    from blender_mrvm.guards import check_not_input

    refs = tmp_path / "refs" / "chair"
    refs.mkdir(parents=True)
    other = tmp_path / "Refs" / "Chair"
    with pytest.raises(OutputError, match="is the reference folder"):
        check_not_input(other, {"reference": refs})
    check_not_input(tmp_path / "out", {"reference": refs})  # another folder: allowed
    from blender_mrvm.guards import same_path

    assert same_path(refs, other) and not same_path(refs, tmp_path / "out")


def test_macos_two_render_dataset_jobs_into_one_folder_in_another_case(tmp_path, case_insensitive_fs):
    pytest.importorskip("bpy")
    from blender_mrvm.operators.dataset import _same_folder

    (tmp_path / "Dataset").mkdir()
    assert _same_folder(tmp_path / "Dataset", tmp_path / "dataset")
    assert not _same_folder(tmp_path / "Dataset", tmp_path / "other")


def test_names_windows_reserves_get_an_underscore():
    """An object or camera named ``aux`` or ``Com1`` (``nul.001`` too: what follows the dot does not matter) became a
    folder or file a dataset copied to Windows cannot hold."""
    from blender_mrvm.scene.objects import safe_id

    assert [safe_id(n) for n in ("CON", "nul", "Com1", "aux.001", "LPT9.x")] == \
        ["CON_", "nul_", "Com1_", "aux_.001", "LPT9_.x"]
    assert [safe_id(n) for n in ("console", "com10", "chair", "auxiliary")] == ["console", "com10", "chair", "auxiliary"]


def test_two_cameras_whose_names_differ_in_case_get_two_plane_files(tmp_path, monkeypatch):
    """Cameras ``Cam`` and ``cam`` got plane images Cam.png and cam.png: one file on macOS and Windows, so the first
    plane showed the second camera's view."""
    pytest.importorskip("bpy")
    from blender_mrvm.scene import image_planes as IP

    monkeypatch.setattr(IP, "_image_paths", lambda: set())
    stems = IP._unique_stems(["Cam", "cam", "CAM"], tmp_path, own_folder=False)
    assert len({s.casefold() for s in stems}) == 3 and stems[0] == "Cam"


def test_obj_material_libraries_are_read_as_utf8_whatever_the_locale(tmp_path, monkeypatch):
    """Windows' default text encoding is a code page: ``mtllib café.mtl`` read back as ``cafÃ©.mtl`` and was reported
    missing, the object losing its colours. The OBJ's lines are read as UTF-8 (so are MTL and other text meshes)."""
    import builtins

    from blender_mrvm.scene import objects as O

    def windows_open(file, mode="r", *args, **kwargs):  # open() without encoding= on Windows
        if "b" not in mode and "encoding" not in kwargs and len(args) < 2:
            kwargs["encoding"] = "cp1252"
        return builtins.open(file, mode, *args, **kwargs)

    monkeypatch.setattr(O, "open", windows_open, raising=False)
    obj = tmp_path / "m.obj"
    obj.write_bytes("mtllib café.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".encode("utf-8"))
    lines = O._mtllib_text_lines(str(obj), 12345, obj.stat().st_size)
    assert [ln.strip() for ln in lines] == ["mtllib café.mtl"]
