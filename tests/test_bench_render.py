"""The render benchmark runs and writes its CSV (figures are measured by `make bench`, not asserted)."""

import csv

import pytest

from blender_mrvm.cli import main


@pytest.mark.slow
def test_bench_render_writes_csv(tmp_path):
    assert main(["bench", "render", "--out", str(tmp_path), "--views", "2", "--resolutions", "16",
                 "--engines", "CYCLES,BLENDER_WORKBENCH", "--samples", "1"]) == 0
    rows = list(csv.DictReader(open(tmp_path / "bench_render.csv")))
    assert [(r["engine"], r["method"]) for r in rows] == [
        ("CYCLES", "naive_loop"), ("CYCLES", "render_dataset"),
        ("BLENDER_WORKBENCH", "naive_loop"), ("BLENDER_WORKBENCH", "render_dataset")]
    assert all(float(r["views_per_second"]) > 0 for r in rows)
