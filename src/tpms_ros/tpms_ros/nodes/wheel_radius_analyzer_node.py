"""``wheel_radius_analyzer``: TPMS by relative rolling radii (Persson 2002, SPEC §3.2) on ROS.

Subscribes ``vehicle/wheel_speeds`` (WheelSpeeds, ~1 kHz), ``vehicle/imu`` (sensor_msgs/Imu,
``angular_velocity.z`` = yaw rate, REP 103) and ``vehicle/driver_inputs`` (DriverInputs: wheel
torques, steering angle); publishes ``tpms/wheel_radius`` (WheelRadiusOffsets) and
``tpms/indication/wheel_radius`` (TpmsIndication) plus ``/diagnostics``. Service
``~/calibrate`` (std_srvs/Trigger) learns the nominal pair offsets over
``calibration_duration_s`` of data, saved to ``calibration_file`` and reloaded at start.

Time alignment. The core runs at ~100 Hz on synchronised samples. Each IMU sample at t_k closes
a bin (t_prev, t_k] (at most one ``1 / sample_rate_hz`` long; IMU samples closer than 0.75 of
that to the previous bin end are skipped, so a faster IMU is decimated): the wheel speeds
stamped in the bin are averaged, and the driver input used is the newest one stamped at or
before t_k. A bin waits until a wheel speed stamped at or after t_k has arrived (topics arrive
in any order); if none comes within ``max_latency_s`` of IMU time, it is processed with the
wheel speeds it has, or as missing (NaN) if it has none. A wheel whose bin holds a bad sample
(non-finite, negative, above ``max_wheel_speed_rad_s``) is NaN in the bin: the core rejects it and
keeps the tire unknown for ``wheel_recover_s``. A driver input older than ``max_input_age_s``
is stale: the torque becomes NaN (longitudinal filters pause) and the steering angle NaN (the
front-axle lateral measurement pauses). Without the IMU no bin closes: the analysis pauses and
the diagnostics say so (its indication then goes stale at the voter).

Processing: aligned bins go to the core in chunks of ``process_period_s``, where an output falls
due and ``process_ahead_s`` before it (so little work is left for the sample an output answers,
hence a short latency).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import DriverInputs, WheelRadiusOffsets

from tpms_ros.core.tires import N_TIRES
from tpms_ros.core.wheel_radius_analysis import PAIR_NAMES, WheelRadiusAnalyzer, WheelRadiusParams
from tpms_ros.nodes.calibrating_tpms_node import CalibratingTpmsNode
from tpms_ros.nodes.wheel_speed_input import subscribe_wheel_speeds
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    WARN,
    output_phase_param,
    param,
    process_ahead_param,
    run_node,
    sensor_subscription,
    stamp_ns,
    time_msg,
)

# core order delta_13, delta_24, delta_34, delta_12 -> message order delta_13, delta_24,
# delta_12, delta_34
_MSG_ORDER = [0, 1, 3, 2]
# a wheel buffer never holds more than this much wheel-speed time (IMU silent), ns
_WHEEL_HORIZON_NS = 2_000_000_000


@dataclass(frozen=True)
class WheelRadiusAnalyzerNodeParams:
    """Node-only parameters of wheel_radius_analyzer (the method's own: WheelRadiusParams)."""

    max_latency_s: float = param(0.2, 'an IMU sample waits at most this long (IMU time) for '
                                 'the wheel speeds of its bin, s', low=0.0, high=10.0)
    max_input_age_s: float = param(0.1, 'a driver input older than this at a bin is stale, s',
                                   low=1e-3, high=10.0)
    validity_hold_s: float = param(1.0, 'longitudinal_valid / lateral_valid: a filter updated '
                                   'within this long, s', low=0.01, high=600.0)
    publish_rate_hz: float = param(10.0, 'highest output rate (in data time), Hz', low=0.01,
                                   high=1000.0)
    process_period_s: float = param(0.1, 'aligned bins go to the core in chunks of this much '
                                    'IMU time, or sooner when an output falls due, s (no '
                                    'effect on the result; per-call overhead)', low=0.0,
                                    high=10.0)
    process_ahead_s: float = process_ahead_param()
    output_phase_s: float = output_phase_param()
    calibrate_on_start: bool = param(False, 'start a calibration with the first data (only '
                                     'if tire pressures are known to be nominal)')
    calibration_file: str = param('', 'YAML file the calibration is saved to and loaded from '
                                  'at start; empty: not persisted', read_only=True)
    diagnostics_period_s: float = param(1.0, 'period of /diagnostics, s', low=0.01,
                                        high=60.0, read_only=True)


class WheelRadiusAnalyzerNode(CalibratingTpmsNode[WheelRadiusParams,
                                                  WheelRadiusAnalyzerNodeParams,
                                                  WheelRadiusAnalyzer]):
    """Wraps :class:`WheelRadiusAnalyzer` with input alignment, calibration and diagnostics."""

    def __init__(self, node_name: str = 'wheel_radius_analyzer', **kwargs: Any) -> None:
        super().__init__(node_name, 'wheel_radius', WheelRadiusParams,
                         WheelRadiusAnalyzerNodeParams, WheelRadiusAnalyzer, **kwargs)
        self._bin_ns = round(1e9 / self.core_parameters.sample_rate_hz)
        # stream checks: only order matters here (the core handles gaps between bins)
        self._checks = {topic: StampCheck(max_gap_s=math.inf)
                        for topic in ('wheel_speeds', 'imu', 'driver_inputs')}
        self._wheels: deque[tuple[int, np.ndarray]] = deque()
        self._imu: deque[tuple[int, float]] = deque()
        # Aligned bins waiting for the core (see process_period_s).
        self._pending: list[tuple[float, np.ndarray, float, float, np.ndarray]] = []
        self._driver: deque[tuple[int, float, np.ndarray]] = deque()
        self._last_bin_end: int | None = None
        # wrong_size: driver inputs; malformed: wheel-speed payloads
        self._counts = dict.fromkeys(('wrong_size', 'malformed', 'empty_bins',
                                      'stale_driver_inputs', 'skipped_imu_samples', 'bins'), 0)
        self._received = dict.fromkeys(self._checks, 0)
        now = self.get_clock().now().nanoseconds
        self._rates = {topic: RateMeter(since_ns=now) for topic in self._checks}
        self._last_trace: np.ndarray | None = None
        self._last_long_update = -math.inf
        self._last_lat_update = -math.inf
        self._gyro_ok = True

        self._radius_pub = self.create_publisher(WheelRadiusOffsets, 'tpms/wheel_radius',
                                                 OUTPUT_QOS)
        subscribe_wheel_speeds(self, self._on_wheel_speeds, self._on_malformed)
        sensor_subscription(self, Imu, 'vehicle/imu', self._on_imu)
        sensor_subscription(self, DriverInputs, 'vehicle/driver_inputs', self._on_driver_inputs)
        self._start_diagnostics()

    # -- inputs --------------------------------------------------------------------------------

    def _accept(self, topic: str, ns: int) -> int | None:
        self._received[topic] += 1
        self._rates[topic].tick()
        return ns if self._checks[topic].check(ns) in ('ok', 'gap') else None

    def _on_malformed(self, _: str) -> None:
        self._received['wheel_speeds'] += 1
        self._counts['malformed'] += 1

    def _on_wheel_speeds(self, stamp: int, speeds: tuple[float, ...]) -> None:
        ns = self._accept('wheel_speeds', stamp)
        if ns is None:
            return
        self._wheels.append((ns, np.array(speeds)))
        while self._wheels and self._wheels[0][0] < ns - _WHEEL_HORIZON_NS:
            self._wheels.popleft()
        self._drain()

    def _on_imu(self, msg: Imu) -> None:
        ns = self._accept('imu', stamp_ns(msg.header.stamp))
        if ns is None:
            return
        # a NaN yaw rate goes through: the core counts it and skips the gyro update
        self._imu.append((ns, float(msg.angular_velocity.z)))
        self._drain()

    def _on_driver_inputs(self, msg: DriverInputs) -> None:
        torque = np.asarray(msg.wheel_torque, dtype=float)
        if torque.shape != (N_TIRES,):
            self._received['driver_inputs'] += 1
            self._counts['wrong_size'] += 1
            return
        ns = self._accept('driver_inputs', stamp_ns(msg.header.stamp))
        if ns is None:
            return
        self._driver.append((ns, float(msg.steering_angle), torque))

    # -- alignment -----------------------------------------------------------------------------

    def _drain(self) -> None:
        """Close every IMU bin whose wheel speeds are complete (or waited long enough)."""
        if not self._imu:
            return
        p = self.parameters
        newest_wheel = self._wheels[-1][0] if self._wheels else None
        newest_imu = self._imu[-1][0]
        latency_ns = int(p.max_latency_s * 1e9)
        rows: list[tuple[float, np.ndarray, float, float, np.ndarray]] = []
        while self._imu:
            t_k, yaw = self._imu[0]
            complete = newest_wheel is not None and newest_wheel >= t_k
            if not complete and newest_imu - t_k <= latency_ns:
                break
            self._imu.popleft()
            if self._last_bin_end is not None and t_k - self._last_bin_end < 0.75 * self._bin_ns:
                self._counts['skipped_imu_samples'] += 1
                continue
            start = t_k - self._bin_ns if self._last_bin_end is None else \
                max(self._last_bin_end, t_k - self._bin_ns)
            self._last_bin_end = t_k
            rows.append((t_k * 1e-9, self._bin_mean(start, t_k), yaw,
                         *self._driver_at(t_k)))
        self._pending.extend(rows)
        if not self._pending:
            return
        first_s, last_s = self._pending[0][0], self._pending[-1][0]
        if self._last_publish_s == -math.inf:
            # The first bin is answered at once, or output_phase_s later.
            self._last_publish_s = first_s - 1.0 / p.publish_rate_hz + p.output_phase_s
        to_output_s = self._last_publish_s + 1.0 / p.publish_rate_hz - last_s
        if (last_s - first_s >= p.process_period_s - 1e-9 or to_output_s <= 1e-9
                or self._ahead.due(to_output_s, p.process_ahead_s)):
            pending, self._pending = self._pending, []
            self._process(pending)

    def _bin_mean(self, start: int, end: int) -> np.ndarray:
        """Mean wheel speeds stamped in (start, end]; NaN for a wheel with a bad sample."""
        while self._wheels and self._wheels[0][0] <= start:
            self._wheels.popleft()
        samples = []
        while self._wheels and self._wheels[0][0] <= end:
            samples.append(self._wheels.popleft()[1])
        self._counts['bins'] += 1
        if not samples:
            self._counts['empty_bins'] += 1
            return np.full(N_TIRES, np.nan)
        block = np.vstack(samples)
        with np.errstate(invalid='ignore'):
            limit = self.core_parameters.max_wheel_speed_rad_s
            bad = ~np.isfinite(block) | (block < 0.0) | (block > limit)
        return np.where(bad.any(axis=0), np.nan, block.mean(axis=0))

    def _driver_at(self, t_k: int) -> tuple[float, np.ndarray]:
        """Steering angle and torques of the newest driver input not newer than t_k."""
        while len(self._driver) > 1 and self._driver[1][0] <= t_k:
            self._driver.popleft()
        if self._driver and self._driver[0][0] <= t_k and \
                t_k - self._driver[0][0] <= self.parameters.max_input_age_s * 1e9:
            _, steer, torque = self._driver[0]
            return steer, torque
        self._counts['stale_driver_inputs'] += 1
        return math.nan, np.full(N_TIRES, np.nan)

    # -- processing and output -----------------------------------------------------------------

    def _process(self, rows: list[tuple[float, np.ndarray, float, float, np.ndarray]]) -> None:
        stamps = np.array([r[0] for r in rows])
        omega = np.vstack([r[1] for r in rows])
        yaw = np.array([r[2] for r in rows])
        steer = np.array([r[3] for r in rows])
        torque = np.vstack([r[4] for r in rows])
        self._calibration.before_chunk()
        estimate = self._analyzer.process(stamps, omega, yaw, torque, steer)
        self._gyro_ok = estimate.gyro_ok
        if estimate.trace.shape[0]:
            self._track_updates(estimate.trace_stamps, estimate.trace)
            event = self._calibration.update(float(estimate.trace_stamps[0]),
                                             float(estimate.trace_stamps[-1]))
            if event:
                self.get_logger().info(event)
        last_s = float(stamps[-1])
        self._last_stamp_s = last_s
        if last_s - self._last_publish_s >= 1.0 / self.parameters.publish_rate_hz - 1e-9:
            self._publish(estimate, rows[-1][0])

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

    def _publish(self, estimate: Any, stamp_s: float) -> None:
        p = self.parameters
        self._last_publish_s = stamp_s
        self._ahead.published()
        header_stamp = time_msg(round(stamp_s * 1e9))
        cal = self._analyzer.calibration

        radius = WheelRadiusOffsets()
        radius.header.stamp = header_stamp
        offsets = estimate.offsets[_MSG_ORDER]
        radius.delta_13, radius.delta_24, radius.delta_12, radius.delta_34 = offsets.tolist()
        radius.gyro_offset = float(estimate.gyro_offset)
        radius.nominal = (cal.nominal_offsets[_MSG_ORDER].tolist() if cal is not None
                          else [math.nan] * 4)
        radius.std_dev = estimate.offsets_std[_MSG_ORDER].tolist()
        radius.longitudinal_valid = stamp_s - self._last_long_update <= p.validity_hold_s
        radius.lateral_valid = (stamp_s - self._last_lat_update <= p.validity_hold_s
                                and estimate.gyro_ok)
        radius.calibrated = cal is not None
        self._radius_pub.publish(radius)

        indication = self._analyzer.indication(stamp_s)
        self._publish_indication(header_stamp, indication, indication.known)

    # -- diagnostics ---------------------------------------------------------------------------

    def _update_diagnostics(self) -> None:
        now = self.get_clock().now().nanoseconds
        rates = {topic: meter.read(now) for topic, meter in self._rates.items()}
        core_cal = self._analyzer.calibration
        counts = self._analyzer.counts
        values: dict[str, Any] = {f'input_rate_hz.{t}': r for t, r in rates.items()}
        values.update({f'received.{t}': n for t, n in self._received.items()})
        for topic, check in self._checks.items():
            for reason in ('out_of_order', 'repeated'):
                values[f'rejected_{reason}.{topic}'] = check.rejected.get(reason, 0)
        values['rejected_wrong_size'] = self._counts['wrong_size']
        values['rejected_malformed'] = self._counts['malformed']
        for key in ('bad_wheel_speed', 'bad_torque', 'bad_gyro', 'gyro_stuck', 'gap',
                    'long_gated', 'lat_gated', 'accepted'):
            values[f'core.{key}'] = counts[key]
        for key in ('bins', 'empty_bins', 'stale_driver_inputs',
                    'skipped_imu_samples'):
            values[key] = self._counts[key]
        received = any(self._received.values())
        values['gyro_ok'] = self._gyro_ok
        tire_values, tire_problems = self._tire_diagnostics(received)
        values.update(tire_values)
        if core_cal is not None:
            # the calibration's coloured-noise factor on each pair's std (1: white as assumed)
            values.update({f'noise_scale.{name}': float(v) for name, v in
                           zip(PAIR_NAMES, core_cal.noise_scale, strict=True)})
        # every problem is listed; the worst sets the level
        problems: list[tuple[int, str]] = []
        silent = [t for t in ('wheel_speeds', 'imu') if rates[t] == 0.0]
        if not received:
            problems.append((WARN, 'waiting for inputs'))
        elif silent:
            problems.append((ERROR, f'vehicle/{" and vehicle/".join(silent)} silent: analysis '
                                    'paused'))
        if received and not self._gyro_ok:
            problems.append((WARN, 'gyro stopped: lateral filter paused'))
        if received and rates['driver_inputs'] == 0.0:
            problems.append((WARN, 'vehicle/driver_inputs silent: longitudinal filters paused'))
        problems += tire_problems
        level = max((lv for lv, _ in problems), default=OK)
        message = '; '.join(text for _, text in problems) or 'ok'
        self._diagnostics.set(level, message, values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``wheel_radius_analyzer`` executable."""
    raise SystemExit(run_node(WheelRadiusAnalyzerNode, args))


if __name__ == '__main__':
    main()
