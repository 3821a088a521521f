"""Image planes: a novel view placed in the scene exactly on its camera's frustum.

For a target camera, :func:`build_image_planes` creates a plane whose four corners lie on the rays
through the image's four outer corners (pixel coordinates (0, 0), (W, 0), (W, H), (0, H) in the
pixel-centre convention of ``geometry/cameras.py``) at a planar depth ``distance`` along the
camera's viewing axis. The corners come from the camera's intrinsics as ``scene/camera.read_camera``
reads them (lens shift, sensor fit, resolution and pixel aspect included), so rendering the camera's
view shows the image pixel for pixel. The plane is parented to its camera (it follows the camera),
and its material is shadeless: the image's colour as emission, mixed with a transparent BSDF by the
image's alpha (background = alpha 0), rendered BLENDED (the Blender 4.2+/5.0 ``surface_render_method``)
and invisible to shadow / diffuse / glossy / transmission rays, so it neither lights nor shades the
scene.

Images are written as PNG (depth as EXR and a semantic map as ``<stem>_semantic.png`` when given) into a folder (default ``//mrvm_novel_views``
next to the .blend; paths are stored relative to the .blend) or packed into the .blend. A file already in the
folder is never written over, not even the image of a plane being replaced: another .blend saved beside this one
(Save As), or this .blend's saved state (File > Revert, quitting without saving, Ctrl-Z), may show it; a re-run
takes a new name (``CamA_1.png``, ...) and the replaced plane's files stay on disk. Only a folder that belongs to
one .blend alone (``PlaneConfig.own_folder``: ``synthesize --blend X --force`` rewriting X) has its files replaced.

Everything is created in the collection of ``PlaneConfig.collection`` ("MRVM novel views" for Synthesize,
"MRVM Sem2NeRF" for Sem2NeRF). A camera keeps one plane per collection: building replaces the camera's plane in
that collection only, and hides (never removes) its planes in other collections, another feature's, which would
otherwise cover the new image in the camera's view or z-fight with it at the same distance
(:attr:`PlaneResult.hidden`, :func:`hidden_note` for the message). Building is a transaction: on any error every
datablock and file it created is removed, every file it replaced is restored and every plane it hid is shown.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from ..datasets.format import atomic_write
from ..errors import InputError, OutputError
from ..geometry import cameras as C
from . import camera as scam
from . import compat
from .objects import remove_new_data, safe_id, snapshot_data

COLLECTION = "MRVM novel views"
PLANE_TAG = "mrvm_plane_of"
"""Custom property on a plane object: the name of the camera it belongs to."""
SHOW_SEMANTIC = "mrvm_show_semantic"
"""Custom property on a plane with a semantic map: 0 shows the image, 1 the semantic map (read by
the material's Attribute node)."""


@dataclass(frozen=True)
class NovelView:
    """One image to place in front of one camera."""

    camera: str
    """Name of the camera object (in ``bpy.data.objects``)."""
    rgba: Path | np.ndarray
    """PNG file, or a uint8 (H, W, 3|4) array (alpha 0 = background)."""
    depth: Path | np.ndarray | None = None
    """Optional planar z-depth: an EXR file or a float (H, W) array, saved beside the image."""
    semantic: Path | np.ndarray | None = None
    """Optional semantic map of the same size (a colour PNG or a uint8 (H, W, 3) array), saved beside
    the image; the plane shows it instead of the image while its ``mrvm_show_semantic`` property is 1."""


@dataclass(frozen=True)
class PlaneConfig:
    """Where and how image planes are built."""

    distance: float = 1.0
    """Planar depth of the plane along the camera's viewing axis, scene units (inside the clip range)."""
    pack: bool = False
    """Pack images (and depth) into the .blend instead of referencing files."""
    folder: str = "//mrvm_novel_views"
    """Folder for PNG/EXR files (``//`` = next to the .blend); in pack mode only the names are kept."""
    collection: str = COLLECTION
    """Collection that receives planes (and generated cameras)."""
    replace: bool = True
    """Remove earlier planes of the same cameras in ``collection`` once the new ones are built (and hide their
    planes in other collections)."""
    interpolation: str = "Linear"
    """Image texture interpolation (Linear, Closest, Cubic)."""
    own_folder: bool = False
    """``folder`` belongs to this .blend alone (``scene.novel_views.write_blend`` replacing a .blend and its
    ``<stem>_novel_views/``): files there of the cameras' names are replaced. Otherwise a file already in the
    folder is never written over, not even an image of a plane this build replaces: another .blend saved in the
    same folder, or this .blend's saved state, may show it (a new file name is taken instead)."""

    def validate(self) -> "PlaneConfig":
        if not (np.isfinite(self.distance) and self.distance > 0):
            raise InputError(f"plane distance must be positive, got {self.distance}")
        if self.interpolation not in ("Linear", "Closest", "Cubic", "Smart"):
            raise InputError(f"unknown interpolation {self.interpolation!r}")
        if not self.pack and not self.folder.strip():
            raise InputError("choose a folder for the novel-view images (or pack them into the .blend)")
        return self


@dataclass
class PlaneResult:
    """What :func:`build_image_planes` created."""

    collection: bpy.types.Collection
    planes: list
    images: list
    files: list
    hidden: list = field(default_factory=list)
    """(camera name, plane object) of the planes of the same cameras in other collections that this build hid."""


# ---------------------------------------------------------------------------------------------
# Geometry (pure numpy; no bpy state)
# ---------------------------------------------------------------------------------------------

FAN_CENTRE_OFFSET = (0.25, 0.125)
"""Offset (pixels) of the plane's inner vertex from the frame centre (see :func:`plane_vertices_camera`)."""


def plane_pixels(intr: C.Intrinsics) -> np.ndarray:
    """(5, 2) pixel coordinates of the plane's vertices: four frame corners, then the inner vertex.

    Corners in order bottom-left, bottom-right, top-right, top-left (counter-clockwise seen from the
    camera, so the faces point at it). The quad is a fan of four triangles around an inner vertex
    at (W/2 + 1/4, H/2 + 1/8): no edge passes through a pixel centre at any resolution (each edge
    would need an even/odd ratio to equal an odd/odd one), so a ray through a pixel centre never
    hits two triangles of the plane at once; Cycles would then apply a semi-transparent pixel's
    alpha twice (the diagonal of a plain quad crosses every diagonal pixel centre of a square image).
    """
    w, h = float(intr.width), float(intr.height)
    ox, oy = FAN_CENTRE_OFFSET
    return np.array([[0.0, h], [w, h], [w, 0.0], [0.0, 0.0], [w / 2.0 + ox, h / 2.0 + oy]])


FACES = [(0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)]
"""Triangles of the plane (vertex indices of :func:`plane_pixels`)."""


def plane_vertices_camera(intr: C.Intrinsics, distance: float) -> np.ndarray:
    """(5, 3) plane vertices at planar depth ``distance`` in Blender camera-local axes.

    Pixel (u, v) maps to OpenCV camera coordinates d * ((u - cx) / fx, (v - cy) / fy, 1), then to
    Blender's camera axes through ``geometry/cameras.py``.
    """
    uv = plane_pixels(intr)
    pts = np.stack([(uv[:, 0] - intr.cx) / intr.fx, (uv[:, 1] - intr.cy) / intr.fy, np.ones(len(uv))], axis=1) * distance
    return C.blender_from_opencv_camera_points(pts)


def plane_uvs(intr: C.Intrinsics) -> np.ndarray:
    """(5, 2) texture coordinates: Blender images start at the bottom-left, PNG rows at the top."""
    uv = plane_pixels(intr)
    return np.stack([uv[:, 0] / intr.width, 1.0 - uv[:, 1] / intr.height], axis=1)


# ---------------------------------------------------------------------------------------------
# Transaction: datablocks and files
# ---------------------------------------------------------------------------------------------

class Transaction:
    """Undo log for building: new datablocks, new files, replaced files (restored on rollback)."""

    def __init__(self) -> None:
        self.before = snapshot_data()
        self._new_files: list[Path] = []
        self._backups: list[tuple[Path, Path]] = []
        self._tmpdirs: list[Path] = []
        self._undo: list = []

    def on_rollback(self, fn) -> None:
        """Call ``fn()`` on rollback (to undo a change to data that existed before)."""
        self._undo.append(fn)

    def tmpdir(self) -> Path:
        d = Path(tempfile.mkdtemp(prefix="mrvm_planes_"))
        self._tmpdirs.append(d)
        return d

    def write(self, path: Path, writer) -> Path:
        """Write ``path`` through ``writer(tmp)`` + rename; an existing file is kept aside until commit."""
        path = Path(path)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise OutputError(f"cannot create folder {path.parent}: {e.strerror or e}") from e
        if path.exists():
            fd, bak = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".bak", dir=path.parent)
            os.close(fd)
            os.replace(path, bak)
            self._backups.append((path, Path(bak)))
        else:
            self._new_files.append(path)
        try:
            atomic_write(path, writer)
        except OSError as e:
            raise OutputError(f"cannot write {path}: {e.strerror or e}") from e
        return path

    def rollback(self) -> None:
        for fn in reversed(self._undo):
            with contextlib.suppress(Exception):
                fn()
        remove_new_data(self.before)
        for p in self._new_files:
            with contextlib.suppress(OSError):
                p.unlink()
        for p, bak in reversed(self._backups):
            with contextlib.suppress(OSError):
                os.replace(bak, p)
        self._cleanup()

    def commit(self) -> None:
        for _, bak in self._backups:
            with contextlib.suppress(OSError):
                bak.unlink()
        self._cleanup()

    def _cleanup(self) -> None:
        for d in self._tmpdirs:
            shutil.rmtree(d, ignore_errors=True)
        self._new_files, self._backups, self._tmpdirs, self._undo = [], [], [], []


@contextlib.contextmanager
def transaction(txn: Transaction | None = None):
    """Yield a :class:`Transaction`; roll it back on any exception, commit otherwise.

    With an outer ``txn`` this is a no-op wrapper: the outer owner commits or rolls back.
    """
    if txn is not None:
        yield txn
        return
    t = Transaction()
    try:
        yield t
    except BaseException:
        t.rollback()
        raise
    t.commit()


# ---------------------------------------------------------------------------------------------
# Inputs
# ---------------------------------------------------------------------------------------------

def _camera_object(name: str) -> bpy.types.Object:
    obj = bpy.data.objects.get(name)
    if obj is None:
        raise InputError(f"camera {name!r} does not exist")
    if obj.type != "CAMERA":
        raise InputError(f"{name!r} is a {obj.type.lower()}, not a camera")
    return obj


def _image_size(src: Path | np.ndarray, what: str) -> tuple[int, int]:
    """(width, height) of a PNG file or an image array; InputError naming what is wrong."""
    if isinstance(src, np.ndarray):
        if src.dtype != np.uint8 or src.ndim != 3 or src.shape[2] not in (3, 4):
            raise InputError(f"{what}: expected a uint8 (H, W, 3|4) array, got {src.dtype} {src.shape}")
        return src.shape[1], src.shape[0]
    p = Path(src)
    if not p.is_file():
        raise InputError(f"{what}: image {p} does not exist")
    from PIL import Image

    try:
        with Image.open(p) as im:
            if im.format != "PNG":
                raise InputError(f"{what}: {p} is {im.format}, expected PNG")
            return im.size
    except InputError:
        raise
    except Exception as e:
        raise InputError(f"{what}: cannot read image {p}: {e}") from e


def _depth_size(src: Path | np.ndarray, what: str) -> tuple[int, int]:
    if isinstance(src, np.ndarray):
        if src.ndim != 2 or not np.issubdtype(src.dtype, np.floating):
            raise InputError(f"{what}: depth must be a float (H, W) array, got {src.dtype} {src.shape}")
        return src.shape[1], src.shape[0]
    p = Path(src)
    if not p.is_file():
        raise InputError(f"{what}: depth file {p} does not exist")
    from ..datasets.format import read_depth

    d = read_depth(p)
    return d.shape[1], d.shape[0]


def _check_aspect(img_wh: tuple[int, int], intr: C.Intrinsics, what: str) -> None:
    """The image must cover the camera frame: the render size at some scale (each side rounded)."""
    w, h = img_wh
    fits_w = abs(h - intr.height * w / intr.width) <= 1.0  # scale taken from the width
    fits_h = abs(w - intr.width * h / intr.height) <= 1.0  # scale taken from the height
    if not (fits_w or fits_h):
        raise InputError(f"{what}: image is {w}x{h} but the camera renders {intr.width}x{intr.height}; "
                         "the image must have the frame's aspect ratio")


def output_folder(cfg: PlaneConfig) -> Path:
    f = cfg.folder.strip()
    if f.startswith("//") and not bpy.data.filepath:
        raise OutputError("save the .blend first or choose an absolute folder for the novel views "
                          "(// is relative to the .blend)")
    return Path(bpy.path.abspath(f))


def blend_relative(p: Path) -> str:
    """A file path as Blender stores it: relative to the saved .blend when possible."""
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(str(p))
        except ValueError:  # another drive (Windows)
            pass
    return str(p)


# ---------------------------------------------------------------------------------------------
# Building blocks
# ---------------------------------------------------------------------------------------------

def ensure_collection(scene: bpy.types.Scene, name: str, txn: Transaction) -> bpy.types.Collection:
    coll = bpy.data.collections.get(name)
    if coll is None:
        coll = bpy.data.collections.new(name)  # removed on rollback with the other new data
    if coll not in scene.collection.children_recursive:
        scene.collection.children.link(coll)
        if coll.as_pointer() in txn.before["collections"]:
            txn.on_rollback(lambda: scene.collection.children.unlink(coll))
    return coll


def _image_paths() -> set[str]:
    """Resolved file paths of the file's images (packed ones aside), those of the planes being replaced included."""
    out = set()
    for img in bpy.data.images:
        if not img.filepath or img.packed_file is not None:
            continue
        try:
            out.add(str(Path(bpy.path.abspath(img.filepath, library=img.library)).resolve()))
        except (OSError, ValueError):
            pass
    return out


def _unique_stems(cameras: list[str], folder: Path | None, own_folder: bool) -> list[str]:
    """File stems per camera, distinct within the run, that overwrite nothing: not a file an image of the .blend
    shows (a plane being replaced included: undo brings it back), nor (unless ``own_folder``) a file already on
    disk, which another .blend in the folder, or this .blend's saved state, may show."""
    in_use = _image_paths()

    def taken(p: Path) -> bool:
        p = str(p.resolve())
        return p in in_use or (not own_folder and os.path.lexists(p))

    used: set[str] = set()
    out = []
    for name in cameras:
        base, k = safe_id(name), 0
        while True:
            s = base if k == 0 else f"{base}_{k}"
            clash = folder is not None and any(taken(folder / f"{s}{ext}")
                                               for ext in (".png", "_depth.exr", "_semantic.png"))
            if s.casefold() not in used and not clash:
                break
            k += 1
        used.add(s.casefold())  # (cameras Cam and cam: one file on macOS and Windows, which ignore case)
        out.append(s)
    return out


def _write_png(txn: Transaction, src: Path | np.ndarray, dst: Path) -> Path:
    if isinstance(src, np.ndarray):
        from PIL import Image

        arr = np.ascontiguousarray(src)
        return txn.write(dst, lambda tmp: Image.fromarray(arr).save(tmp, format="PNG"))
    src = Path(src)
    if dst.exists() and src.resolve() == dst.resolve():
        return dst  # already in place
    return txn.write(dst, lambda tmp: shutil.copyfile(src, tmp))


def _write_exr(txn: Transaction, src: Path | np.ndarray, dst: Path) -> Path:
    if isinstance(src, np.ndarray):
        import OpenEXR

        header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
        chans = {"Y": np.ascontiguousarray(src, dtype=np.float32)}

        def w(tmp: str) -> None:
            with OpenEXR.File(header, chans) as f:
                f.write(tmp)
        return txn.write(dst, w)
    src = Path(src)
    if dst.exists() and src.resolve() == dst.resolve():
        return dst
    return txn.write(dst, lambda tmp: shutil.copyfile(src, tmp))


def _load_image(path: Path, name: str, stored_path: str, pack: bool, non_color: bool = False) -> bpy.types.Image:
    try:
        img = bpy.data.images.load(str(path), check_existing=False)
    except RuntimeError as e:
        raise InputError(f"Blender cannot load {path}: {e}") from e
    img.name = name
    if non_color:
        img.colorspace_settings.name = "Non-Color"
    else:
        img.alpha_mode = "STRAIGHT"
    if pack:
        img.pack()
    img.filepath_raw = stored_path
    return img


def _material(name: str, image: bpy.types.Image, interpolation: str,
              semantic: bpy.types.Image | None = None) -> bpy.types.Material:
    """Shadeless image material: emission of the image colour, transparent where alpha is 0. With a
    ``semantic`` image, the colour is the semantic map's where the object's ``mrvm_show_semantic`` is 1."""
    mat = bpy.data.materials.new(name)
    nt = compat.node_tree(mat)
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    tex = nt.nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = interpolation
    tex.extension = "EXTEND"  # the outermost texels reach the frame edge without fading
    emit = nt.nodes.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = 1.0
    transparent = nt.nodes.new("ShaderNodeBsdfTransparent")
    mix = nt.nodes.new("ShaderNodeMixShader")
    if semantic is None:
        nt.links.new(tex.outputs["Color"], emit.inputs["Color"])
    else:
        stex = nt.nodes.new("ShaderNodeTexImage")
        stex.image = semantic
        stex.interpolation = "Closest"  # label colours are not blended
        stex.extension = "EXTEND"
        attr = nt.nodes.new("ShaderNodeAttribute")
        attr.attribute_type, attr.attribute_name = "OBJECT", SHOW_SEMANTIC
        pick = nt.nodes.new("ShaderNodeMix")
        pick.data_type = "RGBA"
        a_in, b_in = (next(sk for sk in pick.inputs if sk.name == n and sk.type == "RGBA") for n in ("A", "B"))
        nt.links.new(attr.outputs["Fac"], pick.inputs["Factor"])
        nt.links.new(tex.outputs["Color"], a_in)
        nt.links.new(stex.outputs["Color"], b_in)
        nt.links.new(next(sk for sk in pick.outputs if sk.type == "RGBA"), emit.inputs["Color"])
        stex.location, attr.location, pick.location = (-600, -300), (-600, 250), (-400, -150)
    nt.links.new(tex.outputs["Alpha"], mix.inputs["Fac"])
    nt.links.new(transparent.outputs["BSDF"], mix.inputs[1])
    nt.links.new(emit.outputs["Emission"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    for i, n in enumerate((tex, emit, transparent, mix, out)):
        n.location = (-600 + 200 * i, 0)
    transparent.location = (-200, 200)
    # EEVEE (4.2+): forward-rendered blending gives soft alpha edges; no shadow from the plane.
    mat.surface_render_method = "BLENDED"
    mat.use_transparency_overlap = False
    mat.use_transparent_shadow = True
    mat.use_backface_culling = False
    return mat


def _plane_mesh(name: str, intr: C.Intrinsics, distance: float) -> bpy.types.Mesh:
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(map(float, c)) for c in plane_vertices_camera(intr, distance)], [], FACES)
    uvs = plane_uvs(intr)
    uv = mesh.uv_layers.new(name="UVMap")
    for loop in mesh.loops:
        uv.data[loop.index].uv = tuple(uvs[loop.vertex_index])
    mesh.update()
    return mesh


def _plane_object(name: str, mesh: bpy.types.Mesh, cam: bpy.types.Object, coll: bpy.types.Collection) -> bpy.types.Object:
    obj = bpy.data.objects.new(name, mesh)
    coll.objects.link(obj)
    obj.parent = cam
    obj.matrix_parent_inverse = Matrix.Identity(4)
    # World = camera without its scale (read_camera's frame): basis = parent^-1 @ unscaled parent.
    parent = C.as_pose(cam.matrix_world)
    obj.matrix_basis = Matrix((np.linalg.inv(parent) @ C.remove_scale(parent)).tolist())
    for attr in ("visible_shadow", "visible_diffuse", "visible_glossy", "visible_transmission",
                 "visible_volume_scatter"):
        setattr(obj, attr, False)
    obj.hide_select = False
    obj[PLANE_TAG] = cam.name
    return obj


def colour_management_note(scene: bpy.types.Scene) -> str:
    """A note when ``scene`` renders its image planes other than as the images are: a view transform other than
    Standard (AgX, Blender's default since 4.0, maps the synthesized white to 197 of 255 and shifts hues), a look,
    exposure or gamma; '' when it shows them as they are. (The planes are emission shaders of the images: what
    the view transform does to them, it does to every pixel.)"""
    vs = scene.view_settings
    changed = [f"view transform {vs.view_transform}" if vs.view_transform != "Standard" else "",
               f"look {vs.look}" if vs.look not in ("None", "", "Standard - None") else "",
               f"exposure {vs.exposure:g}" if vs.exposure != 0.0 else "",
               f"gamma {vs.gamma:g}" if vs.gamma != 1.0 else "",
               "curves" if vs.use_curve_mapping else ""]
    changed = [c for c in changed if c]
    if not changed:
        return ""
    return (f"the scene's colour management ({', '.join(changed)}) shows the planes other than synthesized; "
            "Render Properties > Color Management > View Transform Standard (no look, exposure 0, gamma 1) shows "
            "them as they are")


def planes_of(camera: bpy.types.Object, collection: bpy.types.Collection | None = None) -> list[bpy.types.Object]:
    """Image planes built for ``camera`` (children tagged with its name); with ``collection``, those in it."""
    return [o for o in camera.children if o.get(PLANE_TAG) == camera.name
            and (collection is None or o.name in collection.objects)]


def _shown(obj: bpy.types.Object, scene: bpy.types.Scene) -> bool:
    """Whether ``obj`` renders or shows in one of ``scene``'s view layers."""
    if not obj.hide_render:
        return True
    for vl in scene.view_layers:
        try:
            if not obj.hide_get(view_layer=vl):
                return True
        except RuntimeError:  # not in that view layer
            pass
    return False


def _hide(obj: bpy.types.Object, scene: bpy.types.Scene, txn: Transaction) -> None:
    """Hide ``obj`` in the render and in ``scene``'s view layers (the Outliner's eye and camera), undone on rollback."""
    before = [(vl, obj.hide_get(view_layer=vl)) for vl in scene.view_layers if vl.objects.get(obj.name) is not None]
    render = obj.hide_render

    def restore() -> None:
        obj.hide_render = render
        for vl, h in before:
            obj.hide_set(h, view_layer=vl)
    txn.on_rollback(restore)
    obj.hide_render = True
    for vl, _ in before:
        obj.hide_set(True, view_layer=vl)


def hidden_note(res: "PlaneResult") -> str:
    """What the message says of the planes a build hid ('' if none): which, of which cameras, where, and how to
    show them again."""
    if not res.hidden:
        return ""
    by_coll: dict[str, list[str]] = {}
    for cam, obj in res.hidden:
        coll = obj.users_collection[0].name if obj.users_collection else "no collection"
        by_coll.setdefault(coll, []).append(cam)
    parts = [f"the plane{'s' if len(cams) > 1 else ''} of {', '.join(repr(c) for c in cams)} in collection {coll!r}"
             for coll, cams in by_coll.items()]
    many = len(res.hidden) > 1
    return (f"{' and '.join(parts)} {'are' if many else 'is'} hidden, not removed (a camera shows one plane at a "
            f"time; show {'them' if many else 'it'} again with the eye and camera icons in the Outliner)")


def _remove_planes(objs: list[bpy.types.Object]) -> None:
    """Remove planes with their mesh, and materials / images no one else uses."""
    meshes = {o.data for o in objs if o.data is not None}
    mats = {s.material for o in objs for s in o.material_slots if s.material is not None}
    imgs = {n.image for m in mats if m.node_tree for n in m.node_tree.nodes
            if n.type == "TEX_IMAGE" and n.image is not None}
    depth_imgs = {bpy.data.images.get(o.get("mrvm_depth_image", "")) for o in objs} - {None}
    bpy.data.batch_remove(list(objs))
    bpy.data.batch_remove([m for m in meshes if m.users == 0])
    bpy.data.batch_remove([m for m in mats if m.users == 0])
    bpy.data.batch_remove([i for i in imgs if i.users == 0])
    bpy.data.batch_remove([i for i in depth_imgs if i.users <= 1])  # only the fake user left


# ---------------------------------------------------------------------------------------------
# The builder
# ---------------------------------------------------------------------------------------------

def check_clip_range(cameras, distance: float) -> None:
    """InputError when ``distance`` lies outside the clip range of one of ``cameras`` (None entries:
    cameras still to be created, skipped: ``scene.novel_views`` gives them a clip range around it)."""
    for cam in cameras:
        if cam is not None and not (cam.data.clip_start < distance < cam.data.clip_end):
            raise InputError(f"plane distance {distance:g} is outside camera {cam.name!r}'s clip range "
                             f"({cam.data.clip_start:g}..{cam.data.clip_end:g})")


def build_image_planes(scene: bpy.types.Scene, views: list[NovelView], cfg: PlaneConfig,
                       txn: Transaction | None = None) -> PlaneResult:
    """Create one image plane per view in ``cfg.collection``; all or nothing (see module doc).

    Everything is checked before anything is created: cameras exist and are perspective, the
    plane lies inside each camera's clip range, images exist and have the frame's aspect ratio,
    depth maps match their image.
    """
    cfg.validate()
    if not views:
        raise InputError("no novel views to place")
    # ---- check (no side effects)
    for vl in scene.view_layers:  # fresh camera matrices (loc/rot/scale set since the last update)
        vl.update()
    cams, intrs = [], []
    for v in views:
        cam = _camera_object(v.camera)
        intr, _ = scam.read_camera(cam, scene)
        check_clip_range([cam], cfg.distance)
        wh = _image_size(v.rgba, f"camera {cam.name!r}")
        _check_aspect(wh, intr, f"camera {cam.name!r}")
        if v.depth is not None and _depth_size(v.depth, f"camera {cam.name!r}") != wh:
            raise InputError(f"camera {cam.name!r}: depth map size differs from its image {wh[0]}x{wh[1]}")
        if v.semantic is not None and _image_size(v.semantic, f"camera {cam.name!r}") != wh:
            raise InputError(f"camera {cam.name!r}: semantic map size differs from its image {wh[0]}x{wh[1]}")
        cams.append(cam)
        intrs.append(intr)
    if len({c.name for c in cams}) != len(cams):
        raise InputError("each camera can take only one novel view per run")
    folder = None if cfg.pack else output_folder(cfg)
    stored_folder = cfg.folder.strip() or "//mrvm_novel_views"

    # ---- build (rolled back on any error)
    with transaction(txn) as t:
        coll = ensure_collection(scene, cfg.collection, t)
        old = [p for c in cams for p in planes_of(c, coll)] if cfg.replace else []
        # the cameras' planes in other collections (another feature's: Sem2NeRF's, Synthesize's) are kept, hidden:
        # shown, they would cover the new image in the camera's view, or z-fight with it at the same distance
        hidden = ([(c.name, p) for c in cams for p in planes_of(c) if p.name not in coll.objects and _shown(p, scene)]
                  if cfg.replace else [])
        for _, p in hidden:
            _hide(p, scene, t)
        work = t.tmpdir() if cfg.pack else None
        planes, images, files = [], [], []
        stems = _unique_stems([c.name for c in cams], folder, cfg.own_folder)
        for v, cam, intr, stem in zip(views, cams, intrs, stems):
            png = _write_png(t, v.rgba, (work or folder) / f"{stem}.png")
            stored = (f"{stored_folder.rstrip('/')}/{stem}.png" if cfg.pack else blend_relative(png))
            img = _load_image(png, f"MRVM {cam.name}", stored, cfg.pack)
            if not cfg.pack:
                files.append(png)
            images.append(img)
            simg = None
            if v.semantic is not None:
                spng = _write_png(t, v.semantic, (work or folder) / f"{stem}_semantic.png")
                stored_s = (f"{stored_folder.rstrip('/')}/{stem}_semantic.png" if cfg.pack else blend_relative(spng))
                simg = _load_image(spng, f"MRVM semantic {cam.name}", stored_s, cfg.pack)
                images.append(simg)
                if not cfg.pack:
                    files.append(spng)
            mesh = _plane_mesh(f"MRVM plane {cam.name}", intr, cfg.distance)
            mesh.materials.append(_material(f"MRVM {cam.name}", img, cfg.interpolation, simg))
            obj = _plane_object(f"MRVM plane {cam.name}", mesh, cam, coll)
            obj["mrvm_image"] = img.name
            if simg is not None:
                obj["mrvm_semantic_image"] = simg.name
                obj[SHOW_SEMANTIC] = 0
            obj["mrvm_distance"] = float(cfg.distance)
            if v.depth is not None:
                exr = _write_exr(t, v.depth, (work or folder) / f"{stem}_depth.exr")
                stored_d = (f"{stored_folder.rstrip('/')}/{stem}_depth.exr" if cfg.pack else blend_relative(exr))
                dimg = _load_image(exr, f"MRVM depth {cam.name}", stored_d, cfg.pack, non_color=True)
                dimg.use_fake_user = True  # referenced by no material: keep it through save/reload
                obj["mrvm_depth_image"] = dimg.name
                images.append(dimg)
                if not cfg.pack:
                    files.append(exr)
            planes.append(obj)
        if old:
            _remove_planes(old)
            for obj in planes:  # take back the names the removed planes held ("... .001" otherwise)
                cam = obj.parent.name
                obj.name = obj.data.name = f"MRVM plane {cam}"
                obj.data.materials[0].name = f"MRVM {cam}"
                for key, name in (("mrvm_image", f"MRVM {cam}"), ("mrvm_depth_image", f"MRVM depth {cam}"),
                                  ("mrvm_semantic_image", f"MRVM semantic {cam}")):
                    if key in obj:
                        img = bpy.data.images[obj[key]]
                        img.name = name  # Blender adds a suffix when another image holds the name
                        obj[key] = img.name
    return PlaneResult(coll, planes, images, files, hidden)
