#!/usr/bin/env bash
# MRVM against the identical model without it at three training budgets (issue 11), on `unseen` (train on
# airplane, car, chair; test on the other ten categories) or `all` (SETTING=all), the paper's recipe in two
# runs: a pretraining run (masking throughout for the MRVM arm; rays inside the object's box for its first
# 75%) of P steps, then a finetuning run of P/3 steps started from it (training.config.FINETUNE: no masking,
# lr 1e-4, whole image). One arm per call, so the two arms run side by side on two cores:
#   scripts/mrvm_budgets.sh mrvm & scripts/mrvm_budgets.sh base; SEED=1 ... for a second seed; RAYS=1024 ... for
#   4x the rays a step at the same number of updates; RESUME=1 to continue runs an earlier call left unfinished
#   (a budget longer than one session: each run resumes exactly from its newest checkpoint, every 1000 steps);
#   FT=official ... for the official code's finetune instead (2P steps at a constant lr 1e-3, no warm-up; runs named
#   budget_[all_][r$RAYS_]oft_...), which starts from the same pretraining run when it is finished (not rerun)
# then: python scripts/mrvm_budgets_table.py
# Needs data/shapenet13_$SETTING (make-shapenet --setting $SETTING --objects-per-category 30 --views 24 --resolution 64).
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
ARM=$1                              # mrvm | base | balanced_mrvm (the `balanced` preset, for bench tradeoff) | mrvm_bn (mrvm.head bn_relu)
BUDGETS=${BUDGETS:-"1000 3000 9000"} # pretraining steps; finetuning adds a third
SEED=${SEED:-0}
SETTING=${SETTING:-unseen}          # unseen | all
NAME=budget_; [ "$SETTING" = unseen ] || NAME=budget_${SETTING}_
CFG=blender_mrvm/assets/checkpoints/ablation/budget_unseen_$ARM.json
RAYS=${RAYS:-}                      # rays per object a step; unset: the recipe's 256. Set, the runs and evaluations
                                    # are named budget_[all_]r$RAYS_... and the table gives them their own rows
if [ -n "$RAYS" ]; then
  NAME=${NAME}r${RAYS}_
  mkdir -p data/runs && c=data/runs/${NAME}${ARM}.json
  $PY -c 'import json, sys; c = json.load(open(sys.argv[1])); c["train"]["rays_per_object"] = int(sys.argv[2]); json.dump(c, open(sys.argv[3], "w"), indent=1)' "$CFG" "$RAYS" "$c"
  CFG=$c
fi
PRE_NAME=$NAME                      # the pretraining runs are the same for either finetune
FT_CFG=$CFG
if [ "${FT:-}" = official ]; then
  NAME=${NAME}oft_
  mkdir -p data/runs && FT_CFG=data/runs/${NAME}${ARM}.json
  $PY -c 'import json, sys; from blender_mrvm.training.config import MRVM_OFFICIAL_FINETUNE as F; c = json.load(open(sys.argv[1])); c["train"].update(F); json.dump(c, open(sys.argv[2], "w"), indent=1)' "$CFG" "$FT_CFG"
elif [ -n "${FT:-}" ]; then
  echo "error: FT must be official or unset, not $FT" >&2; exit 2
fi
DATA=data/shapenet13_$SETTING
FRESH="--no-resume --force"; [ "${RESUME:-0}" = 1 ] && FRESH=""
EV="$PY -m blender_mrvm eval --data $DATA --max-objects-per-category 2 --max-targets 8 --threads 1"
for P in $BUDGETS; do
  F=$((P / 3)); [ "${FT:-}" = official ] && F=$((2 * P))
  R=data/runs/${NAME}${ARM}_s${SEED}_p$P; E=data/eval/${NAME}${ARM}_s${SEED}_p$P
  PRE=data/runs/${PRE_NAME}${ARM}_s${SEED}_p${P}_pre
  if [ "${FT:-}" = official ] && [ -d "$PRE/checkpoints/step_$(printf %07d "$P")" ]; then
    echo "pretraining $PRE is finished: the finetune starts from it"
  else
    $PY -m blender_mrvm train --config $CFG --data $DATA --iterations $P --seed $SEED --out $PRE $FRESH
  fi
  $PY -m blender_mrvm train --config $FT_CFG --data $DATA --init $PRE --iterations $F --seed $SEED --out $R $FRESH
  $EV --checkpoint $R --n-inputs 2 --out ${E}_2v --force
  $EV --checkpoint $R --n-inputs 1 --out ${E}_1v --force
done
