"""Sidebar panels (3D viewport, tab "MRVM"). Each draws only what is available.

Each module in ``MODULES`` defines a ``classes`` tuple; they are registered in order.
"""

import importlib

MODULES = ("main", "capture", "novel_views", "sem2nerf")


def _classes():
    for name in MODULES:
        yield from importlib.import_module(f".{name}", __package__).classes


def register() -> None:
    import bpy

    for cls in _classes():
        bpy.utils.register_class(cls)


def unregister() -> None:
    import bpy

    for cls in reversed(list(_classes())):
        bpy.utils.unregister_class(cls)
