"""recover-poses on videos as a phone user meets them (session review): a camera paused at the ends, a file cut short
by an interrupted copy, FFmpeg's error numbers, video kinds by extension, and spacing advice fit for a video.

The footage is made here: views of a smoothed noise texture, each a crop further along it (a camera moving sideways);
no pycolmap run is needed for what these tests check (the frames chosen and the messages)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")

from blender_mrvm.capture import sfm  # noqa: E402
from blender_mrvm.capture.config import CaptureConfig  # noqa: E402
from blender_mrvm.capture.video import extract_frames, is_video  # noqa: E402
from blender_mrvm.errors import InputError  # noqa: E402
from blender_mrvm.progress import run_to_end  # noqa: E402

W, H = 160, 120


def _views(n: int, step: int = 12) -> list[np.ndarray]:
    """``n`` views of one textured plane, ``step`` pixels apart (RGB, H x W)."""
    rng = np.random.default_rng(3)
    big = rng.random((H // 4 + 2, (W + n * step) // 4 + 2, 3))
    from PIL import Image

    tex = np.asarray(Image.fromarray((big * 255).astype(np.uint8)).resize(((big.shape[1]) * 4, big.shape[0] * 4),
                                                                          Image.BICUBIC))
    return [np.ascontiguousarray(tex[:H, i * step:i * step + W]) for i in range(n)]


def _write(path: Path, frames, fps: int = 8, codec: str = "libx264", options: dict | None = None) -> Path:
    import av

    c = av.open(str(path), "w", options=options or {})
    s = c.add_stream(codec, rate=fps)
    s.height, s.width = frames[0].shape[:2]
    s.pix_fmt = "yuv420p"
    for f in frames:
        for pkt in s.encode(av.VideoFrame.from_ndarray(f, format="rgb24")):
            c.mux(pkt)
    for pkt in s.encode():
        c.mux(pkt)
    c.close()
    return path


def _extract(video: Path, out: Path, count: int):
    return run_to_end(extract_frames(video, out, count))


def test_a_paused_camera_does_not_take_the_frames(tmp_path):
    """A phone video held still for its first and last 1.5 s round 3 s of motion (12 views, each two frames): 12
    frames spread over time took 3 copies of each end's view and sampled the motion at every other view (the mapping
    then failed with 'move the camera between photos'). The paused stretches count once: one frame of each view."""
    views = _views(12)
    seq, view_of = [], []
    for v in [0] * 12 + [i for i in range(12) for _ in range(2)] + [11] * 12:
        seq.append(views[v])
        view_of.append(v)
    video = _write(tmp_path / "orbit with pauses.mp4", seq)
    names, info = _extract(video, tmp_path / "frames", 12)
    kept = [view_of[round(t * 8)] for t in info["times_s"]]
    assert kept == list(range(12)), kept
    assert len(names) == 12 and info["still_frames_dropped"] > 0 and info["frames_asked"] == 12
    assert sorted(p.name for p in (tmp_path / "frames").iterdir()) == names  # no candidate left behind


def test_a_still_video_is_told_in_words(tmp_path):
    video = _write(tmp_path / "tripod.mp4", [_views(1)[0]] * 24)
    with pytest.raises(InputError, match=r"gave \d+ frame\(s\) .*show 1 view\(s\): the camera hardly moved"):
        _extract(video, tmp_path / "frames", 12)


def test_a_video_cut_short_is_an_error_not_a_third_of_a_capture(tmp_path, capsys):
    """A copy stopped before its end (a 'fast start' MP4, index first, so its first part decodes): recover-poses
    made a capture of the frames before the cut (5 of 12, from the first 40 % of the orbit) and exited 0 without a
    word. It is one error line now, exit 2, and no output folder is left."""
    from blender_mrvm.cli import main

    full = _write(tmp_path / "full.mp4", [v for v in _views(12) for _ in range(2)], options={"movflags": "faststart"})
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(full.read_bytes()[:full.stat().st_size * 2 // 3])
    with pytest.raises(InputError, match=r"stops at .* s of its 3\.0 s: the file is damaged or cut short"):
        _extract(cut, tmp_path / "frames", 12)
    capsys.readouterr()
    assert main(["recover-poses", "--images", str(cut), "--out", str(tmp_path / "cap"), "--frames", "12"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("error: video ") and "cut short" in err[0], err
    assert not (tmp_path / "cap").exists()


def test_an_unreadable_video_is_said_in_words(tmp_path):
    """FFmpeg's error came through as '[Errno 1094995529] Invalid data found when processing input: <path>'."""
    full = _write(tmp_path / "full.mp4", _views(12))  # index at the end: half the file has none
    cut = tmp_path / "half.mp4"
    cut.write_bytes(full.read_bytes()[:full.stat().st_size // 2])
    with pytest.raises(InputError) as e:
        _extract(cut, tmp_path / "frames", 12)
    assert "Errno" not in str(e.value) and "damaged or not a whole video" in str(e.value)


def test_an_mpeg_file_is_a_video(tmp_path):
    """.mpg (a camcorder's, a DVD's) was refused as 'neither a folder of photos nor a video'; PyAV reads it."""
    video = _write(tmp_path / "orbit.mpg", _views(6), fps=25, codec="mpeg2video")
    assert is_video(video)
    names, info = _extract(video, tmp_path / "frames", 6)
    assert len(names) == 6 and (info["width"], info["height"]) == (W, H)


def test_spacing_advice_for_a_video_names_frames(tmp_path, monkeypatch):
    """'take one every 10-15 degrees' is a photographer's advice; a video's frames are as far apart as --frames
    spreads them: the error and the warning say so."""
    video = _write(tmp_path / "orbit.mp4", _views(4))

    def failing(images_dir, out_dir, cfg, verbose):
        raise InputError("mapping found no image pair to start from (photos taken more than about 20 degrees apart "
                         "round an object often stop here: take one every 10-15 degrees)")
        yield

    monkeypatch.setattr(sfm, "_recover_poses", failing)
    with pytest.raises(InputError, match=r"10-15 degrees\); these are a video's frames: keep more of them "
                                         r"\(--frames 40, now 20"):
        run_to_end(sfm.recover_poses(video, tmp_path / "out", CaptureConfig(video_frames=20)))
    suspect = {"pairs": 20, "median_disagreement_deg": 9.5, "threshold_deg": 1.5, "suspect": True,
               "photo_spacing_deg": 31.0}
    res = sfm.CaptureResult(tmp_path, ["a"], 1, [], "exhaustive", {}, 0, 0.0, pose_check=suspect,
                            video={"frames_asked": 12, "frames_kept": 12})
    assert res.warnings[0].endswith("these are a video's frames: keep more of them (--frames 24, now 12; in the "
                                    "panel: Video frames), or film the orbit more slowly")
    photos = sfm.CaptureResult(tmp_path, ["a"], 1, [], "exhaustive", {}, 0, 0.0, pose_check=suspect)
    assert "video" not in photos.warnings[0]


class _Stop(Exception):
    pass


def test_a_resumed_video_run_reuses_its_frames_unless_the_video_changed(tmp_path, monkeypatch):
    """A video run stopped after its frames (killed in feature extraction) is continued without --force: it decoded
    the whole video again (minutes for a phone's 4K orbit) though the frames were on disk. They are reused now, with
    the video's record; a video changed since (another size or time) is extracted afresh."""
    import pycolmap

    from blender_mrvm.capture import video as video_mod

    video = _write(tmp_path / "orbit.mp4", _views(8))
    out, cfg = tmp_path / "cap", CaptureConfig(video_frames=6, num_threads=1)

    def stop(*a, **k):
        raise _Stop("killed in feature extraction")

    monkeypatch.setattr(pycolmap, "extract_features", stop)
    with pytest.raises(_Stop):
        run_to_end(sfm.recover_poses(video, out, cfg))
    first = {p.name: p.read_bytes() for p in (out / "frames").glob("*.jpg")}
    assert len(first) == 6
    calls = []

    def counted(*a, **k):
        calls.append(a)
        return (yield from extract_frames(*a, **k))

    monkeypatch.setattr(sfm, "extract_frames", counted)
    with pytest.raises(_Stop):  # resumed (no --force): the frames are the first run's, not decoded again
        run_to_end(sfm.recover_poses(video, out, cfg))
    assert calls == [] and {p.name: p.read_bytes() for p in (out / "frames").glob("*.jpg")} == first
    _write(video, _views(8, step=5))  # the same name, another video
    with pytest.raises(_Stop):
        run_to_end(sfm.recover_poses(video, out, cfg))
    assert len(calls) == 1 and {p.name: p.read_bytes() for p in (out / "frames").glob("*.jpg")} != first
    assert video_mod.extract_frames is extract_frames


def test_an_error_in_a_pycolmap_stage_is_its_own(tmp_path, monkeypatch, capsys):
    """pycolmap 4.2.1's CancellationToken.is_cancelled is a property: ``token.is_cancelled()`` turned any error a
    stage run in a thread raised (here the disk filling up in feature extraction) into "TypeError: 'bool' object is
    not callable", a traceback. It is the stage's own error now: one line, exit 2."""
    import errno

    import pycolmap

    from blender_mrvm.cli import main

    video = _write(tmp_path / "orbit.mp4", _views(6))

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pycolmap, "extract_features", full)
    assert main(["recover-poses", "--images", str(video), "--out", str(tmp_path / "cap"), "--frames", "6"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("error: ") and "space" in err[0].lower(), err
