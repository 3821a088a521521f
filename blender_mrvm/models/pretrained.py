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
patch loss on the CPU (after session 18's, 24's and 26's GPU slices; session 27's also with the depth loss): the
best model for cameras anywhere, about ten times slower than the others on a CPU."""
SEM2NERF_NAME = "sem2nerf_shapenet13_all"
"""Stem of the shipped Sem2NeRF checkpoint (not a novel-view kind of the registry: ``shipped:sem2nerf``)."""


FIGURES = {
    "nerformer_mrvm": "2 views 21.9 dB / LPIPS 0.166 (held-out 64 px objects; nearest view 15.4 dB / 0.234); "
                      "~1.0 s per 128 px view on 2 CPU cores",
    "gpnr": "2 views 18.0 dB / LPIPS 0.304, 5 views 24.4 / 0.136 (held-out 64 px objects); ~1.7 s per 128 px view "
            "on 2 CPU cores; best with many nearby views",
    "gpnr_captures": "15 held-out capture-like rooms, 2 neighbouring photos: 31.6 dB / LPIPS 0.124 (nearest photo "
                     "24.2 / 0.160, mean of the two 27.7 / 0.160); ~6 s per 128 px view on 2 CPU cores",
    "mrvm_anyview": "cameras anywhere (held-out objects, sphere rig, 2 views): 18.6 dB / LPIPS 0.252 (default model "
                    "15.7 / 0.334, nearest view 15.2 / 0.259); on the 30-degree turntable 3.1 dB below the default "
                    "(19.8 against 22.9 dB on held-out turntable objects); "
                    "~1.0 s per 128 px view on 2 CPU cores",
    "mrvm_quality": "cameras anywhere (held-out objects, sphere rig, 2 views): 20.1 dB / LPIPS 0.235 (any-view model "
                    "18.6 / 0.252, nearest view 15.2 / 0.259); on the turntable 21.3 / 0.217 (default 22.9 / 0.164); "
                    "~13 s per 128 px view on 2 CPU cores (the default: 0.6 s in the same run); on an H100 6 FPS "
                    "at 128 px, 1.9 at 256 px through synthesize",
}
"""What the panel shows of each shipped model: measured quality and speed (RECIPE.md has the details; the
object models' speed is ``bench tradeoff --workers 2`` on the idle 2-core box, README "Speed against accuracy";
the capture model's a median of 3 held-out room views at 128 px with 2 chunk workers, session 10)."""


DEFAULT_ELEVATION_DEG = 30.0
"""Where the default model's training cameras sit: the NMR turntable, 30 degrees above the object's centre
(world z up). Off it the model degrades fast (RECIPE.md: sphere-rig views near-empty, 15.7 dB against 22.9
on the turntable); ``mrvm_anyview`` is trained for cameras anywhere."""
ELEVATION_TOLERANCE_DEG = 20.0
"""How far from :data:`DEFAULT_ELEVATION_DEG` a camera may sit before :func:`viewpoint_note` speaks."""


def viewpoint_note(checkpoint, c2ws, centre) -> str:
    """A one-line hint when the default model is asked about cameras (``c2ws``: 4x4 camera-to-world, world z
    up) more than :data:`ELEVATION_TOLERANCE_DEG` above or below its training turntable, seen from ``centre``;
    '' for any other checkpoint or when every camera is near the turntable's elevation."""
    import numpy as np

    default = shipped_or_none(None)
    if default is None or checkpoint is None or Path(checkpoint).resolve() != default.resolve():
        return ""
    d = np.stack([np.asarray(c, np.float64)[:3, 3] for c in c2ws]) - np.asarray(centre, np.float64)[None]
    n = np.linalg.norm(d, axis=1)
    el = np.degrees(np.arcsin(np.clip(d[n > 0, 2] / n[n > 0], -1.0, 1.0)))
    off = np.abs(el - DEFAULT_ELEVATION_DEG) > ELEVATION_TOLERANCE_DEG
    if not off.any():
        return ""
    return (f"{int(off.sum())} of {len(el)} cameras are off the {DEFAULT_ELEVATION_DEG:.0f}-degree turntable the "
            f"default model was trained on (elevations {el.min():.0f} to {el.max():.0f} degrees); for such views "
            "use shipped:mrvm_anyview (the panel's 'NeRFormer + MRVM, any viewpoint'), or shipped:mrvm_quality (its "
            "'quality': sharper there, many times slower on a CPU)")


def _normal_name(name: str | None) -> str:
    return str(name or "").strip().lower().replace("-", "_")


def shipped_checkpoint(kind: str | None = None) -> Path:
    """Path of the shipped model file named ``kind``: a model kind or alias (None = the default model),
    ``sem2nerf`` or a named model of :data:`SHIPPED_NAMED`; :class:`InputError` if this copy of the package
    lacks it or ships no such model."""
    from .registry import kind as kind_of_name

    name = _normal_name(kind)
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
