"""Pose recovery of real captures with pycolmap (bpy-free).

- :mod:`.config`: :class:`CaptureConfig`, the typed settings (defaults are the fast path the
  capture benchmark measures).
- :mod:`.sfm`: :func:`recover_poses`, a progress generator: scan + check the photos, SIFT
  extraction, matching (exhaustive or sequential), incremental mapping, undistortion, export.
- :mod:`.align`: Umeyama similarity alignment, pose errors, automatic up / centre / scale.
- :mod:`.export`: the capture in our dataset format (+ the sparse points as PLY).

pycolmap is imported lazily inside the functions that need it.
"""
