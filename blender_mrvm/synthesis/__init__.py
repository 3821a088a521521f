"""Novel views from posed reference images with a trained checkpoint of any model kind (bpy-free).

The core of ``python -m blender_mrvm synthesize``, of the add-on's Synthesize operator (which runs that
command in the worker process), of ``eval`` (reference sizing) and of ``demo``. See ``views.py``.
"""

from .views import (ALPHA_DEPTH_THRESHOLD, DENSE_NEAREST, References, SynthesisConfig, SynthesisSummary,  # noqa: F401
                    check_reference_folder, encode_references, json_line, load_checkpoint, load_references, nearest_views,
                    object_box, orbit_targets, parse_bbox, reference_shape, reference_sizes, render_target,
                    resize_mask,
                    references_per_target, resize_view, resolve_device, rgba_image, synthesize_views, targets_from_views,
                    trained_size)
