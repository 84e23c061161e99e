"""rail_simulator node: synthesises a shipped scenario, replays it, keeps the bag on request."""

from __future__ import annotations

from collections.abc import Callable
import hashlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu

from rail_monitor_ros.nodes.rail_simulator_node import RailSimulatorNode
from vehicle_monitor_common.bag_io import iter_raw, read_series
from vehicle_monitor_common.node_helpers import ConfigurationError

DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                  reliability=ReliabilityPolicy.RELIABLE)


def _content_hash(bag: Path) -> str:
    digest = hashlib.sha256()
    for topic, msgtype, stamp, data in iter_raw(bag):
        digest.update(f'{topic}{msgtype}{stamp}'.encode())
        digest.update(bytes(data))
    return digest.hexdigest()


def test_scenario_is_synthesised_and_replayed(
        tmp_path: Path, make_node: Callable[..., Any], spin_until: Callable[..., bool]) -> None:
    """The IMM scenario arrives on rail/bogie/imu with the bag's stamps; the bag is kept."""
    got: list[int] = []
    listener = make_node('listener')
    listener.create_subscription(
        Imu, '/rail/bogie/imu',
        lambda m: got.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec), DEEP)
    kept = tmp_path / 'imm'
    simulator = make_node(RailSimulatorNode, parameter_overrides=[
        Parameter('scenario', value='rail_imm_spring_damper_fault'),
        Parameter('output_bag', value=str(kept)), Parameter('wait_for_subscribers', value=1),
        Parameter('rate', value=20.0)])
    recorded = read_series(kept, ['/rail/bogie/imu'])['/rail/bogie/imu']
    assert spin_until(lambda: simulator.done.is_set() and len(got) == len(recorded),
                      timeout_s=30.0), (len(got), len(recorded))
    assert got == list(recorded.stamps_ns)
    assert simulator.error is None


def test_same_seed_gives_the_same_bag(tmp_path: Path, make_node: Callable[..., Any]) -> None:
    """Same scenario and seed -> identical messages; another seed -> different ones."""
    hashes = []
    for name, seed in (('a', 3), ('b', 3), ('c', 4)):
        node = make_node(RailSimulatorNode, node_name=f'sim_{name}', parameter_overrides=[
            Parameter('scenario', value='rail_creep_steps'), Parameter('seed', value=seed),
            Parameter('output_bag', value=str(tmp_path / name)),
            Parameter('rate', value=1e-3)])
        hashes.append(_content_hash(Path(node.bag)))
    assert hashes[0] == hashes[1] != hashes[2]


def test_truth_topics_are_in_the_bag(tmp_path: Path, make_node: Callable[..., Any]) -> None:
    """The synthesised bag carries /truth/creep_factor with the scenario's steps."""
    node = make_node(RailSimulatorNode, parameter_overrides=[
        Parameter('scenario', value='rail_creep_steps'),
        Parameter('output_bag', value=str(tmp_path / 'creep')), Parameter('rate', value=1e-3)])
    truth = read_series(node.bag, ['/truth/creep_factor'])['/truth/creep_factor']
    t = (truth.stamps_ns - truth.stamps_ns[0]) * 1e-9
    c = truth.fields['creep_factor']
    np.testing.assert_allclose([c[t < 4.9].mean(), c[(t > 5.1) & (t < 9.9)].mean(),
                                c[t > 10.1].mean()], [1.0, 0.4, 0.6], atol=1e-6)


@pytest.mark.parametrize('overrides, match', [
    ({'scenario': 'no_such_scenario'}, 'available: .*rail_creep_steps'),
    ({'scenario': 'rail_creep_steps', 'bag': '/tmp/x'}, 'either bag .* or scenario'),
    ({}, 'scenario .* or bag .* is required'),
])
def test_bad_configuration_is_refused(make_node: Callable[..., Any],
                                      overrides: dict[str, Any], match: str) -> None:
    """Unknown scenarios and contradictory modes are refused, naming what is wrong."""
    with pytest.raises(ConfigurationError, match=match):
        make_node(RailSimulatorNode, parameter_overrides=[
            Parameter(k, value=v) for k, v in overrides.items()])


def test_invalid_scenario_file_names_the_key(tmp_path: Path,
                                            make_node: Callable[..., Any]) -> None:
    """A scenario file with an unknown key is refused with the key in the message."""
    bad = tmp_path / 'bad.yaml'
    bad.write_text('duration: 5\nseed: 1\nspeeed: 40\n')
    with pytest.raises(ConfigurationError, match='speeed'):
        make_node(RailSimulatorNode, parameter_overrides=[Parameter('scenario', value=str(bad))])
