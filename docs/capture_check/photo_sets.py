"""The four photo sets taken from each rendered scene (docs/capture_check/README.md), shared by the bench scripts."""
import shutil
from pathlib import Path

SUBSETS = {"arc8": range(12, 20), "arc10": range(0, 10), "arc14": range(5, 19), "ring12": range(0, 24, 2)}


def copy_subset(scene: Path, work: Path, subset: str) -> Path:
    """A fresh ``work/<scene>/<subset>`` folder holding the subset's photos in ``images/``; returns the folder."""
    d = work / scene.name / subset
    shutil.rmtree(d, ignore_errors=True)
    (d / "images").mkdir(parents=True)
    for i in SUBSETS[subset]:
        shutil.copy(scene / "images" / f"{i:03d}.png", d / "images")
    return d
