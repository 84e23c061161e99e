"""The tire stiffness observer's logic, ROS-free: stamp checks, chunking, calibration, outputs.

Wraps :class:`tpms_ros.core.stiffness_observer.TireStiffnessObserver` (Umeno 1997,
docs/methods/tire_stiffness_observer.md);
the node (``tpms_ros.nodes.tire_stiffness_observer_node``) and the offline engine both run it.

Inputs (relative topics): ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz, raw CDR: decoded by
:func:`tpms_ros.processing.wheel_speeds.decode_wheel_speeds`), ``vehicle/driver_inputs``
(DriverInputs, optional: wheel torques and steering angle for the gates). Outputs:
``tpms/tire_stiffness`` (TireStiffness) and ``tpms/indication/stiffness`` (TpmsIndication).

Processing: wheel speeds are buffered and handed to the core in chunks of ``process_period_s``
of *data* time, once more ``process_ahead_s`` before each output falls due (the core's result
does not depend on the chunking), and an output is due every ``1 / publish_rate_hz`` of data
time, so a replay at any speed gives the same outputs. Each output is stamped with the last
wheel-speed sample it answers.

Driver inputs: each wheel-speed sample takes the latest driver-input message not newer than
itself (sample and hold); one older than ``driver_inputs_max_age_s`` is stale and the torque and
cornering gates are skipped for that sample (counted by the core).

Time (:class:`vehicle_monitor_common.input_health.StampCheck`): a repeated or out-of-order
stamp is rejected and counted; a single stamp more than ``jump_horizon_s`` ahead is dropped and
counted ('future_stamp'), never adopted as "now"; a confirmed jump forward or back (a looped or
repeated replay, a clock reset) restarts the filters from the new time line, keeping the
calibration, and the status says so until every tire is estimated again.

Sensor faults (non-finite, negative, absurd, dead, stuck speeds, timing breaks) are the core's:
the wheel is *unknown* (``valid``/``known`` false), never low. Such a fault clears once the
wheel's encoder-ring pattern is back (found again or relearned after the reset). Then the
least squares still hold blocks from around the fault for one memory of the estimator
(:func:`recovery_s`): the tire stays unknown ('recovering') for that much valid data time, so a
transient after a fault is never published as valid, and the status says so. An input rate that
does not match ``sample_rate_hz`` makes every tire unknown ('rate_mismatch') and the status
names both rates.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from tpms_ros.core.stiffness_observer import (
    CHECKING,
    StiffnessEstimate,
    StiffnessObserverParams,
    TireStiffnessObserver,
)
from tpms_ros.core.tires import TIRE_NAMES
from tpms_ros.processing.calibrating_tpms import (
    CalibratingTpmsParams,
    ProcessAhead,
    follow_calibration_check,
    offline_calibration_file,
)
from tpms_ros.processing.wheel_speeds import WHEEL_SPEEDS_TYPE, decode_wheel_speeds
from vehicle_monitor_common.calibration_store import CalibrationManager
from vehicle_monitor_common.input_health import StampCheck
from vehicle_monitor_common.parameters import ConfigurationError, build, param
from vehicle_monitor_common.processing import (
    ERROR,
    OK,
    WARN,
    Input,
    Output,
    ParameterGroup,
    ProcessorSpec,
    Status,
    header_stamp_ns,
)

WHEEL_SPEEDS = 'vehicle/wheel_speeds'
DRIVER_INPUTS = 'vehicle/driver_inputs'
STIFFNESS = 'tpms/tire_stiffness'
INDICATION = 'tpms/indication/stiffness'

# Core reasons that mean the sensor data are bad (ERROR), not that the method is paused.
SENSOR_FAULTS = ('invalid_sample', 'dead_sensor', 'stuck_sensor', 'timing')
# Core reasons for a calibrated, converged estimate that is not trusted (reported unknown).
UNCERTAIN = {
    'uncertain_noisy': 'block stiffnesses spread wider than at calibration',
}


@dataclass(frozen=True)
class TireStiffnessObserverNodeParams(CalibratingTpmsParams):
    """The node's own parameters (the method's are :class:`StiffnessObserverParams`)."""

    use_driver_inputs: bool = param(True, 'subscribe vehicle/driver_inputs for the torque and '
                                    'cornering gates', read_only=True)
    driver_inputs_max_age_s: float = param(0.1, 'a driver-input message older than this is '
                                           'stale (torque and cornering gates skipped), s',
                                           low=1e-3, high=10.0)
    publish_rate_hz: float = param(4.0, 'output rate in data time, Hz', low=0.01, high=100.0)
    process_period_s: float = param(0.25, 'wheel speeds go to the core in chunks of this much '
                                    'data time, s (no effect on the result; shorter: less '
                                    'work when an output falls due, more per-call '
                                    'overhead)', low=0.001, high=10.0)


def chunk_problem(process_period_s: float, sample_rate_hz: float) -> str:
    """Why a chunk period does not fit the sample rate ('' when it does)."""
    if process_period_s * sample_rate_hz < 1.0:
        return (f'process_period_s {process_period_s:g} is shorter than one sample at '
                f'sample_rate_hz {sample_rate_hz:g}')
    return ''


def recovery_s(params: StiffnessObserverParams) -> float:
    """Data time a tire stays 'recovering' after a sensor fault clears: one memory of the least
    squares (``block_s / (1 - forgetting_factor)`` for RLS, the batch window for batch), after
    which the blocks from around the fault weigh less than 1/e (RLS) or are gone (batch)."""
    if params.ls_mode == 'batch':
        return params.batch_window_blocks * params.block_s
    return params.block_s / (1.0 - params.forgetting_factor)


def _to_go_s(first_ns: int, last_ns: int, count: int, rate_hz: float,
             sample_rate_hz: float) -> float:
    """Data time, s, until ``count`` samples from first_ns to last_ns span one period of rate_hz
    (0 or less: they do): n samples cover n mean intervals (one sample: one nominal interval)."""
    if count < 2:
        spanned_s = 1.0 / sample_rate_hz
    else:
        spanned_s = (last_ns - first_ns) * 1e-9 * count / (count - 1)
    return 0.999 / rate_hz - spanned_s


class TireStiffnessObserverProcessor:
    """What the tire stiffness observer does with its inputs (see the module docstring).

    Args:
        params: the method's parameters, handed to the core as they are.
        node_params: chunking, output timing, time checks, calibration.
        calibration_file: where the calibration is kept (resolved; '' = not persisted).
    """

    outputs = {STIFFNESS: 'vehicle_monitor_msgs/msg/TireStiffness',
               INDICATION: 'vehicle_monitor_msgs/msg/TpmsIndication'}

    def __init__(self, params: StiffnessObserverParams,
                 node_params: TireStiffnessObserverNodeParams,
                 calibration_file: str = '') -> None:
        problem = chunk_problem(node_params.process_period_s, params.sample_rate_hz)
        if problem:
            raise ConfigurationError(f'invalid parameters: {problem}')
        self.node_params = node_params
        self.inputs: dict[str, Input] = {WHEEL_SPEEDS: Input(WHEEL_SPEEDS_TYPE, raw=True)}
        if node_params.use_driver_inputs:
            self.inputs[DRIVER_INPUTS] = Input('vehicle_monitor_msgs/msg/DriverInputs',
                                               optional=True)
        self.observer = TireStiffnessObserver(params)
        self.calibration_file = calibration_file
        self._stamps = StampCheck(max_gap_s=math.inf,
                                  jump_horizon_s=node_params.jump_horizon_s)
        self.rejected: Counter[str] = Counter(
            {'malformed': 0, 'repeated': 0, 'out_of_order': 0, 'future_stamp': 0})
        self.received = 0
        self.processed = 0
        self.published = 0
        self.time_jumps = 0
        self._last_jump_s = 0.0
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
        # Per tire: data time (s since origin) until which it is 'recovering' after a fault.
        self._recovering_until = np.full(len(TIRE_NAMES), -math.inf)
        self._faulted = np.zeros(len(TIRE_NAMES), dtype=bool)
        self._restarted = False      # filters restarted by a time jump, not estimating again yet
        self._valid_at_jump = np.zeros(len(TIRE_NAMES), dtype=bool)
        self._rejected_at_last_status: Counter[str] = Counter()
        self._last_t = 0.0
        self.events: list[str] = []  # calibration events for the node's log

        # The core counts its own window (valid data per tire): the manager asks it when done.
        self._calibration = CalibrationManager(self.observer, calibration_file,
                                               'tire_stiffness_observer')
        self._calibration.load()
        if self._calibration.state == 'file_corrupt':
            self.events.append(self._calibration.detail)
        # Only when nothing usable was loaded, so a restart keeps what was learned.
        if node_params.calibrate_on_start and self._calibration.state != 'loaded':
            self._calibration.request(params.calibration_s)

    # -- parameters and calibration ----------------------------------------------------------

    @property
    def params(self) -> StiffnessObserverParams:
        """The method's parameters in force (the core's)."""
        return self.observer.params

    def set_params(self, params: StiffnessObserverParams) -> None:
        """New method parameters: the filters are designed for them, so the estimator is
        rebuilt and the calibration carried over (the core refuses it when the model K
        changed)."""
        if params == self.observer.params:
            return
        self.observer = TireStiffnessObserver(params)
        self._calibration.replace_estimator(self.observer)

    def set_node_params(self, node_params: TireStiffnessObserverNodeParams) -> None:
        """New node parameters (rates, chunking, driver-input age) take effect at once."""
        self.node_params = node_params

    @property
    def calibration(self) -> CalibrationManager:
        """The calibration manager (state, detail, file problem)."""
        return self._calibration

    def request_calibration(self) -> tuple[bool, str]:
        """Learn every tire's nominal stiffness over the next ``calibration_s`` of valid data."""
        return self._calibration.request(self.params.calibration_s)

    def calibration_state(self) -> dict[str, Any] | None:
        """The calibration in force as plain data (None: uncalibrated)."""
        if not self.observer.calibration_complete():
            return None
        return self.observer.calibration_state()

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Put a stored calibration in force; ValueError when it does not fit."""
        self._calibration.put_in_force(state)

    # -- inputs ------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message (the wheel speeds as CDR bytes); the outputs it makes due."""
        if topic == WHEEL_SPEEDS:
            return self._on_wheel_speeds(message)
        if topic == DRIVER_INPUTS:
            self._on_driver_inputs(message)
        return []

    def _on_driver_inputs(self, msg: Any) -> None:
        try:
            torque = np.asarray(msg.wheel_torque, dtype=float)
            steering = float(msg.steering_angle)
            stamp = header_stamp_ns(msg)
        except (TypeError, ValueError, AttributeError):
            return
        if torque.shape != (4,):
            return  # the gates simply hold the previous inputs
        if self._driver and stamp <= self._driver[-1][0]:
            if stamp < self._driver[-1][0] - self.node_params.jump_horizon_s * 1e9:
                self._driver.clear()    # the driver inputs started a new time line
            else:
                return
        self._driver.append((stamp, torque, steering))

    def _on_wheel_speeds(self, data: bytes) -> list[Output]:
        self.received += 1
        try:
            stamp, omega = decode_wheel_speeds(data)
        except ValueError:
            self.rejected['malformed'] += 1
            return []
        verdict = self._stamps.check(stamp)
        if verdict in ('repeated', 'out_of_order', 'future_stamp'):
            self.rejected[verdict] += 1
            return []
        outputs: list[Output] = []
        if verdict == 'jump':
            outputs = self._restart(stamp)
        self._buffer_ns.append(stamp)
        self._buffer_omega.append(omega)
        if not self._window_count:
            self._window_first_ns = stamp
        self._window_count += 1
        p, n = self.params, self.node_params
        # output_phase_s delays the first output (and so every later one)
        to_output_s = _to_go_s(self._window_first_ns, stamp, self._window_count,
                               n.publish_rate_hz, p.sample_rate_hz) + (
            0.0 if self.published else n.output_phase_s)
        if (to_output_s <= 0.0 or self._ahead.due(to_output_s, n.process_ahead_s)
                or _to_go_s(self._buffer_ns[0], stamp, len(self._buffer_ns),
                            1.0 / n.process_period_s, p.sample_rate_hz) <= 0.0):
            outputs += self._process(publish=to_output_s <= 0.0)
        return outputs

    def _restart(self, stamp: int) -> list[Output]:
        """A confirmed time jump: finish the old time line's buffer, then restart the filters
        from the new one (the calibration is kept; a running calibration window restarts)."""
        outputs = self._process(publish=False) if self._buffer_ns else []
        self.time_jumps += 1
        self._last_jump_s = self._stamps.last_jump_s
        self.observer.reset()
        self._calibration.restart()
        self._origin_ns = None
        self._window_count = 0
        self._ahead.published()
        self._driver.clear()
        self._recovering_until[:] = -math.inf
        self._faulted[:] = False
        self._restarted = True
        self._valid_at_jump = (np.asarray(self._estimate.valid) if self._estimate is not None
                               else np.zeros(len(TIRE_NAMES), dtype=bool))
        self._last_t = 0.0
        return outputs

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
        max_age_ns = self.node_params.driver_inputs_max_age_s * 1e9
        fresh = (index >= 0) & (stamps - driver_ns[np.maximum(index, 0)] <= max_age_ns)
        # Keep the last message used (it may hold the next chunk's first samples).
        for _ in range(max(int(index[-1]), 0)):
            self._driver.popleft()
        if not fresh.any():
            return None, None
        held = np.maximum(index, 0)
        return (np.where(fresh[:, None], torque[held], np.nan),
                np.where(fresh, steering[held], np.nan))

    def _process(self, publish: bool) -> list[Output]:
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
        estimate = self.observer.update(omega, stamps=t, wheel_torque=torque,
                                        steering_angle=steering)
        self.processed += int(stamps.size)
        event = self._calibration.update(float(t[0]), float(t[-1]))
        if event:
            self.events.append(event)
        event = follow_calibration_check(
            self._calibration, self.observer.calibration_check,
            self.params.calibration_s if self.node_params.calibrate_on_start else None)
        if event:
            self.events.append(event)
        self._estimate = estimate
        self._last_t = float(t[-1])
        self._follow_faults(estimate)
        if not publish:
            return []
        self._window_count = 0
        self.published += 1
        self._ahead.published()
        return self._outputs(estimate, int(stamps[-1]))

    def _follow_faults(self, est: StiffnessEstimate) -> None:
        """Start a tire's recovery window when its sensor fault clears."""
        # A wheel reset by a sensor fault has its encoder ring's pattern to find again or relearn
        # ('tooth_learning') before its data count: the fault clears after that.
        fault = np.array([s in SENSOR_FAULTS or (s == 'tooth_learning' and faulted)
                          for s, faulted in zip(est.status, self._faulted, strict=True)])
        cleared = self._faulted & ~fault
        self._recovering_until[cleared] = self._last_t + recovery_s(self.params)
        self._faulted = fault
        # The restart note stays until every tire estimated before the jump is again.
        if self._restarted and np.all(np.asarray(est.valid) | ~self._valid_at_jump):
            self._restarted = False

    def recovering(self) -> np.ndarray:
        """Per tire: within its recovery window after a sensor fault."""
        return self._recovering_until > self._last_t

    def rate_mismatch(self) -> bool:
        """The measured input rate breaks the filters' design rate beyond the core's timing
        tolerance."""
        p = self.params
        return bool(math.isfinite(self._input_rate_hz) and abs(
            self._input_rate_hz / p.sample_rate_hz - 1.0) > p.timing_tolerance)

    # -- outputs -----------------------------------------------------------------------------

    def _outputs(self, est: StiffnessEstimate, stamp: int) -> list[Output]:
        # Known: the core judged the tire on good data with a calibration in force (the core
        # never flags a tire it cannot judge), not recovering from a fault, at the right rate.
        trusted = ~self.recovering() & (not self.rate_mismatch())
        valid = np.asarray(est.valid) & trusted
        known = valid & np.asarray(est.wheel_calibrated)
        header = {'frame_id': 'base_link'}
        stiffness = {
            'header': header,
            'delta_k': est.delta_k.tolist(),
            'delta_d': est.delta_d.tolist(),
            'stiffness': est.stiffness.tolist(),
            'stiffness_ratio': est.stiffness_ratio.tolist(),
            'pressure_kpa': est.pressure_kpa.tolist(),
            'pressure_std_kpa': est.pressure_std_kpa.tolist(),
            'valid': [bool(v) for v in valid],
            'calibrated': bool(est.calibrated),
        }
        indication = {
            'header': header,
            'method': 'stiffness',
            'known': [bool(v) for v in known],
            'underinflated': [bool(v) for v in np.asarray(est.underinflated) & known],
            'confidence': [float(c) if k else 0.0
                           for c, k in zip(est.confidence, known, strict=True)],
        }
        return [Output(STIFFNESS, stamp, stiffness), Output(INDICATION, stamp, indication)]

    def tire_status(self) -> list[str]:
        """Per tire: the core's status, or 'recovering' / 'rate_mismatch' where this processor
        does not trust an estimate the core calls ok."""
        if self._estimate is None:
            return ['no_data'] * len(TIRE_NAMES)
        if self.rate_mismatch():
            return ['rate_mismatch'] * len(TIRE_NAMES)
        recovering = self.recovering()
        return ['recovering' if r and s == 'ok' else s
                for s, r in zip(self._estimate.status, recovering, strict=True)]

    def status(self, now_ns: int) -> Status:
        """Health: calibration, rejected input, time jumps, per-tire state, rate."""
        del now_ns  # the adapter reports silence; everything here is in data time
        p = self.params
        calibration = self._calibration
        problems: list[str] = []
        notes: list[str] = []
        level = OK
        est = self._estimate
        values: dict[str, Any] = {
            'calibration_state': calibration.state,
            'calibration_detail': calibration.detail,
            'calibration_file': self.calibration_file or '(not persisted)',
            'samples_received': self.received,
            'samples_processed': self.processed,
            'outputs_published': self.published,
            'sample_rate_hz': p.sample_rate_hz,
            'input_rate_hz': self._input_rate_hz,
            'driven_axle': p.driven_axle,
            'drive_compensation': p.drive_compensation,
            'speed_band_kmh': [p.speed_min_kmh, p.speed_max_kmh],
            'pressure_relation': p.pressure_relation.describe(),
            'time_jumps': self.time_jumps,
            'recovery_s': recovery_s(p),
            'encoder_noise': self.observer.encoder_noise,
        }
        for reason, count in self.rejected.items():
            values[f'rejected_messages_{reason}'] = count
        if calibration.file_problem:
            values['calibration_file_problem'] = calibration.file_problem
        if calibration.state == 'refused':
            level = ERROR
            problems.append(calibration.detail)
        elif calibration.file_problem:
            problems.append(f'calibration file unusable ({calibration.file_problem})')
        if calibration.state in ('uncalibrated', 'failed'):
            problems.append(calibration.detail)
        elif self.observer.calibration_check.pending:
            problems.append(self.observer.calibration_check.status(p))
        elif calibration.state == 'calibrating':
            notes.append(calibration.detail)
        # Rejections are reported while they are recent: the counts stay in the values, the
        # warning clears once a whole output period passed without one.
        recent = self.rejected - self._rejected_at_last_status
        self._rejected_at_last_status = Counter(self.rejected)
        if sum(recent.values()):
            problems.append('wheel-speed messages rejected: ' + ', '.join(
                f'{n} {reason}' for reason, n in sorted(recent.items()) if n))
        if self._restarted:
            problems.append(f'time jump of {self._last_jump_s:+.3g} s: filters restarted '
                            '(calibration kept), estimating again once converged')
        if est is None:
            message = '; '.join(problems) or 'waiting for wheel speeds'
            return Status(WARN, message, values)
        status = self.tire_status()
        if self.rate_mismatch():
            level = ERROR
            problems.insert(0, f'input rate {self._input_rate_hz:.4g} Hz does not match '
                            f'sample_rate_hz {p.sample_rate_hz:g}: every tire unknown, set '
                            'sample_rate_hz')
        values['tire_status'] = status
        values['pressure_kpa'] = est.pressure_kpa.tolist()
        values['pressure_std_kpa'] = est.pressure_std_kpa.tolist()
        values['stiffness_ratio'] = est.stiffness_ratio.tolist()
        values['underinflated'] = [bool(v) for v in est.underinflated]
        values['confidence'] = est.confidence.tolist()
        for name, counts in self.observer.counters.items():
            values[f'core_{name}'] = list(counts)
        for name, per_tire in self.observer.trust_features().items():
            values[f'trust_{name}'] = per_tire.tolist()
        faults = [f'{w}: {s}' for w, s in zip(TIRE_NAMES, status, strict=True)
                  if s in SENSOR_FAULTS]
        recovering = [w for w, s in zip(TIRE_NAMES, status, strict=True) if s == 'recovering']
        uncertain = [f'{w}: {UNCERTAIN[s]}' for w, s in zip(TIRE_NAMES, status, strict=True)
                     if s in UNCERTAIN]
        paused = [f'{w}: {s}' for w, s in zip(TIRE_NAMES, status, strict=True)
                  if s not in (*SENSOR_FAULTS, *UNCERTAIN, 'ok', 'recovering', 'rate_mismatch',
                               CHECKING)]
        low = [w for w, flag, s in zip(TIRE_NAMES, est.underinflated, status, strict=True)
               if flag and s == 'ok']
        if faults:
            level = ERROR
            problems.insert(0, 'unknown (bad sensor data) ' + ', '.join(faults))
        if recovering:
            problems.append(f'recovering after a sensor fault (unknown for up to '
                            f'{recovery_s(p):.3g} s of data): ' + ', '.join(recovering))
        if low:
            problems.append('under-inflated: ' + ', '.join(low))
        if uncertain:
            # Not a fault of the data: the estimate is withheld (unknown, never low).
            problems.append('uncertain (estimate not trusted, reported unknown) '
                            + ', '.join(uncertain))
        if paused:
            # Outside the method's valid conditions or converging: not a fault.
            notes.append('not estimating ' + ', '.join(paused))
        if problems and level == OK:
            level = WARN
        message = '; '.join(problems + notes) or 'all tires estimated'
        return Status(level, message, values)


def make_processor(values: Mapping[str, Any], fqn: str) -> TireStiffnessObserverProcessor:
    """The processor from flat parameter values (the node's and the offline engine's way in).
    The calibration is persisted only where ``calibration_file`` names a file (the node resolves
    an empty one to its own file first; the engine carries a vehicle's calibration from one
    recording to the next itself)."""
    del fqn
    params = build(StiffnessObserverParams, values)
    node_params = build(TireStiffnessObserverNodeParams, values)
    return TireStiffnessObserverProcessor(
        params, node_params, offline_calibration_file(node_params.calibration_file))


def chunk_rule(values: Mapping[str, Any]) -> str:
    """:func:`chunk_problem` across the method's and the node's groups (flat values)."""
    return chunk_problem(float(values['process_period_s']), float(values['sample_rate_hz']))


# The node, declared once: the live node (nodes/tire_stiffness_observer_node.py) and the offline
# engine (make_processor, the registered entry point) build it from this; a chunk holds at least
# one sample (chunk_rule, checked on every runtime change across the two groups).
SPEC = ProcessorSpec(
    'tire_stiffness_observer', 'wheel_speed_sensors', factory=make_processor,
    cross_check=chunk_rule,
    groups=(ParameterGroup(StiffnessObserverParams, 'set_params'),
            ParameterGroup(TireStiffnessObserverNodeParams, 'set_node_params')))
