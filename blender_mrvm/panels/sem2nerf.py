"""The "Sem2NeRF" section of the MRVM sidebar tab: one part mask (a dataset's or painted) seen from a
camera -> image planes with images and semantic maps around the object."""

from __future__ import annotations

import bpy

from .main import MRVMPanel, draw_job
from .novel_views import _torch_warning


_label_cache: dict = {}


def _label_colors(checkpoint: str) -> list[tuple[int, str, str]]:
    """(id, name, '#rrggbb') of the chosen checkpoint's labels; [] when it cannot be read. Reads the
    file's small header once per path and modification time (draw() runs on every redraw)."""
    raw = checkpoint.strip()
    from ..models.pretrained import shipped_or_none

    shipped = shipped_or_none("sem2nerf")
    if (not raw and shipped is None) or (raw.startswith("//") and not bpy.data.filepath):
        return []
    from pathlib import Path

    from ..errors import MRVMError
    from ..models.sem2nerf.render import checkpoint_info, label_colors

    path = Path(bpy.path.abspath(raw)) if raw else shipped
    try:
        key = (str(path), path.stat().st_mtime)
    except OSError:
        return []
    if key not in _label_cache:
        try:
            info = checkpoint_info(path)
            _label_cache[key] = label_colors(info.labels, info.names)
        except MRVMError:
            _label_cache[key] = []
    return _label_cache[key]


class MRVM_PT_sem2nerf(MRVMPanel, bpy.types.Panel):
    bl_label = "Sem2NeRF (from a mask)"
    bl_idname = "MRVM_PT_sem2nerf"
    bl_parent_id = "MRVM_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def poll(cls, context):
        return hasattr(context.scene, "mrvm_sem2nerf")

    def draw(self, context):
        p = context.scene.mrvm_sem2nerf
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column()
        col.enabled = not p.running

        col.prop(p, "checkpoint")
        col.prop(p, "mask_source")
        if p.mask_source == "FILE":
            col.prop(p, "mask_path")
            col.prop(p, "viewpoint")
            col.operator("mrvm.sem2nerf_paint_mask", icon="BRUSH_DATA")
        else:
            col.prop(p, "mask_image")
            col.prop(p, "mask_encoding")
            if p.mask_encoding == "COLORS":
                rows = _label_colors(p.checkpoint)
                col.label(text="Paint with the label colours (hex):" if rows else
                          "Paint with the label colours of the semantic maps", icon="INFO")
                for v, name, hexa in rows:
                    col.label(text=f"{v} {name}: {hexa}")
        if p.mask_source == "IMAGE" or p.viewpoint == "CAMERA":
            col.prop(p, "camera")
        col.prop(p, "edits")

        col.separator()
        col.prop(p, "target_source")
        if p.target_source == "ORBIT":
            col.prop(p, "orbit_count")
        else:
            n = sum(1 for o in context.selected_objects if o.type == "CAMERA")
            col.label(text=f"{n} camera{'s' if n != 1 else ''} selected", icon="CAMERA_DATA" if n else "ERROR")

        col.separator()
        col.prop(p, "style")
        if p.style == "SEED":
            col.prop(p, "style_seed")
        col.prop(p, "mix")
        if p.mix > 0:
            col.prop(p, "mix_seed")
        col.prop(p, "device")
        col.prop(p, "quality")
        col.prop(p, "plane_distance")
        col.prop(p, "output")
        if p.output == "FILES":
            col.prop(p, "output_dir")
        layout.prop(p, "show_semantic")

        _torch_warning(layout, context)
        draw_job(layout, p, "mrvm.sem2nerf", "MOD_MASK", "Generating...")


classes = (MRVM_PT_sem2nerf,)
