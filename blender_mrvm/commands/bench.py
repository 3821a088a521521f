"""Benchmarks: ``python -m blender_mrvm bench <name> ...`` writes its figures to CSV (+ PNG).

Each benchmark is a module ``blender_mrvm/bench/<name>.py`` with ``add_arguments(parser)`` and
``run(args) -> int``. They are measurements, not tests: run them on a quiet machine.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
from pathlib import Path

BENCH_DIR = Path(__file__).resolve().parents[1] / "bench"


def available() -> list[str]:
    return sorted(m.name for m in pkgutil.iter_modules([str(BENCH_DIR)]) if not m.name.startswith("_"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="bench", metavar="NAME")
    sub.required = True
    for name in available():
        mod = importlib.import_module(f"..bench.{name}", __package__)
        bp = sub.add_parser(name, help=(mod.__doc__ or name).strip().splitlines()[0],
                            description=(mod.__doc__ or "").strip())
        mod.add_arguments(bp)
        bp.add_argument("--force", action="store_true",
                        help="replace this bench's earlier results in --out (removed when the measuring starts)")
        bp.set_defaults(_bench=mod, _bench_parser=bp)


def command_line(args) -> str:
    """``python -m blender_mrvm bench NAME`` with every option of that bench at the value it ran with (defaults
    included, so the line repeats the run even after a default changes): what each CSV row records
    (``bench.PROVENANCE_FIELDS``)."""
    import shlex

    words = ["python", "-m", "blender_mrvm", "bench", str(args.bench)]
    parser = getattr(args, "_bench_parser", None)
    for a in (parser._actions if parser is not None else []):
        if not a.option_strings or a.dest in ("help", "force") or not hasattr(args, a.dest):
            continue
        v, flag = getattr(args, a.dest), max(a.option_strings, key=len)
        if isinstance(a, (argparse._StoreTrueAction, argparse._StoreFalseAction)):
            words += [flag] if v != a.default else []
        elif v is not None:
            words += [flag, str(v)]
    return " ".join(shlex.quote(w) for w in words)


def run(args) -> int:
    # every bench writes its figures into --out when it ends: a file or an unwritable place there is refused now,
    # not after the measurements (it had raised FileExistsError at the end of the run)
    if getattr(args, "out", None) is not None:
        from ..guards import check_folder_writable

        check_folder_writable(Path(args.out), "bench output folder")
        # and its earlier results: kept unless --force (they had been overwritten, or mixed with a stopped rerun's)
        from ..bench import check_results

        check_results(Path(args.out), getattr(args._bench, "RESULTS", ()), args.force)
    from ..bench import begin

    begin(command_line(args))
    return int(args._bench.run(args) or 0)
