#!/bin/bash
# Render the real-mesh sets (session 40) from pybullet_data (shared/DESIGN.md's offline real meshes;
# `pip install pybullet==3.2.7`, a test dependency), with the settings of the procedural held-out sets (64 px,
# Cycles 8 spp): the default model's turntable protocol (turntable64_heldout) and sphere64_heldout's sphere rig.
#   docs/real_meshes/render.sh [test|val|blobs]...   (default: test)
#   test:  13 real meshes, held out: real_turntable64 and real_sphere64
#   val:   13 other real meshes (robot and vehicle parts), turntable only: real_val_turntable64
#   blobs: 400 of pybullet's random shapes (random_urdfs 000-400 but 168), turntable, a training set: blobs_turntable64
# None of the test or val meshes is in any training set; the blobs share no file with them.
set -e
cd "$(dirname "$0")/../.."
root=${ROOT:-data}
PY=${PY:-.venv/bin/python}
P=$($PY -c "import pybullet_data; print(pybullet_data.getDataPath())")
COMMON="--views 24 --resolution 64 --samples 8 --seed 1000"
TT="--rig turntable --fov 40 --elevation 30"
srcs() { for m in "$@"; do printf -- "--source %s " "$P/$m"; done; }
for what in ${*:-test}; do
  case $what in
  test)  # textured (duck, table, tray, laikago chassis, a1 trunk, panda hand), coloured by material (soccerball,
         # mug, kuka link), bare (bunny, teddy as convex pieces, husky base STL; lego, whose lego.mtl is not shipped)
    S=$(srcs duck.obj teddy2_VHACD_CHs.obj bunny.obj soccerball.obj objects/mug.obj lego/lego.obj table/table.obj \
        tray/tray_textured.obj laikago/chassis.obj a1/meshes/trunk.obj kuka_iiwa/meshes/link_4.obj \
        husky/meshes/base_link.stl franka_panda/meshes/visual/hand.obj)
    $PY -m blender_mrvm render-dataset $S --category real $COMMON --split test $TT --out "$root/real_turntable64"
    $PY -m blender_mrvm render-dataset $S --category real $COMMON --split test --rig sphere --fov-range 30,60 \
        --distance-range 0.85,1.6 --out "$root/real_sphere64";;
  val)
    S=$(srcs franka_panda/meshes/visual/link1.obj franka_panda/meshes/visual/link3.obj \
        franka_panda/meshes/visual/link5.obj kuka_iiwa/meshes/link_2.obj laikago/hip_motor.obj a1/meshes/calf.obj \
        a1/meshes/thigh.obj husky/meshes/wheel.stl racecar/meshes/left_front_wheel.obj differential/diff_carrier.stl \
        bicycle/files/handlebar_scaled.stl quadruped/tmotor3.obj domino/domino.obj)
    $PY -m blender_mrvm render-dataset $S --category real $COMMON --split val $TT --out "$root/real_val_turntable64";;
  blobs)
    # 168 is left out: its OBJ has NaN vertices (render-dataset refuses it)
    S=$(for i in $(seq -f %03g 0 400); do [ $i = 168 ] || printf "random_urdfs/%s/%s.obj " $i $i; done)
    $PY -m blender_mrvm render-dataset $(srcs $S) --category blob $COMMON --split train $TT \
        --out "$root/blobs_turntable64";;
  *) echo "render.sh: unknown set $what (test, val or blobs)" >&2; exit 2;;
  esac
done
