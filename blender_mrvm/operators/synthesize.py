"""Operator: Synthesize novel views (references + targets in, image planes out).

The model runs in the worker process (``worker.run_worker``: ``python -m blender_mrvm synthesize
--references DIR --views 0 1 --targets targets.json --checkpoint CKPT --device auto --out OUT``,
see ``datasets/novel_views.py`` for the files). Steps:

1. :func:`plan_from_props` checks everything the user chose, with no side effects: references
   (an object folder with posed views, a recovered capture, or scene cameras with images), targets
   (selected cameras, or an orbit around the 3D cursor), the plane settings, the checkpoint;
2. :func:`prepare` picks the worker's Python (``worker.choose_interpreter``), checks it has torch,
   and that this version has the ``synthesize`` command; then writes the job folder;
3. the worker runs (``operators/_modal.ProgressOperator``: modal, one ``next()`` per timer tick with
   the worker's progress in the panel and status bar; Esc cancels it, the child is interrupted and
   nothing is created; ``execute`` runs it to the end for scripts);
4. on the main thread, ``scene.novel_views.import_results`` creates the orbit cameras and one image
   plane per target, all or nothing. The job folder is removed either way.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import bpy

from ..errors import InputError, MRVMError
from ._modal import ProgressOperator

if TYPE_CHECKING:
    from ..progress import ProgressGen

SYNTH_COMMAND = "synthesize"


@dataclass(frozen=True)
class SynthesisJob:
    """One synthesis run, checked and ready to start."""

    reference_dir: Path | None
    """Object folder of the references (None: scene cameras, exported when the job starts)."""
    reference_cameras: tuple[str, ...]
    """Scene cameras whose background images are the references (SCENE source)."""
    views: tuple[int, ...]
    """Reference view indices in the object folder."""
    targets: tuple
    """``datasets.novel_views.Target`` per view to synthesize."""
    checkpoint: Path | str
    """Model checkpoint (file or folder) the worker loads, or ``shipped:auto`` (it picks by the cameras)."""
    device: str
    """auto, cpu or cuda."""
    planes: object
    """``scene.image_planes.PlaneConfig`` for the results."""
    depth: bool
    """Also synthesize and save depth maps (EXR)."""
    ref_size: int = 0
    """The synthesize command's --ref-size: 0 auto, -1 as they are, N pixels on the longer side."""
    quality: str = "full"
    """The synthesize command's --quality: full or preview."""
    adapt_steps: int = 0
    """The synthesize command's --adapt-steps: fine-tune a copy of the model on the references first (0 = off)."""
    nearest: int = 0
    """The synthesize command's --nearest: references per view, its nearest (0 = all, up to the model's most)."""
    reproject: str = "auto"
    """The synthesize command's --reproject: the references' own colours over the views (auto, on, off)."""
    precision: str = "auto"
    """The synthesize command's --precision: auto (bf16 on a GPU; on the CPU int8 where it pays, else fp32), fp32,
    bf16, fp16 or int8."""
    target_uids: tuple = ()
    """``session_uid`` of each target's camera (None: one the results create), found again by it at import
    (:func:`targets_now`); empty: by the targets' names."""


def default_checkpoint(kind: str | None = None) -> Path | None:
    """The model of ``kind`` shipped with the add-on (``models.pretrained``; None = the default model), or
    None when this copy has none."""
    from ..models.pretrained import shipped_or_none

    return shipped_or_none(kind)


def model_available() -> bool:
    """Whether this version's worker has the ``synthesize`` command."""
    from ..cli import COMMANDS

    return SYNTH_COMMAND in COMMANDS


def _abspath(p: str) -> Path:
    return Path(bpy.path.abspath(p.strip()))


def _checkpoint(context, p) -> Path | str:
    from .. import prefs as P

    from ._paths import blend_path

    if p.checkpoint.strip():
        ck = blend_path(p.checkpoint, "the checkpoint")
        if not ck.exists():
            raise InputError(f"checkpoint {ck} does not exist")
        return ck
    pr = P.get(context)
    if pr is not None and pr.checkpoint_dir.strip():
        ck = blend_path(pr.checkpoint_dir, "the default checkpoint of the add-on preferences")
        problem = P.checkpoint_problem(str(ck))  # missing, or a folder of runs: said before the worker starts
        if problem:
            raise InputError(problem)
        return ck
    if p.shipped_model == "auto":  # the worker picks by the cameras (models.pretrained.auto_model)
        if default_checkpoint() is None:
            raise InputError("no checkpoint chosen, and this copy ships no default model: pick a Checkpoint "
                             "(a model.safetensors or run folder that Train / Fine-tune wrote)")
        return "shipped:auto"
    ck = default_checkpoint(p.shipped_model)
    if ck is None:
        raise InputError(f"no checkpoint chosen, and this copy ships no {p.shipped_model} model: pick a Checkpoint "
                         "(a model.safetensors or run folder that Train / Fine-tune wrote) or another Shipped model")
    return ck


def target_uids(targets) -> tuple:
    """The ``session_uid`` of each target's scene camera (None: a camera the results create): what the job finds
    them by when its results arrive (:func:`targets_now`), whatever they are named then."""
    objs = [None if t.generated else bpy.data.objects.get(t.name) for t in targets]
    return tuple(None if o is None else o.session_uid for o in objs)


def targets_now(targets, uids) -> list:
    """A job's targets as the scene names them when its results arrive (the artist goes on working while the worker
    runs): a camera renamed since under its new name (its plane was refused: "removed while synthesizing", the
    results thrown away); one deleted an InputError, also when another object took its name (which got the plane
    made for the deleted camera's view); cameras to create under names no object holds now (another job's results,
    Synthesize in another scene, took the names chosen at the start: "already exists", the results thrown away)."""
    from dataclasses import replace

    from ..scene.novel_views import fresh_names

    if not uids:
        return list(targets)
    by_uid = {o.session_uid: o for o in bpy.data.objects}
    out = []
    for t, uid in zip(targets, uids):
        if not t.generated:
            obj = by_uid.get(uid)
            if obj is None:
                raise InputError(f"target camera {t.name!r} was deleted while the job ran; nothing was added")
            t = replace(t, name=obj.name) if obj.name != t.name else t
        out.append(t)
    new = [k for k, t in enumerate(out) if t.generated]
    if any(out[k].name in bpy.data.objects for k in new):
        names = fresh_names(out[new[0]].name.rsplit(" ", 1)[0], len(new))
        for k, name in zip(new, names):
            out[k] = replace(out[k], name=name)
    return out


def plan_from_props(context) -> SynthesisJob:
    """Check the Novel views settings and the scene; no side effects. MRVMError on bad input."""
    from ..datasets.novel_views import MAX_POOL, parse_views
    from ..scene import image_planes as IP
    from ..scene import novel_views as NV

    p = context.scene.mrvm_novel_views
    scene = context.scene
    # References
    ref_dir, ref_cams, views = None, (), ()
    if p.reference_source in ("DATASET", "CAPTURE"):
        raw = p.dataset_dir if p.reference_source == "DATASET" else p.capture_dir
        what = "an object folder of a rendered dataset" if p.reference_source == "DATASET" else "a capture folder"
        if not raw.strip():
            raise InputError(f"choose {what} for the references")
        if raw.strip().startswith("//") and not bpy.data.filepath:
            raise InputError("save the .blend first or choose an absolute reference folder (// is relative to the .blend)")
        ref_dir, views = NV.check_reference_folder(_abspath(raw), parse_views(p.reference_views))
    else:
        cams = NV.reference_cameras(scene)
        if not cams:
            raise InputError("no scene camera has a reference image (give cameras a background image, "
                             "or use a dataset folder or a recovered capture)")
        if len(cams) > MAX_POOL:
            raise InputError(f"{len(cams)} scene cameras have images; at most {MAX_POOL} references can be given")
        for cam in cams:  # the images must exist now, not when the worker starts
            img = next(bg.image for bg in cam.data.background_images if bg.image is not None)
            if img.packed_file is None and not Path(bpy.path.abspath(img.filepath, library=img.library)).is_file():
                raise InputError(f"the reference image of camera {cam.name!r} does not exist: {img.filepath}")
        ref_cams = tuple(c.name for c in cams)
    # Targets
    if p.target_source == "SELECTED":
        targets = NV.selected_targets(scene, context.selected_objects)
    else:
        targets = NV.orbit_targets(scene, p.orbit_count, p.orbit_radius, p.orbit_elevation, p.orbit_fov,
                                   tuple(scene.cursor.location))
    # Planes
    cfg = IP.PlaneConfig(distance=p.plane_distance, pack=p.output == "PACK", folder=p.output_dir).validate()
    if not cfg.pack:
        IP.output_folder(cfg)  # "//" needs a saved .blend
    # The user's cameras must see their planes; generated (orbit) cameras get a clip range around the
    # distance when they are created (scene.novel_views.import_results).
    IP.check_clip_range([bpy.data.objects.get(t.name) for t in targets], cfg.distance)
    ref_size = {"AUTO": 0, "NATIVE": -1}.get(p.reference_sizing, int(p.reference_size))
    return SynthesisJob(ref_dir, ref_cams, views, tuple(targets), _checkpoint(context, p), p.device.lower(), cfg,
                        p.save_depth, ref_size, p.quality.lower(), int(p.adapt_steps), int(p.nearest),
                        p.photo_colours.lower(), p.precision.lower(), target_uids(targets))


def prepare(context, job: SynthesisJob):
    """The worker's interpreter, after checking it has torch and that synthesis exists in this version."""
    from .. import prefs as P
    from ..worker import choose_interpreter, require

    pr = P.get(context)
    interp = choose_interpreter(pr.python_path if pr else "")
    require(interp, ("torch", "safetensors", "numpy", "PIL", "scipy"))  # scipy: the references' visual hull
    if not model_available():
        raise MRVMError("novel-view synthesis is not available in this version yet: the worker has no "
                        f"`{SYNTH_COMMAND}` command (the trained model has not landed)")
    return interp


def write_job(context, job: SynthesisJob, job_dir: Path) -> list[str]:
    """Write the job folder (references of scene cameras, targets.json); return the worker's arguments."""
    from ..datasets.novel_views import write_targets
    from ..scene import novel_views as NV

    ref_dir, views = job.reference_dir, job.views
    if ref_dir is None:
        cams = [bpy.data.objects[n] for n in job.reference_cameras]
        ref_dir, views = NV.export_scene_references(context.scene, cams, job_dir / "references")
    write_targets(job_dir / "targets.json", list(job.targets), depth=job.depth)
    return ["--references", str(ref_dir), "--views", *(map(str, views) if views else ["all"]),
            "--targets", str(job_dir / "targets.json"),
            "--checkpoint", str(job.checkpoint), "--device", job.device, "--ref-size", str(job.ref_size),
            "--quality", job.quality, "--adapt-steps", str(job.adapt_steps), "--nearest", str(job.nearest),
            "--reproject", job.reproject, "--precision", job.precision, "--out", str(job_dir / "out")]


@dataclass
class SynthesisRun:
    """A finished worker run: what the main thread imports."""

    job: SynthesisJob
    job_dir: Path
    seconds: float


def run_job(context, job: SynthesisJob, interp) -> "ProgressGen":
    """Progress generator: write the job folder, run the worker, return a :class:`SynthesisRun`.

    The job folder is removed on error or cancel (closing the generator interrupts the worker);
    after success :func:`import_run` removes it."""
    from ..worker import run_in_job_folder

    job_dir, result = yield from run_in_job_folder(SYNTH_COMMAND, interp.path, lambda d: write_job(context, job, d),
                                                   "mrvm_synth_")
    return SynthesisRun(job, job_dir, result.seconds)


def run_note(out: Path) -> str:
    """The hints a finished run left in its ``synthesis.json`` for the user (which model Auto picked and why:
    ``models.pretrained.auto_model``; the default model asked about cameras off its training turntable:
    ``models.pretrained.viewpoint_note``; adaptation to few references: ``training.adapt.few_references_note``),
    joined; '' if none."""
    try:
        rep = json.loads((Path(out) / "synthesis.json").read_text())
        notes = [_shipped_in_panel_words(rep.get("model_choice")), rep.get("viewpoint_note"),
                 (rep.get("adaptation") or {}).get("note")]
    except (OSError, ValueError, AttributeError):
        return ""
    return "; ".join(str(n) for n in notes if n)


def _shipped_in_panel_words(text):
    """Auto's choice as the panel says it: ``shipped:<name>`` (the CLI's name of a shipped model) becomes the name
    the panel's *Shipped model* gives it."""
    import re

    from ..props import SHIPPED_MODELS

    if not isinstance(text, str):
        return text
    names = {key: name for key, name, *_ in SHIPPED_MODELS}
    return re.sub(r"\bshipped:([a-z0-9_]+)\b", lambda m: f"'{names[m.group(1)]}'" if m.group(1) in names
                  else m.group(0), text)


def import_run(context, run: SynthesisRun) -> str:
    """Create the cameras and image planes of a finished run (all or nothing); the success message (it names the
    planes of the same cameras in another collection, Sem2NeRF's, that were hidden: ``image_planes.hidden_note``)."""
    from ..scene.image_planes import colour_management_note, hidden_note
    from ..scene.novel_views import import_results

    job = run.job
    try:
        targets = targets_now(job.targets, getattr(job, "target_uids", ()))
        res = import_results(context.scene, targets, run.job_dir / "out", job.planes, depth=job.depth)
        note = "; ".join(n for n in (hidden_note(res), run_note(run.job_dir / "out"),
                                     colour_management_note(context.scene)) if n)
    finally:
        shutil.rmtree(run.job_dir, ignore_errors=True)
    made = sum(1 for t in targets if t.generated)
    return (f"{len(res.planes)} novel view{'s' if len(res.planes) != 1 else ''} in collection {res.collection.name!r}"
            + (f" ({made} new cameras)" if made else "") + f", synthesized in {run.seconds:.1f} s"
            + (f". Note: {note}" if note else ""))


class MRVM_OT_synthesize(ProgressOperator, bpy.types.Operator):
    """Synthesize novel views of the references from the target cameras and place them as image planes aligned to their cameras"""

    bl_idname = "mrvm.synthesize"
    bl_label = "Synthesize Novel Views"
    bl_options = {"REGISTER", "UNDO"}

    props_attr = "mrvm_novel_views"
    job_name = "Synthesis"
    panel_names = {"--ref-size": "Reference size", "--views": "Views", "--nearest": "Per view",
                   "--adapt-steps": "Adapt steps", "--reproject": "Photo colours", "--quality": "Quality",
                   "--precision": "Precision", "--device": "Device", "--checkpoint": "Checkpoint",
                   "--orbit": "Cameras", "--orbit-elevation": "Elevation", "--orbit-radius": "Radius",
                   "--plane-distance": "Plane distance", "--depth": "Depth (EXR)", "--references": "References"}
    stops_softly = True  # a worker job: Esc lets it save its step in progress without blocking the UI
    cancel_hint = "nothing was added"
    timer_interval = 0.1

    @classmethod
    def blocked(cls, context) -> str:
        from ..scene.novel_views import reference_cameras
        from ._modal import SAVE_FIRST, unsaved_relative

        p = context.scene.mrvm_novel_views
        if p.reference_source == "SCENE":
            if not reference_cameras(context.scene):
                return ("No scene camera has a reference image: give cameras a background image, or choose "
                        "another References source")
        else:
            raw, name = ((p.dataset_dir, "Object folder") if p.reference_source == "DATASET"
                         else (p.capture_dir, "Capture"))
            if not raw.strip():
                return f"Choose the references' {name}"
            if unsaved_relative(raw):
                return SAVE_FIRST.format(what=name)
        if p.target_source == "SELECTED" and not any(o.type == "CAMERA" for o in context.selected_objects or ()):
            return "Select the target cameras (or choose Targets: Orbit)"
        if p.output == "FILES" and unsaved_relative(p.output_dir):
            return SAVE_FIRST.format(what="Output") + ", or pack the images into the .blend (Images)"
        if unsaved_relative(p.checkpoint):
            return SAVE_FIRST.format(what="Checkpoint")
        return ""

    def start(self, context):
        job = plan_from_props(context)
        interp = prepare(context, job)
        return run_job(context, job, interp)

    def on_result(self, context, run: SynthesisRun) -> str:
        return import_run(context, run)


classes = (MRVM_OT_synthesize,)
