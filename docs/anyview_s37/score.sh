#!/bin/bash
# Session 37: score a checkpoint ($1) as $2 on the validation sets of rule.md, paired against stage 3's scores
# (made first with name "shipped"). ./score.sh CKPT NAME [test]: "test" scores the test sets instead.
# BASE=a9k pairs against that candidate's scores instead of stage 3's (the near-turntable probe).
# ONLY="near fine" scores only those sets (two lanes on two cores). EVAL_DIR=s38 writes under data/eval/s38 instead (session 38's stage 5: there "shipped" is stage 4).
set -e
cd "$(dirname "$0")/../.."
ck=$1; name=$2; what=${3:-val}
E="env OMP_NUM_THREADS=1 nice .venv/bin/python -m blender_mrvm eval --threads 1 --device cpu --force"
O=data/eval/${EVAL_DIR:-s37}
base=${BASE:-shipped}
cmp() { [ "$name" = shipped ] || echo "--compare-to $O/$1_$base/eval.json"; }
run() { local set=$1; shift; [ -z "$ONLY" ] || [[ " $ONLY " == *" $set "* ]] || return 0; $E --checkpoint $ck --out $O/${set}_$name $(cmp $set) "$@" > /dev/null; }
if [ "$what" = val ]; then
  run sphval_a --data data/sphere64_val --split train --n-inputs 2 --max-targets 10
  run sphval_b --data data/sphere64_val --split test --n-inputs 2 --max-targets 10
  run near --data data/near_turntable64 --split train --n-inputs 2 --max-targets 8
  run fine --data data/fine_turntable64 --split train --n-inputs 2 --max-targets 8
  run ttval --data data/shapenet13_all --split val --input-views 3,15 --max-targets 6
else
  run t_sphere --data data/sphere64_heldout --split train --n-inputs 2 --max-targets 10
  run t_near --data data/near_turntable64 --split test --n-inputs 2 --max-targets 8
  run t_fine --data data/fine_turntable64 --split test --n-inputs 2 --max-targets 8
  run t_turn --data data/turntable64_heldout --split train --n-inputs 2 --max-targets 10
  run t_all --data data/shapenet13_all --split test --input-views 3,15 --max-targets 6
fi
