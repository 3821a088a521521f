"""Novel views in Blender: gather references and targets for the synthesis worker, bring results in.

The synthesis itself runs in the worker process (``worker.run_worker``, DESIGN.md "Where torch runs
inside Blender"); this module is its main-thread half:

- references: an object folder (a rendered dataset's object or a recovered capture), checked with
  ``datasets.format.read_object``; or the scene's cameras that carry a background image (the photo),
  exported as a capture folder (``capture.export.write_capture``) so the worker reads one format;
- targets: the selected cameras, or an orbit around a centre (``geometry.rigs.orbit_poses``) whose
  cameras are only created when the results arrive (a cancelled or failed run leaves nothing);
- :func:`import_results`: in one transaction, the generated cameras and one image plane per target
  (``scene.image_planes``) in the collection "MRVM novel views";
- :func:`write_blend`: the same into a new .blend (the ``synthesize --blend`` CLI and ``make demo``),
  with the reference cameras showing their images and the view transform "Standard".
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import shutil
import sys
import tempfile
from pathlib import Path
from typing import Callable

import bpy
import numpy as np
from mathutils import Matrix

from ..datasets.format import replace_file
from ..datasets.novel_views import Target, blend_images_folder
from ..guards import PARTIAL_PREFIX
from ..errors import CameraConventionError, InputError
from ..geometry import cameras as C
from . import camera as scam
from . import image_planes as IP

ORBIT_PREFIX = "MRVM orbit"


# ---------------------------------------------------------------------------------------------
# References
# ---------------------------------------------------------------------------------------------

def check_reference_folder(folder: Path, views: tuple[int, ...]) -> tuple[Path, tuple[int, ...]]:
    """An object folder (render or capture) whose ``views`` all have an image and a pose (the
    synthesis package owns the rule; this reads no image)."""
    from ..synthesis import check_reference_folder as check

    folder = Path(folder)
    check(folder, views)
    return folder, tuple(views)


def reference_cameras(scene: bpy.types.Scene) -> list[bpy.types.Object]:
    """Scene cameras with a background image (outside the novel-views collection), by name."""
    novel = bpy.data.collections.get(IP.COLLECTION)
    out = []
    for obj in scene.objects:
        if obj.type != "CAMERA" or (novel is not None and obj.name in novel.objects):
            continue
        if any(bg.image is not None for bg in obj.data.background_images):
            out.append(obj)
    return sorted(out, key=lambda o: o.name)


def _image_file(img: bpy.types.Image, tmp: Path) -> Path:
    """A readable file of a Blender image: its file, or its packed bytes written to ``tmp``."""
    if img.packed_file is not None:
        p = tmp / f"packed_{len(list(tmp.iterdir()))}{Path(img.filepath).suffix or '.png'}"
        p.write_bytes(img.packed_file.data)
        return p
    p = Path(bpy.path.abspath(img.filepath, library=img.library))
    if not p.is_file():
        raise InputError(f"image {img.name!r} ({img.filepath}) does not exist")
    return p


def export_scene_references(scene: bpy.types.Scene, cams: list[bpy.types.Object], out_dir: Path) -> tuple[Path, tuple[int, ...]]:
    """Write scene cameras and their background photos as a capture folder; return (folder, views).

    Each camera's intrinsics are read at the scene's render settings and scaled to its photo's size
    (the photo must have the frame's aspect ratio).
    """
    if not cams:
        raise InputError("no scene camera has a reference image (give cameras a background image, "
                         "or use a dataset folder or a recovered capture)")
    out_dir = Path(out_dir)
    tmp = Path(tempfile.mkdtemp(prefix="mrvm_refs_"))
    try:
        return _export(scene, cams, out_dir, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _export(scene, cams, out_dir: Path, tmp: Path) -> tuple[Path, tuple[int, ...]]:
    from PIL import Image

    from ..capture.export import CaptureView, write_capture

    views = []
    for cam in cams:
        bg = next(bg for bg in cam.data.background_images if bg.image is not None)
        path = _image_file(bg.image, tmp)
        try:
            with Image.open(path) as im:
                w, h = im.size
        except Exception as e:
            raise InputError(f"camera {cam.name!r}: cannot read its image {path}: {e}") from e
        intr, c2w = scam.read_camera(cam, scene)
        if abs(h - intr.height * w / intr.width) > 1.0:
            raise InputError(f"camera {cam.name!r}: its image is {w}x{h} but the camera frame is "
                             f"{intr.width}x{intr.height} (different aspect ratio)")
        k = intr.resized(w, h)
        views.append(CaptureView(cam.name, path, k, c2w))
    write_capture(out_dir, views, np.zeros((0, 3)), np.zeros((0, 3), np.uint8),
                  {"kind": "scene cameras", "cameras": [c.name for c in cams]})
    return out_dir, tuple(range(len(views)))


# ---------------------------------------------------------------------------------------------
# Targets
# ---------------------------------------------------------------------------------------------

def selected_targets(scene: bpy.types.Scene, objects) -> list[Target]:
    """Targets for the selected camera objects among ``objects``."""
    cams = sorted((o for o in objects if o.type == "CAMERA"), key=lambda o: o.name)
    if not cams:
        raise InputError("no camera selected: select the target cameras (or generate an orbit)")
    out = []
    for cam in cams:
        intr, c2w = scam.read_camera(cam, scene)
        out.append(Target(cam.name, intr, c2w))
    return out


def _orbit_camera_settings(scene: bpy.types.Scene, fov: float) -> C.BlenderCamera:
    """An AUTO-fit 36 mm camera with field of view ``fov`` along the longer side, at the scene's size."""
    if not 0 < fov < math.pi:
        raise InputError(f"field of view must be between 0 and 180 degrees, got {math.degrees(fov):g}")
    w, h = scam.render_size(scene)
    return C.BlenderCamera(lens=18.0 / math.tan(fov / 2.0), sensor_width=36.0, sensor_height=36.0, sensor_fit="AUTO",
                           resolution_x=w, resolution_y=h,
                           pixel_aspect_x=scene.render.pixel_aspect_x, pixel_aspect_y=scene.render.pixel_aspect_y)


def fresh_names(prefix: str, count: int) -> list[str]:
    """``count`` object names "<prefix> 000", ... that no object holds yet (earlier cameras are kept)."""
    taken = {o.name for o in bpy.data.objects}
    names, i = [], 0
    while len(names) < count:
        n = f"{prefix} {i:03d}"
        if n not in taken:
            names.append(n)
        i += 1
    return names


def orbit_targets(scene: bpy.types.Scene, count: int, radius: float, elevation: float, fov: float,
                  center=(0.0, 0.0, 0.0)) -> list[Target]:
    """``count`` generated targets on a circle around ``center`` (angles in radians), looking at it."""
    from ..geometry.rigs import orbit_poses

    intr = C.intrinsics_from_blender(_orbit_camera_settings(scene, fov))
    names = fresh_names(ORBIT_PREFIX, count)
    poses = orbit_poses(count, radius, math.degrees(elevation), center)
    return [Target(n, intr, p, generated=True) for n, p in zip(names, poses)]


def _same_view(intr: C.Intrinsics, k: C.Intrinsics) -> bool:
    """Whether a camera that renders ``intr`` shows the view ``k``: the same field of view, pixel shape and
    principal point, at any scale (the sides within a pixel of ``k``'s aspect ratio)."""
    same = np.allclose([intr.fx / intr.width, intr.fy / intr.fx, intr.cx / intr.width, intr.cy / intr.height],
                       [k.fx / k.width, k.fy / k.fx, k.cx / k.width, k.cy / k.height], rtol=1e-6, atol=1e-9)
    return bool(same) and abs(k.height - intr.height * k.width / intr.width) <= 1.0


def fits_frame(k: C.Intrinsics, frame: C.BlenderCamera) -> bool:
    """Whether a camera made for the view ``k`` (:func:`_create_camera`) shows it in a scene that renders
    ``frame``'s size and pixel aspect (a scene has one frame shape for all its cameras)."""
    try:
        bc = C.blender_from_intrinsics(k)
    except CameraConventionError:
        return False
    return _same_view(C.intrinsics_from_blender(dataclasses.replace(
        bc, resolution_x=frame.resolution_x, resolution_y=frame.resolution_y,
        pixel_aspect_x=frame.pixel_aspect_x, pixel_aspect_y=frame.pixel_aspect_y)), k)


def _shape(k: C.Intrinsics) -> str:
    return f"{k.width}x{k.height}" + ("" if math.isclose(k.fx, k.fy, rel_tol=1e-6) else f", fy/fx {k.fy / k.fx:.4g}")


CLIP_END_PLANES = 20.0
"""A created camera's clip end, in plane distances (at least Blender's default): about 10 times the depth of the
object's centre when the plane sits at half of it (the default), so the object and what is around it are seen."""


def _create_camera(scene: bpy.types.Scene, t: Target, coll: bpy.types.Collection,
                   plane_distance: float | None = None) -> bpy.types.Object:
    """A camera that renders exactly ``t.intrinsics`` (at any scale) from ``t.c2w_opencv``; with a
    ``plane_distance``, its clip range reaches past it (the camera sees its image plane)."""
    cam = scam.new_camera(t.name, coll)
    if cam.name != t.name:
        raise InputError(f"an object named {t.name!r} already exists")
    bc = C.blender_from_intrinsics(t.intrinsics)
    d = cam.data
    d.type, d.lens_unit = "PERSP", "MILLIMETERS"
    d.sensor_fit, d.sensor_width, d.sensor_height = bc.sensor_fit, bc.sensor_width, bc.sensor_height
    d.lens, d.shift_x, d.shift_y = bc.lens, bc.shift_x, bc.shift_y
    if plane_distance is not None:
        d.clip_start = min(d.clip_start, plane_distance / 2.0)
        # far past the object too: planes float at about half its centre's depth, and 2x that clip end cut a scene
        # scaled x1e4 at the object's centre (4-5 of its box's 8 corners beyond it), seen through these cameras
        d.clip_end = max(d.clip_end, plane_distance * CLIP_END_PLANES)
    cam.matrix_world = Matrix(C.blender_from_opencv(t.c2w_opencv).tolist())
    intr, _ = scam.read_camera(cam, scene)
    if not _same_view(intr, t.intrinsics):
        r = scene.render
        raise InputError(f"camera {t.name!r}: its view ({_shape(t.intrinsics)}) does not fit the scene's frame "
                         f"({intr.width}x{intr.height} px, pixel aspect {r.pixel_aspect_x:g}:{r.pixel_aspect_y:g}); "
                         "set the render size and pixel aspect it was synthesized at")
    return cam


# ---------------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------------

def import_results(scene: bpy.types.Scene, targets: list[Target], out_dir: Path, cfg: IP.PlaneConfig,
                   depth: bool = False, semantic: bool = False, txn: IP.Transaction | None = None) -> IP.PlaneResult:
    """Create generated cameras (their clip range reaches past the plane distance) and one image plane per
    target from the worker's ``out_dir`` (with ``semantic``, each plane also carries the target's semantic
    map, ``Target.semantic_path``).

    All or nothing: a missing or unreadable result, or any other error, leaves the scene and the
    output folder as they were (with an outer ``txn``, its owner commits or rolls back).
    """
    out_dir = Path(out_dir)
    for i, t in enumerate(targets):
        if not (out_dir / t.rgb_path(i)).is_file():
            raise InputError(f"the worker wrote no image for {t.name!r} ({out_dir / t.rgb_path(i)})")
        if depth and not (out_dir / t.depth_path(i)).is_file():
            raise InputError(f"the worker wrote no depth map for {t.name!r} ({out_dir / t.depth_path(i)})")
        if semantic and not (out_dir / t.semantic_path(i)).is_file():
            raise InputError(f"the worker wrote no semantic map for {t.name!r} ({out_dir / t.semantic_path(i)})")
    with IP.transaction(txn) as txn:
        coll = IP.ensure_collection(scene, cfg.collection, txn)
        for t in targets:
            if t.generated:
                _create_camera(scene, t, coll, cfg.distance)
            elif bpy.data.objects.get(t.name) is None:
                raise InputError(f"target camera {t.name!r} was removed while synthesizing")
        views = [IP.NovelView(t.name, out_dir / t.rgb_path(i), out_dir / t.depth_path(i) if depth else None,
                              out_dir / t.semantic_path(i) if semantic else None)
                 for i, t in enumerate(targets)]
        return IP.build_image_planes(scene, views, cfg, txn=txn)


# ---------------------------------------------------------------------------------------------
# A .blend of the results (CLI, demo)
# ---------------------------------------------------------------------------------------------

REFERENCE_COLLECTION = "MRVM references"


def default_plane_distance(targets: list[Target], bbox) -> float:
    """Half the planar depth of the object's centre, median over the targets (planes float between
    each camera and the object; the same distance for every plane)."""
    centre = 0.5 * (np.asarray(bbox[0], np.float64) + np.asarray(bbox[1], np.float64))
    z = [float((C.invert_pose(t.c2w_opencv) @ np.append(centre, 1.0))[2]) for t in targets]
    z = [v for v in z if v > 0]
    if not z:
        raise InputError("the object's centre is behind every target camera; give a plane distance")
    return 0.5 * float(np.median(z))


def blend_frame(targets: list[Target]) -> C.BlenderCamera:
    """The render frame of a .blend of ``targets`` (the largest target's size and pixel aspect; its
    ``resolution_*`` and ``pixel_aspect_*`` are what matter); InputError when a target is no Blender camera
    or the targets cannot share one frame. Needs no scene: ``synthesize --blend`` asks before synthesizing."""
    for t in targets:
        try:
            C.blender_from_intrinsics(t.intrinsics)
        except CameraConventionError as e:
            raise InputError(f"target {t.name!r} cannot be a Blender camera: {e}") from None
    big = max(targets, key=lambda t: (t.intrinsics.width, t.intrinsics.height))
    frame = C.blender_from_intrinsics(big.intrinsics)
    for t in targets:
        if not fits_frame(t.intrinsics, frame):
            raise InputError(f"the targets have different frame shapes ({_shape(big.intrinsics)} and "
                             f"{_shape(t.intrinsics)}); a Blender scene has one frame shape (aspect ratio and "
                             "pixel aspect): write them into separate .blend files")
    return frame


def reference_views_in_frame(folder: Path, views: tuple[int, ...],
                             frame: C.BlenderCamera) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(the reference ``views`` of an object folder a scene of ``frame`` shows, those it cannot: another
    aspect ratio or pixel aspect)."""
    from ..datasets.format import read_object

    ov = read_object(Path(folder))
    pos = {v: k for k, v in enumerate(ov.indices)}
    fits = {v: fits_frame(ov.intrinsics_per_view[pos[v]] if ov.intrinsics_per_view else ov.intrinsics, frame)
            for v in views}
    return tuple(v for v in views if fits[v]), tuple(v for v in views if not fits[v])


def add_reference_cameras(scene: bpy.types.Scene, folder: Path, views: tuple[int, ...]) -> list[bpy.types.Object]:
    """Cameras of reference ``views`` of an object folder, each showing its image as background image (its path
    relative to the .blend, which :func:`write_blend` has saved by now, as the image planes' are: a copied or
    moved project folder finds its own images; absolute when the .blend is unsaved or on another drive);
    InputError for a view the scene's frame cannot show (:func:`reference_views_in_frame` says which)."""
    from ..datasets.format import read_object, view_paths
    from .capture import load_image_relative

    ov = read_object(Path(folder))
    pos = {v: k for k, v in enumerate(ov.indices)}
    coll = bpy.data.collections.get(REFERENCE_COLLECTION) or bpy.data.collections.new(REFERENCE_COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    cams = []
    for v in views:
        k = pos[v]
        intr = ov.intrinsics_per_view[k] if ov.intrinsics_per_view else ov.intrinsics
        cam = _create_camera(scene, Target(f"MRVM reference {v:03d}", intr, ov.c2w_opencv[k], True), coll)
        img = load_image_relative(view_paths(Path(folder), v)["rgb"].resolve())
        bg = cam.data.background_images.new()
        bg.image = img
        cam.data.show_background_images = True
        cams.append(cam)
    return cams


def _remove_dead_partials(folder: Path) -> None:
    """Remove the temporary .blend files (and Blender's ``.blend1`` backups) of :func:`write_blend` runs whose
    process is gone (killed while saving)."""
    for p in Path(folder).glob(f"{PARTIAL_PREFIX}*.blend*"):
        pid = p.name[len(PARTIAL_PREFIX):].split(".")[0]
        if not pid.isdigit() or int(pid) == os.getpid() or not p.is_file():
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            p.unlink(missing_ok=True)
        except (OSError, OverflowError):
            pass  # alive under another user, or not a process id here


def _images_shown(folder: Path, blend: Path | None = None) -> set[Path]:
    """The image files in ``folder`` that the open file (or the .blend ``blend``, read without opening it: its
    images linked for the while) shows; an unreadable ``blend`` (not a .blend at all) shows none."""
    from .objects import quiet_stdout

    def inside(images) -> set[Path]:
        found = set()
        for im in images:
            if im.source == "FILE" and im.filepath and im.packed_file is None:
                f = Path(bpy.path.abspath(im.filepath, library=im.library)).resolve()
                if f.parent == folder.resolve():
                    found.add(f)
        return found

    if blend is None:
        return inside(bpy.data.images)
    libraries = {lib.as_pointer() for lib in bpy.data.libraries}
    try:
        with quiet_stdout(), bpy.data.libraries.load(str(blend), link=True) as (src, dst):
            dst.images = list(src.images)
        return inside(im for im in dst.images if im is not None)
    except (OSError, RuntimeError, ValueError):
        return set()
    finally:  # (its linked images go with it)
        for lib in [lib for lib in bpy.data.libraries if lib.as_pointer() not in libraries]:
            bpy.data.libraries.remove(lib)


def write_blend(blend_path: Path, targets_json: Path, out_dir: Path, references: Path | None = None,
                reference_views: tuple[int, ...] = (), plane_distance: float | None = None, bbox=None,
                populate: Callable[[bpy.types.Scene], None] | None = None) -> Path:
    """A new .blend (the current file is replaced, then opened from it) with a camera and an image plane per
    target of a finished synthesis (``out_dir``) in the targets' frame (:func:`blend_frame`), the reference
    cameras that frame shows (their images as background images; a note names those left out), and
    whatever ``populate(scene)`` adds; images next to it in ``<stem>_novel_views/``, which a replaced .blend
    leaves to it: the images there that the replaced .blend showed and this one does not (the planes of other
    targets) are removed once it is in place, files it did not show (a user's) stay.

    All or nothing: the .blend is built in a temporary file beside it and moved into place at the end, so an
    error leaves an existing .blend, its images and the folders as they were."""
    from ..datasets.novel_views import read_targets
    from ..synthesis.views import make_folder, remove_new_folders
    from .objects import quiet_stdout

    blend_path = Path(blend_path).resolve()
    targets, depth = read_targets(Path(targets_json))
    frame = blend_frame(targets)
    out_dir = Path(out_dir)
    depth = depth and all((out_dir / t.depth_path(i)).is_file() for i, t in enumerate(targets))
    if plane_distance is None:
        if bbox is None:
            raise InputError("give a plane distance or the object's box")
        plane_distance = default_plane_distance(targets, bbox)
    shown: tuple[int, ...] = ()
    if references is not None and reference_views:
        shown, skipped = reference_views_in_frame(Path(references), tuple(reference_views), frame)
        if skipped:
            print(f"note: reference view{'s' if len(skipped) > 1 else ''} {', '.join(map(str, skipped))} left out of "
                  f"{blend_path.name}: a Blender scene has one frame shape, the targets' "
                  f"({_shape(C.intrinsics_from_blender(frame))}), and theirs differs", file=sys.stderr)
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    r = scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = frame.resolution_x, frame.resolution_y, 100
    r.pixel_aspect_x, r.pixel_aspect_y = frame.pixel_aspect_x, frame.pixel_aspect_y
    scene.view_settings.view_transform = "Standard"  # the planes show the images' true colours
    replacing = blend_path.exists()
    folder = blend_images_folder(blend_path)
    folder_existed = folder.exists()
    earlier = _images_shown(folder, blend_path) if replacing and folder_existed else set()
    # a short name (a long but legal .blend name must not overflow 255 bytes) with this process's id: what a killed
    # run left is removed here, once its process is gone
    partial = blend_path.with_name(f"{PARTIAL_PREFIX}{os.getpid()}.blend")
    _remove_dead_partials(blend_path.parent)
    made: list[Path] = []

    def remove_partial() -> None:
        partial.unlink(missing_ok=True)
        Path(str(partial) + "1").unlink(missing_ok=True)  # Blender's backup of the first save

    try:
        made = make_folder(blend_path.parent)
        with IP.transaction() as txn:  # images written over are restored on an error
            with quiet_stdout():  # "//" paths resolve next to the .blend from here on
                bpy.ops.wm.save_as_mainfile(filepath=str(partial), check_existing=False)
            scene = bpy.context.scene
            gen = [dataclasses.replace(t, generated=True) for t in targets]
            cfg = IP.PlaneConfig(distance=float(plane_distance), folder=f"//{folder.name}", own_folder=replacing)
            import_results(scene, gen, out_dir, cfg, depth=depth, txn=txn)
            if shown:
                add_reference_cameras(scene, Path(references), shown)
            scene.camera = bpy.data.objects[gen[0].name]
            if populate is not None:
                populate(scene)
            with quiet_stdout():
                bpy.ops.wm.save_as_mainfile(filepath=str(partial), check_existing=False)
            stale = earlier - _images_shown(folder)
            replace_file(partial, blend_path)  # (Windows: a moment held by an indexer or sync client)
    except BaseException:
        remove_partial()
        if not folder_existed:
            shutil.rmtree(folder, ignore_errors=True)
        remove_new_folders(made)
        raise
    remove_partial()
    for f in stale:  # the replaced .blend's planes' images that this one does not show
        with contextlib.suppress(OSError):
            f.unlink()
    with quiet_stdout():
        bpy.ops.wm.open_mainfile(filepath=str(blend_path))
    return blend_path
