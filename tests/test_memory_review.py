"""Memory with large inputs: what is held at once is bounded, with results unchanged.

The sizes are small here; what is checked is the mechanism (how many views a pass of the image encoder takes, the
largest map it makes, how many full-size images a loader holds, how often an image is read), not memory use.
The measurements behind each (peak RSS of 8000 px references, of 24 views of 2000 px) are in the modules' docs."""

from __future__ import annotations

import argparse
import weakref

import numpy as np
import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from blender_mrvm import synthesis as S
from blender_mrvm import validation as V
from blender_mrvm.datasets import loaders
from blender_mrvm.errors import InputError
from blender_mrvm.models import registry
from blender_mrvm.models.base import ref_cameras
from blender_mrvm.geometry import cameras as C
from blender_mrvm.training.synthetic import make_sphere_dataset

torch.set_num_threads(1)
SIDE = 24

KINDS = {
    "nerformer resnet": ("nerformer_mrvm", "fast", {}),
    "nerformer vgg16": ("nerformer_mrvm", "fast", {"encoder": {"backbone": "vgg16", "pretrained": False,
                                                               "out_dim": 16}}),
    "gpnr": ("gpnr", "fast", {"patch_dim": 8, "d_model": 16, "n_heads": 2, "n_blocks": 1}),
}


def _model(kind: str):
    name, preset, over = KINDS[kind]
    torch.manual_seed(0)
    return registry.build_model(registry.build_config(name, preset, over), load_pretrained=False).eval()


def _features(ctx) -> torch.Tensor:
    return ctx.feats if hasattr(ctx, "feats") else ctx.patches


def _first_conv(model) -> torch.nn.Module:
    if hasattr(model, "patch_embed"):
        return model.patch_embed
    enc = model.encoder
    return enc.vgg[0] if enc.cfg.backbone == "vgg16" else enc.stem[0]


def _intr(side: int) -> C.Intrinsics:
    return C.Intrinsics(side * 1.2, side * 1.2, side / 2, side / 2, side, side)


def _refs(views: int, side: int = SIDE):
    torch.manual_seed(views)
    return torch.rand(views, 3, side, side), ref_cameras([np.eye(4)] * views, [_intr(side)] * views)


@pytest.mark.parametrize("kind", sorted(KINDS))
@pytest.mark.parametrize("views", [2, 3])
def test_references_are_encoded_one_view_at_a_time_with_the_same_features(kind, views):
    """Synthesis and eval (no gradients) encode the references one at a time: the encoder's intermediate maps are
    one view's, not all views' (two 8000 px references at --ref-size 4096 asked for one 4.8 GB allocation). The
    features are those of one pass over all views (what training, with gradients, still runs) to float rounding,
    and one view alone gives its own row of them."""
    model = _model(kind)
    images, cams = _refs(views)
    batches = []
    hook = _first_conv(model).register_forward_hook(lambda m, a, out: batches.append(a[0].shape[0]))
    try:
        with torch.enable_grad():  # one pass over every view: the features as before
            want = _features(model.encode(images, cams)).detach()
        assert batches == [views]
        batches.clear()
        with torch.no_grad():
            got = _features(model.encode(images, cams))
    finally:
        hook.remove()
    assert batches == [1] * views
    assert got.shape == want.shape
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
    with torch.no_grad():
        one = _features(model.encode(images[1:2], ref_cameras([np.eye(4)], [_intr(SIDE)])))
    torch.testing.assert_close(one, want[1:2], rtol=1e-5, atol=1e-6)


class _Largest(TorchDispatchMode):
    """The most elements of any tensor an op makes."""

    def __init__(self):
        super().__init__()
        self.most = 0

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for t in out if isinstance(out, (tuple, list)) else (out,):
            if isinstance(t, torch.Tensor):
                self.most = max(self.most, t.numel())
        return out


@pytest.mark.parametrize("kind", ["nerformer resnet", "nerformer vgg16"])
def test_large_references_are_fused_scale_by_scale(kind, monkeypatch):
    """Over ``encoder.LEAN_FUSE_PIXELS`` the encoder fuses its scales without upsampling each to the finest and
    concatenating them (at 4096 px that concatenation and its parts took 5.5 GiB of a view's peak; now 2.0 GiB): the
    largest map it makes holds no more channels than the widest of the backbone's at stride 2 or the output, and
    the features are those of the concatenated form to float rounding."""
    from blender_mrvm.models import encoder as E

    model = _model(kind)
    enc = model.encoder
    images, _ = _refs(1, 32)
    with torch.no_grad():
        want = enc(images)  # under the threshold: the concatenated form, as before
    monkeypatch.setattr(E, "LEAN_FUSE_PIXELS", 16 * 16)
    with torch.no_grad(), _Largest() as largest:
        got = enc(images)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)
    h2 = w2 = 16  # stride 2
    chans = (64, 128, 256) if enc.cfg.backbone == "vgg16" else enc.cfg.widths
    stride1 = 64 * 32 * 32 if enc.cfg.backbone == "vgg16" else 0  # VGG's first block runs at full size
    concatenated = sum(chans) * h2 * w2
    bound = max(stride1, max(chans[0], enc.cfg.out_dim) * h2 * w2)
    assert largest.most <= bound < concatenated


# ------------------------------------------------------------------------------------------- loaders (train)

@pytest.fixture(scope="module")
def obj(tmp_path_factory):
    data = make_sphere_dataset(tmp_path_factory.mktemp("mem") / "data", n_objects=1, n_views=6, resolution=SIDE,
                               seed=3)
    return data / "spheres" / "obj000"


def _count_alive(monkeypatch, module, name):
    """Counts, at each call of ``module.name`` (an image read), how many images it returned are still alive."""
    alive: list = []
    most = [0]
    real = getattr(module, name)

    def counting(*a, **k):
        img = real(*a, **k)
        alive.append(weakref.ref(img))
        most[0] = max(most[0], sum(r() is not None for r in alive))
        return img

    monkeypatch.setattr(module, name, counting)
    return most, alive


def test_an_object_is_loaded_into_one_array_view_by_view(obj, monkeypatch):
    """``load_ours`` (what ``train`` loads every object with) copies each view into one preallocated float32 array as
    it is read: 24 views of 4000 px (4.3 GiB as float) ran out of memory when the list of views, their stack and its
    float32 copy were held at once (3.3 GiB at the peak for 1.07 GiB of 2000 px views; 1.3 GiB now). Same values."""
    want = np.stack([loaders.to_float_rgb(loaders.F.read_object(obj).rgb(i)) for i in range(6)]).astype(np.float32)
    most, alive = _count_alive(monkeypatch, loaders, "to_float_rgb")
    scene = loaders.load_ours(obj)
    assert len(alive) == 6 and most[0] <= 2  # the view being read (and the one before, until its name is rebound)
    assert scene.images.dtype == np.float32 and np.array_equal(scene.images, want)


def test_srn_objects_are_loaded_view_by_view_too(obj, tmp_path, monkeypatch):
    import shutil

    srn = tmp_path / "srn_obj"
    shutil.copytree(obj / "rgb", srn / "rgb")
    shutil.copytree(obj / "pose", srn / "pose")
    shutil.copy(obj / "intrinsics.txt", srn / "intrinsics.txt")
    want = loaders.load_srn(srn).images
    most, alive = _count_alive(monkeypatch, loaders, "read_colour")
    got = loaders.load_srn(srn).images
    assert len(alive) == 6 and most[0] <= 2 and np.array_equal(got, want)


def test_views_of_different_sizes_are_still_named_all_at_once(tmp_path):
    st = loaders._Stack(3, tmp_path)
    for shape in [(4, 4, 3), (5, 4, 3), (4, 4, 3)]:
        st.add(np.zeros(shape, np.float32))
    with pytest.raises(InputError, match=r"views have different image sizes \[\(4, 4, 3\), \(5, 4, 3\)\]"):
        st.result()


# ------------------------------------------------------------------------------------------- synthesize

def test_the_reference_size_rule_has_one_owner(obj, tmp_path, capsys, monkeypatch):
    """The references' limits (their longer side, their bytes) are checked by validation.py, whether the size is
    known up front (--ref-size N) or after the first read (--ref-size -1): synthesis reads its limits there, and
    either way a user sees one error line (exit 2)."""
    from blender_mrvm.cli import main

    for ref_size, limit in (("9000", V.MAX_REFERENCE_SIDE), ("-1", SIDE // 2)):
        with monkeypatch.context() as m:
            m.setattr(V, "MAX_REFERENCE_SIDE", limit)
            out = tmp_path / f"out{ref_size}"
            code = main(["synthesize", "--references", str(obj), "--views", "0,1", "--ref-size", ref_size,
                         "--target-views", "2", "--out", str(out), "--device", "cpu", "--threads", "1"])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(err) == 1 and err[0].startswith("error: ") and f"{limit}" in err[0], err
        assert "--ref-size" in err[0] and not out.exists()
    calls = []
    real = V.check_reference_memory
    monkeypatch.setattr(V, "check_reference_memory", lambda *a, **k: calls.append(a) or real(*a, **k))
    S.load_references(obj, (0, 1), ref_size=-1, side_limit=SIDE)
    assert calls == [(2, SIDE, SIDE, SIDE)]
    assert not hasattr(S.views, "check_reference_memory")
    monkeypatch.setattr(V, "MAX_REFERENCE_SIDE", SIDE // 2)
    with pytest.raises(InputError, match=f"or 1 to {SIDE // 2} pixels, got {SIDE}"):
        V.check_ref_size("--ref-size", SIDE)


def test_an_orbit_reads_each_reference_once(obj, monkeypatch):
    """An orbit takes the first reference's camera at its size and the others' poses: ``orbit_references`` reads
    each image once (the first was read twice, at its size and at 16 px), and the orbit is the one before."""
    want = S.orbit_targets(S.load_references(obj, (1, 2, 3)), 4)
    reads = []
    real = loaders.to_float_rgb
    monkeypatch.setattr(loaders, "to_float_rgb", lambda *a, **k: reads.append(1) or real(*a, **k))
    refs = S.views.orbit_references(obj, (1, 2, 3), 0, None, 16)
    assert len(reads) == 3
    assert refs.images.shape == (3, 16, 16, 3) and refs.intrinsics[0].width == SIDE
    got = S.orbit_targets(refs, 4)
    assert [(t.intrinsics, t.name) for t in got] == [(t.intrinsics, t.name) for t in want]
    assert all(np.allclose(a.c2w_opencv, b.c2w_opencv) for a, b in zip(got, want))
    big = S.orbit_targets(S.views.orbit_references(obj, (1, 2), 40, None, 16), 2)  # --ref-size 40: its camera at 40
    assert big[0].intrinsics == S.orbit_targets(S.load_references(obj, (1,), 40), 2)[0].intrinsics


def test_synthesize_orbit_reads_each_reference_once(obj, monkeypatch, tmp_path):
    from blender_mrvm.commands import synthesize as synth_cmd

    reads = []
    real = loaders.to_float_rgb
    monkeypatch.setattr(loaders, "to_float_rgb", lambda *a, **k: reads.append(1) or real(*a, **k))
    args = argparse.Namespace(target_views=None, orbit=3, orbit_elevation=20.0, orbit_radius=None, orbit_size=0,
                              references=obj, ref_size=0)
    synth_cmd._make_targets(args, (0, 1, 2), None, tmp_path)
    assert len(reads) == 3
