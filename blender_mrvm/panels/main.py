"""The "MRVM" tab in the 3D viewport sidebar: a parent panel and the Dataset section.

Other features add sections as sub-panels with ``bl_parent_id = "MRVM_PT_main"`` and the
``MRVMPanel`` base class.
"""

from __future__ import annotations

import bpy


def wrap_text(text: str, width: int = 48) -> list[str]:
    """Split a status message into lines that fit the sidebar."""
    words, lines, cur = text.split(), [], ""
    for w in words:
        if cur and len(cur) + 1 + len(w) > width:
            lines.append(cur)
            cur = w
        else:
            cur = f"{cur} {w}" if cur else w
    return lines + ([cur] if cur else [])


def draw_job(layout, props, operator: str, icon: str, running_text: str) -> None:
    """The foot of every section that starts long work: its button and last status, or, while the
    job runs, a progress bar and how to cancel."""
    if props.running:
        layout.progress(factor=props.progress, type="BAR", text=props.status or running_text)
        layout.label(text="Press Esc to cancel", icon="INFO")
        return
    layout.operator(operator, icon=icon)
    for line in wrap_text(props.status) if props.status else ():
        layout.label(text=line)


class MRVMPanel:
    """Base: where every MRVM panel lives."""

    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "MRVM"


class MRVM_PT_main(MRVMPanel, bpy.types.Panel):
    bl_label = "MRVM Novel Views"
    bl_idname = "MRVM_PT_main"

    def draw(self, context):
        self.layout.label(text="Few-shot neural view synthesis")


class MRVM_PT_dataset(MRVMPanel, bpy.types.Panel):
    bl_label = "Dataset"
    bl_idname = "MRVM_PT_dataset"
    bl_parent_id = "MRVM_PT_main"

    @classmethod
    def poll(cls, context):
        return hasattr(context.scene, "mrvm_dataset")

    def draw(self, context):
        p = context.scene.mrvm_dataset
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.enabled = not p.running
        col.prop(p, "source")
        if p.source == "PATH":
            col.prop(p, "source_path")
        elif p.source == "LIBRARY":
            col.prop(p, "library_category")
            col.prop(p, "library_count")
            col.prop(p, "library_seed")
        else:
            from ..operators.dataset import selected_renderable

            n = selected_renderable(context)
            col.label(text=f"{n} object{'s' if n != 1 else ''} to render selected",
                      icon="OBJECT_DATA" if n else "ERROR")
        col.prop(p, "rig")
        if p.rig == "scene":
            n = sum(1 for o in context.scene.objects if o.type == "CAMERA")
            col.label(text=f"{n} camera{'s' if n != 1 else ''} in the scene", icon="CAMERA_DATA")
        else:
            col.prop(p, "views")
            col.prop(p, "fov")
        if p.rig == "turntable":
            col.prop(p, "elevation")
        col.prop(p, "resolution")
        col.prop(p, "engine")
        if p.engine != "BLENDER_WORKBENCH":
            col.prop(p, "samples")
        col.prop(p, "rgba")
        col.prop(p, "seed")
        col.prop(p, "output_dir")
        col.prop(p, "force")
        if p.source == "PATH":
            col.prop(p, "skip_bad_meshes")
        draw_job(layout, p, "mrvm.render_dataset", "RENDER_STILL", "Rendering...")


classes = (MRVM_PT_main, MRVM_PT_dataset)
