"""Settings of pose recovery (one frozen dataclass, a docstring line per field)."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError

CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
DISTORTED_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV")
MATCHERS = ("auto", "exhaustive", "sequential")
CONVERTED_EXTENSIONS = (".heic", ".heif", ".webp")
"""Photo formats pycolmap cannot read (HEIC/HEIF: iPhones' default; WebP), converted to JPEG for it."""
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp") + CONVERTED_EXTENSIONS


@dataclass(frozen=True)
class CaptureConfig:
    """How :func:`capture.sfm.recover_poses` runs (defaults: the benchmarked fast path)."""

    camera_model: str = "SIMPLE_PINHOLE"
    """COLMAP model: SIMPLE_PINHOLE (default: phones undistort in-camera), PINHOLE, or SIMPLE_RADIAL, RADIAL, OPENCV (undistorted on export)."""
    single_camera: bool = False
    """One shared camera for all photos; off by default: COLMAP verifies shared-camera pairs ~2x slower (CPU)."""
    estimate_focal: bool = True
    """A shared camera gets its initial focal length from the view graph (GLOMAP calibration) instead of COLMAP's 1.2 x width guess.
    A mapping from it that leaves photos out is run again from the guess, and the one placing more photos kept."""
    matcher: str = "auto"
    """auto, exhaustive or sequential; auto = sequential for numbered frames beyond exhaustive_max_images."""
    exhaustive_max_images: int = 30
    """auto matches every pair up to this many images (and always when names are not numbered frames)."""
    sequential_overlap: int = 6
    """Sequential matching pairs each frame with this many successors (plus quadratic i+2^k)."""
    max_image_size: int = 1600
    """Images are downscaled to this longer side for feature extraction (poses stay in full resolution)."""
    upsample_below: int = 640
    """SIFT upsamples photos 2x first (octave -1) only when their longer side is below this; larger: ~3x faster."""
    max_num_features: int = 2048
    """SIFT features kept per image (pycolmap's default is 8192)."""
    min_images: int = 3
    """Fewer input images is an error (a pair needs allow_pair)."""
    allow_pair: bool = False
    """Accept exactly two images (a stereo pair): min_images and the mapper's model size drop to 2."""
    min_registered_fraction: float = 0.5
    """Mapping that registers fewer than this fraction of the photos (or under min_images) is an error."""
    init_min_tri_angle: float = 0.0
    """Initial-pair triangulation angle, degrees; 0 = COLMAP's 16 (4 with allow_pair, for short baselines)."""
    num_threads: int = -1
    """CPU threads for extraction, matching and mapping (-1 = all)."""
    seed: int = 0
    """RANSAC / mapper random seed (results repeat run to run)."""
    video_frames: int = 40
    """A video's frames kept for recovery: the sharpest of each of this many equal spans of its duration."""
    normalize: bool = True
    """Rotate the cameras' mean up vector to +z and fit the object of interest in the unit sphere."""
    force: bool = False
    """Overwrite an output folder that already holds files."""

    config_label = "capture"  # not a field: how messages name the fields

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> "CaptureConfig":
        """Types and ranges (run when the config is built); returns the config."""
        from .. import validation as V

        V.check_types(self)
        if self.num_threads != -1 and self.num_threads < 1:
            raise InputError(f"{self.config_label}.num_threads must be -1 (all) or at least 1, got {self.num_threads}")
        V.at_least(self, "seed", 0)
        V.at_least(self, "video_frames", 3)
        V.at_least(self, "sequential_overlap", 1)
        V.at_least(self, "exhaustive_max_images", 2)
        V.at_least(self, "min_images", 2)
        V.at_least(self, "init_min_tri_angle", 0.0)
        if self.camera_model not in CAMERA_MODELS:
            raise InputError(f"unknown camera model {self.camera_model!r}; choose one of {', '.join(CAMERA_MODELS)}")
        if self.matcher not in MATCHERS:
            raise InputError(f"unknown matcher {self.matcher!r}; choose one of {', '.join(MATCHERS)}")
        if self.max_num_features < 64:
            raise InputError(f"max_num_features must be at least 64 (got {self.max_num_features})")
        if self.max_image_size != -1 and self.max_image_size < 64:
            raise InputError(f"max_image_size must be at least 64 or -1 (got {self.max_image_size})")
        if self.upsample_below < 0:
            raise InputError(f"upsample_below must be at least 0 (got {self.upsample_below})")
        if not 0.0 <= self.min_registered_fraction <= 1.0:
            raise InputError("min_registered_fraction must lie in [0, 1]")
        return self

    @property
    def has_distortion(self) -> bool:
        return self.camera_model in DISTORTED_MODELS

    @property
    def shared_camera(self) -> bool:
        """Shared for two-focal models (a Blender scene has one pixel aspect) and pairs (too few views otherwise)."""
        return self.single_camera or self.allow_pair or self.camera_model in ("PINHOLE", "OPENCV")

    def sift_first_octave(self, width: int, height: int) -> int:
        """COLMAP's SIFT first octave for photos of this size: -1 (upsample 2x) below ``upsample_below``, else 0."""
        side = max(width, height)
        if self.max_image_size != -1:
            side = min(side, self.max_image_size)
        return -1 if side < self.upsample_below else 0

    @property
    def required_images(self) -> int:
        return 2 if self.allow_pair else max(self.min_images, 3)
