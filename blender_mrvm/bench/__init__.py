"""Benchmarks (``python -m blender_mrvm bench <name>``); each module writes CSV figures.

Each module names the files it writes into ``--out`` (``RESULTS``). An ``--out`` holding a bench's earlier
results is refused before anything is measured (:func:`check_results`, from ``commands/bench.py``); with
``--force`` they are removed when the measuring starts (:func:`start_results`), so a bench that rewrites its CSV
after every point and is stopped never leaves its new rows beside an earlier run's plot or front.

Every CSV a bench writes (:func:`write_csv`) ends with the :data:`PROVENANCE_FIELDS` columns, the same on every
row: the bench's full command line with every option's value (defaults included), when it started (UTC), the
package version and git commit, Python, torch and the other libraries' versions (numpy; Blender's ``bpy`` and
``pycolmap`` where the bench loaded them), the CPU model and the cores this process may use, so a CSV read a month
later says where it came from (each bench's own columns record the threads and the load per row).
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

PROVENANCE_FIELDS = ("bench_command", "bench_started_utc", "code_version", "python_version", "torch_version",
                     "libraries", "cpu_model", "cpu_count")
"""The columns :func:`write_csv` appends to every bench CSV (:func:`provenance`)."""

_RUN: dict = {}
"""This process's bench run (:func:`begin`): its command line and start time."""


def whole_numbers(text: str, flag: str, minimum: int = 1, maximum: int | None = None) -> list[int]:
    """A comma-separated list of whole numbers given on the command line (``--sizes 64,128``), each within
    [``minimum``, ``maximum``]; an :class:`InputError` naming ``flag`` otherwise, before anything is measured."""
    from ..errors import InputError

    items = [t.strip() for t in str(text).split(",") if t.strip()]
    try:
        values = [int(t) for t in items]
    except ValueError:
        raise InputError(f"{flag}: expected comma-separated whole numbers, got {text!r}") from None
    if not values:
        raise InputError(f"{flag}: none given")
    if any(v < minimum for v in values):
        raise InputError(f"{flag}: each must be at least {minimum}, got {text}")
    if maximum is not None and any(v > maximum for v in values):
        raise InputError(f"{flag}: each must be at most {maximum}, got {text}")
    return values


def names(text: str, flag: str, choices: tuple[str, ...] | None = None) -> list[str]:
    """A comma-separated list of names given on the command line (``--presets fast,gpnr:fast``), blanks dropped;
    an :class:`InputError` naming ``flag`` when it names none (``","``) or, with ``choices``, one outside them,
    before anything is measured."""
    from ..errors import InputError

    items = [t.strip() for t in str(text).split(",") if t.strip()]
    if not items:
        raise InputError(f"{flag}: none given" + (f"; choose from {', '.join(choices)}" if choices else ""))
    bad = [t for t in items if choices is not None and t not in choices]
    if bad:
        raise InputError(f"{flag}: unknown {', '.join(bad)}; choose from {', '.join(choices)}")
    return items


def check_results(out: Path, results: tuple[str, ...], force: bool = False) -> None:
    """OutputError when ``out`` holds any of ``results`` (a bench's files from an earlier run) and ``force`` is
    off; files of other benches or the user's are no business of a bench (``--out docs`` is the usual place)."""
    from ..errors import OutputError
    from ..guards import _shown

    out = Path(out)
    earlier = [n for n in results if (out / n).exists()] if out.is_dir() else []
    if earlier and not force:
        raise OutputError(f"bench output folder {out} already holds this bench's results ({_shown(earlier)}); "
                          "choose another --out or pass --force to replace them")


def start_results(out: Path, results: tuple[str, ...], force: bool = False) -> Path:
    """``out``, created, once the bench's arguments are checked and before its first measurement: refused as
    :func:`check_results` says, else the earlier results removed (``force``), so the folder never mixes them
    with this run's."""
    out = Path(out)
    check_results(out, results, force)
    for n in results:
        if (out / n).is_file():
            (out / n).unlink()
    out.mkdir(parents=True, exist_ok=True)
    return out


def at_least(args, **minimums: int) -> None:
    """Refuse integer options below their minimum, every one named in one line (``at_least(args, repeats=1)``)."""
    from ..errors import InputError

    low = [f"--{k.replace('_', '-')} must be at least {m} (got {getattr(args, k)})"
           for k, m in minimums.items() if getattr(args, k) < m]
    if low:
        raise InputError("; ".join(low))


def begin(command: str) -> None:
    """Record this process's bench run: ``command`` (the command line, every option's value) and the time now;
    :func:`write_csv` writes both into every row (``commands/bench.py`` calls it before a bench runs)."""
    import datetime as dt

    _RUN.clear()
    _RUN.update(command=command, started=dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))


def cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``), else what :mod:`platform` says."""
    import platform

    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith(("model name", "hardware", "cpu model")):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def provenance() -> dict:
    """The :data:`PROVENANCE_FIELDS` of this process: the bench's command and start (:func:`begin`; the process's
    own command line and the time now when no bench began), the code (version, git commit, "+modified" when the
    package's tracked files differ from it), Python, torch, numpy (and bpy, pycolmap where loaded), the CPU model
    and the cores this process may use."""
    import os
    import platform
    import shlex
    import sys

    from .. import __version__
    from ..training.provenance import source_state

    if not _RUN:
        begin(" ".join(shlex.quote(a) for a in ["python", *sys.argv]))
    src = source_state()
    code = __version__ + (f" ({src['commit'][:12]}{'+modified' if src.get('modified') else ''})"
                          if src.get("commit") else "")
    try:
        import torch

        tv = torch.__version__
    except ImportError:
        tv = ""
    libs = []
    for name in ("numpy", "bpy", "pycolmap"):  # Blender and COLMAP where the bench loaded them (render, capture)
        mod = sys.modules.get(name)
        if mod is not None:
            v = getattr(getattr(mod, "app", None), "version_string", None) or getattr(mod, "__version__", "?")
            libs.append(f"{name} {v}")
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return {"bench_command": _RUN["command"], "bench_started_utc": _RUN["started"], "code_version": code,
            "python_version": platform.python_version(), "torch_version": tv, "libraries": "; ".join(libs),
            "cpu_model": cpu_model(), "cpu_count": cores}


def write_csv(path: Path, rows: list[dict], fields: list[str] | None = None, quiet: bool = False) -> Path:
    """Write benchmark rows (dicts with the same keys) as CSV, the :data:`PROVENANCE_FIELDS` columns last, and say
    where; no rows is an InputError before the file is opened (an earlier CSV there stays as it was)."""
    from ..errors import InputError

    path = Path(path)
    if not rows:
        raise InputError(f"nothing was measured: no rows to write to {path}")
    prov = provenance()
    fields = [k for k in (fields or list(rows[0])) if k not in prov] + list(PROVENANCE_FIELDS)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields)
        w.writeheader()
        w.writerows({**r, **prov} for r in rows)
    if not quiet:
        print(f"wrote {path}")
    return path


class PeakMemory:
    """Peak extra memory of a block, in MiB: on CUDA ``torch.cuda.max_memory_allocated`` above what was
    allocated before; on the CPU the process's peak resident set (Linux ``VmHWM``, reset through
    ``/proc/self/clear_refs``) above its resident set before (NaN where that cannot be reset: :func:`mib_cell`
    writes it as an empty cell)::

        with PeakMemory("cpu", release=True) as pm:
            render()
        pm.mib

    ``release`` (the CPU): first hand the allocator's freed memory back to the system (glibc ``malloc_trim``), so
    the resident set before is what is live. The CLI's allocator keeps up to 256 MiB of freed heap mapped
    (``threads.apply_malloc_defaults``): without it a block run after a warm-up reported its peak less whatever
    the warm-up had freed (400 MiB of 20 MiB blocks measured 260 MiB). The block then pays its page faults
    again, so time a render outside a released block.
    """

    def __init__(self, device: str = "cpu", release: bool = False):
        self.cuda = str(device).startswith("cuda")
        self.release = bool(release)
        self.mib = float("nan")

    def __enter__(self) -> "PeakMemory":
        if self.cuda:
            import torch

            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
            self._base = torch.cuda.memory_allocated()
        else:
            if self.release:
                release_freed_memory()
            try:
                with open("/proc/self/clear_refs", "w") as f:
                    f.write("5")
                self._base = _status_kb("VmRSS")
            except OSError:
                self._base = None
        return self

    def __exit__(self, *exc) -> None:
        if self.cuda:
            import torch

            torch.cuda.synchronize()
            self.mib = (torch.cuda.max_memory_allocated() - self._base) / 2 ** 20
        elif self._base is not None:
            hwm = _status_kb("VmHWM")
            self.mib = (hwm - self._base) / 1024 if hwm and self._base else float("nan")


def release_freed_memory() -> bool:
    """Hand the C allocator's freed memory back to the system (glibc ``malloc_trim(0)``); False where there is
    no such call."""
    import ctypes

    try:
        return bool(ctypes.CDLL(None).malloc_trim(0))
    except (OSError, AttributeError):
        return False


def mib_cell(values) -> float | str:
    """The peak of ``values`` (MiB) rounded for a CSV cell; '' when none is a number (the peak could not be
    measured here: an empty cell, not a NaN that ``max`` keeps or drops by its place in the list)."""
    ok = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return round(max(ok), 1) if ok else ""


def _status_kb(key: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0
