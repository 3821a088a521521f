#!/bin/bash
# Session 40: score the shipped object models on the real-mesh sets (render.sh) and, for comparison, on the
# procedural held-out sets with the same cameras and protocol (turntable64_heldout, sphere64_heldout: 13 objects,
# 2 references, 10 targets each, as score.sh's t_turn / t_sphere). Two lanes (one per core), 1 thread each.
# Usage: docs/real_meshes/score.sh [MODELS...]   (default: the four below; `auto` is also known, and picks the
# default on the turntable sets and the any-view model on the sphere sets; `quality` runs int8, its CPU default)
set -e
cd "$(dirname "$0")/../.."
O=data/eval/real
E="env OMP_NUM_THREADS=1 nice .venv/bin/python -m blender_mrvm eval --threads 1 --device cpu --force --split"
models=${*:-default anyview gpnr quality}
ck() { case $1 in default) echo shipped;; anyview) echo shipped:mrvm_anyview;; gpnr) echo shipped:gpnr;;
       quality) echo shipped:mrvm_quality;; auto) echo shipped:auto;; esac; }
# the references of the procedural sets' own protocol (splits/eval_views.json): turntable views 3 and 15, sphere 0 and 1
refs() { case $1 in *turntable*) echo 3,15;; *) echo 0,1;; esac; }
one() { local set=$1 split=$2 m=$3; $E $split --data data/$set --checkpoint $(ck $m) --input-views $(refs $set) --max-targets 10 \
        --out $O/${set}_$m > $O/logs/${set}_$m.log 2>&1 && echo "$(date +%T) done ${set}_$m"; }
mkdir -p $O/logs
lane() { for m in $models; do one $1 $2 $m; one $3 $4 $m; done; }
lane real_turntable64 test turntable64_heldout train &
lane real_sphere64 test sphere64_heldout train &
wait
