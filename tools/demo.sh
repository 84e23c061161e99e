#!/usr/bin/env bash
# The main job: set up (idempotent), then run the road and the rail monitoring graphs on the
# shipped scenario bags and print what every topic carried. Extra arguments go to run_graph
# (e.g. -p vehicle_simulator.rate:=1.0).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/tools/bootstrap.sh"
cd "$ROOT"
# shellcheck disable=SC1091
source tools/env.sh
for domain in tpms_ros/road rail_monitor_ros/rail; do
  package="${domain%/*}" graph="${domain#*/}"
  share=$(python -c "from ament_index_python.packages import get_package_share_directory as g; print(g('$package'))")
  echo "== $graph graph ($share/config/${graph}_graph.yaml)"
  tools/ros2run vehicle_monitor_common run_graph "$share/config/${graph}_graph.yaml" "$@"
done
