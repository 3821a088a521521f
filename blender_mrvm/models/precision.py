"""Inference precision: fp32, or bf16 / fp16 autocast around a model's forward passes (fp16 on a GPU only).

One owner for the benches (``bench model``, ``bench tradeoff``) and synthesis (``synthesize --precision``).
Measured (RECIPE.md "Session 31", ``bench tradeoff --device cuda``, an H100, 128 px views): `quality` renders 1.21x
faster in bf16 and 1.23x in fp16 at the same PSNR and LPIPS (19.88 dB / 0.237 on 13 held-out objects); session 32
scored the default, any-view and GPNR models in bf16 on an H100 within 0.004 dB and 0.0004 LPIPS of their fp32
scores (Sem2NeRF 0.016 dB; 13 held-out objects x 4 views, fp32 scored on the CPU, which matched the GPU's fp32 per
view in session 31; docs/bench_gpu/session32), and session 23 timed them 1.04-1.10x faster in bf16 at 256 px. On the
CPU bf16 scores as fp32 does but is no faster for NeRFormer (session 34, a Zen 4 box with AVX-512 BF16,
docs/bench_quality_cpu: the default 0.82 -> 1.02 s a 128 px view at 19.20 / 0.787 / 0.207 against 19.21 / 0.787 /
0.206; an SSIM loss of 0.07-0.14 recorded before was the benchmark scoring in bf16 too). So synthesis's default,
``auto``, is bf16 on a GPU and fp32 on the CPU (:func:`resolve_precision`)."""

from __future__ import annotations

import contextlib

from ..errors import InputError

PRECISIONS = ("fp32", "bf16", "fp16")
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
        raise InputError(f"{option} fp16 needs a GPU (--device cuda); on the CPU use fp32 or bf16")


def resolve_precision(precision: str, device: str) -> str:
    """``auto``: bf16 on a GPU (the same scores, faster: module docstring), fp32 on the CPU; else ``precision``."""
    if precision != "auto":
        return precision
    return "bf16" if str(device).startswith("cuda") else "fp32"


def autocast(precision: str, device: str):
    """The context a forward pass runs in at ``precision`` on ``device`` (a no-op for fp32)."""
    if precision == "fp32":
        return contextlib.nullcontext()
    import torch

    dtype = {"bf16": torch.bfloat16, "fp16": torch.float16}[precision]
    return torch.autocast("cuda" if str(device).startswith("cuda") else "cpu", dtype=dtype)
