#!/usr/bin/env bash
# What a GPU session carries to the device machine (docs/gpu_session.md): the device has no bpy and no network,
# and a call carries at most 64 MiB with the tracked tree (~14 MB; .git does not travel, session 31); many small
# files count for more than their bytes (session 18: 42 MB of PNGs was refused, the same gzipped into one file, 32 MB, went).
# Builds gpu_carry/ and packs it into gpu_pack/carry.tgz (both git-ignored): carry ["gpu_pack"] and unpack there
# (scripts/gpu_session.sh does, when gpu_carry/ is absent). gpu_carry/ holds:
#   gpu_carry/data/<set>/    a rendered dataset without depth/ and normal/ (training and eval read rgb, mask, pose,
#                            intrinsics, transforms.json and meta): shapenet13_all is 34 MB this way, its train
#                            split alone (SPLITS=train) 24 MB. transforms.json stays: a sphere-rig set's views have
#                            their own fields of view and only it holds them (session 18 dropped it, and the
#                            loader then silently gave every view the first one's; it now refuses)
#   gpu_carry/weights/       ImageNet VGG16 blocks 1-3 (the `accurate`/`paper` encoder, 6.9 MB) and the LPIPS
#                            linear heads; the full VGG16 (57 MB, for the LPIPS loss) does not fit beside the data
# Usage: [SPLITS="train"] [MAX_OBJECTS=N] [PER_CATEGORY=K] [DEPTH=1] [HALF=1] [FULL_VGG=1] [INT8=1] scripts/gpu_carry.sh [DATASET ...]
#   (default data/shapenet13_all); then carry ["gpu_carry"] and run with
#   MRVM_WEIGHTS_DIR=gpu_carry/weights PYTHONPATH=$PWD python3 -m blender_mrvm ... --data gpu_carry/data/<set>
#   SPLITS   keep only the objects these splits list (space-separated, e.g. "train" or "train test"); default all
#   MAX_OBJECTS  with SPLITS: only the first N objects the lists name (e.g. SPLITS=test MAX_OBJECTS=2: a set for
#            timing Sem2NeRF on the GPU, `gpu_session.sh fps`); the carried splits' lists are cut to the objects kept
#   PER_CATEGORY  with SPLITS: only the first K objects of each category (the lists run category by category, so
#            MAX_OBJECTS alone would keep the first categories): both training sets fit one call this way
#            (SPLITS=train PER_CATEGORY=12 HALF=1 for data/shapenet13_all and data/sphere64_train)
#   DEPTH=1  keep depth/ (the depth loss needs it: about 60 kB an object), and the OpenEXR wheel for the device's
#            Python 3.12 in gpu_carry/whl/ (1.7 MB; the device has no OpenEXR, session 32's depth run failed at its
#            first step): `pip download` from the package registry here, at set-up time; gpu_session.sh installs it
#   HALF=1   store the weights in fp16 (they load into fp32 layers: half the bytes, ~1e-3 relative rounding)
#   FULL_VGG=1  all 13 VGG16 convolutions (the LPIPS loss needs them: 57 MB, 29 MB with HALF=1)
#   INT8=1   kernels in int8 with a scale per channel (15 MB with FULL_VGG=1; the LPIPS loss moves under 1 %, session
#            32): room for both training sets beside the LPIPS loss. Never for scoring (gpu_eval_pack.sh stays fp16)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
SETS=("$@"); [ ${#SETS[@]} -gt 0 ] || SETS=(data/shapenet13_all)
rm -rf gpu_carry && mkdir -p gpu_carry/data gpu_carry/weights
grep -qx '/gpu_carry/' .git/info/exclude 2>/dev/null || { mkdir -p .git/info && echo '/gpu_carry/' >> .git/info/exclude; }
EXCL=(--exclude=normal)
[ "${DEPTH:-0}" = 1 ] || EXCL+=(--exclude=depth)
for s in "${SETS[@]}"; do
  name=$(basename "$s")
  if [ -n "${SPLITS:-}" ]; then  # the split lists, the set's settings and the listed objects only
    list=$(for sp in $SPLITS; do cat "$s/splits/$sp.lst"; done | awk -F/ -v k="${PER_CATEGORY:-0}" \
      'k == 0 || n[$1]++ < k' | head -n "${MAX_OBJECTS:-1000000}" | sed "s|^|$name/|")
    tar -C "$(dirname "$s")" "${EXCL[@]}" -cf - "$name/mrvm_dataset.json" "$name/splits" $list | tar -C gpu_carry/data -xf -
    # the carried splits' lists name the carried objects only (the loaders refuse a split with objects missing)
    for sp in $SPLITS; do
      grep -xF -f <(printf '%s\n' $list | sed "s|^$name/||") "$s/splits/$sp.lst" > "gpu_carry/data/$name/splits/$sp.lst" || true
    done
  else
    tar -C "$(dirname "$s")" "${EXCL[@]}" -cf - "$name" | tar -C gpu_carry/data -xf -
  fi
done
$PY scripts/carry_weights.py gpu_carry/weights $([ "${FULL_VGG:-0}" = 1 ] && echo --full) $([ "${HALF:-0}" = 1 ] && echo --half) $([ "${INT8:-0}" = 1 ] && echo --int8)
grep -qx '/gpu_pack/' .git/info/exclude || echo '/gpu_pack/' >> .git/info/exclude
parts=(data weights)
if [ "${DEPTH:-0}" = 1 ]; then
  exr=$($PY -c "import OpenEXR; print(OpenEXR.__version__)")
  $PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 -d gpu_carry/whl "OpenEXR==$exr" \
    || { echo "error: could not fetch the OpenEXR $exr wheel for the device (a depth loss there needs it)" >&2; exit 2; }
  parts+=(whl)
fi
mkdir -p gpu_pack && tar -C gpu_carry -cf - "${parts[@]}" | gzip -6 > gpu_pack/carry.tgz
du -sb gpu_carry | awk '{printf "gpu_carry: %.1f MiB\n", $1 / 1048576}'
du -sb gpu_pack/carry.tgz | awk '{printf "gpu_pack/carry.tgz: %.1f MiB\n", $1 / 1048576}'
# What a call carrying ["gpu_pack"] (and gpu_old/, when it is here: the runbook's fallback tree) takes of the 64 MiB:
# the tracked tree and the untracked files git does not ignore travel too (.git does not). The tree was 13 MiB in
# session 31 and 19.5 MiB on 2026-11-29, so a pack that fitted once may not fit now (session 32's 45.3 MiB does not).
if [ "$(git rev-parse --show-toplevel 2>/dev/null)" = "$PWD" ]; then
  tree=$( { git ls-files -z; git ls-files -z --others --exclude-standard; } | xargs -0 -r du -cb 2>/dev/null \
    | awk '$2 == "total" {s += $1} END {print s + 0}')
  pack=$(du -sb gpu_pack | cut -f1); old=0
  [ -d gpu_old ] && git check-ignore -q gpu_old && old=$(du -sb gpu_old | cut -f1)
  total=$((tree + pack + old))
  awk -v t="$tree" -v p="$pack" -v o="$old" -v a="$total" 'BEGIN {printf "a call carrying [\"gpu_pack\"%s]: %.1f MiB (tree %.1f, gpu_pack %.1f, gpu_old %.1f) of 64 MiB\n", (o > 0 ? ", \"gpu_old\"" : ""), a / 1048576, t / 1048576, p / 1048576, o / 1048576}'
  if [ "$total" -gt $((64 * 1048576)) ]; then
    echo "error: over the 64 MiB a call carries: the call would be refused; carry fewer objects (PER_CATEGORY) or sets" >&2
    exit 3
  fi
fi
