"""Recover camera poses of a folder of photos (pycolmap SfM) and write a capture folder in our
dataset format: undistorted images in rgb/, SRN poses, intrinsics.txt, transforms.json (each frame
names its photo in original_name), meta.json and the sparse points as points.ply.

At least 3 photos of one size are needed; a stereo pair runs with --pair. The output folder must be
empty unless --force is given (then only the capture's own files are replaced); a folder holding only
an unfinished run (failed or killed: no meta.json yet) is resumed without --force: feature extraction
and matching that finished with the same photos and settings are not redone (colmap/stages.json).
"""

from __future__ import annotations

import argparse
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    from ..capture.config import CAMERA_MODELS, MATCHERS, CaptureConfig

    d = CaptureConfig()
    p.add_argument("--images", required=True,
                   help="folder of photos or video frames (PNG/JPEG/TIFF/BMP; HEIC/HEIF, an iPhone's default, and "
                        "WebP through JPEG copies; one size), or a video file (mp4, mov, ...: --frames of it, the "
                        "sharpest of each span, with one shared camera)")
    p.add_argument("--frames", type=int, default=d.video_frames,
                   help=f"a video's frames to recover: the sharpest of each of this many equal spans of it, a "
                        f"paused camera's frames counted once (default {d.video_frames})")
    p.add_argument("--out", required=True, help="capture folder to write")
    p.add_argument("--camera-model", choices=CAMERA_MODELS, default=d.camera_model,
                   help=f"COLMAP camera model; distorted models are undistorted on export (default {d.camera_model})")
    p.add_argument("--single-camera", action="store_true",
                   help="all photos share one camera (slower matching; default: intrinsics per photo)")
    p.add_argument("--no-focal-from-views", action="store_true",
                   help="a shared camera starts from COLMAP's 1.2 x width focal guess, not the view graph's estimate")
    p.add_argument("--matcher", choices=MATCHERS, default=d.matcher,
                   help=f"auto: sequential for more than {d.exhaustive_max_images} numbered frames, else exhaustive")
    p.add_argument("--max-features", type=int, default=d.max_num_features, help="SIFT features per image")
    p.add_argument("--max-image-size", type=int, default=d.max_image_size,
                   help="longer side used for feature extraction (-1 = full size)")
    p.add_argument("--upsample-below", type=int, default=d.upsample_below,
                   help="SIFT upsamples photos 2x only when their longer side is below this many pixels "
                        f"(default {d.upsample_below}; 0 = never; 100000 = always, as COLMAP does)")
    p.add_argument("--overlap", type=int, default=d.sequential_overlap, help="sequential matching: successors per frame")
    p.add_argument("--min-registered", type=float, default=d.min_registered_fraction,
                   help="fail when fewer than this fraction of photos register")
    p.add_argument("--pair", action="store_true", help="accept a stereo pair (2 photos)")
    p.add_argument("--no-normalize", action="store_true", help="keep COLMAP's world (no up / unit-sphere fit)")
    p.add_argument("--threads", type=int, default=d.num_threads, help="CPU threads (0 or -1 = all; default all)")
    p.add_argument("--seed", type=int, default=d.seed, help="seed of COLMAP's random sampling (RANSAC, the mapper)")
    p.add_argument("--force", action="store_true", help="overwrite an output folder that holds files")
    p.add_argument("--verbose", action="store_true", help="show COLMAP's log (without it COLMAP prints nothing, its errors included: "
                   "the command's own error line says what failed)")


FLAGS = {"num_threads": "--threads", "max_num_features": "--max-features", "max_image_size": "--max-image-size",
         "upsample_below": "--upsample-below", "sequential_overlap": "--overlap",
         "min_registered_fraction": "--min-registered", "video_frames": "--frames", "seed": "--seed"}
"""The options of the config's fields, so a message names what the user typed (it said capture.num_threads)."""


def config_from_args(args: argparse.Namespace):
    import re

    from ..capture.config import CaptureConfig
    from ..errors import InputError

    try:
        return CaptureConfig(camera_model=args.camera_model, single_camera=args.single_camera,
                             estimate_focal=not args.no_focal_from_views, matcher=args.matcher,
                             max_num_features=args.max_features, max_image_size=args.max_image_size,
                             upsample_below=args.upsample_below, sequential_overlap=args.overlap,
                             min_registered_fraction=args.min_registered, allow_pair=args.pair,
                             normalize=not args.no_normalize, num_threads=-1 if args.threads == 0 else args.threads,
                             seed=args.seed, video_frames=args.frames, force=args.force).validate()
    except InputError as e:
        text = re.sub(r"\b(?:capture\.)?(" + "|".join(FLAGS) + r")\b", lambda m: FLAGS[m.group(1)], str(e))
        raise InputError(text) from None


def cli_args(images, out, cfg) -> list[str]:
    """The arguments of this command that run ``cfg`` on ``images`` into ``out`` (what the panel's Recover Poses
    hands the worker; :func:`config_from_args` reads them back to ``cfg``)."""
    a = ["--images", str(images), "--out", str(out), "--camera-model", cfg.camera_model, "--matcher", cfg.matcher,
         "--max-features", str(cfg.max_num_features), "--max-image-size", str(cfg.max_image_size),
         "--upsample-below", str(cfg.upsample_below), "--overlap", str(cfg.sequential_overlap),
         "--min-registered", repr(cfg.min_registered_fraction), "--threads", str(cfg.num_threads),
         "--seed", str(cfg.seed), "--frames", str(cfg.video_frames)]
    flags = {"--single-camera": cfg.single_camera, "--no-focal-from-views": not cfg.estimate_focal,
             "--pair": cfg.allow_pair, "--no-normalize": not cfg.normalize, "--force": cfg.force}
    return a + [f for f, on in flags.items() if on]


def run(args: argparse.Namespace) -> int:
    from ..capture.sfm import recover_poses
    from ..progress import run_with_tqdm

    cfg = config_from_args(args)
    res = run_with_tqdm(recover_poses(args.images, args.out, cfg, verbose=args.verbose), desc="recover-poses",
                        unit="%")
    print(f"{args.out}: {res.summary()}")
    if res.unregistered:
        shown = ", ".join(res.unregistered[:5]) + (", ..." if len(res.unregistered) > 5 else "")
        print(f"not registered ({len(res.unregistered)}): {shown}")
    for w in res.warnings:
        print(f"warning: {w}", file=sys.stderr)
    return 0
