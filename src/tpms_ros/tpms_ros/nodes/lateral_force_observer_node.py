"""``lateral_force_observer``: tire forces by SKFMEC (Kim & Huh 2000) on the ROS graph.

Wraps :class:`tpms_ros.core.lateral_force_observer.LateralForceObserver` (SPEC §4).

Topics (relative, so a namespace moves them):

* in ``vehicle/imu`` (sensor_msgs/Imu, 100 Hz): ``linear_acceleration.x/.y`` = ax, ay,
  ``angular_velocity.x`` = roll rate p, ``.z`` = yaw rate r. The IMU drives the filter.
* in ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz) and ``vehicle/driver_inputs``
  (DriverInputs, 100 Hz).
* out ``vehicle/tire_forces`` (TireForces: per-wheel fx, fy, fz; ``fy_front``/``fy_rear`` are
  the axle-*average* per-tire forces Fyf, Fyr of the paper), ``/diagnostics``.

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
  replay at any speed aligns the same way: in an as-fast-as-possible replay the executor takes
  one message per topic in turn and the 100 Hz IMU runs ahead of the 1 kHz wheel speeds in
  data time by up to the player's lead (0.5 s by default), which ``max_wait_s`` must exceed.
  The price: while a topic is silent in real time, outputs lag by ``max_wait_s`` (and are
  skipped as stale anyway). Stale wheel speeds or driver inputs skip the IMU sample (no filter
  step, no output; the next step spans the skipped time) and are counted and reported.

Bad input: out-of-order or repeated stamps on any topic, wheel speeds that are not four finite
values, and driver inputs without four torques are rejected and counted here; non-finite or
saturated IMU values, absurd wheel speeds, steer or torque are rejected by the core (the sample
is skipped, its time carried into the next step), which also restarts after a gap longer than
``max_dt_s`` and resets a covariance that lost positive definiteness (counted). Above the 0.5 g
validity of the load-ratio relation the output says ``within_validity`` false and diagnostics
warn. Diagnostics are refreshed on their own timer (``diagnostics_period_s``), never from an
input callback; events are counted since the previous status.

Parameters: the method's (:class:`ObserverVehicleParams`, :class:`ObserverTuningParams`) and the
node's alignment ones (:class:`LateralForceObserverNodeParams`), each declared once.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import DriverInputs, TireForces

from tpms_ros.core.lateral_force_observer import (
    G,
    LateralForceEstimate,
    LateralForceObserver,
    ObserverTuningParams,
    ObserverVehicleParams,
)
from tpms_ros.nodes.wheel_speed_input import subscribe_wheel_speeds
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.node_helpers import (
    OK,
    OUTPUT_QOS,
    STALE,
    WARN,
    Diagnostics,
    TypedParameters,
    param,
    run_node,
    sensor_subscription,
    stamp_ns,
    time_msg,
)

# Input buffers: bounded so a topic without its IMU partner cannot grow memory.
_MAX_BUFFERED = 5000


@dataclass(frozen=True)
class LateralForceObserverNodeParams:
    """Node-only parameters of lateral_force_observer: input alignment and diagnostics (the
    method's own: :class:`ObserverVehicleParams` and :class:`ObserverTuningParams`)."""

    wheel_speeds_max_age_s: float = param(0.05, 'held wheel speeds older than this are stale '
                                          '(IMU sample skipped), s', low=1e-3, high=10.0)
    driver_inputs_max_age_s: float = param(0.05, 'held driver inputs older than this are stale '
                                           '(IMU sample skipped), s', low=1e-3, high=10.0)
    max_wait_s: float = param(1.0, 'IMU samples wait for late wheel speeds / driver inputs '
                              'until the IMU queue spans this much IMU time, s (must exceed a '
                              "replay's lead)", low=0.0, high=10.0)
    diagnostics_period_s: float = param(1.0, 'period of /diagnostics, s', low=0.01,
                                        high=60.0, read_only=True)


class LateralForceObserverNode(Node):
    """The ``lateral_force_observer`` node (see the module docstring)."""

    def __init__(self, node_name: str = 'lateral_force_observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._vehicle = TypedParameters(self, ObserverVehicleParams,
                                        on_change=self._on_model_change)
        self._tuning = TypedParameters(self, ObserverTuningParams,
                                       on_change=self._on_model_change)
        self._typed = TypedParameters(self, LateralForceObserverNodeParams)
        self._observer = LateralForceObserver(self._vehicle.value, self._tuning.value)
        self._checks = {topic: StampCheck(max_gap_s=math.inf)
                        for topic in ('imu', 'wheel_speeds', 'driver_inputs')}
        self.received = {topic: 0 for topic in self._checks}
        now = self.get_clock().now().nanoseconds
        self._rates = {topic: RateMeter(since_ns=now) for topic in self._checks}
        # Rejections by this node (the core's own are in observer.health.rejected).
        self.rejected: dict[str, int] = {}
        self.skipped = {'stale_wheel_speeds': 0, 'stale_driver_inputs': 0}
        self.published = 0
        self.beyond_validity = 0
        self._imu: deque[tuple[int, float, float, float, float]] = deque()
        self._wheels: deque[tuple[int, np.ndarray]] = deque(maxlen=_MAX_BUFFERED)
        self._driver: deque[tuple[int, float, np.ndarray]] = deque(maxlen=_MAX_BUFFERED)
        self._newest = {'wheel_speeds': -1, 'driver_inputs': -1}
        self._last_step_ns: int | None = None
        self._last: LateralForceEstimate | None = None
        self._last_ay = math.nan
        self._period_events: dict[str, int] = {}
        self._filter_rejected_seen = 0

        self._publisher = self.create_publisher(TireForces, 'vehicle/tire_forces', OUTPUT_QOS)
        sensor_subscription(self, Imu, 'vehicle/imu', self._on_imu)
        subscribe_wheel_speeds(self, self._on_wheel_speeds, self._on_malformed)
        sensor_subscription(self, DriverInputs, 'vehicle/driver_inputs', self._on_driver_inputs)
        self._diagnostics = Diagnostics(self, 'vehicle_imu',
                                        self._typed.value.diagnostics_period_s,
                                        update=self._update_diagnostics)
        self._update_diagnostics()

    @property
    def parameters(self) -> LateralForceObserverNodeParams:
        """The current, validated node-only parameters."""
        return self._typed.value

    @property
    def vehicle_parameters(self) -> ObserverVehicleParams:
        """The observer's current vehicle model."""
        return self._vehicle.value

    @property
    def tuning_parameters(self) -> ObserverTuningParams:
        """The observer's current filter settings."""
        return self._tuning.value

    @property
    def observer(self) -> LateralForceObserver:
        """The estimator core in use."""
        return self._observer

    def _on_model_change(self, _: Any) -> None:
        vehicle, tuning = self._vehicle.value, self._tuning.value
        if vehicle != self._observer.params or tuning != self._observer.tuning:
            # A new model: restart the filter from the next IMU sample; keep the counters.
            health = self._observer.health
            self._observer = LateralForceObserver(vehicle, tuning)
            self._observer.health = health

    # -- inputs ------------------------------------------------------------------------------

    def _reject(self, reason: str) -> None:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        self._period_events[reason] = self._period_events.get(reason, 0) + 1

    def _accept_stamp(self, topic: str, stamp: int) -> int | None:
        self.received[topic] += 1
        self._rates[topic].tick()
        verdict = self._checks[topic].check(stamp)
        if verdict in ('repeated', 'out_of_order'):
            self._reject(f'{topic}_{verdict}')
            return None
        return stamp

    def _on_imu(self, msg: Imu) -> None:
        stamp = self._accept_stamp('imu', stamp_ns(msg.header.stamp))
        if stamp is None:
            return
        acc, rate = msg.linear_acceleration, msg.angular_velocity
        self._imu.append((stamp, float(acc.x), float(acc.y), float(rate.z), float(rate.x)))
        self._drain()

    def _on_malformed(self, _: str) -> None:
        self.received['wheel_speeds'] += 1
        self._rates['wheel_speeds'].tick()
        self._reject('wheel_speeds_malformed')

    def _on_wheel_speeds(self, stamp: int, speeds: tuple[float, ...]) -> None:
        if self._accept_stamp('wheel_speeds', stamp) is None:
            return
        omega = np.array(speeds)
        if not np.all(np.isfinite(omega)):
            # A bad sample must not enter the interval mean; the others still do.
            self._reject('wheel_speeds_invalid')
            return
        self._wheels.append((stamp, omega))
        self._newest['wheel_speeds'] = stamp
        self._drain()

    def _on_driver_inputs(self, msg: DriverInputs) -> None:
        stamp = self._accept_stamp('driver_inputs', stamp_ns(msg.header.stamp))
        if stamp is None:
            return
        torque = np.asarray(msg.wheel_torque, dtype=float)
        if torque.shape != (4,):
            self._reject('driver_inputs_invalid')
            return
        self._driver.append((stamp, float(msg.steering_angle), torque))
        self._newest['driver_inputs'] = stamp
        self._drain()

    def _drain(self) -> None:
        """Process the queued IMU samples whose inputs are complete or waited long enough."""
        wait_ns = self.parameters.max_wait_s * 1e9
        while self._imu:
            stamp = self._imu[0][0]
            caught_up = min(self._newest.values()) >= stamp
            if not (caught_up or self._imu[-1][0] - stamp >= wait_ns
                    or len(self._imu) >= _MAX_BUFFERED):
                return
            self._step(*self._imu.popleft())

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
        if interval:
            return np.mean(interval, axis=0)
        if held is not None and stamp - held[0] <= self.parameters.wheel_speeds_max_age_s * 1e9:
            return held[1]
        return None

    def _driver_at(self, stamp: int) -> tuple[float, np.ndarray] | None:
        """The latest driver inputs not newer than ``stamp``, if fresh enough."""
        held = None
        while self._driver and self._driver[0][0] <= stamp:
            held = self._driver.popleft()
        if held is None:
            return None
        self._driver.appendleft(held)
        if stamp - held[0] > self.parameters.driver_inputs_max_age_s * 1e9:
            return None
        return held[1], held[2]

    def _step(self, stamp: int, ax: float, ay: float, r: float, p: float) -> None:
        omega = self._wheel_speed_at(stamp)
        driver = self._driver_at(stamp)
        if omega is None or driver is None:
            reason = 'stale_wheel_speeds' if omega is None else 'stale_driver_inputs'
            self.skipped[reason] += 1
            self._period_events[reason] = self._period_events.get(reason, 0) + 1
            return
        steer, torque = driver
        # The first call's dt is ignored by the core; later ones span any skipped samples.
        dt = 0.0 if self._last_step_ns is None else (stamp - self._last_step_ns) * 1e-9
        self._last_step_ns = stamp
        estimate = self._observer.step(ax, ay, r, p, omega.tolist(), torque.tolist(), steer, dt)
        if estimate is None or not estimate.accepted:
            return
        self._last = estimate
        self._last_ay = ay
        if not estimate.within_validity:
            self.beyond_validity += 1
            self._period_events['beyond_validity'] = (
                self._period_events.get('beyond_validity', 0) + 1)
        self._publish(estimate, stamp)

    # -- outputs -----------------------------------------------------------------------------

    def _publish(self, est: LateralForceEstimate, stamp: int) -> None:
        msg = TireForces()
        msg.header.stamp = time_msg(stamp)
        msg.header.frame_id = 'base_link'
        msg.fx = [float(v) for v in est.fx]
        msg.fy = [float(v) for v in est.fy]
        msg.fz = [float(v) for v in est.fz]
        # Axle-average per-tire forces, as the core (and Kim & Huh) define Fyf, Fyr.
        msg.fy_front = float(est.fy_front)
        msg.fy_rear = float(est.fy_rear)
        msg.within_validity = bool(est.within_validity)
        self._publisher.publish(msg)
        self.published += 1

    def _update_diagnostics(self) -> None:
        """Refresh the status (Diagnostics timer): counts so far, events since the last one."""
        tuning = self._tuning.value
        limit_g = tuning.validity_ay_mps2 / G
        health = self._observer.health
        events, self._period_events = self._period_events, {}
        now = self.get_clock().now().nanoseconds
        values: dict[str, Any] = {
            f'input_rate_hz.{topic}': meter.read(now) for topic, meter in self._rates.items()}
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
            'filter': ('SKFMEC' if tuning.scaled and tuning.mec else
                       f'EKF (scaled={tuning.scaled}, mec={tuning.mec})'),
        })
        values.update({f'rejected_{k}': v for k, v in self.rejected.items()})
        values.update({f'rejected_by_filter_{k}': v for k, v in health.rejected.items()})
        values.update({f'skipped_{k}': v for k, v in self.skipped.items()})
        if self._last is None:
            self._diagnostics.set(STALE, 'waiting for IMU, wheel speeds and driver inputs',
                                  values)
            return
        values['fy_n'] = self._last.fy.tolist()
        values['fz_n'] = self._last.fz.tolist()
        problems = []
        if not self._last.within_validity or events.get('beyond_validity'):
            problems.append(f'|ay| above {limit_g:g} g: load-ratio split outside its '
                            f'validity ({events.get("beyond_validity", 0)} samples)')
        for reason in ('stale_wheel_speeds', 'stale_driver_inputs'):
            if events.get(reason):
                problems.append(f'{events[reason]} IMU samples skipped: {reason}')
        rejected_now = sum(v for k, v in events.items()
                           if k not in ('beyond_validity', 'stale_wheel_speeds',
                                        'stale_driver_inputs'))
        if rejected_now:
            problems.append(f'{rejected_now} input messages rejected')
        filter_rejected = sum(health.rejected.values())
        if filter_rejected > self._filter_rejected_seen:
            problems.append(f'{filter_rejected - self._filter_rejected_seen} samples rejected '
                            'by the filter (non-finite or saturated)')
            self._filter_rejected_seen = filter_rejected
        if health.covariance_resets:
            values['note'] = 'covariance lost positive definiteness: filter reset (counted)'
        self._diagnostics.set(WARN if problems else OK,
                              '; '.join(problems) or 'estimating tire forces', values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``lateral_force_observer`` executable."""
    raise SystemExit(run_node(LateralForceObserverNode, args))
