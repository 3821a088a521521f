"""Datasets made by other tools, as researchers bring them to `train` and `eval`: NeRF-synthetic, nerfstudio and
instant-ngp ``transforms_<split>.json`` variants and SRN ``intrinsics.txt`` variations, laid out here with numpy
and PIL from known cameras. Each loaded camera is checked by reprojection (a known 3D point lands on the pixel the
true camera puts it), and what cannot be read right is refused in one line (InputError), never loaded wrong."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from PIL import Image

from blender_mrvm import cli
from blender_mrvm.datasets import loaders as L
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import cameras

W, H = 16, 12
FX, FY, CX, CY = 20.0, 19.0, 8.5, 6.5
TRUE = cameras.Intrinsics(FX, FY, CX, CY, W, H)
POSES = [cameras.look_at_opencv(e) for e in ([2.6, 0.5, 0.7], [-1.0, 2.6, 0.3], [0.3, -1.5, 2.4])]
CV2GL = np.diag([1.0, -1.0, -1.0, 1.0])
POINTS = np.array([[0.1, -0.2, 0.15], [0.3, 0.25, -0.1]])
NERF = {"fl_x": FX, "fl_y": FY, "cx": CX, "cy": CY, "w": W, "h": H}


def _rgba(k: int) -> np.ndarray:
    a = np.full((H, W, 4), 255, np.uint8)
    a[3:9, 4:12, k % 3] = 40
    a[:2, :2, 3] = 0
    return a


def _scene(scene, keys, frame_keys=lambda k: {}, matrices=None, names=lambda k: f"./train/r_{k}", split="train",
           save=lambda k, p: Image.fromarray(_rgba(k)).save(p), suffix=".png"):
    """A scene folder: images under train/, transforms_<split>.json with the file's ``keys`` and each frame's."""
    (scene / "train").mkdir(parents=True, exist_ok=True)
    frames = []
    for k, c2w in enumerate(POSES):
        path = scene / names(k)
        save(k, path if path.suffix else path.with_name(path.name + suffix))
        m = (c2w @ CV2GL) if matrices is None else matrices[k]
        frames.append({"file_path": names(k), "transform_matrix": np.asarray(m).tolist(), **frame_keys(k)})
    (scene / f"transforms_{split}.json").write_text(json.dumps({**keys, "frames": frames}))
    return scene


def _reprojects(sc, intr=TRUE, atol=1e-6):
    """Every view puts the known points on the pixels the true camera does."""
    assert len(sc) == len(POSES)
    for i, c2w in enumerate(POSES):
        got, _ = cameras.project(sc.intrinsics[i].K, cameras.invert_pose(sc.c2w[i]), POINTS)
        want, _ = cameras.project(intr.K, cameras.invert_pose(c2w), POINTS)
        assert np.allclose(got, want, atol=atol), (i, got, want)
        assert (sc.intrinsics[i].width, sc.intrinsics[i].height) == (sc.images.shape[2], sc.images.shape[1])


# ----------------------------------------------------------------------------------------------- transforms.json

def test_transforms_cameras_of_other_tools_reproject(tmp_path):
    """nerfstudio / instant-ngp cameras: per-frame intrinsics; a camera written for the full-size images of a
    downscaled set (before: kept at the file's size, the points 6 to 9 pixels off); camera_angle_x with
    camera_angle_y (before: fy = fx); the file's keys a reader need not apply (applied_transform, zero distortion)."""
    _reprojects(L.load_object("nerf", _scene(tmp_path / "per_frame", {}, lambda k: NERF), "train"))
    big = {"fl_x": 2 * FX, "fl_y": 2 * FY, "cx": 2 * CX, "cy": 2 * CY, "w": 2 * W, "h": 2 * H}
    _reprojects(L.load_object("nerf", _scene(tmp_path / "downscaled", big), "train"))
    # no principal point: the centre of the file's size, which is the images' centre
    no_c = {"fl_x": 2 * FX, "fl_y": 2 * FY, "w": 2 * W, "h": 2 * H}
    _reprojects(L.load_object("nerf", _scene(tmp_path / "centred", no_c), "train"),
                cameras.Intrinsics(FX, FY, W / 2, H / 2, W, H))
    angles = {"camera_angle_x": 2 * math.atan(W / (2 * FX)), "camera_angle_y": 2 * math.atan(H / (2 * FY))}
    _reprojects(L.load_object("nerf", _scene(tmp_path / "angles", angles), "train"),
                cameras.Intrinsics(FX, FY, W / 2, H / 2, W, H))
    ns = {**NERF, "camera_model": "OPENCV", "k1": 0.0, "k2": 0, "p1": 0, "p2": 0, "is_fisheye": False,
          "applied_transform": [[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0]]}
    sc = L.load_object("nerf", _scene(tmp_path / "nerfstudio", ns, names=lambda k: f"images/frame_{k:05d}.jpg",
                                      save=lambda k, p: (p.parent.mkdir(exist_ok=True),
                                                         Image.fromarray(_rgba(k)[..., :3]).save(p))), "train")
    _reprojects(sc)
    assert sc.masks is None


def test_transforms_lens_distortion_and_fisheyes_are_refused(tmp_path):
    """A distorted or fisheye camera read as a pinhole one loaded silently (before): refused, naming the keys."""
    cases = {"radial": {**NERF, "camera_model": "OPENCV", "k1": 0.1, "k2": 0.0, "p1": 0.0, "p2": 0.0},
             "tangential": {**NERF, "p2": -0.002},
             "fisheye": {**NERF, "camera_model": "OPENCV_FISHEYE", "k1": 0.0},
             "ngp_fisheye": {**NERF, "is_fisheye": True}}
    for name, keys in cases.items():
        with pytest.raises(InputError, match=r"frame 0 .*(lens distortion|not a pinhole camera)"):
            L.load_object("nerf", _scene(tmp_path / name, keys), "train")
    with pytest.raises(InputError, match=r"frame 1 .*lens distortion k1=0\.05"):  # per frame too
        L.load_object("nerf", _scene(tmp_path / "per_frame", NERF, lambda k: {"k1": 0.05} if k == 1 else {}), "train")


@pytest.mark.parametrize("keys,frame,match", [
    ({}, None, "no focal length"),
    ({"camera_angle_x": "wide"}, None, "camera_angle_x must be a positive number"),
    ({"camera_angle_x": 0}, None, "camera_angle_x must be a positive number"),
    ({"fl_x": None}, None, "fl_x must be a positive number"),
    ({"fl_x": -FX}, None, "fl_x must be a positive number"),
    ({**NERF, "w": 2 * W}, None, "another aspect ratio"),
    ({"camera_angle_x": 0.9}, {"file_path": None}, "frame 1 is not an object with a 'file_path'"),
    ({"camera_angle_x": 0.9}, {"transform_matrix": None}, "frame 1 is not an object with a 'file_path'"),
    ({"camera_angle_x": 0.9}, 7, "frame 1 is not an object"),
])
def test_transforms_that_cannot_be_read_are_one_line_errors(tmp_path, keys, frame, match):
    """Before: KeyError, TypeError, ZeroDivisionError tracebacks, or a negative focal length loaded (a mirrored
    camera); a camera for another aspect ratio was kept at the file's size."""
    scene = _scene(tmp_path / "s", keys)
    if frame is not None:
        tf = scene / "transforms_train.json"
        d = json.loads(tf.read_text())
        if isinstance(frame, dict):  # None: the key left out
            d["frames"][1] = {k: v for k, v in {**d["frames"][1], **frame}.items() if v is not None}
        else:
            d["frames"][1] = frame
        tf.write_text(json.dumps(d))
    with pytest.raises(InputError, match=match):
        L.load_object("nerf", scene, "train")


def test_transforms_errors_reach_the_cli_as_one_line(tmp_path, capsys):
    """eval on a scene without a focal length: one `error:` line and exit 2 (before: a KeyError traceback)."""
    scene = _scene(tmp_path / "s", {}, split="test")
    rc = cli.main(["eval", "--data", str(scene), "--split", "test", "--input-views", "0", "--no-lpips",
                   "--out", str(tmp_path / "ev")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err[-1].startswith("error: ") and "no focal length" in err[-1]


def test_transforms_frames_naming_one_image_twice_are_refused(tmp_path):
    """Two frames of one image were two views (a target that is also a reference scores itself)."""
    scene = _scene(tmp_path / "s", NERF, names=lambda k: "./train/r_0")
    with pytest.raises(InputError, match=r"frames 0 and 1 are both r_0\.png"):
        L.load_object("nerf", scene, "train")


def test_transforms_exr_images_are_named(tmp_path):
    """An EXR frame without its suffix was reported as a missing .png; with it, as an unidentified image."""
    def exr(k, p):
        import OpenEXR

        with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                          {"RGBA": _rgba(k).astype(np.float32) / 255}) as f:
            f.write(str(p))

    with pytest.raises(InputError, match=r"frame 0 \(\./train/r_0\): r_0\.exr is a linear high-dynamic-range image"):
        L.load_object("nerf", _scene(tmp_path / "s", NERF, save=exr, suffix=".exr"), "train")


def test_transforms_poses_of_the_other_convention_are_refused(tmp_path):
    """OpenCV matrices written into a transforms.json loaded silently, the cameras turned away from the scene."""
    scene = _scene(tmp_path / "s", NERF, matrices=POSES)
    with pytest.raises(InputError, match=r"frame \d .*looks away from the scene box.*OpenGL"):
        L.load_object("nerf", scene, "train")


def test_instant_ngp_and_nerfstudio_boxes(tmp_path):
    """The box was NeRF-synthetic's [-1.5, 1.5]^3 whatever the file said: instant-ngp's scale / offset put its unit
    cube elsewhere (p * scale + offset in [0, 1]^3; aabb_scale, the background's extent, is not the object's), and a
    nerfstudio file holds poses in COLMAP's units around any centre (its loader boxes the cameras' region)."""
    keys = {**NERF, "scale": 0.5, "offset": [0.5, 0.0, 0.5], "aabb_scale": 2}
    sc = L.load_object("nerf", _scene(tmp_path / "ngp", keys), "train")
    assert np.allclose(sc.bbox[0], [-1, 0, -1]) and np.allclose(sc.bbox[1], [1, 2, 1])
    _reprojects(sc)
    sc = L.load_object("nerf", _scene(tmp_path / "colmap2nerf", {**NERF, "aabb_scale": 32}), "train")
    assert np.allclose(sc.bbox[0], -1.5) and np.allclose(sc.bbox[1], 1.5)
    centre = np.array([30.0, -10.0, 20.0])  # a nerfstudio capture: ten times NeRF-synthetic's size, off the origin
    moved = [cameras.look_at_opencv(centre + 10 * c2w[:3, 3], centre) for c2w in POSES]
    ns = {**NERF, "camera_model": "OPENCV", "applied_transform": np.eye(4)[:3].tolist()}
    sc = L.load_object("nerf", _scene(tmp_path / "ns", ns, matrices=[c2w @ CV2GL for c2w in moved]), "train")
    lo, hi = sc.bbox
    assert np.all(lo <= centre - 10) and np.all(hi >= centre + 10)  # the object and every camera inside
    assert np.all(hi - lo < 80)


def test_a_lone_transforms_json_is_named(tmp_path):
    """A nerfstudio / instant-ngp folder (transforms.json, no split files) was 'not a dataset this tool reads'."""
    scene = _scene(tmp_path / "s", NERF)
    (scene / "transforms_train.json").rename(scene / "transforms.json")
    with pytest.raises(InputError, match=r"holds a transforms\.json .* copy it to transforms_test\.json"):
        L.detect_format(scene)
    with pytest.raises(InputError, match=r"no transforms_train\.json; it holds a transforms\.json"):
        L.load_object("nerf", scene, "train")


# ----------------------------------------------------------------------------------------------- SRN

def _srn(obj, intrinsics: str, size=(W, H), poses=POSES):
    (obj / "rgb").mkdir(parents=True)
    (obj / "pose").mkdir()
    for k, c2w in enumerate(poses):
        Image.fromarray(np.full((size[1], size[0], 3), 60 * k, np.uint8)).save(obj / "rgb" / f"{k:06d}.png")
        (obj / "pose" / f"{k:06d}.txt").write_text(" ".join(f"{v:.12g}" for v in np.asarray(c2w).reshape(-1)))
    (obj / "intrinsics.txt").write_text(intrinsics)
    return obj


def test_srn_intrinsics_variations(tmp_path):
    """pixelNeRF's layout at the images' size or at another of the same aspect loads; a one-line file (its 'f cx'
    read as 'H W': the camera 6 to 9 pixels off), a K matrix (ZeroDivisionError), a zero focal length or size, and
    'H W' of another aspect (the camera kept the file's height, not the images') are refused."""
    sq = cameras.Intrinsics(FX, FX, CX, CY, W, H)
    _reprojects(L.load_object("srn", _srn(tmp_path / "same", f"{FX} {CX} {CY} 0.\n0. 0. 0.\n1.\n{H} {W}\n")), sq)
    _reprojects(L.load_object("srn", _srn(tmp_path / "2x", f"{2 * FX} {2 * CX} {2 * CY} 0.\r\n0. 0. 0.\r\n1.\r\n"
                                                           f"{2 * H} {2 * W}\r\n")), sq)
    bad = {"one_line": (f"{FX} {CX} {CY} 0.\n", "1 line"),
           "k3": (f"{FX} 0 {CX}\n0 {FX} {CY}\n0 0 1\n", "a K matrix"),
           "k4": (f"{FX} 0 {CX} 0\n0 {FX} {CY} 0\n0 0 1 0\n0 0 0 1\n", "a K matrix"),
           "f0": (f"0 {CX} {CY} 0.\n0. 0. 0.\n1.\n{H} {W}\n", "focal length must be a positive"),
           "size0": (f"{FX} {CX} {CY} 0.\n0. 0. 0.\n1.\n0 0\n", "must be positive"),
           "w_h": (f"{FX} {CX} {CY} 0.\n0. 0. 0.\n1.\n{W} {H}\n", "another aspect ratio")}
    for name, (text, match) in bad.items():
        with pytest.raises(InputError, match=match):
            L.load_object("srn", _srn(tmp_path / name, text))


def test_srn_poses_of_the_other_convention_are_refused(tmp_path):
    """OpenGL camera-to-world matrices in pose/ (SRN's are OpenCV) loaded silently, every camera turned around."""
    obj = _srn(tmp_path / "gl", f"{FX} {CX} {CY} 0.\n0. 0. 0.\n1.\n{H} {W}\n", poses=[c2w @ CV2GL for c2w in POSES])
    with pytest.raises(InputError, match=r"pose/000000\.txt: the camera looks away .*OpenCV"):
        L.load_object("srn", obj)


# ----------------------------------------------------------------------------------------------- NMR/DVR

@pytest.mark.parametrize("spoil,match", [
    (lambda p: p.write_bytes(p.read_bytes()[:100]), "cannot read .*cameras.npz"),  # an interrupted download
    (lambda p: p.write_bytes(b""), "cannot read .*cameras.npz"),
    (lambda p: np.savez(p, world_mat_0=np.array([["a"] * 4] * 3), camera_mat_0=np.eye(4)),
     "world_mat_0 is not a matrix of numbers"),
])
def test_nmr_cameras_that_cannot_be_read_are_one_line_errors(tmp_path, spoil, match):
    """A truncated or empty cameras.npz (BadZipFile, EOFError) or a matrix of text (ValueError) was a traceback."""
    obj = tmp_path / "cat" / "obj"
    (obj / "image").mkdir(parents=True)
    Image.fromarray(_rgba(0)[..., :3]).save(obj / "image" / "0000.png")
    np.savez(obj / "cameras.npz", world_mat_0=np.linalg.inv(POSES[0])[:3], camera_mat_0=np.eye(4))
    spoil(obj / "cameras.npz")
    with pytest.raises(InputError, match=match):
        L.load_object("nmr", obj)


def test_our_own_transforms_json_reads_its_camera_and_refuses_what_it_cannot(tmp_path, capsys):
    """``format.read_transforms`` (our object folders, the panel's capture import): a truncated file was a
    JSONDecodeError traceback from eval; nerfstudio's OPENCV camera with non-zero coefficients was placed as a
    pinhole one; a frame without its matrix was a KeyError. Our own writer's file (zero coefficients) reads back."""
    from blender_mrvm.datasets import format as F

    good = tmp_path / "transforms.json"
    good.write_text(json.dumps(F.transforms_dict(TRUE, [{"file_path": f"rgb/{k:06d}.png", "c2w_opencv": POSES[k]}
                                                        for k in range(3)])))
    frames = json.loads(good.read_text())["frames"]
    got = F.read_transforms(good)
    assert [f.intrinsics for f in got] == [TRUE] * 3
    assert all(np.allclose(f.c2w_opencv, POSES[k]) for k, f in enumerate(got))
    bad = tmp_path / "bad.json"
    for text, needle in [
        (good.read_text()[:40], "is not valid JSON"),
        (json.dumps({**json.loads(good.read_text()), "k1": 0.12}), "lens distortion k1=0.12"),
        (json.dumps({**json.loads(good.read_text()), "camera_model": "OPENCV_FISHEYE"}), "not a pinhole camera"),
        (json.dumps({**json.loads(good.read_text()), "frames": [{"file_path": "rgb/0.png"}]}),
         "needs file_path and transform_matrix"),
        (json.dumps({**json.loads(good.read_text()), "frames": [{**frames[0], "transform_matrix": [[1, 0], [0, 1]]}]}),
         "4x4 matrix"),
        (json.dumps({"frames": {"a": 1}}), "not a transforms.json"),
    ]:
        bad.write_text(text)
        with pytest.raises(InputError, match=needle):
            F.read_transforms(bad)


def test_our_own_and_sem2nerfs_intrinsics_txt_are_read_with_the_srn_checks(tmp_path):
    """``format.read_srn_intrinsics`` (our object folders, sem2nerf --intrinsics) read a one-line file's 'f cx' as
    its 'H W' and took a zero focal length; the SRN loader's layout and value checks are its own now."""
    from blender_mrvm.datasets import format as F

    p = tmp_path / "intrinsics.txt"
    p.write_text("20.0 8.5 6.5 0.\n")
    with pytest.raises(InputError, match="not an SRN intrinsics file: it holds 1 line"):
        F.read_srn_intrinsics(p)
    p.write_text("0.0 8.5 6.5 0.\n0. 0. 0.\n1.\n12 16\n")
    with pytest.raises(InputError, match="focal length must be a positive number"):
        F.read_srn_intrinsics(p)
    p.write_text("20.0 8.5 6.5 0.\n0. 0. 0.\n1.\n12 16\n")
    assert F.read_srn_intrinsics(p) == cameras.Intrinsics(20.0, 20.0, 8.5, 6.5, 16, 12)
