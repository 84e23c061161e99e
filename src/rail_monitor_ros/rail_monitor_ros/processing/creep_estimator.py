"""The creep estimator's logic, ROS-free: sample assembly, input checks, the EKF, its output.

Inputs, per the ``pattern`` parameter: ``rail/lateral_states`` (RailLateralStates; patterns
A-C) or ``rail/bogie/imu`` + ``rail/body/imu`` (sensor_msgs/Imu; pattern D), and optionally
``rail/track_irregularity`` (TrackIrregularity). Output: ``rail/creep_factor`` (CreepFactor)
for every processed sample, stamped with that sample's stamp. The estimator is
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
prediction and resets after a gap longer than its ``max_gap_s``. Here, out-of-order and
repeated stamps are rejected (``input_health.StampCheck``); non-finite or wrongly sized values
are rejected (the sample becomes a prediction step); a measurement channel frozen
(bit-identical) for ``frozen_s`` is a dead sensor and its sample is rejected
(``input_health.FrozenDetector``). All counted in the status.

Why known input when available: with the measured track alignment (the paper's setup) the
yaw creep moment's input is known, which is what makes c observable from bogie and body
motion; without it (unknown-input mode) only pattern A (wheelset states measured) still tracks
c (see the creep_ekf tests): patterns B-D then drift.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping
from dataclasses import dataclass, replace
import math
from typing import Any

import numpy as np

from rail_monitor_ros.core.creep_ekf import (
    BOGIES,
    CreepEkf,
    CreepEkfParams,
    CreepEstimate,
    lateral_states_measurement,
)
from vehicle_monitor_common.imu_pairing import ImuPair, ImuPairer
from vehicle_monitor_common.input_health import FrozenDetector, RateMeter, StampCheck
from vehicle_monitor_common.parameters import ConfigurationError, build, param
from vehicle_monitor_common.processing import OK, WARN, Input, Output, Status

LATERAL_STATES = 'rail/lateral_states'
BOGIE_IMU = 'rail/bogie/imu'
BODY_IMU = 'rail/body/imu'
TRACK = 'rail/track_irregularity'
CREEP = 'rail/creep_factor'
LATERAL_FIELDS = ('wheelset_lateral', 'wheelset_lateral_rate', 'wheelset_yaw',
                  'wheelset_yaw_rate', 'bogie_lateral', 'bogie_lateral_rate', 'bogie_yaw',
                  'bogie_yaw_rate', 'body_lateral', 'body_lateral_rate', 'body_yaw',
                  'body_yaw_rate')


@dataclass(frozen=True)
class CreepEstimatorNodeParams:
    """The node's own parameters (the method's are ``CreepEkfParams``)."""

    use_track_input: bool = param(True, 'use rail/track_irregularity when it is published '
                                  '(known-input mode)', read_only=True)
    pair_tolerance_s: float = param(0.002, 'largest stamp difference of parts of one sample, s',
                                    low=0.0, high=1.0)
    pair_timeout_s: float = param(0.1, 'pattern D: an IMU sample still unpaired when the newest '
                                  'stamp is this much later is given up, s', low=1e-3,
                                  high=10.0)
    track_max_age_s: float = param(0.1, 'the track stream is stale when its last stamp is this '
                                   'much older than the sample, s', low=0.001, high=60.0)
    frozen_s: float = param(0.02, 'a measurement channel bit-identical for this long is a dead '
                            'sensor and its sample rejected, s', low=0.001, high=60.0)
    max_pending: int = param(200, 'most samples waiting for their parts', low=2, high=100000,
                             read_only=True)
    diagnostics_period_s: float = param(1.0, 'period of /diagnostics, s', low=0.01, high=60.0,
                                        read_only=True)
    silence_timeout_s: float = param(1.0, 'an input silent this long after it flowed is an '
                                     'error on /diagnostics, s', low=0.01, high=3600.0,
                                     read_only=True)


@dataclass
class _Pending:
    """One sample being assembled from its streams (``main``: the driving measurement)."""

    stamp: int
    main: np.ndarray | None = None
    track: np.ndarray | None = None


_MISSING = np.empty(0)


def _stamp_ns(message: Any) -> int:
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class CreepEstimatorProcessor:
    """What the creep estimator does with its inputs (see the module docstring).

    Args:
        params: the method's parameters, handed to the EKF as they are.
        node_params: assembly, input checks and diagnostics.
    """

    outputs = {CREEP: 'vehicle_monitor_msgs/msg/CreepFactor'}

    def __init__(self, params: CreepEkfParams, node_params: CreepEstimatorNodeParams) -> None:
        self.node_params = n = node_params
        self.ekf = CreepEkf(params)
        self._bogie_index = BOGIES.index(params.bogie)
        self._driving = BOGIE_IMU if params.pattern == 'D' else LATERAL_STATES
        self.inputs: dict[str, Input] = {}
        if params.pattern == 'D':
            self.inputs[BOGIE_IMU] = Input('sensor_msgs/msg/Imu')
            self.inputs[BODY_IMU] = Input('sensor_msgs/msg/Imu')
        else:
            self.inputs[LATERAL_STATES] = Input('vehicle_monitor_msgs/msg/RailLateralStates')
        if n.use_track_input:
            self.inputs[TRACK] = Input('vehicle_monitor_msgs/msg/TrackIrregularity',
                                       optional=True)
        self._handlers = {LATERAL_STATES: self._on_lateral_states, BOGIE_IMU: self._on_bogie,
                          BODY_IMU: self._on_body, TRACK: self._on_track}
        self._pairer = ImuPairer(n.pair_tolerance_s, n.pair_timeout_s)
        self._pending: list[_Pending] = []
        self._latest = {'main': -1, 'track': -1}
        self._stamps = StampCheck(max_gap_s=math.inf)     # gaps are the core's
        self._last_processed_ns: int | None = None
        self._frozen = FrozenDetector(self.ekf.n_measurements)
        self._period_ns = round(1e9 / params.sample_rate_hz)
        self._rates = {topic: RateMeter() for topic in self.inputs}
        self._counts = dict.fromkeys(
            ('received', 'processed', 'published', 'frozen', 'wrong_size', 'overflow',
             'known_input', 'unknown_input', 'track_received', 'track_wrong_size', 'main_late',
             'track_late'), 0)
        self.last: CreepEstimate | None = None
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

    def update_node_params(self, node_params: CreepEstimatorNodeParams) -> None:
        """The node's runtime-settable parameters changed."""
        self.node_params = node_params
        self._pairer.tolerance_s = node_params.pair_tolerance_s
        self._pairer.timeout_s = node_params.pair_timeout_s

    # -- input ---------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One input message; the outputs of the samples it completes."""
        self._rates[topic].tick()
        return self._handlers[topic](message)

    def _on_lateral_states(self, msg: Any) -> list[Output]:
        self._counts['received'] += 1
        p = self.params
        try:
            fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                      for name in LATERAL_FIELDS}
            vector = lateral_states_measurement(fields, p.pattern, p.bogie,
                                                p.vehicle.bogie_pivot_semi_spacing, p.model)[0]
        except (ValueError, IndexError):
            # unreachable over DDS for fixed-size arrays, but an in-process caller can
            self._counts['wrong_size'] += 1
            return []
        return self._add_part('main', _stamp_ns(msg), vector)

    def _on_bogie(self, msg: Any) -> list[Output]:
        self._counts['received'] += 1
        return self._add_pairs(self._pairer.add('bogie', _stamp_ns(msg), (
            float(msg.linear_acceleration.y), float(msg.angular_velocity.z))))

    def _on_body(self, msg: Any) -> list[Output]:
        return self._add_pairs(self._pairer.add('body', _stamp_ns(msg),
                                                float(msg.linear_acceleration.y)))

    def _add_pairs(self, pairs: list[ImuPair]) -> list[Output]:
        outputs: list[Output] = []
        for pair in pairs:
            # A bogie sample without its body partner is a missing sample (prediction only):
            # an empty measurement marks it.
            vector = (_MISSING if pair.body is None
                      else np.array([*pair.bogie, pair.body]))
            outputs += self._add_part('main', pair.stamp_ns, vector)
        return outputs

    def _on_track(self, msg: Any) -> list[Output]:
        self._counts['track_received'] += 1
        j = self._bogie_index
        alignment = np.asarray(msg.lateral_alignment, dtype=float)
        rate = np.asarray(msg.lateral_alignment_rate, dtype=float)
        if alignment.size < 2 * j + 2:
            self._counts['track_wrong_size'] += 1
            return []
        part = alignment[2 * j:2 * j + 2]
        if rate.size == alignment.size:
            # With its rate the filter's track states follow the track within the sample.
            part = np.concatenate([part, rate[2 * j:2 * j + 2]])
        return self._add_part('track', _stamp_ns(msg), part)

    def _add_part(self, kind: str, stamp: int, value: np.ndarray) -> list[Output]:
        if stamp <= self._latest[kind]:
            # Out of order or repeated on this stream.
            if kind == 'main':
                self._stamps.check(stamp)        # counts the reason
            return []
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
            entry.main = value
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
            overflow = len(self._pending) > n.max_pending
            if not (main_done and track_done) and not overflow:
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
        verdict = self._stamps.check(entry.stamp)
        if verdict in ('repeated', 'out_of_order', 'future_stamp'):
            return None
        assert entry.main is not None
        vector = entry.main if entry.main.size else None     # unpaired IMU sample
        self.ekf.advance_to(entry.stamp)
        self._last_processed_ns = entry.stamp
        vector = self._check_frozen(vector)
        self._counts['known_input' if entry.track is not None else 'unknown_input'] += 1
        estimate = self.ekf.step(vector, entry.track)
        self._counts['processed'] += 1
        self.last = estimate
        self._counts['published'] += 1
        return Output(CREEP, entry.stamp, {
            'header': {'frame_id': f'{self.params.bogie}_bogie'},
            'creep_factor': estimate.creep_factor,
            'std_dev': estimate.std_dev,
            'f11': estimate.f11,
            'f22': estimate.f22,
            'low_adhesion': bool(estimate.low_adhesion)})

    def _check_frozen(self, vector: np.ndarray | None) -> np.ndarray | None:
        if vector is None:
            return None
        if self._frozen.update(vector) * self._period_ns * 1e-9 >= self.node_params.frozen_s:
            self._counts['frozen'] += 1
            return None
        return vector

    # -- status --------------------------------------------------------------------------------

    def status(self, now_ns: int) -> Status:
        """Input rates and health, assembly, the filter's state and the low-adhesion flag."""
        ekf, last = self.ekf, self.last
        rates = {topic: meter.read(now_ns) for topic, meter in self._rates.items()}
        values: dict[str, Any] = {
            'pattern': self.params.pattern,
            'input_rate_hz': rates[self._driving],
            **{f'input_rate_hz.{topic}': rate for topic, rate in rates.items()},
            **self.counts,
            'rejected_out_of_order': self._stamps.rejected.get('out_of_order', 0),
            'rejected_repeated': self._stamps.rejected.get('repeated', 0),
            'rejected_future_stamp': self._stamps.rejected.get('future_stamp', 0),
            **{f'rejected_{k}': v for k, v in self._pairer.rejected.items()},
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
        if self._counts['received'] == 0:
            level, message = WARN, f'waiting for {self._driving}'
        elif ekf.resets:
            level, message = WARN, (f'filter reset {sum(ekf.resets.values())} times (last: '
                                    f'{ekf.last_reset_reason})')
        elif self.node_params.use_track_input and self._track_stale:
            level, message = WARN, 'track input stale: unknown-input mode, c less accurate'
        elif last is not None and last.low_adhesion:
            level, message = WARN, f'low adhesion: creep factor {last.creep_factor:.2f}'
        else:
            level, message = OK, 'ok'
        return Status(level, message, values)


def make_processor(values: Mapping[str, Any], fqn: str) -> CreepEstimatorProcessor:
    """The processor from a node's parameter values (dotted names, as the node gets them);
    the offline engine's way in (entry point group ``vehicle_monitor.processors``).

    Raises:
        ConfigurationError: a value its definition refuses.
    """
    try:
        return CreepEstimatorProcessor(build(CreepEkfParams, values),
                                       build(CreepEstimatorNodeParams, values))
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f'{fqn}: invalid parameters: {exc}') from None
