"""The fault-injection harness itself: faults change what they claim, and only that."""

from __future__ import annotations

import math
from typing import Any

from harness import (
    BAGS,
    TIMING_FAULTS,
    Sample,
    recorded_stream,
    run,
    shift_stamps,
    stamp_of,
    truncated_payload,
    value_faults,
    wheel_speeds_raw,
    window,
)
import numpy as np

from vehicle_monitor_common.bag_io import typestore
from vehicle_monitor_common.processing import Input, Output, Status

TOPICS = {'/rail/bogie/imu': 'bogie', '/rail/body/imu': 'body'}


class Recorder:
    """Records what it is given; publishes ay of the body IMU."""

    inputs = {'bogie': Input('sensor_msgs/msg/Imu'),
              'body': Input('sensor_msgs/msg/Imu', raw=True)}
    outputs = {'ay': 'vehicle_monitor_msgs/msg/CreepFactor'}

    def __init__(self) -> None:
        self.got: list[tuple[str, Any]] = []

    def process(self, topic: str, message: Any) -> list[Output]:
        self.got.append((topic, message))
        if topic == 'bogie':
            ay = message.linear_acceleration.y
            return [Output('ay', stamp_of(message), {'creep_factor': ay})]
        return []

    def status(self, now_ns: int) -> Status:
        return Status()


def _stream() -> list[Sample]:
    return recorded_stream(BAGS / 'rail_creep_steps', TOPICS, seconds=1.0)


def test_recorded_stream_and_delivery() -> None:
    """The stream is the bag's messages in order; raw inputs get bytes, others messages."""
    stream = _stream()
    assert {s.topic for s in stream} == {'bogie', 'body'}
    assert [s.log_ns for s in stream] == sorted(s.log_ns for s in stream)
    recorder = Recorder()
    result = run(recorder, stream)
    assert len(result.of('ay')) == sum(s.topic == 'bogie' for s in stream)
    assert all(isinstance(m, bytes) for t, m in recorder.got if t == 'body')
    assert len(result.statuses) == len(stream)


def test_value_faults_touch_only_their_window() -> None:
    """Each value fault replaces the field in the window and nowhere else."""
    stream = _stream()
    indices = window(stream, 'bogie', 0.2, 0.1)
    assert len(indices) == 20
    for name, fault in value_faults('linear_acceleration.y', 0.5).items():
        faulty = fault(stream, indices)
        inside = [faulty[i].message.linear_acceleration.y for i in indices]
        if name == 'nan':
            assert all(math.isnan(v) for v in inside)
        elif name == 'stuck':
            assert len(set(inside)) == 1
        else:
            before = stream[indices[0]].message.linear_acceleration.y
            assert len(set(inside)) == 1 and inside[0] != before
        outside = [i for i in range(len(stream)) if i not in indices]
        assert all(faulty[i] is stream[i] for i in outside)


def test_timing_faults() -> None:
    """Repeats add samples, reversal keeps the set, gaps drop, bursts add 9 per sample; a stamp
    shift moves header and log time; a truncated payload is shorter bytes."""
    stream = _stream()
    indices = window(stream, 'bogie', 0.5, 0.05)
    n = len(indices)
    assert len(TIMING_FAULTS['repeated_stamps'](stream, indices)) == len(stream) + n
    reordered = TIMING_FAULTS['out_of_order'](stream, indices)
    assert [reordered[i].log_ns for i in indices] == sorted(
        (stream[i].log_ns for i in indices), reverse=True)
    assert len(TIMING_FAULTS['gap'](stream, indices)) == len(stream) - n
    assert len(TIMING_FAULTS['rate_burst'](stream, indices)) == len(stream) + 9 * n
    shifted = shift_stamps(1e4)(stream, indices[:1])
    assert stamp_of(shifted[indices[0]].message) - stamp_of(stream[indices[0]].message) == 10**13
    cut = truncated_payload(stream, indices[:1])[indices[0]].raw_override
    whole = len(typestore().serialize_cdr(stream[indices[0]].message, 'sensor_msgs/msg/Imu'))
    assert cut is not None and len(cut) == whole // 2


def test_hand_made_wheel_speeds_decode() -> None:
    """The hand-made raw WheelSpeeds is what the road nodes' decoder reads."""
    data = wheel_speeds_raw(1_500_000_000, (1.0, 2.0, 3.0, 4.0), 'base_link')
    msg = typestore().deserialize_cdr(data, 'vehicle_monitor_msgs/msg/WheelSpeeds')
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1, 500_000_000)
    assert np.array_equal(msg.omega, [1.0, 2.0, 3.0, 4.0])
