"""`eval` follows the dataset's own SRN-style protocol: input/target ids from splits/eval_views.json,
test-split objects, per-category selection, both trivial baselines and the margin over the better one."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from blender_mrvm.errors import InputError
from blender_mrvm.models import vgg
from blender_mrvm.models.config import model_config
from blender_mrvm.models.metrics import psnr
from blender_mrvm.models.model import GeneralizableNeRF
from blender_mrvm.training.checkpoint import save_checkpoint
from blender_mrvm.training.evaluate import per_category, protocol_views, summarize
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
HAVE_WEIGHTS = (vgg.weights_dir() / vgg.VGG_FILE).is_file()
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
        "sampler": {"n_coarse": 4, "n_fine": 2}}


@pytest.fixture(scope="module")
def two_category_set(tmp_path_factory):
    """Categories 'red' (3 objects) and 'blue' (2), 6 views each; test split: 2 red + 1 blue objects."""
    root = tmp_path_factory.mktemp("evalset")
    make_sphere_dataset(root, n_objects=3, n_views=6, resolution=16, seed=1, category="red")
    make_sphere_dataset(root, n_objects=2, n_views=6, resolution=16, seed=2, category="blue")
    F.write_split(root, "train", ["red/obj000", "blue/obj000"])
    F.write_split(root, "test", ["red/obj001", "red/obj002", "blue/obj001"])
    F.atomic_write_json(root / "splits" / "eval_views.json", {
        "views": 6, "input_views_1": [4], "input_views_2": [4, 1],
        "target_views_1": [0, 1, 2, 3, 5], "target_views_2": [0, 3, 5]})
    return root


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    torch.manual_seed(0)
    cfg = model_config("fast", TINY)
    return save_checkpoint(tmp_path_factory.mktemp("run"), 3, GeneralizableNeRF(cfg), cfg, None)


def test_protocol_views_from_file_srn_and_error(two_category_set, tmp_path):
    assert protocol_views(two_category_set, 2) == ([4, 1], [0, 3, 5], str(two_category_set / "splits" / "eval_views.json"))
    assert protocol_views(two_category_set, 1)[:2] == ([4], [0, 1, 2, 3, 5])
    with pytest.raises(InputError, match="no input_views_3"):
        protocol_views(two_category_set, 3)
    assert protocol_views(tmp_path, 2, "srn")[:2] == ([64, 104], None)  # pixelNeRF's SRN ids
    with pytest.raises(InputError, match="pass --input-views"):
        protocol_views(tmp_path, 1, "ours")


def test_per_category_keeps_order_and_counts():
    items = ["a1", "b1", "a2", "a3", "c1", "b2"]
    assert per_category(items, lambda s: s[0], 1) == ["a1", "b1", "c1"]
    assert per_category(items, lambda s: s[0], 2) == ["a1", "b1", "a2", "c1", "b2"]
    assert per_category(items, lambda s: s[0], 0) == items


def test_gain_over_best_baseline():
    recs = [{"category": "a", "psnr": 25.0, "ssim": 0.9, "baseline_nearest": {"psnr": 18.0, "ssim": 0.7},
             "baseline_mean": {"psnr": 12.0, "ssim": 0.5}},
            {"category": "b", "psnr": 21.0, "ssim": 0.9, "baseline_nearest": {"psnr": 10.0, "ssim": 0.7},
             "baseline_mean": {"psnr": 16.0, "ssim": 0.5}}]
    r = summarize(recs)
    assert r["overall"]["best_baseline"] == "baseline_nearest"  # 14 vs 14 -> ties keep the first
    assert r["overall"]["psnr_gain_over_best_baseline"] == pytest.approx(23.0 - 14.0)
    assert r["per_category"]["b"]["best_baseline"] == "baseline_mean"
    assert r["per_category"]["b"]["psnr_gain_over_best_baseline"] == pytest.approx(5.0)


def test_eval_command_uses_dataset_protocol(two_category_set, checkpoint, tmp_path):
    out = tmp_path / "ev"
    args = ["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--out", str(out),
            "--threads", "1"]
    if not HAVE_WEIGHTS:
        args.append("--no-lpips")
    assert main(args) == 0
    rep = json.loads((out / "eval.json").read_text())
    p = rep["protocol"]
    assert p["input_views"] == [4, 1] and p["target_views"] == [0, 3, 5]
    assert p["objects"] == 3 and p["scored_views"] == 9
    assert rep["data"]["protocol_source"].endswith("eval_views.json") and rep["checkpoint"]["step"] == 3
    assert rep["device"] == ("cuda" if torch.cuda.is_available() else "cpu")  # --device auto
    assert {(v["category"], v["object"]) for v in rep["views"]} == {("red", "obj001"), ("red", "obj002"),
                                                                    ("blue", "obj001")}
    assert {v["view"] for v in rep["views"]} == {0, 3, 5}
    assert rep["per_category"]["red"]["n"] == 6 and rep["per_category"]["blue"]["n"] == 3
    # the mean-colour baseline, recomputed independently from the files
    obj = two_category_set / "blue" / "obj001"
    refs = np.stack([F.read_png(obj / "rgb" / f"{i:06d}.png")[..., :3] for i in (4, 1)]).astype(np.float32) / 255
    gt = F.read_png(obj / "rgb" / "000003.png")[..., :3].astype(np.float32) / 255
    want = float(psnr(torch.from_numpy(np.broadcast_to(refs.reshape(-1, 3).mean(0), gt.shape).copy()),
                      torch.from_numpy(gt))[0])
    got = [v for v in rep["views"] if v["object"] == "obj001" and v["category"] == "blue" and v["view"] == 3][0]
    assert got["baseline_mean"]["psnr"] == pytest.approx(want, abs=1e-4)
    o = rep["overall"]
    best = max(o["baseline_nearest"]["psnr"], o["baseline_mean"]["psnr"])
    assert o["psnr_gain_over_best_baseline"] == pytest.approx(o["psnr"] - best)
    if HAVE_WEIGHTS:
        assert 0 <= o["lpips"] < 1 and 0 <= o["baseline_mean"]["lpips"] < 1
    md = [l for l in (out / "eval.md").read_text().splitlines() if l.startswith("|")]
    assert len(md) == 2 + 2 + 1 and md[-1].startswith("| **overall** | 9 | ")  # header, red, blue, overall
    assert f"| {o['psnr_gain_over_best_baseline']:.2f} |" in md[-1]
    assert f"background pixels" in (out / "eval.md").read_text()  # the sets have masks: the opacity line
    grid = F.read_png(out / "eval_grid.png")  # one row per category first: red and blue, then the 3rd object
    assert grid.shape[0] == 3 * (16 + 2) + 2 and grid.shape[1] == 4 * (16 + 2) + 2

    # paired comparison with another evaluation (here: the same checkpoint -> zero differences)
    out2 = tmp_path / "ev2"
    assert main(["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--no-lpips",
                 "--out", str(out2), "--threads", "1", "--compare-to", str(out / "eval.json")]) == 0
    cmp = json.loads((out2 / "compare.json").read_text())
    assert cmp["overall"]["views"] == 9 and cmp["overall"]["psnr"]["diff"] == pytest.approx(0.0, abs=1e-9)
    assert cmp["overall"]["psnr"]["objects"] == 3 and "lpips" not in cmp["overall"]

    # 1-view protocol and one object per category
    out1 = tmp_path / "ev1"
    assert main(["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--n-inputs", "1",
                 "--max-objects-per-category", "1", "--no-lpips", "--out", str(out1), "--threads", "1"]) == 0
    rep1 = json.loads((out1 / "eval.json").read_text())
    assert rep1["protocol"]["input_views"] == [4] and rep1["protocol"]["scored_views"] == 2 * 5
    assert {v["object"] for v in rep1["views"]} == {"obj001"} and set(rep1["per_category"]) == {"red", "blue"}


def test_eval_precision_is_recorded_and_moves_the_scores_a_little(two_category_set, checkpoint, tmp_path, capsys):
    """--precision: fp32 by default (the protocol's), recorded in eval.json; int8 (the CPU) and bf16 score the same
    views to within a fraction of a dB (the metrics stay float32); fp16 on the CPU and int8 with adaptation are
    one-line errors before anything is written."""
    base = ["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--no-lpips", "--threads",
            "1", "--device", "cpu"]
    reps = {}
    for p in ("default", "int8", "bf16"):
        out = tmp_path / p
        assert main([*base, "--out", str(out), *([] if p == "default" else ["--precision", p])]) == 0
        reps[p] = json.loads((out / "eval.json").read_text())
    assert [reps[p]["precision"] for p in reps] == ["fp32", "int8", "bf16"]
    for p in ("int8", "bf16"):
        diffs = [abs(a["psnr"] - b["psnr"]) for a, b in zip(reps["default"]["views"], reps[p]["views"])]
        assert len(diffs) == 9 and max(diffs) < 0.5, (p, diffs)
    capsys.readouterr()
    for extra, msg in ((["--precision", "fp16"], "fp16 needs a GPU"),
                       (["--precision", "int8", "--adapt-steps", "2"], "do not combine")):
        out = tmp_path / "bad"
        assert main([*base, "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and msg in err[0] and not out.exists(), err


def test_eval_bad_protocol_request(two_category_set, checkpoint, tmp_path, capsys):
    assert main(["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--n-inputs", "5",
                 "--no-lpips", "--out", str(tmp_path / "e")]) == 2
    assert "no input_views_5" in capsys.readouterr().err
    assert main(["eval", "--checkpoint", str(checkpoint), "--data", str(tmp_path / "nope"), "--no-lpips",
                 "--out", str(tmp_path / "e")]) == 2
    assert "does not exist" in capsys.readouterr().err


def test_compare_reports_pairs_views_and_uses_objects_as_units():
    from blender_mrvm.training.evaluate import compare_reports

    def rep(vals):
        return {"views": [{"category": c, "object": o, "view": v, "psnr": p, "ssim": 0.5, "lpips": lp}
                          for (c, o, v, p, lp) in vals]}
    a = rep([("x", "o1", 0, 20.0, 0.1), ("x", "o1", 1, 22.0, 0.1), ("x", "o2", 0, 18.0, 0.3), ("y", "o3", 0, 30.0, 0.2)])
    b = rep([("x", "o1", 0, 19.0, 0.2), ("x", "o1", 1, 19.0, 0.2), ("x", "o2", 0, 19.0, 0.2), ("y", "o3", 0, 29.0, 0.2),
             ("y", "o9", 0, 99.0, 0.0)])  # o9 is scored only in b: ignored
    c = compare_reports(a, b)
    o = c["overall"]
    assert o["views"] == 4 and o["psnr"]["objects"] == 3
    d = np.array([2.0, -1.0, 1.0])  # per-object mean differences: o1 (1+3)/2, o2, o3
    assert o["psnr"]["diff"] == pytest.approx(d.mean()) and o["psnr"]["se_objects"] == pytest.approx(d.std(ddof=1) / 3 ** 0.5)
    assert o["psnr"]["wins"] == pytest.approx(2 / 3) and o["lpips"]["wins"] == pytest.approx(1 / 3)  # lower is better
    assert c["per_category"]["y"]["psnr"]["se_objects"] is None and c["per_category"]["x"]["ssim"]["diff"] == 0.0
    with pytest.raises(InputError):
        compare_reports(a, rep([("z", "q", 0, 1.0, 0.0)]))


def test_compare_refuses_other_data_and_other_references():
    """`eval --compare-to` pairs views by (category, object, view); names repeat across data sets (a turntable and a
    sphere-rig render of one library) and input protocols, so a comparison of other data, another split or views
    rendered from other inputs is refused, naming what differs. Reports without the per-view inputs (written
    before they were kept) are compared on what they record: their protocol's input views, their data."""
    from blender_mrvm.training.evaluate import check_comparable, compare_reports

    def rep(root, inputs, split="test", **protocol):
        return {"data": {"root": root, "split": split, "format": "ours"}, "protocol": protocol,
                "views": [{"category": "c", "object": "o", "view": 3, "inputs": inputs, "psnr": 20.0}]}

    assert compare_reports(rep("/d/sn", [0, 2]), rep("/d/sn/", [0, 2]))["overall"]["views"] == 1
    with pytest.raises(InputError, match="root /d/sn against /d/sn_sphere"):
        compare_reports(rep("/d/sn", [0, 2]), rep("/d/sn_sphere", [0, 2]))
    with pytest.raises(InputError, match="split test against train"):
        compare_reports(rep("/d/sn", [0, 2]), rep("/d/sn", [0, 2], split="train"))
    with pytest.raises(InputError, match=r"view 3 of c/o from other input views \(\[0, 2\] against \[2\]\)"):
        compare_reports(rep("/d/sn", [0, 2]), rep("/d/sn", [2]))
    old = lambda iv: {"protocol": {"input_views": iv},  # noqa: E731  (an eval.json of before: no data, no inputs)
                      "views": [{"category": "c", "object": "o", "view": 3, "psnr": 19.0}]}
    assert compare_reports(rep("/d/sn", [0, 2], input_views=[0, 2]), old([0, 2]))["overall"]["psnr"]["diff"] == 1.0
    with pytest.raises(InputError, match=r"protocol input_views \[0, 2\] against \[0\]"):
        compare_reports(rep("/d/sn", [0, 2], input_views=[0, 2]), old([0]))
    check_comparable({"data": {"root": "/d/sn", "split": "test"}}, old([0]))  # nothing recorded to tell them apart


def test_eval_compare_to_checks_the_pairing_and_force_drops_a_stale_comparison(two_category_set, checkpoint, tmp_path,
                                                                               capsys):
    import shutil

    base = ["eval", "--checkpoint", str(checkpoint), "--no-lpips", "--threads", "1", "--max-objects", "1"]
    a = tmp_path / "a"
    assert main([*base, "--data", str(two_category_set), "--out", str(a)]) == 0
    rec = json.loads((a / "eval.json").read_text())
    assert rec["data"]["root"] == str(two_category_set.resolve()) and rec["data"]["n_inputs"] == 2
    assert [v["inputs"] for v in rec["views"]] == [[4, 1]] * 3
    # the same object names in another set: refused before anything is scored
    other_set = tmp_path / "copy"
    shutil.copytree(two_category_set, other_set)
    capsys.readouterr()
    b = tmp_path / "b"
    assert main([*base, "--data", str(other_set), "--out", str(b), "--compare-to", str(a / "eval.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "of different data: root" in err[0] and not b.exists(), err
    # another input protocol on the same set: the views are scored, the pairing is refused
    assert main([*base, "--data", str(two_category_set), "--n-inputs", "1", "--out", str(b),
                 "--compare-to", str(a / "eval.json")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "from other input views ([4] against [4, 1])" in err[0], err
    assert (b / "eval.json").is_file() and not (b / "compare.json").exists()
    # a comparison that pairs, then a rerun with --force and no --compare-to: the old compare.json goes
    assert main([*base, "--data", str(two_category_set), "--out", str(b), "--force",
                 "--compare-to", str(a / "eval.json")]) == 0
    assert (b / "compare.json").is_file()
    assert main([*base, "--data", str(two_category_set), "--out", str(b), "--force"]) == 0
    assert sorted(p.name for p in b.iterdir()) == ["eval.json", "eval.md", "eval_grid.png"]


def test_eval_with_nothing_to_score_is_an_error(two_category_set, checkpoint, tmp_path, capsys):
    out = tmp_path / "e"
    assert main(["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--no-lpips",
                 "--input-views", "0,1,2,3,4,5", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing to score" in err[0] and not out.exists(), err


def test_eval_stdout_is_one_json_line_with_the_comparison_inside(two_category_set, checkpoint, tmp_path, capsys):
    """eval's stdout had been an indented JSON report (~30 lines) and, with --compare-to, a second indented document
    after it: neither `json.load(stdout)` nor `tail -n1 | jq` read it. Now: one JSON line, the comparison inside."""
    base = ["eval", "--checkpoint", str(checkpoint), "--data", str(two_category_set), "--no-lpips", "--threads", "1",
            "--max-objects", "1", "--max-targets", "1"]
    a, b = tmp_path / "a", tmp_path / "b"
    capsys.readouterr()
    assert main([*base, "--out", str(a)]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) == 1, out
    rep = json.loads(out)
    assert rep["out"] == str(a) and rep["overall"]["n"] == 1 and "compare" not in rep
    assert main([*base, "--out", str(b), "--compare-to", str(a / "eval.json")]) == 0
    out = capsys.readouterr().out
    assert len(out.splitlines()) == 1, out
    rep = json.loads(out)
    assert rep["out"] == str(b) and rep["overall"]["n"] == 1
    c = rep["compare"]
    assert c["file"] == str(b / "compare.json") and c["this"] == c["other"] == str(checkpoint)
    assert c["this_minus_other"] == json.loads((b / "compare.json").read_text())["overall"]
    assert c["this_minus_other"]["psnr"]["diff"] == pytest.approx(0.0, abs=1e-9)
