"""The main job on the shipped defaults (``make demo``).

Until the model lands (issues 4 and 5) the demo renders a small multi-view dataset of objects from
the procedural ShapeNet-13 library (a chair, a car, an airplane, a lamp) and writes a contact sheet:
``demo_out/dataset`` and ``demo_out/contact_sheet.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

DEMO_OBJECTS = ("procedural:chair:0", "procedural:car:2", "procedural:airplane:1", "procedural:lamp:3")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--views", type=int, default=12)
    p.add_argument("--resolution", type=int, default=128)
    p.add_argument("--force", action="store_true")


def run(args) -> int:
    from ..datasets.contact_sheet import dataset_contact_sheet
    from ..progress import run_with_tqdm
    from ..scene.render import RenderConfig, render_dataset

    out = Path(args.out)
    cfg = RenderConfig(out=out / "dataset", sources=DEMO_OBJECTS, views=args.views,
                       resolution=(args.resolution, args.resolution), force=args.force)
    summary = run_with_tqdm(render_dataset(cfg), desc="render", unit="view")
    sheet = dataset_contact_sheet(out / "dataset", out / "contact_sheet.png")
    print(f"rendered {summary.views_rendered} views ({summary.views_skipped} already done) of "
          f"{len(summary.objects)} objects in {summary.seconds:.1f} s -> {cfg.out}")
    print(f"contact sheet: {sheet}")
    return 0
