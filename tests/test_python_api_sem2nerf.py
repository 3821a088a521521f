"""Sem2NeRF through the Python API (``api.render_mask_views``): arrays in, arrays out; its views are the files
``sem2nerf render`` writes for the same inputs (one core: ``models.sem2nerf.render.render_prepared``); masks are read
by the CLI's rules; bad input raises the CLI's one-line messages; torch's threads and random state stay as they were.
The shipped model at ``--quality preview`` and 64 px (its size), a few views: seconds on one thread."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from blender_mrvm import api
from blender_mrvm.cli import main
from blender_mrvm.datasets import format as DF
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras as C
from blender_mrvm.models.sem2nerf import render as R

torch.set_num_threads(1)

SIZE = 64
EYE = (1.5 * math.cos(math.radians(30)), 0.0, 1.5 * math.sin(math.radians(30)))
C2W = C.look_at_opencv(EYE)  # 1.5 units from the origin, 30 degrees up: the model's training views
INTR = C.intrinsics_from_fov(math.radians(40), SIZE, SIZE)  # what the CLI's --fov 40 gives


def _mask() -> np.ndarray:
    """A chair-like part mask of the shipped model's chair labels (65 seat, 66 back, 67 leg)."""
    yy, xx = np.mgrid[:SIZE, :SIZE]
    m = np.zeros((SIZE, SIZE), np.uint8)
    m[(yy - 32) ** 2 + (xx - 32) ** 2 < 13 ** 2] = 65
    m[14:26, 24:40] = 66
    m[40:52, 26:31] = 67
    m[40:52, 34:39] = 67
    return m


@pytest.fixture(scope="module")
def model():
    return api.load_model("shipped:sem2nerf", quality="preview")


def _files(tmp_path: Path, mask: np.ndarray, c2w=C2W) -> tuple[Path, Path]:
    d = tmp_path / "in"
    d.mkdir(exist_ok=True)
    DF.write_png(d / "m.png", mask)
    DF.write_srn_pose(d / "p.txt", c2w)
    return d / "m.png", d / "p.txt"


def _cli(tmp_path: Path, mask: np.ndarray, *extra: str, c2w=C2W) -> tuple[int, Path, Path, Path]:
    m, p = _files(tmp_path, mask, c2w)
    out = tmp_path / "out"
    rc = main(["sem2nerf", "render", "--checkpoint", "shipped:sem2nerf", "--mask", str(m), "--pose", str(p),
               "--out", str(out), "--fov", "40", "--quality", "preview", "--threads", "1", *extra])
    return rc, out, m, p


def test_views_are_the_files_sem2nerf_render_writes(tmp_path, model):
    """Same mask, camera, edits, styles and blend: every array is the CLI's file, byte for byte (poses to the
    text's rounding); the style options change the image."""
    opts = dict(edits=["chair/leg:chair/back"], style_seed=3, mix_seed=5, mix=0.3, blend=7, blend_steps=2)
    rc, out, _, pose = _cli(tmp_path, _mask(), "--views", "3", "--edit", "chair/leg:chair/back", "--style-seed", "3",
                            "--mix-seed", "5", "--mix", "0.3", "--blend", "7", "--blend-steps", "2")
    assert rc == 0
    c2w = DF.read_srn_pose(pose)  # the pose the CLI read (the text rounds it)
    res = api.render_mask_views(model, _mask(), c2w, INTR.K, views=3, **opts)
    assert len(res.views) == 3 and len(res.blend) == 2
    assert np.array_equal(res.mask, DF.read_png(out / "mask_input.png")) and not (res.mask == 67).any()
    assert [list(e) for e in res.edits] == json.loads((out / "sem2nerf.json").read_text())["edits"] == [[67, 66]]
    for k, v in enumerate(res.views):
        assert v.rgb.shape == (SIZE, SIZE, 3) and v.rgb.dtype == np.float32 and v.alpha.shape == (SIZE, SIZE)
        assert np.array_equal(v.rgba(), DF.read_png(out / "rgb" / f"{k:06d}.png"))
        assert np.array_equal(v.semantic, DF.read_png(out / "semantic" / f"{k:06d}.png"))
        assert np.array_equal(v.semantic_color, DF.read_png(out / "semantic_color" / f"{k:06d}.png"))
        assert np.allclose(v.c2w, DF.read_srn_pose(out / "pose" / f"{k:06d}.txt"), atol=1e-6)
        assert v.intrinsics.width == SIZE
    for j, img in enumerate(res.blend):
        assert np.array_equal(DF.to_uint8(img), DF.read_png(out / "blend" / f"{j:06d}.png"))
    assert np.allclose(res.views[0].c2w, C2W, atol=1e-6) and (res.views[0].semantic != 0).any()
    plain = api.render_mask_views(model, _mask(), C2W, INTR.K, views=1)
    assert not np.array_equal(plain.views[0].rgba(), api.render_mask_views(
        model, _mask(), C2W, INTR.K, views=1, style_seed=3).views[0].rgba()), "the style seed changes the image"


def test_target_cameras_and_conventions(model):
    """Target cameras given as the orbit's poses render the orbit's views; a Blender-convention pose is the
    OpenCV one; targets at another size take their own K."""
    orbit = api.render_mask_views(model, _mask(), C2W, INTR.K, views=3)
    poses = np.stack(R.orbit_poses(C2W, 3))
    targets = api.render_mask_views(model, _mask(), C2W, INTR, poses, INTR.K, SIZE, SIZE)
    for a, b in zip(orbit.views, targets.views):
        assert np.array_equal(a.rgba(), b.rgba()) and np.array_equal(a.semantic, b.semantic)
    gl = api.render_mask_views(model, _mask(), C.blender_from_opencv(C2W), INTR.K, C.blender_from_opencv(poses[1]),
                               INTR.K, convention="blender")
    assert len(gl.views) == 1 and np.array_equal(gl.views[0].rgba(), orbit.views[1].rgba())
    small = api.render_mask_views(model, _mask(), C2W, INTR.K, poses[:2], INTR.resized(32, 32).K, 32, 32)
    assert [v.rgb.shape for v in small.views] == [(32, 32, 3)] * 2 and small.views[0].semantic.shape == (32, 32)
    with pytest.raises(InputError, match="target_K"):
        api.render_mask_views(model, _mask(), C2W, INTR.K, poses)


def test_mask_arrays_read_by_the_clis_rules(model):
    """(H, W) ids of any integer type, a grey RGB image (as the CLI reads a grey RGB PNG) and the label-colour image
    ``semantic_color`` shows (RGBA: clear pixels are background) all read as the same part ids."""
    ids = _mask()
    ref = api.render_mask_views(model, ids, C2W, INTR.K, views=1).views[0]
    colour = R.colorize(ids)
    rgba = np.dstack([colour, np.where(ids > 0, 255, 0).astype(np.uint8)])
    rgba[ids == 0, :3] = (10, 200, 30)  # hidden under alpha 0
    for m in (ids.astype(np.int64), np.repeat(ids[..., None], 3, -1), colour, rgba):
        got = api.render_mask_views(model, m, C2W, INTR.K, views=1)
        assert np.array_equal(got.mask, ids) and np.array_equal(got.views[0].rgba(), ref.rgba())
    with pytest.raises(InputError, match="integers in 0..255"):
        api.render_mask_views(model, ids.astype(np.float32), C2W, INTR.K, views=1)
    with pytest.raises(InputError, match="this checkpoint takes 64x64 masks"):
        api.render_mask_views(model, ids[:32], C2W, INTR.K, views=1)
    bad = colour.copy()
    bad[30, 30] = (1, 2, 250)
    with pytest.raises(InputError, match="colours of no label"):
        api.render_mask_views(model, bad, C2W, INTR.K, views=1)


FAR = C.look_at_opencv((11.0, 0.0, 3.0), target=(0.0, 3.0, 0.0))  # Blender's default camera's distance, aimed off


@pytest.mark.parametrize("case", ["unknown_label", "empty", "far_camera", "edit_absent", "seed"])
def test_bad_input_raises_the_clis_message(tmp_path, model, capsys, case):
    mask, c2w, extra, kw = _mask(), C2W, [], {}
    if case == "unknown_label":
        mask[30:34, 30:34] = 250
    elif case == "empty":
        mask[:] = 0
    elif case == "far_camera":
        c2w = FAR
    elif case == "edit_absent":
        mask[mask == 67] = 65
        extra, kw = ["--edit", "67:0"], {"edits": ["67:0"]}
    else:
        extra, kw = ["--style-seed", str(2 ** 64)], {"style_seed": 2 ** 64}
    rc, out, m, p = _cli(tmp_path, mask, *extra, c2w=c2w)
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == 2 and not out.exists() and err.startswith("error: ")
    cli = err[len("error: "):].replace(f"mask {m}", "mask").replace(f"pose {p}", "the mask's camera")
    with pytest.raises(InputError) as e:
        api.render_mask_views(model, mask, c2w, INTR.K, views=2, **kw)
    assert str(e.value) == cli and "\n" not in cli
    assert {"unknown_label": "are not known", "empty": "is empty", "far_camera": "object box",
            "edit_absent": "not in the mask", "seed": "a seed must lie"}[case] in cli


def test_torch_threads_and_random_state_left_alone(model):
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        torch.manual_seed(0)
        expected = torch.rand(4)
        torch.manual_seed(0)
        api.render_mask_views(model, _mask(), C2W, INTR.K, views=1, style_seed=4, mix_seed=1, blend=2, blend_steps=2)
        assert torch.equal(torch.rand(4), expected) and torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_quality_and_kind():
    """load_model takes Sem2NeRF's quality (as --quality); another kind of model is refused in one line."""
    full, preview = api.load_model("shipped:sem2nerf"), api.load_model("shipped:sem2nerf", quality="preview")
    assert (full.quality, preview.quality) == ("full", "preview")
    assert preview.module.cfg.n_coarse < full.module.cfg.n_coarse
    with pytest.raises(InputError, match="quality must be one of"):
        api.load_model("shipped:sem2nerf", quality="best")
    with pytest.raises(InputError, match="Sem2NeRF"):
        api.render_mask_views(api.load_model("shipped:gpnr"), _mask(), C2W, INTR.K, views=1)
