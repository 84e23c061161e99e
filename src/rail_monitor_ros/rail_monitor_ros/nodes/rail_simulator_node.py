"""``rail_simulator``: puts rail-vehicle scenarios on the ROS graph.

Synthetic mode: ``-p scenario:=<yaml or shipped name>`` simulates the 14-DOF rail car on a
random track irregularity with suspension faults and creep changes (bogie and body IMUs,
lateral states, track irregularity, ``/truth/*``) and replays it. Replay mode:
``-p bag:=<rosbag2>`` replays a recording. Timing, loop, rate and flow control are the player's
parameters (vehicle_monitor_common.player).
"""

from __future__ import annotations

import sys
from typing import Any

from rail_monitor_ros.simulation.rail_simulator import scenario_topics
from vehicle_monitor_common.player import run_player
from vehicle_monitor_common.simulator import SimulatorNode


class RailSimulatorNode(SimulatorNode):
    """The rail vehicle simulator node."""

    package = 'rail_monitor_ros'

    def __init__(self, node_name: str = 'rail_simulator', **kwargs: Any) -> None:
        super().__init__(node_name, scenario_topics, **kwargs)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``rail_simulator`` executable."""
    sys.exit(run_player(RailSimulatorNode, args))


if __name__ == '__main__':
    main()
