"""Benchmarks (``python -m blender_mrvm bench <name>``); each module writes CSV figures.

Each module names the files it writes into ``--out`` (``RESULTS``). An ``--out`` holding a bench's earlier
results is refused before anything is measured (:func:`check_results`, from ``commands/bench.py``); with
``--force`` they are removed when the measuring starts (:func:`start_results`), so a bench that rewrites its CSV
after every point and is stopped never leaves its new rows beside an earlier run's plot or front.
"""

from __future__ import annotations

import csv
from pathlib import Path


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


def write_csv(path: Path, rows: list[dict], fields: list[str] | None = None, quiet: bool = False) -> Path:
    """Write benchmark rows (dicts with the same keys) as CSV and say where; no rows is an InputError before the
    file is opened (an earlier CSV there stays as it was)."""
    from ..errors import InputError

    path = Path(path)
    if not rows:
        raise InputError(f"nothing was measured: no rows to write to {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields or list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    if not quiet:
        print(f"wrote {path}")
    return path


class PeakMemory:
    """Peak extra memory of a block, in MiB: on CUDA ``torch.cuda.max_memory_allocated`` above what was
    allocated before; on the CPU the process's peak resident set (Linux ``VmHWM``, reset through
    ``/proc/self/clear_refs``) above its resident set before (NaN where that cannot be reset)::

        with PeakMemory("cpu") as pm:
            render()
        pm.mib
    """

    def __init__(self, device: str = "cpu"):
        self.cuda = str(device).startswith("cuda")
        self.mib = float("nan")

    def __enter__(self) -> "PeakMemory":
        if self.cuda:
            import torch

            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
            self._base = torch.cuda.memory_allocated()
        else:
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
            self.mib = (_status_kb("VmHWM") - self._base) / 1024


def _status_kb(key: str) -> int:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    return 0
