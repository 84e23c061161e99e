"""ROS nodes of issue 6: vibration_analyzer, wheel_radius_analyzer, tpms_voter (in-process).

Inputs are published from a test node with reliable QoS (the nodes' sensor subscriptions are
made reliable through the standard qos_overrides parameters, as a replay does) in chunks, and
each chunk waits on the node's outputs with a deadline. Rates are scaled down (200 Hz wheel
speeds, short calibration windows) to keep the file fast; the estimators themselves are tested
in the cores' tests.
"""

from __future__ import annotations

from collections.abc import Callable
import gc
from pathlib import Path
from typing import Any
import weakref

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from rclpy.clock import Clock as RclpyClock
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from scipy import signal
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger
from vehicle_monitor_msgs.msg import (
    DriverInputs,
    TireResonance,
    TpmsIndication,
    TpmsWarning,
    WheelRadiusOffsets,
    WheelSpeeds,
)
import yaml

from tpms_ros.core.vibration_analysis import VibrationCalibration
from tpms_ros.core.wheel_radius_analysis import WheelRadiusAnalyzer, WheelRadiusCalibration
from tpms_ros.nodes.tpms_voter_node import TpmsVoterNode
from tpms_ros.nodes.vibration_analyzer_node import VibrationAnalyzerNode
from tpms_ros.nodes.wheel_radius_analyzer_node import WheelRadiusAnalyzerNode
from vehicle_monitor_common.calibration_store import load_calibration, save_calibration
from vehicle_monitor_common.node_helpers import ConfigurationError, stamp_ns

CONFIG = Path(__file__).resolve().parents[3] / 'src' / 'tpms_ros' / 'config'
DEEP = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                  reliability=ReliabilityPolicy.RELIABLE)
T0_NS = 1000 * 10**9
FS = 200.0                       # wheel-speed rate of these tests, Hz
NOMINAL_HZ = np.array([42.0, 43.0, 44.0, 45.0])


def _reliable(*topics: str) -> list[Parameter]:
    return [Parameter(f'qos_overrides./{t}.subscription.reliability', value='reliable')
            for t in topics]


def _shipped(name: str) -> list[Parameter]:
    """The shipped config as overrides (nested keys joined by '.', as ROS names them).

    Read with PyYAML, not rclpy's parameter_dict_from_yaml_file: that one turns small floats
    such as 0.000001 into strings (it re-parses str(value) = '1e-06', not a YAML 1.1 float).
    """
    document = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())
    (key,) = document
    assert key in (name, '/**')

    def flatten(prefix: str, table: dict[str, Any]) -> list[Parameter]:
        out = []
        for key, value in table.items():
            if isinstance(value, dict):
                out += flatten(f'{prefix}{key}.', value)
            else:
                out.append(Parameter(f'{prefix}{key}', value=value))
        return out

    return flatten('', document[key]['ros__parameters'])


def _time(ns: int) -> Time:
    return Time(sec=ns // 10**9, nanosec=ns % 10**9)


class Collector:
    """Subscribes to output topics and /diagnostics of one node, keeps every message."""

    def __init__(self, node: Node, topics: dict[str, Any]) -> None:
        self.msgs: dict[str, list[Any]] = {t: [] for t in topics}
        self.diagnostics: list[Any] = []
        for topic, cls in topics.items():
            node.create_subscription(cls, topic, self.msgs[topic].append, DEEP)
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, DEEP)

    def _on_diag(self, msg: DiagnosticArray) -> None:
        self.diagnostics.extend(msg.status)

    def last_stamp(self, topic: str) -> int:
        return stamp_ns(self.msgs[topic][-1].header.stamp) if self.msgs[topic] else -1

    def diag(self, name: str, predicate: Callable[[Any], bool]) -> Any:
        """The newest status of ``name`` satisfying the predicate, or None."""
        for status in reversed(self.diagnostics):
            if status.name == name and predicate(status):
                return status
        return None


def _values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _call_trigger(node: Node, service: str, spin_until: Callable[..., bool]) -> Any:
    client = node.create_client(Trigger, service)
    assert spin_until(client.service_is_ready, 10.0)
    future = client.call_async(Trigger.Request())
    assert spin_until(future.done, 10.0)
    return future.result()


# ---------------------------------------------------------------- vibration_analyzer

def _resonant_wheel_speeds(n: int, freqs: np.ndarray, seed: int) -> np.ndarray:
    """(n, 4) wheel speeds at FS: 70 rad/s + an AR(2) resonance per wheel + sensor noise."""
    rng = np.random.default_rng(seed)
    out = np.empty((n, 4))
    for wheel in range(4):
        w = 2.0 * np.pi * freqs[wheel] / FS
        rho = np.exp(-0.05 * w)
        out[:, wheel] = signal.lfilter([0.01], [1.0, -2.0 * rho * np.cos(w), rho * rho],
                                       rng.standard_normal(n))
    return 70.0 + out + 0.002 * rng.standard_normal((n, 4))


VIB_TEST = {'sample_rate_hz': FS, 'analysis_rate_hz': FS, 'memory_s': 2.0,
            'calibration_settle_s': 1.0, 'min_calibration_s': 2.0,
            'calibration_duration_s': 4.0, 'diagnostics_period_s': 0.1, 'bad_hold_s': 0.5,
            # a stored calibration is used at once here; its check against the tires has its
            # own test (test_vibration_calibration_from_other_tires_is_refused)
            'calibration_check_s': 0.0,
            # The speeds are continuous, no ring's: 9 teeth put them at 0.5 tooth edges per
            # sample, clear of the edge-beat gate (48 would put 2.7, a beat at 66 Hz)
            'encoder_teeth': 9}


def _vibration_node(make_node: Callable[..., Any], calibration_file: Path, namespace: str = '',
                    **extra: Any) -> Any:
    values = {**VIB_TEST, 'calibration_file': str(calibration_file), **extra}
    return make_node(VibrationAnalyzerNode, namespace=namespace or None, parameter_overrides=[
        *_reliable(f'{namespace}/vehicle/wheel_speeds'.lstrip('/')),
        *[Parameter(k, value=v) for k, v in values.items()]])


class WheelFeeder:
    """Publishes WheelSpeeds rows at FS with consecutive stamps, chunk by chunk."""

    def __init__(self, node: Node, collector: Collector, spin_until: Callable[..., bool],
                 namespace: str = '') -> None:
        self.output = f'{namespace}/tpms/tire_resonance'
        self.pub = node.create_publisher(WheelSpeeds, f'{namespace}/vehicle/wheel_speeds', DEEP)
        self.collector = collector
        self.spin_until = spin_until
        self.next_ns = T0_NS
        self.sent: list[int] = []

    def feed(self, omega: np.ndarray, chunk: int = 100) -> None:
        assert self.spin_until(lambda: self.pub.get_subscription_count() > 0, 10.0)
        for start in range(0, len(omega), chunk):
            for row in omega[start:start + chunk]:
                msg = WheelSpeeds()
                msg.header.stamp = _time(self.next_ns)
                msg.omega = row.tolist()
                self.pub.publish(msg)
                self.sent.append(self.next_ns)
                self.next_ns += round(1e9 / FS)
            last = self.sent[-1]
            assert self.spin_until(
                lambda last=last: self.collector.last_stamp(self.output) >= last,
                10.0), 'vibration_analyzer did not answer the chunk'


def test_vibration_starts_with_defaults_and_shipped_config(make_node: Callable[..., Any],
                                                           tmp_path: Path) -> None:
    """Defaults and the shipped YAML start; bad values are refused at start and at runtime."""
    node = make_node(VibrationAnalyzerNode)
    assert node.parameter_values['sample_rate_hz'] == 1000.0
    assert node.processor.calibration.state == 'uncalibrated'
    shipped = make_node(VibrationAnalyzerNode, node_name='vibration_shipped',
                        parameter_overrides=[*_shipped('vibration_analyzer'), Parameter(
                            'calibration_file', value=str(tmp_path / 'v.yaml'))])
    assert shipped.parameter_values['mode_band_hz'] == (40.0, 50.0)
    with pytest.raises(ConfigurationError, match='memory_s'):
        make_node(VibrationAnalyzerNode, node_name='bad1',
                  parameter_overrides=[Parameter('memory_s', value=-1.0)])
    with pytest.raises(ConfigurationError, match='calibration_duration_s'):
        make_node(VibrationAnalyzerNode, node_name='bad2',
                  parameter_overrides=[Parameter('calibration_duration_s', value=5.0)])
    (result,) = node.set_parameters([Parameter('z_flag', value=9.0)])
    assert not result.successful and 'z_flag must be < z_full' in result.reason
    (result,) = node.set_parameters([Parameter('sample_rate_hz', value=500.0)])
    assert not result.successful
    (result,) = node.set_parameters([Parameter('z_flag', value=4.0)])
    assert result.successful and node.processor.core.params.z_flag == 4.0


def test_vibration_calibrates_persists_reloads_and_flags_a_low_tire(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Outputs carry input stamps; ~/calibrate learns the nominal, saves it, a new node loads it;
    a tire whose resonance drops is flagged, the others are not."""
    cal_file = tmp_path / 'vibration.yaml'
    node = _vibration_node(make_node, cal_file)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    feeder = WheelFeeder(tester, out, spin_until)
    feeder.feed(_resonant_wheel_speeds(400, NOMINAL_HZ, seed=1))
    response = _call_trigger(tester, '/vibration_analyzer/calibrate', spin_until)
    assert response.success and node.processor.calibration.state == 'calibrating'
    feeder.feed(_resonant_wheel_speeds(int(4.2 * FS), NOMINAL_HZ, seed=2))
    assert node.processor.calibration.state == 'calibrated'
    nominal = node.processor.core.calibration.nominal_frequency_hz
    np.testing.assert_allclose(nominal, NOMINAL_HZ, atol=1.0)
    stored = load_calibration(cal_file).state
    assert stored is not None and np.allclose(stored['nominal_frequency_hz'], nominal)

    sent = set(feeder.sent)
    for topic in out.msgs:
        assert {stamp_ns(m.header.stamp) for m in out.msgs[topic]} <= sent
    last = out.msgs['/tpms/tire_resonance'][-1]
    assert last.calibrated and all(last.valid)
    np.testing.assert_allclose(last.frequency_hz, NOMINAL_HZ, atol=1.5)
    assert not any(out.msgs['/tpms/indication/vibration'][-1].underinflated)

    low = NOMINAL_HZ.copy()
    low[1] *= 0.9                               # FR: ~25 % pressure loss
    feeder.feed(_resonant_wheel_speeds(int(3 * FS), low, seed=3))
    ind = out.msgs['/tpms/indication/vibration'][-1]
    assert list(ind.underinflated) == [False, True, False, False], list(ind.confidence)
    assert ind.confidence[1] > 0.5 and ind.method == 'vibration'

    again = make_node(VibrationAnalyzerNode, node_name='vibration_again',
                      parameter_overrides=[Parameter('calibration_file', value=str(cal_file))])
    assert again.processor.calibration.state == 'loaded'
    np.testing.assert_array_equal(again.processor.core.calibration.nominal_frequency_hz, nominal)


def test_vibration_bad_input_rejected_and_wheel_unknown(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """NaN, repeated/out-of-order stamps and a malformed payload are counted; the NaN wheel is
    unknown (never low) while the others stay known; the node keeps running."""
    cal_file = tmp_path / 'vibration.yaml'
    save_calibration(cal_file, VibrationCalibration(NOMINAL_HZ, np.full(4, 0.2),
                                                    np.full(4, 10.0)).to_dict())
    node = _vibration_node(make_node, cal_file)
    assert node.processor.calibration.state == 'loaded'
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    feeder = WheelFeeder(tester, out, spin_until)
    feeder.feed(_resonant_wheel_speeds(600, NOMINAL_HZ, seed=4))
    assert all(out.msgs['/tpms/indication/vibration'][-1].known)

    omega = _resonant_wheel_speeds(100, NOMINAL_HZ, seed=5)
    omega[50, 0] = np.nan
    feeder.feed(omega)
    ind = out.msgs['/tpms/indication/vibration'][-1]
    assert list(ind.known) == [False, True, True, True]
    assert not ind.underinflated[0] and ind.confidence[0] == 0.0
    assert not out.msgs['/tpms/tire_resonance'][-1].valid[0]

    # a repeated and an old stamp, then a payload too short for a WheelSpeeds (a replay
    # publishes a damaged bag's bytes as they are)
    for ns in (feeder.sent[-1], feeder.sent[-5]):
        msg = WheelSpeeds()
        msg.header.stamp = _time(ns)
        msg.omega = [70.0] * 4
        feeder.pub.publish(msg)
    feeder.pub.publish(b'\x00\x01\x00\x00' + bytes(20))
    feeder.feed(_resonant_wheel_speeds(200, NOMINAL_HZ, seed=6))
    assert all(out.msgs['/tpms/indication/vibration'][-1].known)   # recovered after bad_hold_s

    def counted(status: Any) -> bool:
        v = _values(status)
        return (v['rejected_repeated'] == '1' and v['rejected_out_of_order'] == '1'
                and v['rejected_malformed'] == '1'
                and v['rejected_bad_value_per_wheel'] == '[1, 0, 0, 0]')

    assert spin_until(lambda: out.diag('/vibration_analyzer', counted) is not None, 5.0)


def test_vibration_processes_ahead_of_each_output_without_changing_it(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """With process_ahead_s the sample an output answers leaves only the last process_ahead_s
    of samples to the core (the bulk went earlier); the outputs are those of process_ahead_s 0."""
    omega = _resonant_wheel_speeds(1000, NOMINAL_HZ, seed=7)
    results = {}
    for ahead_s in (0.0, 0.02):
        namespace = f'/run{len(results)}'
        node = _vibration_node(make_node, tmp_path / f'v{ahead_s}.yaml', namespace=namespace,
                               process_ahead_s=ahead_s, block_s=0.5)
        chunks: list[int] = []
        process = node.processor.core.process

        def counted(block: np.ndarray, process: Callable[..., Any] = process,
                    chunks: list[int] = chunks) -> Any:
            chunks.append(len(block))
            return process(block)

        node.processor.core.process = counted
        tester = make_node(f'tester{len(results)}')
        out = Collector(tester, {f'{namespace}/tpms/tire_resonance': TireResonance})
        WheelFeeder(tester, out, spin_until, namespace).feed(omega)
        results[ahead_s] = (chunks, out.msgs[f'{namespace}/tpms/tire_resonance'])
    (plain_chunks, plain), (ahead_chunks, ahead) = results[0.0], results[0.02]
    period = round(FS / node.parameter_values['publish_rate_hz'])               # 20 samples
    assert plain_chunks == [period] * 50           # cut where each output falls due
    assert ahead_chunks == [period - 4, 4] * 50    # 0.02 s at 200 Hz left for the output
    assert [stamp_ns(m.header.stamp) for m in ahead] == [stamp_ns(m.header.stamp) for m in plain]
    np.testing.assert_allclose([m.frequency_hz for m in ahead], [m.frequency_hz for m in plain],
                               rtol=1e-12)


def test_vibration_output_phase_delays_every_output(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """output_phase_s shifts the outputs in data time and keeps their period (how composed
    nodes stagger their work)."""
    _vibration_node(make_node, tmp_path / 'v.yaml', output_phase_s=0.05)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance})
    feeder = WheelFeeder(tester, out, spin_until)
    assert spin_until(lambda: feeder.pub.get_subscription_count() > 0, 10.0)
    for k, row in enumerate(_resonant_wheel_speeds(400, NOMINAL_HZ, seed=8)):
        msg = WheelSpeeds()
        msg.header.stamp = _time(T0_NS + k * round(1e9 / FS))
        msg.omega = row.tolist()
        feeder.pub.publish(msg)
    # Without a phase the outputs answer samples 19, 39, ...; 0.05 s is 10 samples later.
    expected = [T0_NS + k * round(1e9 / FS) for k in range(29, 400, 20)]
    assert spin_until(lambda: len(out.msgs['/tpms/tire_resonance']) == len(expected), 10.0)
    assert [stamp_ns(m.header.stamp) for m in out.msgs['/tpms/tire_resonance']] == expected


def test_vibration_corrupt_calibration_file_is_reported(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """A corrupt file: the node starts uncalibrated, says so on /diagnostics, tires unknown."""
    cal_file = tmp_path / 'vibration.yaml'
    cal_file.write_text('version: 1\nmethod: vibration\nnominal_frequency_hz: [1, 2\n')
    node = _vibration_node(make_node, cal_file)
    assert node.processor.calibration.state == 'file_corrupt'
    assert node.processor.core.calibration is None
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    WheelFeeder(tester, out, spin_until).feed(_resonant_wheel_speeds(200, NOMINAL_HZ, seed=7))
    assert not any(out.msgs['/tpms/indication/vibration'][-1].known)
    status = _vibration_status_saying(out, spin_until, 'recalibration required')
    assert status.level == b'\x01' and _values(status)['calibration_state'] == 'file_corrupt'


def test_vibration_says_when_held_tooth_periods_beat_in_the_band(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """A 48-tooth ring at 70 rad/s and 200 Hz puts 2.67 tooth edges in a sample: held tooth
    periods would beat with the sampling at 66 Hz, inside the band. The samples are gated, the
    status says so and counts them per wheel; nothing is flagged."""
    _vibration_node(make_node, tmp_path / 'vibration.yaml', encoder_teeth=48)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    WheelFeeder(tester, out, spin_until).feed(_resonant_wheel_speeds(400, NOMINAL_HZ, seed=8))

    def gated_per_wheel(status: Any) -> list[int]:
        return yaml.safe_load(_values(status)['gated_edge_beat_per_wheel'])

    # The status of the last chunk can arrive after the chunk's resonance output (the feeder's
    # signal that it was processed), so the count is waited for, not read off the first status.
    status = _vibration_status_saying(out, spin_until, 'beating with the sampling',
                                      where=lambda s: min(gated_per_wheel(s)) > 300)
    assert status.level == b'\x01'
    gated = gated_per_wheel(status)
    assert len(gated) == 4 and min(gated) > 300
    assert not any(any(m.underinflated) for m in out.msgs['/tpms/indication/vibration'])


def _vibration_status_saying(out: Collector, spin_until: Callable[..., bool], text: str,
                             where: Callable[[Any], bool] = lambda status: True) -> Any:
    """The vibration analyzer's first /diagnostics status whose message has ``text`` (and that
    satisfies ``where``)."""
    found: list[Any] = []

    def reported() -> bool:
        status = out.diag('/vibration_analyzer', lambda s: text in s.message and where(s))
        found.append(status)
        return status is not None

    assert spin_until(reported, 5.0)
    return found[-1]


@pytest.mark.parametrize('calibrate_on_start', [False, True])
def test_vibration_calibration_from_other_tires_is_refused(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path,
        calibrate_on_start: bool) -> None:
    """A stored calibration made on other tires (resonances 30 % below these tires'): tires
    unknown while it is checked, then refused with both resonances named at ERROR, never a low
    tire; with calibrate_on_start a recalibration starts at once and learns these tires."""
    cal_file = tmp_path / 'vibration.yaml'
    save_calibration(cal_file, VibrationCalibration(0.7 * NOMINAL_HZ, np.full(4, 0.2),
                                                    np.full(4, 10.0)).to_dict())
    node = _vibration_node(make_node, cal_file, calibration_check_s=1.0,
                           calibrate_on_start=calibrate_on_start)
    assert node.processor.calibration.state == 'loaded'
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication,
                             '/diagnostics': DiagnosticArray})
    WheelFeeder(tester, out, spin_until).feed(_resonant_wheel_speeds(1600, NOMINAL_HZ, seed=9))
    indications = out.msgs['/tpms/indication/vibration']
    assert not any(any(m.underinflated) for m in indications)
    if calibrate_on_start:
        # recalibrated over the stored file: these tires' resonances, not the stored 0.7 x
        assert node.processor.calibration.state == 'calibrated'
        stored = load_calibration(cal_file).state
        np.testing.assert_allclose(stored['nominal_frequency_hz'], NOMINAL_HZ, atol=1.5)
        assert all(indications[-1].known)
    else:
        assert node.processor.calibration.state == 'refused'
        status = _vibration_status_saying(out, spin_until, 'does not fit these tires')
        assert status.level == b'\x02' and 'recalibrate' in status.message
        assert 'does not fit' in _values(status)['calibration_file_problem']
        assert not any(indications[-1].known)


# ---------------------------------------------------------------- wheel_radius_analyzer

R_N = 0.31
TRACK = 1.55
RAD_TEST = {'calibration_settle_s': 0.5, 'min_calibration_s': 2.0,
            'calibration_duration_s': 3.0, 'diagnostics_period_s': 0.1, 'publish_rate_hz': 100.0,
            'wheel_recover_s': 0.5,
            # the synthetic drive below weaves its speed at up to 3 m/s^2 and has no wheel
            # inertia nor load transfer: the core's acceleration gates and corrections are off
            'accel_max_longitudinal_mps2': 10.0, 'accel_max_lateral_mps2': 10.0,
            'wheel_inertia_kgm2': 0.0, 'cg_height_m': 0.0}


def _drive(n_imu: int, seed: int, t0: float, eps: np.ndarray) -> dict[str, np.ndarray]:
    """A drive at 20 m/s with gentle weaving: IMU/driver inputs at 100 Hz, wheels at 200 Hz.

    ``eps`` are relative radius deviations per tire (a low tire has eps < 0).
    """
    rng = np.random.default_rng(seed)
    t_w = t0 + np.arange(2 * n_imu) / FS + 1.0 / FS      # wheel stamps end on the last IMU one
    t_imu = t0 + np.arange(n_imu) / 100.0 + 0.01
    yaw = 0.05 * np.sin(2 * np.pi * 0.2 * t_w)           # REP 103, positive turning left
    v = 20.0 + 5.0 * np.sin(2 * np.pi * 0.1 * t_w)     # speed changes separate gyro offset
    side = np.array([-1.0, 1.0, -1.0, 1.0])              # left wheels inside a left turn
    v_wheel = v[:, None] + side * yaw[:, None] * TRACK / 2
    torque = np.zeros((n_imu, 4))
    drive_nm = 100.0 + 60.0 * np.sin(2 * np.pi * 0.3 * t_w)    # front drive, varying mu
    torque[:, :2] = drive_nm[1::2, None]
    slip = np.zeros_like(v_wheel)
    slip[:, :2] = (drive_nm / (R_N * 4200.0) / 20.0)[:, None]   # mu / k with k = 20
    omega = v_wheel * (1.0 + slip) / (R_N * (1.0 + eps)) + 0.01 * rng.standard_normal(
        v_wheel.shape)
    gyro = np.interp(t_imu, t_w, yaw) + 0.002 + 0.003 * rng.standard_normal(n_imu)
    return {'t_w': t_w, 'omega': omega, 't_imu': t_imu, 'gyro': gyro, 'torque': torque}


class RadiusFeeder:
    """Publishes wheel speeds, IMU and driver inputs of a drive in 0.2 s chunks."""

    def __init__(self, node: Node, collector: Collector, spin_until: Callable[..., bool]) -> None:
        self.wheel = node.create_publisher(WheelSpeeds, '/vehicle/wheel_speeds', DEEP)
        self.imu = node.create_publisher(Imu, '/vehicle/imu', DEEP)
        self.driver = node.create_publisher(DriverInputs, '/vehicle/driver_inputs', DEEP)
        self.collector = collector
        self.spin_until = spin_until
        self.imu_sent: list[int] = []

    def feed(self, drive: dict[str, np.ndarray]) -> None:
        pubs = (self.wheel, self.imu, self.driver)
        assert self.spin_until(lambda: all(p.get_subscription_count() for p in pubs), 10.0)
        for k in range(0, len(drive['t_imu']), 20):
            for i in range(2 * k, 2 * k + 40):
                msg = WheelSpeeds()
                msg.header.stamp = _time(round(drive['t_w'][i] * 1e9))
                msg.omega = drive['omega'][i].tolist()
                self.wheel.publish(msg)
            for i in range(k, k + 20):
                ns = round(drive['t_imu'][i] * 1e9)
                # Stamped with the IMU sample, as the recordings do: a bin closes once a wheel
                # speed and a driver input at or after its stamp are in.
                driver = DriverInputs()
                driver.header.stamp = _time(ns)
                driver.wheel_torque = drive['torque'][i].tolist()
                self.driver.publish(driver)
                imu = Imu()
                imu.header.stamp = _time(ns)
                imu.angular_velocity.z = float(drive['gyro'][i])
                self.imu.publish(imu)
                self.imu_sent.append(ns)
            last = self.imu_sent[-1]
            assert self.spin_until(
                lambda last=last: self.collector.last_stamp('/tpms/wheel_radius') >= last,
                10.0), 'wheel_radius_analyzer did not answer the chunk'


def _radius_node(make_node: Callable[..., Any], calibration_file: Path, name: str =
                 'wheel_radius_analyzer') -> Any:
    values = {**RAD_TEST, 'calibration_file': str(calibration_file)}
    return make_node(WheelRadiusAnalyzerNode, node_name=name, parameter_overrides=[
        *_reliable('vehicle/wheel_speeds', 'vehicle/imu', 'vehicle/driver_inputs'),
        *[Parameter(k, value=v) for k, v in values.items()]])


def test_wheel_radius_starts_with_defaults_and_shipped_config(
        make_node: Callable[..., Any], tmp_path: Path) -> None:
    """Defaults and the shipped YAML start; bad values are refused at start and at runtime."""
    node = make_node(WheelRadiusAnalyzerNode)
    assert node.parameter_values['driven_axle'] == 'front'
    shipped = make_node(WheelRadiusAnalyzerNode, node_name='radius_shipped',
                        parameter_overrides=[*_shipped('wheel_radius_analyzer'), Parameter(
                            'calibration_file', value=str(tmp_path / 'r.yaml'))])
    assert shipped.parameter_values['static_load_n'] == (4200.0, 4200.0, 3300.0, 3300.0)
    with pytest.raises(ConfigurationError, match='static_load_n'):
        make_node(WheelRadiusAnalyzerNode, node_name='bad1', parameter_overrides=[
            Parameter('static_load_n', value=[4000.0, 4000.0, 3000.0])])
    with pytest.raises(ConfigurationError, match='driven_axle'):
        make_node(WheelRadiusAnalyzerNode, node_name='bad2', parameter_overrides=[
            Parameter('driven_axle', value='middle')])
    (result,) = node.set_parameters([Parameter('min_speed_mps', value=50.0)])
    assert not result.successful and 'min_speed_mps' in result.reason
    (result,) = node.set_parameters([Parameter('mu_max', value=0.2)])
    assert result.successful and node.processor.core.params.mu_max == 0.2


def test_wheel_radius_aligns_calibrates_persists_and_reloads(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Outputs are stamped with IMU stamps; the offsets and the gyro offset are sane; the
    calibration is learned via ~/calibrate, written, and reloaded by a new node."""
    cal_file = tmp_path / 'radius.yaml'
    node = _radius_node(make_node, cal_file)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/wheel_radius': WheelRadiusOffsets,
                             '/tpms/indication/wheel_radius': TpmsIndication})
    feeder = RadiusFeeder(tester, out, spin_until)
    eps = np.array([0.0, 0.002, -0.001, 0.0])           # manufacturing spread
    drives = [_drive(200, seed=1, t0=T0_NS * 1e-9, eps=eps),
              _drive(400, seed=2, t0=T0_NS * 1e-9 + 2.0, eps=eps)]
    feeder.feed(drives[0])
    assert _call_trigger(tester, '/wheel_radius_analyzer/calibrate', spin_until).success
    feeder.feed(drives[1])
    assert node.processor.calibration.state == 'calibrated', node.processor.calibration.detail

    stamps = {stamp_ns(m.header.stamp) for m in out.msgs['/tpms/wheel_radius']}
    assert stamps <= set(feeder.imu_sent) and len(stamps) > 100
    last = out.msgs['/tpms/wheel_radius'][-1]
    assert last.calibrated and last.longitudinal_valid and last.lateral_valid
    r = 1.0 + eps
    truth = {'delta_13': 1.0 - r[0] / r[2], 'delta_24': 1.0 - r[1] / r[3],
             'delta_34': r[2] / r[3] - 1.0, 'delta_12': r[0] / r[1] - 1.0}
    for name, value in truth.items():
        assert abs(getattr(last, name) - value) < 1e-3, (name, getattr(last, name), value)
    # the alignment is exact: the core fed offline with the 10 ms means of the wheel speeds
    # (two 200 Hz samples per IMU stamp) and the driver input before each IMU stamp agrees
    offline = WheelRadiusAnalyzer(node.processor.core.params)
    for drive in drives:
        ref = offline.process(
            drive['t_imu'], 0.5 * (drive['omega'][0::2] + drive['omega'][1::2]),
            drive['gyro'], drive['torque'], np.zeros(len(drive['t_imu'])))
    np.testing.assert_allclose([last.delta_13, last.delta_24, last.delta_34, last.delta_12],
                               ref.offsets, rtol=1e-9, atol=1e-12)
    assert abs(last.gyro_offset - ref.gyro_offset) < 1e-12
    stored = load_calibration(cal_file).state
    assert stored is not None and stored['method'] == 'wheel_radius'

    again = _radius_node(make_node, cal_file, name='radius_again')
    assert again.processor.calibration.state == 'loaded'
    np.testing.assert_allclose(again.processor.core.calibration.nominal_offsets,
                               node.processor.core.calibration.nominal_offsets)
    np.testing.assert_allclose(again.processor.core.calibration.noise_scale,
                               node.processor.core.calibration.noise_scale)


def test_wheel_radius_nan_wheel_is_unknown_and_counted(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """A NaN wheel speed makes that tire unknown (never low) and is counted on /diagnostics, as
    is a malformed wheel-speed payload; a corrupt calibration file is reported and the node keeps
    running."""
    cal_file = tmp_path / 'radius.yaml'
    save_calibration(cal_file, WheelRadiusCalibration(
        np.zeros(4), np.full(4, 2e-4), np.full(4, 30.0)).to_dict())
    node = _radius_node(make_node, cal_file)
    assert node.processor.calibration.state == 'loaded'
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/wheel_radius': WheelRadiusOffsets,
                             '/tpms/indication/wheel_radius': TpmsIndication})
    feeder = RadiusFeeder(tester, out, spin_until)
    drive = _drive(300, seed=3, t0=T0_NS * 1e-9, eps=np.zeros(4))
    drive['omega'][560, 1] = np.nan                      # FR, 0.2 s before the end
    feeder.wheel.publish(b'\x00\x01\x00\x00' + bytes(20))    # not a WheelSpeeds
    feeder.feed(drive)
    ind = out.msgs['/tpms/indication/wheel_radius'][-1]
    assert not ind.known[1] and not ind.underinflated[1] and ind.confidence[1] == 0.0
    assert ind.known[0] or ind.known[2]                  # the others stay informative
    assert not any(ind.underinflated)
    assert spin_until(lambda: out.diag(
        '/wheel_radius_analyzer',
        lambda s: _values(s)['core.bad_wheel_speed'] == '1'
        and _values(s)['rejected_malformed'] == '1'
        and _values(s)['noise_scale.delta_34'] == '1') is not None, 5.0)

    cal_file.write_text('version: 1\nmethod: wheel_radius\nnominal_offsets: 3\n')
    broken = _radius_node(make_node, cal_file, name='radius_broken')
    assert broken.processor.calibration.state == 'file_corrupt'
    assert spin_until(lambda: out.diag(
        '/radius_broken', lambda s: 'recalibration required' in s.message) is not None, 5.0)


# ---------------------------------------------------------------- issue 20 findings
# Each of these failed before the nodes became processors with the handling.


def _calibrated_vibration(make_node: Callable[..., Any], tmp_path: Path,
                          **extra: Any) -> Any:
    cal_file = tmp_path / 'vibration.yaml'
    save_calibration(cal_file, VibrationCalibration(NOMINAL_HZ, np.full(4, 0.2),
                                                    np.full(4, 10.0)).to_dict())
    node = _vibration_node(make_node, cal_file, **extra)
    assert node.processor.calibration.state == 'loaded'
    return node


def test_finding1_vibration_survives_a_future_stamp_and_a_replay_loop(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Finding 1: one wheel-speed message stamped 10 000 s ahead blinded the node (every later
    output held back, tires all unknown); a replay looping back stopped it. Now the lone stamp
    is dropped and counted, and a confirmed jump back restarts the filters on the new time
    line (calibration kept) and outputs go on."""
    _calibrated_vibration(make_node, tmp_path)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    feeder = WheelFeeder(tester, out, spin_until)
    feeder.feed(_resonant_wheel_speeds(600, NOMINAL_HZ, seed=11))
    assert all(out.msgs['/tpms/indication/vibration'][-1].known)
    future = WheelSpeeds()
    future.header.stamp = _time(feeder.next_ns + 10_000 * 10**9)
    future.omega = [70.0] * 4
    feeder.pub.publish(future)
    feeder.feed(_resonant_wheel_speeds(200, NOMINAL_HZ, seed=12))
    assert out.last_stamp('/tpms/tire_resonance') == feeder.sent[-1]
    assert all(out.msgs['/tpms/indication/vibration'][-1].known)
    assert spin_until(lambda: out.diag('/vibration_analyzer', lambda s: _values(s).get(
        'rejected_future_stamp') == '1') is not None, 5.0)

    feeder.next_ns = T0_NS                  # the replay starts over (loop:=true)
    feeder.feed(_resonant_wheel_speeds(400, NOMINAL_HZ, seed=13))
    last = feeder.sent[-1]                 # answered within one output period
    assert spin_until(lambda: last - 10**8 < out.last_stamp('/tpms/tire_resonance') <= last,
                      5.0), (out.last_stamp('/tpms/tire_resonance'), last)
    assert spin_until(lambda: out.diag('/vibration_analyzer', lambda s: 'time jump' in s.message
                                       and s.level == bytes([1])) is not None, 5.0)
    last = out.msgs['/tpms/tire_resonance'][-1]
    assert last.calibrated and not any(out.msgs['/tpms/indication/vibration'][-1].underinflated)


def test_finding6_vibration_rate_mismatch_names_the_rate(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Finding 6: a stream at another rate than sample_rate_hz was analysed as if at the design
    rate (the resonance scales with it: a tire fault from a parameter). Now every tire is
    unknown and the status names both rates, at ERROR."""
    _calibrated_vibration(make_node, tmp_path, sample_rate_hz=2 * FS, analysis_rate_hz=FS)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    feeder = WheelFeeder(tester, out, spin_until)
    assert spin_until(lambda: feeder.pub.get_subscription_count() > 0, 10.0)
    for row in _resonant_wheel_speeds(800, NOMINAL_HZ, seed=14):
        msg = WheelSpeeds()
        msg.header.stamp = _time(feeder.next_ns)
        msg.omega = row.tolist()
        feeder.pub.publish(msg)
        feeder.next_ns += round(1e9 / FS)
    assert spin_until(lambda: len(out.msgs['/tpms/indication/vibration']) >= 30, 10.0)
    for ind in out.msgs['/tpms/indication/vibration']:
        assert not any(ind.known) and not any(ind.underinflated)
    assert spin_until(lambda: out.diag('/vibration_analyzer', lambda s: s.level == bytes([2]) and (
        f'rate {FS:.4g} Hz does not match sample_rate_hz {2 * FS:g}') in s.message)
        is not None, 5.0)


def test_finding7_vibration_says_when_a_wheel_recovers(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Finding 7 (and 3's vibration part): after a long sensor fault the wheel's estimate was
    published as valid while its filters still held the fault (47.5 Hz for 39.4, ~100 s). Now
    the wheel's filters restart when its sensor recovers and it stays unknown, the status
    saying 'recovering', until estimated again."""
    node = _calibrated_vibration(make_node, tmp_path)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/tire_resonance': TireResonance,
                             '/tpms/indication/vibration': TpmsIndication})
    feeder = WheelFeeder(tester, out, spin_until)
    feeder.feed(_resonant_wheel_speeds(600, NOMINAL_HZ, seed=15))
    dead = _resonant_wheel_speeds(400, NOMINAL_HZ, seed=16)
    dead[:, 0] = 0.0                        # FL dead for 2 s
    feeder.feed(dead)
    feeder.feed(_resonant_wheel_speeds(400, NOMINAL_HZ, seed=17))   # 2 s clean: > bad_hold_s
    ind = out.msgs['/tpms/indication/vibration'][-1]
    assert list(ind.known) == [False, True, True, True]
    assert not any(ind.underinflated)
    assert node.processor.recovering().tolist() == [True, False, False, False]
    assert spin_until(lambda: out.diag('/vibration_analyzer', lambda s: 'recovering' in s.message
                                       and 'FL' in s.message) is not None, 5.0)


def test_finding3_wheel_radius_dead_sensor_keeps_the_learned_state(
        make_node: Callable[..., Any], spin_until: Callable[..., bool], tmp_path: Path) -> None:
    """Finding 3: a dead FL sensor (0) for 30 s took delta_12 to -1.99 and the gyro offset to
    -24.7 rad/s, marked valid, and flagged a healthy tire; a stuck sensor was flagged low. Now
    the wheel is bad (named at ERROR), unknown, the filters frozen, and the learned state is
    where it was when the sensor comes back."""
    cal_file = tmp_path / 'radius.yaml'
    node = _radius_node(make_node, cal_file)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/wheel_radius': WheelRadiusOffsets,
                             '/tpms/indication/wheel_radius': TpmsIndication})
    feeder = RadiusFeeder(tester, out, spin_until)
    eps = np.zeros(4)
    t0 = T0_NS * 1e-9
    feeder.feed(_drive(200, seed=21, t0=t0, eps=eps))
    assert _call_trigger(tester, '/wheel_radius_analyzer/calibrate', spin_until).success
    feeder.feed(_drive(400, seed=22, t0=t0 + 2.0, eps=eps))
    assert node.processor.calibration.state == 'calibrated'
    before = out.msgs['/tpms/wheel_radius'][-1]
    for seed, fault in ((23, 'dead'), (25, 'stuck')):
        drive = _drive(300, seed=seed, t0=out.last_stamp('/tpms/wheel_radius') * 1e-9, eps=eps)
        drive['omega'][:, 0] = 0.0 if fault == 'dead' else drive['omega'][0, 0]
        feeder.feed(drive)
        during = out.msgs['/tpms/indication/wheel_radius'][-1]
        assert not during.known[0] and not any(during.underinflated), fault
        assert spin_until(lambda: out.diag(
            '/wheel_radius_analyzer', lambda status: status.level == bytes([2])
            and 'FL (stuck or dead)' in status.message) is not None, 5.0), fault
        after = out.msgs['/tpms/wheel_radius'][-1]
        for name in ('delta_13', 'delta_24', 'delta_12', 'delta_34'):
            assert abs(getattr(after, name) - getattr(before, name)) < 1e-3, (fault, name)
        assert abs(after.gyro_offset - before.gyro_offset) < 0.01, fault
        feeder.feed(_drive(200, seed=seed + 1,
                           t0=out.last_stamp('/tpms/wheel_radius') * 1e-9, eps=eps))
        back = out.msgs['/tpms/indication/wheel_radius'][-1]
        assert all(back.known) and not any(back.underinflated), fault


def test_finding5_shipped_yamls_apply_under_any_namespace_with_own_calibration(
        make_node: Callable[..., Any], tmp_path: Path) -> None:
    """Finding 5: the shipped YAMLs were keyed by the bare node name (ignored under a namespace)
    and the calibration files were fixed paths shared between vehicles. Now a params file
    (``/**``) configures the node under any namespace, and each node of each vehicle keeps its
    calibration in its own file under $ROS_HOME."""
    import os

    for name, cls, key, value in (
            ('vibration_analyzer', VibrationAnalyzerNode, 'bad_hold_s', 0.42),
            ('wheel_radius_analyzer', WheelRadiusAnalyzerNode, 'validity_hold_s', 0.42)):
        document = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())
        assert list(document) == ['/**']
        document['/**']['ros__parameters'][key] = value
        params = tmp_path / f'{name}.yaml'
        params.write_text(yaml.safe_dump(document))
        nodes = [make_node(cls, namespace=f'/car{k}',
                           cli_args=['--ros-args', '--params-file', str(params)])
                 for k in (1, 2)]
        files = set()
        for k, node in enumerate(nodes, start=1):
            assert node.parameter_values[key] == value
            expected = os.path.join(os.environ['ROS_HOME'], 'vehicle_monitor', 'calibration',
                                    f'car{k}', f'{name}.yaml')
            assert node.processor.calibration_file == expected
            files.add(expected)
        assert len(files) == 2


# ---------------------------------------------------------------- tpms_voter

VOTER_TEST = {'set_on_s': 0.5, 'set_off_s': 1.0, 'max_age_s': 0.5, 'diagnostics_period_s': 0.1,
              'publish_rate_hz': 20.0}


def _indication(method: str, ns: int, flags: list[bool], conf: list[float],
                known: list[bool] | None = None) -> TpmsIndication:
    msg = TpmsIndication()
    msg.header.stamp = _time(ns)
    msg.method = method
    msg.underinflated = flags
    msg.confidence = conf
    msg.known = known if known is not None else [True] * 4
    return msg


def test_voter_starts_with_defaults_and_shipped_config(make_node: Callable[..., Any]) -> None:
    """Defaults and the shipped YAML start; h_i <= h0 and bad method names are refused."""
    node = make_node(TpmsVoterNode)
    assert node.processor.voter.params.method_thresholds == {
        'stiffness': 0.8, 'vibration': 0.8, 'wheel_radius': 0.8}
    shipped = make_node(TpmsVoterNode, node_name='voter_shipped',
                        parameter_overrides=_shipped('tpms_voter'))
    assert shipped.parameter_values['methods'] == ('stiffness', 'vibration', 'wheel_radius')
    with pytest.raises(ConfigurationError, match='must be in \\(h0'):
        make_node(TpmsVoterNode, node_name='bad1',
                  parameter_overrides=[Parameter('vibration.threshold', value=0.4)])
    with pytest.raises(ConfigurationError, match='not a valid method name'):
        make_node(TpmsVoterNode, node_name='bad2',
                  parameter_overrides=[Parameter('methods', value=['Vibration!'])])
    (result,) = node.set_parameters([Parameter('vibration.threshold', value=0.3)])
    assert not result.successful and 'h0' in result.reason
    (result,) = node.set_parameters([Parameter('h0', value=0.85)])
    assert not result.successful
    (result,) = node.set_parameters([Parameter('wheel_radius.threshold', value=0.9)])
    assert result.successful
    assert node.processor.voter.params.method_thresholds['wheel_radius'] == 0.9
    # the support a method needs to warn alone: the vibration method's by default and in the
    # shipped file, changeable at runtime, a fraction
    for voter in (node, shipped):
        assert voter.processor.voter.params.method_support == {
            'stiffness': 0.0, 'vibration': 0.3, 'wheel_radius': 0.0}
    (result,) = node.set_parameters([Parameter('stiffness.support', value=0.2)])
    assert result.successful
    assert node.processor.voter.params.method_support['stiffness'] == 0.2
    (result,) = node.set_parameters([Parameter('vibration.support', value=1.5)])
    assert not result.successful
    assert node.processor.voter.params.method_support['vibration'] == 0.3


def test_voter_keeps_both_clock_jump_watches(
        make_node: Callable[..., Any], spin_until: Callable[..., bool],
        publish_clock: Callable[[int], None], monkeypatch: pytest.MonkeyPatch) -> None:
    """The voter watches jumps of its clock twice, for the silence watch every node has and to
    re-anchor its extrapolated data time; both handles stay referenced while registered
    (rclpy's clock holds only a borrowed pointer: the voter once overwrote the first, freed
    while registered) and both act on a /clock going back. Destroyed, the node unregisters
    them."""
    made: list[weakref.ref[Any]] = []
    create = RclpyClock.create_jump_callback

    def recorded(clock: RclpyClock, *args: Any, **kwargs: Any) -> Any:
        handle = create(clock, *args, **kwargs)
        made.append(weakref.ref(handle))
        return handle

    monkeypatch.setattr(RclpyClock, 'create_jump_callback', recorded)
    node = make_node(TpmsVoterNode, parameter_overrides=[Parameter('use_sim_time', value=True)])
    gc.collect()
    handles = [ref() for ref in made]
    assert len(handles) == 2 and all(h is not None for h in handles)
    re_anchored: list[int] = []
    monkeypatch.setattr(node.processor, 'clock_jumped', re_anchored.append)
    assert spin_until(lambda: (publish_clock(100), node.get_clock().now().nanoseconds
                               == 100 * 10**9)[1], 5.0)
    assert spin_until(lambda: (publish_clock(40), node.time_jumps >= 1
                               and 40 * 10**9 in re_anchored)[1], 5.0)
    node.destroy_node()
    assert all(h._clock is None for h in handles)   # unregistered


def test_voter_agreement_warns_single_weak_does_not_and_clears(
        make_node: Callable[..., Any], spin_until: Callable[..., bool]) -> None:
    """Two methods agreeing on FR at 0.6 (> h0 0.5, < h_i 0.8) warn after the hold-off; one
    method alone at 0.6 does not; the warning clears set_off_s after the evidence goes."""
    node = make_node(TpmsVoterNode, parameter_overrides=[
        *_reliable('tpms/indication/vibration', 'tpms/indication/wheel_radius',
                   'tpms/indication/stiffness'),
        *[Parameter(k, value=v) for k, v in {**VOTER_TEST, 'publish_rate_hz': 0.01}.items()],
        Parameter('stiffness.enabled', value=False)])
    # (no periodic output here: every warning answers one indication, in data time)
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/warning': TpmsWarning})
    pubs = {m: tester.create_publisher(TpmsIndication, f'/tpms/indication/{m}', DEEP)
            for m in ('vibration', 'wheel_radius')}
    assert spin_until(lambda: all(p.get_subscription_count() for p in pubs.values()), 10.0)
    weak = ([False, True, False, False], [0.0, 0.6, 0.0, 0.0])
    clear = ([False] * 4, [0.0] * 4)

    def send(t_s: float, per_method: dict[str, tuple[list[bool], list[float]]]) -> int:
        ns = T0_NS + round(t_s * 1e9)
        for method, (flags, conf) in per_method.items():
            pubs[method].publish(_indication(method, ns, flags, conf))
        expected = len(out.msgs['/tpms/warning']) + len(per_method)
        assert spin_until(lambda: len(out.msgs['/tpms/warning']) >= expected, 5.0)
        return ns

    # one weak method (the other says "not low"): disagreement, 0.6 < own h 0.8 -> no warning
    for k in range(20):
        send(0.1 * k, {'vibration': weak, 'wheel_radius': clear})
    assert not any(m.active for m in out.msgs['/tpms/warning'])
    # both agree at 0.6: mean 0.6 > h0 -> warning once the 0.5 s hold-off has passed
    onset = {}
    for k in range(20, 40):
        ns = send(0.1 * k, {'vibration': weak, 'wheel_radius': weak})
        if out.msgs['/tpms/warning'][-1].active and not onset:
            onset['t'] = 0.1 * k
            warning = out.msgs['/tpms/warning'][-1]
            assert stamp_ns(warning.header.stamp) == ns
            assert list(warning.warning) == [False, True, False, False]
            assert set(warning.methods) == {'vibration', 'wheel_radius'}
            assert any('agree' in r for r in warning.reasons)
    assert 2.0 + 0.5 - 1e-6 <= onset['t'] <= 2.0 + 0.7
    # evidence gone: the warning holds for set_off_s, then clears
    cleared = {}
    for k in range(40, 70):
        send(0.1 * k, {'vibration': clear, 'wheel_radius': clear})
        if not out.msgs['/tpms/warning'][-1].active and not cleared:
            cleared['t'] = 0.1 * k
    assert 4.0 + 1.0 - 1e-6 <= cleared['t'] <= 4.0 + 1.2
    assert node.processor.voter.rejected == {'unknown_method': 0, 'out_of_order': 0,
                                             'time_backwards': 0}


def test_voter_stale_method_and_bad_indication_reported(
        make_node: Callable[..., Any], spin_until: Callable[..., bool]) -> None:
    """A method silent longer than max_age_s is reported stale on /diagnostics and dropped from
    the vote; a NaN confidence and a method mismatch are rejected and counted."""
    make_node(TpmsVoterNode, parameter_overrides=[
        *_reliable('tpms/indication/vibration', 'tpms/indication/wheel_radius'),
        *[Parameter(k, value=v) for k, v in VOTER_TEST.items()]])
    tester = make_node('tester')
    out = Collector(tester, {'/tpms/warning': TpmsWarning})
    pub = tester.create_publisher(TpmsIndication, '/tpms/indication/vibration', DEEP)
    radius = tester.create_publisher(TpmsIndication, '/tpms/indication/wheel_radius', DEEP)
    assert spin_until(lambda: pub.get_subscription_count() and radius.get_subscription_count(),
                      10.0)
    radius.publish(_indication('wheel_radius', T0_NS, [False] * 4, [0.0] * 4))
    radius.publish(_indication('vibration', T0_NS + 1, [False] * 4, [0.0] * 4))   # mismatch
    pub.publish(_indication('vibration', T0_NS + 2, [False] * 4, [np.nan, 0, 0, 0]))
    for k in range(1, 15):
        pub.publish(_indication('vibration', T0_NS + k * 100_000_000, [False] * 4, [0.0] * 4))
    assert spin_until(lambda: out.last_stamp('/tpms/warning') == T0_NS + 1_400_000_000, 5.0)
    assert list(out.msgs['/tpms/warning'][-1].methods) == ['vibration']

    def stale(status: Any) -> bool:
        v = _values(status)
        return ('wheel_radius' in v.get('stale_methods', '') and v['rejected_invalid'] == '1'
                and v['rejected_method_mismatch'] == '1')

    status = None

    def found() -> bool:
        nonlocal status
        status = out.diag('/tpms_voter', stale)
        return status is not None

    assert spin_until(found, 5.0)
    assert 'stiffness' in _values(status)['stale_methods'] and status.level == b'\x01'
