"""Paths the panel's settings hold: absolute, or ``//`` relative to the saved .blend (one rule for every section)."""

from __future__ import annotations

from pathlib import Path

import bpy

from ..errors import InputError


def blend_path(raw: str, what: str) -> Path:
    """The absolute path a panel setting names; InputError naming ``what`` when the setting is empty, or ``//``
    relative in a .blend not saved yet (``bpy.path.abspath`` would read it from the folder Blender was started in:
    a dataset rendered from another ``chair.obj``, photos read from elsewhere)."""
    raw = raw.strip()
    if not raw:
        raise InputError(f"choose {what}")
    if raw.startswith("//") and not bpy.data.filepath:
        raise InputError(f"save the .blend first or choose an absolute path for {what} (// is relative to the .blend)")
    return Path(bpy.path.abspath(raw))
