"""creep_estimator node: replay of a simulated creep drop, pairing, bad input, parameters."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
import math
from pathlib import Path
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import CreepFactor, RailLateralStates, TrackIrregularity
import yaml

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams
from rail_monitor_ros.nodes.creep_estimator_node import CreepEstimatorNode
from rail_monitor_ros.offline.creep_runs import simulation_inputs
from rail_monitor_ros.simulation.rail_scenario import RailEvent, shipped_scenario
from rail_monitor_ros.simulation.rail_simulator import (
    RailSimulationResult,
    simulate,
    to_topic_series,
)
from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.node_helpers import ConfigurationError, stamp_ns
from vehicle_monitor_common.player import ScenarioPlayer

CONFIG = Path(__file__).resolve().parents[3] / 'src/rail_monitor_ros/config/creep_estimator.yaml'
DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                  reliability=ReliabilityPolicy.RELIABLE)
STEP_TIME = 2.0


@pytest.fixture(scope='module')
def creep_drop() -> RailSimulationResult:
    """The paper's vehicle and track, shortened: 5 s at 40 m/s, c 1.0 -> 0.4 at 2 s."""
    scenario = replace(shipped_scenario('rail_creep_steps'), duration=5.0,
                       events=(RailEvent(STEP_TIME, 'creep_factor', 0.4),))
    return simulate(scenario)


def _flatten(data: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    """Nested params-file mappings as dotted names (as rcl reads them)."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f'{prefix}{key}.'))
        else:
            out[prefix + key] = value
    return out


def _shipped() -> dict[str, Any]:
    return _flatten(yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters'])


def _config_parameters(**overrides: Any) -> list[Parameter]:
    """The shipped YAML's parameters (what --params-file would give), with overrides."""
    data = _shipped()
    data.update(overrides)
    return [Parameter(k, value=v) for k, v in data.items()]


def _listen(node: Node, got: list[CreepFactor]) -> None:
    node.create_subscription(CreepFactor, 'rail/creep_factor', got.append, DEEP)


def _stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def test_config_yaml_matches_declared_defaults(make_node: Callable[..., Any]) -> None:
    """The shipped YAML loads, names only declared parameters and states their defaults."""
    data = _shipped()
    node = make_node(CreepEstimatorNode, parameter_overrides=_config_parameters())
    plain = make_node(CreepEstimatorNode, node_name='creep_defaults')
    for name, value in data.items():
        assert node.get_parameter(name).value == pytest.approx(value), name
        assert plain.get_parameter(name).value == pytest.approx(value), name
    assert node.processor.ekf.params.pattern == 'C'


def test_replay_tracks_creep_drop(creep_drop: RailSimulationResult, tmp_path: Path,
                                  make_node: Callable[..., Any],
                                  spin_until: Callable[..., bool]) -> None:
    """Bag replay (player, as fast as possible): one CreepFactor per lateral-states sample with
    its stamp, known-input mode throughout, the drop to 40 % followed within 1 s (pattern A,
    the one meeting the method page's 5 %)."""
    series = to_topic_series(creep_drop, start_time=100.0)
    topics = ('/rail/lateral_states', '/rail/track_irregularity')
    bag = write_bag(tmp_path / 'creep_drop', {t: series[t] for t in topics})
    got: list[CreepFactor] = []
    _listen(make_node('listener'), got)
    node = make_node(CreepEstimatorNode, parameter_overrides=_config_parameters(pattern='A'))
    player = make_node(ScenarioPlayer, parameter_overrides=[
        Parameter('bag', value=str(bag)), Parameter('as_fast_as_possible', value=True),
        Parameter('wait_for_subscribers', value=1),
        Parameter('sync_topics', value=['/rail/creep_factor'])])
    n = len(series['/rail/lateral_states'])
    assert spin_until(lambda: len(got) >= n, timeout_s=60.0), f'{len(got)} of {n}'
    assert spin_until(player.done.is_set, timeout_s=10.0)
    stamps = np.array([stamp_ns(m.header.stamp) for m in got])
    np.testing.assert_array_equal(stamps, series['/rail/lateral_states'].stamps_ns)
    counts = node.processor.counts
    # The track stream is not known to be alive before its first message arrives, and DDS may
    # deliver the first few lateral-states samples before it: those few run without the track.
    assert counts['known_input'] >= n - 10 and counts['unpaired'] == 0, counts
    c = np.array([m.creep_factor for m in got])
    t = creep_drop.time
    before = (t > 1.0) & (t < STEP_TIME)
    after = t >= STEP_TIME + 1.0
    # The node is the offline core on the same samples, to rounding; the samples without the
    # track are the first ones (what the offline run replicates).
    y, track, _ = simulation_inputs(creep_drop, 'A')
    missing_track = n - counts['known_input']
    ekf = CreepEkf(node.parameters_of(CreepEkfParams))
    offline = [ekf.step(y[k], None if k < missing_track else track[k]).creep_factor
               for k in range(n)]
    np.testing.assert_allclose(c, offline, rtol=1e-9)
    # Measured on this run: at most 4.5 % off before the drop, 4.9 % from 1 s after it.
    assert np.all(np.abs(c[before] - 1.0) < 0.055)
    assert np.all(np.abs(c[after] / 0.4 - 1.0) < 0.055)
    assert all(m.low_adhesion for m, late in zip(got, after, strict=True) if late)
    assert not any(m.low_adhesion for m, early in zip(got, before, strict=True) if early)
    last = got[-1]
    assert last.f11 == pytest.approx(last.creep_factor * 7.44e6)
    assert last.f22 == pytest.approx(last.creep_factor * 6.79e6)
    assert 0.0 < last.std_dev < 0.2


def test_pattern_d_pairs_imus_and_track(creep_drop: RailSimulationResult,
                                        make_node: Callable[..., Any],
                                        spin_until: Callable[..., bool]) -> None:
    """Pattern D: body IMU and track paired to the bogie IMU by stamp, whatever the arrival
    order (body before bogie here); one output per bogie sample, none unpaired."""
    got: list[CreepFactor] = []
    _listen(make_node('listener'), got)
    node = make_node(CreepEstimatorNode, parameter_overrides=[Parameter('pattern', value='D')])
    pub = make_node('feeder')
    bogie = pub.create_publisher(Imu, 'rail/bogie/imu', DEEP)
    body = pub.create_publisher(Imu, 'rail/body/imu', DEEP)
    track = pub.create_publisher(TrackIrregularity, 'rail/track_irregularity', DEEP)
    assert spin_until(lambda: bogie.get_subscription_count() > 0
                      and body.get_subscription_count() > 0, timeout_s=10.0)
    n = 400
    stamps = (np.round(creep_drop.time[:n] * 1e9)).astype(np.int64) + 50 * 10**9
    for k in range(n):
        m_body = Imu()
        m_body.header.stamp = _stamp(stamps[k] + 300_000)       # 0.3 ms skew: within 2 ms
        m_body.linear_acceleration.y = float(creep_drop.body_lateral_accel[k])
        body.publish(m_body)
        m_track = TrackIrregularity()
        m_track.header.stamp = _stamp(stamps[k])
        m_track.lateral_alignment = creep_drop.measured_track_alignment[k].tolist()
        track.publish(m_track)
        m_bogie = Imu()
        m_bogie.header.stamp = _stamp(stamps[k])
        m_bogie.linear_acceleration.y = float(creep_drop.bogie_lateral_accel[k])
        m_bogie.angular_velocity.z = float(creep_drop.bogie_yaw_rate[k])
        bogie.publish(m_bogie)
        if k % 20 == 0:
            spin_until(lambda: False, timeout_s=0.0)
    # The last sample waits for a later stamp on each stream or for its parts: all are there.
    assert spin_until(lambda: len(got) >= n, timeout_s=20.0), f'{len(got)} of {n}'
    assert [stamp_ns(m.header.stamp) for m in got] == stamps.tolist()
    counts = node.processor.counts
    # The first sample may go before the track stream's first message (not yet alive).
    assert counts['unpaired'] == 0 and counts['known_input'] >= n - 1
    assert node.processor.ekf.rejected == {}
    assert all(math.isfinite(m.creep_factor) for m in got)


def _lateral_msg(result: RailSimulationResult, k: int, stamp: int) -> RailLateralStates:
    msg = RailLateralStates()
    msg.header.stamp = _stamp(stamp)
    names = result.state_names
    row = result.measured_state[k]

    def cols(prefix: str, bodies: list[str]) -> list[float]:
        return [float(row[names.index(f'{prefix}_{b}')]) for b in bodies]

    wheelsets, bogies = ['w1', 'w2', 'w3', 'w4'], ['b1', 'b2']
    msg.wheelset_lateral = cols('y', wheelsets)
    msg.wheelset_lateral_rate = cols('dy', wheelsets)
    msg.wheelset_yaw = cols('psi', wheelsets)
    msg.wheelset_yaw_rate = cols('dpsi', wheelsets)
    msg.bogie_lateral = cols('y', bogies)
    msg.bogie_lateral_rate = cols('dy', bogies)
    msg.bogie_yaw = cols('psi', bogies)
    msg.bogie_yaw_rate = cols('dpsi', bogies)
    msg.body_lateral = float(row[names.index('y_v')])
    msg.body_lateral_rate = float(row[names.index('dy_v')])
    msg.body_yaw = float(row[names.index('psi_v')])
    msg.body_yaw_rate = float(row[names.index('dpsi_v')])
    return msg


def test_bad_input_counted_and_estimate_protected(
        creep_drop: RailSimulationResult, make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """Inf, repeated and out-of-order stamps, a frozen sensor, missing samples and a long gap:
    each rejected or bridged and counted, the node stays up, the estimate stays sane and
    /diagnostics reports the stale track input and the counts."""
    got: list[CreepFactor] = []
    _listen(make_node('listener'), got)
    diagnostics: list[DiagnosticArray] = []
    make_node('diag_listener').create_subscription(DiagnosticArray, '/diagnostics',
                                                   diagnostics.append, DEEP)
    node = make_node(CreepEstimatorNode, parameter_overrides=[
        Parameter('pattern', value='A'), Parameter('diagnostics_period_s', value=0.05)])
    pub = make_node('feeder').create_publisher(RailLateralStates, 'rail/lateral_states', DEEP)
    assert spin_until(lambda: pub.get_subscription_count() > 0, timeout_s=10.0)
    period = 5_000_000
    base = 10 * 10**9
    sent = 0
    for k in range(600):
        stamp = base + k * period
        if 300 <= k < 306:
            continue                                  # 6 missing samples: bridged
        if k >= 500:
            stamp += 10**9                            # 1 s gap: filter reset
        msg = _lateral_msg(creep_drop, k, stamp)
        if k == 100:
            msg.bogie_lateral = [math.inf, 0.0]       # non-finite (NaN: missing_fields)
        if 200 <= k < 250:
            msg = _lateral_msg(creep_drop, 199, stamp)  # frozen sensor for 0.25 s
        pub.publish(msg)
        sent += 1
        if k == 150:
            pub.publish(_lateral_msg(creep_drop, k, stamp))           # repeated stamp
            pub.publish(_lateral_msg(creep_drop, k, stamp - 3 * period))  # out of order
        if k % 25 == 0:
            spin_until(lambda: False, timeout_s=0.0)
    assert spin_until(lambda: len(got) >= sent, timeout_s=20.0), f'{len(got)} of {sent}'
    assert spin_until(lambda: any(
        any(kv.key == 'received' and int(kv.value) >= sent + 2 for kv in d.status[0].values)
        for d in diagnostics), timeout_s=10.0)
    counts = node.processor.counts
    assert counts['received'] == sent + 2
    assert counts['processed'] == sent
    assert counts['predicted_missing'] == 6
    assert counts['gap_resets'] == 1
    # Samples 200-249 repeat sample 199 (50 repeats); from the 4th repeat (0.02 s) on they are
    # rejected: 47.
    assert counts['frozen'] == 47
    assert counts['non_finite'] == 1 and node.processor.ekf.rejected == {}   # refused before it
    status = next(d.status[0] for d in reversed(diagnostics)
                  if any(kv.key == 'received' and int(kv.value) >= sent + 2
                         for kv in d.status[0].values))
    values = {kv.key: kv.value for kv in status.values}
    assert values['rejected_repeated'] == '1' and values['rejected_out_of_order'] == '1'
    assert values['track_input'] == 'stale'
    assert ('track input stale' in status.message or 'reset' in status.message
            or 'recovering' in status.message)
    c = np.array([m.creep_factor for m in got])
    assert np.all(np.isfinite(c)) and np.all((c >= 0.05) & (c <= 2.0))
    # Before the drop at 2 s (sample 400, output 394: 6 samples were missing), without track
    # input and through the bad samples, c stays near nominal.
    err = np.abs(c[50:394] - 1.0)
    assert np.all(err < 0.2), (err.max(), err.argmax() + 50)


def test_parameters_validated(make_node: Callable[..., Any]) -> None:
    """Inconsistent settings are refused at start; speed changes at runtime rebuild the model;
    out-of-range values are refused with the reason."""
    with pytest.raises(ConfigurationError, match='min_creep_factor'):
        make_node(CreepEstimatorNode, parameter_overrides=[
            Parameter('min_creep_factor', value=1.5), Parameter('max_creep_factor', value=1.0)])
    with pytest.raises(ConfigurationError, match='pattern'):
        make_node(CreepEstimatorNode, node_name='bad_pattern',
                  parameter_overrides=[Parameter('pattern', value='E')])
    node = make_node(CreepEstimatorNode, node_name='ok')
    (result,) = node.set_parameters([Parameter('vehicle.speed', value=30.0)])
    assert result.successful and node.processor.ekf.speed == pytest.approx(30.0)
    (result,) = node.set_parameters([Parameter('vehicle.speed', value=-3.0)])
    assert not result.successful
    (result,) = node.set_parameters([Parameter('pattern', value='A')])
    assert not result.successful                      # read-only: model structure
    (result,) = node.set_parameters([Parameter('low_adhesion_threshold', value=0.3)])
    assert result.successful and node.processor.ekf.params.low_adhesion_threshold == 0.3
