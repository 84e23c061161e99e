#!/usr/bin/env bash
# The main job: set up (idempotent), then run the road and the rail monitoring graphs on the
# shipped scenario bags, print the scoreboard (key figure per scenario and method against the
# SPEC §8 targets, and each graph's real-time factor) and write the figures, report.md and
# results.json into out/demo. Extra arguments go to monitor_demo (e.g. --out DIR,
# --only SCENARIO, --update-readme).
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/tools/bootstrap.sh"
cd "$ROOT"
exec tools/ros2run vehicle_monitor_common monitor_demo "$@"
