"""Capture-like renders: a library object in a textured room, filmed along a hand-held camera path.

``render_captures(cfg)`` is a generator (``progress.py``) like ``render_dataset``: one folder per
scene in the project's dataset format (``datasets/format.py``), rgb + exact depth / normals / part
ids (``raster.py``, all surfaces: the object's parts and the room's floor and walls) + poses,
``transforms.json`` and ``meta.json``. What differs from the object sets:

- The background is the scene, not white: ``meta.json`` says ``"background": "scene"`` and its
  ``"bbox"`` is the room's box (everything the views show), so models clip rays to the room, not to
  the object (``"object_bbox"`` keeps the object's box).
- The room: a floor and four walls (no ceiling: sky light comes in from above) with the library's
  procedural materials (``procedural/_materials.py``: wood, fabric, leather, plastic, paint kinds;
  no checkerboards); the subject is a procedural library object standing on the floor at the origin.
- Per scene, seeded: room size and materials, the object (category and seed), the sun's direction,
  strength and colour, the sky's colour and strength, a second (area) light, and the camera path
  (``geometry/paths.py``) and its field of view.

Runs, as ``render_dataset``'s: a scene folder is held (``guards.output_lock``) while it is checked and rendered, so a
second run reaching it is refused in one line instead of removing the first one's unfinished views (shards rendering
one set into one folder hold different scenes and go on side by side); a headless Ctrl-C stops after the view in
flight (``render._sigint_between_views``); a rerun keeps the intact views of an unfinished scene when the scene it
builds is the one they were rendered of (its meta.json, all but ``complete`` and ``split``, is the same), else
renders the scene again from its first view.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

from .. import __version__
from ..datasets import format as F
from ..errors import InputError
from ..geometry import cameras as C
from ..geometry import paths as P
from ..guards import LOCK_FILE, output_lock, sweep_partials
from ..progress import Progress, ProgressGen
from . import compat
from . import objects as O
from . import raster
from .camera import apply_intrinsics, apply_pose, set_clip
from .render import (ENGINES, MAX_RESOLUTION, RenderSession, _sigint_between_views, _Writer, dataset_run,
                     view_intact, write_view)

CATEGORY = "captures"
"""Category folder of every scene (the subject's own category is in meta.json)."""
ROOM_LABELS = {250: "room/floor", 251: "room/wall"}
"""Part ids of the room's surfaces in mask/*.png (the library's part ids stay below 250)."""
FLOOR_KINDS = ("wood", "wood", "fabric", "leather", "plastic", "sail")
WALL_KINDS = ("fabric", "sail", "wood", "plastic", "paint", "white_paint", "leather")
MAX_VIEWS = 1000
MAX_SCENES = 100000


@dataclass(frozen=True)
class CaptureConfig:
    """What ``make-captures`` renders, and how."""

    out: Path
    """Dataset root folder."""
    scenes: int = 12
    """Number of scenes (one library object in one room each)."""
    views: int = 24
    """Views per scene, along one hand-held path."""
    resolution: tuple[int, int] = (64, 64)
    """Image width and height in pixels."""
    engine: str = "CYCLES"
    """Render engine: CYCLES (default) or BLENDER_EEVEE / BLENDER_WORKBENCH."""
    samples: int = 32
    """Samples per pixel."""
    denoise: bool = False
    """Cycles: denoise every view with OpenImageDenoise. At 32 samples the rooms' indirect light is speckled
    (fireflies a photo does not have), and LPIPS scores that noise: against 256-sample renders of the same
    test scenes the shipped capture model's LPIPS is 0.159 instead of 0.186 (docs/gpnr_rooms.md)."""
    seed: int = 0
    """Scene k is drawn from seed + k (room, materials, lights, object, path)."""
    holdout_every: int = 4
    """Every this-many-th view of a path (from view holdout_every // 2 on) is held out as a target."""
    fov_range_deg: tuple[float, float] = (45.0, 65.0)
    """Horizontal field of view per scene (a phone's main camera is about 65 degrees)."""
    shard: tuple[int, int] = (0, 1)
    """(i, n): render only scenes whose index modulo n is i."""
    force: bool = False
    """Write into a folder that holds another dataset or other files."""

    def validate(self) -> None:
        w, h = self.resolution
        if not (isinstance(w, int) and isinstance(h, int)) or not (8 <= w <= MAX_RESOLUTION and 8 <= h <= MAX_RESOLUTION):
            raise InputError(f"resolution must be between 8 and {MAX_RESOLUTION} pixels a side, got {w}x{h}")
        if not 1 <= self.scenes <= MAX_SCENES:
            raise InputError(f"--scenes must be between 1 and {MAX_SCENES}, got {self.scenes}")
        if not 2 <= self.holdout_every <= 100:
            raise InputError(f"--holdout-every must be between 2 and 100, got {self.holdout_every}")
        if not max(4, self.holdout_every) <= self.views <= MAX_VIEWS:
            raise InputError(f"--views must be between {max(4, self.holdout_every)} (a held-out view with "
                             f"neighbours) and {MAX_VIEWS}, got {self.views}")
        if self.engine not in ENGINES:
            raise InputError(f"unknown engine {self.engine!r}; choose one of {', '.join(ENGINES)}")
        if self.denoise and self.engine != "CYCLES":
            raise InputError(f"--denoise is a Cycles option; {self.engine} renders without sampling noise to remove")
        if not 1 <= self.samples <= 65536:
            raise InputError(f"--samples must be between 1 and 65536, got {self.samples}")
        if self.seed < 0:
            raise InputError(f"--seed must not be negative, got {self.seed}")
        f0, f1 = self.fov_range_deg
        if not 10.0 <= f0 <= f1 <= 120.0:
            raise InputError(f"field of view range must lie within 10..120 degrees, got {f0:g},{f1:g}")
        i, n = self.shard
        if n < 1 or not 0 <= i < n:
            raise InputError(f"shard must be i/n with 0 <= i < n, got {i}/{n}")

    def settings(self) -> dict:
        """What makes two renders the same dataset (resume / overwrite checks)."""
        return {"kind": "captures", "views": self.views, "resolution": list(self.resolution), "engine": self.engine,
                "samples": self.samples, "seed": self.seed, "holdout_every": self.holdout_every,
                "fov_range_deg": list(self.fov_range_deg), **({"denoise": True} if self.denoise else {})}


# --------------------------------------------------------------------------------------------
# Splits and the evaluation protocol (bpy-free parts, used by the command too)
# --------------------------------------------------------------------------------------------

def scene_ids(cfg: CaptureConfig) -> list[str]:
    return [f"scene_{cfg.seed + k:06d}" for k in range(cfg.scenes)]


def scene_splits(n: int) -> list[str]:
    """Split of each of ``n`` scenes: the last 20 % (at least one when n >= 2) are held-out test scenes,
    the 10 % before them validation, the rest training (one scene: training)."""
    if n == 1:
        return ["train"]
    n_test = max(1, round(0.2 * n))
    n_val = round(0.1 * n)
    n_train = max(1, n - n_test - n_val)
    n_val = n - n_test - n_train
    return ["train"] * n_train + ["val"] * n_val + ["test"] * n_test


def held_out_views(views: int, every: int) -> list[int]:
    """Targets of the in-between protocol: every ``every``-th view from ``every // 2`` on (never the ends)."""
    return [t for t in range(every // 2, views - 1, every)]


def protocol(views: int, every: int) -> dict:
    """``splits/eval_views.json``: held-out views in between, each with its own neighbouring inputs."""
    targets = held_out_views(views, every)
    rec: dict = {"views": views, "protocol": "held-out views in between: each target is synthesized from its "
                 "nearest non-held-out neighbours on the camera path", "holdout_every": every,
                 "train_views": [v for v in range(views) if v not in targets]}
    for n in range(1, 7):
        try:
            per = P.neighbour_inputs(views, targets, n)
        except InputError:
            break
        rec[f"input_views_{n}"] = sorted({r for refs in per.values() for r in refs})
        rec[f"target_views_{n}"] = targets
        rec[f"target_inputs_{n}"] = {str(t): refs for t, refs in per.items()}
    return rec


# --------------------------------------------------------------------------------------------
# The scene
# --------------------------------------------------------------------------------------------

def _quad(name: str, corners, coll) -> bpy.types.Object:
    """A one-face mesh with its corners in world units (object transform identity, so Object texture
    coordinates are world coordinates: a texture's grain is the same size on every surface)."""
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, c)) for c in corners], [], [(0, 1, 2, 3)])
    me.update()
    ob = bpy.data.objects.new(name, me)
    coll.objects.link(ob)
    return ob


def _world_texture_coords(mat: bpy.types.Material, scale: float) -> None:
    """Feed the material's textures its surface's Object (= world) coordinates times ``scale``."""
    nt = mat.node_tree
    texes = [n for n in nt.nodes if n.type.startswith("TEX_")]
    if not texes:
        return
    coord = nt.nodes.new("ShaderNodeTexCoord")
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.inputs["Scale"].default_value = (scale, scale, scale)
    nt.links.new(coord.outputs["Object"], mapping.inputs["Vector"])
    for t in texes:
        nt.links.new(mapping.outputs["Vector"], t.inputs["Vector"])


def build_room(coll, rng: np.random.Generator, reach: float) -> dict:
    """Floor and four walls around the origin, at least 0.6 beyond ``reach`` (the cameras' farthest
    horizontal distance), with drawn materials; returns the room's record (and its objects)."""
    from .procedural._materials import make_material

    hx, hy = reach + float(rng.uniform(0.6, 1.8)), reach + float(rng.uniform(0.6, 1.8))
    wall_h = float(rng.uniform(2.4, 3.4))
    floor_kind = str(rng.choice(FLOOR_KINDS))
    wall_kinds = [str(rng.choice(WALL_KINDS)) for _ in range(2)]  # opposite walls share a material
    floor = _quad("capture_floor", [(-hx, -hy, 0), (hx, -hy, 0), (hx, hy, 0), (-hx, hy, 0)], coll)
    mat = make_material("capture_floor", floor_kind, rng, 250)
    _world_texture_coords(mat, float(rng.uniform(0.2, 0.45)))
    floor.data.materials.append(mat)
    wall_mats = []
    for k, kind in enumerate(wall_kinds):
        m = make_material(f"capture_wall{k}", kind, rng, 251)
        _world_texture_coords(m, float(rng.uniform(0.2, 0.45)))
        wall_mats.append(m)
    H = wall_h
    corners = [([(-hx, hy, 0), (hx, hy, 0), (hx, hy, H), (-hx, hy, H)], 0),
               ([(-hx, -hy, 0), (hx, -hy, 0), (hx, -hy, H), (-hx, -hy, H)], 0),
               ([(hx, -hy, 0), (hx, hy, 0), (hx, hy, H), (hx, -hy, H)], 1),
               ([(-hx, -hy, 0), (-hx, hy, 0), (-hx, hy, H), (-hx, -hy, H)], 1)]
    walls = []
    for k, (cs, mi) in enumerate(corners):
        w = _quad(f"capture_wall{k}", cs, coll)
        w.data.materials.append(wall_mats[mi])
        walls.append(w)
    return {"objects": [floor, *walls], "half_size": [hx, hy], "wall_height": wall_h,
            "floor_material": floor_kind, "wall_materials": wall_kinds}


def build_lights(scene: bpy.types.Scene, coll, rng: np.random.Generator, room: dict) -> dict:
    """Sky, sun and an area light with drawn colour, strength and direction."""
    world = bpy.data.worlds.new("capture_world")
    bg = next(n for n in compat.node_tree(world).nodes if n.type == "BACKGROUND")
    sky = np.array([rng.uniform(0.55, 0.8), rng.uniform(0.65, 0.85), rng.uniform(0.8, 1.0)])
    sky_strength = float(rng.uniform(0.3, 0.9))
    bg.inputs["Color"].default_value = (*sky, 1.0)
    bg.inputs["Strength"].default_value = sky_strength
    scene.world = world
    sun = bpy.data.lights.new("capture_sun", "SUN")
    sun.energy = float(rng.uniform(1.0, 3.0))
    warm = float(rng.uniform(0.0, 0.25))
    sun.color = (1.0, 1.0 - 0.4 * warm, 1.0 - warm)
    sun.angle = math.radians(float(rng.uniform(2.0, 15.0)))
    el, az = float(rng.uniform(35.0, 75.0)), float(rng.uniform(0.0, 360.0))
    so = bpy.data.objects.new("capture_sun", sun)
    so.rotation_euler = (math.radians(90.0 - el), 0.0, math.radians(az))
    coll.objects.link(so)
    area = bpy.data.lights.new("capture_area", "AREA")
    area.energy = float(rng.uniform(30.0, 150.0))
    area.size = float(rng.uniform(0.8, 2.0))
    ao = bpy.data.objects.new("capture_area", area)
    hx, hy = room["half_size"]
    ao.location = (float(rng.uniform(-0.6, 0.6) * hx), float(rng.uniform(-0.6, 0.6) * hy), room["wall_height"] * 0.95)
    coll.objects.link(ao)  # pointing down (a light's default direction is -z)
    return {"sky_color": sky.tolist(), "sky_strength": sky_strength, "sun_energy": sun.energy,
            "sun_elevation_deg": el, "sun_azimuth_deg": az, "sun_color": list(sun.color),
            "area_energy": area.energy, "area_location": list(ao.location)}


def scene_seed(cfg: CaptureConfig, k: int) -> int:
    return cfg.seed + k


def subject_of(seed: int) -> tuple[str, int]:
    """(category, object seed) of the library object of scene ``seed``: categories in turn."""
    from .procedural import CATEGORIES

    return CATEGORIES[seed % len(CATEGORIES)], seed


# --------------------------------------------------------------------------------------------
# Rendering
# --------------------------------------------------------------------------------------------

@dataclass
class CaptureSummary:
    out: Path
    scenes: list[str] = field(default_factory=list)
    views_rendered: int = 0
    views_skipped: int = 0
    seconds: float = 0.0


class _CaptureSession(RenderSession):
    """A private scene with an opaque background; the room, object and lights are added per scene."""

    def _setup_world_and_light(self) -> None:
        pass

    def __init__(self, cfg, tmpdir):
        super().__init__(cfg, tmpdir)
        self.scene.render.film_transparent = False
        if cfg.engine == "CYCLES":
            self.scene.cycles.use_adaptive_sampling = True
            if cfg.denoise:
                self.scene.cycles.use_denoising = True
                self.scene.cycles.denoiser = "OPENIMAGEDENOISE"


def render_captures(cfg: CaptureConfig) -> ProgressGen:
    """Render this shard's scenes; yields Progress per view, returns a :class:`CaptureSummary`."""
    cfg.validate()
    ids = scene_ids(cfg)
    splits = scene_splits(cfg.scenes)
    i, n = cfg.shard
    mine = [k for k in range(cfg.scenes) if k % n == i]
    summary = CaptureSummary(Path(cfg.out))
    with dataset_run(cfg):  # (the root held for its check; this run registered until its lists are written)
        yield from _render_scenes(cfg, mine, ids, splits, summary)
        write_capture_splits(Path(cfg.out), cfg)
    return summary


def _render_scenes(cfg: CaptureConfig, mine: list[int], ids: list[str], splits: list[str], summary: CaptureSummary):
    total = len(mine) * cfg.views
    done = 0
    t0 = time.perf_counter()
    yield Progress(0, total, "starting")
    with tempfile.TemporaryDirectory(prefix="mrvm_captures_") as tmp, _sigint_between_views() as interrupted:
        for k in mine:
            if interrupted:  # (a Ctrl-C while the last scene's records were written: no next one)
                raise KeyboardInterrupt
            gen = _render_scene(cfg, k, ids[k], splits[k], Path(tmp), summary)
            try:
                for msg in gen:
                    done += 1
                    summary.seconds = time.perf_counter() - t0
                    yield Progress(done, total, msg, skipped=summary.views_skipped)
                    if interrupted:
                        raise KeyboardInterrupt  # between views: closing the scene writes the view in flight
            finally:
                gen.close()
            summary.scenes.append(ids[k])
    summary.seconds = time.perf_counter() - t0


def write_capture_splits(root: Path, cfg: CaptureConfig) -> dict[str, list[str]]:
    """``splits/*.lst`` from the finished scenes on disk, and the protocol file (the root held meanwhile)."""
    from .render import root_held, write_splits_held

    # scenes are <CATEGORY>/<scene id>, as objects are; only this run's: scenes a run with more --scenes left
    # behind are not listed (their split belongs to that run's count)
    with root_held(root):
        splits = write_splits_held(root, cfg.settings(), only={f"{CATEGORY}/{s}" for s in scene_ids(cfg)})
        F.atomic_write_json(Path(root) / "splits" / "eval_views.json", protocol(cfg.views, cfg.holdout_every))
    return splits


def _clear_scene(obj_dir: Path) -> None:
    """Remove what a scene folder holds but its lock file (held by this run: removing it would let another lock it)."""
    F.remove_entries(obj_dir, [p.name for p in obj_dir.iterdir() if p.name != LOCK_FILE])


RESUME_IGNORES = ("complete", "split")
"""meta.json entries that may differ between a scene's unfinished views and a rerun that keeps them."""


def _same_record(a, b) -> bool:
    """Equal JSON records, numbers to float rounding (a scene built again in another process)."""
    return F.same_json(a, b, rel_tol=1e-9, abs_tol=1e-9)


def same_scene(old: dict, new: dict) -> bool:
    """Whether views recorded under meta.json ``old`` are views of the scene ``new`` describes: everything but
    :data:`RESUME_IGNORES` is the same (settings, generator and Blender versions, subject, room, lights, camera path,
    field of view, boxes, labels)."""
    new = json.loads(json.dumps(new))  # as written: tuples are lists
    return isinstance(old, dict) and _same_record({k: v for k, v in old.items() if k not in RESUME_IGNORES},
                                                  {k: v for k, v in new.items() if k not in RESUME_IGNORES})


def _view_kept(obj_dir: Path, v: int, c2w: np.ndarray) -> bool:
    """View ``v`` of an unfinished render of this scene is whole and was taken from pose ``c2w``."""
    if not view_intact(obj_dir, v):
        return False
    try:
        return bool(np.allclose(F.read_srn_pose(F.view_paths(obj_dir, v)["pose"]), c2w, atol=1e-6))
    except Exception:  # noqa: BLE001  (unreadable: render it again)
        return False


def _render_scene(cfg: CaptureConfig, k: int, scene_id: str, split: str, tmpdir: Path, summary: CaptureSummary):
    """One scene's views (a message per view, rendered or kept), its folder held for the while
    (``guards.output_lock``): another run rendering the same scene is refused, not mixed with this one."""
    obj_dir = Path(cfg.out) / CATEGORY / scene_id
    with output_lock(obj_dir, "scene folder"):
        yield from _render_held_scene(cfg, k, scene_id, split, tmpdir, summary, obj_dir)


def _render_held_scene(cfg: CaptureConfig, k: int, scene_id: str, split: str, tmpdir: Path, summary: CaptureSummary,
                       obj_dir: Path):
    meta_path = obj_dir / "meta.json"
    settings = cfg.settings()
    seed = scene_seed(cfg, k)
    old = None
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text())
        except ValueError:
            old = None
        if not isinstance(old, dict) or not F.settings_match(old.get("settings"), settings):
            _clear_scene(obj_dir)  # another render of this scene (prepare_output guarded the root)
            old = None
        elif old.get("complete") and all(view_intact(obj_dir, v) for v in range(old.get("n_views", -1))):
            if old.get("split") != split:  # the split changes no pixel: it follows this run's --scenes, as a fresh
                F.atomic_write_json(meta_path, {**old, "split": split})  # render of that many scenes assigns it
            for v in range(old["n_views"]):
                summary.views_skipped += 1
                yield f"{scene_id}: view {v + 1}/{old['n_views']} (done before)"
            return
    # what a killed run was writing (the views' and records' temporary names; the folder is held: no one else's)
    for d in F.VIEW_DIRS:
        sweep_partials(obj_dir / d, ".*")
    for name in ("meta.json", "transforms.json", "intrinsics.txt"):
        sweep_partials(obj_dir, f".{name}.*")

    rng = np.random.default_rng([seed, 17])
    session = _CaptureSession(cfg, tmpdir)
    writer = _Writer()
    try:
        vl = session.view_layer
        category, obj_seed = subject_of(seed)
        spec = O.resolve_sources((f"procedural:{category}:{obj_seed}",))[0]
        objs = O.load_into(spec, session.coll)
        norm = O.normalization_matrix(O.mesh_vertices_world(objs, vl))
        O.apply_world_transform(objs, norm, vl)
        lo0 = O.mesh_vertices_world(objs, vl).min(axis=0)
        lift = np.eye(4)
        lift[2, 3] = -lo0[2]  # stand on the floor
        turn = float(rng.uniform(0.0, 2.0 * math.pi))
        rot = np.eye(4)
        rot[:2, :2] = [[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]
        O.apply_world_transform(objs, lift @ rot, vl)
        verts = O.mesh_vertices_world(objs, vl)
        obj_lo, obj_hi = verts.min(axis=0), verts.max(axis=0)
        # Camera path around the object's centre, the scene's lens, then a room the path stays inside.
        target = 0.5 * (obj_lo + obj_hi)
        path = P.draw_path(rng, distance_range=(1.0, 1.7))
        poses = P.handheld_poses(path, cfg.views, target)
        fov = float(rng.uniform(*cfg.fov_range_deg))
        reach = float(max(np.abs(p[:2, 3]).max() for p in poses))
        room = build_room(session.coll, rng, reach)
        lights = build_lights(session.scene, session.coll, rng, room)

        meshes = sorted((o for o in objs if o.type == "MESH"), key=lambda o: o.name)
        labels: dict[int, str] = {0: "background (sky)", **ROOM_LABELS}
        from . import procedural

        for j, o in enumerate([*meshes, *room["objects"]], start=1):
            o.pass_index = j
            if o.get("mrvm_part_labels"):
                labels.update(procedural.labels_of(o))
            elif o not in room["objects"]:
                labels[250 - j] = category  # an unlabelled subject mesh: its own id below the room's
                for m in o.data.materials:
                    if m is not None:
                        m.pass_index = 250 - j
        all_objs = [*meshes, *room["objects"]]
        labelled = np.ones(len(all_objs) + 1, dtype=bool)  # every id comes from the material pass index
        tris = O.mesh_triangles(all_objs, vl)

        w, h = cfg.resolution
        intr = C.intrinsics_from_fov(math.radians(fov), w, h)
        hx, hy = room["half_size"]
        scene_lo = np.array([-hx, -hy, 0.0])
        scene_hi = np.array([hx, hy, room["wall_height"]])
        for p in poses:
            if not (np.all(p[:3, 3] > scene_lo) and np.all(p[:3, 3] < scene_hi)):
                raise RuntimeError(f"{scene_id}: a camera of the path left the room ({p[:3, 3].tolist()})")
        near, far = 0.02, float(np.linalg.norm(scene_hi - scene_lo)) * 1.5
        set_clip(session.camera, near, far)
        clip = (session.camera.data.clip_start, session.camera.data.clip_end)
        apply_intrinsics(session.camera, session.scene, intr)

        meta = {
            "format_version": F.FORMAT_VERSION, "generator": f"blender_mrvm {__version__}",
            "kind": "rendered capture", "category": CATEGORY, "object_id": scene_id,
            "source": f"make-captures scene {seed}: procedural:{category}:{obj_seed} in a room",
            "subject": {"category": category, "seed": obj_seed, "source": spec.describe(),
                        "turn_deg": math.degrees(turn)},
            "split": split, "settings": settings, "n_views": cfg.views, "complete": False,
            "background": "scene",
            "background_note": "views show a whole room: no white background, no transparency; 'bbox' is the room's "
                               "box (what models clip rays to), 'object_bbox' the subject's",
            "bbox": [scene_lo.tolist(), scene_hi.tolist()],
            "object_bbox": [obj_lo.tolist(), obj_hi.tolist()],
            "bound_radius": float(np.linalg.norm(scene_hi - scene_lo) / 2), "near": near, "far": far,
            "labels": {str(a): b for a, b in sorted(labels.items())},
            "rgb": "8-bit sRGB (IEC 61966-2-1 transfer of linear render), opaque",
            "depth": "planar z-depth along the camera axis, scene units, channel Y; 0 = sky",
            "normal": "world-space unit normals, channels R G B = x y z; 0 = sky",
            "data_passes": "the first surface along the ray through each pixel centre (rasterized exactly)",
            "intrinsics": {"fl_x": intr.fx, "fl_y": intr.fy, "cx": intr.cx, "cy": intr.cy, "w": w, "h": h},
            "per_view_intrinsics": False,
            "render": {"engine": cfg.engine, "samples": cfg.samples, "seed": seed, "fov_x_deg": fov,
                       "denoise": "OpenImageDenoise" if cfg.denoise else "none", "blender": bpy.app.version_string},
            "room": {k2: v for k2, v in room.items() if k2 != "objects"}, "lights": lights,
            "path": path.record(),
        }
        keep = old is not None and same_scene(old, meta)
        if old is not None and not keep:  # an unfinished render of this scene as another version built it
            _clear_scene(obj_dir)
        F.atomic_write_json(meta_path, meta)
        for d in F.VIEW_DIRS:
            (obj_dir / d).mkdir(exist_ok=True)
        for v, c2w in enumerate(poses):
            if keep and _view_kept(obj_dir, v, c2w):  # rendered before this scene was interrupted
                summary.views_skipped += 1
                yield f"{scene_id}: view {v + 1}/{cfg.views} (done before)"
                continue
            apply_pose(session.camera, c2w)
            colour = session.render_colour(None)
            writer.submit(_make_view, obj_dir, v, colour, tris, intr, c2w, clip, labelled)
            summary.views_rendered += 1
            yield f"{scene_id}: view {v + 1}/{cfg.views}"
        writer.wait()
        F.atomic_write_text(obj_dir / "intrinsics.txt", F.format_srn_intrinsics(intr))
        frames = [{"file_path": f"rgb/{F.view_name(v)}.png", "depth_exr_path": f"depth/{F.view_name(v)}.exr",
                   "normal_exr_path": f"normal/{F.view_name(v)}.exr", "part_mask_path": f"mask/{F.view_name(v)}.png",
                   "c2w_opencv": c2w} for v, c2w in enumerate(poses)]
        F.atomic_write_json(obj_dir / "transforms.json",
                            F.transforms_dict(intr, frames, {"near": near, "far": far,
                                                             "aabb": [scene_lo.tolist(), scene_hi.tolist()]}))
        meta["complete"] = True
        F.atomic_write_json(meta_path, meta)
    finally:
        try:
            writer.close()
        finally:
            session.close()


def _make_view(obj_dir: Path, index: int, colour: dict, tris, intr, c2w, clip, labelled) -> None:
    data = raster.rasterize(tris, intr, c2w, clip[0], clip[1])
    write_view(obj_dir, index, colour, data, labelled, False, c2w)

