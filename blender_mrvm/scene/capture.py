"""Captures in Blender: import a recovered capture as cameras + points, and render synthetic truth.

- :func:`import_capture` reads a capture folder written by ``capture.export`` (our dataset format:
  ``transforms.json`` + ``points.ply``) and creates, in one collection, a camera per registered
  photo (intrinsics through :func:`scene.camera.apply_intrinsics`, pose through
  :func:`scene.camera.apply_pose`), the photo as the camera's background image (its path stored relative to
  the .blend when the .blend is saved: :func:`load_image_relative`), and the sparse points as a mesh with a
  ``Col`` vertex-colour attribute.
- :func:`render_textured_ring` renders a procedurally textured scene from a ring of known cameras
  (Cycles, emission shading, so a few samples are noise-free): ground truth for tests and the
  capture benchmark. Procedural noise / Voronoi textures, not checkerboards, which break SfM.

Image sizes: a Blender scene has one render resolution. A capture is rejected upstream when its
photos differ in size, so the scene resolution is set once to the capture's (undistorted) size and
each camera carries its own lens, sensor and shift. Per-image intrinsics (the capture default for
one-focal models) therefore import exactly as long as they share the pixel aspect fx/fy: always for
SIMPLE_* / RADIAL models (fx = fy) and for PINHOLE / OPENCV, which pose recovery always runs with one
shared camera; a folder that breaks this raises :class:`CameraConventionError`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy
import numpy as np

from ..errors import CameraConventionError, InputError
from ..geometry import cameras as C
from . import camera as scam
from . import compat

# ---------------------------------------------------------------------------------------------
# Import
# ---------------------------------------------------------------------------------------------


def read_ply_points(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Points (N, 3) float64 and colours (N, 3) uint8 of a PLY written by ``capture.export``."""
    from ..capture.export import read_points_ply

    return read_points_ply(path)


def _pixel_aspect(intr: C.Intrinsics) -> float:
    return intr.fx / intr.fy


def load_image_relative(path: Path) -> bpy.types.Image:
    """``bpy.data.images.load`` of ``path`` (an image already loaded from it is reused), its path stored as the
    image planes store theirs (``scene.image_planes.blend_relative``): relative to the .blend when the .blend is
    saved, so a copied or moved project folder finds its own photos; absolute when the .blend is unsaved or the
    file lies on another drive."""
    from .image_planes import blend_relative

    img = bpy.data.images.load(str(path), check_existing=True)
    if img.library is None and img.packed_file is None:
        img.filepath_raw = blend_relative(Path(path))
    return img


def import_capture(capture_dir: Path, scene: bpy.types.Scene, collection_name: str = "MRVM Capture",
                   background_alpha: float = 0.5, point_size: float = 0.0) -> dict:
    """Create cameras, background photos and the point cloud of a capture folder in ``scene``.

    Returns ``{"collection": Collection, "cameras": [Object], "points": Object | None}``.
    """
    from ..datasets.format import read_transforms

    capture_dir = Path(capture_dir)
    tpath = capture_dir / "transforms.json"
    if not tpath.is_file():
        raise InputError(f"{capture_dir} is not a recovered capture (no transforms.json)")
    frames = read_transforms(tpath)
    if not frames:
        raise InputError(f"{tpath} lists no frames")
    sizes = {(f.intrinsics.width, f.intrinsics.height) for f in frames}
    if len(sizes) > 1:
        raise InputError(f"{tpath}: frames differ in size {sorted(sizes)}; a Blender scene has one resolution")
    aspects = [_pixel_aspect(f.intrinsics) for f in frames]
    if max(aspects) - min(aspects) > 1e-6 * max(aspects):
        raise CameraConventionError(f"{tpath}: frames differ in pixel aspect fx/fy ({min(aspects):.6g}..{max(aspects):.6g}); "
                                    "a Blender scene has one pixel aspect (use a SIMPLE_* camera model)")

    coll = bpy.data.collections.new(collection_name)
    scene.collection.children.link(coll)
    cams = []
    for f in frames:
        name = Path(f.extra.get("original_name") or f.file_path).stem
        obj = scam.new_camera(name, coll)
        scam.apply_intrinsics(obj, scene, f.intrinsics)
        scam.apply_pose(obj, f.c2w_opencv)
        obj["mrvm_original_name"] = str(f.extra.get("original_name", ""))
        obj["mrvm_file_path"] = f.file_path
        img_path = capture_dir / f.file_path
        if img_path.is_file():
            img = load_image_relative(img_path)
            cam = obj.data
            cam.show_background_images = True
            bg = cam.background_images.new()
            bg.image = img
            bg.alpha = background_alpha
            bg.frame_method = "STRETCH"  # the photo is exactly the camera frame
        cams.append(obj)
    # Scene clip range from the points (or camera spread): set on every camera.
    pts_obj = None
    ply = capture_dir / "points.ply"
    if ply.is_file():
        xyz, rgb = read_ply_points(ply)
        pts_obj = points_object("points", xyz, rgb, coll)
    centres = np.array([f.c2w_opencv[:3, 3] for f in frames])
    extent = float(np.max(np.linalg.norm(centres - centres.mean(0), axis=1))) if len(centres) > 1 else 1.0
    for obj in cams:
        scam.set_clip(obj, 0.01 * max(extent, 1e-3), 10.0 * max(extent, 1.0))
    scene.camera = cams[0]
    return {"collection": coll, "cameras": cams, "points": pts_obj}


def points_object(name: str, xyz: np.ndarray, rgb: np.ndarray | None, collection: bpy.types.Collection) -> bpy.types.Object:
    """A vertex-only mesh of ``xyz`` with a byte-colour point attribute ``Col`` (sRGB)."""
    mesh = bpy.data.meshes.new(name)
    xyz = np.asarray(xyz, dtype=np.float32).reshape(-1, 3)
    mesh.vertices.add(len(xyz))
    mesh.vertices.foreach_set("co", xyz.ravel())
    if rgb is not None and len(xyz):
        attr = mesh.color_attributes.new(name="Col", type="BYTE_COLOR", domain="POINT")
        rgba = np.ones((len(xyz), 4), dtype=np.float32)
        rgba[:, :3] = np.asarray(rgb, dtype=np.float32).reshape(-1, 3) / 255.0
        # BYTE_COLOR stores sRGB bytes; color_srgb takes sRGB floats (what the PLY holds).
        attr.data.foreach_set("color_srgb", rgba.ravel())
        mesh.color_attributes.active_color = attr
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    return obj


# ---------------------------------------------------------------------------------------------
# Synthetic truth
# ---------------------------------------------------------------------------------------------


def _emission_material(name: str, seed: int, density: float = 1.0) -> bpy.types.Material:
    """A procedural noise x Voronoi texture, emitted (shading-independent colours)."""
    rng = np.random.default_rng(seed)
    mat = bpy.data.materials.new(name)
    nt = compat.node_tree(mat)
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    emit = nt.nodes.new("ShaderNodeEmission")
    coord = nt.nodes.new("ShaderNodeTexCoord")
    noise = nt.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = density * float(rng.uniform(3, 6))
    noise.inputs["Detail"].default_value = 6.0
    vor = nt.nodes.new("ShaderNodeTexVoronoi")
    vor.inputs["Scale"].default_value = density * float(rng.uniform(6, 10))
    mix = nt.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    mix.blend_type = "MULTIPLY"
    mix.inputs["Factor"].default_value = 0.7
    nt.links.new(coord.outputs["Object"], noise.inputs["Vector"])
    nt.links.new(coord.outputs["Object"], vor.inputs["Vector"])
    nt.links.new(noise.outputs["Color"], mix.inputs["A"])
    nt.links.new(vor.outputs["Color"], mix.inputs["B"])
    nt.links.new(mix.outputs["Result"], emit.inputs["Color"])
    nt.links.new(emit.outputs["Emission"], out.inputs["Surface"])
    return mat


def ring_poses(n_views: int, radius: float, height: float, target=(0.0, 0.0, 0.3)) -> list[np.ndarray]:
    """OpenCV camera-to-world poses on a ring around ``target`` (height wobbles, not planar)."""
    poses = []
    for i in range(n_views):
        a = 2.0 * math.pi * i / n_views
        eye = (radius * math.cos(a), radius * math.sin(a), height + 0.05 * radius * math.sin(3 * a))
        poses.append(C.look_at_opencv(eye, target))
    return poses


def render_textured_ring(out_dir: Path, n_views: int = 24, width: int = 320, height: int = 240,
                         radius: float = 4.0, cam_height: float = 1.6, fov_x_deg: float = 60.0,
                         samples: int = 4, seed: int = 0, threads: int = 0) -> list[dict]:
    """Render the synthetic capture scene into ``out_dir/images/000.png ...`` and ``out_dir/truth.json``.

    Returns the truth: one dict per view with ``name``, ``c2w_opencv`` (4x4 list) and ``K``. Builds
    and renders in a scene of its own and removes it afterwards (the user's scenes are untouched).
    """
    out_dir = Path(out_dir)
    img_dir = out_dir / "images"
    img_dir.mkdir(parents=True, exist_ok=True)
    scene = bpy.data.scenes.new("mrvm_capture_truth")
    created = {"objects": [], "meshes": [], "materials": [], "cameras": []}
    try:
        rng = np.random.default_rng(seed)
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = False
        scene.cycles.max_bounces = 0
        if threads:
            scene.render.threads_mode = "FIXED"
            scene.render.threads = threads
        scene.view_settings.view_transform = "Standard"
        compat.set_file_format(scene.render.image_settings, "PNG")
        scene.render.image_settings.color_mode = "RGB"
        scene.render.film_transparent = False
        world = bpy.data.worlds.new("mrvm_capture_world")
        world.color = (0.05, 0.05, 0.05)
        scene.world = world

        def add(mesh: bpy.types.Mesh, loc, rot=(0, 0, 0), scale=(1, 1, 1), density=1.0):
            import bmesh  # noqa: F401  (bpy module always has it)
            obj = bpy.data.objects.new(mesh.name, mesh)
            obj.location, obj.rotation_euler, obj.scale = loc, rot, scale
            mat = _emission_material(mesh.name, int(rng.integers(1 << 30)), density)
            mesh.materials.append(mat)
            scene.collection.objects.link(obj)
            created["objects"].append(obj)
            created["meshes"].append(mesh)
            created["materials"].append(mat)
            return obj

        import bmesh

        def prim(name: str, build) -> bpy.types.Mesh:
            bm = bmesh.new()
            build(bm)
            me = bpy.data.meshes.new(name)
            bm.to_mesh(me)
            bm.free()
            return me

        add(prim("ground", lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=2.0 * radius)),
            (0, 0, 0), density=0.4)
        add(prim("box", lambda bm: bmesh.ops.create_cube(bm, size=1.0)), (0.3, -0.2, 0.5), (0, 0, 0.4))
        add(prim("ball", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=48, v_segments=24, radius=0.45)),
            (-0.7, 0.5, 0.45))
        add(prim("column", lambda bm: bmesh.ops.create_cone(bm, cap_ends=True, segments=32, radius1=0.3,
                                                           radius2=0.3, depth=1.4)), (0.6, 0.9, 0.7))
        # Back walls on two sides give texture beyond the objects at every azimuth.
        w = 2.0 * radius
        for k, (loc, rot) in enumerate([((0, w, 1.5), (math.pi / 2, 0, 0)), ((0, -w, 1.5), (math.pi / 2, 0, 0)),
                                        ((w, 0, 1.5), (math.pi / 2, 0, math.pi / 2)),
                                        ((-w, 0, 1.5), (math.pi / 2, 0, math.pi / 2))]):
            add(prim(f"wall{k}", lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=w)),
                loc, rot, (1.0, 0.25, 1.0), density=0.3)

        intr = C.intrinsics_from_fov(math.radians(fov_x_deg), width, height)
        cam_data = bpy.data.cameras.new("mrvm_truth_cam")
        cam = bpy.data.objects.new("mrvm_truth_cam", cam_data)
        scene.collection.objects.link(cam)
        created["objects"].append(cam)
        created["cameras"].append(cam_data)
        scene.camera = cam
        scam.apply_intrinsics(cam, scene, intr)
        truth = []
        for i, c2w in enumerate(ring_poses(n_views, radius, cam_height)):
            scam.apply_pose(cam, c2w)
            name = f"{i:03d}.png"
            scene.render.filepath = str(img_dir / name)
            bpy.ops.render.render(write_still=True, scene=scene.name)
            k_intr, c2w_read = scam.read_camera(cam, scene)
            truth.append({"name": name, "c2w_opencv": c2w_read.tolist(), "K": k_intr.K.tolist(),
                          "width": width, "height": height})
        (out_dir / "truth.json").write_text(json.dumps({"radius": radius, "views": truth}, indent=1))
        return truth
    finally:
        for obj in created["objects"]:
            bpy.data.objects.remove(obj)
        for me in created["meshes"]:
            bpy.data.meshes.remove(me)
        for m in created["materials"]:
            bpy.data.materials.remove(m)
        for c in created["cameras"]:
            bpy.data.cameras.remove(c)
        w = scene.world
        bpy.data.scenes.remove(scene)
        if w is not None:
            bpy.data.worlds.remove(w)
