"""Add-on preferences: device, folders, and the worker interpreter for the torch side."""

from __future__ import annotations

import bpy
from bpy.props import EnumProperty, StringProperty

# In Blender the add-on's module is ``bl_ext.<repo>.blender_mrvm``; this file sits at its root.
ADDON_ID = __package__


_status: dict = {}
"""The last dependency report per ``python_path`` preference (``draw()`` reads only this)."""


def _python_path(context=None) -> str:
    prefs = get(context)
    return prefs.python_path if prefs else ""


def dependency_status(context=None, cached: bool = False):
    """What the worker's Python (see ``worker.choose_interpreter``) has and lacks: a ``DependencyReport``.

    Probing starts a process (up to 30 s), so it runs at register time (in a thread), when the
    preference changes and from "Check Again", never from ``draw()``: with ``cached`` (what panels and
    the preferences' draw pass) this only reads the last report, a "checking" one until it is there.
    """
    from .worker import DependencyReport, dependency_report

    path = _python_path(context)
    rep = _status.get(path)
    if rep is None and cached:
        return DependencyReport(None, error="", pending=True)
    if rep is None:
        rep = _status[path] = dependency_report(path)
    return rep


def refresh_dependency_status(context=None, background: bool = False) -> None:
    """Probe the worker's Python again (now, or in a thread for register time) and cache the report."""
    import threading

    from .worker import clear_probe_cache, dependency_report

    path = _python_path(context)

    def work() -> None:
        _status[path] = dependency_report(path)

    clear_probe_cache()
    if background:
        threading.Thread(target=work, name="mrvm-dependency-probe", daemon=True).start()
    else:
        work()


def _python_path_changed(self, context) -> None:
    refresh_dependency_status(context, background=True)


class MRVM_OT_check_dependencies(bpy.types.Operator):
    """Check again which dependencies the worker Python has (after installing something)"""

    bl_idname = "mrvm.check_dependencies"
    bl_label = "Check Again"

    def execute(self, context):
        refresh_dependency_status(context)
        rep = dependency_status(context)
        if rep.error or rep.missing:
            self.report({"WARNING"}, rep.error or f"missing in {rep.interpreter.path}: {', '.join(rep.missing)}")
        else:
            self.report({"INFO"}, f"all dependencies found in {rep.interpreter.path}")
        return {"FINISHED"}


class MRVM_OT_copy_install_command(bpy.types.Operator):
    """Copy the command that installs the missing dependencies into the worker Python"""

    bl_idname = "mrvm.copy_install_command"
    bl_label = "Copy Install Command"

    def execute(self, context):
        cmd = dependency_status(context).install_command
        if not cmd:
            self.report({"INFO"}, "nothing is missing")
            return {"CANCELLED"}
        context.window_manager.clipboard = cmd
        self.report({"INFO"}, f"copied: {cmd}")
        return {"FINISHED"}


class MRVM_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    device: EnumProperty(name="Device", items=[
        ("AUTO", "Auto", "CUDA when available, else CPU"),
        ("CPU", "CPU", "Always the CPU"),
        ("CUDA", "CUDA", "An NVIDIA GPU"),
    ], default="AUTO")
    python_path: StringProperty(name="Worker Python", subtype="FILE_PATH", default="",
                                description="Interpreter with torch for training and synthesis; empty = auto-detect a project .venv",
                                update=_python_path_changed)
    checkpoint_dir: StringProperty(name="Checkpoints", subtype="DIR_PATH", default="")
    cache_dir: StringProperty(name="Cache", subtype="DIR_PATH", default="")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "device")
        layout.prop(self, "python_path")
        layout.prop(self, "checkpoint_dir")
        layout.prop(self, "cache_dir")
        box = layout.box()
        rep = dependency_status(context, cached=True)  # draw() never starts a process
        for text, ok in rep.lines():
            box.label(text=text, icon="CHECKMARK" if ok else "ERROR")
        row = box.row()
        row.operator("mrvm.check_dependencies", icon="FILE_REFRESH")
        if rep.install_command:
            row.operator("mrvm.copy_install_command", icon="COPYDOWN")


def get(context=None) -> MRVM_AddonPreferences | None:
    """The add-on's preferences, or None when the add-on is not enabled (e.g. registered by hand)."""
    context = context or bpy.context
    addon = context.preferences.addons.get(ADDON_ID)
    return addon.preferences if addon else None


classes = (MRVM_AddonPreferences, MRVM_OT_check_dependencies, MRVM_OT_copy_install_command)


def register() -> None:
    for cls in classes:
        bpy.utils.register_class(cls)
    _status.clear()
    try:
        refresh_dependency_status(background=True)  # panels show the report once the probe is back
    except Exception:  # preferences not there yet (registered by hand): the first real call probes
        pass


def unregister() -> None:
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
