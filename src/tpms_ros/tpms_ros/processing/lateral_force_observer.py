"""The lateral force observer's logic, ROS-free: alignment, input checks, time jumps, outputs.

Wraps :class:`tpms_ros.core.lateral_force_observer.LateralForceObserver` (tire forces by SKFMEC,
Kim & Huh 2000, docs/methods/lateral_force_observer.md); the node
(``tpms_ros.nodes.lateral_force_observer_node``) and the
offline engine both run it.

Inputs (relative topics):

* ``vehicle/imu`` (sensor_msgs/Imu, 100 Hz): ``linear_acceleration.x/.y`` = ax, ay,
  ``angular_velocity.x`` = roll rate p, ``.z`` = yaw rate r. The IMU drives the filter.
* ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz, raw CDR) and ``vehicle/driver_inputs``
  (DriverInputs, 100 Hz).

Output: ``vehicle/tire_forces`` (TireForces: per-wheel fx, fy, fz; ``fy_front``/``fy_rear`` are
the axle-*average* per-tire forces Fyf, Fyr of the paper).

Time alignment: each IMU sample (stamp t_k, previous one t_(k-1)) is one filter step with
dt = t_k - t_(k-1) and is answered by one output stamped t_k.

* Wheel speeds: the mean of the samples with t_(k-1) < stamp <= t_k (the wheel equation then
  sees the interval's average speed); with none in the interval, the latest sample not newer
  than t_k, if at most ``wheel_speeds_max_age_s`` old (sample and hold).
* Driver inputs: the latest message not newer than t_k, if at most ``driver_inputs_max_age_s``
  old (sample and hold).
* An IMU sample waits until both other topics have delivered a sample at or after t_k, or
  until the queued IMU samples span ``max_wait_s`` of IMU time (a topic is late or silent): it
  is then processed with what is there. The wait is measured on stamps, not on a clock, so a
  replay at any speed aligns the same way. Stale wheel speeds or driver inputs skip the IMU
  sample (no filter step, no output; the next step spans the skipped time) and are counted.

Bad input: out-of-order or repeated stamps on any topic, wheel speeds that are not four finite
values, and driver inputs without four torques are rejected and counted here; so is a wheel-
speed sample with one wheel off the median of the four by more than ``max_wheel_deviation``
(a dead or broken sensor: the forces would follow it), and an IMU whose four channels all
repeat their exact values for ``imu_frozen_s`` (a frozen sensor: its samples are skipped, no
output, until it moves again). Non-finite or saturated IMU values, absurd wheel speeds, steer
or torque are rejected by the core (the sample is skipped, its time carried into the next
step), which also restarts after a gap longer than ``max_dt_s`` and resets a covariance that
lost positive definiteness (counted). Above the 0.5 g validity of the load-ratio relation the
output says ``within_validity`` false and the status warns.

Time (:class:`vehicle_monitor_common.input_health.StampCheck`, per input): a lone stamp more
than ``jump_horizon_s`` ahead is dropped and counted; a confirmed jump forward or back on any
input (a looped or repeated replay, a clock reset) restarts the alignment and the filter from
the new time line, and the status says so until the filter publishes again.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from tpms_ros.core.lateral_force_observer import (
    G,
    LateralForceEstimate,
    LateralForceObserver,
    ObserverTuningParams,
    ObserverVehicleParams,
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
    ProcessorParams,
    ProcessorSpec,
    Status,
    header_stamp_ns,
)
from vehicle_monitor_common.status_report import StatusProblems

TIRE_FORCES = 'vehicle/tire_forces'
_TOPICS = {'imu': IMU, 'wheel_speeds': WHEEL_SPEEDS, 'driver_inputs': DRIVER_INPUTS}
# Input buffers: bounded so a topic without its IMU partner cannot grow memory.
_MAX_BUFFERED = 5000
# below this median wheel speed the plausibility check is off (a stopping car), rad/s
_PLAUSIBLE_MIN_RAD_S = 1.0
# what the status reports as events of the last period, but not as rejected messages
_NOT_REJECTIONS = ('beyond_validity', 'stale_wheel_speeds', 'stale_driver_inputs',
                   'imu_frozen', 'wheel_speeds_rate_burst')


@dataclass(frozen=True)
class LateralForceObserverNodeParams(ProcessorParams):
    """Node-only parameters of lateral_force_observer: input alignment and checks, diagnostics
    (the method's own: :class:`ObserverVehicleParams` and :class:`ObserverTuningParams`)."""

    wheel_speeds_max_age_s: float = param(0.05, 'held wheel speeds older than this are stale '
                                          '(IMU sample skipped), s', low=1e-3, high=10.0)
    driver_inputs_max_age_s: float = param(0.05, 'held driver inputs older than this are stale '
                                           '(IMU sample skipped), s', low=1e-3, high=10.0)
    max_wait_s: float = param(1.0, 'IMU samples wait for late wheel speeds / driver inputs '
                              'until the IMU queue spans this much IMU time, s (must exceed a '
                              "replay's lead)", low=0.0, high=10.0)
    max_wheel_deviation: float = param(0.3, 'a wheel-speed sample with one wheel off the '
                                       'median of the four by more than this fraction is '
                                       'rejected (dead or broken sensor)', low=0.01, high=10.0)
    imu_frozen_s: float = param(0.5, 'an IMU whose ax, ay, roll and yaw rates all repeat '
                                'their exact values this long is frozen: its samples are '
                                'skipped until it moves again, s', low=0.01, high=60.0)
    gyro_noise_warn_ratio: float = param(2.0, 'a yaw-rate or roll-rate residual whose RMS over '
                                         'the last 10 s exceeds this many r_std is a gyro '
                                         'noisier than r_std says (WARN: set r_std)', low=1.0,
                                         high=100.0)


class LateralForceObserverProcessor:
    """What the lateral force observer does with its inputs (see the module docstring).

    Args:
        vehicle: the observer's vehicle model.
        tuning: the observer's filter settings.
        node_params: alignment, input checks, diagnostics.
    """

    inputs = VEHICLE_INPUTS
    outputs = {TIRE_FORCES: 'vehicle_monitor_msgs/msg/TireForces'}

    def __init__(self, vehicle: ObserverVehicleParams, tuning: ObserverTuningParams,
                 node_params: LateralForceObserverNodeParams) -> None:
        self.vehicle = vehicle
        self.tuning = tuning
        self.node_params = node_params
        self.observer = LateralForceObserver(vehicle, tuning)
        self._checks = {topic: StampCheck(max_gap_s=math.inf,
                                          jump_horizon_s=node_params.jump_horizon_s)
                        for topic in _TOPICS}
        self.received = dict.fromkeys(_TOPICS, 0)
        self._handlers = {IMU: self._on_imu, WHEEL_SPEEDS: self._on_wheel_speeds,
                          DRIVER_INPUTS: self._on_driver_inputs}
        self._rates = {topic: RateMeter() for topic in _TOPICS}
        # Rejections here (the core's own are in observer.health.rejected).
        self.rejected: dict[str, int] = {}
        self.skipped = {'stale_wheel_speeds': 0, 'stale_driver_inputs': 0, 'imu_frozen': 0}
        self.published = 0
        self.beyond_validity = 0
        self.time_jumps = 0
        self._last_jump_s = 0.0
        self._restarted = False
        self._imu: deque[tuple[int, float, float, float, float]] = deque()
        self._wheels: deque[tuple[int, tuple[float, ...]]] = deque(maxlen=_MAX_BUFFERED)
        self._driver: deque[tuple[int, float, np.ndarray]] = deque(maxlen=_MAX_BUFFERED)
        self._newest = {'wheel_speeds': -1, 'driver_inputs': -1}
        self._last_step_ns: int | None = None
        self._last: LateralForceEstimate | None = None
        self._last_ay = math.nan
        self._period_events: dict[str, int] = {}
        self._filter_rejected_seen = 0
        self._imu_last: tuple[float, ...] = ()
        self._imu_since_ns = 0
        self._imu_frozen = False
        self._samples_per_interval = 0.0
        self._intervals_seen = 0

    # -- parameters --------------------------------------------------------------------------

    def set_model(self, vehicle: ObserverVehicleParams, tuning: ObserverTuningParams) -> None:
        """A new model: restart the filter from the next IMU sample; keep the counters."""
        self.vehicle, self.tuning = vehicle, tuning
        if vehicle != self.observer.params or tuning != self.observer.tuning:
            health = self.observer.health
            self.observer = LateralForceObserver(vehicle, tuning)
            self.observer.health = health

    def set_node_params(self, node_params: LateralForceObserverNodeParams) -> None:
        """New node parameters take effect at once."""
        self.node_params = node_params

    # -- inputs ------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message (the wheel speeds as CDR bytes); the outputs it makes due."""
        return self._handlers[topic](message)

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        self._event(reason)

    def _event(self, reason: str) -> None:
        self._period_events[reason] = self._period_events.get(reason, 0) + 1

    def _accept_stamp(self, topic: str, stamp: int) -> bool:
        self.received[topic] += 1
        self._rates[topic].tick()
        verdict = self._checks[topic].check(stamp)
        if verdict == 'jump':
            self._restart(self._checks[topic].last_jump_s)
            return True
        if verdict in ('repeated', 'out_of_order', 'future_stamp'):
            self._reject(f'{topic}_{verdict}')
            return False
        return True

    def _restart(self, jump_s: float) -> None:
        """A confirmed time jump on one input: alignment and filter restart from the new time
        line (the other inputs follow it: their next stamps are accepted as it)."""
        self.time_jumps += 1
        self._last_jump_s = jump_s
        self._restarted = True
        self._imu.clear()
        self._wheels.clear()
        self._driver.clear()
        self._newest = {'wheel_speeds': -1, 'driver_inputs': -1}
        self._last_step_ns = None
        self._imu_last, self._imu_frozen = (), False
        health = self.observer.health
        self.observer = LateralForceObserver(self.vehicle, self.tuning)
        self.observer.health = health
        for check in self._checks.values():
            check.last_ns = None

    def _on_imu(self, msg: Any) -> list[Output]:
        stamp = header_stamp_ns(msg)
        if not self._accept_stamp('imu', stamp):
            return []
        acc, rate = msg.linear_acceleration, msg.angular_velocity
        sample = (float(acc.x), float(acc.y), float(rate.z), float(rate.x))
        if sample != self._imu_last:
            self._imu_last, self._imu_since_ns = sample, stamp
        self._imu_frozen = stamp - self._imu_since_ns >= self.node_params.imu_frozen_s * 1e9
        self._imu.append((stamp, *sample))
        return self._drain()

    def _on_wheel_speeds(self, data: bytes) -> list[Output]:
        try:
            stamp, speeds = decode_wheel_speeds(data)
        except ValueError:
            self.received['wheel_speeds'] += 1
            self._rates['wheel_speeds'].tick()
            self._reject('wheel_speeds_malformed')
            return []
        if not self._accept_stamp('wheel_speeds', stamp):
            return []
        # Plain Python on the four floats (the same arithmetic as numpy's): at 1 kHz numpy's
        # per-call overhead was most of this node's cost.
        if not all(map(math.isfinite, speeds)):
            # A bad sample must not enter the interval mean; the others still do.
            self._reject('wheel_speeds_invalid')
            return []
        # the median of four: the mean of the middle two; the farthest wheels from it are the
        # extremes (|w - median| over all four, exactly)
        low, mid_low, mid_high, high = sorted(speeds)
        median = 0.5 * (mid_low + mid_high)
        limit = self.node_params.max_wheel_deviation * median
        if median > _PLAUSIBLE_MIN_RAD_S and (median - low > limit or high - median > limit):
            self._reject('wheel_speeds_implausible')
            return []
        self._wheels.append((stamp, speeds))
        self._newest['wheel_speeds'] = stamp
        return self._drain()

    def _on_driver_inputs(self, msg: Any) -> list[Output]:
        stamp = header_stamp_ns(msg)
        if not self._accept_stamp('driver_inputs', stamp):
            return []
        torque = wheel_torques(msg)
        if torque is None:
            self._reject('driver_inputs_invalid')
            return []
        self._driver.append((stamp, float(msg.steering_angle), torque))
        self._newest['driver_inputs'] = stamp
        return self._drain()

    def _drain(self) -> list[Output]:
        """Process the queued IMU samples whose inputs are complete or waited long enough."""
        wait_ns = self.node_params.max_wait_s * 1e9
        outputs: list[Output] = []
        while self._imu:
            stamp = self._imu[0][0]
            caught_up = min(self._newest.values()) >= stamp
            if not (caught_up or self._imu[-1][0] - stamp >= wait_ns
                    or len(self._imu) >= _MAX_BUFFERED):
                break
            outputs += self._step(*self._imu.popleft())
        return outputs

    # -- alignment and filtering -------------------------------------------------------------

    def _wheel_speed_at(self, stamp: int) -> np.ndarray | None:
        """Mean over (previous IMU stamp, stamp], else the held sample if fresh enough."""
        start = self._last_step_ns if self._last_step_ns is not None else stamp - 1
        interval = [omega for s, omega in self._wheels if start < s <= stamp]
        held = None
        while self._wheels and self._wheels[0][0] <= stamp:
            held = self._wheels.popleft()
        if held is not None:
            self._wheels.appendleft(held)  # kept for a later sample-and-hold
        self._track_rate(len(interval))
        if interval:
            return np.mean(interval, axis=0)
        if held is not None and \
                stamp - held[0] <= self.node_params.wheel_speeds_max_age_s * 1e9:
            return np.array(held[1])
        return None

    def _track_rate(self, samples: int) -> None:
        """Wheel-speed samples per IMU interval against their running mean: a burst (3 times
        as many) is an event on the status (the interval mean is unaffected)."""
        self._intervals_seen += 1
        if self._intervals_seen > 100 and samples > 3.0 * self._samples_per_interval:
            self._event('wheel_speeds_rate_burst')
        else:   # the running mean (over the first 100 intervals, then exponential)
            self._samples_per_interval += ((samples - self._samples_per_interval)
                                           / min(self._intervals_seen, 100))

    def _driver_at(self, stamp: int) -> tuple[float, np.ndarray] | None:
        """The latest driver inputs not newer than ``stamp``, if fresh enough."""
        held = None
        while self._driver and self._driver[0][0] <= stamp:
            held = self._driver.popleft()
        if held is None:
            return None
        self._driver.appendleft(held)
        if stamp - held[0] > self.node_params.driver_inputs_max_age_s * 1e9:
            return None
        return held[1], held[2]

    def _step(self, stamp: int, ax: float, ay: float, r: float, p: float) -> list[Output]:
        omega = self._wheel_speed_at(stamp)
        driver = self._driver_at(stamp)
        if omega is None or driver is None:
            reason = 'stale_wheel_speeds' if omega is None else 'stale_driver_inputs'
            self.skipped[reason] += 1
            self._event(reason)
            return []
        if self._imu_frozen:
            self.skipped['imu_frozen'] += 1
            self._event('imu_frozen')
            return []
        steer, torque = driver
        # The first call's dt is ignored by the core; later ones span any skipped samples.
        dt = 0.0 if self._last_step_ns is None else (stamp - self._last_step_ns) * 1e-9
        self._last_step_ns = stamp
        estimate = self.observer.step(ax, ay, r, p, omega.tolist(), torque.tolist(), steer, dt)
        if estimate is None or not estimate.accepted:
            return []
        self._last = estimate
        self._last_ay = ay
        self._restarted = False
        if not estimate.within_validity:
            self.beyond_validity += 1
            self._event('beyond_validity')
        self.published += 1
        return [Output(TIRE_FORCES, stamp, {
            'header': {'frame_id': 'base_link'},
            'fx': [float(v) for v in estimate.fx],
            'fy': [float(v) for v in estimate.fy],
            'fz': [float(v) for v in estimate.fz],
            # Axle-average per-tire forces, as the core (and Kim & Huh) define Fyf, Fyr.
            'fy_front': float(estimate.fy_front),
            'fy_rear': float(estimate.fy_rear),
            'within_validity': bool(estimate.within_validity),
        })]

    # -- status ------------------------------------------------------------------------------

    def status(self, now_ns: int) -> Status:
        """Health: counts so far, events since the previous status."""
        tuning = self.tuning
        limit_g = tuning.validity_ay_mps2 / G
        health = self.observer.health
        events, self._period_events = self._period_events, {}
        values: dict[str, Any] = {
            f'input_rate_hz.{topic}': meter.read(now_ns) for topic, meter in self._rates.items()}
        values.update({f'received_{topic}': count for topic, count in self.received.items()})
        values.update({
            'filter_steps': health.samples,
            'filter_accepted': health.accepted,
            'outputs_published': self.published,
            'gap_restarts': health.gap_restarts,
            'covariance_resets': health.covariance_resets,
            'samples_beyond_validity': self.beyond_validity,
            'validity_limit_g': limit_g,
            'ay_mps2': self._last_ay,
            'time_jumps': self.time_jumps,
            'filter': ('SKFMEC' if tuning.scaled and tuning.mec else
                       f'EKF (scaled={tuning.scaled}, mec={tuning.mec})')
                      + (', IMM quiet/agile' if tuning.quiet_force_q > 0.0 else ''),
        })
        if tuning.quiet_force_q > 0.0:
            # the share of the agile filter: near 0 in ordinary driving, up in a transient
            values['agile_mode_probability'] = float(self.observer.mode_probabilities[-1])
        values.update({f'rejected_{k}': v for k, v in self.rejected.items()})
        values.update({f'rejected_by_filter_{k}': v for k, v in health.rejected.items()})
        values.update({f'skipped_{k}': v for k, v in self.skipped.items()})
        problems = StatusProblems()
        if self._imu_frozen or events.get('imu_frozen'):
            problems.error(f'IMU frozen (ax, ay, p, r repeat exactly): '
                           f'{events.get("imu_frozen", 0)} samples skipped, no forces published')
        if events.get('wheel_speeds_implausible') or events.get('wheel_speeds_invalid'):
            problems.error('bad wheel speeds (a wheel non-finite, dead or off the others): '
                           'samples rejected')
        if self._restarted:
            problems.warn(f'time jump of {self._last_jump_s:+.3g} s: filter restarted, '
                          'estimating again once inputs align')
        if self._last is None:
            problems.warn('waiting for IMU, wheel speeds and driver inputs')
            return problems.status(values)
        values['fy_n'] = self._last.fy.tolist()
        values['fz_n'] = self._last.fz.tolist()
        if not self._last.within_validity or events.get('beyond_validity'):
            problems.warn(f'|ay| above {limit_g:g} g: load-ratio split outside its validity '
                          f'({events.get("beyond_validity", 0)} samples)')
        for reason in ('stale_wheel_speeds', 'stale_driver_inputs'):
            if events.get(reason):
                problems.warn(f'{events[reason]} IMU samples skipped: {reason}')
        if events.get('wheel_speeds_rate_burst'):
            problems.warn(f"wheel-speed rate burst in {events['wheel_speeds_rate_burst']} IMU "
                          f'intervals (over 3 x {self._samples_per_interval:.3g} samples)')
        rejected_now = sum(v for k, v in events.items() if k not in _NOT_REJECTIONS)
        if rejected_now:
            problems.warn(f'{rejected_now} input messages rejected: ' + ', '.join(
                f'{v} {k}' for k, v in sorted(events.items()) if k not in _NOT_REJECTIONS))
        filter_rejected = sum(health.rejected.values())
        if filter_rejected > self._filter_rejected_seen:
            problems.warn(f'{filter_rejected - self._filter_rejected_seen} samples rejected by '
                          'the filter (non-finite or saturated)')
            self._filter_rejected_seen = filter_rejected
        ratio = self.observer.gyro_residual_ratio
        if ratio is not None:
            values['gyro_residual_ratio'] = [float(ratio[0]), float(ratio[1])]
            if max(ratio) > self.node_params.gyro_noise_warn_ratio:
                problems.warn(f'yaw/roll-rate residuals {ratio[0]:.1f} / {ratio[1]:.1f} x r_std '
                              'over 10 s: the gyro is noisier than r_std says and the forces '
                              "follow its noise (set r_std's r and p to the IMU's noise)")
        if health.covariance_resets:
            values['note'] = 'covariance lost positive definiteness: filter reset (counted)'
        return problems.status(values, 'estimating tire forces')


# The node, declared once: the live node (nodes/lateral_force_observer_node.py) and the offline
# engine (make_processor, the registered entry point) build it from this. A change of the
# vehicle or the tuning goes to one set_model(vehicle, tuning), which restarts the filter.
SPEC = ProcessorSpec(
    'lateral_force_observer', 'vehicle_imu', make=LateralForceObserverProcessor,
    groups=(ParameterGroup(ObserverVehicleParams, 'set_model'),
            ParameterGroup(ObserverTuningParams, 'set_model'),
            ParameterGroup(LateralForceObserverNodeParams, 'set_node_params')))
make_processor = SPEC.make_processor
