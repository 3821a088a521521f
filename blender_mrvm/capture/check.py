"""Does a recovered model agree with its own photo pairs? A check of the poses without the truth.

Incremental mapping can place every photo and still be wrong: a ring of photos taken too far apart, or an arc
whose two halves were joined at a wrong angle, comes out as one model with a small reprojection error whose
cameras are tens of degrees off (`docs/capture_check/`). Each verified photo pair says how the two cameras turn
relative to each other and in which direction the second stands from the first (its matches alone, re-estimated
with the model's cameras); a correct model agrees with most pairs to a fraction of a degree, a wrong one disagrees
with most of them by degrees. Single pairs can disagree in a correct model, so the check reads the median over the
pairs, and only over pairs that COLMAP's verification found in general position (CALIBRATED or UNCALIBRATED): a
pair whose matches lie on one plane (the ground seen from photos 100 degrees apart) re-estimates about 90 degrees
off in a right model, as a plane's matches admit more than one relative pose. A model made of two parts joined at a
wrong angle keeps low medians (the pairs across the joint are few), so the check also asks whether the pairs that
agree with the model still join its photos as all the pairs do (:data:`SPLIT_AGREE_DEG`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from .align import rotation_angle_deg

MIN_INLIERS = 30
"""Pairs with fewer verified matches are left out (their own relative pose is too loose to judge a model by)."""
SUSPECT_MEDIAN_DEG = 1.5
"""Median disagreement (of the rotations, or of the directions) above which the poses are reported as suspect. Set
on synthetic captures with known poses, each step confirmed on a set rendered after its rule was written
(`docs/capture_check/RULE.md`): over 320 photo sets, no model within 1 degree of the truth went over 0.99 degrees
(234 models) and 27 of 34 models more than 10 degrees off went over 1.5."""
MIN_PAIRS = 3
"""Fewer pairs give no verdict (a model of two or three photos is its pairs)."""
CHECK_DIRECTIONS = True
"""Also judge the directions between the cameras' centres (the relative translations, up to scale): 27 instead of
25 of those 34 models flagged, none of the right ones."""


SPLIT_AGREE_DEG = 10.0
"""A pair agrees with the model when both its angles are within this. The model is split when the pairs that agree
leave its photos in more pieces than all the pairs compared do: every pair that would join some of its parts
disagrees, a joint at a wrong angle that the medians cannot see (RULE.md's fourth rule; 5 until the sixth rule)."""
NEAR_TURN_DEG = 60.0
"""The directions' median and the split are judged by the pairs that turn less than this in the model (all pairs
when fewer than :data:`MIN_PAIRS` do). A far pair's own direction is loose: in right models of set G the pairs'
direction disagreement was 0.3 degrees (median) under 40 degrees of turn, 6 at 50-60 and 29 beyond, which flagged
right models of dense captures (RULE.md's sixth rule). The rotations' median keeps every pair. On set H (rendered
after the rule was written; 201 kept models over four ways of running recover-poses: PNG or JPEG with EXIF, one
camera or one a photo) it flagged 6 of 149 right models where the check before it flagged 15, and 36 of 39 models more
than 10 degrees off, as before. On A-F: 0 of 294 right (was 1), 38 of 39 far off (was 39)."""
CHECK_SPLIT = True
"""Also report a split model as suspect. On set F (rendered after the rule was written), over the 68 models
`recover-poses` kept, it flagged none of the 60 right ones and all 5 more than 10 degrees off (the medians alone: 3;
one of the two it added was an arc placed whole, 14 degrees off at medians of 0.4). Over sets A-D and F: 1 of 294
right models flagged (two noisy pairs were its only bridge), 39 of 39 more than 10 degrees off (medians alone: 30)."""


def _pieces(nodes: list[str], edges: list[tuple[str, str]]) -> int:
    """Connected pieces of the graph ``nodes``, ``edges``."""
    parent = {n: n for n in nodes}

    def root(x: str) -> str:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b in edges:
        parent[root(a)] = root(b)
    return len({root(n) for n in nodes})


def _direction_angle_deg(t_a: np.ndarray, t_b: np.ndarray) -> float:
    """Angle between two translations' directions (their lengths, a model's scale, do not count)."""
    c = float(np.dot(t_a, t_b) / max(np.linalg.norm(t_a) * np.linalg.norm(t_b), 1e-12))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _pair_pose_estimator(db: Any, seed: int):
    """``estimate(camera_a, camera_b, a, b, matches)``: a verified pair's own relative pose (pycolmap's estimate, or
    None) from its inlier matches, the database's keypoints read once per photo."""
    import pycolmap

    ransac = pycolmap.RANSACOptions()
    ransac.max_error = 4.0  # pixels; the pairs' inliers were verified at COLMAP's 4 px
    ransac.min_num_trials = 100  # verified inliers converge at once; COLMAP's floor of 1000 made this 8x slower
    ransac.random_seed = seed
    keypoints: dict[int, np.ndarray] = {}

    def points(i: int) -> np.ndarray:
        if i not in keypoints:
            keypoints[i] = np.asarray(db.read_keypoints(i))[:, :2].astype(np.float64)
        return keypoints[i]

    def estimate(camera_a, camera_b, a: int, b: int, matches: np.ndarray):
        return pycolmap.estimate_relative_pose(camera_a, points(a)[matches[:, 0]], camera_b, points(b)[matches[:, 1]],
                                               ransac)
    estimate.points = points  # (the keypoints, for how far the matches move: photo_spacing)
    return estimate


def pair_angles(rec: Any, db_path: Path, min_inliers: int = MIN_INLIERS, seed: int = 0,
                general_only: bool = True, turns: bool = False) -> list[tuple]:
    """``(rotation, direction, photo a, photo b)`` for every verified pair of placed photos in ``db_path`` (at least
    ``min_inliers`` inlier matches; in general position unless ``general_only`` is False): the angle between the
    pair's own relative rotation (re-estimated from its matches with the model's cameras) and the model ``rec``'s,
    and between the two directions from the first camera's centre to the second's, in degrees. With ``turns``, each
    tuple also ends with the pair's turn in the model (the angle of its relative rotation), in degrees."""
    import pycolmap

    placed = set(rec.reg_image_ids())
    cfg = pycolmap.TwoViewGeometryConfiguration
    general = {int(cfg.CALIBRATED), int(cfg.UNCALIBRATED)}
    angles: list[tuple[float, float, str, str]] = []
    db = pycolmap.Database.open(Path(db_path))
    try:
        estimate = _pair_pose_estimator(db, seed)
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            matches = geometry.inlier_matches
            if a not in placed or b not in placed or len(matches) < min_inliers:
                continue
            if general_only and int(geometry.config) not in general:
                continue
            im_a, im_b = rec.images[a], rec.images[b]
            est = estimate(rec.cameras[im_a.camera_id], rec.cameras[im_b.camera_id], a, b, matches)
            if est is None:
                continue
            pair = est["cam2_from_cam1"]
            model = im_b.cam_from_world() * im_a.cam_from_world().inverse()
            angle = (rotation_angle_deg(pair.rotation.matrix() @ model.rotation.matrix().T),
                     _direction_angle_deg(np.asarray(pair.translation), np.asarray(model.translation)),
                     im_a.name, im_b.name)
            angles.append(angle + (rotation_angle_deg(model.rotation.matrix()),) if turns else angle)
    finally:
        db.close()
    return angles


def pair_pose_check(rec: Any, db_path: Path, min_inliers: int = MIN_INLIERS, seed: int = 0,
                    general_only: bool = True, directions: bool = CHECK_DIRECTIONS,
                    split_check: bool = CHECK_SPLIT) -> dict:
    """Compare the relative pose of every verified pair of placed photos in ``db_path`` (at least ``min_inliers``
    inlier matches; in general position unless ``general_only`` is False) with the model ``rec``'s: the angle
    between the two relative rotations, and between the two directions from the first camera's centre to the
    second's (:func:`pair_angles`). Returns what ``meta.json`` records as ``pose_check``: the pairs compared, the
    median of each angle, the share of rotations over 5 degrees, the three worst pairs, the threshold, the pieces
    the disagreeing pairs split the model into (``split_pieces``, see :data:`SPLIT_AGREE_DEG`) and ``suspect``
    (the rotations' median, or with ``directions`` either median, over :data:`SUSPECT_MEDIAN_DEG`; or with
    ``split_check`` a split model)."""
    with_turns = pair_angles(rec, db_path, min_inliers, seed, general_only, turns=True)
    angles = [x[:4] for x in with_turns]
    near = [x[:4] for x in with_turns if x[4] < NEAR_TURN_DEG]
    judged = near if len(near) >= MIN_PAIRS else angles  # the directions and the split (RULE.md's sixth rule)
    rot = np.array([x[0] for x in angles])
    dirs = np.array([x[1] for x in judged])
    enough = len(angles) >= MIN_PAIRS
    median = float(np.median(rot)) if enough else None
    median_dir = float(np.median(dirs)) if enough else None
    suspect = enough and (median > SUSPECT_MEDIAN_DEG or (directions and median_dir > SUSPECT_MEDIAN_DEG))
    names = [rec.images[i].name for i in rec.reg_image_ids()]
    split = (_pieces(names, [(a, b) for r, d, a, b in judged if max(r, d) <= SPLIT_AGREE_DEG])
             - _pieces(names, [(a, b) for _, _, a, b in judged]))
    suspect = suspect or (enough and split_check and split > 0)
    worst = sorted(angles, key=lambda x: -max(x[0], x[1]))[:3]
    return {"pairs": len(angles), "min_inliers": min_inliers,
            "median_disagreement_deg": None if median is None else round(median, 3),
            "median_direction_deg": None if median_dir is None else round(median_dir, 3),
            "share_over_5deg": round(float((rot > 5.0).mean()), 3) if len(rot) else None,
            "worst": [[a, b, round(r, 2), round(d, 2)] for r, d, a, b in worst],
            "threshold_deg": SUSPECT_MEDIAN_DEG, "directions_checked": bool(directions),
            "split_pieces": int(split), "split_agree_deg": SPLIT_AGREE_DEG, "split_checked": bool(split_check),
            "near_turn_deg": NEAR_TURN_DEG, "near_pairs": len(near),
            "suspect": bool(suspect)}


SPARSE_SPACING_DEG = 22.5
"""Photos whose spacing (:func:`photo_spacing`) is this or more are called too far apart. On the synthetic photo sets
of `docs/capture_check/` (sets A-F: 300 arcs of photos 15 degrees apart and 100 rings 30 degrees apart), measured with
the camera of the model the mapping made: every arc 13.0-19.1 degrees, every ring 26.1-66.6. The mapping places 232 of
240 such arcs whole and right, and 1 of 80 rings (A-D)."""


STILL_SHIFT_PX = 1.0
"""Photos whose matches move less than this (pixels; the median over the photos of their best pair's median match
shift, :func:`photo_spacing`) show one view: copies of one photo (0.0 px) or a burst from a tripod (0.1 px with
sensor noise), which the mapping cannot start from (no baseline). The error line said the photos were too far apart
("take one every 10-15 degrees"); the slowest real motion tried, photos of noise 3 px apart, moved 3.0 px."""


def spacing_camera(rec: Any) -> Any | None:
    """One pinhole camera for every photo, from a model that placed at least 3 (the median focal length of its
    cameras; its first camera's size and principal point), or None. A model's focal length is what makes
    :func:`photo_spacing`'s angles right: without EXIF the database's cameras hold a guess (1.2 x the width) that was
    0.5-2.5x the truth on the synthetic sets, which moves the angles about as much (and the view graph's calibration
    was 0.54-2.47x on their rings)."""
    import pycolmap

    if rec is None or rec.num_reg_images() < 3 or not rec.cameras:
        return None
    cams = list(rec.cameras.values())
    focal = [float(np.mean([c.params[i] for i in c.focal_length_idxs()])) for c in cams]
    cx, cy = (float(cams[0].params[i]) for i in cams[0].principal_point_idxs())
    return pycolmap.Camera(model="SIMPLE_PINHOLE", width=cams[0].width, height=cams[0].height,
                           params=[float(np.median(focal)), cx, cy])


def photo_spacing(db_path: Path, camera: Any | None = None, min_inliers: int = MIN_INLIERS, seed: int = 0) -> dict:
    """How far apart the photos of a match database were taken, from their matches alone: for each photo, the angle
    its camera turns to reach the photo it shares the most verified matches with (their relative pose estimated with
    ``camera`` for every photo, see :func:`spacing_camera`; the database's own cameras without one), and the median
    over the photos. Also the photos that share fewer than ``min_inliers`` verified matches with every other photo.
    Returns ``{"spacing_deg": median or None, "focal_from": ..., "photos": n, "unmatched": [names]}``, where
    ``focal_from`` is "model" (``camera`` given), "exif" (every camera of the database holds a prior focal length,
    which feature extraction reads from the photos' EXIF; the view graph's calibration sets one too, so "exif" is
    only true of a database as extraction and matching left it) or "database" (COLMAP's 1.2 x width guess)."""
    import pycolmap

    best: dict[int, tuple[int, float, float]] = {}  # image id -> (inliers, turn in deg, shift in px) of its best pair
    db = pycolmap.Database.open(Path(db_path))
    try:
        cams = {c.camera_id: c for c in db.read_all_cameras()}
        all_prior = bool(cams) and all(c.has_prior_focal_length for c in cams.values())
        images = {im.image_id: im for im in db.read_all_images()}
        estimate = _pair_pose_estimator(db, seed)
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geometry in zip(pair_ids, geometries):
            a, b = pycolmap.pair_id_to_image_pair(pair_id)
            matches = geometry.inlier_matches
            if len(matches) < min_inliers or a not in images or b not in images:
                continue
            if min(best.get(a, (0,))[0], best.get(b, (0,))[0]) >= len(matches):
                continue  # neither photo's best pair: no pose to estimate
            est = estimate(camera or cams[images[a].camera_id], camera or cams[images[b].camera_id], a, b, matches)
            if est is None:
                continue
            turn = rotation_angle_deg(est["cam2_from_cam1"].rotation.matrix())
            moved = estimate.points(a)[matches[:, 0]] - estimate.points(b)[matches[:, 1]]
            shift = float(np.median(np.linalg.norm(moved, axis=1)))
            for i in (a, b):
                if len(matches) > best.get(i, (0,))[0]:
                    best[i] = (len(matches), turn, shift)
    finally:
        db.close()
    turns = [t for _, t, _ in best.values()]
    shifts = [s for _, _, s in best.values()]
    return {"spacing_deg": round(float(np.median(turns)), 1) if turns else None,
            "focal_from": "model" if camera is not None else ("exif" if all_prior else "database"), "photos": len(images),
            "unmatched": sorted((im.name for i, im in images.items() if i not in best), key=str.lower),
            "shift_px": round(float(np.median(shifts)), 2) if shifts else None}


def spacing_named(spacing: dict) -> bool:
    """Whether :func:`photo_spacing` found the photos too far apart with a focal length to trust (the model's or the
    photos' EXIF), or not moved at all (:func:`spacing_still`): what :func:`spacing_advice` names with a figure."""
    deg = spacing.get("spacing_deg")
    far = deg is not None and deg >= SPARSE_SPACING_DEG and spacing.get("focal_from") in ("model", "exif")
    return far or spacing_still(spacing)


def spacing_still(spacing: dict) -> bool:
    """Whether :func:`photo_spacing` found photos that show one view (:data:`STILL_SHIFT_PX`); their turn is noise."""
    shift = spacing.get("shift_px")
    return shift is not None and shift < STILL_SHIFT_PX


def spacing_advice(spacing: dict, rename: dict[str, str] | None = None) -> str:
    """What a user can do about photos :func:`photo_spacing` found too far apart or unmatched ('' when nothing):
    a clause to end an error or warning line with. ``rename`` maps the database's names to the user's photos."""
    parts = []
    deg = spacing.get("spacing_deg")
    if spacing_still(spacing):
        parts.append(f"the photos show one view (matched points move a median of {spacing['shift_px']:.1f} px between "
                     "neighbouring photos: copies of one photo, or taken from one place): move the camera between "
                     "photos")
    elif spacing_named(spacing):
        parts.append(f"neighbouring photos are about {deg:.0f} degrees apart (median over the photos of the turn to "
                     "the one each shares the most matches with), too far for mapping, which needs points seen in "
                     "three photos: take one every 10-15 degrees")
    unmatched = [(rename or {}).get(n, n) for n in spacing.get("unmatched", [])]
    if unmatched:
        shown = ", ".join(unmatched[:3]) + (", ..." if len(unmatched) > 3 else "")
        parts.append(f"{len(unmatched)} photo(s) share too few matches with every other photo (blurred, too dark, "
                     f"or of something else?): {shown}")
    return "; ".join(parts)


def warning(check: dict) -> str | None:
    """The one-line warning for a suspect check, else None."""
    if not check.get("suspect"):
        return None
    direction = check.get("median_direction_deg")
    how = f"{check['median_disagreement_deg']:.1f} degrees in rotation"
    if check.get("directions_checked") and direction is not None:
        how += f" and {direction:.1f} in the direction between the cameras"
    what = (f"{check['pairs']} photo pairs' own geometry disagrees with the model by a median of {how} (right "
            f"models: under 1)")
    medians = [v for v in (check["median_disagreement_deg"], direction if check.get("directions_checked") else None)
               if v is not None]
    if check.get("split_pieces", 0) > 0 and max(medians, default=0.0) <= check["threshold_deg"]:
        what = (f"the photo pairs that join {check['split_pieces'] + 1} parts of the model all disagree with it by "
                f"more than {check['split_agree_deg']:g} degrees (a wrong joint; the pairs' medians look right)")
    closer = "Photos taken closer together (more overlap between neighbours) help"
    spacing = check.get("photo_spacing_deg")
    if spacing is not None and spacing >= SPARSE_SPACING_DEG:
        closer = (f"Neighbouring photos are about {spacing:.0f} degrees apart (see photo_spacing_deg): one every "
                  "10-15 degrees helps")
    return f"the recovered poses may be wrong: {what}. {closer}; meta.json's pose_check names the worst pairs"
