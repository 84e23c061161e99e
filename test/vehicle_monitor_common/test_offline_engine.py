"""The offline engine: processors wired by topic over a recording, without ROS."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vehicle_monitor_common.bag_io import read_messages, write_bag
from vehicle_monitor_common.offline_engine import (
    EngineNode,
    OfflineGraph,
    expand_topic,
    write_outputs,
)
from vehicle_monitor_common.processing import Input, Output, Status
from vehicle_monitor_common.series import TopicSeries

MS = 1_000_000


class Scale:
    """Publishes 2 * ay of every IMU sample as a creep factor, stamped with the sample."""

    inputs = {'imu': Input('sensor_msgs/msg/Imu')}
    outputs = {'factor': 'vehicle_monitor_msgs/msg/CreepFactor'}

    def process(self, topic: str, message: Any) -> list[Output]:
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        return [Output('factor', stamp, {'creep_factor': 2.0 * message.linear_acceleration.y})]

    def status(self, now_ns: int) -> Status:
        return Status()


class Count:
    """Reads the factors raw and publishes a running count of them every second one."""

    inputs = {'factor': Input('vehicle_monitor_msgs/msg/CreepFactor', raw=True)}
    outputs = {'count': 'vehicle_monitor_msgs/msg/TpmsIndication'}

    def __init__(self) -> None:
        self.seen: list[bytes] = []

    def process(self, topic: str, message: Any) -> list[Output]:
        assert isinstance(message, bytes)
        self.seen.append(message)
        if len(self.seen) % 2:
            return []
        return [Output('count', len(self.seen), {'method': f'n{len(self.seen)}',
                                                 'confidence': np.full(4, 0.5)})]

    def status(self, now_ns: int) -> Status:
        return Status()


def _bag(tmp_path: Path) -> Path:
    stamps = 1_000 * 1_000_000_000 + np.arange(6, dtype=np.int64) * 10 * MS
    series = {'/car1/imu': TopicSeries('sensor_msgs/msg/Imu', stamps,
                                       {'linear_acceleration.y': np.arange(6.0)}),
              '/other': TopicSeries('sensor_msgs/msg/Imu', stamps + 1, {})}
    path = tmp_path / 'in'
    write_bag(path, series)
    return path


def test_topic_names_resolve_as_in_ros() -> None:
    """Relative names take the namespace; remappings apply to the expanded name."""
    assert expand_topic('imu', '/car1', {}) == '/car1/imu'
    assert expand_topic('/clock', '/car1', {}) == '/clock'
    assert expand_topic('factor', '/car1', {'factor': 'f2'}) == '/car1/f2'
    assert expand_topic('x', '', {'/x': '/y'}) == '/y'


def test_outputs_flow_through_the_graph_in_order(tmp_path: Path) -> None:
    """Each input reaches its subscriber decoded; each output at once reaches the processors
    subscribing it (raw bytes for a raw input); everything lands in the output bag stamped with
    the sample it answers."""
    counter = Count()
    graph = OfflineGraph([EngineNode('/car1/scale', Scale(), '/car1'),
                          EngineNode('/car1/count', counter, '/car1')])
    assert graph.input_topics == {'/car1/imu', '/car1/factor'}
    stats = write_outputs(graph, _bag(tmp_path), tmp_path / 'out')
    assert stats.messages_in == 6 and stats.messages_out == 9
    assert stats.published == {'/car1/factor': 6, '/car1/count': 3}
    assert stats.data_s == 0.05
    factors = list(read_messages(tmp_path / 'out', ['/car1/factor']))
    assert [m.creep_factor for _, _, _, m in factors] == [0.0, 2.0, 4.0, 6.0, 8.0, 10.0]
    assert [stamp % 1_000_000_000 for _, _, stamp, _ in factors] == [k * 10 * MS for k in range(6)]
    counts = read_messages(tmp_path / 'out', ['/car1/count'])
    assert [m.method for _, _, _, m in counts] == ['n2', 'n4', 'n6']
    assert len(counter.seen) == 6 and all(isinstance(b, bytes) for b in counter.seen)
