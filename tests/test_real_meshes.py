"""Real meshes as users bring them (shared/DESIGN.md's offline ones, from pybullet_data): an OBJ whose colour is an
image texture named by its MTL, an OBJ with several materials, a bare STL. The procedural library and the synthetic
test meshes never exercise the importers' material paths; these renders do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from blender_mrvm.progress import run_to_end

pytestmark = pytest.mark.slow
pybullet_data = pytest.importorskip("pybullet_data", reason="pybullet (a test dependency) ships the real meshes")
DATA = Path(pybullet_data.getDataPath())


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    import bpy

    from blender_mrvm.scene.render import RenderConfig, render_dataset

    bpy.ops.wm.read_homefile(use_empty=True)
    out = tmp_path_factory.mktemp("real") / "d"
    sources = tuple(str(DATA / m) for m in ("duck.obj", "soccerball.obj", "husky/meshes/base_link.stl"))
    summary = run_to_end(render_dataset(RenderConfig(out=out, sources=sources, views=4, rig="turntable",
                                                     resolution=(48, 48), samples=4, seed=0)))
    bpy.ops.wm.read_homefile(use_empty=True)
    return out, summary


def _foreground(root: Path, obj: str) -> np.ndarray:
    ov = F.read_object(root / "custom" / obj)
    rgb = np.stack([ov.rgb(i) for i in range(len(ov.indices))])[..., :3].astype(np.float32) / 255.0
    mask = np.stack([ov.mask(i) > 0 for i in range(len(ov.indices))])
    assert mask.mean() > 0.05, f"{obj}: the object covers {mask.mean():.3f} of the pixels"
    return rgb[mask]


def test_every_real_mesh_renders_normalized(real):
    root, summary = real
    assert sorted(summary.objects) == ["custom/base_link", "custom/duck", "custom/soccerball"]
    for obj in ("duck", "soccerball", "base_link"):
        meta = json.loads((root / "custom" / obj / "meta.json").read_text())
        lo, hi = np.array(meta["bbox"])
        assert np.allclose((lo + hi) / 2, 0, atol=1e-5) and np.isclose(np.linalg.norm(hi - lo), 1.0, atol=1e-5)


def test_obj_texture_from_its_mtl_reaches_the_images(real):
    """duck.mtl maps duckCM.png (a yellow duck, orange beak) as the diffuse colour; without it the importer's
    fallback would render the MTL's grey Kd 0.64."""
    fg = _foreground(real[0], "duck")
    r, g, b = np.median(fg, axis=0)
    assert r > 0.6 and g > 0.45 and b < 0.3, (r, g, b)


def test_obj_with_several_materials_keeps_them(real):
    """soccerball.obj: black and white patches from two MTL materials, not one."""
    lum = _foreground(real[0], "soccerball").mean(axis=1)
    assert (lum < 0.25).mean() > 0.05 and (lum > 0.6).mean() > 0.3, ((lum < 0.25).mean(), (lum > 0.6).mean())


def test_missing_texture_renders_the_material_colour_and_says_so(tmp_path, bpy_empty, capfd):
    """The duck without duckCM.png: Blender would render the surface magenta (its missing-image colour) into the
    dataset; the render takes the MTL's own grey instead, records the file in meta.json and warns."""
    import shutil

    from blender_mrvm.scene.render import RenderConfig, render_dataset

    for f in ("duck.obj", "duck.mtl"):
        shutil.copy(DATA / f, tmp_path / f)
    out = tmp_path / "d"
    summary = run_to_end(render_dataset(RenderConfig(out=out, sources=(str(tmp_path / "duck.obj"),), views=2,
                                                     rig="turntable", resolution=(32, 32), samples=2)))
    assert len(summary.warnings) == 1 and "duckCM.png" in summary.warnings[0], summary.warnings
    assert json.loads((out / "custom" / "duck" / "meta.json").read_text())["missing_textures"] == ["duckCM.png"]
    r, g, b = np.median(_foreground(out, "duck"), axis=0)
    assert abs(r - g) < 0.05 and abs(r - b) < 0.05 and g > 0.4, (r, g, b)  # grey, not magenta (g 0)
    assert "Failed to open dir" not in capfd.readouterr().err  # Blender's importer's own noise, said better above


def test_linked_files_of_an_obj_and_a_gltf(tmp_path):
    """The files a mesh names beside its own bytes: an MTL's textures after their options (names with spaces, a
    Windows path found by its base name), a glTF's external buffers and images (URL-encoded), data URIs skipped;
    a named file that is absent is listed as missing."""
    from blender_mrvm.scene.objects import linked_files

    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\n")
    (tmp_path / "m.mtl").write_text("newmtl a\nKd 1 1 1\nmap_Kd -s 1 1 1 -o 0.5 -bm 0.2 my wood.png\n"
                                    "bump -bm 1.5 C:\\textures\\n.png\nmap_d alpha.png\n")
    (tmp_path / "my wood.png").write_bytes(b"x")
    (tmp_path / "n.png").write_bytes(b"y")
    got = linked_files(tmp_path / "m.obj")
    assert got == [("my wood.png", tmp_path / "my wood.png"), ("C:/textures/n.png", tmp_path / "n.png"),
                   ("alpha.png", None)]
    (tmp_path / "s.gltf").write_text(json.dumps({
        "buffers": [{"uri": "s%20data.bin"}, {"uri": "data:application/octet-stream;base64,AAAA"}],
        "images": [{"uri": "tex.png"}, {"bufferView": 0}]}))
    (tmp_path / "s data.bin").write_bytes(b"z")
    assert linked_files(tmp_path / "s.gltf") == [("s%20data.bin", tmp_path / "s data.bin"), ("tex.png", None)]
    (tmp_path / "bad.gltf").write_text("{not json")
    assert linked_files(tmp_path / "bad.gltf") == [] and linked_files(tmp_path / "nothing.stl") == []


def test_resume_notices_a_texture_that_changed_or_appeared(tmp_path, bpy_empty):
    """A texture is part of what a view was rendered from: the duck rendered without its PNG, then with it, must
    not resume on the grey views (nor on yellow ones after the PNG changes); --force renders it again."""
    import shutil

    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    for f in ("duck.obj", "duck.mtl"):
        shutil.copy(DATA / f, tmp_path / f)
    out = tmp_path / "d"
    cfg = dict(out=out, sources=(str(tmp_path / "duck.obj"),), views=2, rig="turntable", resolution=(24, 24),
               samples=1)
    run_to_end(render_dataset(RenderConfig(**cfg)))
    meta_path = out / "custom" / "duck" / "meta.json"
    first = json.loads(meta_path.read_text())
    assert first["linked_files_hash"].startswith("sha256:")
    assert run_to_end(render_dataset(RenderConfig(**cfg))).views_skipped == 2, "nothing changed: resumed"
    shutil.copy(DATA / "duckCM.png", tmp_path / "duckCM.png")  # the texture appears
    with pytest.raises(OutputError, match="texture"):
        run_to_end(render_dataset(RenderConfig(**cfg)))
    s = run_to_end(render_dataset(RenderConfig(**cfg, force=True)))
    assert s.views_rendered == 2 and not s.warnings
    second = json.loads(meta_path.read_text())
    assert second["source_hash"] == first["source_hash"] and second["linked_files_hash"] != first["linked_files_hash"]
    assert "missing_textures" not in second
    (tmp_path / "duckCM.png").write_bytes((tmp_path / "duckCM.png").read_bytes()[:-1] + b"\0")  # changed bytes
    with pytest.raises(OutputError, match="changed"):
        run_to_end(render_dataset(RenderConfig(**cfg)))
    # a dataset rendered before the linked files' hash was kept still resumes
    del second["linked_files_hash"]
    meta_path.write_text(json.dumps(second))
    assert run_to_end(render_dataset(RenderConfig(**cfg))).views_skipped == 2


def test_resume_notices_a_texture_of_a_file_read_with_assimp(tmp_path, bpy_empty):
    """The textures of a file read with assimp are part of what its views were rendered from, as an OBJ's are: a
    COLLADA rendered before its texture was there is not resumed once it is (the warning's advice, --force, then
    renders it with the texture); of an X3D texture's list of files to try, the one that is there is named."""
    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.objects import linked_files
    from blender_mrvm.scene.render import RenderConfig, render_dataset
    from tests.helpers import write_collada, write_x3d

    write_collada(tmp_path / "m.dae", "Y_UP", texture="blue.png")
    assert linked_files(tmp_path / "m.dae") == [("blue.png", None)]
    out = tmp_path / "d"
    cfg = dict(out=out, sources=(str(tmp_path / "m.dae"),), views=2, rig="turntable", resolution=(24, 24), samples=1)
    s = run_to_end(render_dataset(RenderConfig(**cfg)))
    assert any("blue.png" in w and "--force" in w for w in s.warnings), s.warnings
    F.write_png(tmp_path / "blue.png", np.full((8, 8, 3), (20, 40, 220), np.uint8))  # the texture appears
    assert linked_files(tmp_path / "m.dae") == [("blue.png", tmp_path / "blue.png")]
    with pytest.raises(OutputError, match="texture"):
        run_to_end(render_dataset(RenderConfig(**cfg)))
    s = run_to_end(render_dataset(RenderConfig(**cfg, force=True)))
    assert s.views_rendered == 2 and not s.warnings
    r, g, b = np.median(_foreground(out, "m"), axis=0)
    assert b - r > 0.3 and b - g > 0.3, (r, g, b)

    write_x3d(tmp_path / "k.x3d", texture_urls='"k.png" "k.gif"')
    (tmp_path / "k.gif").write_bytes(b"GIF89a")
    assert linked_files(tmp_path / "k.x3d") == [("k.gif", tmp_path / "k.gif")]
    (tmp_path / "k.gif").unlink()
    assert linked_files(tmp_path / "k.x3d") == [("k.png", None)]


def test_texture_named_the_windows_way_is_found_beside_the_mesh(tmp_path, bpy_empty):
    """An MTL written on Windows names `textures\\DUCKCM.PNG` where the file sits beside the mesh as duckCM.png:
    the render finds it (backslashes, then the base name in any letter case) instead of dropping the texture."""
    import shutil

    from blender_mrvm.scene.objects import linked_files
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    shutil.copy(DATA / "duck.obj", tmp_path / "duck.obj")
    shutil.copy(DATA / "duckCM.png", tmp_path / "duckCM.png")
    mtl = (DATA / "duck.mtl").read_text()
    assert "duckCM.png" in mtl
    (tmp_path / "duck.mtl").write_text(mtl.replace("duckCM.png", "textures\\DUCKCM.PNG"))
    assert linked_files(tmp_path / "duck.obj")[0] == ("textures/DUCKCM.PNG", tmp_path / "duckCM.png")
    out = tmp_path / "d"
    summary = run_to_end(render_dataset(RenderConfig(out=out, sources=(str(tmp_path / "duck.obj"),), views=2,
                                                     rig="turntable", resolution=(32, 32), samples=2)))
    assert not summary.warnings, summary.warnings
    assert "missing_textures" not in json.loads((out / "custom" / "duck" / "meta.json").read_text())
    r, g, b = np.median(_foreground(out, "duck"), axis=0)
    assert r > 0.6 and g > 0.45 and b < 0.3, (r, g, b)  # the texture's yellow


def test_fbx_with_an_external_texture_renders_it_and_resume_notices_it_change(tmp_path, bpy_empty):
    """The duck exported to FBX with its texture beside it (not embedded): the render is the texture's yellow, the
    texture is one of the file's linked files, and a resume after the texture changed is refused."""
    import addon_utils
    import bpy

    from blender_mrvm.errors import OutputError
    from blender_mrvm.scene.objects import linked_files
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    addon_utils.enable("io_scene_fbx", default_set=False)
    bpy.ops.wm.obj_import(filepath=str(DATA / "duck.obj"), forward_axis="NEGATIVE_Z", up_axis="Y")
    fbx = tmp_path / "duck.fbx"
    bpy.ops.export_scene.fbx(filepath=str(fbx), path_mode="COPY", embed_textures=False)
    bpy.ops.wm.read_homefile(use_empty=True)
    png = tmp_path / "duck.fbm" / "duckCM.png"  # Blender's exporter copies it into the FBX's media folder
    assert [(Path(n).name, f) for n, f in linked_files(fbx)] == [("duckCM.png", png)]
    cfg = dict(out=tmp_path / "d", sources=(str(fbx),), views=2, rig="turntable", resolution=(32, 32), samples=2)
    assert not run_to_end(render_dataset(RenderConfig(**cfg))).warnings
    r, g, b = np.median(_foreground(tmp_path / "d", "duck"), axis=0)
    assert r > 0.6 and g > 0.45 and b < 0.3, (r, g, b)
    png.write_bytes(png.read_bytes()[:-1] + b"\0")
    with pytest.raises(OutputError, match="texture"):
        run_to_end(render_dataset(RenderConfig(**cfg)))
