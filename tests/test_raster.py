"""The rasterized data passes (``scene/raster.py``) are the pixel-centre values Cycles would give.

bpy-free: analytic planes and edges at known pixel centres, near clipping, both faces visible.
With Blender: a 1-sample Cycles render with a near-zero pixel filter (what ``render-dataset`` used
to render for its data passes) and the rasterizer agree pixel for pixel on masks and ids, to float32
rounding on depth, and on normals.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from blender_mrvm.geometry import cameras as C
from blender_mrvm.scene import raster as R


def _tris(verts, normals=None, obj=1, mat=0):
    verts = np.asarray(verts, dtype=np.float64).reshape(-1, 3, 3)
    ng = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    if normals is None:
        normals = np.repeat((ng / np.linalg.norm(ng, axis=1, keepdims=True))[:, None], 3, axis=1)
    n = len(verts)
    return R.Triangles(verts, np.asarray(normals, dtype=np.float64), ng, np.full(n, obj, np.int64),
                       np.full(n, mat, np.int64))


def _quad(x0, x1, y0, y1, z):
    a, b, c, d = (x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z)
    return [a, b, c, a, c, d]


IDENTITY = np.eye(4)  # OpenCV camera at the origin looking down +z


def test_plane_depth_and_pixel_centre_edges():
    intr = C.Intrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    # a plane at z = 2 whose left edge projects to x = 8 + 20 * (-0.1 / 2) * ... = 5.0 + 0.3 px
    z = 2.0
    x_left = (5.3 - intr.cx) / intr.fx * z  # image x 5.3: the centre of column 5 (5.5) is inside, of 4 (4.5) not
    x_right = (11.7 - intr.cx) / intr.fx * z  # image x 11.7: column 11 (11.5) inside, 12 (12.5) not
    y_top, y_bot = (2.2 - intr.cy) / intr.fy * z, (9.8 - intr.cy) / intr.fy * z
    d = R.rasterize(_tris(_quad(x_left, x_right, y_top, y_bot, z)), intr, IDENTITY)
    cols = np.flatnonzero(d.triangle.max(axis=0) >= 0)
    rows = np.flatnonzero(d.triangle.max(axis=1) >= 0)
    assert cols.tolist() == list(range(5, 12)) and rows.tolist() == list(range(2, 10))
    fg = d.triangle >= 0
    assert np.allclose(d.depth[fg], z, rtol=0, atol=1e-12) and (d.depth[~fg] == 0).all()
    # the plane faces -z (towards the camera): its normal is (0, 0, -1) whichever way it is wound
    assert np.allclose(d.normal[fg], [0, 0, -1])
    flipped = _quad(x_left, x_right, y_top, y_bot, z)
    flipped = [flipped[i] for i in (0, 2, 1, 3, 5, 4)]
    d2 = R.rasterize(_tris(flipped), intr, IDENTITY)
    assert np.allclose(d2.normal[fg], [0, 0, -1]) and ((d2.triangle >= 0) == fg).all()


def test_tilted_plane_depth_is_exact_and_nearest_surface_wins():
    intr = C.Intrinsics(fx=30.0, fy=30.0, cx=16.0, cy=16.0, width=32, height=32)
    c2w = C.look_at_opencv((0.3, -3.0, 0.8), target=(0.0, 0.0, 0.0))
    # tilted plane through the origin, normal n; a smaller parallel plane in front of it
    n = np.array([0.2, -1.0, 0.3]) / np.linalg.norm([0.2, -1.0, 0.3])
    u = np.cross(n, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(n, u)
    big = 2.0 * np.array([-u - v, u - v, u + v, -u - v, u + v, -u + v])
    front = 0.3 * big + 0.5 * n
    tris = R.concatenate([_tris(big, obj=1), _tris(front, obj=2)])
    d = R.rasterize(tris, intr, c2w)
    o, dirs = C.rays_opencv(intr, c2w, normalize=False)  # unit camera z: t is the planar depth
    for obj, offset in ((1, 0.0), (2, 0.5)):
        sel = d.object_id == obj
        assert sel.sum() > 20
        t = (offset - o[sel] @ n) / (dirs[sel] @ n)  # ray / plane intersection
        assert np.allclose(d.depth[sel], t, rtol=1e-12)
    assert (d.object_id == 2).sum() < (d.object_id == 1).sum()


def test_geometry_behind_the_camera_and_clip_distances():
    intr = C.Intrinsics(fx=10.0, fy=10.0, cx=8.0, cy=8.0, width=16, height=16)
    # a floor reaching from behind the camera to far in front of it
    floor = [(-5, 1, -5), (5, 1, -5), (5, 1, 20), (-5, 1, -5), (5, 1, 20), (-5, 1, 20)]
    d = R.rasterize(_tris(floor), intr, IDENTITY, clip_start=0.1, clip_end=100.0)
    fg = d.triangle >= 0
    assert fg[:8].sum() == 0 and fg[9:].all(), "below the horizon only"
    rows = np.arange(16)[:, None] + 0.5
    with np.errstate(divide="ignore"):
        expected = np.where(rows > 8, 1.0 / ((rows - 8) / 10.0), 0.0)  # y = 1 plane: z = fy / (v - cy)
    exp = np.broadcast_to(expected, (16, 16))
    inside = fg & (exp <= 20)
    assert np.allclose(d.depth[inside], exp[inside], rtol=1e-12)
    # clip_end along the ray: the far part of the floor disappears
    d2 = R.rasterize(_tris(floor), intr, IDENTITY, clip_start=0.1, clip_end=3.0)
    assert (d2.triangle >= 0).sum() < fg.sum() and d2.depth.max() <= 3.0


def test_pixel_box_bounds_the_projection():
    intr = C.Intrinsics(fx=20.0, fy=20.0, cx=8.0, cy=6.0, width=16, height=12)
    tris = _tris(_quad(-0.2, 0.1, -0.1, 0.15, 2.0))
    box = R.pixel_box(tris, intr, IDENTITY, margin=2)
    d = R.rasterize(tris, intr, IDENTITY)
    ys, xs = np.nonzero(d.triangle >= 0)
    i0, i1, j0, j1 = box
    assert i0 <= xs.min() - 2 and i1 >= xs.max() + 2 and j0 <= ys.min() - 2 and j1 >= ys.max() + 2
    assert (i1 - i0 + 1) * (j1 - j0 + 1) < 16 * 12
    # the convex hull's vertices bound the projection as all vertices do
    rng = np.random.default_rng(0)
    blob = _tris(rng.normal(size=(300, 3)) * 0.3 + [0, 0, 3])
    c2w = C.look_at_opencv((0.5, -0.4, 0.0), target=(0, 0, 3))
    pts = R.outline_points(blob)
    assert len(pts) < 300 and R.pixel_box(pts, intr, c2w, 0) == R.pixel_box(blob, intr, c2w, 0)
    behind = _tris(_quad(-1, 1, -1, 1, -1.0) + _quad(-1, 1, -1, 1, 2.0))
    assert R.pixel_box(behind, intr, IDENTITY, margin=2) is None


# --------------------------------------------------------------------------------------------
# Against Cycles
# --------------------------------------------------------------------------------------------

def _cycles_data_passes(bpy, scene, tmp: Path) -> dict:
    from blender_mrvm.datasets.format import read_exr_parts
    from blender_mrvm.scene import compat

    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device, cy.samples, cy.use_adaptive_sampling, cy.use_denoising = "CPU", 1, False, False
    cy.filter_width = 0.01
    vl = scene.view_layers[0]
    vl.use_pass_z = vl.use_pass_normal = vl.use_pass_object_index = vl.use_pass_material_index = True
    s = scene.render.image_settings
    compat.set_file_format(s, "OPEN_EXR_MULTILAYER")
    s.color_depth = "32"
    scene.render.filepath = str(tmp / "data.exr")
    scene.render.use_file_extension = False
    bpy.ops.render.render(write_still=True, scene=scene.name)
    return compat.exr_passes(read_exr_parts(tmp / "data.exr"))


@pytest.mark.slow
@pytest.mark.parametrize("source", ["mesh", "glb", "procedural:chair:3", "selected"])
def test_matches_a_pixel_centre_cycles_render(tmp_path, bpy_empty, source):
    import bpy

    from blender_mrvm.geometry import rigs
    from blender_mrvm.scene import objects as O
    from blender_mrvm.scene.camera import apply_intrinsics, apply_pose, new_camera, set_clip
    from tests.helpers import write_mesh

    scene = bpy_empty
    coll = bpy.data.collections.new("objs")
    scene.collection.children.link(coll)
    src = str(write_mesh(tmp_path / f"m.{'ply' if source == 'mesh' else source}")) if source in ("mesh", "glb") \
        else source
    if source == "selected":  # a user's object whose render differs from its viewport
        bpy.ops.mesh.primitive_monkey_add()
        monkey = bpy.context.active_object
        sub = monkey.modifiers.new("sub", "SUBSURF")
        sub.levels, sub.render_levels = 0, 2
        monkey.modifiers.new("hidden_in_viewport", "SOLIDIFY").show_viewport = False
    objs = O.load_into(O.resolve_sources((src,))[0], coll)
    if source == "selected":
        scene.collection.objects.unlink(monkey)  # only the private copy is rendered
    vl = scene.view_layers[0]
    O.apply_world_transform(objs, O.normalization_matrix(O.mesh_vertices_world(objs, vl)), vl)
    for o in objs:
        o.pass_index = 1
    tris = O.mesh_triangles(objs, vl)
    cam = new_camera("cam", coll)
    scene.camera = cam
    w, h = 96, 80
    intr = C.intrinsics_from_fov(math.radians(40), w, h)
    apply_intrinsics(cam, scene, intr)
    poses = rigs.rig_poses("sphere", 3, rigs.framing_distance(0.5, intr.fov_x), seed=1)
    near, far = rigs.near_far(poses, 0.5)
    set_clip(cam, near, far)
    for c2w in poses:
        apply_pose(cam, c2w)
        ref = _cycles_data_passes(bpy, scene, tmp_path)
        d = R.rasterize(tris, intr, c2w, cam.data.clip_start, cam.data.clip_end)
        fg_ref = np.rint(ref["Object Index"]["X"]) > 0
        fg = d.triangle >= 0
        assert fg.sum() > 500
        assert (fg == fg_ref).all(), f"{(fg != fg_ref).sum()} pixels differ in coverage"
        assert (np.rint(ref["Material Index"]["X"])[fg] == d.material_id[fg]).all()
        rel = np.abs(ref["Depth"]["Z"][fg] - d.depth[fg]) / d.depth[fg]
        assert rel.max() < 5e-5, f"depth: max relative difference {rel.max():.2e}"  # float32 in the EXR
        n = ref["Normal"]
        n_ref = np.stack([n["X"], n["Y"], n["Z"]], axis=-1)[fg]
        cos = np.einsum("nk,nk->n", n_ref / np.linalg.norm(n_ref, axis=1, keepdims=True), d.normal[fg])
        if source in ("mesh", "selected"):  # flat faces (the subdivided monkey's are not planar): the triangle's normal
            assert cos.min() > 0.9999
        else:
            # smooth shading: the interpolated normal; Cycles' pass averages its BSDF closures'
            # normals, which it bends on a few grazing pixels (measured: 1-2 %, at most 13 degrees)
            assert (cos > 0.9999).mean() > 0.95 and cos.min() > 0.95


@pytest.mark.slow
def test_border_render_is_the_full_render(tmp_path, bpy_empty):
    """Cycles renders only the box the object can reach: the image is the full render, bit for bit;
    a box that cuts the object (its outer ring not empty) falls back to the full render."""
    import bpy

    from blender_mrvm.geometry import rigs
    from blender_mrvm.scene import objects as O
    from blender_mrvm.scene.camera import apply_intrinsics, apply_pose
    from blender_mrvm.scene.render import RenderConfig, RenderSession
    from tests.helpers import write_mesh

    mesh = write_mesh(tmp_path / "m.ply")
    w, h = 64, 48
    cfg = RenderConfig(out=tmp_path, sources=(str(mesh),), resolution=(w, h), samples=4)
    session = RenderSession(cfg, tmp_path)
    try:
        objs = O.load_into(O.resolve_sources(cfg.sources)[0], session.coll)
        vl = session.view_layer
        O.apply_world_transform(objs, O.normalization_matrix(O.mesh_vertices_world(objs, vl)), vl)
        tris = O.mesh_triangles(objs, vl)
        intr = C.intrinsics_from_fov(math.radians(40), w, h)
        apply_intrinsics(session.camera, session.scene, intr)
        margin = int(math.ceil(session.scene.cycles.filter_width / 2)) + 1

        def rgba(passes):
            c = passes["Combined"]
            return np.stack([c["R"], c["G"], c["B"], c["A"]], axis=-1)

        for c2w in rigs.rig_poses("sphere", 3, rigs.framing_distance(0.5, intr.fov_x), seed=2):
            apply_pose(session.camera, c2w)
            full = rgba(session.render_colour(None))
            box = R.pixel_box(R.outline_points(tris), intr, c2w, margin)
            i0, i1, j0, j1 = box
            assert (i1 - i0 + 1) * (j1 - j0 + 1) < 0.9 * w * h, "the box saves work"
            assert (rgba(session.render_colour(box)) == full).all()
            cut = (i0 + 8, i1 - 8, j0 + 8, j1 - 8)  # inside the object: its ring is not empty
            assert (rgba(session.render_colour(cut)) == full).all()
    finally:
        session.close()
