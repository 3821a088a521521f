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

VIDEO_EXTENSIONS = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".mts", ".3gp")
"""Video files recover-poses takes instead of a folder of photos."""


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


def extract_frames(video: Path, out_dir: Path, count: int) -> ProgressGen:
    """Write the sharpest frame of each of ``count`` equal spans of ``video`` to ``out_dir`` as frame_000001.jpg,
    ... A progress generator over the decoded frames; returns (names, info): info holds the video's frame rate,
    duration, size, display rotation (every frame's up: :func:`up_from_rotation`) and the kept frames' times."""
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
        raise InputError(f"cannot read video {video}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") \
            from None
    try:
        if not container.streams.video:
            raise InputError(f"cannot read video {video}: it holds no video stream")
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
            raise InputError(f"cannot read video {video}: its duration is unknown or zero")
        start = (stream.start_time * tb) if stream.start_time is not None and tb else 0.0
        out_dir.mkdir(parents=True, exist_ok=True)
        kept: dict[int, tuple[float, float]] = {}  # span -> (sharpness, time) of the frame written for it
        held: list = []  # the current span's sharpest frame so far: [span, sharpness, time, rgb] (one in memory)
        size = (0, 0)

        def flush() -> None:
            span, sharp, t, rgb = held
            if span not in kept or sharp > kept[span][0]:
                Image.fromarray(rgb).save(out_dir / f"span_{span:06d}.jpg", "JPEG", quality=95)
                kept[span] = (sharp, t)

        rotation = 0.0
        seen = 0
        expected = total or int(duration * rate) or 0
        try:
            for frame in container.decode(stream):
                seen += 1
                t = (frame.pts * tb - start) if frame.pts is not None and tb else (seen - 1) / (rate or 1.0)
                span = min(count - 1, max(0, int(t / duration * count)))
                rotation = float(getattr(frame, "rotation", 0) or 0)
                size = (frame.width, frame.height)
                sharp = _sharpness(frame.to_ndarray(format="gray"))
                if held and held[0] != span:
                    flush()
                    held.clear()
                if not held or sharp > held[1]:
                    held[:] = [span, sharp, t, frame.to_ndarray(format="rgb24")]
                if seen % 10 == 0:
                    yield Progress(min(seen, expected) if expected else 0, expected,
                                   f"reading frames of {video.name}: {seen}" + (f" of {expected}" if expected else ""))
        except av.FFmpegError as e:
            if not kept and not held:
                raise InputError(f"cannot read video {video}: {str(e).splitlines()[0]}") from None
            # a damaged tail: keep the frames read before it
        if held:
            flush()
    finally:
        container.close()
    if len(kept) < 3:
        raise InputError(f"video {video} gave {len(kept)} frame(s) (of {seen} decoded); pose recovery needs at "
                         "least 3")
    names, times = [], []
    for k, span in enumerate(sorted(kept)):
        name = f"frame_{k + 1:06d}.jpg"
        (out_dir / f"span_{span:06d}.jpg").replace(out_dir / name)
        names.append(name)
        times.append(round(kept[span][1], 4))
    info = {"path": str(video.resolve()), "frames_decoded": seen, "frames_kept": len(names), "fps": rate,
            "duration_s": round(duration, 4), "width": size[0], "height": size[1],
            "display_rotation_deg": rotation, "times_s": times}
    return names, info
