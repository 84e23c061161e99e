"""``tire_stiffness_observer``: TPMS by tire stiffness (Umeno 1997) on the ROS graph.

Wraps :class:`tpms_ros.core.stiffness_observer.TireStiffnessObserver` (SPEC §2).

Topics (relative, so a namespace moves them):

* in ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz): the estimator's signal.
* in ``vehicle/driver_inputs`` (DriverInputs, optional): wheel torques and steering angle for
  the hard braking/traction and cornering gates.
* out ``tpms/tire_stiffness`` (TireStiffness), ``tpms/indication/stiffness`` (TpmsIndication,
  method ``stiffness``), ``/diagnostics``.
* service ``~/calibrate`` (std_srvs/Trigger): learn every tire's nominal stiffness over the next
  ``calibration_s`` of *valid* data (the tires must be at ``nominal_pressure_kpa``).

Processing: wheel speeds are buffered and handed to the core in chunks of ``process_period_s``
of *data* time, once more ``process_ahead_s`` before each output falls due (the core's result
does not depend on the chunking; processing ahead leaves little work for the sample an output
answers, hence a short latency), and an output is published every ``1 / publish_rate_hz`` of
data time, so a replay at any speed gives the same outputs. Each output is stamped with the last
wheel-speed sample it answers.

Time alignment of the driver inputs: each wheel-speed sample takes the latest driver-input
message not newer than itself (sample and hold); one older than ``driver_inputs_max_age_s`` is
stale and the torque and cornering gates are skipped for that sample (counted in the core's
``torque_invalid`` and ``steering_invalid``).

Bad input: a payload that is not a WheelSpeeds, or a repeated or out-of-order stamp, is
rejected and counted here; non-finite, negative, dead and stuck speeds, gaps and sample-rate
changes are rejected per wheel by the core, which reports the tire *unknown* (``valid`` and
``known`` false), never low. The input rate is measured and a mismatch with
``sample_rate_hz`` reported: a real rate change needs ``sample_rate_hz`` set (which rebuilds
the estimator, keeping its calibration).

Calibration persistence: with ``calibration_file`` set, a finished calibration is written there
(atomically, ``vehicle_monitor_common.calibration_store``) and loaded at start. A missing file
is a first start; an unusable one is reported on ``/diagnostics`` and ignored (the node runs
uncalibrated and asks for ``~/calibrate``). ``calibrate_on_start`` starts a calibration at start
only when no usable calibration was loaded, so a restart keeps what was learned.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger
from vehicle_monitor_msgs.msg import DriverInputs, TireStiffness, TpmsIndication

from tpms_ros.core.stiffness_observer import (
    StiffnessEstimate,
    StiffnessObserverParams,
    TireStiffnessObserver,
)
from tpms_ros.core.tires import TIRE_NAMES
from tpms_ros.nodes.wheel_speed_input import subscribe_wheel_speeds
from vehicle_monitor_common.calibration_store import CalibrationManager
from vehicle_monitor_common.input_health import StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    STALE,
    WARN,
    ConfigurationError,
    Diagnostics,
    ProcessAhead,
    TypedParameters,
    output_phase_param,
    process_ahead_param,
    run_node,
    sensor_subscription,
    stamp_ns,
    time_msg,
)
from vehicle_monitor_common.parameters import param

# Core reasons that mean the sensor data are bad (ERROR), not that the method is paused.
SENSOR_FAULTS = ('invalid_sample', 'dead_sensor', 'stuck_sensor', 'timing')


def _to_go_s(first_ns: int, last_ns: int, count: int, rate_hz: float,
             sample_rate_hz: float) -> float:
    """Data time, s, until ``count`` samples from first_ns to last_ns span one period of rate_hz
    (0 or less: they do): n samples cover n mean intervals (one sample: one nominal interval)."""
    if count < 2:
        spanned_s = 1.0 / sample_rate_hz
    else:
        spanned_s = (last_ns - first_ns) * 1e-9 * count / (count - 1)
    return 0.999 / rate_hz - spanned_s


def _chunk_problem(process_period_s: float, sample_rate_hz: float) -> str:
    """Why a chunk period does not fit the sample rate ('' when it does)."""
    if process_period_s * sample_rate_hz < 1.0:
        return (f'process_period_s {process_period_s:g} is shorter than one sample at '
                f'sample_rate_hz {sample_rate_hz:g}')
    return ''


@dataclass(frozen=True)
class TireStiffnessObserverNodeParams:
    """The node's own parameters (the method's are :class:`StiffnessObserverParams`)."""

    use_driver_inputs: bool = param(True, 'subscribe vehicle/driver_inputs for the torque and '
                                    'cornering gates', read_only=True)
    driver_inputs_max_age_s: float = param(0.1, 'a driver-input message older than this is '
                                           'stale (torque and cornering gates skipped), s',
                                           low=1e-3, high=10.0)
    calibrate_on_start: bool = param(False, 'start a calibration at start when no usable '
                                     'calibration file was loaded', read_only=True)
    calibration_file: str = param('', 'YAML file the calibration is saved to and loaded '
                                  'from at start; empty: not persisted', read_only=True)
    publish_rate_hz: float = param(4.0, 'output rate in data time, Hz', low=0.01, high=100.0)
    process_period_s: float = param(0.25, 'wheel speeds go to the core in chunks of this much '
                                    'data time, s (no effect on the result; shorter: less '
                                    'work when an output falls due, more per-call '
                                    'overhead)', low=0.001, high=10.0)
    process_ahead_s: float = process_ahead_param()
    output_phase_s: float = output_phase_param()


class TireStiffnessObserverNode(Node):
    """The ``tire_stiffness_observer`` node (see the module docstring)."""

    def __init__(self, node_name: str = 'tire_stiffness_observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        # The method's parameters are the core's own; the node's are topics, rates and files.
        self._method_params = TypedParameters(self, StiffnessObserverParams,
                                              on_change=self._on_change)
        self._node_params = TypedParameters(self, TireStiffnessObserverNodeParams)
        p, n = self._method_params.value, self._node_params.value
        problem = _chunk_problem(n.process_period_s, p.sample_rate_hz)
        if problem:
            raise ConfigurationError(f'invalid parameters: {problem}')
        self.add_on_set_parameters_callback(self._validate_chunk)
        self._observer = TireStiffnessObserver(p)
        self._stamps = StampCheck(max_gap_s=math.inf)
        self.rejected: dict[str, int] = {'malformed': 0, 'repeated': 0, 'out_of_order': 0}
        self.received = 0
        self.processed = 0
        self.published = 0
        self._buffer_ns: list[int] = []
        self._buffer_omega: list[Any] = []
        # Samples since the last output and the first of them (outputs every publish period).
        self._window_count = 0
        self._window_first_ns = 0
        self._ahead = ProcessAhead()
        # (stamp ns, wheel torques, steering angle) of the driver inputs, for the gates.
        self._driver: deque[tuple[int, np.ndarray, float]] = deque(maxlen=1000)
        self._origin_ns: int | None = None
        self._input_rate_hz = math.nan
        self._estimate: StiffnessEstimate | None = None

        # The core counts its own window (valid data per tire): the manager asks it when done.
        self._calibration = CalibrationManager(self._observer, n.calibration_file,
                                               'tire_stiffness_observer')
        self._calibration.load()
        if self._calibration.state == 'file_corrupt':
            self.get_logger().warning(self._calibration.detail)
        # Only when nothing usable was loaded, so a restart keeps what was learned.
        if n.calibrate_on_start and self._calibration.state != 'loaded':
            self._calibration.request(p.calibration_s)

        self._stiffness_pub = self.create_publisher(TireStiffness, 'tpms/tire_stiffness',
                                                    OUTPUT_QOS)
        self._indication_pub = self.create_publisher(TpmsIndication, 'tpms/indication/stiffness',
                                                     OUTPUT_QOS)
        subscribe_wheel_speeds(self, self._on_wheel_speeds, self._on_malformed)
        if n.use_driver_inputs:
            sensor_subscription(self, DriverInputs, 'vehicle/driver_inputs',
                                self._on_driver_inputs)
        self.create_service(Trigger, '~/calibrate', self._on_calibrate)
        # The status is refreshed when it is published (1 Hz), not with every output: the
        # output's latency does not carry it.
        self._diagnostics = Diagnostics(self, hardware_id='wheel_speed_sensors',
                                        update=self._update_diagnostics)
        self._update_diagnostics()

    # -- parameters and calibration ----------------------------------------------------------

    @property
    def parameters(self) -> StiffnessObserverParams:
        """The method's current, validated parameters (the core's)."""
        return self._method_params.value

    @property
    def node_parameters(self) -> TireStiffnessObserverNodeParams:
        """The node's own current, validated parameters."""
        return self._node_params.value

    @property
    def observer(self) -> TireStiffnessObserver:
        """The estimator core in use."""
        return self._observer

    def _validate_chunk(self, parameters: list[Parameter]) -> SetParametersResult:
        # The one rule across the two parameter classes: a chunk holds at least one sample.
        values = {prm.name: prm.value for prm in parameters}
        problem = _chunk_problem(
            float(values.get('process_period_s', self.node_parameters.process_period_s)),
            float(values.get('sample_rate_hz', self.parameters.sample_rate_hz)))
        return SetParametersResult(successful=not problem, reason=problem)

    @property
    def calibration_state(self) -> str:
        """uncalibrated, loaded, calibrating, calibrated, failed or file_corrupt."""
        return self._calibration.state

    @property
    def calibration_file_problem(self) -> str:
        """Why the calibration file was unusable ('' if it was not, or once one is saved)."""
        return self._calibration.file_problem

    def _on_change(self, p: StiffnessObserverParams) -> None:
        if p == self._observer.params:
            return
        # The filters are designed for these values: build a new estimator and carry the
        # calibration over (the core refuses it when the model K changed).
        self._observer = TireStiffnessObserver(p)
        self._calibration.replace_estimator(self._observer)
        self._update_diagnostics()

    def _on_calibrate(self, _: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self._calibration.request(
            self.parameters.calibration_s)
        self._update_diagnostics()
        return response

    # -- inputs ------------------------------------------------------------------------------

    def _on_driver_inputs(self, msg: DriverInputs) -> None:
        torque = np.asarray(msg.wheel_torque, dtype=float)
        stamp = stamp_ns(msg.header.stamp)
        if torque.shape != (4,) or (self._driver and stamp <= self._driver[-1][0]):
            return  # the gates simply hold the previous inputs
        self._driver.append((stamp, torque, float(msg.steering_angle)))

    def _on_malformed(self, _: str) -> None:
        self.received += 1
        self.rejected['malformed'] += 1

    def _on_wheel_speeds(self, stamp: int, omega: tuple[float, ...]) -> None:
        self.received += 1
        verdict = self._stamps.check(stamp)
        if verdict in ('repeated', 'out_of_order'):
            self.rejected[verdict] += 1
            return
        self._buffer_ns.append(stamp)
        self._buffer_omega.append(omega)
        if not self._window_count:
            self._window_first_ns = stamp
        self._window_count += 1
        p, n = self.parameters, self.node_parameters
        # output_phase_s delays the first output (and so every later one)
        to_output_s = _to_go_s(self._window_first_ns, stamp, self._window_count,
                               n.publish_rate_hz, p.sample_rate_hz) + (
            0.0 if self.published else n.output_phase_s)
        if (to_output_s <= 0.0 or self._ahead.due(to_output_s, n.process_ahead_s)
                or _to_go_s(self._buffer_ns[0], stamp, len(self._buffer_ns),
                            1.0 / n.process_period_s, p.sample_rate_hz) <= 0.0):
            self._process(publish=to_output_s <= 0.0)

    def _driver_inputs_for(self, stamps: np.ndarray,
                           ) -> tuple[np.ndarray | None, np.ndarray | None]:
        """Sample-and-hold wheel torques (N, 4) and steering angle (N,) for each wheel-speed
        stamp (NaN where stale), or None without driver inputs."""
        if not self._driver:
            return None, None
        driver_ns = np.array([d[0] for d in self._driver], dtype=np.int64)
        torque = np.array([d[1] for d in self._driver])
        steering = np.array([d[2] for d in self._driver])
        index = np.searchsorted(driver_ns, stamps, side='right') - 1
        max_age_ns = self.node_parameters.driver_inputs_max_age_s * 1e9
        fresh = (index >= 0) & (stamps - driver_ns[np.maximum(index, 0)] <= max_age_ns)
        # Keep the last message used (it may hold the next chunk's first samples).
        for _ in range(max(int(index[-1]), 0)):
            self._driver.popleft()
        if not fresh.any():
            return None, None
        held = np.maximum(index, 0)
        return (np.where(fresh[:, None], torque[held], np.nan),
                np.where(fresh, steering[held], np.nan))

    def _process(self, publish: bool) -> None:
        stamps = np.array(self._buffer_ns, dtype=np.int64)
        omega = np.array(self._buffer_omega, dtype=float)
        self._buffer_ns.clear()
        self._buffer_omega.clear()
        if self._origin_ns is None:
            self._origin_ns = int(stamps[0])
        # Seconds from the first sample keep full float resolution on epoch stamps.
        t = (stamps - self._origin_ns) * 1e-9
        if stamps.size > 1:
            self._input_rate_hz = 1.0 / float(np.median(np.diff(t)))
        torque, steering = self._driver_inputs_for(stamps)
        self._calibration.before_chunk()
        estimate = self._observer.update(omega, stamps=t, wheel_torque=torque,
                                         steering_angle=steering)
        self.processed += int(stamps.size)
        event = self._calibration.update(float(t[0]), float(t[-1]))
        if event:
            self.get_logger().info(event)
        self._estimate = estimate
        if publish:
            self._window_count = 0
            self._publish(estimate, int(stamps[-1]))

    # -- outputs -----------------------------------------------------------------------------

    def _publish(self, est: StiffnessEstimate, stamp: int) -> None:
        stiffness = TireStiffness()
        stiffness.header.stamp = time_msg(stamp)
        stiffness.header.frame_id = 'base_link'
        stiffness.delta_k = est.delta_k.tolist()
        stiffness.delta_d = est.delta_d.tolist()
        stiffness.stiffness = est.stiffness.tolist()
        stiffness.stiffness_ratio = est.stiffness_ratio.tolist()
        stiffness.pressure_kpa = est.pressure_kpa.tolist()
        stiffness.pressure_std_kpa = est.pressure_std_kpa.tolist()
        stiffness.valid = [bool(v) for v in est.valid]
        stiffness.calibrated = bool(est.calibrated)
        indication = TpmsIndication()
        indication.header = stiffness.header
        indication.method = 'stiffness'
        # Known: the core judged the tire on good data with a calibration in force; the core
        # never flags a tire it cannot judge.
        known = np.asarray(est.valid) & np.asarray(est.wheel_calibrated)
        indication.known = [bool(v) for v in known]
        indication.underinflated = [bool(v) for v in np.asarray(est.underinflated) & known]
        indication.confidence = [float(c) if k else 0.0
                                 for c, k in zip(est.confidence, known, strict=True)]
        self._stiffness_pub.publish(stiffness)
        self._indication_pub.publish(indication)
        self.published += 1
        self._ahead.published()

    def _update_diagnostics(self) -> None:
        p = self.parameters
        problems: list[str] = []
        notes: list[str] = []
        level = OK
        est = self._estimate
        values: dict[str, Any] = {
            'calibration_state': self.calibration_state,
            'calibration_detail': self._calibration.detail,
            'calibration_file': self.node_parameters.calibration_file or '(none)',
            'samples_received': self.received,
            'samples_processed': self.processed,
            'outputs_published': self.published,
            'sample_rate_hz': p.sample_rate_hz,
            'input_rate_hz': self._input_rate_hz,
            'driven_axle': p.driven_axle,
            'drive_compensation': p.drive_compensation,
            'speed_band_kmh': [p.speed_min_kmh, p.speed_max_kmh],
        }
        for reason, count in self.rejected.items():
            values[f'rejected_messages_{reason}'] = count
        if self.calibration_file_problem:
            values['calibration_file_problem'] = self.calibration_file_problem
            problems.append(f'calibration file unusable ({self.calibration_file_problem})')
        if self.calibration_state in ('uncalibrated', 'failed'):
            problems.append(self._calibration.detail)
        elif self.calibration_state == 'calibrating':
            notes.append('calibrating')
        if sum(self.rejected.values()):
            problems.append(f'{sum(self.rejected.values())} wheel-speed messages rejected')
        if est is None:
            message = '; '.join(problems) or 'waiting for wheel speeds'
            self._diagnostics.set(WARN if problems else STALE, message, values)
            return
        # A mismatch beyond the core's own timing tolerance breaks its filters' continuity.
        if abs(self._input_rate_hz / p.sample_rate_hz - 1.0) > p.timing_tolerance:
            problems.append(f'input rate {self._input_rate_hz:.4g} Hz does not match '
                            f'sample_rate_hz {p.sample_rate_hz:g}: set sample_rate_hz')
        values['tire_status'] = list(est.status)
        values['pressure_kpa'] = est.pressure_kpa.tolist()
        values['pressure_std_kpa'] = est.pressure_std_kpa.tolist()
        values['stiffness_ratio'] = est.stiffness_ratio.tolist()
        values['underinflated'] = [bool(v) for v in est.underinflated]
        values['confidence'] = est.confidence.tolist()
        for name, counts in self._observer.counters.items():
            values[f'core_{name}'] = list(counts)
        faults = [f'{w}: {s}' for w, s in zip(TIRE_NAMES, est.status, strict=True)
                  if s in SENSOR_FAULTS]
        paused = [f'{w}: {s}' for w, s in zip(TIRE_NAMES, est.status, strict=True)
                  if s != 'ok' and s not in SENSOR_FAULTS]
        low = [w for w, flag in zip(TIRE_NAMES, est.underinflated, strict=True) if flag]
        if faults:
            level = ERROR
            problems.insert(0, 'unknown (bad sensor data) ' + ', '.join(faults))
        if low:
            problems.append('under-inflated: ' + ', '.join(low))
        if paused:
            # Outside the method's valid conditions or converging: not a fault.
            notes.append('not estimating ' + ', '.join(paused))
        if problems and level == OK:
            level = WARN
        message = '; '.join(problems + notes) or 'all tires estimated'
        self._diagnostics.set(level, message, values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``tire_stiffness_observer`` executable."""
    raise SystemExit(run_node(TireStiffnessObserverNode, args))
