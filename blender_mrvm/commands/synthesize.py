"""Synthesize novel views from posed reference images with a trained checkpoint.

References are an object folder of our dataset format (a rendered object, a recovered capture, or
scene cameras exported by the add-on). Targets are a targets.json (see datasets/novel_views.py), the
cameras of views of the reference folder (--target-views, to compare with their images), or an
orbit around the object (--orbit N). Writes OUT/rgb/NNNNNN.png (RGBA, alpha = the model's opacity, raised where its colour needs more),
OUT/depth/NNNNNN.exr with --depth (planar z-depth), OUT/targets.json and OUT/synthesis.json;
nothing is written when anything fails. With --blend it also writes a .blend holding the target
cameras and their image planes (needs the bpy module).

  python -m blender_mrvm synthesize --references data/chair/obj --views 3,15 --orbit 8 --out novel --blend novel/scene.blend
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from ..errors import InputError
from ..models.precision import SYNTH_PRECISIONS


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--references", type=Path, required=True, help="object folder with rgb/ + pose/ (render or capture)")
    p.add_argument("--views", nargs="+", default=None, help="reference view indices, e.g. 0,1 or 0 1, or all "
                   "(default: all, at most 500; with more than --nearest allows, each target uses its nearest, see --nearest)")
    p.add_argument("--nearest", type=int, default=0, metavar="K",
                   help="render each view from its K nearest references (by direction and distance; fewer is faster, "
                   "docs/guide/novel_views.md, 'Many references'); 0 (default) = every reference when there are "
                   "at most 5, else the 5 nearest")
    p.add_argument("--reproject", choices=("auto", "on", "off"), default="auto",
                   help="lay the references' own colours over each view where they see its surface, through the model's "
                   "depth (each reference used is rendered once more): auto (default) = on when each view is rendered "
                   "from its nearest of more references (a dense capture) by a model that predicts its colours at "
                   "--quality full; off otherwise, for GPNR (its colours already are the references') and at preview")
    tg = p.add_mutually_exclusive_group(required=True)
    tg.add_argument("--targets", type=Path, help="targets.json naming the cameras to synthesize")
    tg.add_argument("--target-views", nargs="+", help="synthesize these views of the reference folder, e.g. 0,5,9, to "
                    "compare with their images (with no --views, every other view is a reference)")
    tg.add_argument("--orbit", type=int, metavar="N", help="synthesize N views on a circle around the object")
    p.add_argument("--orbit-elevation", type=float, default=None,
                   help="with --orbit: its elevation in degrees (default 20)")
    p.add_argument("--orbit-radius", type=float, default=None,
                   help="with --orbit: its radius (default: the references' distance)")
    p.add_argument("--orbit-size", type=int, default=0,
                   help="with --orbit: its images' longer side in pixels (default: the references')")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="model file, checkpoint folder or run folder of any model kind, or shipped:<kind> such as shipped:gpnr, shipped:gpnr_captures for rooms and photo captures, shipped:mrvm_anyview for cameras off the turntable, or shipped:mrvm_quality (GPU-trained, best for cameras anywhere, slow on a CPU) (default: shipped:auto, the shipped NeRFormer+MRVM model that fits the cameras: the default model on its 30-degree training turntable, else the any-view model on a CPU and the quality model on a GPU; synthesis.json's model_choice says which)")
    p.add_argument("--device", default="auto", help="auto (CUDA when available), cpu or cuda[:N] (default auto)")
    p.add_argument("--compile", action="store_true",
                   help="torch.compile the model's networks first (on an H100 1.2x faster through synthesize than "
                        "eager after a first view of ~30 s; on a CPU about a tenth faster after minutes of compiling; "
                        "docs/guide/speed.md)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--depth", action="store_true", default=None, help="also write depth maps (EXR); "
                   "default: as targets.json says")
    p.add_argument("--chunk", type=int, default=0, help="rays per forward pass (0 = the model's setting; at least 16384 on a GPU)")
    p.add_argument("--ref-size", type=int, default=0, help="resize references to this longer side in pixels; "
                   "0 (default) shrinks references larger than the model's training images to that size; "
                   "-1 keeps the first reference's size")
    p.add_argument("--bbox", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="object box in world units (default: from the reference folder)")
    p.add_argument("--threads", type=int, default=0, help="CPU threads (0 = every core): views render that many ray chunks side by side, one core each")
    p.add_argument("--quality", choices=("full", "preview"), default="full",
                   help="full (default: as the model was trained) or preview (half the samples per ray: about half "
                   "the time for -0.19 dB with the default model, docs/guide/speed.md)")
    p.add_argument("--precision", choices=SYNTH_PRECISIONS, default="auto",
                   help="auto (default: bf16 on a GPU, where every shipped model scores the same and renders "
                   "1.04-1.21x faster; on the CPU int8 for NeRFormer models with wide enough layers, the quality model "
                   "1.3x faster at the same scores, else fp32), fp32, bf16, fp16 (a GPU only) or int8 (linear layers; "
                   "the CPU only); synthesis.json records the one used (models/precision.py)")
    p.add_argument("--skip-empty", choices=("cull", "tighten", "off"), default="cull",
                   help="empty-space skipping inside the object's box when the references have masks: cull "
                   "(default; rays missing the references' visual hull are background, same images to < 1/255; under "
                   "int8, whose activations are scaled per ray chunk, to int8's own rounding, a few 1/255), "
                   "tighten (also shorten rays to the hull; loses PSNR with models trained on box-length rays), off")
    from ..training.adapt import add_arguments as add_adapt_arguments

    add_adapt_arguments(p)
    p.add_argument("--blend", type=Path, default=None, help="also write a .blend with the cameras and image planes "
                   "(the targets must share one frame shape; reference cameras of another are left out, with a note)")
    p.add_argument("--force", action="store_true", help="write into an output folder that holds files and replace "
                   "an existing --blend file (never the reference folder)")
    p.add_argument("--plane-distance", type=float, default=None,
                   help="image planes' distance from their cameras for --blend (default: half the depth of the object's "
                        "box centre, median over the targets: the planes float between camera and object)")


def run(args) -> int:
    from ..datasets.novel_views import parse_views
    from ..progress import run_with_tqdm
    from ..synthesis import SynthesisConfig, json_line, parse_bbox, synthesize_views
    from ..training.adapt import from_args as adapt_from_args

    from dataclasses import replace

    from .. import validation as V
    from ..guards import check_folder_writable, check_name_length, check_new_file
    from ..synthesis.views import _check_out

    views = parse_views(" ".join(args.views)) if args.views else ()
    views_note = None
    if args.target_views:
        views, views_note = _references_beside_targets(args.references, views, _target_view_ids(args))
    bbox = parse_bbox(args.bbox) if args.bbox is not None else None
    # Every argument is checked (the config validates itself) before anything is read or written.
    cfg = SynthesisConfig(references=args.references, targets=args.targets or args.out / "targets.json",
                          out=args.out, views=views, checkpoint=args.checkpoint, device=args.device, depth=args.depth,
                          chunk_rays=args.chunk, ref_size=args.ref_size, bbox=bbox, threads=args.threads,
                          quality=args.quality, precision=args.precision, skip_empty=args.skip_empty, force=args.force,
                          nearest=args.nearest, adapt=adapt_from_args(args), reproject=args.reproject,
                          compile=args.compile)
    orbit_only = [f for f, v in (("--orbit-elevation", args.orbit_elevation), ("--orbit-radius", args.orbit_radius),
                                 ("--orbit-size", args.orbit_size or None)) if v is not None]
    if orbit_only and args.orbit is None:  # they were taken and ignored
        raise InputError(f"{', '.join(orbit_only)}: only for --orbit N (the orbit's cameras); without it "
                         "nothing would use it")
    if args.orbit_elevation is None:
        args.orbit_elevation = 20.0
    if args.orbit_size:
        V.check_image_side("--orbit-size", args.orbit_size)
    if args.orbit is not None:
        V.check_count("--orbit", args.orbit, 1, 10000)
        if args.orbit_radius is not None and not (math.isfinite(args.orbit_radius) and args.orbit_radius > 0):
            raise InputError(f"--orbit-radius must be a positive distance, got {args.orbit_radius}")
        if not (math.isfinite(args.orbit_elevation) and -90 < args.orbit_elevation < 90):
            raise InputError(f"--orbit-elevation must be between -90 and 90 degrees, got {args.orbit_elevation}")
    if args.plane_distance is not None and not (math.isfinite(args.plane_distance) and args.plane_distance > 0):
        raise InputError(f"--plane-distance must be a positive distance, got {args.plane_distance}")
    check_name_length(args.out, "--out")
    _check_out(args.out, cfg)
    if args.blend is not None:
        _check_blend_path(args.blend)
        from ..datasets.novel_views import blend_images_folder

        # before any view is synthesized: the .blend and its images' folder (<stem>_novel_views) are named last
        check_name_length(args.blend, "--blend")
        check_name_length(blend_images_folder(args.blend), "--blend (its images' folder)")
        check_new_file(args.blend, args.force, ".blend file")
        check_folder_writable(args.blend.resolve().parent, "folder of the .blend file")
    if views_note:  # (once every argument is checked: a bad one is one error line)
        print(f"note: {views_note}", file=sys.stderr)
    import tempfile

    with tempfile.TemporaryDirectory(prefix="mrvm_targets_") as tmp:
        targets = args.targets if args.targets is not None else _make_targets(args, views, bbox, Path(tmp))
        cfg = replace(cfg, targets=targets)
        blend = _blend_writer(args, targets) if args.blend is not None else None
        summary = run_with_tqdm(synthesize_views(cfg, blend), desc="synthesize", unit="ray")
    if args.blend is not None:
        print(f"wrote {args.blend.resolve()}")
    print(json_line(summary))
    return 0


def _blend_writer(args, targets: Path):
    """Check, before anything is synthesized, that the targets make one .blend
    (``scene.novel_views.blend_frame``); return the step that writes it from the finished views, which
    ``synthesize_views`` runs before they move into --out (an error there leaves nothing written)."""
    from ..datasets.novel_views import read_targets
    from ..scene.novel_views import blend_frame, write_blend

    blend_frame(read_targets(targets)[0])

    def write(folder: Path, summary) -> None:
        # the run's own targets.json (whether depth maps were written: --depth over the targets file's word)
        ran = folder / "targets.json" if (folder / "targets.json").is_file() else targets
        write_blend(args.blend, ran, folder, references=args.references,
                    reference_views=tuple(int(v) for v in summary.references[1]),
                    plane_distance=args.plane_distance, bbox=summary.bbox)
    return write


def _target_view_ids(args) -> list[int]:
    from ..errors import InputError

    try:
        return [int(v) for v in " ".join(args.target_views).replace(",", " ").split()]
    except ValueError:
        raise InputError(f"--target-views must be view numbers like 0,5,9, got {' '.join(args.target_views)!r}") from None


def _references_beside_targets(folder: Path, views: tuple[int, ...],
                               targets: list[int]) -> tuple[tuple[int, ...], str | None]:
    """The reference views for ``--target-views``, which are rendered to be compared with their images, and a note
    for the user: with no ``--views`` (every view), every view but the targets (a target among its own references
    is largely a copy of the image it is compared with: 24.5 dB against 19.3 held out, on a 64 px chair); views
    given are kept as given, the note naming any that is also a target."""
    from ..datasets import format as F

    both = sorted(set(views) & set(targets))
    if views:
        return views, (f"view(s) {', '.join(map(str, both))} are references and targets: those views see their own "
                       "images, so they are not novel views (leave them out of --views to compare)") if both else None
    try:
        every = F.read_object(Path(folder)).indices
    except (InputError, OSError, ValueError, KeyError):
        return views, None  # the reference folder's own checks say what is wrong with it
    held = sorted(set(every) & set(targets))
    rest = tuple(v for v in every if v not in set(targets))
    if not rest:
        raise InputError(f"--target-views names every view of {folder}: none is left to be a reference; "
                         "give the references with --views")
    return rest, (f"view(s) {', '.join(map(str, held))} held out of the references: they are the targets, "
                  "rendered to compare with their images") if held else None


ORBIT_POSE_SIZE = 16
"""The size (longer side, pixels) the references are read at to place an orbit: only their poses and the box count."""


def _make_targets(args, views, bbox, tmp: Path) -> Path:
    """targets.json for --target-views or --orbit, written into ``tmp``."""
    from ..datasets.novel_views import write_targets
    from ..errors import InputError
    from ..synthesis import orbit_targets, targets_from_views

    if args.target_views:
        targets = targets_from_views(args.references, _target_view_ids(args))
    else:
        if args.orbit < 1:
            raise InputError(f"--orbit needs at least one view, got {args.orbit}")
        # the orbit's size: the references' own (or --ref-size), not the model's auto size. Only the first view
        # is kept at that size (its camera is the orbit's); the others give their poses and are held small: all
        # of them at their own size took 9.6 GB for 50 photos of 4000x4000 before a view was rendered. Each image
        # is read once (the first had been read twice: at its size and at the pose size).
        from ..synthesis.views import check_reference_folder, orbit_references

        chosen = check_reference_folder(args.references, views)[1]
        refs = orbit_references(args.references, chosen, args.ref_size, bbox, ORBIT_POSE_SIZE)
        targets = orbit_targets(refs, args.orbit, args.orbit_elevation, args.orbit_radius, args.orbit_size)
    return write_targets(tmp / "targets.json", targets)


def _check_blend_path(path: Path) -> None:
    from ..errors import InputError

    if path.suffix.lower() != ".blend":
        raise InputError(f"--blend must name a .blend file, got {path}")
    try:
        import bpy  # noqa: F401
    except ImportError:
        raise InputError("--blend needs the bpy module (pip install bpy, or run inside Blender)") from None
