"""The benchmarks as a researcher uses them (review): a front that is the front (ties, NaN), the peak memory
as labelled under the CLI's allocator, CSVs that say where they came from, no silent NaN, and a sweep that can
make no point refused before --out is touched. bpy-free; each test takes seconds and asserts no timing."""

from __future__ import annotations

import csv
import math
import platform
import random
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.bench import tradeoff as tr


def _dominated(r: dict, others: list[dict]) -> bool:
    c, l = float(r["c"]), float(r["l"])
    return any(float(s["c"]) <= c and float(s["l"]) <= l and (float(s["c"]) < c or float(s["l"]) < l)
               for s in others if s is not r)


def _finite(r: dict) -> bool:
    try:
        return math.isfinite(float(r["c"])) and math.isfinite(float(r["l"]))
    except (TypeError, ValueError):
        return False


def test_pareto_is_the_brute_force_front_with_ties_nan_and_inf():
    """Against a brute-force front on made-up points: a NaN cost had sorted anywhere and put itself on the front
    (hiding real points behind its loss), an infinite cost too, and of two identical points only one was kept
    (neither dominates the other)."""
    assert [r["n"] for r in tr.pareto([{"c": float("nan"), "l": 0.1, "n": "nan"}, {"c": 2.0, "l": 0.2, "n": "a"}],
                                      "c", "l")] == ["a"]
    assert [r["n"] for r in tr.pareto([{"c": 1.0, "l": 0.2, "n": "a"}, {"c": 1.0, "l": 0.2, "n": "b"},
                                       {"c": 1.0, "l": 0.3, "n": "c"}, {"c": 2.0, "l": 0.2, "n": "d"}],
                                      "c", "l")] == ["a", "b"]
    assert tr.pareto([{"c": "nan", "l": "0.1"}, {"c": 1, "l": "inf"}, {"c": "", "l": 0.1}], "c", "l") == []
    rng = random.Random(0)
    for _ in range(2000):
        rows = [{"i": i, "c": rng.choice([1, 1, 2, 3, float("nan"), float("inf"), "", "nan"]),
                 "l": rng.choice([0.1, 0.2, 0.2, 0.3, float("nan"), "", "-inf"])} for i in range(rng.randint(1, 7))]
        ok = [r for r in rows if _finite(r)]
        want = sorted((float(r["c"]), float(r["l"]), r["i"]) for r in ok if not _dominated(r, ok))
        got = [(float(r["c"]), float(r["l"]), r["i"]) for r in tr.pareto(rows, "c", "l")]
        assert sorted(got) == want, rows
        assert got == sorted(got, key=lambda t: t[:2])  # sorted by cost, then loss


def _row(point: str, cpu, psnr, lpips) -> dict:
    return {"kind": "nerformer_mrvm", "checkpoint": "shipped:nerformer_mrvm", "preset": "balanced", "point": point,
            "cpu_seconds_per_view": cpu, "psnr": psnr, "ssim": 0.6, "lpips": lpips, "quality": "measured",
            "size": 32}


def test_front_names_the_points_a_nan_score_leaves_out_and_the_plot_survives_them(tmp_path, capsys):
    """A point whose PSNR / LPIPS (or CPU seconds) came out NaN was dropped from the fronts and the plot without a
    word; a NaN cost made the plot's axis NaN."""
    rows = [_row("a", 0.5, 20.0, 0.3), _row("nan score", 1.0, float("nan"), float("nan")),
            _row("nan cost", float("nan"), 21.0, 0.25), _row("b", 2.0, 22.0, 0.2)]
    tr.write_front(rows, tmp_path, 1.0)
    text = (tmp_path / "bench_tradeoff_front.md").read_text()
    assert "## Left out (no finite CPU seconds, PSNR or LPIPS)" in text
    assert ": nan score (" in text and ": nan cost (" in text
    assert "warning: 2 point(s) have no finite" in capsys.readouterr().out
    assert (tmp_path / "bench_tradeoff.png").stat().st_size > 0


def test_no_lpips_panel_says_it_was_not_measured(tmp_path):
    """--no-lpips left the plot's left half blank, with no title."""
    from PIL import Image

    tr.plot([_row("a", 0.5, 20.0, ""), _row("b", 2.0, 22.0, "")], tmp_path / "p.png")
    img = np.asarray(Image.open(tmp_path / "p.png").convert("L"))
    assert (img[:30, :500] < 128).any()  # the left panel's note


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc" or not Path("/proc/self/clear_refs").exists(),
                    reason="glibc malloc and Linux VmHWM")
def test_peak_memory_counts_what_the_warm_up_freed_under_the_clis_allocator():
    """`python -m blender_mrvm` keeps up to 256 MiB of freed heap mapped (threads.apply_malloc_defaults); the
    benches measured the peak of the renders after a warm-up above a resident set that already held the warm-up's
    freed blocks, so 160 MiB of 8 MiB blocks read as a few MiB. Now the memory is measured on one more render
    with the freed memory handed back first (PeakMemory(release=True)), outside the timed ones."""
    from blender_mrvm import threads
    from blender_mrvm.bench import PeakMemory

    if threads.apply_malloc_defaults() != "tuned":
        pytest.skip("the tuned allocator is not available here")

    def render():
        blocks = [np.ones(2 ** 20) for _ in range(20)]  # 20 x 8 MiB, below the 32 MiB mmap threshold: heap
        return {"s": sum(float(b[0]) for b in blocks)}

    _, t = tr._timed(render, "fp32", 2, "cpu")
    assert t["peak_extra_mib"] > 140
    with PeakMemory("cpu", release=True) as pm:
        render()
    assert pm.mib > 140


def test_a_peak_that_cannot_be_measured_is_an_empty_cell_not_nan(tmp_path, monkeypatch):
    """Where /proc/self/clear_refs cannot be written (no Linux, a locked-down container) PeakMemory gives NaN:
    `bench model` wrote 'nan' into peak_extra_mib (and `max` over NaN and numbers depends on their order)."""
    import blender_mrvm.bench as b
    from blender_mrvm.cli import main

    class NoPeak(b.PeakMemory):
        def __exit__(self, *exc):
            self.mib = float("nan")

    monkeypatch.setattr(b, "PeakMemory", NoPeak)
    monkeypatch.setattr("blender_mrvm.bench.model.PeakMemory", NoPeak)
    out = tmp_path / "m"
    assert main(["bench", "model", "--presets", "fast", "--views", "1", "--sizes", "8", "--repeats", "1",
                 "--threads", "1", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "bench_model.csv")))
    assert rows[0]["peak_extra_mib"] == ""
    assert "nan" not in (out / "bench_model.csv").read_text().lower()
    from blender_mrvm.bench import mib_cell

    assert mib_cell([float("nan"), 3.0]) == mib_cell([3.0, float("nan")]) == 3.0 and mib_cell([float("nan")]) == ""


def test_every_bench_csv_says_where_it_came_from(tmp_path):
    """A CSV read a month later had no date, command, code version or CPU model (bench profile: not even the
    torch version or the load)."""
    from blender_mrvm.bench import PROVENANCE_FIELDS
    from blender_mrvm.cli import main

    out = tmp_path / "p"
    assert main(["bench", "profile", "--presets", "fast", "--size", "8", "--out", str(out)]) == 0
    rows = list(csv.DictReader(open(out / "bench_profile.csv")))
    assert list(rows[0])[-len(PROVENANCE_FIELDS):] == list(PROVENANCE_FIELDS)
    r = rows[0]
    assert r["bench_command"] == (f"python -m blender_mrvm bench profile --out {out} --presets fast --size 8 "
                                  "--views 2 --threads 1")  # every option, defaults included
    assert r["bench_started_utc"].endswith("Z") and r["code_version"].startswith("0.") and r["torch_version"]
    assert r["cpu_model"] and int(r["cpu_count"]) >= 1 and r["python_version"] == platform.python_version()
    assert r["load_1min"] != ""
    assert len({row["bench_started_utc"] for row in rows}) == 1


def test_a_sweep_that_can_make_no_point_is_refused_before_out_is_touched(tmp_path, capsys):
    """Objects of 2 views leave no target beside the base point's 2 references: the bench made --out (with
    --force it removed the earlier results), loaded the model, then said only 'nothing was measured: no rows to
    write'. Now one line names why, exit 2, and --out is as it was."""
    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F
    from blender_mrvm.training.synthetic import make_sphere_dataset

    data = make_sphere_dataset(tmp_path / "ds", n_objects=1, n_views=2, resolution=8, seed=1)
    F.write_split(data, "test", F.read_split(data, "train"))
    args = ["bench", "tradeoff", "--data", str(data), "--checkpoints", "shipped:gpnr", "--axes", "base,samples",
            "--objects", "1", "--targets", "1", "--size", "8", "--repeats", "1", "--no-lpips"]
    assert main([*args, "--out", str(tmp_path / "new")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no point of --axes base,samples can be measured") and "have 2 view(s)" in err
    assert not (tmp_path / "new").exists()
    old = tmp_path / "old"
    old.mkdir()
    (old / "bench_tradeoff.csv").write_text("earlier\n")
    assert main([*args, "--out", str(old), "--force"]) == 2
    assert (old / "bench_tradeoff.csv").read_text() == "earlier\n"
    assert tr.candidate_points(["base", "refs"]) and any(tr.fits(p, 2) for p in tr.candidate_points(["base", "refs"]))


def _capture_run(rep: int, err, registered: str) -> dict:
    from blender_mrvm.bench.capture import STAGES

    return {"method": "ours", "images": 10, "repeat": rep, "width": 64, "height": 48, "subset": "arc",
            "matcher": "exhaustive", "max_features": 2048, "sift_first_octave": 0,
            **{f"{s}_s": 1.0 for s in STAGES}, "total_s": 1.0, **{f"{s}_cpu_s": 1.0 for s in STAGES},
            "total_cpu_s": 1.0, "registered": registered, "median_rot_deg": err, "median_centre_pct_radius": err,
            "load_1min": 1.0, "error": ""}


def test_capture_medians_over_repeats_do_not_depend_on_the_order_of_a_failed_run():
    """`bench capture` writes NaN errors for a run that registered too few photos; statistics.median over them
    depended on the runs' order (0.3 or NaN for the same three runs). A failed run now counts as the worst, and a
    median that falls on one is an empty cell."""
    from blender_mrvm.bench.capture import summarize

    nan = float("nan")
    runs = [_capture_run(0, 0.3, "10/10"), _capture_run(1, nan, "0/10"), _capture_run(2, 0.1, "10/10")]
    got = {summarize(order)[0]["median_rot_deg"] for order in (runs, runs[::-1], runs[1:] + runs[:1])}
    assert got == {0.3}
    worst = summarize([_capture_run(0, nan, "0/10"), _capture_run(1, "", "1/10"), _capture_run(2, 0.1, "10/10")])[0]
    assert worst["median_rot_deg"] == "" and worst["accurate"] is False


def test_bench_render_keeps_the_pairs_measured_before_ctrl_c(tmp_path, monkeypatch):
    """`bench render` wrote its CSV only at the end: Ctrl-C after an hour of renders kept nothing."""
    import argparse

    from blender_mrvm.bench import render as br

    calls = []

    def fake(mesh, out, engine, res, views, samples):
        calls.append(res)
        if res == 32:
            raise KeyboardInterrupt
        return 0.5

    monkeypatch.setattr(br, "naive_loop", fake)
    monkeypatch.setattr(br, "ours", fake)
    monkeypatch.setattr(br, "_mesh", lambda folder: folder / "m.ply")
    args = argparse.Namespace(out=tmp_path / "r", views=1, eevee_views=1, resolutions="16,32",
                              engines="BLENDER_WORKBENCH", samples=1, repeats=1, force=False)
    with pytest.raises(KeyboardInterrupt):
        br.run(args)
    rows = list(csv.DictReader(open(tmp_path / "r" / "bench_render.csv")))
    assert [(r["resolution"], r["method"]) for r in rows] == [("16", "naive_loop"), ("16", "render_dataset")]


def test_bench_train_measures_memory_on_a_step_of_its_own_with_the_freed_memory_released(tmp_path, monkeypatch):
    """The peak of `bench train` was taken over the timed steps, above a resident set holding what the warm-up
    freed; it is now one more step, after the timed ones, in a PeakMemory(release=True)."""
    from blender_mrvm.bench import PeakMemory
    from blender_mrvm.bench import train as bt
    from blender_mrvm.cli import main

    made = []

    class Spy(PeakMemory):
        def __init__(self, device="cpu", release=False):
            super().__init__(device)
            self.release = release
            made.append(self)

    monkeypatch.setattr(bt, "PeakMemory", Spy)
    out = tmp_path / "t"
    assert main(["bench", "train", "--presets", "fast", "--batches", "1x16", "--steps", "1", "--warmup", "1",
                 "--resolution", "8", "--out", str(out)]) == 0
    assert len(made) == 1 and made[0].release
    row = next(csv.DictReader(open(out / "bench_train.csv")))
    assert row["peak_extra_mib"] != "" and float(row["peak_extra_mib"]) >= 0


def test_sem2nerf_masks_of_another_size_are_refused_before_force_removes_the_earlier_results(tmp_path, capsys):
    """`bench tradeoff --checkpoints shipped:sem2nerf --force` on a set rendered at another size: --force had
    removed the earlier results, then the mask size was refused (nothing measured, nothing kept)."""
    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F
    from blender_mrvm.training.synthetic import make_sphere_dataset

    data = make_sphere_dataset(tmp_path / "ds", n_objects=1, n_views=4, resolution=8, seed=1)
    F.write_split(data, "test", F.read_split(data, "train"))
    old = tmp_path / "old"
    old.mkdir()
    (old / "bench_tradeoff.csv").write_text("earlier\n")
    assert main(["bench", "tradeoff", "--data", str(data), "--checkpoints", "shipped:sem2nerf", "--axes", "base",
                 "--objects", "1", "--targets", "1", "--size", "8", "--repeats", "1", "--no-lpips",
                 "--out", str(old), "--force"]) == 2
    assert "masks are 8x8 px" in capsys.readouterr().err
    assert (old / "bench_tradeoff.csv").read_text() == "earlier\n"
