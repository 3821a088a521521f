"""`train --image-size N` (train.image_size): a dataset rendered larger than the model trains at is resized when
each view is loaded (colours by area, masks conservatively, depth maps by the nearest valid sample, the cameras
exactly), the checkpoints record the size trained at, a resume at another size and upsampling are refused, and
`eval` of such a checkpoint scores at its training size by default."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from blender_mrvm.datasets import loaders as L
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.models.checkpoint_files import MODEL_FILE, find_checkpoint, read_header_meta
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 16, "n_heads": 2},
        "sampler": {"n_coarse": 8, "n_fine": 4}}


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_sphere_dataset(tmp_path_factory.mktemp("isz") / "d", n_objects=3, n_views=4, resolution=32, seed=2)


def _first(data):
    (fmt, path), *_ = L.list_objects(data, None, "train")
    return fmt, path


def test_loaded_views_take_the_size_and_their_cameras_scale_exactly(data):
    fmt, path = _first(data)
    big = L.load_object(fmt, path, depth=True)
    small = L.load_object(fmt, path, depth=True, image_size=16)
    assert big.images.shape[1:3] == (32, 32)
    assert small.images.shape == (len(big), 16, 16, 3) and small.images.dtype == np.float32
    assert small.masks.shape == (len(big), 16, 16) and small.depths.shape == (len(big), 16, 16)
    # colours: the mean of each 2x2 footprint (area filtering)
    np.testing.assert_allclose(small.images, big.images.reshape(len(big), 16, 2, 16, 2, 3).mean((2, 4)), atol=1e-6)
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.3, 0.3, (20, 3))
    for k in range(len(big)):
        ib, is_ = big.intrinsics[k], small.intrinsics[k]
        assert (is_.width, is_.height) == (16, 16) and is_ == ib.resized(16, 16)
        w2c = np.linalg.inv(big.c2w[k])
        uv_big, _ = C.project(ib.K, w2c, pts)
        uv_small, _ = C.project(is_.K, w2c, pts)
        np.testing.assert_allclose(uv_small, uv_big / 2, atol=1e-9)  # the same place, scaled
    # masks conservative: every object pixel of the full-size mask lies in an object pixel of the small one
    ys, xs = np.nonzero(big.masks[0])
    assert small.masks[0][ys // 2, xs // 2].all()
    from blender_mrvm.synthesis.views import resize_mask

    assert all((small.masks[k] == resize_mask(big.masks[k], 16, 16)).all() for k in range(len(big)))
    # depth: a pixel has a depth where its footprint sees a surface, and it is one of the footprint's samples
    for k in range(len(big)):
        foot = big.depths[k].reshape(16, 2, 16, 2).transpose(0, 2, 1, 3).reshape(16, 16, 4)
        assert ((small.depths[k] > 0) == (foot > 0).any(-1)).all()
        hit = small.depths[k] > 0
        assert np.isclose(foot[hit], small.depths[k][hit][:, None]).any(-1).all()


def test_masks_are_conservative_at_a_scale_that_is_not_whole():
    m = np.zeros((32, 32), bool)
    m[:, 16] = True  # a one-pixel-wide leg
    m[5, 3] = True
    small = L.resize_object_mask(m, 12, 12)  # 32 / 12: footprints of 2.67 px
    s = 32 / 12
    for y, x in zip(*np.nonzero(m)):  # every object pixel overlaps an object pixel of the small mask
        assert small[int(y // s), int(x // s)] and small[min(11, int((y + 0.999) // s)), min(11, int((x + 0.999) // s))]
    assert small.sum() < 12 * 12 / 2
    d = np.where(m, 2.0, 0.0).astype(np.float32)
    assert ((L.resize_depth(d, 12, 12) > 0) == small).all()


def test_upsampling_is_refused_in_one_line(data, tmp_path, capsys):
    from blender_mrvm.cli import main

    with pytest.raises(InputError, match="upsampling adds nothing"):
        L.load_object(*_first(data), image_size=64)
    assert main(["train", "--data", str(data), "--out", str(tmp_path / "r"), "--image-size", "64",
                 "--iterations", "1"]) != 0
    err = [x for x in capsys.readouterr().err.splitlines() if x.startswith("error:")]
    assert len(err) == 1 and "upsampling adds nothing" in err[0] and "32x32" in err[0]
    assert not (tmp_path / "r" / "checkpoints").exists()


@pytest.fixture(scope="module")
def run16(data, tmp_path_factory):
    from blender_mrvm.cli import main
    from blender_mrvm.training import trainer

    out = tmp_path_factory.mktemp("isz_run") / "r"
    cfg = {"model": {"preset": "fast", "overrides": TINY},
           "train": {"iterations": 2, "rays_per_object": 32, "objects_per_step": 2, "max_ref_views": 2,
                     "lr_warmup": 0, "ckpt_every": 1, "threads": 1, "seed": 1}}
    (out.parent / "run.json").write_text(json.dumps(cfg))
    shapes = []
    real = trainer.RayBatcher

    class Spy(real):
        def __init__(self, scenes, *a, **k):
            shapes.extend((s.images.shape, None if s.masks is None else s.masks.shape) for s in scenes)
            super().__init__(scenes, *a, **k)

    trainer.RayBatcher = Spy
    try:
        rc = main(["train", "--config", str(out.parent / "run.json"), "--data", str(data), "--out", str(out),
                   "--image-size", "16"])
    finally:
        trainer.RayBatcher = real
    assert rc == 0
    return out, shapes


def test_a_run_at_image_size_16_trains_and_records_16(run16):
    out, shapes = run16
    assert shapes and all(im[1:3] == (16, 16) and (m is None or m[1:] == (16, 16)) for im, m in shapes)
    meta = read_header_meta(find_checkpoint(out / "checkpoints") / MODEL_FILE)
    assert meta["train_image_size"] == "16"
    assert json.loads(meta["train_config"])["image_size"] == 16
    assert json.loads((out / "config.json").read_text())["train"]["image_size"] == 16


def test_a_resume_at_another_size_is_refused_in_one_line(run16, capsys):
    from blender_mrvm.cli import main

    out, _ = run16
    before = sorted(p.name for p in (out / "checkpoints").iterdir())
    for other in ("8", "0"):
        capsys.readouterr()
        assert main(["train", "--data", _data_of(out),
                     "--out", str(out), "--iterations", "3", "--image-size", other]) != 0
        err = [x for x in capsys.readouterr().err.splitlines() if x.startswith("error:")]
        assert len(err) == 1 and "--image-size 16" in err[0], err
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == before
    assert json.loads((out / "config.json").read_text())["train"]["image_size"] == 16


def _data_of(run):
    return json.loads((run / "config.json").read_text())["train"]["data"]


def test_eval_scores_such_a_checkpoint_at_its_training_size(run16, tmp_path):
    from blender_mrvm.cli import main

    out, _ = run16
    data = _data_of(out)
    assert main(["eval", "--checkpoint", str(out), "--data", data, "--input-views", "0", "--no-lpips",
                 "--max-targets", "1", "--out", str(tmp_path / "e"), "--threads", "1"]) == 0
    rep = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert rep["image_size"]["used"] == 16 and rep["protocol"]["reference_sizes"] == [[16, 16]]
    assert main(["eval", "--checkpoint", str(out), "--data", data, "--input-views", "0", "--no-lpips",
                 "--max-targets", "1", "--out", str(tmp_path / "e0"), "--threads", "1", "--image-size", "0"]) == 0
    rep0 = json.loads((tmp_path / "e0" / "eval.json").read_text())
    assert rep0["image_size"]["used"] == 0 and rep0["protocol"]["reference_sizes"] == [[16, 16]]
