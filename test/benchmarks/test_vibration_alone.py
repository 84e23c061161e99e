"""The vibration-alone diagnosis summarises each tire's resonance and confidence per window
(benchmarks/vibration_alone.py)."""

from __future__ import annotations

import importlib
from pathlib import Path
import sys

import numpy as np

BENCHMARKS = Path(__file__).resolve().parents[2] / 'benchmarks'
sys.path.insert(0, str(BENCHMARKS))    # the scripts import eval_tpms_family beside them
vibration_alone = importlib.import_module('vibration_alone')


def test_windows_average_the_known_resonances_and_keep_the_largest_confidence() -> None:
    """0.1 s blocks over 25 s in 10 s windows: FL drops from 40 to 37 Hz at 10 s, RR is
    unknown in the second window, confidence peaks once per window; the last window is short."""
    stamps = np.arange(1, 251) * 0.1
    speed = np.where(stamps < 10.0, 20.0, 30.0)
    frequency = np.full((stamps.size, 4), 40.0)
    frequency[stamps >= 10.0, 0] = 37.0
    frequency[(stamps >= 10.0) & (stamps < 20.0), 3] = np.nan
    confidence = np.zeros((stamps.size, 4))
    confidence[50, 1] = 0.7
    confidence[150, 0] = 0.9
    rows = vibration_alone.window_summary(stamps, speed, frequency, confidence, 10.0)
    assert [t0 for t0, *_ in rows] == [0.0, 10.0, 20.0]
    (_, v0, f0, c0), (_, v1, f1, c1), (_, v2, f2, _) = rows
    assert v0 == np.mean(speed[stamps < 10.0]) and v1 == 30.0 and v2 == 30.0
    np.testing.assert_allclose(f0, [40.0, 40.0, 40.0, 40.0])
    np.testing.assert_allclose(f1[:3], [37.0, 40.0, 40.0])
    assert np.isnan(f1[3])
    np.testing.assert_allclose(f2, [37.0, 40.0, 40.0, 40.0])
    np.testing.assert_allclose(c0, [0.0, 0.7, 0.0, 0.0])
    np.testing.assert_allclose(c1, [0.9, 0.0, 0.0, 0.0])
