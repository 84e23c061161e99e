"""Learning a nominal at nominal tire pressure: what the calibrating TPMS cores share.

The vibration and wheel-radius cores calibrate the same way: while a run is on they add, per
tire or pair, the count of valid samples, their sum and their sum of squares; at the end the
window must hold enough valid data, and the mean and standard deviation follow
(:func:`calibration_moments`). The calibration in force, whether a run is on and its
persistence as plain data are the same bookkeeping in both (:class:`CalibratedCore`), which
is what ``calibration_store.CalibrationManager`` drives.
"""

from __future__ import annotations

from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np


class _Persistable(Protocol):
    def to_dict(self) -> dict[str, Any]: ...


Cal = TypeVar('Cal', bound=_Persistable)


class CalibratedCore(Generic[Cal]):
    """The calibration bookkeeping of a core: the calibration in force (or None), whether a
    run is on, the end of a run (the window's moments, :func:`calibration_moments`) and the
    calibration as plain data to persist. The core keeps ``_cal_sum`` (count, sum, sum of
    squares per channel) while ``_calibrating``; it implements ``start_calibration``,
    ``_calibration_from`` (the calibration from the window's moments) and
    ``load_calibration_state``, and names ``calibration_counts`` and
    ``calibration_rate_hz``."""

    #: what a calibration window counts per channel, for the error (e.g. ``known estimates
    #: per tire``)
    calibration_counts: ClassVar[str]
    params: Any
    _calibration: Cal | None
    _calibrating: bool
    _cal_sum: np.ndarray

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

    @property
    def calibration_rate_hz(self) -> float:
        """The rate the calibration window's counts are at, Hz."""
        raise NotImplementedError

    def finish_calibration(self) -> Cal:
        """End calibration and put it in force.

        Raises:
            ValueError: not calibrating, or a channel has less than ``min_calibration_s`` of
                valid data after settling (the previous calibration stays in force).
        """
        if not self._calibrating:
            raise ValueError('finish_calibration called without start_calibration')
        mean, std, duration = calibration_moments(
            self._cal_sum, self.calibration_rate_hz, self.params.min_calibration_s,
            self.calibration_counts)
        self._calibration = self._calibration_from(mean, std, duration)
        self._calibrating = False
        return self._calibration

    def _calibration_from(self, mean: np.ndarray, std: np.ndarray,
                          duration_s: np.ndarray) -> Cal:
        """The calibration from the window's per-channel mean, std and valid duration."""
        raise NotImplementedError


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


def check_calibration_window(params: Any) -> None:
    """A calibration run must hold its settling time and the least valid data it needs.

    Raises:
        ValueError: ``calibration_duration_s < calibration_settle_s + min_calibration_s``.
    """
    least = params.calibration_settle_s + params.min_calibration_s
    if params.calibration_duration_s < least:
        raise ValueError(
            f'calibration_duration_s ({params.calibration_duration_s:g}) must be at least '
            f'calibration_settle_s + min_calibration_s ({least:g})')
