"""Colours of the sources a dataset renders and of the photos a capture keeps (issue: colour review, second part).

Blender 5.0 files may work in another linear space than Rec.709 (ACEScg, Linear Rec.2020): a colour given as
numbers is taken in the file's working space. The procedural library's colours and the colours mesh files hold
(OBJ ``Kd``, glTF ``baseColorFactor``, PLY vertex colours) are linear Rec.709; Blender's importers keep their numbers
as they are, so in an ACEScg file they rendered other colours than in a Rec.709 one. A Workbench dataset draws each
material's Viewport Display colour, which a .blend's materials usually leave grey: said in a warning. Photos with
a non-sRGB ICC profile are converted before COLMAP sees them, and float photos outside [0, 1] refused before it runs.
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from tests.helpers import P3_TO_709, p3_profile

ORANGE = (0.8, 0.2, 0.05)


def _working_spaces(bpy) -> list[str]:
    cs = getattr(bpy.data, "colorspace", None)
    if cs is None or not hasattr(cs, "working_space"):
        pytest.skip("this Blender has one working colour space (< 5.0)")
    return list(cs.bl_rna.properties["working_space"].enum_items.keys())


def _gltf_cube(path: Path, rgb) -> None:
    """A glTF cube (embedded buffer) whose material's baseColorFactor is ``rgb`` (linear Rec.709, glTF's)."""
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    idx = np.array([[q[0], q[1], q[2], q[0], q[2], q[3]] for q in quads], np.uint16).ravel()
    blob = v.tobytes() + idx.tobytes()
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"name": "orange", "pbrMetallicRoughness": {"baseColorFactor": [*rgb, 1.0],
                                                                  "metallicFactor": 0.0}}],
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": v.nbytes},
                        {"buffer": 0, "byteOffset": v.nbytes, "byteLength": idx.nbytes}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3",
                       "min": [-0.5] * 3, "max": [0.5] * 3},
                      {"bufferView": 1, "componentType": 5123, "count": len(idx), "type": "SCALAR"}],
    }
    path.write_text(json.dumps(doc))


def _obj_cube(path: Path, rgb) -> None:
    path.with_suffix(".mtl").write_text(f"newmtl orange\nKd {rgb[0]} {rgb[1]} {rgb[2]}\n")
    v = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    path.write_text(f"mtllib {path.with_suffix('.mtl').name}\n" + "".join(f"v {a} {b} {c}\n" for a, b, c in v)
                    + "usemtl orange\n" + "".join(f"f {' '.join(str(i + 1) for i in q)}\n" for q in quads))


def _ply_cube(path: Path) -> None:
    """A PLY cube whose vertex colours (8-bit sRGB, as scans store them) are all one orange."""
    v = [(x, y, z) for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    path.write_text("ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\nproperty float z\n"
                    "property uchar red\nproperty uchar green\nproperty uchar blue\nelement face 6\n"
                    "property list uchar int vertex_indices\nend_header\n"
                    + "".join(f"{a} {b} {c} 230 120 40\n" for a, b, c in v)
                    + "".join(f"4 {' '.join(map(str, q))}\n" for q in quads))


def _object_images(out: Path) -> dict[str, np.ndarray]:
    return {p.parent.parent.name: F.read_png(p).astype(int) for p in sorted(out.glob("*/*/rgb/000000.png"))}


# --------------------------------------------------------------------------------------------- problem 1

def test_library_and_mesh_file_colours_render_the_same_in_every_working_space(tmp_path, bpy_empty):
    """The procedural chair, an OBJ's Kd and a glTF's baseColorFactor rendered in an ACEScg file came out up to
    ~30/255 off the same sources rendered in a Linear Rec.709 file: their Rec.709 numbers were taken as ACEScg ones.
    Converted into the file's working space when the material is made, they render the same in every working space
    Blender offers: Workbench (the Viewport Display colour; no sampling noise) within 2/255 mean on the object,
    Cycles (the node tree) within 2/255 in the object's mean colour (its noise averages out)."""
    import bpy

    from blender_mrvm.progress import run_to_end
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    spaces = _working_spaces(bpy)
    assert "ACEScg" in spaces
    _obj_cube(tmp_path / "cube.obj", ORANGE)
    _gltf_cube(tmp_path / "box.gltf", ORANGE)
    sources = ("procedural:chair:10", str(tmp_path / "cube.obj"), str(tmp_path / "box.gltf"))
    off = {}
    for engine in ("BLENDER_WORKBENCH", "CYCLES"):
        images = {}
        for ws in spaces:
            bpy.ops.wm.read_homefile(use_empty=True)
            if ws != "Linear Rec.709":
                assert bpy.ops.wm.set_working_color_space(working_space=ws) == {"FINISHED"}
            out = tmp_path / f"{engine}_{ws.replace(' ', '_')}"
            run_to_end(render_dataset(RenderConfig(out=out, sources=sources, views=1, resolution=(24, 24),
                                                   engine=engine, samples=4)))
            images[ws] = _object_images(out)
        ref = images["Linear Rec.709"]
        assert len(ref) == 3
        for name, im in ref.items():
            fg = (im[..., :3] < 250).any(-1)
            assert fg.sum() > 30, name  # the object is there
            assert (im[fg].mean(0)[0] - im[fg].mean(0)[2]) > 25, (engine, name, im[fg].mean(0))  # and coloured
            for ws in spaces:
                d = np.abs(images[ws][name] - im)[fg]
                off[engine, ws, name] = round(float(d.mean() if engine == "BLENDER_WORKBENCH" else
                                                    np.abs(images[ws][name][fg].mean(0) - im[fg].mean(0)).max()), 2)
    assert max(off.values()) <= 2.0, off


def test_vertex_colours_of_a_scan_are_the_same_colours_in_every_working_space(tmp_path, bpy_empty):
    """A PLY scan's vertex colours (8-bit sRGB in the file) are read by Blender's importer as linear Rec.709 float
    colours, whose numbers an ACEScg file took as ACEScg (an orange scan shown red: sRGB (0.98, 0, 0) for
    (0.90, 0.47, 0.16)). Converted on import, they are the same colours (as sRGB) in every working space."""
    import bpy

    from blender_mrvm.scene import objects as O

    spaces = _working_spaces(bpy)
    _ply_cube(tmp_path / "scan.ply")
    spec = O.ObjectSpec("file", "custom", "scan", path=str(tmp_path / "scan.ply"))
    shown = {}
    for ws in spaces:
        bpy.ops.wm.read_homefile(use_empty=True)
        if ws != "Linear Rec.709":
            assert bpy.ops.wm.set_working_color_space(working_space=ws) == {"FINISHED"}
        coll = bpy.data.collections.new("c")
        bpy.context.scene.collection.children.link(coll)
        (ob,) = [o for o in O.load_into(spec, coll) if o.type == "MESH"]
        attrs = ob.data.color_attributes
        assert len(attrs) == 1 and attrs[0].data_type == "FLOAT_COLOR"  # (what the test is about)
        shown[ws] = np.array([d.color_srgb[:3] for d in attrs[0].data])
    assert np.abs(shown["Linear Rec.709"] - np.array([230, 120, 40]) / 255.0).max() < 0.01
    for ws in spaces:
        assert np.abs(shown[ws] - shown["Linear Rec.709"]).max() < 0.005, (ws, shown[ws][0], shown["Linear Rec.709"][0])


def test_colours_in_a_rec709_file_keep_their_numbers(tmp_path, bpy_empty):
    """In a Linear Rec.709 file (every file before Blender 5.0) nothing is converted: the numbers stay exact."""
    import bpy

    from blender_mrvm.scene import objects as O
    from blender_mrvm.scene.procedural._materials import make_material

    assert O.rec709_to_scene_linear() is None
    mat = make_material("m", "paint", np.random.default_rng(0), 1, color=ORANGE)
    want = np.array((*ORANGE, 1.0), dtype=np.float32)  # (as Blender stores them)
    assert np.array_equal(np.array(mat.diffuse_color, dtype=np.float32), want)
    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    assert np.array_equal(np.array(bsdf.inputs["Base Color"].default_value, dtype=np.float32), want)


def test_vector_sockets_are_not_converted(bpy_empty):
    """A normal map's colour socket holds a direction, not a colour: left as it is (as Blender's own change of
    working space leaves it), while every colour socket, ramp and Viewport Display colour is converted."""
    import bpy
    from mathutils import Color

    from blender_mrvm.scene import objects as O
    from blender_mrvm.scene import compat

    if "ACEScg" not in _working_spaces(bpy):
        pytest.skip("no ACEScg working space")
    assert bpy.ops.wm.set_working_color_space(working_space="ACEScg") == {"FINISHED"}
    mat = bpy.data.materials.new("m")
    nt = compat.node_tree(mat)
    nm = nt.nodes.new("ShaderNodeNormalMap")
    nm.inputs["Color"].default_value = (0.5, 0.5, 1.0, 1.0)
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (*ORANGE, 1.0)
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (*ORANGE, 1.0)
    mat.diffuse_color = (*ORANGE, 0.5)
    O.rec709_colours_to_working_space([mat, mat])  # (named twice: converted once)
    want = Color(ORANGE).from_rec709_linear_to_scene_linear()[:]
    assert tuple(nm.inputs["Color"].default_value) == pytest.approx((0.5, 0.5, 1.0, 1.0))
    for got in (bsdf.inputs["Base Color"].default_value, ramp.color_ramp.elements[0].color):
        assert tuple(got) == pytest.approx((*want, 1.0), abs=1e-5)
    assert tuple(mat.diffuse_color) == pytest.approx((*want, 0.5), abs=1e-5)  # (alpha kept)


# --------------------------------------------------------------------------------------------- problem 2

def _material(bpy, name: str, base=None, viewport=None, textured: bool = False):
    from blender_mrvm.scene import compat

    mat = bpy.data.materials.new(name)
    bsdf = next(n for n in compat.node_tree(mat).nodes if n.type == "BSDF_PRINCIPLED")
    if base is not None:
        bsdf.inputs["Base Color"].default_value = (*base, 1.0)
    if textured:
        tex = mat.node_tree.nodes.new("ShaderNodeTexChecker")
        mat.node_tree.links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
    if viewport is not None:
        mat.diffuse_color = (*viewport, 1.0)
    return mat


def test_workbench_grey_viewport_colours_are_named(bpy_empty):
    """Workbench draws a material's Viewport Display colour; a .blend's or selected object's material whose shader
    is coloured while that colour is the default grey rendered grey without a word. Those materials are named (the
    orange shader, the textured one), not the ones Workbench draws right (a Viewport Display colour set, a grey
    shader, a material without nodes' own colour), and nothing of the user's is changed."""
    import bpy

    from blender_mrvm.scene import objects as O

    bpy.ops.mesh.primitive_cube_add()
    a = bpy.context.active_object
    bpy.ops.mesh.primitive_cube_add()
    b = bpy.context.active_object
    for m in (_material(bpy, "Orange", base=ORANGE), _material(bpy, "Set", base=ORANGE, viewport=ORANGE),
              _material(bpy, "Grey")):
        a.data.materials.append(m)
    for m in (_material(bpy, "Checker", textured=True), a.data.materials[0], None):
        b.data.materials.append(m)
    before = [tuple(m.diffuse_color) for m in bpy.data.materials]
    names = O.viewport_grey_materials([a, b])
    assert names == ["Checker", "Orange"]
    assert [tuple(m.diffuse_color) for m in bpy.data.materials] == before
    msg = O.viewport_grey_warning(names)
    assert "\n" not in msg and "Checker" in msg and "Orange" in msg and "Viewport Display" in msg
    assert "Workbench" in msg and "Cycles" in msg
    assert O.viewport_grey_warning([]) is None
    many = O.viewport_grey_warning([f"M{i}" for i in range(5)])
    assert "M2" in many and "M3" not in many and "5 material" in many


# --------------------------------------------------------------------------------------------- problem 3


def test_float_photos_outside_0_1_are_refused_before_colmap(tmp_path):
    """A float TIFF with values beyond [0, 1] (an HDR or a raw sensor dump) was read by pycolmap clipped, mapped,
    and refused only at the export, after the whole run; now check_images refuses it first, naming the photo. A
    32-bit integer image beyond 16 bits too; one in [0, 1] passes."""
    from PIL import Image

    from blender_mrvm.capture.config import CaptureConfig
    from blender_mrvm.capture.sfm import check_images
    from blender_mrvm.errors import InputError

    d = tmp_path / "in"
    d.mkdir()
    ramp = np.linspace(0.0, 1.0, 48, dtype=np.float32).reshape(6, 8)
    for i in range(3):
        Image.fromarray(ramp).save(d / f"{i}.tif")
    assert check_images(d, ["0.tif", "1.tif", "2.tif"], CaptureConfig()) == ((8, 6), [])
    Image.fromarray(ramp * 2.5).save(d / "1.tif")
    with pytest.raises(InputError, match=r"1\.tif is a float image with values outside \[0, 1\]") as e:
        check_images(d, ["0.tif", "1.tif", "2.tif"], CaptureConfig())
    assert "\n" not in str(e.value)
    Image.fromarray((ramp * 70000).astype(np.int32)).save(d / "1.tif")  # mode I
    with pytest.raises(InputError, match=r"1\.tif is a 32-bit integer image with values outside"):
        check_images(d, ["0.tif", "1.tif", "2.tif"], CaptureConfig())


def test_colmap_undistortion_keeps_a_photos_icc_profile(tmp_path):
    """What ``rgb/`` relies on for photos with an ICC profile (Display P3) that COLMAP undistorts: the undistorted
    copy keeps the profile (pycolmap 4.2: read, undistorted and written as COLMAP's undistorter does), so the export
    converts it to sRGB as it converts the photos themselves. A guard: a pycolmap that drops it fails here."""
    from PIL import Image

    icc = p3_profile()
    a = np.zeros((48, 64, 3), np.uint8)
    a[:] = (200, 60, 30)
    for ext, kw in ((".jpg", {"quality": 98}), (".png", {}), (".tif", {})):
        Image.fromarray(a).save(tmp_path / f"p3{ext}", icc_profile=icc, **kw)
    import pycolmap  # (after Pillow wrote: pycolmap's zlib loaded first breaks Pillow's PNG writer)

    cam = pycolmap.Camera(model="SIMPLE_RADIAL", width=64, height=48, params=[60.0, 32.0, 24.0, -0.05])
    for ext in (".jpg", ".png", ".tif"):
        bitmap = pycolmap.Bitmap.read(str(tmp_path / f"p3{ext}"), True)
        undistorted, _ = pycolmap.undistort_image(pycolmap.UndistortCameraOptions(), bitmap, cam)
        undistorted.write(str(tmp_path / f"und{ext}"))
        assert Image.open(tmp_path / f"und{ext}").info.get("icc_profile") == icc, ext


def test_float_and_p3_photos_come_into_rgb_as_srgb_through_undistortion(ring, tmp_path):
    """With a camera model that has distortion, rgb/ holds COLMAP's undistorted copies. Of a float TIFF photo (in
    [0, 1]) COLMAP wrote a 3-channel float TIFF that Pillow cannot open: the export failed (UnidentifiedImageError)
    after the whole run. Such photos now reach pycolmap as 8-bit PNG copies (readable_photos), and rgb/ holds them
    as the loaders read the photo; Display P3 PNGs, whose profile the undistorted copies keep, come out sRGB."""
    from PIL import Image

    from blender_mrvm.capture.config import CaptureConfig
    from blender_mrvm.capture.sfm import recover_poses
    from blender_mrvm.progress import run_to_end

    icc = p3_profile()
    d = tmp_path / "in"
    d.mkdir()
    tint = np.array([1.0, 0.55, 0.25])  # (a colour P3 changes)
    for i in range(5):
        rgb = (np.asarray(Image.open(ring[0] / f"{i:03d}.png").convert("RGB")) * tint).astype(np.uint8)
        if i % 2:
            Image.fromarray(rgb).save(d / f"{i:03d}.png", icc_profile=icc)
        else:
            Image.fromarray(np.asarray(Image.fromarray(rgb).convert("L"), np.float32) / 255.0).save(d / f"{i:03d}.tif")
    res = run_to_end(recover_poses(d, tmp_path / "out", CaptureConfig(num_threads=1, single_camera=True,
                                                                     camera_model="SIMPLE_RADIAL")))
    assert len(res.registered) == 5
    meta = json.loads((tmp_path / "out" / "meta.json").read_text())
    assert meta["undistorted"]
    frames = json.loads((tmp_path / "out" / "transforms.json").read_text())["frames"]
    for fr in frames:
        got = np.asarray(Image.open(tmp_path / "out" / fr["file_path"]))
        assert got.dtype == np.uint8 and got.ndim == 3 and got.shape[2] == 3
        photo = Image.open(d / fr["original_name"])
        if photo.mode == "F":
            want = np.asarray(photo).mean() * 255.0
            assert abs(got.mean() - want) < 3.0, (fr["original_name"], got.mean(), want)
        else:  # the photo's colours in sRGB (undistortion crops a border: means, not pixels)
            lin = F.srgb_to_linear(np.asarray(photo.convert("RGB")).reshape(-1, 3) / 255.0) @ P3_TO_709.T
            want = F.linear_to_srgb(np.clip(lin, 0, 1)).mean(0) * 255.0
            raw = np.asarray(photo.convert("RGB")).reshape(-1, 3).mean(0)
            assert np.abs(got.reshape(-1, 3).mean(0) - want).max() < 3.0, (got.reshape(-1, 3).mean(0), want)
            assert np.abs(raw - want).max() > 8.0  # (the test tells P3 from sRGB)


def test_a_workbench_dataset_of_a_grey_viewport_material_says_so(tmp_path, bpy_empty, capsys):
    """render-dataset --engine BLENDER_WORKBENCH of a .blend whose orange material keeps the default grey Viewport
    Display colour drew a grey cube without a word; it warns once, naming the material (and renders it as before:
    the user's material is not changed). Cycles does not warn."""
    import bpy

    from blender_mrvm.cli import main

    bpy.ops.mesh.primitive_cube_add(size=1.0)
    cube = bpy.context.active_object
    cube.data.materials.append(_material(bpy, "Orange", base=ORANGE))
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "plain.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)  # (rendered as a source, not as the open file)
    for engine, says in (("BLENDER_WORKBENCH", True), ("CYCLES", False)):
        capsys.readouterr()
        assert main(["render-dataset", "--source", str(tmp_path / "plain.blend"), "--engine", engine, "--views", "1",
                     "--resolution", "16", "--samples", "1", "--out", str(tmp_path / engine)]) == 0
        err = [ln for ln in capsys.readouterr().err.splitlines() if "Viewport Display" in ln]
        assert len(err) == int(says), err
        if says:
            assert "Orange" in err[0] and "Workbench" in err[0] and "Cycles" in err[0]
        im = _object_images(tmp_path / engine)["plain"]
        fg = (im[..., :3] < 250).any(-1)
        assert fg.sum() > 10
        spread = im[fg].mean(0)[0] - im[fg].mean(0)[2]
        assert (spread < 5) if says else (spread > 30), (engine, im[fg].mean(0))  # grey in Workbench, as before
