"""Tooth-error correction on both ECU speed forms (issue 21): held tooth period, window average."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as sig

from tpms_ros.core.tooth_correction import ToothErrorCorrector
from tpms_ros.core.wheel_encoder import encoder_wheel_speed

FS = 1000.0
TEETH = 48


def _ring_speed(method: str, speed: float, seconds: float = 40.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """(measured, clean) speed of one wheel at ``speed`` rad/s with a 40 Hz wobble: a 0.25 % ring
    and a perfect one read the same way."""
    t = np.arange(0.0, seconds, 1e-4)
    rng = np.random.default_rng(4)
    true = speed + 2.0 * np.sin(2 * np.pi * 0.05 * t) + 0.05 * np.sin(2 * np.pi * 40.0 * t)
    errors = rng.normal(0.0, 0.0025 * 2 * np.pi / TEETH, TEETH)
    errors -= errors.mean()
    t_out = np.arange(0.01, seconds, 1.0 / FS)
    measured = encoder_wheel_speed(t, true, t_out, errors, 0.7, 2e-6, method, 0.006)
    clean = encoder_wheel_speed(t, true, t_out, np.zeros(TEETH), 0.7, 2e-6, method, 0.006)
    return measured, clean


@pytest.mark.parametrize(('method', 'speed', 'angle_mode'), [
    ('tooth_period', 80.0, False), ('window_average', 80.0, True),
    ('tooth_period', 105.0, False), ('window_average', 105.0, True)])   # 0.8 edges per sample
def test_correction_removes_most_of_the_ring_error_on_both_forms(method: str, speed: float,
                                                                 angle_mode: bool) -> None:
    measured, true = _ring_speed(method, speed)
    sos = sig.butter(2, 5.0, fs=FS, output='sos')
    reference = sig.sosfilt(sos, measured, zi=sig.sosfilt_zi(sos) * measured[0])[0]
    corrector = ToothErrorCorrector(1, TEETH, FS, 10.0, 0.5, 250)
    out = np.empty_like(measured)
    for start in range(0, measured.size, 250):
        sl = slice(start, start + 250)
        out[sl] = corrector.process(measured[sl, None], reference[sl, None],
                                    np.ones((measured[sl].size, 1), dtype=bool))[:, 0]
    assert bool(corrector.angle_mode[0]) is angle_mode
    late = slice(measured.size // 2, None)
    raw = np.std(np.log(measured[late] / true[late]))
    fixed = np.std(np.log(out[late] / true[late]))
    assert fixed < 0.5 * raw, (raw, fixed)
