"""Render a ShapeNet-style multi-view dataset: the one core function behind the operator and the CLI.

``render_dataset(cfg)`` is a generator (see ``progress.py``): it yields a :class:`Progress` after
every view and returns a :class:`RenderSummary`. The CLI drives it with a tqdm bar; the modal
operator steps it on a timer and cancels with ``close()``.

How a view is made: every dataset object is loaded into a private scene (the user's scenes and
objects are never modified) and normalized like ShapeNet. The colour is one render per camera with
the chosen engine (Cycles by default, anti-aliased) into a multi-layer EXR. The data passes (depth,
normals, object and part ids) are not rendered: ``raster.py`` computes them exactly for the ray
through each pixel centre (the convention of ``geometry/cameras.py``) from the object's triangles,
which are read once per object; they match a 1-sample, zero-filter Cycles render pixel for pixel
(``tests/test_raster.py``) at a fraction of its cost. numpy turns them into the dataset files: RGB
composited on white (or RGBA) with the sRGB transfer function (what Blender's "Standard" view
transform applies), planar z-depth and world normals as float32 EXR, and the part-id mask. A writer
thread rasterizes and writes view i while Cycles renders view i + 1 (the render releases the GIL).

What each view was rendered from is recorded (``source_hash`` in ``meta.json``, and for a mesh file
``linked_files_hash``: the textures and buffers it names) and checked on resume, and a finished view
counts only if its files are intact (a truncated PNG is rendered again).

Runs: an object folder is held (``guards.output_lock``) while it is checked and rendered, so a second run reaching
it is refused in one line (shards rendering into one folder hold different objects and go on side by side), and
what a killed run was writing there (temporary names) is removed first. The dataset root is held only for a moment
(:func:`root_held`: its manifest's check and write, the split lists, the sweep of what killed runs left there), and a
run registers itself there until it ends (:func:`dataset_run`): a run with other settings, ``--force`` or not, is
refused while one renders, since it would replace the manifest that run's objects are described by.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import itertools
import json
import math
import os
import re
import shutil
import signal
import tempfile
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import bpy
import numpy as np

from .. import __version__
from ..datasets import format as F
from ..errors import InputError, OutputError
from ..geometry import cameras as C
from ..geometry import rigs
from ..guards import LOCK_FILE, output_lock, sweep_partials
from ..progress import Progress, ProgressGen
from . import compat
from . import objects as O
from . import raster
from .camera import apply_intrinsics, apply_pose, new_camera, read_camera, render_size, set_clip

ENGINES = ("CYCLES", "BLENDER_EEVEE", "BLENDER_WORKBENCH")
MAX_RESOLUTION = 8192
MAX_VIEWS = 10000
"""Views per object at most (NeRF-synthetic uses 100-400, SRN 50-250): a typo cannot queue days of work."""


@dataclass(frozen=True)
class RenderConfig:
    """What ``render-dataset`` renders, and how."""

    out: Path
    """Dataset root folder."""
    sources: tuple[str, ...]
    """Source strings: mesh files, folders (ShapeNetCore or mesh files), 'selected', 'procedural:<cat>:<seed>'."""
    rig: str = "sphere"
    """Camera rig: sphere, hemisphere, spiral, turntable or scene."""
    views: int = 24
    """Views per object (the scene rig uses every camera of the scene)."""
    resolution: tuple[int, int] = (128, 128)
    """Image width and height in pixels."""
    engine: str = "CYCLES"
    """Render engine for colour: CYCLES, BLENDER_EEVEE or BLENDER_WORKBENCH."""
    samples: int = 32
    """Samples per pixel (Cycles, EEVEE)."""
    rgba: bool = False
    """Write RGBA images instead of compositing on white."""
    fov_deg: float = 40.0
    """Horizontal field of view of generated cameras; the distance adapts so the object fills the frame."""
    elevation_deg: float = 20.0
    """Elevation of the turntable rig."""
    seed: int = 0
    """Seed of random rigs and of the train/val/test assignment."""
    category: str | None = None
    """Category folder for sources that have none (mesh files, selected objects)."""
    shard: tuple[int, int] = (0, 1)
    """(i, n): render only objects whose index modulo n is i (deterministic split of the work)."""
    force: bool = False
    """Overwrite an output folder that holds another dataset or other files."""
    split: str | None = None
    """Put every object of this run into this split (train/val/test); None = seeded by the fractions."""
    split_fractions: tuple[float, float, float] = (0.8, 0.1, 0.1)
    """Train/val/test shares for the seeded assignment."""
    fov_range_deg: tuple[float, float] | None = None
    """Sphere / hemisphere rigs: draw each view's horizontal field of view from this range (degrees) and its
    distance from ``distance_range``, seeded per object (``rigs.varied_cameras``); None = one ``fov_deg``."""
    distance_range: tuple[float, float] | None = None
    """With ``fov_range_deg``: camera distance as multiples of the framing distance at the view's field of view."""
    elevation_range_deg: tuple[float, float] | None = None
    """With ``fov_range_deg``: keep the directions to this band of elevations (degrees); None = the whole rig."""
    skip_bad_meshes: bool = False
    """Skip a mesh file that cannot be read or is refused (no faces, NaN coordinates, ...) and go on with the next,
    naming it in the summary's warnings, instead of stopping at it (a folder of thousands of meshes). Not a
    dataset setting: it changes no render."""
    scene_cameras: tuple | None = None
    """The scene rig's cameras (names, intrinsics at the dataset's resolution, poses: ``_cameras_record``), which
    ``render_dataset`` fills in from the scene: another set of cameras is another dataset. Not a user option."""

    def validate(self) -> None:
        try:  # OpenEXR writes depth and normals only under UTF-8 paths (a ValueError, after a half-written object)
            str(self.out).encode("utf-8")
        except UnicodeEncodeError:
            raise InputError(f"output folder {str(self.out).encode('utf-8', 'surrogateescape')!r}: its name is not "
                             "UTF-8 text, which the EXR writer cannot write into; rename it") from None
        w, h = self.resolution
        if not (isinstance(w, int) and isinstance(h, int)) or w < 1 or h < 1:
            raise InputError(f"resolution must be at least 1x1, got {w}x{h}")
        if w > MAX_RESOLUTION or h > MAX_RESOLUTION:
            raise InputError(f"resolution {w}x{h} exceeds the maximum of {MAX_RESOLUTION}")
        if self.rig not in rigs.RIGS:
            raise InputError(f"unknown rig {self.rig!r}; choose one of {', '.join(rigs.RIGS)}")
        if self.rig != "scene" and self.views < 1:
            raise InputError(f"number of views must be at least 1, got {self.views}")
        if self.rig != "scene" and self.views > MAX_VIEWS:
            raise InputError(f"number of views must be at most {MAX_VIEWS} per object, got {self.views}")
        if self.engine not in ENGINES:
            raise InputError(f"unknown engine {self.engine!r}; choose one of {', '.join(ENGINES)}")
        if self.samples < 1:
            raise InputError(f"samples must be at least 1, got {self.samples}")
        if not 0.0 < self.fov_deg < 180.0:
            raise InputError(f"field of view must be between 0 and 180 degrees, got {self.fov_deg:g}")
        i, n = self.shard
        if n < 1 or not 0 <= i < n:
            raise InputError(f"shard must be i/n with 0 <= i < n, got {i}/{n}")
        if self.split is not None and self.split not in F.SPLITS:
            raise InputError(f"split must be one of {', '.join(F.SPLITS)}, got {self.split!r}")
        if (self.fov_range_deg is None) != (self.distance_range is None):
            raise InputError("varied cameras need both a field of view range and a distance range")
        if self.elevation_range_deg is not None and self.fov_range_deg is None:
            raise InputError("an elevation range needs varied cameras (a field of view range and a distance range)")
        if self.fov_range_deg is not None:
            if self.elevation_range_deg is not None:
                rigs.check_elevation_range(self.rig, self.elevation_range_deg)
            if self.rig not in rigs.VARIED_RIGS:
                raise InputError(f"varied field of view and distance need the sphere or hemisphere rig, got {self.rig!r}")
            f0, f1 = self.fov_range_deg
            d0, d1 = self.distance_range
            if not 0.0 < f0 <= f1 < 180.0:
                raise InputError(f"field of view range must lie within (0, 180) degrees, got {f0:g},{f1:g}")
            if not 0.0 < d0 <= d1 <= 100.0:
                raise InputError(f"distance range must be positive multiples up to 100, got {d0:g},{d1:g}")
        fr = self.split_fractions
        if len(fr) != 3 or min(fr) < 0 or not math.isclose(sum(fr), 1.0, abs_tol=1e-6):
            raise InputError(f"split fractions must be three non-negative numbers summing to 1, got {fr}")

    def settings(self) -> dict:
        """What makes two renders of the same object the same dataset (resume / overwrite checks)."""
        d = {"rig": self.rig, "views": self.views if self.rig != "scene" else None,
             "resolution": list(self.resolution), "engine": self.engine, "samples": self.samples,
             "rgba": self.rgba, "fov_deg": self.fov_deg,
             "elevation_deg": self.elevation_deg if self.rig == "turntable" else None,
             "seed": self.seed}
        if self.rig == "scene" and self.scene_cameras is not None:
            d["scene_cameras"] = [list(c) for c in self.scene_cameras]
        if self.fov_range_deg is not None:  # only then: settings of earlier datasets stay byte-identical
            d.update({"fov_range_deg": list(self.fov_range_deg), "distance_range": list(self.distance_range),
                      "camera_seed": "per object"})
            if self.elevation_range_deg is not None:
                d["elevation_range_deg"] = list(self.elevation_range_deg)
        return d


@dataclass
class RenderSummary:
    out: Path
    objects: list[str] = field(default_factory=list)
    views_rendered: int = 0
    views_skipped: int = 0
    seconds: float = 0.0
    warnings: list[str] = field(default_factory=list)
    """One line each, for the end of the run: what was rendered other than the sources asked (missing textures) or
    not at all (meshes skipped by ``skip_bad_meshes``)."""
    skipped: list[str] = field(default_factory=list)
    """Objects left out as unusable meshes (``skip_bad_meshes``; each also a warning)."""
    per_view_intrinsics: list[str] = field(default_factory=list)
    """Objects rendered in this run whose views differ in intrinsics (the SRN ``intrinsics.txt`` holds the first
    view's: one warning at the end names them)."""
    started: float = 0.0
    """``time.perf_counter()`` when the first object was started."""
    viewport_grey: list[str] = field(default_factory=list)
    """Materials a Workbench run drew in their default grey Viewport Display colour while their shaders are coloured
    (``objects.viewport_grey_materials``; one warning at the end names them)."""

    @property
    def views_per_second(self) -> float:
        return self.views_rendered / self.seconds if self.seconds > 0 else 0.0


# --------------------------------------------------------------------------------------------
# Output folder
# --------------------------------------------------------------------------------------------

def _settings_diff(a: dict, b: dict) -> str:
    def one(k):
        va, vb = a.get(k), b.get(k)
        if k == "scene_cameras" and isinstance(va, list) and isinstance(vb, list):
            return (f"scene_cameras {len(va)} cameras != {len(vb)} cameras" if len(va) != len(vb) else
                    "scene_cameras: the cameras' names, intrinsics or poses differ")
        return f"{k} {va} != {vb}"

    said = ", ".join(one(k) for k in F.differing_settings(a, b)[:3])
    if (a.get("rig") == b.get("rig") == "scene" and isinstance(a.get("resolution"), list)
            and a.get("resolution") != b.get("resolution")):  # one --resolution number: the scene's frame shape
        said += ("; with --rig scene one --resolution number is the longer side of the scene's frame (since session "
                 f"54; R meant RxR before), so --resolution {'x'.join(map(str, a['resolution']))} resumes this dataset")
    return said


RUN_PREFIX = ".mrvm-run-"
"""A run's registration in a dataset root (``.mrvm-run-XXXXXXXX``, a hidden folder holding ``run.json``): held
(``guards.output_lock``) from the run's check of the root until it ends, so that another run can tell it is live."""

# What this code writes for a moment in a dataset root, by ``tempfile``'s names (8 of ``[a-z0-9_]``): the write
# probe, the root manifest's and the split lists' atomic writes (``format.atomic_write``), capture sets' protocol file.
_ROOT_TEMPORARY = re.compile(r"\.write-test-[a-z0-9_]{8}|\." + re.escape(F.ROOT_MANIFEST) + r"\.[a-z0-9_]{8}\.json")
_SPLITS_TEMPORARY = re.compile(r"\.(?:train|val|test)\.lst\.[a-z0-9_]{8}\.lst|\.eval_views\.json\.[a-z0-9_]{8}\.json")
_RUN_NAME = re.compile(re.escape(RUN_PREFIX) + r"[a-z0-9_]{8}")
ROOT_WAIT_S = 600.0
"""How long a run waits for another to let go of the dataset root (held for a moment: its manifest's check and
write, the split lists) before it gives up, naming the holder."""


def _own_temporary(name: str) -> bool:
    """A name this code has in a dataset root for a while: the root's lock, a live run's registration, the write probe,
    the manifest's atomic write (another shard starting into the same new folder at the same time has them there)."""
    return name == LOCK_FILE or name.startswith((".write-test-", f".{F.ROOT_MANIFEST}.", RUN_PREFIX))


@contextlib.contextmanager
def root_held(out: Path, wait_s: float | None = None):
    """Hold the dataset root ``out`` (``guards.output_lock`` on ``<out>/.lock``; created when missing) for a moment:
    the check and write of its manifest, the split lists, the sweep of what killed runs left there. Every write into
    the root itself happens under it, so a sweep under it removes nothing a live run is about to rename. Shards wait
    for each other here (up to ``wait_s``, default :data:`ROOT_WAIT_S`) instead of refusing."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output path {out} exists and is not a folder")
    deadline = time.monotonic() + (ROOT_WAIT_S if wait_s is None else wait_s)
    with contextlib.ExitStack() as stack:
        for attempt in itertools.count():
            try:
                out.mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise OutputError(f"output folder {out} is not writable ({e.strerror or e})") from None
            try:
                stack.enter_context(output_lock(out, "dataset folder"))
                break
            except OutputError:  # another run holds it for a moment
                if time.monotonic() >= deadline:
                    raise
                time.sleep(0.05)
            except FileNotFoundError as e:  # removed as we came (empty, by a run refused in the new folder): again
                if attempt >= 20:
                    raise OutputError(f"output folder {out} is not writable ({e.strerror or e})") from None
            except OSError as e:
                if e.errno == errno.ENOLCK:  # (an NFS mount without its lock service)
                    raise OutputError(f"output folder {out}: its file system does not lock files ({e.strerror}), "
                                      "which runs and shards sharing it need; mount it with locks or render into a "
                                      "local folder") from None
                raise OutputError(f"output folder {out} is not writable ({e.strerror or e})") from None
        yield out


def _run_record(reg: Path) -> str:
    """How a live run's registration names it: pid, host and start time."""
    try:
        r = json.loads((reg / "run.json").read_text())
        return f"pid {r['pid']} on {r['host']}, started {r['started']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "pid unknown"


def live_runs(out: Path) -> list[tuple[str, dict | None]]:
    """Under :func:`root_held`: the runs rendering into ``out`` now (each as its words and its settings); the
    registrations no one holds (a killed run's) are removed on the way."""
    found = []
    for reg in sorted(Path(out).iterdir()):
        if not (_RUN_NAME.fullmatch(reg.name) and reg.is_dir() and not reg.is_symlink()):
            continue
        try:
            with output_lock(reg, "run"):  # no one holds it: the run that made it is gone
                shutil.rmtree(reg, ignore_errors=True)
        except OutputError:
            try:
                settings = json.loads((reg / "run.json").read_text()).get("settings")
            except (OSError, ValueError, AttributeError):
                settings = None
            found.append((_run_record(reg), settings))
    return found


def sweep_root(out: Path) -> list[tuple[str, dict | None]]:
    """Under :func:`root_held`: remove the temporary files killed runs left in the dataset root and its ``splits/``
    (only this code's names; no live run can be writing them: it writes them under the same hold) and the
    registrations of runs that are gone; return the live runs (:func:`live_runs`)."""
    out = Path(out)
    live = live_runs(out)
    for folder, names in ((out, _ROOT_TEMPORARY), (out / "splits", _SPLITS_TEMPORARY)):
        if not folder.is_dir() or folder.is_symlink():
            continue
        for p in folder.iterdir():
            if names.fullmatch(p.name) and p.is_file() and not p.is_symlink():
                with contextlib.suppress(OSError):
                    p.unlink()
    return live


def _refuse_other_runs(out: Path, settings: dict) -> None:
    """Under :func:`root_held`: sweep the root (:func:`sweep_root`) and refuse when a live run renders into it with
    other settings (``--force`` would replace the manifest its objects are described by)."""
    for words, theirs in sweep_root(out):
        if not F.settings_match(theirs, settings):
            diff = _settings_diff(theirs, settings) if isinstance(theirs, dict) else "unknown settings"
            raise OutputError(f"{out} is being rendered by another run ({words}) with other settings "
                              f"({diff}); wait for it to end or stop it, or choose another folder "
                              "(--force replaces a dataset no run is rendering)")


def prepare_root(cfg) -> None:
    """:func:`prepare_output` as :func:`dataset_run` does it, without registering a run: the root held, swept, and
    refused while a run of other settings renders into it (``make-shapenet`` checks its folder so before recording
    its plan)."""
    with root_held(Path(cfg.out)):
        _refuse_other_runs(Path(cfg.out), cfg.settings())
        prepare_output(cfg)


@contextlib.contextmanager
def dataset_run(cfg):
    """A run into the dataset root ``cfg.out`` (a :class:`RenderConfig`, or anything with ``out``, ``force`` and
    ``settings()``): with the root held, sweep what killed runs left there, refuse when a live run renders into it
    with other settings (``--force`` would replace the manifest its objects are described by; shards with the same
    settings go on side by side), check and write the manifest (:func:`prepare_output`) and register this run, which
    stays registered until the block ends."""
    import datetime
    import socket

    out = Path(cfg.out)
    settings = cfg.settings()
    with contextlib.ExitStack() as run:
        with root_held(out):
            _refuse_other_runs(out, settings)
            prepare_output(cfg)
            reg = Path(tempfile.mkdtemp(prefix=RUN_PREFIX, dir=out))  # (a full disk: the CLI's one line says so)
            run.callback(shutil.rmtree, reg, True)  # (last: after the hold below is let go)
            run.enter_context(output_lock(reg, "run"))
            F.atomic_write_json(reg / "run.json", {
                "pid": os.getpid(), "host": socket.gethostname(),
                "started": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
                "settings": settings})
        yield out


def prepare_output(cfg: RenderConfig) -> None:
    """Check the dataset root and write its manifest; refuse to mix with another dataset unless ``force``. Called
    with the root held (:func:`dataset_run`)."""
    out = Path(cfg.out)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output path {out} exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=out)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise OutputError(f"output folder {out} is not writable ({e.strerror or e})") from None
    manifest = out / F.ROOT_MANIFEST
    settings = cfg.settings()
    if manifest.exists():
        try:
            old = json.loads(manifest.read_text())
        except (OSError, ValueError):
            old = {}
        if not F.settings_match(old.get("settings"), settings) and not cfg.force:
            raise OutputError(f"{out} holds a dataset rendered with other settings "
                              f"({_settings_diff(old.get('settings') or {}, settings)}); "
                              "use --force (in the panel: Overwrite) to overwrite it or choose another folder")
    elif any(p.name != F.ROOT_MANIFEST and not _own_temporary(p.name) for p in out.iterdir()) and not cfg.force:
        raise OutputError(f"{out} is not empty and holds no blender_mrvm dataset; "
                          "use --force (in the panel: Overwrite) to write into it or choose an empty folder")
    F.atomic_write_json(manifest, {"format": "blender_mrvm dataset", "format_version": F.FORMAT_VERSION,
                                   "generator": f"blender_mrvm {__version__}", "settings": settings})


def object_camera_seed(cfg: RenderConfig, key: str) -> int:
    """The seed of an object's varied cameras: the run's seed and the object's key (other objects, other views)."""
    return int(hashlib.sha1(f"cameras:{cfg.seed}:{key}".encode()).hexdigest()[:8], 16)


def assign_split(cfg: RenderConfig, key: str) -> str:
    if cfg.split:
        return cfg.split
    u = int(hashlib.sha1(f"{cfg.seed}:{key}".encode()).hexdigest()[:8], 16) / 2**32
    tr, va, _ = cfg.split_fractions
    return "train" if u < tr else ("val" if u < tr + va else "test")


def write_splits(root: Path, settings: dict | None = None, only: set[str] | None = None) -> dict[str, list[str]]:
    """Rewrite ``splits/*.lst`` from the finished objects on disk that match ``settings`` (default: the
    root manifest's); ``only``: of these objects (``category/object_id``) alone.

    Shards rendering into one folder each rewrite the lists when they finish; one that read the folder just before
    another's last object was finished, and wrote just after it, would leave that object out. So the lists are read
    again after writing, and written again until what was written is what is on disk: every object finished before
    a shard's last write is then in the lists (each list is replaced whole, atomically, on any filesystem). The root is
    held meanwhile (:func:`root_held`): shards write the lists one at a time, and a sweep of the root removes no
    list's temporary file that a live run is about to rename."""
    with root_held(root):
        return write_splits_held(root, settings, only)


def write_splits_held(root: Path, settings: dict | None = None, only: set[str] | None = None) -> dict[str, list[str]]:
    """:func:`write_splits` with the root already held (:func:`root_held`, which is not re-entrant)."""
    root = Path(root)
    if settings is None:
        settings = json.loads((root / F.ROOT_MANIFEST).read_text()).get("settings")
    splits = _finished_splits(root, settings, only)
    for _ in range(100):  # each round needs another object finished meanwhile: a handful at most
        for s, entries in splits.items():
            F.write_split(root, s, entries)
        again = _finished_splits(root, settings, only)
        if again == splits:
            break
        splits = again
    return splits


def _finished_splits(root: Path, settings, only: set[str] | None) -> dict[str, list[str]]:
    """The finished objects on disk that match ``settings`` (and are in ``only``), by their recorded split."""
    splits: dict[str, list[str]] = {s: [] for s in F.SPLITS}
    for meta_path in sorted(root.glob("*/*/meta.json")):
        try:
            meta = json.loads(meta_path.read_text())
        except (ValueError, FileNotFoundError):  # not valid JSON, or removed by another shard meanwhile
            continue
        key = f"{meta.get('category')}/{meta.get('object_id')}"
        if (meta.get("complete") and F.settings_match(meta.get("settings"), settings) and meta.get("split") in splits
                and (only is None or key in only)):
            splits[meta["split"]].append(key)
    return splits


# --------------------------------------------------------------------------------------------
# The private render scene
# --------------------------------------------------------------------------------------------

class RenderSession:
    """A private scene holding one dataset object, a camera, a light and a world.

    Everything it creates is removed by :meth:`close`, also after an error or a cancel.
    """

    def __init__(self, cfg: RenderConfig, tmpdir: Path):
        self.cfg = cfg
        self.tmpdir = tmpdir
        self._before = O.snapshot_data()
        self._scenes_before = {s.as_pointer() for s in bpy.data.scenes}
        self._had_render_result = any(im.type == "RENDER_RESULT" for im in bpy.data.images)
        self._own: dict[str, set[int]] | None = None  # what the session made, once sealed
        self._own_scenes: set[int] | None = None
        self.scene = bpy.data.scenes.new("MRVM_render")
        self.coll = bpy.data.collections.new("MRVM_objects")
        self.scene.collection.children.link(self.coll)
        self._setup_world_and_light()
        self.camera = new_camera("MRVM_camera", self.coll)
        self.scene.camera = self.camera
        if cfg.engine == "CYCLES":
            self._setup_cycles(self.scene, cfg.samples)
        else:
            compat.set_engine(self.scene, cfg.engine)
            self._setup_common(self.scene)
            if cfg.engine == "BLENDER_EEVEE":
                self.scene.eevee.taa_render_samples = cfg.samples
            else:
                self.scene.display.shading.light = "STUDIO"
                self.scene.display.shading.color_type = "MATERIAL"
                self.scene.display.render_aa = "8"
        self.scene.render.filepath = str(tmpdir / f"{self.scene.name}.exr")

    @property
    def view_layer(self) -> bpy.types.ViewLayer:
        return self.scene.view_layers[0]

    def _setup_common(self, sc: bpy.types.Scene) -> None:
        w, h = self.cfg.resolution
        r = sc.render
        r.resolution_x, r.resolution_y, r.resolution_percentage = w, h, 100
        r.pixel_aspect_x = r.pixel_aspect_y = 1.0
        r.film_transparent = True
        r.use_file_extension = False
        s = r.image_settings
        compat.set_file_format(s, "OPEN_EXR_MULTILAYER")
        s.color_depth = "32"
        s.exr_codec = "NONE"
        _rec709_exr(s)
        sc.view_settings.view_transform = "Standard"
        sc.view_layers[0].use_pass_z = False  # colour only: the data passes are rasterized

    def _setup_cycles(self, sc: bpy.types.Scene, samples: int) -> None:
        sc.render.engine = "CYCLES"
        self._setup_common(sc)
        cy = sc.cycles
        cy.device = "CPU"
        cy.samples = samples
        cy.use_denoising = False
        cy.use_adaptive_sampling = samples > 1
        cy.seed = 0
        cy.use_animated_seed = False
        cy.max_bounces, cy.diffuse_bounces, cy.glossy_bounces = 4, 2, 2
        cy.transmission_bounces, cy.transparent_max_bounces, cy.volume_bounces = 4, 8, 0
        sc.render.use_persistent_data = True

    def _setup_world_and_light(self) -> None:
        world = bpy.data.worlds.new("MRVM_world")
        bg = next(n for n in compat.node_tree(world).nodes if n.type == "BACKGROUND")
        bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        bg.inputs["Strength"].default_value = 0.6
        self.scene.world = world
        sun = bpy.data.lights.new("MRVM_sun", "SUN")
        sun.energy = 2.5
        sun.angle = math.radians(10)
        ob = bpy.data.objects.new("MRVM_sun", sun)
        ob.rotation_euler = (math.radians(40), math.radians(10), math.radians(30))
        self.coll.objects.link(ob)

    def seal(self) -> None:
        """Record what the session made: its scene and what loading the object made. Called once the object is
        loaded, in the same step as ``__init__``: the views render one a step from the panel's modal operator, and
        what the user (or another job) creates between the steps is theirs: :meth:`close` removed it all."""
        now = O.snapshot_data()
        self._own = {name: now[name] - self._before[name] for name in now}
        self._own_scenes = {s.as_pointer() for s in bpy.data.scenes} - self._scenes_before

    def close(self) -> None:
        """Remove what the session made (before :meth:`seal`, in the step that made it: everything new)."""
        own_scenes = self._own_scenes
        for sc in [s for s in bpy.data.scenes if s.as_pointer() not in self._scenes_before
                   and (own_scenes is None or s.as_pointer() in own_scenes)]:
            bpy.data.scenes.remove(sc)
        if self._own is None:
            O.remove_new_data(self._before)
        else:
            O.remove_data(self._own)
        if not self._had_render_result:  # the image the renders made (Blender makes it at the first one)
            for im in [im for im in bpy.data.images if im.type == "RENDER_RESULT"]:
                bpy.data.images.remove(im)

    # ------------------------------------------------------------------
    def render_colour(self, box: tuple[int, int, int, int] | None) -> dict[str, dict[str, np.ndarray]]:
        """Render the colour, only inside ``box`` (inclusive pixel ranges i0, i1, j0, j1) when given.

        Outside the box nothing of the object can reach a pixel (``raster.pixel_box`` widens the
        object's projection by the pixel filter's reach), so those pixels are transparent black in a
        full render too; inside it Cycles samples exactly as in a full render (its sampling pattern
        depends on the pixel, not on the border), so the image is the same, bit for bit, and the
        background pixels around the object cost nothing. If the box's outer ring is not empty after
        all (geometry that the mesh does not describe, such as displacement), the full image is rendered.
        """
        r = self.scene.render
        w, h = r.resolution_x, r.resolution_y
        if box is not None and box == (0, w - 1, 0, h - 1):
            box = None
        if box is None:
            r.use_border = False
            return self.render_passes()
        i0, i1, j0, j1 = box
        r.use_border, r.use_crop_to_border = True, False
        # Blender's border is in fractions of the image, y up from the bottom.
        r.border_min_x, r.border_max_x = i0 / w, (i1 + 1) / w
        r.border_min_y, r.border_max_y = (h - 1 - j1) / h, (h - j0) / h
        passes = self.render_passes()
        a = passes["Combined"]["A"]
        ring = [a[j0, i0:i1 + 1] if j0 > 0 else None, a[j1, i0:i1 + 1] if j1 < h - 1 else None,
                a[j0:j1 + 1, i0] if i0 > 0 else None, a[j0:j1 + 1, i1] if i1 < w - 1 else None]
        if a.shape != (h, w) or any(x is not None and x.any() for x in ring):
            r.use_border = False
            return self.render_passes()
        return passes

    def render_passes(self, scene: bpy.types.Scene | None = None) -> dict[str, dict[str, np.ndarray]]:
        """Render ``scene`` (default: the session's) and return ``{pass name: {channel: (H, W) array}}``."""
        scene = scene or self.scene
        with O.quiet_stdout():
            bpy.ops.render.render(write_still=True, scene=scene.name)
        return compat.exr_passes(F.read_exr_parts(Path(scene.render.filepath)))


# --------------------------------------------------------------------------------------------
# Per-view outputs
# --------------------------------------------------------------------------------------------

REC709 = "Linear Rec.709"
"""The colour space of the EXR the colour is rendered into, whose numbers :func:`rgb_image` encodes as sRGB."""


def working_space() -> str:
    """The open file's working colour space (Blender 5.0: File > Color Management; Linear Rec.709 before)."""
    cs = getattr(bpy.data, "colorspace", None)
    return str(getattr(cs, "working_space", "") or REC709)


def _rec709_exr(settings: bpy.types.ImageFormatSettings) -> None:
    """Make the EXR hold linear Rec.709 whatever the file's working colour space: a render's linear numbers are in
    the working space (ACEScg or Linear Rec.2020 in a file set so, Blender 5.0), and the dataset's sRGB PNGs encode
    Rec.709 numbers (the sRGB primaries), so ACEScg numbers written as they are would shift every colour. Blender
    converts on save with its own OpenColorIO config (the image-format override of the EXR's colour space), for
    every working space it offers. A Blender without the override (or an OCIO config without Linear Rec.709) can
    only render a Linear Rec.709 file: another working space is refused in one line."""
    try:
        settings.color_management = "OVERRIDE"
        settings.linear_colorspace_settings.name = REC709
    except (AttributeError, TypeError) as e:  # no such setting / no such colour space in this OCIO config
        with contextlib.suppress(AttributeError, TypeError):
            settings.color_management = "FOLLOW_SCENE"
        ws = working_space()
        if ws != REC709:
            raise InputError(f"cannot render from the working colour space {ws!r}: this Blender cannot convert it to "
                             f"{REC709} ({e}); set File > Color Management > Working Space to {REC709}") from None


def _combined_rgba(passes: dict) -> np.ndarray:
    c = passes["Combined"]
    return np.stack([c["R"], c["G"], c["B"], c["A"]], axis=-1).astype(np.float64)


def rgb_image(rgba_premult: np.ndarray, rgba_out: bool) -> np.ndarray:
    """Linear Rec.709 premultiplied RGBA (the EXR: :func:`_rec709_exr`) -> uint8 sRGB on white (H, W, 3) or straight
    RGBA (H, W, 4), both in linear light as Blender composites and un-premultiplies (``format.composite_on_white``
    reads the RGBA back as the image on white)."""
    rgb, a = rgba_premult[..., :3], np.clip(rgba_premult[..., 3:4], 0.0, 1.0)
    if not rgba_out:
        return F.to_uint8(F.linear_to_srgb(rgb + (1.0 - a)))
    with np.errstate(divide="ignore", invalid="ignore"):
        straight = np.where(a > 0, rgb / np.maximum(a, 1e-12), 0.0)
    return np.concatenate([F.to_uint8(F.linear_to_srgb(straight)), F.to_uint8(a)], axis=-1)


def part_mask(data: raster.DataPasses, labelled_ids: np.ndarray) -> np.ndarray:
    """Part ids: the material pass index for part-labelled objects, else the object pass index."""
    ob, ma = data.object_id, data.material_id
    is_labelled = labelled_ids[np.clip(ob, 0, len(labelled_ids) - 1)]
    return np.where(ob == 0, 0, np.where(is_labelled, ma, ob)).astype(np.uint8)


_TMP_NAMES = itertools.count()


def _replace_into(path: str, write) -> None:
    """Write a file through ``write(tmp)`` under a hidden name beside it, then rename it into place.

    The same promise as ``format.atomic_write`` (never half-written, ordinary permissions) with
    less per-file work: the folders exist, the name is unique to this process, the file is created
    with the umask's permissions. Five files a view made that the writer thread's largest cost."""
    folder, name = os.path.split(path)
    # (bounded: a long but legal name must not overflow the file system's 255 bytes)
    tmp = os.path.join(folder, f".{name[:40]}.{os.getpid()}.{next(_TMP_NAMES)}{os.path.splitext(name)[1][:16]}")
    try:
        write(tmp)
        F.replace_file(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _text_writer(text: str):
    def w(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
    return w


def write_view(obj_dir: Path, index: int, colour: dict, data: raster.DataPasses, labelled_ids: np.ndarray,
               rgba_out: bool, c2w_opencv: np.ndarray) -> None:
    """The five files of a view (the folders exist); the pose, written last, is its commit point."""
    base, name = str(obj_dir), F.view_name(index)
    path = {k: f"{base}/{k}/{name}{F.VIEW_EXT[k]}" for k in F.VIEW_DIRS}
    _replace_into(path["rgb"], F.png_writer(rgb_image(_combined_rgba(colour), rgba_out)))
    _replace_into(path["depth"], F.exr_writer({"Y": data.depth}))
    n = data.normal
    _replace_into(path["normal"], F.exr_writer({"R": n[..., 0], "G": n[..., 1], "B": n[..., 2]}))
    _replace_into(path["mask"], F.png_writer(part_mask(data, labelled_ids)))
    _replace_into(path["pose"], _text_writer(F.format_pose(c2w_opencv)))


_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"


def view_intact(obj_dir: Path, index: int) -> bool:
    """A finished view whose files are whole: PNGs end with their IEND chunk, EXRs decode, the pose
    parses. Files are written atomically, so this catches damage from outside (a truncated copy)."""
    paths = F.view_paths(obj_dir, index)
    try:
        for k in ("rgb", "mask"):
            with open(paths[k], "rb") as f:
                if f.seek(0, os.SEEK_END) < 67:  # smallest PNG
                    return False
                f.seek(-len(_PNG_END), os.SEEK_END)
                if f.read() != _PNG_END:
                    return False
        for k in ("depth", "normal"):
            ch = F.read_exr(paths[k])
            if not ch or any(v.size == 0 for v in ch.values()):
                return False
        return np.isfinite(F.read_srn_pose(paths["pose"])).all()
    except Exception:  # any unreadable file: the view is not finished
        return False


class _Writer:
    """One background thread that rasterizes and writes a view while the next one renders.

    At most one view is in flight; :meth:`wait` returns when it is on disk (or raises its error)."""

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="mrvm_write")
        self._pending: Future | None = None

    def submit(self, fn, *args) -> None:
        self.wait()
        self._pending = self._pool.submit(fn, *args)

    def wait(self) -> None:
        pending, self._pending = self._pending, None
        if pending is not None:
            try:
                pending.result()
            except OSError as e:
                raise OutputError(f"cannot write the dataset files ({e.strerror or e})") from None

    def close(self) -> None:
        try:
            self.wait()
        finally:
            self._pool.shutdown(wait=True)


# --------------------------------------------------------------------------------------------
# Cameras of an object
# --------------------------------------------------------------------------------------------

def _cameras_record(scene_cams: list[tuple[C.Intrinsics, np.ndarray, str]]) -> tuple:
    """The scene rig's cameras as the dataset's settings record them: per camera its name, intrinsics at the dataset's
    resolution (fx, fy, cx, cy, width, height) and pose (the top 3 rows of camera-to-world), to 6 decimals. Numbers,
    not a hash: a camera read again after Blender evaluates the scene moves by ~1e-7, which settings comparisons
    allow (``format.settings_match``) and a hash would not."""
    return tuple((name, *(round(float(x), 6) + 0.0 for x in [intr.fx, intr.fy, intr.cx, intr.cy, intr.width,
                                                               intr.height, *np.asarray(c2w)[:3].ravel()]))
                 for intr, c2w, name in scene_cams)


def _scene_cameras(user_scene: bpy.types.Scene, cfg: RenderConfig) -> list[tuple[C.Intrinsics, np.ndarray, str]]:
    """The cameras of the scene rig: those a render of ``user_scene``'s view layer could look through (in no
    collection excluded from it or hidden from renders, not hidden from renders themselves), by name, with their
    poses as the scene evaluates them at its frame (parents, constraints, animation)."""
    vl = bpy.context.view_layer if bpy.context.scene == user_scene and bpy.context.view_layer else \
        user_scene.view_layers[0]
    shown = O.render_shown(vl)
    cams = sorted((o for o in user_scene.objects if o.type == "CAMERA" and o.as_pointer() in shown),
                  key=lambda o: o.name)
    if not cams:
        left = [o.name for o in user_scene.objects if o.type == "CAMERA"]
        raise InputError("the 'scene' rig needs cameras in the scene; none found" if not left else
                         f"the 'scene' rig needs cameras a render of the scene shows; its camera(s) "
                         f"{', '.join(sorted(left)[:3])} are hidden from renders or in a collection excluded from "
                         "the view layer or hidden from renders")
    depsgraph = O._scene_depsgraph(user_scene)
    w, h = cfg.resolution
    out = []
    for cam in cams:
        # The camera's lens, sensor and shift at the dataset's resolution.
        with _temporary_resolution(user_scene, w, h):
            intr, c2w = read_camera(cam.evaluated_get(depsgraph), user_scene)
        out.append((intr, c2w, cam.name))
    return out


def scene_frame_size(scene: bpy.types.Scene, longer: int) -> tuple[int, int]:
    """The dataset size of the scene rig asked for as one number ``longer`` (``--resolution R``; the panel's
    Resolution): the scene's own frame shape, pixel aspect included, with its longer side ``longer`` pixels (square
    pixels), so the views show what the artist framed (a square frame would add or cut a band, by sensor fit)."""
    r = scene.render
    aspect = (r.resolution_x * r.pixel_aspect_x) / (r.resolution_y * r.pixel_aspect_y)
    if aspect >= 1.0:
        return longer, max(1, round(longer / aspect))
    return max(1, round(longer * aspect)), longer


def _frame_change(scene: bpy.types.Scene, w: int, h: int) -> str | None:
    """A warning when the scene rig's dataset frame (``w`` x ``h``, square pixels) shows another part of the view than
    the scene's frame does (another shape: a band added or cut, by the cameras' sensor fit), else None."""
    r = scene.render
    sw, sh = render_size(scene)
    aspect = (r.resolution_x * r.pixel_aspect_x) / (r.resolution_y * r.pixel_aspect_y)
    if abs(w - h * aspect) <= 1.0 and abs(h - w / aspect) <= 1.0:
        return None
    fix = "x".join(map(str, scene_frame_size(scene, max(w, h))))
    pixels = (f" with pixels {r.pixel_aspect_x:g}:{r.pixel_aspect_y:g}"
              if r.pixel_aspect_x != r.pixel_aspect_y else "")
    return (f"the scene's cameras frame {sw}x{sh}{pixels}; the dataset's {w}x{h} views show a band more or less of "
            f"the scene than that frame (by each camera's sensor fit): --resolution {fix} (or one number) keeps it, in "
            "a new dataset")


class _temporary_resolution:
    def __init__(self, scene, w, h):
        self.r, self.new = scene.render, (w, h, 100, 1.0, 1.0)

    def __enter__(self):
        r = self.r
        self.old = (r.resolution_x, r.resolution_y, r.resolution_percentage, r.pixel_aspect_x, r.pixel_aspect_y)
        r.resolution_x, r.resolution_y, r.resolution_percentage, r.pixel_aspect_x, r.pixel_aspect_y = self.new

    def __exit__(self, *exc):
        r = self.r
        r.resolution_x, r.resolution_y, r.resolution_percentage, r.pixel_aspect_x, r.pixel_aspect_y = self.old


def _normalize_pose(c2w: np.ndarray, norm: np.ndarray) -> np.ndarray:
    """A camera pose in the normalized object frame (uniform scale: rotation kept, centre moved)."""
    out = c2w.copy()
    out[:3, 3] = norm[:3, :3] @ c2w[:3, 3] + norm[:3, 3]
    return out


# --------------------------------------------------------------------------------------------
# The core function
# --------------------------------------------------------------------------------------------

def shard_specs(specs: list[O.ObjectSpec], shard: tuple[int, int]) -> list[O.ObjectSpec]:
    i, n = shard
    ordered = sorted(specs, key=lambda s: s.key)
    return [s for k, s in enumerate(ordered) if k % n == i]


@contextlib.contextmanager
def _sigint_between_views():
    """In a headless run, turn Ctrl-C (SIGINT) into a flag that is checked between views.

    Python's default handler raises KeyboardInterrupt wherever the main thread happens to be; during
    a render that is inside a Python callback Blender runs (Cycles' engine), which Blender catches
    and prints, so the render went on to the end. The flag makes ``render_dataset`` raise
    KeyboardInterrupt after the view in flight is written. Inside Blender's UI (not background)
    SIGINT is left alone: the modal operator cancels with ``close()``."""
    flag: list[int] = []
    previous = None
    if bpy.app.background and threading.current_thread() is threading.main_thread():
        try:
            previous = signal.signal(signal.SIGINT, lambda signum, frame: flag.append(signum))
        except (ValueError, OSError):
            previous = None
    try:
        yield flag
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


def _remove_if_untouched(out: Path) -> None:
    """Remove a dataset folder this run created if it holds nothing but its root manifest and empty folders."""
    if all(p.is_dir() or p == out / F.ROOT_MANIFEST for p in out.rglob("*")):
        shutil.rmtree(out, ignore_errors=True)


def render_dataset(cfg: RenderConfig) -> ProgressGen:
    """Render every object of ``cfg.sources`` (this shard's share); yields Progress, returns RenderSummary."""
    cfg.validate()
    user_scene = bpy.context.scene
    passed_over: list[str] = []
    specs = shard_specs(O.resolve_sources(tuple(cfg.sources), cfg.category, passed_over), cfg.shard)
    scene_cams = _scene_cameras(user_scene, cfg) if cfg.rig == "scene" else None
    if scene_cams is not None:
        cfg = replace(cfg, scene_cameras=_cameras_record(scene_cams))
        reframed = _frame_change(user_scene, *cfg.resolution)
        if reframed:
            passed_over.append(reframed)
    fresh = not Path(cfg.out).exists() and cfg.shard[1] == 1  # (another shard may be starting into it too)
    summary = RenderSummary(Path(cfg.out))
    summary.warnings.extend(passed_over)
    state = {"done": 0}
    try:
        with dataset_run(cfg):  # registered until the lists are written: --force of other settings waits for it
            yield from _render_specs(cfg, specs, scene_cams, summary, state)
            if summary.skipped and not summary.objects:  # (--skip-bad-meshes wrote an empty dataset with exit 0)
                state["done"] = 0
                raise InputError(f"every mesh was skipped as unusable ({len(summary.skipped)}: "
                                 f"{', '.join(summary.skipped[:3])}{', ...' if len(summary.skipped) > 3 else ''}); "
                                 "nothing was rendered")
            write_splits(Path(cfg.out))
    except Exception:
        if fresh and state["done"] == 0:  # e.g. the first mesh cannot be read: leave no empty dataset behind
            _remove_if_untouched(Path(cfg.out))
        raise
    grey = O.viewport_grey_warning(summary.viewport_grey)
    if grey:
        summary.warnings.append(grey)
    if summary.per_view_intrinsics:
        named = summary.per_view_intrinsics
        summary.warnings.append(
            f"{len(named)} object(s) ({', '.join(named[:3])}{', ...' if len(named) > 3 else ''}) have views with "
            "different intrinsics (focal length or principal point): each view's are in transforms.json (which this "
            "package reads), while the SRN intrinsics.txt can hold only one, the first view's; readers of the SRN "
            "layout alone (pixelNeRF's) would misplace the other views")
    summary.seconds = time.perf_counter() - summary.started
    return summary


def _render_specs(cfg: RenderConfig, specs: list[O.ObjectSpec], scene_cams, summary: RenderSummary, state: dict):
    """Render ``specs`` into the registered root; yields Progress (``state["done"]``: the views reported)."""
    n_views = len(scene_cams) if scene_cams else cfg.views
    total = len(specs) * n_views
    t0 = summary.started = time.perf_counter()
    yield Progress(0, total, "starting")
    with tempfile.TemporaryDirectory(prefix="mrvm_render_") as tmp, _sigint_between_views() as interrupted:
        for spec in specs:
            views = _render_object(cfg, spec, scene_cams, Path(tmp), summary)
            started = state["done"]
            try:
                for event in views:
                    state["done"] += 1
                    summary.seconds = time.perf_counter() - t0
                    yield Progress(state["done"], total, event, skipped=summary.views_skipped)
                    if interrupted:
                        raise KeyboardInterrupt  # between views: every reported view is on disk
            except InputError as e:  # the mesh itself is unusable, before any of its views was written
                skippable = spec.kind == "file" and state["done"] == started
                if skippable and not cfg.skip_bad_meshes and len(specs) > 1:
                    raise InputError(f"{e} (to render the other {len(specs) - 1} object(s) without it: "
                                     "--skip-bad-meshes, in the panel Skip bad meshes)") from None
                if not (cfg.skip_bad_meshes and skippable):
                    raise
                summary.warnings.append(f"{spec.key} skipped: {e}")
                summary.skipped.append(spec.key)
                state["done"] += n_views
                yield Progress(state["done"], total, f"{spec.key}: skipped ({e})", skipped=summary.views_skipped)
                continue
            finally:
                views.close()
            summary.objects.append(spec.key)


def _render_object(cfg: RenderConfig, spec: O.ObjectSpec, scene_cams, tmpdir: Path, summary: RenderSummary):
    """Render one object; yields a message per view (rendered or skipped). Its folder is held for the while
    (``guards.output_lock``): a second run reaching it (the same command twice) is refused in one line instead of
    removing or mixing in this one's views; shards rendering one dataset into one folder hold different objects and
    go on side by side (a lock of the whole dataset would refuse them). What a killed run was writing there is
    removed first (its temporary names; the folder is held: no one else's)."""
    obj_dir = Path(cfg.out) / spec.category / spec.object_id
    spec = O.with_current_names(spec)  # (a selected object renamed since the run began)
    with output_lock(obj_dir, "object folder"):
        for d in F.VIEW_DIRS:  # _replace_into's names: hidden, the view's number first (not a user's .DS_Store)
            sweep_partials(obj_dir / d, ".[0-9]*")
        for name in ("meta.json", "transforms.json", "intrinsics.txt"):  # format.atomic_write's
            sweep_partials(obj_dir, f".{name}.*")
        return (yield from _render_held_object(cfg, spec, scene_cams, tmpdir, summary, obj_dir))


def _clear_object(obj_dir: Path) -> None:
    """Remove what an object folder holds but its lock file (held by this run: removing it would let another run
    lock the folder while this one renders into it)."""
    F.remove_entries(obj_dir, [p.name for p in obj_dir.iterdir() if p.name != LOCK_FILE])


def _render_held_object(cfg: RenderConfig, spec: O.ObjectSpec, scene_cams, tmpdir: Path, summary: RenderSummary,
                        obj_dir: Path):
    settings = cfg.settings()
    meta_path = obj_dir / "meta.json"
    source_hash = O.source_fingerprint(spec)
    linked_hash = O.linked_files_fingerprint(spec)
    looks_hash = O.appearance_fingerprint(spec)
    old = None
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text())
        except ValueError:
            old = {}
        # the same source: as described, or the same bytes under another spelling of its path (relative, absolute,
        # from another folder: a resume from the panel of a render started in a shell)
        same_source = old.get("source") == spec.describe() or (
            spec.kind == "file" and old.get("source_hash") == source_hash and old.get("category") == spec.category)
        if not F.settings_match(old.get("settings"), settings) or not same_source:
            if not cfg.force:
                raise OutputError(f"{obj_dir} holds another render of {spec.key} "
                                  f"({old.get('source')}); use --force (in the panel: Overwrite) to overwrite it")
            _clear_object(obj_dir)
        elif (old.get("source_hash") not in (None, source_hash)  # None: rendered before hashes were kept
              or old.get("linked_files_hash") not in (None, linked_hash)
              or old.get("appearance_hash") not in (None, looks_hash)):
            if not cfg.force:
                raise OutputError(f"{obj_dir} holds views of {spec.describe()} as it was before it changed "
                                  "(its content, its materials, or a texture, buffer or linked .blend file it names, "
                                  "differs from what they were rendered from); use --force (in the panel: Overwrite) "
                                  "to render it again")
            _clear_object(obj_dir)
        elif spec.kind == "procedural" and old.get("appearance_hash") is None and not old.get("complete"):
            # interrupted under a version that kept no hash of the built object: the library's geometry has changed
            # since for some seeds (chairs' arm posts, 74a022c), and a resume mixed two chairs in one object's views
            if not cfg.force:
                raise OutputError(f"{obj_dir} holds unfinished views of {spec.describe()} from a version that did "
                                  "not record the object it built (the library has changed some objects since), so "
                                  "they cannot be checked against this one's; use --force (in the panel: Overwrite) "
                                  "to render it again")
            _clear_object(obj_dir)
        elif old.get("complete") and all(view_intact(obj_dir, i) for i in range(old.get("n_views", -1))):
            update = {"split": assign_split(cfg, spec.key), "source": spec.describe()}
            if any(old.get(k) != v for k, v in update.items()):  # neither changes a pixel: the record follows the run
                if old.get("split") != update["split"]:
                    summary.warnings.append(f"{spec.key}: finished before in split {old.get('split')!r}, now in "
                                            f"{update['split']!r} as this run assigns")
                F.atomic_write_json(meta_path, {**old, **update})
            for i in range(old["n_views"]):
                summary.views_skipped += 1
                yield f"{spec.key}: view {i + 1}/{old['n_views']} (done before)"
            return

    session = RenderSession(cfg, tmpdir)
    writer = _Writer()
    try:
        missing_tex: list[str] = []
        made_opaque: list[str] = []
        missing_mtl: list[str] = []
        objs = O.load_into(spec, session.coll, missing_tex, made_opaque, work_dir=tmpdir, missing_libraries=missing_mtl)
        if cfg.engine == "BLENDER_WORKBENCH" and (spec.kind == "selected" or (
                spec.kind == "file" and Path(spec.member or spec.path).suffix.lower() == ".blend")):
            summary.viewport_grey.extend(n for n in O.viewport_grey_materials(objs) if n not in summary.viewport_grey)
        if spec.kind == "file":  # names relative to the mesh's folder (an archive's: where it is unpacked)
            images_base = O.archive_root(spec, tmpdir) if spec.member else Path(spec.path).parent
        else:
            images_base = Path(bpy.data.filepath).parent if bpy.data.filepath else None
        images_hash = O.rendered_images_fingerprint(objs, images_base)
        if meta_path.exists() and "rendered_images_hash" in (old or {}) and old["rendered_images_hash"] != images_hash:
            # the images the render read (found by the importer, or a selected object's) changed since the views
            # before were rendered: those views would not match these (a finished object is never re-imported)
            if not cfg.force:
                raise OutputError(f"{obj_dir} holds views of {spec.describe()} rendered with other images than "
                                  "its materials read now (a texture changed, appeared or went); use --force (in the "
                                  "panel: Overwrite) to render it again")
            _clear_object(obj_dir)
        if made_opaque:
            summary.warnings.append(
                f"{spec.key}: {len(made_opaque)} material(s) read as fully transparent ({', '.join(made_opaque[:3])}"
                f"{', ...' if len(made_opaque) > 3 else ''}: alpha 0 with nothing driving it, how importers read many "
                "3ds Max exports to FBX or COLLADA), rendered opaque")
        if missing_mtl:
            summary.warnings.append(
                f"{spec.key}: {len(missing_mtl)} material library file(s) not found ({', '.join(missing_mtl[:3])}"
                f"{', ...' if len(missing_mtl) > 3 else ''}): the materials they define render a default grey; put the "
                ".mtl files beside the mesh and render again with --force")
        if missing_tex:
            summary.warnings.append(
                f"{spec.key}: {len(missing_tex)} texture file(s) not found ({', '.join(missing_tex[:3])}"
                f"{', ...' if len(missing_tex) > 3 else ''}), rendered with the material's own colour instead; "
                "put the files where the mesh's materials name them and render again with --force")
        vl = session.view_layer
        O.check_vertices(O.mesh_vertices_world(objs, vl), spec.describe())
        imprecise = O.float32_precision_warning(objs, vl, spec.key)
        if imprecise:
            summary.warnings.append(imprecise)
        norm = O.normalization_matrix(O.mesh_vertices_world(objs, vl), spec.describe())
        loose = O.loose_vertices(objs, vl)  # left out of the bounds (a scan's stray points): said, as they moved them
        old_norm = ((old or {}).get("normalization") or {}).get("matrix") if meta_path.exists() else None
        if old_norm is not None and not np.allclose(np.asarray(old_norm, dtype=np.float64), norm, atol=1e-6):
            # the unfinished object's views were framed by other bounds (rendered before session 52, which leaves
            # vertices no face uses out of them and renders collection instances): they would not match these
            if not cfg.force:
                raise OutputError(f"{obj_dir} holds views of {spec.describe()} normalized to other bounds than it has "
                                  "now (this version frames objects by the vertices their faces use, and renders "
                                  "collection instances); use --force (in the panel: Overwrite) to render it again")
            _clear_object(obj_dir)
        if loose is not None:
            summary.warnings.append(
                f"{spec.key}: {loose['count']} vertices that no face of some area uses (stray points, loose vertices "
                "or edges, faces of no area: they render nothing) left out of the bounds it is normalized and framed by; they reached well beyond "
                "its faces (meta.json: loose_vertices)")
        O.apply_world_transform(objs, norm, vl)
        radius = float(np.linalg.norm(O.mesh_vertices_world(objs, vl), axis=1).max())

        # Object / part ids for the mask pass.
        meshes = sorted((o for o in objs if O.renders(o)), key=lambda o: o.name)
        labelled = np.zeros(len(meshes) + 1, dtype=bool)
        labels: dict[int, str] = {0: "background"}
        for k, o in enumerate(meshes, start=1):
            o.pass_index = k
            if o.get("mrvm_part_labels"):
                from . import procedural

                labelled[k] = True
                labels.update(procedural.labels_of(o))
            else:
                labels[k] = spec.category if len(meshes) == 1 else o.name
        if len(labels) > 256:
            raise InputError(f"{spec.key} has more than 255 parts; the uint8 mask cannot hold them")
        tris = O.mesh_triangles(objs, vl)  # once per object: the data passes of every view
        if len(tris) == 0 or float(np.linalg.norm(np.cross(tris.verts[:, 1] - tris.verts[:, 0],
                                                           tris.verts[:, 2] - tris.verts[:, 0]), axis=1).sum()) < 1e-12:
            raise InputError(f"{spec.describe()} has no faces with any area (every face is a line or a point), so "
                             "no view would show anything; fix or re-export the mesh")
        outline = raster.outline_points(tris)

        # Cameras.
        w, h = cfg.resolution
        if scene_cams is not None:
            intrs = [c[0] for c in scene_cams]
            poses = [_normalize_pose(c[1], norm) for c in scene_cams]
            cam_names = [c[2] for c in scene_cams]
        elif cfg.fov_range_deg is not None:
            poses, intrs, cam_records = rigs.varied_cameras(cfg.rig, cfg.views, radius, w, h, cfg.fov_range_deg,
                                                            cfg.distance_range, seed=object_camera_seed(cfg, spec.key),
                                                            elevation_range_deg=cfg.elevation_range_deg)
            cam_names = []
        else:
            intr = C.intrinsics_from_fov(math.radians(cfg.fov_deg), w, h)
            fov_min = min(intr.fov_x, intr.fov_y)
            dist = rigs.framing_distance(radius, fov_min)
            poses = rigs.rig_poses(cfg.rig, cfg.views, dist, seed=cfg.seed, elevation_deg=cfg.elevation_deg)
            intrs = [intr] * len(poses)
            cam_names = []
        near, far = rigs.near_far(poses, radius)
        set_clip(session.camera, near, far)
        clip = (session.camera.data.clip_start, session.camera.data.clip_end)
        # Cycles renders only the pixels the object can reach (the rest is transparent anyway): its
        # pixel filter spreads a pixel's samples over +-filter_width/2 pixels; one pixel more for safety.
        border_margin = int(math.ceil(session.scene.cycles.filter_width / 2)) + 1 if cfg.engine == "CYCLES" else 0

        split = assign_split(cfg, spec.key)
        lo = O.mesh_vertices_world(objs, vl).min(axis=0)
        hi = O.mesh_vertices_world(objs, vl).max(axis=0)
        meta = {
            "format_version": F.FORMAT_VERSION, "generator": f"blender_mrvm {__version__}",
            "category": spec.category, "object_id": spec.object_id, "source": spec.describe(),
            "source_hash": source_hash,
            **({"linked_files_hash": linked_hash} if linked_hash is not None else {}),
            **({"appearance_hash": looks_hash} if looks_hash is not None else {}),
            "rendered_images_hash": images_hash,  # None: its materials read no image file
            "split": split, "settings": settings, "n_views": len(poses), "complete": False,
            "normalization": {"matrix": norm.tolist(), "scale": float(norm[0, 0]),
                              "note": "x_normalized = matrix @ x_source (ShapeNetCore v2: bbox centre 0, diagonal 1)"},
            "bbox": [lo.tolist(), hi.tolist()], "bound_radius": radius, "near": near, "far": far,
            "labels": {str(k): v for k, v in sorted(labels.items())},
            "background": "transparent (RGBA, straight alpha)" if cfg.rgba else "white",
            "rgb": "8-bit sRGB (IEC 61966-2-1 transfer of linear render)",
            "depth": "planar z-depth along the camera axis, scene units, channel Y; 0 = background",
            "normal": "world-space unit normals, channels R G B = x y z; 0 = background",
            "data_passes": "the first surface along the ray through each pixel centre (rasterized exactly)",
            "intrinsics": {"fl_x": intrs[0].fx, "fl_y": intrs[0].fy, "cx": intrs[0].cx, "cy": intrs[0].cy,
                           "w": w, "h": h},
            "per_view_intrinsics": len({(i.fx, i.fy, i.cx, i.cy) for i in intrs}) > 1,
            "render": {"engine": cfg.engine, "samples": cfg.samples, "rig": cfg.rig, "seed": cfg.seed,
                       "fov_deg": cfg.fov_deg, "blender": bpy.app.version_string},
        }
        if cam_names:
            meta["scene_cameras"] = cam_names
        if missing_tex:
            meta["missing_textures"] = missing_tex  # rendered with their material's own colour
        if missing_mtl:
            meta["missing_material_libraries"] = missing_mtl  # its materials rendered a default grey
        if made_opaque:
            meta["made_opaque"] = made_opaque  # alpha 0 with nothing driving it: rendered at alpha 1
        if loose is not None:
            meta["loose_vertices"] = loose  # left out of bbox and normalization: the bounds they would have given
        if cfg.fov_range_deg is not None:
            meta["render"].update({"fov_range_deg": list(cfg.fov_range_deg), "distance_range": list(cfg.distance_range),
                                   "camera_seed": object_camera_seed(cfg, spec.key)})
            if cfg.elevation_range_deg is not None:
                meta["render"]["elevation_range_deg"] = list(cfg.elevation_range_deg)
            meta["cameras"] = cam_records  # per view: fov_x_deg, distance, distance_factor (exact: see transforms.json)
        F.atomic_write_json(meta_path, meta)
        for k in F.VIEW_DIRS:
            (obj_dir / k).mkdir(exist_ok=True)
        session.seal()  # the object is loaded: what is made from here on (between the views' steps) is not ours

        current_intr = None
        opacity: list[tuple] = []  # per rendered view (inside, outside the mask), from the writer thread
        rendered_now = 0
        for i, (intr, c2w) in enumerate(zip(intrs, poses)):
            msg = f"{spec.key}: view {i + 1}/{len(poses)}"
            if view_intact(obj_dir, i):
                summary.views_skipped += 1
                yield msg + " (done before)"
                continue
            if intr != current_intr:
                apply_intrinsics(session.camera, session.scene, intr)
                current_intr = intr
            apply_pose(session.camera, c2w)
            box = raster.pixel_box(outline, intr, c2w, border_margin) if border_margin else None
            colour = session.render_colour(box)
            # Rasterized and written on the writer thread while the next view renders.
            writer.submit(_make_view, obj_dir, i, colour, tris, intr, c2w, clip, labelled, cfg.rgba, opacity)
            summary.views_rendered += 1
            rendered_now += 1
            yield msg
        writer.wait()
        if rendered_now and not opacity:  # (the writer appends a view's figures only where its mask has a pixel)
            summary.warnings.append(
                f"{spec.key}: covers no pixel in any of the {rendered_now} views rendered (its masks are empty): it is "
                f"too thin or too small to show at {intrs[0].width}x{intrs[0].height} (e.g. a needle or a sheet seen "
                "edge-on, or a part far larger than the rest sets the framing); check the mesh")

        # Per-object camera files (from the poses, so they are exact whatever was resumed).
        F.atomic_write_text(obj_dir / "intrinsics.txt", F.format_srn_intrinsics(intrs[0]))
        if meta["per_view_intrinsics"]:
            summary.per_view_intrinsics.append(spec.key)
        frames = []
        for i, (intr, c2w) in enumerate(zip(intrs, poses)):
            n = F.view_name(i)
            fr = {"file_path": f"rgb/{n}.png", "depth_exr_path": f"depth/{n}.exr",
                  "normal_exr_path": f"normal/{n}.exr", "part_mask_path": f"mask/{n}.png", "c2w_opencv": c2w}
            if meta["per_view_intrinsics"]:
                fr.update({"fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx, "cy": intr.cy})
            frames.append(fr)
        F.atomic_write_json(obj_dir / "transforms.json",
                            F.transforms_dict(intrs[0], frames, {"near": near, "far": far,
                                                                 "aabb": [lo.tolist(), hi.tolist()]}))
        seen = [o[0] for o in opacity if o[0] is not None]  # views where the object is more than its edges
        inside = float(np.median(seen)) if seen else 1.0
        sized = [o[1] for o in opacity if o[1] is not None]  # views where the object covers 16 pixels or more
        outside = float(np.median(sized)) if sized else 0.0
        if inside < SEE_THROUGH:
            meta["see_through"] = {"median_opacity_over_mask": round(inside, 3)}
            summary.warnings.append(
                f"{spec.key}: the images show through the object (median opacity {inside:.2f} over the pixels its "
                "masks and depth give it): its materials are transparent; the masks and depth still show the surface")
        if outside > UNMASKED:
            meta["unmasked"] = {"median_opaque_outside_mask": round(outside, 3)}
            summary.warnings.append(
                f"{spec.key}: the images draw surfaces the masks and depth do not have (opaque pixels outside the "
                f"mask: {100 * outside:.0f}% of its area, median): true displacement, instances or hair render in "
                "the colour but are not in the mesh; apply them to the mesh to keep the passes exact")
        meta["complete"] = True
        F.atomic_write_json(meta_path, meta)
    finally:
        try:
            writer.close()  # the view in flight is finished (a cancel keeps every view it reported)
        finally:
            session.close()


def _make_view(obj_dir: Path, index: int, colour: dict, tris: raster.Triangles, intr: C.Intrinsics,
               c2w: np.ndarray, clip: tuple[float, float], labelled: np.ndarray, rgba: bool,
               opacity: list[tuple]) -> None:
    """The writer thread's job for one view: its exact data passes, then its files (no bpy here); appends to
    ``opacity`` the colour's mean opacity over the mask's inner object pixels (None where the object is nothing but
    edges: thin parts are partly covered pixels) and the opaque pixels outside the mask as a share of its object
    pixels (None where it covers under 16 pixels) (see :data:`SEE_THROUGH`, :data:`UNMASKED`)."""
    data = raster.rasterize(tris, intr, c2w, clip[0], clip[1])
    write_view(obj_dir, index, colour, data, labelled, rgba, c2w)
    on = data.object_id > 0
    if on.any():
        alpha = np.clip(colour["Combined"]["A"], 0, 1)
        pad = np.pad(on, 1)
        sides = (pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:])
        near = on | sides[0] | sides[1] | sides[2] | sides[3]  # grown by a pixel: antialiased edges are no geometry
        inner = on & sides[0] & sides[1] & sides[2] & sides[3]  # shrunk by one: edge pixels are partly covered
        opacity.append((float(alpha[inner].mean()) if inner.any() else None,
                        float(((alpha > 0.9) & ~near).sum() / on.sum()) if on.sum() >= 16 else None))


SEE_THROUGH = 0.5
"""An object whose colour renders with a median opacity below this over the pixels its mask and depth give it is
named in a warning: the masks and depth show a surface the images show through (transparent or glass materials,
or an importer's misread opacity)."""
UNMASKED = 0.05
"""An object whose images draw opaque pixels outside its masks (grown by a pixel), a median share above this of its
mask's pixels, is named in a warning: Cycles renders surfaces the mesh does not hold (true displacement, instances,
hair), which have no masks or depth."""


def config_dict(cfg: RenderConfig) -> dict:
    d = asdict(cfg)
    d["out"] = str(cfg.out)
    return d
