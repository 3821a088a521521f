#!/bin/bash
# Session 46: fine-tune the shipped default on 71 real meshes (docs/real_meshes/render.sh train) exactly as a user
# does (`train --init shipped`, the panel's 2000 steps and 256 rays an object), at the fine-tuning policy's rate
# (training.config.FINETUNE: lr 1e-4) and at others named by a run config (lr_*.json); one torch thread a run.
#   docs/finetune_rate/run.sh LR SEED [ITERATIONS]     e.g. run.sh 1e-4 0; run.sh 1e-3 0
#   docs/finetune_rate/run.sh losses SEED               lr 1e-4 with the shipped model's own losses (losses.json)
set -e
cd "$(dirname "$0")/../.."
lr=$1; seed=$2; it=${3:-2000}
cfg=""; [ "$lr" = 1e-4 ] || cfg="--config docs/finetune_rate/lr_$lr.json"  # 1e-4: the policy itself, no config
name=lr$lr
if [ "$lr" = losses ]; then cfg="--config docs/finetune_rate/losses.json"; name=losses; fi
suffix=""; [ "$it" = 2000 ] || suffix="_i$it"
env OMP_NUM_THREADS=1 nice .venv/bin/python -m blender_mrvm train $cfg --init shipped \
  --data data/real_train_turntable64 --iterations "$it" --seed "$seed" --out "data/runs/ftr_${name}_s${seed}${suffix}"
