#!/bin/bash
# Render the real-mesh sets (session 40) from pybullet_data (shared/DESIGN.md's offline real meshes;
# `pip install pybullet==3.2.7`, a test dependency), with the settings of the procedural held-out sets (64 px,
# Cycles 8 spp): the default model's turntable protocol (turntable64_heldout) and sphere64_heldout's sphere rig.
#   docs/real_meshes/render.sh [test|val|blobs|train]...   (default: test)
#   test:  13 real meshes, held out: real_turntable64 and real_sphere64
#   val:   13 other real meshes (robot and vehicle parts), turntable only: real_val_turntable64
#   blobs: 400 of pybullet's random shapes (random_urdfs 000-400 but 168), turntable, a training set: blobs_turntable64
#   train: 71 other real meshes (robot, vehicle and gripper parts, toys, a shelf, a stone), turntable, a training set
#          for fine-tuning (session 46): real_train_turntable64
# None of the test or val meshes is in any training set; the blobs share no file with them, and the real training
# meshes leave out every other version of a test or val mesh (its STL or low-resolution twin, its mirror, the
# other racecar wheels, the other mugs and trays, aliengo's trunk, calf and thigh, the jenga block).
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
  train)
    S=$(srcs a1/meshes/hip.obj bicycle/files/all_pedal_parts.stl bicycle/files/bike_rack.stl \
        bicycle/files/frame_scaled.stl bicycle/files/wheel_axels.stl bicycle/files/wheel_scaled.stl \
        toys/concave_box.obj toys/cube.obj toys/cylinder.obj toys/prism.obj toys/shape_sorter.obj \
        differential/diff_arm.stl differential/diff_carrier_cover.stl differential/diff_leftshaft.stl \
        differential/diff_motor_cover.stl differential/diff_pinion.stl differential/diff_ring.stl \
        differential/diff_side.stl differential/diff_spider.stl differential/diff_spider_shaft.stl \
        differential/diff_stand.stl franka_panda/meshes/visual/finger.obj franka_panda/meshes/visual/link2.obj \
        franka_panda/meshes/visual/link4.obj franka_panda/meshes/visual/link6.obj gripper/meshes/GUIDE_WSG50_110.stl \
        gripper/meshes/WSG-FMF.stl gripper/meshes/WSG50_110.stl gripper/meshes/l_gripper_tip_scaled.stl \
        husky/meshes/bumper.stl husky/meshes/top_plate.stl husky/meshes/user_rail.stl kiva_shelf/meshes/pod_lowres.stl \
        kuka_iiwa/meshes/finger_base_left.stl kuka_iiwa/meshes/finger_tip_left.stl kuka_iiwa/meshes/link_0.obj \
        kuka_iiwa/meshes/link_1.obj kuka_iiwa/meshes/link_3.obj kuka_iiwa/meshes/link_5.obj \
        kuka_iiwa/meshes/link_6.obj kuka_iiwa/meshes/link_7.obj l_finger.stl l_finger_tip.stl laikago/lower_leg3.obj \
        laikago/upper_leg_left.obj laikago/upper_leg_left2.obj mini_cheetah/meshes/mini_abad.obj \
        mini_cheetah/meshes/mini_body.obj mini_cheetah/meshes/mini_lower_link.obj \
        mini_cheetah/meshes/mini_upper_link.obj quadruped/microtaur/channel.stl quadruped/microtaur/d435i.stl \
        quadruped/microtaur/fr12_h101.stl quadruped/microtaur/fr13_s102.stl quadruped/microtaur/plate.stl \
        quadruped/microtaur/toe_brake.stl quadruped/microtaur/xavier.stl quadruped/microtaur/xm430w210.stl \
        racecar/meshes/cone.obj racecar/meshes/hokuyo.obj textured_sphere_smooth.obj stone.obj \
        torus/torus_textured.obj table_square/table.obj)
    # the xArm's links share their names with the Panda's (one object folder each): linked under other names (STL
    # files name no material library, so nothing is lost)
    X="$root/real_train_src"; mkdir -p "$X"
    for m in base link1 link2 link3 link4 link5 link6; do
      ln -sf "$P/xarm/xarm_description/meshes/xarm6/visual/$m.stl" "$X/xarm_$m.stl"; S="$S --source $X/xarm_$m.stl"
    done
    $PY -m blender_mrvm render-dataset $S --category real $COMMON --split train $TT \
        --out "$root/real_train_turntable64";;
  *) echo "render.sh: unknown set $what (test, val, blobs or train)" >&2; exit 2;;
  esac
done
