"""Benchmarks (``python -m blender_mrvm bench <name>``); each module writes CSV figures."""

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


def at_least(args, **minimums: int) -> None:
    """Refuse integer options below their minimum, every one named in one line (``at_least(args, repeats=1)``)."""
    from ..errors import InputError

    low = [f"--{k.replace('_', '-')} must be at least {m} (got {getattr(args, k)})"
           for k, m in minimums.items() if getattr(args, k) < m]
    if low:
        raise InputError("; ".join(low))


def write_csv(path: Path, rows: list[dict], fields: list[str] | None = None, quiet: bool = False) -> Path:
    """Write benchmark rows (dicts with the same keys) as CSV and say where."""
    path = Path(path)
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
