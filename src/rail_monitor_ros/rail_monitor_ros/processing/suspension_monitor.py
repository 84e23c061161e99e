"""The suspension monitor's logic, ROS-free: IMU pairing, input checks, the IMM, its outputs.

Inputs: ``rail/bogie/imu`` (sensor_msgs/Imu: linear_acceleration.y, angular_velocity.z),
``rail/body/imu`` (linear_acceleration.y, the body accelerometer above the monitored front
bogie) and, when enabled, ``rail/track_irregularity`` (TrackIrregularity: wheelsets front to
rear, the monitored bogie's are indices 0 and 1; the full-car model takes the alignment under
all four (or the first two) as measurements of its track model, the half-car model turns the
first two into wheelset inputs), ``rail/creep_factor`` (CreepFactor) and ``rail/speed`` (the
train's speed: :class:`~rail_monitor_ros.processing.rail_imu_inputs.SpeedInput`). Output:
``rail/suspension/modes`` (ModeProbabilities), one per processed IMU pair. The estimator is
:class:`rail_monitor_ros.core.suspension_imm.SuspensionImm`, given ``SuspensionImmParams`` as
they are; the node-only parameters are :class:`SuspensionMonitorNodeParams`.

Time: every input stream's stamps are checked on arrival (``input_health.StampCheck``):
repeated and out-of-order stamps are rejected, a lone stamp more than ``jump_horizon_s`` ahead
is dropped and counted, and a confirmed jump of data time (a looped or repeated replay, a
clock reset) restarts the IMM, the pairing and the held inputs (the status says so for
``fault_recovery_s``). The two IMUs are paired by stamp
(:class:`vehicle_monitor_common.imu_pairing.ImuPairer`, ``pair_tolerance_s``,
``pair_timeout_s``); a pair carries the bogie sample's stamp, which the output carries too. A
bogie sample without partner is dropped and counted ('unpaired'). Each pair's stamp goes to the
core, which owns data time: it bridges missing samples by prediction and restarts its states
after a gap longer than ``max_gap_s`` (probabilities kept).

* Track irregularity: sample-and-hold of the latest message not newer than the pair's stamp
  (plus ``pair_tolerance_s``); older than ``track_max_age_s``, it is stale and the
  process-noise model is used (the status says so).
* Creep factor (full car): the model follows the latest confident estimate not newer than the
  pair's stamp (re-discretised in steps of ``creep_resolution``, with hysteresis). Unmodelled,
  a creep change looks like a suspension fault.
* Speed: the model runs at the latest published speed not newer than the pair's stamp (the
  bank stepped to it, re-discretised every ``speed_resolution_mps``); stale, it keeps the last;
  below ``min_speed_mps`` the pair is an input fault (the IMM held).

Both are decided in data time, not by arrival: a pair waits until each of these streams has
delivered its sample for the pair's stamp (or a later one), unless the stream is silent for
more than ``pair_timeout_s`` of data time. So the node, whose inputs arrive from different
publishers, and the offline engine give the same outputs.

Input faults never become suspension faults. A bad IMU sample (non-finite, saturated, frozen
sensor) is rejected and counted and the IMM is not stepped: its probabilities are held (the
outputs repeat them with ``fault_detected`` false) and the status reports an input fault at
WARN. A frozen, malformed or non-finite track message is rejected; a track stream that was in
use and goes stale switches the IMM to the process-noise model. After an input fault or a
switch of the track model, and after a time jump, ``fault_detected`` stays false for
``fault_recovery_s`` of data time (the status says 'recovering'), the time the IMM needs to
settle again (measured: docs/methods/suspension_monitor.md). A configured car that is unstable
at its speed (above its critical speed: a wrong speed, conicity or suspension parameter, or a
car that hunts) declares no fault and reports ERROR until it is stable again.
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from rail_monitor_ros.core.rail_model import MAX_CREEP_FACTOR, wheelset_inputs_from_track
from rail_monitor_ros.core.suspension_imm import (
    ProbabilitySnapshot,
    SuspensionImm,
    SuspensionImmParams,
)
from rail_monitor_ros.processing.rail_imu_inputs import (
    SPEED,
    SPEED_TYPE,
    HeldStream,
    RailImuInputs,
    RailImuNodeParams,
    SpeedInput,
)
from vehicle_monitor_common.imu_pairing import ImuPair
from vehicle_monitor_common.input_health import FrozenDetector, all_finite
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.processing import (
    ERROR,
    OK,
    WARN,
    Input,
    Output,
    ParameterGroup,
    ProcessorSpec,
    Status,
)

BOGIE_IMU = 'rail/bogie/imu'
BODY_IMU = 'rail/body/imu'
TRACK = 'rail/track_irregularity'
CREEP = 'rail/creep_factor'
MODES = 'rail/suspension/modes'


@dataclass(frozen=True)
class SuspensionMonitorNodeParams(RailImuNodeParams):
    """The node's own parameters (the method's are ``SuspensionImmParams``; the IMU pairing and
    limits are :class:`RailImuNodeParams`)."""

    use_creep_factor: bool = param(True, 'full car: follow rail/creep_factor (the creep '
                                   'estimator) in the model', read_only=True)
    creep_max_std: float = param(0.2, 'a creep factor estimate with a larger std is not used, 1',
                                 low=1e-6, high=10.0)
    use_track_irregularity: bool = param(True, 'use rail/track_irregularity as known inputs '
                                         'when fresh', read_only=True)
    track_max_age_s: float = param(0.02, 'older track irregularity is stale, s', low=0.0,
                                   high=10.0)
    frozen_samples: int = param(20, 'this many identical consecutive values = frozen sensor',
                                low=2, high=100000)
    fault_recovery_s: float = param(2.0, 'after an input fault, a track or creep model switch '
                                    'or a time jump, no fault is declared for this long (the '
                                    'IMM settles), s', low=0.0, high=60.0)


class _RepeatCounter:
    """How many consecutive messages repeated the previous one exactly (all channels: a
    frozen measurement system; one constant channel may be a straight track)."""

    def __init__(self) -> None:
        self._last: np.ndarray | None = None
        self._repeats = 0

    def update(self, values: np.ndarray) -> int:
        same = self._last is not None and np.array_equal(values, self._last)
        self._repeats = self._repeats + 1 if same else 0
        self._last = values.copy()
        return self._repeats

    def reset(self) -> None:
        self._last, self._repeats = None, 0


# After a pair closer than half a period to the previous one (a burst), the IMM holds until
# the pairs have come at their rate for this many periods.
BURST_PERIODS = 10
_STREAMS = {BOGIE_IMU: 'bogie', BODY_IMU: 'body', TRACK: 'track', CREEP: 'creep',
            SPEED: 'speed'}


class SuspensionMonitorProcessor(RailImuInputs[SuspensionMonitorNodeParams]):
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
        n = node_params
        inputs = {BOGIE_IMU: Input('sensor_msgs/msg/Imu'), BODY_IMU: Input('sensor_msgs/msg/Imu')}
        if n.use_track_irregularity:
            inputs[TRACK] = Input('vehicle_monitor_msgs/msg/TrackIrregularity', optional=True)
        if n.use_creep_factor:
            inputs[CREEP] = Input('vehicle_monitor_msgs/msg/CreepFactor', optional=True)
        if n.use_speed_input:
            inputs[SPEED] = Input(SPEED_TYPE, optional=True)
        super().__init__(node_params, inputs)
        self.params = params
        self.imm = SuspensionImm(params)
        self._normal_modes = np.array([mode.kind == 'normal' for mode in self.imm.modes])
        self._mode_names = [m.name for m in self.imm.modes]
        self._rejected: Counter[str] = Counter()
        self.processed = 0
        self.known_input_samples = 0
        self.time_jumps = 0
        self._track = HeldStream()
        self._creep = HeldStream()
        self._speed = SpeedInput(n.use_speed_input)
        # The held streams a pair waits for: those this node subscribes.
        self._awaited = tuple(held for held, used in ((self._track, n.use_track_irregularity),
                                                      (self._creep, n.use_creep_factor),
                                                      (self._speed.held, n.use_speed_input))
                              if used)
        self._pending: deque[ImuPair] = deque()
        self._track_state = 'not received' if n.use_track_irregularity else 'disabled'
        self._creep_state = 'not received' if n.use_creep_factor else 'disabled'
        self._track_fresh = False
        self._track_used = False      # the known-input model has been in use
        self._frozen = FrozenDetector(3)
        # The IMM's learned state before each of the last samples (a frozen run is found late).
        self._snapshots: deque[ProbabilitySnapshot] = deque(maxlen=n.frozen_samples)
        self._track_frozen = _RepeatCounter()
        self._input_fault = ''
        # Data time until which no fault is declared, and why (input fault, model switch, jump).
        self._suppress_until_ns: int | None = None
        self._suppress_reason = ''
        self._last_stamp_ns: int | None = None
        self._burst_until_ns: int | None = None
        self.last_output: Output | None = None
        self._handlers = {BOGIE_IMU: self._on_bogie, BODY_IMU: self._on_body,
                          TRACK: self._on_track, CREEP: self._on_creep_factor,
                          SPEED: self._on_speed}

    @property
    def rejected(self) -> Counter[str]:
        """Rejected inputs by reason (input checks, pairing, stamps)."""
        counts = Counter(self._rejected)
        counts['unpaired'] += sum(self._pairer.unpaired.values())
        counts.update(self._pairer.rejected)
        counts['speed_invalid'] += self._speed.invalid
        return +counts

    def update_params(self, params: SuspensionImmParams) -> None:
        """The method's runtime-settable parameters changed."""
        self.imm.update_runtime_params(params)

    # ------------------------------------------------------------------ inputs
    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message; the outputs of the IMU pairs it completes."""
        stamp = self._received(topic, message)
        if stamp is None:
            return []
        return self._handlers[topic](stamp, message)

    def _reject_stamp(self, topic: str, verdict: str) -> None:
        self._rejected[f'{_STREAMS[topic]}_{verdict}'] += 1

    def _restart(self, stamp: int, why: str) -> None:
        """Data time jumped: the IMM, the pairing and the held inputs start again (a jump is
        no suspension change: the IMM starts from the normal mode, as at start)."""
        self.time_jumps += 1
        self.imm.reset()
        self._pairer.reset()
        self._pending.clear()
        self._track.clear()
        self._creep.clear()
        self._speed.clear()
        self._frozen.reset()
        self._snapshots.clear()
        self._track_frozen.reset()
        self._track_fresh = self._track_used = False
        self._stamp_checks = self._new_stamp_checks()
        self._last_stamp_ns = self._burst_until_ns = None
        self._suppress(stamp, why)

    def _suppress(self, stamp: int, why: str) -> None:
        self._suppress_until_ns = stamp + round(self.node_params.fault_recovery_s * 1e9)
        self._suppress_reason = why

    def _on_bogie(self, stamp: int, msg: Any) -> list[Output]:
        return self._add_pairs(self._pairer.add('bogie', stamp, (
            float(msg.linear_acceleration.y), float(msg.angular_velocity.z))))

    def _on_body(self, stamp: int, msg: Any) -> list[Output]:
        return self._add_pairs(self._pairer.add('body', stamp, float(msg.linear_acceleration.y)))

    def _on_creep_factor(self, stamp: int, msg: Any) -> list[Output]:
        self._creep.seen(stamp)
        c, std = float(msg.creep_factor), float(msg.std_dev)
        if not (math.isfinite(c) and 0.0 < c <= MAX_CREEP_FACTOR and math.isfinite(std)):
            self._rejected['creep_factor_invalid'] += 1
        else:
            self._creep.add(stamp, (c, std))
        return self._drain()

    def _on_speed(self, stamp: int, msg: Any) -> list[Output]:
        self._speed.add(stamp, msg)
        return self._drain()

    def _on_track(self, stamp: int, msg: Any) -> list[Output]:
        self._track.seen(stamp)
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < 2 or (rate.size not in (0, alignment.size)):
            self._rejected['track_irregularity_size'] += 1
            return self._drain()
        # All four wheelsets when the model has the rear bogie, else the monitored bogie's.
        full_car = self.params.estimation_model == 'full_car'
        used = 4 if alignment.size >= 4 and full_car else 2
        if not (all_finite(alignment[:used]) and all_finite(rate[:used])):
            self._rejected['track_irregularity_non_finite'] += 1
            return self._drain()
        # A track measurement repeating itself bit for bit is a frozen sensor, not a track.
        if self._track_frozen.update(alignment[:used]) >= self.node_params.frozen_samples - 1:
            self._rejected['track_irregularity_frozen'] += 1
            return self._drain()
        self._track.add(stamp, (alignment[:used].copy(),
                                rate[:used].copy() if rate.size else None))
        return self._drain()

    def _add_pairs(self, pairs: list[ImuPair]) -> list[Output]:
        for pair in pairs:
            if pair.body is not None:          # else counted by the pairer: 'unpaired'
                self._pending.append(pair)
        return self._drain()

    def _drain(self) -> list[Output]:
        """Process the waiting pairs, in stamp order, whose held inputs are settled."""
        n = self.node_params
        tolerance = round(n.pair_tolerance_s * 1e9)
        wait = round(n.pair_timeout_s * 1e9)
        outputs = []
        while self._pending:
            pair, newest = self._pending[0], self._pending[-1].stamp_ns
            if not all(held.settled(pair.stamp_ns, newest, tolerance, wait)
                       for held in self._awaited):
                break
            self._pending.popleft()
            speed, speed_fault = self._speed.at(pair.stamp_ns, n, self.imm.vehicle.speed)
            if speed is not None:
                self.imm.set_speed(speed)
            self._follow_creep(pair.stamp_ns, tolerance)
            output = self._process(pair.stamp_ns, np.array([*pair.bogie, pair.body]),
                                   speed_fault)
            if output is not None:
                outputs.append(output)
        return outputs

    def _follow_creep(self, stamp: int, tolerance: int) -> None:
        held = self._creep.at(stamp, tolerance)
        if held is None:
            return
        c, std = held[1]
        imm = self.imm
        normal = float(imm.smoothed[self._normal_modes].sum())
        if std > self.node_params.creep_max_std:
            self._creep_state = (f'uncertain (std {std:.2f}): model keeps '
                                 f'{imm.creep_factor:.2f}')
        elif imm.fault.detected or normal < 0.5:
            # Under a suspension fault the creep estimate may be off (on
            # rail_imm_spring_damper_fault a full-car creep model without suspension error
            # states ran 0.72-1.57 for a true 1.0, std 0.06-0.29), and every switch of the
            # bank suppresses the declaration (a damper fault declared after 3.6 s instead of
            # 0.09 s). Held until the suspension is normal again.
            self._creep_state = (f'held while a suspension fault is suspected: model keeps '
                                 f'{imm.creep_factor:.2f}')
        else:
            before = imm.creep_factor
            imm.set_creep_factor(c)
            self._creep_state = 'following'
            if imm.creep_factor != before:
                # The bank was rebuilt for another creep factor while the estimate still
                # settles after the step: a transient that is no suspension change (measured:
                # a false damper fault on rail_creep_steps once the factor is followed without
                # lag), so no fault is declared while the IMM settles, as after a track switch.
                self._suppress(stamp, 'creep model switched')

    def _check(self, z: np.ndarray) -> str:
        n = self.node_params
        if not all_finite(z):
            return 'non_finite'
        if n.imu_saturated(z):
            return 'saturated'
        if self._frozen.update(z) >= n.frozen_samples - 1:
            return 'frozen_sensor'
        return ''

    def _known_input(self, stamp: int) -> np.ndarray | None:
        n = self.node_params
        held = self._track.at(stamp, round(n.pair_tolerance_s * 1e9))
        fresh = False
        if not n.use_track_irregularity:
            self._track_state = 'disabled'
        elif held is None:
            self._track_state = ('not received' if self._track.latest is None
                                 else 'stale: process-noise model')
        else:
            age = (stamp - held[0]) * 1e-9
            fresh = -n.pair_tolerance_s <= age <= n.track_max_age_s
            self._track_state = ('fresh: known-input model' if fresh
                                 else f'stale ({age:.3f} s): process-noise model')
        if fresh != self._track_fresh and self._track_used:
            # The IMM's model switches (not the first time the track comes): its probabilities
            # settle first.
            self._suppress(stamp, f'track input {"back" if fresh else "stale"}')
        self._track_fresh = fresh
        self._track_used = self._track_used or fresh
        if not fresh or held is None:
            return None
        alignment, rate = held[1]
        if self.params.estimation_model == 'full_car':
            return alignment   # measurements of the track model under the wheelsets
        # Half car: the monitored bogie's [y_lead, y_trail, psi_lead, psi_trail].
        return wheelset_inputs_from_track(alignment[None, :2],
                                          None if rate is None else rate[None, :2],
                                          self.params.vehicle.speed)[0]

    def _process(self, stamp: int, z: np.ndarray, speed_fault: str) -> Output | None:
        period_ns = 1e9 / self.params.sample_rate_hz
        if self._last_stamp_ns is not None and stamp - self._last_stamp_ns < 0.5 * period_ns:
            # Closer than half a period to the previous pair: a burst, not the sensor's rate;
            # the IMM holds until the stream is back at its rate for BURST_PERIODS periods.
            self._rejected['rate_burst'] += 1
            self._burst_until_ns = stamp + round(BURST_PERIODS * period_ns)
            return None
        self._last_stamp_ns = stamp
        problem = self._check(z) or speed_fault
        if not problem and self._burst_until_ns is not None and stamp < self._burst_until_ns:
            problem = 'rate_burst'
        if problem:
            # Held: the IMM is not stepped (a gap for its data time when the input returns).
            if problem == 'frozen_sensor' and self._input_fault != problem and self._snapshots:
                # Found frozen after frozen_samples: the IMM had taken the run's first samples;
                # back to before them (probabilities and decision; the states restart).
                run = min(self.node_params.frozen_samples - 1, len(self._snapshots))
                self.imm.restore(self._snapshots[-run])
                self._snapshots.clear()
            self._rejected[problem] += 1
            self._input_fault = problem
            self._suppress(stamp, f'input fault ({problem})')
            if self.last_output is None:
                return None
            imm = self.imm      # held (or restored): what it knew before the fault
            fields = {**self.last_output.fields, 'probability': imm.mu.copy(),
                      'smoothed_probability': imm.smoothed.copy(),
                      'most_likely': int(np.argmax(imm.smoothed)),
                      'spring_ratio': imm.spring_ratio, 'damper_ratio': imm.damper_ratio}
        else:
            self._input_fault = ''
            self._snapshots.append(self.imm.snapshot())
            out = self.imm.step(z, self._known_input(stamp), stamp_ns=stamp)
            self.known_input_samples += int(out.known_input)
            self.processed += 1
            fields = {
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
                'fault_component': out.fault.component}
        if not self.imm.model_stable:
            # The configured car is unstable at this speed (above its critical speed): the
            # modes' likelihoods mean nothing (measured on healthy development cars with the
            # model told 1.05-1.2 x their critical speed: normal below 0.5 for 62-83 % of
            # the time), so no fault is declared until the model is stable again and settled.
            self._suppress(stamp, 'the model was unstable')
        if self._suppressed(stamp):
            fields.update(fault_detected=False, fault_component='')
        self.last_output = Output(MODES, stamp, fields)
        return self.last_output

    def _suppressed(self, stamp: int) -> bool:
        return self._suppress_until_ns is not None and stamp < self._suppress_until_ns

    # ------------------------------------------------------------------ status
    def status(self, now_ns: int) -> Status:
        """Input rates and health, pairing, the model's state and the decision."""
        values: dict[str, Any] = {
            f'input_rate_hz.{topic}': rate for topic, rate in self._input_rates(now_ns).items()}
        values.update({
            'processed_samples': self.processed,
            'known_input_samples': self.known_input_samples,
            'missing_samples': self.imm.missing_samples,
            'gap_restarts': self.imm.gap_restarts,
            'time_jumps': self.time_jumps,
            'track_irregularity': self._track_state,
            'creep_factor_input': self._creep_state,
            'speed_input': self._speed.state,
            'model_speed': self.imm.vehicle.speed,
            'model_creep_factor': self.imm.creep_factor,
            'model_stable': self.imm.model_stable,
            'covariance_repairs': self.imm.covariance_repairs,
            'steady_state_failures': self.imm.steady_state_failures,
            'rediscretizations': self.imm.rediscretizations,
            'waiting_pairs': len(self._pending),
        })
        values.update({f'rejected_{k}': v for k, v in sorted(self.rejected.items())})
        if self.last_output is None:
            new = self._new_rejections(self.rejected, self.params.sample_rate_hz)
            return Status(WARN if new else OK, f'inputs rejected: {new}' if new
                          else 'waiting for paired IMU samples', values)
        out = self.last_output.fields
        spring, damper, component = out['spring_ratio'], out['damper_ratio'], \
            out['fault_component']
        values.update({
            'most_likely_mode': self._mode_names[out['most_likely']],
            'spring_ratio': spring, 'damper_ratio': damper,
            'fault_component': component or 'none'})
        # Silence (the adapter reports it per input at ERROR): never claim 'normal' on old data.
        silent_s = self._silent_s(self.processed + self._rejected_samples(), now_ns)
        if silent_s > self.node_params.silence_timeout_s:
            return Status(WARN, f'no IMU pair for {silent_s:.1f} s: suspension state unknown',
                          values)
        if self._input_fault:
            return Status(WARN, f'input fault ({self._input_fault}): estimates held, '
                          'suspension state unknown', values)
        new = self._new_rejections(self.rejected, self.params.sample_rate_hz)
        if new:
            return Status(WARN, f'inputs rejected since last report: {new}', values)
        if not self.imm.model_stable:
            imm = self.imm
            return Status(ERROR, f'the configured car is unstable at {imm.vehicle.speed:.1f} m/s '
                          f'(creep factor {imm.creep_factor:.2f}): above its critical speed, no '
                          'fault decision; check vehicle.speed and the vehicle parameters', values)
        if self._last_stamp_ns is not None and self._suppressed(self._last_stamp_ns):
            assert self._suppress_until_ns is not None
            left = (self._suppress_until_ns - self._last_stamp_ns) * 1e-9
            return Status(WARN, f'recovering after {self._suppress_reason}: no fault decision '
                          f'for {left:.1f} s', values)
        if self.node_params.use_track_irregularity and self._track.latest is not None \
                and not self._track_fresh:
            return Status(WARN, f'track input {self._track_state}', values)
        if self._speed.stale:
            return Status(WARN, f'speed input {self._speed.state}', values)
        if out['fault_detected']:
            size = {'spring': f'spring {spring:.2f}', 'damper': f'damper {damper:.2f}',
                    'spring+damper': f'spring {spring:.2f}, damper {damper:.2f}'}[component]
            severe = (component == 'spring+damper'
                      or max(abs(spring - 1.0), abs(damper - 1.0)) >= 0.4)
            return Status(ERROR if severe else WARN, f'suspension fault: {size} x nominal',
                          values)
        return Status(OK, 'suspension normal', values)

    def _rejected_samples(self) -> int:
        return sum(v for k, v in self._rejected.items()
                   if k in ('non_finite', 'saturated', 'frozen_sensor'))


# The node, declared once: the live node (nodes/suspension_monitor_node.py) and the offline
# engine (make_processor, the registered entry point) build it from this.
SPEC = ProcessorSpec(
    'suspension_monitor', 'rail_suspension_imm', make=SuspensionMonitorProcessor,
    groups=(ParameterGroup(SuspensionImmParams, 'update_params'),
            ParameterGroup(SuspensionMonitorNodeParams, 'update_node_params')))
make_processor = SPEC.make_processor
