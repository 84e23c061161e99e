"""Nominal value and spread of a calibration window from running sums, shared by the cores.

The vibration and wheel-radius cores learn their nominal the same way: while calibrating they
add, per tire or pair, the count of valid samples, their sum and their sum of squares; at the
end the window must hold enough valid data, and the mean and standard deviation follow.
"""

from __future__ import annotations

import numpy as np


def calibration_moments(sums: np.ndarray, rate_hz: float, min_s: float,
                        what: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, standard deviation and duration of a calibration window.

    Args:
        sums: (3, n) rows count, sum and sum of squares of the valid samples of n channels.
        rate_hz: sample rate the counts are at, Hz.
        min_s: least seconds of valid samples each channel needs.
        what: what was counted, for the error (e.g. ``known estimates per tire``).

    Returns:
        (mean, std, duration_s), each (n,).

    Raises:
        ValueError: a channel has less than ``min_s`` of valid samples.
    """
    count, total, total_sq = sums
    duration = count / rate_hz
    if np.any(duration < min_s):
        raise ValueError(f'calibration too short: {np.round(duration, 1)} s of {what}, '
                         f'need {min_s} s')
    mean = total / count
    std = np.sqrt(np.maximum(total_sq / count - mean * mean, 0.0))
    return mean, std, duration
