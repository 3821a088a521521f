"""Render a ShapeNet-13-style multi-view set from the procedural library, with the papers' splits.

Settings (as in pixelNeRF / NeRFormer evaluations on ShapeNet-NMR):

- ``all``: category-agnostic; every category is split into train/val/test objects.
- ``unseen``: train (and val) on airplane, car, chair; test on the other 10 categories.

Views follow the NMR layout by default (a turntable at 30 degrees elevation, 24 views), the papers'
protocol. ``--rig sphere`` or ``--rig hemisphere`` renders the cameras users have instead: directions
uniform on the sphere (or its upper half), a horizontal field of view drawn per view from
``--fov-range`` and a distance per view from ``--distance-range`` (multiples of the distance at which
the object's bounding sphere fills that view), seeded per object and recorded exactly in the per-view
poses and intrinsics (``transforms.json`` frames, ``meta.json`` "cameras"). The
evaluation protocol is fixed and written next to the split lists: ``splits/eval_views.json``
names the input view ids for 1-view and 2-view tests and the remaining target views;
``splits/test_views.lst`` repeats it per test object (``category/object_id inputs1 | inputs2``).

The plan (its parameters and every planned object with its split) is recorded in ``splits/plan.json`` before
anything renders: a shard (``--shard i/n``) whose plan differs from the recorded one is refused (two plans' shards
mixed their objects into one set), and each shard's summary says how many planned objects are finished and which
shards are still to run (the split lists hold the finished objects only).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

from ..datasets.format import PLAN_FILE, plan_path, planned_but_unlisted, read_plan  # noqa: F401

UNSEEN_TRAIN = ("airplane", "car", "chair")
SETTINGS = ("all", "unseen")
RIGS = ("turntable", "sphere", "hemisphere")
TURNTABLE_ELEVATION = 30.0
FOV_DEFAULT = (30.0, 60.0)  # = geometry.rigs.FOV_RANGE_DEG (not imported: --help stays instant)
DIST_DEFAULT = (0.85, 1.6)  # = geometry.rigs.DISTANCE_RANGE
SPLIT_RULES = {  # how plan() splits a category's objects (recorded: another rule is another plan)
    "all": "per category: 20% of the objects to test (at least 1), 10% to val (rounded), the rest to train; "
           "a category of 1 object: train only",
    "unseen": f"{', '.join(UNSEEN_TRAIN)}: 10% of the objects to val (rounded down), the rest to train; "
              "the other categories: every object to test",
}
# the plan's parameters, in the order a difference is named, and how the command line calls them
PLAN_PARAMETERS = (("setting", "--setting"), ("objects_per_category", "--objects-per-category"), ("seed", "--seed"),
                   ("categories", "categories"), ("split_rule", "split rule"))


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--setting", choices=SETTINGS, default="all", help="all: category-agnostic; unseen: "
                   "train on airplane/car/chair, test on the other 10")
    p.add_argument("--objects-per-category", type=int, default=2,
                   help="objects (seeds) per category (default 2). all: 20%% of a category's objects to test (at least "
                        "1) and 10%% to val (rounded), 1 object a category is train only; unseen: 10%% of the train "
                        "categories' objects to val (none below 10), every object of the other 10 to test")
    p.add_argument("--views", type=int, default=24, help="views per object (NMR uses 24)")
    p.add_argument("--resolution", type=int, default=64, help="square image size in pixels (NMR uses 64)")
    p.add_argument("--out", required=True, help="dataset root folder")
    p.add_argument("--shard", default="0/1", help="i/n: render only this deterministic share of the objects (every "
                   "shard of a folder runs the plan recorded in its splits/plan.json)")
    p.add_argument("--engine", default="CYCLES", type=str.upper, choices=("CYCLES", "BLENDER_EEVEE", "BLENDER_WORKBENCH"),
                   help="render engine, as render-dataset's")
    p.add_argument("--samples", type=int, default=8, help="samples per pixel")
    p.add_argument("--seed", type=int, default=0, help="first object seed (objects use seed .. seed+N-1)")
    p.add_argument("--force", action="store_true", help="write into a folder that holds another dataset, or another "
                   "plan (replacing the plan recorded in its splits/plan.json)")
    p.add_argument("--rig", choices=RIGS, default="turntable",
                   help="turntable (default: NMR layout, 30 degrees elevation), or sphere / hemisphere with a field "
                        "of view and a distance drawn per view (seeded per object)")
    p.add_argument("--fov-range", default=None, metavar="MIN,MAX",
                   help="sphere/hemisphere rigs: horizontal field of view per view, degrees (default %g,%g)" % FOV_DEFAULT)
    p.add_argument("--distance-range", default=None, metavar="MIN,MAX",
                   help="sphere/hemisphere rigs: camera distance per view, as multiples of the distance at which the "
                        "object's bounding sphere fills the view (default %g,%g)" % DIST_DEFAULT)
    p.add_argument("--elevation-range", default=None, metavar="MIN,MAX",
                   help="sphere/hemisphere rigs: keep the camera directions to this band of elevations, degrees "
                        "(e.g. 10,50 for cameras near the turntable's 30; a band that starts below the horizon is "
                        "written --elevation-range=-30,10; default: the whole rig)")


def eval_views(views: int, rig: str = "turntable") -> dict:
    """Fixed input view ids (1- and 2-view tests) and the targets (every other view).

    Turntable: a three-quarter front view and the opposite side. Sphere / hemisphere: views 0 and 1,
    whose directions (like every view's) are independent and uniform, so the pair's angle varies per
    object as a user's photos would."""
    from ..errors import InputError

    if views < 3:
        raise InputError(f"the evaluation protocol needs at least 3 views per object, got {views}")
    if rig == "turntable":
        first = round(views * 0.125) % views  # a three-quarter front view on the turntable
        second = (first + views // 2) % views  # the opposite side
    else:
        first, second = 0, 1
    return {"views": views, "input_views_1": [first], "input_views_2": [first, second],
            "target_views_1": [v for v in range(views) if v != first],
            "target_views_2": [v for v in range(views) if v not in (first, second)]}


def plan(setting: str, per_category: int, first_seed: int = 0) -> dict[str, list[str]]:
    """Source strings per split: {"train": [...], "val": [...], "test": [...]} (bpy-free)."""
    from ..errors import InputError
    from ..scene.procedural._registry import CATEGORIES

    if setting not in SETTINGS:
        raise InputError(f"unknown setting {setting!r}; choose all or unseen")
    if per_category < 1:
        raise InputError(f"--objects-per-category must be at least 1, got {per_category}")
    if first_seed < 0:
        raise InputError(f"--seed must not be negative, got {first_seed}")
    if first_seed + per_category > 2 ** 63:  # found before anything renders, not at the last seed
        raise InputError(f"--seed {first_seed} with --objects-per-category {per_category} reaches seed "
                         f"{first_seed + per_category - 1}; seeds must be below 2**63")
    out: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    for cat in CATEGORIES:
        seeds = list(range(first_seed, first_seed + per_category))
        srcs = [f"procedural:{cat}:{s}" for s in seeds]
        if setting == "unseen":
            if cat in UNSEEN_TRAIN:
                n_val = per_category // 10
                out["train"] += srcs[:per_category - n_val]
                out["val"] += srcs[per_category - n_val:]
            else:
                out["test"] += srcs
        else:
            if per_category == 1:
                out["train"] += srcs
                continue
            n_test = max(1, round(per_category * 0.2))
            n_val = round(per_category * 0.1)
            n_train = per_category - n_test - n_val
            out["train"] += srcs[:n_train]
            out["val"] += srcs[n_train:n_train + n_val]
            out["test"] += srcs[n_train + n_val:]
    return out


def camera_settings(args) -> dict:
    """The RenderConfig fields of the camera rig (bpy-free): the turntable's, or the varied rig's ranges."""
    from ..errors import InputError
    from ..geometry.rigs import parse_range

    rig = getattr(args, "rig", "turntable")
    fov, dist = getattr(args, "fov_range", None), getattr(args, "distance_range", None)
    el = getattr(args, "elevation_range", None)
    if rig not in RIGS:
        raise InputError(f"unknown rig {rig!r}; choose one of {', '.join(RIGS)}")
    if rig == "turntable":
        if fov is not None or dist is not None or el is not None:
            raise InputError("--fov-range, --distance-range and --elevation-range need --rig sphere or hemisphere")
        return {"rig": "turntable", "elevation_deg": TURNTABLE_ELEVATION}
    cams = {"rig": rig,
            "fov_range_deg": parse_range(fov, "--fov-range", 0.0, 179.0) if fov is not None else FOV_DEFAULT,
            "distance_range": parse_range(dist, "--distance-range", 0.0, 100.0) if dist is not None else DIST_DEFAULT}
    if el is not None:
        cams["elevation_range_deg"] = parse_range(el, "--elevation-range", -90.0, 90.0, inclusive_lo=True)
    return cams


def render_configs(args) -> list[tuple[str, object]]:
    """(split, RenderConfig) per non-empty split, in render order (validated; needs bpy for RenderConfig)."""
    from ..errors import InputError
    from ..scene.render import RenderConfig
    from .render_dataset import parse_shard

    if args.views < 1:
        raise InputError(f"--views must be at least 1, got {args.views}")
    if not 1 <= args.resolution <= 8192:
        raise InputError(f"--resolution must be between 1 and 8192, got {args.resolution}")
    shard = parse_shard(args.shard)
    cams = camera_settings(args)
    groups = plan(args.setting, args.objects_per_category, args.seed)
    out, cfgs = Path(args.out), []
    for split, sources in groups.items():
        if not sources:
            continue
        # --force for every group: each split's objects rendered with other settings are rendered again (the
        # first group's run has claimed the folder; objects already rendered with these settings are kept)
        cfg = RenderConfig(out=out, sources=tuple(sources), views=args.views,
                           resolution=(args.resolution, args.resolution), engine=args.engine, samples=args.samples,
                           seed=args.seed, shard=shard, force=args.force, split=split, **cams)
        cfg.validate()
        cfgs.append((split, cfg))
    return cfgs


def protocol_rig(cams: dict) -> dict:
    """The rig as eval_views.json records it (the turntable's record is what it always was)."""
    if cams["rig"] == "turntable":
        return {"rig": "turntable", "elevation_deg": cams["elevation_deg"]}
    rec = {"rig": cams["rig"], "fov_range_deg": list(cams["fov_range_deg"]),
           "distance_range": list(cams["distance_range"]), "cameras": "per object, seeded (meta.json 'cameras')"}
    if cams.get("elevation_range_deg") is not None:
        rec["elevation_range_deg"] = list(cams["elevation_range_deg"])
    return rec


def plan_record(args, objects: dict[str, list[str]]) -> dict:
    """What splits/plan.json records: the plan's parameters and its objects (``category/object_id``) per split."""
    from ..scene.procedural._registry import CATEGORIES

    return {"command": "make-shapenet", "setting": args.setting, "objects_per_category": args.objects_per_category,
            "seed": args.seed, "categories": list(CATEGORIES), "split_rule": SPLIT_RULES[args.setting],
            "objects": {split: list(keys) for split, keys in objects.items()}}


def plan_difference(old: dict, new: dict) -> str | None:
    """The first parameter in which two plans differ, in words (None: the same plan)."""
    for key, name in PLAN_PARAMETERS:
        if old.get(key) != new[key]:
            if key == "categories":
                return (f"categories: {len(old.get(key) or [])} there, this version's {len(new[key])} here"
                        if isinstance(old.get(key), list) else "categories: none recorded there")
            if key == "split_rule":
                return "split rule: this version splits a category's objects otherwise"
            return f"{name} {old.get(key)} there, {new[key]} here"
    if old.get("objects") != new["objects"]:
        return "objects: these parameters give other objects in this version"
    return None


def _refuse_other_plan(out: Path, old: dict, new: dict) -> None:
    diff = plan_difference(old, new) if old else f"{plan_path(out)} cannot be read"
    if diff is not None:
        from ..errors import OutputError

        raise OutputError(f"{out} holds the shards of another make-shapenet plan ({diff}; splits/{PLAN_FILE}): "
                          "shards of two plans mix their objects into one set; run with that plan's parameters, use "
                          "--force to replace the plan (objects finished with these render settings are kept and "
                          "move to this plan's splits), or choose another folder")


def _record_plan(out: Path, record: dict, force: bool) -> None:
    """Write splits/plan.json: created only where none is (two shards starting at once with other plans cannot
    both record theirs: the second finds the first's and is refused), replaced with ``force``."""
    from ..datasets import format as F

    path = plan_path(out)
    if force:
        F.atomic_write_json(path, record)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{PLAN_FILE}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(json.dumps(record, indent=2) + "\n")
        F.ordinary_permissions(Path(tmp))
        try:
            os.link(tmp, path)  # whole, and only if there is none
        except FileExistsError:
            pass
        except OSError:  # a file system without hard links
            if not path.exists():
                F.atomic_write_json(path, record)
    finally:
        os.unlink(tmp)
    old = read_plan(out)
    if old is not None:
        _refuse_other_plan(out, old, record)


def _remove_if_untouched(out: Path) -> None:
    """Remove a folder this run created if it holds nothing but the root manifest, the plan and empty folders."""
    import shutil

    from ..datasets import format as F

    keep = {out / F.ROOT_MANIFEST, plan_path(out)}
    if all(p.is_dir() or p in keep for p in out.rglob("*")):
        shutil.rmtree(out, ignore_errors=True)


def run(args) -> int:
    from ..datasets import format as F
    from ..errors import OutputError
    from ..progress import run_with_tqdm
    from ..scene.objects import resolve_sources
    from ..scene.render import prepare_root, render_dataset, root_held, write_splits
    from .render_dataset import parse_shard

    cams = camera_settings(args)
    cfgs = render_configs(args)
    shard = parse_shard(args.shard)
    protocol = eval_views(args.views, cams["rig"])
    groups = plan(args.setting, args.objects_per_category, args.seed)
    out = Path(args.out)
    objects = {split: [spec.key for spec in resolve_sources(tuple(srcs), None, [])] if srcs else []
               for split, srcs in groups.items()}
    record = plan_record(args, objects)
    # Before anything renders: shards of another plan (other objects a category, seed, setting) in this folder
    # would mix two plans' objects into one set's lists
    old_plan = read_plan(out)
    if old_plan is not None and not args.force:
        _refuse_other_plan(out, old_plan, record)
    elif old_plan is not None and (not old_plan or plan_difference(old_plan, record) is not None):
        print(f"note: --force: this run's plan replaces the one recorded in {plan_path(out)} ("
              f"{plan_difference(old_plan, record) if old_plan else 'unreadable'})", file=sys.stderr)
    empty = [split for split in ("val", "test") if not groups[split]]
    if empty:  # legal (a training set; the held-out sets' --seed 1000 recipe), but eval then finds nothing
        print(f"note: --setting {args.setting} with --objects-per-category {args.objects_per_category} gives no "
              f"{' and no '.join(empty)} objects (see --help)", file=sys.stderr)
    fresh = not out.exists() and shard[1] == 1  # (another shard may be starting into it too)
    total_views = 0
    try:
        if cfgs:
            # the folder is this dataset's (or refused, also while a run of other settings renders into it)
            prepare_root(cfgs[0][1])  # before the plan goes into it
        _record_plan(out, record, args.force)
        for split, cfg in cfgs:
            summary = run_with_tqdm(render_dataset(cfg), desc=f"{args.setting}/{split}", unit="view")
            total_views += summary.views_rendered
            for w in summary.warnings:
                print(f"warning: {w}", file=sys.stderr)
    except Exception:
        if fresh and total_views == 0:  # e.g. refused before rendering: leave no empty dataset behind
            _remove_if_untouched(out)
        raise
    now = read_plan(out)
    if now is not None and (not now or plan_difference(now, record) is not None):
        raise OutputError(f"the plan recorded in {plan_path(out)} was replaced while this shard rendered (another run "
                          "with --force); this shard's objects are on disk, the split lists are that plan's")
    # The splits are this plan's objects, each in the split the plan gives it: objects of an earlier plan in the
    # same folder (more objects a category, another setting) stay on disk but out of the lists, and so does a
    # planned object finished in another split before (its shard moves it when it runs)
    split_of = {key: split for split, keys in objects.items() for key in keys}
    only = set()
    for key, split in split_of.items():
        try:
            meta = json.loads((out / key / "meta.json").read_text())
        except (OSError, ValueError):
            meta = None
        if not isinstance(meta, dict) or meta.get("split") in (None, split):
            only.add(key)
    lists = write_splits(out, only=only)
    others = sum(1 for p in out.glob("*/*/meta.json") if f"{p.parent.parent.name}/{p.parent.name}" not in split_of)
    if others > 0:
        print(f"note: {others} object folder(s) in {out} are not part of this plan (an earlier plan's) and are left "
              "out of the split lists", file=sys.stderr)
    finished = {key for keys in lists.values() for key in keys}
    # each split's objects are sharded on their own (render_configs: one render per split), sorted by key
    remaining = sorted({k % shard[1] for keys in objects.values() for k, key in enumerate(sorted(keys))
                        if key not in finished})
    splits_dir = out / "splits"
    splits_dir.mkdir(parents=True, exist_ok=True)
    test_ids = F.read_split(out, "test") if (splits_dir / "test.lst").exists() else []
    proto = dict(protocol, setting=args.setting,
                 train_categories=sorted({s.split(":")[1] for s in groups["train"]}),
                 test_categories=sorted({s.split(":")[1] for s in groups["test"]}),
                 **protocol_rig(cams))
    lines = [f"{t} {' '.join(map(str, protocol['input_views_1']))} | {' '.join(map(str, protocol['input_views_2']))}"
             for t in test_ids]
    with root_held(out):  # (a shard starting meanwhile sweeps the root's temporaries: only under this hold)
        F.atomic_write_json(splits_dir / "eval_views.json", proto)
        F.atomic_write_text(splits_dir / "test_views.lst", "\n".join(lines) + ("\n" if lines else ""))
    n_planned = len(split_of)
    if not remaining:
        print(f"wrote {Path(out).resolve()} ({args.setting}: {len(lists['train'])} train, {len(lists['val'])} val, "
              f"{len(lists['test'])} test objects; {total_views} views rendered in this shard)")
    else:
        parts = ", ".join(f"{len(lists[s])} of {len(objects[s])} {s}" for s in F.SPLITS if objects[s])
        todo = ("run the other shards: " + " ".join(f"--shard {i}/{shard[1]}" for i in remaining)
                if shard[1] > 1 else "run again to finish them")
        print(f"wrote {Path(out).resolve()} ({args.setting}: {len(finished)} of {n_planned} planned objects finished ({parts}); "
              f"{total_views} views rendered in this shard); {todo}")
        print(f"note: the split lists hold the {len(finished)} finished objects only: train and eval refuse the set "
              "until the shards named have run (or those still running have finished)", file=sys.stderr)
    print(json.dumps({k: proto[k] for k in ("input_views_1", "input_views_2")}))
    return 0
