"""Does a recovered model agree with its own photo pairs? A check of the poses without the truth.

Incremental mapping can place every photo and still be wrong: a ring of photos taken too far apart, or an arc
whose two halves were joined at a wrong angle, comes out as one model with a small reprojection error whose
cameras are tens of degrees off (`docs/capture_check/`). Each verified photo pair says how the two cameras turn
relative to each other (its matches alone, re-estimated with the model's cameras); a correct model agrees with
most pairs to a fraction of a degree, a wrong one disagrees with most of them by degrees. Single pairs can
disagree in a correct model, so the check reads the median over the pairs, and only over pairs that COLMAP's
verification found in general position (CALIBRATED or UNCALIBRATED): a pair whose matches lie on one plane (the
ground seen from photos 100 degrees apart) re-estimates about 90 degrees off in a right model, as a plane's
matches admit more than one relative pose.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .align import rotation_angle_deg

MIN_INLIERS = 30
"""Pairs with fewer verified matches are left out (their own relative pose is too loose to judge a model by)."""
SUSPECT_MEDIAN_DEG = 1.5
"""Median disagreement above which the poses are reported as suspect. Chosen on 160 synthetic captures with known
poses and confirmed on 80 others by a rule written first (`docs/capture_check/`): no model within 1 degree of the
truth went over 0.71 degrees; 19 of 25 models more than 10 degrees off went over 1.5."""
MIN_PAIRS = 3
"""Fewer pairs give no verdict (a model of two or three photos is its pairs)."""


def pair_rotation_check(rec: Any, db_path: Path, min_inliers: int = MIN_INLIERS, seed: int = 0,
                        general_only: bool = True) -> dict:
    """Compare the relative rotation of every verified pair of placed photos in ``db_path`` (at least
    ``min_inliers`` inlier matches; in general position unless ``general_only`` is False) with the model
    ``rec``'s. Returns what ``meta.json`` records as
    ``pose_check``: the pairs compared, the median and the share over 5 degrees of their disagreement, the
    three worst pairs, the threshold and ``suspect`` (median over :data:`SUSPECT_MEDIAN_DEG`)."""
    import pycolmap

    ransac = pycolmap.RANSACOptions()
    ransac.max_error = 4.0  # pixels; the pairs' inliers were verified at COLMAP's 4 px
    ransac.min_num_trials = 100  # verified inliers converge at once; COLMAP's floor of 1000 made this 8x slower
    ransac.random_seed = seed
    placed = set(rec.reg_image_ids())
    cfg = pycolmap.TwoViewGeometryConfiguration
    general = {int(cfg.CALIBRATED), int(cfg.UNCALIBRATED)}
    angles: list[tuple[float, str, str]] = []
    keypoints: dict[int, np.ndarray] = {}
    db = pycolmap.Database.open(Path(db_path))
    try:
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            matches = geometry.inlier_matches
            if a not in placed or b not in placed or len(matches) < min_inliers:
                continue
            if general_only and int(geometry.config) not in general:
                continue
            for i in (a, b):
                if i not in keypoints:
                    keypoints[i] = np.asarray(db.read_keypoints(i))[:, :2].astype(np.float64)
            im_a, im_b = rec.images[a], rec.images[b]
            est = pycolmap.estimate_relative_pose(rec.cameras[im_a.camera_id], keypoints[a][matches[:, 0]],
                                                  rec.cameras[im_b.camera_id], keypoints[b][matches[:, 1]], ransac)
            if est is None:
                continue
            r_pair = est["cam2_from_cam1"].rotation.matrix()
            r_model = (im_b.cam_from_world() * im_a.cam_from_world().inverse()).rotation.matrix()
            angles.append((rotation_angle_deg(r_pair @ r_model.T), im_a.name, im_b.name))
    finally:
        db.close()
    deg = np.array([x[0] for x in angles])
    median = float(np.median(deg)) if len(deg) >= MIN_PAIRS else None
    worst = sorted(angles, reverse=True)[:3]
    return {"pairs": len(angles), "min_inliers": min_inliers,
            "median_disagreement_deg": None if median is None else round(median, 3),
            "share_over_5deg": round(float((deg > 5.0).mean()), 3) if len(deg) else None,
            "worst": [[a, b, round(d, 2)] for d, a, b in worst],
            "threshold_deg": SUSPECT_MEDIAN_DEG, "suspect": median is not None and median > SUSPECT_MEDIAN_DEG}


def warning(check: dict) -> str | None:
    """The one-line warning for a suspect check, else None."""
    if not check.get("suspect"):
        return None
    return (f"the recovered poses may be wrong: {check['pairs']} photo pairs' own geometry disagrees with the "
            f"model by a median of {check['median_disagreement_deg']:.1f} degrees (right models: under 1). Photos "
            f"taken closer together (more overlap between neighbours) help; meta.json's pose_check names the "
            f"worst pairs")
