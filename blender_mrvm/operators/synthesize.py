"""Operator: Synthesize novel views (references + targets in, image planes out).

The model runs in the worker process (``worker.run_worker``: ``python -m blender_mrvm synthesize
--references DIR --views 0 1 --targets targets.json --checkpoint CKPT --device auto --out OUT``,
see ``datasets/novel_views.py`` for the files). Steps:

1. :func:`plan_from_props` checks everything the user chose, with no side effects: references
   (an object folder with posed views, a recovered capture, or scene cameras with images), targets
   (selected cameras, or an orbit around the 3D cursor), the plane settings, the checkpoint;
2. :func:`prepare` picks the worker's Python (``worker.choose_interpreter``), checks it has torch,
   and that this version has the ``synthesize`` command; then writes the job folder;
3. the worker runs (modal: one ``next()`` per timer tick, Esc cancels it and nothing is created);
4. on the main thread, ``scene.novel_views.import_results`` creates the orbit cameras and one image
   plane per target, all or nothing.

Until the trained model and its ``synthesize`` command exist (issue 4), step 2 fails with a clear
message; nothing here fakes a result.
"""

from __future__ import annotations

import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import bpy

from ..errors import InputError, MRVMError

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
    checkpoint: Path
    """Model checkpoint (file or folder) the worker loads."""
    device: str
    """auto, cpu or cuda."""
    planes: object
    """``scene.image_planes.PlaneConfig`` for the results."""
    depth: bool
    """Also synthesize and save depth maps (EXR)."""


def default_checkpoint() -> Path | None:
    """The model shipped with the add-on (``models.pretrained``), or None when this copy has none."""
    from ..models import pretrained

    try:
        return pretrained.default_checkpoint()
    except InputError:
        return None


def model_available() -> bool:
    """Whether this version's worker has the ``synthesize`` command."""
    from ..cli import COMMANDS

    return SYNTH_COMMAND in COMMANDS


def _abspath(p: str) -> Path:
    return Path(bpy.path.abspath(p.strip()))


def _checkpoint(context, p) -> Path:
    from .. import prefs as P

    if p.checkpoint.strip():
        ck = _abspath(p.checkpoint)
        if not ck.exists():
            raise InputError(f"checkpoint {ck} does not exist")
        return ck
    pr = P.get(context)
    if pr is not None and pr.checkpoint_dir.strip():
        ck = _abspath(pr.checkpoint_dir)
        if not ck.exists():
            raise InputError(f"the checkpoint folder set in the add-on preferences does not exist: {ck}")
        return ck
    ck = default_checkpoint()
    if ck is None:
        raise InputError("no checkpoint chosen, and this version ships no trained model yet: pick a checkpoint "
                         "(model.safetensors written by `python -m blender_mrvm train`)")
    return ck


def plan_from_props(context) -> SynthesisJob:
    """Check the Novel views settings and the scene; no side effects. MRVMError on bad input."""
    from ..datasets.novel_views import parse_views
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
        if len(cams) > 10:
            raise InputError(f"{len(cams)} scene cameras have images; at most 10 references are used")
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
    for t in targets:
        obj = bpy.data.objects.get(t.name)
        if obj is not None and not (obj.data.clip_start < cfg.distance < obj.data.clip_end):
            raise InputError(f"plane distance {cfg.distance:g} is outside camera {t.name!r}'s clip range "
                             f"({obj.data.clip_start:g}..{obj.data.clip_end:g})")
    return SynthesisJob(ref_dir, ref_cams, views, tuple(targets), _checkpoint(context, p), p.device.lower(), cfg,
                        p.save_depth)


def prepare(context, job: SynthesisJob):
    """The worker's interpreter, after checking it has torch and that synthesis exists in this version."""
    from .. import prefs as P
    from ..worker import choose_interpreter, require

    pr = P.get(context)
    interp = choose_interpreter(pr.python_path if pr else "")
    require(interp, ("torch", "safetensors", "numpy", "PIL"))
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
    return ["--references", str(ref_dir), "--views", *map(str, views), "--targets", str(job_dir / "targets.json"),
            "--checkpoint", str(job.checkpoint), "--device", job.device, "--out", str(job_dir / "out")]


def _import(context, job: SynthesisJob, job_dir: Path) -> str:
    from ..scene.novel_views import import_results

    res = import_results(context.scene, list(job.targets), job_dir / "out", job.planes, depth=job.depth)
    made = sum(1 for t in job.targets if t.generated)
    return (f"{len(res.planes)} novel view{'s' if len(res.planes) != 1 else ''} in collection {res.collection.name!r}"
            + (f" ({made} new cameras)" if made else ""))


class MRVM_OT_synthesize(bpy.types.Operator):
    """Synthesize novel views of the references from the target cameras and place them as image planes aligned to their cameras"""

    bl_idname = "mrvm.synthesize"
    bl_label = "Synthesize Novel Views"
    bl_options = {"REGISTER", "UNDO"}

    _gen = None
    _timer = None
    _job = None
    _dir = None

    def _start(self, context):
        from ..worker import run_worker

        job = plan_from_props(context)
        interp = prepare(context, job)
        job_dir = Path(tempfile.mkdtemp(prefix="mrvm_synth_"))
        try:
            args = write_job(context, job, job_dir)
            gen = run_worker(SYNTH_COMMAND, args, interp.path)
            first = next(gen)
        except BaseException:
            shutil.rmtree(job_dir, ignore_errors=True)
            raise
        self._job, self._dir, self._gen = job, job_dir, gen
        return first

    def _cleanup(self):
        if self._gen is not None:
            self._gen.close()
            self._gen = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None

    def execute(self, context):
        from ..progress import run_to_end

        props = context.scene.mrvm_novel_views
        try:
            self._start(context)
            run_to_end(self._gen)
            msg = _import(context, self._job, self._dir)
        except MRVMError as e:
            props.status = str(e)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        finally:
            self._cleanup()
        props.status = msg
        self.report({"INFO"}, msg)
        return {"FINISHED"}

    def invoke(self, context, event):
        props = context.scene.mrvm_novel_views
        if props.running:
            self.report({"WARNING"}, "Synthesis is already running")
            return {"CANCELLED"}
        try:
            first = self._start(context)
        except MRVMError as e:
            self._cleanup()
            props.status = str(e)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        props.running, props.progress, props.status = True, first.fraction, first.message
        wm = context.window_manager
        wm.progress_begin(0, 100)
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _finish(self, context, cancelled: bool, message: str, level: str = "INFO"):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        self._cleanup()
        if context.workspace:
            context.workspace.status_text_set(None)
        props = context.scene.mrvm_novel_views
        props.running = False
        props.status = message
        self.report({level}, message)
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        return {"CANCELLED"} if cancelled else {"FINISHED"}

    def cancel(self, context):  # Blender closing the operator (file load, quit)
        self._finish(context, True, "Synthesis cancelled", "WARNING")

    def modal(self, context, event):
        if event.type == "ESC":
            return self._finish(context, True, "Synthesis cancelled; nothing was added", "WARNING")
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        try:
            ev = next(self._gen)
        except StopIteration:
            try:
                msg = _import(context, self._job, self._dir)
            except MRVMError as e:
                return self._finish(context, True, str(e), "ERROR")
            return self._finish(context, False, msg)
        except MRVMError as e:
            return self._finish(context, True, str(e), "ERROR")
        props = context.scene.mrvm_novel_views
        props.progress, props.status = ev.fraction, f"{ev.message} (Esc to cancel)"
        context.window_manager.progress_update(int(100 * ev.fraction))
        if context.workspace:
            context.workspace.status_text_set(f"MRVM: {props.status}")
        for area in context.screen.areas if context.screen else ():
            if area.type == "VIEW_3D":
                area.tag_redraw()
        return {"RUNNING_MODAL"}


classes = (MRVM_OT_synthesize,)
