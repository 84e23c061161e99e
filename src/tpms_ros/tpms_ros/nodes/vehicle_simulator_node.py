"""``vehicle_simulator``: puts road-vehicle scenarios on the ROS graph.

Synthetic mode: ``-p scenario:=<yaml or shipped name>`` simulates the road vehicle (14-DOF
handling truth with Magic Formula tires, torsional tire wheel speeds through a 48-tooth encoder,
IMU, driver inputs, ``/truth/*``) and replays it. Replay mode: ``-p bag:=<rosbag2>`` replays a
recording. Timing, loop, rate and flow control are the player's parameters
(vehicle_monitor_common.player).
"""

from __future__ import annotations

from tpms_ros.simulation.road_simulator import scenario_topics
from vehicle_monitor_common.simulator import SimulatorNode


class VehicleSimulatorNode(
        SimulatorNode, name='vehicle_simulator', package='tpms_ros',
        synthesis=scenario_topics):
    """The road vehicle simulator node."""


main = VehicleSimulatorNode.main
