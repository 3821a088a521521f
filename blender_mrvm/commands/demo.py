"""The main job on the shipped defaults (``make demo``): novel views of objects the model never saw.

1. renders held-out objects of the procedural ShapeNet-13 library the way the test split is
   rendered (``make-shapenet``: turntable at 30 degrees elevation, 24 views, 64 px, Cycles), from
   seeds no training set uses (1000 and up);
2. synthesizes every other view of each object from the test protocol's 2 reference views with the
   shipped checkpoint (``python -m blender_mrvm synthesize``'s core);
3. prints PSNR / SSIM / LPIPS-VGG of the synthesized views against the rendered ground truth, with
   the two trivial baselines for scale (nearest reference view, mean colour), into metrics.json too;
4. writes ``demo_out/scene.blend`` (the first object, its reference cameras, a ring of target cameras
   with the synthesized views as image planes in place, view transform "Standard"),
   ``demo_out/scene.png`` (that scene rendered from an overview camera) and
   ``demo_out/contact_sheet.png`` (per view: references, prediction, ground truth).

A copy of the package without the shipped checkpoint (and no --checkpoint) renders the dataset
and its contact sheet only, and says why on stderr: 4 objects, 12 views each at 128 px unless
--objects, --views or --resolution say otherwise.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

DEMO_CATEGORIES = ("chair", "car", "airplane", "lamp", "sofa", "table")
DEMO_SEED = 1000
"""First object seed of the demo: training sets use seeds 0 .. objects-per-category - 1."""
DATASET_ONLY_OBJECTS = ("procedural:chair:0", "procedural:car:2", "procedural:airplane:1", "procedural:lamp:3")
DATASET_ONLY_VIEWS, DATASET_ONLY_RESOLUTION = 12, 128
"""Without a model: what is rendered when --objects, --views and --resolution are not given (the objects first, then
the other categories' held-out objects when --objects asks for more)."""
DEMO_OBJECTS, DEMO_VIEWS, DEMO_RESOLUTION = 4, 24, 64
"""With a model: the defaults of --objects, --views (the test split's 24) and --resolution (the training set's 64)."""
SCENE_TARGETS = 6
"""Target cameras (image planes) in scene.blend: evenly spaced around the first object."""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--checkpoint", type=Path, default=None, help="model checkpoint, or shipped:<kind> (default: the shipped model)")
    p.add_argument("--objects", type=int, default=None, help=f"held-out objects, one per category of "
                   f"{', '.join(DEMO_CATEGORIES)} (default {DEMO_OBJECTS}; without a model {len(DATASET_ONLY_OBJECTS)})")
    p.add_argument("--views", type=int, default=None, help=f"turntable views per object (default {DEMO_VIEWS}, the "
                   f"test split's; without a model {DATASET_ONLY_VIEWS})")
    p.add_argument("--resolution", type=int, default=None, help=f"image size in pixels (default {DEMO_RESOLUTION}, "
                   f"the training set's; without a model {DATASET_ONLY_RESOLUTION})")
    p.add_argument("--scene-resolution", type=int, default=128, help="size of the image planes' views in scene.blend")
    p.add_argument("--ref-size", type=int, default=0, help="references' longer side for the model: 0 (default) shrinks "
                   "references larger than the model's training images to that size, -1 keeps them, N pixels")
    p.add_argument("--device", default="auto", help="auto (CUDA when available), cpu or cuda[:N] (default auto)")
    p.add_argument("--threads", type=int, default=0, help="CPU threads (0 = every core): views render that many ray chunks side by side, one core each")
    p.add_argument("--no-lpips", action="store_true", help="skip LPIPS (otherwise the offline weights are required)")
    p.add_argument("--no-picture", action="store_true", help="do not render demo_out/scene.png")
    p.add_argument("--force", action="store_true", help="re-render objects rendered with other settings and write "
                   "into an --out folder holding files the demo did not write (or changed since)")


DEMO_FILES = ("scene.blend", "scene.png", "contact_sheet.png", "metrics.json")
"""The demo's own files; its folders are ``dataset``, ``novel`` and scene.blend's images folder
(``datasets.novel_views.blend_images_folder``)."""
"""What the demo writes at the top of --out (besides dataset/ and novel/)."""


def demo_folder(out) -> "OwnedFolder":
    from ..guards import OwnedFolder

    from ..datasets.novel_views import blend_images_folder

    return OwnedFolder(Path(out), "mrvm_demo.json", DEMO_FILES,
                       ("dataset", "novel", blend_images_folder(Path(out) / "scene.blend").name))


def fill_defaults(args, with_model: bool = True) -> None:
    """--objects, --views and --resolution not given (None): the demo's defaults, or without a model the
    dataset-only ones (``DATASET_ONLY_*``)."""
    defaults = ((DEMO_OBJECTS, DEMO_VIEWS, DEMO_RESOLUTION) if with_model else
                (len(DATASET_ONLY_OBJECTS), DATASET_ONLY_VIEWS, DATASET_ONLY_RESOLUTION))
    for name, value in zip(("objects", "views", "resolution"), defaults):
        if getattr(args, name, None) is None:
            setattr(args, name, value)


def dataset_only_sources(n: int) -> tuple[str, ...]:
    """The first ``n`` objects the demo renders without a model: ``DATASET_ONLY_OBJECTS``, then the held-out objects
    of the categories they leave out."""
    used = {s.split(":")[1] for s in DATASET_ONLY_OBJECTS}
    more = tuple(f"procedural:{c}:{DEMO_SEED + i}" for i, c in enumerate(DEMO_CATEGORIES) if c not in used)
    return (tuple(DATASET_ONLY_OBJECTS) + more)[:n]


def check_args(args) -> None:
    """Every number, the device and the output folder, before anything is rendered or written."""
    from .. import validation as V
    from ..errors import InputError

    fill_defaults(args)  # (run fills them first, knowing whether there is a model)

    V.check_count("--views", args.views, 3, 360)
    V.check_image_side("--resolution", args.resolution, 8, 1024)
    V.check_image_side("--scene-resolution", args.scene_resolution, 8, 4096)
    V.check_ref_size("--ref-size", args.ref_size)
    V.check_count("--threads", args.threads, 0, 4096)
    V.check_device_name("--device", args.device)
    if args.device.strip().lower().startswith("cuda"):  # found before the dataset renders, not after
        from ..synthesis.views import resolve_device

        resolve_device(args.device)
    if not 1 <= args.objects <= len(DEMO_CATEGORIES):
        raise InputError(f"--objects must be between 1 and {len(DEMO_CATEGORIES)}, got {args.objects}")
    if args.checkpoint is not None:
        from ..models.pretrained import resolve_checkpoint

        args.checkpoint = resolve_checkpoint(args.checkpoint)  # a path, or shipped / shipped:<kind>
    demo_folder(args.out).check(args.force)


def check_reference_size(args, ck: Path) -> None:
    """InputError, before anything is rendered, when synthesis would refuse the references the demo renders: with
    --ref-size 0 references smaller than the images the model was trained on are refused, not upsampled
    (``synthesis.views.synthesize_views``; ``reference_sizes`` says how large that is)."""
    from ..errors import InputError
    from ..synthesis.views import reference_sizes

    _, trained = reference_sizes(args.ref_size, ck)
    if args.ref_size == 0 and trained and args.resolution < trained:
        raise InputError(f"--resolution {args.resolution} renders references smaller than the {trained} px this "
                         f"model was trained on; use --resolution {trained} or more, or pass --ref-size {trained} to "
                         "upsample them (--ref-size -1 uses them as they are)")


def run(args) -> int:
    import sys

    from ..errors import InputError

    missing = None
    if args.checkpoint is None:
        from ..models.pretrained import default_checkpoint

        try:
            args.checkpoint = default_checkpoint()
        except InputError as e:
            missing = e
    fill_defaults(args, with_model=missing is None)  # without a model: the dataset-only defaults, unless given
    check_args(args)
    if missing is not None:  # notes on stderr, as every command's: stdout holds what was done
        print(f"note: {missing}", file=sys.stderr)
        print("note: without a model the demo renders the dataset and its contact sheet only", file=sys.stderr)
        return dataset_only(args)
    return novel_views_demo(args)


# ---------------------------------------------------------------------------------------------
# Without a model: the dataset only
# ---------------------------------------------------------------------------------------------

def dataset_only(args) -> int:
    from ..datasets.contact_sheet import dataset_contact_sheet
    from ..progress import run_with_tqdm
    from ..scene.render import RenderConfig, render_dataset

    out = Path(args.out)
    owned = demo_folder(out)
    owned.claim()
    cfg = RenderConfig(out=out / "dataset", sources=dataset_only_sources(args.objects), views=args.views,
                       resolution=(args.resolution, args.resolution), force=args.force)
    summary = run_with_tqdm(render_dataset(cfg), desc="render", unit="view")
    sheet = dataset_contact_sheet(out / "dataset", out / "contact_sheet.png")
    owned.wrote("contact_sheet.png")
    print(f"rendered {summary.views_rendered} views ({summary.views_skipped} already done) of "
          f"{len(summary.objects)} objects in {summary.seconds:.1f} s -> {cfg.out}")
    print(f"contact sheet: {sheet}")
    return 0


# ---------------------------------------------------------------------------------------------
# With a model
# ---------------------------------------------------------------------------------------------

def novel_views_demo(args) -> int:
    import numpy as np

    from ..datasets import format as F
    from ..datasets.loaders import to_float_rgb
    from ..datasets.novel_views import write_targets
    from ..progress import run_with_tqdm
    from ..scene.render import RenderConfig, render_dataset
    from ..synthesis import SynthesisConfig, load_checkpoint, synthesize_views, targets_from_views
    from ..training.evaluate import alpha_scores, scores_against, summarize
    from .make_shapenet import eval_views

    t_start = time.perf_counter()
    from ..threads import set_torch_threads

    set_torch_threads(args.threads)
    out = Path(args.out)
    protocol = eval_views(args.views)
    refs, target_views = protocol["input_views_2"], protocol["target_views_2"]
    cats = DEMO_CATEGORIES[:args.objects]
    sources = tuple(f"procedural:{c}:{DEMO_SEED + i}" for i, c in enumerate(cats))
    _, mcfg, meta, ck = load_checkpoint(args.checkpoint)  # fail early, before rendering, on a bad checkpoint
    check_reference_size(args, ck)
    owned = demo_folder(out)
    owned.claim()
    lpips = None
    if not args.no_lpips:
        from ..models.metrics import LPIPS

        lpips = LPIPS()

    # 1. Ground truth: held-out objects rendered like the test split.
    t = time.perf_counter()
    cfg = RenderConfig(out=out / "dataset", sources=sources, rig="turntable", views=args.views,
                       resolution=(args.resolution, args.resolution), engine="CYCLES", samples=8,
                       fov_deg=40.0, elevation_deg=30.0, split="test", force=args.force)
    rs = run_with_tqdm(render_dataset(cfg), desc="render", unit="view")
    t_render = time.perf_counter() - t
    obj_dirs = [out / "dataset" / c / f"{c}_{DEMO_SEED + i:06d}" for i, c in enumerate(cats)]

    # 2. + 3. Synthesis and scores.
    t = time.perf_counter()
    records, rows = [], []
    for obj in obj_dirs:
        cat = obj.parent.name
        job = out / "novel" / cat
        targets = targets_from_views(obj, target_views)
        write_targets(job / "targets.json", targets)
        syn = SynthesisConfig(references=obj, targets=job / "targets.json", out=job / "out", views=tuple(refs),
                              checkpoint=ck, device=args.device, depth=False, ref_size=args.ref_size,
                              threads=args.threads, force=True)  # novel/ is the demo's own working folder
        run_with_tqdm(synthesize_views(syn), desc=f"synthesize {cat}", unit="ray")
        ov = F.read_object(obj)
        pos = {v: k for k, v in enumerate(ov.indices)}
        ref_imgs = [to_float_rgb(ov.rgb(pos[v])) for v in refs]
        mean = np.mean([im.reshape(-1, 3).mean(0) for im in ref_imgs], axis=0)
        for i, (tg, v) in enumerate(zip(targets, target_views)):
            pred = to_float_rgb(F.read_png(job / "out" / tg.rgb_path(i)))  # the written RGBA over white
            gt = to_float_rgb(ov.rgb(pos[v]))
            near = ref_imgs[_nearest(ov, [pos[r] for r in refs], pos[v])]
            alpha = F.read_png(job / "out" / tg.rgb_path(i))[..., 3].astype(np.float64) / 255.0
            sc = scores_against(gt, {"model": pred, "baseline_nearest": near,
                                     "baseline_mean": np.broadcast_to(mean, gt.shape).astype(np.float32)}, lpips)
            rec = {"category": cat, "object": obj.name, "view": v, **sc["model"],
                   "alpha": alpha_scores(alpha, np.asarray(ov.mask(pos[v])) > 0),
                   "baseline_nearest": sc["baseline_nearest"], "baseline_mean": sc["baseline_mean"]}
            records.append(rec)
            rows.append((cat, v, ref_imgs, pred, gt, rec["psnr"]))
    t_synth = time.perf_counter() - t
    report = summarize(records)
    report.update({"checkpoint": str(ck), "checkpoint_step": meta.get("step"), "model": mcfg.name,
                   "objects": list(sources), "protocol": {"views": args.views, "input_views": refs,
                                                          "target_views": target_views},
                   "resolution": args.resolution, "ref_size": args.ref_size, "seconds": {"render": t_render, "synthesis_and_scores": t_synth}})
    _print_table(report, lpips is not None)

    # 4. Contact sheet, scene.blend, picture.
    sheet = contact_sheet(rows, out / "contact_sheet.png", per_object=3)
    owned.wrote("contact_sheet.png")
    t = time.perf_counter()
    blend, picture = build_scene(args, obj_dirs[0], sources[0], refs, ck, out, render_picture=not args.no_picture)
    owned.wrote("scene.blend")
    if picture:
        owned.wrote("scene.png")
    report["seconds"]["scene"] = time.perf_counter() - t
    report["seconds"]["total"] = time.perf_counter() - t_start
    F.atomic_write_json(out / "metrics.json", {**report, "views": records})
    owned.wrote("metrics.json")
    print(f"contact sheet: {sheet}")
    print(f"scene: {blend}" + (f" (rendered: {picture})" if picture else ""))
    print(f"metrics: {out / 'metrics.json'}  ({rs.views_rendered} views rendered, "
          f"{report['seconds']['total']:.0f} s in all)")
    return 0


def _nearest(ov, refs: list[int], tgt: int) -> int:
    """Index into ``refs`` of the reference whose camera direction is closest to the target's."""
    import numpy as np

    c = lambda k: ov.c2w_opencv[k][:3, 3] / np.linalg.norm(ov.c2w_opencv[k][:3, 3])  # noqa: E731
    return max(range(len(refs)), key=lambda j: float(c(refs[j]) @ c(tgt)))


def _print_table(report: dict, with_lpips: bool) -> None:
    def f(v, fmt):
        return format(v, fmt) if v is not None else "-"

    head = f"{'':12s} {'PSNR':>7s} {'SSIM':>6s} {'LPIPS':>6s}   {'nearest ref':>11s} {'mean colour':>11s}  (PSNR)"
    print(head)
    items = list(report["per_category"].items()) + [("overall", report["overall"])]
    for name, b in items:
        print(f"{name:12s} {f(b['psnr'], '7.2f')} {f(b['ssim'], '6.3f')} {f(b['lpips'], '6.3f') if with_lpips else '     -'}"
              f"   {f(b['baseline_nearest']['psnr'], '11.2f')} {f(b['baseline_mean']['psnr'], '11.2f')}")
    o = report["overall"]
    print(f"{o['n']} synthesized views from 2 references each; PSNR {o['psnr_gain_over_best_baseline']:+.2f} dB "
          f"over the better trivial baseline")
    a = o.get("alpha")
    if a:
        print(f"alpha (opacity) vs object masks: {f(a['background'], '.3f')} mean on background, {f(a['object'], '.3f')} "
              f"on the object, IoU {f(a['iou'], '.3f')}")  # (None: no view has such pixels)


# ---------------------------------------------------------------------------------------------
# Contact sheet
# ---------------------------------------------------------------------------------------------

def contact_sheet(rows, path: Path, per_object: int = 4, tile: int = 128) -> Path:
    """One line per view: reference 1, reference 2, prediction, ground truth (labelled)."""
    import numpy as np
    from PIL import Image, ImageDraw

    from ..datasets import format as F

    picked, by_cat = [], {}
    for r in rows:
        by_cat.setdefault(r[0], []).append(r)
    for cat, rs in by_cat.items():
        idx = sorted({round(k * (len(rs) - 1) / max(per_object - 1, 1)) for k in range(min(per_object, len(rs)))})
        picked += [rs[i] for i in idx]
    n_ref = len(picked[0][2])
    cols = n_ref + 2
    pad, head, label_w = 4, 18, 112
    W = label_w + cols * (tile + pad) + pad
    H = head + len(picked) * (tile + pad) + pad
    sheet = Image.new("RGB", (W, H), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    titles = [f"reference {k + 1}" for k in range(n_ref)] + ["prediction", "ground truth"]
    for j, ttl in enumerate(titles):
        draw.text((label_w + pad + j * (tile + pad) + 4, 3), ttl, fill=(0, 0, 0))
    for i, (cat, v, refs, pred, gt, p) in enumerate(picked):
        y = head + pad + i * (tile + pad)
        draw.text((6, y + tile // 2 - 12), f"{cat}, view {v}", fill=(0, 0, 0))
        draw.text((6, y + tile // 2 + 2), f"PSNR {p:.2f} dB", fill=(80, 80, 80))
        for j, im in enumerate([*refs, pred, gt]):
            tile_img = Image.fromarray(F.to_uint8(np.asarray(im)[..., :3])).resize((tile, tile), Image.NEAREST)
            sheet.paste(tile_img, (label_w + pad + j * (tile + pad), y))
    F.write_png(Path(path), np.asarray(sheet))
    return Path(path)


# ---------------------------------------------------------------------------------------------
# scene.blend and its picture
# ---------------------------------------------------------------------------------------------

def build_scene(args, obj_dir: Path, source: str, refs: list[int], ck: Path, out: Path,
                render_picture: bool = True) -> tuple[Path, Path | None]:
    """scene.blend: the object, its reference cameras, SCENE_TARGETS target cameras with their synthesized
    views (at --scene-resolution) as image planes, an overview camera; optionally rendered to scene.png."""
    import numpy as np

    from ..datasets import format as F
    from ..datasets.novel_views import write_targets
    from ..progress import run_with_tqdm
    from ..scene.novel_views import write_blend
    from ..synthesis import SynthesisConfig, synthesize_views, targets_from_views

    ov = F.read_object(obj_dir)
    n = len(ov.indices)
    # Evenly spaced around the turntable: the nearest free view that is not a reference.
    picks: list[int] = []
    for k in range(min(SCENE_TARGETS, n - len(refs))):
        want = (k + 0.5) * n / SCENE_TARGETS
        free = [v for v in range(n) if v not in refs and v not in picks]
        picks.append(min(free, key=lambda v: min(abs(v - want), n - abs(v - want))))
    scale = args.scene_resolution / args.resolution
    targets = [type(t)(f"MRVM view {v:02d}", t.intrinsics.scaled(scale), t.c2w_opencv)
               for t, v in zip(targets_from_views(obj_dir, picks), picks)]
    job = out / "novel" / "scene"
    write_targets(job / "targets.json", targets)
    run_with_tqdm(synthesize_views(SynthesisConfig(obj_dir, job / "targets.json", job / "out", tuple(refs), ck,
                                                   args.device, depth=False, ref_size=args.ref_size,
                                                   threads=args.threads, force=True)),
                  desc="synthesize scene", unit="ray")
    meta = ov.meta
    bbox = (np.asarray(meta["bbox"][0]), np.asarray(meta["bbox"][1]))
    centre = 0.5 * (bbox[0] + bbox[1])
    cam_dist = float(np.median([np.linalg.norm(p[:3, 3] - centre) for p in ov.c2w_opencv]))

    def populate(scene):
        _populate(scene, source, np.asarray(meta["normalization"]["matrix"]), centre, cam_dist)

    blend = write_blend(out / "scene.blend", job / "targets.json", job / "out", references=obj_dir,
                        reference_views=tuple(refs), bbox=bbox, populate=populate)
    picture = render_scene_picture(out / "scene.png") if render_picture else None
    return blend, picture


def _populate(scene, source: str, norm, centre, cam_dist: float) -> None:
    """The demo object (normalised as in the dataset), a sun, a grey world and the overview camera."""
    import bpy
    import numpy as np

    from ..geometry import cameras as C
    from ..scene import camera as scam
    from ..scene import compat
    from ..scene import objects as O

    coll = bpy.data.collections.new("MRVM demo object")
    scene.collection.children.link(coll)
    (spec,) = O.resolve_sources((source,))
    objs = O.load_into(spec, coll)
    O.apply_world_transform(objs, norm, bpy.context.view_layer)
    sun = bpy.data.lights.new("MRVM sun", "SUN")
    sun.energy = 3.0
    sun.angle = math.radians(10)
    sun_ob = bpy.data.objects.new("MRVM sun", sun)
    sun_ob.rotation_euler = (math.radians(40), math.radians(10), math.radians(30))
    coll.objects.link(sun_ob)
    world = bpy.data.worlds.new("MRVM demo world")
    bg = next(n for n in compat.node_tree(world).nodes if n.type == "BACKGROUND")
    bg.inputs["Color"].default_value = (0.30, 0.32, 0.36, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world
    # Overview camera: higher and farther than the ring, looking at the object.
    el, az = math.radians(52.0), math.radians(-60.0)  # above the ring: the near planes do not hide the object
    d = 2.2 * cam_dist
    eye = centre + d * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    _plane_frames(scene, coll)
    cam = scam.new_camera("MRVM overview", coll)
    cam.data.lens = 44.0
    cam.data.clip_start, cam.data.clip_end = 0.01, 100.0
    scam.apply_pose(cam, C.look_at_opencv(eye, centre))
    scene.camera = cam


def _plane_frames(scene, coll) -> None:
    """A thin dark frame along each image plane's border, so the planes read as pictures in the render."""
    import bpy

    from ..scene import compat
    from ..scene import image_planes as IP

    mat = bpy.data.materials.new("MRVM plane frame")
    mat.diffuse_color = (0.05, 0.05, 0.05, 1.0)
    bsdf = next(n for n in compat.node_tree(mat).nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Base Color"].default_value = (0.05, 0.05, 0.05, 1.0)
    for plane in [o for o in scene.objects if o.get(IP.PLANE_TAG)]:
        corners = [tuple(v.co) for v in list(plane.data.vertices)[:4]]
        size = max((plane.data.vertices[0].co - plane.data.vertices[2].co).length, 1e-6)
        cu = bpy.data.curves.new(f"MRVM frame {plane.parent.name}", "CURVE")
        cu.dimensions = "3D"
        cu.bevel_depth = 0.006 * size
        sp = cu.splines.new("POLY")
        sp.points.add(3)
        for pt, c in zip(sp.points, corners):
            pt.co = (*c, 1.0)
        sp.use_cyclic_u = True
        cu.materials.append(mat)
        ob = bpy.data.objects.new(cu.name, cu)
        coll.objects.link(ob)
        ob.parent = plane
        ob.matrix_parent_inverse.identity()


def render_scene_picture(path: Path, width: int = 640, height: int = 420, samples: int = 24) -> Path:
    """Render the open scene from its camera to ``path`` (Cycles, CPU); the .blend is not changed."""
    import bpy

    from ..scene import compat
    from ..scene.objects import quiet_stdout

    sc = bpy.context.scene
    r = sc.render
    saved = (r.resolution_x, r.resolution_y, r.engine, r.filepath)
    fmt = r.image_settings
    saved_format = (getattr(fmt, "media_type", None), fmt.file_format, fmt.color_mode)
    try:
        r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
        r.engine = "CYCLES"
        sc.cycles.device = "CPU"
        sc.cycles.samples = samples
        sc.cycles.use_denoising = False
        compat.set_file_format(fmt, "PNG")
        fmt.color_mode = "RGB"
        r.filepath = str(Path(path).resolve())
        with quiet_stdout():
            bpy.ops.render.render(write_still=True)
    finally:
        r.resolution_x, r.resolution_y, r.engine, r.filepath = saved
        if saved_format[0] is not None:
            fmt.media_type = saved_format[0]
        fmt.file_format, fmt.color_mode = saved_format[1:]
    return Path(path)

