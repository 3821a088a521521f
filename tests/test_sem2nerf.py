"""Sem2NeRF: input builders and the model (CPU, tiny shapes)."""

from __future__ import annotations

import types

import numpy as np
import pytest
import torch

from blender_mrvm.errors import InputError
from blender_mrvm.models.sem2nerf import inputs as I

torch.set_num_threads(1)


def _mask(size=64):
    return I.synthetic_mask(size)


# ------------------------------------------------------------------------------------------ inputs

def test_one_hot_shapes_and_values():
    m = _mask(64)
    labels = [0, 1, 2, 3, 4, 9]
    oh = I.one_hot(m, labels)
    assert oh.shape == (6, 64, 64) and oh.dtype == np.float32
    assert np.array_equal(oh.sum(0), np.ones((64, 64), np.float32))
    assert oh[5].sum() == 0  # label 9 absent
    for i, lab in enumerate(labels):
        assert np.array_equal(oh[i] > 0, m == lab)


def test_unknown_label_is_an_error():
    m = _mask(32)
    with pytest.raises(InputError, match=r"\[4\]"):
        I.one_hot(m, [0, 1, 2, 3])


def test_thickness_scales_with_resolution():
    assert I.contour_thickness(512, 512) == 3
    assert I.contour_thickness(1024, 768) == 6
    assert I.contour_thickness(64, 64) == 1
    assert I.contour_thickness(256, 256) == 2


def test_contours_lie_on_label_boundaries():
    m = _mask(128)
    c = I.contour_map(m, thickness=1) > 0
    # every thin contour pixel has a 4-neighbour of another label (or lies on the image edge)
    pad = np.pad(m, 1, mode="edge")
    nb_diff = np.zeros_like(c)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        nb_diff |= pad[dy:dy + 128, dx:dx + 128] != m
    assert c.any()
    assert np.all(nb_diff[c])
    assert np.all(m[c] != 0)  # drawn on the labelled side of the boundary
    # and of every pair of 4-neighbours with two different non-background labels, at least one
    # pixel is on a contour (the outer one of a region nested in another is not: that is a hole)
    for a, b in ((m[1:], m[:-1]), (m[:, 1:], m[:, :-1])):
        ca, cb = (c[1:], c[:-1]) if a.shape[0] == 127 else (c[:, 1:], c[:, :-1])
        pair = (a != b) & (a != 0) & (b != 0)
        assert pair.any() and np.all((ca | cb)[pair])


def test_external_contours_skip_holes_and_match_reference():
    m = np.zeros((40, 40), np.uint8)
    m[5:35, 5:35] = 1
    m[15:25, 15:25] = 0  # a background hole inside label 1: not an external contour
    c = I.contour_map(m, thickness=1) > 0
    assert not c[14, 20] and not c[25, 20]  # pixels of label 1 bordering the hole
    assert c[5, 20] and c[34, 20]
    for size in (64, 512):
        mm = _mask(size)
        assert np.array_equal(I.contour_map(mm), I.contour_map_reference(mm))
    # random blocky part maps (holes, nested regions, edge contact) agree with the plain reference
    from scipy import ndimage

    rng = np.random.default_rng(0)
    for _ in range(10):
        r = ndimage.zoom(rng.integers(0, 4, (8, 8)).astype(np.uint8), 12, order=0)
        assert np.array_equal(I.contour_map(r), I.contour_map_reference(r))
    # a region touching the image edge is outlined along the edge
    e = np.zeros((20, 20), np.uint8)
    e[:10] = 2
    ce = I.contour_map(e, thickness=1) > 0
    assert ce[0, 5] and ce[9, 5] and not ce[5, 5]


def test_contour_thickness_drawn():
    m = np.zeros((512, 512), np.uint8)
    m[100:400, 100:400] = 1
    c = I.contour_map(m) > 0
    # 3 px thick, centred on the border pixel row 100: rows 99, 100, 101
    assert c[99:102, 250].all() and not c[98, 250] and not c[102, 250]


def test_distance_field_zero_on_contour_and_growing():
    m = np.zeros((64, 64), np.uint8)
    m[16:48, 16:48] = 1
    c = I.contour_map(m)
    d = I.distance_field(c)
    assert d.shape == (64, 64) and d.dtype == np.float32
    assert d.min() == 0.0 and d.max() == pytest.approx(1.0)
    assert np.all(d[c > 0] == 0)
    assert np.all(d[c == 0] > 0)
    row = d[32, 16:32]  # from the contour (x=16) to the centre (x=31.5): strictly increasing
    assert np.all(np.diff(row) > 0)
    # Euclidean: distance to contour pixel (x=16) at (32, 24) is 8, before normalisation
    from scipy import ndimage

    raw = ndimage.distance_transform_edt(c == 0)
    assert np.allclose(d, raw / raw.max())
    assert raw[32, 24] == pytest.approx(24 - 16)


def test_distance_field_large_masks_within_stated_bound():
    """Above 128 px the field goes through a 128 px grid: within (2 f - 1) / sqrt(2) px of exact."""
    from scipy import ndimage

    c = I.contour_map(I.synthetic_mask(512))
    d = I.distance_field(c)
    raw = ndimage.distance_transform_edt(c == 0)
    bound = (2 * 4 - 1) / np.sqrt(2)
    assert d.dtype == np.float32 and d.min() == 0.0 and d.max() == pytest.approx(1.0)
    assert np.all(d[c > 0] == 0) and np.all(d[c == 0] > 0)
    approx = I._coarse_distance(c > 0.5, 4)
    err = np.abs(approx - raw)
    assert err.max() <= bound and err.mean() < 2.0
    assert np.abs(d - raw / raw.max()).max() < 2 * bound / raw.max()
    rng = np.random.default_rng(3)  # sparse random contours, odd sizes (padding at the edges)
    for h, w in ((300, 517), (640, 200)):
        cc = rng.random((h, w)) < 3e-4
        f = -(-max(h, w) // I.EXACT_MAX_SIDE)
        assert np.abs(I._coarse_distance(cc, f) - ndimage.distance_transform_edt(~cc)).max() <= (2 * f - 1) / np.sqrt(2)


def test_empty_mask_inputs():
    m = np.zeros((32, 32), np.uint8)
    x = I.build_inputs(m, [0, 1])
    assert x.shape == (4, 32, 32)
    assert np.all(x[0] == 1) and np.all(x[1] == 0) and np.all(x[2] == 0) and np.all(x[3] == 1)
    assert np.isfinite(x).all() and x.min() >= 0 and x.max() <= 1


def test_bench_writes_csv(tmp_path):
    res = I.bench(tmp_path, size=64, repeats=2)
    text = (tmp_path / "bench_sem2nerf_inputs.csv").read_text().splitlines()
    assert text[0].startswith("builder,size")
    assert {"one_hot", "contour_map", "distance_field", "build_inputs"} <= set(res)
    assert len(text) == 1 + len(res)
    from blender_mrvm.bench import PROVENANCE_FIELDS  # (it wrote its own CSV without them)

    assert text[0].endswith(",".join(PROVENANCE_FIELDS))


def test_palette_mask_png_reads_as_grey_values_not_indices(tmp_path):
    """A palette PNG with grey entries holds the ids its greys show (not its palette indices, which np.asarray
    gives); one with coloured entries (a quantised semantic_color map) is refused."""
    from PIL import Image

    from blender_mrvm.models.sem2nerf.render import colorize, read_mask_png

    m = np.zeros((8, 8), np.uint8)
    m[2:4], m[4:6], m[6:] = 1, 3, 7
    vals = np.unique(m)
    im = Image.fromarray(np.searchsorted(vals, m).astype(np.uint8), "P")  # indices 0..3
    im.putpalette([int(v) for v in vals for _ in range(3)])
    im.save(tmp_path / "grey.png")
    assert np.array_equal(read_mask_png(tmp_path / "grey.png"), m)
    Image.fromarray(colorize(m)).quantize(8).save(tmp_path / "colours.png")
    with pytest.raises(InputError, match="palette image with coloured entries.*8-bit greyscale"):
        read_mask_png(tmp_path / "colours.png")


def test_colour_of_an_unknown_label_is_not_read_as_a_known_one():
    """The colour of id 8 lies within the tolerance of id 100's: with 100 known and 8 not, it reads as 8 (which
    the mask check names), not as 100; colours a step off still read as their known labels, also labels 7 apart."""
    from blender_mrvm.models.sem2nerf.render import check_input_mask, colorize, mask_from_rgba, palette

    assert np.abs(np.subtract(palette(8), palette(100))).max() <= 24
    labels = (0, 3, 53, 65, 100, 149)
    m = np.zeros((8, 8), np.uint8)
    m[1], m[2], m[3], m[4], m[5] = 8, 65, 3, 53, 149
    assert sorted(np.unique(mask_from_rgba(colorize(m), labels, "COLORS", "img"))) == [0, 3, 8, 53, 65, 149]
    info = types.SimpleNamespace(size=8, labels=labels, names=tuple(map(str, labels)))
    with pytest.raises(InputError, match=r"label id\(s\) \[8\] are not known"):
        check_input_mask(mask_from_rgba(colorize(m), labels, "COLORS", "img"), info, "img")
    m[1] = 100
    off = np.clip(colorize(m).astype(int) + 1, 0, 255).astype(np.uint8)  # every channel a step off
    off[0] = 250  # near white: background
    assert np.array_equal(mask_from_rgba(off, labels, "COLORS", "img"), m)
    every = np.arange(256, dtype=np.uint8)[None]
    assert np.array_equal(mask_from_rgba(colorize(every), labels, "COLORS", "img"), every)


# ------------------------------------------------------------------------------------------- model

@pytest.fixture(scope="module")
def tiny():
    from blender_mrvm.models.sem2nerf.config import sem2nerf_config
    from blender_mrvm.models.sem2nerf.model import Sem2NeRF

    torch.manual_seed(0)
    cfg = sem2nerf_config("fast", image_size=32, labels=(0, 3, 5), label_names=("background", "a", "b"),
                          pretrained=False, style_mean_samples=1000, n_coarse=8, n_fine=4, hidden=16,
                          n_layers=2, encoder_hidden=32, vgg_layers=4)
    return Sem2NeRF(cfg).eval()


def _mask_inputs(cfg, seed=0):
    m = np.zeros((cfg.image_size, cfg.image_size), np.uint8)
    m[8:24, 10:22] = 3
    m[20:28, 12:20] = 5
    return torch.from_numpy(I.build_inputs(m, cfg.labels))[None]


def _rays(n=64, seed=0):
    from blender_mrvm.geometry import cameras
    from blender_mrvm.models.rays import make_rays, normalize_pose

    intr = cameras.intrinsics_from_fov(np.deg2rad(40), 8, 8)
    c2w = cameras.look_at_opencv(np.array([1.2, -0.8, 0.7]))
    b = make_rays(intr, normalize_pose(c2w, np.zeros(3), 0.5), None, box=1.0)
    return b, intr, c2w


def test_model_shapes_and_one_logit_per_label(tiny):
    cfg = tiny.cfg
    x = _mask_inputs(cfg)
    assert x.shape == (1, cfg.in_channels, 32, 32)
    code = tiny.encode(x, _rays()[2][None], _rays()[1])
    assert code.shape == (1, 2 * cfg.n_layers * cfg.hidden)
    assert code.fmap.shape == (1, cfg.local_channels, 32, 32) and code.K.shape == (1, 3, 3)
    b, intr, c2w = _rays()
    out = tiny.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], code, tiny.default_style())
    assert out["rgb"].shape == (1, 64, 3) and out["acc"].shape == (1, 64)
    assert out["semantic"].shape == (1, 64, cfg.n_labels) == (1, 64, 3)
    # log-probabilities: they exponentiate to a distribution over the known labels
    assert torch.allclose(out["semantic"].exp().sum(-1), torch.ones(1, 64), atol=1e-3)
    img = tiny.render_image(intr, c2w, code, tiny.default_style())
    assert img["rgb"].shape == (8, 8, 3) and img["semantic"].shape == (8, 8, 3) and img["acc"].shape == (8, 8)


def test_no_nan_for_empty_and_extreme(tiny):
    cfg = tiny.cfg
    code = tiny.encode(_mask_inputs(cfg), _rays()[2][None], _rays()[1])
    b, _, _ = _rays()
    # all rays miss: background everywhere, no evaluation
    miss = torch.zeros_like(b.hit)
    out = tiny.render_rays(b.origins[None], b.dirs[None], b.far[None], miss[None], code, tiny.default_style())
    assert torch.all(out["rgb"] == 1) and torch.all(out["acc"] == 0)
    assert torch.all(out["semantic"].argmax(-1) == 0)
    # zero-length rays, huge codes and a huge style: finite
    far0 = torch.zeros_like(b.far)
    from blender_mrvm.models.sem2nerf.model import MaskCode

    huge = MaskCode(code.code * 1e4, code.fmap * 1e4, code.index, code.K, code.w2c)
    out = tiny.render_rays(b.origins[None], b.dirs[None], far0[None], b.hit[None], huge,
                           tiny.default_style() * 1e4)
    for v in out.values():
        assert torch.isfinite(v).all()
    # extreme inputs (all-zero / all-one channels) and gradients through the whole model
    tiny.train()
    for x in (torch.zeros(1, cfg.in_channels, 32, 32), torch.ones(1, cfg.in_channels, 32, 32)):
        code = tiny.encode(x, _rays()[2][None] * 1e3, _rays()[1])
        out = tiny.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], code,
                               tiny.default_style(), perturb=True)
        loss = out["rgb"].mean() + out["semantic"].mean()
        loss.backward()
        assert all(torch.isfinite(p.grad).all() for p in tiny.parameters() if p.grad is not None)
        tiny.zero_grad()
    tiny.eval()


def test_default_style_is_mean_of_mapping(tiny):
    cfg = tiny.cfg
    g = torch.Generator().manual_seed(0)
    z = torch.randn(cfg.style_mean_samples, cfg.z_dim, generator=g)
    with torch.no_grad():
        assert torch.allclose(tiny.style_mean, tiny.mapping(z).mean(0), atol=1e-6)
    assert not torch.allclose(tiny.style_from_seed(1), tiny.style_from_seed(2))


def test_style_blend_changes_image_monotonically(tiny):
    from dataclasses import replace

    from blender_mrvm.models.sem2nerf.model import Sem2NeRF

    torch.manual_seed(1)
    tiny = Sem2NeRF(replace(tiny.cfg, density_bias=3.0)).eval()  # an opaque field: colour shows
    code = tiny.encode(_mask_inputs(tiny.cfg), _rays()[2][None], _rays()[1])
    b, _, _ = _rays()
    with torch.no_grad():
        s0, s1 = tiny.style_from_seed(1), tiny.style_from_seed(2)
        imgs = []
        for a in np.linspace(0, 1, 6):
            s = (1 - a) * s0 + a * s1
            imgs.append(tiny.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], code, s)["rgb"])
    d0 = [float((im - imgs[0]).abs().mean()) for im in imgs]
    d1 = [float((im - imgs[-1]).abs().mean()) for im in imgs]
    assert d0[-1] > 1e-4  # the two styles give different images
    assert all(x < y for x, y in zip(d0, d0[1:]))  # away from style 0 ...
    assert all(x > y for x, y in zip(d1, d1[1:]))  # ... towards style 1


def test_encoder_starts_from_imagenet_vgg():
    from blender_mrvm.models.sem2nerf.config import sem2nerf_config
    from blender_mrvm.models.sem2nerf.model import MaskEncoder
    from blender_mrvm.models.vgg import load_vgg16_features

    cfg = sem2nerf_config("fast", image_size=32, labels=(0, 1, 2), label_names=("b", "x", "y"), vgg_layers=4)
    enc = MaskEncoder(cfg)
    ref = load_vgg16_features(4)
    assert torch.equal(enc.backbone[2].weight, ref[2].weight)
    w0 = ref[0].weight.mean(1, keepdim=True) * (3.0 / cfg.in_channels)
    assert torch.allclose(enc.backbone[0].weight, w0.expand(-1, cfg.in_channels, -1, -1))


def test_pixel_aligned_features_sample_the_input_pixel(tiny):
    """Every point on the ray through input pixel (x, y) sees the input mask at (x, y): the rendered
    input view can follow the mask (the global code alone gave category-average shapes, mIoU 0.31)."""
    from blender_mrvm.geometry import cameras
    from blender_mrvm.models.rays import make_rays, normalize_pose
    from blender_mrvm.models.sem2nerf.model import local_features

    cfg = tiny.cfg
    x = _mask_inputs(cfg)
    intr = cameras.intrinsics_from_fov(np.deg2rad(40), 32, 32)
    c2w = cameras.look_at_opencv(np.array([1.2, -0.8, 0.7]))
    mc = tiny.encode(x, c2w[None], intr)
    b = make_rays(intr, normalize_pose(c2w, np.zeros(3), cfg.scene_box), None, box=1.0)
    hit = b.hit.numpy()
    t = torch.linspace(0.05, 0.95, 5, dtype=torch.float64)[None, :, None] * b.far[:, None, None]
    pts = (b.origins[:, None] + t * b.dirs[:, None]).reshape(1, -1, 3).float()
    feat, got, inside = local_features(pts, mc)
    idx = x[0, : cfg.n_labels].argmax(0).reshape(-1).numpy()
    got = got.reshape(32 * 32, 5).numpy()
    assert np.array_equal(got[hit], np.repeat(idx[hit, None], 5, 1))
    assert (inside.reshape(32 * 32, 5)[hit] == 1).all()  # inside the image, in front of the camera
    # the local map sampled at pixel centres is the map's pixel (bilinear weights 1)
    fm = mc.fmap[0].reshape(cfg.local_channels, -1).T  # (S*S, L)
    assert torch.allclose(feat.reshape(32 * 32, 5, -1)[hit][:, 2, : cfg.local_channels], fm[torch.from_numpy(hit)],
                          atol=1e-4)
    # a point behind the camera sees nothing
    behind = torch.tensor(normalize_pose(c2w, np.zeros(3), cfg.scene_box)[:3, 3] * 1.5, dtype=torch.float32)
    f2, i2, in2 = local_features(behind.view(1, 1, 3), mc)
    assert (f2 == 0).all() and int(i2) == 0 and float(in2) == 0


def test_pixel_aligned_input_view_semantics_follow_the_mask(tiny):
    """An opaque pixel-aligned field with a strong label gain renders the input mask's labels in the
    input view (what the input-view mIoU measures)."""
    from dataclasses import replace

    from blender_mrvm.geometry import cameras
    from blender_mrvm.models.sem2nerf.model import Sem2NeRF
    from blender_mrvm.training.sem2nerf import miou

    torch.manual_seed(0)
    m = Sem2NeRF(replace(tiny.cfg, density_bias=6.0)).eval()
    with torch.no_grad():
        m.field.label_gain.fill_(100.0)
    intr = cameras.intrinsics_from_fov(np.deg2rad(40), 32, 32)
    c2w = cameras.look_at_opencv(np.array([1.2, -0.8, 0.7]))
    x = _mask_inputs(m.cfg)
    img = m.render_image(intr, c2w, m.encode(x, c2w[None], intr), m.default_style())
    sem = np.asarray(m.cfg.labels)[img["semantic"].argmax(-1).numpy()]
    gt = np.asarray(m.cfg.labels)[x[0, : m.cfg.n_labels].argmax(0).numpy()]
    fg = gt > 0
    assert (sem[fg] == gt[fg]).all()
    assert miou(np.where(fg, gt, 0), np.where(fg, sem, 0)) == 1.0


def test_global_only_configs_still_load_and_render(tiny):
    """A checkpoint config written before pixel_aligned existed reads as global-only (its weights have no
    local branch), and that model still encodes to a plain code tensor and renders."""
    from dataclasses import replace

    from blender_mrvm.models.config import from_dict, to_dict
    from blender_mrvm.models.sem2nerf.config import Sem2NeRFConfig
    from blender_mrvm.models.sem2nerf.model import Sem2NeRF

    d = to_dict(tiny.cfg)
    for k in ("pixel_aligned", "local_channels", "local_hidden"):
        d.pop(k)
    old = from_dict(Sem2NeRFConfig, d)
    assert old.pixel_aligned is False
    m = Sem2NeRF(replace(old, style_mean_samples=10)).eval()
    assert not any(k.startswith(("field.local", "encoder.local")) for k in m.state_dict())
    code = m.encode(_mask_inputs(old), _rays()[2][None])
    assert isinstance(code, torch.Tensor) and code.shape == (1, 2 * old.n_layers * old.hidden)
    b, _, _ = _rays()
    assert torch.isfinite(m.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], code,
                                        m.default_style())["rgb"]).all()


def test_inference_keeps_the_coarse_points_and_renders_what_evaluating_them_again_renders(tiny, monkeypatch):
    """At inference (no grad) the final pass evaluates only the fine points and merges them with the coarse
    ones' values; with grad it evaluates all again. Same view either way, and 40 % fewer points queried."""
    from dataclasses import replace

    from blender_mrvm.models.sem2nerf.model import Sem2NeRF

    torch.manual_seed(1)
    m = Sem2NeRF(replace(tiny.cfg, density_bias=1.0, style_mean_samples=10)).eval()  # a field with structure
    code = m.encode(_mask_inputs(m.cfg), _rays()[2][None], _rays()[1])
    b, _, _ = _rays()
    args = (b.origins[None], b.dirs[None], b.far[None], b.hit[None], code, m.default_style())
    counts = []
    real_query = Sem2NeRF.query
    monkeypatch.setattr(Sem2NeRF, "query", lambda self, pts, *a: counts.append(pts.shape[1]) or real_query(self, pts, *a))
    with torch.no_grad():
        fast = m.render_rays(*args)
    n_fast, counts[:] = sum(counts), []
    with torch.enable_grad():
        full = m.render_rays(*args)
    n_full = sum(counts)
    rays = b.hit.numel()  # (a batch item with any hit renders all its rays and keeps the hits)
    c, f = m.cfg.n_coarse, m.cfg.n_fine
    assert n_fast == rays * (c + f) and n_full == rays * (2 * c + f)
    assert fast["acc"].max() > 0.2  # not an empty field, where anything would agree
    for k in ("rgb", "acc", "semantic"):
        assert torch.allclose(fast[k], full[k].detach(), atol=1e-5), k


def test_render_image_evaluates_only_the_rays_it_needs(tiny):
    """render_image renders only rays that cross the box (and, with cull_cone, the input mask's silhouette
    cone) and gives the rest the background: the same image as rendering every ray, ray for ray."""
    from dataclasses import replace

    from blender_mrvm.geometry import cameras
    from blender_mrvm.models.rays import make_rays, normalize_pose
    from blender_mrvm.models.sem2nerf.model import Sem2NeRF, silhouette_cone

    torch.manual_seed(2)
    m = Sem2NeRF(replace(tiny.cfg, density_bias=1.0, style_mean_samples=10, chunk_rays=37)).eval()
    _, in_intr, in_c2w = _rays()
    code = m.encode(_mask_inputs(m.cfg), in_c2w[None], in_intr)
    intr = cameras.intrinsics_from_fov(np.deg2rad(110), 12, 12)  # wide enough that the corners miss the box
    c2w = cameras.look_at_opencv(np.array([0.0, -1.3, 0.2]))
    b = make_rays(intr, normalize_pose(c2w, np.zeros(3), m.cfg.scene_box), None, box=1.0)
    assert 0 < int(b.hit.sum()) < len(b)
    with torch.no_grad():
        full = m.render_rays(b.origins[None], b.dirs[None], b.far[None], b.hit[None], code, m.default_style())
    img = m.render_image(intr, c2w, code, m.default_style())
    assert m.last_render_stats == {"rays": len(b), "box": int(b.hit.sum()), "evaluated": int(b.hit.sum())}
    for k in ("rgb", "acc", "semantic"):
        assert torch.allclose(img[k].reshape(full[k][0].shape), full[k][0], atol=1e-5), k
    # the silhouette cone: off the mask's foreground cone the rays are background, on it they render as before
    cone = silhouette_cone(b, code)
    assert 0 < int((cone & b.hit).sum()) < int(b.hit.sum())
    m.cfg = replace(m.cfg, cull_cone=True)
    culled = m.render_image(intr, c2w, code, m.default_style())
    assert m.last_render_stats["evaluated"] == int((cone & b.hit).sum())
    keep = (cone & b.hit).reshape(12, 12)
    assert torch.allclose(culled["rgb"][keep], img["rgb"][keep], atol=1e-5)
    assert torch.all(culled["rgb"][~keep] == 1) and torch.all(culled["acc"][~keep] == 0)
    assert torch.all(culled["semantic"][~keep].argmax(-1) == 0)
    # the rays made by torch where the model renders (a GPU's path, forced here on the CPU): the same view
    from blender_mrvm.models import base

    stats = dict(m.last_render_stats)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(base, "rays_on_host", lambda device: False)
        dev_path = m.render_image(intr, c2w, code, m.default_style())
    assert m.last_render_stats == stats
    small = m.render_image(intr, c2w, code, m.default_style(), chunk=5)  # a chunk asked for (bench tradeoff's axis)
    for k in ("rgb", "acc", "semantic"):
        assert torch.allclose(dev_path[k], culled[k], atol=1e-5), k
        assert torch.allclose(small[k], culled[k], atol=1e-5), k


def test_silhouette_cone_follows_the_mask():
    """A ray through the foreground's cone is in it, one that passes beside the object is not; a dilation of
    the mask widens the cone."""
    from blender_mrvm.geometry import cameras
    from blender_mrvm.models.rays import RayBundle
    from blender_mrvm.models.sem2nerf.model import MaskCode, silhouette_cone

    S = 32
    index = torch.zeros(1, 1, S, S)
    index[..., 14:18, 14:18] = 1.0  # a small object at the image centre
    intr = cameras.intrinsics_from_fov(np.deg2rad(40), S, S)
    K = torch.tensor([[[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]]])
    w2c = torch.eye(4)[None]
    w2c[0, 2, 3] = 2.0  # the input camera 2 units behind the origin, looking along +z
    mc = MaskCode(torch.zeros(1, 4), torch.zeros(1, 2, S, S), index, K, w2c)
    # rays along x at depth 2 in front of the camera: through the centre (on the cone), and 0.8 to the side
    o = torch.tensor([[-1.0, 0.0, 0.0], [-1.0, 0.8, 0.0]])
    d = torch.tensor([[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    b = RayBundle(o, d, torch.full((2,), 2.0), torch.ones(2, dtype=torch.bool), torch.zeros(2))
    assert silhouette_cone(b, mc).tolist() == [True, False]
    # a ray 1.5 px (at depth 2) beside the foreground's edge: outside without dilation, inside with 2 px
    y = (18 + 1.5 - intr.cy) / intr.fy * 2.0
    b1 = RayBundle(torch.tensor([[-1.0, y, 0.0]]), d[:1], torch.full((1,), 2.0), torch.ones(1, dtype=torch.bool),
                   torch.zeros(1))
    assert silhouette_cone(b1, mc, dilate_px=0).tolist() == [False]
    assert silhouette_cone(b1, mc, dilate_px=2).tolist() == [True]
