"""The Python API (``blender_mrvm.api``, ``docs/guide/python_api.md``): the guide's examples run as written; a view
rendered through the API is the one ``synthesize`` writes for the same inputs; nothing global changes; bad input
raises instead of exiting or scoring nonsense."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide" / "python_api.md"
OBJECT = Path("data/chair/chair_001000")

torch.set_num_threads(1)

needs_bpy = pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="rendering the dataset needs bpy")


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A folder holding the guide's ``data/`` (its render-dataset command; 4 samples instead of 32 for speed)."""
    d = tmp_path_factory.mktemp("python_api")
    cmd = [sys.executable, "-m", "blender_mrvm", "render-dataset", "--source", "procedural:chair:1000", "--rig",
           "turntable", "--elevation", "30", "--views", "8", "--resolution", "64", "--samples", "4", "--out", "data/"]
    subprocess.run(cmd, cwd=d, check=True, capture_output=True, timeout=300,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    assert (d / OBJECT / "meta.json").is_file()
    return d


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def test_guide_render_command_is_the_fixtures():
    """The fixture renders what the guide's shell block says (but for the samples)."""
    text = GUIDE.read_text()
    assert "--source procedural:chair:1000 --rig turntable --elevation 30" in text
    assert "--views 8 --resolution 64 --out data/" in text
    assert len(python_blocks(text)) >= 6


@needs_bpy
def test_guide_examples_run(workdir, monkeypatch, capsys):
    monkeypatch.chdir(workdir)
    threads = torch.get_num_threads()
    ns: dict = {}
    for i, block in enumerate(python_blocks(GUIDE.read_text())):
        try:
            exec(compile(block, f"python_api.md block {i}", "exec"), ns)
        except Exception as e:  # name the block
            raise AssertionError(f"guide block {i} failed: {type(e).__name__}: {e}\n{block}") from e
    out = capsys.readouterr().out
    assert "nerformer_mrvm fp32 64" in out and "True" in out
    assert ns["view"].rgb.shape == (64, 64, 3) and ns["views"][1].rgb.shape == (32, 32, 3)
    assert ns["name"] == "shipped:nerformer_mrvm"
    assert torch.get_num_threads() == threads


@needs_bpy
def test_view_is_the_one_synthesize_writes(workdir, tmp_path):
    """Same checkpoint, references and targets: the API's RGBA is the CLI's PNG byte for byte, its depth the EXR."""
    from blender_mrvm import api
    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F

    obj = workdir / OBJECT
    out = tmp_path / "novel"
    assert main(["synthesize", "--references", str(obj), "--views", "0,4", "--target-views", "2,6", "--out", str(out),
                 "--device", "cpu", "--threads", "1", "--depth"]) == 0
    rep = json.loads((out / "synthesis.json").read_text())
    assert rep["model_kind"] == "nerformer_mrvm" and rep["precision"] == "fp32"
    model = api.load_model(api.auto_model(api.load_references(obj, [0, 4]), np.stack(
        [api.read_object(obj).c2w[k] for k in (2, 6)]), api.read_object(obj).intrinsics[2].K, 64, 64)[0])
    assert Path(rep["checkpoint"]).resolve() == model.path.resolve()
    scene = api.read_object(obj)
    views = api.render_views(model, api.load_references(obj, [0, 4]), scene.c2w[[2, 6]], scene.intrinsics[2].K, 64, 64)
    for i, v in enumerate(views):
        np.testing.assert_array_equal(v.rgba(), F.read_png(out / f"rgb/{i:06d}.png"))
        np.testing.assert_array_equal(v.depth, F.read_depth(out / f"depth/{i:06d}.exr"))
    # the same references given as arrays (uint8 files' pixels, OpenCV poses, K) render the same view
    imgs = [F.read_png(obj / "rgb" / f"{k:06d}.png") for k in (0, 4)]
    refs = api.references(imgs, scene.c2w[[0, 4]], scene.intrinsics[0].K, bbox=scene.bbox, masks=scene.masks[[0, 4]])
    v = api.render_view(model, refs, scene.c2w[2], scene.intrinsics[2].K, 64, 64)
    np.testing.assert_array_equal(v.rgba(), views[0].rgba())


@needs_bpy
def test_gpnr_view_matches_synthesize(workdir, tmp_path):
    from blender_mrvm import api
    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F

    obj = workdir / OBJECT
    out = tmp_path / "gpnr"
    assert main(["synthesize", "--references", str(obj), "--views", "0,4", "--target-views", "2", "--out", str(out),
                 "--device", "cpu", "--threads", "1", "--checkpoint", "shipped:gpnr"]) == 0
    scene = api.read_object(obj)
    v = api.render_view(api.load_model("shipped:gpnr"), api.load_references(obj, [0, 4]), scene.c2w[2],
                        scene.intrinsics[2].K, 64, 64)
    np.testing.assert_array_equal(v.rgba(), F.read_png(out / "rgb/000000.png"))


@needs_bpy
def test_nearest_references_match_synthesize(workdir, tmp_path):
    """Each view from its 2 nearest of 6 references (their masks all carving the hull), as ``--nearest 2``."""
    from blender_mrvm import api
    from blender_mrvm.cli import main
    from blender_mrvm.datasets import format as F

    obj = workdir / OBJECT
    out = tmp_path / "nearest"
    pool = [0, 1, 3, 4, 5, 7]
    assert main(["synthesize", "--references", str(obj), "--views", ",".join(map(str, pool)), "--target-views", "2,6",
                 "--nearest", "2", "--reproject", "off", "--out", str(out), "--device", "cpu", "--threads", "1",
                 "--checkpoint", "shipped"]) == 0
    rep = json.loads((out / "synthesis.json").read_text())
    scene = api.read_object(obj)
    views = api.render_views(api.load_model("shipped"), api.load_references(obj, pool), scene.c2w[[2, 6]],
                             scene.intrinsics[2].K, 64, 64, nearest=2)
    for i, v in enumerate(views):
        assert [pool[k] for k in v.reference_views] == rep["targets"][i]["reference_views"]
        np.testing.assert_array_equal(v.rgba(), F.read_png(out / f"rgb/{i:06d}.png"))


def _sphere_object(tmp_path) -> Path:
    from blender_mrvm.training.synthetic import make_sphere_dataset

    return make_sphere_dataset(tmp_path / "d", n_objects=1, n_views=4, resolution=16, seed=1) / "spheres" / "obj000"


def test_rendering_leaves_torch_threads_alone(tmp_path):
    """``synthesize_views`` sets torch's threads to 1 for the process (``threads.render_workers``); the API does not."""
    from blender_mrvm import api

    obj = _sphere_object(tmp_path)
    scene = api.read_object(obj)
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        model = api.load_model("shipped:gpnr", precision="fp32")
        v = api.render_view(model, api.load_references(obj, [0, 1]), scene.c2w[2], scene.intrinsics[2].K, 16, 16,
                            ref_size=-1, workers=2)
        assert torch.get_num_threads() == 2 and torch.get_default_dtype() == torch.float32
        assert v.rgb.shape == (16, 16, 3) and np.isfinite(v.rgb).all() and torch.is_grad_enabled()
    finally:
        torch.set_num_threads(before)


def test_loading_leaves_torch_random_state_alone(tmp_path):
    """Building a module draws its initial weights from torch's global generator (``synthesis.load_checkpoint``
    moves it); a seeded script draws the same numbers whether or not it loaded models, LPIPS or rendered."""
    from blender_mrvm import api
    from blender_mrvm.synthesis import load_checkpoint

    torch.manual_seed(0)
    expected = torch.rand(4)
    torch.manual_seed(0)
    load_checkpoint("shipped:gpnr")
    assert not torch.equal(torch.rand(4), expected)  # what the API guards against
    obj = _sphere_object(tmp_path)
    scene = api.read_object(obj)
    torch.manual_seed(0)
    m = api.load_model("shipped:gpnr")
    api.load_model("shipped:sem2nerf")
    api.lpips_metric()
    api.render_view(m, api.load_references(obj, [0, 1]), scene.c2w[2], scene.intrinsics[2].K, 16, 16, ref_size=-1)
    assert torch.equal(torch.rand(4), expected)


def test_import_is_bpy_free_and_changes_nothing():
    code = ("import os, sys, signal, warnings, torch; env = dict(os.environ); f = list(warnings.filters); "
            "s = signal.getsignal(signal.SIGINT); import blender_mrvm.api; "
            "assert 'bpy' not in sys.modules and 'blender_mrvm.cli' not in sys.modules; "
            "assert dict(os.environ) == env and list(warnings.filters) == f and signal.getsignal(signal.SIGINT) is s")
    env = {k: v for k, v in os.environ.items() if k != "OMP_WAIT_POLICY"}
    subprocess.run([sys.executable, "-c", code], check=True, cwd=ROOT, env=env, timeout=120)


def test_scores_take_uint8_and_refuse_0_255_floats():
    """``models.metrics.psnr`` scores 0-255 arrays as nonsense (-14 dB for a 34 dB pair); ``api.scores`` reads uint8
    as the loaders do and refuses floats outside [0, 1]."""
    from blender_mrvm import api
    from blender_mrvm.errors import InputError

    rng = np.random.default_rng(0)
    a = (rng.random((24, 24, 3)) * 255).astype(np.uint8)
    b = np.clip(a.astype(int) + 5, 0, 255).astype(np.uint8)
    s8, sf = api.scores(a, b), api.scores(a / 255.0, b / 255.0)
    assert s8["psnr"] == pytest.approx(sf["psnr"], abs=1e-3) and 30 < s8["psnr"] < 40
    assert s8["ssim"] == pytest.approx(sf["ssim"], abs=1e-5) and "lpips" not in s8
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        api.scores(a.astype(np.float32), b.astype(np.float32))
    with pytest.raises(InputError, match="differ in size"):
        api.scores(a, b[:12])


def test_bad_inputs_raise_not_exit(tmp_path):
    from blender_mrvm import api
    from blender_mrvm.errors import InputError, MRVMError

    obj = _sphere_object(tmp_path)
    scene = api.read_object(obj)
    K = scene.intrinsics[0].K
    with pytest.raises(InputError, match="convention"):
        api.references(scene.images[:2], scene.c2w[:2], K, convention="colmap")
    with pytest.raises(InputError, match="not a camera pose"):
        api.references(scene.images[:2], scene.c2w[:2] * 2.0, K)
    with pytest.raises(InputError, match="as many poses"):
        api.references(scene.images[:2], scene.c2w[:1], K)
    with pytest.raises(InputError, match="masks"):
        api.references(scene.images[:2], scene.c2w[:2], K, masks=np.ones((2, 3, 3), bool))
    with pytest.raises(MRVMError):
        api.load_model("shipped:auto")
    refs = api.load_references(obj, [0, 1])
    model = api.load_model("shipped")
    with pytest.raises(InputError, match="ref_size=64"):  # 16 px references for a 64 px model: the CLI's rule
        api.render_view(model, refs, scene.c2w[2], K, 16, 16)
    with pytest.raises(InputError, match="one"):
        api.render_view(model, refs, scene.c2w[2:4], K, 16, 16, ref_size=-1)


def test_sem2nerf_loads_and_is_refused_for_references(tmp_path):
    from blender_mrvm import api
    from blender_mrvm.errors import InputError

    m = api.load_model("shipped:sem2nerf")
    assert m.kind == "sem2nerf" and type(m.module).__name__ == "Sem2NeRF" and not m.module.training
    obj = _sphere_object(tmp_path)
    scene = api.read_object(obj)
    with pytest.raises(InputError, match="part mask"):
        api.render_view(m, api.load_references(obj, [0]), scene.c2w[1], scene.intrinsics[1].K, 16, 16)
