"""Scenario player: every message in order with its stamps, bag time on /clock, bad input; what
the graph recorder writes of a replay (the bag format)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import subprocess
from typing import Any

from builtin_interfaces.msg import Time
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import TpmsWarning, WheelSpeeds

from vehicle_monitor_common.bag_io import read_series
from vehicle_monitor_common.node_helpers import ConfigurationError, stamp_ns
from vehicle_monitor_common.player import ScenarioPlayer
from vehicle_monitor_common.recorder import GraphRecorder
from vehicle_monitor_common.series import TopicSeries

DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                  reliability=ReliabilityPolicy.RELIABLE)
TYPES = {'/vehicle/wheel_speeds': WheelSpeeds, '/vehicle/imu': Imu, '/tpms/warning': TpmsWarning}


def _listen(node: Node, received: list[tuple[str, int, Any]]) -> None:
    for topic, cls in TYPES.items():
        node.create_subscription(
            cls, topic, lambda msg, t=topic: received.append((t, stamp_ns(msg.header.stamp), msg)),
            DEEP)


def _expected(series: dict[str, TopicSeries]) -> list[tuple[str, int]]:
    pairs = [(int(s), order, topic) for order, (topic, ts) in enumerate(series.items())
             for s in ts.stamps_ns]
    return [(topic, stamp) for stamp, _, topic in sorted(pairs)]


@pytest.mark.parametrize('mode', [
    {'as_fast_as_possible': True},
    {'rate': 20.0},
])
def test_replay_delivers_every_message_in_order(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any],
        spin_until: Callable[..., bool], mode: dict[str, Any]) -> None:
    """A subscriber receives every message of the bag, in bag order, with its stamps and data."""
    path, series = small_bag
    received: list[tuple[str, int, Any]] = []
    listener = make_node('listener')
    _listen(listener, received)
    player = make_node(ScenarioPlayer, parameter_overrides=[
        Parameter('bag', value=str(path)), Parameter('wait_for_subscribers', value=1),
        *[Parameter(k, value=v) for k, v in mode.items()]])
    total = sum(len(s) for s in series.values())
    assert spin_until(lambda: len(received) >= total, timeout_s=20.0), \
        f'received {len(received)} of {total}'
    assert spin_until(player.done.is_set, timeout_s=5.0)
    assert player.error is None
    # Each topic in order; across topics, the bag's order (one publisher per topic, so only
    # per-topic order is guaranteed by DDS).
    for topic in TYPES:
        got = [stamp for t, stamp, _ in received if t == topic]
        assert got == [stamp for t, stamp in _expected(series) if t == topic]
    omega = np.array([m.omega for t, _, m in received if t == '/vehicle/wheel_speeds'])
    np.testing.assert_array_equal(omega, series['/vehicle/wheel_speeds'].fields['omega'])
    assert dict(player.published) == {t: len(s) for t, s in series.items()}


def test_sim_time_node_sees_bag_time(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """A node with use_sim_time runs on the bag's time, published on /clock."""
    path, series = small_bag
    seen: list[int] = []
    sim_node = make_node('sim_time_node',
                         parameter_overrides=[Parameter('use_sim_time', value=True)])
    sim_node.create_subscription(
        WheelSpeeds, '/vehicle/wheel_speeds',
        lambda _: seen.append(sim_node.get_clock().now().nanoseconds), DEEP)
    player = make_node(ScenarioPlayer, parameter_overrides=[
        Parameter('bag', value=str(path)), Parameter('wait_for_subscribers', value=1),
        Parameter('rate', value=10.0)])
    assert spin_until(lambda: player.done.is_set() and len(seen) == 200, timeout_s=20.0)
    start, end = (int(series['/vehicle/wheel_speeds'].stamps_ns[i]) for i in (0, -1))
    assert all(start <= t <= end for t in seen), (min(seen), max(seen))
    # /clock advances with the replay: the last samples see late bag time.
    assert seen[-1] >= end - 100_000_000
    assert sim_node.get_clock().now().nanoseconds <= end + 1


def test_start_offset_and_topic_selection(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """start_offset skips bag time; topics restricts what is published."""
    path, series = small_bag
    received: list[tuple[str, int, Any]] = []
    _listen(make_node('listener'), received)
    player = make_node(ScenarioPlayer, parameter_overrides=[
        Parameter('bag', value=str(path)), Parameter('wait_for_subscribers', value=1),
        Parameter('as_fast_as_possible', value=True), Parameter('start_offset', value=0.5),
        Parameter('topics', value=['/vehicle/wheel_speeds'])])
    assert spin_until(player.done.is_set, timeout_s=20.0)
    assert spin_until(lambda: len(received) >= 100, timeout_s=5.0)
    assert {t for t, _, _ in received} == {'/vehicle/wheel_speeds'}
    assert min(s for _, s, _ in received) == 1000 * 10**9 + 500_000_000
    assert len(received) == 100


def test_loop_replays_again(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """With loop, the bag starts over: the first stamp comes back and the replay goes on."""
    path, series = small_bag
    received: list[tuple[str, int, Any]] = []
    _listen(make_node('listener'), received)
    player = make_node(ScenarioPlayer, parameter_overrides=[
        Parameter('bag', value=str(path)), Parameter('wait_for_subscribers', value=1),
        Parameter('rate', value=50.0), Parameter('loop', value=True),
        Parameter('topics', value=['/vehicle/imu'])])
    first = int(series['/vehicle/imu'].stamps_ns[0])
    assert spin_until(lambda: [s for _, s, _ in received].count(first) >= 2, timeout_s=20.0)
    assert not player.done.is_set()


def test_namespace_moves_replayed_topics(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """A player in namespace /car1 publishes /car1/vehicle/... (one graph per vehicle)."""
    path, _ = small_bag
    got: list[Any] = []
    listener = make_node('listener')
    listener.create_subscription(WheelSpeeds, '/car1/vehicle/wheel_speeds', got.append, DEEP)
    player = make_node(ScenarioPlayer, namespace='/car1', parameter_overrides=[
        Parameter('bag', value=str(path)), Parameter('wait_for_subscribers', value=0),
        Parameter('topics', value=['/vehicle/wheel_speeds']), Parameter('rate', value=50.0)])
    assert spin_until(lambda: player.done.is_set() and len(got) > 0, timeout_s=20.0)
    assert player.get_fully_qualified_name() == '/car1/scenario_player'


@pytest.mark.parametrize('overrides, match', [
    ({}, 'parameter bag is required'),
    ({'bag': '/definitely/not/here'}, 'no such bag'),
    ({'bag': 'SMALL_BAG', 'rate': 0.0}, 'parameter rate'),
    ({'bag': 'SMALL_BAG', 'topics': ['/nope']}, 'topic /nope is not in bag'),
])
def test_bad_configuration_is_refused(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any],
        overrides: dict[str, Any], match: str) -> None:
    """Bad parameters raise ConfigurationError naming the problem; no replay starts."""
    path, _ = small_bag
    values = {k: str(path) if v == 'SMALL_BAG' else v for k, v in overrides.items()}
    with pytest.raises(ConfigurationError, match=match):
        make_node(ScenarioPlayer, parameter_overrides=[
            Parameter(k, value=v) for k, v in values.items()])


def test_rate_change_at_runtime_is_validated(
        small_bag: tuple[Path, dict[str, TopicSeries]], make_node: Callable[..., Any]) -> None:
    """A negative rate set at runtime is refused with the reason; a valid one is taken."""
    path, _ = small_bag
    player = make_node(ScenarioPlayer, parameter_overrides=[
        Parameter('bag', value=str(path)), Parameter('rate', value=0.01)])
    (result,) = player.set_parameters([Parameter('rate', value=-2.0)])
    assert not result.successful and 'rate' in result.reason
    (result,) = player.set_parameters([Parameter('rate', value=5.0)])
    assert result.successful and player.parameters.rate == 5.0


@pytest.mark.parametrize('args, match', [
    ([], 'or bag (a recording to replay) is required'),
    (['-p', 'bag:=/no/such/bag'], 'no such bag'),
    (['-p', 'rate:=-1.0'], 'parameter rate'),
])
def test_executable_reports_user_errors_in_one_line(
        small_bag: tuple[Path, dict[str, TopicSeries]], executable: Callable[[str, str], str],
        args: list[str], match: str) -> None:
    """The vehicle_simulator executable exits non-zero with one line, no traceback."""
    path, _ = small_bag
    if args and args[1].startswith('rate'):
        args = ['-p', f'bag:={path}', *args]
    result = subprocess.run([executable('tpms_ros', 'vehicle_simulator'), '--ros-args', *args],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode != 0
    assert match in result.stderr
    assert 'Traceback' not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_executable_replays_and_exits_zero(
        small_bag: tuple[Path, dict[str, TopicSeries]],
        executable: Callable[[str, str], str]) -> None:
    """vehicle_simulator in replay mode plays the bag and exits 0 when done."""
    path, _ = small_bag
    result = subprocess.run([executable('tpms_ros', 'vehicle_simulator'), '--ros-args',
                             '-p', f'bag:={path}', '-p', 'as_fast_as_possible:=true'],
                            capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert 'replayed 251 messages on 3 topics' in result.stderr + result.stdout


def test_stamp_helper() -> None:
    """stamp_ns converts builtin_interfaces/Time exactly."""
    assert stamp_ns(Time(sec=3, nanosec=7)) == 3_000_000_007


def test_recorder_writes_plain_mcap_that_both_readers_read(
        small_bag: tuple[Path, dict[str, TopicSeries]], ros_context: Any, executor: Any,
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """A recorded replay is one .mcap with zstd chunks; rosbags and mcap decode the same data."""
    path, series = small_bag
    target = tmp_path / 'recorded'
    recorder = GraphRecorder(context=ros_context, parameter_overrides=[
        Parameter('bag', value=str(target)), Parameter('topics', value=list(TYPES))])
    executor.add_node(recorder)
    try:
        make_node(ScenarioPlayer, parameter_overrides=[
            Parameter('bag', value=str(path)), Parameter('wait_for_subscribers', value=1),
            Parameter('as_fast_as_possible', value=True)])
        expected = {topic: len(s) for topic, s in series.items()}
        assert spin_until(lambda: {t: s.count for t, s in recorder.stats.items()} == expected,
                          timeout_s=20.0), {t: s.count for t, s in recorder.stats.items()}
    finally:
        executor.remove_node(recorder)
        recorder.destroy_node()
    assert sorted(f.name for f in target.iterdir()) == ['metadata.yaml', 'recorded.mcap']
    omega = series['/vehicle/wheel_speeds'].fields['omega']
    np.testing.assert_array_equal(
        read_series(target)['/vehicle/wheel_speeds'].fields['omega'], omega)
    with open(target / 'recorded.mcap', 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        assert {chunk.compression for chunk in summary.chunk_indexes} == {'zstd'}
        wheels = [msg.omega for _, channel, _, msg in reader.iter_decoded_messages(
            log_time_order=True) if channel.topic == '/vehicle/wheel_speeds']
    np.testing.assert_array_equal(np.array(wheels), omega)
