"""vehicle_simulator node: synthesises a shipped road scenario and replays it at a rate."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from vehicle_monitor_msgs.msg import WheelSpeeds

from tpms_ros.nodes.vehicle_simulator_node import VehicleSimulatorNode
from vehicle_monitor_common.bag_io import bag_topics

DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=20000,
                  reliability=ReliabilityPolicy.RELIABLE)


def test_kim_huh_scenario_replays_every_wheel_speed(
        tmp_path: Path, make_node: Callable[..., Any], spin_until: Callable[..., bool]) -> None:
    """10 s at 1 kHz (both ends): every wheel-speed message arrives, near 70 km/h."""
    got: list[WheelSpeeds] = []
    make_node('listener').create_subscription(WheelSpeeds, '/vehicle/wheel_speeds',
                                              got.append, DEEP)
    simulator = make_node(VehicleSimulatorNode, parameter_overrides=[
        Parameter('scenario', value='kim_huh_lateral'),
        Parameter('output_bag', value=str(tmp_path / 'kh')),
        Parameter('wait_for_subscribers', value=1), Parameter('rate', value=2.0),
        Parameter('topics', value=['/vehicle/wheel_speeds'])])
    expected = bag_topics(simulator.bag)['/vehicle/wheel_speeds'].count
    assert expected == 10_001
    assert spin_until(lambda: len(got) == expected, timeout_s=60.0), len(got)
    assert {'/vehicle/imu', '/vehicle/driver_inputs', '/truth/tire_forces',
            '/truth/tire_pressure', '/truth/vehicle_state'} <= set(bag_topics(simulator.bag))
    speed = got[100].omega.mean() * 0.305 * 3.6
    assert 60.0 < speed < 80.0
