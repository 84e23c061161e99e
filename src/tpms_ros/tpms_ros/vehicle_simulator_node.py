"""``vehicle_simulator``: puts road-vehicle scenarios on the ROS graph.

Replay mode: ``-p bag:=<rosbag2>`` replays a recording (synthetic or from a vehicle) onto
``/vehicle/*`` and ``/truth/*`` with ``/clock``; see vehicle_monitor_common.player for the
parameters (rate, as_fast_as_possible, start_offset, loop, topics, sync_topics).
"""

from __future__ import annotations

import sys

from vehicle_monitor_common.player import run_player


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``vehicle_simulator`` executable."""
    sys.exit(run_player('vehicle_simulator', args))


if __name__ == '__main__':
    main()
