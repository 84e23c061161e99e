"""``suspension_monitor``: secondary-suspension fault detection by IMM (SPEC §5) on ROS 2.

Subscribes ``rail/bogie/imu`` (sensor_msgs/Imu: linear_acceleration.y, angular_velocity.z),
``rail/body/imu`` (linear_acceleration.y, the body accelerometer above the monitored front
bogie) and optionally ``rail/track_irregularity`` (TrackIrregularity: wheelsets front to rear,
the monitored bogie's are indices 0 and 1; the full-car model takes the alignment under all
four (or the first two) as measurements of its track model, the half-car model turns the first
two into wheelset inputs); publishes
``rail/suspension/modes`` (ModeProbabilities) and ``/diagnostics``. The estimator is
:class:`rail_monitor_ros.core.suspension_imm.SuspensionImm`; this node converts and checks
messages.

Time alignment:

* The two IMUs are paired by stamp: a bogie and a body sample whose stamps differ by at most
  ``pair_tolerance`` form one measurement, stamped with the bogie sample's stamp (the output
  carries it). Unpaired samples wait up to ``pair_timeout`` (in stamp time, measured against the
  newest stamp seen) and are then dropped and counted ('unpaired': a dead IMU or mismatched
  rates show up here).
* Pairs are processed in stamp order; a pair not newer than the last one is rejected
  ('out_of_order' / 'repeated'). Missing samples shorter than ``max_gap`` are bridged by
  predict-only steps; a longer gap restarts the filter states (mode probabilities kept).
* Creep factor (``rail/creep_factor``, the creep estimator's output; full car): the model
  follows the latest estimate as it arrives (adhesion changes over seconds; re-discretised in
  steps of the core's ``creep_resolution``, 0.1, with hysteresis). Unmodelled, a creep change
  looks like a suspension fault.
* Track irregularity: sample-and-hold of the latest message not newer than the pair's stamp
  (plus ``pair_tolerance``); older than ``track_max_age``, it is stale and the process-noise
  model is used (diagnostics say so).

Bad input (non-finite, saturated, frozen sensor, wrong array sizes) is rejected and counted;
the IMM then only predicts, so no fault is declared from bad data; the diagnostic reports an
input fault instead.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import CreepFactor, ModeProbabilities, TrackIrregularity

from rail_monitor_ros.core.rail_model import (
    MAX_CREEP_FACTOR,
    RailVehicleParams,
    wheelset_inputs_from_track,
)
from rail_monitor_ros.core.suspension_imm import FaultDecision, SuspensionImm, SuspensionImmConfig
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    WARN,
    Diagnostics,
    TypedParameters,
    param,
    sensor_subscription,
    stamp_ns,
)


@dataclass(frozen=True)
class SuspensionMonitorParameters:
    """Parameters of the suspension monitor (see config/suspension_monitor.yaml)."""

    sample_rate: float = param(200.0, 'IMU sample rate, Hz', low=1.0, high=10000.0,
                               read_only=True)
    estimation_model: str = param('full_car', 'IMM model: full_car (14-DOF car driven by the '
                                  'track; body IMU above the front bogie) or half_car (the '
                                  'paper)',
                                  choices=('full_car', 'half_car'), read_only=True)
    spring_start: float = param(1.1, 'first spring-mode ratio', low=0.01, high=5.0,
                                read_only=True)
    spring_stop: float = param(1.7, 'last spring-mode ratio', low=0.01, high=5.0,
                               read_only=True)
    spring_step: float = param(0.1, 'spring-mode ratio step', low=0.001, high=5.0,
                               read_only=True)
    damper_start: float = param(1.0, 'first damper-mode ratio', low=0.01, high=5.0,
                                read_only=True)
    damper_stop: float = param(0.3, 'last damper-mode ratio', low=0.01, high=5.0,
                               read_only=True)
    damper_step: float = param(0.1, 'damper-mode ratio step', low=0.001, high=5.0,
                               read_only=True)
    mean_sojourn_time: float = param(10.0, 'mean time in a mode (sets the Markov matrix), s',
                                     low=0.01, high=1e6, read_only=True)
    probability_floor: float = param(1e-9, 'lower bound of every mode probability',
                                     low=0.0, high=0.009, read_only=True)
    smoothing_window: float = param(0.1, 'moving-average window of the probabilities, s',
                                    low=0.0, high=60.0, read_only=True)
    adaptive: bool = param(True, 'damper modes take the estimated spring ratio (compound '
                           'faults)', read_only=True)
    steady_state_gains: bool = param(True, 'after the warm-up, each mode runs on its '
                                     'steady-state covariance plus the mixing spread (about 8x '
                                     'faster on the full car); false: the exact IMM',
                                     read_only=True)
    warmup_time: float = param(1.0, 'exact IMM cycles after every start of the states, s',
                               low=0.005, high=600.0, read_only=True)
    track_roughness: float = param(2.119e-7, 'full car: track alignment spectrum A_a, m rad',
                                   low=1e-12, high=1e-3, read_only=True)
    track_corner_wavenumber: float = param(0.8246, 'full car: alignment spectrum Omega_c, '
                                           'rad/m', low=1e-4, high=100.0, read_only=True)
    track_long_wavenumber: float = param(0.0206, 'full car: alignment spectrum Omega_r, rad/m',
                                         low=1e-5, high=100.0, read_only=True)
    delay_min_wavelength: float = param(5.0, 'full car: wheelset-to-wheelset delays accurate '
                                        'down to this track wavelength, m', low=0.1,
                                        high=100.0, read_only=True)
    known_track_std: float = param(5e-4, 'full car: measured track alignment std, m',
                                   low=1e-9, high=1.0, read_only=True)
    input_correlation_time: float = param(1.0, 'half car: wheelset motion model slow pole '
                                          '(time constant), s', low=1e-3, high=100.0,
                                          read_only=True)
    input_bandwidth: float = param(3.0, 'half car: wheelset motion model fast pole, Hz', low=0.01,
                                   high=100.0, read_only=True)
    wheelset_lateral_std: float = param(3e-3, 'half car: wheelset lateral std, m', low=1e-9,
                                        high=1.0, read_only=True)
    wheelset_yaw_std: float = param(2e-3, 'half car: wheelset yaw std, rad', low=1e-9, high=1.0,
                                    read_only=True)
    known_input_lateral_std: float = param(1.5e-3, 'half car: wheelset deviation from the '
                                           'track alignment, m', low=1e-9, high=1.0,
                                           read_only=True)
    known_input_yaw_std: float = param(1.5e-3, 'half car: wheelset yaw deviation from '
                                       'alignment rate / speed, rad', low=1e-9, high=1.0,
                                       read_only=True)
    bogie_accel_noise: float = param(0.02, 'bogie lateral accelerometer noise std, m/s^2',
                                     low=1e-9, high=100.0, read_only=True)
    bogie_gyro_noise: float = param(1e-3, 'bogie yaw-rate gyro noise std, rad/s', low=1e-9,
                                    high=10.0, read_only=True)
    body_accel_noise: float = param(0.02, 'body lateral accelerometer noise std, m/s^2',
                                    low=1e-9, high=100.0, read_only=True)
    fault_threshold: float = param(0.6, 'smoothed hypothesis probability to declare or clear '
                                   'a fault', low=0.01, high=0.99)
    hold_time: float = param(0.25, 'time above the threshold before declaring, s', low=0.0,
                             high=600.0)
    speed: float = param(40.0, 'forward speed, m/s (full car: creep forces, track bandwidth '
                         'and delays, re-discretised on change; half car: known inputs)',
                         low=0.1, high=150.0)
    body_mass: float = param(11000.0, 'body mass carried by one bogie (half the body), kg',
                             low=1.0, high=1e6, read_only=True)
    body_yaw_inertia: float = param(RailVehicleParams().body_yaw_inertia, 'body yaw inertia '
                                    '(full car model), kg m^2', low=1.0, high=1e9,
                                    read_only=True)
    bogie_pivot_semi_spacing: float = param(9.5, 'body centre to bogie centre (full car '
                                            'model), m', low=0.1, high=50.0, read_only=True)
    bogie_mass: float = param(2500.0, 'bogie mass, kg', low=1.0, high=1e5, read_only=True)
    bogie_yaw_inertia: float = param(2300.0, 'bogie yaw inertia, kg m^2', low=1.0, high=1e6,
                                     read_only=True)
    primary_lateral_stiffness: float = param(4000e3, 'primary lateral stiffness per wheelset, '
                                             'N/m', low=1.0, high=1e10, read_only=True)
    primary_yaw_stiffness: float = param(2500e3, 'primary yaw stiffness per wheelset, N m/rad',
                                         low=1.0, high=1e10, read_only=True)
    secondary_lateral_stiffness: float = param(1000e3, 'nominal secondary lateral stiffness '
                                               '(both sides), N/m', low=1.0, high=1e10,
                                               read_only=True)
    secondary_lateral_damping: float = param(60e3, 'nominal secondary lateral damping (both '
                                             'sides), N s/m', low=1.0, high=1e9, read_only=True)
    anti_yaw_damping: float = param(1000e3, 'anti-yaw damping (both sides), N m s/rad',
                                    low=0.0, high=1e10, read_only=True)
    semi_wheelbase: float = param(1.05, 'semi-wheelbase a0, m', low=0.01, high=10.0,
                                  read_only=True)
    pair_tolerance: float = param(1e-3, 'largest stamp difference of a bogie/body IMU pair, s',
                                  low=0.0, high=1.0)
    pair_timeout: float = param(0.1, 'an unpaired IMU sample is dropped after this, s',
                                low=1e-3, high=10.0)
    max_gap: float = param(0.5, 'a longer gap between pairs restarts the filter states, s',
                           low=1e-3, high=3600.0)
    use_creep_factor: bool = param(True, 'full car: follow rail/creep_factor (the creep '
                                   'estimator) in the model', read_only=True)
    creep_max_std: float = param(0.2, 'a creep factor estimate with a larger std is not used',
                                 low=1e-6, high=10.0)
    use_track_irregularity: bool = param(True, 'use rail/track_irregularity as known inputs '
                                         'when fresh', read_only=True)
    track_max_age: float = param(0.02, 'older track irregularity is stale, s', low=0.0,
                                 high=10.0)
    accel_limit: float = param(50.0, 'an acceleration at or beyond this is saturated, m/s^2',
                               low=0.1, high=1e4)
    gyro_limit: float = param(5.0, 'a yaw rate at or beyond this is saturated, rad/s',
                              low=0.01, high=1e3)
    frozen_samples: int = param(20, 'this many identical consecutive values = frozen sensor',
                                low=2, high=100000)
    diagnostics_period: float = param(1.0, '/diagnostics period, s', low=0.01, high=60.0,
                                      read_only=True)

    def imm_config(self) -> SuspensionImmConfig:
        """The core's configuration."""
        return SuspensionImmConfig(
            sample_rate=self.sample_rate, estimation_model=self.estimation_model,
            spring_start=self.spring_start,
            spring_stop=self.spring_stop, spring_step=self.spring_step,
            damper_start=self.damper_start, damper_stop=self.damper_stop,
            damper_step=self.damper_step, mean_sojourn_time=self.mean_sojourn_time,
            probability_floor=self.probability_floor,
            smoothing_window=max(self.smoothing_window, 1.0 / self.sample_rate),
            adaptive=self.adaptive, steady_state_gains=self.steady_state_gains,
            warmup_time=self.warmup_time, track_roughness=self.track_roughness,
            track_corner_wavenumber=self.track_corner_wavenumber,
            track_long_wavenumber=self.track_long_wavenumber,
            delay_min_wavelength=self.delay_min_wavelength,
            known_track_std=self.known_track_std,
            input_correlation_time=self.input_correlation_time,
            input_bandwidth=self.input_bandwidth,
            wheelset_lateral_std=self.wheelset_lateral_std,
            wheelset_yaw_std=self.wheelset_yaw_std,
            known_input_lateral_std=self.known_input_lateral_std,
            known_input_yaw_std=self.known_input_yaw_std,
            bogie_accel_noise=self.bogie_accel_noise, bogie_gyro_noise=self.bogie_gyro_noise,
            body_accel_noise=self.body_accel_noise, fault_threshold=self.fault_threshold,
            hold_time=self.hold_time)

    def vehicle(self) -> RailVehicleParams:
        """The model's vehicle parameters (sides split evenly)."""
        return RailVehicleParams(
            body_mass=self.body_mass, body_yaw_inertia=self.body_yaw_inertia,
            bogie_pivot_semi_spacing=self.bogie_pivot_semi_spacing, bogie_mass=self.bogie_mass,
            bogie_yaw_inertia=self.bogie_yaw_inertia,
            primary_lateral_stiffness=self.primary_lateral_stiffness,
            primary_yaw_stiffness=self.primary_yaw_stiffness,
            secondary_lateral_stiffness_left=0.5 * self.secondary_lateral_stiffness,
            secondary_lateral_stiffness_right=0.5 * self.secondary_lateral_stiffness,
            secondary_lateral_damping_left=0.5 * self.secondary_lateral_damping,
            secondary_lateral_damping_right=0.5 * self.secondary_lateral_damping,
            anti_yaw_damping_left=0.5 * self.anti_yaw_damping,
            anti_yaw_damping_right=0.5 * self.anti_yaw_damping,
            semi_wheelbase=self.semi_wheelbase, speed=self.speed)

    def __post_init__(self) -> None:
        # Cross-field rules of the core (grids, sojourn time vs sample period) at start and on
        # every runtime change.
        self.imm_config()


class _FrozenDetector:
    """Counts identical consecutive values of one channel."""

    def __init__(self) -> None:
        self.last: float | None = None
        self.repeats = 0

    def update(self, value: float) -> int:
        self.repeats = self.repeats + 1 if value == self.last else 0
        self.last = value
        return self.repeats


class SuspensionMonitorNode(Node):
    """IMM suspension monitor node (see the module docstring for time alignment)."""

    def __init__(self, node_name: str = 'suspension_monitor', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, SuspensionMonitorParameters,
                                      on_change=self._on_change)
        p = self._typed.value
        self.imm = SuspensionImm(p.imm_config(), p.vehicle())
        self._mode_names = [m.name for m in self.imm.modes]
        self.rejected: Counter[str] = Counter()
        self.processed = 0
        self.known_input_samples = 0
        self._bogie: deque[tuple[int, float, float]] = deque()
        self._body: deque[tuple[int, float]] = deque()
        self._newest_ns = 0
        self._last_pair_ns: int | None = None
        self._track: tuple[int, np.ndarray, np.ndarray | None] | None = None
        self._track_state = 'not received'
        self._creep_state = 'not received' if p.use_creep_factor else 'disabled'
        self._frozen = [_FrozenDetector() for _ in range(3)]
        self._input_fault = ''
        self._first_wall: float | None = None
        self.last_output: ModeProbabilities | None = None
        sensor_subscription(self, Imu, 'rail/bogie/imu', self._on_bogie)
        sensor_subscription(self, Imu, 'rail/body/imu', self._on_body)
        if p.use_track_irregularity:
            sensor_subscription(self, TrackIrregularity, 'rail/track_irregularity', self._on_track)
        if p.use_creep_factor:
            sensor_subscription(self, CreepFactor, 'rail/creep_factor', self._on_creep_factor)
        self._publisher = self.create_publisher(ModeProbabilities, 'rail/suspension/modes',
                                                OUTPUT_QOS)
        self.diagnostics = Diagnostics(self, 'rail_suspension_imm', p.diagnostics_period,
                                       update=self._update_diagnostics)
        self._update_diagnostics()

    @property
    def parameters(self) -> SuspensionMonitorParameters:
        """The current validated parameters."""
        return self._typed.value

    def _on_change(self, p: SuspensionMonitorParameters) -> None:
        self.imm.decision = FaultDecision(p.fault_threshold, p.hold_time, 1.0 / p.sample_rate)
        self.imm.set_speed(p.speed)

    # ------------------------------------------------------------------ inputs
    def _reject(self, reason: str) -> None:
        self.rejected[reason] += 1

    def _on_bogie(self, msg: Imu) -> None:
        stamp = stamp_ns(msg.header.stamp)
        self._bogie.append((stamp, float(msg.linear_acceleration.y),
                            float(msg.angular_velocity.z)))
        self._pair(stamp)

    def _on_body(self, msg: Imu) -> None:
        stamp = stamp_ns(msg.header.stamp)
        self._body.append((stamp, float(msg.linear_acceleration.y)))
        self._pair(stamp)

    def _on_creep_factor(self, msg: CreepFactor) -> None:
        c, std = float(msg.creep_factor), float(msg.std_dev)
        if not (np.isfinite(c) and 0.0 < c <= MAX_CREEP_FACTOR and np.isfinite(std)):
            self._reject('creep_factor_invalid')
            return
        if std > self.parameters.creep_max_std:
            self._creep_state = (f'uncertain (std {std:.2f}): model keeps '
                                 f'{self.imm.creep_factor:.2f}')
            return
        self.imm.set_creep_factor(c)
        self._creep_state = 'following'

    def _on_track(self, msg: TrackIrregularity) -> None:
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < 2 or (rate.size not in (0, alignment.size)):
            self._reject('track_irregularity_size')
            return
        # All four wheelsets when the model has the rear bogie, else the monitored bogie's.
        full_car = self.parameters.estimation_model == 'full_car'
        used = 4 if alignment.size >= 4 and full_car else 2
        if not (np.all(np.isfinite(alignment[:used])) and np.all(np.isfinite(rate[:used]))):
            self._reject('track_irregularity_non_finite')
            return
        self._track = (stamp_ns(msg.header.stamp), alignment[:used].copy(),
                       rate[:used].copy() if rate.size else None)

    def _pair(self, stamp: int) -> None:
        """Match bogie and body samples by stamp; process the pairs in stamp order."""
        p = self.parameters
        tolerance = int(p.pair_tolerance * 1e9)
        self._newest_ns = max(self._newest_ns, stamp)
        pairs = []
        for bogie in list(self._bogie):
            partner = next((b for b in self._body if abs(b[0] - bogie[0]) <= tolerance), None)
            if partner is not None:
                self._bogie.remove(bogie)
                self._body.remove(partner)
                pairs.append((bogie[0], np.array([bogie[1], bogie[2], partner[1]])))
        timeout = int(p.pair_timeout * 1e9)
        for queue in (self._bogie, self._body):
            while queue and self._newest_ns - queue[0][0] > timeout:
                queue.popleft()
                self._reject('unpaired')
        for pair_stamp, z in sorted(pairs, key=lambda item: item[0]):
            self._process(pair_stamp, z)

    def _check(self, z: np.ndarray) -> str:
        p = self.parameters
        if not np.all(np.isfinite(z)):
            return 'non_finite'
        if abs(z[0]) >= p.accel_limit or abs(z[2]) >= p.accel_limit:
            return 'saturated'
        if abs(z[1]) >= p.gyro_limit:
            return 'saturated'
        frozen = [d.update(float(v)) for d, v in zip(self._frozen, z, strict=True)]
        if max(frozen) >= p.frozen_samples - 1:
            return 'frozen_sensor'
        return ''

    def _known_input(self, stamp: int) -> np.ndarray | None:
        p = self.parameters
        if not p.use_track_irregularity or self._track is None:
            self._track_state = 'not received' if p.use_track_irregularity else 'disabled'
            return None
        track_stamp, alignment, rate = self._track
        age = (stamp - track_stamp) * 1e-9
        if age < -p.pair_tolerance or age > p.track_max_age:
            self._track_state = f'stale ({age:.3f} s): process-noise model'
            return None
        self._track_state = 'fresh: known-input model'
        if p.estimation_model == 'full_car':
            return alignment   # measurements of the track model under the wheelsets
        # Half car: the monitored bogie's [y_lead, y_trail, psi_lead, psi_trail].
        return wheelset_inputs_from_track(alignment[None, :2],
                                          None if rate is None else rate[None, :2], p.speed)[0]

    def _process(self, stamp: int, z: np.ndarray) -> None:
        p = self.parameters
        dt_ns = 1e9 / p.sample_rate
        if self._last_pair_ns is not None:
            if stamp == self._last_pair_ns:
                self._reject('repeated')
                return
            if stamp < self._last_pair_ns:
                self._reject('out_of_order')
                return
            gap = (stamp - self._last_pair_ns) * 1e-9
            if gap > p.max_gap:
                self._reject('gap_restart')
                self.imm.reset_states()
            else:
                # Bridge missing samples with predict-only steps (the model is discretised at
                # the nominal rate).
                missing = int(round((stamp - self._last_pair_ns) / dt_ns)) - 1
                for _ in range(max(0, missing)):
                    self.imm.step(None)
                if missing > 0:
                    self.rejected['missing_samples'] += missing
        self._last_pair_ns = stamp
        problem = self._check(z)
        self._input_fault = problem
        if problem:
            self._reject(problem)
            out = self.imm.step(None)
        else:
            known = self._known_input(stamp)
            out = self.imm.step(z, known)
            self.known_input_samples += int(out.known_input)
            self.processed += 1
        if self._first_wall is None:
            self._first_wall = self.get_clock().now().nanoseconds * 1e-9
        msg = ModeProbabilities()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        msg.header.frame_id = 'front_bogie'
        msg.modes = self._mode_names
        msg.probability = out.probability.tolist()
        msg.smoothed_probability = out.smoothed_probability.tolist()
        msg.mode_spring_ratio = out.mode_spring_ratio.tolist()
        msg.mode_damper_ratio = out.mode_damper_ratio.tolist()
        msg.most_likely = out.most_likely
        msg.spring_ratio = out.spring_ratio
        msg.damper_ratio = out.damper_ratio
        msg.fault_detected = out.fault.detected
        msg.fault_component = out.fault.component
        self._publisher.publish(msg)
        self.last_output = msg

    # ------------------------------------------------------------------ diagnostics
    def _update_diagnostics(self) -> None:
        out = self.last_output
        values: dict[str, Any] = {
            'processed_samples': self.processed,
            'known_input_samples': self.known_input_samples,
            'track_irregularity': self._track_state,
            'creep_factor_input': self._creep_state,
            'model_creep_factor': self.imm.creep_factor,
            'covariance_repairs': self.imm.covariance_repairs,
            'steady_state_failures': self.imm.steady_state_failures,
            'rediscretizations': self.imm.rediscretizations,
        }
        values.update({f'rejected_{k}': v for k, v in sorted(self.rejected.items())})
        if out is None:
            self.diagnostics.set(OK, 'waiting for paired IMU samples', values)
            return
        values.update({
            'most_likely_mode': self._mode_names[out.most_likely],
            'spring_ratio': out.spring_ratio, 'damper_ratio': out.damper_ratio,
            'fault_component': out.fault_component or 'none'})
        if self._input_fault:
            self.diagnostics.set(WARN, f'input fault ({self._input_fault}): estimates held',
                                 values)
        elif out.fault_detected:
            size = {'spring': f'spring {out.spring_ratio:.2f}',
                    'damper': f'damper {out.damper_ratio:.2f}',
                    'spring+damper': f'spring {out.spring_ratio:.2f}, damper '
                                     f'{out.damper_ratio:.2f}'}[out.fault_component]
            severe = (out.fault_component == 'spring+damper'
                      or max(abs(out.spring_ratio - 1.0), abs(out.damper_ratio - 1.0)) >= 0.4)
            self.diagnostics.set(ERROR if severe else WARN,
                                 f'suspension fault: {size} x nominal', values)
        else:
            self.diagnostics.set(OK, 'suspension normal', values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``suspension_monitor`` executable."""
    import sys

    from vehicle_monitor_common.node_helpers import run_node

    sys.exit(run_node(SuspensionMonitorNode, args))


if __name__ == '__main__':
    main()

