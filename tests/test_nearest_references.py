"""Many references (a dense capture): `synthesize` takes up to MAX_POOL references and renders each target
from its K nearest (`--nearest`, or the model's most when there are more than it takes); `eval --nearest K`
scores each protocol target from its K nearest other views. Bad counts are one line, nothing written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm import synthesis as S
from blender_mrvm.cli import main
from blender_mrvm.datasets import format as F
from blender_mrvm.datasets.loaders import load_ours
from blender_mrvm.datasets.novel_views import MAX_POOL, parse_views
from blender_mrvm.errors import InputError
from blender_mrvm.training.synthetic import make_sphere_dataset

from test_synthesize import tiny_checkpoint

torch.set_num_threads(1)
N_VIEWS = 14  # more than a model takes (10)


@pytest.fixture(scope="module")
def dense(tmp_path_factory):
    root = tmp_path_factory.mktemp("dense")
    data = make_sphere_dataset(root / "data", n_objects=1, n_views=N_VIEWS, resolution=12, seed=3)
    return root, data / "spheres" / "obj000", tiny_checkpoint(root / "run")


def _pool_nearest(obj: Path, rep: dict, pool: list[int], target: dict, k: int) -> list[int]:
    """The ``k`` views of ``pool`` nearest the target, by the rule synthesis uses, recomputed here."""
    ov = F.read_object(obj)
    c2w = [ov.c2w_opencv[ov.indices.index(v)] for v in pool]
    tgt = ov.c2w_opencv[ov.indices.index(int(target["name"].split()[-1]))]
    return [pool[i] for i in S.nearest_views(c2w, tgt, np.mean(rep["bbox"], 0), k)]


def _synth(obj, ck, out, *extra):
    return ["synthesize", "--references", str(obj), "--target-views", "2,9", "--checkpoint", str(ck),
            "--out", str(out), "--device", "cpu", "--threads", "1", *extra]


def test_every_view_of_a_dense_folder_is_the_pool_and_each_target_takes_its_nearest(dense, tmp_path):
    root, obj, ck = dense
    pool = [v for v in range(N_VIEWS) if v not in (2, 9)]
    assert main(_synth(obj, ck, tmp_path / "k3", "--views", ",".join(map(str, pool)), "--nearest", "3")) == 0
    rep = json.loads((tmp_path / "k3" / "synthesis.json").read_text())
    assert rep["references"]["views"] == pool and rep["nearest"] == 3
    used = [t["reference_views"] for t in rep["targets"]]
    assert used[0] != used[1]  # two targets on different sides take different references
    for t in rep["targets"]:
        assert t["reference_views"] == sorted(_pool_nearest(obj, rep, pool, t, 3))
    # No --views: every view but the targets is the pool (12 > the 10 a model takes; a target among its own
    # references was largely a copy of the image it is compared with): each target takes its DENSE_NEAREST (5)
    # nearest of them.
    assert main(_synth(obj, ck, tmp_path / "auto")) == 0
    rep = json.loads((tmp_path / "auto" / "synthesis.json").read_text())
    assert rep["references"]["views"] == pool and rep["nearest"] == 0
    for t in rep["targets"]:
        assert len(t["reference_views"]) == S.DENSE_NEAREST == 5 and int(t["name"].split()[-1]) not in t["reference_views"]
        assert t["reference_views"] == sorted(_pool_nearest(obj, rep, pool, t, 5))
    # Seven references (up to 10 were all used for every view: 8 photos around a room gave the room model 21.25
    # dB where each view's 5 nearest give 24.38, docs/nearest.md): each view's 5 nearest of them; five: all
    seven = [0, 1, 3, 5, 7, 8, 11]
    assert main(_synth(obj, ck, tmp_path / "seven", "--views", ",".join(map(str, seven)))) == 0
    rep = json.loads((tmp_path / "seven" / "synthesis.json").read_text())
    for t in rep["targets"]:
        assert t["reference_views"] == sorted(_pool_nearest(obj, rep, seven, t, 5))
    assert main(_synth(obj, ck, tmp_path / "five", "--views", "0,1,3,5,7")) == 0
    rep = json.loads((tmp_path / "five" / "synthesis.json").read_text())
    assert all(t["reference_views"] == [0, 1, 3, 5, 7] for t in rep["targets"])
    # --views all is the same pool; the images of the same references are the same
    assert main(_synth(obj, ck, tmp_path / "all", "--views", "all")) == 0
    for i in range(2):
        assert np.array_equal(F.read_png(tmp_path / "auto" / f"rgb/{i:06d}.png"),
                              F.read_png(tmp_path / "all" / f"rgb/{i:06d}.png"))


def test_nearest_as_many_as_there_are_renders_like_plain_references(dense, tmp_path):
    root, obj, ck = dense
    assert main(_synth(obj, ck, tmp_path / "plain", "--views", "0,5,11")) == 0
    assert main(_synth(obj, ck, tmp_path / "k5", "--views", "0,5,11", "--nearest", "5")) == 0
    for i in range(2):
        assert np.array_equal(F.read_png(tmp_path / "plain" / f"rgb/{i:06d}.png"),
                              F.read_png(tmp_path / "k5" / f"rgb/{i:06d}.png"))


def _gpnr_checkpoint(path: Path, lo: int, hi: int) -> Path:
    from blender_mrvm.models import registry
    from blender_mrvm.training.checkpoint import save_checkpoint

    cfg = registry.build_config("gpnr", "fast", {"patch_dim": 4, "n_samples": 6, "d_model": 8, "n_heads": 2,
                                                 "n_blocks": 1, "min_ref_views": lo, "max_ref_views": hi})
    torch.manual_seed(0)
    return save_checkpoint(path, 1, registry.build_model(cfg), cfg, None)


@pytest.mark.parametrize("extra, model, message", [
    (["--nearest", "11"], None, "--nearest"),
    (["--nearest", "-1"], None, "--nearest"),
    (["--views", "0,1,3,4,5", "--nearest", "4"], (2, 3), "takes at most 3 reference views"),
    (["--views", "0,1,3", "--nearest", "1"], (2, 3), "needs at least 2 reference views"),
    (["--views", "0"], (2, 3), "needs at least 2 reference views"),
])
def test_bad_reference_counts_are_one_line_and_write_nothing(dense, tmp_path, capsys, extra, model, message):
    root, obj, ck = dense
    if model is not None:
        ck = _gpnr_checkpoint(tmp_path / "ck", *model)
    capsys.readouterr()
    assert main(_synth(obj, ck, tmp_path / "out", *extra)) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and message in err[0], err
    assert not (tmp_path / "out").exists()


def test_a_model_taking_fewer_than_the_pool_renders_each_target_from_its_nearest(dense, tmp_path):
    root, obj, _ = dense
    ck = _gpnr_checkpoint(tmp_path / "ck", 2, 3)
    assert main(_synth(obj, ck, tmp_path / "out", "--views", "all")) == 0
    rep = json.loads((tmp_path / "out" / "synthesis.json").read_text())
    pool = [v for v in range(N_VIEWS) if v not in (2, 9)]  # every view but the targets
    for t in rep["targets"]:
        assert t["reference_views"] == sorted(_pool_nearest(obj, rep, pool, t, 3))
    assert rep["reference_colours"] is None  # GPNR's colours already are the references': auto leaves them


def test_parse_views_takes_all_and_up_to_the_pool_size():
    assert parse_views("all") == () and parse_views(" ALL ") == ()
    assert len(parse_views(" ".join(map(str, range(MAX_POOL))))) == MAX_POOL
    with pytest.raises(InputError, match=f"at most {MAX_POOL}"):
        parse_views(" ".join(map(str, range(MAX_POOL + 1))))


def test_eval_nearest_takes_each_targets_nearest_other_views(dense):
    """`eval --nearest K`: the protocol's targets, each from its K nearest views among the others (or among
    a given pool), never itself."""
    from blender_mrvm.training.evaluate import _jobs, nearest_of

    _, obj, _ = dense
    s = load_ours(obj)
    jobs = _jobs(s, [0, 7], None, None, 0, 3, None)
    assert [t for _, _, (t,) in jobs] == [k for k in range(N_VIEWS) if k not in (0, 7)]  # the protocol's targets
    for _, refs, (t,) in jobs:
        others = [k for k in range(N_VIEWS) if k != t]
        assert t not in refs and len(refs) == 3 and refs == sorted(nearest_of(s, others, t, 3))
    pool = [0, 3, 7, 11]  # --input-views with --nearest: the nearest of those, every other view a target
    for _, refs, (t,) in _jobs(s, pool, None, None, 0, 2, pool):
        assert set(refs) <= set(pool) and len(refs) == 2
    with pytest.raises(InputError, match="fewer than 4 other views"):
        _jobs(s, [0, 3, 7], None, None, 0, 4, [0, 3, 7])
    with pytest.raises(InputError, match="no view"):
        _jobs(s, [0, 99], None, None, 0, 2, [0, 99])
    # without --nearest: one job with the protocol's references for every target, as before
    assert [(r, len(t)) for _, r, t in _jobs(s, [0, 7], None, None, 5, 0, None)] == [([0, 7], 5)]


def test_eval_cli_records_nearest_in_the_protocol(dense, tmp_path):
    root, obj, ck = dense
    out = tmp_path / "ev"
    assert main(["eval", "--checkpoint", str(ck), "--data", str(root / "data"), "--split", "test",
                 "--input-views", "0,4,8,12", "--nearest", "2", "--max-targets", "2", "--no-lpips",
                 "--threads", "1", "--out", str(out)]) == 0
    rep = json.loads((out / "eval.json").read_text())
    assert rep["protocol"]["nearest"] == 2 and rep["protocol"]["pool"] == [0, 4, 8, 12]
    assert rep["protocol"]["scored_views"] == 2 and "baseline_blend" in rep["overall"]
    # as synthesis, each view from its nearest also takes the photos' colours (auto), the model alone beside it
    assert rep["protocol"]["reproject"]["depth"] == "model" and "model_only" in rep["views"][0]
    assert main(["eval", "--checkpoint", str(ck), "--data", str(root / "data"), "--split", "test",
                 "--input-views", "0,4", "--max-targets", "2", "--no-lpips", "--threads", "1",
                 "--out", str(tmp_path / "plain")]) == 0
    assert json.loads((tmp_path / "plain" / "eval.json").read_text())["protocol"]["reproject"] is None


def test_every_references_mask_carves_the_hull_a_view_is_rendered_within(dense, tmp_path):
    """A view rendered from its 2 nearest references of 12 is culled by the hull of all 12 masks: never more
    rays evaluated than with the hull of its 2 alone, and the world hull of the same views is the encoded
    references' hull exactly."""
    from blender_mrvm.training.checkpoint import load_model

    root, obj, ck = dense
    pool = [v for v in range(N_VIEWS) if v not in (2, 9)]
    assert main(_synth(obj, ck, tmp_path / "pool", "--views", ",".join(map(str, pool)), "--nearest", "2")) == 0
    rep = json.loads((tmp_path / "pool" / "synthesis.json").read_text())
    for i, t in enumerate(rep["targets"]):
        two = ",".join(map(str, t["reference_views"]))
        assert main(_synth(obj, ck, tmp_path / f"two{i}", "--views", two)) == 0
        alone = json.loads((tmp_path / f"two{i}" / "synthesis.json").read_text())["targets"][i]
        assert t["evaluated_rays"] <= alone["evaluated_rays"] and t["box_rays"] == alone["box_rays"]
    assert sum(t["evaluated_rays"] for t in rep["targets"]) < sum(
        json.loads((tmp_path / f"two{i}" / "synthesis.json").read_text())["targets"][i]["evaluated_rays"]
        for i in range(2))  # the other masks do carve
    model, _, _ = load_model(ck)
    refs = S.load_references(obj, (0, 5, 11))
    ctx, ns = S.encode_references(model, refs)
    a = model.hull(ctx, refs.masks, ns.box).occupied
    b = model.world_hull(refs.masks, refs.c2w, refs.intrinsics, refs.bbox).occupied
    assert torch.equal(a, b)


def test_adapting_to_a_dense_set_draws_each_held_out_views_nearest(dense):
    """Adaptation with fewer inputs than the other references (a dense set whose views each render from
    their nearest few) draws every step's references as the held-out view's nearest, as capture training
    does; otherwise they are a random subset, as before."""
    from blender_mrvm.training import trainer
    from blender_mrvm.training.adapt import AdaptConfig, _train_config
    from blender_mrvm.training.evaluate import nearest_of

    _, obj, _ = dense
    s = load_ours(obj)
    cfg = _train_config(AdaptConfig(steps=1), 3, True)
    near = trainer.RayBatcher([s], cfg, 0.1, 0, nearest=True)
    rand = trainer.RayBatcher([s], cfg, 0.1, 0)
    nearest_draws = 0
    for _ in range(8):
        for batcher in (near, rand):
            b = batcher.draw(False)
            t, refs = b["target_view"], b["ref_views"]
            assert len(refs) == 3 and t not in refs
            is_nearest = sorted(refs) == sorted(nearest_of(s, [k for k in range(len(s)) if k != t], t, 3))
            if batcher is near:
                assert is_nearest
            else:
                nearest_draws += is_nearest
    assert nearest_draws < 8  # random subsets are not always the nearest


def test_reference_colours_on_in_a_dense_capture_and_exact_from_a_views_own_photo(dense, tmp_path):
    """`--reproject` (auto: on when each view takes its nearest of more references): the references used are
    rendered once for their depth; a view rendered at a reference's own camera from that reference alone, by a
    model that is opaque at the box, takes the photo's own colours wherever the photo shows the object."""
    root, obj, ck = dense
    assert main(_synth(obj, ck, tmp_path / "auto")) == 0  # 14 views > 10: each view its 5 nearest, colours on
    rep = json.loads((tmp_path / "auto" / "synthesis.json").read_text())
    rc = rep["reference_colours"]
    assert rc["mode"] == "auto" and rc["reference_renders"] == len({v for t in rep["targets"] for v in t["colour_views"]})
    for t in rep["targets"]:  # the colours come from the view's nearest max_refs of the references it uses
        assert 0 <= t["reference_share"] <= 1 and len(t["colour_views"]) == rc["max_refs"] == 2
        assert set(t["colour_views"]) <= set(t["reference_views"])
        assert t["colour_views"] == sorted(_pool_nearest(obj, rep, t["reference_views"], t, 2))
    assert main(_synth(obj, ck, tmp_path / "fast", "--quality", "preview")) == 0  # preview: speed first, off
    assert json.loads((tmp_path / "fast" / "synthesis.json").read_text())["reference_colours"] is None
    assert main(_synth(obj, ck, tmp_path / "few", "--views", "0,5,11")) == 0  # every reference for every view: off
    rep = json.loads((tmp_path / "few" / "synthesis.json").read_text())
    assert rep["reference_colours"] is None and "reference_share" not in rep["targets"][0]

    from test_synthesize import tiny_checkpoint

    opaque = tiny_checkpoint(root / "opaque", {"render": {"density_bias": 30.0}})
    args = ["synthesize", "--references", str(obj), "--views", "4", "--target-views", "4", "--checkpoint", str(opaque),
            "--out", None, "--device", "cpu", "--threads", "1", "--ref-size", "-1", "--reproject", None]
    for mode in ("on", "off"):
        args[10], args[-1] = str(tmp_path / mode), mode
        assert main(args) == 0
    on, off = (F.read_png(tmp_path / m / "rgb" / "000000.png").astype(int) for m in ("on", "off"))
    photo = F.read_png(obj / "rgb" / "000004.png")[..., :3].astype(int)
    mask = F.read_png(obj / "mask" / "000004.png") > 0
    mask = mask if mask.ndim == 2 else mask[..., 0]
    assert mask.sum() > 10 and np.abs(on[mask][:, :3] - photo[mask]).max() <= 1
    assert np.array_equal(on[~mask], off[~mask])  # elsewhere the model's own colours
    assert np.abs(off[mask][:, :3] - photo[mask]).max() > 10  # which are not the photo's
    rep = json.loads((tmp_path / "on" / "synthesis.json").read_text())
    assert rep["reference_colours"]["reference_renders"] == 1 and rep["targets"][0]["reference_share"] > 0
