#!/usr/bin/env bash
# The tests that use Blender, under another Blender than the pinned bpy 5.0.1: the extension's manifest says
# Blender 4.2 and later (blender_version_min), so `make test` also runs them under 4.2 LTS (.ci/run).
#   scripts/test_blender_version.sh 4.2.23       (or: make test-blender BPY=4.2.23)
# The venv .venv-bpy$BPY holds that bpy and every other package at the main venv's versions (made once, ~1 min,
# a 350 MB wheel); the project is installed editable, so the tests run the working tree. Pass criterion: the
# JUnit report (the bpy 4.x modules can crash or stall while the interpreter exits, after the tests ran).
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
  SKIP='bpy'
  [ $PY313 = 1 ] && SKIP='bpy|numpy|torch|pybullet'
  "$PY" -m pip freeze --exclude-editable | grep -v -E "^($SKIP)==" > "$VENV/requirements.txt"
  [ $PY313 = 1 ] && echo "torch==2.13.0" >> "$VENV/requirements.txt"
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
# Left out under every bpy but the pinned 5.0.1, with the reason: the pose-recovery tests on the synthetic capture
# (the ring; tests/test_capture*.py and one resume test), but for the two whose subject is Blender's side (its
# cameras project like COLMAP's; the operator adds the cameras). Their subject is pycolmap in the worker Python, and
# their bounds were set on the ring as 5.0 renders it. Other Blenders render it a little differently (4.x hashes its
# noise and Voronoi textures otherwise; 5.1+ has other Cycles noise, 0.0002 of 255 a pixel on average), and on
# 8-12 photos of 320 x 240 that moves pycolmap across those bounds, differently from run to run (pycolmap's
# threads): seen under 4.2, 4.4, 5.1 and 5.3, 1 to 7 of them a run. One such failure was a fault of recover-poses
# (the mapping kept a focal-length start 13 % off), fixed in session 48 (docs/blender_versions.md).
DESELECT=()
PINNED=$(grep -o '"bpy==[0-9.]*"' pyproject.toml | tr -dc '0-9.')  # the bpy `make test` runs
if [ "$BPY" != "$PINNED" ]; then
  TESTS="$(echo "$TESTS" | grep -v -x -e tests/test_capture.py -e tests/test_capture_undistort.py)
tests/test_capture.py::test_blender_cameras_project_like_colmap
tests/test_capture.py::test_recover_poses_operator_creates_cameras"
  DESELECT=("tests/test_faults.py::test_recover_poses_resumes_finished_stages")
fi
REPORT=$VENV/junit.xml
rm -f "$REPORT"
echo "Blender tests under bpy $BPY ($(echo $TESTS | wc -w) files or tests, ${#DESELECT[@]} more left out)"
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
