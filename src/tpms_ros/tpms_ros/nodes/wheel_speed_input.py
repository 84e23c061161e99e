"""The raw ``vehicle/wheel_speeds`` subscription of the road nodes that are not processors yet.

The decoding is ROS-free and lives in :mod:`tpms_ros.processing.wheel_speeds` (re-exported
here); a :class:`~vehicle_monitor_common.processor_node.ProcessorNode` subscribes raw inputs
itself and needs none of this.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from vehicle_monitor_msgs.msg import WheelSpeeds

from tpms_ros.processing.wheel_speeds import decode_wheel_speeds
from vehicle_monitor_common.node_helpers import sensor_subscription

__all__ = ['WheelSpeedCallback', 'decode_wheel_speeds', 'subscribe_wheel_speeds']

WheelSpeedCallback = Callable[[int, tuple[float, float, float, float]], None]


def subscribe_wheel_speeds(node: Node, on_sample: WheelSpeedCallback,
                           on_malformed: Callable[[str], None]) -> Any:
    """Subscribe ``vehicle/wheel_speeds`` as a sensor input (SENSOR_QOS, qos_overrides), raw;
    ``on_sample(stamp_ns, omega)`` gets each sample, ``on_malformed(reason)`` each payload that
    is not a WheelSpeeds (a replay of a damaged bag publishes whatever bytes it holds)."""

    def on_data(data: bytes) -> None:
        try:
            stamp, omega = decode_wheel_speeds(data)
        except ValueError as exc:
            on_malformed(str(exc))
            return
        on_sample(stamp, omega)

    return sensor_subscription(node, WheelSpeeds, 'vehicle/wheel_speeds', on_data, raw=True)
