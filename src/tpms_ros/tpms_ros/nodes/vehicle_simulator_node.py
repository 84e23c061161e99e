"""``vehicle_simulator``: puts road-vehicle scenarios on the ROS graph.

Synthetic mode: ``-p scenario:=<yaml or shipped name>`` simulates the road vehicle (14-DOF
handling truth with Magic Formula tires, torsional tire wheel speeds through a 48-tooth encoder,
IMU, driver inputs, ``/truth/*``) and replays it. Replay mode: ``-p bag:=<rosbag2>`` replays a
recording. Timing, loop, rate and flow control are the player's parameters
(vehicle_monitor_common.player).
"""

from __future__ import annotations

import sys
from typing import Any

from tpms_ros.simulation.road_simulator import scenario_topics
from vehicle_monitor_common.player import run_player
from vehicle_monitor_common.simulator import SimulatorNode


class VehicleSimulatorNode(SimulatorNode):
    """The road vehicle simulator node."""

    package = 'tpms_ros'

    def __init__(self, node_name: str = 'vehicle_simulator', **kwargs: Any) -> None:
        super().__init__(node_name, scenario_topics, **kwargs)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``vehicle_simulator`` executable."""
    sys.exit(run_player(VehicleSimulatorNode, args))


if __name__ == '__main__':
    main()
