#!/bin/bash
# Session 35 probe: score a checkpoint ($1, name $2) on the three sets of data/notes/q35_rule.md, paired against
# the shipped quality file's scores on the same views (made first with name "shipped").
set -e
cd /work/main
ck=$1; name=$2
E="env OMP_NUM_THREADS=1 nice .venv/bin/python -m blender_mrvm eval --threads 1 --device cpu --force"
cmp() { [ "$name" = shipped ] || echo "--compare-to data/eval/q35_$1_shipped/eval.json"; }
$E --checkpoint $ck --data data/shapenet13_all --split val --n-inputs 2 --max-objects-per-category 1 \
   --max-targets 4 --out data/eval/q35_ttval_$name $(cmp ttval)
$E --checkpoint $ck --data data/shapenet13_all --split train --input-views 3,15 --max-objects-per-category 2 \
   --max-targets 6 --out data/eval/q35_train_$name $(cmp train)
$E --checkpoint $ck --data data/sphere64_val --split train --n-inputs 2 --max-objects-per-category 1 \
   --max-targets 4 --out data/eval/q35_sphval_$name $(cmp sphval)
