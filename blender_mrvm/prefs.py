"""Add-on preferences: device, folders, and the worker interpreter for the torch side."""

from __future__ import annotations

import importlib.util

import bpy
from bpy.props import EnumProperty, StringProperty

# In Blender the add-on's module is ``bl_ext.<repo>.blender_mrvm``; this file sits at its root.
ADDON_ID = __package__


def dependency_status() -> list[tuple[str, bool, str]]:
    """(name, available, how to get it) for the heavy dependencies, in Blender's own Python."""
    out = []
    for mod, pip_name in (("torch", "torch==2.13.0"), ("OpenEXR", "openexr"), ("pycolmap", "pycolmap==4.2.1")):
        ok = importlib.util.find_spec(mod) is not None
        out.append((mod, ok, f"pip install {pip_name}"))
    return out


class MRVM_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    device: EnumProperty(name="Device", items=[
        ("AUTO", "Auto", "CUDA when available, else CPU"),
        ("CPU", "CPU", "Always the CPU"),
        ("CUDA", "CUDA", "An NVIDIA GPU"),
    ], default="AUTO")
    python_path: StringProperty(name="Worker Python", subtype="FILE_PATH", default="",
                                description="Interpreter with torch for training and synthesis; empty = auto-detect a project .venv")
    checkpoint_dir: StringProperty(name="Checkpoints", subtype="DIR_PATH", default="")
    cache_dir: StringProperty(name="Cache", subtype="DIR_PATH", default="")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "device")
        layout.prop(self, "python_path")
        layout.prop(self, "checkpoint_dir")
        layout.prop(self, "cache_dir")
        box = layout.box()
        box.label(text="Dependencies in Blender's Python:")
        for name, ok, how in dependency_status():
            box.label(text=f"{name}: found" if ok else f"{name}: missing ({how}, or set Worker Python)",
                      icon="CHECKMARK" if ok else "ERROR")


def get(context=None) -> MRVM_AddonPreferences | None:
    """The add-on's preferences, or None when the add-on is not enabled (e.g. registered by hand)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return addon.preferences if addon else None


classes = (MRVM_AddonPreferences,)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
