"""The raw wheel-speed decoder against rclpy's own serialisation, and its refusals."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from vehicle_monitor_msgs.msg import WheelSpeeds

from tpms_ros.processing.wheel_speeds import decode_wheel_speeds
from vehicle_monitor_common.bag_io import typestore


@pytest.mark.parametrize('frame_id', ['', 'b', 'base_link', 'a_frame_of_23_characters'])
def test_decodes_what_rclpy_and_rosbags_serialise(frame_id: str) -> None:
    """Every frame_id length (the padding before omega changes with it), both serialisers."""
    rng = np.random.default_rng(len(frame_id))
    msg = WheelSpeeds()
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_123, 987_654_321
    msg.header.frame_id = frame_id
    msg.omega = rng.uniform(-100.0, 100.0, 4).tolist()
    expected = (1_700_000_123 * 10**9 + 987_654_321, tuple(msg.omega))
    assert decode_wheel_speeds(serialize_message(msg)) == expected

    store = typestore()
    cls = store.types['vehicle_monitor_msgs/msg/WheelSpeeds']
    header = store.types['std_msgs/msg/Header']
    stamp = store.types['builtin_interfaces/msg/Time'](sec=1_700_000_123, nanosec=987_654_321)
    other = cls(header=header(stamp=stamp, frame_id=frame_id), omega=np.array(msg.omega))
    assert decode_wheel_speeds(store.serialize_cdr(other, cls.__msgtype__)) == expected


def test_big_endian_and_xcdr2_layouts() -> None:
    """CDR big-endian (8-byte alignment) and XCDR2 little-endian (4-byte alignment)."""
    omega = (1.5, -2.25, 3.0, 4.125)
    frame = b'abcdef\x00'          # omega after 19 bytes: at 24 in CDR, at 20 in XCDR2
    big = (b'\x00\x00\x00\x00' + struct.pack('>iII', 5, 6, 7) + frame + bytes(5)
           + struct.pack('>4d', *omega))
    assert decode_wheel_speeds(big) == (5 * 10**9 + 6, omega)
    xcdr2 = (b'\x00\x07\x00\x00' + struct.pack('<iII', 5, 6, 7) + frame + bytes(1)
             + struct.pack('<4d', *omega))
    assert decode_wheel_speeds(xcdr2) == (5 * 10**9 + 6, omega)


@pytest.mark.parametrize('payload, reason', [
    (b'', 'encapsulation'),
    (b'\x12\x34\x00\x00' + bytes(60), 'encapsulation'),
    (b'\x00\x01\x00\x00' + bytes(8), 'too short'),
    (b'\x00\x01\x00\x00' + struct.pack('<iII', 1, 2, 10**6) + bytes(40), 'frame_id'),
])
def test_malformed_payloads_are_refused(payload: bytes, reason: str) -> None:
    with pytest.raises(ValueError, match=reason):
        decode_wheel_speeds(payload)
