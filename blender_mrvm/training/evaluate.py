"""Evaluation with the SRN / pixelNeRF protocol: fixed input view ids per object, every other view scored.

The input view ids come from the dataset's own protocol file where it has one
(``splits/eval_views.json`` written by ``make-shapenet``: ``input_views_1`` / ``input_views_2`` and
the matching ``target_views_*``), else from pixelNeRF's fixed SRN ids (64 / 64, 104), else they must
be given. Reports PSNR, SSIM and LPIPS-VGG per category and overall (means over all scored views),
plus the two trivial baselines the acceptance criterion compares against: the nearest reference
view shown as the answer (by camera direction), and the mean colour of the reference images, and
the model's PSNR margin over the better of the two. Writes a JSON report, the same figures as a
Markdown table (``eval.md``) and a PNG grid (one row per category: references | ground truth | prediction).
"""

from __future__ import annotations

import json
import math
from collections import defaultdict
from dataclasses import asdict
from pathlib import Path
from functools import partial
from typing import Any, Sequence

import numpy as np
import torch

from ..datasets import format as F
from ..datasets.loaders import ObjectScene
from ..errors import InputError
from ..models.metrics import psnr, ssim, ssim_gauss
from ..models.reproject import ReprojectConfig
from ..progress import Progress, as_step_of
from ..synthesis import reference_shape, resize_mask, resize_view

METRICS = ("psnr", "ssim", "lpips", "ssim_gauss")
"""Reported metrics: ``ssim`` is pixelNeRF's convention (scikit-image's defaults), ``ssim_gauss`` the
Gaussian-window SSIM (what reports before session 3 called ``ssim``)."""
LOWER_IS_BETTER = ("lpips", "depth_abs_rel", "depth_missing", "depth_rel_median")
"""Per-view scores where less is better (the rest: more)."""
PROTOCOL_FILE = "eval_views.json"
"""Protocol file under ``<root>/splits/`` (written by ``make-shapenet``)."""
SRN_INPUT_VIEWS = {1: [64], 2: [64, 104]}
"""pixelNeRF's fixed SRN input views (``eval.py --source``), used for SRN folders without a protocol file."""


def protocol_views(root: Path, n_inputs: int, fmt: str | None = None) -> tuple[list[int], list[int] | None, str]:
    """(input view ids, target view ids or None = every other view, where they came from) for ``n_inputs``.

    Reads ``<root>/splits/eval_views.json`` (``input_views_<n>``, ``target_views_<n>``); SRN folders
    without one use pixelNeRF's ids; anything else is an :class:`InputError` asking for explicit ids."""
    path = Path(root) / "splits" / PROTOCOL_FILE
    if path.is_file():
        try:
            rec = json.loads(path.read_text())
        except json.JSONDecodeError as e:
            raise InputError(f"{path}: not valid JSON ({e})") from e
        key = f"input_views_{n_inputs}"
        if key not in rec:
            have = sorted(k.rsplit("_", 1)[1] for k in rec if k.startswith("input_views_"))
            raise InputError(f"{path} has no {key} (it defines {', '.join(have) or 'no'} input count(s)); "
                             f"pass --input-views explicitly")
        inputs = [int(v) for v in rec[key]]
        targets = rec.get(f"target_views_{n_inputs}")
        return inputs, ([int(v) for v in targets] if targets is not None else None), str(path)
    if fmt == "srn" and n_inputs in SRN_INPUT_VIEWS:
        return list(SRN_INPUT_VIEWS[n_inputs]), None, "pixelNeRF SRN protocol"
    raise InputError(f"{root} has no splits/{PROTOCOL_FILE} naming the fixed input views; "
                     f"pass --input-views (e.g. 0 or 0,1)")


def protocol_target_inputs(root: Path, n_inputs: int) -> dict[int, list[int]] | None:
    """Per-target input views of the dataset's protocol (``target_inputs_<n>`` in ``eval_views.json``:
    {target view id: [input view ids]}, as ``make-captures`` writes: each held-out view of a camera path
    is synthesized from its neighbours on the path), or None when the protocol has one input set for all."""
    path = Path(root) / "splits" / PROTOCOL_FILE
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text()).get(f"target_inputs_{n_inputs}")
    except (json.JSONDecodeError, AttributeError) as e:
        raise InputError(f"{path}: not a protocol file ({e})") from e
    if rec is None:
        return None
    try:
        return {int(t): [int(v) for v in refs] for t, refs in rec.items()}
    except (AttributeError, TypeError, ValueError):
        raise InputError(f"{path}: target_inputs_{n_inputs} must map target view ids to lists of view ids") from None


def per_category(items: Sequence, category, k: int) -> list:
    """The first ``k`` items of every category, order kept (``k`` <= 0 keeps all)."""
    if k <= 0:
        return list(items)
    seen: dict[str, int] = defaultdict(int)
    out = []
    for it in items:
        c = category(it)
        if seen[c] < k:
            seen[c] += 1
            out.append(it)
    return out


def nearest_of(scene: ObjectScene, pool: Sequence[int], tgt: int, k: int) -> list[int]:
    """The ``k`` views of ``pool`` (positions in the scene) nearest view ``tgt``, in pool order, by the rule
    synthesis picks references with (angle between the directions from the box centre, plus the log-ratio
    of the distances: any pose, any distance)."""
    from ..synthesis import nearest_views

    c = 0.5 * (np.asarray(scene.bbox[0], np.float64) + np.asarray(scene.bbox[1], np.float64))
    return [pool[i] for i in nearest_views([scene.c2w[r] for r in pool], scene.c2w[tgt], c, k)]


def _nearest_ref(scene: ObjectScene, refs: Sequence[int], tgt: int) -> int:
    """The reference nearest the target (:func:`nearest_of`)."""
    return nearest_of(scene, refs, tgt, 1)[0]


def _spread(items: list, k: int) -> list:
    """At most ``k`` of ``items``, evenly spread (``k`` <= 0 keeps all)."""
    if k and len(items) > k:
        return [items[i] for i in np.linspace(0, len(items) - 1, k).round().astype(int)]
    return items


def _model_views(s: ObjectScene, views: Sequence[int], w: int, h: int):
    """(images, c2w, intrinsics, masks or None) of views (positions) at ``w`` x ``h``, as the model sees them."""
    mv = [resize_view(s.images[r], s.intrinsics[r], w, h) for r in views]
    masks = None if s.masks is None else np.stack([resize_mask(s.masks[r], w, h) for r in views])
    return np.stack([im for im, _ in mv]), [s.c2w[r] for r in views], [k for _, k in mv], masks


def _pool_positions(s: ObjectScene, pool) -> list[int]:
    """Positions of the pool's views in the scene (None = every view)."""
    if pool is None:
        return list(range(len(s)))
    pos = {vid: k for k, vid in enumerate(s.view_ids)}
    return [pos[v] for v in pool]


def _jobs(s: ObjectScene, input_views, target_views, target_inputs, max_targets: int, nearest: int,
          pool) -> list[tuple[ObjectScene, list[int], list[int]]]:
    """One object's (scene, reference positions, target positions) jobs (see :func:`evaluate`)."""
    pos = {vid: k for k, vid in enumerate(s.view_ids)}
    what = f"object {s.category}/{s.name}"
    if target_inputs is not None:
        wanted = sorted(target_inputs) if target_views is None else list(target_views)
        absent = [v for v in wanted if v not in pos or v not in target_inputs
                  or (not nearest and any(r not in pos for r in target_inputs[v]))]
        if absent:
            raise InputError(f"{what} lacks target view(s) {absent[:5]} or their inputs")
        per = _spread([([pos[r] for r in target_inputs[v]], pos[v]) for v in wanted], max_targets)
    else:
        missing = [v for v in [*input_views, *(pool or [])] if v not in pos]
        if missing:
            raise InputError(f"{what} has no view(s) {missing} to use as input")
        refs = [pos[v] for v in input_views]
        if target_views is None:
            targets = [k for k in range(len(s)) if k not in refs]
        else:
            absent = [v for v in target_views if v not in pos]
            if absent:
                raise InputError(f"{what} has no target view(s) {absent[:5]}")
            targets = [pos[v] for v in target_views if pos[v] not in refs]
        targets = _spread(targets, max_targets)
        if not nearest:
            return [(s, refs, targets)]
        per = [(refs, t) for t in targets]
    if nearest:
        among = _pool_positions(s, pool)
        short = [s.view_ids[t] for _, t in per if len([k for k in among if k != t]) < nearest]
        if short:
            raise InputError(f"{what}: fewer than {nearest} other views to take the nearest from (target "
                             f"view {short[0]})")
        per = [(nearest_of(s, [k for k in among if k != t], t, nearest), t) for _, t in per]
    return [(s, list(refs), [t]) for refs, t in per]


def scores_against(gt, candidates: dict[str, Any], lpips) -> dict[str, dict[str, float]]:
    """PSNR, SSIM (pixelNeRF's and the Gaussian one) and, with ``lpips`` (:class:`models.metrics.LPIPS`), LPIPS of
    each named (H, W, 3) image in [0, 1] (tensor or array) against ``gt``. The LPIPS of all of them goes through VGG
    in one batch with ``gt`` (a view's model image and its baselines at 64 px: 136 ms against 376 ms one pair at a
    time on one core). Scored in float32 whatever autocast the caller renders under: the benches render a
    precision point inside ``torch.autocast``, and on the CPU that ran SSIM's filters and LPIPS's VGG in bf16 too
    (SSIM 0.11-0.14 low at the same PSNR, session 34: the "speckle" recorded since session 21 was the metric's)."""
    g = torch.as_tensor(np.ascontiguousarray(gt), dtype=torch.float32)
    imgs = {k: torch.as_tensor(np.ascontiguousarray(v), dtype=torch.float32) for k, v in candidates.items()}
    with torch.autocast("cpu", enabled=False):
        out = {k: {"psnr": float(psnr(p, g)[0]), "ssim": float(ssim(p, g)[0]),
                   "ssim_gauss": float(ssim_gauss(p, g)[0])} for k, p in imgs.items()}
    if lpips is not None and imgs:
        dev = lpips.shift.device
        batch = torch.stack(list(imgs.values())).permute(0, 3, 1, 2)
        with torch.no_grad(), torch.autocast(dev.type, enabled=False):
            d = lpips.distance(batch.to(dev), g.permute(2, 0, 1)[None].to(dev))
        for k, v in zip(imgs, d.tolist()):
            out[k]["lpips"] = float(v)
    return out


def alpha_scores(acc: np.ndarray, mask: np.ndarray) -> dict[str, float | None]:
    """How well the accumulated opacity (the image planes' alpha) matches the object mask: mean opacity
    on background and on object pixels (None where the view has none: a view without the object in frame had
    counted an opacity of 0 on its object pixels, pulling the mean over views down), and the IoU of opacity > 0.5
    with the mask."""
    acc, mask = np.asarray(acc, np.float64), np.asarray(mask, bool)
    pred = acc > 0.5
    union = np.logical_or(pred, mask).sum()
    return {"background": float(acc[~mask].mean()) if (~mask).any() else None,
            "object": float(acc[mask].mean()) if mask.any() else None,
            "iou": float(np.logical_and(pred, mask).sum() / union) if union else 1.0}


DEPTH_SCORES = ("depth_abs_rel", "depth_missing", "depth_rel_median")
"""Per view, over the pixels where the data's depth map sees a surface: the mean |rendered - true| / true distance
along the ray with nothing rendered counting as 1 (``depth_abs_rel``), the share of them the model rendered
nothing on (``depth_missing``), and the median relative error over the rest (``depth_rel_median``: how far off
the surface is where the model drew one, the figure ``eval --reproject`` depends on)."""


def depth_scores(depth: np.ndarray, z: np.ndarray, intr) -> dict[str, float]:
    """:data:`DEPTH_SCORES` of the model's ``depth`` (H, W), along the ray, 0 where it rendered nothing, against
    the planar depth map ``z`` (0 = nothing); {} for a view without a surface, no ``depth_rel_median`` where
    the model rendered none of it."""
    from ..geometry import cameras

    true = cameras.ray_distances(z, intr)
    fg = true > 0
    if not fg.any():
        return {}
    true, got = true[fg], np.asarray(depth, np.float64)[fg]
    rel = np.abs(got - true) / true
    drawn = got > 0
    out = {"depth_abs_rel": float(np.mean(np.where(drawn, rel, 1.0))), "depth_missing": float(1 - drawn.mean())}
    if drawn.any():
        out["depth_rel_median"] = float(np.median(rel[drawn]))
    return out


def evaluate(model, scenes: list[ObjectScene], input_views: Sequence[int], lpips=None, max_targets: int = 0,
             out_dir: Path | None = None, grid_objects: int = 13, chunk: int | None = None,
             target_views: Sequence[int] | None = None, extra: dict[str, Any] | None = None,
             ref_size: int = 0, max_ref_size: int = 0, target_inputs: dict[int, Sequence[int]] | None = None,
             skip: str = "off", workers: int = 1, adapt=None, nearest: int = 0,
             pool: Sequence[int] | None = None, reproject: str = "off", reproject_cfg=None):
    """Progress generator; returns the report dict (also written to ``out_dir/eval.json``).

    ``reproject``: "model" lays the references' own colours over each view where they see its surface
    (``models/reproject.py``), through the model's depth (its renders of the view and of each reference);
    "gt" through the data's depth maps and masks instead (the ceiling with exact geometry; the data must have
    them, at the references' size). Each view then also records the model's own scores (``model_only``) and
    the report the paired difference (``reprojection_minus_model``). ``reproject_cfg``: a
    :class:`models.reproject.ReprojectConfig`.

    ``nearest``: render each target from its ``nearest`` nearest views (:func:`nearest_of`) among ``pool``
    (view ids; None = every view of the object), the target itself excluded, instead of the protocol's
    references: a dense capture, where every other photo is at hand. The protocol still picks the targets.
    As in synthesis, the masks of the whole pool (the target's excluded) carve the visual hull.

    ``adapt``: an :class:`training.adapt.AdaptConfig`; when on, each reference set gets its own copy of the
    model fine-tuned on those references alone (leave one out) before its targets render.

    ``ref_size`` / ``max_ref_size``: the model sees the references resized as synthesis does
    (``synthesize.reference_shape``); baselines and ground truth stay at the dataset's size.

    ``skip``: empty-space skipping mode (``models/hull.py``) for objects with masks; ``workers``: ray chunks
    rendered side by side (``threads.render_workers``).

    ``target_views``: view ids to score (None = every view that is not an input); ``extra``: entries
    added to the report (e.g. the checkpoint and the protocol's source); ``target_inputs``: {target view
    id: input view ids} when each target has its own references (then ``target_views`` defaults to its
    keys and ``input_views`` is not used)."""
    model.eval()
    reproject_cfg = reproject_cfg or ReprojectConfig()
    no_depth = [f"{s.category}/{s.name}" for s in scenes if s.depths is None] if reproject == "gt" else []
    if no_depth:
        raise InputError(f"--reproject gt needs the data's depth maps; {len(no_depth)} object(s) have none "
                         f"(first: {no_depth[0]})")
    if adapt is not None and not adapt.on:
        adapt = None
    records: list[dict[str, Any]] = []
    grid_rows = []
    jobs = []
    for s in scenes:
        jobs += _jobs(s, input_views, target_views, target_inputs, max_targets, nearest, pool)
    total = sum(len(t) for _, _, t in jobs)
    if not total:  # every view an input (--input-views 0,1,2,3 of 4 views): an empty report is no evaluation
        raise InputError(f"nothing to score: every target view of the {len(scenes)} object(s) is one of the input "
                         f"views {list(input_views)}; leave some views out of the inputs")
    small = [s for s, _, _ in jobs if min(s.images.shape[1:3]) < getattr(lpips, "MIN_SIZE", 0)]
    if small:  # before anything renders (it had been max_pool2d's traceback after the first view)
        s = small[0]
        raise InputError(f"object {s.category}/{s.name} has {s.images.shape[2]}x{s.images.shape[1]} px views: "
                         f"LPIPS-VGG needs at least {lpips.MIN_SIZE} px a side; pass --no-lpips")
    # grid: the first object of every category, then further objects, up to grid_objects rows
    firsts = {}
    seen_objects = set()
    for oi, (s, _, _) in enumerate(jobs):
        firsts.setdefault(s.category, oi)
        seen_objects.add(id(s))
    grid_set = set((list(firsts.values()) + [i for i in range(len(jobs)) if i not in firsts.values()])[:grid_objects])
    done = 0
    sizes: set = set()
    for oi, (s, refs, targets) in enumerate(jobs):
        ref_imgs = s.images[refs]
        mean_col = ref_imgs.reshape(-1, 3).mean(0)
        w, h = reference_shape(s.intrinsics[refs[0]], ref_size, max_ref_size)
        ref_images, ref_c2w, ref_intr, ref_masks = _model_views(s, refs, w, h)
        sizes.add((w, h))
        # nearest: the pool is every other view (the target's excluded); its masks carve the hull and the
        # model adapts to all of it, as synthesis does with a dense set of references
        others = [k for k in _pool_positions(s, pool) if k not in targets] if nearest else refs
        m = model
        if adapt is not None:
            from .adapt import adapt as adapt_to

            a_views = _model_views(s, others, w, h) if nearest else (ref_images, ref_c2w, ref_intr, ref_masks)
            m = yield from as_step_of(adapt_to(model, *a_views[:3], s.bbox, adapt, a_views[3], s.background, lpips,
                                               max_refs=len(refs) if nearest else 0), done, total,
                                      lambda p, o=f"{s.category}/{s.name}": f"{o}: {p.message}")
        hull = None
        if nearest and s.masks is not None and skip != "off":
            hull = model.world_hull(s.masks[others], [s.c2w[k] for k in others], [s.intrinsics[k] for k in others],
                                    s.bbox)
        elif ref_masks is not None and skip != "off":  # the references' hull once for all the object's targets
            hull = model.world_hull(ref_masks, ref_c2w, ref_intr, s.bbox)  # (synthesize would build it per view)
        render = partial(m.synthesize, ref_images, ref_c2w, ref_intr, s.bbox, chunk=chunk, ref_masks=ref_masks,
                         skip=skip, workers=workers, hull=hull)
        geometry: dict[int, tuple] = {}  # reference position -> its geometry, rendered when first read
        for ti, t in enumerate(targets):
            out = render(s.c2w[t], s.intrinsics[t])
            pred = out["color"]
            gt = torch.from_numpy(s.images[t])
            cands = {}
            if reproject != "off":
                cands["model_only"] = pred
                pred, share = _reprojected(s, t, out, reproject, reproject_cfg, refs,
                                           ref_images, ref_c2w, ref_intr, ref_masks, render, geometry)
            cands["model"] = pred
            near = torch.from_numpy(s.images[_nearest_ref(s, refs, t)])
            if near.shape == gt.shape:
                cands["baseline_nearest"] = near
            cands["baseline_mean"] = np.broadcast_to(mean_col, gt.shape)
            if (target_inputs is not None or nearest) and ref_imgs.shape[1:] == gt.shape:
                # neighbouring references: their pixel-wise mean is a third trivial answer (a blur that
                # PSNR rewards; reported beside the others, not counted in the best-baseline margin)
                cands["baseline_blend"] = ref_imgs.mean(0).astype(np.float32)
            sc = scores_against(gt, cands, lpips)
            rec = {"category": s.category, "object": s.name, "view": int(s.view_ids[t]),
                   "inputs": [int(s.view_ids[r]) for r in refs], **sc["model"]}  # what --compare-to pairs on
            if reproject != "off":
                rec.update({"model_only": sc["model_only"], "reference_share": share})
            if s.masks is not None and not s.masks[t].all():  # (a room's masks hold every pixel: nothing to score)
                rec["alpha"] = alpha_scores(out["acc"].numpy(), s.masks[t])
            if s.depths is not None:
                rec.update(depth_scores(out["depth"].numpy(), s.depths[t], s.intrinsics[t]))
            rec.update({k: v for k, v in sc.items() if k.startswith("baseline_")})
            records.append(rec)
            if ti == 0 and oi in grid_set:
                grid_rows.append([*ref_imgs, s.images[t], pred.numpy()])
            done += 1
            yield Progress(done, total, f"{s.category}/{s.name} view {s.view_ids[t]}: {rec['psnr']:.2f} dB")
    report = summarize(records)
    report["protocol"] = {"input_views": list(input_views) if target_inputs is None and not nearest else "per target",
                          "nearest": nearest or None,
                          "pool": None if not nearest else "every other view" if pool is None else list(pool),
                          "target_views": list(target_views) if target_views is not None else "all others",
                          "max_targets": max_targets, "objects": len(seen_objects),
                          "empty_space_skipping": skipping_record(skip, [s for s in scenes if id(s) in seen_objects]),
                          "reference_sizes": sorted([list(x) for x in sizes]),
                          "scored_views": len(records), "lpips": "vgg v0.1" if lpips is not None else None,
                          "adaptation": asdict(adapt) if adapt is not None else None,
                          "reproject": None if reproject == "off" else
                          {"depth": reproject, **asdict(reproject_cfg)}}
    if reproject != "off" and records:
        own = [{**r, **r["model_only"]} for r in records]
        paired = compare_reports({"views": records}, {"views": own})["overall"]
        for k in DEPTH_SCORES:  # the model's depth is scored either way
            paired.pop(k, None)
        report["reprojection_minus_model"] = paired
    report.update(extra or {})
    lists = sorted({s.split_list for s in scenes if id(s) in seen_objects and getattr(s, "split_list", None)})
    if lists:  # NMR/DVR: which split lists named the objects (pixelNeRF's softras_ or DVR's own)
        report["data"] = {**(report.get("data") or {}), "split_lists": lists}
    if out_dir is not None:
        out_dir = Path(out_dir)
        F.atomic_write_text(out_dir / "eval.json", report_json({**report, "views": records}) + "\n")
        F.atomic_write_text(out_dir / "eval.md", markdown_table(report))
        if grid_rows:
            F.write_png(out_dir / "eval_grid.png", make_grid(grid_rows))
            report["grid"] = str(out_dir / "eval_grid.png")
    return report


def skipping_record(skip: str, scenes: Sequence[ObjectScene]) -> str:
    """What ``eval.json``'s protocol records as empty-space skipping: ``skip`` as asked where every object has masks
    (the references' visual hull needs them), "off (no masks)" where none has, and the share otherwise."""
    if skip == "off" or not scenes:
        return skip
    masked = sum(s.masks is not None for s in scenes)
    if masked == len(scenes):
        return skip
    if not masked:
        return "off (no masks)"
    return f"{skip} for the {masked} of {len(scenes)} objects with masks, off for the rest"


def _reference_geometry(s: ObjectScene, r: int, source: str, image, intr, mask, render):
    """(distances along the rays (h, w), object mask (h, w)) of reference ``r`` (a position in the scene) for
    ``eval --reproject``: the model's render of that view ("model"; depth where its opacity reaches one half, as
    synthesis writes it; the data's mask where it has one, else that opacity) or the data's depth map ("gt")."""
    from ..geometry import cameras

    if source == "gt":
        if s.depths[r].shape != image.shape[:2]:
            raise InputError(f"--reproject gt needs references at the dataset's size ({s.depths[r].shape[1]} px "
                             f"wide), the model sees them at {image.shape[1]} px: pass --ref-size -1")
        dist = cameras.ray_distances(s.depths[r], s.intrinsics[r])
        return dist, dist > 0
    from ..synthesis.views import ALPHA_DEPTH_THRESHOLD

    o = render(s.c2w[r], intr)
    drawn = o["acc"].numpy() >= ALPHA_DEPTH_THRESHOLD  # as synthesis: its depth maps hold a surface only there
    return np.where(drawn, o["depth"].numpy(), 0.0), mask if mask is not None else drawn


def _reprojected(s: ObjectScene, t: int, out: dict, source: str, cfg, refs, ref_images, ref_c2w, ref_intr, ref_masks,
                 render, geometry: dict):
    """(the view with the colours of its ``cfg.max_refs`` nearest references laid over, (H, W, 3) tensor; share of
    its pixels taken at least half from them) for ``eval --reproject``; ``geometry`` caches each reference's."""
    from ..geometry import cameras
    from ..models import reproject as rp
    from ..synthesis.views import colour_lenders

    centre = 0.5 * (np.asarray(s.bbox[0], np.float64) + np.asarray(s.bbox[1], np.float64))
    pick = list(colour_lenders(ref_c2w, s.c2w[t], centre, cfg))
    for j in pick:
        if j not in geometry:
            geometry[j] = _reference_geometry(s, refs[j], source, ref_images[j], ref_intr[j],
                                              None if ref_masks is None else ref_masks[j], render)
    if source == "gt":
        depth = cameras.ray_distances(s.depths[t], s.intrinsics[t])
        acc = (depth > 0).astype(np.float32)
    else:
        depth, acc = out["depth"].numpy(), out["acc"].numpy()
    pred, share = rp.lay_over(out["color"].numpy(), acc, depth, s.c2w[t], s.intrinsics[t], ref_images[pick],
                              [ref_c2w[j] for j in pick], [ref_intr[j] for j in pick], [geometry[j] for j in pick], cfg)
    return torch.from_numpy(pred), share


def _values(recs, key, sub=None) -> list:
    """The records' ``key`` (in their ``sub`` dict), where they have one (None: a score the view has not)."""
    vals = [(r[sub] if sub else r).get(key) for r in recs if sub is None or sub in r]
    return [v for v in vals if v is not None]


def _mean(recs, key, sub=None):
    """Mean of a per-view score; PSNR leaves out its +inf (an image equal to the truth, counted by
    :func:`_identical`), while a NaN stays in and makes the mean NaN (null in the report), as for every other
    score: a NaN view had been dropped from the PSNR mean alone, which then stood on fewer views than ``n``."""
    vals = _values(recs, key, sub)
    vals = [v for v in vals if v != float("inf")] if key == "psnr" else vals
    return float(np.mean(vals)) if vals else None


def _identical(recs, sub=None) -> int:
    """Views whose image equals the truth (PSNR +inf, left out of the PSNR mean)."""
    return sum(v == float("inf") for v in _values(recs, "psnr", sub))


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    by_cat = defaultdict(list)
    for r in records:
        by_cat[r["category"]].append(r)

    def block(recs):
        b = {m: _mean(recs, m) for m in METRICS}
        b["n"] = len(recs)
        b["baseline_nearest"] = {m: _mean(recs, m, "baseline_nearest") for m in METRICS}
        b["baseline_mean"] = {m: _mean(recs, m, "baseline_mean") for m in METRICS}
        if any("baseline_blend" in r for r in recs):
            b["baseline_blend"] = {m: _mean(recs, m, "baseline_blend") for m in METRICS}
        alphas = [r["alpha"] for r in recs if "alpha" in r]
        if alphas:
            b["alpha"] = {k: _mean(alphas, k) for k in ("background", "object", "iou")}  # over the views that have it
        for k in DEPTH_SCORES:
            if any(k in r for r in recs):
                b[k] = _mean(recs, k)
        if any("model_only" in r for r in recs):
            b["model_only"] = {m: _mean(recs, m, "model_only") for m in METRICS}
            b["reference_share"] = _mean(recs, "reference_share")
        # a view equal to the truth has PSNR +inf (null per view in eval.json); its mean leaves it out, said here
        # (it had been left out without a word, and the model's and a baseline's means then stood on other views)
        for sub in (None, "baseline_nearest", "baseline_mean", "baseline_blend", "model_only"):
            k = _identical(recs, sub)
            if k:
                (b if sub is None else b[sub])["psnr_identical_views"] = k
        base = {k: b[k]["psnr"] for k in ("baseline_nearest", "baseline_mean") if b[k]["psnr"] is not None}
        if base and b["psnr"] is not None:
            best = max(base, key=base.get)
            b["best_baseline"] = best
            b["psnr_gain_over_best_baseline"] = b["psnr"] - base[best]
        return b

    return {"overall": block(records), "per_category": {c: block(v) for c, v in sorted(by_cat.items())}}


def make_grid(rows: list[list[np.ndarray]], pad: int = 2) -> np.ndarray:
    """uint8 image: one row per object, cells resized (nearest) to the first cell's height."""
    h = max(r[-1].shape[0] for r in rows)
    cols = max(len(r) for r in rows)
    w = max(c.shape[1] for r in rows for c in r)
    out = np.ones((len(rows) * (h + pad) + pad, cols * (w + pad) + pad, 3), np.float32)
    for i, r in enumerate(rows):
        # references left-aligned, ground truth and prediction in the last two columns
        cells = list(r[:-2]) + [None] * (cols - len(r)) + list(r[-2:])
        for j, c in enumerate(cells):
            if c is None:
                continue
            c = np.asarray(c, np.float32)
            yi = (np.arange(h) * c.shape[0] // h)
            xi = (np.arange(w) * c.shape[1] // w)
            y0, x0 = pad + i * (h + pad), pad + j * (w + pad)
            out[y0:y0 + h, x0:x0 + w] = c[yi][:, xi, :3]
    return F.to_uint8(out)


def report_json(report: dict, indent: int | None = 2) -> str:
    """The report as JSON; a non-finite number (an SSIM of a NaN render) is null, as a missing mean is: NaN is not
    JSON, and readers other than Python's refuse it. ``indent=None``: one line (what `eval` prints last on stdout)."""
    return json.dumps(_finite(report), indent=indent, allow_nan=False)


def _finite(v):
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    if isinstance(v, (float, np.floating)) and not math.isfinite(v):
        return None
    return v


def markdown_table(report: dict) -> str:
    """The report as a Markdown table: per category and overall, model vs. both trivial baselines."""
    def f(v, nd):  # "-" as eval.json's null: a missing or non-finite mean (an SSIM of images under its window)
        return "-" if v is None or not math.isfinite(v) else f"{v:.{nd}f}"

    head = ("| category | views | PSNR | SSIM | LPIPS | SSIM (Gaussian) | nearest-view PSNR / SSIM / LPIPS "
            "| mean-colour PSNR / SSIM / LPIPS | PSNR gain over better baseline |\n"
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|\n")
    rows = []
    for name, b in [*report["per_category"].items(), ("**overall**", report["overall"])]:
        bn, bm = b["baseline_nearest"], b["baseline_mean"]
        rows.append(f"| {name} | {b['n']} | {f(b['psnr'], 2)} | {f(b['ssim'], 3)} | {f(b['lpips'], 3)} "
                    f"| {f(b.get('ssim_gauss'), 3)} "
                    f"| {f(bn['psnr'], 2)} / {f(bn['ssim'], 3)} / {f(bn['lpips'], 3)} "
                    f"| {f(bm['psnr'], 2)} / {f(bm['ssim'], 3)} / {f(bm['lpips'], 3)} "
                    f"| {f(b.get('psnr_gain_over_best_baseline'), 2)} |")
    text = head + "\n".join(rows) + "\n"
    bb = report["overall"].get("baseline_blend")
    if bb:
        text += (f"\nPixel-wise mean of each target's references (its neighbours): PSNR {f(bb['psnr'], 2)}, SSIM "
                 f"{f(bb['ssim'], 3)}, LPIPS {f(bb['lpips'], 3)} (not counted in the gain over the better baseline).\n")
    text += ("\nSSIM: scikit-image's defaults (7x7 uniform window, sample covariance), as pixelNeRF reports it; "
             "SSIM (Gaussian): 11x11 Gaussian window, sigma 1.5.\n")
    o = report["overall"]
    same = {lab: b["psnr_identical_views"] for lab, b in (("model", o), ("nearest view", o["baseline_nearest"]),
                                                          ("mean colour", o["baseline_mean"]))
            if b.get("psnr_identical_views")}
    if same:
        text += ("\nPSNR leaves out the views whose image equals the truth (infinite PSNR): "
                 + ", ".join(f"{k} {v} of {o['n']}" for k, v in same.items()) + ".\n")
    a = report["overall"].get("alpha")
    if a:
        text += (f"\nOpacity (the image planes' alpha) against the object masks: mean {f(a['background'], 3)} on "
                 f"background pixels, {f(a['object'], 3)} on object pixels; IoU of opacity > 0.5 with the mask "
                 f"{f(a['iou'], 3)}.\n")
    dr = report["overall"].get("depth_abs_rel")
    if dr is not None:
        o = report["overall"]
        text += (f"\nDepth against the depth maps, where they see a surface: mean absolute relative error of the "
                 f"distance along the ray {dr:.4f} (nothing rendered counts as 1); nothing rendered on "
                 f"{f(o.get('depth_missing'), 4)} of those pixels; median relative error where something was "
                 f"{f(o.get('depth_rel_median'), 4)}.\n")
    mo = report["overall"].get("model_only")
    if mo:
        rp = (report.get("protocol") or {}).get("reproject") or {}
        text += (f"\nThe references' colours laid over each view through the {rp.get('depth', '?')} depth (eval "
                 f"--reproject): {report['overall']['reference_share']:.1%} of the pixels taken at least half from them; "
                 f"the model alone: PSNR {f(mo['psnr'], 2)}, SSIM {f(mo['ssim'], 3)}, LPIPS {f(mo['lpips'], 3)}.\n")
    return text


COMPARED_DATA = ("root", "split", "format", "split_lists")
"""``eval.json``'s ``data`` entries two evaluations must share to be paired (object names repeat across sets:
a turntable and a sphere-rig render of the same library, another resolution)."""
COMPARED_PROTOCOL = ("input_views", "nearest", "pool")
"""``eval.json``'s ``protocol`` entries compared when a report has no per-view ``inputs`` (written before they
were recorded)."""


COMPARED_SETTINGS = ("precision", "device", "protocol.empty_space_skipping", "protocol.reference_sizes",
                     "protocol.adaptation", "protocol.reproject", "image_size.used")
"""Rendering settings ``compare_reports`` lists when two evaluations differ in them (``settings_differ``): a
paired difference then measures the setting as much as the checkpoint, which ``compare.json`` had not said."""


def setting_differences(a: dict, b: dict) -> dict[str, list]:
    """{setting: [a's, b's]} of the :data:`COMPARED_SETTINGS` both reports record and differ in."""
    out = {}
    for key in COMPARED_SETTINGS:
        va, vb, found = a, b, True
        for part in key.split("."):
            if not (isinstance(va, dict) and isinstance(vb, dict) and part in va and part in vb):
                found = False
                break
            va, vb = va[part], vb[part]
        if found and va != vb:
            out[key] = [va, vb]
    return out


def _same_root(x, y) -> bool:
    """Two recorded data roots name the same folder (a relative one, as reports before this recorded it, is read
    against the current folder)."""
    import os

    norm = lambda p: os.path.normcase(os.path.abspath(os.path.expanduser(str(p))))  # noqa: E731
    return x == y or norm(x) == norm(y)


def check_comparable(a: dict, b: dict) -> None:
    """InputError naming what differs unless reports ``a`` and ``b`` (``eval.json`` dicts, or parts of them) scored
    the same views of the same data from the same references: their ``data`` root, split and format
    (:data:`COMPARED_DATA`), and for every view both scored its input view ids (``inputs``). Only what both
    record is compared: a report written before the per-view inputs were kept is compared on its protocol's
    input views, nearest and pool (:data:`COMPARED_PROTOCOL`) instead, one without ``data`` on its views alone."""
    da, db = a.get("data") or {}, b.get("data") or {}
    for k in COMPARED_DATA:
        x, y = da.get(k), db.get(k)
        if x is not None and y is not None and not (_same_root(x, y) if k == "root" else x == y):
            raise InputError(f"the two evaluations are of different data: {k} {x} against {y}; a paired comparison "
                             "needs the same views of the same data set and split")
    views = [r for r in (*a.get("views", ()), *b.get("views", ()))]
    if views and all("inputs" in r for r in views):
        key = lambda r: (r["category"], r["object"], r["view"])  # noqa: E731
        ia = {key(r): r["inputs"] for r in a.get("views", ())}
        for r in b.get("views", ()):
            k = key(r)
            if k in ia and list(ia[k]) != list(r["inputs"]):
                raise InputError(f"the two evaluations rendered view {k[2]} of {k[0]}/{k[1]} from other input views "
                                 f"({list(ia[k])} against {list(r['inputs'])}): another input protocol (--n-inputs, "
                                 "--input-views, --nearest) cannot be paired")
        return
    pa, pb = a.get("protocol") or {}, b.get("protocol") or {}
    for k in COMPARED_PROTOCOL:
        if k in pa and k in pb and pa[k] != pb[k]:
            raise InputError(f"the two evaluations used other input views: protocol {k} {pa[k]} against {pb[k]}; "
                             "another input protocol cannot be paired")


def compare_reports(a: dict, b: dict) -> dict:
    """Paired difference a - b of two evaluations of the same views (``eval.json`` dicts with 'views'); an
    InputError first when they are not of the same data and references (:func:`check_comparable`).

    Per metric, overall and per category, the object is the unit (the views of one object are correlated):
    ``diff`` is the mean over objects of each object's mean difference over its common views (every object
    counts alike, however many views it has), ``se_objects`` its standard error over objects, ``wins`` the share
    of objects on which a is better (higher PSNR/SSIM, lower LPIPS) and ``ties`` the share on which neither is (a
    wins of 0 had read as "worse on every object" where the two were equal); ``diff_views`` is the mean difference
    over the common views themselves (the two differ when objects have different numbers of views). ``unpaired``
    counts the views only one of them scored (left out: the figures are of the common views alone);
    ``settings_differ`` the rendering settings the two differ in (:func:`setting_differences`)."""
    check_comparable(a, b)
    key = lambda r: (r["category"], r["object"], r["view"])  # noqa: E731
    va, vb = {key(r): r for r in a["views"]}, {key(r): r for r in b["views"]}
    common = sorted(set(va) & set(vb))
    if not common:
        raise InputError("the two evaluations share no scored view")

    def stats(keys):
        out = {"views": len(keys)}
        for m in (*METRICS, *DEPTH_SCORES):
            per_obj = defaultdict(list)
            for k in keys:
                x, y = va[k].get(m), vb[k].get(m)
                if x is not None and y is not None and np.isfinite(x) and np.isfinite(y):
                    per_obj[k[:2]].append(x - y)
            if not per_obj:
                continue
            d = np.array([np.mean(v) for v in per_obj.values()])
            se = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else None
            better = d < 0 if m in LOWER_IS_BETTER else d > 0
            out[m] = {"diff": float(d.mean()), "se_objects": se, "objects": len(d), "wins": float(better.mean()),
                      "ties": float((d == 0).mean()),
                      "diff_views": float(np.mean([x for v in per_obj.values() for x in v]))}
        return out

    cats = sorted({k[0] for k in common})
    return {"overall": stats(common), "per_category": {c: stats([k for k in common if k[0] == c]) for c in cats},
            "unpaired": {"this": len(set(va) - set(vb)), "other": len(set(vb) - set(va))},
            "settings_differ": setting_differences(a, b)}
