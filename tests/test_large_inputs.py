"""Large inputs a user may plausibly give: memory stays bounded (or the run is refused up front in one line).

The sizes are small here; what is checked is how many full-size images are held at once, which is what made
50 photos of 4000x4000 take 9.6 GB (a 6 GiB cap failed at the 28th) before they were shrunk to 64 px."""

from __future__ import annotations

import argparse
import weakref

import numpy as np
import pytest

from blender_mrvm import synthesis as S
from blender_mrvm.commands import synthesize as synth_cmd
from blender_mrvm.datasets import loaders
from blender_mrvm.errors import InputError
from blender_mrvm.training.synthetic import make_sphere_dataset

SIDE = 32


@pytest.fixture(scope="module")
def obj(tmp_path_factory):
    data = make_sphere_dataset(tmp_path_factory.mktemp("large") / "data", n_objects=1, n_views=6,
                               resolution=SIDE, seed=1)
    return data / "spheres" / "obj000"


@pytest.fixture
def full_size_alive(monkeypatch):
    """Counts, at each image read, how many full-size (SIDE px) float images are still alive: the most at once."""
    alive: list = []
    most = [0]
    real = loaders.to_float_rgb

    def counting(arr, *a, **k):
        img = real(arr, *a, **k)
        if max(img.shape[:2]) == SIDE:
            alive.append(weakref.ref(img))
        most[0] = max(most[0], sum(r() is not None for r in alive))
        return img

    monkeypatch.setattr(loaders, "to_float_rgb", counting)
    return most


def test_references_are_resized_as_they_are_read(obj, full_size_alive):
    refs = S.load_references(obj, (), ref_size=8)
    assert refs.images.shape == (6, 8, 8, 3) and [k.width for k in refs.intrinsics] == [8] * 6
    assert full_size_alive[0] <= 2  # the one being read (and the last one, until its name is rebound)


def test_orbit_holds_one_full_size_reference(obj, full_size_alive, tmp_path):
    args = argparse.Namespace(target_views=None, orbit=3, orbit_elevation=20.0, orbit_radius=None, orbit_size=0,
                              references=obj, ref_size=0)
    path = synth_cmd._make_targets(args, (), None, tmp_path)
    assert full_size_alive[0] <= 2
    from blender_mrvm.datasets.novel_views import read_targets

    got = read_targets(path)[0]
    want = S.orbit_targets(S.load_references(obj), 3)  # the orbit as before: the references' own size and poses
    assert [(t.intrinsics, t.name) for t in got] == [(t.intrinsics, t.name) for t in want]
    assert all(np.allclose(a.c2w_opencv, b.c2w_opencv) for a, b in zip(got, want))


def test_references_over_the_memory_limit_are_refused_after_one_read(obj, monkeypatch, tmp_path, capsys):
    """Too many too large references: one error line naming the limit and the --ref-size that fits, after reading
    one image, before the others are read (a 6 GiB cap failed at the 28th of 50 at 4000x4000, after 16 s)."""
    from blender_mrvm import validation as V
    from blender_mrvm.cli import main

    reads = []
    real = loaders.to_float_rgb
    monkeypatch.setattr(loaders, "to_float_rgb", lambda *a, **k: reads.append(1) or real(*a, **k))
    monkeypatch.setattr(V, "MAX_REFERENCE_BYTES", 5 * SIDE * SIDE * 12, raising=False)  # five of the six fit
    out = tmp_path / "out"
    code = main(["synthesize", "--references", str(obj), "--views", "all", "--ref-size", "-1", "--orbit", "2",
                 "--orbit-size", "8", "--out", str(out), "--device", "cpu", "--threads", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: 6 reference views at 32x32"), err
    assert "--ref-size 29 or smaller" in err[0] and "--views" in err[0]
    assert not out.exists()
    reads.clear()
    with pytest.raises(InputError, match="over the"):
        S.load_references(obj, (), ref_size=-1)
    assert len(reads) == 1
    assert S.load_references(obj, (), ref_size=29).images.shape[0] == 6  # what the message says fits


def test_references_kept_larger_than_the_side_limit_are_refused(obj, monkeypatch, tmp_path, capsys):
    """--ref-size -1 keeps the photos' own size, which --ref-size N caps at validation.MAX_REFERENCE_SIDE: over it,
    one error line naming the --ref-size that fits (two 8000x8000 photos ran out of an 8 GiB cap in the encoder)."""
    from blender_mrvm import validation as V
    from blender_mrvm.cli import main

    monkeypatch.setattr(V, "MAX_REFERENCE_SIDE", SIDE // 2)
    out = tmp_path / "out"
    code = main(["synthesize", "--references", str(obj), "--views", "0,1", "--ref-size", "-1", "--target-views",
                 "2", "--out", str(out), "--device", "cpu", "--threads", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and err[0].startswith("error: the reference views would be 32x32, over the "
                                                             "16 px limit"), err
    assert f"--ref-size {SIDE // 2} or smaller" in err[0] and not out.exists()
