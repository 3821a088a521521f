"""Write a PNG contact sheet of a rendered dataset: per object, RGB / depth / part mask / normals."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", required=True, help="dataset root folder")
    p.add_argument("--out", required=True, help="PNG file to write (an existing file needs --force)")
    p.add_argument("--objects", type=int, default=8, help="at most this many objects (rows)")
    p.add_argument("--views", type=int, default=4, help="views per object")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")


def run(args) -> int:
    from .. import validation as V
    from ..datasets.contact_sheet import dataset_contact_sheet
    from ..errors import InputError
    from ..guards import check_new_file

    V.check_count("--objects", args.objects, 1, 1000)
    V.check_count("--views", args.views, 1, 100)
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise InputError(f"--out must name a .png file, got {out}")
    if not Path(args.dataset).is_dir():
        raise InputError(f"dataset folder {args.dataset} does not exist")
    check_new_file(out, args.force, "contact sheet")
    left_out: list[str] = []
    path = dataset_contact_sheet(Path(args.dataset), out, args.objects, args.views, left_out=left_out)
    if left_out:
        print(f"note: {len(left_out)} object folder(s) left out, not finished or without views to show: "
              f"{', '.join(left_out[:5])}{', ...' if len(left_out) > 5 else ''}", file=sys.stderr)
    print(f"wrote {path}")
    return 0
