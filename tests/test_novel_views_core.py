"""bpy-free parts of novel views: the orbit rig, targets.json, reference view lists; and (with Blender) where the
.blend of a synthesis stores its images."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from blender_mrvm.datasets.novel_views import Target, parse_views, read_targets, write_targets
from blender_mrvm.errors import InputError
from blender_mrvm.geometry.cameras import Intrinsics
from blender_mrvm.geometry.rigs import orbit_poses


def test_orbit_poses_circle_elevation_and_look_at():
    center = np.array([0.5, -1.0, 0.25])
    poses = orbit_poses(6, 3.0, 30.0, center, start_azimuth_deg=90.0)
    assert len(poses) == 6
    pos = np.array([p[:3, 3] for p in poses])
    off = pos - center
    assert np.allclose(np.linalg.norm(off, axis=1), 3.0)
    assert np.allclose(off[:, 2], 3.0 * math.sin(math.radians(30.0)))
    assert np.allclose(off[0], [0.0, 3.0 * math.cos(math.radians(30.0)), 1.5], atol=1e-12)  # azimuth 90 = +y
    az = np.degrees(np.arctan2(off[:, 1], off[:, 0]))
    assert np.allclose(np.diff(np.unwrap(np.radians(az))), math.radians(60.0))  # evenly, counter-clockwise
    for p, o in zip(poses, off):
        r = p[:3, :3]
        assert np.allclose(r.T @ r, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(r), 1.0)
        assert np.allclose(r[:, 2], -o / 3.0)  # OpenCV +z looks at the centre
        assert r[2, 1] < 0  # image "down" points down in the world: the horizon is level, not upside down
    with pytest.raises(InputError, match="at least one"):
        orbit_poses(0, 1.0)
    with pytest.raises(InputError, match="radius"):
        orbit_poses(3, 0.0)
    with pytest.raises(InputError, match="elevation"):
        orbit_poses(3, 1.0, 95.0)
    top = orbit_poses(2, 2.0, 90.0)  # straight above: still proper rotations looking down
    assert all(np.allclose(p[:3, 2], [0, 0, -1]) for p in top)


def test_targets_round_trip(tmp_path):
    k = Intrinsics(40.0, 30.0, 16.5, 11.0, 32, 24)
    c2w = orbit_poses(2, 2.0, 10.0)
    ts = [Target("A", k, c2w[0]), Target("MRVM orbit 000", k, c2w[1], generated=True)]
    path = write_targets(tmp_path / "targets.json", ts, depth=True)
    d = json.loads(path.read_text())
    assert [t["rgb"] for t in d["targets"]] == ["rgb/000000.png", "rgb/000001.png"]
    assert [t["depth"] for t in d["targets"]] == ["depth/000000.exr", "depth/000001.exr"]
    back, depth = read_targets(path)
    assert depth is True
    for a, b in zip(ts, back):
        assert (a.name, a.intrinsics, a.generated) == (b.name, b.intrinsics, b.generated)
        assert np.array_equal(a.c2w_opencv, b.c2w_opencv)
    with pytest.raises(InputError, match="unique"):
        write_targets(tmp_path / "t2.json", [ts[0], ts[0]])
    with pytest.raises(InputError, match="no target"):
        write_targets(tmp_path / "t3.json", [])
    (tmp_path / "bad.json").write_text(json.dumps({"format": "blender_mrvm.targets", "version": 1, "targets": [{"name": "x"}]}))
    with pytest.raises(InputError, match="target 0 is malformed"):
        read_targets(tmp_path / "bad.json")
    with pytest.raises(InputError, match="does not exist"):
        read_targets(tmp_path / "none.json")
    (tmp_path / "other.json").write_text("{}")
    with pytest.raises(InputError, match="not a targets file"):
        read_targets(tmp_path / "other.json")



def test_read_targets_checks_every_value(tmp_path):
    """A value the synthesis cannot use is one InputError naming the target and the field, never a traceback, a
    huge allocation or a silently mirrored image; two targets of one name are refused (each names a camera)."""
    k = Intrinsics(40.0, 40.0, 16.0, 12.0, 32, 24)
    good = json.loads(write_targets(tmp_path / "good.json", [Target("A", k, orbit_poses(1, 2.0)[0])]).read_text())
    row = good["targets"][0]

    def fails(doc, msg):
        (tmp_path / "t.json").write_text(json.dumps(doc))
        with pytest.raises(InputError, match=msg):
            read_targets(tmp_path / "t.json")

    fails([1, 2], "not a targets file")
    fails({**good, "version": "1.0"}, "not a targets file")
    fails({**good, "targets": {"A": row}}, "'targets' must be a list")
    for key, value, msg in (("w", 0, r"target 0 \('A'\): w must be between 1 and 8192 pixels, got 0"),
                            ("h", 100000, "h must be between 1 and 8192 pixels"),
                            ("w", 32.5, "w must be a whole number"),
                            ("fl_x", -5, "fl_x must be a positive focal length"),
                            ("fl_y", 0, "fl_y must be a positive focal length"),
                            ("cx", float("nan"), "cx must be a finite number"),
                            ("cy", "12", "cy must be a finite number"),
                            ("c2w_opencv", [[1, 0, 0], [0, 1, 0], [0, 0, 1]], "c2w_opencv must be a finite 4x4"),
                            ("c2w_opencv", [[float("inf")] * 4] * 4, "c2w_opencv must be a finite 4x4"),
                            ("c2w_opencv", "eye", "c2w_opencv must be a finite 4x4"),
                            ("generated", "yes", "generated must be true or false"),
                            ("name", "", "name must be a non-empty text")):
        fails({**good, "targets": [{**row, key: value}]}, msg)
    fails({**good, "targets": [row, {**row, "rgb": "rgb/000001.png"}]}, "two targets are named 'A'")
    three_by_four = {**row, "c2w_opencv": row["c2w_opencv"][:3]}
    (tmp_path / "t.json").write_text(json.dumps({**good, "targets": [three_by_four]}))
    (back,), _ = read_targets(tmp_path / "t.json")
    assert np.array_equal(back.c2w_opencv, np.asarray(row["c2w_opencv"]))

def test_parse_views():
    assert parse_views("0 1") == (0, 1)
    assert parse_views(" 3, 5,7 ") == (3, 5, 7)
    for bad, msg in (("", "at least one"), ("a b", "view numbers"), ("1 1", "distinct"), ("-1", "non-negative"),
                     (" ".join(map(str, range(501))), "at most 500")):
        with pytest.raises(InputError, match=msg):
            parse_views(bad)


def test_dependency_report_lines(tmp_path):
    from blender_mrvm import worker as W

    it = W.Interpreter("/py", "project venv")
    rep = W.DependencyReport(it, "3.11.7", {"torch": None, "safetensors": "0.4", "numpy": "1.26.4", "PIL": "10.0",
                                           "scipy": "1.13.1", "OpenEXR": None, "pycolmap": "4.2.1",
                                           "pillow_heif": "1.8.1", "av": "18.1.0"})
    assert rep.missing == ["torch", "OpenEXR"]
    assert rep.install_command == '"/py" -m pip install "torch==2.13.0" "openexr>=3.3"'
    lines = rep.lines()
    assert lines[0] == ("Worker Python (project .venv, 3.11.7): /py", True)
    assert ("torch: missing (needed for training and novel-view synthesis)", False) in lines
    assert ("numpy 1.26.4", True) in lines
    assert lines[-1] == ('Install with: "/py" -m pip install "torch==2.13.0" "openexr>=3.3"', False)
    bad = W.dependency_report(str(tmp_path / "nope"))
    assert bad.interpreter is None and bad.lines() == [(f"the worker Python set in the add-on preferences does not exist: {tmp_path / 'nope'}", False)]


def test_write_blend_stores_the_reference_images_relative_so_a_moved_project_finds_them(empty_scene, tmp_path):
    """``write_blend`` (``synthesize --blend``, ``make demo``'s scene.blend): the reference cameras' background
    images are stored relative to the .blend, as its image planes are, so a project folder that is copied shows its
    own references and one that is moved still finds them."""
    import shutil
    from pathlib import Path

    import bpy

    from blender_mrvm.capture.export import CaptureView, write_capture
    from blender_mrvm.datasets import format as F
    from blender_mrvm.geometry import cameras as C
    from blender_mrvm.scene.novel_views import write_blend

    k = C.intrinsics_from_fov(0.8, 16, 16)
    proj, out = tmp_path / "proj", tmp_path / "out"
    views = []
    for i in range(2):
        F.write_png(tmp_path / f"p{i}.png", np.full((16, 16, 3), 50 * (i + 1), np.uint8))
        views.append(CaptureView(f"p{i}.png", tmp_path / f"p{i}.png", k, C.look_at_opencv((3.0 * math.cos(i), 3.0 * math.sin(i), 1.0))))
    refs = proj / "dataset" / "obj"
    write_capture(refs, views, np.zeros((0, 3)), np.zeros((0, 3), np.uint8), {"registered": 2, "total": 2})
    write_targets(out / "targets.json", [Target("view", k, C.look_at_opencv((0.0, -3.0, 1.0)))])
    F.write_png(out / "rgb" / "000000.png", np.full((16, 16, 4), 200, np.uint8))
    blend = write_blend(proj / "scene.blend", out / "targets.json", out, references=refs, reference_views=(0, 1),
                        plane_distance=1.0)

    def paths() -> dict[str, str]:
        got = {o.name: o.data.background_images[0].image.filepath for o in bpy.data.objects
               if o.type == "CAMERA" and len(o.data.background_images)}
        got["plane"] = bpy.data.images["MRVM view"].filepath
        return got

    assert paths() == {"MRVM reference 000": "//dataset/obj/rgb/000000.png",
                       "MRVM reference 001": "//dataset/obj/rgb/000001.png", "plane": "//scene_novel_views/view.png"}
    shutil.copytree(proj, tmp_path / "copy")
    proj.rename(tmp_path / "moved proj")
    for where in ("copy", "moved proj"):
        bpy.ops.wm.open_mainfile(filepath=str(tmp_path / where / blend.name))
        for path in paths().values():
            p = Path(bpy.path.abspath(path))
            assert p.is_file() and (tmp_path / where) in p.parents, (where, path)


def test_created_cameras_see_past_the_object_at_any_scale(empty_scene, tmp_path):
    """Created cameras clipped at twice the plane distance (the plane sits at half the object's centre depth): in a
    scene scaled x1e4 (centre 15350 away) the clip end fell exactly on the object's centre, cutting it in half seen
    through them. They now reach well past it, and the plane stays inside the range."""
    import bpy

    from blender_mrvm.datasets import format as F
    from blender_mrvm.geometry import cameras as C
    from blender_mrvm.scene.novel_views import write_blend

    k = C.intrinsics_from_fov(0.8, 16, 16)
    out = tmp_path / "out"
    write_targets(out / "targets.json", [Target("view", k, C.look_at_opencv((0.0, -15350.0, 0.0)))])
    F.write_png(out / "rgb" / "000000.png", np.full((16, 16, 4), 200, np.uint8))
    bbox = np.array([[-3000.0, -3000.0, -3000.0], [3000.0, 3000.0, 3000.0]])
    write_blend(tmp_path / "s.blend", out / "targets.json", out, bbox=bbox)
    d = bpy.data.objects["view"].data
    far_corner = 15350.0 + 3000.0 * math.sqrt(3)
    assert d.clip_start < 15350.0 / 2 < d.clip_end and d.clip_end > far_corner, (d.clip_start, d.clip_end)
