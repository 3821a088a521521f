"""The main job on the shipped defaults (``make demo``).

Until the model lands (issue 4/5) the demo renders a small multi-view dataset of built-in test
objects and writes a contact sheet: ``demo_out/dataset`` and ``demo_out/contact_sheet.png``.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def demo_meshes(folder: Path) -> list[Path]:
    """A few real-looking test meshes made with trimesh (nothing is downloaded)."""
    import numpy as np
    import trimesh

    folder.mkdir(parents=True, exist_ok=True)
    torus = trimesh.creation.torus(major_radius=0.5, minor_radius=0.18)
    cup = trimesh.creation.annulus(r_min=0.32, r_max=0.4, height=0.8)
    base = trimesh.creation.cylinder(radius=0.4, height=0.08)
    base.apply_translation([0, 0, -0.4])
    cup = trimesh.util.concatenate([cup, base])
    lamp = trimesh.util.concatenate([
        trimesh.creation.cylinder(radius=0.25, height=0.05),
        trimesh.creation.cylinder(radius=0.03, height=0.9, transform=trimesh.transformations.translation_matrix([0, 0, 0.45])),
        trimesh.creation.cone(radius=0.3, height=0.3, transform=trimesh.transformations.translation_matrix([0, 0, 0.8])),
    ])
    out = []
    for name, m, ext in (("torus", torus, ".ply"), ("cup", cup, ".off"), ("lamp", lamp, ".stl")):
        p = folder / f"{name}{ext}"
        m.export(p)
        out.append(p)
    assert np.isfinite(torus.vertices).all()
    return out


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
    meshes = demo_meshes(out / "meshes")
    cfg = RenderConfig(out=out / "dataset", sources=tuple(str(m) for m in meshes), views=args.views,
                       resolution=(args.resolution, args.resolution), category="demo", force=args.force)
    summary = run_with_tqdm(render_dataset(cfg), desc="render", unit="view")
    sheet = dataset_contact_sheet(out / "dataset", out / "contact_sheet.png")
    print(f"rendered {summary.views_rendered} views ({summary.views_skipped} already done) of "
          f"{len(summary.objects)} objects in {summary.seconds:.1f} s -> {cfg.out}")
    print(f"contact sheet: {sheet}")
    return 0
