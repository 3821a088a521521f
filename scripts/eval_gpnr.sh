#!/usr/bin/env bash
# The GPNR evaluations of RECIPE.md: GPNR beside NeRFormer+MRVM with 2, 5 and 10 reference views, and the
# equal-budget ablations (after training the four configs in blender_mrvm/assets/checkpoints/ablation/gpnr_*.json).
# Needs data/shapenet13_all (make-shapenet --setting all --objects-per-category 30 --resolution 64).
set -u
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
ev() { $PY -m blender_mrvm eval --data data/shapenet13_all --threads 1 --force "$@"; }  # reruns replace their scores
V2=3,15; V5=1,6,11,16,21; V10=0,2,5,7,10,12,14,17,19,22
for m in gpnr nerformer; do
  ck=shipped:gpnr; [ $m = nerformer ] && ck=shipped
  ev --checkpoint $ck --input-views $V2 --max-objects-per-category 2 --max-targets 6 --out data/eval/cmp_${m}_2v
  ev --checkpoint $ck --input-views $V5 --max-objects-per-category 2 --max-targets 6 --out data/eval/cmp_${m}_5v
  ev --checkpoint $ck --input-views $V10 --max-objects-per-category 1 --max-targets 4 --out data/eval/cmp_${m}_10v
done
for v in base features norays nocoords; do
  [ -d data/runs/gpnr_abl_$v ] && ev --checkpoint data/runs/gpnr_abl_$v --input-views $V5 --max-objects-per-category 1 \
      --max-targets 6 --out data/eval/abl_$v
done
