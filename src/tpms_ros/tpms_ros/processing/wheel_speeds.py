"""The 1 kHz wheel-speed input of the road processors, decoded from its serialised form.

``vehicle/wheel_speeds`` is the graph's densest stream and four nodes read it. rclpy turns each
delivery into a Python ``WheelSpeeds`` (with its ``Header`` and ``Time``) per subscription, which
costs about as much as the delivery itself: measured on this machine, 27 us per delivery typed
vs 13 us raw (five subscribers, EventsExecutor). The processors therefore take it raw
(``Input(..., raw=True)``: the node and the offline engine hand over the CDR bytes) and read the
two things they use, the stamp and the four speeds, straight from the bytes.

Layout of ``vehicle_monitor_msgs/msg/WheelSpeeds`` after the 4-byte encapsulation header
(offsets from the end of that header): int32 ``header.stamp.sec``, uint32 ``nanosec``, uint32
length of ``header.frame_id`` (with its NUL) and its bytes, then ``float64[4] omega`` aligned to
8 bytes (classic CDR) or 4 (XCDR2). Both byte orders are read.
"""

from __future__ import annotations

import struct
from typing import Any

WHEEL_SPEEDS_TYPE = 'vehicle_monitor_msgs/msg/WheelSpeeds'

# Encapsulation identifier (first two bytes) -> (byte order, alignment of a float64).
_ENCAPSULATIONS = {b'\x00\x00': ('>', 8), b'\x00\x01': ('<', 8),     # CDR (XCDR1)
                   b'\x00\x06': ('>', 4), b'\x00\x07': ('<', 4)}     # plain CDR2 (XCDR2)
_HEAD = {order: struct.Struct(f'{order}iII') for order in '<>'}
_OMEGA = {order: struct.Struct(f'{order}4d') for order in '<>'}


# The latest bytes object decoded and its result: the offline engine hands the same message
# object to all four processors, which then decode it once (a bytes object cannot change, and
# the reference kept here keeps its identity from being reused).
_last_decoded: tuple[bytes, tuple[int, tuple[float, float, float, float]]] | None = None


def decode_wheel_speeds(data: bytes) -> tuple[int, tuple[float, float, float, float]]:
    """(header stamp in ns, omega) of a serialised WheelSpeeds.

    Raises:
        ValueError: the bytes are not a WheelSpeeds (unknown encapsulation, too short).
    """
    global _last_decoded
    last = _last_decoded     # read once: another executor thread may replace it meanwhile
    if last is not None and last[0] is data:
        return last[1]
    decoded = _decode(data)
    if type(data) is bytes:
        _last_decoded = data, decoded
    return decoded


def _decode(data: bytes) -> tuple[int, tuple[float, float, float, float]]:
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
