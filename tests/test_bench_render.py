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


def test_bench_render_checks_its_engines_and_its_earlier_results_first(tmp_path, capsys):
    """--engines FOO had been a TypeError traceback after the first engine's renders, ',' an IndexError in write_csv
    after it emptied the CSV; an --out holding bench_render.csv is refused unless --force."""
    out = tmp_path / "b"
    for engines, msg in (("FOO", "--engines: unknown FOO"), (",", "--engines: none given")):
        assert main(["bench", "render", "--out", str(out), "--engines", engines]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0] and not out.exists(), err
    out.mkdir()
    (out / "bench_render.csv").write_text("earlier")
    assert main(["bench", "render", "--out", str(out), "--engines", "CYCLES"]) == 2
    assert "already holds this bench's results (bench_render.csv)" in capsys.readouterr().err
    assert (out / "bench_render.csv").read_text() == "earlier"
