"""Inference precision: fp32, bf16 / fp16 autocast around a model's forward passes (fp16 on a GPU only), or int8
(the CPU only): the model's linear layers with int8 weights (per output channel) and activations quantized per
batch on the fly (PyTorch's dynamic quantization; :func:`for_precision`).

One owner for the benches (``bench model``, ``bench tradeoff``) and synthesis (``synthesize --precision``).
Measured (RECIPE.md "Session 31", ``bench tradeoff --device cuda``, an H100, 128 px views): `quality` renders 1.21x
faster in bf16 and 1.23x in fp16 at the same PSNR and LPIPS (19.88 dB / 0.237 on 13 held-out objects); session 32
scored the default, any-view and GPNR models in bf16 on an H100 within 0.004 dB and 0.0004 LPIPS of their fp32
scores (Sem2NeRF 0.016 dB; 13 held-out objects x 4 views, fp32 scored on the CPU, which matched the GPU's fp32 per
view in session 31; docs/bench_gpu/session32), and session 23 timed them 1.04-1.10x faster in bf16 at 256 px. On the
CPU bf16 scores as fp32 does but is no faster for NeRFormer (session 34, a Zen 4 box with AVX-512 BF16,
docs/bench_quality_cpu: the default 0.82 -> 1.02 s a 128 px view at 19.20 / 0.787 / 0.207 against 19.21 / 0.787 /
0.206; an SSIM loss of 0.07-0.14 recorded before was the benchmark scoring in bf16 too). So synthesis's default,
``auto``, is bf16 on a GPU.

On the CPU int8 pays instead where the linear layers are wide (session 36, docs/bench_int8, the 2-core box, a
128 px view with synthesize's 2 chunk workers, fp32 and int8 alternated): the shipped `quality` (layers 64-256 wide)
12.28 -> 9.45 s (1.30x; 1.29-1.35x on one core), the room GPNR 8.61 -> 7.25 s (1.19x); for the 32-48-wide default,
any-view and object GPNR models 0.93-1.08x, i.e. nothing. `quality` scores the same in int8 (13 held-out sphere-rig
objects: 20.09 dB / LPIPS 0.214 both; a view within 53 dB of its fp32 render); the room GPNR loses a little
(-0.04 dB, LPIPS +0.0007 on 6 held-out rooms; 30 dB from fp32). So ``auto`` is int8 on the CPU for a wide enough
model (:data:`INT8_MIN_WIDTH`) of a kind int8 leaves as it is (``int8_auto``: NeRFormer, not GPNR), else fp32."""

from __future__ import annotations

import contextlib

from ..errors import InputError

PRECISIONS = ("fp32", "bf16", "fp16", "int8")
SYNTH_PRECISIONS = ("auto", *PRECISIONS)
"""What synthesis takes (``synthesize --precision``, the panel): ``auto`` resolves by the device."""

CPU_BF16_NOTE = ("bf16 on the CPU renders the same views as fp32 but no faster (docs/bench_quality_cpu); "
                 "it pays on a GPU")


def check_precision(option: str, precision: str, device: str | None = None, auto: bool = False) -> None:
    """One-line :class:`InputError` for a precision that is unknown or, fp16, asked of the CPU (``device`` None:
    the device is not known yet, only the name is checked); ``auto`` allows :data:`SYNTH_PRECISIONS`' ``auto``."""
    names = SYNTH_PRECISIONS if auto else PRECISIONS
    if precision not in names:
        raise InputError(f"{option} must be one of {', '.join(names)}, got {precision!r}")
    if device is not None and precision == "fp16" and not str(device).startswith("cuda"):
        raise InputError(f"{option} fp16 needs a GPU (--device cuda); on the CPU use fp32, bf16 or int8")
    if device is not None and precision == "int8" and str(device).startswith("cuda"):
        raise InputError(f"{option} int8 runs on the CPU only (PyTorch's dynamic quantization); on a GPU use bf16 "
                         "or fp16")


INT8_MIN_WIDTH = 60
"""int8 pays on the CPU for a model whose linear layers are at least this wide: the narrow side of each layer,
weighted by its weights (:func:`linear_width`). Its input is quantized on every call, a cost only wide enough
products repay (session 36, docs/bench_int8, 128 px, 2 chunk workers): `quality` (width 64) 1.30x, the room GPNR
(64) 1.19x; the object GPNR (48) 1.02-1.08x, the default and any-view models (32) 0.93-1.07x. With random weights
and one thread (``bench model``): `fast` (24) 0.77x, `accurate` 1.25x, GPNR `accurate` (128) 1.67x."""


def linear_width(model) -> float:
    """The narrow side (min of in and out features) of ``model``'s linear layers, weighted by their weights; 0
    without any."""
    import torch

    lin = [m for m in model.modules() if isinstance(m, torch.nn.Linear)]
    n = sum(m.weight.numel() for m in lin)
    return sum(min(m.in_features, m.out_features) * m.weight.numel() for m in lin) / n if n else 0.0


def resolve_precision(precision: str, device: str, model=None, compiled: bool = False) -> str:
    """``auto``: bf16 on a GPU; on the CPU int8 for a ``model`` wide enough for it to pay (:data:`INT8_MIN_WIDTH`)
    whose kind int8 leaves as it is (``int8_auto``) and not ``compiled``, else fp32 (module docstring); any other
    ``precision`` as it is."""
    if precision != "auto":
        return precision
    if str(device).startswith("cuda"):
        return "bf16"
    return ("int8" if model is not None and not compiled and getattr(model, "int8_auto", False)
            and linear_width(model) >= INT8_MIN_WIDTH else "fp32")


def for_precision(model, precision: str, inplace: bool = False):
    """The model to run at ``precision``: ``model`` itself unless int8, which gives its linear layers int8 weights,
    one scale per output channel (``inplace``: ``model``'s own layers are replaced; else a copy is). Refuses a model
    on a GPU. Autocast (:func:`autocast`) is what the float precisions need instead."""
    if precision != "int8":
        return model
    # (dynamic quantization scales a layer's input once per call, over a whole chunk of rays: under int8 a ray's
    # colour moves with the rays beside it in its chunk, by int8's own rounding (up to ~7/255 on `quality`, 53 dB
    # from fp32 either way): --chunk and --skip-empty cull change pixels by that much, where fp32 is exact)
    import warnings

    import torch
    from torch.ao.quantization import per_channel_dynamic_qconfig, quantize_dynamic

    if any(p.device.type != "cpu" for p in model.parameters()):
        raise InputError("int8 runs on the CPU only; this model is on a GPU")
    with warnings.catch_warnings():  # torch 2.13 flags the quantized tensor type as deprecated; the pin keeps it
        warnings.simplefilter("ignore")
        return quantize_dynamic(model, {torch.nn.Linear: per_channel_dynamic_qconfig}, dtype=torch.qint8,
                                inplace=inplace)


def autocast(precision: str, device: str):
    """The context a forward pass runs in at ``precision`` on ``device`` (a no-op for fp32 and int8: int8 is in
    the weights, :func:`for_precision`)."""
    if precision in ("fp32", "int8"):
        return contextlib.nullcontext()
    import torch

    dtype = {"bf16": torch.bfloat16, "fp16": torch.float16}[precision]
    return torch.autocast("cuda" if str(device).startswith("cuda") else "cpu", dtype=dtype)
