"""make-captures (issue 10): library objects in textured rooms along hand-held camera paths, written in
the dataset format with held-out in-between views and held-out scenes."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from blender_mrvm.cli import main
from blender_mrvm.geometry import paths as P


def _path(seed, n=24, **kw):
    spec = P.draw_path(np.random.default_rng(seed), **kw)
    return spec, np.stack(P.handheld_poses(spec, n, target=(0.0, 0.0, 0.3)))


def _angle(a, b):
    r = a[:3, :3].T @ b[:3, :3]
    return math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1)))


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("n", [12, 24, 60])
def test_paths_are_smooth_like_a_walk(seed, n):
    spec, poses = _path(seed, n)
    c = poses[:, :3, 3]
    if spec.span_deg >= 360:  # a loop joins up: the step back to the first camera is an ordinary step
        c = np.concatenate([c, c[:1]])
        poses = np.concatenate([poses, poses[:1]])
    step = np.linalg.norm(np.diff(c, axis=0), axis=1)
    mean = step.mean()
    arc = math.radians(spec.span_deg) * spec.distance / (len(c) - 1)
    assert mean == pytest.approx(arc, rel=0.25)  # it walks round the object, not back and forth
    assert step.max() < 2.2 * mean and step.min() > 0.35 * mean  # bounded step, never standing still
    accel = np.linalg.norm(c[2:] - 2 * c[1:-1] + c[:-2], axis=1)
    bend = mean * math.radians(spec.span_deg) / (len(c) - 1)  # what walking round a circle alone gives
    if n >= 24:  # 12 views round a loop are 30 degrees apart: sparse, not jerky
        assert accel.max() < bend + 0.3 * mean  # smooth: the step changes little from one camera to the next
    turn = [_angle(a, b) for a, b in zip(poses[:-1], poses[1:])]
    assert max(turn) < 1.6 * spec.span_deg / (len(c) - 1) + 3.0  # no sudden swings of the view direction
    # hand-held: height, distance, roll and aim all drift, within their bounds
    d = np.linalg.norm(c[:, :2], axis=1)
    assert d.max() <= spec.distance * (1 + spec.distance_jitter) + 1e-9 and np.ptp(d) > 0.01 * spec.distance
    assert np.ptp(c[:, 2]) > 0.005 and np.all(np.abs(c[:, 2] - 0.3 - spec.height) <= spec.height_jitter + 1e-9)
    for p in poses:  # the camera looks at the object, give or take the aim's wander
        fwd, to = p[:3, 2], np.array([0, 0, 0.3]) - p[:3, 3]
        assert math.degrees(math.acos(fwd @ to / np.linalg.norm(to))) < 6.0


def test_paths_are_seeded():
    a, pa = _path(5)
    b, pb = _path(5)
    _, pc = _path(6)
    assert a == b and np.array_equal(pa, pb) and not np.allclose(pa, pc)
    rolls = []
    for s in range(20):
        _, p = _path(s)
        side = p[:, :3, 0]
        rolls.append(np.degrees(np.arcsin(np.clip(side[:, 2], -1, 1))))  # right axis tilts with roll
    r = np.abs(np.concatenate(rolls))
    assert 0.3 < r.max() < 5.0  # a small roll, never a tilted horizon


def test_held_out_views_and_their_neighbours():
    from blender_mrvm.scene.capture_scenes import held_out_views, protocol, scene_splits

    assert held_out_views(24, 4) == [2, 6, 10, 14, 18, 22]
    rec = protocol(24, 4)
    assert rec["target_inputs_1"]["2"] == [1] and rec["target_inputs_2"]["6"] == [5, 7]
    assert rec["target_inputs_4"]["22"] == [20, 21, 23, 19][:0] + [19, 20, 21, 23]
    for n in range(1, 7):
        per = rec[f"target_inputs_{n}"]
        assert all(len(v) == n and not set(v) & set(rec[f"target_views_{n}"]) for v in per.values())
        assert set(rec[f"input_views_{n}"]) == {r for v in per.values() for r in v}
    assert set(rec["train_views"]).isdisjoint(rec["target_views_2"]) and len(rec["train_views"]) == 18
    assert scene_splits(1) == ["train"] and scene_splits(2) == ["train", "test"]
    assert scene_splits(12) == ["train"] * 9 + ["val"] + ["test"] * 2


@pytest.mark.parametrize("argv,match", [
    (["--views", "3"], "--views must be between"),
    (["--scenes", "0"], "--scenes must be between"),
    (["--resolution", "4"], "resolution must be between"),
    (["--resolution", "abc"], "resolution must be"),
    (["--holdout-every", "1"], "--holdout-every"),
    (["--fov-range", "70,50"], "exceeds its max"),
    (["--fov-range", "5,50"], "field of view range"),
    (["--engine", "FOO"], "unknown engine"),
    (["--shard", "2/2"], "shard"),
    (["--samples", "0"], "--samples"),
    (["--seed", "-1"], "--seed"),
    (["--denoise", "--engine", "BLENDER_WORKBENCH"], "--denoise is a Cycles option"),
])
def test_bad_arguments_are_one_line_errors_with_nothing_written(tmp_path, capsys, argv, match):
    out = tmp_path / "caps"
    assert main(["make-captures", "--out", str(out), *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and match in err[0], err
    assert not out.exists()


def test_refuses_a_folder_holding_other_files(tmp_path, capsys, bpy_empty):
    out = tmp_path / "caps"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["make-captures", "--out", str(out), "--scenes", "1", "--views", "4", "--resolution", "8"]) == 2
    assert "not empty" in capsys.readouterr().err and sorted(p.name for p in out.iterdir()) == ["notes.txt"]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """2 scenes x 6 views at 24 px, Cycles at 2 samples (a few seconds)."""
    import bpy  # noqa: F401

    out = tmp_path_factory.mktemp("caps") / "tiny"
    assert main(["make-captures", "--scenes", "2", "--views", "6", "--resolution", "24", "--samples", "2",
                 "--seed", "3", "--out", str(out)]) == 0
    return out


def test_tiny_capture_render_is_a_valid_dataset_with_a_scene_background(tiny):
    from blender_mrvm.datasets import format as F
    from blender_mrvm.datasets.loaders import load_dataset

    assert F.read_split(tiny, "train") == ["captures/scene_000003"]
    assert F.read_split(tiny, "test") == ["captures/scene_000004"]  # a held-out scene
    (scene,) = load_dataset(tiny, "test")
    assert len(scene) == 6 and scene.images.shape == (6, 24, 24, 3) and scene.background == "scene"
    meta = json.loads((tiny / "captures" / "scene_000004" / "meta.json").read_text())
    assert meta["complete"] and meta["background"] == "scene"
    lo, hi = np.array(meta["bbox"])
    olo, ohi = np.array(meta["object_bbox"])
    assert np.allclose(scene.bbox[0], lo) and np.all(lo <= olo) and np.all(ohi < hi)  # models clip to the room
    assert olo[2] == pytest.approx(0.0, abs=1e-9) == lo[2]  # the object stands on the floor
    for c in scene.c2w:
        assert np.all(lo < c[:3, 3]) and np.all(c[:3, 3] < hi)  # every camera inside the room
    assert (scene.foreground_boxes() == [0, 0, 24, 24]).all()
    # not on white: the room fills the frame; the masks label the object's parts and the room's surfaces
    assert scene.images.mean() < 0.9 and (scene.images > 0.98).all(-1).mean() < 0.5
    ids = {int(i) for i in np.unique(np.stack([F.read_png(p) for p in sorted((tiny / "captures" / "scene_000004" / "mask").glob("*.png"))]))}
    assert {250, 251} <= ids and any(0 < i < 250 for i in ids) and {str(i) for i in ids} <= set(meta["labels"])
    proto = json.loads((tiny / "splits" / "eval_views.json").read_text())
    assert proto["target_views_2"] == [2] and proto["target_inputs_2"] == {"2": [1, 3]}


def test_tiny_capture_poses_reproject_and_paths_are_smooth(tiny):
    from blender_mrvm.datasets import format as F
    from tests.helpers import depth_consistency

    for sid in ("scene_000003", "scene_000004"):
        ov = F.read_object(tiny / "captures" / sid)
        tf = F.read_transforms(tiny / "captures" / sid / "transforms.json")
        assert all(np.allclose(f.c2w_opencv, p, atol=1e-7) for f, p in zip(tf, ov.c2w_opencv))
        # every surface has depth (room + object): neighbouring views must agree wherever both see it
        errs = np.concatenate([depth_consistency(ov, a, a + 1) for a in range(5)] +
                              [depth_consistency(ov, a + 1, a) for a in range(5)])
        # (24 px: bilinear interpolation of planar depth across the floor costs ~2e-3 of relative error)
        assert errs.size > 500 and np.median(errs) < 5e-3, np.median(errs)
        shifted = F.ObjectViews(ov.path, ov.meta, ov.intrinsics, [p.copy() for p in ov.c2w_opencv], ov.indices,
                                ov.intrinsics_per_view)
        shifted.c2w_opencv[1][:3, 3] += 0.03 * np.linalg.norm(ov.c2w_opencv[1][:3, 3])  # a 3 % pose error
        assert np.median(depth_consistency(shifted, 0, 1)) > 4 * np.median(errs)  # ... would show
        c = np.stack([p[:3, 3] for p in ov.c2w_opencv])
        step = np.linalg.norm(np.diff(c, axis=0), axis=1)
        assert step.max() < 2.2 * step.mean()


def test_more_or_fewer_scenes_on_a_set_give_the_splits_of_a_fresh_run(tiny, tmp_path, bpy_empty):
    """Raising --scenes on an existing set re-labels the kept scenes' splits as a fresh run of that many assigns
    them (a kept test scene had stayed test: 3 test scenes of 10 where a fresh run has 2); lowering it lists only
    the run's scenes."""
    import shutil

    from blender_mrvm.datasets import format as F
    from blender_mrvm.scene.capture_scenes import scene_splits

    out = tmp_path / "grown"
    shutil.copytree(tiny, out)
    base = ["make-captures", "--views", "6", "--resolution", "24", "--samples", "2", "--seed", "3", "--out", str(out)]
    assert main([*base, "--scenes", "3"]) == 0
    want = dict(zip(["captures/scene_000003", "captures/scene_000004", "captures/scene_000005"], scene_splits(3)))
    assert want["captures/scene_000004"] == "train"  # test among 2 scenes, train among 3
    for split in ("train", "val", "test"):
        assert F.read_split(out, split) == [k for k, v in want.items() if v == split], split
    for key, split in want.items():
        assert json.loads((out / key / "meta.json").read_text())["split"] == split
    assert main([*base, "--scenes", "1"]) == 0  # nothing rendered; scenes 4 and 5 are not this run's
    assert F.read_split(out, "train") == ["captures/scene_000003"]
    assert F.read_split(out, "test") == [] and F.read_split(out, "val") == []


def test_capture_seeds_are_deterministic(tiny, tmp_path, bpy_empty):
    """The same seed renders the same scene (cameras, room, lights, images); the next seed another one."""
    from blender_mrvm.datasets import format as F

    out = tmp_path / "again"
    assert main(["make-captures", "--scenes", "1", "--views", "6", "--resolution", "24", "--samples", "2",
                 "--seed", "4", "--out", str(out)]) == 0
    a, b = tiny / "captures" / "scene_000004", out / "captures" / "scene_000004"
    ma, mb = (json.loads((d / "meta.json").read_text()) for d in (a, b))
    for k in ("path", "room", "lights", "subject", "bbox", "intrinsics"):
        assert ma[k] == mb[k], k
    for v in range(6):
        assert (a / "pose" / f"{v:06d}.txt").read_text() == (b / "pose" / f"{v:06d}.txt").read_text()
        assert np.array_equal(F.read_png(a / "rgb" / f"{v:06d}.png"), F.read_png(b / "rgb" / f"{v:06d}.png"))
    m3 = json.loads((tiny / "captures" / "scene_000003" / "meta.json").read_text())
    assert m3["path"] != ma["path"] and m3["subject"] != ma["subject"]


def test_denoise_renders_the_same_scene_without_the_sampling_noise(tiny, tmp_path, bpy_empty):
    """--denoise: the same cameras and room, the speckle of 2 samples a pixel smoothed away (OpenImageDenoise)."""
    from blender_mrvm.datasets import format as F

    out = tmp_path / "clean"
    assert main(["make-captures", "--scenes", "1", "--views", "6", "--resolution", "24", "--samples", "2",
                 "--seed", "4", "--denoise", "--out", str(out)]) == 0
    a, b = tiny / "captures" / "scene_000004", out / "captures" / "scene_000004"
    mb = json.loads((b / "meta.json").read_text())
    assert mb["render"]["denoise"] == "OpenImageDenoise" and mb["path"] == json.loads((a / "meta.json").read_text())["path"]

    def speckle(img):  # mean absolute Laplacian: pixel-to-pixel noise
        x = img.astype(np.float32).mean(-1)
        return np.abs(4 * x[1:-1, 1:-1] - x[:-2, 1:-1] - x[2:, 1:-1] - x[1:-1, :-2] - x[1:-1, 2:]).mean()

    noisy = [speckle(F.read_png(a / "rgb" / f"{v:06d}.png")) for v in range(6)]
    clean = [speckle(F.read_png(b / "rgb" / f"{v:06d}.png")) for v in range(6)]
    assert all(c < 0.7 * n for c, n in zip(clean, noisy)), (clean, noisy)
    # the scene is the same: the mean colour of each view barely moves
    for v in range(6):
        ia, ib = (F.read_png(d / "rgb" / f"{v:06d}.png").astype(np.float32) for d in (a, b))
        assert abs(ia.mean() - ib.mean()) < 8


def test_eval_scores_each_held_out_view_from_its_neighbours(tiny):
    """eval's per-target protocol: the model gets the target's neighbours; the nearest-photo baseline is one of them."""
    import torch

    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.training.evaluate import evaluate, protocol_target_inputs, protocol_views

    class Stub(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.calls = []

        def synthesize(self, images, c2w, intr, bbox, tc2w, tintr, chunk=None, **_skipping):
            self.calls.append([tuple(np.round(p[:3, 3], 6)) for p in c2w])
            return {"color": torch.from_numpy(np.asarray(images).mean(0)), "acc": torch.ones(images.shape[1:3])}

    scenes = load_dataset(tiny, "train")
    inputs, targets, _ = protocol_views(tiny, 2)
    per = protocol_target_inputs(tiny, 2)
    assert per == {2: [1, 3]} and targets == [2] and inputs == [1, 3]
    model = Stub()
    gen = evaluate(model, scenes, inputs, target_views=targets, target_inputs=per)
    try:
        while True:
            next(gen)
    except StopIteration as stop:
        report = stop.value
    s = scenes[0]
    assert model.calls == [[tuple(np.round(s.c2w[i][:3, 3], 6)) for i in (1, 3)]]
    assert report["overall"]["n"] == 1 and report["protocol"]["input_views"] == "per target"
    assert report["overall"]["baseline_nearest"]["psnr"] is not None
    # a room's masks hold every pixel: eval.md said 'IoU of opacity with the mask 1.000', a figure of nothing
    assert s.masks is not None and s.masks[2].all() and "alpha" not in report["overall"]
    blend = np.mean([s.images[1], s.images[3]], 0)  # the two neighbours' pixel-wise mean, as the stub answers
    assert report["overall"]["baseline_blend"]["psnr"] == pytest.approx(report["overall"]["psnr"], abs=1e-4)
    assert report["overall"]["baseline_blend"]["psnr"] == pytest.approx(
        -10 * np.log10(((blend - s.images[2]) ** 2).mean()), abs=1e-3)


def test_training_on_captures_draws_the_targets_nearest_views_as_references(tiny):
    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.models.base import normalized_scene
    from blender_mrvm.synthesis import nearest_views
    from blender_mrvm.training.config import TrainConfig
    from blender_mrvm.training.trainer import RayBatcher

    scenes = load_dataset(tiny, "train")
    b = RayBatcher(scenes, TrainConfig(min_ref_views=2, max_ref_views=2, rays_per_object=8), 0.05, seed=0)
    s = scenes[0]
    sc = normalized_scene(s.bbox[0], s.bbox[1], 0.05)
    centres = np.stack([sc.pose(p)[:3, 3] for p in s.c2w])
    centre = 0.5 * (s.bbox[0] + s.bbox[1])
    for _ in range(10):
        d = b.draw(False)
        # cameras are inside the room's box: every ray starts at the target camera's centre
        tgt = int(np.argmin(np.linalg.norm(centres - d["rays"].origins[0].numpy(), axis=1)))
        assert np.allclose(d["rays"].origins.numpy(), centres[tgt], atol=1e-9)
        refs = sorted(int(np.argmin(np.linalg.norm(centres - np.linalg.inv(w)[:3, 3], axis=1)))
                      for w in d["cams"].w2c.numpy())
        others = [v for v in range(len(s)) if v != tgt]
        assert refs == sorted(others[i] for i in nearest_views([s.c2w[v] for v in others], s.c2w[tgt], centre, 2))


# --------------------------------------------------------------------------------------------
# Runs: one at a time in a scene, Ctrl-C between views, resume per view
# --------------------------------------------------------------------------------------------

SMALL = ["--scenes", "1", "--views", "6", "--resolution", "16", "--samples", "1", "--seed", "7"]
"""One scene of 6 views at 16 px, Cycles at 1 sample (about a second)."""
SCENE = "captures/scene_000007"


def _on_view(monkeypatch, view: int, action) -> None:
    """Run ``action()`` while view ``view`` of a scene renders (inside Cycles' render, as a signal or a second run
    arrives), once."""
    from blender_mrvm.scene import capture_scenes as CS

    render = CS._CaptureSession.render_colour
    calls = []

    def render_colour(self, box):
        calls.append(1)
        if len(calls) == view + 1:
            action()
        return render(self, box)

    monkeypatch.setattr(CS._CaptureSession, "render_colour", render_colour)


def _files(scene_dir):
    """Identity of each view's files (a file written again is a new inode)."""
    return {p.relative_to(scene_dir).as_posix(): (p.stat().st_ino, p.stat().st_mtime_ns)
            for d in ("rgb", "depth", "normal", "mask", "pose") for p in (scene_dir / d).iterdir()
            if not p.name.startswith(".")}


def test_a_second_run_into_a_scene_being_rendered_is_refused(tmp_path, capsys, monkeypatch, bpy_empty):
    """A second make-captures reaching the scene another one renders is refused in one line and touches nothing; the
    first finishes whole. (It removed the first one's unfinished scene, which then died with 'cannot write the dataset
    files'.)"""
    from blender_mrvm.datasets import format as F
    from blender_mrvm.scene.render import view_intact

    out = tmp_path / "caps"
    second = {}

    def second_run():
        capsys.readouterr()
        second["rc"] = main(["make-captures", *SMALL, "--out", str(out)])
        second["err"] = capsys.readouterr().err

    _on_view(monkeypatch, 2, second_run)
    assert main(["make-captures", *SMALL, "--out", str(out)]) == 0
    errors = [line for line in second["err"].splitlines() if line.startswith("error:")]
    assert second["rc"] == 2 and len(errors) == 1 and "in use by another process" in errors[0], second["err"]
    scene = out / SCENE
    meta = json.loads((scene / "meta.json").read_text())
    assert meta["complete"] and all(view_intact(scene, v) for v in range(6))
    assert F.read_split(out, "train") == [SCENE] and not (scene / ".lock").exists()


def test_ctrl_c_stops_after_the_view_in_flight_and_keeps_the_finished_ones(tmp_path, capsys, monkeypatch, bpy_empty):
    """SIGINT to a headless make-captures while Cycles renders: exit 130 and one line after the view in flight is
    written (Blender swallowed the KeyboardInterrupt in Cycles' callback, printed its traceback, and the run went on
    to the end with exit 0)."""
    import signal

    from blender_mrvm.scene.render import view_intact

    def ctrl_c():
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:  # raised inside Cycles' Python callback, Blender catches and prints it
            pass

    _on_view(monkeypatch, 2, ctrl_c)
    out = tmp_path / "caps"
    before = signal.getsignal(signal.SIGINT)  # (Python's, or SIG_IGN under nohup or a background shell)
    assert main(["make-captures", *SMALL, "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: interrupted; the views finished so far are kept; the same command goes on from them"]
    scene = out / SCENE
    assert sorted(p.name for p in (scene / "pose").iterdir()) == [f"{v:06d}.txt" for v in range(3)]
    assert all(view_intact(scene, v) for v in range(3))  # the view in flight (2) is written too
    assert not json.loads((scene / "meta.json").read_text())["complete"]
    assert not list(scene.rglob(".*")), "no lock or temporary files left behind"
    assert signal.getsignal(signal.SIGINT) is before  # Ctrl-C is handled as before the run again


def test_a_rerun_after_kill_keeps_the_finished_views_of_the_same_scene(tmp_path, capsys, bpy_empty):
    """A scene a killed run left unfinished resumes at its first missing view when it is the same scene (its
    meta.json but 'complete' and 'split'); the killed run's lock and temporary files are swept. (It was rendered again
    from view 0.) A scene built otherwise (another version's room, path, ...) is rendered again whole."""
    from blender_mrvm.datasets.loaders import load_dataset
    from blender_mrvm.scene.render import view_intact

    out = tmp_path / "caps"
    args = ["make-captures", *SMALL, "--out", str(out)]
    assert main(args) == 0
    scene = out / SCENE

    def killed_after(n):  # what kill -9 during view n leaves: views before it, a lock, temporaries, no records
        meta = json.loads((scene / "meta.json").read_text())
        (scene / "meta.json").write_text(json.dumps({**meta, "complete": False}))
        for v in range(n, 6):
            for d, ext in (("rgb", "png"), ("depth", "exr"), ("normal", "exr"), ("mask", "png"), ("pose", "txt")):
                (scene / d / f"{v:06d}.{ext}").unlink()
        for name in ("transforms.json", "intrinsics.txt"):
            (scene / name).unlink()
        (scene / ".lock").write_text("999999\n")
        (scene / "rgb" / f".{n:06d}.png.999999.3.png").write_bytes(b"\x89PNG half")
        (scene / ".transforms.json.k2j4x.json").write_text("{")
        return meta

    meta = killed_after(4)
    kept = _files(scene)
    capsys.readouterr()
    assert main(args) == 0
    assert "2 views rendered, 4 already done" in capsys.readouterr().out
    now = _files(scene)
    assert all(now[k] == v for k, v in kept.items()), "a finished view was rendered again"
    assert all(view_intact(scene, v) for v in range(6)) and json.loads((scene / "meta.json").read_text())["complete"]
    assert not list(scene.rglob(".*")), "the killed run's lock and temporaries are swept"
    (loaded,) = load_dataset(out, "train")
    assert len(loaded) == 6

    meta = killed_after(3)
    moved = {**meta["path"], "distance": meta["path"]["distance"] * 1.1}  # the views of another camera path
    (scene / "meta.json").write_text(json.dumps({**meta, "complete": False, "path": moved}))
    kept = _files(scene)
    capsys.readouterr()
    assert main(args) == 0
    assert "6 views rendered, 0 already done" in capsys.readouterr().out
    now = _files(scene)
    assert all(now[k] != v for k, v in kept.items())
    assert json.loads((scene / "meta.json").read_text())["path"] == meta["path"]
