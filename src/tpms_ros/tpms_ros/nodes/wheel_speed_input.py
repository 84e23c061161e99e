"""The 1 kHz wheel-speed input of the road nodes, decoded from its serialised form.

``vehicle/wheel_speeds`` is the graph's densest stream and four nodes read it. rclpy turns each
delivery into a Python ``WheelSpeeds`` (with its ``Header`` and ``Time``) per subscription, which
costs about as much as the delivery itself: measured on this machine, 27 us per delivery typed
vs 13 us raw (five subscribers, EventsExecutor). The nodes therefore subscribe raw and read the
two things they use, the stamp and the four speeds, straight from the CDR bytes.

Layout of ``vehicle_monitor_msgs/msg/WheelSpeeds`` after the 4-byte encapsulation header
(offsets from the end of that header): int32 ``header.stamp.sec``, uint32 ``nanosec``, uint32
length of ``header.frame_id`` (with its NUL) and its bytes, then ``float64[4] omega`` aligned to
8 bytes (classic CDR) or 4 (XCDR2). Both byte orders are read.
"""

from __future__ import annotations

from collections.abc import Callable
import struct
from typing import Any

from rclpy.node import Node
from vehicle_monitor_msgs.msg import WheelSpeeds

from vehicle_monitor_common.node_helpers import sensor_subscription

# Encapsulation identifier (first two bytes) -> (byte order, alignment of a float64).
_ENCAPSULATIONS = {b'\x00\x00': ('>', 8), b'\x00\x01': ('<', 8),     # CDR (XCDR1)
                   b'\x00\x06': ('>', 4), b'\x00\x07': ('<', 4)}     # plain CDR2 (XCDR2)
_HEAD = {order: struct.Struct(f'{order}iII') for order in '<>'}
_OMEGA = {order: struct.Struct(f'{order}4d') for order in '<>'}

WheelSpeedCallback = Callable[[int, tuple[float, float, float, float]], None]


def decode_wheel_speeds(data: bytes) -> tuple[int, tuple[float, float, float, float]]:
    """(header stamp in ns, omega) of a serialised WheelSpeeds.

    Raises:
        ValueError: the bytes are not a WheelSpeeds (unknown encapsulation, too short).
    """
    kind = _ENCAPSULATIONS.get(bytes(data[:2]))
    if kind is None:
        raise ValueError(f'unknown CDR encapsulation {bytes(data[:2]).hex()}')
    order, align = kind
    if len(data) < 4 + _HEAD[order].size:
        raise ValueError(f'{len(data)} bytes: too short for a WheelSpeeds')
    sec, nanosec, frame_id_length = _HEAD[order].unpack_from(data, 4)
    offset = _HEAD[order].size + frame_id_length
    offset += -offset % align
    if len(data) < 4 + offset + _OMEGA[order].size:
        raise ValueError(f'{len(data)} bytes: too short for a WheelSpeeds with a '
                         f'{frame_id_length}-byte frame_id')
    omega: Any = _OMEGA[order].unpack_from(data, 4 + offset)
    return sec * 1_000_000_000 + nanosec, omega


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
