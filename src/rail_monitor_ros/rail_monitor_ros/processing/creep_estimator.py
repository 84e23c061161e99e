"""The creep estimator's logic, ROS-free: sample assembly, input checks, the EKF, its output.

Inputs, per the ``pattern`` parameter: ``rail/lateral_states`` (RailLateralStates; patterns
A-C) or ``rail/bogie/imu`` + ``rail/body/imu`` (sensor_msgs/Imu; pattern D), and optionally
``rail/track_irregularity`` (TrackIrregularity) and ``rail/speed`` (the train's speed, held per
sample as the model's: :class:`~rail_monitor_ros.processing.rail_imu_inputs.SpeedInput`; a
sample waits until the speed stream has reached its stamp or fallen silent). Output:
``rail/creep_factor`` (CreepFactor) for every processed sample, stamped with that sample's
stamp. The estimator is
:class:`rail_monitor_ros.core.creep_ekf.CreepEkf`, given ``CreepEkfParams`` as they are; the
node-only parameters are :class:`CreepEstimatorNodeParams`.

Time alignment. The *driving* stream is ``rail/lateral_states`` (A-C) or the bogie IMU (D); its
stamp is the sample time. For D the two IMUs are paired first
(:class:`vehicle_monitor_common.imu_pairing.ImuPairer`, ``pair_tolerance_s``,
``pair_timeout_s``); a bogie sample without its body partner makes the sample missing
(prediction only, counted ``unpaired``). The track alignment is paired with the driving sample
when their stamps differ by at most ``pair_tolerance_s``. A sample is processed once it is
complete, or as soon as every stream still missing its part has delivered a later stamp
(topics arrive in order, so that part will not come): it then goes on without it, in the
unknown-input mode for that sample. The track stream is waited for only while it is alive (its
last stamp within ``track_max_age_s`` of the sample); beyond, it is *stale*: reported in the
status, and the filter runs on with the track as process noise.

Data time is the core's (:meth:`CreepEkf.advance_to`): it bridges missing samples by
prediction and resets after a gap longer than its ``max_gap_s``. Here, every input stream's
stamps are checked on arrival (``input_health.StampCheck``): out-of-order and repeated stamps
are rejected, a lone stamp more than ``jump_horizon_s`` ahead is dropped and counted, and a
confirmed jump of data time (a looped or repeated replay, a clock reset) restarts the filter
and the assembly (the status says so for ``recovery_s``). NaN in a field the pattern reads
(:func:`~rail_monitor_ros.core.creep_ekf.pattern_fields`; pattern D: its three IMU channels) is
that field not measured: the pattern is not fed, the sample is rejected and the status is ERROR
naming the pattern and the fields until they arrive again (NaN elsewhere is ignored). Other
non-finite or wrongly sized values are rejected (the sample becomes a prediction step); a
measurement channel frozen (bit-identical) for ``frozen_s`` is a dead sensor and its sample is
rejected (``input_health.FrozenDetector``); pattern D: an acceleration or yaw rate at its limit
is saturated and rejected. All counted in the status.

Input faults never become a low-adhesion alarm. While the driving measurement is rejected, and
(patterns B-D, which cannot observe c without it) while a track input that was in use is
lost, stale, frozen or malformed, the filter only predicts: c is held, its published
``std_dev`` is widened to at least :data:`UNKNOWN_STD` (unknown; the suspension monitor then
ignores it) and ``low_adhesion`` keeps its last value. For ``recovery_s`` after such a fault
ends, the estimate is still reported with the widened std and the status says 'recovering'
(the time the filter needs to settle again: measured, docs/methods/creep_estimator.md).

Why known input when available: with the measured track alignment (the paper's setup) the
yaw creep moment's input is known, which is what makes c observable from bogie and body
motion; without it (unknown-input mode) only pattern A (wheelset states measured) still tracks
c (see the creep_ekf tests): patterns B-D then drift.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass, replace
import math
from typing import Any

import numpy as np

from rail_monitor_ros.core.creep_ekf import (
    CreepEkf,
    CreepEkfParams,
    CreepEstimate,
    lateral_states_measurement,
    measurement_fields,
    pattern_fields,
    track_wheelsets,
)
from rail_monitor_ros.processing.rail_imu_inputs import (
    SPEED,
    SPEED_TYPE,
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

LATERAL_STATES = 'rail/lateral_states'
BOGIE_IMU = 'rail/bogie/imu'
BODY_IMU = 'rail/body/imu'
TRACK = 'rail/track_irregularity'
CREEP = 'rail/creep_factor'
# Published std_dev of an estimate that is held, not measured (input fault, track lost): c is
# unknown within about its whole range (the suspension monitor's creep_max_std refuses it).
UNKNOWN_STD = 1.0
_LATERAL_SIZES = {'wheelset': 4, 'bogie': 2, 'body': 1}   # RailLateralStates' fixed sizes
LATERAL_FIELDS = ('wheelset_lateral', 'wheelset_lateral_rate', 'wheelset_yaw',
                  'wheelset_yaw_rate', 'bogie_lateral', 'bogie_lateral_rate', 'bogie_yaw',
                  'bogie_yaw_rate', 'body_lateral', 'body_lateral_rate', 'body_yaw',
                  'body_yaw_rate')
_FIELD_SIZES = {name: _LATERAL_SIZES[name.split('_')[0]] for name in LATERAL_FIELDS}


@dataclass(frozen=True)
class CreepEstimatorNodeParams(RailImuNodeParams):
    """The node's own parameters (the method's are ``CreepEkfParams``; the IMU pairing and
    limits, pattern D's, are :class:`RailImuNodeParams`)."""

    # A sample's parts (the IMUs, or the lateral states, and the track) come from separate
    # publishers: twice the suspension monitor's tolerance.
    pair_tolerance_s: float = param(0.002, 'largest stamp difference of a bogie/body IMU pair '
                                    '(and of the parts of one sample), s', low=0.0, high=1.0)
    use_track_input: bool = param(True, 'use rail/track_irregularity when it is published '
                                  '(known-input mode)', read_only=True)
    track_max_age_s: float = param(0.1, 'the track stream is stale when its last stamp is this '
                                   'much older than the sample, s', low=0.001, high=60.0)
    frozen_s: float = param(0.02, 'a measurement channel bit-identical for this long is a dead '
                            'sensor and its sample rejected, s', low=0.001, high=60.0)
    max_pending: int = param(200, 'most samples waiting for their parts', low=2, high=100000,
                             read_only=True)
    recovery_s: float = param(1.0, 'after an input fault or a time jump the estimate is '
                              'reported unknown (std widened) this long while the filter '
                              'settles, s', low=0.0, high=600.0)


@dataclass
class _Pending:
    """One sample being assembled from its streams (``main``: the driving measurement)."""

    stamp: int
    main: np.ndarray | None = None
    track: np.ndarray | None = None
    unfed: tuple[str, ...] = ()     # the pattern's fields the driving message lacks (NaN)


_MISSING = np.empty(0)
# After a sample closer than half a period to the previous one (a burst), the filter only
# predicts until the samples have come at their rate for this many periods.
BURST_PERIODS = 10
# Counters of rejected inputs (the status names the new ones).
_REJECTIONS = ('missing_fields', 'frozen', 'wrong_size', 'non_finite', 'saturated', 'rate_burst',
               'track_wrong_size', 'track_frozen', 'main_late', 'track_late', 'overflow',
               'below_min_speed')
_WRONG_SIZE = np.empty(0)
# Pattern D's measurement channels, in the order of its vector.
_IMU_CHANNELS = (f'{BOGIE_IMU} linear_acceleration.y', f'{BOGIE_IMU} angular_velocity.z',
                 f'{BODY_IMU} linear_acceleration.y')


class CreepEstimatorProcessor(RailImuInputs[CreepEstimatorNodeParams]):
    """What the creep estimator does with its inputs (see the module docstring).

    Args:
        params: the method's parameters, handed to the EKF as they are.
        node_params: assembly, input checks and diagnostics.
    """

    outputs = {CREEP: 'vehicle_monitor_msgs/msg/CreepFactor'}

    def __init__(self, params: CreepEkfParams, node_params: CreepEstimatorNodeParams) -> None:
        inputs: dict[str, Input] = {}
        if params.pattern == 'D':
            inputs[BOGIE_IMU] = Input('sensor_msgs/msg/Imu')
            inputs[BODY_IMU] = Input('sensor_msgs/msg/Imu')
        else:
            inputs[LATERAL_STATES] = Input('vehicle_monitor_msgs/msg/RailLateralStates')
        if node_params.use_track_input:
            inputs[TRACK] = Input('vehicle_monitor_msgs/msg/TrackIrregularity', optional=True)
        if node_params.use_speed_input:
            inputs[SPEED] = Input(SPEED_TYPE, optional=True)
        super().__init__(node_params, inputs)
        self.ekf = CreepEkf(params)
        # Patterns A-C of the end model measure a selection of the lateral states' fields.
        self._selection = (None if params.pattern == 'D' else
                           measurement_fields(params.pattern, params.bogie, params.model))
        self._driving = BOGIE_IMU if params.pattern == 'D' else LATERAL_STATES
        self._handlers = {LATERAL_STATES: self._on_lateral_states, BOGIE_IMU: self._on_bogie,
                          BODY_IMU: self._on_body, TRACK: self._on_track,
                          SPEED: self._on_speed}
        self._speed = SpeedInput(node_params.use_speed_input)
        self._pending: list[_Pending] = []
        self._latest = {'main': -1, 'track': -1}
        self._stamp_rejected: dict[str, int] = {}
        self._last_processed_ns: int | None = None
        self._frozen = FrozenDetector(self.ekf.n_measurements)
        self._track_frozen: FrozenDetector | None = None
        self._track_frozen_size = 0
        self._period_ns = round(1e9 / params.sample_rate_hz)
        self._counts = dict.fromkeys(
            ('received', 'processed', 'published', 'frozen', 'wrong_size', 'overflow',
             'known_input', 'unknown_input', 'track_received', 'track_wrong_size', 'main_late',
             'track_late', 'non_finite', 'saturated', 'track_frozen', 'track_lost', 'held',
             'time_jumps', 'rate_burst', 'missing_fields', 'below_min_speed'), 0)
        self.last: CreepEstimate | None = None
        # Input faults: the current one, and the data time until which the estimate is still
        # reported unknown (and why); the low-adhesion flag held meanwhile.
        self._fault = ''
        self._unfed: tuple[str, ...] = ()   # of the last processed sample
        self._recover_until_ns: int | None = None
        self._recover_reason = ''
        self._held_low_adhesion = False
        self._track_used = False      # a sample had its track part (known-input mode in use)
        self._resets_seen = 0
        self._burst_until_ns: int | None = None
        self._arrivals: dict[str, int] = {}     # last stamp of each measurement stream
        self._track_stale = True

    @property
    def params(self) -> CreepEkfParams:
        """The method's current parameters."""
        return self.ekf.params

    @property
    def counts(self) -> dict[str, int]:
        """Input, pairing and rejection counters (core ones: ``ekf``)."""
        return {**self._counts, 'unpaired': self._pairer.unpaired['bogie'],
                'unpaired_body': self._pairer.unpaired['body'],
                'predicted_missing': self.ekf.predicted_missing,
                'gap_resets': self.ekf.gap_resets}

    def update_params(self, params: CreepEkfParams) -> None:
        """The method's runtime-settable parameters changed: speed, the low-adhesion flag and
        the gap limit (the others are read-only)."""
        self.ekf.params = replace(self.ekf.params,
                                  low_adhesion_threshold=params.low_adhesion_threshold,
                                  low_adhesion_hysteresis=params.low_adhesion_hysteresis,
                                  max_gap_s=params.max_gap_s)
        self.ekf.set_speed(params.vehicle.speed)

    # -- input ---------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message; the outputs of the samples it completes."""
        if topic == self._driving:
            self._counts['received'] += 1
        stamp = self._received(topic, message)
        if stamp is None or self._burst(topic, stamp):
            return []
        return self._handlers[topic](stamp, message)

    def _burst(self, topic: str, stamp: int) -> bool:
        """Whether a measurement sample comes closer than half a period after the previous
        one of its stream (a burst, not the sensor's rate): refused, and the filter only
        predicts until the stream is back at its rate for BURST_PERIODS periods."""
        if topic == TRACK:
            return False
        last, self._arrivals[topic] = self._arrivals.get(topic), stamp
        if last is not None and 2 * (stamp - last) < self._period_ns:
            self._counts['rate_burst'] += 1
            self._burst_until_ns = stamp + BURST_PERIODS * self._period_ns
            return True
        return False

    def _reject_stamp(self, topic: str, verdict: str) -> None:
        del topic       # counted by reason over all inputs
        self._stamp_rejected[verdict] = self._stamp_rejected.get(verdict, 0) + 1

    def _restart(self, stamp: int, why: str) -> None:
        """Data time jumped: the filter and the assembly start again (as at start)."""
        self._counts['time_jumps'] += 1
        # A new filter (as at start; data time starts again with the next stamp), its
        # counters carried on.
        old, self.ekf = self.ekf, CreepEkf(self.ekf.params)
        self.ekf.rejected, self.ekf.resets = old.rejected, old.resets
        self.ekf.gap_resets, self.ekf.predicted_missing = old.gap_resets, old.predicted_missing
        self._resets_seen = sum(self.ekf.resets.values()) + self.ekf.gap_resets
        self._pairer.reset()
        self._pending.clear()
        self._latest = {'main': -1, 'track': -1}
        self._last_processed_ns = self._burst_until_ns = None
        self._speed.clear()
        self._arrivals.clear()
        self._frozen.reset()
        self._track_frozen = None
        self._track_used = False
        self._fault = ''
        self._stamp_checks = self._new_stamp_checks()
        self._recover(stamp, why)

    def _recover(self, stamp: int, why: str) -> None:
        if not self._recovering(stamp):
            self._held_low_adhesion = bool(self.last.low_adhesion) if self.last else False
        self._recover_until_ns = stamp + round(self.node_params.recovery_s * 1e9)
        self._recover_reason = why

    def _recovering(self, stamp: int) -> bool:
        return self._recover_until_ns is not None and stamp < self._recover_until_ns

    def _on_lateral_states(self, stamp: int, msg: Any) -> list[Output]:
        p = self.params
        try:
            fields = {name: np.asarray(getattr(msg, name), dtype=float)
                      for name in LATERAL_FIELDS}
            sizes = {name: f.size for name, f in fields.items()}
            if any(sizes[name] != size for name, size in _FIELD_SIZES.items()):
                raise ValueError(f'array sizes {sizes}')
            if self._selection is not None:
                # The vector is a selection of fields: taken directly, one sample.
                vector = np.array([fields[name] if index is None else fields[name][index]
                                   for name, index in self._selection])
            else:
                vector = lateral_states_measurement(
                    {name: f[None, ...] for name, f in fields.items()}, p.pattern, p.bogie,
                    p.vehicle.bogie_pivot_semi_spacing, p.model)[0]
        except (ValueError, IndexError):
            # Unreachable over DDS for fixed-size arrays, but an in-process caller can: the
            # sample is missing (prediction only), not a gap.
            self._counts['wrong_size'] += 1
            return self._add_part('main', stamp, _WRONG_SIZE)
        # NaN is the message's "not measured": the pattern is not fed (other fields may be NaN).
        # Every field the pattern reads enters its vector, so only a NaN there names them.
        unfed = () if all_finite(vector) else tuple(
            name if index is None else f'{name}[{index}]'
            for name, index in pattern_fields(p.pattern, p.bogie, p.model)
            if np.isnan(fields[name] if index is None else fields[name][index]))
        return self._add_part('main', stamp, vector, unfed)

    def _on_bogie(self, stamp: int, msg: Any) -> list[Output]:
        return self._add_pairs(self._pairer.add('bogie', stamp, (
            float(msg.linear_acceleration.y), float(msg.angular_velocity.z))))

    def _on_body(self, stamp: int, msg: Any) -> list[Output]:
        return self._add_pairs(self._pairer.add('body', stamp, float(msg.linear_acceleration.y)))

    def _add_pairs(self, pairs: list[ImuPair]) -> list[Output]:
        outputs: list[Output] = []
        for pair in pairs:
            if pair.body is None:
                # A bogie sample without its body partner is a missing sample (prediction
                # only): an empty measurement marks it.
                outputs += self._add_part('main', pair.stamp_ns, _MISSING)
                continue
            vector = np.array([*pair.bogie, pair.body])
            unfed = tuple(name for name, value in zip(_IMU_CHANNELS, vector, strict=True)
                          if np.isnan(value))
            outputs += self._add_part('main', pair.stamp_ns, vector, unfed)
        return outputs

    def _on_speed(self, stamp: int, msg: Any) -> list[Output]:
        self._speed.add(stamp, msg)
        return self._drain()

    def _on_track(self, stamp: int, msg: Any) -> list[Output]:
        self._counts['track_received'] += 1
        pair = track_wheelsets(self.params.bogie, self.params.model)
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < pair.stop:
            self._counts['track_wrong_size'] += 1
            return []
        part = alignment[pair]
        if rate.size == alignment.size:
            # With its rate the filter's track states follow the track within the sample.
            part = np.concatenate([part, rate[pair]])
        # A channel repeating bit for bit: a frozen track measurement (a measured track is
        # never exactly constant: its sensors' noise).
        if self._track_frozen is None or self._track_frozen_size != part.size:
            self._track_frozen, self._track_frozen_size = FrozenDetector(part.size), part.size
        if self._track_frozen.update(part) * self._period_ns * 1e-9 >= self.node_params.frozen_s:
            self._counts['track_frozen'] += 1
            return []
        return self._add_part('track', stamp, part)

    def _add_part(self, kind: str, stamp: int, value: np.ndarray,
                  unfed: tuple[str, ...] = ()) -> list[Output]:
        if stamp <= self._latest[kind]:
            return []                            # out of order (refused on arrival already)
        self._latest[kind] = stamp
        if self._last_processed_ns is not None and stamp < self._last_processed_ns:
            # A part of a sample already processed without it; the stream is alive though.
            self._counts[f'{kind}_late'] += 1
            return []
        entry = self._find(stamp)
        if entry is None:
            entry = _Pending(stamp)
            bisect.insort(self._pending, entry, key=lambda e: e.stamp)
        if kind == 'main':
            entry.main, entry.unfed = value, unfed
        else:
            entry.track = value
        return self._drain()

    def _find(self, stamp: int) -> _Pending | None:
        tolerance = round(self.node_params.pair_tolerance_s * 1e9)
        for entry in self._pending:
            if abs(entry.stamp - stamp) <= tolerance:
                return entry
        return None

    def _drain(self) -> list[Output]:
        """Process pending samples in stamp order while each is complete or final."""
        n = self.node_params
        tolerance = round(n.pair_tolerance_s * 1e9)
        max_age = round(n.track_max_age_s * 1e9)
        wait = round(n.pair_timeout_s * 1e9)
        outputs: list[Output] = []
        while self._pending:
            entry = self._pending[0]
            s = entry.stamp
            # A part is settled when present or when its stream is already past this sample.
            main_done = entry.main is not None or self._latest['main'] > s + tolerance
            track_alive = (n.use_track_input and self._latest['track'] >= 0
                           and self._latest['track'] >= s - max_age)
            track_done = (not track_alive or entry.track is not None
                          or self._latest['track'] > s + tolerance)
            speed_done = not n.use_speed_input or self._speed.held.settled(
                s, self._latest['main'], tolerance, wait)
            overflow = len(self._pending) > n.max_pending
            if not (main_done and track_done and speed_done) and not overflow:
                break
            if overflow:
                self._counts['overflow'] += 1
            self._pending.pop(0)
            self._track_stale = not track_alive
            if entry.main is None:
                continue                         # parts without a driving sample: dropped
            output = self._process(entry)
            if output is not None:
                outputs.append(output)
        return outputs

    # -- processing ----------------------------------------------------------------------------

    def _process(self, entry: _Pending) -> Output | None:
        assert entry.main is not None
        stamp = entry.stamp
        if self._last_processed_ns is not None and \
                2 * (stamp - self._last_processed_ns) < self._period_ns:
            # Closer than half a period to the previous sample: a burst, not the sensor's rate;
            # the filter only predicts until the stream is back at its rate for BURST_PERIODS.
            self._counts['rate_burst'] += 1
            self._burst_until_ns = stamp + BURST_PERIODS * self._period_ns
            return None
        self.ekf.advance_to(stamp)
        self._last_processed_ns = stamp
        self._unfed = entry.unfed
        speed, speed_fault = self._speed.at(stamp, self.node_params, self.ekf.speed)
        if speed is not None:
            self.ekf.set_speed(speed)
        vector, fault = self._check_measurement(entry)
        if speed_fault and not fault:
            self._counts[speed_fault] += 1
            fault = speed_fault
        if not fault and self._burst_until_ns is not None and stamp < self._burst_until_ns:
            fault = 'rate_burst'
        track = entry.track
        if track is not None:
            self._track_used = True
        elif self._track_used and self.params.pattern != 'A':
            # B-D do not observe c without the track (it drifts): hold it until it returns.
            fault = fault or 'track_lost'
            self._counts['track_lost'] += 1
        if fault == 'rate_burst':
            fault = f'rate_burst (faster than {self.params.sample_rate_hz:g} Hz)'
        if fault:
            self._counts['held'] += 1
            vector = None                        # the track part (if any) is still used
            self._recover(stamp, f'input fault ({fault})')
        self._fault = fault
        self._counts['known_input' if track is not None else 'unknown_input'] += 1
        estimate = self.ekf.step(vector, track)
        resets = sum(self.ekf.resets.values()) + self.ekf.gap_resets
        if resets != self._resets_seen:
            self._resets_seen = resets
            self._recover(stamp, f'filter reset ({self.ekf.last_reset_reason or "gap"})')
        self._counts['processed'] += 1
        self.last = estimate
        self._counts['published'] += 1
        std, low_adhesion = estimate.std_dev, bool(estimate.low_adhesion)
        if self._recovering(stamp):
            # Not measured now (or not settled yet): unknown, and no alarm from it.
            std, low_adhesion = max(std, UNKNOWN_STD), self._held_low_adhesion
        return Output(CREEP, stamp, {
            'header': {'frame_id': f'{self.params.bogie}_bogie'},
            'creep_factor': estimate.creep_factor,
            'std_dev': std,
            'f11': estimate.f11,
            'f22': estimate.f22,
            'low_adhesion': low_adhesion})

    def _check_measurement(self, entry: _Pending) -> tuple[np.ndarray | None, str]:
        """The driving measurement, or None with the input fault ('' for a missing sample)."""
        main = entry.main
        assert main is not None
        if main is _WRONG_SIZE:
            return None, 'wrong_size'
        if not main.size:
            return None, ''                      # unpaired IMU sample: missing
        if entry.unfed:
            self._counts['missing_fields'] += 1
            return None, 'missing_fields'
        if not all_finite(main):
            self._counts['non_finite'] += 1
            return None, 'non_finite'
        n = self.node_params
        if self.params.pattern == 'D' and n.imu_saturated(main):
            self._counts['saturated'] += 1
            return None, 'saturated'
        if self._frozen.update(main) * self._period_ns * 1e-9 >= n.frozen_s:
            self._counts['frozen'] += 1
            return None, 'frozen_sensor'
        return main, ''

    # -- status --------------------------------------------------------------------------------

    def status(self, now_ns: int) -> Status:
        """Input rates and health, assembly, the filter's state and the low-adhesion flag."""
        ekf, last = self.ekf, self.last
        rates = self._input_rates(now_ns)
        values: dict[str, Any] = {
            'pattern': self.params.pattern,
            'input_rate_hz': rates[self._driving],
            **{f'input_rate_hz.{topic}': rate for topic, rate in rates.items()},
            **self.counts,
            'rejected_out_of_order': self._stamp_rejected.get('out_of_order', 0),
            'rejected_repeated': self._stamp_rejected.get('repeated', 0),
            'rejected_future_stamp': self._stamp_rejected.get('future_stamp', 0),
            **{f'rejected_{k}': v for k, v in self._pairer.rejected.items()},
            **{f'rejected_{k}': v for k, v in ekf.rejected.items()},
            'clipped_at_bound': ekf.clipped,
            'changes_detected': ekf.changes_detected,
            'changes_dropped': ekf.changes_dropped,
            'log_creep_rate_per_s': ekf.log_creep_rate_per_s,
            **{f'resets_{k}': v for k, v in ekf.resets.items()},
            'discretizations': ekf.discretizations,
            'track_input': 'stale' if self._track_stale else 'known',
            'creep_factor': last.creep_factor if last else math.nan,
            'std_dev': last.std_dev if last else math.nan,
            'low_adhesion': bool(last.low_adhesion) if last else False,
            'model_speed': ekf.speed,
            'speed_input': self._speed.state,
        }
        # Silence (the adapter reports it per input at ERROR): no claim on old data.
        silent_s = self._silent_s(self._counts['received'], now_ns)
        recovering = (self._last_processed_ns is not None
                      and self._recovering(self._last_processed_ns))
        if self._counts['received'] == 0:
            level, message = WARN, f'waiting for {self._driving}'
        elif silent_s > self.node_params.silence_timeout_s:
            level, message = WARN, (f'no {self._driving} for {silent_s:.1f} s: creep factor '
                                    'unknown')
        elif self._unfed:
            level, message = ERROR, (f'pattern {self.params.pattern} not fed: '
                                     f'{", ".join(self._unfed)} missing (NaN): creep factor '
                                     'unknown')
        elif self._fault:
            level, message = WARN, (f'input fault ({self._fault}): creep factor held, '
                                    'unknown (std widened)')
        elif new := self._new_rejections(self._rejections(), self.params.sample_rate_hz):
            level, message = WARN, f'inputs rejected since last report: {new}'
        elif recovering:
            assert self._recover_until_ns is not None and self._last_processed_ns is not None
            left = (self._recover_until_ns - self._last_processed_ns) * 1e-9
            level, message = WARN, (f'recovering after {self._recover_reason}: std widened for '
                                    f'{left:.1f} s')
        elif self.node_params.use_track_input and self._track_stale:
            level, message = WARN, 'track input stale: unknown-input mode, c less accurate'
        elif self._speed.stale:
            level, message = WARN, f'speed input {self._speed.state}'
        elif last is not None and last.low_adhesion:
            level, message = WARN, f'low adhesion: creep factor {last.creep_factor:.2f}'
        else:
            level, message = OK, 'ok'
        return Status(level, message, values)


    def _rejections(self) -> dict[str, int]:
        """Rejected inputs so far, by reason."""
        return {**{k: self._counts[k] for k in _REJECTIONS},
                'unpaired': self._pairer.unpaired['bogie'], **self._stamp_rejected,
                'speed_invalid': self._speed.invalid,
                **{f'ekf_{k}': v for k, v in self.ekf.rejected.items()}}


# The node, declared once: the live node (nodes/creep_estimator_node.py) and the offline engine
# (make_processor, the registered entry point) build it from this.
SPEC = ProcessorSpec(
    'creep_estimator', 'rail/creep/{bogie}', make=CreepEstimatorProcessor,
    groups=(ParameterGroup(CreepEkfParams, 'update_params'),
            ParameterGroup(CreepEstimatorNodeParams, 'update_node_params')))
make_processor = SPEC.make_processor
