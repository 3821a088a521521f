"""Benchmarks (``python -m blender_mrvm bench <name>``); each module writes CSV figures."""

from __future__ import annotations

import csv
from pathlib import Path


def write_csv(path: Path, rows: list[dict], fields: list[str] | None = None) -> Path:
    """Write benchmark rows (dicts with the same keys) as CSV and say where."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields or list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {path}")
    return path
