"""The worker process: heavy work (training, synthesis, pose recovery) runs in a child ``python -m
blender_mrvm <command> ...`` (DESIGN.md, "Where torch runs inside Blender"). bpy-free.

- :func:`choose_interpreter` picks the Python that runs the child: the one set in the add-on
  preferences when there is one (the user's explicit choice), else the running Python (Blender's own)
  when it has the dependencies, else a project ``.venv`` found next to the add-on or repository.
- :func:`probe` reports which dependencies an interpreter has (without importing them), and
  :func:`install_hint` the one command that installs what is missing.
- :func:`run_worker` starts the child with ``MRVM_PROGRESS=json`` (so ``progress.run_with_tqdm``
  prints one JSON line per event on stdout) and is itself a progress generator: a modal operator
  calls ``next()`` once per timer tick (each call waits at most ``poll_s``), and cancels with
  ``gen.close()``, which interrupts the child (SIGINT, Ctrl-Break on Windows: the CLI closes its own generator,
  keeping finished work) and escalates to terminate / kill when it does not exit in time. A child that
  fails raises :class:`WorkerError` with its one ``error: ...`` line.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from .errors import Cancelled, InputError, MRVMError
from .progress import Progress, ProgressGen

PACKAGE_DIR = Path(__file__).resolve().parent
"""The package folder (``blender_mrvm/``, or the installed extension's folder)."""

DEPENDENCIES: tuple[tuple[str, str, str], ...] = (
    ("torch", "torch==2.13.0", "training and novel-view synthesis"),
    ("safetensors", "safetensors>=0.4", "model checkpoints"),
    ("numpy", "numpy>=1.24,<2", "everything"),
    ("PIL", "pillow>=10", "PNG images"),
    ("scipy", "scipy>=1.11", "Sem2NeRF's mask inputs and the references' visual hull"),
    ("OpenEXR", "openexr>=3.3", "depth and normal maps (EXR)"),
    ("pycolmap", "pycolmap==4.2.1", "recovering the poses of photos"),
    ("pillow_heif", "pillow-heif>=1.0", "HEIC photos (an iPhone's default) to recover poses from"),
    ("av", "av>=14", "videos to recover poses from"),
)
"""(import name, pip requirement, what needs it) of the worker's dependencies (pins as pyproject.toml)."""

_PROBE = r"""
import importlib.util, importlib.metadata, json, sys
dists = {"PIL": "pillow", "OpenEXR": "openexr", "pillow_heif": "pillow-heif"}
out = {}
for m in sys.argv[1:]:
    try:
        found = importlib.util.find_spec(m) is not None
    except Exception:
        found = False
    v = None
    if found:
        try:
            v = importlib.metadata.version(dists.get(m, m))
        except Exception:
            v = "unknown version"
    out[m] = v
print(json.dumps({"python": sys.version.split()[0], "modules": out}))
"""


class WorkerError(MRVMError):
    """The worker process failed; the message is its one-line error."""

    def __init__(self, message: str, returncode: int | None = None):
        super().__init__(message)
        self.returncode = returncode


# ---------------------------------------------------------------------------------------------
# Interpreters
# ---------------------------------------------------------------------------------------------

def module_name() -> str:
    """Module the child runs with ``-m``: the package folder's name (the extension id)."""
    return PACKAGE_DIR.name


def venv_python(venv: Path) -> Path:
    return venv / ("Scripts/python.exe" if os.name == "nt" else "bin/python")


def find_project_venv(start: Path | None = None, levels: int = 4) -> Path | None:
    """The ``.venv`` interpreter of the project holding the add-on (symlinks followed), or None."""
    starts = [Path(start) if start else PACKAGE_DIR]
    starts.append(starts[0].resolve())
    for s in starts:
        for d in [s, *list(s.parents)[:levels]]:
            py = venv_python(d / ".venv")
            if py.is_file():
                return py
    return None


@dataclass(frozen=True)
class Interpreter:
    """The Python chosen to run the worker."""

    path: str
    """Executable."""
    source: str
    """Why: "preferences", "blender" (the running Python) or "project venv"."""


_probe_cache: dict[tuple[str, float], dict] = {}


def probe(python: str, timeout: float = 30.0, needs: tuple[str, ...] = ()) -> dict:
    """``{"python": version, "modules": {name: version or None}}`` for ``python`` (cached per file).

    Uses ``find_spec`` (nothing is imported, so it takes well under a second). A cached report that lacks one
    of ``needs`` is not trusted: installing a package (as the error message says) changes nothing the cache
    key sees, so that interpreter is probed again. Raises :class:`InputError` when the interpreter cannot run.
    """
    p = Path(python)
    if not p.is_file():
        raise InputError(f"worker Python {python} does not exist")
    key = (str(p), p.stat().st_mtime)
    cached = _probe_cache.get(key)
    if cached is not None and all(cached["modules"].get(m) for m in needs):
        return cached
    try:
        cp = subprocess.run([str(p), "-c", _PROBE, *[m for m, _, _ in DEPENDENCIES]], capture_output=True, text=True,
                            timeout=timeout, env=clean_env(), stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:  # its message would hold the whole probe script
        raise InputError(f"worker Python {python} did not answer within {timeout:g} s") from None
    except OSError as e:
        raise InputError(f"worker Python {python} cannot run: {e.strerror or e}") from e
    try:
        out = json.loads(cp.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        last = (cp.stderr.strip().splitlines() or ["no output"])[-1]
        raise InputError(f"worker Python {python} cannot run: {last}") from None
    _probe_cache[key] = out
    return out


def clear_probe_cache() -> None:
    _probe_cache.clear()


def missing(python: str, needs: tuple[str, ...] = ("torch",)) -> list[str]:
    """Import names of ``needs`` that ``python`` lacks."""
    mods = probe(python, needs=needs)["modules"]
    return [m for m in needs if not mods.get(m)]


def install_hint(python: str, names: list[str]) -> str:
    """The command that installs ``names`` (import names) into ``python``."""
    specs = {m: spec for m, spec, _ in DEPENDENCIES}
    reqs = " ".join(f'"{specs.get(n, n)}"' for n in names)
    return f'"{python}" -m pip install {reqs}'


def choose_interpreter(python_path: str = "", needs: tuple[str, ...] = ("torch",)) -> Interpreter:
    """The worker's Python: the preference if set, else this Python if it has ``needs``, else a project .venv.

    Falls back to this Python (which then lacks something; :func:`missing` says what).
    """
    pref = python_path.strip()
    if pref:
        p = Path(os.path.expanduser(pref))
        if p.is_dir():  # a venv folder instead of its interpreter
            if not venv_python(p).is_file():
                raise InputError(f"the worker Python set in the add-on preferences is a folder without "
                                 f"{venv_python(Path()).as_posix()}: {pref} (set a Python executable or a venv "
                                 "folder)")
            p = venv_python(p)
        if not p.is_file():
            raise InputError(f"the worker Python set in the add-on preferences does not exist: {pref}")
        return Interpreter(str(p), "preferences")
    own = sys.executable
    try:
        if own and not missing(own, needs):
            return Interpreter(own, "blender")
    except InputError:
        pass
    venv = find_project_venv()
    if venv is not None:
        return Interpreter(str(venv), "project venv")
    return Interpreter(own, "blender")


def require(interp: Interpreter, needs: tuple[str, ...] = ("torch",)) -> None:
    """Raise :class:`InputError` naming what ``interp`` lacks and the command that installs it."""
    lacking = missing(interp.path, needs)
    if lacking:
        raise InputError(f"{', '.join(lacking)} missing in the worker Python {interp.path} ({interp.source}); "
                         f"install with: {install_hint(interp.path, lacking)} (or set Worker Python in the add-on preferences)")


# ---------------------------------------------------------------------------------------------
# Running
# ---------------------------------------------------------------------------------------------

def clean_env() -> dict[str, str]:
    """This environment for a child Python, without the variables that point Blender's own Python elsewhere."""
    env = dict(os.environ)
    for k in ("PYTHONHOME", "PYTHONSTARTUP", "PYTHONEXECUTABLE"):  # Blender's, not the child's
        env.pop(k, None)
    return env


WEIGHTS_ENV = "MRVM_WEIGHTS_DIR"
"""The environment variable ``models/vgg.py`` reads the offline weight cache folder from."""
WEIGHT_FILES = ("vgg16_imagenet_features.safetensors", "lpips_vgg_v0.1_lin.safetensors")
"""The files ``fetch-weights`` writes there (``models/vgg.py``'s VGG_FILE and LPIPS_FILE; that module needs torch)."""
FETCH_WEIGHTS = "python -m blender_mrvm fetch-weights"

preferences_cache_dir = None
"""A callable giving the add-on preferences' Cache folder ('' when unset); set by ``prefs.register`` (this module
stays bpy-free)."""


def weights_dir(python: str = "", cache_dir: str | None = None) -> Path:
    """The offline weight cache (VGG16 / LPIPS, written by ``fetch-weights``) a worker run by ``python`` reads: the
    add-on preferences' Cache folder (``cache_dir``; None: ask :data:`preferences_cache_dir`) when set, else
    ``$MRVM_WEIGHTS_DIR``, else, when ``python`` is a venv's (``<venv>/bin/python``), ``<venv>/../.cache/weights``
    where that exists (the project's cache, where ``fetch-weights`` run in the project puts them), else the
    package's own default (``models/vgg.py``: ``.cache/weights`` beside the package folder)."""
    if cache_dir is None:
        cache_dir = preferences_cache_dir() if preferences_cache_dir is not None else ""
    if cache_dir and cache_dir.strip():
        return Path(os.path.expanduser(cache_dir.strip()))
    if os.environ.get(WEIGHTS_ENV):
        return Path(os.environ[WEIGHTS_ENV])
    if python:
        venv = Path(python).parent.parent
        project = venv.parent / ".cache" / "weights"
        if (venv / "pyvenv.cfg").is_file() and project.is_dir():
            return project
    return PACKAGE_DIR.parent / ".cache" / "weights"


def missing_weights(folder: Path) -> list[str]:
    """The files of :data:`WEIGHT_FILES` that ``folder`` lacks."""
    return [f for f in WEIGHT_FILES if not (Path(folder) / f).is_file()]


def worker_env(extra: dict[str, str] | None = None, python: str = "") -> dict[str, str]:
    """The child's environment: the package importable, JSON progress, unbuffered UTF-8 output, the offline weight
    cache (:func:`weights_dir` of ``python``) in ``MRVM_WEIGHTS_DIR``."""
    from .progress import PROGRESS_ENV

    env = clean_env()
    parent = str(PACKAGE_DIR.parent)
    env["PYTHONPATH"] = os.pathsep.join([parent, *[p for p in env.get("PYTHONPATH", "").split(os.pathsep) if p]])
    env[PROGRESS_ENV] = "json"
    env["PYTHONUNBUFFERED"] = "1"
    env["PYTHONIOENCODING"] = "utf-8"
    env[WEIGHTS_ENV] = str(weights_dir(python))
    env.update(extra or {})
    from .threads import apply_omp_defaults

    return dict(apply_omp_defaults(env))


def worker_argv(python: str, command: str, args: list[str]) -> list[str]:
    return [python, "-m", module_name(), command, *map(str, args)]


@dataclass
class WorkerResult:
    """What a finished worker left besides its files."""

    returncode: int
    seconds: float
    output: list[str] = field(default_factory=list)
    """stdout lines that were not progress events (the command's own report)."""
    stderr_tail: list[str] = field(default_factory=list)
    events: int = 0
    """Progress events received."""


def parse_progress(line: str) -> Progress | None:
    """A progress event from one stdout line, or None for any other line."""
    i = line.find('{"mrvm"')  # C-level prints (Blender's render log) may share the line
    if i < 0:
        return None
    s = line[i:].strip()
    try:
        d = json.loads(s)
    except ValueError:
        return None
    if not isinstance(d, dict) or d.get("mrvm") != "progress":
        return None
    try:
        return Progress(int(d.get("done", 0)), int(d.get("total", 0)), str(d.get("message", "")),
                        int(d.get("skipped", 0)))
    except (TypeError, ValueError):
        return None


def error_message(returncode: int, stderr_lines: list[str], python: str) -> str:
    """The one line a failed child's error is reported as: its own ``error:`` line, a missing module's install line,
    else what stopped it in an artist's words (it had been "worker failed (exit code 1): <the traceback's last line>",
    and the traceback was nowhere: :func:`run_worker` now prints the child's last output to the system console)."""
    errs = [ln[len("error: "):].strip() for ln in stderr_lines if ln.startswith("error: ")]
    if errs:
        return errs[-1]
    for ln in reversed(stderr_lines):
        if "No module named" in ln:
            name = ln.split("No module named", 1)[1].strip().strip("'\"").split(".")[0]
            return f"{name} is missing in the worker Python {python}; install with: {install_hint(python, [name])}"
    tail = next((ln.strip() for ln in reversed(stderr_lines) if ln.strip()), "no message")
    if returncode < 0:  # a signal no one here sent (the job's own Esc is Cancelled): the system's, or another program's
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = f"signal {-returncode}"
        why = " (the system may have run out of memory: lower the sizes, or close other programs)" \
            if name == "SIGKILL" else ""
        return f"the worker was stopped by {name}{why}; its last output is in the system console ({tail})"
    return (f"unexpected error in the worker, a bug (exit code {returncode}: {tail}); its last output is in the "
            "system console")


def _reader(stream, name: str, q: queue.Queue) -> None:
    try:
        for line in iter(stream.readline, ""):
            q.put((name, line.rstrip("\r\n")))
    except (OSError, ValueError):
        pass
    finally:
        q.put((name, None))


def _signal(proc: subprocess.Popen, sig) -> None:
    try:
        if os.name == "posix":
            os.killpg(proc.pid, sig)  # the child leads its own process group (torchrun's ranks too)
        elif sig == signal.SIGINT:
            # Windows: the child leads its own process group (CREATE_NEW_PROCESS_GROUP), where Ctrl-C is off but
            # Ctrl-Break reaches it; the CLI takes it as Ctrl-C (cli.main) and finishes and keeps its step in
            # progress. A terminate here (as before) lost it: the first Esc in Train dropped the steps since the last
            # checkpoint. Where the event cannot be sent (no console shared with the child) it is terminated.
            try:
                proc.send_signal(signal.CTRL_BREAK_EVENT)
            except (AttributeError, ValueError, OSError):
                proc.terminate()
        else:
            proc.kill() if sig == getattr(signal, "SIGKILL", None) else proc.terminate()
    except (ProcessLookupError, PermissionError, OSError):
        pass


def stop(proc: subprocess.Popen, grace_s: float = 5.0, interrupted: bool = False) -> int | None:
    """Interrupt ``proc`` (the CLI then closes its work cleanly), then terminate, then kill; ``interrupted``: it
    has been interrupted already (and was asked to stop at once): terminate, then kill."""
    steps = ([] if interrupted else [(signal.SIGINT, grace_s)]) + [(signal.SIGTERM, 2.0)]
    if hasattr(signal, "SIGKILL"):
        steps.append((signal.SIGKILL, 5.0))
    for sig, wait in steps:
        if proc.poll() is not None:
            break
        _signal(proc, sig)
        try:
            proc.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            continue
    return proc.poll()


INTERRUPT = "interrupt"
"""What a caller ``send()``s into :func:`run_worker` (through any ``yield from``) to stop the child without waiting
for it: it is interrupted (it finishes and saves the step in progress), the generator goes on yielding while it
winds down, and escalates to terminate and kill past the grace time; then :class:`Cancelled`. Closing the generator
instead stops the child before it returns (blocking up to the grace time)."""


def run_worker(command: str, args: list[str], python: str, *, cwd: str | Path | None = None,
               env: dict[str, str] | None = None, poll_s: float = 0.1, grace_s: float = 5.0,
               on_start=None) -> ProgressGen:
    """Run ``python -m blender_mrvm <command> <args>`` as a progress generator (see module doc).

    ``on_start(proc)`` is called with the ``subprocess.Popen`` once the child runs. Yields the
    latest :class:`Progress` at least every ``poll_s`` seconds; returns a
    :class:`WorkerResult`. Raises :class:`WorkerError` (the child's ``error: ...`` line) when the
    child fails, :class:`Cancelled` when it was interrupted from outside.
    """
    argv = worker_argv(python, command, args)
    t0 = time.monotonic()
    try:
        proc = subprocess.Popen(argv, cwd=str(cwd) if cwd else None, env=worker_env(env, python),
                                stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, encoding="utf-8",
                                errors="replace", bufsize=1, start_new_session=(os.name == "posix"),
                                creationflags=getattr(subprocess, "CREATE_NEW_PROCESS_GROUP", 0))
    except OSError as e:
        raise WorkerError(f"cannot start the worker Python {python}: {e.strerror or e}") from e
    if on_start is not None:
        on_start(proc)
    q: queue.Queue = queue.Queue()
    threads = [threading.Thread(target=_reader, args=(s, n, q), daemon=True)
               for s, n in ((proc.stdout, "out"), (proc.stderr, "err"))]
    for t in threads:
        t.start()
    result = WorkerResult(returncode=-1, seconds=0.0)
    stderr_tail: deque[str] = deque(maxlen=50)
    last = Progress(0, 0, f"starting {command}")
    open_streams = 2
    stopping: list = []  # (signal sent, when): the escalation after an INTERRUPT sent in

    def wind_down(msg) -> None:
        """Interrupt on INTERRUPT; past the grace time terminate, 2 s later kill (never blocking the caller)."""
        now = time.monotonic()
        if msg == INTERRUPT and not stopping:
            _signal(proc, signal.SIGINT)
            stopping.append((signal.SIGINT, now))
        elif stopping and proc.poll() is None:
            sig, since = stopping[-1]
            if sig == signal.SIGINT and now - since > grace_s:
                _signal(proc, signal.SIGTERM)
                stopping.append((signal.SIGTERM, now))
            elif sig == signal.SIGTERM and now - since > 2.0 and hasattr(signal, "SIGKILL"):
                _signal(proc, signal.SIGKILL)
                stopping.append((signal.SIGKILL, now))

    try:
        wind_down((yield last))
        while open_streams:
            deadline = time.monotonic() + poll_s
            got = False
            while open_streams:
                try:
                    timeout = 0.0 if got else max(0.0, deadline - time.monotonic())
                    name, line = q.get(timeout=timeout) if timeout > 0 else q.get_nowait()
                except queue.Empty:
                    break
                if line is None:
                    open_streams -= 1
                    continue
                if name == "out":
                    ev = parse_progress(line)
                    if ev is not None:
                        last, got = ev, True
                        result.events += 1
                    elif line.strip():
                        result.output.append(line)
                        del result.output[:-200]
                else:
                    stderr_tail.append(line)
            if open_streams:
                if stopping:
                    last = Progress(last.done, last.total, f"stopping {command}: the step in progress is finished "
                                    "and kept (Esc again stops at once)")
                wind_down((yield last))
        rc = proc.wait()
    finally:
        if proc.poll() is None:  # closed: after an INTERRUPT, that is Esc again, "stops at once": no second grace
            stop(proc, grace_s, interrupted=bool(stopping))  # (the child ignores a second SIGINT while it winds
            # down, and Blender's UI was frozen for the whole grace: up to 30 s for Train)
        for t in threads:
            t.join(timeout=1.0)
        for s in (proc.stdout, proc.stderr):
            try:
                s.close()
            except OSError:
                pass
    result.returncode, result.seconds, result.stderr_tail = rc, time.monotonic() - t0, list(stderr_tail)
    if rc == 0:
        return result
    if rc in (130, -signal.SIGINT) or (stopping and rc != 0):
        raise Cancelled("the worker was interrupted; finished work is kept")
    if not any(ln.startswith("error: ") for ln in stderr_tail):  # a crash: its traceback for the bug report
        print(f"blender_mrvm: the {command} worker ended with exit code {rc}; its last output:", file=sys.stderr)
        for ln in stderr_tail:
            print(f"  {ln}", file=sys.stderr)
    raise WorkerError(error_message(rc, list(stderr_tail), python), rc)


def run_in_job_folder(command: str, python: str, write_args, prefix: str = "mrvm_job_"):
    """Progress generator of an operator's worker run: a new temporary job folder, ``write_args(folder)``
    -> the worker's arguments, then :func:`run_worker`; returns ``(folder, WorkerResult)``. The folder
    is removed when anything fails or the run is cancelled (the generator closed); after success the
    caller owns it (and removes it once it has read the results)."""
    job_dir = Path(tempfile.mkdtemp(prefix=prefix))
    ok = False
    try:
        args = write_args(job_dir)
        result = yield from run_worker(command, args, python)
        ok = True
        return job_dir, result
    finally:
        if not ok:
            shutil.rmtree(job_dir, ignore_errors=True)


# ---------------------------------------------------------------------------------------------
# Dependency status (the add-on preferences draw it)
# ---------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class DependencyReport:
    """What the worker's Python has and lacks."""

    interpreter: Interpreter | None
    """The chosen interpreter (None when it could not be chosen: ``error`` says why)."""
    python_version: str = ""
    """Its Python version."""
    modules: dict = field(default_factory=dict)
    """Import name -> version, or None when missing."""
    error: str = ""
    """Why no interpreter could be checked (a bad preference path, a Python that does not run)."""
    pending: bool = False
    """Not checked yet (the add-on probes in the background at register time)."""

    @property
    def missing(self) -> list[str]:
        return [m for m, _, _ in DEPENDENCIES if not self.modules.get(m)]

    @property
    def install_command(self) -> str:
        return install_hint(self.interpreter.path, self.missing) if self.interpreter and self.missing else ""

    def lines(self) -> list[tuple[str, bool]]:
        """(text, ok) lines for a status box: the interpreter, each dependency, the install command."""
        if self.pending:
            return [("Checking the worker Python...", True)]
        if self.error:
            return [(self.error, False)]
        it = self.interpreter
        src = {"preferences": "set in preferences", "blender": "Blender's own", "project venv": "project .venv"}[it.source]
        out = [(f"Worker Python ({src}, {self.python_version}): {it.path}", True)]
        for m, _, why in DEPENDENCIES:
            v = self.modules.get(m)
            out.append((f"{m} {v}" if v else f"{m}: missing (needed for {why})", bool(v)))
        if self.missing:
            out.append((f"Install with: {self.install_command}", False))
        return out


def dependency_report(python_path: str = "") -> DependencyReport:
    """The dependency status of the interpreter :func:`choose_interpreter` picks for ``python_path``."""
    try:
        it = choose_interpreter(python_path)
        info = probe(it.path)
    except InputError as e:
        return DependencyReport(None, error=str(e))
    return DependencyReport(it, info.get("python", ""), dict(info.get("modules", {})))
