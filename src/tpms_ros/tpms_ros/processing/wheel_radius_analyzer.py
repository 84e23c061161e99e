"""The wheel-radius analyzer's logic, ROS-free: alignment, calibration, sensor faults, outputs.

Wraps :class:`tpms_ros.core.wheel_radius_analysis.WheelRadiusAnalyzer` (TPMS by relative
rolling radii, Persson 2002, docs/methods/wheel_radius_analyzer.md); the node
(``tpms_ros.nodes.wheel_radius_analyzer_node``)
and the offline engine both run it.

Inputs (relative topics): ``vehicle/wheel_speeds`` (WheelSpeeds, ~1 kHz, raw CDR),
``vehicle/imu`` (sensor_msgs/Imu, ``angular_velocity.z`` = yaw rate, REP 103) and
``vehicle/driver_inputs`` (DriverInputs: wheel torques, steering angle). Outputs:
``tpms/wheel_radius`` (WheelRadiusOffsets) and ``tpms/indication/wheel_radius``
(TpmsIndication).

Time alignment. The core runs at ~100 Hz on synchronised samples. Each IMU sample at t_k closes
a bin (t_prev, t_k] (at most one ``1 / sample_rate_hz`` long; IMU samples closer than 0.75 of
that to the previous bin end are skipped, so a faster IMU is decimated): the wheel speeds
stamped in the bin are averaged, and the driver input used is the newest one stamped at or
before t_k. A bin waits until a wheel speed and a driver input stamped at or after t_k have
arrived, and whether the pending bins are processed is decided bin by bin: topics arrive in
any order, and neither what a bin holds nor where a chunk ends may depend on it, or the live
graph's outputs would depend on its delivery (with the driver inputs 30 messages late, 120 of
121 outputs of road_kim_huh_relation_check differed before). The price: a bin waits for the
next driver input, up to one of its periods when its stamps lag the IMU's (none on the
recordings, which stamp both alike). If they do not come within ``max_latency_s`` of IMU
time, the bin is processed with the wheel speeds it has, or as missing (NaN) if it has none
(without driver inputs every bin waits that long). A driver input older than
``max_input_age_s`` is stale: the torque becomes NaN (longitudinal filters pause) and the
steering angle NaN (the front-axle lateral measurement pauses). Without the IMU no bin closes:
the analysis pauses (the node reports the silence).

Processing: aligned bins go to the core in chunks of ``process_period_s``, where an output falls
due and ``process_ahead_s`` before it (so little work is left for the sample an output answers,
hence a short latency).

Sensor faults never become tire faults. A wheel whose bin holds a bad sample is NaN in the bin:
non-finite, negative or above ``max_wheel_speed_rad_s``; stuck or dead (the same value repeated
exactly for ``stuck_s``, unless all four wheels read 0: standstill); or implausible (its bin mean
off the median of the four by more than ``max_wheel_deviation`` while the car moves: a dead or
broken sensor). The core then freezes every filter update (the pair offsets delta_12, delta_34,
the longitudinal deltas and the gyro offset are learned state) while a wheel is bad and for
``wheel_recover_s`` after, and keeps the tire unknown as long: the learned state is the one
from before the fault, right again as soon as the hold ends.

Time (:class:`vehicle_monitor_common.input_health.StampCheck`, per input): out-of-order and
repeated stamps are rejected; a lone stamp more than ``jump_horizon_s`` ahead is dropped and
counted; a confirmed jump forward or back on any input (a looped or repeated replay, a clock
reset) restarts the alignment, what in the filters depends on time (yaw states, the wheel
acceleration filter, timers) and the output timing from the new time line, keeping the learned
offsets and the calibration, and the status says so until every tire known before is known
again.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from tpms_ros.core.tires import N_TIRES, TIRE_NAMES
from tpms_ros.core.wheel_radius_analysis import (
    PAIR_NAMES,
    RadiusEstimate,
    WheelRadiusAnalyzer,
    WheelRadiusParams,
)
from tpms_ros.processing.calibrating_tpms import (
    INDICATION_TYPE,
    CalibratingTpmsParams,
    CalibratingTpmsProcessor,
    from_parameters,
)
from tpms_ros.processing.vehicle_inputs import (
    DRIVER_INPUTS,
    IMU,
    VEHICLE_INPUTS,
    WHEEL_SPEEDS,
    wheel_torques,
)
from tpms_ros.processing.wheel_speeds import decode_wheel_speeds
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.processing import (
    Output,
    ParameterGroup,
    ProcessorSpec,
    Status,
    header_stamp_ns,
)
from vehicle_monitor_common.status_report import NewSinceLastStatus, StatusProblems

RADIUS = 'tpms/wheel_radius'
_TOPICS = {'wheel_speeds': WHEEL_SPEEDS, 'imu': IMU, 'driver_inputs': DRIVER_INPUTS}
# core order delta_13, delta_24, delta_34, delta_12 -> message order delta_13, delta_24,
# delta_12, delta_34
_MSG_ORDER = [0, 1, 3, 2]
# a wheel buffer never holds more than this much wheel-speed time (IMU silent), ns
_WHEEL_HORIZON_NS = 2_000_000_000
# below this median wheel speed the plausibility check is off (a stopping car), rad/s
_PLAUSIBLE_MIN_RAD_S = 1.0

Row = tuple[float, np.ndarray, float, float, np.ndarray]   # t, omega, yaw, steer, torque


@dataclass(frozen=True)
class WheelRadiusAnalyzerNodeParams(CalibratingTpmsParams):
    """Node-only parameters of wheel_radius_analyzer (the method's own: WheelRadiusParams)."""

    max_latency_s: float = param(0.2, 'an IMU sample waits at most this long (IMU time) for '
                                 'the wheel speeds of its bin, s', low=0.0, high=10.0)
    max_input_age_s: float = param(0.1, 'a driver input older than this at a bin is stale, s',
                                   low=1e-3, high=10.0)
    validity_hold_s: float = param(1.0, 'longitudinal_valid / lateral_valid: a filter updated '
                                   'within this long, s', low=0.01, high=600.0)
    stuck_s: float = param(0.1, 'a wheel speed repeated exactly this long is a stuck or dead '
                           'sensor (the wheel is bad until it changes; all four at 0 is '
                           'standstill), s', low=0.001, high=60.0)
    max_wheel_deviation: float = param(0.3, "a wheel whose bin mean is off the median of the "
                                       'four by more than this fraction is a broken sensor '
                                       '(bad for that bin)', low=0.01, high=10.0)
    publish_rate_hz: float = param(10.0, 'highest output rate (in data time), Hz', low=0.01,
                                   high=1000.0)
    process_period_s: float = param(0.1, 'aligned bins go to the core in chunks of this much '
                                    'IMU time, or sooner when an output falls due, s (no '
                                    'effect on the result; per-call overhead)', low=0.0,
                                    high=10.0)


class WheelRadiusAnalyzerProcessor(
        CalibratingTpmsProcessor[WheelRadiusParams, WheelRadiusAnalyzerNodeParams,
                                 WheelRadiusAnalyzer]):
    """What the wheel-radius analyzer does with its inputs (see the module docstring): the
    three streams aligned into bins for the core, which its node parameters set with output
    timing, time checks, fault detection and calibration (arguments as
    :class:`CalibratingTpmsProcessor`'s, without the method name and core)."""

    inputs = VEHICLE_INPUTS
    outputs = {RADIUS: 'vehicle_monitor_msgs/msg/WheelRadiusOffsets',
               'tpms/indication/wheel_radius': INDICATION_TYPE}

    def __init__(self, params: WheelRadiusParams, node_params: WheelRadiusAnalyzerNodeParams,
                 calibration_file: str = '') -> None:
        super().__init__('wheel_radius', params, node_params, WheelRadiusAnalyzer,
                         calibration_file)
        self._bin_ns = round(1e9 / params.sample_rate_hz)
        # stream checks: order and time jumps (the core handles gaps between bins)
        self._checks = {topic: StampCheck(max_gap_s=math.inf,
                                          jump_horizon_s=node_params.jump_horizon_s)
                        for topic in _TOPICS}
        # (stamp, speeds, stuck per wheel) of the wheel speeds not binned yet: tuples, as
        # decoded (a numpy array per 1 kHz sample cost more than the binning)
        self._wheels: deque[tuple[int, tuple[float, ...], tuple[bool, ...]]] = deque()
        self._imu: deque[tuple[int, float]] = deque()
        self._pending: list[Row] = []         # aligned bins waiting for the core
        self._driver: deque[tuple[int, float, np.ndarray]] = deque()
        self._last_bin_end: int | None = None
        # wrong_size: driver inputs; malformed: wheel-speed payloads
        self.counts = dict.fromkeys(('wrong_size', 'malformed', 'empty_bins',
                                     'stale_driver_inputs', 'skipped_imu_samples', 'bins',
                                     'stuck_wheel_bins', 'implausible_wheel_bins',
                                     'rate_bursts'), 0)
        self._samples_per_bin = 0.0
        self._bins_seen = 0
        self.received = dict.fromkeys(_TOPICS, 0)
        self._handlers = {WHEEL_SPEEDS: self._on_wheel_speeds, IMU: self._on_imu,
                          DRIVER_INPUTS: self._on_driver_inputs}
        self._rates = {topic: RateMeter() for topic in _TOPICS}
        self._last_trace: np.ndarray | None = None
        self._last_long_update = -math.inf
        self._last_lat_update = -math.inf
        self._gyro_ok = True
        # stuck detection per wheel: last value and the stamp since which it reads it
        self._last_value: tuple[float, ...] = (math.nan,) * N_TIRES
        self._value_since_ns = [0] * N_TIRES
        self._fault_kind = [''] * N_TIRES                 # last fault per wheel, for the status
        self._new_rejections = NewSinceLastStatus()
        self._events_at_status: dict[str, int] = {}

    # -- inputs --------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message (the wheel speeds as CDR bytes); the outputs it makes due."""
        return self._handlers[topic](message)

    def _accept(self, topic: str, ns: int) -> tuple[int | None, list[Output]]:
        """The stamp if it is accepted (after a confirmed time jump everything restarts)."""
        self.received[topic] += 1
        self._rates[topic].tick()
        verdict = self._checks[topic].check(ns)
        if verdict == 'jump':
            return ns, self._restart(self._checks[topic].last_jump_s)
        return (ns if verdict in ('ok', 'gap') else None), []

    def _restart(self, jump_s: float) -> list[Output]:
        """A confirmed time jump on one input: what the old time line still holds goes to the
        core, then alignment, filters and output timing restart (calibration kept); the other
        inputs follow the new time line (their next stamps are accepted as it)."""
        outputs = self._process(self._pending) if self._pending else []
        self._pending = []
        self._wheels.clear()
        self._imu.clear()
        self._driver.clear()
        self._last_bin_end = None
        self._last_trace = None
        self._last_long_update = self._last_lat_update = -math.inf
        self.core.restart_time()
        self._note_jump(jump_s)
        for check in self._checks.values():
            check.last_ns = None
        return outputs

    def _on_wheel_speeds(self, data: bytes) -> list[Output]:
        try:
            stamp, speeds = decode_wheel_speeds(data)
        except ValueError:
            self.received['wheel_speeds'] += 1
            self.counts['malformed'] += 1
            return []
        ns, outputs = self._accept('wheel_speeds', stamp)
        if ns is None:
            return outputs
        self._wheels.append((ns, speeds, self._follow_stuck(ns, speeds)))
        while self._wheels and self._wheels[0][0] < ns - _WHEEL_HORIZON_NS:
            self._wheels.popleft()
        return outputs + self._drain()

    def _follow_stuck(self, stamp: int, speeds: tuple[float, ...]) -> tuple[bool, ...]:
        """Per wheel: has read the exact same value for ``stuck_s`` (dead or stuck sensor;
        all four at 0 is standstill, not a fault). Plain Python: it runs per 1 kHz sample."""
        since, last = self._value_since_ns, self._last_value
        for w in range(N_TIRES):
            if speeds[w] != last[w]:
                since[w] = stamp
        self._last_value = speeds
        limit = stamp - self.node_params.stuck_s * 1e9
        if not any(speeds):
            return (False,) * N_TIRES
        return tuple(t <= limit for t in since)

    def _on_imu(self, msg: Any) -> list[Output]:
        ns, outputs = self._accept('imu', header_stamp_ns(msg))
        if ns is None:
            return outputs
        # a NaN yaw rate goes through: the core counts it and skips the gyro update
        self._imu.append((ns, float(msg.angular_velocity.z)))
        return outputs + self._drain()

    def _on_driver_inputs(self, msg: Any) -> list[Output]:
        torque = wheel_torques(msg)
        if torque is None:
            self.received['driver_inputs'] += 1
            self.counts['wrong_size'] += 1
            return []
        ns, outputs = self._accept('driver_inputs', header_stamp_ns(msg))
        if ns is None:
            return outputs
        self._driver.append((ns, float(msg.steering_angle), torque))
        return outputs + self._drain()

    # -- alignment -----------------------------------------------------------------------------

    def _drain(self) -> list[Output]:
        """Close every IMU bin whose wheel speeds and driver input are in (or waited long
        enough)."""
        if not self._imu:
            return []
        newest_wheel = self._wheels[-1][0] if self._wheels else None
        newest_driver = self._driver[-1][0] if self._driver else None
        newest_imu = self._imu[-1][0]
        latency_ns = int(self.node_params.max_latency_s * 1e9)
        outputs: list[Output] = []
        while self._imu:
            t_k, yaw = self._imu[0]
            # Complete once every input has passed t_k: what a bin holds must not depend on
            # the order the topics arrive in (the live graph's delivery).
            complete = (newest_wheel is not None and newest_wheel >= t_k
                        and newest_driver is not None and newest_driver >= t_k)
            if not complete and newest_imu - t_k <= latency_ns:
                break
            self._imu.popleft()
            if self._last_bin_end is not None and t_k - self._last_bin_end < 0.75 * self._bin_ns:
                self.counts['skipped_imu_samples'] += 1
                continue
            start = t_k - self._bin_ns if self._last_bin_end is None else \
                max(self._last_bin_end, t_k - self._bin_ns)
            self._last_bin_end = t_k
            self._pending.append(
                (t_k * 1e-9, self._bin_mean(start, t_k), yaw, *self._driver_at(t_k)))
            # Due or not is decided bin by bin, not for the bins one message closes together.
            outputs += self._process_if_due()
        return outputs

    def _process_if_due(self) -> list[Output]:
        """Process the pending bins when a chunk is full or an output falls due (soon)."""
        n = self.node_params
        first_s, last_s = self._pending[0][0], self._pending[-1][0]
        if self._last_publish_s == -math.inf:
            # The first bin is answered at once, or output_phase_s later.
            self._last_publish_s = first_s - 1.0 / n.publish_rate_hz + n.output_phase_s
        to_output_s = self._last_publish_s + 1.0 / n.publish_rate_hz - last_s
        if (last_s - first_s >= n.process_period_s - 1e-9 or to_output_s <= 1e-9
                or self._ahead.due(to_output_s, n.process_ahead_s)):
            pending, self._pending = self._pending, []
            return self._process(pending)
        return []

    def _bin_mean(self, start: int, end: int) -> np.ndarray:
        """Mean wheel speeds stamped in (start, end]; NaN for a wheel with a bad sample (see
        the module docstring)."""
        while self._wheels and self._wheels[0][0] <= start:
            self._wheels.popleft()
        samples, stuck_rows = [], []
        while self._wheels and self._wheels[0][0] <= end:
            _, omega, stuck_now = self._wheels.popleft()
            samples.append(omega)
            stuck_rows.append(stuck_now)
        self.counts['bins'] += 1
        if not samples:
            self.counts['empty_bins'] += 1
            return np.full(N_TIRES, np.nan)
        if not any(map(any, stuck_rows)) and all(map(self._plain, samples)):
            # the usual bin: no wheel to flag, the mean as below
            self._track_rate(len(samples))
            return np.array(samples).mean(axis=0)
        stuck = np.array(stuck_rows).any(axis=0)
        block = np.array(samples)
        with np.errstate(invalid='ignore'):
            limit = self.params.max_wheel_speed_rad_s
            invalid = ~np.isfinite(block) | (block < 0.0) | (block > limit)
            # per sample: a wheel off the median of the four (a dead or broken sensor; the
            # first such sample already, so no bin mixes it in)
            median = np.median(block, axis=1, keepdims=True)
            implausible = ~invalid & (median > _PLAUSIBLE_MIN_RAD_S) & (
                np.abs(block - median) > self.node_params.max_wheel_deviation * median)
        bad = invalid.any(axis=0)
        off = implausible.any(axis=0) & ~bad
        for w in np.flatnonzero(bad):
            self._fault_kind[w] = 'invalid'
        for w in np.flatnonzero(stuck & ~bad):
            self._fault_kind[w] = 'stuck or dead'
        for w in np.flatnonzero(off & ~stuck):
            self._fault_kind[w] = 'implausible'
        self.counts['stuck_wheel_bins'] += int(stuck.any())
        self.counts['implausible_wheel_bins'] += int(off.any())
        self._track_rate(len(samples))
        return np.where(bad | stuck | off, np.nan, block.mean(axis=0))

    def _plain(self, speeds: tuple[float, ...]) -> bool:
        """No wheel of one sample is invalid or implausible, as :meth:`_bin_mean` judges them
        on the bin's array (per sample in plain Python: ten numpy operations a bin cost three
        times as much when, as almost always, nothing is flagged)."""
        if not all(map(math.isfinite, speeds)):
            return False
        low, mid_low, mid_high, high = sorted(speeds)
        if low < 0.0 or high > self.params.max_wheel_speed_rad_s:
            return False
        # the farthest wheels from the median are the extremes (|w - median|, exactly)
        median = 0.5 * (mid_low + mid_high)
        limit = self.node_params.max_wheel_deviation * median
        return not (median > _PLAUSIBLE_MIN_RAD_S
                    and (median - low > limit or high - median > limit))

    def _track_rate(self, samples: int) -> None:
        """Wheel-speed samples per bin against their running mean: a burst (3 times as many)
        is counted and reported (the bin means are unaffected; the rate is the sensor's)."""
        self._bins_seen += 1
        if self._bins_seen > 100 and samples > 3.0 * self._samples_per_bin:
            self.counts['rate_bursts'] += 1
        else:   # the running mean (over the first 100 bins, then exponential)
            self._samples_per_bin += ((samples - self._samples_per_bin)
                                      / min(self._bins_seen, 100))

    def _driver_at(self, t_k: int) -> tuple[float, np.ndarray]:
        """Steering angle and torques of the newest driver input not newer than t_k."""
        while len(self._driver) > 1 and self._driver[1][0] <= t_k:
            self._driver.popleft()
        if self._driver and self._driver[0][0] <= t_k and \
                t_k - self._driver[0][0] <= self.node_params.max_input_age_s * 1e9:
            _, steer, torque = self._driver[0]
            return steer, torque
        self.counts['stale_driver_inputs'] += 1
        return math.nan, np.full(N_TIRES, np.nan)

    # -- processing and output -----------------------------------------------------------------

    def _process(self, rows: list[Row]) -> list[Output]:
        stamps = np.array([r[0] for r in rows])
        omega = np.vstack([r[1] for r in rows])
        yaw = np.array([r[2] for r in rows])
        steer = np.array([r[3] for r in rows])
        torque = np.vstack([r[4] for r in rows])
        self._calibration.before_chunk()
        estimate = self.core.process(stamps, omega, yaw, torque, steer)
        self._gyro_ok = estimate.gyro_ok
        if estimate.trace.shape[0]:
            self._track_updates(estimate.trace_stamps, estimate.trace)
            self._calibration_event(float(estimate.trace_stamps[0]),
                                    float(estimate.trace_stamps[-1]))
        last_s = float(stamps[-1])
        self._last_stamp_s = last_s
        if last_s - self._last_publish_s >= 1.0 / self.node_params.publish_rate_hz - 1e-9:
            return self._outputs(estimate, rows[-1][0])
        return []

    def _track_updates(self, stamps: np.ndarray, trace: np.ndarray) -> None:
        """A filter was updated where its states moved (a predict alone leaves x unchanged)."""
        previous = trace[0] if self._last_trace is None else self._last_trace
        moved = np.diff(np.vstack([previous, trace]), axis=0) != 0.0
        long_rows = np.flatnonzero(moved[:, :2].any(axis=1))
        lat_rows = np.flatnonzero(moved[:, 2:].any(axis=1))
        if long_rows.size:
            self._last_long_update = float(stamps[long_rows[-1]])
        if lat_rows.size:
            self._last_lat_update = float(stamps[lat_rows[-1]])
        self._last_trace = trace[-1].copy()

    def _outputs(self, estimate: RadiusEstimate, stamp_s: float) -> list[Output]:
        n = self.node_params
        self._last_publish_s = stamp_s
        self._ahead.published()
        stamp = round(stamp_s * 1e9)
        cal = self.core.calibration
        offsets = estimate.offsets[_MSG_ORDER].tolist()
        radius: dict[str, Any] = dict(zip(('delta_13', 'delta_24', 'delta_12', 'delta_34'),
                                          offsets, strict=True))
        radius['gyro_offset'] = float(estimate.gyro_offset)
        radius['nominal'] = (cal.nominal_offsets[_MSG_ORDER].tolist() if cal is not None
                             else [math.nan] * 4)
        radius['std_dev'] = estimate.offsets_std[_MSG_ORDER].tolist()
        radius['longitudinal_valid'] = stamp_s - self._last_long_update <= n.validity_hold_s
        radius['lateral_valid'] = (stamp_s - self._last_lat_update <= n.validity_hold_s
                                   and estimate.gyro_ok)
        radius['calibrated'] = cal is not None
        indication = self.core.indication(stamp_s)
        return [Output(RADIUS, stamp, radius),
                self._indication_output(stamp, indication, indication.known)]

    # -- status ----------------------------------------------------------------------------------

    def bad_wheels(self) -> np.ndarray:
        """Per wheel: bad within ``wheel_recover_s`` of the latest processed bin (unknown)."""
        last_bad = self.core.last_bad_wheel_s()
        return self._last_stamp_s - last_bad < self.params.wheel_recover_s

    def status(self, now_ns: int) -> Status:
        """Health: inputs, rejections, sensor faults, gyro, calibration, tires."""
        rates = {topic: meter.read(now_ns) for topic, meter in self._rates.items()}
        core_cal = self.core.calibration
        counts = self.core.counts
        values: dict[str, Any] = {f'input_rate_hz.{t}': r for t, r in rates.items()}
        values.update({f'received.{t}': n for t, n in self.received.items()})
        rejected: dict[str, int] = {}
        for topic, check in self._checks.items():
            for reason in ('out_of_order', 'repeated', 'future_stamp'):
                rejected[f'{reason}.{topic}'] = check.rejected.get(reason, 0)
        rejected['wrong_size'] = self.counts['wrong_size']        # driver inputs
        rejected['malformed'] = self.counts['malformed']          # wheel speeds
        values.update({f'rejected_{k}': v for k, v in rejected.items()})
        for key in ('bad_wheel_speed', 'bad_torque', 'bad_gyro', 'gyro_stuck', 'gap',
                    'long_gated', 'lat_gated', 'accepted'):
            values[f'core.{key}'] = counts[key]
        for key in ('bins', 'empty_bins', 'stale_driver_inputs', 'skipped_imu_samples',
                    'stuck_wheel_bins', 'implausible_wheel_bins', 'rate_bursts'):
            values[key] = self.counts[key]
        values['wheel_samples_per_bin'] = self._samples_per_bin
        received = any(self.received.values())
        values['gyro_ok'] = self._gyro_ok
        tire_values, tire_problems = self._tire_status(received)
        values.update(tire_values)
        if core_cal is not None:
            # the calibration's coloured-noise factor on each pair's std (1: white as assumed)
            values.update({f'noise_scale.{name}': float(v) for name, v in
                           zip(PAIR_NAMES, core_cal.noise_scale, strict=True)})
        # every problem is listed; the worst sets the level
        problems = StatusProblems()
        bad = self.bad_wheels() if received else np.zeros(N_TIRES, dtype=bool)
        if bad.any():
            names = ', '.join(f'{TIRE_NAMES[w]} ({self._fault_kind[w] or "invalid"})'
                              for w in np.flatnonzero(bad))
            problems.error(f'bad wheel speeds: {names}; filters frozen, tires unknown')
        if received and not self._gyro_ok:
            problems.warn('gyro stopped: lateral filter paused')
        events = {'bad_gyro': counts['bad_gyro'], 'bad_torque': counts['bad_torque'],
                  'rate_bursts': self.counts['rate_bursts']}
        recent_events = {k: v - self._events_at_status.get(k, 0) for k, v in events.items()}
        self._events_at_status = events
        if recent_events['bad_gyro']:
            problems.warn(f"{recent_events['bad_gyro']} non-finite yaw rates: gyro updates "
                          'skipped')
        if recent_events['bad_torque']:
            problems.warn(f"{recent_events['bad_torque']} non-finite wheel torques: "
                          'longitudinal updates skipped')
        if recent_events['rate_bursts']:
            problems.warn(f"wheel-speed rate bursts in {recent_events['rate_bursts']} bins "
                          f'(over 3 x {self._samples_per_bin:.3g} samples per bin)')
        new_rejections = self._new_rejections.text(rejected)
        if new_rejections:
            problems.warn('messages rejected: ' + new_rejections)
        problems.extend(tire_problems)
        return problems.status(values)


# The node, declared once: the live node (nodes/wheel_radius_analyzer_node.py) and the offline
# engine (make_processor, the registered entry point) build it from this.
SPEC = ProcessorSpec(
    'wheel_radius_analyzer', 'tpms/wheel_radius',
    make=from_parameters(WheelRadiusAnalyzerProcessor),
    groups=(ParameterGroup(WheelRadiusParams, 'set_params'),
            ParameterGroup(WheelRadiusAnalyzerNodeParams, 'set_node_params')))
make_processor = SPEC.make_processor
