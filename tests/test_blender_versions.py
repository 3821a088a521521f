"""What differs between the Blender versions the extension supports (4.2 LTS to 5.0): ``scene/compat.py``.

These run under whichever ``bpy`` the venv has; ``make test-blender BPY=4.2.23`` runs them, with every other test
that uses Blender, under another one (docs/blender_versions.md).
"""

from __future__ import annotations

import numpy as np
import pytest

from blender_mrvm.scene import compat


def _planes(h=2, w=3):
    rng = np.random.default_rng(0)
    return {k: rng.random((h, w)).astype(np.float32) for k in ("R", "G", "B", "A", "Z", "X", "X2", "NX", "NY", "NZ")}


def test_a_multilayer_exr_reads_the_same_passes_in_either_layout():
    """5.0 writes a part a pass, 4.2-4.5 one part of ``layer.pass.channel`` channels with short index names."""
    c = _planes()
    one_part = {"": {"ViewLayer.Combined.R": c["R"], "ViewLayer.Combined.G": c["G"], "ViewLayer.Combined.B": c["B"],
                     "ViewLayer.Combined.A": c["A"], "ViewLayer.Depth.Z": c["Z"], "ViewLayer.IndexOB.X": c["X"],
                     "ViewLayer.IndexMA.X": c["X2"], "ViewLayer.Normal.X": c["NX"], "ViewLayer.Normal.Y": c["NY"],
                     "ViewLayer.Normal.Z": c["NZ"]}}
    bare = {"ViewLayer.Combined": {"R": c["R"], "G": c["G"], "B": c["B"], "A": c["A"]},
            "ViewLayer.Depth": {"Z": c["Z"]}, "ViewLayer.Object Index": {"X": c["X"]},
            "ViewLayer.Material Index": {"X": c["X2"]},
            "ViewLayer.Normal": {"X": c["NX"], "Y": c["NY"], "Z": c["NZ"]}}
    full = {part: {f"{part}.{k}": v for k, v in chans.items()} for part, chans in bare.items()}
    want = {"Combined": {"R": c["R"], "G": c["G"], "B": c["B"], "A": c["A"]}, "Depth": {"Z": c["Z"]},
            "Object Index": {"X": c["X"]}, "Material Index": {"X": c["X2"]},
            "Normal": {"X": c["NX"], "Y": c["NY"], "Z": c["NZ"]}}
    for parts in (one_part, bare, full):
        got = compat.exr_passes(parts)
        assert got.keys() == want.keys()
        for p, chans in want.items():
            assert got[p].keys() == chans.keys()
            for k, v in chans.items():
                assert got[p][k] is v


def test_a_render_reads_back_its_colour_and_depth_passes(tmp_path, bpy_empty):
    """Whatever EXR layout this Blender writes, a multi-layer render reads back as passes: colour where the cube
    is, and its planar depth there."""
    import bpy

    from blender_mrvm.datasets.format import read_exr_parts

    scene = bpy_empty
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    cam.location = (0.0, 0.0, 4.0)  # looking down -Z at the cube's top face, 3.5 away
    scene.camera = cam
    r = scene.render
    compat.set_engine(scene, "CYCLES")
    scene.cycles.samples, scene.cycles.device = 1, "CPU"
    r.resolution_x = r.resolution_y = 16
    r.resolution_percentage = 100
    r.film_transparent = True
    r.use_file_extension = False
    scene.view_layers[0].use_pass_z = True
    compat.set_file_format(r.image_settings, "OPEN_EXR_MULTILAYER")
    assert r.image_settings.file_format == "OPEN_EXR_MULTILAYER"
    r.image_settings.color_depth = "32"
    r.filepath = str(tmp_path / "v.exr")
    bpy.ops.render.render(write_still=True, scene=scene.name)
    passes = compat.exr_passes(read_exr_parts(tmp_path / "v.exr"))
    a, z = passes["Combined"]["A"], passes["Depth"]["Z"]
    assert a.shape == (16, 16) and a[8, 8] > 0.99 and a[0, 0] < 0.01
    assert abs(float(z[8, 8]) - 3.5) < 1e-3


def test_engines_by_the_projects_names(bpy_empty):
    """``BLENDER_EEVEE`` is this Blender's EEVEE (``BLENDER_EEVEE_NEXT`` in 4.2-4.5); an unknown engine is refused."""
    scene = bpy_empty
    for name in ("CYCLES", "BLENDER_WORKBENCH", "BLENDER_EEVEE"):
        compat.set_engine(scene, name)
        assert scene.render.engine in compat._ENGINE_ALIASES.get(name, (name,))
    with pytest.raises(TypeError, match="no render engine NOT_AN_ENGINE"):
        compat.set_engine(scene, "NOT_AN_ENGINE")


def test_new_materials_and_worlds_get_their_node_trees(bpy_empty):
    """Before 5.0 a new material or world has no node tree; ``node_tree`` gives it the default one."""
    import bpy

    mat = bpy.data.materials.new("m")
    assert any(n.type == "BSDF_PRINCIPLED" for n in compat.node_tree(mat).nodes)
    world = bpy.data.worlds.new("w")
    assert any(n.type == "BACKGROUND" for n in compat.node_tree(world).nodes)
    assert compat.node_tree(mat) == mat.node_tree  # a second call keeps the tree


def test_png_file_format(bpy_empty):
    s = bpy_empty.render.image_settings
    compat.set_file_format(s, "OPEN_EXR_MULTILAYER")
    compat.set_file_format(s, "PNG")
    assert s.file_format == "PNG"
    if hasattr(s, "media_type"):
        assert s.media_type == "IMAGE"
