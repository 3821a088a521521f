"""Sidebar panels (3D viewport, tab "MRVM"). Each draws only what is available.

Each module in ``MODULES`` defines a ``classes`` tuple; they are registered in order.
"""

import importlib

import bpy

MODULES = ("main", "capture", "novel_views", "sem2nerf")

CLASSES = tuple(c for name in MODULES for c in importlib.import_module(f".{name}", __package__).classes)
"""Every class of the modules in ``MODULES``, in registration order."""

register, unregister = bpy.utils.register_classes_factory(CLASSES)
