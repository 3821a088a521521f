"""The ImageNet VGG16 and LPIPS weights a device call carries (no network there): one owner for
`scripts/gpu_carry.sh` (training: blocks 1-3 unless FULL_VGG) and `scripts/gpu_eval_pack.sh` (LPIPS: all 13
convolutions, fp16).

    python scripts/carry_weights.py OUT_DIR [--full] [--half]

--full   all 13 convolutions (the LPIPS loss and score need them: 57 MB, 29 MB with --half); default conv1_1 ..
         relu3_3 (the `accurate` / `paper` encoder)
--half   store them in fp16 (they load into fp32 layers: half the bytes, ~1e-3 relative rounding)
--int8   convolution kernels in int8 with a scale per output channel (a quarter of the bytes: 15 MB with --full);
         for the LPIPS *loss* of a training call whose data leaves no room for the fp16 file (LPIPS within 1 %,
         models.vgg.quantize_int8); never for scoring"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    from safetensors.torch import load_file, save_file

    from blender_mrvm.models import vgg

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out", type=Path)
    p.add_argument("--full", action="store_true")
    p.add_argument("--half", action="store_true")
    p.add_argument("--int8", action="store_true")
    a = p.parse_args(argv)
    src = vgg.weights_dir()
    full = load_file(str(src / vgg.VGG_FILE))
    keep = full if a.full else {k: v for k, v in full.items() if int(k.split(".")[0]) < 16}  # conv1_1 .. relu3_3
    if a.int8:
        keep = vgg.quantize_int8(keep)
    elif a.half:
        keep = {k: v.half() for k, v in keep.items()}
    a.out.mkdir(parents=True, exist_ok=True)
    save_file(keep, str(a.out / vgg.VGG_FILE))
    save_file(load_file(str(src / vgg.LPIPS_FILE)), str(a.out / vgg.LPIPS_FILE))
    return 0


if __name__ == "__main__":
    sys.exit(main())
