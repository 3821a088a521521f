"""Image planes: corners on the frustum (Blender's own projection), the render shows the image,
save/reload keeps everything (packed and files), errors leave the scene as it was."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.errors import InputError, OutputError

# (resolution, pixel aspect, lens, sensor fit, sensor w/h, shift x/y)
CAMERAS = {
    "shifted": ((40, 28), (1.0, 1.0), 30.0, "AUTO", (36.0, 24.0), (0.13, -0.07)),
    "portrait": ((24, 36), (1.0, 1.0), 42.0, "VERTICAL", (36.0, 20.0), (-0.05, 0.11)),
    "non_square_pixels": ((36, 30), (1.0, 1.6), 25.0, "HORIZONTAL", (32.0, 24.0), (0.0, 0.09)),
    "wide_pixels": ((30, 30), (1.7, 1.0), 35.0, "AUTO", (36.0, 24.0), (0.2, 0.0)),
}


def _scene_camera(scene, name, spec, location=(3.0, -2.0, 1.5), rotation=(1.2, 0.1, 0.9), scale=(1.0, 1.0, 1.0)):
    from blender_mrvm.scene import camera as scam

    (w, h), (ax, ay), lens, fit, (sw, sh), (sx, sy) = spec
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
    r.pixel_aspect_x, r.pixel_aspect_y = ax, ay
    cam = scam.new_camera(name, scene.collection)
    d = cam.data
    d.lens, d.sensor_fit, d.sensor_width, d.sensor_height, d.shift_x, d.shift_y = lens, fit, sw, sh, sx, sy
    cam.location, cam.rotation_euler, cam.scale = location, rotation, scale
    scene.camera = cam
    return cam


def _test_image(w, h, seed=0):
    """Per-pixel random colours (any flip or one-pixel slip shows), a transparent block, a half-alpha band."""
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
    img[..., 3] = 255
    img[h // 5: h // 2, w // 10: w // 3, 3] = 0
    img[-3:, :, 3] = 128
    return img


def _frame_px(scene, cam, plane):
    """Pixel coordinates (top-left origin) of the plane's corners by Blender's own camera projection."""
    import bpy
    from bpy_extras.object_utils import world_to_camera_view

    bpy.context.view_layer.update()
    w, h = scene.render.resolution_x, scene.render.resolution_y
    out = []
    for v in list(plane.data.vertices)[:4]:  # the frame corners (vertex 4 is the fan's inner vertex)
        q = world_to_camera_view(scene, cam, plane.matrix_world @ v.co)
        out.append((q.x * w, (1.0 - q.y) * h))
    return np.array(out)


def _planar_depths(cam, plane):
    from blender_mrvm.geometry import cameras as C

    w2c = C.invert_pose(C.opencv_from_blender(C.remove_scale(C.as_pose(cam.matrix_world))))
    pts = np.array([list(plane.matrix_world @ v.co) for v in plane.data.vertices])
    return (pts @ w2c[:3, :3].T + w2c[:3, 3])[:, 2]


def _render(scene, path: Path) -> np.ndarray:
    """1-sample, near-zero-filter Cycles render of the scene camera, Standard view: pixel-centre samples."""
    import bpy
    from PIL import Image

    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.filter_width = 0.01
    scene.cycles.use_denoising = False
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    s = scene.render.image_settings
    s.file_format, s.color_mode, s.color_depth = "PNG", "RGBA", "8"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True, scene=scene.name)
    with Image.open(path) as im:
        return np.asarray(im).copy()


def _state(tmp_path: Path):
    """Every datablock name, the scene's collections and the files under tmp_path (for 'nothing changed')."""
    import bpy

    names = {k: sorted(d.name for d in getattr(bpy.data, k))
             for k in ("objects", "meshes", "materials", "images", "collections", "cameras")}
    names["scene_children"] = sorted(c.name for c in bpy.context.scene.collection.children)
    names["files"] = sorted((str(p.relative_to(tmp_path)), p.read_bytes()) for p in tmp_path.rglob("*") if p.is_file())
    return names


@pytest.mark.parametrize("kind", list(CAMERAS))
def test_corners_on_frame_and_render_shows_image(kind, empty_scene, tmp_path):
    import bpy

    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    cam = _scene_camera(scene, "Target", CAMERAS[kind], scale=(1.0, 1.0, 1.0) if kind != "shifted" else (2.0, 0.5, 1.3))
    w, h = CAMERAS[kind][0]
    img = _test_image(w, h)
    res = IP.build_image_planes(scene, [IP.NovelView("Target", img)], IP.PlaneConfig(distance=2.5, folder=str(tmp_path / "nv")))
    plane = res.planes[0]
    assert res.collection.name == "MRVM novel views" and plane.name in res.collection.objects
    assert plane.parent == cam and IP.planes_of(cam) == [plane]

    # Blender's own projection (camera.view_frame: shift, sensor fit, pixel aspect) puts the corners on the frame.
    corners = np.array([[0, h], [w, h], [w, 0], [0, 0]], dtype=float)
    err = np.abs(_frame_px(scene, cam, plane) - corners).max()
    assert err < 0.5, f"{kind}: corners off by {err:.3g} px"
    assert np.allclose(_planar_depths(cam, plane), 2.5, atol=1e-5)

    # The material: emission of the saved PNG, transparent by its alpha.
    mat = plane.data.materials[0]
    nt = mat.node_tree
    tex = next(n for n in nt.nodes if n.type == "TEX_IMAGE")
    out = next(n for n in nt.nodes if n.type == "OUTPUT_MATERIAL")
    mix = out.inputs["Surface"].links[0].from_node
    assert mix.type == "MIX_SHADER" and mix.inputs["Fac"].links[0].from_socket == tex.outputs["Alpha"]
    assert {mix.inputs[1].links[0].from_node.type, mix.inputs[2].links[0].from_node.type} == {"BSDF_TRANSPARENT", "EMISSION"}
    assert Path(bpy.path.abspath(tex.image.filepath)).resolve() == (tmp_path / "nv" / "Target.png").resolve()
    assert mat.surface_render_method == "BLENDED"
    assert not plane.visible_shadow and plane.visible_camera

    # Rendering the camera's view shows the image pixel for pixel (no flip, no half-pixel slip).
    got = _render(scene, tmp_path / "render.png")
    assert got.shape == img.shape
    assert np.abs(got[..., 3].astype(int) - img[..., 3]).max() <= 1
    opaque = img[..., 3] == 255
    assert np.abs(got[..., :3].astype(int) - img[..., :3])[opaque].max() <= 2
    half = img[..., 3] == 128  # straight alpha: colour is unpremultiplied back to the image's (8-bit rounding)
    assert np.abs(got[..., :3].astype(int) - img[..., :3])[half].mean() <= 2

    # The plane follows its camera.
    cam.location = (-1.0, 4.0, 2.0)
    cam.rotation_euler = (0.7, -0.2, 2.5)
    assert np.abs(_frame_px(scene, cam, plane) - corners).max() < 0.5


def test_image_at_another_scale_and_from_file(empty_scene, tmp_path):
    from PIL import Image

    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    _scene_camera(scene, "Cam", CAMERAS["shifted"])
    src = tmp_path / "in.png"
    Image.fromarray(_test_image(80, 56)).save(src)  # twice the render size
    res = IP.build_image_planes(scene, [IP.NovelView("Cam", src)], IP.PlaneConfig(distance=1.0, folder=str(tmp_path / "nv")))
    assert (tmp_path / "nv" / "Cam.png").read_bytes() == src.read_bytes()
    assert tuple(res.images[0].size) == (80, 56)


def _images_equal(img, expected: np.ndarray) -> float:
    """Max abs difference (0..255) between a Blender image's pixels and an (H, W, 4) uint8 array."""
    w, h = img.size
    px = np.array(img.pixels[:], dtype=np.float32).reshape(h, w, 4)[::-1]  # Blender rows start at the bottom
    return float(np.abs(px * 255.0 - expected).max())


@pytest.mark.parametrize("pack", [False, True], ids=["files", "packed"])
def test_save_and_reload(pack, empty_scene, tmp_path):
    import bpy

    from blender_mrvm.datasets.format import read_depth
    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    _scene_camera(scene, "CamA", CAMERAS["shifted"])
    _scene_camera(scene, "CamB", CAMERAS["shifted"], location=(-3.0, 2.0, 1.0), rotation=(1.1, 0.0, -2.3))
    imgs = {"CamA": _test_image(40, 28, 1), "CamB": _test_image(40, 28, 2)}
    depth = np.linspace(1.0, 3.0, 40 * 28, dtype=np.float32).reshape(28, 40)
    views = [IP.NovelView("CamA", imgs["CamA"], depth=depth), IP.NovelView("CamB", imgs["CamB"])]
    IP.build_image_planes(scene, views, IP.PlaneConfig(distance=1.5, pack=pack))
    folder = tmp_path / "mrvm_novel_views"
    if pack:
        assert not folder.exists(), "packed mode writes no files next to the .blend"
    else:
        assert sorted(p.name for p in folder.iterdir()) == ["CamA.png", "CamA_depth.exr", "CamB.png"]
        assert np.array_equal(read_depth(folder / "CamA_depth.exr"), depth)
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert "MRVM novel views" not in bpy.data.collections
    bpy.ops.wm.open_mainfile(filepath=str(blend))

    coll = bpy.data.collections["MRVM novel views"]
    assert coll.name in bpy.context.scene.collection.children
    for name in ("CamA", "CamB"):
        cam = bpy.data.objects[name]
        (plane,) = IP.planes_of(cam)
        assert plane.name in coll.objects and plane.parent == cam
        img = plane.data.materials[0].node_tree.nodes["Image Texture"].image
        assert (img.packed_file is not None) == pack
        if not pack:
            assert img.filepath.startswith("//"), "files are referenced relative to the .blend"
            assert Path(bpy.path.abspath(img.filepath)).resolve() == (folder / f"{name}.png").resolve()
        assert _images_equal(img, imgs[name]) <= 0.51
        w, h = 40, 28
        corners = np.array([[0, h], [w, h], [w, 0], [0, 0]], dtype=float)
        assert np.abs(_frame_px(bpy.context.scene, cam, plane) - corners).max() < 0.5
    dimg = bpy.data.images[bpy.data.objects["CamA"].children[0]["mrvm_depth_image"]]
    assert (dimg.packed_file is not None) == pack and dimg.colorspace_settings.name == "Non-Color"
    assert tuple(dimg.size) == (40, 28)


def test_rebuild_replaces_the_old_plane(empty_scene, tmp_path):
    import bpy

    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    cam = _scene_camera(scene, "Cam", CAMERAS["portrait"])
    cfg = IP.PlaneConfig(distance=1.0, folder=str(tmp_path))
    IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(24, 36, 1))], cfg)
    IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(24, 36, 2))], cfg)
    (plane,) = IP.planes_of(cam)
    assert len(bpy.data.meshes) == 1 and len(bpy.data.materials) == 1 and len(bpy.data.images) == 1
    assert (plane.name, bpy.data.images[0].name, bpy.data.materials[0].name) == ("MRVM plane Cam", "MRVM Cam", "MRVM Cam")
    assert _images_equal(bpy.data.images[0], _test_image(24, 36, 2)) <= 0.51


def test_errors_leave_the_scene_as_it_was(empty_scene, tmp_path):
    import bpy

    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    _scene_camera(scene, "Cam", CAMERAS["shifted"])
    bpy.data.objects.new("Empty", None)
    scene.collection.objects.link(bpy.data.objects["Empty"])
    folder = tmp_path / "nv"
    cfg = IP.PlaneConfig(distance=1.0, folder=str(folder))
    ok = IP.NovelView("Cam", _test_image(40, 28))
    before = _state(tmp_path)
    cases = [
        ([IP.NovelView("Nope", _test_image(40, 28))], cfg, "camera 'Nope' does not exist"),
        ([ok, IP.NovelView("Empty", _test_image(40, 28))], cfg, "not a camera"),
        ([IP.NovelView("Cam", tmp_path / "missing.png")], cfg, "does not exist"),
        ([IP.NovelView("Cam", _test_image(40, 40))], cfg, "aspect ratio"),
        ([IP.NovelView("Cam", _test_image(40, 28), depth=np.ones((5, 5), np.float32))], cfg, "depth map size"),
        ([ok], IP.PlaneConfig(distance=1e5, folder=str(folder)), "clip range"),
        ([ok], IP.PlaneConfig(distance=-1.0, folder=str(folder)), "positive"),
        ([], cfg, "no novel views"),
    ]
    for views, c, msg in cases:
        with pytest.raises(InputError, match=msg):
            IP.build_image_planes(scene, views, c)
        assert _state(tmp_path) == before, msg
    # "//" needs a saved .blend.
    with pytest.raises(OutputError, match="save the .blend"):
        IP.build_image_planes(scene, [ok], IP.PlaneConfig(distance=1.0))
    assert _state(tmp_path) == before


def test_failure_midway_rolls_back_datablocks_and_files(empty_scene, tmp_path, monkeypatch):
    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    _scene_camera(scene, "A", CAMERAS["shifted"])
    _scene_camera(scene, "B", CAMERAS["shifted"], location=(0.0, -4.0, 1.0))
    folder = tmp_path / "nv"
    folder.mkdir()
    (folder / "A.png").write_bytes(b"an older file the user keeps")
    # An existing collection of that name, not linked to the scene: linked for the build, unlinked on rollback.
    import bpy

    bpy.data.collections.new("MRVM novel views")
    before = _state(tmp_path)
    calls = []
    real = IP._material

    def failing(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise RuntimeError("disk full (simulated)")
        return real(*a, **k)

    monkeypatch.setattr(IP, "_material", failing)
    views = [IP.NovelView("A", _test_image(40, 28)), IP.NovelView("B", _test_image(40, 28), depth=np.ones((28, 40), np.float32))]
    with pytest.raises(RuntimeError, match="simulated"):
        IP.build_image_planes(scene, views, IP.PlaneConfig(distance=1.0, folder=str(folder)))
    assert len(calls) == 2, "the first plane was built before the failure"
    assert _state(tmp_path) == before
    assert not any(p.name.endswith(".bak") or p.name.startswith(".") for p in folder.iterdir())


def test_file_names_never_overwrite_another_planes_image(empty_scene, tmp_path):
    import bpy

    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    a = _scene_camera(scene, "Cam 1", CAMERAS["shifted"])
    b = _scene_camera(scene, "Cam_1", CAMERAS["shifted"], location=(0.0, -4.0, 1.0))
    cfg = IP.PlaneConfig(distance=1.0, folder=str(tmp_path))
    IP.build_image_planes(scene, [IP.NovelView("Cam 1", _test_image(40, 28, 1))], cfg)
    IP.build_image_planes(scene, [IP.NovelView("Cam_1", _test_image(40, 28, 2))], cfg)  # same safe name
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["Cam_1.png", "Cam_1_1.png"]
    for cam, seed in ((a, 1), (b, 2)):
        (plane,) = IP.planes_of(cam)
        img = bpy.data.images[plane["mrvm_image"]]
        img.reload()
        assert _images_equal(img, _test_image(40, 28, seed)) <= 0.51
    # Rebuilding a camera's plane takes a new file name: the saved .blend (or undo) may still show the old one.
    IP.build_image_planes(scene, [IP.NovelView("Cam_1", _test_image(40, 28, 3))], cfg)
    assert sorted(p.name for p in tmp_path.glob("*.png")) == ["Cam_1.png", "Cam_1_1.png", "Cam_1_2.png"]
    assert Path(bpy.path.abspath(bpy.data.images[IP.planes_of(b)[0]["mrvm_image"]].filepath)).name == "Cam_1_2.png"


def test_blend_files_sharing_a_folder_keep_their_own_images(empty_scene, tmp_path):
    """Two .blend files saved in one folder, each with a camera "Camera" and the default image folder: the second
    one's plane takes a new file name, so reopening the first still shows its own image; rebuilding a plane in the
    first file takes a third name, so the second's image stays as it was."""
    import bpy

    from blender_mrvm.scene import image_planes as IP

    def build(blend: Path, seed: int) -> Path:
        bpy.ops.wm.read_homefile(use_empty=True)
        scene = bpy.context.scene
        _scene_camera(scene, "Camera", CAMERAS["shifted"])
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        IP.build_image_planes(bpy.context.scene, [IP.NovelView("Camera", _test_image(40, 28, seed))],
                              IP.PlaneConfig(distance=1.0))
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))
        return Path(bpy.path.abspath(bpy.data.images["MRVM Camera"].filepath))

    a = build(tmp_path / "chair_A.blend", 1)
    b = build(tmp_path / "table_B.blend", 2)
    assert (a.name, b.name) == ("Camera.png", "Camera_1.png") and a.parent == b.parent == tmp_path / "mrvm_novel_views"
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "chair_A.blend"))
    img = bpy.data.images["MRVM Camera"]
    assert Path(bpy.path.abspath(img.filepath)) == a and _images_equal(img, _test_image(40, 28, 1)) <= 0.51
    IP.build_image_planes(bpy.context.scene, [IP.NovelView("Camera", _test_image(40, 28, 3))],
                          IP.PlaneConfig(distance=1.0))
    assert sorted(p.name for p in a.parent.iterdir()) == ["Camera.png", "Camera_1.png", "Camera_2.png"]
    assert _images_equal(bpy.data.images["MRVM Camera"], _test_image(40, 28, 3)) <= 0.51


def test_a_rerun_never_writes_over_an_image_a_saved_blend_shows(empty_scene, tmp_path):
    """Re-running for a camera that has a plane writes new files (CamA_1.png, ...), never over the old plane's: a
    .blend saved as a new version beside the original (both share //mrvm_novel_views), and the saved file after
    File > Revert (or quitting without saving), still show their own images. The replaced plane's files stay."""
    import bpy

    from blender_mrvm.scene import image_planes as IP

    v1, v2 = tmp_path / "scene.blend", tmp_path / "scene_v2.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(v1))
    _scene_camera(bpy.context.scene, "CamA", CAMERAS["shifted"])
    depth = np.ones((28, 40), np.float32)

    def build(seed: int) -> str:
        IP.build_image_planes(bpy.context.scene, [IP.NovelView("CamA", _test_image(40, 28, seed), depth=depth * seed)],
                              IP.PlaneConfig(distance=1.0))
        return bpy.data.images["MRVM CamA"].filepath

    def shows(blend: Path, path: str, seed: int) -> None:
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        img = bpy.data.images["MRVM CamA"]
        assert img.filepath == path, blend.name
        img.reload()
        assert _images_equal(img, _test_image(40, 28, seed)) <= 0.51, blend.name

    folder = tmp_path / "mrvm_novel_views"
    assert build(1) == "//mrvm_novel_views/CamA.png"
    bpy.ops.wm.save_mainfile()
    saved = {p.name: p.read_bytes() for p in folder.iterdir()}
    # a new version saved beside it, synthesized again
    bpy.ops.wm.save_as_mainfile(filepath=str(v2))
    assert build(2) == "//mrvm_novel_views/CamA_1.png"
    bpy.ops.wm.save_mainfile()
    # a third run in v2, discarded (File > Revert)
    assert build(3) == "//mrvm_novel_views/CamA_2.png"
    bpy.ops.wm.revert_mainfile()
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.name in saved} == saved
    assert sorted(p.name for p in folder.iterdir()) == [
        "CamA.png", "CamA_1.png", "CamA_1_depth.exr", "CamA_2.png", "CamA_2_depth.exr", "CamA_depth.exr"]
    shows(v2, "//mrvm_novel_views/CamA_1.png", 2)
    shows(v1, "//mrvm_novel_views/CamA.png", 1)
    from blender_mrvm.datasets.format import read_depth

    assert np.array_equal(read_depth(folder / "CamA_depth.exr"), depth)


def test_a_camera_keeps_one_plane_per_collection_and_another_features_plane_is_hidden(empty_scene, tmp_path,
                                                                                        monkeypatch):
    """Synthesize ("MRVM novel views") and Sem2NeRF ("MRVM Sem2NeRF") on one camera: each build replaces the
    camera's plane in its own collection only; the other feature's plane is kept, hidden in the viewport and the
    render (at the same distance the two would z-fight; nearer, one covers the other in the camera's view), and the
    note says so. A build that fails shows it again."""
    import bpy

    from blender_mrvm.scene import image_planes as IP

    scene = empty_scene
    cam = _scene_camera(scene, "Cam", CAMERAS["shifted"])
    nv = IP.PlaneConfig(distance=1.0, folder=str(tmp_path / "nv"))
    s2n = IP.PlaneConfig(distance=1.0, folder=str(tmp_path / "s2n"), collection="MRVM Sem2NeRF")
    sem = np.full((28, 40, 3), 60, np.uint8)

    def shown(o) -> bool:
        return not o.hide_render and not o.hide_get()

    first = IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(40, 28, 1))], nv)
    (synth,) = first.planes
    res = IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(40, 28, 2), semantic=sem)], s2n)
    (gen,) = res.planes
    assert set(IP.planes_of(cam)) == {synth, gen}, "Sem2NeRF keeps Synthesize's plane"
    assert first.hidden == [] and IP.hidden_note(first) == ""
    assert IP.planes_of(cam, bpy.data.collections["MRVM novel views"]) == [synth]
    assert not shown(synth) and shown(gen) and res.hidden == [("Cam", synth)]
    assert IP.hidden_note(res) == (
        "the plane of 'Cam' in collection 'MRVM novel views' is hidden, not removed (a camera shows one plane at a "
        "time; show it again with the eye and camera icons in the Outliner)")
    img = bpy.data.images[synth["mrvm_image"]]
    img.reload()
    assert _images_equal(img, _test_image(40, 28, 1)) <= 0.51, "its image is untouched"
    # again in Sem2NeRF: its own plane is replaced, nothing more is hidden
    res = IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(40, 28, 3), semantic=sem)], s2n)
    (gen,) = res.planes
    assert set(IP.planes_of(cam)) == {synth, gen} and res.hidden == [] and not shown(synth)
    assert IP.planes_of(cam, bpy.data.collections["MRVM Sem2NeRF"]) == [gen]
    # Synthesize again: its own (hidden) plane is replaced by a shown one, Sem2NeRF's is hidden
    res = IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(40, 28, 4))], nv)
    (synth,) = res.planes
    assert set(IP.planes_of(cam)) == {synth, gen} and shown(synth) and not shown(gen)
    assert res.hidden == [("Cam", gen)] and "in collection 'MRVM Sem2NeRF' is hidden" in IP.hidden_note(res)
    # a Sem2NeRF build that fails leaves Synthesize's plane shown
    monkeypatch.setattr(IP, "_material", lambda *a, **k: (_ for _ in ()).throw(RuntimeError("simulated")))
    with pytest.raises(RuntimeError, match="simulated"):
        IP.build_image_planes(scene, [IP.NovelView("Cam", _test_image(40, 28, 5), semantic=sem)], s2n)
    assert set(IP.planes_of(cam)) == {synth, gen} and shown(synth) and not shown(gen)


def test_the_finish_messages_say_which_plane_of_another_feature_was_hidden(empty_scene, tmp_path):
    """Sem2NeRF's views on a camera with a Synthesize plane (and the converse): the success message names the plane
    kept hidden, so nothing of the scene changes silently."""
    import types

    import bpy

    from blender_mrvm.datasets.format import write_png
    from blender_mrvm.datasets.novel_views import Target
    from blender_mrvm.operators import sem2nerf as OS
    from blender_mrvm.operators import synthesize as OY
    from blender_mrvm.scene import camera as scam
    from blender_mrvm.scene import image_planes as IP
    from blender_mrvm.scene.sem2nerf import COLLECTION

    scene = empty_scene
    scene.view_settings.view_transform = "Standard"
    cam = _scene_camera(scene, "CamA", CAMERAS["shifted"])
    intr, c2w = scam.read_camera(cam, scene)
    target = Target("CamA", intr, c2w)

    def run(seed: int, name: str):
        job_dir = tmp_path / name
        write_png(job_dir / "out" / target.rgb_path(0), _test_image(40, 28, seed))
        write_png(job_dir / "out" / target.semantic_path(0), np.full((28, 40, 3), 80, np.uint8))
        return job_dir

    synth = IP.PlaneConfig(distance=1.0, folder=str(tmp_path / "nv"))
    s2n = IP.PlaneConfig(distance=1.0, folder=str(tmp_path / "s2n"), collection=COLLECTION)
    msg = OY.import_run(bpy.context, OY.SynthesisRun(types.SimpleNamespace(targets=(target,), planes=synth, depth=False),
                                                     run(1, "j1"), 1.0))
    assert "hidden" not in msg, msg
    msg = OS.import_run(bpy.context, OS.Sem2NeRFRun(types.SimpleNamespace(targets=(target,), planes=s2n,
                                                                          mask_name="mask m.png"), run(2, "j2"), 1.0))
    assert msg.startswith("1 Sem2NeRF view of mask m.png in collection 'MRVM Sem2NeRF'"), msg
    assert msg.endswith(". Note: the plane of 'CamA' in collection 'MRVM novel views' is hidden, not removed (a camera "
                        "shows one plane at a time; show it again with the eye and camera icons in the Outliner)"), msg
    assert len(IP.planes_of(cam)) == 2
    msg = OY.import_run(bpy.context, OY.SynthesisRun(types.SimpleNamespace(targets=(target,), planes=synth, depth=False),
                                                     run(3, "j3"), 1.0))
    assert "Note: the plane of 'CamA' in collection 'MRVM Sem2NeRF' is hidden, not removed" in msg, msg
    assert len(IP.planes_of(cam)) == 2 and not (tmp_path / "j3").exists()
