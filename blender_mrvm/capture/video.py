"""Frames of a video for pose recovery: a phone's orbit around an object is a video as often as a folder of photos.

:func:`extract_frames` decodes the video once (PyAV, which carries its own FFmpeg) and keeps ``count`` frames spread
evenly over its duration: in each of ``count`` equal spans of time, the sharpest frame (the variance of a Laplacian
of a quarter-size grey image; a frame blurred by the hand's motion has less of it). Frames are written as JPEG
(quality 95) with their stored pixels, as a photo's are read; the video's display rotation (a phone held upright
stores its frames turned and says so in the file) gives each frame's up in its camera's axes, as a photo's EXIF
orientation does (:func:`capture.sfm.photo_ups`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..progress import Progress, ProgressGen

VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts", ".m2ts", ".3gp", ".3g2", ".mpg", ".mpeg",
                    ".wmv", ".flv", ".ogv", ".mxf", ".qt")
"""Video files recover-poses takes instead of a folder of photos (PyAV reads them all; .mpg and the rest after
.3gp were refused as 'neither a folder of photos nor a video' before the video review)."""


def is_video(path: Path) -> bool:
    return Path(path).is_file() and Path(path).suffix.lower() in VIDEO_EXTENSIONS


def up_from_rotation(degrees: float) -> tuple[float, float, float]:
    """A frame's up in its camera's axes (OpenCV: x right, y down) from the video's display rotation, in degrees
    counter-clockwise as FFmpeg's display matrix gives it (a phone held upright: -90, the frame turned a quarter
    clockwise to be shown, so its left edge is up)."""
    quarter = int(round(float(degrees) / 90.0)) % 4
    return {0: (0.0, -1.0, 0.0), 1: (1.0, 0.0, 0.0), 2: (0.0, 1.0, 0.0), 3: (-1.0, 0.0, 0.0)}[quarter]


def _sharpness(grey: np.ndarray) -> float:
    """Variance of the 4-neighbour Laplacian of a quarter-size copy (motion blur lowers it)."""
    g = grey[::4, ::4].astype(np.float32) if min(grey.shape) >= 64 else grey.astype(np.float32)
    lap = 4 * g[1:-1, 1:-1] - g[:-2, 1:-1] - g[2:, 1:-1] - g[1:-1, :-2] - g[1:-1, 2:]
    return float(lap.var()) if lap.size else 0.0


CANDIDATES_PER_FRAME = 4
"""Spans of a video searched per frame kept: each span's sharpest frame is a candidate, and candidates of a paused
camera (:data:`STILL_LEVEL`) are dropped before the frames are chosen from the rest."""

STILL_LEVEL = 1.0
"""Mean absolute difference (grey levels, of copies about 64 pixels wide) under which a candidate frame shows the
view of the one before it: the camera paused. A paused stretch took frames of one view in proportion to its time
(a video held still for its first and last seconds gave 3 copies of each end's view of 12 frames, the moving part
sampled 30 degrees apart, and the mapping failed with 'move the camera between photos')."""


def _thumbnail(grey: np.ndarray) -> np.ndarray:
    """Block means of ``grey`` about 64 pixels along its longer side (noise and a hand's jitter average out)."""
    h, w = grey.shape
    k = max(1, max(h, w) // 64)
    g = grey[:h // k * k, :w // k * k].astype(np.float32)
    return g.reshape(h // k, k, w // k, k).mean(axis=(1, 3))


def _av_error(e: Exception) -> str:
    """FFmpeg's error in words (it said '[Errno 1094995529] Invalid data found when processing input: path')."""
    import av

    if isinstance(e, getattr(av, "InvalidDataError", ())) or "Invalid data" in str(e):
        return "the file is damaged or not a whole video (cut short while it was copied?)"
    text = str(e).splitlines()[0] if str(e) else type(e).__name__
    return text.split("] ", 1)[1] if text.startswith("[Errno") and "] " in text else text


def extract_frames(video: Path, out_dir: Path, count: int) -> ProgressGen:
    """Write ``count`` frames of ``video`` to ``out_dir`` as frame_000001.jpg, ... spread over it: the sharpest frame
    of each of ``CANDIDATES_PER_FRAME * count`` equal spans of time is a candidate; candidates that show the view of
    the one before (a paused camera: :data:`STILL_LEVEL`) are dropped, the sharpest of each run kept; the rest are
    split into ``count`` groups in order and each group's sharpest kept (without a pause: the sharpest frame of each
    of ``count`` equal spans). A progress generator over the decoded frames; returns (names, info): info holds the
    video's frame rate, duration, size, display rotation (every frame's up: :func:`up_from_rotation`), the kept
    frames' times and the candidates dropped as a paused camera's."""
    try:
        import av
    except ImportError:
        raise InputError(f"{video} is a video; reading it needs PyAV (pip install av into the Python that runs "
                         "this), or extract its frames into a folder first "
                         f"(ffmpeg -i '{Path(video).name}' -vf fps=2 frames/%04d.jpg)") from None
    from PIL import Image

    video, out_dir = Path(video), Path(out_dir)
    try:
        container = av.open(str(video))
    except (av.FFmpegError, OSError) as e:
        raise InputError(f"cannot read video {video}: {_av_error(e)}") from None
    spans = CANDIDATES_PER_FRAME * count
    try:
        if not container.streams.video:
            raise InputError(f"cannot read video {video}: it holds no video stream (only sound?)")
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        tb = float(stream.time_base) if stream.time_base else 0.0
        duration = (stream.duration * tb if stream.duration and tb else
                    (container.duration / 1e6 if container.duration else 0.0))
        total = stream.frames or 0
        rate = float(stream.average_rate) if stream.average_rate else 0.0
        if not duration and total and rate:
            duration = total / rate
        if duration <= 0:
            raise InputError(f"cannot read video {video}: its duration is unknown or zero (a still image, or a "
                             "recording that holds no frames?)")
        start = (stream.start_time * tb) if stream.start_time is not None and tb else 0.0
        out_dir.mkdir(parents=True, exist_ok=True)
        kept: dict[int, tuple[float, float, np.ndarray]] = {}  # span -> (sharpness, time, thumbnail) of its candidate
        held: list = []  # the current span's sharpest frame so far: [span, sharpness, time, rgb, grey] (one in memory)
        size = (0, 0)

        def flush() -> None:
            span, sharp, t, rgb, grey = held
            if span not in kept or sharp > kept[span][0]:
                Image.fromarray(rgb).save(out_dir / f"span_{span:06d}.jpg", "JPEG", quality=95)
                kept[span] = (sharp, t, _thumbnail(grey))

        rotation = 0.0
        seen, last_t, damaged = 0, 0.0, None
        expected = total or int(duration * rate) or 0
        try:
            for frame in container.decode(stream):
                seen += 1
                t = (frame.pts * tb - start) if frame.pts is not None and tb else (seen - 1) / (rate or 1.0)
                last_t = max(last_t, t)
                span = min(spans - 1, max(0, int(t / duration * spans)))
                rotation = float(getattr(frame, "rotation", 0) or 0)
                size = (frame.width, frame.height)
                grey = frame.to_ndarray(format="gray")
                sharp = _sharpness(grey)
                if held and held[0] != span:
                    flush()
                    held.clear()
                if not held or sharp > held[1]:
                    held[:] = [span, sharp, t, frame.to_ndarray(format="rgb24"), grey]
                if seen % 10 == 0:
                    yield Progress(min(seen, expected) if expected else 0, expected,
                                   f"reading frames of {video.name}: {seen}" + (f" of {expected}" if expected else ""))
        except av.FFmpegError as e:
            damaged = e
        if held:
            flush()
            held.clear()
    finally:
        container.close()
    # a file cut short (a copy stopped before its end) decodes its first part only: its frames would all come from
    # there (the capture of a third of an orbit, exit 0)
    step = 1.0 / rate if rate else 0.0
    if seen and last_t + step < 0.9 * duration:
        raise InputError(f"video {video} stops at {last_t + step:.1f} s of its {duration:.1f} s: the file is damaged "
                         "or cut short (copied before it was complete?); copy it again, or cut it to its readable part")
    if damaged is not None and not kept:
        raise InputError(f"cannot read video {video}: {_av_error(damaged)}")
    candidates = sorted(kept)
    runs: list[int] = []  # candidates left, one of each run that shows one view (the sharpest)
    anchor = None  # the run's first candidate, which the next ones are compared with (a slow pan is not one view)
    for span in candidates:
        if anchor is not None and float(np.abs(kept[span][2] - kept[anchor][2]).mean()) < STILL_LEVEL:
            if kept[span][0] > kept[runs[-1]][0]:
                runs[-1] = span
            continue
        runs.append(span)
        anchor = span
    chosen = runs if len(runs) <= count else [max(g, key=lambda s: kept[s][0])
                                             for g in np.array_split(np.array(runs), count)]
    chosen = [int(s) for s in chosen]
    for span in set(candidates) - set(chosen):
        (out_dir / f"span_{span:06d}.jpg").unlink(missing_ok=True)
    if len(chosen) < 3:
        views = (f" that show {len(runs)} view(s): the camera hardly moved (film while walking round the subject; "
                 "frames of one view are kept once)") if len(runs) < len(candidates) else ""
        raise InputError(f"video {video} gave {len(candidates)} frame(s) (of {seen} decoded){views}; pose recovery "
                         "needs at least 3")
    names, times = [], []
    for k, span in enumerate(chosen):
        name = f"frame_{k + 1:06d}.jpg"
        (out_dir / f"span_{span:06d}.jpg").replace(out_dir / name)
        names.append(name)
        times.append(round(kept[span][1], 4))
    info = {"path": str(video.resolve()), "frames_decoded": seen, "frames_asked": count, "frames_kept": len(names),
            "fps": rate,
            "duration_s": round(duration, 4), "width": size[0], "height": size[1],
            "display_rotation_deg": rotation, "times_s": times,
            "still_frames_dropped": len(candidates) - len(runs)}
    return names, info
