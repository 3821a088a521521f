"""The embedded generalizable NeRF (bpy-free): configs, samplers, renderer, encoder, NeRFormer, MRVM, metrics.

Import submodules directly (``from blender_mrvm.models.model import GeneralizableNeRF``); this package
imports nothing heavy itself.
"""
