"""The "MRVM" tab in the 3D viewport sidebar: a parent panel and the Dataset section.

Other features add sections as sub-panels with ``bl_parent_id = "MRVM_PT_main"`` and the
``MRVMPanel`` base class.
"""

from __future__ import annotations

import bpy


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
            n = sum(1 for o in context.selected_objects if o.type == "MESH")
            col.label(text=f"{n} mesh object{'s' if n != 1 else ''} selected", icon="OBJECT_DATA")
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
        if p.running:
            layout.progress(factor=p.progress, type="BAR", text=p.status or "Rendering...")
            layout.label(text="Press Esc to cancel", icon="INFO")
        else:
            layout.operator("mrvm.render_dataset", icon="RENDER_STILL")
            if p.status:
                layout.label(text=p.status)


classes = (MRVM_PT_main, MRVM_PT_dataset)
