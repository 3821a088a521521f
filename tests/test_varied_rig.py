"""make-shapenet --rig sphere/hemisphere: per-view field of view and distance, recorded exactly; the
turntable default unchanged (issue 11, item 4)."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from blender_mrvm.commands import make_shapenet as M
from blender_mrvm.errors import InputError
from blender_mrvm.geometry import rigs


def _args(**kw):
    p = argparse.ArgumentParser()
    M.add_arguments(p)
    argv = ["--out", str(kw.pop("out", "/nonexistent/out"))]
    for k, v in kw.items():  # a value written "=v" goes as --name=v (one that starts with a minus sign)
        v = str(v)
        argv += [f"--{k.replace('_', '-')}{v}"] if v.startswith("=") else [f"--{k.replace('_', '-')}", v]
    return p.parse_args(argv)


@pytest.mark.parametrize("rig", ["sphere", "hemisphere"])
def test_varied_cameras_stay_in_their_ranges_and_look_at_the_object(rig):
    poses, intrs, recs = rigs.varied_cameras(rig, 400, 0.5, 64, 48, (30.0, 60.0), (0.85, 1.6), seed=3)
    fov = np.array([math.degrees(i.fov_x) for i in intrs])
    assert 30.0 <= fov.min() and fov.max() <= 60.0 and fov.max() - fov.min() > 25.0  # varied, within the range
    for p, intr, r in zip(poses, intrs, recs):
        c = p[:3, 3]
        fill = rigs.framing_distance(0.5, min(intr.fov_x, intr.fov_y), margin=1.0)  # narrower side: 48 px
        assert np.linalg.norm(c) == pytest.approx(r["distance"]) == pytest.approx(fill * r["distance_factor"])
        assert 0.85 <= r["distance_factor"] <= 1.6 and r["fov_x_deg"] == pytest.approx(math.degrees(intr.fov_x))
        assert np.allclose(p[:3, 2], -c / np.linalg.norm(c))  # optical axis through the origin
        assert abs(np.linalg.det(p[:3, :3]) - 1) < 1e-9
    k = np.array([r["distance_factor"] for r in recs])
    assert k.max() - k.min() > 0.6
    z = np.array([p[2, 3] for p in poses])
    assert (z >= 0).all() if rig == "hemisphere" else (z.min() < 0 < z.max())
    again = rigs.varied_cameras(rig, 400, 0.5, 64, 48, (30.0, 60.0), (0.85, 1.6), seed=3)
    other = rigs.varied_cameras(rig, 400, 0.5, 64, 48, (30.0, 60.0), (0.85, 1.6), seed=4)
    assert all(np.array_equal(a, b) for a, b in zip(poses, again[0])) and again[1] == intrs
    assert not np.allclose(poses[0], other[0][0])


def test_default_stays_the_turntable_byte_for_byte():
    """The default plan, render settings and protocol are what they were before the rig option."""
    args = _args()
    assert M.camera_settings(args) == {"rig": "turntable", "elevation_deg": 30.0}
    cfgs = M.render_configs(args)
    assert [(s, c.sources) for s, c in cfgs] == [(k, tuple(v)) for k, v in M.plan("all", 2).items() if v]
    for _, cfg in cfgs:
        assert cfg.settings() == {"rig": "turntable", "views": 24, "resolution": [64, 64], "engine": "CYCLES",
                                  "samples": 8, "rgba": False, "fov_deg": 40.0, "elevation_deg": 30.0, "seed": 0}
        assert cfg.fov_range_deg is None and cfg.distance_range is None
    assert M.protocol_rig(M.camera_settings(args)) == {"rig": "turntable", "elevation_deg": 30.0}
    assert M.eval_views(24) == M.eval_views(24, "turntable")
    assert M.eval_views(24)["input_views_2"] == [3, 15]


def test_sphere_rig_settings_and_protocol():
    args = _args(rig="hemisphere", fov_range="35,50", distance_range="1,1.2")
    cams = M.camera_settings(args)
    assert cams == {"rig": "hemisphere", "fov_range_deg": (35.0, 50.0), "distance_range": (1.0, 1.2)}
    st = M.render_configs(args)[0][1].settings()
    assert st["fov_range_deg"] == [35.0, 50.0] and st["distance_range"] == [1.0, 1.2] and st["rig"] == "hemisphere"
    assert M.camera_settings(_args(rig="sphere"))["fov_range_deg"] == rigs.FOV_RANGE_DEG == M.FOV_DEFAULT
    assert M.DIST_DEFAULT == rigs.DISTANCE_RANGE
    p = M.eval_views(24, "sphere")
    assert p["input_views_2"] == [0, 1] and len(p["target_views_2"]) == 22


@pytest.mark.parametrize("kw,match", [
    ({"fov_range": "30,60"}, "need --rig sphere"),
    ({"rig": "sphere", "fov_range": "60,30"}, "exceeds its max"),
    ({"rig": "sphere", "fov_range": "0,30"}, "must lie within"),
    ({"rig": "sphere", "fov_range": "30,190"}, "must lie within"),
    ({"rig": "sphere", "fov_range": "a,b"}, "two numbers"),
    ({"rig": "sphere", "distance_range": "0,1"}, "must lie within"),
    ({"rig": "sphere", "distance_range": "1,2,3"}, "two finite numbers"),
    ({"rig": "sphere", "distance_range": "nan,1"}, "two finite numbers"),
])
def test_bad_rig_arguments_are_one_line_errors(kw, match):
    with pytest.raises(InputError, match=match):
        M.camera_settings(_args(**kw))


def test_bad_rig_arguments_write_nothing(tmp_path, capsys):
    from blender_mrvm.cli import main

    out = tmp_path / "ds"
    assert main(["make-shapenet", "--rig", "sphere", "--fov-range", "60,30", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --fov-range") and not out.exists()


def test_sphere_rig_renders_poses_and_intrinsics_that_reproject(bpy_empty, tmp_path):
    """A tiny render: every view's intrinsics and pose (as written) put Cycles' silhouette where the
    recorded camera says, and the views' depths agree with each other across different focal lengths."""
    from blender_mrvm.datasets import format as F
    from blender_mrvm.progress import run_with_tqdm
    from blender_mrvm.scene.render import RenderConfig, render_dataset
    from tests.helpers import depth_consistency

    out = tmp_path / "sphere"
    cfg = RenderConfig(out=out, sources=("procedural:car:3",), rig="sphere", views=6, resolution=(64, 48),
                       samples=4, fov_range_deg=(30.0, 60.0), distance_range=(0.85, 1.6), split="test")
    run_with_tqdm(render_dataset(cfg), desc="t", unit="view")
    ov = F.read_object(out / "car" / "car_000003")
    meta = ov.meta
    assert meta["per_view_intrinsics"] and len(meta["cameras"]) == 6
    fovs = [math.degrees(i.fov_x) for i in ov.intrinsics_per_view]
    assert len(set(np.round(fovs, 6))) == 6 and all(30 <= f <= 60 for f in fovs)
    for rec, intr, c2w in zip(meta["cameras"], ov.intrinsics_per_view, ov.c2w_opencv):
        assert rec["fov_x_deg"] == pytest.approx(math.degrees(intr.fov_x), abs=1e-6)  # transforms.json is exact
        assert rec["distance"] == pytest.approx(np.linalg.norm(c2w[:3, 3]), rel=1e-6)
    # Cycles' colour (object on white) against the silhouette rasterized from the recorded camera
    for i in range(6):
        rgb = ov.rgb(i).astype(np.float64)
        fg_rgb = (rgb < 250).any(-1)
        fg_mask = ov.mask(i) > 0
        iou = (fg_rgb & fg_mask).sum() / (fg_rgb | fg_mask).sum()
        ys, xs = np.mgrid[0:48, 0:64]
        c_rgb = np.array([xs[fg_rgb].mean(), ys[fg_rgb].mean()])
        c_mask = np.array([xs[fg_mask].mean(), ys[fg_mask].mean()])
        assert iou > 0.85 and np.linalg.norm(c_rgb - c_mask) < 0.5, (i, iou, c_rgb - c_mask)
    errs = np.concatenate([depth_consistency(ov, a, b) for a in range(6) for b in range(6) if a != b])
    assert errs.size > 100 and np.median(errs) < 1e-3
    # intrinsics.txt holds one camera: without transforms.json the views' own fields of view would be lost
    tf = out / "car" / "car_000003" / "transforms.json"
    frames = json.loads(tf.read_text())
    frames["frames"] = frames["frames"][:-1]
    tf.write_text(json.dumps(frames))
    with pytest.raises(InputError, match="lacks view 5; restore it"):
        F.read_object(out / "car" / "car_000003")
    tf.unlink()
    with pytest.raises(InputError, match="own intrinsics .*transforms.json, which is missing"):
        F.read_object(out / "car" / "car_000003")


def test_nearest_view_baseline_weighs_direction_and_distance():
    """eval's nearest-view baseline on arbitrary poses: the synthesis rule (angle + log distance ratio),
    not direction alone; on a turntable (equal distances) it is the plain nearest direction as before."""
    from blender_mrvm.datasets.loaders import ObjectScene
    from blender_mrvm.geometry.cameras import look_at_opencv, intrinsics_from_fov
    from blender_mrvm.training.evaluate import _nearest_ref

    def at(az_deg, dist, el_deg=20.0):
        a, e = math.radians(az_deg), math.radians(el_deg)
        return look_at_opencv(dist * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)]))

    intr = intrinsics_from_fov(math.radians(40), 8, 8)
    poses = [at(0, 1.5), at(3, 6.0), at(12, 1.6), at(180, 1.5)]  # target 0
    s = ObjectScene("o", "c", np.zeros((4, 8, 8, 3), np.float32), np.stack(poses), [intr] * 4,
                    (np.full(3, -0.5), np.full(3, 0.5)), [0, 1, 2, 3])
    assert _nearest_ref(s, [1, 2, 3], 0) == 2  # 12 degrees away at the same distance beats 3 degrees at 4x the distance
    tt = [at(az, 1.5) for az in (0, 15, 40, 180)]
    s2 = ObjectScene("o", "c", np.zeros((4, 8, 8, 3), np.float32), np.stack(tt), [intr] * 4,
                     (np.full(3, -0.5), np.full(3, 0.5)), [0, 1, 2, 3])
    assert _nearest_ref(s2, [2, 1, 3], 0) == 1


def test_render_dataset_takes_the_varied_rig_too(tmp_path, capsys):
    from blender_mrvm.commands.render_dataset import add_arguments, config_from_args

    p = argparse.ArgumentParser()
    add_arguments(p)
    cfg = config_from_args(p.parse_args(["--source", "procedural:car:0", "--out", str(tmp_path / "a"),
                                         "--rig", "hemisphere", "--fov-range", "35,45"]))
    assert cfg.fov_range_deg == (35.0, 45.0) and cfg.distance_range == rigs.DISTANCE_RANGE
    cfg.validate()
    assert config_from_args(p.parse_args(["--source", "x", "--out", "y"])).fov_range_deg is None
    from blender_mrvm.cli import main

    out = tmp_path / "b"
    assert main(["render-dataset", "--source", "procedural:car:0", "--rig", "turntable", "--fov-range", "30,40",
                 "--out", str(out)]) == 2
    assert "sphere or hemisphere" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("rig,band", [("sphere", (5.0, 55.0)), ("sphere", (-30.0, 10.0)), ("hemisphere", (20.0, 40.0))])
def test_an_elevation_band_keeps_every_camera_in_it(rig, band):
    """--elevation-range: directions uniform over the band (azimuth all round, sine of the elevation uniform);
    the other draws keep their ranges, and without a band the rig is what it was (the same poses)."""
    poses, intrs, recs = rigs.varied_cameras(rig, 400, 0.5, 64, 64, (30.0, 60.0), (0.85, 1.6), seed=3,
                                             elevation_range_deg=band)
    c = np.stack([p[:3, 3] for p in poses])
    el = np.degrees(np.arcsin(c[:, 2] / np.linalg.norm(c, axis=1)))
    assert band[0] - 1e-9 <= el.min() and el.max() <= band[1] + 1e-9
    assert el.max() - el.min() > 0.8 * (band[1] - band[0])  # the band is filled, not one ring
    s = np.sin(np.radians(el))
    lo, hi = np.sin(np.radians(band))
    assert abs(s.mean() - 0.5 * (lo + hi)) < 0.05 * (hi - lo)  # uniform in the sine: equal area
    az = np.arctan2(c[:, 1], c[:, 0])
    assert np.histogram(az, bins=4, range=(-math.pi, math.pi))[0].min() > 60  # all round
    for p, intr, r in zip(poses, intrs, recs):
        assert np.allclose(p[:3, 2], -p[:3, 3] / np.linalg.norm(p[:3, 3]))
        assert 30.0 <= r["fov_x_deg"] <= 60.0 and 0.85 <= r["distance_factor"] <= 1.6
    whole = rigs.varied_cameras(rig, 400, 0.5, 64, 64, (30.0, 60.0), (0.85, 1.6), seed=3)
    # without a band, the draws of datasets rendered before the option (pinned: view 0's centre, view 1's fov)
    assert np.allclose(whole[0][0][:3, 3], [-0.857207, -0.951802, 0.122904], atol=1e-6)
    assert whole[2][1]["fov_x_deg"] == pytest.approx(33.892526, abs=1e-6)


def test_elevation_band_is_recorded_and_checked(tmp_path, capsys):
    args = _args(rig="sphere", fov_range="28,52", distance_range="0.85,1.3", elevation_range="5,55")
    cams = M.camera_settings(args)
    assert cams["elevation_range_deg"] == (5.0, 55.0)
    st = M.render_configs(args)[0][1].settings()
    assert st["elevation_range_deg"] == [5.0, 55.0]
    assert M.protocol_rig(cams)["elevation_range_deg"] == [5.0, 55.0]
    assert "elevation_range_deg" not in M.render_configs(_args(rig="sphere"))[0][1].settings()  # as before
    for kw, match in [({"elevation_range": "10,50"}, "need --rig sphere"),
                      ({"rig": "sphere", "elevation_range": "50,10"}, "exceeds its max"),
                      ({"rig": "sphere", "elevation_range": "0,95"}, "must lie within")]:
        with pytest.raises(InputError, match=match):
            M.camera_settings(_args(**kw))
    with pytest.raises(InputError, match="below the horizon"):
        M.render_configs(_args(rig="hemisphere", elevation_range="=-10,20"))
    from blender_mrvm.cli import main

    out = tmp_path / "c"
    assert main(["render-dataset", "--source", "procedural:car:0", "--rig", "hemisphere", "--elevation-range=-20,10",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "below the horizon" in err[0] and not out.exists()
