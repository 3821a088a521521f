"""blender_mrvm: few-shot neural view synthesis inside Blender.

This module imports nothing heavy: Blender calls :func:`register` / :func:`unregister`, which import
the Blender side (``props``, ``prefs``, ``operators``, ``panels``) lazily, and the bpy-free layers
(``geometry``, ``datasets``, ``models``, ``training``, ``capture``) import without Blender.
Inside the package every import is relative: Blender loads extensions as ``bl_ext.<repo>.<id>``.
"""

__version__ = "0.1.0"

_registered_modules: list = []


def _blender_modules():
    from . import operators, panels, prefs, props

    # Order matters: properties and preferences first (operators and panels read them).
    return [props, prefs, operators, panels]


def register() -> None:
    """Register every class and property of the add-on (safe to call after unregister())."""
    if _registered_modules:
        unregister()
    for mod in _blender_modules():
        mod.register()
        _registered_modules.append(mod)


def unregister() -> None:
    """End the jobs still running (Blender frees a running modal operator whose class goes without cancelling it:
    its worker, timer and progress bar would stay), then unregister everything register() registered, in reverse
    order."""
    if _registered_modules:
        from .operators._modal import end_live_jobs

        end_live_jobs()
    while _registered_modules:
        _registered_modules.pop().unregister()
