#!/usr/bin/env bash
# Held-out sets and models for scoring on the device machine (`gpu_session.sh score`, docs/gpu_session.md):
# evaluating `quality` on the CPU takes ~5 s a 64 px view (about an hour for a rule's validation sets and two
# models); on an H100 the same takes a few minutes of device time. The device has no bpy and no network, and the
# LPIPS score needs all 13 VGG16 convolutions, so they travel in fp16 (29 MB) beside slimmed copies of the sets.
# Usage: scripts/gpu_eval_pack.sh SET:SPLIT[:PER_CATEGORY] ... [-- MODEL.safetensors ...]
#   SET:SPLIT      a rendered dataset and the split to score (e.g. data/shapenet13_all:val); a set named twice
#                  keeps both splits
#   PER_CATEGORY   only the first K objects of each category of that split (as `eval --max-objects-per-category K`
#                  picks them); the carried split list names only those
#   MODEL          files copied to gpu_eval/models/ (score them there as gpu_eval/models/<name>)
# Writes gpu_eval/eval.tgz (git-ignored): carry ["gpu_eval"]; `gpu_session.sh score` unpacks it. Depth and
# normal maps stay behind (no depth error is scored there).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
specs=(); models=()
while [ $# -gt 0 ]; do
  if [ "$1" = -- ]; then shift; models=("$@"); break; fi
  specs+=("$1"); shift
done
[ ${#specs[@]} -gt 0 ] || { echo "usage: $0 SET:SPLIT[:PER_CATEGORY] ... [-- MODEL ...]" >&2; exit 2; }
stage=$(mktemp -d); trap 'rm -rf "$stage"' EXIT
mkdir -p "$stage/data" "$stage/weights" "$stage/models"
for spec in "${specs[@]}"; do
  IFS=: read -r set split k <<< "$spec"
  [ -f "$set/splits/$split.lst" ] || { echo "error: $set has no split $split" >&2; exit 2; }
  name=$(basename "$set")
  list=$(awk -F/ -v k="${k:-0}" 'k == 0 || n[$1]++ < k' "$set/splits/$split.lst")
  mkdir -p "$stage/data/$name/splits"
  cp "$set/mrvm_dataset.json" "$stage/data/$name/"
  cp "$set"/splits/*.json "$stage/data/$name/splits/" 2>/dev/null || true
  printf '%s\n' $list > "$stage/data/$name/splits/$split.lst"
  tar -C "$set" --exclude=depth --exclude=normal -cf - $list | tar -C "$stage/data/$name" -xf -
done
for m in "${models[@]}"; do cp "$m" "$stage/models/"; done
$PY scripts/carry_weights.py "$stage/weights" --full --half
grep -qx '/gpu_eval/' .git/info/exclude || echo '/gpu_eval/' >> .git/info/exclude
mkdir -p gpu_eval && tar -C "$stage" -cf - data weights models | gzip -6 > gpu_eval/eval.tgz
du -sb gpu_eval/eval.tgz | awk '{printf "gpu_eval/eval.tgz: %.1f MiB (the tracked tree is ~14 MB; a call carries 64 MiB)\n", $1 / 1048576}'
