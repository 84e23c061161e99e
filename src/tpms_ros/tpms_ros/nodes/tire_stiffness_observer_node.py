"""``tire_stiffness_observer``: TPMS by tire stiffness (Umeno 1997) on the ROS graph.

Wraps :class:`tpms_ros.core.stiffness_observer.TireStiffnessObserver` (SPEC §2).

Topics (relative, so a namespace moves them):

* in ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz): the estimator's signal.
* in ``vehicle/driver_inputs`` (DriverInputs, optional): wheel torques for the hard
  braking/traction gate.
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

from builtin_interfaces.msg import Time
import numpy as np
from rclpy.node import Node
from std_srvs.srv import Trigger
from vehicle_monitor_msgs.msg import DriverInputs, TireStiffness, TpmsIndication

from tpms_ros.core.stiffness_observer import (
    PressureRelation,
    StiffnessEstimate,
    StiffnessObserverParams,
    TireStiffnessObserver,
)
from tpms_ros.core.tire_model import TorsionalTire
from tpms_ros.nodes.wheel_speed_input import subscribe_wheel_speeds
from vehicle_monitor_common.calibration_store import load_calibration, save_calibration
from vehicle_monitor_common.input_health import StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    STALE,
    WARN,
    Diagnostics,
    ProcessAhead,
    TypedParameters,
    output_phase_param,
    param,
    process_ahead_param,
    run_node,
    sensor_subscription,
    stamp_ns,
)

WHEELS = ('FL', 'FR', 'RL', 'RR')
# Core reasons that mean the sensor data are bad (ERROR), not that the method is paused.
SENSOR_FAULTS = ('invalid_sample', 'dead_sensor', 'stuck_sensor', 'timing')
# Defaults of the core and of its nominal tire: the node's defaults are these, not copies.
_D = StiffnessObserverParams()
_TIRE = TorsionalTire()
# Relative input-rate deviation reported as a mismatch (the core's timing tolerance).
RATE_TOLERANCE = _D.timing_tolerance


def _to_go_s(first_ns: int, last_ns: int, count: int, rate_hz: float,
             sample_rate_hz: float) -> float:
    """Data time, s, until ``count`` samples from first_ns to last_ns span one period of rate_hz
    (0 or less: they do): n samples cover n mean intervals (one sample: one nominal interval)."""
    if count < 2:
        spanned_s = 1.0 / sample_rate_hz
    else:
        spanned_s = (last_ns - first_ns) * 1e-9 * count / (count - 1)
    return 0.999 / rate_hz - spanned_s


@dataclass(frozen=True)
class StiffnessNodeParameters:
    """Parameters of the ``tire_stiffness_observer`` node (defaults: paper and SPEC §2)."""

    sample_rate_hz: float = param(
        _D.sample_rate_hz, 'wheel-speed sample rate the filters are built for, Hz (a change '
        'rebuilds the estimator, keeping its calibration)', low=50.0, high=20000.0)
    j1: float = param(_TIRE.j1, 'model rim-side inertia J1, kg m^2', low=1e-3, high=100.0)
    j2: float = param(_TIRE.j2, 'model belt-side inertia J2, kg m^2', low=1e-3, high=100.0)
    k: float = param(_TIRE.k, 'model torsional stiffness K at nominal pressure, N m/rad '
                     '(a change invalidates the calibration)', low=1.0, high=1e7)
    d: float = param(_TIRE.d, 'model torsional damping D, N m s/rad', low=0.0, high=1e4)
    observer_pole_factor: float = param(
        _D.observer_pole_factor, 'observer pole radius as a multiple of the model resonance',
        low=1.0, high=50.0)
    band_low_hz: float = param(_D.band_hz[0], 'pre-filter pass band lower edge, Hz', low=0.1,
                               high=10000.0)
    band_high_hz: float = param(_D.band_hz[1], 'pre-filter pass band upper edge, Hz', low=0.1,
                                high=10000.0)
    band_order: int = param(_D.band_order, 'Butterworth order of each band edge', low=1, high=8)
    forgetting_factor: float = param(
        _D.forgetting_factor, 'RLS forgetting factor rho per LS block (memory '
        'block_s / (1 - rho))', low=0.5, high=0.9999)
    block_s: float = param(_D.block_s, 'least-squares block length (one RLS update), s', low=0.01,
                           high=10.0)
    ls_mode: str = param(_D.ls_mode, 'least squares: recursive with forgetting or batch over a '
                         'window', choices=('rls', 'batch'))
    batch_window_blocks: int = param(
        _D.batch_window_blocks, 'batch LS window, blocks', low=2, high=100000)
    driven_axle: str = param(_D.driven_axle, 'axle(s) with drive-wheel compensation',
                             choices=('front', 'rear', 'none', 'all'))
    drive_compensation: str = param(
        _D.drive_compensation, "driven-axle compensation: 'partner' (the partner wheel's lagged "
        "speed as nuisance regressors) or 'difference' (the paper's wL - wR regression)",
        choices=('partner', 'difference'))
    partner_lag_s: float = param(
        _D.partner_lag_s, 'partner compensation: half-width of the two-sided lag window (output '
        'delay), s', low=0.0, high=1.0)
    partner_lag_step_s: float = param(
        _D.partner_lag_step_s, 'partner compensation: lag spacing, s (>= one sample)',
        low=1e-5, high=0.1)
    nominal_pressure_kpa: tuple[float, ...] = param(
        _D.nominal_pressure_kpa, 'placard pressure of each tire FL, FR, RL, RR, kPa '
        '(gauge); the pressure at calibration')
    pressure_slope: float = param(
        _D.pressure_relation.slope, 'K <-> pressure relation: relative stiffness change per '
        'relative pressure change (K/K0 = 1 - slope (1 - p/p0))', low=0.01, high=10.0)
    warning_pressure_ratio: float = param(
        _D.warning_pressure_ratio, 'a tire is flagged below this fraction of its nominal pressure',
        low=0.01, high=0.999)
    rolling_radius_m: float = param(
        _D.rolling_radius_m, 'nominal rolling radius for the speed gates, m', low=0.05, high=2.0)
    speed_min_kmh: float = param(
        _D.speed_band_kmh[0], 'lower edge of the speed band where the method is valid, km/h',
        low=0.0, high=500.0)
    speed_max_kmh: float = param(
        _D.speed_band_kmh[1], 'upper edge of the valid speed band, km/h', low=0.0, high=500.0)
    max_accel_mps2: float = param(
        _D.max_accel_mps2, '|acceleration| above this (hard braking/traction) pauses the '
        'estimate, m/s^2', low=0.01, high=50.0)
    max_slip: float = param(
        _D.max_slip, '|wheel speed / median wheel speed - 1| above this pauses the wheel',
        low=1e-3, high=1.0)
    max_wheel_torque_nm: float = param(
        _D.max_wheel_torque_nm, '|wheel torque| above this pauses the wheel, N m',
        low=1.0, high=1e5)
    max_lateral_accel_mps2: float = param(
        _D.max_lateral_accel_mps2, 'lateral acceleration (from steering and speed) above this '
        'pauses the estimate, m/s^2', low=0.01, high=50.0)
    wheelbase_m: float = param(
        _D.wheelbase_m, 'wheelbase for the lateral acceleration, m', low=0.5, high=20.0)
    use_driver_inputs: bool = param(True, 'subscribe vehicle/driver_inputs for the torque and '
                                    'cornering gates', read_only=True)
    driver_inputs_max_age_s: float = param(0.1, 'a driver-input message older than this is '
                                           'stale (torque and cornering gates skipped), s',
                                           low=1e-3, high=10.0)
    calibration_s: float = param(_D.calibration_s, 'valid data per tire a calibration collects, s',
                                 low=1.0, high=3600.0)
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

    def __post_init__(self) -> None:
        if self.process_period_s * self.sample_rate_hz < 1.0:
            raise ValueError(f'process_period_s {self.process_period_s:g} is shorter than one '
                             f'sample at sample_rate_hz {self.sample_rate_hz:g}')
        if len(self.nominal_pressure_kpa) != 4:
            raise ValueError('nominal_pressure_kpa must hold 4 values (FL, FR, RL, RR), got '
                             f'{len(self.nominal_pressure_kpa)}')
        tire = self.tire()  # validates J1, J2, K, D
        pole_hz = self.observer_pole_factor * tire.resonance_hz
        if not pole_hz < 0.5 * self.sample_rate_hz:
            raise ValueError(f'observer_pole_factor {self.observer_pole_factor:g} puts the '
                             f'observer poles at {pole_hz:.0f} Hz, above the Nyquist frequency '
                             f'{0.5 * self.sample_rate_hz:g} Hz')
        self.estimator_params()  # the core's own checks, with its reasons

    def tire(self) -> TorsionalTire:
        """The estimator's nominal tire model."""
        return TorsionalTire(self.j1, self.j2, self.k, self.d)

    def estimator_params(self) -> StiffnessObserverParams:
        """The core's parameters."""
        return StiffnessObserverParams(
            sample_rate_hz=self.sample_rate_hz,
            band_hz=(self.band_low_hz, self.band_high_hz), band_order=self.band_order,
            observer_pole_factor=self.observer_pole_factor, block_s=self.block_s,
            forgetting_factor=self.forgetting_factor,
            ls_mode=self.ls_mode,  # type: ignore[arg-type]
            batch_window_blocks=self.batch_window_blocks,
            driven_axle=self.driven_axle,  # type: ignore[arg-type]
            drive_compensation=self.drive_compensation,  # type: ignore[arg-type]
            partner_lag_s=self.partner_lag_s, partner_lag_step_s=self.partner_lag_step_s,
            calibration_s=self.calibration_s,
            nominal_pressure_kpa=tuple(float(v) for v in self.nominal_pressure_kpa),  # type: ignore[arg-type]
            pressure_relation=PressureRelation(self.pressure_slope),
            warning_pressure_ratio=self.warning_pressure_ratio,
            rolling_radius_m=self.rolling_radius_m,
            speed_band_kmh=(self.speed_min_kmh, self.speed_max_kmh),
            max_accel_mps2=self.max_accel_mps2, max_slip=self.max_slip,
            max_wheel_torque_nm=self.max_wheel_torque_nm,
            max_lateral_accel_mps2=self.max_lateral_accel_mps2, wheelbase_m=self.wheelbase_m)


def _time_msg(ns: int) -> Time:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


class TireStiffnessObserverNode(Node):
    """The ``tire_stiffness_observer`` node (see the module docstring)."""

    def __init__(self, node_name: str = 'tire_stiffness_observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, StiffnessNodeParameters, on_change=self._on_change)
        p = self._typed.value
        self._observer = TireStiffnessObserver(p.estimator_params(), p.tire())
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

        self.calibration_state = 'uncalibrated'
        self.calibration_detail = 'no calibration: call ~/calibrate with nominal tire pressures'
        # Why the calibration file was unusable; reported until a calibration is saved.
        self.calibration_file_problem = ''
        self._load_calibration_file()
        if p.calibrate_on_start and self.calibration_state != 'loaded':
            self._start_calibration()

        self._stiffness_pub = self.create_publisher(TireStiffness, 'tpms/tire_stiffness',
                                                    OUTPUT_QOS)
        self._indication_pub = self.create_publisher(TpmsIndication, 'tpms/indication/stiffness',
                                                     OUTPUT_QOS)
        subscribe_wheel_speeds(self, self._on_wheel_speeds, self._on_malformed)
        if p.use_driver_inputs:
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
    def parameters(self) -> StiffnessNodeParameters:
        """The current, validated parameters."""
        return self._typed.value

    @property
    def observer(self) -> TireStiffnessObserver:
        """The estimator core in use."""
        return self._observer

    def _on_change(self, p: StiffnessNodeParameters) -> None:
        new_params, new_tire = p.estimator_params(), p.tire()
        if new_params == self._observer.params and new_tire == self._observer.tires[0]:
            return
        # The filters are designed for these values: build a new estimator and carry the
        # calibration over (the core refuses it when the model K changed).
        old = self._observer
        self._observer = TireStiffnessObserver(new_params, new_tire)
        if self.calibration_state == 'calibrating':
            self._start_calibration()
        elif self.calibration_state in ('loaded', 'calibrated'):
            try:
                self._observer.load_calibration(old.calibration_state())
                self.calibration_detail += ' (kept across a parameter change)'
            except ValueError as exc:
                self.calibration_state = 'uncalibrated'
                self.calibration_detail = (f'calibration dropped by a parameter change ({exc}): '
                                           'recalibration required (~/calibrate)')
        self._update_diagnostics()

    def _load_calibration_file(self) -> None:
        path = self.parameters.calibration_file
        if not path:
            return
        loaded = load_calibration(path)
        if loaded.state is None:
            if loaded.problem:
                self._file_corrupt(loaded.problem)
            return
        try:
            self._observer.load_calibration(loaded.state)
        except ValueError as exc:
            self._file_corrupt(f'{path} rejected: {exc}')
            return
        self.calibration_state = 'loaded'
        self.calibration_detail = f'calibration loaded from {path}'

    def _file_corrupt(self, problem: str) -> None:
        self.calibration_state = 'file_corrupt'
        self.calibration_file_problem = problem
        self.calibration_detail = (f'calibration file unusable ({problem}): running '
                                   'uncalibrated, recalibration required (~/calibrate)')
        self.get_logger().warning(self.calibration_detail)

    def _start_calibration(self) -> None:
        self._observer.start_calibration(self.parameters.calibration_s)
        self.calibration_state = 'calibrating'
        self.calibration_detail = (f'calibrating over {self.parameters.calibration_s:g} s of '
                                   'valid data per tire (tires must be at nominal pressure)')

    def _on_calibrate(self, _: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.calibration_state == 'calibrating':
            response.success = False
            response.message = 'a calibration is already running'
            return response
        self._start_calibration()
        response.success = True
        response.message = self.calibration_detail
        self._update_diagnostics()
        return response

    def _check_calibration(self) -> None:
        if self.calibration_state != 'calibrating' or self._observer.calibrating:
            return
        state = self._observer.calibration_state()
        self.calibration_state = 'calibrated'
        path = self.parameters.calibration_file
        if not path:
            self.calibration_detail = 'calibrated (not persisted: calibration_file is empty)'
            return
        problem = save_calibration(path, state, comment='tire_stiffness_observer calibration '
                                   '(written by the node; delete to forget)')
        self.calibration_detail = (f'calibrated, NOT saved: {problem}' if problem
                                   else f'calibrated, saved to {path}')
        if not problem:
            self.calibration_file_problem = ''
        self.get_logger().info(self.calibration_detail)

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
        p = self.parameters
        # output_phase_s delays the first output (and so every later one)
        to_output_s = _to_go_s(self._window_first_ns, stamp, self._window_count,
                               p.publish_rate_hz, p.sample_rate_hz) + (
            0.0 if self.published else p.output_phase_s)
        if (to_output_s <= 0.0 or self._ahead.due(to_output_s, p.process_ahead_s)
                or _to_go_s(self._buffer_ns[0], stamp, len(self._buffer_ns),
                            1.0 / p.process_period_s, p.sample_rate_hz) <= 0.0):
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
        max_age_ns = self.parameters.driver_inputs_max_age_s * 1e9
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
        estimate = self._observer.update(omega, stamps=t, wheel_torque=torque,
                                         steering_angle=steering)
        self.processed += int(stamps.size)
        self._estimate = estimate
        self._check_calibration()
        if publish:
            self._window_count = 0
            self._publish(estimate, int(stamps[-1]))

    # -- outputs -----------------------------------------------------------------------------

    def _publish(self, est: StiffnessEstimate, stamp: int) -> None:
        stiffness = TireStiffness()
        stiffness.header.stamp = _time_msg(stamp)
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
            'calibration_detail': self.calibration_detail,
            'calibration_file': p.calibration_file or '(none)',
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
        if self.calibration_state == 'uncalibrated':
            problems.append(self.calibration_detail)
        elif self.calibration_state == 'calibrating':
            notes.append('calibrating')
        if sum(self.rejected.values()):
            problems.append(f'{sum(self.rejected.values())} wheel-speed messages rejected')
        if est is None:
            message = '; '.join(problems) or 'waiting for wheel speeds'
            self._diagnostics.set(WARN if problems else STALE, message, values)
            return
        if abs(self._input_rate_hz / p.sample_rate_hz - 1.0) > RATE_TOLERANCE:
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
        faults = [f'{w}: {s}' for w, s in zip(WHEELS, est.status, strict=True)
                  if s in SENSOR_FAULTS]
        paused = [f'{w}: {s}' for w, s in zip(WHEELS, est.status, strict=True)
                  if s != 'ok' and s not in SENSOR_FAULTS]
        low = [w for w, flag in zip(WHEELS, est.underinflated, strict=True) if flag]
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
