"""``rail_simulator``: puts rail-vehicle scenarios on the ROS graph.

Synthetic mode: ``-p scenario:=<yaml or shipped name>`` simulates the 14-DOF rail car on a
random track irregularity with suspension faults and creep changes (bogie and body IMUs,
lateral states, track irregularity, ``/truth/*``) and replays it. Replay mode:
``-p bag:=<rosbag2>`` replays a recording. Timing, loop, rate and flow control are the player's
parameters (vehicle_monitor_common.player).
"""

from __future__ import annotations

from rail_monitor_ros.simulation.rail_simulator import scenario_topics
from vehicle_monitor_common.simulator import SimulatorNode


class RailSimulatorNode(
        SimulatorNode, name='rail_simulator', package='rail_monitor_ros',
        synthesis=scenario_topics):
    """The rail vehicle simulator node."""


main = RailSimulatorNode.main
