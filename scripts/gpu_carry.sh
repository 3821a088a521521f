#!/usr/bin/env bash
# What a GPU session carries to the device machine (docs/gpu_session.md): the device has no bpy and no network,
# and a call carries at most 64 MiB with the repository (~8 MB). Builds gpu_carry/ (git-ignored):
#   gpu_carry/data/<set>/    a rendered dataset without depth/, normal/ and transforms.json (training and eval
#                            read rgb, mask, pose, intrinsics and meta only): shapenet13_all is 34 MB this way
#   gpu_carry/weights/       ImageNet VGG16 blocks 1-3 (the `accurate`/`paper` encoder, 6.9 MB) and the LPIPS
#                            linear heads; the full VGG16 (57 MB, for the LPIPS loss) does not fit beside the data
# Usage: scripts/gpu_carry.sh [DATASET ...]   (default data/shapenet13_all); then carry ["gpu_carry"] and run with
#   MRVM_WEIGHTS_DIR=gpu_carry/weights PYTHONPATH=$PWD python3 -m blender_mrvm ... --data gpu_carry/data/<set>
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
SETS=("$@"); [ ${#SETS[@]} -gt 0 ] || SETS=(data/shapenet13_all)
rm -rf gpu_carry && mkdir -p gpu_carry/data gpu_carry/weights
grep -qx '/gpu_carry/' .git/info/exclude 2>/dev/null || { mkdir -p .git/info && echo '/gpu_carry/' >> .git/info/exclude; }
for s in "${SETS[@]}"; do
  tar -C "$(dirname "$s")" --exclude=depth --exclude=normal --exclude=transforms.json -cf - "$(basename "$s")" \
    | tar -C gpu_carry/data -xf -
done
$PY - <<'EOF'
from pathlib import Path
from safetensors.torch import load_file, save_file
from blender_mrvm.models import vgg
src = vgg.weights_dir()
full = load_file(str(src / vgg.VGG_FILE))
keep = {k: v for k, v in full.items() if int(k.split(".")[0]) < 16}  # conv1_1 .. relu3_3: the encoder's blocks
save_file(keep, "gpu_carry/weights/" + vgg.VGG_FILE)
save_file(load_file(str(src / vgg.LPIPS_FILE)), "gpu_carry/weights/" + vgg.LPIPS_FILE)
EOF
du -sb gpu_carry | awk '{printf "gpu_carry: %.1f MiB (the repository adds ~8 MB; a call carries 64 MiB)\n", $1 / 1048576}'
