"""Synthesize novel views from posed reference images with a trained checkpoint.

References are an object folder of our dataset format (a rendered object, a recovered capture, or
scene cameras exported by the add-on); targets are a targets.json (see datasets/novel_views.py).
Writes OUT/rgb/NNNNNN.png (RGBA, alpha = the model's opacity), OUT/depth/NNNNNN.exr with --depth
(planar z-depth) and OUT/synthesis.json; nothing is written when anything fails. With --blend it
also writes a .blend holding the target cameras and their image planes (needs the bpy module).

  python -m blender_mrvm synthesize --references data/chair/obj --views 3,15 --targets targets.json --out novel
"""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--references", type=Path, required=True, help="object folder with rgb/ + pose/ (render or capture)")
    p.add_argument("--views", nargs="+", default=None, help="reference view indices, e.g. 0,1 or 0 1 (default: all, at most 10)")
    p.add_argument("--targets", type=Path, required=True, help="targets.json naming the cameras to synthesize")
    p.add_argument("--checkpoint", type=Path, default=None,
                   help="model file, checkpoint folder or run folder (default: the shipped model)")
    p.add_argument("--device", default="auto", help="auto (CUDA when available), cpu or cuda (default auto)")
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument("--depth", action="store_true", default=None, help="also write depth maps (EXR); "
                   "default: as targets.json says")
    p.add_argument("--chunk", type=int, default=0, help="rays per forward pass (0 = the model's setting)")
    p.add_argument("--ref-size", type=int, default=0, help="resize references to this longer side in pixels "
                   "(0 = the first reference's size)")
    p.add_argument("--bbox", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="object box in world units (default: from the reference folder)")
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0 = default)")
    p.add_argument("--blend", type=Path, default=None, help="also write a .blend with the cameras and image planes")
    p.add_argument("--plane-distance", type=float, default=None,
                   help="image planes' distance from their cameras for --blend (default: through the object's centre)")


def run(args) -> int:
    from ..datasets.novel_views import parse_views
    from ..progress import run_with_tqdm
    from ..training.synthesize import SynthesisConfig, json_line, parse_bbox, synthesize_views

    views = parse_views(" ".join(args.views)) if args.views else ()
    bbox = parse_bbox(args.bbox) if args.bbox is not None else None
    if args.blend is not None:
        _check_blend_path(args.blend)
    cfg = SynthesisConfig(references=args.references, targets=args.targets, out=args.out, views=views,
                          checkpoint=args.checkpoint, device=args.device, depth=args.depth, chunk_rays=args.chunk,
                          ref_size=args.ref_size, bbox=bbox, threads=args.threads)
    summary = run_with_tqdm(synthesize_views(cfg), desc="synthesize", unit="ray")
    if args.blend is not None:
        from ..scene.novel_views import write_blend

        blend = write_blend(args.blend, args.targets, args.out, references=args.references,
                            reference_views=tuple(int(v) for v in summary.references[1]),
                            plane_distance=args.plane_distance, bbox=summary.bbox)
        print(f"wrote {blend}")
    print(json_line(summary))
    return 0


def _check_blend_path(path: Path) -> None:
    from ..errors import InputError

    if path.suffix.lower() != ".blend":
        raise InputError(f"--blend must name a .blend file, got {path}")
    try:
        import bpy  # noqa: F401
    except ImportError:
        raise InputError("--blend needs the bpy module (pip install bpy, or run inside Blender)") from None
