"""tire_stiffness_observer node: parameters, simulator data in, outputs, calibration, bad input.

Inputs come from the road simulator (a shortened Umeno scenario: 60 km/h smooth asphalt, FR
stepped 200 -> 140 kPa at 7 s), published by a test node in bursts the node's queue can hold.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
import dataclasses
from pathlib import Path
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger
from vehicle_monitor_msgs.msg import DriverInputs, TireStiffness, TpmsIndication, WheelSpeeds
import yaml

from tpms_ros.core.stiffness_observer import StiffnessObserverParams, TireStiffnessObserver
from tpms_ros.nodes.tire_stiffness_observer_node import TireStiffnessObserverNode
from tpms_ros.simulation.road_scenario import ScenarioEvent, load_scenario
from tpms_ros.simulation.road_simulator import RoadSimulationResult, simulate_scenario
from vehicle_monitor_common.node_helpers import ConfigurationError, stamp_ns

PKG = Path(__file__).resolve().parents[3] / 'src' / 'tpms_ros'
CONFIG = PKG / 'config' / 'tire_stiffness_observer.yaml'
DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                  reliability=ReliabilityPolicy.RELIABLE)
START_NS = 1_700_000_000 * 10**9  # epoch-like stamps: the node must keep ms resolution
# Short memory and tooth learning so a 16 s run calibrates, converges and follows a step (the
# defaults are for minutes of driving).
FAST = {'block_s': 0.1, 'forgetting_factor': 0.97, 'calibration_s': 4.0, 'tooth_learned_s': 1.0}


@pytest.fixture(scope='module')
def drive() -> RoadSimulationResult:
    """16 s at 60 km/h on smooth asphalt, FR 200 -> 140 kPa over 7-8 s (seeded)."""
    scenario = load_scenario(PKG / 'scenarios' / 'umeno_step_60kmh_smooth_asphalt.yaml')
    scenario = dataclasses.replace(scenario, duration_s=16.0, events=(
        ScenarioEvent('pressure_step', 7.0, (1,), to_kpa=140.0, duration_s=1.0),))
    return simulate_scenario(scenario)


def _dotted(mapping: dict[str, Any], prefix: str = '') -> Iterator[tuple[str, Any]]:
    """A nested params-file mapping as (dotted name, value) pairs."""
    for key, value in mapping.items():
        if isinstance(value, dict):
            yield from _dotted(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def _overrides(values: dict[str, Any]) -> list[Parameter]:
    return [Parameter(k, value=v) for k, v in values.items()]


def _stamps(result: RoadSimulationResult) -> np.ndarray:
    return START_NS + np.round(result.wheel_speed_t * 1e9).astype(np.int64)


class Harness:
    """A test node that publishes wheel speeds and records the observer's outputs."""

    def __init__(self, make_node: Callable[..., Any], spin_until: Callable[..., bool]) -> None:
        self.node = make_node('stiffness_test_driver')
        self.spin_until = spin_until
        self.pub = self.node.create_publisher(WheelSpeeds, 'vehicle/wheel_speeds', DEEP)
        self.stiffness: list[TireStiffness] = []
        self.indication: list[TpmsIndication] = []
        self.diagnostics: list[Any] = []
        self.node.create_subscription(TireStiffness, 'tpms/tire_stiffness',
                                      self.stiffness.append, DEEP)
        self.node.create_subscription(TpmsIndication, 'tpms/indication/stiffness',
                                      self.indication.append, DEEP)
        self.node.create_subscription(
            DiagnosticArray, '/diagnostics',
            lambda m: self.diagnostics.extend(s for s in m.status
                                              if 'tire_stiffness_observer' in s.name), DEEP)

    def feed(self, observer: TireStiffnessObserverNode, stamps: np.ndarray,
             omega: np.ndarray, burst: int = 250) -> None:
        """Publish every sample; wait after each burst until the observer has taken it."""
        assert self.spin_until(lambda: self.pub.get_subscription_count() > 0, 10.0)
        for start in range(0, len(stamps), burst):
            target = observer.processor.received + min(burst, len(stamps) - start)
            for stamp, row in zip(stamps[start:start + burst], omega[start:start + burst],
                                  strict=True):
                msg = WheelSpeeds()
                msg.header.stamp = Time(sec=int(stamp) // 10**9, nanosec=int(stamp) % 10**9)
                msg.omega = [float(v) for v in row]
                self.pub.publish(msg)
            assert self.spin_until(lambda t=target: observer.processor.received >= t, 10.0), \
                f'observer got {observer.processor.received} of {target}'


def test_defaults_and_shipped_yaml(make_node: Callable[..., Any]) -> None:
    """The node starts with its defaults and with the shipped YAML, which sets every key."""
    default = make_node(TireStiffnessObserverNode)
    assert default.parameter_values['sample_rate_hz'] == 1000.0
    assert default.processor.calibration.state == 'uncalibrated'
    node = make_node(TireStiffnessObserverNode, node_name='tire_stiffness_observer',
                     cli_args=['--ros-args', '--params-file', str(CONFIG)])
    shipped = dict(_dotted(
        yaml.safe_load(CONFIG.read_text())['/**']['ros__parameters']))
    declared = node.parameter_values
    assert set(shipped) == set(declared)
    for name, value in shipped.items():
        got = declared[name]
        assert (list(got) if isinstance(got, tuple) else got) == value, name


@pytest.mark.parametrize('values, match', [
    ({'process_period_s': 0.002, 'sample_rate_hz': 400.0}, 'shorter than one sample'),
    ({'band_low_hz': 70.0}, 'band_hz'),
    ({'observer_pole_factor': 20.0}, 'Nyquist'),
    ({'driven_axle': 'middle'}, 'driven_axle'),
    ({'drive_compensation': 'sum'}, 'drive_compensation'),
    ({'partner_lag_step_s': 1e-4}, 'partner_lag_step_s'),
    ({'tire.k': -5.0}, 'parameter tire.k'),
    ({'nominal_pressure_kpa': [200.0, 200.0]}, 'nominal_pressure_kpa'),
])
def test_invalid_parameters_refused_at_start(make_node: Callable[..., Any],
                                             values: dict[str, Any], match: str) -> None:
    """A bad value stops the node at start with a ConfigurationError naming the problem."""
    with pytest.raises(ConfigurationError, match=match):
        make_node(TireStiffnessObserverNode, parameter_overrides=_overrides(values))


def test_invalid_parameters_refused_at_runtime(make_node: Callable[..., Any]) -> None:
    """At runtime a bad set is refused with its reason and the old value stays in force."""
    node = make_node(TireStiffnessObserverNode)
    (result,) = node.set_parameters([Parameter('band_high_hz', value=20.0)])
    assert not result.successful and 'band_hz' in result.reason
    (result,) = node.set_parameters([Parameter('forgetting_factor', value=1.5)])
    assert not result.successful
    assert node.parameter_values['band_high_hz'] == 60.0
    assert node.parameter_values['forgetting_factor'] == 0.98
    (result,) = node.set_parameters([Parameter('forgetting_factor', value=0.95)])
    assert result.successful
    assert node.processor.observer.params.forgetting_factor == 0.95  # rebuilt with the new value
    (result,) = node.set_parameters([Parameter('drive_compensation', value='difference')])
    assert result.successful and node.processor.observer.params.drive_compensation == 'difference'
    # The rule across the two groups, checked with the other group's value in force.
    (result,) = node.set_parameters([Parameter('process_period_s', value=0.002)])
    assert result.successful
    (result,) = node.set_parameters([Parameter('sample_rate_hz', value=400.0)])
    assert not result.successful and 'shorter than one sample' in result.reason
    assert node.parameter_values['sample_rate_hz'] == 1000.0


def test_tracks_truth_calibrates_and_persists(
        drive: RoadSimulationResult, make_node: Callable[..., Any],
        spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Calibrated via ~/calibrate; outputs carry input stamps, equal the core offline, follow
    the FR step without cross-talk; the calibration is saved and a new node reloads it."""
    cal_file = tmp_path / 'cal' / 'stiffness.yaml'
    params = {**FAST, 'calibration_file': str(cal_file)}
    harness = Harness(make_node, spin_until)
    node = make_node(TireStiffnessObserverNode, parameter_overrides=_overrides(params))
    client = harness.node.create_client(Trigger, 'tire_stiffness_observer/calibrate')
    assert client.wait_for_service(timeout_sec=10.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(future.done, 10.0)
    assert future.result().success, future.result().message
    assert node.processor.calibration.state == 'calibrating'

    stamps = _stamps(drive)
    harness.feed(node, stamps, drive.wheel_speed)
    n_out = len(stamps) // 250
    assert spin_until(lambda: len(harness.stiffness) >= n_out
                      and len(harness.indication) >= n_out, 10.0)
    out_stamps = np.array([stamp_ns(m.header.stamp) for m in harness.stiffness])
    # Every output answers the last sample of a 0.25 s chunk (publish_rate_hz 4).
    np.testing.assert_array_equal(out_stamps, stamps[249::250][:n_out])
    assert [stamp_ns(m.header.stamp) for m in harness.indication] == out_stamps.tolist()
    assert {m.method for m in harness.indication} == {'stiffness'}

    # The node is a thin wrapper: the core fed the same chunks offline gives the same numbers.
    offline = TireStiffnessObserver(node.processor.observer.params, node.processor.observer.tires)
    offline.start_calibration(FAST['calibration_s'])
    seconds = (stamps - stamps[0]) * 1e-9
    expected = [offline.update(drive.wheel_speed[s:s + 250], stamps=seconds[s:s + 250])
                for s in range(0, 250 * n_out, 250)]
    got = np.array([m.pressure_kpa for m in harness.stiffness])
    want = np.array([e.pressure_kpa for e in expected])
    np.testing.assert_allclose(got, want, rtol=1e-12, equal_nan=True)

    assert node.processor.calibration.state == 'calibrated' and cal_file.exists()
    assert harness.stiffness[-1].calibrated
    t_out = (out_stamps - START_NS) * 1e-9
    truth = np.column_stack([np.interp(t_out, drive.handling.t, drive.pressure_kpa[:, w])
                             for w in range(4)])
    late = (t_out > 12.0) & (t_out < 15.5)
    assert np.all(np.array([m.valid for m in harness.stiffness])[late])
    est = got[late].mean(axis=0)
    # Unchanged tires stay near 200 kPa (measured 195.3-197.7, spread ~2 kPa).
    assert np.all(np.abs(est[[0, 2, 3]] - 200.0) < 10.0), est
    # FR (truth 140 kPa) follows the 60 kPa drop (measured 151.7 kPa: most of the rest is the
    # lag of the 3.3 s RLS memory, 4-7.5 s after the step).
    assert truth[late, 1].mean() < 141.0
    assert est[1] < 160.0 and est[1] < est[[0, 2, 3]].mean() - 35.0, est

    reloaded = make_node(TireStiffnessObserverNode, node_name='tire_stiffness_observer_2',
                         parameter_overrides=_overrides(params))
    assert reloaded.processor.calibration.state == 'loaded'
    assert reloaded.processor.observer.calibration_state() == yaml.safe_load(cal_file.read_text())


@pytest.mark.parametrize('content', ['k_nominal: [1, 2\n', 'version: 99\nk_nominal: [1]\n',
                                     '- just\n- a list\n'])
def test_corrupt_calibration_file_reported(
        content: str, make_node: Callable[..., Any], spin_until: Callable[..., bool],
        tmp_path: Path) -> None:
    """A corrupt file does not crash the node: /diagnostics says so, recalibration asked."""
    cal_file = tmp_path / 'stiffness.yaml'
    cal_file.write_text(content)
    harness = Harness(make_node, spin_until)
    node = make_node(TireStiffnessObserverNode, parameter_overrides=_overrides(
        {'calibration_file': str(cal_file), 'calibrate_on_start': True}))
    # calibrate_on_start recalibrates because nothing usable was loaded.
    calibration = node.processor.calibration
    assert calibration.state == 'calibrating' and calibration.file_problem
    assert spin_until(lambda: any('calibration file unusable' in s.message
                                  for s in harness.diagnostics), 5.0)
    status = next(s for s in harness.diagnostics if 'calibration file unusable' in s.message)
    assert status.level == bytes([1])  # WARN
    assert cal_file.read_text() == content  # left for the user to inspect


def test_bad_input_rejected_and_wheel_unknown(
        drive: RoadSimulationResult, make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """Malformed payloads, repeated and out-of-order messages are counted; a NaN wheel is
    unknown, never flagged low, and the other wheels keep estimating."""
    harness = Harness(make_node, spin_until)
    node = make_node(TireStiffnessObserverNode, parameter_overrides=_overrides(
        {**FAST, 'calibrate_on_start': True}))
    stamps = _stamps(drive)[:6000]
    omega = drive.wheel_speed[:6000].copy()
    omega[5000:, 0] = np.nan   # FL sensor returns NaN for the last second
    harness.feed(node, stamps[:5500], omega[:5500])
    # Out-of-order and repeated stamps, then the rest in order.
    harness.feed(node, stamps[[5400, 5499, 10]], omega[[5400, 5499, 10]], burst=3)
    harness.feed(node, stamps[5500:], omega[5500:])
    # A payload that is not a WheelSpeeds (a replay publishes a damaged bag's bytes as they are).
    harness.pub.publish(b'\x00\x01\x00\x00' + bytes(20))
    assert spin_until(lambda: node.processor.rejected['malformed'] == 1, 5.0)
    assert dict(node.processor.rejected) == {'malformed': 1, 'repeated': 1, 'out_of_order': 2,
                                             'future_stamp': 0}
    assert spin_until(lambda: len(harness.indication) >= 24, 10.0)
    last = harness.indication[-1]
    assert not last.known[0] and not last.underinflated[0] and last.confidence[0] == 0.0
    assert all(last.known[1:])   # calibrated after 4 s and still judged on good data
    assert list(harness.stiffness[-1].valid) == [False, True, True, True]
    assert node.processor.observer.counters['invalid_sample'][0] == 1000
    assert spin_until(lambda: any(s.level == bytes([2]) and 'FL: invalid_sample' in s.message
                                  for s in harness.diagnostics), 5.0)


def test_steering_from_driver_inputs_pauses_the_estimate_when_cornering(
        make_node: Callable[..., Any], spin_until: Callable[..., bool],
        drive: RoadSimulationResult) -> None:
    """Driver inputs with a steering angle meaning twice the lateral limit at 60 km/h: every
    wheel's samples are held back by the cornering gate (counted by the core), and the torques
    pass too."""
    node = make_node(TireStiffnessObserverNode, node_name='stiffness_cornering')
    harness = Harness(make_node, spin_until)
    driver = harness.node.create_publisher(DriverInputs, 'vehicle/driver_inputs', DEEP)
    assert spin_until(lambda: driver.get_subscription_count() > 0, 10.0)
    stamps = _stamps(drive)[:3000]
    p = node.parameters_of(StiffnessObserverParams)
    speed = 60.0 / 3.6
    steering = float(np.arctan(2.0 * p.max_lateral_accel_mps2 * p.wheelbase_m / speed ** 2))
    for stamp in range(int(stamps[0]), int(stamps[-1]) + 1, 10_000_000):   # 100 Hz
        msg = DriverInputs()
        msg.header.stamp = Time(sec=stamp // 10**9, nanosec=stamp % 10**9)
        msg.steering_angle = steering
        msg.wheel_torque = [0.0, 0.0, 50.0, 50.0]
        driver.publish(msg)
    assert spin_until(lambda: len(node.processor._driver) >= 250, 10.0)
    harness.feed(node, stamps, drive.wheel_speed[:3000])
    assert spin_until(lambda: node.processor.processed >= 2750, 10.0)
    counts = node.processor.observer.counters
    # Every sample after the filters' settling, or while the tooth pattern is learned.
    assert counts['cornering'][0] + counts['settling'][0] + counts['tooth_learning'][0] \
        >= node.processor.processed - 1
    assert counts['cornering'][0] >= 1500, counts['cornering']
    assert counts['steering_invalid'][0] == 0 and counts['torque_invalid'][0] == 0
