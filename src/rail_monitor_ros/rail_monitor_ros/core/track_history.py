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
    """Ring buffer of the front wheelsets' track samples, one row per filter sample.

    Args:
        width: values per sample (the front pair's alignment, and their rates).
        capacity: samples kept (the longest delay looked up, in samples, plus two).
    """

    def __init__(self, width: int, capacity: int) -> None:
        if width < 1 or capacity < 2:
            raise ValueError(f'need width >= 1 and capacity >= 2, got {width}, {capacity}')
        self._rows = np.full((capacity, width), np.nan)
        self._count = 0

    @property
    def capacity(self) -> int:
        """Samples kept."""
        return self._rows.shape[0]

    def clear(self) -> None:
        """Forget every sample (a reset or a jump of data time: the past is not this track)."""
        self._rows.fill(np.nan)
        self._count = 0

    def push(self, values: np.ndarray | None) -> None:
        """The sample of this filter step; None (or NaN entries) where nothing was measured."""
        row = self._rows[self._count % self.capacity]
        if values is None:
            row.fill(np.nan)
        else:
            row[:] = np.nan
            row[:len(values)] = values
        self._count += 1

    def delayed(self, delay_samples: float) -> np.ndarray | None:
        """The samples ``delay_samples`` before the last one pushed, linearly interpolated;
        None when that is older than what is kept. NaN where either neighbour lacks a value."""
        if not delay_samples >= 0.0:
            raise ValueError(f'delay must be >= 0, got {delay_samples}')
        back = math.floor(delay_samples)
        fraction = delay_samples - back
        oldest = back + 1 if fraction > 0.0 else back
        if oldest >= min(self._count, self.capacity):
            return None
        last = self._count - 1
        newer_row = self._rows[(last - back) % self.capacity]
        if fraction == 0.0:
            return newer_row.copy()
        older_row = self._rows[(last - back - 1) % self.capacity]
        return (1.0 - fraction) * newer_row + fraction * older_row
