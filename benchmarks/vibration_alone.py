"""The vibration analyzer alone on a family drive: each tire's resonance and confidence by window.

A diagnosis (docs/methods/tpms_family_evaluation.md, sixth session of 2026-12-04: a healthy
tire's rise on held-out car 21019): the vibration core alone is run on a drive that
``eval_tpms_family.py --sim-cache`` simulated and kept, as that evaluation feeds it (0.1 s
blocks, the car's user parameters, the calibration from the start of the drive, finished once
``--calibration-s`` have passed and the window is complete). Printed: the calibration (nominal
and noise per tire), then per window the mean wheel speed, each tire's mean resonance and its
largest confidence. Comparing two trees, or a drive with its perfect-ring twin
(``eval_tpms_family.py --ring-scale 0``), shows where a frequency moves and why.

``python benchmarks/vibration_alone.py DRIVE.pkl [--window-s 10] [--vibration-set NAME=VALUE]``
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from eval_tpms_family import VIBRATION_BLOCK_S, Settings, kept_drive, method_params
import numpy as np

from tpms_ros.core.vibration_analysis import VibrationAnalyzer, VibrationParams
from vehicle_monitor_common.parameters import parse_assignments


def analyse(path: Path, calibration_s: float, vibration_set: dict[str, Any]
            ) -> dict[str, np.ndarray]:
    """Run the core on the cached drive; per 0.1 s block: stamp, mean wheel speed of the four
    wheels (rad/s), each tire's resonance (Hz) and confidence, plus the calibration."""
    result, car = kept_drive(path)
    params = method_params(car, Settings(vibration_set=vibration_set))[0]
    analyzer = VibrationAnalyzer(params)
    analyzer.start_calibration()
    block = max(1, round(VIBRATION_BLOCK_S * params.sample_rate_hz))
    omega = result.wheel_speed
    n = omega.shape[0] // block
    stamps, speed = np.empty(n), np.empty(n)
    frequency, confidence = np.full((n, 4), np.nan), np.zeros((n, 4))
    for k in range(n):
        part = omega[k * block:(k + 1) * block]
        estimate = analyzer.process(part)
        now = result.wheel_speed_t[(k + 1) * block - 1]
        if now >= calibration_s and analyzer.calibrating and analyzer.calibration_complete():
            analyzer.finish_calibration()
        stamps[k], speed[k] = now, float(np.mean(part))
        frequency[k] = np.where(estimate.known, estimate.frequency_hz, np.nan)
        confidence[k] = analyzer.indication(now).confidence
    calibration = analyzer.calibration
    unknown = np.full(4, np.nan)
    return {'stamps': stamps, 'speed': speed, 'frequency': frequency, 'confidence': confidence,
            'nominal': unknown if calibration is None else calibration.nominal_frequency_hz,
            'noise': unknown if calibration is None else calibration.noise_hz}


def window_summary(stamps: np.ndarray, speed: np.ndarray, frequency: np.ndarray,
                   confidence: np.ndarray, window_s: float
                   ) -> list[tuple[float, float, np.ndarray, np.ndarray]]:
    """Per window [t0, t0 + window_s): (t0, mean speed, mean resonance per tire over its known
    blocks (NaN if none), largest confidence per tire)."""
    rows = []
    for t0 in np.arange(0.0, stamps[-1], window_s):
        inside = (stamps >= t0) & (stamps < t0 + window_s)
        if not inside.any():
            continue
        known = np.isfinite(frequency[inside])
        counts = known.sum(axis=0)
        sums = np.where(known, frequency[inside], 0.0).sum(axis=0)
        means = np.divide(sums, counts, out=np.full(4, np.nan), where=counts > 0)
        rows.append((float(t0), float(speed[inside].mean()), means,
                     confidence[inside].max(axis=0)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('drive', type=Path, help='a drive cached by eval_tpms_family.py')
    parser.add_argument('--calibration-s', type=float, default=Settings.calibration_s)
    parser.add_argument('--window-s', type=float, default=10.0)
    parser.add_argument('--vibration-set', action='append', default=[], metavar='NAME=VALUE',
                        help='a vibration analyzer parameter (repeatable)')
    args = parser.parse_args()
    run = analyse(args.drive, args.calibration_s,
                  parse_assignments(args.vibration_set, VibrationParams()))
    print(f'{args.drive.name}: calibration nominal FL FR RL RR '
          + ' '.join(f'{x:.2f}' for x in run['nominal']) + ' Hz, noise '
          + ' '.join(f'{x:.2f}' for x in run['noise']) + ' Hz')
    print('   t0 (s)  speed (rad/s)  resonance FL FR RL RR (Hz)     largest confidence')
    for t0, speed, means, peak in window_summary(run['stamps'], run['speed'], run['frequency'],
                                                 run['confidence'], args.window_s):
        print(f'{t0:9.0f}  {speed:13.1f}  ' + ' '.join(f'{x:6.2f}' for x in means) + '  '
              + ' '.join(f'{x:5.2f}' for x in peak))


if __name__ == '__main__':
    main()
