#!/usr/bin/env bash
# References per view in a dense capture (eval --nearest K): each protocol target rendered from its K nearest
# other views, for objects (24-view turntable and sphere rigs, held-out objects) and capture-like rooms (24
# photos on a path, held-out rooms). One thread, sequential; quality only (time: bench tradeoff --axes nearest).
#   scripts/nearest_sweep.sh [objects|sphere|rooms]...
set -eu
cd "$(dirname "$0")/.."
PY=${PY:-.venv/bin/python}
EV="$PY -m blender_mrvm eval --split train --threads 1 --force"
[ $# -gt 0 ] || set -- objects sphere rooms
for what in "$@"; do
  case $what in
    objects) for K in 2 3 5 10; do
        $EV --checkpoint shipped --data data/turntable64_heldout --max-targets 6 --nearest $K --out data/eval/nearest_turntable_k$K
      done ;;
    sphere) for K in 2 3 5 10; do
        $EV --checkpoint shipped:mrvm_anyview --data data/sphere64_heldout --max-targets 6 --nearest $K --out data/eval/nearest_sphere_k$K
      done ;;
    rooms) for K in 2 3 4 6 10; do
        $EV --checkpoint shipped:gpnr_captures --data data/captures64_heldout --n-inputs 2 --nearest $K --out data/eval/nearest_rooms_k$K
      done ;;
  esac
done
