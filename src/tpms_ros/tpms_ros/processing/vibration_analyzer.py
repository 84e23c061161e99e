"""The vibration analyzer's logic, ROS-free: stamps, blocks, calibration, sensor faults, outputs.

Wraps :class:`tpms_ros.core.vibration_analysis.VibrationAnalyzer` (TPMS by tire torsional
resonance, Persson 2002, docs/methods/vibration_analyzer.md); the node
(``tpms_ros.nodes.vibration_analyzer_node``) and
the offline engine both run it.

Input (relative topic): ``vehicle/wheel_speeds`` (WheelSpeeds, ~1 kHz, raw CDR: decoded by
:func:`tpms_ros.processing.wheel_speeds.decode_wheel_speeds`). Outputs: ``tpms/tire_resonance``
(TireResonance) and ``tpms/indication/vibration`` (TpmsIndication), both stamped with the last
wheel-speed sample of the block they answer.

Samples are buffered into blocks of ``block_s`` (the core is vectorised over a block; one call
per sample would cost ~100x more), cut where an output falls due and ``process_ahead_s`` before
(so little work is left for the sample an output answers, hence a short latency).

Time (:class:`vehicle_monitor_common.input_health.StampCheck`): an out-of-order or repeated
sample is rejected; a few missing samples (at most ``max_gap_s``) are filled with NaN rows, which
the core treats as bad samples (held, skipped by the regression), so the block stays uniformly
sampled; a longer gap restarts the filters. A lone stamp more than ``jump_horizon_s`` ahead is
dropped and counted ('future_stamp'), never adopted as "now"; a confirmed jump forward or back
(a looped or repeated replay, a clock reset) restarts the filters and the output timing on the
new time line, keeping the calibration; the status says so until every tire known before is
known again.

Sensor faults: a wheel with a bad sample (non-finite, negative, above ``max_wheel_speed_rad_s``,
stuck or dead: an exactly repeated value for ``stuck_s``) is unknown for ``bad_hold_s``
afterwards, never flagged low. A fault that lasted ``reset_after_fault_s`` or more restarts that
wheel's filters when its sensor recovers (the tooth-error pattern was learned against a wheel
angle integrated from held values). After any restart of a wheel's filters (that, a gap, a time
jump, the input rate back to normal) the wheel is 'recovering': unknown until its resonance is
estimated again and :func:`recovery_s` of data went in, and the status says so. An input rate
that does not match ``sample_rate_hz`` makes every tire unknown and the status names both rates;
when it is right again, the filters (fed at the wrong rate) restart.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import pairwise
import math
from statistics import median
from typing import Any

import numpy as np

from tpms_ros.core.tires import N_TIRES, TIRE_NAMES
from tpms_ros.core.vibration_analysis import (
    TOOTH_MEMORY_S,
    ResonanceEstimate,
    VibrationAnalyzer,
    VibrationParams,
)
from tpms_ros.processing.calibrating_tpms import (
    INDICATION_TYPE,
    CalibratingTpmsParams,
    CalibratingTpmsProcessor,
    follow_calibration_check,
    from_parameters,
)
from tpms_ros.processing.wheel_speeds import WHEEL_SPEEDS_TYPE, decode_wheel_speeds
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.processing import (
    Input,
    Output,
    ParameterGroup,
    ProcessorSpec,
    Status,
)
from vehicle_monitor_common.status_report import NewSinceLastStatus, StatusProblems

WHEEL_SPEEDS = 'vehicle/wheel_speeds'
RESONANCE = 'tpms/tire_resonance'
RATE_TOLERANCE = 0.1
"""A block whose median sample interval differs from 1 / sample_rate_hz by more than this
fraction is at the wrong rate: the band-pass and the AR(2) are designed for sample_rate_hz."""


@dataclass(frozen=True)
class VibrationAnalyzerNodeParams(CalibratingTpmsParams):
    """Node-only parameters of vibration_analyzer (the method's own: :class:`VibrationParams`)."""

    block_s: float = param(0.1, 'wheel-speed samples are processed in blocks of this '
                           'duration at most, s (no effect on the result; shorter: more '
                           'per-call overhead)', low=0.005, high=5.0, read_only=True)
    max_gap_s: float = param(0.05, 'a longer gap between wheel-speed stamps restarts the '
                             'filters; shorter ones are filled as missing samples, s',
                             low=1e-4, high=10.0)
    bad_hold_s: float = param(1.0, 'a wheel stays unknown this long after a bad sample, s',
                              low=0.0, high=600.0)
    reset_after_fault_s: float = param(0.5, "a wheel's sensor fault (bad samples) lasting this "
                                       'long or more restarts its filters when it recovers; '
                                       'the wheel is unknown (recovering) until estimated '
                                       'again, s', low=0.0, high=600.0)
    publish_rate_hz: float = param(10.0, 'highest output rate (in data time); outputs follow '
                                   'processed blocks, Hz', low=0.01, high=1000.0)


def recovery_s(params: VibrationParams) -> float:
    """Data time a wheel stays 'recovering' (unknown) after its filters restarted: the longer of
    the RLS memory and the tooth-error pattern's memory (``TOOTH_MEMORY_S``). Before that the
    regression or the pattern divided out of the speed rest on too little data: measured on
    bags/road_puncture_15pct_fl, a restarted estimate is 1-1.7 Hz off an uninterrupted one
    (3 sigma of a tire's noise) in the first 8 s, within 0.5 Hz after 20 s."""
    return float(max(params.memory_s, TOOTH_MEMORY_S))


class VibrationAnalyzerProcessor(
        CalibratingTpmsProcessor[VibrationParams, VibrationAnalyzerNodeParams,
                                 VibrationAnalyzer]):
    """What the vibration analyzer does with its wheel speeds (see the module docstring); its
    node parameters set the blocks, output timing, time checks, fault handling and calibration
    (arguments as :class:`CalibratingTpmsProcessor`'s, without the method name and core)."""

    inputs = {WHEEL_SPEEDS: Input(WHEEL_SPEEDS_TYPE, raw=True)}
    outputs = {RESONANCE: 'vehicle_monitor_msgs/msg/TireResonance',
               'tpms/indication/vibration': INDICATION_TYPE}

    def __init__(self, params: VibrationParams, node_params: VibrationAnalyzerNodeParams,
                 calibration_file: str = '') -> None:
        super().__init__('vibration', params, node_params, VibrationAnalyzer, calibration_file)
        self._period_ns = round(1e9 / params.sample_rate_hz)
        self._block_len = max(1, round(node_params.block_s * params.sample_rate_hz))
        self._stamps = StampCheck(max_gap_s=node_params.max_gap_s,
                                  jump_horizon_s=node_params.jump_horizon_s)
        # the block's rows as decoded tuples (a numpy array per 1 kHz sample cost more than the
        # rest of the per-sample work)
        self._buffer: list[tuple[float, ...]] = []
        self._buffer_stamps: list[int] = []     # of the received samples (not the NaN rows)
        self._buffer_first_ns = 0
        self._buffer_last_ns = 0
        self.counts = dict.fromkeys(('received', 'processed_blocks', 'malformed', 'gaps',
                                     'missing_samples', 'wheel_resets'), 0)
        self._missing_per_wheel = 0          # NaN rows inserted here (the core counts them)
        self._block_missing = 0              # ... of which in the current buffer
        self._last_bad_s = np.full(N_TIRES, -math.inf)
        self._fault_since_s = np.full(N_TIRES, math.nan)   # start of a running fault episode
        self._recovering_since_s = np.full(N_TIRES, math.nan)
        self._input_rate_hz = math.nan
        self._rate_was_wrong = False
        self._rate = RateMeter()
        self._new_rejections = NewSinceLastStatus()
        self._new_beat_gated = NewSinceLastStatus()

    def set_node_params(self, node_params: VibrationAnalyzerNodeParams) -> None:
        """New node parameters take effect at once (the gap limit on the next sample)."""
        super().set_node_params(node_params)
        self._stamps.max_gap_s = node_params.max_gap_s

    # -- input ---------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One wheel-speed message (CDR bytes); the outputs it makes due."""
        if topic != WHEEL_SPEEDS:
            return []
        self.counts['received'] += 1
        self._rate.tick()
        try:
            stamp, speeds = decode_wheel_speeds(message)
        except ValueError:
            self.counts['malformed'] += 1
            return []
        return self._on_sample(stamp, speeds)

    def _on_sample(self, stamp: int, speeds: tuple[float, ...]) -> list[Output]:
        verdict = self._stamps.check(stamp)
        if verdict in ('repeated', 'out_of_order', 'future_stamp'):
            return []
        outputs: list[Output] = []
        if verdict in ('gap', 'jump'):
            outputs += self._process_buffer()
            self.core.reset_filters()
            if verdict == 'gap':
                self.counts['gaps'] += 1
                gap_s = (stamp - self._buffer_last_ns) * 1e-9
                self._note_restart(f'gap of {gap_s:.3g} s in the wheel speeds')
            else:
                self._note_jump(self._stamps.last_jump_s)
                self._last_bad_s[:] = -math.inf
                self._fault_since_s[:] = math.nan
            self._recovering_since_s[:] = stamp * 1e-9
        elif self._buffer_last_ns and stamp - self._buffer_last_ns != self._period_ns:
            # bridge a few missing samples with NaN rows: the block stays uniformly sampled (a
            # sample one period after the last, the usual one, misses none: no division)
            missing = round((stamp - self._buffer_last_ns) / self._period_ns) - 1
            if missing > 0:
                self.counts['missing_samples'] += missing
                self._missing_per_wheel += missing
                self._block_missing += missing
                self._buffer.extend([(math.nan,) * N_TIRES] * missing)
        if not self._buffer:
            self._buffer_first_ns = stamp
        self._buffer.append(speeds)
        self._buffer_stamps.append(stamp)
        self._buffer_last_ns = stamp
        n = self.node_params
        if self._last_publish_s == -math.inf:
            # The first output answers one publish period of data (n samples, n intervals),
            # output_phase_s more.
            self._last_publish_s = (stamp * 1e-9 - 1.0 / self.params.sample_rate_hz
                                    + n.output_phase_s)
        to_output_s = self._last_publish_s + 1.0 / n.publish_rate_hz - stamp * 1e-9
        if (len(self._buffer) >= self._block_len or to_output_s <= 1e-9
                or self._ahead.due(to_output_s, n.process_ahead_s)):
            outputs += self._process_buffer()
        return outputs

    def _process_buffer(self) -> list[Output]:
        if not self._buffer:
            return []
        block = np.array(self._buffer)
        first_s, last_s = self._buffer_first_ns * 1e-9, self._buffer_last_ns * 1e-9
        self._measure_rate(self._buffer_stamps)
        self._buffer = []
        self._buffer_stamps = []
        inserted, self._block_missing = self._block_missing, 0
        rejected_before = self.core.rejected.copy()
        self._calibration.before_chunk()
        estimate = self.core.process(block)
        self.counts['processed_blocks'] += 1
        # a wheel whose block held a rejected sample is unknown for bad_hold_s: its latest
        # estimate may predate the fault. The NaN rows bridging missing samples are not faults.
        faulty = self.core.rejected - rejected_before > inserted
        self._last_bad_s[faulty] = last_s
        self._follow_faults(faulty, first_s, last_s)
        self._calibration_event(first_s, last_s)
        event = follow_calibration_check(
            self._calibration, self.core.calibration_check,
            self._calibration_duration_s() if self.node_params.calibrate_on_start else None)
        if event:
            self.events.append(event)
        self._last_stamp_s = last_s
        if last_s - self._last_publish_s >= 1.0 / self.node_params.publish_rate_hz - 1e-9:
            return self._outputs(estimate, self._buffer_last_ns, last_s)
        return []

    def _measure_rate(self, stamps: list[int]) -> None:
        """The input rate from the block's received stamps (median interval; a few missing
        samples do not move it); kept from the previous block when this one is too short. When
        a wrong rate ends, the filters, fed at the wrong rate, restart."""
        if len(stamps) >= 3:
            interval_ns = median([later - earlier for earlier, later in pairwise(stamps)])
            if interval_ns > 0.0:
                self._input_rate_hz = 1e9 / interval_ns
        mismatch = self.rate_mismatch()
        if self._rate_was_wrong and not mismatch:
            self.core.reset_filters()
            self._note_restart(f'wheel-speed rate back to {self._input_rate_hz:.4g} Hz')
            self._recovering_since_s[:] = stamps[0] * 1e-9
        self._rate_was_wrong = mismatch

    def rate_mismatch(self) -> bool:
        """The measured input rate is not ``sample_rate_hz`` (the filters' design rate)."""
        return bool(math.isfinite(self._input_rate_hz) and abs(
            self._input_rate_hz / self.params.sample_rate_hz - 1.0) > RATE_TOLERANCE)

    def _follow_faults(self, faulty: np.ndarray, first_s: float, last_s: float) -> None:
        """Track each wheel's fault episode; restart a wheel's filters when it recovers from a
        long one, and end its recovery once it is estimated again after a full memory."""
        starting = faulty & np.isnan(self._fault_since_s)
        self._fault_since_s[starting] = first_s
        cleared = ~faulty & np.isfinite(self._fault_since_s)
        for w in np.flatnonzero(cleared):
            if self._last_bad_s[w] - self._fault_since_s[w] >= \
                    self.node_params.reset_after_fault_s:
                self.core.reset_wheel(int(w))
                self.counts['wheel_resets'] += 1
                self._recovering_since_s[w] = last_s
            self._fault_since_s[w] = math.nan
        done = (np.isfinite(self._recovering_since_s) & self.core.known_wheels()
                & (last_s - self._recovering_since_s >= recovery_s(self.params)))
        self._recovering_since_s[done] = math.nan

    def recovering(self) -> np.ndarray:
        """Per wheel: its filters restarted after a sensor fault, not estimated again yet."""
        return np.isfinite(self._recovering_since_s)

    # -- output --------------------------------------------------------------------------------

    def _outputs(self, estimate: ResonanceEstimate, stamp: int, stamp_s: float) -> list[Output]:
        self._last_publish_s = stamp_s
        self._ahead.published()
        sensor_ok = ((stamp_s - self._last_bad_s >= self.node_params.bad_hold_s)
                     & ~self.recovering() & (not self.rate_mismatch()))
        valid = estimate.known & sensor_ok
        cal = self.core.calibration
        resonance: dict[str, Any] = {
            'frequency_hz': np.where(valid, estimate.frequency_hz, np.nan).tolist()}
        if cal is not None:
            sigma = self.core.frequency_sigma_hz()
            resonance['frequency_std_hz'] = np.where(valid, sigma, np.nan).tolist()
            resonance['nominal_frequency_hz'] = cal.nominal_frequency_hz.tolist()
        else:
            resonance['frequency_std_hz'] = [math.nan] * N_TIRES
            resonance['nominal_frequency_hz'] = [math.nan] * N_TIRES
        resonance['valid'] = valid.tolist()
        resonance['calibrated'] = cal is not None
        indication = self.core.indication(stamp_s)
        return [Output(RESONANCE, stamp, resonance),
                self._indication_output(stamp, indication, indication.known & sensor_ok)]

    # -- status ----------------------------------------------------------------------------------

    def status(self, now_ns: int) -> Status:
        """Health: input counts and rate, rejections, sensor faults, calibration, tires."""
        p = self.params
        rate = self._rate.read(now_ns)
        rejected_values = self.core.rejected - self._missing_per_wheel
        rejected = {'out_of_order': self._stamps.rejected.get('out_of_order', 0),
                    'repeated': self._stamps.rejected.get('repeated', 0),
                    'future_stamp': self._stamps.rejected.get('future_stamp', 0),
                    'malformed': self.counts['malformed']}
        values: dict[str, Any] = {
            'input_rate_hz': rate,
            'sample_interval_rate_hz': self._input_rate_hz,
            'sample_rate_hz': p.sample_rate_hz,
            'received': self.counts['received'],
            'processed_blocks': self.counts['processed_blocks'],
            **{f'rejected_{k}': v for k, v in rejected.items()},
            'rejected_bad_value_per_wheel': rejected_values.tolist(),
            'gated_low_speed_per_wheel': self.core.gated.tolist(),
            'gated_edge_beat_per_wheel': self.core.beat_gated.tolist(),
            'missing_samples': self.counts['missing_samples'],
            'gaps': self.counts['gaps'],
            'wheel_filter_resets': self.counts['wheel_resets'],
            'recovery_s': recovery_s(p),
        }
        received = self.counts['received'] > 0
        tire_values, tire_problems = self._tire_status(received)
        values.update(tire_values)
        # every problem is listed; the worst sets the level
        problems = StatusProblems()
        if self.rate_mismatch():
            problems.error(f'wheel-speed rate {self._input_rate_hz:.4g} Hz does not match '
                           f'sample_rate_hz {p.sample_rate_hz:g}: every tire unknown, set '
                           'sample_rate_hz')
        elif self.counts['missing_samples'] > self.counts['received']:
            problems.warn('wheel speeds arrive slower than sample_rate_hz: check the parameter')
        # Sensor faults: wheels inside their hold after a bad sample.
        bad = self._last_stamp_s - self._last_bad_s < self.node_params.bad_hold_s
        if received and bad.any():
            names = ', '.join(TIRE_NAMES[i] for i in np.flatnonzero(bad))
            problems.error(f'bad wheel speeds (non-finite, negative, absurd, stuck or dead): '
                           f'{names} unknown')
        recovering = self.recovering()
        if recovering.any():
            names = ', '.join(TIRE_NAMES[i] for i in np.flatnonzero(recovering))
            problems.warn(f'recovering after a filter restart (sensor fault, gap, time jump or '
                          f'rate): {names} unknown until estimated again (at least '
                          f'{recovery_s(p):.3g} s of data)')
        new_rejections = self._new_rejections.text(rejected)
        if new_rejections:
            problems.warn('wheel-speed messages rejected: ' + new_rejections)
        beat_gated = self._new_beat_gated.text(dict(zip(TIRE_NAMES,
                                                        self.core.beat_gated.tolist(),
                                                        strict=True)))
        if beat_gated:
            problems.warn('wheel speeds gated, held tooth periods beating with the sampling '
                          f'inside the band at this speed (samples): {beat_gated}')
        if self.core.calibration_check.pending:
            problems.warn(self.core.calibration_check.status(p))
        problems.extend(tire_problems)
        rejected_total = sum(rejected.values()) + int(rejected_values.sum())
        return problems.status(values, f'ok ({rejected_total} samples rejected so far)'
                               if rejected_total else 'ok')


# The node, declared once: the live node (nodes/vibration_analyzer_node.py) and the offline engine
# (make_processor, the registered entry point) build it from this.
SPEC = ProcessorSpec(
    'vibration_analyzer', 'tpms/vibration', make=from_parameters(VibrationAnalyzerProcessor),
    groups=(ParameterGroup(VibrationParams, 'set_params'),
            ParameterGroup(VibrationAnalyzerNodeParams, 'set_node_params')))
make_processor = SPEC.make_processor
