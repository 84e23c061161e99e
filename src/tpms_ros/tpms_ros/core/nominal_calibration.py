"""Learning a nominal at nominal tire pressure: what the calibrating TPMS cores share.

The vibration and wheel-radius cores calibrate the same way: while a run is on they add, per
tire or pair, the count of valid samples, their sum and their sum of squares; at the end the
window must hold enough valid data, and the mean and standard deviation follow
(:func:`calibration_moments`). The calibration in force, whether a run is on and its
persistence as plain data are the same bookkeeping in both (:class:`CalibratedCore`), which
is what ``calibration_store.CalibrationManager`` drives.
"""

from __future__ import annotations

from typing import Any, Generic, Protocol, TypeVar

import numpy as np


class _Persistable(Protocol):
    def to_dict(self) -> dict[str, Any]: ...


Cal = TypeVar('Cal', bound=_Persistable)


class CalibratedCore(Generic[Cal]):
    """The calibration bookkeeping of a core: the calibration in force (or None), whether a
    run is on, and the calibration as plain data to persist. The core sets ``_calibration``
    and ``_calibrating``; it implements ``start_calibration``, ``finish_calibration`` (calling
    :meth:`_check_calibrating` first) and ``load_calibration_state``."""

    _calibration: Cal | None
    _calibrating: bool

    @property
    def calibration(self) -> Cal | None:
        """The calibration in force, or None."""
        return self._calibration

    @property
    def calibrating(self) -> bool:
        """True between ``start_calibration`` and ``finish_calibration``."""
        return self._calibrating

    def calibration_state(self) -> dict[str, Any]:
        """Calibration as a plain dict (to persist); raises ValueError if not calibrated."""
        if self._calibration is None:
            raise ValueError('not calibrated')
        return self._calibration.to_dict()

    def _check_calibrating(self) -> None:
        if not self._calibrating:
            raise ValueError('finish_calibration called without start_calibration')


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
