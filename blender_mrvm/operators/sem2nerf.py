"""Operator: Sem2NeRF, one part mask seen from a camera -> image planes (image + semantic map) around it.

The model runs in the worker process (``python -m blender_mrvm sem2nerf render --checkpoint CKPT
--mask mask.png --pose pose.txt --intrinsics intrinsics.txt --targets targets.json --out OUT``, see
``models/sem2nerf/render.py``). Steps, as for novel views (``operators/synthesize.py``):

1. :func:`plan_from_props` checks everything with no side effects, through the CLI's own checks
   (``models/sem2nerf/render.py``: a Sem2NeRF checkpoint, a mask of its size with labels it knows and
   not empty, a rigid camera pose): the mask comes from a dataset's ``mask/*.png`` or a Blender image
   (``scene/sem2nerf.image_rgba``, read as label colours or part ids), its viewpoint from the dataset's
   pose or a scene camera, the views from an orbit of new cameras or the selected cameras;
2. the worker's Python is checked (torch), the job folder written, the worker runs modally with its
   progress; Esc interrupts it and removes the job folder, so nothing is created;
3. on the main thread ``scene.novel_views.import_results`` creates the orbit cameras and one image
   plane per view, each with its semantic map, all or nothing, in the collection "MRVM Sem2NeRF" (a selected
   camera's plane there is replaced; its Synthesize plane, in "MRVM novel views", is hidden, not removed, and the
   message says so).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import bpy
import numpy as np

from ..errors import InputError
from ._modal import ProgressOperator

if TYPE_CHECKING:
    from ..progress import ProgressGen

WORKER_COMMAND = "sem2nerf"


@dataclass(frozen=True)
class Sem2NeRFJob:
    """One Sem2NeRF run, checked and ready to start."""

    checkpoint: Path
    """The Sem2NeRF model file."""
    mask: np.ndarray
    """(S, S) uint8 part ids, checked against the checkpoint."""
    mask_name: str
    """Where the mask came from (messages)."""
    c2w: np.ndarray
    """OpenCV camera-to-world of the mask's camera."""
    intrinsics: object
    """Its intrinsics at S x S."""
    targets: tuple
    """``datasets.novel_views.Target`` per view to generate."""
    device: str
    """auto, cpu or cuda."""
    planes: object
    """``scene.image_planes.PlaneConfig`` of the results."""
    style_seed: int | None = None
    """Style of this seed (None = the mean style)."""
    mix_seed: int | None = None
    """Blend toward the style of this seed ..."""
    mix: float = 0.0
    """... by this factor."""
    quality: str = "full"
    """The render command's --quality: full or preview."""
    target_uids: tuple = ()
    """``session_uid`` of each target's camera (None: one the results create): ``synthesize.targets_now``."""


def _path_setting(raw: str, what: str) -> Path:
    from ._paths import blend_path

    return blend_path(raw, what)


def checkpoint_from_props(p):
    """The header of the panel's Sem2NeRF checkpoint (empty = the shipped model); MRVMError when it is none."""
    from ..models.pretrained import shipped_or_none
    from ..models.sem2nerf import render as R

    shipped = shipped_or_none("sem2nerf")
    if not p.checkpoint.strip() and shipped is not None:
        ck = shipped  # empty = the shipped Sem2NeRF model
    else:
        ck = _path_setting(p.checkpoint, "a Sem2NeRF checkpoint (trained with `python -m blender_mrvm sem2nerf train`)")
    if not ck.exists():
        raise InputError(f"checkpoint {ck} does not exist")
    return R.checkpoint_info(ck)


def plan_from_props(context) -> Sem2NeRFJob:
    """Check the Sem2NeRF settings and the scene; no side effects. MRVMError on bad input."""
    from ..models.sem2nerf import render as R
    from ..scene import image_planes as IP
    from ..scene import sem2nerf as S
    from .synthesize import target_uids

    p = context.scene.mrvm_sem2nerf
    scene = context.scene
    info = checkpoint_from_props(p)
    # The mask and its viewpoint
    if p.mask_source == "FILE":
        path = _path_setting(p.mask_path, "the mask file (a dataset's mask/NNNNNN.png)")
        raw, where = R.read_mask_png(path), f"mask {path}"
    else:
        img = p.mask_image
        if img is not None and p.mask_encoding == "IDS" and img.is_float:
            # a 16-bit PNG of part ids is loaded as floats id / 65535: its ids read as 0 or 1 (an id of 193 became
            # part 1, 65 background) with no word; the CLI refuses such masks as well
            raise InputError(f"image {img.name!r} holds 16-bit or float pixels; part ids are 8-bit grey values: "
                             "save it as an 8-bit greyscale PNG")
        if img is not None and tuple(img.size) != (info.size, info.size) and min(img.size) > 0:
            # before its colours are read on the main thread (the blend check's cost grows with the pixels)
            raise InputError(f"image {img.name!r} is {img.size[0]}x{img.size[1]}; this checkpoint takes "
                             f"{info.size}x{info.size} masks")
        raw = R.mask_from_rgba(S.image_rgba(img), info.labels, p.mask_encoding,
                               f"image {img.name!r}" if img is not None else "image")
        where = f"image {img.name!r}"
    edits = tuple(e.strip() for e in p.edits.replace(";", ",").split(",") if e.strip())
    mask, _ = R.check_input_mask(raw, info, where, edits)  # the worker gets the edited mask
    if p.viewpoint == "DATASET" and p.mask_source == "FILE":
        pose = path.parent.parent / "pose" / f"{path.stem}.txt"
        if not pose.is_file():
            raise InputError(f"mask {path} has no pose in its dataset ({pose} does not exist): "
                             "choose a scene camera as its viewpoint")
        c2w, intr = R.mask_camera_files(pose, "", info.size)
    else:  # a painted mask is always seen from a scene camera
        intr, c2w = S.mask_camera(scene, p.camera, info.size)
    seen_from = "its dataset pose" if p.viewpoint == "DATASET" and p.mask_source == "FILE" else repr(p.camera.name)
    R.check_camera_sees_box(mask, intr, c2w, info.scene_box, f"{where} seen from {seen_from}")
    # The views to generate
    if p.target_source == "ORBIT":
        targets = S.orbit_targets(scene, intr, c2w, p.orbit_count)
    else:
        targets = S.camera_targets(scene, context.selected_objects, info.size)
    cfg = IP.PlaneConfig(distance=p.plane_distance, pack=p.output == "PACK", folder=p.output_dir,
                         collection=S.COLLECTION).validate()
    if not cfg.pack:
        IP.output_folder(cfg)  # "//" needs a saved .blend
    IP.check_clip_range([bpy.data.objects.get(t.name) for t in targets], cfg.distance)
    return Sem2NeRFJob(info.model_file, mask, where, c2w, intr, tuple(targets), p.device.lower(), cfg,
                       p.style_seed if p.style == "SEED" else None,
                       p.mix_seed if p.mix > 0 else None, float(p.mix), p.quality.lower(), target_uids(targets))


def prepare(context, job: Sem2NeRFJob):
    """The worker's interpreter, after checking it has what Sem2NeRF needs."""
    from .. import prefs as P
    from ..worker import choose_interpreter, require

    pr = P.get(context)
    interp = choose_interpreter(pr.python_path if pr else "")
    require(interp, ("torch", "safetensors", "numpy", "PIL", "scipy"))  # scipy: the mask's inputs (build_inputs)
    return interp


def write_job(job: Sem2NeRFJob, job_dir: Path) -> list[str]:
    """Write the job folder (mask, its camera, targets.json); return the worker's arguments."""
    from ..datasets import format as DF
    from ..datasets.novel_views import write_targets

    DF.write_png(job_dir / "mask.png", job.mask)
    DF.write_srn_pose(job_dir / "pose.txt", job.c2w)
    (job_dir / "intrinsics.txt").write_text(DF.format_srn_intrinsics(job.intrinsics))
    write_targets(job_dir / "targets.json", list(job.targets))
    args = ["render", "--checkpoint", str(job.checkpoint), "--mask", str(job_dir / "mask.png"),
            "--pose", str(job_dir / "pose.txt"), "--intrinsics", str(job_dir / "intrinsics.txt"),
            "--targets", str(job_dir / "targets.json"), "--device", job.device, "--quality", job.quality,
            "--out", str(job_dir / "out")]
    if job.style_seed is not None:
        args += ["--style-seed", str(job.style_seed)]
    if job.mix_seed is not None:
        args += ["--mix-seed", str(job.mix_seed), "--mix", repr(job.mix)]
    return args


@dataclass
class Sem2NeRFRun:
    """A finished worker run: what the main thread imports."""

    job: Sem2NeRFJob
    job_dir: Path
    seconds: float


def run_job(job: Sem2NeRFJob, interp) -> "ProgressGen":
    """Progress generator: write the job folder, run the worker, return a :class:`Sem2NeRFRun`.
    The job folder is removed on error or cancel; after success :func:`import_run` removes it."""
    from ..worker import run_in_job_folder

    job_dir, result = yield from run_in_job_folder(WORKER_COMMAND, interp.path, lambda d: write_job(job, d),
                                                   "mrvm_sem2nerf_")
    return Sem2NeRFRun(job, job_dir, result.seconds)


def import_run(context, run: Sem2NeRFRun) -> str:
    """Create the cameras and image planes (image + semantic map) of a finished run; the success message (it names
    the planes of the same cameras in another collection, Synthesize's, that were hidden, not removed:
    ``image_planes.hidden_note``)."""
    from ..scene.novel_views import import_results
    from .synthesize import targets_now

    job = run.job
    try:
        targets = targets_now(job.targets, getattr(job, "target_uids", ()))  # cameras renamed or deleted since
        res = import_results(context.scene, targets, run.job_dir / "out", job.planes, semantic=True)
    finally:
        shutil.rmtree(run.job_dir, ignore_errors=True)
    if getattr(context.scene.mrvm_sem2nerf, "show_semantic", False):  # new planes as the panel's checkbox says
        from ..scene.sem2nerf import set_show_semantic

        set_show_semantic(True)
    from ..scene.image_planes import colour_management_note, hidden_note

    made = sum(1 for t in targets if t.generated)
    n = len(res.planes)
    note = "; ".join(x for x in (hidden_note(res), colour_management_note(context.scene)) if x)
    return (f"{n} Sem2NeRF view{'s' if n != 1 else ''} of {job.mask_name} in collection {res.collection.name!r}"
            + (f" ({made} new cameras)" if made else "") + f", generated in {run.seconds:.1f} s"
            + (f". Note: {note}" if note else ""))


class MRVM_OT_sem2nerf_paint_mask(bpy.types.Operator):
    """Open the chosen dataset mask as an image in label colours, ready to paint in the image editor, and use it as the mask"""

    bl_idname = "mrvm.sem2nerf_paint_mask"
    bl_label = "Open Mask for Painting"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        from ..errors import MRVMError
        from ..models.sem2nerf import render as R
        from ..models.sem2nerf.inputs import check_mask
        from ..scene.sem2nerf import new_mask_image

        p = context.scene.mrvm_sem2nerf
        try:
            path = _path_setting(p.mask_path, "the mask file (a dataset's mask/NNNNNN.png)")
            # labels the checkpoint does not know would be painted in colours that read back as no label or another
            mask = check_mask(R.read_mask_png(path), checkpoint_from_props(p).labels, f"mask {path}")
            img = new_mask_image(f"{path.parent.parent.name} {path.stem}", R.colorize(mask))
        except MRVMError as e:
            p.status = str(e)
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        p.mask_image, p.mask_source, p.mask_encoding = img, "IMAGE", "COLORS"
        p.status = f"mask opened as image {img.name!r}: paint it in the image editor (label colours, a hard brush)"
        self.report({"INFO"}, p.status)
        return {"FINISHED"}


class MRVM_OT_sem2nerf(ProgressOperator, bpy.types.Operator):
    """Generate views and semantic maps of an object from one part mask seen from a camera (Sem2NeRF), as image planes"""

    bl_idname = "mrvm.sem2nerf"
    bl_label = "Generate from Mask"
    bl_options = {"REGISTER", "UNDO"}

    props_attr = "mrvm_sem2nerf"
    job_name = "Sem2NeRF"
    panel_names = {"--edit": "Relabel", "--style-seed": "Seed", "--mix-seed": "Blend seed", "--mix": "Blend",
                   "--quality": "Quality", "--device": "Device", "--checkpoint": "Checkpoint", "--views": "Cameras",
                   "--mask": "Mask file"}
    stops_softly = True  # a worker job: Esc lets it save its step in progress without blocking the UI
    cancel_hint = "nothing was added"
    timer_interval = 0.1

    @classmethod
    def blocked(cls, context) -> str:
        from ._modal import SAVE_FIRST, unsaved_relative

        p = context.scene.mrvm_sem2nerf
        if p.mask_source == "FILE" and not p.mask_path.strip():
            return "Choose the Mask file (a dataset's mask/NNNNNN.png) or a Blender image as the Mask"
        if p.mask_source == "IMAGE" and p.mask_image is None:
            return "Choose the mask image (painted or opened in the image editor)"
        if (p.mask_source == "IMAGE" or p.viewpoint == "CAMERA") and p.camera is None:
            return "Choose the camera the mask is seen from"
        if p.target_source == "SELECTED" and not any(o.type == "CAMERA" for o in context.selected_objects or ()):
            return "Select the cameras to generate views of (or choose Views: Orbit)"
        if p.output == "FILES" and unsaved_relative(p.output_dir):
            return SAVE_FIRST.format(what="Output") + ", or pack the images into the .blend (Images)"
        for name, value in (("Mask file", p.mask_path if p.mask_source == "FILE" else ""),
                            ("Checkpoint", p.checkpoint)):
            if unsaved_relative(value):
                return SAVE_FIRST.format(what=name)
        return ""

    def start(self, context):
        job = plan_from_props(context)
        interp = prepare(context, job)
        return run_job(job, interp)

    def on_result(self, context, run: Sem2NeRFRun) -> str:
        return import_run(context, run)


classes = (MRVM_OT_sem2nerf_paint_mask, MRVM_OT_sem2nerf)
