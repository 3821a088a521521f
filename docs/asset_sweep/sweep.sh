#!/usr/bin/env bash
# Render every mesh file under the given folders on its own (render-dataset, 4 views at 32 px, 4 samples) and
# print one line per file: its exit code, the path, its error/warning lines, traceback count and non-progress
# line count. Session 41's sweeps (README.md here):
#   apt-get download assimp-testmodels && dpkg-deb -x assimp-testmodels_*.deb /tmp/atm
#   M=/tmp/atm/usr/share/assimp/models; docs/asset_sweep/sweep.sh /tmp/sweep $M/OBJ $M/PLY $M/STL $M/OFF $M/glTF2 $M/FBX
#   session 42, the formats read with assimp: docs/asset_sweep/sweep.sh /tmp/sweep_assimp $M/Collada $M/FBX $M/3DS \
#       $M/LWO $M/X $M/AC $M/ASE $M/3MF $M/MS3D
#   docs/asset_sweep/sweep.sh /tmp/pbsweep "$(.venv/bin/python -c 'import pybullet_data as p; print(p.getDataPath())')"
set -u
out=$1; shift
PY=${PY:-$(cd "$(dirname "$0")/../.." && pwd)/.venv/bin/python}
VIEWS=${VIEWS:-4}
mkdir -p "$out"
find "$@" -type f \( -iname "*.obj" -o -iname "*.ply" -o -iname "*.stl" -o -iname "*.off" -o -iname "*.gltf" \
    -o -iname "*.glb" -o -iname "*.fbx" -o -iname "*.dae" -o -iname "*.3ds" -o -iname "*.lwo" -o -iname "*.x" \
    -o -iname "*.ac" -o -iname "*.ase" -o -iname "*.3mf" -o -iname "*.ms3d" -o -iname "*.x3d" -o -iname "*.amf" -o -iname "*.dxf" \) | grep -v " " | grep -v random_urdfs | sort | awk '{printf "%03d %s\n", NR, $0}' > "$out/list.txt"
while read -r n f; do
    timeout 300 "$PY" -m blender_mrvm render-dataset --source "$f" --views "$VIEWS" --resolution 32 --samples 4 \
        --out "$out/d$n" > "$out/o$n.txt" 2>&1
    rc=$?
    echo "$n rc=$rc $f | $(grep -E '^(error|warning)' "$out/o$n.txt" | tr '\n' ' ' | cut -c1-220)" \
         "tb=$(grep -c Traceback "$out/o$n.txt") lines=$(grep -vc '^render:' "$out/o$n.txt")"
done < "$out/list.txt"
