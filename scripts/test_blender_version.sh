#!/usr/bin/env bash
# The tests that use Blender, under another Blender than the pinned bpy 5.0.1: the extension's manifest says
# Blender 4.2 and later (blender_version_min), so `make test` also runs them under 4.2 LTS (.ci/run).
#   scripts/test_blender_version.sh 4.2.23       (or: make test-blender BPY=4.2.23)
# The venv .venv-bpy$BPY holds that bpy and every other package at the main venv's versions (made once, ~1 min,
# a 350 MB wheel); the project is installed editable, so the tests run the working tree. Pass criterion: the
# JUnit report (the bpy 4.x modules can crash or stall while the interpreter exits, after the tests ran).
# Left out, with the reason (under 4.x; 5.1+ below): tests whose pycolmap thresholds are tuned to the synthetic capture's procedural
# texture as Blender 5.0 draws it (4.x hashes noise and Voronoi differently: another texture of the same kind, on
# which SfM registers 5 of 8 photos or finds the focal length 2-3 % off); they test pose recovery, not Blender.
# docs/blender_versions.md has the results.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ $# -ne 1 ] || [ -z "$1" ]; then
  echo "error: usage: scripts/test_blender_version.sh BPY_VERSION (a bpy wheel's version, e.g. 4.2.23)" >&2; exit 2
fi
BPY=$1
PY=${PY:-.venv/bin/python}
VENV=.venv-bpy$BPY
# Blender 5.1 and later are built for Python 3.13 and numpy 2 (bpy 5.3: numpy>=2.2), so their venv takes a Python
# 3.13 (on PATH, or pyenv's) and lets pip pick numpy; everything else stays at the main venv's versions, except:
# torch 2.13.0 for 3.13 is PyPI's CUDA build (~4 GB with its CUDA packages; the CPU build on this disk is cp311
# only), and pybullet 3.2.7 has no cp313 wheel, so its pure-data pybullet_data (the real meshes) is copied over.
PY313=0
case "$BPY" in 4.*|5.0|5.0.*) ;; *) PY313=1 ;; esac
if [ ! -f "$VENV/.installed-stamp" ]; then
  rm -rf "$VENV"
  if [ $PY313 = 1 ]; then
    BASE=
    for c in $(command -v python3.13) $(ls -d "$(pyenv root 2>/dev/null || echo ~/.pyenv)"/versions/3.13*/bin/python3.13 2>/dev/null); do
      # a pyenv shim is on PATH even where it cannot run 3.13: take the first that does
      if "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 13))' 2>/dev/null; then BASE=$c; break; fi
    done
    if [ -z "$BASE" ]; then
      # exit 3, not 2: .ci/run tells "this machine cannot run it" apart from a failure
      echo "error: bpy $BPY needs Python 3.13 (Blender 5.1 and later); none on PATH or in pyenv" >&2; exit 3
    fi
  else
    BASE=$(command -v python3.11 || command -v python3)
  fi
  "$BASE" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip
  if [ $PY313 = 1 ]; then
    "$PY" -m pip freeze --exclude-editable | grep -v -E '^(bpy|numpy|torch|pybullet)==' > "$VENV/requirements.txt"
    echo "torch==2.13.0" >> "$VENV/requirements.txt"
  else
    "$PY" -m pip freeze --exclude-editable | grep -v '^bpy==' > "$VENV/requirements.txt"
  fi
  "$VENV/bin/python" -m pip install -q "bpy==$BPY" -r "$VENV/requirements.txt"
  if [ $PY313 = 1 ]; then
    DATA=$("$PY" -c "import pybullet_data, os; print(os.path.dirname(pybullet_data.__file__))" 2>/dev/null || true)
    SITE=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")
    if [ -n "$DATA" ]; then cp -r "$DATA" "$SITE/"; fi
  fi
  "$VENV/bin/python" -m pip install -q --no-deps --ignore-requires-python -e .  # the project pins 3.11 (the pinned bpy)
  touch "$VENV/.installed-stamp"
fi
TESTS=$(grep -l "import bpy\|bpy_empty\|empty_scene\|(addon\|, addon" tests/test_*.py)
if [ $PY313 = 1 ]; then
  # 5.1+ draws the same texture as 5.0, but its Cycles noise differs (0.0002 of 255 a PNG pixel on average, up to
  # 6 of 255 in the tests' JPEGs). On these photo sets of the ring that tips pycolmap's incremental mapping: under
  # 5.3 10 photos of an arc register 6 (two models, focal lengths 5-13 % off), under 5.1 9 of 10; other mapping
  # seeds register all 10 on the 5.3 set. They sit near a cliff of the mapper, not of Blender (docs/blender_versions.md)
  DESELECT=(
    "tests/test_capture.py::test_phone_photos_in_heic_and_webp_are_read"
    "tests/test_capture.py::test_portrait_phone_photos_keep_the_scene_upright[6]"
    "tests/test_capture_undistort.py::test_simple_radial_per_photo_cameras_undistort_to_one_size"
    "tests/test_capture_undistort.py::test_opencv_exported_images_are_undistorted"
  )
else
  DESELECT=(
    "tests/test_capture.py::test_phone_photos_in_heic_and_webp_are_read"
    "tests/test_capture_undistort.py::test_opencv_lens_poses_and_pinhole_output"
    "tests/test_capture_undistort.py::test_opencv_exported_images_are_undistorted"
    "tests/test_faults.py::test_recover_poses_resumes_finished_stages"
  )
fi
[ "$BPY" = 5.0.1 ] && DESELECT=()
REPORT=$VENV/junit.xml
rm -f "$REPORT"
echo "Blender tests under bpy $BPY ($(echo $TESTS | wc -w) files, ${#DESELECT[@]} left out)"
set +e
MRVM_REQUIRE_WEIGHTS=1 timeout 1800 "$VENV/bin/python" -m pytest -q -p no:cacheprovider --junitxml="$REPORT" \
  "${DESELECT[@]/#/--deselect=}" $TESTS
rc=$?
set -e
"$PY" - "$REPORT" "$rc" "$BPY" <<'EOF'
import sys, xml.etree.ElementTree as ET
from pathlib import Path
report, rc, bpy = Path(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
if not report.is_file():
    sys.exit(f"error: bpy {bpy}: pytest wrote no report (exit status {rc})")
s = ET.parse(report).getroot()
s = s if s.tag == "testsuite" else s.find("testsuite")
n, bad = int(s.get("tests")), int(s.get("failures")) + int(s.get("errors"))
print(f"bpy {bpy}: {n} tests, {bad} failed or errored, {s.get('skipped')} skipped, pytest exit status {rc}")
sys.exit(1 if bad or n == 0 else 0)
EOF
