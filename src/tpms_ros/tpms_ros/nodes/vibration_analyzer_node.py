"""``vibration_analyzer``: TPMS by tire torsional resonance (Persson 2002, SPEC §3.1) on ROS.

Subscribes ``vehicle/wheel_speeds`` (WheelSpeeds, ~1 kHz) and publishes ``tpms/tire_resonance``
(TireResonance) and ``tpms/indication/vibration`` (TpmsIndication), both stamped with the last
wheel-speed sample of the block they answer, plus ``/diagnostics``. Service ``~/calibrate``
(std_srvs/Trigger) learns each tire's nominal resonance over ``calibration_duration_s`` of data;
the result is saved to ``calibration_file`` and reloaded at start.

Samples are buffered into blocks of ``block_s`` (the core is vectorised over a block; one call
per sample would cost ~100x more), cut where an output falls due and ``process_ahead_s`` before
(so little work is left for the sample an output answers, hence a short latency).

Stamps: an out-of-order or repeated sample is rejected; a few missing samples (at most
``max_gap_s``) are filled with NaN rows, which the core treats as bad samples (held, skipped by
the regression), so the block stays uniformly sampled; a longer gap restarts the filters. A
wheel with a bad sample (non-finite, negative, above ``max_wheel_speed_rad_s``, stuck) is
unknown for ``bad_hold_s`` afterwards, never flagged low.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from vehicle_monitor_msgs.msg import TireResonance

from tpms_ros.core.tires import N_TIRES
from tpms_ros.core.vibration_analysis import VibrationAnalyzer, VibrationParams
from tpms_ros.nodes.calibrating_tpms_node import CalibratingTpmsNode
from tpms_ros.nodes.wheel_speed_input import subscribe_wheel_speeds
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    WARN,
    output_phase_param,
    param,
    process_ahead_param,
    run_node,
    time_msg,
)


@dataclass(frozen=True)
class VibrationAnalyzerNodeParams:
    """Node-only parameters of vibration_analyzer (the method's own: :class:`VibrationParams`)."""

    block_s: float = param(0.1, 'wheel-speed samples are processed in blocks of this '
                           'duration at most, s (no effect on the result; shorter: more '
                           'per-call overhead)', low=0.005, high=5.0, read_only=True)
    process_ahead_s: float = process_ahead_param()
    output_phase_s: float = output_phase_param()
    max_gap_s: float = param(0.05, 'a longer gap between wheel-speed stamps restarts the '
                             'filters; shorter ones are filled as missing samples, s',
                             low=1e-4, high=10.0)
    bad_hold_s: float = param(1.0, 'a wheel stays unknown this long after a bad sample, s',
                              low=0.0, high=600.0)
    publish_rate_hz: float = param(10.0, 'highest output rate (in data time); outputs follow '
                                   'processed blocks, Hz', low=0.01, high=1000.0)
    calibrate_on_start: bool = param(False, 'start a calibration with the first data (only '
                                     'if tire pressures are known to be nominal)')
    calibration_file: str = param('', 'YAML file the calibration is saved to and loaded from '
                                  'at start; empty: not persisted', read_only=True)
    diagnostics_period_s: float = param(1.0, 'period of /diagnostics, s', low=0.01,
                                        high=60.0, read_only=True)


class VibrationAnalyzerNode(
        CalibratingTpmsNode[VibrationParams, VibrationAnalyzerNodeParams, VibrationAnalyzer]):
    """Wraps :class:`VibrationAnalyzer` (four tires) with ROS topics, calibration, diagnostics."""

    def __init__(self, node_name: str = 'vibration_analyzer', **kwargs: Any) -> None:
        super().__init__(node_name, 'vibration', VibrationParams, VibrationAnalyzerNodeParams,
                         VibrationAnalyzer, **kwargs)
        core, p = self.core_parameters, self.parameters
        self._period_ns = round(1e9 / core.sample_rate_hz)
        self._block_len = max(1, round(p.block_s * core.sample_rate_hz))
        self._stamps = StampCheck(max_gap_s=p.max_gap_s)
        self._buffer: list[np.ndarray] = []
        self._buffer_first_ns = 0
        self._buffer_last_ns = 0
        self._counts = dict.fromkeys(('received', 'processed_blocks', 'malformed', 'gaps',
                                      'missing_samples'), 0)
        self._missing_per_wheel = 0          # NaN rows the node inserted (core counts them)
        self._block_missing = 0              # ... of which in the current buffer
        self._last_bad_s = np.full(N_TIRES, -math.inf)
        self._rate = RateMeter(since_ns=self.get_clock().now().nanoseconds)

        self._resonance_pub = self.create_publisher(TireResonance, 'tpms/tire_resonance',
                                                    OUTPUT_QOS)
        subscribe_wheel_speeds(self, self._on_wheel_speeds, self._on_malformed)
        self._start_diagnostics()

    def _on_change(self, p: VibrationAnalyzerNodeParams) -> None:
        self._stamps.max_gap_s = p.max_gap_s

    # -- input ---------------------------------------------------------------------------------

    def _on_malformed(self, _: str) -> None:
        self._counts['received'] += 1
        self._rate.tick()
        self._counts['malformed'] += 1

    def _on_wheel_speeds(self, stamp: int, speeds: tuple[float, ...]) -> None:
        self._counts['received'] += 1
        self._rate.tick()
        omega = np.array(speeds)
        verdict = self._stamps.check(stamp)
        if verdict in ('repeated', 'out_of_order'):
            return
        if verdict == 'gap':
            self._counts['gaps'] += 1
            self._process_buffer()
            self._analyzer.reset_filters()
            self._calibration.restart()
        elif self._buffer_last_ns:
            # bridge a few missing samples with NaN rows: the block stays uniformly sampled
            missing = round((stamp - self._buffer_last_ns) / self._period_ns) - 1
            if missing > 0:
                self._counts['missing_samples'] += missing
                self._missing_per_wheel += missing
                self._block_missing += missing
                self._buffer.extend(np.full(N_TIRES, np.nan) for _ in range(missing))
        if not self._buffer:
            self._buffer_first_ns = stamp
        self._buffer.append(omega)
        self._buffer_last_ns = stamp
        p = self.parameters
        if self._last_publish_s == -math.inf:
            # The first output answers one publish period of data (n samples, n intervals),
            # output_phase_s more.
            self._last_publish_s = (stamp * 1e-9 - 1.0 / self.core_parameters.sample_rate_hz
                                    + p.output_phase_s)
        to_output_s = self._last_publish_s + 1.0 / p.publish_rate_hz - stamp * 1e-9
        if (len(self._buffer) >= self._block_len or to_output_s <= 1e-9
                or self._ahead.due(to_output_s, p.process_ahead_s)):
            self._process_buffer()

    def _process_buffer(self) -> None:
        if not self._buffer:
            return
        block = np.vstack(self._buffer)
        first_s, last_s = self._buffer_first_ns * 1e-9, self._buffer_last_ns * 1e-9
        self._buffer = []
        inserted, self._block_missing = self._block_missing, 0
        rejected_before = self._analyzer.rejected.copy()
        self._calibration.before_chunk()
        estimate = self._analyzer.process(block)
        self._counts['processed_blocks'] += 1
        # a wheel whose block held a rejected sample is unknown for bad_hold_s: its latest
        # estimate may predate the fault. The NaN rows bridging missing samples are not faults.
        self._last_bad_s[self._analyzer.rejected - rejected_before > inserted] = last_s
        event = self._calibration.update(first_s, last_s)
        if event:
            self.get_logger().info(event)
        self._last_stamp_s = last_s
        if last_s - self._last_publish_s >= 1.0 / self.parameters.publish_rate_hz - 1e-9:
            self._publish(estimate.frequency_hz, estimate.known, self._buffer_last_ns, last_s)

    # -- output --------------------------------------------------------------------------------

    def _publish(self, frequency: np.ndarray, core_known: np.ndarray, stamp: int,
                 stamp_s: float) -> None:
        self._last_publish_s = stamp_s
        self._ahead.published()
        sensor_ok = stamp_s - self._last_bad_s >= self.parameters.bad_hold_s
        valid = core_known & sensor_ok
        cal = self._analyzer.calibration
        header_stamp = time_msg(stamp)

        resonance = TireResonance()
        resonance.header.stamp = header_stamp
        resonance.frequency_hz = np.where(valid, frequency, np.nan).tolist()
        if cal is not None:
            sigma = np.maximum(cal.noise_hz,
                               self.core_parameters.rel_noise_floor * cal.nominal_frequency_hz)
            resonance.frequency_std_hz = np.where(valid, sigma, np.nan).tolist()
            resonance.nominal_frequency_hz = cal.nominal_frequency_hz.tolist()
        else:
            resonance.frequency_std_hz = [math.nan] * N_TIRES
            resonance.nominal_frequency_hz = [math.nan] * N_TIRES
        resonance.valid = valid.tolist()
        resonance.calibrated = cal is not None
        self._resonance_pub.publish(resonance)

        indication = self._analyzer.indication(stamp_s)
        self._publish_indication(header_stamp, indication, indication.known & sensor_ok)

    # -- diagnostics ---------------------------------------------------------------------------

    def _update_diagnostics(self) -> None:
        rate = self._rate.read(self.get_clock().now().nanoseconds)
        rejected_values = self._analyzer.rejected - self._missing_per_wheel
        values: dict[str, Any] = {
            'input_rate_hz': rate,
            'received': self._counts['received'],
            'processed_blocks': self._counts['processed_blocks'],
            'rejected_out_of_order': self._stamps.rejected.get('out_of_order', 0),
            'rejected_repeated': self._stamps.rejected.get('repeated', 0),
            'rejected_malformed': self._counts['malformed'],
            'rejected_bad_value_per_wheel': rejected_values.tolist(),
            'gated_low_speed_per_wheel': self._analyzer.gated.tolist(),
            'missing_samples': self._counts['missing_samples'],
            'gaps': self._counts['gaps'],
        }
        tire_values, tire_problems = self._tire_diagnostics(self._counts['received'] > 0)
        values.update(tire_values)
        rejected_total = (sum(self._stamps.rejected.values()) + self._counts['malformed']
                          + int(rejected_values.sum()))
        # every problem is listed; the worst sets the level
        problems: list[tuple[int, str]] = []
        if self._counts['received'] == 0:
            problems.append((WARN, 'waiting for vehicle/wheel_speeds'))
        elif rate == 0.0:
            problems.append((ERROR, 'vehicle/wheel_speeds silent'))
        if self._counts['missing_samples'] > self._counts['received']:
            problems.append((WARN, 'wheel speeds arrive slower than sample_rate_hz: check the '
                                   'parameter'))
        problems += tire_problems
        level = max((lv for lv, _ in problems), default=OK)
        message = '; '.join(text for _, text in problems) or (
            f'ok ({rejected_total} samples rejected so far)' if rejected_total else 'ok')
        self._diagnostics.set(level, message, values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``vibration_analyzer`` executable."""
    raise SystemExit(run_node(VibrationAnalyzerNode, args))


if __name__ == '__main__':
    main()
