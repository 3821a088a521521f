#!/bin/bash
# Session 40: score a checkpoint ($1) as $2 on rule.md's validation sets (or, with "test", its test sets), paired
# against the shipped default's scores (made first, with name "shipped" and checkpoint "shipped").
#   docs/real_s40/score.sh CKPT NAME [val|test]
set -e
cd "$(dirname "$0")/../.."
ck=$1; name=$2; what=${3:-val}
E="env OMP_NUM_THREADS=1 nice .venv/bin/python -m blender_mrvm eval --threads 1 --device cpu --force"
O=data/eval/real_s40
cmp() { [ "$name" = shipped ] || echo "--compare-to $O/$1_shipped/eval.json"; }
run() { local set=$1; shift; $E --checkpoint $ck --out $O/${set}_$name $(cmp $set) "$@" > /dev/null; }
if [ "$what" = val ]; then
  run realval --data data/real_val_turntable64 --split val --input-views 3,15 --max-targets 10 &
  run ttval --data data/shapenet13_all --split val --input-views 3,15 --max-targets 6
  wait
else
  run t_real --data data/real_turntable64 --split test --input-views 3,15 --max-targets 10 &
  run t_turn --data data/turntable64_heldout --split train --input-views 3,15 --max-targets 10
  wait
  run t_all --data data/shapenet13_all --split test --input-views 3,15 --max-targets 6
fi
