"""The "Model" and "Novel views" sections of the MRVM sidebar tab: training / fine-tuning the model,
and synthesizing novel views (references, targets, checkpoint, image planes)."""

from __future__ import annotations

import bpy

from .main import MRVMPanel, draw_job, wrap_text


def _count(n: int, word: str) -> str:
    return f"{n} {word}{'s' if n != 1 else ''}"


def _torch_warning(layout, context) -> None:
    from .. import prefs as P

    rep = P.dependency_status(context, cached=True)  # draw() never starts a process
    if rep.pending:
        return
    if rep.error or "torch" in rep.missing:
        box = layout.box()
        box.label(text=rep.error or "torch is missing in the worker Python", icon="ERROR")
        box.label(text="See the add-on preferences for what to install")


def _holds_run(run_dir: str) -> bool:
    raw = run_dir.strip()
    if not raw or (raw.startswith("//") and not bpy.data.filepath):
        return False
    from pathlib import Path

    return (Path(bpy.path.abspath(raw)) / "config.json").is_file()


class MRVM_PT_model(MRVMPanel, bpy.types.Panel):
    bl_label = "Model"
    bl_idname = "MRVM_PT_model"
    bl_parent_id = "MRVM_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return hasattr(context.scene, "mrvm_train")

    def draw(self, context):
        p = context.scene.mrvm_train
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.enabled = not p.running
        col.prop(p, "data_dir")
        col.prop(p, "run_dir")
        col.prop(p, "start_from")
        if p.start_from == "CHECKPOINT":
            col.prop(p, "init_checkpoint")
        else:
            col.prop(p, "model_kind")
            if p.start_from == "NEW":
                col.prop(p, "preset")
        if p.start_from != "NEW":
            col.prop(p, "keep_losses")
        col.prop(p, "iterations")
        col.prop(p, "checkpoint_every")
        col.prop(p, "rays_per_object")
        col.prop(p, "resume")
        if not p.resume and _holds_run(p.run_dir):
            col.prop(p, "overwrite_run")
        col.prop(p, "use_for_synthesis")
        if p.resume and _holds_run(p.run_dir):
            col.label(text="The run folder holds a run: training continues it", icon="INFO")
        _torch_warning(layout, context)
        draw_job(layout, p, "mrvm.train", "MOD_NOISE", "Training...")


class MRVM_PT_novel_views(MRVMPanel, bpy.types.Panel):
    bl_label = "Novel Views"
    bl_idname = "MRVM_PT_novel_views"
    bl_parent_id = "MRVM_PT_main"

    @classmethod
    def poll(cls, context):
        return hasattr(context.scene, "mrvm_novel_views")

    def draw(self, context):
        from ..scene.novel_views import reference_cameras

        p = context.scene.mrvm_novel_views
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.enabled = not p.running

        col.prop(p, "reference_source")
        if p.reference_source == "DATASET":
            col.prop(p, "dataset_dir")
            col.prop(p, "reference_views")
        elif p.reference_source == "CAPTURE":
            col.prop(p, "capture_dir")
            col.prop(p, "reference_views")
        else:
            n = len(reference_cameras(context.scene))
            col.label(text=f"{_count(n, 'camera')} with a reference image", icon="CAMERA_DATA" if n else "ERROR")

        col.separator()
        col.prop(p, "target_source")
        if p.target_source == "SELECTED":
            n = sum(1 for o in context.selected_objects if o.type == "CAMERA")
            col.label(text=f"{_count(n, 'camera')} selected", icon="CAMERA_DATA" if n else "ERROR")
        else:
            col.prop(p, "orbit_count")
            col.prop(p, "orbit_elevation")
            col.prop(p, "orbit_radius")
            col.prop(p, "orbit_fov")
            col.label(text="Around the 3D cursor", icon="PIVOT_CURSOR")

        col.separator()
        col.prop(p, "checkpoint")
        if not p.checkpoint.strip():
            from .. import prefs as P
            from ..models.pretrained import shipped_or_none

            pr = P.get(context)
            if pr is not None and pr.checkpoint_dir.strip():
                col.label(text="Model: the Default checkpoint of the preferences", icon="INFO")
            else:
                from ..models.pretrained import FIGURES

                col.prop(p, "shipped_model")
                ck = shipped_or_none(None if p.shipped_model == "auto" else p.shipped_model)
                if ck is not None:  # the measured figures, over as many lines as the sidebar needs (a label is
                    # cut off at the sidebar's edge, never wrapped)
                    text = FIGURES.get(p.shipped_model, "not measured")
                    for k, line in enumerate(wrap_text(text if p.shipped_model == "auto" else
                                                       f"Measured: {text}")):
                        col.label(text=line, icon="INFO" if k == 0 else "BLANK1")
                else:
                    col.label(text="Not in this copy: choose a checkpoint or the other model", icon="ERROR")
        col.prop(p, "device")
        col.prop(p, "quality")
        col.prop(p, "precision")
        col.prop(p, "reference_sizing")
        if p.reference_sizing == "CUSTOM":
            col.prop(p, "reference_size")
        col.prop(p, "nearest")
        col.prop(p, "photo_colours")
        col.prop(p, "adapt_steps")
        col.prop(p, "plane_distance")
        col.prop(p, "output")
        if p.output == "FILES":
            col.prop(p, "output_dir")
        col.prop(p, "save_depth")

        _torch_warning(layout, context)
        draw_job(layout, p, "mrvm.synthesize", "RENDER_RESULT", "Synthesizing...")


classes = (MRVM_PT_model, MRVM_PT_novel_views)
