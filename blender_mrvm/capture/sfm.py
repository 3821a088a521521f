"""Pose recovery with pycolmap: photos folder -> capture folder in our dataset format.

:func:`recover_poses` is a progress generator (see ``progress.py``). Each pycolmap stage runs in a
worker thread (pycolmap releases the GIL), or in a child Python for the stages that work on the
database alone (matching, the focal length from the view graph: a native crash there is an error line,
not the end of this process), and the generator yields a :class:`Progress` every ``poll`` seconds while
it waits, so a Blender modal operator stepping it per timer tick never blocks the UI for longer than
that. Closing the generator (``gen.close()``, Ctrl-C on the CLI) cancels the running stage through
pycolmap's ``CancellationToken`` (or kills the child) and raises nothing further; what was finished
stays in ``<out>/colmap``.

Stages and what they check (each failure is one line naming the problem):

1. scan      fewer than ``required_images`` photos, an unreadable photo, photos of differing size,
             an output folder that already holds files (without ``force``)
2. extract   SIFT, at most ``max_num_features`` per image on images of at most ``max_image_size``;
             the image is upsampled 2x first (first octave -1) only below ``upsample_below`` px; a focal
             length from EXIF that mapping would refuse is dropped (:func:`_drop_bogus_focal_priors`)
3. match     exhaustive, or sequential for numbered frames (``matcher="auto"``); no verified pair
             means the photos do not overlap
4. map       (a shared camera first gets its focal length from the view graph, ``estimate_focal``)
             incremental mapping; the largest model is kept; registering fewer than
             ``min_registered_fraction`` of the photos is an error (the partial model is kept and
             named in the message, ``colmap/report.json`` lists what registered)
5. undistort when the camera model has distortion (SIMPLE_RADIAL, RADIAL, OPENCV): pinhole images
             and intrinsics, per-photo cameras all at one size (:func:`undistort_options`)
6. export    up / centre / scale normalization and the dataset folder (``capture.export``)
"""

from __future__ import annotations

import json
import math
import re
import shutil
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..errors import Cancelled, InputError, OutputError
from ..guards import LOCK_FILE
from ..geometry import cameras as C
from ..progress import Progress, ProgressGen
from . import align
from .check import pair_pose_check, photo_spacing, spacing_advice, spacing_camera, spacing_named
from .check import warning as check_warning
from .config import CONVERTED_EXTENSIONS, IMAGE_EXTENSIONS, CaptureConfig
from .video import VIDEO_EXTENSIONS, extract_frames, is_video, up_from_rotation
from ..datasets.format import colour_pixels, remove_entries
from .export import OUTPUT_ENTRIES, RUN_MARKER, CaptureView, open_photo, photo_rgb8, write_capture

POLL_S = 0.1
FORMAT_VERSION = 1
MIN_MODEL_POINTS = 20
"""A kept model with fewer 3D points is an error: its photos were placed without depth to place them by. 8 photos of a
panorama (one camera turned on the spot: an image warped by K R K^-1) came out as 4-5 placed photos with 0-10 points
and exit 0, no warning (the pose check has no pair in general position to judge); every other set tried kept 40 or
more (2 photos of 320x240; 100 photos of 96x72: 484)."""
# Overall progress: percent reached at the end of each stage.
_STAGE_END = {"scan": 2, "extract": 35, "match": 55, "map": 90, "undistort": 95, "export": 100}


@dataclass
class CaptureResult:
    """What :func:`recover_poses` returns."""

    out_dir: Path
    """The capture folder written."""
    registered: list[str]
    """Photos with a recovered pose, in output order (rgb/000000.png is registered[0])."""
    total: int
    """Photos in the input folder."""
    unregistered: list[str]
    """Photos the mapper could not place."""
    matcher: str
    """The matcher used (exhaustive or sequential)."""
    timings: dict[str, float]
    """Seconds per stage (wall clock)."""
    num_points: int
    """Sparse 3D points written to points.ply."""
    mean_reprojection_error: float
    """Of the kept COLMAP model, pixels."""
    cpu_timings: dict[str, float] = field(default_factory=dict)
    """CPU seconds per stage (this process, all threads); unlike wall time, barely moved by other load."""
    c2w_opencv: list[np.ndarray] = field(default_factory=list)
    """Output poses (normalized world), one per registered photo."""
    intrinsics: list[C.Intrinsics] = field(default_factory=list)
    """Output (undistorted) intrinsics, one per registered photo."""
    pose_check: dict = field(default_factory=dict)
    """The kept model against its photo pairs (:func:`capture.check.pair_pose_check`; ``meta.json``'s)."""
    video: dict = field(default_factory=dict)
    """A video's frames: ``meta.json``'s ``video`` (empty for photos)."""

    @property
    def warnings(self) -> list[str]:
        """What the user should know about the result (one line each)."""
        w = check_warning(self.pose_check)
        if w and self.video:
            w += video_spacing_hint(self.video.get("frames_asked", self.video.get("frames_kept", 0)), w)
        return [w] if w else []

    def summary(self) -> str:
        t = ", ".join(f"{k} {v:.1f}s" for k, v in self.timings.items())
        return (f"registered {len(self.registered)}/{self.total} images, {self.num_points} points, "
                f"reprojection {self.mean_reprojection_error:.2f}px, {self.matcher} matching; {t}")


def _diagnosis(db_path: Path, rec: Any, renamed: dict[str, str], seed: int,
               match_db: Path | None = None) -> tuple[str, bool]:
    """Why a mapping may have left photos out: a clause for its error line ('' when nothing is found), and whether it
    names how far apart the photos are. Photos taken too far apart, or photos that match no other
    (:func:`check.spacing_advice`). The spacing's focal length is the model's (3 photos or more), else the photos'
    EXIF as ``match_db`` (the database as matching left it) holds it. A diagnosis that fails says nothing, so the
    error itself is never lost."""
    try:
        camera = spacing_camera(rec)
        if camera is None and match_db is not None:
            spacing = photo_spacing(match_db, None, seed=seed)
        else:
            spacing = photo_spacing(db_path, camera, seed=seed)
            if camera is None:
                spacing["focal_from"] = "database"  # a calibrated database's prior is not the photos' EXIF
        advice = spacing_advice(spacing, renamed)
    except (ValueError, RuntimeError, OSError):
        return "", False
    return (f": {advice}" if advice else ""), spacing_named(spacing)


def natural_key(name: str) -> list:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


def list_images(images_dir: Path) -> list[str]:
    """Photo file names in ``images_dir`` (not recursive), in natural order."""
    images_dir = Path(images_dir)
    if images_dir.is_file():
        raise InputError(f"{images_dir} is a file, neither a folder of photos nor a video recover-poses reads "
                         f"({', '.join(VIDEO_EXTENSIONS)}); give the folder of photos, or convert the video to one "
                         "of these")
    if not images_dir.is_dir():
        raise InputError(f"image folder {images_dir} does not exist")
    names = [p.name for p in images_dir.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
    return sorted(names, key=natural_key)


def looks_like_frames(names: list[str]) -> bool:
    """True when the names are one prefix + increasing numbers (frames of a video, a burst)."""
    if len(names) < 2:
        return False
    pat = re.compile(r"^(.*?)(\d+)(\D*)$")
    ms = [pat.match(Path(n).stem) for n in names]
    if not all(ms):
        return False
    if len({(m.group(1), m.group(3)) for m in ms}) != 1:
        return False
    nums = [int(m.group(2)) for m in ms]
    return all(b > a for a, b in zip(nums, nums[1:]))


def choose_matcher(cfg: CaptureConfig, names: list[str]) -> str:
    if cfg.matcher != "auto":
        return cfg.matcher
    if len(names) > cfg.exhaustive_max_images and looks_like_frames(names):
        return "sequential"
    return "exhaustive"


def check_images(images_dir: Path, names: list[str], cfg: CaptureConfig) -> tuple[tuple[int, int], list[str]]:
    """Check count, readability, values and sizes; return the common (width, height) and the photos of the transposed
    size (one camera held both ways, the turn baked into the pixels, as photo apps export them), read turned to the
    common size (:func:`readable_photos`). A float photo with values outside [0, 1] (or a 32-bit integer one outside
    0..65535) is refused here, before pycolmap reads it (it clipped it, and the export refused it after mapping)."""
    need = cfg.required_images
    if len(names) < need:
        hint = "" if cfg.allow_pair or len(names) != 2 else " (a stereo pair needs --pair)"
        raise InputError(f"found {len(names)} image(s) in {images_dir}; pose recovery needs at least {need}{hint}"
                         f"{_other_files_hint(images_dir)}")
    if len(names) > 2 and cfg.allow_pair and cfg.min_images > 2:
        pass  # a pair flag with more images simply runs the normal path
    from PIL import UnidentifiedImageError

    if any(Path(n).suffix.lower() in (".heic", ".heif") for n in names):
        _heif_opener(images_dir)
    sizes: dict[tuple[int, int], list[str]] = {}
    for n in names:
        try:
            with open_photo(images_dir / n) as im:
                im.load()
                if im.mode in ("F", "I"):  # their values must be colours: InputError naming the photo otherwise
                    colour_pixels(im, images_dir / n)
                sizes.setdefault(im.size, []).append(n)
        except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as e:
            raise InputError(f"cannot read image {images_dir / n}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from e
    common = max(sizes, key=lambda s: (len(sizes[s]), s[0] >= s[1]))  # the most photos; on a tie, landscape
    turned = sizes.get(common[::-1], []) if common[0] != common[1] else []
    if len(sizes) > 1 + bool(turned):
        odd = [(s, v[0], len(v)) for s, v in sizes.items() if s not in (common, common[::-1])]
        s, example, count = odd[0]
        raise InputError(f"images differ in size: {example} is {s[0]}x{s[1]} but {sizes[common][0]} is "
                         f"{common[0]}x{common[1]} ({sum(c for _, _, c in odd)} of {len(names)} differ); "
                         "use photos of one size (or of one size held both ways)")
    return common, turned


RAW_EXTENSIONS = (".dng", ".cr2", ".cr3", ".nef", ".arw", ".orf", ".rw2", ".raf", ".pef", ".srw")
"""Camera RAW files, which neither pycolmap nor Pillow reads."""


def _other_files_hint(images_dir: Path) -> str:
    """What else a folder with too few photos holds that the user may have meant: videos, camera RAW files."""
    try:
        files = [p for p in Path(images_dir).iterdir() if p.is_file()]
    except OSError:
        return ""
    videos = sorted(p.name for p in files if p.suffix.lower() in VIDEO_EXTENSIONS)
    raws = [p for p in files if p.suffix.lower() in RAW_EXTENSIONS]
    if videos:
        more = ", ..." if len(videos) > 1 else ""
        return (f"; it holds {len(videos)} video(s) ({videos[0]}{more}): to use a video's frames, give the video "
                f"itself (--images {Path(images_dir) / videos[0]}; in the panel, as Photos)")
    if raws:
        return (f"; it holds {len(raws)} camera RAW file(s) ({raws[0].suffix}), which pycolmap cannot read: export "
                "them as JPEG or TIFF")
    return ""


def _heif_opener(images_dir: Path) -> None:
    """Let Pillow open HEIC/HEIF photos (pillow-heif); an InputError saying what to do when it is not installed."""
    try:
        import pillow_heif
    except ImportError:
        raise InputError(f"{images_dir} holds HEIC/HEIF photos (an iPhone's default), which need pillow-heif "
                         "(pip install pillow-heif into the Python that runs this), or export them as JPEG") from None
    pillow_heif.register_heif_opener()


def converted_name(name: str, names: list[str], ext: str = ".jpg") -> str:
    """The name of the copy of a photo pycolmap cannot read as it is: its stem + ``ext`` (.jpg, or .png), or its
    whole name + ``ext`` where that is taken by another photo."""
    stem = Path(name).stem + ext
    taken = {n.lower() for n in names if n != name}
    return stem if stem.lower() not in taken else name + ext


def wide_photo(path: Path) -> bool:
    """Whether a photo is a float or 32-bit integer image (a TIFF's: Pillow's modes F and I). pycolmap reads a float
    image in [0, 1] right, but writes its undistorted copy as a 3-channel float TIFF, which Pillow cannot open (the
    export failed on it), and reads a 32-bit integer one as black; :func:`readable_photos` gives it an 8-bit copy.
    Only the header is read."""
    if path.suffix.lower() not in (".tif", ".tiff"):
        return False
    try:
        with open_photo(path) as im:
            return im.mode in ("F", "I")
    except (OSError, SyntaxError, ValueError):
        return False


def readable_photos(images_dir: Path, names: list[str], work: Path, turned: list[str] = ()) -> ProgressGen:
    """The folder and names pycolmap reads: ``images_dir`` itself when every photo is a format it reads at one size,
    else ``work/photos`` with the other formats (:data:`CONVERTED_EXTENSIONS`) and the ``turned`` photos (of the
    transposed size) converted to JPEG (quality 95, the photo's EXIF kept, so the focal length prior stays; the
    stored pixels, as a JPEG's are read, except that a HEIF's are turned as libheif shows them, and a turned photo
    is turned a quarter counter-clockwise, which :func:`photo_ups` turns its up by), float and 32-bit integer photos
    (:func:`wide_photo`) to 8-bit PNG (lossless: the pixels ``rgb/`` holds of them), and the rest copied. A progress
    generator; returns (folder, names there, {name there: photo's name} of those renamed).

    Every conversion is to 8-bit sRGB (``export.photo_rgb8``: an ICC profile converted); a photo copied as it is
    keeps its profile, which COLMAP's undistortion keeps in the copies it writes (JPEG, PNG, TIFF; pycolmap 4.2),
    so ``rgb/`` is sRGB whether or not the photos were undistorted (``export.write_capture`` converts)."""
    turned = set(turned)
    wide = {n for n in names if wide_photo(images_dir / n)}
    todo = [n for n in names if Path(n).suffix.lower() in CONVERTED_EXTENSIONS or n in turned or n in wide]
    if not todo:
        return images_dir, names, {}
    from PIL import Image

    if any(Path(n).suffix.lower() in (".heic", ".heif") for n in todo):
        _heif_opener(images_dir)
    photos = work / "photos"
    if photos.exists():
        shutil.rmtree(photos)
    photos.mkdir(parents=True)
    out, renamed = [], {}
    for i, n in enumerate(names):
        if n in todo:
            new = converted_name(n, names, ".png" if n in wide else ".jpg")
            with open_photo(images_dir / n) as im:
                exif = im.getexif()
                rgb = Image.fromarray(photo_rgb8(im, images_dir / n))
            if n in turned:
                rgb = rgb.transpose(Image.Transpose.ROTATE_90)  # counter-clockwise: to the common size
            if Path(n).suffix.lower() in (".heic", ".heif"):
                exif[0x0112] = 1  # libheif turned the pixels as the photo is shown (its size as check_images saw)
            if n in wide:
                rgb.save(photos / new, "PNG", compress_level=1, exif=exif.tobytes())
            else:
                rgb.save(photos / new, "JPEG", quality=95, exif=exif.tobytes())  # others: as a JPEG's stored pixels
            renamed[new] = n
            yield Progress(i + 1, len(names), f"{'turning' if n in turned else 'converting'} {n} for pycolmap")
        else:
            new = n
            shutil.copy2(images_dir / n, photos / n)
        out.append(new)
    return photos, out, renamed


# A photo's up in its stored pixels' camera axes (OpenCV: x right, y down) by its EXIF orientation (the turn or
# mirror that shows it upright: 6 turns it 90 degrees clockwise, so its left edge is up; PIL's exif_transpose).
_EXIF_UP = {1: (0, -1, 0), 2: (0, -1, 0), 3: (0, 1, 0), 4: (0, 1, 0), 5: (-1, 0, 0), 6: (-1, 0, 0), 7: (1, 0, 0),
            8: (1, 0, 0)}


def photo_orientation(path: Path) -> int:
    """A photo's EXIF orientation (1 when it has none; HEIF's pixels come turned already)."""
    if path.suffix.lower() in (".heic", ".heif"):
        return 1
    try:
        with open_photo(path) as im:
            value = im.getexif().get(0x0112, 1)
    except (OSError, ValueError, SyntaxError):
        return 1
    return value if value in _EXIF_UP else 1


def photo_ups(images_dir: Path, names: list[str], turned: list[str] = ()) -> tuple[list[np.ndarray], dict[str, int]]:
    """Each photo's up vector in its camera's axes (pycolmap reads the stored pixels, so a phone held upright for a
    portrait photo is a camera turned 90 degrees about its axis; a ``turned`` photo was read turned a quarter
    counter-clockwise, :func:`readable_photos`) and {name: EXIF orientation} of those stored turned."""
    orient = {n: photo_orientation(Path(images_dir) / n) for n in names}
    turned = set(turned)
    ups = []
    for n in names:
        x, y, z = _EXIF_UP[orient[n]]
        ups.append(np.array((y, -x, z) if n in turned else (x, y, z), dtype=np.float64))  # (x, y) -> (y, -x)
    return ups, {n: o for n, o in orient.items() if o != 1}


def _scaled(gen: ProgressGen, end: int):
    """Run a progress generator as the part of the overall 0-100 before ``end``; return what it returns."""
    while True:
        try:
            ev = next(gen)
        except StopIteration as stop:
            return stop.value
        yield Progress(int(end * ev.fraction), 100, ev.message)


_EXPORT_TEMPORARY = re.compile(r"\.(?:intrinsics\.txt|transforms\.json|meta\.json|points\.ply)\.[a-z0-9_]{8}"
                               r"\.(?:txt|json|ply)")
"""The temporary names of the capture folder's files while ``format.atomic_write`` writes them (``tempfile``'s 8
characters): a run killed then left one, and its rerun was refused as a folder holding other files."""


def prepare_output(out_dir: Path, images_dir: Path, force: bool) -> None:
    """Refuse an occupied output folder unless ``force``; with it, remove only what we write. A folder
    holding only an unfinished run of ours (no meta.json, which is written last) is continued without
    ``force``: its ``colmap/`` stays, and :func:`recover_poses` skips the stages it finished with the
    same photos and settings (``colmap/stages.json``), as a resumed render skips finished views."""
    out, img = Path(out_dir).resolve(), Path(images_dir).resolve()
    if out == img or out in img.parents:
        raise OutputError(f"output folder {out_dir} contains the photos; choose another folder")
    if out.exists() and not out.is_dir():
        raise OutputError(f"output {out_dir} exists and is not a folder")
    if out.is_dir():
        if (out / RUN_MARKER).is_file():  # ours, and held (recover_poses): what a killed export was writing is no one's
            for p in out.iterdir():
                if _EXPORT_TEMPORARY.fullmatch(p.name) and p.is_file() and not p.is_symlink():
                    p.unlink(missing_ok=True)
        present = sorted(p.name for p in out.iterdir() if p.name != LOCK_FILE)
        # ours and stopped before meta.json (written last): its marker says so, not names alone (a folder of the
        # user's own frames/, colmap/ or points.ply was wiped as one)
        unfinished = (present and set(present) <= set(OUTPUT_ENTRIES) and "meta.json" not in present
                      and RUN_MARKER in present)
        if present:
            if not force and not unfinished:
                named = [n for n in present if n != RUN_MARKER]
                shown = ", ".join(named[:3]) + (", ..." if len(named) > 3 else "")
                raise OutputError(f"output folder {out_dir} already holds files ({shown}); pass --force (in the panel: "
                                  "Overwrite) to overwrite")
            # a failed or killed run: resume its stages (a video's: with the frames it extracted, _extracted_frames)
            keep = ({"colmap", "frames"} if is_video(images_dir) else {"colmap"}) if unfinished and not force else set()
            remove_entries(out, [e for e in OUTPUT_ENTRIES if e not in keep])
    out.mkdir(parents=True, exist_ok=True)
    (out / RUN_MARKER).write_text("a recover-poses run's output folder\n")


EXTRACTED_LOG = ".extracted.json"
"""In ``frames/``: the video's stamp (:func:`run_stamp`), the frames extracted from it and its ``meta.json`` record.
A resumed run of the same video and settings reads its frames from there: it decoded the whole video again (a
minute or more for a phone's 4K orbit) before the stages it skipped."""


def _extracted_frames(frames_dir: Path, stamp: dict) -> tuple[list[str], dict] | None:
    """(names, video record) of the frames an unfinished run extracted from the video ``stamp`` describes; None when
    there are none, or they came from another video (its size or time changed) or other settings."""
    try:
        log = json.loads((Path(frames_dir) / EXTRACTED_LOG).read_text())
        names, video = log["names"], log["video"]
        if log["stamp"] != stamp or not all((Path(frames_dir) / n).is_file() for n in names):
            return None
        return list(names), dict(video)
    except (OSError, ValueError, KeyError, TypeError):
        return None


RESUMABLE_STAGES = ("extract", "match")
"""Stages whose result (the database) a rerun of an unfinished run reuses."""


def run_stamp(images_dir: Path, names: list[str], cfg: CaptureConfig) -> dict:
    """What the database's content depends on: the photos (name, size, mtime) and the settings (not
    --force or the thread count). A rerun reuses finished stages only when it is the same."""
    photos = []
    for n in names:
        st = (Path(images_dir) / n).stat()
        photos.append([n, st.st_size, st.st_mtime_ns])
    settings = {k: v for k, v in asdict(cfg).items() if k not in ("force", "num_threads")}
    return {"version": 1, "images": str(Path(images_dir).resolve()), "photos": photos, "settings": settings}


class StageLog:
    """``colmap/stages.json``: the resumable stages finished with one stamp, each with a snapshot of the
    database as that stage left it (``database.<stage>.db``; later stages change the cameras). A rerun
    with the same stamp restores the newest snapshot and skips those stages; another stamp (other photos
    or settings), a damaged log or a missing snapshot starts ``colmap/`` afresh."""

    def __init__(self, work: Path, stamp: dict):
        self.work, self.path, self.stamp = Path(work), Path(work) / "stages.json", stamp
        self.done: set[str] = set()
        try:
            log = json.loads(self.path.read_text()) if self.path.is_file() else None
        except (ValueError, OSError):
            log = None
        if isinstance(log, dict) and log.get("stamp") == stamp:
            done = [s for s in RESUMABLE_STAGES if s in log.get("done", [])]
            done = done[:next((i for i, s in enumerate(RESUMABLE_STAGES) if s not in done), len(done))]
            snap = self.snapshot(done[-1]) if done else None
            if snap is not None and snap.is_file():
                for p in list(self.work.iterdir()):  # everything but the snapshot and the log
                    if p not in (snap, self.path):
                        shutil.rmtree(p) if p.is_dir() else p.unlink()
                shutil.copyfile(snap, self.work / "database.db")
                self.done = set(done)
        if not self.done:
            if self.work.exists():
                shutil.rmtree(self.work)
            self.work.mkdir(parents=True, exist_ok=True)
            self._write()

    def snapshot(self, stage: str) -> Path:
        """The database as ``stage`` left it (until :meth:`close`); check that it exists."""
        return self.work / f"database.{stage}.db"

    def finish(self, stage: str) -> None:
        """Record a finished stage (snapshot first, then the log: a kill in between loses only the stage)."""
        from ..datasets.format import atomic_write

        atomic_write(self.snapshot(stage), lambda tmp: shutil.copyfile(self.work / "database.db", tmp))
        for old in self.done:
            self.snapshot(old).unlink(missing_ok=True)
        self.done.add(stage)
        self._write()

    def close(self) -> None:
        """The run finished: its snapshots are not needed any more (the log stays, as a record)."""
        for stage in RESUMABLE_STAGES:
            self.snapshot(stage).unlink(missing_ok=True)

    def _write(self) -> None:
        from ..datasets.format import atomic_write_json

        atomic_write_json(self.path, {"stamp": self.stamp, "done": sorted(self.done)})


def _run_in_thread(fn: Callable[[], Any], token, label: str, done: int, status: Callable[[], str] | None = None,
                   poll: float = POLL_S) -> ProgressGen:
    """Run ``fn`` in a worker thread, yielding Progress while it runs; cancel it if closed or interrupted.

    The thread's end is its own event, not ``Thread.is_alive``: a Ctrl-C that lands in ``Thread.join`` makes Python
    3.11 mark the thread stopped while it still runs (the bpo-45274 handling in ``_wait_for_tstate_lock``), so the
    stage was neither cancelled nor waited for, and the interpreter exited under pycolmap's running C++ thread
    ("terminate called without an active exception", a native stack trace, exit 134 instead of 130)."""
    out: dict[str, Any] = {}
    finished = threading.Event()

    def target() -> None:
        try:
            out["value"] = fn()
        except BaseException as e:  # noqa: BLE001  (re-raised in the generator's thread)
            out["error"] = e
        finally:
            finished.set()

    th = threading.Thread(target=target, name=f"mrvm-capture-{label}", daemon=True)
    t0 = time.perf_counter()
    th.start()
    try:
        while not finished.wait(poll):
            extra = status() if status else ""
            yield Progress(done, 100, f"{label}{' ' + extra if extra else ''} ({time.perf_counter() - t0:.0f}s)")
    finally:
        if not finished.is_set():  # closed or interrupted: cancel the pycolmap stage and wait for it
            token.cancel()
            _wait_through_interrupts(finished, poll)
        th.join()  # (finished: only the thread's last bytecodes are left)
    if "error" in out:
        # pycolmap 4.2.1's is_cancelled is a property, not a method: calling it turned every error a stage raised
        # (a photo pycolmap could not read, a mapping option it refused) into "TypeError: 'bool' object is not
        # callable", a traceback that named neither the stage nor its error
        cancelled = token.is_cancelled
        if cancelled() if callable(cancelled) else cancelled:
            raise Cancelled(f"{label} cancelled")
        raise out["error"]
    return out.get("value")


_CHILD_STAGE = """
import os, pickle, signal, sys
signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the parent's: it kills this process
if hasattr(signal, "SIGBREAK"):  # Windows: the panel's Esc is a Ctrl-Break to the worker's group, this one included
    signal.signal(signal.SIGBREAK, signal.SIG_IGN)
if sys.platform.startswith("linux"):  # and so does the parent's end (a worker killed by the panel): no orphan writes
    try:
        import ctypes
        ctypes.CDLL(None).prctl(1, 9)  # PR_SET_PDEATHSIG, SIGKILL
    except Exception:
        pass
if os.getppid() != int(sys.argv[2]):  # (the parent ended before that)
    sys.exit(1)
sys.path[:0] = [p for p in pickle.load(sys.stdin.buffer) if p not in sys.path]
import pycolmap
call, args, kwargs, level = pickle.load(sys.stdin.buffer)
pycolmap.logging.minloglevel = level
if level:  # a crash here is reported in words: no core dump into the user's folder (--verbose: one may be)
    try:
        import resource
        resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    except Exception:
        pass
try:
    out = ("value", getattr(pycolmap, call)(*args, **kwargs))
except Exception as e:
    out = ("error", f"{type(e).__name__}: {e}")
with open(sys.argv[1], "wb") as f:
    pickle.dump(out, f)
"""


def _run_in_child(call: str, args: tuple, kwargs: dict, label: str, done: int, work: Path, verbose: bool,
                  hint: str = "", poll: float = POLL_S) -> ProgressGen:
    """``pycolmap.<call>(*args, **kwargs)`` in a child Python, yielding Progress while it runs; its return value.

    For the stages that work on the database alone (matching, the focal length from the view graph). A native crash
    there ends the child, not this process: pycolmap's shared-focal relative-pose solver (poselib's
    ``relpose_6pt_shared_focal``) segfaulted in matching on photos of one shared camera whose pairs are all
    homographies (a flat subject photographed moving sideways), and recover-poses died with exit 139 and no word
    (tests/test_capture.py). It is one line now, naming ``hint``. Closing this generator or a Ctrl-C kills the child
    and waits for it (so the focal-length step, which pycolmap gives no cancel token, is cancellable too); SQLite
    rolls a killed write back on the next open. The child's stderr goes to ``work/pycolmap_stage.log`` unless
    ``verbose``, and only with ``verbose`` may it dump core: where core dumps were on (``ulimit -c unlimited``, a
    core_pattern of ``core``), each such crash left a 230 MB ``core`` file in the folder recover-poses ran from. On
    Linux the child also ends with this process (a worker the panel had to kill)."""
    import os
    import pickle
    import signal
    import subprocess
    import sys

    from ..worker import clean_env

    result = work / f".{call}.result"
    log = work / "pycolmap_stage.log"
    result.unlink(missing_ok=True)
    with open(log, "wb") as err:
        proc = subprocess.Popen([sys.executable, "-c", _CHILD_STAGE, str(result), str(os.getpid())],
                                stdin=subprocess.PIPE,
                                stdout=None if verbose else subprocess.DEVNULL, stderr=None if verbose else err,
                                env=clean_env())
    t0 = time.perf_counter()
    try:
        proc.stdin.write(pickle.dumps([p for p in sys.path if p]))
        proc.stdin.write(pickle.dumps((call, args, kwargs, 0 if verbose else 3)))
        proc.stdin.close()
    except BrokenPipeError:  # the child ended at once; its return code says how
        pass
    try:
        while True:
            try:
                proc.wait(timeout=poll)
                break
            except subprocess.TimeoutExpired:
                yield Progress(done, 100, f"{label} ({time.perf_counter() - t0:.0f}s)")
    finally:
        if proc.returncode is None:  # closed or interrupted
            proc.kill()
            while True:
                try:
                    proc.wait()
                    break
                except KeyboardInterrupt:
                    continue
    rc = proc.returncode
    try:
        status, value = pickle.loads(result.read_bytes()) if rc == 0 and result.is_file() else (None, None)
    finally:
        result.unlink(missing_ok=True)
    if status == "value":
        return value
    if status == "error":
        raise RuntimeError(f"pycolmap {call}: {value}")
    try:
        how = f"signal {signal.Signals(-rc).name}" if rc < 0 else f"exit {rc}"
    except ValueError:
        how = f"signal {-rc}"
    logged = "" if verbose or not log.is_file() or not log.stat().st_size else f" (its log: {log})"
    raise InputError(f"pycolmap crashed ({how}) while {label}{hint}; what was finished is kept in {work}{logged}")


def _shared_camera_hint(cfg: CaptureConfig, video: bool, count: int) -> str:
    """The clause a crash in matching ends with when the photos share one camera (pycolmap's shared-focal solver,
    :func:`_run_in_child`): how to run with one camera per photo. Every way a run comes to share one is named, not
    --single-camera alone: ``--camera-model PINHOLE`` and ``OPENCV`` share one whatever the flags, and ``--pair`` too,
    so a run with ``--camera-model OPENCV`` that crashed so was told to drop a --single-camera it had not given (and
    crashed again without it). '' when each photo has its own camera."""
    if not cfg.shared_camera:
        return ""
    changes = []
    if cfg.single_camera and not video:
        changes.append("without --single-camera")
    if cfg.allow_pair:
        changes.append("without --pair" + (" (with a third photo: a pair always shares one camera)" if count < 3
                                           else ""))
    if cfg.camera_model in ("PINHOLE", "OPENCV"):  # (config.shared_camera: the two-focal models share one)
        lens = "SIMPLE_RADIAL" if cfg.has_distortion else "SIMPLE_PINHOLE"
        changes.append(f"with --camera-model {lens} ({cfg.camera_model} shares one camera between all photos)")
    again = "extract the video's frames into a folder and run on them" if video else "run again"
    return (f"; with one camera for all photos pycolmap was seen to crash so on photos of a flat subject taken "
            f"moving sideways: {again}{' ' if changes else ''}{' and '.join(changes)}")


def _wait_through_interrupts(finished: threading.Event, poll: float) -> None:
    """Wait for a cancelled stage to end, a Ctrl-C more included: the process cannot end safely while pycolmap's
    thread runs (a cancelled stage stops within its current image or pair)."""
    while True:
        try:
            if finished.wait(poll):
                return
        except KeyboardInterrupt:
            continue


def _drop_bogus_focal_priors(db_path: Path) -> list[int]:
    """Forget a focal length from the photos' EXIF that the mapping would refuse; return the cameras changed.

    The incremental mapper leaves out every photo whose camera's focal length is under 0.1 or over 10 times its longer
    side (``min_focal_length_ratio``, ``max_focal_length_ratio``: a field of view over 157 or under 6 degrees). A
    focal length from EXIF out there (a 35 mm equivalent of 1 mm, or of 65535 mm, as a damaged tag reads) left
    photos that match well with no pair to start from, and the error line said they were 179 degrees apart. Such a
    camera starts from COLMAP's guess for a photo without EXIF (1.2 x the longer side), not marked as a prior."""
    import pycolmap

    lo, hi = (getattr(pycolmap.IncrementalPipelineOptions().mapper, k) for k in ("min_focal_length_ratio",
                                                                                 "max_focal_length_ratio"))
    changed = []
    db = pycolmap.Database.open(str(db_path))
    try:
        for cam in db.read_all_cameras():
            side = max(cam.width, cam.height)
            idx = list(cam.focal_length_idxs())
            params = np.array(cam.params, dtype=np.float64)
            if not cam.has_prior_focal_length or all(lo * side <= params[i] <= hi * side for i in idx):
                continue
            params[idx] = 1.2 * side
            cam.params = params
            cam.has_prior_focal_length = False
            db.update_camera(cam)
            changed.append(cam.camera_id)
    finally:
        db.close()
    return changed


def _pair_stats(db_path: Path, min_inliers: int) -> tuple[int, int, set[int]]:
    """(verified pairs, pairs tried, ids of images in a verified pair). The pairs tried are the matches table's rows:
    ``read_two_view_geometries`` leaves out pairs without a match, so it counted 0 of 45 pairs tried, none matching."""
    import pycolmap

    db = pycolmap.Database.open(str(db_path))
    try:
        pair_ids, geoms = db.read_two_view_geometries()
        tried = max(len(pair_ids), int(db.num_matched_image_pairs()))
        verified, connected = 0, set()
        for pid, g in zip(pair_ids, geoms):
            if len(g.inlier_matches) >= min_inliers and g.config not in (
                    pycolmap.TwoViewGeometryConfiguration.UNDEFINED, pycolmap.TwoViewGeometryConfiguration.DEGENERATE):
                verified += 1
                connected.update(_pair_to_ids(pid))
        return verified, tried, connected
    finally:
        db.close()


def _pair_to_ids(pair_id) -> tuple[int, int]:
    if isinstance(pair_id, tuple):
        return int(pair_id[0]), int(pair_id[1])
    k = 2147483647
    pid = int(pair_id)
    return pid // k, pid % k


def _db_image_names(db_path: Path) -> dict[int, str]:
    import pycolmap

    db = pycolmap.Database.open(str(db_path))
    try:
        return {im.image_id: im.name for im in db.read_all_images()}
    finally:
        db.close()


def recover_poses(images_dir: Path, out_dir: Path, cfg: CaptureConfig = CaptureConfig(),
                  verbose: bool = False) -> ProgressGen:
    """Recover camera poses of the photos in ``images_dir`` and write a capture folder to ``out_dir``.

    A generator of :class:`Progress`; its return value is a :class:`CaptureResult`. ``out_dir`` is held for the
    whole run (``guards.output_lock``): a second run into it is refused (two wrote one COLMAP database).
    """
    from ..guards import output_lock

    with output_lock(Path(out_dir), "capture folder"):
        try:
            return (yield from _recover_poses(images_dir, out_dir, cfg, verbose))
        except InputError as e:
            hint = video_spacing_hint(cfg.video_frames, str(e)) if is_video(images_dir) else ""
            if not hint:
                raise
            raise InputError(f"{e}{hint}") from None


def video_spacing_hint(frames: int, message: str) -> str:
    """The clause an error or warning that says the photos are too far apart (or show one view) ends with when they
    are a video's frames: its advice ('take one every 10-15 degrees') is a photographer's; a video's frames are as
    far apart as --frames spreads them. '' for other messages."""
    if "10-15 degrees" in message:
        return (f"; these are a video's frames: keep more of them (--frames {2 * frames}, now {frames}; in the panel: "
                "Video frames), or film the orbit more slowly")
    return ""


def _recover_poses(images_dir: Path, out_dir: Path, cfg: CaptureConfig, verbose: bool) -> ProgressGen:
    import pycolmap

    cfg.validate()
    images_dir, out_dir = Path(images_dir), Path(out_dir)
    # Without --verbose COLMAP says nothing: its errors ('Failed to create any sparse model', twice) came before our
    # own one-line error that names the problem and what to try; --verbose shows its whole log.
    pycolmap.logging.minloglevel = 0 if verbose else 3
    timings: dict[str, float] = {}
    cpu_timings: dict[str, float] = {}  # process CPU seconds (all threads): robust to a busy machine
    t, c = time.perf_counter(), time.process_time()

    # 1. scan (a video: its frames first)
    source, video_info = images_dir, None
    if is_video(images_dir):
        cfg = replace(cfg, single_camera=True)  # one camera: its focal length from the view graph (no EXIF)
        fresh = not [p for p in out_dir.iterdir() if p.name != LOCK_FILE]  # (held: output_lock made it)
        prepare_output(out_dir, images_dir, cfg.force)
        stamp = run_stamp(images_dir.parent, [images_dir.name], cfg)
        images_dir = out_dir / "frames"
        try:
            reused = _extracted_frames(images_dir, stamp)  # a resumed run: the frames it extracted (same video)
            if reused is None:
                if images_dir.exists():
                    shutil.rmtree(images_dir)
                names, video_info = yield from _scaled(extract_frames(source, images_dir, cfg.video_frames),
                                                       _STAGE_END["scan"])
                from ..datasets.format import atomic_write_json

                atomic_write_json(images_dir / EXTRACTED_LOG, {"stamp": stamp, "names": names, "video": video_info})
            else:
                names, video_info = reused
            size, turned_photos = check_images(images_dir, names, cfg)
        except BaseException:
            if fresh:  # a video that cannot be read leaves no output folder behind (output_lock removes it empty)
                remove_entries(out_dir, [p.name for p in out_dir.iterdir() if p.name != LOCK_FILE])
            raise
    else:
        names = list_images(images_dir)
        size, turned_photos = check_images(images_dir, names, cfg)
        prepare_output(out_dir, images_dir, cfg.force)
        stamp = run_stamp(images_dir, names, cfg)
    work = out_dir / "colmap"
    stages = StageLog(work, stamp)
    db_path = work / "database.db"
    matcher = choose_matcher(cfg, names)
    # pycolmap reads run_names in photo_dir (JPEG copies of photos in formats it cannot read); names stay the photos'
    photo_dir, run_names, renamed = yield from _scaled(readable_photos(images_dir, names, work, turned_photos),
                                                       _STAGE_END["scan"])
    timings["scan"], cpu_timings["scan"] = time.perf_counter() - t, time.process_time() - c
    resumed = f", resuming after {', '.join(sorted(stages.done))}" if stages.done else ""
    yield Progress(_STAGE_END["scan"], 100, f"{len(names)} images, {matcher} matching{resumed}")
    token = pycolmap.CancellationToken()
    threads = cfg.num_threads

    # 2. extract
    t, c = time.perf_counter(), time.process_time()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = cfg.camera_model
    ext = pycolmap.FeatureExtractionOptions()
    ext.max_image_size = cfg.max_image_size
    ext.num_threads = threads
    ext.sift.max_num_features = cfg.max_num_features
    first_octave = cfg.sift_first_octave(*size)
    ext.sift.first_octave = first_octave
    mode = pycolmap.CameraMode.SINGLE if cfg.shared_camera else pycolmap.CameraMode.PER_IMAGE
    if "extract" not in stages.done:
        yield from _run_in_thread(lambda: pycolmap.extract_features(
            db_path, photo_dir, image_names=run_names, camera_mode=mode, reader_options=reader, extraction_options=ext,
            device=pycolmap.Device.cpu, cancellation_token=token), token, "extracting features", _STAGE_END["scan"])
        _drop_bogus_focal_priors(db_path)
        stages.finish("extract")
    else:  # resumed: the checks a fresh run makes of the cameras extraction wrote, made again (a run stopped after its
        # features were extracted by a version without them, or stopped between them and its log, skipped them)
        _drop_bogus_focal_priors(db_path)
    timings["extract"], cpu_timings["extract"] = time.perf_counter() - t, time.process_time() - c

    # 3. match
    t, c = time.perf_counter(), time.process_time()
    mopts = pycolmap.FeatureMatchingOptions()
    mopts.num_threads = threads
    ver = pycolmap.TwoViewGeometryOptions()
    ver.ransac.random_seed = cfg.seed
    kwargs = dict(matching_options=mopts, verification_options=ver, device=pycolmap.Device.cpu)
    if matcher != "exhaustive":
        pairing = pycolmap.SequentialPairingOptions()
        pairing.overlap = cfg.sequential_overlap
        pairing.quadratic_overlap = True
        pairing.loop_detection = False
        kwargs["pairing_options"] = pairing
    # one camera shared by all photos: the pairs' verification estimates its focal length with the solver that crashed
    shared = _shared_camera_hint(cfg, video_info is not None, len(names))
    if "match" not in stages.done:
        yield from _run_in_child(f"match_{matcher}", (db_path,), kwargs, f"{matcher} matching", _STAGE_END["extract"],
                                 work, verbose, hint=shared)
        stages.finish("match")
    verified, tried, connected = _pair_stats(db_path, ver.min_num_inliers)
    timings["match"], cpu_timings["match"] = time.perf_counter() - t, time.process_time() - c
    if verified == 0:
        raise InputError(f"the images do not overlap: none of {tried} image pairs share enough matched features "
                         f"(database kept in {db_path})")
    id_to_name = _db_image_names(db_path)
    yield Progress(_STAGE_END["match"], 100, f"{verified}/{tried} pairs verified")

    # 4. map
    t, c = time.perf_counter(), time.process_time()
    focal_from_view_graph = cfg.estimate_focal and cfg.shared_camera and len(names) >= 3
    if focal_from_view_graph:
        vgc = pycolmap.ViewGraphCalibrationOptions()
        vgc.random_seed = cfg.seed
        focal_from_view_graph = yield from _run_in_child(
            "calibrate_view_graph", (db_path, vgc), {}, "estimating the focal length", _STAGE_END["match"], work,
            verbose, hint="; --no-focal-from-views skips this step")
    need = max(cfg.required_images, math.ceil(cfg.min_registered_fraction * len(names)))
    mopt = pycolmap.IncrementalPipelineOptions()
    mopt.num_threads = threads
    mopt.random_seed = cfg.seed
    mopt.min_model_size = min(cfg.required_images, len(names))
    tri = cfg.init_min_tri_angle or (4.0 if cfg.allow_pair else 0.0)
    if tri:
        mopt.mapper.init_min_tri_angle = tri
    if cfg.allow_pair and len(names) == 2:
        # Every track of a pair is a two-view track, which COLMAP ignores by default.
        mopt.triangulation.ignore_two_view_tracks = False
        mopt.mapper.init_min_num_inliers = 50

    def mapping(db: Path, out: Path, label: str):
        """One incremental mapping of ``db`` into ``out`` (afresh): its reconstructions, by model index."""
        if out.exists():
            shutil.rmtree(out)
        out.mkdir(parents=True)
        count = {"n": 0}

        def on_image() -> None:
            count["n"] += 1

        def on_init() -> None:
            count["n"] = 2

        return (yield from _run_in_thread(
            lambda: pycolmap.incremental_mapping(db, photo_dir, out, mopt, initial_image_pair_callback=on_init,
                                                 next_image_callback=on_image, cancellation_token=token),
            token, label, _STAGE_END["match"], status=lambda: f"{count['n']}/{len(names)} registered"))

    def largest(recs) -> tuple[int, Any]:
        return max(recs.items(), key=lambda kv: kv[1].num_reg_images()) if recs else (-1, None)

    sparse = work / "sparse"
    recs = yield from mapping(db_path, sparse, "mapping")
    best_idx, rec = largest(recs)
    tries = [{"focal_start": "view graph" if focal_from_view_graph else "1.2 x width guess",
              "registered": rec.num_reg_images() if rec else 0, "models": len(recs)}]
    matched = stages.snapshot("match")
    if focal_from_view_graph and tries[0]["registered"] < len(names) and matched.is_file():
        # The mapping seldom moves far from its focal-length start: from a view-graph estimate 13 % off, 10 photos
        # of an arc split into models of 6 and 5 that kept it; from COLMAP's 1.2 x width guess all 10 were placed,
        # the focal length within 1 % (docs/blender_versions.md). So a mapping that leaves photos out is run again
        # from the database as matching left it (before the calibration), and the one placing more is kept.
        guess_db = work / "database.guess.db"
        shutil.copyfile(matched, guess_db)
        recs2 = yield from mapping(guess_db, work / "sparse_guess", "mapping again from the 1.2 x width focal guess")
        idx2, rec2 = largest(recs2)
        tries.append({"focal_start": "1.2 x width guess", "registered": rec2.num_reg_images() if rec2 else 0,
                      "models": len(recs2)})
        if tries[1]["registered"] > tries[0]["registered"]:  # kept: the model in sparse_guess/, and its database
            recs, best_idx, rec, sparse = recs2, idx2, rec2, work / "sparse_guess"
            focal_from_view_graph = False
            guess_db.replace(db_path)  # colmap/database.db is the database of the kept model, as after one mapping
        else:  # the first mapping stays: nothing of the second is left to mislead
            guess_db.unlink()
            shutil.rmtree(work / "sparse_guess")
    timings["map"], cpu_timings["map"] = time.perf_counter() - t, time.process_time() - c
    match_db = matched if matched.is_file() else None  # the database as matching left it: the photos' EXIF priors
    if not recs:
        _write_report(work, names, [], None, timings, tries)
        # (no model: the spacing is measured only with the photos' EXIF focal length; without it, the usual cause is
        # named in words: on set G of docs/capture_check/, 17 of 20 rings of photos 40 degrees apart stopped here)
        diagnosis, named = _diagnosis(db_path, None, renamed, cfg.seed, match_db)
        usual = "" if named else (
            "; photos taken more than about 20 degrees apart round an object often stop here: take one every 10-15 "
            "degrees")
        raise InputError(f"mapping found no image pair to start from (too little overlap or baseline{usual})"
                         f"{diagnosis}; database kept in {db_path}")
    reg_names = sorted((rec.images[i].name for i in rec.reg_image_ids()), key=natural_key)  # as pycolmap reads them
    reg_photos = [renamed.get(n, n) for n in reg_names]
    model_dir = sparse / str(best_idx)
    if not model_dir.is_dir():  # pycolmap writes sparse/<idx>; make sure the kept model is on disk
        model_dir.mkdir(parents=True, exist_ok=True)
        rec.write(model_dir)
    _write_report(work, names, reg_photos, model_dir, timings, tries)
    if len(reg_names) < need:
        missing = [n for n in names if n not in set(reg_photos)]
        shown = ", ".join(missing[:3]) + (", ..." if len(missing) > 3 else "")
        raise InputError(f"mapping registered only {len(reg_names)} of {len(names)} images (need {need})"
                         f"{_diagnosis(db_path, rec, renamed, cfg.seed, match_db)[0]}; "
                         f"partial model kept in {model_dir}; "
                         f"not registered: {shown}")
    if rec.num_points3D() < MIN_MODEL_POINTS:
        raise InputError(f"mapping placed {len(reg_names)} of {len(names)} images but kept only {rec.num_points3D()} "
                         f"3D points (need {MIN_MODEL_POINTS}): the photos show no depth, as when the camera turns on "
                         "the spot (a panorama); move the camera round the subject between photos; model kept in "
                         f"{model_dir}")
    yield Progress(_STAGE_END["map"], 100, f"registered {len(reg_names)}/{len(names)}")

    # 4b. check the model against its photo pairs (a model can place every photo and be wrong)
    t, c = time.perf_counter(), time.process_time()
    try:
        pose_check = pair_pose_check(rec, db_path, seed=cfg.seed)
    except (ValueError, RuntimeError) as e:  # pycolmap's checks: a diagnostic that fails must not lose the capture
        pose_check = {"error": f"{type(e).__name__}: {e}", "suspect": False}
    if pose_check.get("suspect"):  # say whether the photos were taken too far apart (the usual cause)
        try:
            pose_check["photo_spacing_deg"] = photo_spacing(db_path, spacing_camera(rec), seed=cfg.seed)["spacing_deg"]
        except (ValueError, RuntimeError):
            pass
    timings["check"], cpu_timings["check"] = time.perf_counter() - t, time.process_time() - c

    # 5. undistort
    image_root, und_model = photo_dir, None
    if cfg.has_distortion:
        t, c = time.perf_counter(), time.process_time()
        und = work / "undistorted"
        if und.exists():
            shutil.rmtree(und)
        uopts = undistort_options([rec.cameras[rec.images[i].camera_id] for i in rec.reg_image_ids()])
        yield from _run_in_thread(lambda: pycolmap.undistort_images(
            und, model_dir, photo_dir, image_names=reg_names, output_type="COLMAP", undistort_options=uopts,
            num_threads=threads, cancellation_token=token), token, "undistorting", _STAGE_END["map"])
        rec = pycolmap.Reconstruction(str(und / "sparse"))
        sizes = sorted({(cam.width, cam.height) for cam in (rec.cameras[im.camera_id] for im in rec.images.values())})
        if len(sizes) > 1:
            raise OutputError(f"undistorted photos came out in {len(sizes)} sizes {sizes[:3]}; a capture has one "
                              f"resolution (model kept in {und / 'sparse'})")
        image_root, und_model = und / "images", und / "sparse"
        timings["undistort"], cpu_timings["undistort"] = time.perf_counter() - t, time.process_time() - c
        yield Progress(_STAGE_END["undistort"], 100, "undistorted")

    # 6. export
    t, c = time.perf_counter(), time.process_time()
    if video_info is None:
        ups_cam, turned = photo_ups(images_dir, reg_photos, turned_photos)
    else:  # one display rotation for every frame
        ups_cam, turned = [np.array(up_from_rotation(video_info["display_rotation_deg"]))] * len(reg_photos), {}
    by_name = {im.name: im for im in rec.images.values() if im.has_pose}
    c2ws, intrs = [], []
    for n in reg_names:
        im = by_name[n]
        cam = rec.cameras[im.camera_id]
        intrs.append(C.Intrinsics.from_K(cam.calibration_matrix(), cam.width, cam.height))
        c2ws.append(C.c2w_opencv_from_w2c(im.cam_from_world().matrix()))
    pts = rec.points3D
    xyz = np.array([p.xyz for p in pts.values()], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([p.color for p in pts.values()], dtype=np.uint8).reshape(-1, 3)
    if cfg.normalize:
        norm = align.auto_normalization(c2ws, xyz, ups_cam)
        s, r, tr = norm.s_r_t()
        c2ws = [align.apply_similarity_to_pose(p, s, r, tr) for p in c2ws]
        xyz = (s * xyz @ r.T + tr) if len(xyz) else xyz
        norm_json = norm.to_json()
    else:
        norm_json = None
    views = [CaptureView(renamed.get(n, n), image_root / n, k, p) for n, k, p in zip(reg_names, intrs, c2ws)]
    unregistered = [n for n in names if n not in set(reg_photos)]
    reproj = float(rec.compute_mean_reprojection_error())
    # (the meta records the export time up to here)
    timings["export"], cpu_timings["export"] = time.perf_counter() - t, time.process_time() - c
    meta = {
        "kind": "capture", "version": FORMAT_VERSION, "source": str(source.resolve()),
        "registered": len(reg_names), "total": len(names), "unregistered": unregistered,
        "camera_model": cfg.camera_model, "undistorted": cfg.has_distortion, "matcher": matcher,
        "sift_first_octave": first_octave, "focal_from_view_graph": bool(focal_from_view_graph),
        "num_points": int(len(xyz)), "mean_reprojection_error_px": reproj,
        "normalization": norm_json, "timings_s": timings, "cpu_timings_s": cpu_timings,
        "config": asdict(cfg),
        # photos pycolmap cannot read as they are (HEIC, WebP) were read as JPEG copies, float and 32-bit TIFFs as
        # 8-bit PNG copies: {copy's name: photo's name}
        "converted_photos": renamed,
        # photos stored turned (a phone held upright): their EXIF orientation, which gave the scene's up
        "exif_orientation": turned,
        # photos of the transposed size (one camera held both ways), read turned a quarter counter-clockwise
        "turned_photos": turned_photos,
        # a video's frames (frames/, named frame_000001.jpg, ...): where they came from and when
        "video": video_info,
        "colmap_model": str(model_dir.relative_to(out_dir)),
        # each mapping run: its focal length's start, photos registered in its largest model, models it made
        "mappings": tries,
        # the kept model against its photo pairs' own relative poses (capture/check.py); suspect: likely wrong
        "pose_check": pose_check,
        # The model whose (pinhole) cameras and 2D points match rgb/ (the undistorted one, when undistorted).
        "colmap_export_model": str((und_model or model_dir).relative_to(out_dir)),
    }
    # The scene's box, so a scene model (GPNR) can clip rays to it: the photos show a whole scene.
    lo, hi, how = align.scene_box(xyz, c2ws)
    meta.update({"background": "scene", "bbox": [lo.tolist(), hi.tolist()], "bbox_source": how,
                 "background_note": "real photos: no white background; 'bbox' is the scene's box from the sparse "
                                    "points (what models clip rays to)"})
    if cfg.normalize:
        meta["object_bbox"] = [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]  # the normalization's unit sphere
    if len({(v.intrinsics.fx, v.intrinsics.fy, v.intrinsics.cx, v.intrinsics.cy) for v in views}) > 1:
        meta["per_view_intrinsics"] = True  # (one camera a photo): a copy without transforms.json is refused, not
        # read with the first photo's intrinsics for every view (datasets.format.read_object)
    write_capture(out_dir, views, xyz, rgb, meta)
    stages.close()
    timings["export"], cpu_timings["export"] = time.perf_counter() - t, time.process_time() - c
    yield Progress(_STAGE_END["export"], 100, f"registered {len(reg_names)}/{len(names)}")
    return CaptureResult(out_dir, reg_photos, len(names), unregistered, matcher, timings, int(len(xyz)), reproj,
                         cpu_timings, c2ws, intrs, pose_check, video_info or {})


def undistort_options(cameras: list) -> Any:
    """COLMAP's undistortion options, set so that every camera comes out at one image size.

    COLMAP sizes each undistorted camera after its own distortion (the largest frame with no blank
    pixels), so per-photo cameras (SIMPLE_RADIAL / RADIAL without ``single_camera``) came out a few
    pixels apart (330x243 ... 335x245 for 24 views of the 320x240 test ring), while a dataset and a
    Blender scene have one resolution. With several cameras every one is scaled by the smallest of
    their no-blank scales (x and y; ``min_scale = max_scale``): one size, no blank pixels, each
    camera keeps its focal length. One camera keeps COLMAP's own (per-axis) sizing.
    """
    import pycolmap

    opts = pycolmap.UndistortCameraOptions()
    cams = list({c.camera_id: c for c in cameras}.values())
    if len(cams) > 1:
        scales = []
        for c in cams:
            u = pycolmap.undistort_camera(opts, c)
            scales += [u.width / c.width, u.height / c.height]
        opts.min_scale = opts.max_scale = min(scales)
    return opts


def _write_report(work: Path, names: list[str], registered: list[str], model_dir: Path | None,
                  timings: dict[str, float], tries: list[dict]) -> None:
    """``colmap/report.json``: what the mapping achieved (kept also when the run fails), with each mapping."""
    rep = {"total": len(names), "registered": registered,
           "unregistered": [n for n in names if n not in set(registered)],
           "model": str(model_dir) if model_dir else None, "timings_s": timings, "mappings": tries}
    (work / "report.json").write_text(json.dumps(rep, indent=1) + "\n")
