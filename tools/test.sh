#!/usr/bin/env bash
# Sets up the workspace (idempotent) and runs every check: ruff, mypy, the pytest suite.
# Extra arguments go to pytest (e.g. tools/test.sh -k player).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/tools/bootstrap.sh"
cd "$ROOT"
# shellcheck disable=SC1091
source tools/env.sh
echo "== ruff"
ruff check src test benchmarks tools
echo "== mypy"
mypy src/vehicle_monitor_common src/tpms_ros/tpms_ros src/rail_monitor_ros/rail_monitor_ros
echo "== pytest"
python -m pytest "$@"
