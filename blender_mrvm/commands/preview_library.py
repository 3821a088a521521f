"""Render a contact sheet PNG of the procedural object library: several seeds of every category."""

from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="PNG file to write (an existing file needs --force)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.add_argument("--seeds", type=int, default=6, help="seeds per category (0 .. N-1 from --first-seed)")
    p.add_argument("--first-seed", type=int, default=0, help="first seed")
    p.add_argument("--categories", default="all", help="comma-separated categories, or 'all'")
    p.add_argument("--size", type=int, default=160, help="tile size in pixels")
    p.add_argument("--engine", default="WORKBENCH", choices=("WORKBENCH", "CYCLES"),
                   type=lambda s: s.upper().removeprefix("BLENDER_"),
                   help="render engine (BLENDER_WORKBENCH, as the other commands spell it, is WORKBENCH)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel")
    p.add_argument("--parts", action="store_true", help="colour faces by part label instead of material")


def run(args) -> int:
    from ..errors import InputError
    from ..guards import check_new_file
    from ..progress import run_with_tqdm
    from ..scene.procedural import CATEGORIES
    from ..scene.procedural.preview import contact_sheet

    if args.seeds <= 0:
        raise InputError(f"--seeds must be positive, got {args.seeds}")
    if args.first_seed < 0:
        raise InputError(f"--first-seed must not be negative, got {args.first_seed}")
    if args.samples < 1:  # Cycles' 0 samples renders nothing, silently
        raise InputError(f"--samples must be at least 1, got {args.samples}")
    if args.first_seed + args.seeds > 2 ** 63:  # found before the first tile renders, not at the last
        raise InputError(f"--first-seed {args.first_seed} with --seeds {args.seeds} reaches seed "
                         f"{args.first_seed + args.seeds - 1}; seeds must be below 2**63")
    out = Path(args.out)
    cats = CATEGORIES if args.categories == "all" else tuple(c.strip() for c in args.categories.split(",") if c.strip())
    if not cats:
        raise InputError(f"--categories names no category ({args.categories!r}); give comma-separated categories "
                         f"({', '.join(CATEGORIES)}) or 'all'")
    # before rendering: it had replaced an existing PNG without asking, and failed on a folder only at the end
    check_new_file(out, args.force, "contact sheet")
    if out.suffix.lower() != ".png":  # the sheet is written as a PNG whatever the name says
        raise InputError(f"--out must name a .png file, got {out}")
    seeds = tuple(range(args.first_seed, args.first_seed + args.seeds))
    path = run_with_tqdm(contact_sheet(out, cats, seeds, args.size, args.engine, args.samples, args.parts),
                         desc="preview", unit="obj")
    print(f"wrote {path}")
    return 0
