"""Colour conventions of the files the package writes and reads (issue: colour review).

One convention for straight alpha, Blender's: an RGBA file holds sRGB-encoded straight colour, shown over a
background mixed in linear light (``format.composite_on_white``, ``format.uncomposite``). The loaders read an
``--rgba`` dataset as the dataset rendered on white; synthesize's and Sem2NeRF's RGBA over white give back the
model's output; a .blend in another working colour space (ACEScg) renders the same dataset as a Linear Rec.709 one;
photos come into ``rgb/`` as 8-bit sRGB (float images scaled from [0, 1], ICC profiles converted).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from tests.helpers import P3_TO_709, p3_profile


def _mix_over_white(straight: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Straight sRGB colour with alpha over white mixed in linear light, written out (what Blender shows)."""
    return F.linear_to_srgb(F.srgb_to_linear(straight) * a + (1.0 - a))


def _linear_over_white(rgba8: np.ndarray) -> np.ndarray:
    x = rgba8.astype(np.float64) / 255.0
    return _mix_over_white(x[..., :3], x[..., 3:])


# --------------------------------------------------------------------------------------------- straight alpha

def test_loaders_mix_straight_alpha_over_white_in_linear_light():
    """to_float_rgb mixed RGBA over white in the sRGB numbers (c a + 1 - a): an --rgba dataset trained on darker
    soft edges than the same dataset rendered on white. Now in linear light, as Blender; opaque pixels and empty
    ones are exact; grey + alpha too; NeRF-synthetic scenes keep their benchmark's sRGB-number mix."""
    from blender_mrvm.datasets.loaders import to_float_rgb

    rng = np.random.default_rng(0)
    rgba = rng.integers(0, 256, (8, 8, 4), dtype=np.uint8)
    rgba[0, :, 3], rgba[1, :, 3] = 255, 0
    got = to_float_rgb(rgba)
    assert got.dtype == np.float32
    assert np.abs(got - _linear_over_white(rgba)).max() < 1e-5
    assert np.array_equal(got[0], rgba[0, :, :3] / np.float32(255.0)) and (got[1] == 1.0).all()
    la = rgba[..., [0, 3]]
    assert np.abs(to_float_rgb(la) - _linear_over_white(rgba[..., [0, 0, 0, 3]])).max() < 1e-5
    x = rgba.astype(np.float32) / 255.0
    assert np.abs(to_float_rgb(rgba, linear_alpha=False) - (x[..., :3] * x[..., 3:] + 1 - x[..., 3:])).max() < 1e-6


def test_synthesize_rgba_over_white_in_linear_light_is_the_models_colour():
    """rgba_image derived the straight colour in sRGB numbers, so Blender's image plane of the view over white (a
    linear-light mix) showed soft edges up to ~1/10 lighter than the model's output. Now lin(s) = (lin(c) - (1 -
    a)) / a with the stored 8-bit alpha: mixed back over white it is the model's colour within 1/255."""
    from blender_mrvm.synthesis.views import rgba_image

    rng = np.random.default_rng(1)
    acc = rng.uniform(0.0, 1.0, (32, 32))
    acc[:4] = 0.0
    acc[4:8] = 1.0
    straight = rng.uniform(0.0, 1.0, (32, 32, 3))
    colour = _mix_over_white(straight, acc[..., None])  # a colour a straight one can give, on white
    out = rgba_image(colour, acc)
    assert out.dtype == np.uint8 and out.shape == (32, 32, 4)
    assert np.array_equal(out[..., 3], F.to_uint8(acc))
    assert np.abs(_linear_over_white(out) - colour).max() <= 1.0 / 255.0 + 1e-9
    assert (out[:4, :, :3] == 255).all()  # no opacity: the colour (white) is kept
    scene = rgba_image(colour, acc, scene=True)
    assert (scene[..., 3] == 255).all() and np.array_equal(scene[..., :3], F.to_uint8(colour))


@pytest.mark.parametrize("background", [1.0, 0.0])
def test_a_colour_its_opacity_cannot_show_raises_the_alpha(background):
    """A model's colour and opacity need not agree: 5% of the shipped model's pixels (soft edges) are darker than the
    white their opacity lets through, and clipping their straight colour to black showed them up to 31/255 lighter
    than the model drew them. The stored alpha is raised to the least that shows the colour: the file over its
    background is the model's output within 8-bit rounding, and agreeing pixels keep the model's opacity."""
    rng = np.random.default_rng(3)
    colour = rng.uniform(0.0, 1.0, (64, 3))
    acc = rng.uniform(0.0, 1.0, 64)
    out = F.straight_rgba(colour, acc, background).astype(np.float64) / 255.0
    lin_s, a = F.srgb_to_linear(out[:, :3]), out[:, 3:]
    shown = F.linear_to_srgb(lin_s * a + background * (1.0 - a))
    assert np.abs(shown - colour).max() <= 1.5 / 255.0, np.abs(shown - colour).max()
    lin = F.srgb_to_linear(colour)
    agree = (lin.min(-1) >= 1.0 - acc) if background else (lin.max(-1) <= acc)
    assert 0 < agree.sum() < 64
    assert np.array_equal(out[agree, 3], F.to_uint8(acc)[agree] / 255.0) and (out[:, 3] >= F.to_uint8(acc) / 255.0).all()


def test_uncomposite_over_black_and_clipping():
    """The straight colour of a colour on black (a model trained on black); colours darker than white at that alpha
    allows clip to black."""
    a = np.array([[0.5], [0.25]])
    lin_s = np.array([[0.2, 0.4, 0.8], [1.0, 0.0, 0.5]])
    on_black = F.linear_to_srgb(lin_s * a)
    assert np.allclose(F.srgb_to_linear(F.uncomposite(on_black, a, background=0.0)), lin_s, atol=1e-9)
    assert np.allclose(F.uncomposite(np.zeros((1, 3)), [[0.5]]), 0.0)


def test_rgba_dataset_loads_as_the_dataset_rendered_on_white(tmp_path, bpy_empty):
    """The same object rendered on white and with --rgba (one render, two encodings, both in linear light as
    Blender composites) loads equal within 1/255 (the loader mixed the RGBA in sRGB numbers: soft edges darker)."""
    import torch

    torch.set_num_threads(1)
    from blender_mrvm.datasets.loaders import load_ours
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    loaded = {}
    for rgba in (False, True):
        out = tmp_path / f"d{int(rgba)}"
        run_to_end(render_dataset(RenderConfig(out=out, sources=("procedural:chair:0",), views=2, resolution=(24, 24),
                                               samples=2, rgba=rgba)))
        obj = next(p for p in out.glob("*/*") if p.is_dir())
        loaded[rgba] = load_ours(obj).images
        if rgba:
            alpha = np.stack([F.read_png(obj / "rgb" / f"{F.view_name(i)}.png")[..., 3] for i in range(2)])
    soft = (alpha > 0) & (alpha < 255)
    assert soft.sum() > 20  # anti-aliased edges to compare
    d = np.abs(loaded[True] - loaded[False]).max(-1)
    assert d.max() <= 1.0 / 255.0 + 1e-6, (d.max() * 255, (d[soft] * 255).mean())


def test_sem2nerf_rgba_holds_straight_colour(tmp_path, monkeypatch):
    """Sem2NeRF wrote its colour on white with its opacity as alpha, so a straight-alpha reader (the loaders,
    Blender) put it over white a second time: soft edges too light. Now the colour is un-composited as synthesize's,
    over the model's background in linear light."""
    import torch

    torch.set_num_threads(1)
    from blender_mrvm.models.sem2nerf.config import sem2nerf_config
    from blender_mrvm.models.sem2nerf.model import Sem2NeRF
    from blender_mrvm.models.sem2nerf.render import RenderRequest, render_from_mask
    from blender_mrvm.progress import run_to_end
    from blender_mrvm.training.sem2nerf import save_checkpoint

    torch.manual_seed(0)
    cfg = sem2nerf_config("fast", image_size=16, labels=(0, 3), label_names=("background", "a"), pretrained=False,
                          style_mean_samples=10, n_coarse=4, n_fine=2, hidden=8, n_layers=1, encoder_hidden=16,
                          vgg_layers=4, z_dim=8, mapping_hidden=8)
    run = tmp_path / "run"
    save_checkpoint(run, 1, Sem2NeRF(cfg).eval(), 16, None)
    rng = np.random.default_rng(2)
    straight = rng.uniform(0.0, 1.0, (16, 16, 3))
    acc = rng.uniform(0.0, 1.0, (16, 16))
    acc[:2] = 0.0
    on_white = _mix_over_white(straight, acc[..., None])

    def render_image(self, intr, c2w, code, style, **kw):
        sem = torch.zeros(16, 16, 2)
        return {"rgb": torch.from_numpy(on_white).float(), "acc": torch.from_numpy(acc).float(), "semantic": sem}

    monkeypatch.setattr(Sem2NeRF, "render_image", render_image)
    mask = np.zeros((16, 16), np.uint8)
    mask[4:12, 4:12] = 3
    F.write_png(tmp_path / "in" / "mask.png", mask)
    c2w = np.array([[1, 0, 0, 0], [0, -1, 0, 0], [0, 0, -1, 2.0], [0, 0, 0, 1]])  # 2 units from the origin
    F.write_srn_pose(tmp_path / "in" / "pose.txt", c2w)
    run_to_end(render_from_mask(RenderRequest(checkpoint=str(run), mask=str(tmp_path / "in" / "mask.png"),
                                              pose=str(tmp_path / "in" / "pose.txt"), out=str(tmp_path / "out"),
                                              views=1, threads=1)))
    out = F.read_png(tmp_path / "out" / "rgb" / "000000.png")
    assert np.array_equal(out[..., 3], F.to_uint8(acc))
    assert np.abs(_linear_over_white(out) - on_white).max() <= 1.0 / 255.0 + 1e-6


# --------------------------------------------------------------------------------------------- photos

def test_float_and_16_bit_photos_scale_as_the_loaders_read_them():
    """photo_rgb8 scaled a float (mode F) photo by 1/257 like a 16-bit one: a float TIFF in [0, 1] came out black
    in rgb/. It now reads the photo as the loaders do (format.colour_pixels): [0, 1] to 0..255, 16 bits over 257."""
    from PIL import Image

    from blender_mrvm.capture.export import photo_rgb8

    grey = np.linspace(0.0, 1.0, 64, dtype=np.float32).reshape(8, 8)
    got = photo_rgb8(Image.fromarray(grey, mode="F"))
    assert got.shape == (8, 8, 3) and got.dtype == np.uint8
    assert np.array_equal(got[..., 1], F.to_uint8(grey)) and got.max() == 255
    sixteen = (grey * 65535).round().astype(np.uint16)
    assert np.array_equal(photo_rgb8(Image.fromarray(sixteen))[..., 0], np.round(sixteen / 257.0).astype(np.uint8))


def test_p3_photos_are_converted_to_srgb(tmp_path):
    """An iPhone photo's numbers are Display P3 (its ICC profile says so); rgb/ holds 8-bit sRGB without a
    profile, so they were read as sRGB: duller reds and greens. write_capture (JPEG, and an 8-bit RGB PNG, which it
    copied as it was) and readable_photos' conversion (WebP here) now convert them; an sRGB-tagged photo keeps its
    numbers exactly."""
    from PIL import Image, ImageCms

    from blender_mrvm.capture.export import CaptureView, write_capture
    from blender_mrvm.capture.sfm import readable_photos
    from blender_mrvm.geometry.cameras import Intrinsics
    from blender_mrvm.progress import run_to_end

    icc = p3_profile()
    cols = np.array([(230, 40, 40), (40, 200, 60), (210, 170, 140), (200, 200, 200)], np.uint8)  # red green skin grey
    a = np.repeat(np.repeat(cols[None], 8, 0), 8, 1)  # 8 x 32
    want = F.to_uint8(F.linear_to_srgb(F.srgb_to_linear(cols / 255.0) @ P3_TO_709.T))
    srgb_icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    (tmp_path / "in").mkdir()
    Image.fromarray(a).save(tmp_path / "in" / "p3.jpg", quality=100, subsampling=0, icc_profile=icc)
    Image.fromarray(a).save(tmp_path / "in" / "p3.png", icc_profile=icc)
    Image.fromarray(a).save(tmp_path / "in" / "srgb.png", icc_profile=srgb_icc)
    Image.fromarray(a).save(tmp_path / "in" / "p3.webp", lossless=True, icc_profile=icc)
    names = ["p3.jpg", "p3.png", "srgb.png"]
    views = [CaptureView(n, tmp_path / "in" / n, Intrinsics(32, 32, 16, 4, 32, 8), np.eye(4)) for n in names]
    write_capture(tmp_path / "cap", views, np.zeros((0, 3)), np.zeros((0, 3), np.uint8), {"kind": "test"})
    for i, n in enumerate(names):
        im = Image.open(tmp_path / "cap" / "rgb" / f"{F.view_name(i)}.png")
        got = np.asarray(im)[4, 4::8].astype(int)
        ref = cols if n == "srgb.png" else want
        assert np.abs(got - ref).max() <= 2, (n, got.tolist(), ref.tolist())
    assert np.array_equal(np.asarray(Image.open(tmp_path / "cap" / "rgb" / "000002.png")), a)  # sRGB: as it was
    assert np.abs(want.astype(int) - cols).max() > 10  # (the test tells P3 from sRGB)
    folder, new, _ = run_to_end(readable_photos(tmp_path / "in", ["p3.webp"], tmp_path / "work"))
    got = np.asarray(Image.open(folder / new[0]))[4, 4::8].astype(int)
    assert np.abs(got - want).max() <= 3, (got.tolist(), want.tolist())  # (a JPEG's rounding)


# --------------------------------------------------------------------------------------------- working spaces

def _emissive_cube_blend(bpy, path: Path) -> None:
    """A selected cube whose colour is its emission (no sampling noise: the render is its colour exactly)."""
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    ob = bpy.context.active_object
    ob.rotation_euler = (0.3, 0.2, 0.5)
    from blender_mrvm.scene import compat

    m = bpy.data.materials.new("M")
    nt = compat.node_tree(m)
    for n in list(nt.nodes):
        if n.type != "OUTPUT_MATERIAL":
            nt.nodes.remove(n)
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (0.8, 0.2, 0.05, 1.0)
    nt.links.new(em.outputs["Emission"], next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL").inputs["Surface"])
    ob.data.materials.append(m)
    for o in bpy.data.objects:
        o.select_set(o == ob)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def test_blend_in_every_working_space_renders_the_same_dataset(tmp_path, bpy_empty):
    """A .blend in the ACEScg working space (Blender 5.0) rendered ACEScg numbers into the EXR, which were written
    as Rec.709 ones (sRGB PNGs): every colour shifted (~25/255 on an orange cube). The EXR is now Linear Rec.709
    whatever the working space (Blender converts with its own OCIO config), for each space Blender offers."""
    import bpy

    from blender_mrvm.cli import main

    cs = getattr(bpy.data, "colorspace", None)
    if cs is None or not hasattr(cs, "working_space"):
        pytest.skip("this Blender has one working colour space (< 5.0)")
    spaces = cs.bl_rna.properties["working_space"].enum_items.keys()
    assert "ACEScg" in spaces
    plain = tmp_path / "Linear Rec.709.blend"
    _emissive_cube_blend(bpy, plain)
    for ws in spaces:
        blend = tmp_path / f"{ws}.blend"
        if ws != "Linear Rec.709":
            bpy.ops.wm.open_mainfile(filepath=str(plain))
            assert bpy.ops.wm.set_working_color_space(working_space=ws) == {"FINISHED"}
            bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        assert main(["render-dataset", "--source", "selected", "--blend", str(blend), "--views", "1", "--resolution",
                     "16", "--samples", "1", "--out", str(tmp_path / ws)]) == 0
    images = {ws: F.read_png(next((tmp_path / ws).glob("*/*/rgb/000000.png"))).astype(int) for ws in spaces}
    ref = images["Linear Rec.709"]
    assert (ref[..., :3] < 250).any(-1).sum() > 20  # the cube is there
    for ws in spaces:
        assert np.abs(images[ws] - ref).max() <= 2, (ws, np.abs(images[ws] - ref).max())


def test_a_working_space_that_cannot_be_converted_is_refused_in_one_line(monkeypatch):
    """A Blender whose EXR output cannot be set to Linear Rec.709 renders only a Linear Rec.709 file."""
    from blender_mrvm.errors import InputError
    from blender_mrvm.scene import render as R

    class NoOverride:
        def __setattr__(self, name, value):
            raise AttributeError(name)

    monkeypatch.setattr(R, "working_space", lambda: "Linear Rec.709")
    R._rec709_exr(NoOverride())  # nothing to convert
    monkeypatch.setattr(R, "working_space", lambda: "ACEScg")
    with pytest.raises(InputError) as e:
        R._rec709_exr(NoOverride())
    assert "'ACEScg'" in str(e.value) and "\n" not in str(e.value)


def test_contact_sheet_shows_rgba_views_as_the_loaders_read_them():
    """The contact sheet mixed an --rgba dataset's soft edges over white in the sRGB numbers (up to 74/255 darker than
    the views the model trains on) and cast 16-bit images to 8 bits; it shows what ``to_float_rgb`` reads now."""
    from blender_mrvm.datasets.contact_sheet import _rgb
    from blender_mrvm.datasets.format import to_uint8
    from blender_mrvm.datasets.loaders import to_float_rgb

    rgba = np.random.default_rng(1).integers(0, 256, (6, 7, 4), dtype=np.uint8)
    assert np.array_equal(_rgb(rgba), to_uint8(to_float_rgb(rgba)))
    rgb = rgba[..., :3]
    assert np.array_equal(_rgb(rgb), rgb) and np.array_equal(_rgb(rgb[..., 0]), np.repeat(rgb[..., :1], 3, -1))
    wide = rgb.astype(np.uint16) * 257
    assert np.array_equal(_rgb(wide), rgb)
