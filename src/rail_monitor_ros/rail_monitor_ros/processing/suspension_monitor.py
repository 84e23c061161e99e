"""The suspension monitor's logic, ROS-free: IMU pairing, input checks, the IMM, its outputs.

Inputs: ``rail/bogie/imu`` (sensor_msgs/Imu: linear_acceleration.y, angular_velocity.z),
``rail/body/imu`` (linear_acceleration.y, the body accelerometer above the monitored front
bogie) and, when enabled, ``rail/track_irregularity`` (TrackIrregularity: wheelsets front to
rear, the monitored bogie's are indices 0 and 1; the full-car model takes the alignment under
all four (or the first two) as measurements of its track model, the half-car model turns the
first two into wheelset inputs) and ``rail/creep_factor`` (CreepFactor). Output:
``rail/suspension/modes`` (ModeProbabilities), one per processed IMU pair. The estimator is
:class:`rail_monitor_ros.core.suspension_imm.SuspensionImm`, given ``SuspensionImmParams`` as
they are; the node-only parameters are :class:`SuspensionMonitorNodeParams`.

Time: the two IMUs are paired by stamp (:class:`vehicle_monitor_common.imu_pairing.ImuPairer`,
``pair_tolerance_s``, ``pair_timeout_s``); a pair carries the bogie sample's stamp, which the
output carries too. A bogie sample without partner is dropped and counted ('unpaired').
Repeated and out-of-order stamps are rejected here; each pair's stamp goes to the core, which
owns data time: it bridges missing samples by prediction and restarts its states after a gap
longer than ``max_gap_s`` (probabilities kept).

* Creep factor (full car): the model follows the latest confident estimate as it arrives
  (re-discretised in steps of ``creep_resolution``, with hysteresis). Unmodelled, a creep change
  looks like a suspension fault.
* Track irregularity: sample-and-hold of the latest message not newer than the pair's stamp
  (plus ``pair_tolerance_s``); older than ``track_max_age_s``, it is stale and the
  process-noise model is used (the status says so).

Bad input (non-finite, saturated, frozen sensor, wrong array sizes) is rejected and counted;
the IMM then only predicts, so no fault is declared from bad data; the status reports an input
fault instead.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from rail_monitor_ros.core.rail_model import MAX_CREEP_FACTOR, wheelset_inputs_from_track
from rail_monitor_ros.core.suspension_imm import SuspensionImm, SuspensionImmParams
from vehicle_monitor_common.imu_pairing import ImuPair, ImuPairer
from vehicle_monitor_common.input_health import FrozenDetector, RateMeter, StampCheck
from vehicle_monitor_common.parameters import ConfigurationError, build, param
from vehicle_monitor_common.processing import ERROR, OK, WARN, Input, Output, Status

BOGIE_IMU = 'rail/bogie/imu'
BODY_IMU = 'rail/body/imu'
TRACK = 'rail/track_irregularity'
CREEP = 'rail/creep_factor'
MODES = 'rail/suspension/modes'


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
    silence_timeout_s: float = param(1.0, 'an input silent this long after it flowed is an '
                                     'error on /diagnostics, s', low=0.01, high=3600.0,
                                     read_only=True)


def _stamp_ns(message: Any) -> int:
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class SuspensionMonitorProcessor:
    """What the suspension monitor does with its inputs (see the module docstring).

    Args:
        params: the method's parameters, handed to the IMM as they are.
        node_params: pairing, input checks and diagnostics.
    """

    # Typed as the Processor protocol declares them (its attributes are invariant).
    inputs: Mapping[str, Input]
    outputs: Mapping[str, str] = {MODES: 'vehicle_monitor_msgs/msg/ModeProbabilities'}

    def __init__(self, params: SuspensionImmParams,
                 node_params: SuspensionMonitorNodeParams) -> None:
        self.params = params
        self.node_params = n = node_params
        inputs = {BOGIE_IMU: Input('sensor_msgs/msg/Imu'), BODY_IMU: Input('sensor_msgs/msg/Imu')}
        if n.use_track_irregularity:
            inputs[TRACK] = Input('vehicle_monitor_msgs/msg/TrackIrregularity', optional=True)
        if n.use_creep_factor:
            inputs[CREEP] = Input('vehicle_monitor_msgs/msg/CreepFactor', optional=True)
        self.inputs = inputs
        self.imm = SuspensionImm(params)
        self._mode_names = [m.name for m in self.imm.modes]
        self._rejected: Counter[str] = Counter()
        self.processed = 0
        self.known_input_samples = 0
        self._pairer = ImuPairer(n.pair_tolerance_s, n.pair_timeout_s)
        self._stamps = StampCheck(max_gap_s=math.inf)   # gaps are the core's
        self._rates = {topic: RateMeter() for topic in self.inputs}
        self._track: tuple[int, np.ndarray, np.ndarray | None] | None = None
        self._track_state = 'not received' if n.use_track_irregularity else 'disabled'
        self._creep_state = 'not received' if n.use_creep_factor else 'disabled'
        self._frozen = FrozenDetector(3)
        self._input_fault = ''
        self.last_output: Output | None = None
        self._handlers = {BOGIE_IMU: self._on_bogie, BODY_IMU: self._on_body,
                          TRACK: self._on_track, CREEP: self._on_creep_factor}

    @property
    def rejected(self) -> Counter[str]:
        """Rejected inputs by reason (input checks, pairing, stamps)."""
        counts = Counter(self._rejected)
        counts['unpaired'] += sum(self._pairer.unpaired.values())
        counts.update(self._pairer.rejected)
        counts.update(self._stamps.rejected)
        return +counts

    def update_params(self, params: SuspensionImmParams) -> None:
        """The method's runtime-settable parameters changed."""
        self.imm.update_runtime_params(params)

    def update_node_params(self, node_params: SuspensionMonitorNodeParams) -> None:
        """The node's runtime-settable parameters changed."""
        self.node_params = node_params
        self._pairer.tolerance_s = node_params.pair_tolerance_s
        self._pairer.timeout_s = node_params.pair_timeout_s

    # ------------------------------------------------------------------ inputs
    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message; the outputs of the IMU pairs it completes."""
        self._rates[topic].tick()
        return self._handlers[topic](message)

    def _on_bogie(self, msg: Any) -> list[Output]:
        return self._process_pairs(self._pairer.add('bogie', _stamp_ns(msg), (
            float(msg.linear_acceleration.y), float(msg.angular_velocity.z))))

    def _on_body(self, msg: Any) -> list[Output]:
        return self._process_pairs(self._pairer.add('body', _stamp_ns(msg),
                                                    float(msg.linear_acceleration.y)))

    def _on_creep_factor(self, msg: Any) -> list[Output]:
        c, std = float(msg.creep_factor), float(msg.std_dev)
        if not (np.isfinite(c) and 0.0 < c <= MAX_CREEP_FACTOR and np.isfinite(std)):
            self._rejected['creep_factor_invalid'] += 1
        elif std > self.node_params.creep_max_std:
            self._creep_state = (f'uncertain (std {std:.2f}): model keeps '
                                 f'{self.imm.creep_factor:.2f}')
        else:
            self.imm.set_creep_factor(c)
            self._creep_state = 'following'
        return []

    def _on_track(self, msg: Any) -> list[Output]:
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < 2 or (rate.size not in (0, alignment.size)):
            self._rejected['track_irregularity_size'] += 1
            return []
        # All four wheelsets when the model has the rear bogie, else the monitored bogie's.
        full_car = self.params.estimation_model == 'full_car'
        used = 4 if alignment.size >= 4 and full_car else 2
        if not (np.all(np.isfinite(alignment[:used])) and np.all(np.isfinite(rate[:used]))):
            self._rejected['track_irregularity_non_finite'] += 1
            return []
        self._track = (_stamp_ns(msg), alignment[:used].copy(),
                       rate[:used].copy() if rate.size else None)
        return []

    def _process_pairs(self, pairs: list[ImuPair]) -> list[Output]:
        outputs = []
        for pair in pairs:
            if pair.body is None:
                continue                       # counted by the pairer: 'unpaired'
            if self._stamps.check(pair.stamp_ns) in ('repeated', 'out_of_order'):
                continue
            outputs.append(self._process(pair.stamp_ns, np.array([*pair.bogie, pair.body])))
        return outputs

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
                                          self.params.vehicle.speed)[0]

    def _process(self, stamp: int, z: np.ndarray) -> Output:
        problem = self._check(z)
        self._input_fault = problem
        if problem:
            self._rejected[problem] += 1
            out = self.imm.step(None, stamp_ns=stamp)
        else:
            out = self.imm.step(z, self._known_input(stamp), stamp_ns=stamp)
            self.known_input_samples += int(out.known_input)
            self.processed += 1
        self.last_output = Output(MODES, stamp, {
            'header': {'frame_id': 'front_bogie'},
            'modes': self._mode_names,
            'probability': out.probability,
            'smoothed_probability': out.smoothed_probability,
            'mode_spring_ratio': out.mode_spring_ratio,
            'mode_damper_ratio': out.mode_damper_ratio,
            'most_likely': out.most_likely,
            'spring_ratio': out.spring_ratio,
            'damper_ratio': out.damper_ratio,
            'fault_detected': out.fault.detected,
            'fault_component': out.fault.component})
        return self.last_output

    # ------------------------------------------------------------------ status
    def status(self, now_ns: int) -> Status:
        """Input rates and health, pairing, the model's state and the decision."""
        values: dict[str, Any] = {
            f'input_rate_hz.{topic}': meter.read(now_ns) for topic, meter in self._rates.items()}
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
        if self.last_output is None:
            return Status(OK, 'waiting for paired IMU samples', values)
        out = self.last_output.fields
        spring, damper, component = out['spring_ratio'], out['damper_ratio'], \
            out['fault_component']
        values.update({
            'most_likely_mode': self._mode_names[out['most_likely']],
            'spring_ratio': spring, 'damper_ratio': damper,
            'fault_component': component or 'none'})
        if self._input_fault:
            return Status(WARN, f'input fault ({self._input_fault}): estimates held', values)
        if out['fault_detected']:
            size = {'spring': f'spring {spring:.2f}', 'damper': f'damper {damper:.2f}',
                    'spring+damper': f'spring {spring:.2f}, damper {damper:.2f}'}[component]
            severe = (component == 'spring+damper'
                      or max(abs(spring - 1.0), abs(damper - 1.0)) >= 0.4)
            return Status(ERROR if severe else WARN, f'suspension fault: {size} x nominal',
                          values)
        return Status(OK, 'suspension normal', values)


def make_processor(values: Mapping[str, Any], fqn: str) -> SuspensionMonitorProcessor:
    """The processor from a node's parameter values (dotted names, as the node gets them);
    the offline engine's way in (entry point group ``vehicle_monitor.processors``).

    Raises:
        ConfigurationError: a value its definition refuses.
    """
    try:
        return SuspensionMonitorProcessor(build(SuspensionImmParams, values),
                                          build(SuspensionMonitorNodeParams, values))
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f'{fqn}: invalid parameters: {exc}') from None
