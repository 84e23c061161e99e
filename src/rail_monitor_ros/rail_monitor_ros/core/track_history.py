"""The track the rear wheelsets run on: the front wheelsets' measured track, a wheelbase later.

On a track every wheelset meets the same alignment: the wheelset ``d`` metres behind another
sees at time t what that one saw at t - d / v. A car that measures the track at its front
bogie (the contract's ``TrackIrregularity``: at least the monitored bogie's two wheelsets)
therefore knows the track under its rear bogie too, from its own recent measurements. The
creep estimator's full-car model uses it (docs/methods/creep_estimator.md): the delays built
from the track spectrum's shaping filter (Pade sections, as the suspension monitor's track
model) do not reproduce a measured track at the accuracy of a survey, the kept samples do
(docs/methods/rail_family_evaluation.md, 2026-12-05). No ROS.
"""

from __future__ import annotations

import math

import numpy as np


class TrackHistory:
    """Ring buffer of the front wheelsets' track samples, one row per filter sample, each with
    the distance the car had travelled at it.

    A rear wheelset ``d`` behind reads what the front one read where the car stood ``d``
    earlier: looked up by distance, not by ``d / v`` of the present speed, which on a car
    accelerating at 0.5 m/s^2 at 25 m/s misses the 17.5 m between the bogies by a sample
    (pattern C's estimate was biased 0.5-3 % low on such runs).

    Between two samples the lookup interpolates by the cubic through the four samples around
    the distance (Catmull-Rom: a quadratic's values exactly; linear next to the newest or
    oldest sample, or where one of the outer two lacks a value). Linearly, the interpolated
    track is smoothed by an amount that changes with the distance's fraction between two
    samples, and the creep EKF's likelihood then had a kink wherever the rear pair's distance
    crossed a sample: over a tachometer's scale it rose and fell with a period of one
    sample's travel (development car 1003 at 31.0 m/s: kinks 0.85 % apart, some 20 nats deep)
    and on the nominal car at 40 m/s, whose rear pair stands 87.5 samples behind, it was
    lowest at the true speed. With the cubic the rates at the rear pair are closer to the true
    ones (1003: 2.6e-4 against 9.8e-5 m/s rms, the noise 1e-4) and the likelihood is smooth
    (docs/methods/creep_estimator.md, "The tachometer's scale").

    Args:
        width: values per sample (the front pair's alignment, and their rates).
        capacity: samples kept (the longest delay looked up, in samples, plus two).
    """

    def __init__(self, width: int, capacity: int) -> None:
        if width < 1 or capacity < 2:
            raise ValueError(f'need width >= 1 and capacity >= 2, got {width}, {capacity}')
        self._rows = np.full((capacity, width), np.nan)
        self._distance = np.full(capacity, np.nan)
        self._count = 0

    @property
    def capacity(self) -> int:
        """Samples kept."""
        return self._rows.shape[0]

    def clear(self) -> None:
        """Forget every sample (a reset or a jump of data time: the past is not this track)."""
        self._rows.fill(np.nan)
        self._distance.fill(np.nan)
        self._count = 0

    def push(self, values: np.ndarray | None, distance: float) -> None:
        """The sample of this filter step, None (or NaN entries) where nothing was measured,
        and the distance travelled at it, m (increasing from one sample to the next)."""
        slot = self._count % self.capacity
        row = self._rows[slot]
        if values is None:
            row.fill(np.nan)
        else:
            row[:] = np.nan
            row[:len(values)] = values
        self._distance[slot] = distance
        self._count += 1

    def behind(self, metres: float) -> np.ndarray | None:
        """The samples where the car stood ``metres`` before the last one pushed, interpolated
        at that distance's fraction between two samples (class docstring); None when that is
        older than what is kept. NaN where either neighbour lacks a value."""
        if not metres >= 0.0:
            raise ValueError(f'distance behind must be >= 0, got {metres}')
        kept = min(self._count, self.capacity)
        if kept == 0:
            return None
        cap, newest = self.capacity, self._count - 1
        target = self._distance[newest % cap] - metres
        oldest = self._count - kept
        if target < self._distance[oldest % cap]:
            return None
        # Bisection over the kept samples (logical indices, distances increasing): the newest
        # index whose distance is at most the target.
        low, high = oldest, newest
        while low < high:
            middle = (low + high + 1) // 2
            if self._distance[middle % cap] <= target:
                low = middle
            else:
                high = middle - 1
        older_row = self._rows[low % cap]
        fraction = 0.0 if low == newest else (
            (target - self._distance[low % cap])
            / (self._distance[(low + 1) % cap] - self._distance[low % cap]))
        if fraction == 0.0:
            return older_row.copy()
        if low - 1 < oldest or low + 2 > newest:
            return (1.0 - fraction) * older_row + fraction * self._rows[(low + 1) % cap]
        # Catmull-Rom through the four samples around the target, as one product; linear where
        # an outer one lacks a value.
        f = fraction
        f2, f3 = f * f, f * f * f
        weights = np.array([0.5 * (-f + 2.0 * f2 - f3), 1.0 - 2.5 * f2 + 1.5 * f3,
                            0.5 * (f + 4.0 * f2 - 3.0 * f3), 0.5 * (f3 - f2)])
        first = (low - 1) % cap
        block = (self._rows[first:first + 4] if first + 4 <= cap
                 else self._rows[np.arange(low - 1, low + 3) % cap])
        cubic = weights @ block
        if math.isfinite(cubic.sum()):
            return cubic
        linear = (1.0 - fraction) * block[1] + fraction * block[2]
        return np.where(np.isfinite(cubic), cubic, linear)
