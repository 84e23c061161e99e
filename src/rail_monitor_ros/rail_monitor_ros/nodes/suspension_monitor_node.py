"""``suspension_monitor``: secondary-suspension fault detection by IMM (SPEC §5) on ROS 2.

Subscribes ``rail/bogie/imu`` (sensor_msgs/Imu: linear_acceleration.y, angular_velocity.z),
``rail/body/imu`` (linear_acceleration.y, the body accelerometer above the monitored front
bogie) and optionally ``rail/track_irregularity`` (TrackIrregularity: wheelsets front to rear,
the monitored bogie's are indices 0 and 1; the full-car model takes the alignment under all
four (or the first two) as measurements of its track model, the half-car model turns the first
two into wheelset inputs) and ``rail/creep_factor``; publishes ``rail/suspension/modes``
(ModeProbabilities) and ``/diagnostics``. The estimator is
:class:`rail_monitor_ros.core.suspension_imm.SuspensionImm`, whose parameters
(``SuspensionImmParams``) are this node's ROS parameters as they are; the node-only ones
(pairing, input checks, diagnostics) are :class:`SuspensionMonitorNodeParams`.

Time: the two IMUs are paired by stamp (:class:`vehicle_monitor_common.imu_pairing.ImuPairer`,
``pair_tolerance_s``, ``pair_timeout_s``); a pair carries the bogie sample's stamp, which the
output carries too. A bogie sample without partner is dropped and counted ('unpaired'). The
node rejects repeated and out-of-order stamps and passes each pair's stamp to the core, which
owns data time: it bridges missing samples by prediction and restarts its states after a gap
longer than ``max_gap_s`` (probabilities kept).

* Creep factor (full car): the model follows the latest confident estimate as it arrives
  (re-discretised in steps of ``creep_resolution``, with hysteresis). Unmodelled, a creep change
  looks like a suspension fault.
* Track irregularity: sample-and-hold of the latest message not newer than the pair's stamp
  (plus ``pair_tolerance_s``); older than ``track_max_age_s``, it is stale and the
  process-noise model is used (diagnostics say so).

Bad input (non-finite, saturated, frozen sensor, wrong array sizes) is rejected and counted;
the IMM then only predicts, so no fault is declared from bad data; the diagnostic reports an
input fault instead.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from rclpy.node import Node
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import CreepFactor, ModeProbabilities, TrackIrregularity

from rail_monitor_ros.core.rail_model import MAX_CREEP_FACTOR, wheelset_inputs_from_track
from rail_monitor_ros.core.suspension_imm import SuspensionImm, SuspensionImmParams
from vehicle_monitor_common.imu_pairing import ImuPair, ImuPairer
from vehicle_monitor_common.input_health import FrozenDetector, RateMeter, StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    WARN,
    Diagnostics,
    TypedParameters,
    sensor_subscription,
    stamp_ns,
    time_msg,
)
from vehicle_monitor_common.parameters import param

INPUTS = ('bogie_imu', 'body_imu', 'track_irregularity', 'creep_factor')


@dataclass(frozen=True)
class SuspensionMonitorNodeParams:
    """The node's own parameters (the method's are ``SuspensionImmParams``)."""

    pair_tolerance_s: float = param(1e-3, 'largest stamp difference of a bogie/body IMU pair, s',
                                    low=0.0, high=1.0)
    pair_timeout_s: float = param(0.1, 'an unpaired IMU sample is dropped after this, s',
                                  low=1e-3, high=10.0)
    use_creep_factor: bool = param(True, 'full car: follow rail/creep_factor (the creep '
                                   'estimator) in the model', read_only=True)
    creep_max_std: float = param(0.2, 'a creep factor estimate with a larger std is not used, 1',
                                 low=1e-6, high=10.0)
    use_track_irregularity: bool = param(True, 'use rail/track_irregularity as known inputs '
                                         'when fresh', read_only=True)
    track_max_age_s: float = param(0.02, 'older track irregularity is stale, s', low=0.0,
                                   high=10.0)
    accel_limit_mps2: float = param(50.0, 'an acceleration at or beyond this is saturated, '
                                    'm/s^2', low=0.1, high=1e4)
    gyro_limit_rad_s: float = param(5.0, 'a yaw rate at or beyond this is saturated, rad/s',
                                    low=0.01, high=1e3)
    frozen_samples: int = param(20, 'this many identical consecutive values = frozen sensor',
                                low=2, high=100000)
    diagnostics_period_s: float = param(1.0, '/diagnostics period, s', low=0.01, high=60.0,
                                        read_only=True)


class SuspensionMonitorNode(Node):
    """IMM suspension monitor node (see the module docstring for time alignment)."""

    def __init__(self, node_name: str = 'suspension_monitor', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, SuspensionImmParams,
                                      on_change=self._on_change)
        self._node_typed = TypedParameters(self, SuspensionMonitorNodeParams,
                                           on_change=self._on_node_change)
        n = self.node_params
        self.imm = SuspensionImm(self.params)
        self._mode_names = [m.name for m in self.imm.modes]
        self._rejected: Counter[str] = Counter()
        self.processed = 0
        self.known_input_samples = 0
        self._pairer = ImuPairer(n.pair_tolerance_s, n.pair_timeout_s)
        self._stamps = StampCheck(max_gap_s=math.inf)   # gaps are the core's
        self._rates = {name: RateMeter() for name in INPUTS}
        self._track: tuple[int, np.ndarray, np.ndarray | None] | None = None
        self._track_state = 'not received'
        self._creep_state = 'not received' if n.use_creep_factor else 'disabled'
        self._frozen = FrozenDetector(3)
        self._input_fault = ''
        self.last_output: ModeProbabilities | None = None
        sensor_subscription(self, Imu, 'rail/bogie/imu', self._on_bogie)
        sensor_subscription(self, Imu, 'rail/body/imu', self._on_body)
        if n.use_track_irregularity:
            sensor_subscription(self, TrackIrregularity, 'rail/track_irregularity', self._on_track)
        if n.use_creep_factor:
            sensor_subscription(self, CreepFactor, 'rail/creep_factor', self._on_creep_factor)
        self._publisher = self.create_publisher(ModeProbabilities, 'rail/suspension/modes',
                                                OUTPUT_QOS)
        self.diagnostics = Diagnostics(self, 'rail_suspension_imm', n.diagnostics_period_s,
                                       update=self._update_diagnostics)
        self._update_diagnostics()

    @property
    def params(self) -> SuspensionImmParams:
        """The method's current validated parameters."""
        return self._typed.value

    @property
    def node_params(self) -> SuspensionMonitorNodeParams:
        """The node's current validated parameters."""
        return self._node_typed.value

    @property
    def rejected(self) -> Counter[str]:
        """Rejected inputs by reason (node checks, pairing, stamps)."""
        counts = Counter(self._rejected)
        counts['unpaired'] += sum(self._pairer.unpaired.values())
        counts.update(self._pairer.rejected)
        counts.update(self._stamps.rejected)
        return +counts

    def _on_change(self, p: SuspensionImmParams) -> None:
        self.imm.update_runtime_params(p)

    def _on_node_change(self, n: SuspensionMonitorNodeParams) -> None:
        self._pairer.tolerance_s = n.pair_tolerance_s
        self._pairer.timeout_s = n.pair_timeout_s

    # ------------------------------------------------------------------ inputs
    def _on_bogie(self, msg: Imu) -> None:
        self._rates['bogie_imu'].tick()
        self._process_pairs(self._pairer.add('bogie', stamp_ns(msg.header.stamp), (
            float(msg.linear_acceleration.y), float(msg.angular_velocity.z))))

    def _on_body(self, msg: Imu) -> None:
        self._rates['body_imu'].tick()
        self._process_pairs(self._pairer.add('body', stamp_ns(msg.header.stamp),
                                             float(msg.linear_acceleration.y)))

    def _on_creep_factor(self, msg: CreepFactor) -> None:
        self._rates['creep_factor'].tick()
        c, std = float(msg.creep_factor), float(msg.std_dev)
        if not (np.isfinite(c) and 0.0 < c <= MAX_CREEP_FACTOR and np.isfinite(std)):
            self._rejected['creep_factor_invalid'] += 1
            return
        if std > self.node_params.creep_max_std:
            self._creep_state = (f'uncertain (std {std:.2f}): model keeps '
                                 f'{self.imm.creep_factor:.2f}')
            return
        self.imm.set_creep_factor(c)
        self._creep_state = 'following'

    def _on_track(self, msg: TrackIrregularity) -> None:
        self._rates['track_irregularity'].tick()
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < 2 or (rate.size not in (0, alignment.size)):
            self._rejected['track_irregularity_size'] += 1
            return
        # All four wheelsets when the model has the rear bogie, else the monitored bogie's.
        full_car = self.params.estimation_model == 'full_car'
        used = 4 if alignment.size >= 4 and full_car else 2
        if not (np.all(np.isfinite(alignment[:used])) and np.all(np.isfinite(rate[:used]))):
            self._rejected['track_irregularity_non_finite'] += 1
            return
        self._track = (stamp_ns(msg.header.stamp), alignment[:used].copy(),
                       rate[:used].copy() if rate.size else None)

    def _process_pairs(self, pairs: list[ImuPair]) -> None:
        for pair in pairs:
            if pair.body is None:
                continue                       # counted by the pairer: 'unpaired'
            if self._stamps.check(pair.stamp_ns) in ('repeated', 'out_of_order'):
                continue
            self._process(pair.stamp_ns, np.array([*pair.bogie, pair.body]))

    def _check(self, z: np.ndarray) -> str:
        n = self.node_params
        if not np.all(np.isfinite(z)):
            return 'non_finite'
        if abs(z[0]) >= n.accel_limit_mps2 or abs(z[2]) >= n.accel_limit_mps2:
            return 'saturated'
        if abs(z[1]) >= n.gyro_limit_rad_s:
            return 'saturated'
        if self._frozen.update(z) >= n.frozen_samples - 1:
            return 'frozen_sensor'
        return ''

    def _known_input(self, stamp: int) -> np.ndarray | None:
        n = self.node_params
        if not n.use_track_irregularity or self._track is None:
            self._track_state = 'not received' if n.use_track_irregularity else 'disabled'
            return None
        track_stamp, alignment, rate = self._track
        age = (stamp - track_stamp) * 1e-9
        if age < -n.pair_tolerance_s or age > n.track_max_age_s:
            self._track_state = f'stale ({age:.3f} s): process-noise model'
            return None
        self._track_state = 'fresh: known-input model'
        if self.params.estimation_model == 'full_car':
            return alignment   # measurements of the track model under the wheelsets
        # Half car: the monitored bogie's [y_lead, y_trail, psi_lead, psi_trail].
        return wheelset_inputs_from_track(alignment[None, :2],
                                          None if rate is None else rate[None, :2],
                                          self.params.vehicle.speed_mps)[0]

    def _process(self, stamp: int, z: np.ndarray) -> None:
        problem = self._check(z)
        self._input_fault = problem
        if problem:
            self._rejected[problem] += 1
            out = self.imm.step(None, stamp_ns=stamp)
        else:
            out = self.imm.step(z, self._known_input(stamp), stamp_ns=stamp)
            self.known_input_samples += int(out.known_input)
            self.processed += 1
        msg = ModeProbabilities()
        msg.header.stamp = time_msg(stamp)
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
        now_ns = self.get_clock().now().nanoseconds
        values: dict[str, Any] = {
            f'input_rate_hz.{name}': meter.read(now_ns) for name, meter in self._rates.items()}
        values.update({
            'processed_samples': self.processed,
            'known_input_samples': self.known_input_samples,
            'missing_samples': self.imm.missing_samples,
            'gap_restarts': self.imm.gap_restarts,
            'track_irregularity': self._track_state,
            'creep_factor_input': self._creep_state,
            'model_creep_factor': self.imm.creep_factor,
            'covariance_repairs': self.imm.covariance_repairs,
            'steady_state_failures': self.imm.steady_state_failures,
            'rediscretizations': self.imm.rediscretizations,
        })
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
