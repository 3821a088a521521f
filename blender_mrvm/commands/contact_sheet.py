"""Write a PNG contact sheet of a rendered dataset: per object, RGB / depth / part mask / normals."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--dataset", required=True, help="dataset root folder")
    p.add_argument("--out", required=True, help="PNG file to write")
    p.add_argument("--objects", type=int, default=8, help="at most this many objects (rows)")
    p.add_argument("--views", type=int, default=4, help="views per object")


def run(args) -> int:
    from ..datasets.contact_sheet import dataset_contact_sheet

    path = dataset_contact_sheet(Path(args.dataset), Path(args.out), args.objects, args.views)
    print(f"wrote {path}")
    return 0
