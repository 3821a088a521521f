"""The Python API: load a model, render novel views from reference arrays, score them, read a dataset (bpy-free).

What a script or a notebook calls instead of ``python -m blender_mrvm ...``; ``docs/guide/python_api.md`` states
the conventions and shows each entry point. Every function here wraps the code the CLI runs (``synthesis.views``,
``models.pretrained``, ``training.evaluate``, ``datasets.loaders``, ``models.sem2nerf.render``); none copies it.
Importing this module imports neither bpy nor the CLI (which sets ``OMP_WAIT_POLICY`` on import), and no function
here changes torch's thread count, default dtype, grad mode (outside its own ``no_grad``), the warnings filters,
signal handlers, the working directory or the environment. Errors are exceptions (:class:`InputError` for bad
input), never an exit; the CLI's stderr notes become :class:`UserWarning` s.

Conventions (the dataset format's, ``datasets/format.py``, ``geometry/cameras.py``):

- images: HWC, RGB or RGBA (straight alpha), uint8 / uint16 / float in [0, 1], sRGB-encoded (what a PNG holds);
  RGBA is mixed over white in linear light, as Blender composites. Outputs are float32 sRGB in [0, 1] on white.
- poses: 4x4 (or 3x4) camera-to-world in world units, world z up; camera axes OpenCV (x right, y down, looking
  down +z) unless ``convention`` says "opengl" / "blender" (x right, y up, looking down -z: ``transforms.json``,
  Blender's ``matrix_world``).
- intrinsics: 3x3 K in pixels of the image it belongs to, the top-left pixel's centre at (0.5, 0.5) (an unshifted
  camera has cx = W / 2); or a :class:`Intrinsics`.
- depth: planar z along the camera's axis in world units (the CLI's EXR), 0 where the opacity is below 0.5.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .errors import InputError
from .geometry.cameras import Intrinsics

__all__ = ["Model", "View", "Intrinsics", "InputError", "load_model", "references", "load_references",
           "auto_model", "render_views", "render_view", "scores", "lpips_metric", "read_object", "SHIPPED_MODELS",
           "CONVENTIONS", "MaskView", "MaskRender", "render_mask_views"]

CONVENTIONS = ("opencv", "opengl", "blender")
"""Camera-axis conventions a pose may be given in (``geometry/cameras.py``)."""
SHIPPED_MODELS = ("shipped", "shipped:mrvm_anyview", "shipped:mrvm_quality", "shipped:gpnr", "shipped:gpnr_captures",
                  "shipped:sem2nerf")
"""The shipped checkpoints by name (``shipped`` is the default NeRFormer+MRVM model; README "Shipped models")."""


@dataclass
class Model:
    """A loaded checkpoint, ready to render (:func:`load_model`)."""

    module: Any
    """The torch module (eval mode): ``GeneralizableNeRF`` (NeRFormer+MRVM), ``GPNR`` or ``Sem2NeRF``."""
    kind: str
    """``nerformer_mrvm``, ``gpnr`` or ``sem2nerf``."""
    config: Any
    """The model config the checkpoint was saved with."""
    meta: dict
    """The checkpoint's metadata (step, ``train_image_size``, ...)."""
    path: Path
    """The model file."""
    device: Any
    """torch.device the model lives on."""
    precision: str = "fp32"
    """What the forward passes run at (``models/precision.py``; ``auto`` resolved as ``synthesize`` resolves it)."""
    quality: str = "full"
    """``full`` or ``preview`` (half the samples per ray)."""

    @property
    def train_size(self) -> int:
        """The longer image side the model was trained on (0 when unknown)."""
        from .synthesis.views import trained_size

        return trained_size(self.path)


@dataclass
class View:
    """One rendered view (:func:`render_views`), HWC numpy arrays."""

    rgb: np.ndarray
    """(H, W, 3) float32 in [0, 1]: sRGB-encoded colour composited on white (what the CLI's PNG shows over white)."""
    alpha: np.ndarray
    """(H, W) float32 in [0, 1]: the model's accumulated opacity."""
    depth: np.ndarray
    """(H, W) float32 planar z-depth in world units (the CLI's ``--depth`` EXR); 0 where ``alpha`` < 0.5."""
    ray_depth: np.ndarray
    """(H, W) float32 expected distance along each pixel's ray, world units, wherever anything was rendered."""
    reference_views: tuple = ()
    """Positions of the references the view was rendered from."""
    scene: bool = False
    """The references show a whole scene (background 'scene'): :meth:`rgba` is opaque."""
    info: dict = field(default_factory=dict)
    """Rays, box rays and evaluated rays."""

    def rgba(self) -> np.ndarray:
        """(H, W, 4) uint8 straight-alpha RGBA, the bytes ``synthesize`` writes to ``rgb/NNNNNN.png``."""
        from .synthesis.views import rgba_image

        return rgba_image(self.rgb, self.alpha, self.scene)


# ------------------------------------------------------------------------------------------------ models

def load_model(checkpoint: str | Path = "shipped", device: str = "cpu", precision: str = "auto",
               quality: str = "full") -> Model:
    """Load a checkpoint of any kind: ``shipped`` (the default model), ``shipped:<name>`` (:data:`SHIPPED_MODELS`),
    a model file, a checkpoint folder or a run folder. ``device``: cpu, cuda[:N] or auto. ``precision``: auto (as
    ``synthesize``: bf16 on a GPU; on the CPU int8 for models wide enough to gain, else fp32), fp32, bf16, fp16 or
    int8. ``quality``: full or preview. ``shipped:auto`` needs the cameras: see :func:`auto_model`.

    A Sem2NeRF checkpoint loads too (``kind`` 'sem2nerf', fp32, at ``quality``); it renders from a part mask, not
    references: :func:`render_mask_views` (``sem2nerf render``), and :func:`render_views` refuses it.

    Torch's global random state is left as it was (building a module draws its initial weights from it before the
    checkpoint's replace them: a seeded experiment would otherwise depend on which models it loaded)."""
    import torch

    with torch.random.fork_rng(devices=[]):
        return _load_model(checkpoint, device, precision, quality)


def _load_model(checkpoint, device: str, precision: str, quality: str) -> Model:
    from .models.checkpoint_files import model_file_of, model_kind, read_header_meta
    from .models.pretrained import resolve_checkpoint
    from .synthesis.views import resolve_device

    dev = resolve_device(device)
    path = resolve_checkpoint(checkpoint)
    if model_kind(read_header_meta(model_file_of(path))) == "sem2nerf":
        from .models.registry import QUALITY_LEVELS
        from .models.sem2nerf.render import checkpoint_info, load_render_model

        if precision not in ("auto", "fp32"):
            raise InputError("a Sem2NeRF model renders at fp32 (precision auto or fp32)")
        if quality not in QUALITY_LEVELS:
            raise InputError(f"quality must be one of {', '.join(QUALITY_LEVELS)}, got {quality!r}")
        info = checkpoint_info(path)
        module, cfg = load_render_model(info.model_file, str(dev), quality)
        return Model(module, "sem2nerf", cfg, info.meta, Path(module.checkpoint_file), dev, "fp32", quality)
    from .models.config import merge
    from .models.precision import check_precision, for_precision, resolve_precision
    from .models.registry import QUALITY_LEVELS, quality_overrides
    from .synthesis.views import load_checkpoint

    check_precision("precision", precision, dev.type, auto=True)
    if quality not in QUALITY_LEVELS:
        raise InputError(f"quality must be one of {', '.join(QUALITY_LEVELS)}, got {quality!r}")
    module, cfg, meta, path = load_checkpoint(path, dev)
    precision = resolve_precision(precision, dev.type, module)
    module.cfg = merge(module.cfg, quality_overrides(module.cfg, quality))
    module = for_precision(module, precision, inplace=True)
    return Model(module, module.kind, cfg, meta, Path(getattr(module, "checkpoint_file", path)), dev, precision,
                 quality)


# ------------------------------------------------------------------------------------------------ inputs

def _pose(m, convention: str) -> np.ndarray:
    """A 4x4 OpenCV camera-to-world pose from one given in ``convention``; checked rigid."""
    from .datasets.format import check_pose
    from .geometry import cameras as C

    if convention not in CONVENTIONS:
        raise InputError(f"convention must be one of {', '.join(CONVENTIONS)}, got {convention!r}")
    p = C.as_pose(np.asarray(m, np.float64))
    p = p if convention == "opencv" else C.opencv_from_blender(p)
    check_pose(p, "pose")
    return p


def _poses(c2w, convention: str) -> list[np.ndarray]:
    a = np.asarray(c2w, np.float64)
    a = a[None] if a.ndim == 2 else a
    return [_pose(m, convention) for m in a]


def _intrinsics(K, width: int, height: int) -> Intrinsics:
    if isinstance(K, Intrinsics):
        if (K.width, K.height) != (int(width), int(height)):
            return K.resized(int(width), int(height))
        return K
    return Intrinsics.from_K(np.asarray(K, np.float64), int(width), int(height))


def _image(x) -> np.ndarray:
    """An image file or an HWC array as float32 sRGB RGB in [0, 1] on white (``loaders.to_float_rgb``)."""
    from .datasets.loaders import read_colour, to_float_rgb

    if isinstance(x, (str, Path)):
        return read_colour(Path(x))
    a = np.asarray(x)
    if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[-1] not in (1, 2, 3, 4)):
        raise InputError(f"an image is (H, W), (H, W, 3) or (H, W, 4) (HWC), got shape {a.shape}")
    if a.dtype.kind == "f" and a.size and (np.nanmax(a) > 1.0 + 1e-6 or np.nanmin(a) < -1e-6):
        raise InputError(f"a float image holds values in [0, 1], got {np.nanmin(a):.3g} to {np.nanmax(a):.3g} "
                         "(divide 0-255 values by 255, or pass uint8)")
    return to_float_rgb(a)


def references(images, c2w, K, *, convention: str = "opencv", bbox=None, masks=None,
               background: str = "white"):
    """Reference views from arrays (or image files): a :class:`synthesis.References` for :func:`render_views`.

    ``images``: V images (paths, or HWC arrays: see the module doc), one size. ``c2w``: (V, 4, 4) camera-to-world in
    ``convention``. ``K``: (3, 3) shared or (V, 3, 3), pixels of these images, pixel centres at +0.5, or
    :class:`Intrinsics`. ``bbox``: ((min x, y, z), (max x, y, z)) of the object in world units; None = where the
    cameras' optical axes meet (radius half their distance), as ``synthesize`` guesses it for a folder without
    one. ``masks``: (V, H, W) bool object masks (True = object), which let rays that miss the references' visual
    hull skip the model. ``background``: 'white' (an object on white) or 'scene' (a room or photo capture)."""
    from .synthesis.views import References, object_box, parse_bbox

    imgs = [_image(x) for x in (images if not isinstance(images, np.ndarray) or images.ndim == 4 else [images])]
    if not imgs:
        raise InputError("references need at least one image")
    shapes = {im.shape for im in imgs}
    if len(shapes) != 1:
        raise InputError(f"the reference images must share one size, got {sorted(shapes)}")
    h, w = imgs[0].shape[:2]
    poses = _poses(c2w, convention)
    Ks = K if isinstance(K, (list, tuple)) else ([K] * len(imgs) if isinstance(K, Intrinsics) or np.ndim(K) == 2
                                                   else list(K))
    if len(poses) != len(imgs) or len(Ks) != len(imgs):
        raise InputError(f"{len(imgs)} images need as many poses and intrinsics, got {len(poses)} and {len(Ks)}")
    intrs = [_intrinsics(k, w, h) for k in Ks]
    if bbox is None:
        box, src = object_box({}, poses)
    else:
        box, src = parse_bbox([*bbox[0], *bbox[1]]), "given"
    m = None
    if masks is not None:
        m = np.asarray(masks).astype(bool)
        if m.shape != (len(imgs), h, w):
            raise InputError(f"masks must be (V, H, W) = {(len(imgs), h, w)}, got {m.shape}")
    if background not in ("white", "scene"):
        raise InputError(f"background must be 'white' or 'scene', got {background!r}")
    return References(Path("<arrays>"), tuple(range(len(imgs))), np.stack(imgs).astype(np.float32), poses, intrs,
                      box, src, m, background)


def load_references(folder: str | Path, views: Sequence[int] = ()):
    """Reference views of an object folder (a render, a recovered capture), at their own size, as ``synthesize
    --references FOLDER --views ...`` reads them (box from ``meta.json``, masks from ``mask/``); () = every view."""
    from .synthesis.views import load_references as _load

    return _load(Path(folder), tuple(int(v) for v in views))


def read_object(folder: str | Path, depth: bool = False):
    """Every view of an object folder of our format: a ``datasets.loaders.ObjectScene`` with ``images`` (N, H, W, 3)
    float32 sRGB on white, ``c2w`` (N, 4, 4) OpenCV, ``intrinsics`` (N :class:`Intrinsics`), ``bbox``, ``masks``
    (N, H, W) bool or None, ``view_ids`` and, with ``depth``, ``depths`` (N, H, W) planar z (0 = nothing)."""
    from .datasets.loaders import load_ours

    return load_ours(Path(folder), depth=depth)


def auto_model(refs, target_c2w, target_K, width: int, height: int, *, convention: str = "opencv",
               gpu: bool = False) -> tuple[str, str]:
    """``shipped:auto``'s choice for these references and targets: (checkpoint name for :func:`load_model`, why),
    the rule ``synthesize`` applies (``models.pretrained.auto_model``)."""
    from .models.pretrained import auto_model as _auto
    from .synthesis.views import FRAMING_BOXES

    tc = _poses(target_c2w, convention)
    tk = _target_intrinsics(target_K, len(tc), width, height)
    name, why = _auto([*refs.c2w, *tc], [*refs.intrinsics, *tk], refs.bbox, refs.bbox_source in FRAMING_BOXES,
                      gpu=gpu, background=refs.background)
    return f"shipped:{name}", why


def _target_intrinsics(K, n: int, width: int, height: int) -> list[Intrinsics]:
    Ks = K if isinstance(K, (list, tuple)) else ([K] * n if isinstance(K, Intrinsics) or np.ndim(K) == 2 else list(K))
    if len(Ks) != n:
        raise InputError(f"{n} target poses need as many intrinsics, got {len(Ks)}")
    return [_intrinsics(k, width, height) for k in Ks]


# ------------------------------------------------------------------------------------------------ rendering

def _sized(refs, model: Model, ref_size: int):
    """``refs`` at the size ``synthesize --ref-size`` gives them (``synthesis.views.reference_sizes``)."""
    from dataclasses import replace

    from .synthesis.views import reference_shape, reference_sizes, resize_mask, resize_view

    size, max_size = reference_sizes(int(ref_size), model.path)
    k0 = refs.intrinsics[0]
    w, h = reference_shape(k0, size, max_size)
    if int(ref_size) == 0 and max_size and max(k0.width, k0.height) < max_size:
        raise InputError(f"the reference images are {k0.width}x{k0.height}, smaller than the {max_size} px this model "
                         f"was trained on; pass ref_size={max_size} to upsample them or ref_size=-1 to use them as "
                         "they are")
    if all((k.width, k.height) == (w, h) for k in refs.intrinsics):
        return refs
    views = [resize_view(im, k, w, h) for im, k in zip(refs.images, refs.intrinsics)]
    masks = None if refs.masks is None else np.stack([resize_mask(m, w, h) for m in refs.masks])
    return replace(refs, images=np.stack([im for im, _ in views]).astype(np.float32),
                   intrinsics=[k for _, k in views], masks=masks)


def render_views(model: Model, refs, target_c2w, target_K, width: int, height: int, *,
                 convention: str = "opencv", ref_size: int = 0, nearest: int = 0, skip_empty: str = "cull",
                 chunk: int = 0, workers: int = 1, _stacklevel: int = 2) -> list[View]:
    """Novel views of ``refs`` (:func:`references` or :func:`load_references`) at the cameras ``target_c2w``
    ((4, 4) or (N, 4, 4) in ``convention``) with ``target_K`` ((3, 3) shared, (N, 3, 3) or :class:`Intrinsics`, in
    pixels of a ``width`` x ``height`` image); a list of :class:`View`, one a camera. The same numbers as
    ``synthesize`` with the same checkpoint, references and options (not here: ``--adapt-steps``, and
    ``--reproject``, which ``auto`` turns on only when a view uses fewer references than were given).

    ``ref_size``: 0 shrinks references larger than the model's training images to that size (and refuses smaller
    ones), N > 0 resizes them to N px on the longer side, -1 keeps them. ``nearest``: each view from its K nearest
    references (0: every reference up to 5, else the 5 nearest). ``skip_empty``: cull, tighten or off (needs masks).
    ``workers``: ray chunks rendered side by side on threads (torch's own thread count is left as it is)."""
    import torch

    from .models.background import for_rendering
    from .models.hull import MODES
    from .progress import run_to_end
    from .synthesis.views import TargetRenderer, references_per_target

    if model.kind == "sem2nerf":
        raise InputError("a Sem2NeRF model renders from a part mask, not from reference views: "
                         "api.render_mask_views (`python -m blender_mrvm sem2nerf render`)")
    if skip_empty not in MODES:
        raise InputError(f"skip_empty must be one of {', '.join(MODES)}, got {skip_empty!r}")
    net, dev = model.module, model.device
    refs = _sized(refs, model, ref_size)
    tc = _poses(target_c2w, convention)
    tk = _target_intrinsics(target_K, len(tc), width, height)
    note = for_rendering(net, refs.background)
    if note:
        warnings.warn(note, UserWarning, stacklevel=_stacklevel)
    from .models.pretrained import viewpoint_note
    from .synthesis.views import FRAMING_BOXES

    note = viewpoint_note(model.path, [*refs.c2w, *tc], [*refs.intrinsics, *tk], refs.bbox,
                          refs.bbox_source in FRAMING_BOXES)  # a shipped model named for cameras it does not fit
    if note:
        warnings.warn(note, UserWarning, stacklevel=_stacklevel)
    chunk_n = net.inference_chunk(chunk if chunk and chunk > 0 else None)
    out = []
    with torch.no_grad():
        renderer = TargetRenderer(net, refs, references_per_target(net, len(refs.views), int(nearest)), skip_empty,
                                  model.precision, chunk_n, dev, max(1, int(workers)))
        for c2w, intr in zip(tc, tk):
            res, keep, _ = run_to_end(renderer.render(intr, c2w))
            out.append(View(res["color"].astype(np.float32), res["acc"].astype(np.float32),
                            res["depth_z"].astype(np.float32), res["depth"].astype(np.float32), tuple(keep),
                            refs.background == "scene",
                            {k: res[k] for k in ("rays", "box_rays", "evaluated")}))
    return out


def render_view(model: Model, refs, target_c2w, target_K, width: int, height: int, **options) -> View:
    """One view: :func:`render_views` of a single (4, 4) pose."""
    if np.asarray(target_c2w).ndim != 2:
        raise InputError("render_view takes one (4, 4) pose; render_views takes several")
    return render_views(model, refs, target_c2w, target_K, width, height, _stacklevel=3, **options)[0]


# ------------------------------------------------------------------------------------------------ Sem2NeRF

@dataclass
class MaskView:
    """One view of a Sem2NeRF model (:func:`render_mask_views`), HWC numpy arrays."""

    rgb: np.ndarray
    """(H, W, 3) float32 in [0, 1]: sRGB-encoded colour on the model's background (white for the shipped model)."""
    alpha: np.ndarray
    """(H, W) float32 in [0, 1]: the model's opacity."""
    semantic: np.ndarray
    """(H, W) uint8 part ids (argmax of the rendered semantic map): ``semantic/NNNNNN.png``."""
    semantic_color: np.ndarray
    """(H, W, 3) uint8: the ids in their label colours: ``semantic_color/NNNNNN.png``."""
    c2w: np.ndarray
    """(4, 4) OpenCV camera-to-world of the view (``pose/NNNNNN.txt``; whatever ``convention`` the call took)."""
    intrinsics: Intrinsics
    _rgba: np.ndarray = field(repr=False, default=None)

    def rgba(self) -> np.ndarray:
        """(H, W, 4) uint8 straight-alpha RGBA, the bytes ``sem2nerf render`` writes to ``rgb/NNNNNN.png``."""
        return self._rgba.copy()


@dataclass
class MaskRender:
    """What :func:`render_mask_views` returns."""

    views: list
    """A :class:`MaskView` per camera (the orbit's view 0 is the mask's camera)."""
    mask: np.ndarray
    """(H, W) uint8 part ids the model saw (after the edits): ``mask_input.png``."""
    edits: list
    """The edits as (source id, destination id)."""
    blend: list = field(default_factory=list)
    """With ``blend``: (H, W, 3) float32 images of the mask's view along the style blend (``blend/NNNNNN.png``)."""


def render_mask_views(model: Model, mask, c2w, K, target_c2w=None, target_K=None, width: int = 0, height: int = 0,
                      *, convention: str = "opencv", views: int = 8, edits: Sequence[str] = (),
                      style_seed: int | None = None, mix_seed: int | None = None, mix: float = 0.5,
                      blend: int | None = None, blend_steps: int = 5) -> MaskRender:
    """Views of a Sem2NeRF model (``load_model("shipped:sem2nerf")``) from one part mask: what ``sem2nerf render``
    writes, as arrays (``models.sem2nerf.render.render_prepared``, the render both share).

    ``mask``: (H, W) integer part ids, or an (H, W, 3|4) uint8 image: grey = the ids (as the CLI reads a PNG), else
    the label colours (``semantic_color``'s; alpha < 128 is background); the checkpoint's size, square
    (``models.sem2nerf.render.mask_from_array``). ``c2w``: its camera, (4, 4) in ``convention``; ``K``: (3, 3) in
    pixels of the mask, or :class:`Intrinsics`. Targets: ``target_c2w`` ((4, 4) or (N, 4, 4) in ``convention``)
    with ``target_K`` (shared or one each, pixels of a ``width`` x ``height`` image; 0 = the mask's size); None =
    ``views`` cameras orbiting the world z axis through the mask's camera (``--views``). ``edits``: 'SRC:DST'
    (ids or label names, ``--edit``) applied in order. ``style_seed`` (None = the mean style), ``mix_seed`` with
    ``mix`` (``--mix-seed``, ``--mix``: 0.5 as the CLI), ``blend`` with ``blend_steps`` (``--blend``). The quality
    is the model's (``load_model(..., quality="preview")``). Torch's thread count and random state are left as
    they were. InputError with the CLI's messages for a mask of unknown labels, an empty mask, bad edits, a camera
    from which the mask does not lie over the model's box."""
    import torch

    from .models.sem2nerf import render as R

    if model.kind != "sem2nerf":
        raise InputError(f"render_mask_views renders a Sem2NeRF model (load_model('shipped:sem2nerf')), got a "
                         f"{model.kind} model: render_views renders it from references")
    if mix_seed is None:
        mix = 0.0
    R.check_render_options(int(views), int(blend_steps), float(mix),
                           {"--style-seed": style_seed, "--mix-seed": mix_seed, "--blend": blend}, model.quality)
    info = R.checkpoint_info(model.path)
    ids = R.mask_from_array(mask, info.labels, "mask")
    cam = _pose(c2w, convention)
    intr = _intrinsics(K, info.size, info.size)
    p = R.prepare_mask(info, ids, tuple(str(e) for e in edits), cam, intr, int(views), "mask", "the mask's camera")
    if target_c2w is not None:
        if target_K is None:
            raise InputError("target_c2w needs target_K (the targets' intrinsics)")
        tc = _poses(target_c2w, convention)
        tk = _target_intrinsics(target_K, len(tc), int(width) or info.size, int(height) or info.size)
        p.views = list(zip(tk, tc))
    out = MaskRender([], p.mask.copy(), [tuple(e) for e in p.edits])
    with torch.random.fork_rng(devices=[]):
        for kind, _, res in R.render_prepared(model.module, p, style_seed, mix_seed, float(mix), blend,
                                              int(blend_steps)):
            if kind == "view":
                out.views.append(MaskView(res.rgb, res.alpha, res.semantic, res.semantic_color, res.c2w,
                                          res.intrinsics, res.rgba))
            else:
                out.blend.append(res)
    return out


# ------------------------------------------------------------------------------------------------ metrics

def lpips_metric(device: str = "cpu"):
    """LPIPS v0.1 over ImageNet VGG16 (``models.metrics.LPIPS``) from the offline weight cache
    (``python -m blender_mrvm fetch-weights``; ``$MRVM_WEIGHTS_DIR``); build it once, pass it to :func:`scores`.
    Torch's global random state is left as it was (:func:`load_model`)."""
    import torch

    from .models.metrics import LPIPS
    from .synthesis.views import resolve_device

    with torch.random.fork_rng(devices=[]):
        return LPIPS().to(resolve_device(device)).eval()


def scores(pred, gt, lpips=None) -> dict[str, float]:
    """``eval``'s metrics of one image against its ground truth (``training.evaluate.scores_against``): ``psnr``
    (dB), ``ssim`` (pixelNeRF's: scikit-image defaults, 7x7 uniform window), ``ssim_gauss`` (Wang et al.: 11x11
    Gaussian, sigma 1.5) and, with ``lpips`` (:func:`lpips_metric`, or True to build one), ``lpips``. Images as
    everywhere here (HWC, uint8 or float [0, 1], sRGB; RGBA is mixed over white first); they must share a size.
    SSIM is NaN below 7 px (11 for ``ssim_gauss``), LPIPS needs 16 px."""
    from .training.evaluate import scores_against

    p, g = _image(pred), _image(gt)
    if p.shape != g.shape:
        raise InputError(f"prediction {p.shape} and ground truth {g.shape} differ in size")
    if lpips is True:
        lpips = lpips_metric()
    if lpips is not None and min(p.shape[:2]) < lpips.MIN_SIZE:
        raise InputError(f"LPIPS-VGG needs images of at least {lpips.MIN_SIZE} px a side, got {p.shape[1]}x"
                         f"{p.shape[0]} (pass lpips=None)")
    return scores_against(g, {"pred": p}, lpips)["pred"]
