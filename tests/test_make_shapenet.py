"""make-shapenet: the papers' splits (all / unseen), the fixed evaluation views, and a tiny real run."""

from __future__ import annotations

import json

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
    # Another setting into the same folder: the finished objects move to the splits this plan gives them (they
    # kept their old split, so the unseen protocol's test categories were trained on, or the other way round)
    code = main(["make-shapenet", "--setting", "all", "--objects-per-category", "1", "--views", "4",
                 "--resolution", "12", "--samples", "1", "--out", str(out)])
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
