"""suspension_monitor node: config, fault detection from published IMUs, pairing, bad input."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
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
from vehicle_monitor_msgs.msg import CreepFactor, ModeProbabilities, TrackIrregularity
import yaml

from rail_monitor_ros.core.suspension_imm import SuspensionImmParams
from rail_monitor_ros.nodes.suspension_monitor_node import SuspensionMonitorNode
from rail_monitor_ros.processing.suspension_monitor import SuspensionMonitorNodeParams
from rail_monitor_ros.simulation.rail_scenario import shipped_scenario
from rail_monitor_ros.simulation.rail_simulator import simulate, to_topic_series
from vehicle_monitor_common.bag_io import read_series, write_bag
from vehicle_monitor_common.node_helpers import ConfigurationError, stamp_ns
from vehicle_monitor_common.parameters import parameter_specs

CONFIG = (Path(__file__).resolve().parents[3]
          / 'src/rail_monitor_ros/config/suspension_monitor.yaml')
DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                  reliability=ReliabilityPolicy.RELIABLE)
START_NS = 1_000 * 10**9
DT_NS = 5_000_000


@dataclass(frozen=True)
class _ImuData:
    time: np.ndarray           # (N,) s from the first sample
    measurements: np.ndarray   # (N, 3) bogie lateral accel, bogie yaw rate, body lateral accel


@pytest.fixture(scope='module')
def paper_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's run on the rail simulator's 14-DOF full car (spring 150 % at 3 s, damper
    50 % at 6 s) as the bag the simulator writes."""
    return write_bag(tmp_path_factory.mktemp('imm') / 'paper', to_topic_series(
        simulate(shipped_scenario('rail_imm_spring_damper_fault'))))


@cache
def _imu_from_bag(path: Path) -> _ImuData:
    series = read_series(path, ['/rail/bogie/imu', '/rail/body/imu'])
    bogie, body = series['/rail/bogie/imu'], series['/rail/body/imu']
    assert np.array_equal(bogie.stamps_ns, body.stamps_ns)
    z = np.column_stack([bogie.fields['linear_acceleration.y'],
                         bogie.fields['angular_velocity.z'], body.fields['linear_acceleration.y']])
    stamps = np.asarray(bogie.stamps_ns)
    first_5_s = slice(0, 1000)
    return _ImuData((stamps[first_5_s] - stamps[0]) * 1e-9, z[first_5_s])


def _flatten(mapping: dict[str, Any], prefix: str = '') -> dict[str, Any]:
    """A params file's nested mapping as dotted names (what --params-file declares)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f'{prefix}{key}.'))
        else:
            out[f'{prefix}{key}'] = value
    return out


def _config_parameters(**overrides: Any) -> list[Parameter]:
    """The shipped YAML (what --params-file gives), reliable inputs, with overrides."""
    data = _flatten(yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters'])
    data.update(overrides)
    params = [Parameter(k, value=v) for k, v in data.items()]
    params += [Parameter(f'qos_overrides./{t}.subscription.reliability', value='reliable')
               for t in ('rail/bogie/imu', 'rail/body/imu', 'rail/track_irregularity')]
    return params


def _stamp(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


class _Feeder:
    """Publishes IMU (and track) samples as the rail simulator would."""

    def __init__(self, node: Node) -> None:
        self.bogie = node.create_publisher(Imu, 'rail/bogie/imu', DEEP)
        self.body = node.create_publisher(Imu, 'rail/body/imu', DEEP)
        self.track = node.create_publisher(TrackIrregularity, 'rail/track_irregularity', DEEP)

    def imu(self, stamp: int, z: np.ndarray, *, bogie: bool = True, body: bool = True) -> None:
        if bogie:
            msg = Imu()
            msg.header.stamp = _stamp(stamp)
            msg.linear_acceleration.y = float(z[0])
            msg.angular_velocity.z = float(z[1])
            self.bogie.publish(msg)
        if body:
            msg = Imu()
            msg.header.stamp = _stamp(stamp)
            msg.linear_acceleration.y = float(z[2])
            self.body.publish(msg)

    def alignment(self, stamp: int, alignment: list[float], rate: list[float]) -> None:
        msg = TrackIrregularity()
        msg.header.stamp = _stamp(stamp)
        msg.lateral_alignment = alignment
        msg.lateral_alignment_rate = rate
        self.track.publish(msg)


def _setup(make_node: Callable[..., Any], **overrides: Any) -> tuple[Any, _Feeder,
                                                                      list[ModeProbabilities],
                                                                      list[DiagnosticArray]]:
    monitor = make_node(SuspensionMonitorNode, parameter_overrides=_config_parameters(**overrides))
    test_node = make_node('feeder')
    got: list[ModeProbabilities] = []
    diagnostics: list[DiagnosticArray] = []
    test_node.create_subscription(ModeProbabilities, 'rail/suspension/modes', got.append, DEEP)
    test_node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, DEEP)
    return monitor, _Feeder(test_node), got, diagnostics


def test_config_yaml_matches_declared_defaults(make_node: Callable[..., Any]) -> None:
    """Every key of the shipped YAML is a declared parameter with the same default, and every
    declared parameter (the method's and the node's) is in it."""
    data = _flatten(yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters'])
    node = make_node(SuspensionMonitorNode)
    for key, value in data.items():
        assert node.has_parameter(key), key
        assert node.get_parameter(key).value == pytest.approx(value), key
    declared = {*parameter_specs(SuspensionImmParams), *parameter_specs(
        SuspensionMonitorNodeParams)}
    assert set(data) == {spec.name for spec in declared}


def test_detects_spring_fault_from_published_imus(make_node: Callable[..., Any],
                                                  spin_until: Callable[..., bool],
                                                  paper_bag: Path) -> None:
    """The paper's first 5 s (full-car simulator bag) as IMU messages: one output per pair
    with the input's stamp, normal before 3 s, spring fault declared after it, diagnostics
    WARN/ERROR naming it and reporting the input rate."""
    data = _imu_from_bag(paper_bag)
    monitor, feeder, got, diagnostics = _setup(make_node, use_track_irregularity=False,
                                               diagnostics_period_s=0.05)
    stamps = START_NS + np.arange(len(data.time), dtype=np.int64) * DT_NS
    for k0 in range(0, len(stamps), 100):
        end = min(k0 + 100, len(stamps))
        for k in range(k0, end):
            feeder.imu(int(stamps[k]), data.measurements[k])
        assert spin_until(lambda n=end: len(got) >= n, timeout_s=20.0)
    assert [stamp_ns(m.header.stamp) for m in got] == stamps.tolist()
    t = (np.array([stamp_ns(m.header.stamp) for m in got]) - START_NS) * 1e-9
    detected = np.array([m.fault_detected for m in got])
    assert not detected[t < 3.0].any()
    assert detected[-1] and got[-1].fault_component == 'spring'
    assert abs(got[-1].spring_ratio - 1.5) < 0.1
    assert list(got[-1].modes)[5] == 'spring_150' and len(got[-1].modes) == 16
    assert abs(sum(got[-1].probability) - 1.0) < 1e-9
    assert spin_until(lambda: any('suspension fault: spring' in s.message
                                  for d in diagnostics for s in d.status), timeout_s=5.0)
    status = [s for d in diagnostics for s in d.status if 'suspension fault' in s.message][-1]
    assert status.level in (b'\x01', b'\x02')
    assert monitor.processor.rejected.total() == 0
    rates = [float(kv.value) for d in diagnostics for st in d.status for kv in st.values
             if kv.key == 'input_rate_hz.rail/bogie/imu']
    assert rates and max(rates) > 0.0           # the input rate is reported


def test_bad_input_is_rejected_and_counted(make_node: Callable[..., Any],
                                           spin_until: Callable[..., bool],
                                           paper_bag: Path) -> None:
    """NaN, saturated, repeated and out-of-order stamps, an unpaired sample, a frozen sensor:
    counted, outputs stay finite, no fault, and the diagnostic reports an input fault."""
    data = _imu_from_bag(paper_bag)
    monitor, feeder, got, diagnostics = _setup(make_node, frozen_samples=5,
                                               diagnostics_period_s=0.05)
    z = data.measurements
    s = [START_NS + k * DT_NS for k in range(200)]
    for k in range(50):
        feeder.imu(s[k], z[k])
    assert spin_until(lambda: len(got) >= 50)
    feeder.imu(s[50], np.array([math.nan, 0.0, 0.0]))
    feeder.imu(s[51], np.array([80.0, 0.0, 0.0]))
    feeder.imu(s[51], z[51])                      # repeated stamp
    feeder.imu(s[40], z[40])                      # out of order
    feeder.imu(s[52], z[52], body=False)          # body sample lost
    for k in range(53, 60):
        feeder.imu(s[k], np.array([0.1, 0.01, 0.2]))   # frozen
    for k in range(60, 120):
        feeder.imu(s[k], z[k])
    assert spin_until(lambda: stamp_ns(got[-1].header.stamp) == s[119] if got else False)
    counts = monitor.processor.rejected
    assert counts['non_finite'] == 1 and counts['saturated'] == 1
    assert counts['bogie_repeated'] == 1 and counts['body_repeated'] == 1
    assert counts['bogie_out_of_order'] == 1 and counts['body_out_of_order'] == 1
    assert counts['unpaired'] >= 1 and counts['frozen_sensor'] >= 3
    assert all(np.all(np.isfinite(m.probability)) for m in got)
    assert not any(m.fault_detected for m in got)
    feeder.imu(s[120], np.array([math.inf, 0.0, 0.0]))
    assert spin_until(lambda: stamp_ns(got[-1].header.stamp) == s[120])
    assert spin_until(lambda: any('input fault' in st.message for d in diagnostics
                                  for st in d.status))


def test_known_inputs_used_when_fresh_and_stale_reported(
        make_node: Callable[..., Any], spin_until: Callable[..., bool],
        paper_bag: Path) -> None:
    """Fresh track irregularity -> known-input model (held up to track_max_age_s = 20 ms, four
    samples); after that the process-noise model and a 'stale' diagnostic; a wrongly sized
    track message is counted. A pair waits for its track sample while the track stream is
    alive (pair_timeout_s = 0.1 s of data time, 20 samples), so once the track stops the
    outputs come 20 samples late, then at once. (No creep estimator and no speed here: a
    stream never heard is waited for as long at the start, so the node is told not to follow
    them.)"""
    data = _imu_from_bag(paper_bag)
    monitor, feeder, got, _ = _setup(make_node, use_creep_factor=False, use_speed_input=False)
    for k in range(60):
        stamp = START_NS + k * DT_NS
        if k < 30:
            feeder.alignment(stamp, [1e-3 + k * 1e-6, 2e-3, 0.0, 0.0],   # not frozen
                             [0.01, 0.0, 0.0, 0.0])
            assert spin_until(lambda s=stamp: monitor.processor._track.latest == s)
        feeder.imu(stamp, data.measurements[k])
        if k < 30 or k >= 50:
            assert spin_until(lambda n=k + 1: len(got) >= n)
        else:
            assert spin_until(lambda: monitor.processor._pairer.pending == 0)
            assert len(got) == 30
    assert monitor.processor.known_input_samples == 30 + 4
    assert 'stale' in monitor.processor._track_state
    feeder.alignment(START_NS + 60 * DT_NS, [1e-3], [])
    assert spin_until(lambda: monitor.processor.rejected['track_irregularity_size'] == 1)


def test_model_follows_the_creep_estimate(make_node: Callable[..., Any],
                                          spin_until: Callable[..., bool]) -> None:
    """A confident creep factor estimate re-discretises the full-car bank at that factor; an
    uncertain one is not used (said on diagnostics), an invalid one is counted. (No speed
    stream: the node is told not to wait for one.)"""
    monitor, feeder, _, _ = _setup(make_node, use_track_irregularity=False,
                                   use_speed_input=False)
    publisher = make_node('creep_feeder').create_publisher(CreepFactor, 'rail/creep_factor',
                                                           DEEP)
    assert spin_until(lambda: publisher.get_subscription_count() > 0)
    f_before = monitor.processor.imm._f.copy()

    sent = [0]

    def send(c: float, std: float) -> None:
        """A creep estimate and the IMU pair at its stamp (the model follows the estimate at
        the next pair not older than it: data time)."""
        k = sent[0] = sent[0] + 1
        msg = CreepFactor()
        msg.header.stamp = _stamp(START_NS + k * DT_NS)
        msg.creep_factor, msg.std_dev = c, std
        publisher.publish(msg)
        assert spin_until(lambda: monitor.processor._creep.latest == START_NS + k * DT_NS)
        feeder.imu(START_NS + k * DT_NS, np.array([0.01 * k, 0.001 * k, 0.02 * k]))

    send(0.5, 0.5)
    assert spin_until(lambda: 'uncertain' in monitor.processor._creep_state)
    assert monitor.processor.imm.creep_factor == 1.0
    send(0.5, 0.02)
    assert spin_until(lambda: monitor.processor.imm.creep_factor == 0.5)
    assert monitor.processor._creep_state == 'following'
    assert not np.allclose(monitor.processor.imm._f, f_before)
    send(math.nan, 0.02)
    assert spin_until(lambda: monitor.processor.rejected['creep_factor_invalid'] == 1)
    assert monitor.processor.imm.creep_factor == 0.5


def test_parameters_validated(make_node: Callable[..., Any]) -> None:
    """A bad grid is refused at start; a bad runtime threshold is refused, a good one taken;
    a speed change re-discretises the full-car bank (its creep forces and track delays
    depend on it)."""
    with pytest.raises(ConfigurationError, match='spring_stop|mean_sojourn'):
        make_node(SuspensionMonitorNode, parameter_overrides=[
            Parameter('mean_sojourn_time_s', value=0.001)])
    node = make_node(SuspensionMonitorNode)
    (result,) = node.set_parameters([Parameter('fault_threshold', value=1.5)])
    assert not result.successful and 'fault_threshold' in result.reason
    (result,) = node.set_parameters([Parameter('fault_threshold', value=0.8)])
    assert result.successful and node.processor.imm.decision.threshold == 0.8
    f_before = node.processor.imm._f.copy()
    (result,) = node.set_parameters([Parameter('vehicle.speed', value=30.0)])
    assert result.successful and node.processor.imm.vehicle.speed == 30.0
    assert not np.allclose(node.processor.imm._f, f_before)
    (result,) = node.set_parameters([Parameter('vehicle.body_mass', value=9000.0)])
    assert not result.successful
