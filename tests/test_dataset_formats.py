"""The public formats `eval` and training read (SRN, NMR/DVR, NeRF-synthetic), laid out here with numpy and PIL
following each release's own convention (not through our writers): image modes decoded to their colours, DVR's
projection world_mat and scale_mat, pixelNeRF's softras split lists, rigid poses, the splits of NeRF-synthetic
scenes, the formats' masks and what eval.json records of them."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from PIL import Image

from blender_mrvm.datasets import format as F
from blender_mrvm.datasets import loaders as L
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras
from blender_mrvm.models.config import model_config
from blender_mrvm.models.model import GeneralizableNeRF
from blender_mrvm.training.evaluate import evaluate
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
W = H = 16
FX, FY, CX, CY = 20.0, 19.0, 8.5, 7.5
INTR = cameras.Intrinsics(FX, FY, CX, CY, W, H)
K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1.0]])
POSES = [cameras.look_at_opencv(e) for e in ([2.0, 0.5, 0.7], [-1.0, 2.0, 0.3], [0.3, -1.5, 1.8], [-1.2, -1.1, -0.9])]
CV2GL = np.diag([1.0, -1.0, -1.0, 1.0])
COLOURS = np.array([[255, 255, 255], [200, 30, 40], [20, 160, 60], [40, 50, 210]], np.uint8)
TINY = {"encoder": {"widths": [8, 8, 8], "out_dim": 8}, "nerformer": {"d_model": 8},
        "sampler": {"n_coarse": 4, "n_fine": 2}}


def _index(k: int) -> np.ndarray:
    """(H, W) colour indices of view ``k``: white (0) around a square of colours 1-3."""
    idx = np.zeros((H, W), np.uint8)
    idx[4:12, 3 + k % 3:11 + k % 3] = 1 + k % 3
    idx[6:9, 6:9] = 1 + (k + 1) % 3
    return idx


def _rgb(k: int) -> np.ndarray:
    return COLOURS[_index(k)]


def _check_rays(scene, poses=POSES, intr=INTR, atol=1e-6):
    assert len(scene) == len(poses)
    for i, c2w in enumerate(poses):
        o1, d1 = cameras.rays_opencv(scene.intrinsics[i], scene.c2w[i])
        o2, d2 = cameras.rays_opencv(intr, c2w)
        assert np.allclose(o1, o2, atol=atol) and np.allclose(d1, d2, atol=atol), i


def _srn_object(obj, save=lambda k, path: Image.fromarray(_rgb(k)).save(path), suffix=".png", intrinsics=True):
    (obj / "rgb").mkdir(parents=True)
    (obj / "pose").mkdir()
    for k, c2w in enumerate(POSES):
        save(k, obj / "rgb" / f"{k:06d}{suffix}")
        (obj / "pose" / f"{k:06d}.txt").write_text(" ".join(f"{v:.12g}" for v in c2w.reshape(-1)) + "\n")
    if intrinsics:  # SRN: one focal length
        (obj / "intrinsics.txt").write_text(f"{FX} {CX} {CY} 0.\n0. 0. 0.\n1.\n{H} {W}\n")


def _nmr_object(obj, world_mats, camera_mat=None, scale_mat=None, masks=None, suffix=".png"):
    """DVR layout: image/0000.png, mask/0000.png, cameras.npz."""
    (obj / "image").mkdir(parents=True)
    cams = {}
    for k, wm in enumerate(world_mats):
        Image.fromarray(_rgb(k)).save(obj / "image" / f"{k:04d}{suffix}")
        cams[f"world_mat_{k}"] = wm
        cams[f"camera_mat_{k}"] = np.eye(4) if camera_mat is None else camera_mat
        if scale_mat is not None:
            cams[f"scale_mat_{k}"] = scale_mat
        if masks is not None:
            (obj / "mask").mkdir(exist_ok=True)
            Image.fromarray(masks[k]).save(obj / "mask" / f"{k:04d}.png")
    np.savez(obj / "cameras.npz", **cams)


def _ndc_camera_mat():
    cm = np.eye(4)
    cm[0, 0], cm[1, 1] = FX / (W / 2), FY / (H / 2)
    cm[0, 2], cm[1, 2] = (CX - W / 2) / (W / 2), (CY - H / 2) / (H / 2)
    return cm


def _nerf_scene(scene, split="test", matrices=None, rgba=True, stem_suffix=""):
    (scene / split).mkdir(parents=True)
    frames = []
    for k, c2w in enumerate(POSES):
        rgb = _rgb(k)
        if rgba:
            a = np.where(_index(k) > 0, 255, 0).astype(np.uint8)
            a[0, 0] = 100  # below one half: empty
            a[4, 4] = 200 if _index(k)[4, 4] else a[4, 4]
            Image.fromarray(np.dstack([np.where(a[..., None] > 0, rgb, 0), a]).astype(np.uint8), "RGBA").save(
                scene / split / f"r_{k}{stem_suffix or '.png'}")
        else:
            Image.fromarray(rgb).save(scene / split / f"r_{k}.png")
        m = (c2w @ CV2GL) if matrices is None else matrices[k]
        frames.append({"file_path": f"./{split}/r_{k}", "rotation": 0.0, "transform_matrix": np.asarray(m).tolist()})
    fov = 2 * math.atan(W / (2 * FX))
    (scene / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": fov, "frames": frames}))


def _run(gen):
    try:
        while True:
            next(gen)
    except StopIteration as e:
        return e.value


@pytest.fixture(scope="module")
def tiny_model():
    torch.manual_seed(0)
    return GeneralizableNeRF(model_config("fast", TINY))


# ----------------------------------------------------------------------------------------------- 1. image modes

def _palette_image(k: int) -> Image.Image:
    im = Image.fromarray(_index(k), "P")
    im.putpalette(COLOURS.reshape(-1).tolist())
    return im


def test_palette_srn_images_are_read_as_their_colours_not_indices(tmp_path):
    """A palette PNG (pngquant, optipng) was read as its index map: grey images, PSNR 6 instead of 18."""
    obj = tmp_path / "cars_test" / "a"
    _srn_object(obj, save=lambda k, p: _palette_image(k).save(p))
    assert Image.open(obj / "rgb" / "000000.png").mode == "P"
    sc = L.load_object("srn", obj)
    want = np.stack([_rgb(k) for k in range(len(POSES))]).astype(np.float32) / 255
    assert np.array_equal(sc.images, want)


def test_palette_with_transparency_composites_on_white_and_our_format_reads_colours_keeps_mask_ids(tmp_path):
    root = make_sphere_dataset(tmp_path / "ds", n_objects=1, n_views=3, resolution=16, seed=3)
    obj = next(root.glob("*/*/meta.json")).parent
    ref = L.load_ours(obj)
    # view 0's rgb as a palette image with one transparent entry (index 0 shows black, transparent -> white)
    idx = _index(0)
    im = Image.fromarray(idx, "P")
    im.putpalette([0, 0, 0, *COLOURS[1:].reshape(-1).tolist()])
    im.save(obj / "rgb" / "000000.png", transparency=0)
    # view 0's part-id mask as a palette image: its ids are the indices, as before
    mask = np.asarray(Image.open(obj / "mask" / "000000.png"))
    pm = Image.fromarray(mask, "P")
    pm.putpalette([v for i in range(256) for v in (i * 7 % 256, 0, 255 - i)])
    pm.save(obj / "mask" / "000000.png")
    sc = L.load_ours(obj)
    assert np.array_equal(sc.images[0], COLOURS[idx].astype(np.float32) / 255)  # index 0 transparent -> white
    assert np.array_equal(sc.images[1:], ref.images[1:])
    assert np.array_equal(F.read_object(obj).mask(0), mask) and np.array_equal(sc.masks, ref.masks)


def test_other_modes_decode_to_colours(tmp_path):
    rgb = _rgb(1)
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "cmyk.tif")
    assert np.array_equal(F.read_png(tmp_path / "cmyk.tif", colour=True), rgb)
    g = np.arange(H * W, dtype=np.int32).reshape(H, W) * 200
    Image.fromarray(g, "I").save(tmp_path / "i32.tif")
    got = F.read_png(tmp_path / "i32.tif", colour=True)
    assert got.dtype == np.uint16 and np.array_equal(got, g)
    Image.fromarray((g * 1000).astype(np.int32), "I").save(tmp_path / "big.tif")
    with pytest.raises(InputError, match="outside 0..65535"):
        F.read_png(tmp_path / "big.tif", colour=True)
    f = (g / g.max()).astype(np.float32)
    Image.fromarray(f, "F").save(tmp_path / "f.tif")
    assert np.allclose(L.read_colour(tmp_path / "f.tif")[..., 0], f)
    Image.fromarray(f * 3, "F").save(tmp_path / "f3.tif")
    with pytest.raises(InputError, match=r"outside \[0, 1\]"):
        F.read_png(tmp_path / "f3.tif", colour=True)
    Image.fromarray(_index(2) > 0).save(tmp_path / "bilevel.png")
    assert np.array_equal(L.read_colour(tmp_path / "bilevel.png")[..., 0], (_index(2) > 0).astype(np.float32))
    # without colour=True a palette file still gives its indices (masks: part ids)
    _palette_image(2).save(tmp_path / "p.png")
    assert np.array_equal(F.read_png(tmp_path / "p.png"), _index(2))


# ----------------------------------------------------------------------------------------------- 2./3. DVR cameras

def test_dvr_projection_world_mat_is_decomposed(tmp_path):
    """DVR's multi-view convention world_mat = K [R | t] (pixels) was read as a rigid pose."""
    mats = []
    for k, c2w in enumerate(POSES):
        P = np.eye(4)
        P[:3, :4] = K @ cameras.invert_pose(c2w)[:3, :4]
        scaled = np.vstack([3.7 * P[:3], [0, 0, 0, 1]])  # a projection is read up to scale and sign, 3x4 or 4x4
        mats.append(-2.0 * P[:3] if k == 2 else scaled if k == 0 else P)
    _nmr_object(tmp_path / "c" / "o", mats)
    sc = L.load_nmr(tmp_path / "c" / "o")
    _check_rays(sc)


@pytest.mark.parametrize("bad,match", [
    ("scaled", r"neither a rigid world-to-camera pose .* nor a projection K \[R \| t\].*scale_mat"),
    ("scaled_up", r"neither a rigid .* scaled rotation \(scale 3\).*scale_mat"),
    ("mirrored", r"neither a rigid .* mirrored rotation"),
    ("skew", r"neither a rigid .* skew"),
    ("singular", r"neither a rigid .* singular"),
])
def test_dvr_world_mat_that_is_neither_pose_nor_projection_is_refused(tmp_path, bad, match):
    w2c = cameras.invert_pose(POSES[0])
    if bad in ("scaled", "scaled_up", "mirrored"):
        m = w2c.copy()
        m[:3, :3] *= {"scaled": 0.5, "scaled_up": 3.0, "mirrored": 1.0}[bad]
        if bad == "mirrored":
            m[0, :3] *= -1
    elif bad == "skew":
        Ks = K.copy()
        Ks[0, 1] = 3.0
        m = np.vstack([Ks @ w2c[:3], [0, 0, 0, 1]])
    else:
        m = w2c.copy()
        m[:3, 2] = m[:3, 0]
    _nmr_object(tmp_path / "c" / "o", [m], camera_mat=_ndc_camera_mat())
    with pytest.raises(InputError, match=match):
        L.load_nmr(tmp_path / "c" / "o")


@pytest.mark.parametrize("projection", [False, True])
def test_dvr_scale_mat_is_applied(tmp_path, projection):
    """A world scaled (and moved) by scale_mat gives the rays of the normalised one (pixelNeRF's DVR loader)."""
    s, b = 2.5, np.array([0.3, -0.2, 0.1])
    S = np.eye(4)
    S[:3, :3] *= s
    S[:3, 3] = b
    mats = []
    for c2w in POSES:
        cw = c2w.copy()
        cw[:3, 3] = s * c2w[:3, 3] + b  # the same camera in world units: world = S @ normalised
        w2c = cameras.invert_pose(cw)
        mats.append(np.vstack([K @ w2c[:3], [0, 0, 0, 1]]) if projection else w2c)
    cm = None if projection else _ndc_camera_mat()
    _nmr_object(tmp_path / "scaled" / "o", mats, camera_mat=cm, scale_mat=S)
    _check_rays(L.load_nmr(tmp_path / "scaled" / "o"))
    unscaled = [cameras.invert_pose(c2w) for c2w in POSES]
    _nmr_object(tmp_path / "unit" / "o", unscaled, camera_mat=_ndc_camera_mat(), scale_mat=np.eye(4))
    _check_rays(L.load_nmr(tmp_path / "unit" / "o"))
    S2 = np.diag([2.0, 3.0, 2.0, 1.0])
    _nmr_object(tmp_path / "aniso" / "o", mats, camera_mat=cm, scale_mat=S2)
    with pytest.raises(InputError, match="scale_mat must be a uniform scale and a translation"):
        L.load_nmr(tmp_path / "aniso" / "o")


# ----------------------------------------------------------------------------------------------- 4. NMR split lists

def _nmr_set(root, names=("a", "b")):
    for n in names:
        _nmr_object(root / "02958343" / n, [cameras.invert_pose(c) for c in POSES], camera_mat=_ndc_camera_mat())
    return root


def test_nmr_prefers_pixelnerf_softras_lists_and_names_the_alternatives(tmp_path):
    root = _nmr_set(tmp_path / "nmr")
    (root / "02958343" / "softras_test.lst").write_text("b\n")
    (root / "02958343" / "softras_train.lst").write_text("a\n")
    assert L.list_objects(root, split="test") == [("nmr", root / "02958343" / "b")]  # only softras lists
    (root / "02958343" / "test.lst").write_text("a\n")  # DVR's own list beside it: softras still wins
    objs = L.list_objects(root, split="test")
    assert objs == [("nmr", root / "02958343" / "b")]
    assert L.load_object(*objs[0], "test").split_list == "02958343/softras_test.lst"
    with pytest.raises(InputError, match=r"softras_val\.lst .*<category>/val\.lst .*02958343/softras_test\.lst"):
        L.list_objects(root, split="val")
    (root / "02958343" / "softras_test.lst").write_text("b\nghost\n")
    with pytest.raises(InputError, match="lists 'ghost'"):
        L.list_objects(root, split="test")


# ----------------------------------------------------------------------------------------------- 5. rigid poses

def test_nerf_synthetic_poses_must_be_rigid(tmp_path):
    mats = [c2w @ CV2GL for c2w in POSES]
    mats[1] = mats[1].copy()
    mats[1][:3, :3] *= 1.5
    _nerf_scene(tmp_path / "lego", matrices=mats)
    with pytest.raises(InputError, match=r"transforms_test\.json: frame 1 .* not a camera pose"):
        L.load_object("nerf", tmp_path / "lego", "test")


# ----------------------------------------------------------------------------------------------- 6. NeRF splits

def test_nerf_synthetic_scenes_are_found_by_the_split_asked(tmp_path):
    for name in ("lego", "ship"):
        _nerf_scene(tmp_path / name, split="test")
    objs = L.list_objects(tmp_path, split="test")
    assert objs == [("nerf", tmp_path / "lego"), ("nerf", tmp_path / "ship")]
    sc = L.load_object(*objs[0], "test")
    _check_rays(sc, intr=cameras.Intrinsics(FX, FX, W / 2, H / 2, W, H))
    assert sc.category == "lego"  # the scene's name, not ''
    # and eval's --max-objects-per-category groups by it (every scene fell in one group, the root's)
    assert [L.object_category(*o) for o in objs] == ["lego", "ship"]
    with pytest.raises(InputError, match=r"transforms_val\.json \(the scenes have split\(s\) test\)"):
        L.list_objects(tmp_path, split="val")


# ----------------------------------------------------------------------------------------------- 7. masks

def test_format_masks_are_read(tmp_path):
    masks = []
    for k in range(len(POSES)):
        m = np.where(_index(k) > 0, 255, 0).astype(np.uint8)
        m[0, :4] = (100, 127, 128, 200)
        masks.append(m)
    _nmr_object(tmp_path / "c" / "o", [cameras.invert_pose(c) for c in POSES], camera_mat=_ndc_camera_mat(),
                masks=masks)
    sc = L.load_nmr(tmp_path / "c" / "o")
    assert sc.masks is not None and np.array_equal(sc.masks, np.stack(masks) > 127)
    _nerf_scene(tmp_path / "lego")
    sn = L.load_object("nerf", tmp_path / "lego", "test")
    want = np.stack([_index(k) > 0 for k in range(len(POSES))])
    assert sn.masks is not None and np.array_equal(sn.masks, want)  # alpha 100 of 255 at (0, 0): empty
    assert np.allclose(sn.images[:, 0, 0], 1.0)  # transparent black -> white
    _nerf_scene(tmp_path / "opaque", rgba=False)
    assert L.load_object("nerf", tmp_path / "opaque", "test").masks is None


def test_eval_records_split_lists_and_skipping_without_masks(tmp_path, tiny_model):
    root = _nmr_set(tmp_path / "nmr", names=("a",))
    (root / "02958343" / "softras_test.lst").write_text("a\n")
    sc = L.load_object(*L.list_objects(root, split="test")[0], "test")
    assert sc.masks is None
    rep = _run(evaluate(tiny_model, [sc], [0], max_targets=1, skip="cull", extra={"data": {"split": "test"}}))
    assert rep["data"] == {"split": "test", "split_lists": ["02958343/softras_test.lst"]}
    assert rep["protocol"]["empty_space_skipping"] == "off (no masks)"
    sc.masks = np.ones((len(sc), H, W), bool)
    rep = _run(evaluate(tiny_model, [sc], [0], max_targets=1, skip="cull"))
    assert rep["protocol"]["empty_space_skipping"] == "cull"
    from blender_mrvm.training.evaluate import skipping_record

    bare = L.ObjectScene("x", "c", sc.images, sc.c2w, sc.intrinsics, sc.bbox, sc.view_ids)
    assert skipping_record("tighten", [sc, bare]) == "tighten for the 1 of 2 objects with masks, off for the rest"
    assert skipping_record("off", [bare]) == "off"


# ----------------------------------------------------------------------------------------------- minor

def test_srn_categories_missing_intrinsics_plain_split_folders(tmp_path):
    _srn_object(tmp_path / "srn" / "cars_test" / "a")
    _srn_object(tmp_path / "srn" / "cars_test" / "b", intrinsics=False)
    objs = L.list_objects(tmp_path / "srn", split="test")
    assert objs == [("srn", tmp_path / "srn" / "cars_test" / "a"), ("srn", tmp_path / "srn" / "cars_test" / "b")]
    assert L.load_object(*objs[0]).category == "cars"
    with pytest.raises(InputError, match="without intrinsics.txt"):
        L.load_object(*objs[1])
    _srn_object(tmp_path / "plain" / "test" / "c")
    with pytest.raises(InputError, match="the 'test' split of an SRN set, not 'train'"):
        L.list_objects(tmp_path / "plain" / "test", split="train")
    objs = L.list_objects(tmp_path / "plain", split="test")
    assert objs == [("srn", tmp_path / "plain" / "test" / "c")] and L.load_object(*objs[0]).category == "plain"


def test_uppercase_suffixes(tmp_path):
    _srn_object(tmp_path / "cars_test" / "a", suffix=".PNG")
    _check_rays(L.load_object("srn", tmp_path / "cars_test" / "a"), intr=cameras.Intrinsics(FX, FX, CX, CY, W, H))
    _nmr_object(tmp_path / "c" / "o", [cameras.invert_pose(c) for c in POSES], camera_mat=_ndc_camera_mat(),
                suffix=".JPG")
    assert len(L.load_nmr(tmp_path / "c" / "o")) == len(POSES)
    _nerf_scene(tmp_path / "lego", stem_suffix=".PNG")
    sn = L.load_object("nerf", tmp_path / "lego", "test")
    assert len(sn) == len(POSES) and sn.masks is not None


def test_our_format_reads_as_before(tmp_path):
    """Our own renders: the images are the PNG's pixels over white, as the loader always gave them (a guard: passes
    before and after the fixes)."""
    root = make_sphere_dataset(tmp_path / "ds", n_objects=1, n_views=3, resolution=16, seed=5)
    obj = next(root.glob("*/*/meta.json")).parent
    sc = L.load_ours(obj)
    for k in range(3):
        raw = np.asarray(Image.open(obj / "rgb" / f"{k:06d}.png")).astype(np.float32) / 255
        if raw.shape[-1] == 4:
            raw = raw[..., :3] * raw[..., 3:] + (1 - raw[..., 3:])
        assert np.array_equal(sc.images[k], np.clip(raw[..., :3], 0, 1))


@pytest.mark.parametrize("layout", ["srn", "nerf", "nmr", "none"])
def test_an_object_folder_of_another_tool_is_named_not_called_broken(tmp_path, layout):
    """synthesize (and the other readers of one object folder) given an SRN object or a NeRF-synthetic scene said only
    "not an object folder (no meta.json)", as if the folder were damaged: the layout and who reads it are named."""
    folder = tmp_path / layout
    folder.mkdir()
    if layout == "srn":
        (folder / "intrinsics.txt").write_text("100 16 16 0\n0 0 0\n1\n32 32\n")
        (folder / "rgb").mkdir()
    elif layout == "nerf":
        (folder / "transforms_train.json").write_text('{"camera_angle_x": 0.7, "frames": []}')
    elif layout == "nmr":
        np.savez(folder / "cameras.npz", world_mat_0=np.eye(4))
    with pytest.raises(InputError) as e:
        F.read_object(folder)
    msg = str(e.value)
    assert msg.startswith(f"{folder} is not an object folder (no meta.json)") and "\n" not in msg
    if layout == "none":
        assert msg == f"{folder} is not an object folder (no meta.json)"
    else:
        assert f"it holds {F.LAYOUT_NAMES[layout]}" in msg and f"--format {layout}" in msg
