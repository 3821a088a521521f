"""make-shapenet: the papers' splits (all / unseen), the fixed evaluation views, and a tiny real run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from blender_mrvm.commands import make_shapenet as M
from blender_mrvm.commands.render_dataset import parse_shard
from blender_mrvm.errors import InputError


def test_unseen_setting_trains_on_three_and_tests_on_ten():
    g = M.plan("unseen", 10)
    cats = lambda srcs: {s.split(":")[1] for s in srcs}  # noqa: E731
    assert cats(g["train"]) == {"airplane", "car", "chair"} == cats(g["val"])
    assert len(cats(g["test"])) == 10 and not cats(g["test"]) & {"airplane", "car", "chair"}
    assert len(g["train"]) == 27 and len(g["val"]) == 3 and len(g["test"]) == 100


def test_all_setting_splits_every_category():
    g = M.plan("all", 10)
    for split, n in (("train", 7), ("val", 1), ("test", 2)):
        per = {}
        for s in g[split]:
            per[s.split(":")[1]] = per.get(s.split(":")[1], 0) + 1
        assert len(per) == 13 and set(per.values()) == {n}
    assert not set(g["train"]) & set(g["test"])


def test_eval_views_are_fixed_and_disjoint_from_targets():
    p = M.eval_views(24)
    assert p["input_views_1"] == [3] and p["input_views_2"] == [3, 15]
    assert set(p["input_views_2"]).isdisjoint(p["target_views_2"])
    assert len(p["target_views_1"]) == 23 and len(p["target_views_2"]) == 22


@pytest.mark.parametrize("call,match", [
    (lambda: M.plan("all", 0), "objects-per-category"),
    (lambda: M.plan("some", 3), "unknown setting"),
    (lambda: M.plan("all", 3, -1), "must not be negative"),
    (lambda: parse_shard("3/2"), "shard"),
    (lambda: parse_shard("x"), "shard"),
    (lambda: M.eval_views(2), "at least 3 views"),
    # the last seed past the range was found only after the other objects rendered
    (lambda: M.plan("all", 2, 2 ** 63 - 1), r"reaches seed 9223372036854775808; seeds must be below 2\*\*63"),
])
def test_bad_arguments_are_clear_errors(call, match):
    with pytest.raises(InputError, match=match):
        call()


@pytest.mark.slow
def test_tiny_unseen_set_renders_with_splits_and_part_masks(bpy_empty, tmp_path):
    import numpy as np

    from blender_mrvm.cli import main
    from blender_mrvm.datasets.format import read_png, read_split
    from blender_mrvm.scene.procedural import PART_LABELS

    out = tmp_path / "sn"
    code = main(["make-shapenet", "--setting", "unseen", "--objects-per-category", "1", "--views", "4",
                 "--resolution", "16", "--samples", "1", "--out", str(out)])
    assert code == 0
    assert read_split(out, "train") == ["airplane/airplane_000000", "car/car_000000", "chair/chair_000000"]
    test = read_split(out, "test")
    assert len(test) == 10 and "bench/bench_000000" in test
    proto = json.loads((out / "splits" / "eval_views.json").read_text())
    assert proto["input_views_1"] == [0] and proto["input_views_2"] == [0, 2] and proto["setting"] == "unseen"
    lines = (out / "splits" / "test_views.lst").read_text().splitlines()
    assert lines[0] == f"{test[0]} 0 | 0 2" and len(lines) == 10
    meta = json.loads((out / "chair" / "chair_000000" / "meta.json").read_text())
    ids = set()
    for v in range(4):
        ids |= set(np.unique(read_png(out / "chair" / "chair_000000" / "mask" / f"{v:06d}.png")).tolist())
    ids.discard(0)
    assert ids and all(PART_LABELS[i].startswith("chair/") for i in ids)
    assert {str(i) for i in ids} <= set(meta["labels"])

    # --force renders every split again at the new settings (it reached the first split only: the test split's
    # objects were refused with "use --force" on every rerun)
    code = main(["make-shapenet", "--setting", "unseen", "--objects-per-category", "1", "--views", "4",
                 "--resolution", "12", "--samples", "1", "--force", "--out", str(out)])
    assert code == 0
    assert json.loads((out / "bench" / "bench_000000" / "meta.json").read_text())["settings"]["resolution"] == [12, 12]
    assert len(read_split(out, "test")) == 10
    # Another setting into the same folder is another plan: refused before rendering without --force (shards of
    # two plans mixed their objects into one set); with it, the finished objects move to the splits this plan gives
    # them (they kept their old split, so the unseen protocol's test categories were trained on, or the other way)
    argv = ["make-shapenet", "--setting", "all", "--objects-per-category", "1", "--views", "4",
            "--resolution", "12", "--samples", "1", "--out", str(out)]
    assert main(argv) == 2
    code = main(argv + ["--force"])
    assert code == 0
    assert len(read_split(out, "train")) == 13 and read_split(out, "test") == []
    assert json.loads((out / "bench" / "bench_000000" / "meta.json").read_text())["split"] == "train"


def test_a_seed_range_past_the_limit_is_refused_before_any_render(tmp_path, capsys):
    """make-shapenet and preview-library found a last seed past 2**63 only after rendering every seed before it."""
    from blender_mrvm.cli import main

    assert main(["make-shapenet", "--seed", str(2 ** 63 - 1), "--objects-per-category", "2", "--views", "3",
                 "--resolution", "8", "--out", str(tmp_path / "d")]) == 2
    assert "seeds must be below 2**63" in capsys.readouterr().err and not (tmp_path / "d").exists()
    assert main(["preview-library", "--first-seed", str(2 ** 63 - 2), "--seeds", "3", "--categories", "chair",
                 "--out", str(tmp_path / "p.png")]) == 2
    assert "seeds must be below 2**63" in capsys.readouterr().err and not (tmp_path / "p.png").exists()


def test_a_plan_without_held_out_objects_says_so(tmp_path, capsys, monkeypatch):
    """--objects-per-category 1 (or below 10 with unseen) gives empty val or test lists: legal, but eval later found
    nothing to score without a word here."""
    from blender_mrvm.cli import main

    monkeypatch.setattr(M, "render_configs", lambda args: [])  # the plan and its note alone: nothing rendered
    import blender_mrvm.scene.render as R

    monkeypatch.setattr(R, "write_splits", lambda *a, **k: {"train": [], "val": [], "test": []})
    main(["make-shapenet", "--objects-per-category", "1", "--views", "3", "--resolution", "8",
          "--out", str(tmp_path / "d")])
    assert "gives no val and no test objects" in capsys.readouterr().err
    main(["make-shapenet", "--objects-per-category", "10", "--views", "3", "--resolution", "8",
          "--out", str(tmp_path / "e")])
    assert "gives no" not in capsys.readouterr().err


def test_preview_library_refuses_zero_samples(tmp_path, capsys):
    """Cycles at 0 samples wrote a sheet of empty tiles without a word."""
    from blender_mrvm.cli import main

    assert main(["preview-library", "--engine", "CYCLES", "--samples", "0", "--seeds", "1", "--categories", "chair",
                 "--out", str(tmp_path / "p.png")]) == 2
    assert "--samples must be at least 1" in capsys.readouterr().err and not (tmp_path / "p.png").exists()


# ---- shards (--shard i/n): the plan recorded in splits/plan.json -------------------------------------------------

TINY = ["make-shapenet", "--views", "3", "--resolution", "8", "--engine", "BLENDER_WORKBENCH"]


def _summary(capsys) -> tuple[str, str]:
    cap = capsys.readouterr()
    return next(line for line in cap.out.splitlines() if line.startswith("wrote ")), cap.err


@pytest.mark.slow
def test_a_shard_says_how_much_of_the_plan_is_finished_and_which_shards_remain(bpy_empty, tmp_path, capsys,
                                                                                 monkeypatch):
    """After --shard 0/2 alone the summary said '13 train, 0 val, 0 test objects' while the lists held 7; shards of
    another count (1/3, 2/3) ended with 11 of 13 listed and no word. The summary names the folder by its absolute
    path (it printed --out as given, as render-dataset did)."""
    from blender_mrvm.cli import main
    from blender_mrvm.datasets.format import read_split

    out = tmp_path / "sn"
    monkeypatch.chdir(tmp_path)
    argv = TINY + ["--objects-per-category", "1", "--out", "sn"]
    assert main(argv + ["--shard", "0/2"]) == 0
    line, err = _summary(capsys)
    assert line.startswith(f"wrote {out.resolve()} (")
    assert "7 of 13 planned objects finished" in line and line.endswith("run the other shards: --shard 1/2")
    assert "the split lists hold the 7 finished objects only" in err
    assert len(read_split(out, "train")) == 7
    rec = json.loads((out / "splits" / M.PLAN_FILE).read_text())  # the plan: its parameters and every object
    assert (rec["setting"], rec["objects_per_category"], rec["seed"]) == ("all", 1, 0) and len(rec["categories"]) == 13
    assert len(rec["objects"]["train"]) == 13 and "chair/chair_000000" in rec["objects"]["train"]
    missing, planned = M.planned_but_unlisted(out, "train")  # what a reader of the set (train, eval) can ask
    assert planned == 13 and len(missing) == 6
    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.errors import InputError

    with pytest.raises(InputError, match=r"half-rendered: 6 of 13 objects make-shapenet planned for split 'train'"):
        load_dataset(out, "train")  # train and eval took the 7 finished objects as the whole set
    # shards of another count: the summary names the shards of that count still to run
    assert main(argv + ["--shard", "1/3"]) == 0
    line, _ = _summary(capsys)
    assert "9 of 13 planned objects finished" in line and line.endswith("--shard 0/3 --shard 2/3")
    assert main(argv + ["--shard", "2/3"]) == 0
    line, _ = _summary(capsys)
    assert "11 of 13 planned objects finished" in line and line.endswith("run the other shards: --shard 0/3")
    assert main(argv + ["--shard", "0/3"]) == 0
    line, err = _summary(capsys)
    assert "(all: 13 train, 0 val, 0 test objects;" in line and "planned" not in line and "finished objects" not in err
    assert M.planned_but_unlisted(out, "train") == ([], 13)


@pytest.mark.slow
def test_a_shard_of_another_plan_is_refused_before_rendering(bpy_empty, tmp_path, capsys, monkeypatch):
    """Shards run with another --objects-per-category mixed two plans into one folder without a word (val.lst held
    objects the current plan has no val for, categories without a test object)."""
    from blender_mrvm.cli import main
    from blender_mrvm.datasets.format import read_split
    import blender_mrvm.scene.render as R

    out = tmp_path / "sn"
    base = TINY + ["--out", str(out)]
    assert main(base + ["--objects-per-category", "2", "--shard", "1/2"]) == 0
    capsys.readouterr()
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    render = R.render_dataset

    def no_render(cfg):
        raise AssertionError("rendered before the plan was compared")

    monkeypatch.setattr(R, "render_dataset", no_render)
    for extra, named in ((["--objects-per-category", "3", "--shard", "0/2"], "--objects-per-category 2 there, 3 here"),
                         (["--objects-per-category", "2", "--seed", "5"], "--seed 0 there, 5 here"),
                         (["--objects-per-category", "10", "--setting", "unseen"], "--setting all there, unseen here")):
        assert main(base + extra) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and err.startswith("error: ") and named in err
        assert "--force" in err and "another folder" in err
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before  # nothing written, nothing rendered
    monkeypatch.setattr(R, "render_dataset", render)

    # --force replaces the plan. Its seed-1 objects are train (test in the old plan, where shard 1/2 finished
    # them) and in its shard 1/2: they stay out of the lists until that shard moves them (test.lst held them)
    assert main(base + ["--objects-per-category", "3", "--shard", "0/2", "--force"]) == 0
    line, err = _summary(capsys)
    assert "plan replaces the one recorded in" in err and "(--objects-per-category 2 there, 3 here)" in err
    assert "20 of 39 planned objects finished (13 of 26 train, 7 of 13 test)" in line
    assert line.endswith("run the other shards: --shard 1/2")
    rec = json.loads((out / "splits" / M.PLAN_FILE).read_text())
    assert rec["objects_per_category"] == 3
    for split in ("train", "test"):
        assert set(read_split(out, split)) <= set(rec["objects"][split])
    assert not [k for k in read_split(out, "test") if k.endswith("_000001")]
    assert main(base + ["--objects-per-category", "2", "--shard", "0/2"]) == 2  # the old plan's shards: refused
    assert "--objects-per-category 3 there, 2 here" in capsys.readouterr().err
    assert main(base + ["--objects-per-category", "3", "--shard", "1/2"]) == 0
    line, _ = _summary(capsys)
    assert "(all: 26 train, 0 val, 13 test objects;" in line


@pytest.mark.slow
def test_a_dataset_without_a_recorded_plan_records_it(bpy_empty, tmp_path, capsys):
    """Datasets rendered before plans were recorded go on: the next shard records its plan."""
    from blender_mrvm.cli import main

    out = tmp_path / "sn"
    argv = TINY + ["--objects-per-category", "1", "--out", str(out)]
    assert main(argv + ["--shard", "0/2"]) == 0
    (out / "splits" / M.PLAN_FILE).unlink()
    capsys.readouterr()
    assert main(argv + ["--shard", "1/2"]) == 0
    line, _ = _summary(capsys)
    assert "(all: 13 train, 0 val, 0 test objects;" in line
    assert json.loads((out / "splits" / M.PLAN_FILE).read_text())["objects_per_category"] == 1
    assert main(TINY + ["--objects-per-category", "2", "--shard", "0/2", "--out", str(out)]) == 2


def _plan(**kw):
    from types import SimpleNamespace

    args = SimpleNamespace(**{"setting": "all", "objects_per_category": 2, "seed": 0, **kw})
    g = M.plan(args.setting, args.objects_per_category, args.seed)
    keys = {split: [src.split(":")[1] + "/" + src.replace(":", "_") for src in srcs] for split, srcs in g.items()}
    return M.plan_record(args, keys)


def test_plans_differ_by_the_parameter_named(tmp_path):
    """Every parameter that moves objects between splits makes another plan (bpy-free)."""
    from blender_mrvm.errors import OutputError

    a = _plan()
    assert M.plan_difference(a, _plan()) is None
    assert M.plan_difference(a, _plan(objects_per_category=3)) == "--objects-per-category 2 there, 3 here"
    assert M.plan_difference(a, _plan(seed=4)) == "--seed 0 there, 4 here"
    assert M.plan_difference(a, _plan(setting="unseen")) == "--setting all there, unseen here"
    assert "categories: 12 there" in M.plan_difference(dict(a, categories=a["categories"][:12]), a)
    assert "split rule" in M.plan_difference(dict(a, split_rule="per category: 30% to test"), a)
    moved = dict(a, objects={"train": a["objects"]["test"], "val": [], "test": a["objects"]["train"]})
    assert "other objects" in M.plan_difference(moved, a)
    # recorded once: a shard that finds another plan there (one starting at the same moment) is refused, the same
    # plan passes, --force replaces it
    M._record_plan(tmp_path, a, force=False)
    assert json.loads((tmp_path / "splits" / M.PLAN_FILE).read_text()) == a
    M._record_plan(tmp_path, _plan(), force=False)
    with pytest.raises(OutputError, match="--seed 0 there, 1 here"):
        M._record_plan(tmp_path, _plan(seed=1), force=False)
    M._record_plan(tmp_path, _plan(seed=1), force=True)
    assert json.loads((tmp_path / "splits" / M.PLAN_FILE).read_text())["seed"] == 1
    assert [p.name for p in (tmp_path / "splits").iterdir()] == [M.PLAN_FILE]  # no temporary left behind


@pytest.mark.slow
def test_the_protocol_files_are_written_with_the_dataset_root_held(bpy_empty, tmp_path, monkeypatch):
    """A render shard starting sweeps the root's temporaries (a killed run's) under the root's hold; make-shapenet wrote
    splits/eval_views.json outside it, so a shard of a cluster array starting at that moment could remove its
    temporary file before the rename (a traceback, the protocol file missing)."""
    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F

    out = tmp_path / "sn"
    held_while_writing = []
    real = F.atomic_write_json

    def write(path, obj, *a, **k):
        if Path(path).name == "eval_views.json" and Path(path).parent.parent == out:
            held_while_writing.append((out / ".lock").is_file())
        return real(path, obj, *a, **k)

    monkeypatch.setattr(F, "atomic_write_json", write)
    assert main(TINY + ["--objects-per-category", "1", "--shard", "0/13", "--out", str(out)]) == 0
    assert held_while_writing == [True]
