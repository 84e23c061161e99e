"""``creep_estimator``: wheel-rail creep factor by augmented-state EKF (SPEC §6) on ROS.

Subscribes, per the ``pattern`` parameter, ``rail/lateral_states`` (RailLateralStates; patterns
A-C) or ``rail/bogie/imu`` + ``rail/body/imu`` (sensor_msgs/Imu; pattern D), and optionally
``rail/track_irregularity`` (TrackIrregularity); publishes ``rail/creep_factor`` (CreepFactor)
for every processed sample, stamped with that sample's stamp, and ``/diagnostics``. The
estimator is :class:`rail_monitor_ros.core.creep_ekf.CreepEkf`.

Time alignment. The *driving* stream is ``rail/lateral_states`` (A-C) or the bogie IMU (D); its
stamp is the sample time. Parts of one sample (the body IMU for D, the track alignment) are
paired with it when their stamps differ by at most ``pair_tolerance_s``. A sample is processed
once it is complete, or as soon as every stream still missing its part has delivered a later
stamp (topics arrive in order, so that part will not come): the sample then goes on without
it. A missing body IMU makes the sample missing (prediction only, counted ``unpaired``); a
missing track sample means the unknown-input mode for that sample. The track stream is waited
for only while it is alive (its last stamp within ``track_max_age_s`` of the sample); beyond,
it is *stale*: reported on /diagnostics, and the filter runs on with the track as process noise.

Why known input when available: with the measured track alignment (the paper's setup) the
yaw creep moment's input is known, which is what makes c observable from bogie and body
motion; without it (unknown-input mode) only pattern A (wheelset states measured) still tracks
c (see the creep_ekf tests and the issue report): patterns B-D then drift.

Bad input: out-of-order or repeated stamps are rejected; non-finite or wrongly sized values are
rejected (the sample becomes a prediction step); a measurement vector frozen (bit-identical)
for ``frozen_s`` is rejected as a dead sensor; a few missing samples (up to ``max_gap_s``) are
bridged by prediction steps; a longer gap resets the filter. All counted on /diagnostics.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, replace
import math
from typing import Any

from builtin_interfaces.msg import Time
import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import CreepFactor, RailLateralStates, TrackIrregularity

from rail_monitor_ros.core.creep_ekf import (
    BOGIES,
    MODELS,
    CreepEkf,
    CreepEkfParams,
    CreepEstimate,
    lateral_states_measurement,
)
from rail_monitor_ros.core.rail_model import OBSERVATION_PATTERNS, RailVehicleParams
from vehicle_monitor_common.input_health import StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    WARN,
    Diagnostics,
    TypedParameters,
    param,
    run_node,
    sensor_subscription,
    stamp_ns,
)

_F = CreepEkfParams()
_V = RailVehicleParams()
_LATERAL_FIELDS = ('wheelset_lateral', 'wheelset_lateral_rate', 'wheelset_yaw',
                   'wheelset_yaw_rate', 'bogie_lateral', 'bogie_lateral_rate', 'bogie_yaw',
                   'bogie_yaw_rate', 'body_lateral', 'body_lateral_rate', 'body_yaw',
                   'body_yaw_rate')
# Vehicle parameters the half car uses (RailVehicleParams field names), all read-only but speed.
_VEHICLE_FIELDS = ('wheelset_mass', 'wheelset_yaw_inertia', 'bogie_mass', 'bogie_yaw_inertia',
                   'body_mass', 'primary_lateral_stiffness', 'primary_yaw_stiffness',
                   'secondary_lateral_stiffness_left', 'secondary_lateral_stiffness_right',
                   'secondary_lateral_damping_left', 'secondary_lateral_damping_right',
                   'anti_yaw_damping_left', 'anti_yaw_damping_right',
                   'longitudinal_creep_coefficient', 'lateral_creep_coefficient',
                   'semi_wheelbase', 'half_gauge', 'conicity', 'wheel_radius', 'speed',
                   'bogie_pivot_semi_spacing')
_FILTER_FIELDS = ('model', 'bogie', 'initial_creep_factor', 'initial_log_creep_std',
                  'creep_walk_std', 'change_drift', 'change_threshold', 'change_log_std',
                  'min_creep_factor', 'max_creep_factor', 'lateral_accel_process_std',
                  'yaw_accel_process_std', 'body_accel_process_std', 'other_bogie_force_std',
                  'other_bogie_moment_std', 'other_bogie_correlation_s', 'track_slope_std',
                  'track_slope_walk', 'initial_track_std', 'displacement_noise',
                  'velocity_noise', 'yaw_noise', 'yaw_rate_noise', 'accel_noise', 'gyro_noise',
                  'track_noise', 'track_rate_noise', 'rediscretize_tolerance',
                  'speed_tolerance', 'gate_sigma', 'divergence_window_s',
                  'divergence_nis_ratio', 'max_outlier_run_s', 'bound_hold_s',
                  'low_adhesion_threshold', 'low_adhesion_hysteresis')


def _ro(default: Any, description: str, low: float | None = None,
        high: float | None = None) -> Any:
    return param(default, description, low=low, high=high, read_only=True)


@dataclass(frozen=True)
class CreepEstimatorParameters:
    """Parameters of the creep_estimator node (filter ones: see CreepEkfParams)."""

    pattern: str = param('C', 'observation pattern: A, B, C (rail/lateral_states) or D (bogie '
                         'and body IMUs)', choices=OBSERVATION_PATTERNS, read_only=True)
    bogie: str = param('front', 'monitored bogie (patterns A-C; the IMUs of D are where they '
                       'are mounted)', choices=BOGIES, read_only=True)
    model: str = param(_F.model, "estimation model: 'end' (one end of the full car: bogie, "
                       "wheelsets, body lateral and yaw) or 'half' (the paper's 7-DOF half car)",
                       choices=MODELS, read_only=True)
    sample_rate_hz: float = _ro(_F.sample_rate_hz, 'rate of the driving topic, Hz', 10.0, 5000.0)
    use_track_input: bool = param(True, 'use rail/track_irregularity when it is published '
                                  '(known-input mode)', read_only=True)
    pair_tolerance_s: float = param(0.002, 'largest stamp difference of parts of one sample, s',
                                    low=0.0, high=1.0)
    track_max_age_s: float = param(0.1, 'the track stream is stale when its last stamp is this '
                                   'much older than the sample, s', low=0.001, high=60.0)
    max_gap_s: float = param(0.5, 'missing samples up to this gap are bridged by prediction; '
                             'a longer gap resets the filter, s', low=0.001, high=60.0)
    frozen_s: float = param(0.02, 'a bit-identical measurement vector for this long is a dead '
                            'sensor and rejected, s', low=0.001, high=60.0)
    max_pending: int = param(200, 'most samples waiting for their parts', low=2, high=100000,
                             read_only=True)
    diagnostics_period_s: float = _ro(1.0, 'period of /diagnostics, s', 0.01, 60.0)
    # Vehicle (estimation model; defaults: Chonan & Tsunashima Table 1).
    wheelset_mass: float = _ro(_V.wheelset_mass, 'mw, kg', 1.0, 1e5)
    wheelset_yaw_inertia: float = _ro(_V.wheelset_yaw_inertia, 'Iw, kg m^2', 1.0, 1e5)
    bogie_mass: float = _ro(_V.bogie_mass, 'mb, kg', 1.0, 1e5)
    bogie_yaw_inertia: float = _ro(_V.bogie_yaw_inertia, 'Ib, kg m^2', 1.0, 1e6)
    body_mass: float = _ro(_V.body_mass, 'mv, body mass carried by one bogie, kg', 1.0, 1e6)
    primary_lateral_stiffness: float = _ro(_V.primary_lateral_stiffness,
                                           'Ky per wheelset, N/m', 1.0, 1e9)
    primary_yaw_stiffness: float = _ro(_V.primary_yaw_stiffness, 'Kp per wheelset, N m/rad',
                                       1.0, 1e9)
    secondary_lateral_stiffness_left: float = _ro(_V.secondary_lateral_stiffness_left,
                                                  'Kylb, N/m', 1.0, 1e9)
    secondary_lateral_stiffness_right: float = _ro(_V.secondary_lateral_stiffness_right,
                                                   'Kyrb, N/m', 1.0, 1e9)
    secondary_lateral_damping_left: float = _ro(_V.secondary_lateral_damping_left,
                                                'Cylb, N s/m', 0.0, 1e8)
    secondary_lateral_damping_right: float = _ro(_V.secondary_lateral_damping_right,
                                                 'Cyrb, N s/m', 0.0, 1e8)
    anti_yaw_damping_left: float = _ro(_V.anti_yaw_damping_left, 'anti-yaw damping, N m s/rad',
                                       0.0, 1e8)
    anti_yaw_damping_right: float = _ro(_V.anti_yaw_damping_right,
                                        'anti-yaw damping, N m s/rad', 0.0, 1e8)
    longitudinal_creep_coefficient: float = _ro(_V.longitudinal_creep_coefficient,
                                                'nominal f11, N', 1.0, 1e9)
    lateral_creep_coefficient: float = _ro(_V.lateral_creep_coefficient, 'nominal f22, N',
                                           1.0, 1e9)
    semi_wheelbase: float = _ro(_V.semi_wheelbase, 'a0, m', 0.1, 10.0)
    half_gauge: float = _ro(_V.half_gauge, 'l0, m', 0.1, 2.0)
    conicity: float = _ro(_V.conicity, 'effective conicity lambda', 1e-3, 1.0)
    wheel_radius: float = _ro(_V.wheel_radius, 'r0, m', 0.1, 2.0)
    speed: float = param(_V.speed, 'forward speed, m/s (no speed topic in the contract: set it '
                         'at runtime; the model is rebuilt)', low=1.0, high=150.0)
    bogie_pivot_semi_spacing: float = _ro(_V.bogie_pivot_semi_spacing, 'lv, body centre to '
                                          'bogie centre (body measured above the bogie), m',
                                          0.1, 50.0)
    # Filter.
    initial_creep_factor: float = _ro(_F.initial_creep_factor, 'c at start and after a reset',
                                      0.01, 2.0)
    initial_log_creep_std: float = _ro(_F.initial_log_creep_std, 'initial std of ln c',
                                       1e-4, 10.0)
    creep_walk_std: float = _ro(_F.creep_walk_std, 'random walk of ln c between detected '
                                'changes, 1/sqrt(s)', 1e-6, 10.0)
    change_drift: float = _ro(_F.change_drift, 'CUSUM drift per sample, std of the ln c '
                              'correction', 1e-4, 10.0)
    change_threshold: float = _ro(_F.change_threshold, 'CUSUM alarm level, same units',
                                  1e-3, 1e6)
    change_log_std: float = _ro(_F.change_log_std, 'std added to ln c on a detected change',
                                1e-4, 10.0)
    min_creep_factor: float = _ro(_F.min_creep_factor, 'lower bound of c', 1e-3, 2.0)
    max_creep_factor: float = _ro(_F.max_creep_factor, 'upper bound of c', 1e-3, 2.0)
    lateral_accel_process_std: float = _ro(_F.lateral_accel_process_std, 'model error on '
                                           'wheelsets and bogie, m/s^2', 1e-6, 100.0)
    yaw_accel_process_std: float = _ro(_F.yaw_accel_process_std, 'model error on yaw, rad/s^2',
                                       1e-6, 100.0)
    body_accel_process_std: float = _ro(_F.body_accel_process_std, 'model error on the body, '
                                        'm/s^2', 1e-6, 100.0)
    other_bogie_force_std: float = _ro(_F.other_bogie_force_std, "end model: std of the other "
                                       "bogie's lateral force beyond a still bogie, N",
                                       1e-3, 1e7)
    other_bogie_moment_std: float = _ro(_F.other_bogie_moment_std, "end model: std of the "
                                        "other bogie's anti-yaw moment, N m", 1e-3, 1e7)
    other_bogie_correlation_s: float = _ro(_F.other_bogie_correlation_s, 'end model: their '
                                           'correlation time, s', 1e-4, 100.0)
    track_slope_std: float = _ro(_F.track_slope_std, 'std of the track alignment slope, rad',
                                 1e-7, 0.1)
    track_slope_walk: float = _ro(_F.track_slope_walk, 'random walk of the track slope along '
                                  'the track, rad/sqrt(m)', 1e-8, 0.1)
    initial_track_std: float = _ro(_F.initial_track_std, 'initial std of the track states, m',
                                   1e-6, 1.0)
    displacement_noise: float = _ro(_F.displacement_noise, 'lateral displacement noise, m',
                                    1e-7, 1.0)
    velocity_noise: float = _ro(_F.velocity_noise, 'lateral velocity noise, m/s', 1e-7, 10.0)
    yaw_noise: float = _ro(_F.yaw_noise, 'yaw angle noise, rad', 1e-8, 1.0)
    yaw_rate_noise: float = _ro(_F.yaw_rate_noise, 'yaw rate noise (states), rad/s', 1e-8, 10.0)
    accel_noise: float = _ro(_F.accel_noise, 'accelerometer noise, m/s^2', 1e-6, 100.0)
    gyro_noise: float = _ro(_F.gyro_noise, 'gyro noise, rad/s', 1e-8, 10.0)
    track_noise: float = _ro(_F.track_noise, 'track alignment measurement noise, m', 1e-7, 1.0)
    track_rate_noise: float = _ro(_F.track_rate_noise, 'track alignment rate measurement '
                                  'noise, m/s', 1e-7, 10.0)
    rediscretize_tolerance: float = _ro(_F.rediscretize_tolerance, 'grid of cached '
                                        'discretisations in ln c', 1e-5, 0.5)
    speed_tolerance: float = _ro(_F.speed_tolerance, 'speed change that rebuilds the model, '
                                 'm/s', 1e-4, 10.0)
    gate_sigma: float = _ro(_F.gate_sigma, 'outlier gate, innovation standard deviations',
                            1.0, 1e3)
    divergence_window_s: float = _ro(_F.divergence_window_s, 'averaging time of the innovation '
                                     'consistency test, s', 0.01, 600.0)
    divergence_nis_ratio: float = _ro(_F.divergence_nis_ratio, 'averaged NIS per channel that '
                                      'declares divergence', 1.0, 1e6)
    max_outlier_run_s: float = _ro(_F.max_outlier_run_s, 'consecutive outliers that declare '
                                   'divergence, s', 0.001, 600.0)
    bound_hold_s: float = _ro(_F.bound_hold_s, 'time pinned at a bound that declares '
                              'divergence, s', 0.001, 600.0)
    low_adhesion_threshold: float = param(_F.low_adhesion_threshold, 'low_adhesion turns on '
                                          'below this c', low=0.01, high=2.0)
    low_adhesion_hysteresis: float = param(_F.low_adhesion_hysteresis, 'and off above threshold '
                                           '+ this', low=0.0, high=1.0)

    def __post_init__(self) -> None:
        self.core()      # the core's own rules (bounds, positive values)

    def core(self) -> CreepEkfParams:
        """The core's parameters (raises ValueError on an inconsistent set)."""
        vehicle = RailVehicleParams(**{name: float(getattr(self, name))
                                       for name in _VEHICLE_FIELDS})
        return CreepEkfParams(vehicle=vehicle, pattern=self.pattern,
                              sample_rate_hz=self.sample_rate_hz,
                              **{name: getattr(self, name) for name in _FILTER_FIELDS})


@dataclass
class _Pending:
    """One sample being assembled from its streams."""

    stamp: int
    main: np.ndarray | None = None
    body: float | None = None
    track: np.ndarray | None = None
    track_bad: str = ''


class CreepEstimatorNode(Node):
    """Wraps :class:`CreepEkf` with ROS topics, sample assembly and diagnostics."""

    def __init__(self, node_name: str = 'creep_estimator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, CreepEstimatorParameters, on_change=self._on_change)
        p = self._typed.value
        self._ekf = CreepEkf(p.core())
        self._period_ns = round(1e9 / p.sample_rate_hz)
        self._bogie_index = BOGIES.index(p.bogie)
        self._pending: list[_Pending] = []
        self._latest = {'main': -1, 'body': -1, 'track': -1}
        self._stamps = StampCheck(max_gap_s=p.max_gap_s)
        self._last_processed_ns: int | None = None
        self._last_vector: np.ndarray | None = None
        self._frozen_run = 0
        self._counts = dict.fromkeys(
            ('received', 'processed', 'published', 'predicted_missing', 'unpaired',
             'frozen', 'wrong_size', 'gap_resets', 'overflow', 'known_input', 'unknown_input',
             'track_received', 'track_wrong_size', 'main_late', 'body_late', 'track_late'),
            0)
        self._rate_count = 0
        self._rate_since_ns = self.get_clock().now().nanoseconds
        self._last: CreepEstimate | None = None
        self._track_stale = True

        self._publisher = self.create_publisher(CreepFactor, 'rail/creep_factor', OUTPUT_QOS)
        if p.pattern == 'D':
            sensor_subscription(self, Imu, 'rail/bogie/imu', self._on_bogie_imu)
            sensor_subscription(self, Imu, 'rail/body/imu', self._on_body_imu)
        else:
            sensor_subscription(self, RailLateralStates, 'rail/lateral_states',
                                self._on_lateral_states)
        if p.use_track_input:
            sensor_subscription(self, TrackIrregularity, 'rail/track_irregularity', self._on_track)
        self._diagnostics = Diagnostics(self, f'rail/creep/{p.bogie}', p.diagnostics_period_s,
                                        update=self._update_diagnostics)
        self._update_diagnostics()

    @property
    def parameters(self) -> CreepEstimatorParameters:
        """The current, validated parameters."""
        return self._typed.value

    @property
    def estimator(self) -> CreepEkf:
        """The core filter (read access for tests and tools)."""
        return self._ekf

    @property
    def counts(self) -> dict[str, int]:
        """Node-level counters (input, pairing, rejections); core ones: ``estimator``."""
        return dict(self._counts)

    def _on_change(self, p: CreepEstimatorParameters) -> None:
        # Only speed, the low-adhesion flag and the node's timing can change at runtime.
        self._ekf.params = replace(self._ekf.params,
                                   low_adhesion_threshold=p.low_adhesion_threshold,
                                   low_adhesion_hysteresis=p.low_adhesion_hysteresis)
        self._ekf.set_speed(p.speed)
        self._stamps.max_gap_s = p.max_gap_s

    # -- input ---------------------------------------------------------------------------------

    def _on_lateral_states(self, msg: RailLateralStates) -> None:
        self._counts['received'] += 1
        self._rate_count += 1
        try:
            fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                      for name in _LATERAL_FIELDS}
            vector = lateral_states_measurement(
                fields, self.parameters.pattern, self.parameters.bogie,
                self.parameters.bogie_pivot_semi_spacing, self.parameters.model)[0]
        except (ValueError, IndexError):
            # unreachable over DDS for fixed-size arrays, but an in-process caller can
            self._counts['wrong_size'] += 1
            return
        self._add_part('main', stamp_ns(msg.header.stamp), vector)

    def _on_bogie_imu(self, msg: Imu) -> None:
        self._counts['received'] += 1
        self._rate_count += 1
        vector = np.array([msg.linear_acceleration.y, msg.angular_velocity.z, math.nan])
        self._add_part('main', stamp_ns(msg.header.stamp), vector)

    def _on_body_imu(self, msg: Imu) -> None:
        self._add_part('body', stamp_ns(msg.header.stamp), float(msg.linear_acceleration.y))

    def _on_track(self, msg: TrackIrregularity) -> None:
        self._counts['track_received'] += 1
        j = self._bogie_index
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < 2 * j + 2:
            self._counts['track_wrong_size'] += 1
            return
        part = alignment[2 * j:2 * j + 2]
        if rate.size == alignment.size:
            # With its rate the filter's track states follow the track within the sample.
            part = np.concatenate([part, rate[2 * j:2 * j + 2]])
        self._add_part('track', stamp_ns(msg.header.stamp), part)

    def _add_part(self, kind: str, stamp: int, value: Any) -> None:
        if stamp <= self._latest[kind]:
            # Out of order or repeated on this stream.
            if kind == 'main':
                self._stamps.check(stamp)        # counts the reason
            return
        self._latest[kind] = stamp
        if self._last_processed_ns is not None and stamp < self._last_processed_ns:
            # A part of a sample already processed without it; the stream is alive though.
            self._counts[f'{kind}_late'] += 1
            return
        entry = self._find(stamp)
        if entry is None:
            entry = _Pending(stamp)
            bisect.insort(self._pending, entry, key=lambda e: e.stamp)
        if kind == 'main':
            entry.main = value
        elif kind == 'body':
            entry.body = value
        else:
            entry.track = value
        self._drain()

    def _find(self, stamp: int) -> _Pending | None:
        tolerance = round(self.parameters.pair_tolerance_s * 1e9)
        for entry in self._pending:
            if abs(entry.stamp - stamp) <= tolerance:
                return entry
        return None

    def _drain(self) -> None:
        """Process pending samples in stamp order while each is complete or final."""
        tolerance = round(self.parameters.pair_tolerance_s * 1e9)
        max_age = round(self.parameters.track_max_age_s * 1e9)
        while self._pending:
            entry = self._pending[0]
            s = entry.stamp
            # A part is settled when present or when its stream is already past this sample.
            main_done = entry.main is not None or self._latest['main'] > s + tolerance
            body_done = (self.parameters.pattern != 'D' or entry.body is not None
                         or self._latest['body'] > s + tolerance)
            track_alive = (self.parameters.use_track_input and self._latest['track'] >= 0
                           and self._latest['track'] >= s - max_age)
            track_done = (not track_alive or entry.track is not None
                          or self._latest['track'] > s + tolerance)
            overflow = len(self._pending) > self.parameters.max_pending
            if not (main_done and body_done and track_done) and not overflow:
                return
            if overflow:
                self._counts['overflow'] += 1
            self._pending.pop(0)
            self._track_stale = not track_alive
            if entry.main is None:
                continue                         # parts without a driving sample: dropped
            self._process(entry)

    # -- processing ----------------------------------------------------------------------------

    def _process(self, entry: _Pending) -> None:
        verdict = self._stamps.check(entry.stamp)
        if verdict in ('repeated', 'out_of_order'):
            return
        assert entry.main is not None
        vector: np.ndarray | None = entry.main
        if self.parameters.pattern == 'D':
            if entry.body is None:
                self._counts['unpaired'] += 1
                vector = None
            else:
                vector = entry.main.copy()
                vector[2] = entry.body
        if verdict == 'gap':
            self._counts['gap_resets'] += 1
            self._ekf.reset()
        elif self._last_processed_ns is not None:
            missing = round((entry.stamp - self._last_processed_ns) / self._period_ns) - 1
            for _ in range(max(0, missing)):
                self._ekf.step(None)             # bridge missing samples by prediction
            self._counts['predicted_missing'] += max(0, missing)
        self._last_processed_ns = entry.stamp
        vector = self._check_frozen(vector)
        self._counts['known_input' if entry.track is not None else 'unknown_input'] += 1
        estimate = self._ekf.step(vector, entry.track)
        self._counts['processed'] += 1
        if estimate.reset:
            self.get_logger().warning(
                f'creep filter diverged ({self._ekf.last_reset_reason}): reset')
        self._last = estimate
        self._publish(entry.stamp, estimate)

    def _check_frozen(self, vector: np.ndarray | None) -> np.ndarray | None:
        if vector is None:
            return None
        if self._last_vector is not None and np.array_equal(vector, self._last_vector):
            self._frozen_run += 1
        else:
            self._frozen_run = 0
        self._last_vector = vector
        if self._frozen_run * self._period_ns * 1e-9 >= self.parameters.frozen_s:
            self._counts['frozen'] += 1
            return None
        return vector

    def _publish(self, stamp: int, estimate: CreepEstimate) -> None:
        msg = CreepFactor()
        sec, nanosec = divmod(stamp, 1_000_000_000)
        msg.header.stamp = Time(sec=sec, nanosec=nanosec)
        msg.header.frame_id = f'{self.parameters.bogie}_bogie'
        msg.creep_factor = estimate.creep_factor
        msg.std_dev = estimate.std_dev
        msg.f11 = estimate.f11
        msg.f22 = estimate.f22
        msg.low_adhesion = estimate.low_adhesion
        self._publisher.publish(msg)
        self._counts['published'] += 1

    # -- diagnostics ---------------------------------------------------------------------------

    def _update_diagnostics(self) -> None:
        now = self.get_clock().now().nanoseconds
        elapsed = (now - self._rate_since_ns) * 1e-9
        rate = self._rate_count / elapsed if elapsed > 0 else 0.0
        self._rate_count, self._rate_since_ns = 0, now
        ekf = self._ekf
        last = self._last
        values: dict[str, Any] = {
            'pattern': self.parameters.pattern,
            'input_rate_hz': rate,
            **self._counts,
            'rejected_out_of_order': self._stamps.rejected.get('out_of_order', 0),
            'rejected_repeated': self._stamps.rejected.get('repeated', 0),
            **{f'rejected_{k}': v for k, v in ekf.rejected.items()},
            'clipped_at_bound': ekf.clipped,
            'changes_detected': ekf.changes_detected,
            **{f'resets_{k}': v for k, v in ekf.resets.items()},
            'discretizations': ekf.discretizations,
            'track_input': 'stale' if self._track_stale else 'known',
            'creep_factor': last.creep_factor if last else math.nan,
            'std_dev': last.std_dev if last else math.nan,
            'low_adhesion': bool(last.low_adhesion) if last else False,
            'model_speed': ekf.speed,
        }
        driving = 'rail/bogie/imu' if self.parameters.pattern == 'D' else 'rail/lateral_states'
        if self._counts['received'] == 0:
            level, message = WARN, f'waiting for {driving}'
        elif rate == 0.0:
            level, message = ERROR, f'{driving} silent'
        elif ekf.resets:
            level, message = WARN, (f'filter reset {sum(ekf.resets.values())} times (last: '
                                    f'{ekf.last_reset_reason})')
        elif self.parameters.use_track_input and self._track_stale:
            level, message = WARN, 'track input stale: unknown-input mode, c less accurate'
        elif last is not None and last.low_adhesion:
            level, message = WARN, f'low adhesion: creep factor {last.creep_factor:.2f}'
        else:
            level, message = OK, 'ok'
        self._diagnostics.set(level, message, values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``creep_estimator`` executable."""
    raise SystemExit(run_node(lambda: CreepEstimatorNode(), args))


if __name__ == '__main__':
    main()
