#!/bin/bash
# Session 46: score a checkpoint ($1) as $2 on the held-out sets of rule.md: the 13 real validation meshes and the
# 13 real test meshes (never trained on; the default's turntable, references 3 and 15, 10 targets) and the
# library's validation objects (shapenet13_all val, 39 x 6 targets).
#   docs/finetune_rate/score.sh CKPT NAME
set -e
cd "$(dirname "$0")/../.."
ck=$1; name=$2
E="env OMP_NUM_THREADS=1 nice .venv/bin/python -m blender_mrvm eval --threads 1 --device cpu --force"
O=data/eval/finetune_rate
$E --checkpoint $ck --out $O/rval_$name --data data/real_val_turntable64 --split val --input-views 3,15 --max-targets 10 >/dev/null
$E --checkpoint $ck --out $O/rtest_$name --data data/real_turntable64 --split test --input-views 3,15 --max-targets 10 >/dev/null
$E --checkpoint $ck --out $O/lib_$name --data data/shapenet13_all --split val --input-views 3,15 --max-targets 6 >/dev/null
