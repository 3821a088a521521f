"""Dataset objects: where they come from, how they are loaded into a render scene, normalization.

A *source* string names what to render:

- ``selected``: each selected mesh object of the current file (copies are rendered; the user's
  objects are never modified);
- a mesh file (OBJ, PLY, STL, glTF/GLB, OFF, FBX, USD/USDA/USDC/USDZ, Alembic) or a .blend (what a render of its
  first scene shows);
- a folder: a ShapeNetCore folder (v2: ``<synset>/<model>/models/model_normalized.obj``, v1:
  ``<synset>/<model>/model.obj``; one synset folder or the whole tree) or a folder of mesh files;
- ``procedural:<category>:<seed>``: a generated object of the procedural library.

Objects are normalized as ShapeNetCore v2 is: centred on their bounding-box centre and scaled so
the bounding-box diagonal is 1. The 4x4 normalization matrix is recorded in ``meta.json``.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import os
import re
import sys
from dataclasses import dataclass, field, replace
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from ..errors import InputError
from . import compat

# Formats Blender has no importer for (COLLADA left Blender in 5.0; it reads binary FBX only), read with the Open
# Asset Import Library (the assimp-py package) where it is installed: :func:`_import_with_assimp`.
ASSIMP_EXTS = {".dae": "COLLADA", ".3ds": "3D Studio", ".lwo": "LightWave", ".x": "DirectX", ".ac": "AC3D",
               ".ase": "3ds Max ASE", ".3mf": "3MF", ".ms3d": "MilkShape 3D", ".x3d": "X3D", ".amf": "AMF",
               ".dxf": "DXF"}
_ASSIMP_PIN = "assimp-py==1.1.0"


def _assimp_available() -> bool:
    try:
        import assimp_py  # noqa: F401
    except ImportError:
        return False
    return True


_HAVE_ASSIMP = _assimp_available()
MESH_EXTS = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off", ".fbx", ".usd", ".usda", ".usdc", ".usdz", ".abc",
             ".blend") + (tuple(ASSIMP_EXTS) if _HAVE_ASSIMP else ())
# 3D formats this Blender cannot import or that are not a mesh file to import: a folder's files of these kinds are
# named in a warning instead of passed over without a word.
_EXPORT, _CAD = "export it as glTF, FBX or OBJ", "tessellate it to STL or OBJ in its CAD tool"
_ASSIMP_ADVICE = f"; or install {_ASSIMP_PIN} into the Python that runs the render, which reads it"
OTHER_3D_EXTS = {".max": _EXPORT, ".skp": _EXPORT, ".c4d": _EXPORT, ".wrl": _EXPORT, ".x3dv": _EXPORT,
                 ".ma": "export it as FBX or USD", ".mb": "export it as FBX or USD",
                 ".step": _CAD, ".stp": _CAD, ".iges": _CAD, ".igs": _CAD}
if not _HAVE_ASSIMP:
    OTHER_3D_EXTS.update({ext: f"Blender has no {name} importer; {_EXPORT}{_ASSIMP_ADVICE}"
                          for ext, name in ASSIMP_EXTS.items()})

# ShapeNetCore v2 synset ids of the 13 categories used by SRN / NMR / pixelNeRF.
SHAPENET_SYNSETS = {
    "02691156": "airplane", "02828884": "bench", "02933112": "cabinet", "02958343": "car",
    "03001627": "chair", "03211117": "display", "03636649": "lamp", "03691459": "loudspeaker",
    "04090263": "rifle", "04256520": "sofa", "04379243": "table", "04401088": "telephone",
    "04530566": "watercraft",
}


@dataclass(frozen=True)
class ObjectSpec:
    """One dataset object to render."""

    kind: str
    """'selected', 'file' or 'procedural'."""
    category: str
    """Category folder name."""
    object_id: str
    """Object folder name (unique within the category)."""
    path: str = ""
    """Mesh file (kind 'file')."""
    names: tuple[str, ...] = ()
    """Blender object names (kind 'selected')."""
    seed: int = 0
    """Seed (kind 'procedural')."""
    params: tuple[tuple[str, str], ...] = field(default_factory=tuple)
    """Generator parameters (kind 'procedural')."""
    member: str = ""
    """The mesh file inside the zip archive ``path`` (kind 'file'; empty for a file on disk)."""
    uids: tuple[int, ...] = field(default=(), compare=False)
    """``session_uid`` of each of ``names`` when chosen (kind 'selected'): :func:`with_current_names`."""

    @property
    def key(self) -> str:
        return f"{self.category}/{self.object_id}"

    def describe(self) -> str:
        if self.kind == "file":
            return f"{self.path}!/{self.member}" if self.member else self.path
        if self.kind == "procedural":
            return f"procedural:{self.category}:{self.seed}"
        return "selected:" + ",".join(self.names)


_WINDOWS_RESERVED = re.compile(r"(?i)(con|prn|aux|nul|com[1-9]|lpt[1-9])")
"""Names Windows gives no file or folder, whatever follows their first dot (``NUL.obj`` too): an object or camera
so named (``aux``, ``Com1``) made a folder or file a dataset copied to Windows cannot hold; :func:`safe_id` adds
an underscore."""


def safe_id(name: str) -> str:
    """A folder-safe object id: ``name``'s letters, digits, dots, dashes and underscores, any other run of characters
    an underscore. A name with characters outside ASCII keeps its readable part (accents dropped: ``café`` reads
    ``cafe``) and ends in a short stable hash of the whole name (``椅子`` is ``object_`` and six hex digits), so
    names in other scripts do not all become one id; an ASCII name's id is what it always was, but for the names
    Windows reserves (``CON``, ``nul.001``: ``CON_``, ``nul_.001``... see :data:`_WINDOWS_RESERVED`)."""
    import hashlib
    import unicodedata

    if name.isascii():
        out = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "object"
        head, dot, rest = out.partition(".")
        return f"{head}_{dot}{rest}" if _WINDOWS_RESERVED.fullmatch(head) else out
    name = unicodedata.normalize("NFC", name)  # macOS lists names decomposed: one name, one id
    readable = unicodedata.normalize("NFKD", name).encode("ascii", "ignore").decode()
    return f"{safe_id(readable)}_{hashlib.sha256(name.encode('utf-8', 'surrogateescape')).hexdigest()[:6]}"


_SYNSET = re.compile(r"\d{8}")
"""A ShapeNet synset folder's name (WordNet offsets: 8 digits)."""


def _shapenet_model(rel: tuple[str, ...], root_name: str) -> tuple[str, str, str] | None:
    """(version, synset folder, model id) of a file at ``rel`` (its path's parts below a folder named ``root_name``)
    where ShapeNetCore keeps a model, else None. v2: ``<synset>/<model>/models/model_normalized.obj`` (a name no other
    layout uses: any synset folder name is taken, as it always was); v1 (the NMR renders' source):
    ``<synset>/<model>/model.obj``, whose common file name is taken only below a synset folder of 8 digits (Google
    Scanned Objects' ``<name>/meshes/model.obj`` is no ShapeNet). Either below the root, or below the root as one
    synset folder."""
    for version, tail, any_name in (("v2", ("models", "model_normalized.obj"), True), ("v1", ("model.obj",), False)):
        if len(rel) < len(tail) or rel[-len(tail):] != tail:
            continue
        head = rel[:-len(tail)]
        if len(head) == 2 and (any_name or _SYNSET.fullmatch(head[0])):
            return version, head[0], head[1]
        if len(head) == 1 and (any_name or _SYNSET.fullmatch(root_name)):
            return version, root_name, head[0]
    return None


def folder_files(root: Path) -> list[Path]:
    """The mesh files, archives and files of other 3D formats in a folder and its subfolders at any depth, sorted.
    Hidden names (starting with '.': macOS's AppleDouble ``._chair.obj``, ``.git``) and ``__MACOSX`` folders are left
    out, as the archive reader leaves them out; linked folders are followed, each folder once."""
    exts = {*MESH_EXTS, *ARCHIVE_EXTS, *OTHER_3D_EXTS}
    out: list[Path] = []
    seen: set[str] = set()
    for top, dirs, files in os.walk(root, followlinks=True):
        real = os.path.realpath(top)
        if real in seen:  # a link back up the tree, or a folder reached by two links
            dirs[:] = []
            continue
        seen.add(real)
        dirs[:] = [d for d in dirs if not d.startswith(".") and d != "__MACOSX"]
        out.extend(Path(top) / f for f in files if not f.startswith(".") and Path(f).suffix.lower() in exts
                   and os.path.isfile(os.path.join(top, f)))
    return sorted(out)


def _names(files: list[Path], root: Path, n: int = 3) -> str:
    """Up to ``n`` files' paths below ``root``, then '...' if there are more."""
    return ", ".join(str(f.relative_to(root)) for f in files[:n]) + (", ..." if len(files) > n else "")


def _folder_specs(src: str, root: Path, category: str | None, passed_over: list[str] | None) -> list[ObjectSpec]:
    """The objects of a folder: a ShapeNetCore folder's models (:func:`_shapenet_model`; its other mesh files are named
    in ``passed_over`` as not rendered), else every mesh file and zip archive of mesh files in it and its subfolders
    (:func:`folder_files`; files of one name in different folders are named by them: :func:`_named_by_folder`).
    Archives without mesh files or that cannot be read, and files of other 3D formats, are named in
    ``passed_over``."""
    files = folder_files(root)
    found = [(f, _shapenet_model(f.relative_to(root).parts, Path(os.path.abspath(root)).name)) for f in files]
    models = [(f, m) for f, m in found if m is not None and m[0] == "v2"] or [(f, m) for f, m in found if m is not None]
    warn = passed_over.append if passed_over is not None else (lambda _: None)
    if models:
        taken = {f for f, _ in models}
        rest = [f for f in files if f not in taken]
        if rest:
            warn(f"{src}: {len(rest)} file(s) outside ShapeNetCore's <synset>/<model> layout not rendered "
                 f"({_names(rest, root)}): give them as sources of their own")
        return [ObjectSpec("file", safe_id(category or SHAPENET_SYNSETS.get(synset, synset)), safe_id(model),
                           path=str(f)) for f, (_, synset, model) in models]
    meshes = [f for f in files if f.suffix.lower() in MESH_EXTS]
    other = [f for f in files if f.suffix.lower() in OTHER_3D_EXTS]
    archives = [(f, _archive_members(f, quiet=True)) for f in files if f.suffix.lower() in ARCHIVE_EXTS]
    broken = [f for f, m in archives if m is None]
    specs = [spec for f, m in archives if m for spec in _archive_specs(f, m, category)]
    specs += [ObjectSpec("file", safe_id(category or "custom"), safe_id(f.stem), path=str(f)) for f in meshes]
    if not specs:
        hint = (f"; it holds {len(other)} {other[0].suffix} file(s): {OTHER_3D_EXTS[other[0].suffix.lower()]}"
                if other else f"; {_names(broken, root)} cannot be read (damaged, or not a zip file)" if broken else "")
        raise InputError(f"no mesh files ({', '.join(MESH_EXTS)}) or ShapeNet models in folder {src}{hint}")
    empty = [f for f, m in archives if m == []]
    if empty:
        warn(f"{src}: {len(empty)} .zip file(s) with no mesh file inside not rendered ({_names(empty, root)})")
    if broken:
        warn(f"{src}: {len(broken)} archive(s) that cannot be read (damaged, or not a zip file) not rendered "
             f"({_names(broken, root)})")
    for ext in sorted({f.suffix.lower() for f in other}):
        these = [f for f in other if f.suffix.lower() == ext]
        warn(f"{src}: {len(these)} {ext} file(s) not rendered ({_names(these, root)}): {OTHER_3D_EXTS[ext]}")
    return specs


def resolve_sources(sources: tuple[str, ...], category: str | None = None,
                    passed_over: list[str] | None = None) -> list[ObjectSpec]:
    """Turn source strings into object specs; raises InputError for anything unusable. What a folder holds that is
    not rendered (files of another 3D format, archives without meshes, files outside a ShapeNet layout) is appended
    to ``passed_over`` as a message each. A source named twice (a file by two spellings of its path, ``procedural:
    chair:1`` and ``procedural:chair:01``) is one object; two different sources that map to one object folder are
    refused."""
    if not sources:
        raise InputError("no source given: name mesh files, a folder, 'selected' or 'procedural:<category>:<seed>'")
    specs: list[ObjectSpec] = []
    for src in sources:
        if src == "selected":
            chosen = list(bpy.context.selected_objects) if bpy.context.view_layer else []
            objs = [o for o in chosen if o.type in _MESHLIKE and (o.type != "META" or _metaball_basis(o))]
            parts = sorted(o.name for o in chosen if o.type == "META" and not _metaball_basis(o))
            if parts and passed_over is not None:
                passed_over.append(f"selected metaball(s) {', '.join(parts[:3])}{', ...' if len(parts) > 3 else ''} "
                                   "not rendered on their own: a metaball adds to the surface of its family's first "
                                   "one (its name without the number), which is rendered when it is selected")
            if not objs:
                raise InputError("no mesh, curve, surface, text or metaball objects are selected"
                                 + (" (of a metaball family, select the one whose name ends in no number)"
                                    if parts else ""))
            for o in sorted(objs, key=lambda o: o.name):
                cat = category or str(o.get("mrvm_category", "custom"))
                specs.append(ObjectSpec("selected", safe_id(cat), safe_id(o.name), names=(o.name,),
                                        uids=(o.session_uid,)))
        elif src.startswith("procedural:"):
            parts = src.split(":")
            if len(parts) != 3 or not parts[1]:
                raise InputError(f"procedural source must be 'procedural:<category>:<seed>', got {src!r}")
            try:
                seed = int(parts[2])
            except ValueError:
                raise InputError(f"seed must be an integer in {src!r}") from None
            if seed < 0:
                raise InputError(f"seed must be non-negative in {src!r}")
            _check_procedural(parts[1], seed, src)
            specs.append(ObjectSpec("procedural", parts[1], f"{parts[1]}_{seed:06d}", seed=seed))
        else:
            p = Path(src).expanduser()
            if not p.exists():
                raise InputError(f"mesh file or folder not found: {src}")
            if p.is_dir():
                specs.extend(_folder_specs(src, p, category, passed_over))
            elif p.suffix.lower() in ARCHIVE_EXTS:
                members = _archive_members(p)
                if not members:
                    raise InputError(f"no mesh files ({', '.join(MESH_EXTS)}) in archive {src}"
                                     + ("; a .dae in it is read with assimp-py, which is not installed here"
                                        if p.suffix.lower() in (".kmz", ".zae") and ".dae" not in MESH_EXTS else ""))
                specs.extend(_archive_specs(p, members, category))
            else:
                if p.suffix.lower() not in MESH_EXTS:
                    hint = f" ({OTHER_3D_EXTS[p.suffix.lower()]})" if p.suffix.lower() in OTHER_3D_EXTS else ""
                    raise InputError(f"unsupported mesh format {p.suffix or '(none)'!r} for {src}{hint}; "
                                     f"supported: {', '.join(MESH_EXTS)}, and .zip, .kmz or .zae archives of them")
                specs.append(ObjectSpec("file", safe_id(category or "custom"), safe_id(p.stem), path=str(p)))
    specs = _named_by_folder(_distinct(specs))
    counts = collections.Counter(s.key for s in specs)
    dup = sorted(k for k, n in counts.items() if n > 1)
    if dup:
        same = [s.describe() for s in specs if s.key == dup[0]]
        raise InputError(f"two sources map to the same object folder: {dup[0]} ({' and '.join(same[:2])}; "
                         "rename one)")
    return specs


def _check_procedural(category: str, seed: int, src: str) -> None:
    """Refuse a procedural source the library cannot build (an unknown category, a seed out of range) when the
    sources are read, not when its turn comes after the objects before it rendered."""
    try:
        from . import procedural
    except ImportError:
        raise InputError("the procedural object library is not available in this build") from None
    try:
        procedural.sample_parameters(category, seed)
    except InputError as e:
        raise InputError(f"{e} (in {src!r})") from None


def with_current_names(spec: ObjectSpec) -> ObjectSpec:
    """``spec`` with its selected objects under the names they have now: the artist goes on working while the panel's
    Render Dataset runs, and an object renamed before its turn stopped the render ("object 'Table' no longer
    exists", the objects after it not rendered). Found by the ``session_uid`` recorded when it was chosen; its
    object folder stays the one named at the start. One deleted since is an InputError, also when another object
    has taken its name (which would be rendered into its folder); a spec without uids is looked up by name."""
    if spec.kind != "selected" or not spec.uids:
        return spec
    by_uid = {o.session_uid: o.name for o in bpy.data.objects}
    gone = [name for name, uid in zip(spec.names, spec.uids) if uid not in by_uid]
    if gone:
        raise InputError(f"object {gone[0]!r} was deleted while the render ran")
    names = tuple(by_uid[uid] for uid in spec.uids)
    return spec if names == spec.names else replace(spec, names=names)


def _distinct(specs: list[ObjectSpec]) -> list[ObjectSpec]:
    """``specs`` without repeats of one source for one object folder: the same file (its path resolved, and the member
    inside an archive), procedural object or selected object named twice is rendered once, as first named."""
    seen: set[tuple] = set()
    out = []
    for s in specs:
        what = (s.kind, os.path.realpath(Path(s.path).expanduser()) if s.kind == "file" else "", s.member, s.seed,
                s.names, s.params, s.category, s.object_id)
        if what not in seen:
            seen.add(what)
            out.append(s)
    return out


def _named_by_folder(specs: list[ObjectSpec]) -> list[ObjectSpec]:
    """Mesh files of one name in different folders (a robot's ``link1.stl`` and another's) named by their folders:
    the first folder below the folders they share (``franka_panda/meshes/visual/link1.obj`` and
    ``xarm/.../visual/link1.stl`` are ``franka_panda_link1`` and ``xarm_link1``), or every folder below it where
    those first folders are alike too. Files in one folder (``link_0.obj`` beside ``link_0.stl``: one object in two
    formats) keep their name, and the caller refuses them as one object folder."""
    groups: dict[str, list[int]] = {}
    for i, s in enumerate(specs):
        groups.setdefault(s.key, []).append(i)
    out = list(specs)
    for idx in groups.values():
        if len(idx) < 2 or any(specs[i].kind != "file" or specs[i].member for i in idx):
            continue
        dirs = [Path(specs[i].path).expanduser().absolute().parent for i in idx]
        if len(set(dirs)) < len(dirs):
            continue
        top = Path(os.path.commonpath(dirs))
        rel = [d.relative_to(top).parts for d in dirs]
        first = [r[:1] for r in rel]
        for i, r, f in zip(idx, rel, first, strict=True):
            parts = f if first.count(f) == 1 else r
            name = "_".join((*parts, Path(specs[i].path).stem))
            out[i] = ObjectSpec("file", specs[i].category, safe_id(name), path=specs[i].path)
    return out


# Zip archives of mesh files: a downloaded model (.zip), Google Earth and SketchUp's KMZ and zipped COLLADA (.zae),
# each a zip of COLLADA files and their textures. One is unpacked, whole, into the render's work folder: beyond
# ARCHIVE_LIMIT_BYTES it is refused (unzip it and name the folder instead).
ARCHIVE_EXTS = (".zip", ".kmz", ".zae")
ARCHIVE_LIMIT_BYTES = 4 << 30


def _archive_members(path: Path, quiet: bool = False) -> list[str] | None:
    """The mesh files inside a zip archive, at any depth, sorted (macOS resource forks left out). A file that is not
    a readable zip (damaged, truncated) is an InputError, or with ``quiet`` None."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            names = [i.filename for i in z.infolist() if not i.is_dir()]
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        if quiet:
            return None
        raise InputError(f"cannot read archive {path}: {str(e).strip() or 'not a zip file'}") from None
    return sorted(n for n in names if Path(n).suffix.lower() in MESH_EXTS and not n.startswith("__MACOSX/")
                  and not Path(n).name.startswith("._"))


def _archive_specs(path: Path, members: list[str], category: str | None) -> list[ObjectSpec]:
    """One object a mesh file inside the archive: named by the archive (and, when it holds several, by the file's
    path in it without its suffix: ``pack.zip``'s ``chairs/a.obj`` is ``pack_chairs_a``)."""
    one = len(members) == 1
    return [ObjectSpec("file", safe_id(category or "custom"),
                       safe_id(path.stem if one else f"{path.stem}_{Path(m).with_suffix('')}"), path=str(path),
                       member=m)
            for m in members]


def source_file(spec: ObjectSpec, work_dir: Path | None = None) -> Path:
    """The mesh file to import for a 'file' spec: the file itself, or, for a file inside a zip archive, where the
    archive is unpacked (once a run) under ``work_dir`` (a temporary folder removed at exit when None), with the
    files around it, so textures, buffers and caches it names are read from there."""
    if not spec.member:
        return Path(spec.path)
    return archive_root(spec, work_dir) / spec.member


def archive_root(spec: ObjectSpec, work_dir: Path | None = None) -> Path:
    """The folder a 'file' spec's zip archive is unpacked into (see :func:`source_file`)."""
    import hashlib
    import zipfile

    if work_dir is None:
        work_dir = _process_work_dir()
    root = Path(work_dir) / "archives" / hashlib.sha256(str(Path(spec.path).resolve()).encode()).hexdigest()[:16]
    if not (root / ".unpacked").is_file():
        try:
            with zipfile.ZipFile(spec.path) as z:
                size = sum(i.file_size for i in z.infolist())
                if size > ARCHIVE_LIMIT_BYTES:
                    raise InputError(f"archive {spec.path} unpacks to {size / 2**30:.1f} GiB, more than "
                                     f"{ARCHIVE_LIMIT_BYTES / 2**30:.0f} GiB: unzip it and name the folder instead")
                z.extractall(root)  # zipfile keeps every member under root (no absolute paths, no '..')
        except (zipfile.BadZipFile, OSError, EOFError) as e:
            raise InputError(f"cannot read archive {spec.path}: {str(e).strip() or 'not a zip file'}") from None
        (root / ".unpacked").touch()
    return root


_WORK_DIR: list[Path] = []


def _process_work_dir() -> Path:
    if not _WORK_DIR:
        import atexit
        import shutil
        import tempfile

        _WORK_DIR.append(Path(tempfile.mkdtemp(prefix="mrvm_archives_")))
        atexit.register(shutil.rmtree, _WORK_DIR[0], True)
    return _WORK_DIR[0]


# --------------------------------------------------------------------------------------------
# Loading into a scene
# --------------------------------------------------------------------------------------------

_DATA_COLLECTIONS = ("objects", "meshes", "materials", "images", "textures", "node_groups", "cameras",
                     "lights", "worlds", "collections", "curves", "armatures", "actions", "particles")


def snapshot_data(names: tuple[str, ...] = _DATA_COLLECTIONS) -> dict[str, set[int]]:
    """Pointers of the datablocks in ``bpy.data``'s collections ``names`` (by default every kind that may be created
    while loading or rendering; :func:`all_id_collections` for every kind)."""
    return {name: {d.as_pointer() for d in getattr(bpy.data, name)} for name in names}


def all_id_collections() -> tuple[str, ...]:
    """The names of every collection of data blocks in ``bpy.data`` (libraries among them)."""
    def is_id(t) -> bool:
        while t is not None:
            if t.identifier == "ID":
                return True
            t = t.base
        return False

    return tuple(p.identifier for p in bpy.data.bl_rna.properties if p.type == "COLLECTION" and is_id(p.fixed_type))


_REMOVE_FIRST = ("objects", "collections", "meshes", "curves", "armatures", "cameras", "lights", "materials",
                 "node_groups", "textures", "images", "worlds", "actions")


def remove_new_data(before: dict[str, set[int]]) -> None:
    """Remove datablocks created since ``before`` in the collections it holds (the user's own data is untouched);
    library entries last, once nothing of theirs is left."""
    _remove_where(before, lambda name, ptr: ptr not in before[name])


def remove_data(own: dict[str, set[int]]) -> None:
    """Remove the datablocks ``own`` names (pointers per collection, as :func:`snapshot_data` gives them) that still
    exist; library entries last."""
    _remove_where(own, lambda name, ptr: ptr in own[name])


def _remove_where(collections: dict[str, set[int]], pick) -> None:
    order = [n for n in _REMOVE_FIRST if n in collections] + [n for n in collections if n not in _REMOVE_FIRST
                                                              and n != "libraries"]
    for name in order:
        chosen = [d for d in getattr(bpy.data, name) if pick(name, d.as_pointer())]
        if chosen:
            bpy.data.batch_remove(chosen)
    if "libraries" in collections:
        for lib in [lib for lib in bpy.data.libraries if pick("libraries", lib.as_pointer())]:
            bpy.data.libraries.remove(lib)


@contextlib.contextmanager
def _fd_to(fd: int, stream, target: int, flush_after: bool):
    """Point file descriptor ``fd`` (``stream``'s, flushed first) at ``target`` inside the block; a descriptor that
    cannot be duplicated (no console) is left as it is."""
    try:
        stream.flush()
        saved = os.dup(fd)
    except (OSError, ValueError):
        yield
        return
    os.dup2(target, fd)
    try:
        yield
    finally:
        if flush_after:
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        os.dup2(saved, fd)
        os.close(saved)


@contextlib.contextmanager
def quiet_stdout():
    """Silence Blender's C-level progress prints (render 'Fra:' lines, importer timings) on fd 1."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        with _fd_to(1, sys.stdout, devnull, flush_after=False):
            yield
    finally:
        os.close(devnull)


# What Blender's OBJ importer prints on stderr when a texture's folder is missing (the image search): said better
# by the render's own warning about missing textures, so it is dropped.
_IMPORTER_NOISE = re.compile(r"^Failed to open dir \(No such file or directory\):")


@contextlib.contextmanager
def filtered_stderr(drop: re.Pattern = _IMPORTER_NOISE):
    """Hold what is written on fd 2 (Blender's C-level messages, and Python's) and pass it on afterwards without
    the lines ``drop`` matches; all of it is dropped when the block raises (the caller's error says what failed:
    a corrupt USD or Alembic file makes their libraries print their own lines, an add-on importer a traceback)."""
    import tempfile

    with tempfile.TemporaryFile() as held:
        with _fd_to(2, sys.stderr, held.fileno(), flush_after=True):
            yield
        held.seek(0)  # reached only when the block did not raise
        kept = [ln for ln in held.read().decode(errors="replace").splitlines(keepends=True) if not drop.match(ln)]
        if kept:
            sys.stderr.write("".join(kept))
            sys.stderr.flush()


def _import_file(path: Path, frame: list | None = None) -> list[bpy.types.Object]:
    """Import a mesh file with Blender's importers (trimesh for OFF; a .blend's scene appended and reduced to what
    its render shows, its frame put in ``frame``: :func:`_blend_rendered`); return the new objects, without the
    file's lights and cameras."""
    ext = path.suffix.lower()
    check_mesh_file(path)
    before = {o.as_pointer() for o in bpy.data.objects}
    with quiet_stdout(), filtered_stderr():  # what the importers print is dropped when the file is refused
        try:
            scenes = _append_blend_scene(path) if ext == ".blend" else _run_importer(path, ext)
        except RuntimeError as e:
            lines = [ln.strip() for ln in str(e).strip().splitlines() if ln.strip()]
            said = [ln for ln in lines if not ln.startswith("Location:")] or lines or ["the importer failed"]
            said = re.sub(r"^Error:\s*|,? see console for details?\.?$", "", said[-1]) or "the importer failed"
            raise InputError(f"cannot read mesh file {path}: {said}") from None
        new = [o for o in bpy.data.objects if o.as_pointer() not in before]
        if ext == ".blend":
            new = _blend_rendered(new, scenes, frame)
        new = _drop_scene_objects(new)
        meshes = [o for o in new if o.type == "MESH" and _has_faces(o)]
        if not meshes:
            for o in new:
                bpy.data.objects.remove(o)
            raise InputError(f"cannot read mesh file {path}: no faces found (points or lines only, or a corrupt or "
                             "empty file)")
    return new


_ASSIMP_TEXT_EXTS = (".ac", ".ase")  # text-only formats of assimp's, which it reads as UTF-8 only
_OBJ_NONFINITE = re.compile(rb"(?im)^[ \t]*v[ \t][^\n#]*?(?<![a-z0-9_.])[+-]?(nan|inf(inity)?)(?![a-z0-9_])")


def check_mesh_file(path: Path) -> None:
    """Refuse a mesh file with NaN or infinite vertex coordinates, or an OBJ, AC3D or ASE file in UTF-16 (InputError,
    one line).

    Blender's importers silently replace them with 0 (mesh validation), so the object would be
    rendered with vertices the file does not have; trimesh reads the numbers as they are. OBJ is
    scanned as text (fast for big ShapeNet files); OFF is checked where trimesh imports it."""
    ext = path.suffix.lower()
    bad = 0
    if ext == ".obj" or ext in _ASSIMP_TEXT_EXTS:
        try:
            if ext == ".obj":
                data = path.read_bytes()  # all of it: the non-finite scan below
            else:
                with open(path, "rb") as f:
                    data = f.read(4096)
        except OSError:
            return  # the importer reports it
        if data[:2] in (b"\xff\xfe", b"\xfe\xff") or b"\0" in data[:4096]:
            reader = ("Blender's OBJ importer misreads without a word (signs and decimals of numbers are lost)"
                      if ext == ".obj" else f"assimp's {ASSIMP_EXTS[ext]} reader cannot parse")
            raise InputError(f"cannot read mesh file {path}: it is UTF-16 or UTF-32 text (or holds NUL bytes), "
                             f"which {reader}; save it as UTF-8, e.g. iconv -f UTF-16 -t UTF-8 '{path.name}' > "
                             f"'{path.stem}_utf8{path.suffix}'")
        if ext == ".obj":
            bad = len(_OBJ_NONFINITE.findall(data))
    elif ext in (".ply", ".stl", ".glb", ".gltf"):
        import trimesh

        try:
            with quiet_stdout():
                tm = trimesh.load(str(path), force="mesh", process=False)
            verts = np.asarray(tm.vertices, dtype=np.float64)
        except Exception:  # trimesh cannot read it: leave the verdict to Blender's importer
            return
        bad = int((~np.isfinite(verts).all(axis=1)).sum()) if verts.ndim == 2 else 0
    if bad:
        raise InputError(f"mesh file {path} has {bad} vertices that are not finite numbers (NaN or infinite); "
                         "fix or re-export the mesh")


def _has_faces(o: bpy.types.Object) -> bool:
    """Whether a mesh object has faces once evaluated (an Alembic or USD cache fills its mesh in a modifier)."""
    if len(o.data.polygons) > 0:
        return True
    with evaluated_mesh(o.evaluated_get(bpy.context.evaluated_depsgraph_get())) as me:
        return len(me.polygons) > 0


@contextlib.contextmanager
def evaluated_mesh(ev: bpy.types.Object):
    """The mesh of an evaluated object (modifiers applied), freed when the block ends."""
    me = ev.to_mesh()
    try:
        yield me
    finally:
        ev.to_mesh_clear()


def rendered_meshes(objs: list[bpy.types.Object], view_layer: bpy.types.ViewLayer):
    """``(object, evaluated object)`` for each render-visible mesh of ``objs`` (:func:`renders`), ``view_layer``
    updated first."""
    view_layer.update()
    depsgraph = view_layer.depsgraph
    return [(o, o.evaluated_get(depsgraph)) for o in objs if renders(o)]


def _drop_scene_objects(new: list[bpy.types.Object]) -> list[bpy.types.Object]:
    """Remove the lights and cameras a file brought (glTF, FBX): a dataset is lit and seen by the renderer's own
    rig. Their children keep where they are. Returns the objects left."""
    drop = [o for o in new if o.type in ("LIGHT", "CAMERA", "SPEAKER", "LIGHT_PROBE")]
    if not drop:
        return new
    gone = {o.as_pointer() for o in drop}
    kept = [o for o in new if o.as_pointer() not in gone]
    for o in kept:
        if o.parent is not None and o.parent.as_pointer() in gone:
            mw = o.matrix_world.copy()
            o.parent = None
            o.matrix_world = mw
    for o in drop:
        bpy.data.objects.remove(o)
    return kept


@contextlib.contextmanager
def _fbx_lights_readable():
    """Blender 5.0.1's FBX importer fails on any file with a light (it sets ``lamp.cycles.cast_shadow``, which 5.0
    removed: AttributeError). While it runs, a light that fails so is kept as created; the lights are dropped
    after the import anyway (:func:`_drop_scene_objects`)."""
    try:
        from io_scene_fbx import import_fbx
    except ImportError:
        yield
        return
    orig = import_fbx.blen_read_light

    def read_light(*args, **kwargs):
        before = {lt.as_pointer() for lt in bpy.data.lights}
        try:
            return orig(*args, **kwargs)
        except AttributeError:
            made = [lt for lt in bpy.data.lights if lt.as_pointer() not in before]
            if not made:
                raise
            return made[0]

    import_fbx.blen_read_light = read_light
    try:
        yield
    finally:
        import_fbx.blen_read_light = orig


def _known(op, **kwargs) -> dict:
    """The keyword arguments this Blender's operator ``op`` has (the importers gained options between 4.2 and 5.0;
    one it lacks keeps its default there)."""
    names = {p.identifier for p in op.get_rna_type().properties}
    return {k: v for k, v in kwargs.items() if k in names}


def _run_importer(path: Path, ext: str) -> None:
    """Run the Blender importer for ``ext`` (OBJ is read as Y-up, like ShapeNet; trimesh for OFF; assimp for the
    formats Blender has no importer for, ASCII FBX among them). FBX, USD and Alembic use their files' own axes; USD
    is read without its cameras, lights, world or instancing (so every surface is a mesh object the data passes
    see), at its render purpose."""
    if ext == ".obj":
        import tempfile

        with tempfile.TemporaryDirectory(prefix="mrvm_obj_") as tmp:
            bpy.ops.wm.obj_import(filepath=str(_obj_for_blender(path, Path(tmp))), use_split_objects=False,
                                  use_split_groups=False, forward_axis="NEGATIVE_Z", up_axis="Y")
    elif ext == ".ply":
        bpy.ops.wm.ply_import(filepath=str(path))
    elif ext == ".stl":
        bpy.ops.wm.stl_import(filepath=str(path))
    elif ext in (".glb", ".gltf"):
        import addon_utils

        addon_utils.enable("io_scene_gltf2", default_set=False)
        bpy.ops.import_scene.gltf(filepath=str(path))
    elif ext == ".off":
        _import_with_trimesh(path)
    elif ext == ".fbx" and not _binary_fbx(path):  # Blender reads binary FBX only
        _import_with_assimp(path, "ASCII FBX")
    elif ext == ".fbx":
        import addon_utils

        addon_utils.enable("io_scene_fbx", default_set=False)
        with _fbx_lights_readable():
            bpy.ops.import_scene.fbx(filepath=str(path), use_anim=False)
    elif ext in ASSIMP_EXTS:
        _import_with_assimp(path, ASSIMP_EXTS[ext])
    elif ext in (".usd", ".usda", ".usdc", ".usdz"):
        op = bpy.ops.wm.usd_import
        op(**_known(op, filepath=str(path), import_cameras=False, import_lights=False, create_world_material=False,
                    support_scene_instancing=False, import_guide=False, import_proxy=False, import_render=True,
                    import_visible_only=True, set_frame_range=False))
    elif ext == ".abc":
        op = bpy.ops.wm.alembic_import
        op(**_known(op, filepath=str(path), as_background_job=False, set_frame_range=False))


def _append_blend_scene(path: Path) -> list:
    """Append a .blend's scene (the first by name) with its objects; return it (in a list) for
    :func:`_blend_rendered`, which keeps what a render of it shows."""
    if _is_open_file(path):
        raise InputError(f"{path} is the open file: render its objects with the source 'selected'")
    try:
        with bpy.data.libraries.load(str(path), link=False) as (src, dst):
            if not src.scenes:
                raise InputError(f"cannot read {path}: it holds no scene")
            dst.scenes = [sorted(src.scenes)[0]]
    except OSError as e:
        raise InputError(f"cannot read {path}: {str(e).strip() or 'not a .blend file'}") from None
    scenes = [sc for sc in dst.scenes if sc is not None]
    lost = sorted({o.name for sc in scenes for o in sc.objects
                   if o.is_missing or (o.data is not None and o.data.is_missing)})
    if lost:  # Blender renders the rest; a dataset of the rest would not be what the file shows
        libs = sorted({bpy.path.abspath(lib.filepath, library=lib.parent) for lib in bpy.data.libraries
                       if lib.is_missing})
        where = (f"the linked file{'s' if len(libs) > 1 else ''} {', '.join(libs)} cannot be read" if libs else
                 "its linked files no longer hold them")
        n = len(lost)
        raise InputError(f"cannot read {path}: {n} object{'s' if n > 1 else ''} of its scene ({', '.join(lost[:3])}"
                         f"{', ...' if n > 3 else ''}) {'are' if n > 1 else 'is'} linked from another .blend and "
                         f"missing: {where}. "
                         "Relocate the library in Blender (the Outliner's Blender File view) and save, or make "
                         "the objects local")
    return scenes


def _object_ref_props(stack) -> list[tuple]:
    """(item, property name, object) of each object the modifiers or constraints of ``stack`` point to (any Object
    pointer property)."""
    out = []
    for item in stack:
        for prop in item.bl_rna.properties:
            if prop.type == "POINTER" and getattr(prop.fixed_type, "identifier", "") == "Object":
                val = getattr(item, prop.identifier, None)
                if val is not None:
                    out.append((item, prop.identifier, val))
    return out


def _object_refs(stack) -> list:
    """The objects the modifiers or constraints of ``stack`` point to (:func:`_object_ref_props`)."""
    return [val for _, _, val in _object_ref_props(stack)]


_MAX_INSTANCE_DEPTH = 8
"""Collection instances inside instances are realized this deep (Blender's own limit)."""
_CURVE_TYPES = ("CURVE", "SURFACE", "FONT", "META")
"""Object types whose surfaces render but are no meshes (made meshes for the data passes by :func:`_blend_rendered`)."""


def _instanced_objects(coll) -> list:
    """The objects a collection instance of ``coll`` renders: those of it and its child collections, not hidden from
    renders (nor in a collection that is), once each. A view layer's exclusion does not count (an asset collection
    is commonly excluded from the scene and shown through instances)."""
    out: dict[int, object] = {}

    def walk(c):
        if c.hide_render:
            return
        for o in c.objects:
            if not o.hide_render:
                out.setdefault(o.as_pointer(), o)
        for child in c.children:
            walk(child)

    walk(coll)
    return list(out.values())


def _realized_instances(objs: list, shown: set[int], scene) -> list:
    """Objects of their own for what the collection instances among ``objs`` render (an empty instancing a collection:
    a linked asset, kitbashing), so colour, masks and normalization all hold them: a copy of each instanced surface
    at its place in the instance (the instance's matrix, less the collection's instance offset, times the object's),
    sharing its data and materials, with copies of the objects its modifiers use moved alike and hidden from renders
    (a boolean's cutter: the result is the same), and instances within instances. The empties stop instancing (the
    copies render in their place); the shown copies are added to ``shown``. Constraints and animation are not
    copied: each copy keeps the placement its object has in ``scene`` (the appended scene, evaluated here when it
    has instances: the placements a file saves can be older than its objects' locations)."""
    made: list = []
    if not any(o.instance_type == "COLLECTION" and o.instance_collection is not None for o in objs):
        return made
    with bpy.context.temp_override(scene=scene, view_layer=scene.view_layers[0]):
        depsgraph = bpy.context.evaluated_depsgraph_get()

    def world(o) -> Matrix:
        return o.evaluated_get(depsgraph).matrix_world.copy()

    def realize(instancer, parent: Matrix, depth: int) -> None:
        coll = instancer.instance_collection
        if depth >= _MAX_INSTANCE_DEPTH or coll is None:
            return
        place = parent @ world(instancer) @ Matrix.Translation(-coll.instance_offset)
        copies: dict[int, bpy.types.Object] = {}

        def copy_of(o, show: bool):
            c = copies.get(o.as_pointer())
            if c is not None:  # made before as what a modifier uses: shown too where the collection shows it
                if show and c.hide_render:
                    c.hide_render = False
                    shown.add(c.as_pointer())
                return c
            c = copies[o.as_pointer()] = o.copy()
            c.animation_data_clear()
            c.constraints.clear()
            c.parent = None
            c.matrix_world = place @ world(o)
            c.instance_type = "NONE"
            c.hide_render = not show
            if show:
                shown.add(c.as_pointer())
            made.append(c)
            for item, name, dep in _object_ref_props(c.modifiers):
                setattr(item, name, copy_of(dep, False))
            return c

        for o in _instanced_objects(coll):
            if o.type == "MESH" or o.type in _CURVE_TYPES:
                copy_of(o, True)
            if o.instance_type == "COLLECTION":
                realize(o, place, depth + 1)  # its place in this instance is place @ its own

    for o in objs:
        if o.instance_type == "COLLECTION" and o.instance_collection is not None:
            realize(o, Matrix.Identity(4), 0)
            with contextlib.suppress(AttributeError, RuntimeError, TypeError):  # a linked empty cannot be changed
                o.instance_type = "NONE"
    return made


MAX_INSTANCES = 200_000
"""Geometry-nodes, particle and vertex/face instances one object may have: they are made real meshes for the data
passes (:func:`_realized_geometry_instances`); an object with more is refused (a scatter of millions of instances
renders cheaply in Cycles, but as one mesh it would not fit in memory)."""
MAX_INSTANCED_FACES = 20_000_000
"""Faces the instances of one object may add up to once they are made real meshes (as :data:`MAX_INSTANCES`)."""
_MESHLIKE = ("MESH", *_CURVE_TYPES)
"""Types of instanced objects whose surfaces are made meshes (hair curves, point clouds and volumes are not:
they render in the colour only)."""


def _node_instancer(o) -> bool:
    """Whether ``o``'s geometry nodes modifiers may make instances (one of them renders)."""
    return any(m.type == "NODES" and m.show_render and m.node_group is not None for m in o.modifiers)


def _dupli_systems(o) -> list:
    """The particle system modifiers of ``o`` that render instances of an object or collection."""
    out = []
    for m in o.modifiers:
        if m.type == "PARTICLE_SYSTEM" and m.show_render:
            st = m.particle_system.settings
            if st is not None and st.render_type in ("OBJECT", "COLLECTION"):
                out.append(m)
    return out


def _dupli_instancer(o) -> bool:
    """Whether ``o`` instances objects by particles or by its vertices or faces (not geometry nodes)."""
    return o.type == "MESH" and (o.instance_type in ("VERTS", "FACES") or bool(_dupli_systems(o)))


def _scene_depsgraph(scene):
    """``scene``'s evaluated dependency graph (its first view layer's; the context's own where that is it)."""
    vl = bpy.context.view_layer
    if vl is not None and bpy.context.scene == scene:
        return bpy.context.evaluated_depsgraph_get()
    with bpy.context.temp_override(scene=scene, view_layer=scene.view_layers[0]):
        return bpy.context.evaluated_depsgraph_get()


def _instance_key(ob) -> tuple[int, int]:
    """What tells instanced geometry apart: its object (as the file has it) and its evaluated data."""
    return ob.original.as_pointer(), ob.data.as_pointer() if ob.data is not None else 0


def _instance_records(depsgraph, instancers: dict[int, object], keep) -> dict[int, list]:
    """Per instancer (by pointer; ``instancers`` maps the pointer of the object as ``depsgraph`` has it to what the
    error messages name): its instances ``keep(instancer, instance)`` takes, as (:func:`_instance_key`, world
    matrix), with the instance count and face count checked against :data:`MAX_INSTANCES` and
    :data:`MAX_INSTANCED_FACES`. (An instance's object lives only while ``object_instances`` is iterated.)"""
    out: dict[int, list] = {p: [] for p in instancers}
    faces: dict[int, int] = {p: 0 for p in instancers}
    per_data: dict[tuple[int, int], int] = {}
    for inst in depsgraph.object_instances:
        if not inst.is_instance or inst.parent is None:
            continue
        p = inst.parent.original.as_pointer()
        if p not in out:
            continue
        ob = inst.object
        if ob.type not in _MESHLIKE or not keep(instancers[p], inst):
            continue
        key = _instance_key(ob)
        out[p].append((key, inst.matrix_world.copy()))
        if key not in per_data:
            per_data[key] = len(ob.data.polygons) if ob.type == "MESH" and ob.data is not None else 0
        faces[p] += per_data[key]
    for p, found in out.items():
        name = instancers[p].name
        if len(found) > MAX_INSTANCES:
            raise InputError(f"object {name!r} has {len(found)} instances (geometry nodes, particles or vertex/face "
                             f"instancing), more than the {MAX_INSTANCES} that are made meshes for the masks and "
                             "depth; render fewer (a lower density or count), or realize and decimate them")
        if faces[p] > MAX_INSTANCED_FACES:
            raise InputError(f"object {name!r} has {len(found)} instances of {faces[p]} faces in all, more than the "
                             f"{MAX_INSTANCED_FACES} that are made meshes for the masks and depth; render fewer or "
                             "simpler instances")
    return out


def _instanced_meshes(depsgraph, keys: set) -> dict:
    """For each :func:`_instance_key` of ``keys``: (a new mesh of that instanced geometry, with its layers, the
    materials its object renders it with), or None where it has no faces. The caller removes the meshes."""
    out: dict = {}
    for inst in depsgraph.object_instances:
        if not inst.is_instance or len(out) == len(keys):
            continue
        ob = inst.object
        if ob.type not in _MESHLIKE:
            continue
        key = _instance_key(ob)
        if key not in keys or key in out:
            continue
        try:
            me = bpy.data.meshes.new_from_object(ob, preserve_all_data_layers=True, depsgraph=depsgraph)
        except RuntimeError:  # nothing to make a mesh of (an empty curve)
            out[key] = None
            continue
        if len(me.polygons) == 0:
            bpy.data.meshes.remove(me)
            out[key] = None
            continue
        slots = [s.material for s in ob.material_slots]  # evaluated copies: their originals are kept
        mats = slots if slots and len(slots) >= len(me.materials) else list(me.materials)
        out[key] = (me, [m.original if m is not None else None for m in mats])
    return out


def _realize_node_group():
    """A geometry nodes group that realizes every instance of its input (made for the render; removed with it)."""
    ng = bpy.data.node_groups.new("MRVM_realize_instances", "GeometryNodeTree")
    ng.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    ng.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = ng.nodes.new("NodeGroupInput"), ng.nodes.new("NodeGroupOutput")
    realize = ng.nodes.new("GeometryNodeRealizeInstances")
    ng.links.new(gin.outputs[0], realize.inputs[0])
    ng.links.new(realize.outputs[0], gout.inputs[0])
    return ng


def _realize_node_instances(objs: list, scene) -> bool:
    """Make the geometry nodes instances of ``objs`` (our own objects, evaluated in ``scene``: Instance on Points, a
    scatter) real geometry: a modifier realizing them is added at the end of each such object's stack, so its
    evaluated mesh, which the data passes and the bounds read, is what Cycles renders (the instances' materials, UV
    maps and attributes come along). Returns whether any object changed."""
    cands = {o.as_pointer(): o for o in objs if o.type in _MESHLIKE and not o.hide_render and _node_instancer(o)}
    if not cands:
        return False
    depsgraph = _scene_depsgraph(scene)
    found = _instance_records(depsgraph, cands, lambda o, inst: inst.particle_system is None)
    group = None
    for p, insts in found.items():
        if not insts:
            continue
        o = cands[p]
        if group is None:
            group = _realize_node_group()
        mod = o.modifiers.new("MRVM_realize_instances", "NODES")
        mod.node_group = group
    if group is not None:
        _scene_depsgraph(scene)  # evaluated again: what reads the objects next (a curve made a mesh) sees it
    return group is not None


_ATTRIBUTE_FIELDS = {"FLOAT": ("value", 1, np.float32), "INT": ("value", 1, np.int32), "BOOLEAN": ("value", 1, bool),
                     "FLOAT_VECTOR": ("vector", 3, np.float32), "FLOAT_COLOR": ("color", 4, np.float32),
                     "BYTE_COLOR": ("color", 4, np.float32), "FLOAT2": ("vector", 2, np.float32),
                     "INT8": ("value", 1, np.int32), "INT16_2D": ("value", 2, np.int32),
                     "INT32_2D": ("value", 2, np.int32), "QUATERNION": ("value", 4, np.float32),
                     "FLOAT4X4": ("value", 16, np.float32)}
"""How :func:`_mesh_arrays` reads each kind of mesh attribute: (field, components, dtype)."""


def _mesh_arrays(me) -> dict:
    """A mesh's geometry and attributes as arrays (:func:`_joined_mesh` puts copies of it together)."""
    def get(seq, name, n, dtype, width=1):
        arr = np.empty(n * width, dtype=dtype)
        if n:
            seq.foreach_get(name, arr)
        return arr.reshape(n, width) if width > 1 else arr

    nv, ne, nl, nf = len(me.vertices), len(me.edges), len(me.loops), len(me.polygons)
    sizes = {"POINT": nv, "EDGE": ne, "FACE": nf, "CORNER": nl}
    attrs = {}
    for a in me.attributes:
        if a.name.startswith(".") or a.name in ("position", "material_index") or a.domain not in sizes \
                or a.data_type not in _ATTRIBUTE_FIELDS:
            continue
        fld, width, dtype = _ATTRIBUTE_FIELDS[a.data_type]
        attrs[a.name] = (a.domain, a.data_type, get(a.data, fld, sizes[a.domain], dtype, width))
    uv_render = [u.name for u in me.uv_layers if u.active_render]
    colours = me.color_attributes
    return {"co": get(me.vertices, "co", nv, np.float64, 3), "edges": get(me.edges, "vertices", ne, np.int64, 2),
            "corner_vert": get(me.loops, "vertex_index", nl, np.int64),
            "corner_edge": get(me.loops, "edge_index", nl, np.int64),
            "loop_start": get(me.polygons, "loop_start", nf, np.int64),
            "loop_total": get(me.polygons, "loop_total", nf, np.int64),
            "material_index": get(me.polygons, "material_index", nf, np.int64), "attrs": attrs,
            "uv_active": me.uv_layers.active.name if me.uv_layers.active is not None else None,
            "uv_render": uv_render[0] if uv_render else None,
            "colour_active": colours.active_color_name if len(colours) else None,
            "colour_render": colours.default_color_name if len(colours) else None}


def _joined_mesh(name: str, groups: list[tuple[dict, list, np.ndarray]]):
    """One mesh of many placed copies of meshes: ``groups`` holds per mesh its arrays (:func:`_mesh_arrays`), its
    materials (the instanced object's slots) and the world matrices of its copies (K, 4, 4). Materials are joined
    into one slot list (a mesh without any gets a slot of its own with none), attributes of one name are joined
    (zero where a mesh has none), and a mirrored copy's faces are turned round so their normals face out as
    Cycles shades the instance."""
    mats: list = []
    slot_of: dict[int, int] = {}

    def slot(m) -> int:
        key = m.as_pointer() if m is not None else 0
        if key not in slot_of:
            slot_of[key] = len(mats)
            mats.append(m)
        return slot_of[key]

    kinds: dict[str, tuple[str, str]] = {}
    for arrays, _, _ in groups:
        for aname, (domain, dtype, _) in arrays["attrs"].items():
            kinds.setdefault(aname, (domain, dtype))
    co, edges, cvert, cedge, lstart, mindex = [], [], [], [], [], []
    attrs: dict[str, list] = {aname: [] for aname in kinds}
    nv = ne = nl = 0
    for arrays, materials, mw in groups:
        k = len(mw)
        v, e, lo = len(arrays["co"]), len(arrays["edges"]), len(arrays["corner_vert"])
        f = len(arrays["loop_start"])
        lin, move = mw[:, :3, :3], mw[:, :3, 3]
        co.append((np.einsum("kij,vj->kvi", lin, arrays["co"]) + move[:, None, :]).reshape(-1, 3))
        mirrored = np.linalg.det(lin) < 0
        # a face's corners in reverse order (for mirrored copies): corner j takes corner n-1-j's vertex and the edge
        # of corner n-2-j (the edge from corner j's vertex on to the next one)
        start = np.repeat(arrays["loop_start"], arrays["loop_total"])
        n = np.repeat(arrays["loop_total"], arrays["loop_total"])
        j = np.arange(lo) - start
        rev_v, rev_e = start + (n - 1 - j), start + (n - 2 - j) % np.maximum(n, 1)
        ident = np.arange(lo)
        pick_v = np.where(mirrored[:, None], rev_v[None, :], ident[None, :])  # (K, L)
        pick_e = np.where(mirrored[:, None], rev_e[None, :], ident[None, :])
        vofs = nv + v * np.arange(k)[:, None]
        eofs = ne + e * np.arange(k)[:, None]
        edges.append((arrays["edges"][None, :, :] + vofs[:, :, None]).reshape(-1, 2))
        cvert.append((arrays["corner_vert"][pick_v] + vofs).ravel())
        cedge.append((arrays["corner_edge"][pick_e] + eofs).ravel())
        lstart.append((arrays["loop_start"][None, :] + nl + lo * np.arange(k)[:, None]).ravel())
        local = [slot(m) for m in materials] or [slot(None)]
        mi = np.asarray(local, dtype=np.int64)[np.clip(arrays["material_index"], 0, len(local) - 1)]
        mindex.append(np.tile(mi, k))
        sizes = {"POINT": v, "EDGE": e, "FACE": f, "CORNER": lo}
        for aname, (domain, dtype) in kinds.items():
            fld, width, np_type = _ATTRIBUTE_FIELDS[dtype]
            have = arrays["attrs"].get(aname)
            if have is None or have[:2] != (domain, dtype):
                attrs[aname].append(np.zeros((k * sizes[domain], width), dtype=np_type))
                continue
            vals = have[2].reshape(sizes[domain], width)
            if domain == "CORNER":
                out = vals[pick_v]  # (K, L, width)
            else:
                out = np.broadcast_to(vals, (k, *vals.shape))
            if aname == "custom_normal" and dtype == "FLOAT_VECTOR":  # free normals turn with the copy
                nrm = np.linalg.inv(lin).transpose(0, 2, 1)
                out = np.einsum("kij,knj->kni", nrm, out)
                out /= np.maximum(np.linalg.norm(out, axis=2, keepdims=True), 1e-12)
            attrs[aname].append(np.asarray(out, dtype=np_type).reshape(-1, width))
        nv, ne, nl = nv + k * v, ne + k * e, nl + k * lo

    me = bpy.data.meshes.new(name)
    cat = (lambda parts, dtype: np.concatenate(parts).astype(dtype, copy=False).ravel())
    me.vertices.add(nv)
    me.vertices.foreach_set("co", cat(co, np.float32))
    me.edges.add(ne)
    me.edges.foreach_set("vertices", cat(edges, np.int32))
    me.loops.add(nl)
    me.loops.foreach_set("vertex_index", cat(cvert, np.int32))
    me.loops.foreach_set("edge_index", cat(cedge, np.int32))
    starts = cat(lstart, np.int32)
    me.polygons.add(len(starts))
    me.polygons.foreach_set("loop_start", starts)
    me.polygons.foreach_set("material_index", cat(mindex, np.int32))
    for aname, (domain, dtype) in kinds.items():
        fld, _, np_type = _ATTRIBUTE_FIELDS[dtype]
        a = me.attributes.get(aname) or me.attributes.new(aname, dtype, domain)
        a.data.foreach_set(fld, cat(attrs[aname], np_type))
    for m in mats:
        me.materials.append(m)
    first = groups[0][0]
    for key, flag in (("uv_active", "active"), ("uv_render", "active_render")):
        if first[key] is not None and first[key] in me.uv_layers:
            setattr(me.uv_layers[first[key]], flag, True)
    cols = me.color_attributes
    if first["colour_active"] and first["colour_active"] in cols:
        cols.active_color_name = first["colour_active"]
    if first["colour_render"] and first["colour_render"] in cols:
        cols.default_color_name = first["colour_render"]
    me.update()
    return me


def _baked_instances(name: str, insts: list, depsgraph):
    """A mesh object holding every instance of ``insts`` ((:func:`_instance_key`, world matrix) pairs: an
    instancer's particles or vertex/face instances) at its place, in world space; ``None`` when they hold no
    faces. Each instanced geometry's mesh is made once, with its materials (:func:`_instanced_meshes`)."""
    by_source: dict[tuple[int, int], list] = {}
    for key, mw in insts:
        by_source.setdefault(key, []).append(mw)
    meshes = _instanced_meshes(depsgraph, set(by_source))
    try:
        groups = [(_mesh_arrays(meshes[key][0]), meshes[key][1], np.array([np.array(m) for m in mws]))
                  for key, mws in by_source.items() if meshes.get(key) is not None]
    finally:
        for made in meshes.values():
            if made is not None:
                bpy.data.meshes.remove(made[0])
    if not groups:
        return None
    return bpy.data.objects.new(name + "_instances", _joined_mesh(name + "_instances", groups))


def _bake_dupli_instances(pairs: list[tuple[object, object]], scene) -> list:
    """Real meshes for the particle and vertex/face instances of objects: ``pairs`` holds (the instancer as it is
    in ``scene``, our object that renders in its place: itself for a .blend's, a copy for a selected one). Each
    instancer's instances (read from ``scene``'s evaluation: their meshes, materials and world places) are joined
    into one new mesh object (:func:`_baked_instances`), and our object stops instancing: its instancing particle
    systems stop rendering, vertex/face instancing is turned off, and the object itself is hidden from renders
    where its instancer is not shown in renders (``show_instancer_for_render``). Returns the new objects, the
    children the instancing placed (now hidden from renders: they render only as instances) left to the caller."""
    pairs = [(src, ours) for src, ours in pairs if _dupli_instancer(src) and not ours.hide_render]
    if not pairs:
        return []
    depsgraph = _scene_depsgraph(scene)
    children = {src.as_pointer(): {c.as_pointer() for c in src.children} for src, _ in pairs}

    def keep(src, inst) -> bool:
        if inst.particle_system is not None:
            return inst.particle_system.settings.render_type in ("OBJECT", "COLLECTION")
        return src.instance_type in ("VERTS", "FACES") and \
            inst.object.original.as_pointer() in children[src.as_pointer()]

    found = _instance_records(depsgraph, {src.as_pointer(): src for src, _ in pairs}, keep)
    made = []
    for src, ours in pairs:
        insts = found[src.as_pointer()]
        baked = _baked_instances(src.name, insts, depsgraph) if insts else None
        if baked is not None:
            made.append(baked)
        for m in _dupli_systems(ours):
            m.show_render = m.show_viewport = False
        if ours.instance_type in ("VERTS", "FACES"):
            ours.instance_type = "NONE"
        if not src.show_instancer_for_render:
            ours.hide_render = True
    return made


@contextlib.contextmanager
def _particles_as_rendered(objs: list):
    """Inside the block, the particle systems of ``objs`` that instance objects show as many particles and children
    as a render does (the evaluation read here is a viewport one, which shows the settings' display percentage and
    viewport child count); the settings are set back after (they may be the user's own)."""
    saved = []
    seen: set[int] = set()
    for o in objs:
        for m in _dupli_systems(o):
            st = m.particle_system.settings
            if st.as_pointer() in seen:
                continue
            seen.add(st.as_pointer())
            was = (st.display_percentage, st.child_percent)
            if was != (100, st.rendered_child_count):
                saved.append((st, was))
                st.display_percentage, st.child_percent = 100, st.rendered_child_count
    try:
        yield
    finally:
        for st, (shown, children) in saved:
            st.display_percentage, st.child_percent = shown, children


def _realized_geometry_instances(objs: list, shown: set[int], scene) -> list:
    """Real meshes for what the geometry nodes, particle and vertex/face instancing of the shown objects of ``objs``
    (a .blend's, in its appended ``scene``) render: geometry nodes instances are realized on the object itself
    (:func:`_realize_node_instances`), particle and vertex/face instances are joined into a new object per
    instancer (:func:`_bake_dupli_instances`), which is returned and added to ``shown``; the children that vertex or
    face instancing placed are hidden from renders (Blender renders them only as instances). Objects outside
    ``scene`` (collection instances made objects) are linked to it for the evaluation."""
    mine = [o for o in objs if o.as_pointer() in shown]
    if not any(_node_instancer(o) or _dupli_instancer(o) for o in mine):
        return []
    inside = {o.as_pointer() for o in scene.objects}
    extra = [o for o in objs if o.as_pointer() not in inside]
    for o in extra:
        scene.collection.objects.link(o)
    try:
        for o in mine:
            if o.type == "MESH":
                render_evaluation(o)
        _realize_node_instances(mine, scene)
        placed = [c for o in mine if o.type == "MESH" and o.instance_type in ("VERTS", "FACES") for c in o.children]
        with _particles_as_rendered(mine):
            made = _bake_dupli_instances([(o, o) for o in mine], scene)
    finally:
        for o in extra:
            scene.collection.objects.unlink(o)
    for c in placed:
        c.hide_render = True
    shown.update(o.as_pointer() for o in made)
    return made


def _blend_rendered(new: list[bpy.types.Object], scenes: list, frame: list | None = None) -> list[bpy.types.Object]:
    """Of the objects a .blend's scene brought, those its render shows (not excluded from its view layer, no
    collection or object hidden from renders), as static meshes of what its render shows at the scene's frame
    (:func:`_bake_evaluated`: modifiers at their render settings, armatures, constraints, drivers and animation
    evaluated and applied; curves, surfaces, text and metaballs made meshes, at their render resolution; objects
    hidden in viewports evaluated too); the scene itself removed. Objects left out (an armature, a boolean's hidden
    cutter, a constraint's target: what the shown ones used) stay in the file's data unlinked. Collection instances
    are made objects of their own (:func:`_realized_instances`); geometry nodes, particle and vertex/face instances
    are made real meshes (:func:`_realized_geometry_instances`). What renders but is no surface (hair curves, a
    volume) is kept as it is, with the parents and objects it uses. ``frame`` (when given) gets the scene's frame
    and subframe: the render's scene takes them (materials animated)."""
    shown: set[int] = set()
    for sc in scenes:
        shown |= render_shown(sc.view_layers[0])
    keep = [o for o in new if o.as_pointer() in shown]
    if scenes:  # (one: _append_blend_scene's)
        keep += _realized_instances(keep, shown, scenes[0])
        keep += _realized_geometry_instances(keep, shown, scenes[0])
    if not scenes:
        return keep
    scene = scenes[0]  # (one: _append_blend_scene's)
    if frame is not None:
        frame[:] = [scene.frame_current, scene.frame_subframe]
    drawn = [o for o in keep if o.as_pointer() in shown and (o.type == "MESH" or o.type in _CURVE_TYPES)]
    for o in drawn:
        render_evaluation(o)
        _render_resolution(o)
    for c in _scene_collections(scene):  # disabled in viewports: the (viewport) evaluation would leave them out
        with contextlib.suppress(AttributeError, RuntimeError, TypeError):  # a linked collection cannot be changed
            c.hide_viewport = False
    inside = {o.as_pointer() for o in scene.objects}
    extra = [o for o in drawn if o.as_pointer() not in inside]  # collection instances made objects
    for o in extra:
        scene.collection.objects.link(o)
    try:
        out = _bake_evaluated(drawn, _scene_depsgraph(scene))
    finally:
        for o in extra:
            scene.collection.objects.unlink(o)
    ptrs = {o.as_pointer() for o in keep}
    appended = {o.as_pointer() for o in new}
    baked = {o.as_pointer() for o in drawn}
    others = [o for o in keep if o.as_pointer() not in baked]  # what renders but is no surface of the data passes (hair curves)
    todo = list(others)
    while todo:  # their parents, and the objects their modifiers and constraints use
        o = todo.pop()
        for dep in [o.parent, *_object_refs(o.modifiers), *_object_refs(o.constraints)]:
            if dep is not None and dep.as_pointer() in appended and dep.as_pointer() not in ptrs:
                dep.hide_render = dep.hide_render or dep.as_pointer() not in shown  # moved along, never drawn
                others.append(dep)
                ptrs.add(dep.as_pointer())
                todo.append(dep)
    for sc in scenes:
        bpy.data.scenes.remove(sc)
    return out + others


def render_shown(view_layer) -> set[int]:
    """Pointers of the objects a render of ``view_layer`` shows: in no collection excluded from it or hidden from
    renders, and not hidden from renders themselves."""
    shown: set[int] = set()

    def walk(lc):
        if lc.exclude or lc.collection.hide_render:
            return
        shown.update(o.as_pointer() for o in lc.collection.objects if not o.hide_render)
        for child in lc.children:
            walk(child)

    walk(view_layer.layer_collection)
    return shown


def _scene_collections(scene) -> list:
    out, todo = [], list(scene.collection.children)
    while todo:
        c = todo.pop()
        out.append(c)
        todo.extend(c.children)
    return out


def _render_resolution(o) -> None:
    """Make a private curve, surface, text or metaball evaluate at its render resolution (its data is private: a
    .blend's appended copy)."""
    d = o.data
    with contextlib.suppress(AttributeError, RuntimeError, TypeError):  # linked data cannot be changed
        if o.type == "META" and d.resolution != d.render_resolution:
            d.resolution = d.render_resolution
        elif o.type in ("CURVE", "SURFACE", "FONT"):
            if d.render_resolution_u and d.resolution_u != d.render_resolution_u:
                d.resolution_u = d.render_resolution_u
            if o.type == "SURFACE" and d.render_resolution_v and d.resolution_v != d.render_resolution_v:
                d.resolution_v = d.render_resolution_v


def _bake_evaluated(objs: list, depsgraph) -> list:
    """Make ``objs`` (private objects, made to evaluate as a render does: :func:`render_evaluation`) static meshes of
    what ``depsgraph`` evaluates of them at its frame: each mesh object gets a new mesh of its evaluated geometry
    (modifiers, shape keys, armatures, geometry nodes; its UV maps, colour attributes and other attributes, part ids
    among them, kept) and its evaluated world matrix, and loses its modifiers, constraints, parent, animation and
    drivers; a curve, surface, text or metaball is replaced by a new mesh object made so (a metaball family's
    surface is its basis's). Nothing the render shows then depends on other objects or on the frame, so normalizing
    (:func:`apply_world_transform`) moves every surface alike and Cycles renders what the data passes rasterize.
    Curves and metaballs that make no faces are left out. Returns the objects."""
    found = []
    for o in objs:  # all read first: changing an object tags the evaluation as outdated
        ev = o.evaluated_get(depsgraph)
        try:
            me = bpy.data.meshes.new_from_object(ev, preserve_all_data_layers=True, depsgraph=depsgraph)
        except RuntimeError:  # nothing to make a mesh of (an empty curve)
            me = None
        found.append((o, me, ev.matrix_world.copy()))
    out = []
    for o, me, mw in found:
        if o.type != "MESH":
            if me is None or len(me.polygons) == 0:
                if me is not None:
                    bpy.data.meshes.remove(me)
                continue
            mo = bpy.data.objects.new(o.name + "_mesh", me)
            for k in ("hide_render", "visible_camera", "pass_index", "color"):
                setattr(mo, k, getattr(o, k))
            out.append(mo)
        else:
            if me is None:
                me = bpy.data.meshes.new(o.data.name)
            mo = o
            mo.modifiers.clear()
            mo.constraints.clear()
            mo.animation_data_clear()
            mo.parent = None
            mo.data = me
            mo.instance_type = "NONE"
            out.append(mo)
        mo.matrix_world = mw
    return out


def _binary_fbx(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(21) == b"Kaydara FBX Binary  \x00"
    except OSError:
        return True  # Blender's importer reports it


# assimp's scenes are Y-up (its loaders turn a COLLADA Z_UP asset, an FBX's axes and 3DS's, ASE's and DXF's Z-up
# that way; AC3D, LightWave, MilkShape, DirectX and X3D are Y-up formats); Blender is Z-up: x, y, z -> x, -z, y, as
# Blender's glTF importer turns glTF's Y-up. 3MF and AMF are Z-up formats whose coordinates assimp keeps as written.
_Y_UP_TO_Z_UP = Matrix(((1, 0, 0, 0), (0, 0, -1, 0), (0, 1, 0, 0), (0, 0, 0, 1)))
_ASSIMP_TO_Z_UP = {".3mf": Matrix.Identity(4), ".amf": Matrix.Identity(4)}


def _assimp_scene(path: Path, fmt: str):
    """assimp-py's scene of ``path`` (triangles; a file that mixes lines or points with faces is read from a copy
    without them: :data:`_FACES_ONLY`). An InputError when assimp-py is missing or the file holds no faces; a
    :class:`_NoMesh` with assimp's reason when it cannot read it. The last file's scene is kept while its size and
    time are unchanged: the resume hash (:func:`linked_files`) and the import that follows read it once."""
    try:
        st = Path(path).stat()
    except OSError:
        st = None
    key = (str(path), st.st_size, st.st_mtime_ns) if st is not None else None
    if key is not None and _LAST_SCENE and _LAST_SCENE[0] == key:
        return _LAST_SCENE[1]
    scene = _read_assimp_scene(path, fmt)
    _LAST_SCENE[:] = [key, scene] if key is not None else []
    return scene


_LAST_SCENE: list = []  # [(path, size, mtime), scene] of :func:`_assimp_scene`'s last file


def _read_assimp_scene(path: Path, fmt: str):
    try:
        import assimp_py as A
    except ImportError:
        raise InputError(f"cannot read mesh file {path}: Blender has no {fmt} importer, and assimp-py, which reads "
                         f"it, is not installed in this Python (pip install {_ASSIMP_PIN}); or {_EXPORT}") from None
    flags = (A.Process_Triangulate | A.Process_SortByPType | A.Process_JoinIdenticalVertices
             | A.Process_TransformUVCoords  # a material's UV scale, offset and rotation, baked into the UVs
             | A.Process_ValidateDataStructure)
    try:
        return _assimp_import(A, path, flags)
    except FileNotFoundError:
        raise InputError(f"cannot read mesh file {path}: no such file") from None
    except ValueError:  # assimp-py takes triangles only: its loader kept lines or points
        if path.suffix.lower() not in _FACES_ONLY:
            raise InputError(f"cannot read mesh file {path}: it holds lines or points, which assimp-py does not read "
                             f"({fmt} files of faces only are read); {_EXPORT}") from None
    import tempfile

    with tempfile.TemporaryDirectory(prefix="mrvm_faces_") as tmp:  # lines render nothing: read it without them
        copy = Path(tmp) / path.name
        _FACES_ONLY[path.suffix.lower()](path, copy)
        try:
            return _assimp_import(A, copy, flags)
        except (ValueError, _NoMesh):
            raise InputError(f"cannot read mesh file {path}: it holds lines or points only, no faces") from None


def _assimp_texture(d: dict, folder: Path) -> str | None:
    """The diffuse texture an assimp material names (``*N``: embedded), as a file name to find beside the mesh;
    of X3D's list of URLs to try in turn ("a.png" "a.gif", which assimp hands over as a.png""a.gif), the first
    that is there."""
    textures = d.get("TEXTURES") or {}
    names = textures.get(1) or textures.get(12) or []  # aiTextureType_DIFFUSE, aiTextureType_BASE_COLOR
    if not names:
        return None
    name = str(names[0])
    if '"' in name:
        urls = [u.strip() for u in name.split('"') if u.strip()] or [name]
        name = next((u for u in urls if find_beside(folder, u) is not None), urls[0])
    return name


def _assimp_texture_names(path: Path) -> list[str]:
    """The texture files a file read with assimp names (not embedded ones), once each in order; [] when assimp-py
    cannot read it (the import reports that)."""
    try:
        scene = _assimp_scene(path, ASSIMP_EXTS.get(path.suffix.lower(), "ASCII FBX"))
    except (InputError, RuntimeError):
        return []
    names = (_assimp_texture(dict(m), path.parent) for m in scene.materials)
    return list(dict.fromkeys(n for n in names if n and not n.startswith("*")))


def _import_with_assimp(path: Path, fmt: str) -> None:
    """Read a file of a format Blender cannot import with assimp (assimp-py): every node's triangle meshes (points
    and lines are dropped) become mesh objects at the node's world transform, with the file's normals, first UV
    map and per-vertex colours; a material becomes a Principled BSDF of its diffuse colour, opacity and diffuse
    texture (looked for beside the file as :func:`find_beside` does; one that is not there is dropped with a warning
    by :func:`drop_missing_textures`). The file's cameras and lights are not read."""
    scene = _assimp_scene(path, fmt)
    materials: dict[int, bpy.types.Material] = {}
    meshes: dict[int, bpy.types.Mesh | None] = {}
    coll = bpy.context.scene.collection

    def material(i: int) -> bpy.types.Material:
        if i not in materials:
            materials[i] = _assimp_material(scene.materials[i] if 0 <= i < len(scene.materials) else {}, path)
        return materials[i]

    def mesh(i: int) -> bpy.types.Mesh | None:
        if i not in meshes:
            me = meshes[i] = _assimp_mesh(scene.meshes[i])
            if me is not None:
                mat = material(scene.meshes[i].material_index)
                if "Col" in me.color_attributes and not any(n.type == "TEX_IMAGE" for n in mat.node_tree.nodes):
                    mat = mat.copy()  # its vertex colours, as the material's diffuse colour
                    node = mat.node_tree.nodes.new("ShaderNodeVertexColor")
                    node.layer_name = "Col"
                    bsdf = next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
                    mat.node_tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
                me.materials.append(mat)
        return meshes[i]

    todo = [(scene.root_node, Matrix.Identity(4))]
    while todo:
        node, parent = todo.pop()
        world = parent @ Matrix([list(r) for r in node.transformation])
        for i in node.mesh_indices:
            me = mesh(i)
            if me is not None:
                obj = bpy.data.objects.new(node.name or me.name, me)
                obj.matrix_world = _ASSIMP_TO_Z_UP.get(path.suffix.lower(), _Y_UP_TO_Z_UP) @ world
                coll.objects.link(obj)
        todo.extend((c, world) for c in node.children)


class _NoMesh(RuntimeError):
    """assimp's loader failed: its reason, or one for a scene without meshes, where assimp gives none (the caller of
    :func:`_import_with_assimp` reports it as the file's)."""


def _assimp_import(A, path: Path, flags: int):
    try:
        return A.import_file(str(path), flags)
    except RuntimeError as e:
        said = re.sub(r"^Assimp error loading '[^']*':\s*", "", str(e)).strip()
        raise _NoMesh(said or "assimp found no mesh in it (cameras or lights only, or a file it cannot parse)") \
            from None


def _xml_without(*tags: str):
    """A function that copies an XML file without the elements ``tags`` (with what is inside them)."""
    pattern = re.compile(rb"<(" + "|".join(tags).encode() + rb")\b[^>]*?(?:/>|>.*?</\1\s*>)", re.S)

    def copy(path: Path, out: Path) -> None:
        out.write_bytes(pattern.sub(b"", path.read_bytes()))
    return copy


def _dxf_faces_only(path: Path, out: Path) -> None:
    """A copy of a DXF file without its LINE, 3DLINE and POINT entities, which CAD drawings mix with faces."""
    pairs = path.read_bytes().splitlines(keepends=True)
    keep: list[bytes] = []
    drop = False
    for i in range(0, len(pairs) - 1, 2):
        code, value = pairs[i], pairs[i + 1]
        if code.strip() == b"0":
            drop = value.strip() in (b"LINE", b"3DLINE", b"POINT")
        if not drop:
            keep += (code, value)
    out.write_bytes(b"".join(keep + pairs[len(pairs) - len(pairs) % 2:]))


def _ac3d_faces_only(path: Path, out: Path) -> None:
    """A copy of an AC3D file without its line and closed-line surfaces (``SURF`` types 1 and 2; FlightGear's models
    draw wires and edges with them), each object's ``numsurf`` counting the polygons kept, and without the vertices
    of an object left with none (assimp reads those as points)."""
    src = path.read_text(encoding="utf-8", errors="surrogateescape").splitlines()
    dst: list[str] = []
    numvert = -1  # where the current object's numvert line is in dst
    i = 0
    while i < len(src):
        line = src[i]
        word = line.split(None, 1)[0] if line.strip() else ""
        if word == "numvert":
            numvert = len(dst)
        if word == "data" and len(line.split()) > 1 and line.split()[1].isdigit():  # free text of that many bytes
            n, j = int(line.split()[1]), i + 1
            taken = 0
            while j < len(src) and taken < n:
                taken += len(src[j]) + 1
                j += 1
            dst += src[i:j]
            i = j
            continue
        if word != "numsurf":
            dst.append(line)
            i += 1
            continue
        count, i = int(line.split()[1]), i + 1
        kept: list[str] = []
        n_kept = 0
        for _ in range(count):
            surf: list[str] = []
            while i < len(src) and not src[i].lstrip().startswith("refs"):
                surf.append(src[i])
                i += 1
            if i >= len(src):
                raise InputError(f"cannot read mesh file {path}: a surface without its refs (a damaged AC3D file)")
            refs = int(src[i].split()[1])
            surf += src[i:i + 1 + refs]
            i += 1 + refs
            kind = int(surf[0].split()[1], 0) & 0xF if surf[0].lstrip().startswith("SURF") else 0
            if kind == 0:  # a polygon
                kept += surf
                n_kept += 1
        if n_kept == 0 and numvert >= 0:  # points: render nothing either
            dst[numvert:] = ["numvert 0"]
        dst.append(f"numsurf {n_kept}")
        dst += kept
    out.write_text("\n".join(dst) + "\n", encoding="utf-8", errors="surrogateescape")


# Readers of a copy without the lines and points of a file that mixes them with faces: assimp-py cannot hand lines
# over, and they render nothing (SketchUp's and Google Earth's COLLADA edges, FlightGear's AC3D wires, CAD drawings)
_FACES_ONLY = {".dae": _xml_without("lines", "linestrips"), ".ac": _ac3d_faces_only,
               ".x3d": _xml_without("IndexedLineSet", "LineSet", "PointSet"), ".dxf": _dxf_faces_only}


def _assimp_mesh(m) -> bpy.types.Mesh | None:
    """A Blender mesh of an assimp mesh's triangles (None for a points or lines mesh)."""
    verts = np.frombuffer(m.vertices, dtype=np.float32).reshape(-1, 3)
    if m.num_faces == 0 or len(m.indices) != 3 * m.num_faces:  # SortByPType: one primitive kind a mesh
        return None
    tris = np.frombuffer(m.indices, dtype=np.uint32).reshape(-1, 3)
    me = bpy.data.meshes.new(m.name or "mesh")
    me.vertices.add(len(verts))
    me.vertices.foreach_set("co", verts.ravel())
    me.loops.add(tris.size)
    me.loops.foreach_set("vertex_index", tris.ravel().astype(np.int32))
    me.polygons.add(len(tris))
    me.polygons.foreach_set("loop_start", np.arange(0, tris.size, 3, dtype=np.int32))
    corner = tris.ravel()
    if m.texcoords and m.texcoords[0] is not None and len(m.texcoords[0]):
        uv = np.frombuffer(m.texcoords[0], dtype=np.float32).reshape(len(verts), -1)[:, :2]
        me.uv_layers.new(name="UVMap").data.foreach_set("uv", uv[corner].ravel())
    if m.colors and m.colors[0] is not None and len(m.colors[0]):
        col = np.frombuffer(m.colors[0], dtype=np.float32).reshape(len(verts), 4)
        attr = me.color_attributes.new("Col", "FLOAT_COLOR", "POINT")
        attr.data.foreach_set("color", col.ravel())
    me.update(calc_edges=True)
    me.validate(clean_customdata=False)
    if m.normals is not None and len(m.normals) == len(m.vertices) and len(me.vertices) == len(verts):
        n = np.frombuffer(m.normals, dtype=np.float32).reshape(-1, 3)
        if np.isfinite(n).all():
            me.shade_smooth()
            me.normals_split_custom_set_from_vertices(n.tolist())
    return me


def _assimp_material(d: dict, path: Path) -> bpy.types.Material:
    """A Principled BSDF of an assimp material's diffuse colour, opacity and diffuse texture."""
    mat = bpy.data.materials.new(str(d.get("NAME") or "material"))
    tree = compat.node_tree(mat)
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    rgba = d.get("COLOR_DIFFUSE") or d.get("COLOR_BASE")
    if rgba:
        bsdf.inputs["Base Color"].default_value = (*[float(c) for c in rgba[:3]], 1.0)
        mat.diffuse_color = (*[float(c) for c in rgba[:3]], 1.0)
    opacity = d.get("OPACITY")
    if opacity is not None and 0.0 <= float(opacity) < 1.0:
        bsdf.inputs["Alpha"].default_value = float(opacity)
    name = _assimp_texture(d, path.parent)
    if name:
        node = tree.nodes.new("ShaderNodeTexImage")
        if name.startswith("*"):  # embedded in the file: assimp-py does not hand its bytes over
            img = bpy.data.images.new(f"embedded texture {name[1:]}", 1, 1)
            img.source, img.filepath = "FILE", str(path.parent / f"<embedded texture {name[1:]}>")
        else:
            found = find_beside(path.parent, name)
            img = (bpy.data.images.load(str(found), check_existing=True) if found is not None else
                   bpy.data.images.new(Path(name.replace("\\", "/")).name or name, 1, 1))
            if found is None:
                img.source, img.filepath = "FILE", str(path.parent / name.replace("\\", "/"))
        node.image = img
        tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def _import_with_trimesh(path: Path) -> None:
    import trimesh

    try:
        tm = trimesh.load(str(path), force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for corrupt files
        raise InputError(f"cannot read mesh file {path}: {e}") from None
    if not isinstance(tm, trimesh.Trimesh) or len(tm.faces) == 0:
        raise InputError(f"cannot read mesh file {path}: no faces found (corrupt or empty file)")
    check_vertices(np.asarray(tm.vertices, dtype=np.float64), f"mesh file {path}")
    mesh = bpy.data.meshes.new(path.stem)
    mesh.from_pydata(np.asarray(tm.vertices, dtype=np.float64).tolist(), [], np.asarray(tm.faces).tolist())
    mesh.validate()
    obj = bpy.data.objects.new(path.stem, mesh)
    bpy.context.scene.collection.objects.link(obj)


def find_beside(folder: Path, name: str) -> Path | None:
    """A file a mesh names, looked for as meshes made on Windows need: ``name`` as written (backslashes as folder
    separators) under ``folder``, else the same path in any letter case, else its base name in ``folder``, else that
    base name in any letter case."""
    name = name.replace("\\", "/")
    base = Path(name).name
    for cand in (Path(folder) / name, _any_case(Path(folder), name), Path(folder) / base):
        if cand is not None and cand.is_file():
            return cand
    if base:
        low = base.lower()
        with contextlib.suppress(OSError):
            for f in sorted(Path(folder).iterdir()):
                if f.name.lower() == low and f.is_file():
                    return f
    return None


def _any_case(folder: Path, name: str) -> Path | None:
    """``name`` (a relative path with / separators) under ``folder``, each part matched in any letter case, as
    Windows would find it; None when a part is not there."""
    cur = folder
    for part in [p for p in name.split("/") if p not in ("", ".")]:
        if part == "..":
            cur = cur.parent
            continue
        if (cur / part).exists():
            cur = cur / part
            continue
        try:
            match = next((c for c in sorted(cur.iterdir()) if c.name.lower() == part.lower()), None)
        except OSError:
            return None
        if match is None:
            return None
        cur = match
    return cur


def _image_missing(img, search: Path | None = None) -> bool:
    """Whether an image datablock names a file that is not there (Blender renders it magenta). Blender reads a
    path written with Windows backslashes; with ``search`` (the mesh file's folder) a file found there by
    :func:`find_beside` is pointed to instead of counted missing."""
    if img is None or img.packed_file is not None or img.source not in ("FILE", "SEQUENCE", "MOVIE"):
        return False
    path = bpy.path.abspath(img.filepath, library=img.library)
    if os.path.isfile(path) or os.path.isfile(path.replace("\\", "/")):
        return False
    found = find_beside(search, Path(path.replace("\\", "/")).name) if search is not None else None
    if found is None:
        return True
    img.filepath = str(found)
    img.reload()
    return False


def drop_missing_textures(objs: list[bpy.types.Object], search: Path | None = None) -> list[str]:
    """Unlink every image texture of these (imported) objects' materials whose file is missing, so the surface
    takes its material's own colour (an OBJ's ``Kd``) instead of Blender's missing-texture magenta; return the
    missing files' names (sorted, once each). A texture found in ``search`` (the mesh file's folder) under its
    base name, in any letter case, is used from there instead. Only for imported files: materials of the user's
    own objects are never touched."""
    missing: set[str] = set()
    for m in _node_materials(objs):
        tree = m.node_tree
        for n in [n for n in tree.nodes if n.type == "TEX_IMAGE" and _image_missing(n.image, search)]:
            missing.add(Path(bpy.path.abspath(n.image.filepath).replace("\\", "/")).name or n.image.name)
            for link in [lk for lk in tree.links if lk.from_node == n]:
                tree.links.remove(link)
    return sorted(missing)


def _node_materials(objs: list[bpy.types.Object]):
    """Each node material of these objects' meshes, once."""
    done: set[int] = set()
    for o in objs:
        if o.type != "MESH":
            continue
        for m in o.data.materials:
            if m is None or m.node_tree is None or m.as_pointer() in done:
                continue
            done.add(m.as_pointer())
            yield m


def _vertex_colour_material(attribute: str) -> bpy.types.Material:
    """A Principled BSDF whose base colour is the mesh's colour attribute ``attribute`` (the roughness of the
    default grey)."""
    mat = bpy.data.materials.new(f"MRVM_vertex_colours_{attribute}")
    tree = compat.node_tree(mat)
    bsdf = next(n for n in tree.nodes if n.type == "BSDF_PRINCIPLED")
    node = tree.nodes.new("ShaderNodeVertexColor")
    node.layer_name = attribute
    tree.links.new(node.outputs["Color"], bsdf.inputs["Base Color"])
    bsdf.inputs["Roughness"].default_value = 0.6
    return mat


def opaque_invisible_materials(objs: list[bpy.types.Object]) -> list[str]:
    """Set to 1 the alpha of these (imported) objects' materials whose Principled BSDF alpha is 0 with nothing
    linked to it; return their names (sorted). Blender's FBX importer reads such a 0 from files of 3ds Max and
    other exporters that mean an opaque surface (its own comment: the formula is a guess), and the object would
    render as nothing while its masks and depth show it. Only for imported files."""
    fixed: set[str] = set()
    for m in _node_materials(objs):
        for n in m.node_tree.nodes:
            a = n.inputs.get("Alpha") if n.type == "BSDF_PRINCIPLED" else None
            if a is not None and not a.is_linked and a.default_value <= 0.0:
                a.default_value = 1.0
                fixed.add(m.name)
    return sorted(fixed)


# Working colour spaces. Blender takes a colour given as numbers (a node socket's value, a colour ramp's stops, a
# material's Viewport Display colour, a float colour attribute) in the open file's working space, which Blender 5.0
# lets a file set to ACEScg or Linear Rec.2020 (File > Color Management > Working Space). The procedural library's
# colours and the colours mesh files hold (an OBJ's Kd, a glTF's baseColorFactor, PLY and OBJ vertex colours, FBX
# and USD colours, assimp's) are linear Rec.709, and Blender 5.0's importers keep their numbers as they are: in an
# ACEScg file they rendered other colours (an orange OBJ 31/255 off). Converted here when they are made; a .blend
# appended as a source is converted by Blender itself, and the user's own materials are already in the file's space.

_VECTOR_COLOUR_NODES = frozenset({"ShaderNodeNormalMap", "ShaderNodeVectorDisplacement"})
"""Nodes whose colour socket holds a vector, not a colour (Blender's own change of working space leaves them)."""


def rec709_to_scene_linear() -> np.ndarray | None:
    """The 3x3 matrix that takes linear Rec.709 numbers to the open file's working space (scene linear), from
    Blender's own OpenColorIO conversion; None where the two are one: a Linear Rec.709 file, and every file before
    Blender 5.0 (one working space, whose conversion is the identity to about 1e-5 there: left exact)."""
    from mathutils import Color

    if not hasattr(Color, "from_rec709_linear_to_scene_linear"):
        return None
    m = np.array([Color(tuple(e)).from_rec709_linear_to_scene_linear()[:] for e in np.eye(3)], dtype=np.float64).T
    return None if np.abs(m - np.eye(3)).max() < 1e-4 else m


def rec709_colours_to_working_space(materials=(), meshes=(), node_groups=()) -> None:
    """Convert colours made from linear Rec.709 numbers into the open file's working space (nothing to do in a
    Linear Rec.709 file: :func:`rec709_to_scene_linear`): ``materials``' Viewport Display colours and their node
    trees' colour sockets and colour ramps, the same in ``node_groups`` (with their inputs' defaults), and
    ``meshes``' float colour attributes (8-bit ones hold sRGB, which Blender converts itself). Each once. Only for
    what the package makes or imports: never the user's own data, which is in the file's space already."""
    m = rec709_to_scene_linear()
    if m is None:
        return

    def conv(v) -> tuple:
        v = tuple(v)
        return (*(m @ np.asarray(v[:3], dtype=np.float64)).tolist(), *v[3:])

    def tree(t) -> None:
        if t is None or t.as_pointer() in done:
            return
        done.add(t.as_pointer())
        for n in t.nodes:
            if n.bl_idname in _VECTOR_COLOUR_NODES:
                continue
            for s in (*n.inputs, *n.outputs):
                if s.type == "RGBA" and hasattr(s, "default_value"):
                    s.default_value = conv(s.default_value)
            ramp = getattr(n, "color_ramp", None)
            for e in (ramp.elements if ramp is not None else ()):
                e.color = conv(e.color)
        interface = getattr(t, "interface", None)
        for item in (interface.items_tree if interface is not None else ()):
            if getattr(item, "item_type", "") == "SOCKET" and getattr(item, "socket_type", "") == "NodeSocketColor":
                item.default_value = conv(item.default_value)

    done: set[int] = set()
    for mat in materials:
        if mat is None or mat.as_pointer() in done:
            continue
        done.add(mat.as_pointer())
        mat.diffuse_color = conv(mat.diffuse_color)
        mat.specular_color = conv(mat.specular_color)
        tree(mat.node_tree)
    for g in node_groups:
        tree(g)
    for me in meshes:
        if me is None or me.as_pointer() in done:
            continue
        done.add(me.as_pointer())
        for attr in getattr(me, "color_attributes", ()):
            if attr.data_type != "FLOAT_COLOR" or not len(attr.data):
                continue
            rgba = np.empty(len(attr.data) * 4, dtype=np.float32)
            attr.data.foreach_get("color", rgba)
            rgba = rgba.reshape(-1, 4)
            rgba[:, :3] = rgba[:, :3].astype(np.float64) @ m.T
            attr.data.foreach_set("color", rgba.ravel())


def _imported_to_working_space(before: dict[str, set[int]]) -> None:
    """The colours of the materials, node groups and meshes made since ``before`` (:func:`snapshot_data`; a mesh
    file's import), from linear Rec.709 into the file's working space."""
    made = {name: [d for d in getattr(bpy.data, name) if d.as_pointer() not in before[name]] for name in before}
    rec709_colours_to_working_space(made["materials"], made["meshes"], made["node_groups"])


# Workbench draws each material's Viewport Display colour (Material.diffuse_color), not its shader: a material whose
# node tree is coloured while that colour is Blender's default grey (how artists leave it) renders grey there.

_DEFAULT_VIEWPORT_COLOUR = (0.8, 0.8, 0.8)
"""Blender's default Viewport Display colour of a material, and the default colour of a Principled or Diffuse
BSDF (grey: the same numbers in every working space)."""


def _default_grey(rgb) -> bool:
    return bool(np.abs(np.asarray(tuple(rgb)[:3], dtype=np.float64) - _DEFAULT_VIEWPORT_COLOUR).max() < 1e-3)


def _shader_coloured(tree) -> bool:
    """Whether a Principled or Diffuse BSDF that the material's output renders (upstream of its active output) has
    a base colour other than the default grey: a value, or anything linked to it (a texture, vertex colours)."""
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL"]
    active = [n for n in outputs if n.is_active_output] or outputs
    todo, seen = list(active), set()
    while todo:
        n = todo.pop()
        if n.as_pointer() in seen:
            continue
        seen.add(n.as_pointer())
        socket = (n.inputs.get("Base Color") if n.type == "BSDF_PRINCIPLED" else
                  n.inputs.get("Color") if n.type == "BSDF_DIFFUSE" else None)
        if socket is not None and (socket.is_linked or not _default_grey(socket.default_value)):
            return True
        todo.extend(lk.from_node for s in n.inputs for lk in s.links if not lk.is_muted)
    return False


def viewport_grey_materials(objs: list[bpy.types.Object]) -> list[str]:
    """Names (sorted, once each) of the materials of these objects whose Viewport Display colour is Blender's default
    grey while their shader's base colour is not (:func:`_shader_coloured`): what a Workbench render draws grey
    though Cycles and EEVEE render it coloured. Nothing is modified (a .blend's or the user's own materials)."""
    names: set[str] = set()
    done: set[int] = set()
    for o in objs:
        for slot in getattr(o, "material_slots", ()):
            mat = slot.material
            if mat is None or mat.as_pointer() in done:
                continue
            done.add(mat.as_pointer())
            if (_default_grey(mat.diffuse_color) and compat.uses_nodes(mat) and mat.node_tree is not None
                    and _shader_coloured(mat.node_tree)):
                names.add(mat.name)
    return sorted(names)


def viewport_grey_warning(names: list[str]) -> str | None:
    """One line for the end of a Workbench run about the materials :func:`viewport_grey_materials` found (None for
    none): named up to 3."""
    if not names:
        return None
    n = len(names)
    return (f"{n} material(s) ({', '.join(names[:3])}{', ...' if n > 3 else ''}) rendered grey: Workbench draws each "
            "material's Viewport Display colour (Material Properties > Viewport Display > Color, left at its default "
            "grey) while their shaders are coloured; Cycles or EEVEE (--engine CYCLES or BLENDER_EEVEE) render the "
            "shader")


def _top_level(objs: list[bpy.types.Object]) -> list[bpy.types.Object]:
    ids = {o.as_pointer() for o in objs}
    return [o for o in objs if o.parent is None or o.parent.as_pointer() not in ids]


def load_into(spec: ObjectSpec, collection: bpy.types.Collection, missing_textures: list[str] | None = None,
              made_opaque: list[str] | None = None, work_dir: Path | None = None,
              missing_libraries: list[str] | None = None) -> list[bpy.types.Object]:
    """Load a dataset object into ``collection`` (objects only live there); return its objects. A mesh file's
    textures that are missing are dropped (:func:`drop_missing_textures`) and their names appended to
    ``missing_textures``; its materials read as fully transparent are made opaque (:func:`opaque_invisible_materials`)
    and their names appended to ``made_opaque`` (each when given). An OBJ's material libraries that are nowhere
    beside it are appended to ``missing_libraries``. A mesh file's colours (linear Rec.709) are converted into the
    file's working space (:func:`rec709_colours_to_working_space`). A file inside a zip archive is read where the
    archive is unpacked under ``work_dir`` (:func:`source_file`), which must outlive the render."""
    if spec.kind == "file":
        path = source_file(spec, work_dir)
        frame: list = []
        made_before = snapshot_data(("materials", "meshes", "node_groups"))
        try:
            new = _import_file(path, frame)
        except InputError as e:  # named as the user named it, not where the archive was unpacked
            raise InputError(str(e).replace(str(path), spec.describe())) from None
        if frame:  # a .blend's: its render's frame (what its materials' animation shows)
            _follow_frame(collection, *frame)
        lost = drop_missing_textures(new, path.parent)
        if missing_textures is not None:
            missing_textures.extend(lost)
        if missing_libraries is not None and path.suffix.lower() == ".obj":
            missing_libraries.extend(missing_material_libraries(path))
        fixed = opaque_invisible_materials(new)
        if made_opaque is not None:
            made_opaque.extend(fixed)
        default = None
        by_colours: dict[str, bpy.types.Material] = {}
        for o in new:
            for c in list(o.users_collection):
                c.objects.unlink(o)
            collection.objects.link(o)
            colours = o.data.color_attributes if o.type == "MESH" else None
            if colours and not any(o.data.materials):
                # A scan's vertex colours (PLY, OBJ's "v x y z r g b") are its only colour: read them, as other
                # tools show such a file (they rendered grey before)
                name = (colours.active_color or colours[0]).name
                if name not in by_colours:
                    by_colours[name] = _vertex_colour_material(name)
                o.data.materials.append(by_colours[name])
            elif o.type == "MESH" and not any(o.data.materials):
                # Imported geometry without materials: a neutral grey reads against the white background.
                if default is None:
                    default = bpy.data.materials.new("MRVM_default_grey")
                    default.diffuse_color = (0.45, 0.45, 0.45, 1.0)
                    bsdf = next(n for n in compat.node_tree(default).nodes if n.type == "BSDF_PRINCIPLED")
                    bsdf.inputs["Base Color"].default_value = (0.45, 0.45, 0.45, 1.0)
                    bsdf.inputs["Roughness"].default_value = 0.6
                o.data.materials.clear()
                o.data.materials.append(default)
        if path.suffix.lower() != ".blend":  # (an appended .blend's colours: converted by Blender on append)
            _imported_to_working_space(made_before)
        return new
    if spec.kind == "selected":
        user = bpy.context.scene
        _follow_frame(collection, user.frame_current, user.frame_subframe)
        srcs, copies, metas = [], [], []
        for name in spec.names:
            src = bpy.data.objects.get(name)
            if src is None:
                raise InputError(f"object {name!r} no longer exists")
            if src.type == "META":  # its surface is its family's, in the user's scene
                metas += _baked_metaball(src, user)
                continue
            ob = _render_copy(src)  # parent, constraints and animation kept until it is evaluated at the frame
            collection.objects.link(ob)
            srcs.append(src)
            copies.append(ob)
        made = _realized_selected_instances(srcs, copies, collection)
        scenes = _scenes_of(collection)
        out = _bake_evaluated(copies, _scene_depsgraph(scenes[0])) if copies and scenes else copies
        for ob in out + metas:
            if ob.name not in collection.objects:
                collection.objects.link(ob)
        for ob in copies:
            if ob.type != "MESH":  # made a mesh object of its own
                bpy.data.objects.remove(ob)
        return out + metas + made
    if spec.kind == "procedural":
        try:
            from . import procedural
        except ImportError:
            raise InputError("the procedural object library is not available in this build") from None
        params = dict(spec.params)
        ob = procedural.build(spec.category, spec.seed, collection, **params)
        return [ob]
    raise InputError(f"unknown source kind {spec.kind!r}")



def _realized_selected_instances(srcs: list, copies: list, collection) -> list:
    """Real meshes for what the geometry nodes, particle and vertex/face instancing of selected objects render
    (``copies``, in ``collection``, are what is rendered of ``srcs``): geometry nodes instances are realized on the
    copies, evaluated in the render's scene (:func:`_realize_node_instances`); particle and vertex/face instances are
    read from the scene the user's object is in, as it shows them, and joined into a new object each, linked to
    ``collection`` (:func:`_bake_dupli_instances`; the particle settings are set to show as many particles as a
    render does for that moment, then set back). Returns the new objects; nothing of the user's changes."""
    here = copies[0].users_scene if copies else ()
    if here:
        _realize_node_instances(copies, here[0])
    pairs = [(src, ob) for src, ob in zip(srcs, copies) if _dupli_instancer(src)]
    if not pairs:
        return []
    made = []
    for src, ob in pairs:
        scenes = src.users_scene
        user_scene = bpy.context.scene if bpy.context.scene in scenes else (scenes[0] if scenes else None)
        if user_scene is None:
            continue
        with _particles_as_rendered([src]):
            made += _bake_dupli_instances([(src, ob)], user_scene)
    for o in made:
        collection.objects.link(o)
    return made

def _scenes_of(collection) -> list:
    """The scenes ``collection`` is in (as a child collection, at any depth)."""
    return [sc for sc in bpy.data.scenes if sc.collection == collection
            or any(c == collection for c in sc.collection.children_recursive)]


def _follow_frame(collection, frame: int, subframe: float) -> None:
    """Put the scenes ``collection`` renders in (the render's own: never the user's current scene) at ``frame``:
    the frame the objects were evaluated at, which their materials' animation shows too."""
    for sc in _scenes_of(collection):
        if sc != bpy.context.scene and (sc.frame_current, sc.frame_subframe) != (frame, subframe):
            sc.frame_current, sc.frame_subframe = frame, subframe


def _metaball_basis(o) -> bool:
    """Whether a metaball object draws its family's surface (Blender's rule: its name ends in no digit; the others
    of the family, named as it is with a number, add to that surface)."""
    return not o.name[-1:].isdigit()


def _baked_metaball(src, scene) -> list:
    """A new mesh object of the surface a selected (basis) metaball's family makes in ``scene`` (the user's, where
    the family is: :func:`_bake_evaluated`), evaluated at its render resolution (set on the family's metaballs for
    the moment, then back)."""
    family = {o.data.as_pointer(): o.data for o in scene.objects if o.type == "META"
              and (o == src or o.name.rsplit(".", 1)[0] == src.name and o.name.rsplit(".", 1)[-1].isdigit())}
    was = {p: d.resolution for p, d in family.items()}
    try:
        for d in family.values():
            if d.resolution != d.render_resolution:
                d.resolution = d.render_resolution
        return _bake_evaluated([src], _scene_depsgraph(scene))
    finally:
        for p, d in family.items():
            if d.resolution != was[p]:
                d.resolution = was[p]
        _scene_depsgraph(scene)


def _render_copy(src):
    """A copy of a selected object that evaluates as a render does (:func:`render_evaluation`; a curve's or text's
    data copied, at its render resolution), sharing its mesh and materials: nothing of the user's is modified."""
    ob = src.copy()
    if ob.type in ("CURVE", "SURFACE", "FONT"):
        ob.data = src.data.copy()
        _render_resolution(ob)
    render_evaluation(ob)
    return ob


@contextlib.contextmanager
def _rendered_sources(names: tuple[str, ...]):
    """Inside the block, ``{name: evaluated object}`` of the selected objects ``names`` as a render of the user's
    scene shows them at its frame: copies (:func:`_render_copy`) evaluated in a scene of their own, a metaball in
    the user's scene (its family is there). What it made is removed after."""
    user = bpy.context.scene
    srcs = []
    for name in names:
        src = bpy.data.objects.get(name)
        if src is None:
            raise InputError(f"object {name!r} no longer exists")
        srcs.append(src)
    before = snapshot_data()
    scene = bpy.data.scenes.new("MRVM_evaluation")
    try:
        scene.frame_current, scene.frame_subframe = user.frame_current, user.frame_subframe
        copies = {}
        for src in srcs:
            if src.type != "META":
                copies[src.name] = _render_copy(src)
                scene.collection.objects.link(copies[src.name])
        depsgraph = _scene_depsgraph(scene) if copies else None
        user_graph = _scene_depsgraph(user) if len(copies) < len(srcs) else None
        yield {src.name: (copies[src.name].evaluated_get(depsgraph) if src.name in copies
                          else src.evaluated_get(user_graph)) for src in srcs}
    finally:
        bpy.data.scenes.remove(scene)
        remove_new_data(before)


def render_evaluation(ob: bpy.types.Object) -> None:
    """Make a private copy evaluate as a render does: modifiers shown in renders only, subdivision
    and multires at their render levels, and shown in viewports (a viewport evaluation leaves an object hidden in
    viewports out). Normalization and the data passes read the evaluated mesh (a viewport evaluation); Cycles
    renders the render evaluation, and the two must agree."""
    if ob.hide_viewport:
        ob.hide_viewport = False
    for m in ob.modifiers:
        if m.show_viewport != m.show_render:
            m.show_viewport = m.show_render
        if m.type in ("SUBSURF", "MULTIRES") and m.levels != m.render_levels:
            m.levels = m.render_levels


def renders(o: bpy.types.Object) -> bool:
    """Whether an object is a mesh the camera sees in a render (what the data passes hold)."""
    return o.type == "MESH" and not o.hide_render and getattr(o, "visible_camera", True)


DEGENERATE_AREA = 1e-9
"""A face whose area is below this share of its mesh's squared bounding-box diagonal renders nothing (three vertices
at one point, a sliver on a line): its vertices do not count as used for the bounds (:func:`_world_vertices`)."""


def _world_vertices(objs: list[bpy.types.Object], view_layer: bpy.types.ViewLayer):
    """(world-space vertices, whether a face of some area uses each) of each evaluated, render-visible mesh of ``objs``.

    A face of no area (:data:`DEGENERATE_AREA`) does not count: one such face 20 units from a 1-unit box set the
    bounds the box was framed by, and it rendered as one pixel a view, without a word."""
    out = []
    for _, ev in rendered_meshes(objs, view_layer):
        with evaluated_mesh(ev) as me:
            co = np.empty(len(me.vertices) * 3, dtype=np.float64)
            me.vertices.foreach_get("co", co)
            corners = np.empty(len(me.loops), dtype=np.int32)
            me.loops.foreach_get("vertex_index", corners)
            area = np.empty(len(me.polygons), dtype=np.float64)
            me.polygons.foreach_get("area", area)
            total = np.empty(len(me.polygons), dtype=np.int32)
            me.polygons.foreach_get("loop_total", total)  # (a face's corners follow each other, faces in order)
        used = np.zeros(len(co) // 3, dtype=bool)
        pts = co.reshape(-1, 3)
        if len(corners):
            span = pts[corners]
            diag2 = float(np.sum((span.max(axis=0) - span.min(axis=0)) ** 2)) if np.isfinite(span).all() else 0.0
            kept = corners[np.repeat(area > DEGENERATE_AREA * diag2, total)] if diag2 > 0 else corners
            used[kept if len(kept) else corners] = True  # (all of no area: the size checks refuse it)
        m = np.array(ev.matrix_world, dtype=np.float64)
        out.append((co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3], used))
    return out


def mesh_vertices_world(objs: list[bpy.types.Object], view_layer: bpy.types.ViewLayer) -> np.ndarray:
    """World-space vertices that faces use, of the evaluated, render-visible meshes (modifiers applied) in
    ``view_layer``, (N, 3): the meshes :func:`mesh_triangles` rasterizes. A vertex no face uses (a scan's stray
    point, a loose vertex or edge) renders nothing and is left out, so it cannot set the bounds the object is
    normalized and framed by (:func:`loose_vertices` tells when it would have)."""
    pts = [co[used] for co, used in _world_vertices(objs, view_layer)]
    if not pts or sum(len(p) for p in pts) == 0:
        raise InputError("the object has no faces (points or lines only): nothing of it would render")
    return np.concatenate(pts)


LOOSE_BOUNDS = 0.01
"""Vertices no face uses that reach beyond the faces' bounding box by more than this share of its diagonal are
named in a warning (:func:`loose_vertices`)."""


def loose_vertices(objs: list[bpy.types.Object], view_layer: bpy.types.ViewLayer) -> dict | None:
    """Where vertices that no face uses (left out of the bounds: :func:`mesh_vertices_world`) would have moved the
    bounding box by more than :data:`LOOSE_BOUNDS` of its diagonal: ``{"count": how many such vertices the meshes
    hold, "bbox_with_them": [lo, hi]}`` (world space, as the object was loaded), for ``meta.json`` and a warning;
    else None."""
    parts = _world_vertices(objs, view_layer)
    faces = np.concatenate([co[used] for co, used in parts] or [np.empty((0, 3))])
    loose = np.concatenate([co[~used] for co, used in parts] or [np.empty((0, 3))])
    if len(loose) == 0 or len(faces) == 0 or not np.isfinite(faces).all():
        return None  # nothing left out, or nothing to bound (the render refuses the object)
    lo, hi = faces.min(axis=0), faces.max(axis=0)
    reach = loose[np.isfinite(loose).all(axis=1)]
    lo_all = np.minimum(lo, reach.min(axis=0)) if len(reach) else lo
    hi_all = np.maximum(hi, reach.max(axis=0)) if len(reach) else hi
    if max(np.abs(lo_all - lo).max(), np.abs(hi_all - hi).max()) <= LOOSE_BOUNDS * float(np.linalg.norm(hi - lo)):
        return None
    return {"count": len(loose), "bbox_with_them": [lo_all.tolist(), hi_all.tolist()]}


def normalization_matrix(verts: np.ndarray, what: str = "the object") -> np.ndarray:
    """ShapeNetCore v2 normalization: bbox centre to the origin, bbox diagonal to 1."""
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if not np.isfinite(diag) or diag <= 0:
        raise InputError(f"{what} is degenerate (zero-size bounding box: all its vertices at one point)")
    s = 1.0 / diag
    n = np.eye(4)
    n[:3, :3] *= s
    n[:3, 3] = -s * (lo + hi) / 2.0
    return n


def apply_world_transform(objs: list[bpy.types.Object], m: np.ndarray, view_layer: bpy.types.ViewLayer) -> None:
    """Left-multiply ``m`` onto the world matrix of the top-level objects (children follow)."""
    mm = Matrix(m.tolist())
    for o in _top_level(objs):
        o.matrix_world = mm @ o.matrix_world
    view_layer.update()


def mesh_triangles(objs: list[bpy.types.Object], view_layer: bpy.types.ViewLayer):
    """World-space triangles of the evaluated, render-visible meshes of ``objs`` for the data passes.

    Each triangle carries its corner (shading) normals, its object's ``pass_index`` and its
    material's ``pass_index`` (what Cycles' Object Index and Material Index passes hold). The
    triangulation is Blender's own (``loop_triangles``), the one Cycles renders.
    """
    from .raster import Triangles, concatenate

    parts = []
    for o, ev in rendered_meshes(objs, view_layer):
        with evaluated_mesh(ev) as me:
            if hasattr(me, "calc_loop_triangles"):
                me.calc_loop_triangles()
            n = len(me.loop_triangles)
            if n == 0:
                continue
            co = np.empty(len(me.vertices) * 3, dtype=np.float64)
            me.vertices.foreach_get("co", co)
            tv = np.empty(n * 3, dtype=np.int64)
            me.loop_triangles.foreach_get("vertices", tv)
            tl = np.empty(n * 3, dtype=np.int64)
            me.loop_triangles.foreach_get("loops", tl)
            slot = np.empty(n, dtype=np.int64)
            me.loop_triangles.foreach_get("material_index", slot)
            cn = np.empty(len(me.loops) * 3, dtype=np.float64)
            me.corner_normals.foreach_get("vector", cn)
            tp = np.empty(n, dtype=np.int64)
            me.loop_triangles.foreach_get("polygon_index", tp)
            smooth = np.empty(len(me.polygons), dtype=bool)
            me.polygons.foreach_get("use_smooth", smooth)
            mats = [m.pass_index if m is not None else 0 for m in me.materials] or [0]
        m = np.array(ev.matrix_world, dtype=np.float64)
        lin = m[:3, :3]
        verts = (co.reshape(-1, 3) @ lin.T + m[:3, 3])[tv.reshape(-1, 3)]
        nrm_mat = np.linalg.inv(lin)  # normals transform with the inverse transpose (row vectors: n @ inv)
        nrm = cn.reshape(-1, 3) @ nrm_mat
        nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-300)
        ng = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
        if np.linalg.det(lin) < 0:  # a mirrored object keeps its own normals' orientation
            ng = -ng
        corner = nrm[tl.reshape(-1, 3)]
        # Flat faces shade with their triangle's own normal (a non-planar quad's two triangles
        # differ from the face normal), as Cycles does; smooth ones interpolate the corner normals.
        flat = ~smooth[tp]
        if flat.any():
            unit = ng[flat] / np.maximum(np.linalg.norm(ng[flat], axis=1, keepdims=True), 1e-300)
            corner[flat] = unit[:, None, :]
        mat_ids = np.asarray(mats, dtype=np.int64)[np.clip(slot, 0, len(mats) - 1)]
        parts.append(Triangles(verts, corner, ng, np.full(n, int(o.pass_index), np.int64), mat_ids))
    return concatenate(parts)


MAX_COORDINATE = 1e9
"""Vertex coordinates beyond this (scene units) mark a broken mesh: normalization would squeeze the
real geometry into a point and every view would come out blank."""


FLOAT32_STEP = 1e-3
"""Largest float32 spacing of a mesh's stored vertex coordinates, as a share of its size, rendered without a warning
(:func:`float32_precision_warning`)."""


def float32_precision_warning(objs: list[bpy.types.Object], view_layer: bpy.types.ViewLayer, name: str) -> str | None:
    """A warning when a mesh's vertices are stored so far from its origin, for its size, that float32 (Blender's vertex
    type) snaps them to a grid coarser than :data:`FLOAT32_STEP` of the object: a scan in UTM coordinates (5.3e6
    units away) snapped to half a unit, its sphere rendered blocky and the colour (Cycles, float32) 1-5 px off the
    masks and depth (float64). Placed far by the object's location instead, the mesh stays exact. None when fine."""
    worst = 0.0
    for _, ev in rendered_meshes(objs, view_layer):
        with evaluated_mesh(ev) as me:
            co = np.empty(len(me.vertices) * 3, dtype=np.float64)
            me.vertices.foreach_get("co", co)
        pts = co.reshape(-1, 3)
        if not len(pts) or not np.isfinite(pts).all():
            continue
        size = float(np.linalg.norm(pts.max(axis=0) - pts.min(axis=0)))
        if size > 0:
            worst = max(worst, float(np.spacing(np.float32(np.abs(pts).max()))) / size)
    if worst <= FLOAT32_STEP:
        return None
    return (f"{name}: its vertices are stored so far from the mesh's origin, for its size, that Blender's float32 "
            f"coordinates snap them to a grid of {100 * worst:.2g}% of the object (its shape is coarsened and the "
            "colour can be off the masks and depth by a pixel or more); move it near the origin before exporting "
            "(e.g. subtract the scan's offset)")


def check_vertices(verts: np.ndarray, what: str) -> None:
    """Refuse vertices that are NaN, infinite or absurdly far away (InputError, one line)."""
    verts = np.asarray(verts)
    bad = ~np.isfinite(verts).all(axis=1)
    if bad.any():
        raise InputError(f"{what} has {int(bad.sum())} vertices that are not finite numbers (NaN or infinite); "
                         "fix or re-export the mesh")
    far = float(np.abs(verts).max()) if len(verts) else 0.0
    if far > MAX_COORDINATE:
        raise InputError(f"{what} has a vertex coordinate of {far:.3g}, beyond +-{MAX_COORDINATE:g} scene units "
                         "(a broken mesh would render as blank views); fix or re-export the mesh")


def source_fingerprint(spec: ObjectSpec) -> str:
    """What a dataset object is rendered from, as a hash: a changed source gets a new fingerprint.

    Mesh files: their bytes (and an OBJ's material libraries beside it); inside a zip archive, the archive's bytes.
    Procedural objects: the
    full generator parameters. Selected objects: their geometry as a render of the user's scene evaluates it at its
    frame (:func:`_rendered_sources`: render levels, modifiers shown in renders; a viewport-only change leaves it as
    it was, and where viewport and render agree it is the hash the viewport evaluation gave before, so datasets
    rendered then resume), placement and material names (their materials themselves, UVs and colours:
    :func:`appearance_fingerprint`).
    """
    import hashlib

    h = hashlib.sha256()
    if spec.kind == "file" and spec.member:  # the archive's bytes: every file around the mesh inside it too
        h.update(spec.member.encode() + b"\0")
        _hash_file(h, Path(spec.path), f"cannot read archive {spec.path}")
    elif spec.kind == "file":
        path = Path(spec.path)
        files = [path]
        if path.suffix.lower() == ".obj":
            files += _obj_material_libraries(path)
        for f in files:
            h.update(f.name.encode("utf-8", "surrogateescape") + b"\0")  # (a name's bytes need not be UTF-8)
            _hash_file(h, f, f"cannot read mesh file {f}")
    elif spec.kind == "procedural":
        from . import procedural

        h.update(repr(sorted(procedural.sample_parameters(spec.category, spec.seed, **dict(spec.params)).items())).encode())
    else:
        with _rendered_sources(spec.names) as evaluated:
            for name in spec.names:
                ev = evaluated[name]
                with evaluated_mesh(ev) as me:
                    co = np.empty(len(me.vertices) * 3, dtype=np.float32)
                    me.vertices.foreach_get("co", co)
                    lv = np.empty(len(me.loops), dtype=np.int32)
                    me.loops.foreach_get("vertex_index", lv)
                    h.update(co.tobytes() + lv.tobytes())
                    h.update(repr([m.name if m else "" for m in me.materials]).encode())
                h.update(np.array(bpy.data.objects[name].matrix_world, dtype=np.float32).tobytes())
    return "sha256:" + h.hexdigest()


_NODE_LAYOUT = frozenset({"location", "location_absolute", "width", "height", "dimensions", "select", "hide",
                          "show_options", "show_preview", "show_texture", "label", "color", "use_custom_color",
                          "warning_propagation", "color_tag", "bl_description", "bl_icon", "bl_label", "bl_idname",
                          "bl_static_type", "bl_width_default", "bl_width_min", "bl_width_max", "bl_height_default",
                          "bl_height_min", "bl_height_max", "type", "name", "rna_type"})
"""Node properties that place or label a node in the editor and change no render."""


def _plain(v):
    """An RNA value as plain, hashable data (arrays and matrices as nested tuples)."""
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    try:
        return tuple(_plain(x) for x in v)
    except TypeError:
        return repr(v)


_NOT_LOOKS = frozenset({"paint_active_slot", "paint_clone_slot", "preview_render_type", "use_preview_world",
                        "use_nodes"})
"""Material properties of the editor (texture painting, the preview sphere) that change no render, and ``use_nodes``
(read through ``compat.uses_nodes``: deprecated in 5.0)."""


def _rna_values(struct) -> list:
    """``struct``'s own settings: (name, value) of its properties that are plain values (not links to other data),
    without an ID's bookkeeping (users, session ids: they differ between sessions and copies)."""
    skip = _NODE_LAYOUT | _NOT_LOOKS | {p.identifier for p in bpy.types.ID.bl_rna.properties}
    out = []
    for prop in struct.bl_rna.properties:
        pid = prop.identifier
        if pid in skip or prop.type in ("POINTER", "COLLECTION"):
            continue
        try:
            out.append((pid, _plain(getattr(struct, pid))))
        except (AttributeError, TypeError, RuntimeError):
            continue
    return out


def _material_description(mat, seen: set[int]) -> list:
    """What a material renders from: its settings, and its node tree's nodes, their settings and inputs, and the
    links between them (node groups followed; the image files are :func:`rendered_images_fingerprint`'s)."""
    if mat is None:
        return [None]
    desc: list = [mat.name, _rna_values(mat)]

    def tree(t):
        if t is None or t.as_pointer() in seen:
            return
        seen.add(t.as_pointer())
        for n in sorted(t.nodes, key=lambda n: n.name):
            img = getattr(n, "image", None)
            desc.append((n.name, n.bl_idname, _rna_values(n), img.name if img is not None else None,
                         [(i.identifier, _plain(getattr(i, "default_value", None))) for i in n.inputs]))
            if getattr(n, "node_tree", None) is not None:
                desc.append(("group", n.name, n.node_tree.name))
                tree(n.node_tree)
        desc.append(sorted((lk.from_node.name, lk.from_socket.identifier, lk.to_node.name, lk.to_socket.identifier,
                            lk.is_muted) for lk in t.links))

    desc.append(compat.uses_nodes(mat))
    tree(mat.node_tree if compat.uses_nodes(mat) else None)
    return desc


def appearance_fingerprint(spec: ObjectSpec) -> str | None:
    """Selected objects' looks beyond their geometry, as a hash: their materials (settings, node trees), UV maps,
    colour attributes and object colour. A procedural object: what the library builds from its parameters
    (:func:`_procedural_build_fingerprint`). ``None`` for mesh files, whose bytes hold all of it
    (:func:`source_fingerprint`). Kept beside it so datasets rendered before it was kept still resume."""
    if spec.kind == "procedural":
        return _procedural_build_fingerprint(spec)
    if spec.kind != "selected":
        return None
    import hashlib

    h = hashlib.sha256()
    seen: set[int] = set()
    with _rendered_sources(spec.names) as evaluated:
        for name in spec.names:
            src = bpy.data.objects[name]
            h.update(repr([(slot.link, _material_description(slot.material, seen)) for slot in src.material_slots]
                          + [_plain(src.color)]).encode())
            _hash_looks(h, evaluated[name])
    return "sha256:" + h.hexdigest()


def _hash_looks(h, ev) -> None:
    """Add the UV maps and colour attributes of an evaluated object's mesh to the hash ``h``."""
    with evaluated_mesh(ev) as me:
        for uv in me.uv_layers:
            a = np.empty(len(uv.data) * 2, dtype=np.float32)
            uv.data.foreach_get("uv", a)
            h.update(uv.name.encode() + b"\0" + a.tobytes())
        for attr in getattr(me, "color_attributes", ()):
            a = np.empty(len(attr.data) * 4, dtype=np.float32)
            attr.data.foreach_get("color", a)
            h.update(attr.name.encode() + attr.domain.encode() + b"\0" + a.tobytes())


def _procedural_build_fingerprint(spec: ObjectSpec) -> str:
    """The object the procedural library builds for ``spec``, as a hash: its vertices, faces, part labels, sharp
    edges and its materials' nodes, node inputs and links.

    :func:`source_fingerprint` hashes the generator's parameters only, which stay the same when a later version of
    the library builds other geometry or colours from them: an object interrupted under one version and resumed
    under another would mix the two. Built in a collection of its own (no scene sees it) and removed again; a few
    milliseconds an object. Material and node names are left out (Blender suffixes them when a name is taken)."""
    import hashlib

    from . import procedural

    coll = bpy.data.collections.new("mrvm_fingerprint")
    ob = None
    try:
        ob = procedural.build(spec.category, spec.seed, coll, **dict(spec.params))
        me = ob.data
        h = hashlib.sha256()
        co = np.empty(len(me.vertices) * 3, dtype=np.float64)
        me.vertices.foreach_get("co", co)
        # Positions on a 1e-4 grid (the object's bbox diagonal is 1), faces and edges as sets of positions: bmesh's
        # bevel is not bit-exact from one process to the next (a few vertices one float32 step apart, listed in
        # another order, faces started at another corner), which renders the same images
        at = [tuple(q) for q in np.round(co.reshape(-1, 3) * 1e4).astype(np.int64).tolist()]
        part = me.attributes.get("part_id")
        rows = []
        for k, poly in enumerate(me.polygons):
            v = [at[i] for i in poly.vertices]
            first = v.index(min(v))
            rows.append((tuple(v[first:] + v[:first]), poly.material_index, poly.use_smooth,
                         part.data[k].value if part is not None else None))
        h.update(repr(sorted(rows)).encode())
        h.update(repr(sorted(tuple(sorted((at[a], at[b]))) for a, b in (e.vertices for e in me.edges
                                                                      if e.use_edge_sharp))).encode())
        for mat in me.materials:
            tree = mat.node_tree if mat is not None and compat.uses_nodes(mat) else None
            desc: list = [tuple(_plain(getattr(mat, k, None)) for k in ("diffuse_color", "roughness", "metallic",
                                                                       "pass_index"))] if mat else [None]
            if tree is not None:
                for n in sorted(tree.nodes, key=lambda n: (n.bl_idname, n.name)):
                    desc.append((n.bl_idname, [(i.identifier, _plain(getattr(i, "default_value", None)))
                                               for i in n.inputs]))
                desc.append(sorted((lk.from_node.bl_idname, lk.from_socket.identifier, lk.to_node.bl_idname,
                                    lk.to_socket.identifier) for lk in tree.links))
            h.update(repr(desc).encode())
        return "sha256:" + h.hexdigest()
    finally:
        if ob is not None:
            mesh, mats = ob.data, [m for m in ob.data.materials if m is not None]
            bpy.data.objects.remove(ob)
            bpy.data.meshes.remove(mesh)
            for m in mats:
                if m.users == 0:
                    bpy.data.materials.remove(m)
        bpy.data.collections.remove(coll)


def linked_files_fingerprint(spec: ObjectSpec) -> str | None:
    """The files a mesh file names (:func:`linked_files`), as a hash: ``None`` for sources that are not files.

    Kept beside :func:`source_fingerprint`, not inside it, so datasets rendered before it was kept still resume.
    A named file that is missing counts as missing (by name), so its appearance later changes the hash too."""
    if spec.kind != "file" or spec.member:  # an archive's files are in its own bytes (source_fingerprint)
        return None
    return _named_files_hash(linked_files(Path(spec.path)), f"the mesh file {spec.path}")


def _named_files_hash(named, named_by: str) -> str:
    """A hash of (name, file or None when missing) pairs, in order: each name, then the file's bytes or "missing"
    (so a file that appears later changes it too); an unreadable file is an InputError that says ``named_by``
    names it."""
    import hashlib

    h = hashlib.sha256()
    for name, f in named:
        h.update(name.encode("utf-8", "surrogateescape") + b"\0")
        if f is None:
            h.update(b"missing\0")
        else:
            _hash_file(h, f, f"cannot read {f} (named by {named_by})")
    return "sha256:" + h.hexdigest()


def rendered_images_fingerprint(objs: list[bpy.types.Object], base: Path | None) -> str | None:
    """The image files the materials of these objects' rendered meshes read (through node groups too; packed and
    generated images are in the source itself), as a hash of their names and bytes: ``None`` when they read none.

    What the importers found, not what the file names: a texture an FBX importer found by searching folders, a USD
    file's textures, those of a selected object's materials. Names are relative to ``base`` (the mesh file's folder,
    the open .blend's) where they lie under it, so a dataset moved with its sources still resumes. A missing file
    counts by name, as in :func:`linked_files_fingerprint`."""
    files: dict[str, Path] = {}
    seen: set[int] = set()

    def walk(tree):
        if tree is None or tree.as_pointer() in seen:
            return
        seen.add(tree.as_pointer())
        for n in tree.nodes:
            img = getattr(n, "image", None)
            if isinstance(img, bpy.types.Image) and _external_image(img):
                f = _blender_file(img.filepath, img.library)
                files[_relative_name(f, base)] = f
            if n.type == "GROUP":
                walk(n.node_tree)

    for o in objs:
        if renders(o):
            for slot in o.material_slots:
                if slot.material is not None:
                    walk(slot.material.node_tree)
    if not files:
        return None
    return _named_files_hash([(n, files[n] if files[n].is_file() else None) for n in sorted(files)],
                             "a material of the object")


def _hash_file(h, path: Path, what: str) -> None:
    """Feed a file's bytes to the hash ``h``; an unreadable file is an InputError starting with ``what``."""
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
    except OSError as e:
        raise InputError(f"{what}: {e.strerror or e}") from None


# MTL texture statements and how many arguments each of their options takes (the OBJ/MTL specification; -o, -s
# and -t take one to three numbers).
_MTL_TEXTURE = re.compile(r"^\s*(map_\w+|bump|disp|decal|refl|norm)\s+(.+?)\s*$", re.I)
_MTL_OPTION_ARGS = {"-blendu": 1, "-blendv": 1, "-boost": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1,
                    "-clamp": 1, "-bm": 1, "-imfchan": 1, "-type": 1, "-cc": 1}


def _mtl_texture_name(args: str) -> str:
    """The file name of an MTL texture statement's arguments (after its options; it may hold spaces)."""
    toks = args.split()
    i = 0
    while i < len(toks) and toks[i].lower() in _MTL_OPTION_ARGS:
        n = _MTL_OPTION_ARGS[toks[i].lower()]
        i += 1
        for _ in range(n):
            if i >= len(toks) - 1:
                break
            if n == 3:  # -o / -s / -t: one to three numbers
                try:
                    float(toks[i])
                except ValueError:
                    break
            i += 1
    return " ".join(toks[i:]).replace("\\", "/")


def linked_files(path: Path) -> list[tuple[str, Path | None]]:
    """The files a mesh file names beside its own bytes, as (name as written, the file or ``None`` if missing),
    in order: an OBJ's textures (through its MTL libraries), a binary FBX's or a .blend's images it does not embed,
    the textures of a file read with assimp (COLLADA, ASCII FBX, 3DS, ...),
    the other .blend files a .blend links data from (and their images), the asset paths of a USD text layer
    (sublayers, references, payloads, textures) and a glTF's external buffers and images. A texture
    name that is not found as written is looked for by its base name beside the MTL (:func:`find_beside`), as the
    render does."""
    path = Path(path)
    ext = path.suffix.lower()
    out: list[tuple[str, Path | None]] = []
    if ext == ".obj":
        for mtl in _obj_material_libraries(path):
            try:
                lines = mtl.read_text(encoding="utf-8", errors="replace").splitlines()
            except OSError:
                continue
            for line in lines:
                m = _MTL_TEXTURE.match(line)
                if not m:
                    continue
                name = _mtl_texture_name(m.group(2))
                if not name:
                    continue
                out.append((name, find_beside(mtl.parent, name)))
    elif ext == ".fbx" and not _binary_fbx(path):
        for name in _assimp_texture_names(path):
            out.append((name, find_beside(path.parent, name)))
    elif ext == ".fbx":
        for name in _fbx_texture_names(path):
            out.append((name, find_beside(path.parent, name)))
    elif ext in ASSIMP_EXTS:
        for name in _assimp_texture_names(path):
            out.append((name, find_beside(path.parent, name)))
    elif ext == ".blend":
        for name in _blend_image_files(path) + _blend_library_files(path):
            f = path.parent / name
            out.append((name, f if f.is_file() else None))
    elif ext == ".usda":
        try:
            text = path.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return out  # the importer reports it
        names = {m.group(1) or m.group(2) for m in _USDA_ASSET.finditer(text)}
        for name in sorted(n for n in names if "://" not in n and "<UDIM>" not in n.upper()):
            f = path.parent / name  # sublayers, references, payloads, textures
            out.append((name, f if f.is_file() else None))
    elif ext == ".gltf":
        import json
        from urllib.parse import unquote

        try:
            doc = json.loads(path.read_text(encoding="utf-8", errors="replace"))
        except (OSError, ValueError):
            return out  # the importer reports it
        if not isinstance(doc, dict):
            return out
        for key in ("buffers", "images"):
            for item in doc.get(key) or []:
                uri = item.get("uri") if isinstance(item, dict) else None
                if isinstance(uri, str) and uri and not uri.startswith("data:"):
                    f = path.parent / unquote(uri)
                    out.append((uri, f if f.is_file() else None))
    return out


# A USD text layer's asset paths (@path@; @@@path@@@ when the path holds an @); URLs and UDIM patterns are left out.
_USDA_ASSET = re.compile(r"(?<!@)@(?!@)([^@\n]+?)@(?!@)|@@@(.+?)@@@")


def _fbx_texture_names(path: Path) -> list[str]:
    """The image files a binary FBX names and does not embed (its Video nodes' RelativeFilename, else Filename),
    sorted, once each; [] when Blender's FBX parser cannot read it (the import reports that)."""
    try:
        import addon_utils

        addon_utils.enable("io_scene_fbx", default_set=False)
        from io_scene_fbx import parse_fbx

        root, _ = parse_fbx.parse(str(path))
    except Exception:  # not a binary FBX, damaged: the importer's own error says so
        return []
    names: set[str] = set()
    todo = [root]
    while todo:
        e = todo.pop()
        for c in e.elems:
            if c.id == b"Video":
                props = {cc.id: cc.props for cc in c.elems}
                content = props.get(b"Content")
                if content and isinstance(content[0], bytes) and len(content[0]) > 0:
                    continue  # embedded
                for key in (b"RelativeFilename", b"Filename", b"FileName"):
                    val = props.get(key)
                    if val and isinstance(val[0], bytes) and val[0].strip():
                        names.add(val[0].decode(errors="replace").replace("\\", "/"))
                        break
            else:
                todo.append(c)
    return sorted(names)


def _blend_image_files(path: Path) -> list[str]:
    """The image files a .blend uses and does not pack, relative to its folder where they lie under it (else
    absolute), sorted; its images are appended for a moment to read their paths, then removed."""
    if _is_open_file(path):
        return []  # the render's own reading refuses it
    with _borrowed():
        with bpy.data.libraries.load(str(path), link=False) as (src, dst):
            dst.images = list(src.images)
        return sorted({_name_beside(path, im.filepath, im.library) for im in dst.images
                       if im is not None and _external_image(im)})
    return []  # unreadable: the render's own reading says so


def _is_open_file(path: Path) -> bool:
    """Whether ``path`` is the .blend open in this Blender (which it cannot read as a library)."""
    return bool(bpy.data.filepath) and Path(bpy.data.filepath).resolve() == Path(path).resolve()


class _borrowed:
    """Everything a block adds to ``bpy.data`` (data blocks and the library entries they came through) is removed
    when it ends, so reading another .blend leaves nothing in the open file. A block that raises OSError or
    ValueError (an unreadable file, or the open file itself) is ended quietly, and the code after the block
    runs."""

    def __enter__(self):
        self.before = snapshot_data(all_id_collections())
        return self

    def __exit__(self, kind, value, tb):
        remove_new_data(self.before)
        return kind is not None and issubclass(kind, (OSError, ValueError))


def _external_image(im) -> bool:
    return im.packed_file is None and im.source in ("FILE", "SEQUENCE", "MOVIE") and bool(im.filepath)


def _name_beside(path: Path, filepath: str, library) -> str:
    """A Blender file path (``//`` relative to ``library``'s file, or the open one) as the hash names it: relative to
    the .blend ``path``'s folder where it lies under it, else absolute."""
    return _relative_name(_blender_file(filepath, library), Path(path).parent)


def _blender_file(filepath: str, library) -> Path:
    """A Blender file path (``//`` relative to ``library``'s file, or the open one's; Windows separators) resolved."""
    return Path(bpy.path.abspath(filepath, library=library).replace("\\", "/")).resolve()


def _relative_name(f: Path, base: Path | None) -> str:
    """``f`` relative to the folder ``base`` where it lies under it, else absolute."""
    base = Path(base).resolve() if base is not None else None
    return str(f.relative_to(base)) if base is not None and f.is_relative_to(base) else str(f)


def _blend_library_files(path: Path) -> list[str]:
    """The other .blend files a .blend's scenes link data from, directly or through each other, and the image
    files that linked data uses and does not pack, sorted ([] for a file that links nothing, so such a file's
    ``linked_files_hash`` is what it was before libraries were counted). Its scenes are linked for a moment to
    read them, then removed with every library entry that came along."""
    me = Path(path).resolve()
    if _is_open_file(me):
        return []  # the render's own reading refuses it (Blender 4.2 crashes linking the open file's scenes)
    with _borrowed():
        with bpy.data.libraries.load(str(path), link=True) as (src, dst):
            dst.scenes = list(src.scenes)
        libs = [lib for lib in bpy.data.libraries
                if Path(bpy.path.abspath(lib.filepath, library=lib.parent)).resolve() != me
                and _links_from(lib, me)]
        names = {_name_beside(path, lib.filepath, lib.parent) for lib in libs if lib.packed_file is None}
        inside = {lib.as_pointer() for lib in libs}
        names |= {_name_beside(path, im.filepath, im.library) for im in bpy.data.images
                  if im.library is not None and im.library.as_pointer() in inside and _external_image(im)}
        return sorted(names)
    return []  # unreadable: the render's own reading says so


def _links_from(lib, me: Path) -> bool:
    """Whether the library entry ``lib`` was reached through the .blend ``me`` (its parent chain leads there)."""
    while lib.parent is not None:
        lib = lib.parent
        if Path(bpy.path.abspath(lib.filepath, library=lib.parent)).resolve() == me:
            return True
    return False


def _obj_material_libraries(path: Path) -> list[Path]:
    """The material libraries an OBJ's ``mtllib`` lines name that are there (:func:`_mtllib_lines`), in order."""
    return [f for _, found, _ in _mtllib_lines(path) for f in found]


def _mtllib_lines(path: Path) -> list[tuple[str, list[Path], list[str]]]:
    """Each ``mtllib`` line of an OBJ: (the line, the files it names that are there, the names that are not). A line
    may name several files (the OBJ specification), a Windows path or another letter case; each is looked for as
    :func:`find_beside` does. The whole rest of the line is tried first, as Blender's importer reads it (a name
    with spaces). The OBJ is read once per version of it (the hashes, the import and its warning all ask); the
    libraries are looked for at each call."""
    path = Path(path)
    try:
        st = path.stat()
    except OSError:
        return []
    out = []
    for line in _mtllib_text_lines(str(path), st.st_mtime_ns, st.st_size):
        rest = line[6:].strip()
        whole = path.parent / rest
        if whole.is_file():
            out.append((line, [whole], []))
            continue
        found, missing = [], []
        for name in rest.split():
            f = find_beside(path.parent, name)
            (found.append(f) if f is not None else missing.append(name))
        out.append((line, found, missing))
    return out


@functools.lru_cache(maxsize=16)
def _mtllib_text_lines(path: str, _mtime_ns: int, _size: int) -> tuple[str, ...]:
    """An OBJ's ``mtllib`` lines that name something (cached by the file's path, modification time and size)."""
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as f:
            return tuple(ln for ln in f if ln.startswith("mtllib") and ln[6:7].isspace() and ln[6:].strip())
    except OSError:
        return ()


def _obj_for_blender(path: Path, tmp: Path) -> Path:
    """The OBJ to hand Blender's importer: the file itself when each ``mtllib`` line names one library as written,
    else a copy in ``tmp`` whose ``mtllib`` lines name each library found by its path from there, one a line (Blender
    reads the rest of the line as one name, in the letter case written, so a line of several names, a Windows path
    or another case lost every colour without a word)."""
    lines = _mtllib_lines(path)
    if all(len(found) == 1 and not missing and found[0] == path.parent / line[6:].strip()
           for line, found, missing in lines):
        return path
    def named(f: Path) -> str:  # Blender joins the OBJ's folder and the name, even an absolute one
        try:
            return os.path.relpath(f.resolve(), tmp.resolve())
        except ValueError:  # another drive (Windows): the library beside the copy; its textures are then
            shutil.copy2(f, tmp / f.name)  # found beside the mesh (drop_missing_textures)
            return f.name

    import shutil

    fixes = {line: "".join(f"mtllib {named(f)}\n" for f in found) for line, found, _ in lines}
    out = tmp / path.name
    with open(path, "r", encoding="utf-8", errors="surrogateescape", newline="") as src, \
            open(out, "w", encoding="utf-8", errors="surrogateescape", newline="") as dst:
        for line in src:
            dst.write(fixes.get(line.replace("\r\n", "\n"), line) if line.startswith("mtllib") else line)
    return out


def missing_material_libraries(path: Path) -> list[str]:
    """The material libraries an OBJ names that are nowhere beside it (its materials then render a default grey)."""
    return sorted({name for _, _, missing in _mtllib_lines(path) for name in missing})
