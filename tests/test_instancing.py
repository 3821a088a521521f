"""Geometry nodes, particle and vertex/face instances are rendered as real meshes: colour, masks, depth, part ids and
the normalization all hold them, for .blend sources and selected objects, and nothing is left behind."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from blender_mrvm.datasets import format as F
from blender_mrvm.errors import InputError
from blender_mrvm.progress import run_to_end

pytestmark = pytest.mark.slow

_KINDS = ("objects", "meshes", "materials", "node_groups", "particles", "collections", "scenes")


def _render(**kw):
    from blender_mrvm.scene.render import RenderConfig, render_dataset

    kw.setdefault("resolution", (32, 32))
    kw.setdefault("samples", 1)
    kw.setdefault("views", 3)
    kw.setdefault("rgba", True)
    return run_to_end(render_dataset(RenderConfig(**kw)))


def _counts() -> dict:
    import bpy

    return {k: len(getattr(bpy.data, k)) for k in _KINDS}


def _red(name="red"):
    import bpy

    from blender_mrvm.scene import compat

    mat = bpy.data.materials.new(name)
    bsdf = next(n for n in compat.node_tree(mat).nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.8, 0.02, 0.02, 1.0)
    return mat


def _cube(size, location, hidden=True, name="Piece"):
    """A red cube away from the rest, hidden from renders (it renders only where it is instanced)."""
    import bpy

    bpy.ops.mesh.primitive_cube_add(size=size, location=location)
    cube = bpy.context.active_object
    cube.name = name
    cube.data.materials.append(_red())
    cube.hide_render = hidden
    return cube


def _gn_grid(piece):
    """A 3 x 3 grid (2 units wide, at z = 0) whose geometry nodes turn every point into an instance of ``piece``."""
    import bpy

    bpy.ops.mesh.primitive_grid_add(x_subdivisions=2, y_subdivisions=2, size=2)
    grid = bpy.context.active_object
    grid.name = "Grid"
    ng = bpy.data.node_groups.new("scatter", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    iop, info = ng.nodes.new("GeometryNodeInstanceOnPoints"), ng.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = piece
    ng.links.new(gin.outputs[0], iop.inputs["Points"])
    ng.links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    ng.links.new(iop.outputs["Instances"], gout.inputs[0])
    grid.modifiers.new("scatter", "NODES").node_group = ng
    return grid


def _emitter(piece, count=30, shown=True, display=100):
    """A 4 x 4 plane with hair particles rendered as ``piece``."""
    import bpy

    bpy.ops.mesh.primitive_plane_add(size=4)
    plane = bpy.context.active_object
    plane.name = "Meadow"
    plane.modifiers.new("hair", "PARTICLE_SYSTEM")
    st = plane.particle_systems[0].settings
    st.type, st.count, st.hair_length = "HAIR", count, 1.0
    st.render_type, st.instance_object, st.particle_size = "OBJECT", piece, 1.0
    st.display_percentage = display
    plane.show_instancer_for_render = shown
    return plane


def _verts_parent(piece):
    """A 2 x 2 plane instancing its child ``piece`` at its four vertices: the child one unit above the plane's centre
    is instanced one unit above each corner (it renders only there)."""
    import bpy

    bpy.ops.mesh.primitive_plane_add(size=2)
    plane = bpy.context.active_object
    plane.name = "Stand"
    piece.hide_render = False  # a child of a vertex instancer renders only as its instances
    piece.parent = plane
    piece.location = (0, 0, 1)
    plane.instance_type = "VERTS"
    return plane


def _save(tmp_path, name="scene"):
    import bpy

    path = tmp_path / f"{name}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    return path


def _check_views(obj_dir, min_px=8):
    """The masks and depth cover what the colour draws, in every view."""
    meta = json.loads((obj_dir / "meta.json").read_text())
    assert meta["complete"] and "unmasked" not in meta and "see_through" not in meta, meta
    ov = F.read_object(obj_dir)
    for i in range(len(ov.indices)):
        alpha = ov.rgb(i)[..., 3] > 127
        mask, depth = ov.mask(i) > 0, ov.depth(i) > 0
        assert (mask == (depth > 0)).all() or (mask == depth).all()
        assert mask.sum() >= min_px, "the instances are in the masks"
        both = (alpha & mask).sum() / max((alpha | mask).sum(), 1)
        assert both > 0.8, (i, both, alpha.sum(), mask.sum())
    return meta


def _bbox(meta) -> np.ndarray:
    """The object's bounds in its source's space (meta.json's bbox is normalized)."""
    norm = np.array(meta["normalization"]["matrix"])
    lo, hi = np.array(meta["bbox"])
    s = norm[0, 0]
    return np.stack([(lo - norm[:3, 3]) / s, (hi - norm[:3, 3]) / s])


def test_a_geometry_nodes_scatter_in_a_blend_file_is_rendered(tmp_path, bpy_empty):
    """A grid whose geometry nodes make each of its 9 points an instance of a hidden red cube: its evaluated mesh
    is empty (the file was refused as having no faces); now the 9 cubes are in colour, masks, depth and bounds, one
    part, and nothing of the file is left."""
    _gn_grid(_cube(0.4, (5, 5, 5)))
    path = _save(tmp_path, "scatter")
    before = _counts()
    s = _render(out=tmp_path / "d", sources=(str(path),))
    assert s.objects == ["custom/scatter"] and not s.warnings, s.warnings
    meta = _check_views(tmp_path / "d" / "custom" / "scatter")
    assert sorted(meta["labels"].values()) == ["background", "custom"], meta["labels"]
    assert np.allclose(_bbox(meta), [[-1.2, -1.2, -0.2], [1.2, 1.2, 0.2]], atol=1e-4), _bbox(meta)
    ov = F.read_object(tmp_path / "d" / "custom" / "scatter")
    px = np.concatenate([ov.rgb(i)[..., :3][ov.mask(i) > 0].astype(float) for i in range(3)])
    assert np.median(px[:, 0]) > np.median(px[:, 1]) + 60, "the instances' material is rendered"
    assert _counts() == before, "nothing of the .blend is left in the open file"


def test_particles_and_vertex_instances_in_a_blend_file_are_rendered(tmp_path, bpy_empty):
    """Hair particles rendered as a hidden cube (the viewport shows a tenth of them; a render, and the data passes,
    all 40), and a plane 3 units up instancing its child at its vertices (the child renders only as the instances,
    a unit above each corner, not above the plane's centre where it is): colour, masks and bounds hold every
    instance, the emitter and the stand once each, the child nowhere else; nothing of the file is left."""
    import bpy

    _emitter(_cube(0.3, (30, 0, 0)), count=40, display=10)
    stand = _verts_parent(_cube(0.5, (0, 0, 0), name="Leg"))
    stand.location = (0, 0, 3)
    path = _save(tmp_path, "garden")
    before = _counts()
    s = _render(out=tmp_path / "d", sources=(str(path),))
    assert s.objects == ["custom/garden"] and not s.warnings, s.warnings
    meta = _check_views(tmp_path / "d" / "custom" / "garden")
    assert sorted(meta["labels"].values()) == ["Meadow", "Meadow_instances", "Stand", "Stand_instances",
                                               "background"], meta["labels"]
    lo, hi = _bbox(meta)
    assert np.isclose(hi[2], 4.25, atol=1e-4) and lo[2] < -0.05, (lo, hi)  # the legs; cubes sunk into the meadow
    assert np.allclose(hi[:2], 2, atol=0.3) and np.allclose(lo[:2], -2, atol=0.3), (lo, hi)
    assert _counts() == before, "nothing of the .blend is left in the open file"
    assert not bpy.data.particles


def test_loading_realizes_every_instance_once(tmp_path, bpy_empty):
    """What loading makes of instancers: no instance is left for Cycles to render beside the meshes made of them
    (nothing rendered twice), each particle and vertex instance is there once, all particles though the viewport
    shows few, an emitter not shown in renders is hidden, and the user's particle settings are as they were."""
    import bpy

    from blender_mrvm.scene import objects as O

    scene = bpy_empty
    _gn_grid(_cube(0.4, (5, 5, 5)))
    meadow = _emitter(_cube(0.3, (30, 0, 0), name="Stone"), count=25, shown=False, display=20)
    _verts_parent(_cube(0.5, (0, 0, 0), name="Leg"))
    for o in bpy.data.objects:
        o.select_set(o.name in ("Grid", "Meadow", "Stand"))
    specs = O.resolve_sources(("selected",))
    assert [s.object_id for s in specs] == ["Grid", "Meadow", "Stand"]
    render = bpy.data.scenes.new("R")
    coll = bpy.data.collections.new("C")
    render.collection.children.link(coll)
    loaded = {s.object_id: O.load_into(s, coll) for s in specs}
    with bpy.context.temp_override(scene=render, view_layer=render.view_layers[0]):
        dg = bpy.context.evaluated_depsgraph_get()
    assert not [i for i in dg.object_instances if i.is_instance], "no instance is rendered beside its mesh"
    faces = {k: sum(len(o.evaluated_get(dg).to_mesh().polygons) for o in objs if O.renders(o))
             for k, objs in loaded.items()}
    assert faces == {"Grid": 9 * 6, "Meadow": 25 * 6, "Stand": 1 + 4 * 6}, faces
    for objs in loaded.values():
        for o in objs:
            o.evaluated_get(dg).to_mesh_clear()
    assert [o.name for o in loaded["Meadow"] if O.renders(o)] == ["Meadow_instances"]
    assert meadow.particle_systems[0].settings.display_percentage == 20 and meadow.modifiers[0].show_render
    assert bpy.data.objects["Stand"].instance_type == "VERTS" and not bpy.data.objects["Leg"].hide_render
    assert len(scene.objects) == 6


def test_selected_instancers_are_rendered(tmp_path, bpy_empty):
    """``selected``: a geometry nodes scatter, a particle emitter and a vertex instancer, each its own object with
    all its instances in colour, masks and bounds; the user's objects and data are as they were."""
    import bpy

    _gn_grid(_cube(0.4, (5, 5, 5)))
    meadow = _emitter(_cube(0.3, (30, 0, 0), name="Stone"), count=25, display=20)
    _verts_parent(_cube(0.5, (0, 0, 0), name="Leg"))
    for o in bpy.data.objects:
        o.select_set(o.name in ("Grid", "Meadow", "Stand"))
    before = _counts()
    s = _render(out=tmp_path / "d", sources=("selected",))
    assert s.objects == ["custom/Grid", "custom/Meadow", "custom/Stand"] and not s.warnings, s.warnings
    metas = {k: _check_views(tmp_path / "d" / "custom" / k) for k in ("Grid", "Meadow", "Stand")}
    assert np.allclose(_bbox(metas["Grid"]), [[-1.2, -1.2, -0.2], [1.2, 1.2, 0.2]], atol=1e-4)
    lo, hi = _bbox(metas["Stand"])
    assert np.allclose([lo, hi], [[-1.25, -1.25, 0], [1.25, 1.25, 1.25]], atol=1e-4), (lo, hi)
    assert _bbox(metas["Meadow"])[1][2] > 0.05  # the cubes stand above the plane
    assert _counts() == before
    assert meadow.particle_systems[0].settings.display_percentage == 20
    assert bpy.data.objects["Stand"].instance_type == "VERTS" and bpy.data.objects["Grid"].modifiers[-1].name == \
        "scatter"


def test_too_many_instances_are_refused_by_name(tmp_path, bpy_empty, monkeypatch):
    """An instancer with more instances than are made meshes is refused with its name and count."""
    from blender_mrvm.scene import objects as O

    _gn_grid(_cube(0.4, (5, 5, 5)))
    path = _save(tmp_path, "dense")
    monkeypatch.setattr(O, "MAX_INSTANCES", 5)
    with pytest.raises(InputError, match=r"'Grid' has 9 instances"):
        _render(out=tmp_path / "d", sources=(str(path),))
    monkeypatch.setattr(O, "MAX_INSTANCES", 100)
    monkeypatch.setattr(O, "MAX_INSTANCED_FACES", 50)
    with pytest.raises(InputError, match=r"'Grid' has 9 instances of 54 faces"):
        _render(out=tmp_path / "e", sources=(str(path),))


def test_a_curve_scattering_instances_in_a_blend_file_is_rendered(tmp_path, bpy_empty):
    """A Bézier curve whose geometry nodes put a cube at each of its points (a scatter along a path): the curve made
    a mesh holds the cubes (it held nothing: the file was refused as having no faces)."""
    import bpy

    piece = _cube(0.4, (5, 5, 5))
    bpy.ops.curve.primitive_bezier_curve_add()
    path_ob = bpy.context.active_object
    ng = bpy.data.node_groups.new("along", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    points, iop = ng.nodes.new("GeometryNodeCurveToPoints"), ng.nodes.new("GeometryNodeInstanceOnPoints")
    info = ng.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = piece
    ng.links.new(gin.outputs[0], points.inputs[0])
    ng.links.new(points.outputs["Points"], iop.inputs["Points"])
    ng.links.new(info.outputs["Geometry"], iop.inputs["Instance"])
    ng.links.new(iop.outputs[0], gout.inputs[0])
    path_ob.modifiers.new("along", "NODES").node_group = ng
    path = _save(tmp_path, "path")
    before = _counts()
    s = _render(out=tmp_path / "d", sources=(str(path),))
    assert s.objects == ["custom/path"] and not s.warnings, s.warnings
    meta = _check_views(tmp_path / "d" / "custom" / "path")
    lo, hi = _bbox(meta)
    assert np.isclose(hi[0] - lo[0], 2.4, atol=1e-3), (lo, hi)  # the curve's ends at x = -1 and 1, cubes 0.4 wide
    assert _counts() == before
