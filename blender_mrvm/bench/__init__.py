"""Benchmarks (``python -m blender_mrvm bench <name>``); each module writes CSV figures."""
