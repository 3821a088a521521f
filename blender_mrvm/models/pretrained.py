"""The model shipped with the add-on: where it lives and how the CLI finds it (bpy-free).

The default checkpoint was trained by our own ``train`` command on the procedural ShapeNet-13
``all`` setting; its recipe and evaluation table are in ``assets/checkpoints/RECIPE.md``. It is a
plain model file (safetensors with the model config and format version in its metadata), loaded
with ``training.checkpoint.load_model`` like any other checkpoint.
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

ASSET_DIR = Path(__file__).resolve().parents[1] / "assets" / "checkpoints"
"""Folder of the shipped checkpoints (inside the package, so the extension zip carries it)."""
DEFAULT_NAME = "mrvm_shapenet13_all"
"""Stem of the default checkpoint: ``<stem>.safetensors`` (weights + config) and ``<stem>.json`` (run config)."""
SHIPPED = {"nerformer_mrvm": DEFAULT_NAME, "gpnr": "gpnr_shapenet13_all"}
"""Stem of the shipped checkpoint of each model kind (the first is the default)."""
SHIPPED_NAMED = {"gpnr_captures": "gpnr_captures64", "mrvm_anyview": "mrvm_shapenet13_anyview",
                 "mrvm_quality": "mrvm_shapenet13_quality"}
"""Further shipped models of a kind, by name (``shipped:<name>``): ``gpnr_captures``, the GPNR model
fine-tuned on capture-like rooms (``make-captures``) for scenes and photo captures rather than objects on
white; ``mrvm_anyview``, the default NeRFormer+MRVM model fine-tuned on turntable and sphere-rig renders
(directions anywhere, field of view 30-60 degrees, varied distance) for cameras off the turntable;
``mrvm_quality``, the `accurate` preset (the paper's NeRFormer arch, ImageNet VGG16 encoder, 32 + 16 samples)
pretrained with MRVM and fine-tuned on a GPU on turntable and sphere-rig renders, then fine-tuned with the LPIPS
patch loss on the CPU (after session 18's, 24's and 26's GPU slices; session 27's also with the depth loss), and
since session 32 with the LPIPS loss inside a GPU slice: the best model for cameras anywhere, about ten times
slower than the others on a CPU."""
SEM2NERF_NAME = "sem2nerf_shapenet13_all"
"""Stem of the shipped Sem2NeRF checkpoint (not a novel-view kind of the registry: ``shipped:sem2nerf``)."""


FIGURES = {
    "auto": "the default model on its training turntable (2 views 21.9 dB / LPIPS 0.166), else the any-view model "
            "on the CPU (5-25 degrees off the turntable 19.0 / 0.258 against the default's 14.4 / 0.375; sphere rig "
            "19.2 / 0.238 against 15.0 / 0.343; ~1.0 s per 128 px view on 2 CPU cores) and the quality model on a "
            "GPU (+0.5 to +1.3 dB over the any-view model there on library objects, level on real meshes); captures of a "
            "whole scene: GPNR for rooms",
    "nerformer_mrvm": "2 views 21.9 dB / LPIPS 0.166 (held-out 64 px objects; nearest view 15.4 dB / 0.234), on "
                      "its training turntable's cameras only (a few degrees off them the any-view model is better); "
                      "~1.0 s per 128 px view on 2 CPU cores",
    "gpnr": "2 views 18.0 dB / LPIPS 0.304, 5 views 24.4 / 0.136 (held-out 64 px objects); ~1.7 s per 128 px view "
            "on 2 CPU cores; best with many nearby views",
    "gpnr_captures": "15 held-out capture-like rooms, 2 neighbouring photos: 31.6 dB / LPIPS 0.124 (nearest photo "
                     "24.2 / 0.160, mean of the two 27.7 / 0.160); ~6 s per 128 px view on 2 CPU cores",
    "mrvm_anyview": "cameras anywhere (held-out objects, sphere rig, 2 views): 19.1 dB / LPIPS 0.246 (default model "
                    "15.7 / 0.334, nearest view 15.2 / 0.259); on the 30-degree turntable 2.6 dB below the default "
                    "(20.3 against 22.9 dB on held-out turntable objects); "
                    "~1.0 s per 128 px view on 2 CPU cores",
    "mrvm_quality": "cameras anywhere (held-out objects, sphere rig, 2 views): 20.4 dB / LPIPS 0.218 (any-view model "
                    "19.1 / 0.246, nearest view 15.2 / 0.259); on the turntable 21.6 / 0.189 (default 22.9 / 0.164); "
                    "~9.5 s per 128 px view on 2 CPU cores in int8, Auto's precision there (12.3 s in fp32; the "
                    "default: 0.6 s); on an H100 6 FPS "
                    "at 128 px, 1.9 at 256 px through synthesize",
}
"""What the panel shows of each shipped model: measured quality and speed (RECIPE.md has the details; the
object models' speed is ``bench tradeoff --workers 2`` on the idle 2-core box, docs/guide/speed.md;
the capture model's a median of 3 held-out room views at 128 px with 2 chunk workers, session 10)."""


DEFAULT_ELEVATION_DEG = 30.0
"""Where the default model's training cameras sit: the NMR turntable, 30 degrees above the object's centre
(world z up). Off it the model degrades fast (RECIPE.md: sphere-rig views near-empty, 15.7 dB against 22.9
on the turntable); ``mrvm_anyview`` is trained for cameras anywhere."""
TURNTABLE_FOV_DEG = 40.0
"""The default model's training cameras' field of view (square 64 px images)."""
TURNTABLE_FRAMING = (0.75, 1.05)
"""The default model's training framings: camera distance times the sine of half the narrower field of view,
over half the object box's diagonal (``make-shapenet``'s turntable frames each object's bounding sphere at 1.05x,
and those spheres are 0.72-1.0 of the box's half-diagonal)."""
TURNTABLE_AZIMUTH_STEP_DEG = 15.0
"""The default model's training azimuths: ``make-shapenet``'s 24 turntable views, every 15 degrees from 0."""
TURNTABLE_TOLERANCE = (2.0, 2.0, 0.01, 2.0)
"""How far a camera may sit from the default model's training cameras, in :func:`turntable_offsets`' four
columns (elevation, field of view and azimuth in degrees, framing in log-distance), for the default model to be
picked over the any-view model. Measured on held-out objects (RECIPE.md "Which model for which cameras",
``scripts/viewpoint_rule.py``): the default model wins only on its own training cameras (by 2.3 dB on the
turntable's validation objects); where every camera was within 5 degrees of them in height, field of view and
azimuth (framing inside), the any-view model was already ahead (+0.7 dB, 53 views), at 5-25 degrees by +1 to
+5 dB. The crossover lies between, so the bound is set below it."""
AUTO = "auto"
"""``shipped:auto``: the shipped object model that fits the cameras and the device (:func:`auto_model`);
synthesis's default."""


def _camera_geometry(c2ws, intrinsics, bbox):
    """Per camera, seen from the centre of the object's box (world z up): elevation and azimuth (degrees), the
    narrower field of view (degrees) and the framing (:data:`TURNTABLE_FRAMING`'s measure), as four arrays."""
    import numpy as np

    lo, hi = (np.asarray(b, np.float64) for b in bbox)
    centre, half = 0.5 * (lo + hi), 0.5 * float(np.linalg.norm(hi - lo))
    d = np.stack([np.asarray(c, np.float64)[:3, 3] for c in c2ws]).reshape(-1, 3) - centre[None]
    dist = np.linalg.norm(d, axis=1)
    el = np.where(dist > 0, np.degrees(np.arcsin(np.clip(d[:, 2] / np.maximum(dist, 1e-300), -1.0, 1.0))), 90.0)
    az = np.degrees(np.arctan2(d[:, 1], d[:, 0]))
    fov = np.array([min(i.fov_x, i.fov_y) for i in intrinsics], np.float64).reshape(-1)
    framing = dist * np.sin(fov / 2.0) / half if half > 0 else np.ones_like(dist)
    return el, az, np.degrees(fov), framing


def turntable_offsets(c2ws, intrinsics, bbox):
    """How far each camera sits from the default model's training cameras: an (n, 4) array of the elevation
    offset from :data:`DEFAULT_ELEVATION_DEG` (degrees, above the box's centre, world z up), the narrower field
    of view's offset from :data:`TURNTABLE_FOV_DEG` (degrees), the framing's log-distance outside
    :data:`TURNTABLE_FRAMING` (0 inside it) and the azimuth's offset from the nearest training azimuth
    (:data:`TURNTABLE_AZIMUTH_STEP_DEG`, degrees). ``c2ws``: 4x4 camera-to-world; ``intrinsics``: one per
    camera (``fov_x`` / ``fov_y`` in radians); ``bbox``: (min, max) corners of the object's box."""
    import numpy as np

    if not len(c2ws):
        return np.zeros((0, 4))
    return _offsets(*_camera_geometry(c2ws, intrinsics, bbox))


def _offsets(el, az, fov, framing):
    """:func:`turntable_offsets` from :func:`_camera_geometry`'s arrays."""
    import numpy as np

    step = TURNTABLE_AZIMUTH_STEP_DEG
    lo, hi = TURNTABLE_FRAMING
    f = np.maximum(framing, 1e-9)
    outside = np.maximum(0.0, np.maximum(np.log(lo / f), np.log(f / hi)))
    return np.stack([np.abs(el - DEFAULT_ELEVATION_DEG), np.abs(fov - TURNTABLE_FOV_DEG), outside,
                     np.abs((az + step / 2.0) % step - step / 2.0)], axis=1)


def _off_turntable(c2ws, intrinsics, bbox, framing_known: bool) -> tuple[int, int, str]:
    """(cameras off the default model's training cameras, cameras, what is off: '' when none is)."""
    import numpy as np

    if not len(c2ws):
        return 0, 0, ""
    el, az, fov, framing = _camera_geometry(c2ws, intrinsics, bbox)
    off = _offsets(el, az, fov, framing)
    if not framing_known:
        off[:, 2] = 0.0  # a box guessed from the cameras says nothing of the framing
    bad = off > np.asarray(TURNTABLE_TOLERANCE)[None]
    n = int(bad.any(axis=1).sum())
    if n == 0:
        return 0, len(off), ""
    what = []
    if bad[:, 0].any():
        what.append(f"elevations {el.min():.0f} to {el.max():.0f} degrees against {DEFAULT_ELEVATION_DEG:.0f}")
    if bad[:, 1].any():
        what.append(f"fields of view {fov.min():.0f} to {fov.max():.0f} degrees against {TURNTABLE_FOV_DEG:.0f}")
    if bad[:, 2].any():
        what.append("the object framed nearer or farther than on the turntable")
    if bad[:, 3].any():
        what.append(f"azimuths between its training views (every {TURNTABLE_AZIMUTH_STEP_DEG:.0f} degrees)")
    return n, len(off), "; ".join(what)


def auto_model(c2ws, intrinsics, bbox, framing_known: bool = True, gpu: bool = False,
               background: str = "white") -> tuple[str, str]:
    """``shipped:auto``: (the shipped model for these references and cameras, one line saying why). References
    that show a whole scene (``background`` 'scene': a recovered or rendered capture) get GPNR for rooms and
    captures (``gpnr_captures``: +6.1 dB over the objects-on-white model on held-out rooms,
    docs/guide/model_kinds.md). Objects on white get the default model when every camera (references and targets) sits within
    :data:`TURNTABLE_TOLERANCE` of its training turntable; otherwise, on a GPU (``gpu``), the quality model
    (``mrvm_quality``: 0.5-1.3 dB better than the any-view model off the turntable on the library's objects, level
    with it on real meshes (docs/real_meshes/), many times slower on a CPU), else the any-view model
    (``mrvm_anyview``, as fast as the default). A model this copy lacks falls back
    to the next (the default last). ``framing_known`` False (a box guessed from the cameras) leaves the framing
    out of the choice."""
    if background == "scene" and shipped_or_none("gpnr_captures") is not None:
        return "gpnr_captures", ("auto: GPNR for rooms and captures (shipped:gpnr_captures): the references show a "
                                 "whole scene (meta.json background: scene), not an object on white")
    n, total, what = _off_turntable(c2ws, intrinsics, bbox, framing_known)
    if n == 0:
        return "nerformer_mrvm", (f"auto: the default model (all {total} cameras on the {DEFAULT_ELEVATION_DEG:.0f}"
                                  "-degree turntable it was trained on)")
    off = f"{n} of {total} cameras are off the default model's turntable ({what})"
    if gpu and shipped_or_none("mrvm_quality") is not None:
        return "mrvm_quality", f"auto: the quality model (shipped:mrvm_quality, on the GPU): {off}"
    if shipped_or_none("mrvm_anyview") is None:
        return "nerformer_mrvm", f"auto: the default model, though {off}: this copy ships no any-view model"
    return "mrvm_anyview", (f"auto: the any-view model (shipped:mrvm_anyview): {off}; shipped:mrvm_quality is "
                            "sharper there on library-like objects (+0.5 to +1.3 dB; level on real meshes), many "
                            "times slower on a CPU")


def is_auto(checkpoint) -> bool:
    """Whether a checkpoint argument asks for :func:`auto_model`'s choice (``shipped:auto``)."""
    raw = "" if checkpoint is None else str(checkpoint).strip().lower()
    return raw == f"shipped:{AUTO}"


TURNTABLE_HELD_OUT = {"nerformer_mrvm": (22.9, 0.164), "mrvm_quality": (21.6, 0.189), "mrvm_anyview": (20.3, 0.226)}
"""PSNR (dB) and LPIPS of the shipped NeRFormer+MRVM models on held-out objects seen from the default model's
training turntable (``data/turntable64_heldout``, 13 objects x 10 views, 2 references; RECIPE.md: stage 7,
"Session 32", "Any-view stage 5, shipped"). The nearest reference view scores 17.4 / 0.223 there."""


def _is_shipped(checkpoint, name: str | None) -> bool:
    p = shipped_or_none(name)
    return p is not None and checkpoint is not None and Path(checkpoint).resolve() == p.resolve()


def viewpoint_note(checkpoint, c2ws, intrinsics, bbox, framing_known: bool = True) -> str:
    """A one-line hint when a shipped NeRFormer+MRVM model, named explicitly, does not fit the cameras (the
    cameras as for :func:`turntable_offsets`): the default model asked about cameras beyond
    :data:`TURNTABLE_TOLERANCE` of its training turntable, or the any-view or quality model asked about cameras
    that all sit on it, where the default model renders better (:data:`TURNTABLE_HELD_OUT`) and faster on a CPU.
    '' for any other checkpoint, or when the model fits the cameras."""
    if shipped_or_none(None) is None:
        return ""
    name = next((k for k in ("nerformer_mrvm", "mrvm_quality", "mrvm_anyview")
                 if _is_shipped(checkpoint, None if k == "nerformer_mrvm" else k)), None)
    if name is None:
        return ""
    n, total, what = _off_turntable(c2ws, intrinsics, bbox, framing_known)
    if name != "nerformer_mrvm":
        if not total or n:
            return ""
        (p0, l0), (p1, l1) = TURNTABLE_HELD_OUT["nerformer_mrvm"], TURNTABLE_HELD_OUT[name]
        model, faster = (("quality model", "many times faster on a CPU") if name == "mrvm_quality"
                         else ("any-view model", "as fast"))
        return (f"all {total} cameras are on the {DEFAULT_ELEVATION_DEG:.0f}-degree turntable the default model "
                f"was trained on, where it renders better than the {model} (held-out objects: {p0:.1f} dB / "
                f"LPIPS {l0:.3f} against {p1:.1f} / {l1:.3f}) and {faster}; for such views use shipped:auto "
                "or shipped (the panel's 'Auto' or its default model)")
    if n == 0:
        return ""
    return (f"{n} of {total} cameras are off the {DEFAULT_ELEVATION_DEG:.0f}-degree turntable the default model was "
            f"trained on ({what}); for such views use shipped:auto or shipped:mrvm_anyview (the panel's 'Auto' or "
            "'NeRFormer + MRVM, any viewpoint'), or shipped:mrvm_quality (its 'quality': sharper there, many times "
            "slower on a CPU)")


def _normal_name(name: str | None) -> str:
    return str(name or "").strip().lower().replace("-", "_")


def shipped_checkpoint(kind: str | None = None) -> Path:
    """Path of the shipped model file named ``kind``: a model kind or alias (None = the default model),
    ``sem2nerf`` or a named model of :data:`SHIPPED_NAMED`; :class:`InputError` if this copy of the package
    lacks it or ships no such model."""
    from .registry import kind as kind_of_name

    name = _normal_name(kind)
    if name == AUTO:
        raise InputError("shipped:auto picks a model from the cameras of a synthesis (synthesize and the panel); "
                         "here name one: shipped, shipped:mrvm_anyview or shipped:mrvm_quality")
    named = {"sem2nerf": (SEM2NERF_NAME, "Sem2NeRF", "a checkpoint of `python -m blender_mrvm sem2nerf train`"),
             **{n: (stem, n, "--checkpoint") for n, stem in SHIPPED_NAMED.items()}}
    if name in named:
        stem, title, instead = named[name]
        p = ASSET_DIR / f"{stem}.safetensors"
        if not p.is_file():
            raise InputError(f"this copy ships no {title} model ({p} is missing); pass {instead}")
        return p
    try:
        k = kind_of_name(kind).name
    except InputError:
        raise InputError(f"no shipped model is called {kind!r}; this version ships "
                         f"{', '.join(sorted([*SHIPPED, *named]))}") from None
    if k not in SHIPPED:
        raise InputError(f"no {k} model is shipped; pass --checkpoint or train one with `python -m blender_mrvm train`")
    p = ASSET_DIR / f"{SHIPPED[k]}.safetensors"
    if not p.is_file():
        what = "default checkpoint" if k == "nerformer_mrvm" else f"{k} checkpoint"
        raise InputError(f"the shipped {what} {p} is missing (a partial install?); "
                         f"pass --checkpoint or train one with `python -m blender_mrvm train`")
    return p


def shipped_or_none(kind: str | None = None) -> Path | None:
    """:func:`shipped_checkpoint`, or None when this copy lacks it (for the panel and the add-on's checks)."""
    try:
        return shipped_checkpoint(kind)
    except InputError:
        return None


def shipped_kinds() -> list[str]:
    """The model kinds whose shipped checkpoint this copy of the package has."""
    return [k for k, stem in SHIPPED.items() if (ASSET_DIR / f"{stem}.safetensors").is_file()]


def default_checkpoint() -> Path:
    """Path of the shipped default model file; :class:`InputError` if this copy of the package lacks it."""
    return shipped_checkpoint(None)


def default_run_config() -> Path:
    """The run config (model + train sections) the default checkpoint was trained with."""
    return ASSET_DIR / f"{DEFAULT_NAME}.json"


def resolve_checkpoint(path) -> Path:
    """The one fallback rule for a checkpoint argument: None, '' or 'shipped' = the shipped default model
    (:func:`default_checkpoint`), 'shipped:<kind>' = the shipped model of that kind (e.g. shipped:gpnr);
    anything else is that path, which must exist. InputError otherwise."""
    raw = "" if path is None else str(path).strip()
    if raw == "" or raw.lower() == "shipped":
        return default_checkpoint()
    if raw.lower().startswith("shipped:"):
        return shipped_checkpoint(raw.split(":", 1)[1])
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"checkpoint {p} does not exist")
    return p
