"""Could fewer samples, denoised, give `render-dataset` the 16-sample image faster? (issue 13; session 50)

Session 35's ceiling (`ceiling_probe.py`) holds the image fixed. This probe asks what the image's samples buy:
`render-dataset` (the whole command, Cycles CPU, its scene and settings) renders the same objects at several
sample counts, with and without OpenImageDenoise (albedo and normal guides, the accurate prefilter, high quality),
and every view's written colour (`rgb/*.png`, sRGB on white, what a model trains on) is scored against the same
view rendered at ``--ref-spp`` samples (the converged image). The error is split by where it is: pixels on the
object's silhouette (the exact part mask differs within one pixel) and the rest.

Objects: `bench render`'s bench object and one procedural object from each of 7 categories; the sphere rig.
A fresh scene per configuration (with persistent data, Cycles keeps a scene's first sample count).

    PYTHONPATH=$PWD .venv/bin/python docs/bench_render_ceiling/samples_probe.py --out /tmp/samples_probe \\
        --resolution 64 --views 4 --csv docs/bench_render_ceiling/samples_64.csv
"""
from __future__ import annotations

import argparse
import os
import platform
import shutil
import time
from pathlib import Path

import bpy
import numpy as np
from PIL import Image
from scipy import ndimage

from blender_mrvm.bench import write_csv
from blender_mrvm.bench.render import _mesh
from blender_mrvm.progress import run_to_end
from blender_mrvm.scene import render as R

SOURCES = ("procedural:chair:1", "procedural:car:2", "procedural:lamp:3", "procedural:airplane:4",
           "procedural:sofa:5", "procedural:watercraft:6", "procedural:table:7")
CONFIGS = ((32, False), (16, False), (16, True), (8, False), (8, True), (4, False), (4, True), (1, False), (1, True))

_DENOISE = [False]
_setup_cycles = R.RenderSession._setup_cycles


def _setup_cycles_maybe_denoised(self, sc, samples):
    _setup_cycles(self, sc, samples)
    if _DENOISE[0]:
        cy = sc.cycles
        cy.use_denoising, cy.denoiser = True, "OPENIMAGEDENOISE"
        cy.denoising_input_passes, cy.denoising_prefilter, cy.denoising_quality = "RGB_ALBEDO_NORMAL", "ACCURATE", "HIGH"


R.RenderSession._setup_cycles = _setup_cycles_maybe_denoised


def render(out: Path, sources: tuple[str, ...], res: int, views: int, samples: int, denoise: bool) -> float:
    """Seconds a view of the whole `render-dataset` command."""
    _DENOISE[0] = denoise
    bpy.ops.wm.read_homefile(use_empty=True)
    cfg = R.RenderConfig(out=out, sources=sources, views=views, resolution=(res, res), samples=samples,
                         category="bench", split="test")
    t0 = time.perf_counter()
    summary = run_to_end(R.render_dataset(cfg))
    return (time.perf_counter() - t0) / summary.views_rendered


def views_of(root: Path) -> dict[Path, tuple[np.ndarray, np.ndarray]]:
    """{relative rgb path: (sRGB image in [0, 1], object mask)} of a rendered dataset."""
    out = {}
    for p in sorted(root.rglob("rgb/*.png")):
        mask = np.asarray(Image.open(p.parent.parent / "mask" / p.name)) > 0
        out[p.relative_to(root)] = (np.asarray(Image.open(p), dtype=np.float64) / 255.0, mask)
    return out


def psnr(se: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / max(se.mean(), 1e-12)))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True, help="scratch folder")
    ap.add_argument("--resolution", type=int, default=64)
    ap.add_argument("--views", type=int, default=4, help="views per object")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=2, help="timing repeats, the order reversed on odd ones")
    ap.add_argument("--csv", required=True)
    a = ap.parse_args()
    scratch = Path(a.out)
    scratch.mkdir(parents=True, exist_ok=True)
    sources = (str(_mesh(scratch)),) + SOURCES
    render(scratch / "ref", sources, a.resolution, a.views, a.ref_spp, False)
    ref = views_of(scratch / "ref")
    edge = {k: ndimage.maximum_filter(m, 3) != ndimage.minimum_filter(m, 3) for k, (_, m) in ref.items()}
    rows = []
    machine = f"{platform.machine()} {os.cpu_count()} cpu, bpy {bpy.app.version_string}"
    for rep in range(a.repeats):
        for samples, denoise in (CONFIGS if rep % 2 == 0 else CONFIGS[::-1]):
            d = scratch / f"s{samples}_d{int(denoise)}_r{rep}"
            sec = render(d, sources, a.resolution, a.views, samples, denoise)
            got = views_of(d)
            se_all, se_edge, se_rest = [], [], []
            for k, (img, _) in ref.items():
                se = ((got[k][0] - img) ** 2).mean(axis=-1)
                se_all.append(se.ravel())
                se_edge.append(se[edge[k]])
                se_rest.append(se[~edge[k]])
            se_all, se_edge, se_rest = (np.concatenate(x) for x in (se_all, se_edge, se_rest))
            per_view = [psnr(((got[k][0] - img) ** 2)) for k, (img, _) in ref.items()]
            row = {"resolution": a.resolution, "samples": samples, "denoise": "oidn" if denoise else "none",
                   "repeat": rep, "views": len(ref), "ms_per_view": round(sec * 1000, 1),
                   "psnr_vs_ref": round(psnr(se_all), 2), "psnr_view_min": round(min(per_view), 2),
                   "psnr_silhouette": round(psnr(se_edge), 2), "psnr_elsewhere": round(psnr(se_rest), 2),
                   "share_of_error_on_silhouette": round(float(se_edge.sum() / max(se_all.sum(), 1e-12)), 3),
                   "silhouette_pixel_share": round(se_edge.size / se_all.size, 3),
                   "ref_spp": a.ref_spp, "load_1min": round(os.getloadavg()[0], 2), "machine": machine}
            rows.append(row)
            print(row, flush=True)
            shutil.rmtree(d)
    write_csv(Path(a.csv), rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
