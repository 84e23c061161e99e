"""Learning a nominal at nominal tire pressure: what the calibrating TPMS cores share.

The vibration and wheel-radius cores calibrate the same way: while a run is on they add, per
tire or pair, the count of valid samples, their sum and their sum of squares; at the end the
window must hold enough valid data, and the mean and standard deviation follow
(:func:`calibration_moments`). The calibration in force, whether a run is on and its
persistence as plain data are the same bookkeeping in both (:class:`CalibratedCore`), which
is what ``calibration_store.CalibrationManager`` drives.

A calibration put in force from outside (the file at start, the fleet job's chain) may have
been made on other tires; the vibration and stiffness cores check it against the tires before
using it the same way (:class:`StoredCalibrationCheck`, parameters
:class:`StoredCalibrationCheckParams`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar, Generic, Protocol, TypeVar

import numpy as np

from vehicle_monitor_common.parameters import param


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
    #: the channels' names (tires or tire pairs), for what a window still lacks
    calibration_channels: ClassVar[tuple[str, ...]]
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

    def calibration_missing(self) -> str:
        """The channels with less than ``min_calibration_s`` of valid data in the running
        window ('' when none): a window goes on collecting valid data as it comes until every
        channel has it (the manager's ``calibration_duration_s`` is the least it lasts)."""
        valid_s = self._cal_sum[0] / self.calibration_rate_hz
        need = self.params.min_calibration_s
        short = [f'{name} {s:.1f}' for name, s in zip(self.calibration_channels, valid_s,
                                                     strict=True) if s < need]
        return (f'{", ".join(short)} of {need:g} s of {self.calibration_counts}'
                if short else '')

    def calibration_complete(self) -> bool:
        """Every channel has ``min_calibration_s`` of valid data in the running window."""
        return not self.calibration_missing()

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


@dataclass(frozen=True)
class StoredCalibrationCheckParams:
    """How a stored calibration is checked against the tires (the vibration and stiffness cores'
    parameters derive from this: one definition for both).

    - ``calibration_check_s``: until the tires have been estimated for this much data after a
      stored calibration was put in force, every tire is unknown; then it is refused when the
      median over the tires of the resonance ratio (measured / stored; for the stiffness,
      sqrt(K / K0), the resonance ratio it implies) is above ``calibration_fit_ratio`` or below
      its inverse. Pressure cannot explain that: on the paper's line a 20 % overpressure
      raises the resonance about 6 %, and 1 / 1.25 is a stiffness of 0.64, about 40 % of
      nominal pressure on every tire. The band is that wide because the estimates wander: on
      the car family's 32 tuning cars the 20 s mean of the four tires' median resonance ratio
      stayed within 0.89-1.14 of their own calibration at nominal pressure
      (docs/methods/vibration_analyzer.md).
    """

    calibration_check_s: float = param(20.0, 'a stored calibration is checked against this '
                                       'much data of estimated tires before it is used (tires '
                                       'unknown until then), s (0: used at once)', low=0.0,
                                       high=3600.0)
    calibration_fit_ratio: float = param(1.25, 'a stored calibration is refused (made on other '
                                         'tires) when the median over the tires of the '
                                         'resonance ratio, measured / stored, is above this or '
                                         'below its inverse', low=1.01, high=10.0)


class StoredCalibrationCheck:
    """The check of a stored calibration against the tires (see
    :class:`StoredCalibrationCheckParams`): per tire, the data time with an estimate and the
    time-weighted sum of its resonance ratio, until one tire has ``calibration_check_s``."""

    def __init__(self, n_tires: int) -> None:
        self.pending = False            # a stored calibration in force, not checked yet
        self.misfit = ''                # why the last stored calibration was refused
        self._seconds = np.zeros(n_tires)
        self._ratio_s = np.zeros(n_tires)

    def start(self, params: StoredCalibrationCheckParams) -> None:
        """A stored calibration was put in force: check it (unless the check is off)."""
        self.pending = params.calibration_check_s > 0.0
        self.misfit = ''
        self._seconds[:] = 0.0
        self._ratio_s[:] = 0.0

    def cancel(self) -> None:
        """A calibration run started: nothing stored to check any more."""
        self.pending = False
        self.misfit = ''

    def progress_s(self) -> float:
        """Data time of estimates so far (the tire with the most), s."""
        return float(self._seconds.max())

    def add(self, ratio: np.ndarray, row_s: float, params: StoredCalibrationCheckParams
            ) -> tuple[float, np.ndarray] | None:
        """Add (M, tires) resonance ratios (NaN: no estimate), each row ``row_s`` of data.

        Returns:
            None while pending; once decided, (median ratio, per-tire mean ratio with NaN for
            the tires with less than half the check's data); the caller refuses the
            calibration when the median is outside ``1 / calibration_fit_ratio ..
            calibration_fit_ratio`` (:meth:`fits`).
        """
        ok = np.isfinite(ratio)
        self._seconds += ok.sum(axis=0) * row_s
        self._ratio_s += np.where(ok, ratio, 0.0).sum(axis=0) * row_s
        needed = params.calibration_check_s
        if self._seconds.max() < needed:
            return None
        self.pending = False
        used = self._seconds >= 0.5 * needed
        mean = np.where(used, self._ratio_s / np.maximum(self._seconds, 1e-12), np.nan)
        return float(np.median(mean[used])), mean

    @staticmethod
    def fits(median_ratio: float, params: StoredCalibrationCheckParams) -> bool:
        """Whether a median resonance ratio lies within the band."""
        fit = params.calibration_fit_ratio
        return 1.0 / fit <= median_ratio <= fit

    def refuse(self, measured: str, stored: str, median_ratio: float,
               params: StoredCalibrationCheckParams) -> None:
        """Record why the stored calibration is refused (the core then drops it): what was
        measured and what was stored, each as the core words it."""
        fit = params.calibration_fit_ratio
        self.misfit = (f'stored calibration does not fit these tires: {measured} against '
                       f'{stored} stored (median resonance ratio {median_ratio:.2f}, outside '
                       f'1/{fit:g}..{fit:g}): made on other tires?')

    def status(self, params: StoredCalibrationCheckParams) -> str:
        """The status line while the check is pending."""
        return (f'checking the stored calibration against the tires ({self.progress_s():.1f} / '
                f'{params.calibration_check_s:g} s of estimates): tires unknown until then')
