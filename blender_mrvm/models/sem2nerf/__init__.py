"""Sem2NeRF (Chen et al., ECCV 2022): one part mask seen from a known camera -> a radiance field with
per-point part logits. ``inputs`` (mask builders, numpy), ``config`` (typed presets), ``model``
(encoder, mapping network, FiLM-SIREN field, rendering), ``render`` (the CLI's synthesis core).
Imports nothing heavy at package level; bpy-free."""
