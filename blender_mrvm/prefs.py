"""Add-on preferences: device, folders, and the worker interpreter for the torch side."""

from __future__ import annotations

import time

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


def checkpoint_problem(path: str) -> str:
    """Why the default checkpoint set in the preferences is not one ('' when it is, or is unset): a folder of runs
    (or anything else without a model) is named with what is expected instead. Reads checkpoint headers only (no
    torch)."""
    from pathlib import Path

    from .models.checkpoint_files import find_checkpoint

    raw = path.strip()
    if not raw:
        return ""
    p = Path(bpy.path.abspath(raw)).expanduser()
    if not p.exists():
        return f"the default checkpoint set in the add-on preferences does not exist: {p}"
    if find_checkpoint(p) is not None:
        return ""
    runs: list[str] = []
    if p.is_dir():
        try:
            runs = sorted(d.name for d in p.iterdir() if d.is_dir() and find_checkpoint(d) is not None)
        except OSError:
            pass
    held = f" (it holds the runs {', '.join(runs[:3])}{', ...' if len(runs) > 3 else ''}: choose one)" if runs else ""
    return (f"the default checkpoint set in the add-on preferences, {p}, is not a checkpoint{held}: it expects a model "
            ".safetensors file, a checkpoint folder or one run folder (holding checkpoints/)")


def _cache_dir(context=None) -> str:
    """The Cache preference as an absolute folder ('' when unset or the add-on is not enabled)."""
    prefs = get(context)
    return bpy.path.abspath(prefs.cache_dir.strip()) if prefs and prefs.cache_dir.strip() else ""


_checkpoint_notes: dict = {}
"""(time, checkpoint_problem()) per preference value: draw() looks again after a few seconds."""


class MRVM_AddonPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON_ID

    device: EnumProperty(name="Training device", items=[
        ("AUTO", "Auto", "CUDA when available, else CPU"),
        ("CPU", "CPU", "Always the CPU"),
        ("CUDA", "CUDA", "An NVIDIA GPU"),
    ], default="AUTO", description="Where Train / Fine-tune runs (Synthesize novel views and Sem2NeRF have their own "
                                   "Device setting in their panels)")
    python_path: StringProperty(name="Worker Python", subtype="FILE_PATH", default="",
                                description="Interpreter with torch for training and synthesis; empty = auto-detect a project .venv",
                                update=_python_path_changed)
    checkpoint_dir: StringProperty(name="Default checkpoint", subtype="DIR_PATH", default="",
                                   description="The one checkpoint Synthesize novel views uses when its own Checkpoint "
                                               "is empty, instead of the shipped models: a run folder, a checkpoint "
                                               "folder or a model .safetensors file (not a folder of runs)")
    cache_dir: StringProperty(name="Weights cache", subtype="DIR_PATH", default="",
                              description="Folder of the offline VGG16 / LPIPS weights the worker reads (Keep its "
                                          "losses, VGG16 encoders), where `python -m blender_mrvm fetch-weights --out "
                                          "FOLDER` put them; empty = the project's .cache/weights beside a project "
                                          ".venv's worker Python, else .cache/weights beside the add-on's folder")

    def draw(self, context):
        layout = self.layout
        layout.prop(self, "device")
        layout.prop(self, "python_path")
        layout.prop(self, "checkpoint_dir")
        seen = _checkpoint_notes.get(self.checkpoint_dir)
        if seen is None or time.monotonic() - seen[0] > 3.0:  # a few stat calls and headers, not at every redraw
            seen = _checkpoint_notes[self.checkpoint_dir] = (time.monotonic(), checkpoint_problem(self.checkpoint_dir))
        note = seen[1]
        if note:
            layout.label(text=note, icon="ERROR")
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
    from . import worker

    for cls in classes:
        bpy.utils.register_class(cls)
    _status.clear()
    _checkpoint_notes.clear()
    worker.preferences_cache_dir = _cache_dir  # the worker's MRVM_WEIGHTS_DIR
    try:
        refresh_dependency_status(background=True)  # panels show the report once the probe is back
    except Exception:  # preferences not there yet (registered by hand): the first real call probes
        pass


def unregister() -> None:
    from . import worker

    worker.preferences_cache_dir = None
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
