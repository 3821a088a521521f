"""What differs between the Blender versions the extension supports: 4.2 LTS to 5.0.

The manifest says ``blender_version_min = "4.2.0"``. The API the scene layer uses changed in four places
between 4.2 and 5.0; each one has a helper here, so the rest of the code is written once:

- the EEVEE engine is ``BLENDER_EEVEE_NEXT`` in 4.2-4.5 and ``BLENDER_EEVEE`` again in 5.0 (:func:`set_engine`;
  the project's own name is ``BLENDER_EEVEE`` everywhere, on the command line and in the panel);
- an image format has a ``media_type`` to set before its file format only from 5.0 (:func:`set_file_format`);
- a multi-layer EXR holds one part per pass from 5.0, and one part with ``layer.pass.channel`` names before
  (:func:`exr_passes`);
- new materials and worlds have a node tree from 5.0, and none before (:func:`node_tree`), and ``use_nodes`` is
  deprecated in 5.0 (:func:`uses_nodes`).

``tests/test_blender_versions.py`` runs under any of them; ``make test-blender BPY=4.2.23`` runs the Blender tests
against another Blender (docs/blender_versions.md).
"""

from __future__ import annotations

import numpy as np

# The project's engine names -> what older Blenders call the same engine.
_ENGINE_ALIASES = {"BLENDER_EEVEE": ("BLENDER_EEVEE", "BLENDER_EEVEE_NEXT")}


def set_engine(scene, name: str) -> None:
    """Set ``scene.render.engine`` to the project's engine ``name`` under this Blender's identifier for it."""
    last: Exception | None = None
    for ident in _ENGINE_ALIASES.get(name, (name,)):
        try:
            scene.render.engine = ident
            return
        except TypeError as e:  # not an engine of this Blender
            last = e
    raise TypeError(f"this Blender has no render engine {name}") from last


_MEDIA = {"OPEN_EXR_MULTILAYER": "MULTI_LAYER_IMAGE", "FFMPEG": "VIDEO"}


def set_file_format(settings, file_format: str) -> None:
    """Set an ``ImageFormatSettings``' file format; from Blender 5.0 its media type first (a multi-layer EXR is
    not an image format there until the media type says so)."""
    if hasattr(settings, "media_type"):
        settings.media_type = _MEDIA.get(file_format, "IMAGE")
    settings.file_format = file_format


def exr_passes(parts: dict[str, dict[str, np.ndarray]]) -> dict[str, dict[str, np.ndarray]]:
    """``{pass: {channel: array}}`` from a Blender multi-layer EXR's parts (``read_exr_parts``' output).

    Blender 5.0 writes one part a pass (part ``ViewLayer.Combined``, channels ``R, G, B, A``, or the channels
    named in full); 4.2-4.5 write one part whose channels are ``ViewLayer.Combined.R``, with the index passes
    under short names (``IndexOB``), given here by 5.0's (``Object Index``). A channel's pass is the name's
    second-to-last dot component, or the part's name when the channel's name is bare."""
    out: dict[str, dict[str, np.ndarray]] = {}
    for part, chans in parts.items():
        part_pass = part.rsplit(".", 1)[-1] if part else ""
        for k, v in chans.items():
            bits = k.split(".")
            p = bits[-2] if len(bits) >= 2 else part_pass
            out.setdefault(_PASS_NAMES.get(p, p), {})[bits[-1]] = v
    return out


# Blender < 5.0's short EXR names of passes -> 5.0's.
_PASS_NAMES = {"IndexOB": "Object Index", "IndexMA": "Material Index"}


def uses_nodes(idblock) -> bool:
    """Whether a material or world renders from its node tree: always from 5.0 (``use_nodes`` is deprecated there,
    and reading it warns), where ``use_nodes`` says before."""
    import bpy

    if bpy.app.version >= (5, 0, 0):
        return idblock.node_tree is not None
    return bool(idblock.use_nodes)


def node_tree(idblock):
    """A material's or world's node tree, made where this Blender created the block without one (< 5.0)."""
    if idblock.node_tree is None:
        idblock.use_nodes = True
    return idblock.node_tree
