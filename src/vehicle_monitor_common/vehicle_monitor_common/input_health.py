"""Input plumbing every node shares, ROS-free: stamp checks, rate meter, frozen-sensor detector.

A node keeps one :class:`StampCheck` and one :class:`RateMeter` per input stream and a
:class:`FrozenDetector` per sensor whose channels can freeze; it reports their counts on its
diagnostics. Cores may use them too (no ROS import here).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import math

import numpy as np


def all_finite(values: np.ndarray) -> bool:
    """Whether every value of a small array is finite (as ``np.isfinite(values).all()``, in a
    tenth of its time for the few channels of one sample)."""
    return all(map(math.isfinite, values.ravel().tolist()))


@dataclass
class StampCheck:
    """Classifies each incoming header stamp of one input stream, and follows time jumps.

    Out-of-order and repeated stamps are rejected (the filters assume increasing time); a gap
    longer than ``max_gap_s`` is accepted but flagged so the caller can restart its filters.

    A stamp more than ``jump_horizon_s`` ahead of the last one, or behind it, is never adopted
    as the new "now" on its own: a single far-future stamp (a corrupt message) is dropped and
    counted, and the stream goes on. Only when ``confirm_samples`` stamps in a row continue the
    new time line (each after the previous by at most ``jump_horizon_s``) is the jump real (a
    looped or repeated replay, a reset or step of the clock): the last of them is returned as
    ``'jump'``, and the caller restarts its filters from there (calibration is kept), as
    robot_localization does on a time jump. Until then those stamps are rejected as
    ``'future_stamp'`` or ``'out_of_order'``.
    """

    max_gap_s: float
    jump_horizon_s: float = 10.0
    confirm_samples: int = 5
    last_ns: int | None = None
    rejected: dict[str, int] = dataclasses.field(default_factory=dict)
    jumps: int = 0
    last_jump_s: float = 0.0
    _candidate_ns: int | None = None
    _candidate_count: int = 0

    def check(self, stamp_ns: int) -> str:
        """'ok', 'gap' (accepted, filters should restart), 'jump' (accepted: a confirmed jump
        of ``last_jump_s``, filters must restart), or a rejection: 'repeated', 'out_of_order',
        'future_stamp'."""
        if self.last_ns is None:
            self.last_ns = stamp_ns
            return 'ok'
        step_ns = stamp_ns - self.last_ns
        if 0 < step_ns <= self.jump_horizon_s * 1e9:
            self._candidate_ns, self._candidate_count = None, 0
            self.last_ns = stamp_ns
            return 'gap' if step_ns * 1e-9 > self.max_gap_s else 'ok'
        if step_ns == 0:
            return self._reject('repeated')
        if self._continues_candidate(stamp_ns):
            self._candidate_count += 1
        else:
            self._candidate_count = 1
        self._candidate_ns = stamp_ns
        if self._candidate_count >= self.confirm_samples:
            self.jumps += 1
            self.last_jump_s = step_ns * 1e-9
            self.last_ns, self._candidate_ns, self._candidate_count = stamp_ns, None, 0
            return 'jump'
        return self._reject('future_stamp' if step_ns > 0 else 'out_of_order')

    def _continues_candidate(self, stamp_ns: int) -> bool:
        if self._candidate_ns is None:
            return False
        step_ns = stamp_ns - self._candidate_ns
        return 0 < step_ns <= self.jump_horizon_s * 1e9

    def _reject(self, reason: str) -> str:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return reason


@dataclass
class RateMeter:
    """Messages per second of one input over the interval between two reads (on any clock)."""

    count: int = 0
    since_ns: int | None = None

    def tick(self, n: int = 1) -> None:
        """``n`` messages arrived."""
        self.count += n

    def read(self, now_ns: int) -> float:
        """Rate since the previous read, Hz (0 on the first read), and start a new interval."""
        elapsed_s = 0.0 if self.since_ns is None else (now_ns - self.since_ns) * 1e-9
        rate = self.count / elapsed_s if elapsed_s > 0.0 else 0.0
        self.count, self.since_ns = 0, now_ns
        return rate


class FrozenDetector:
    """Counts, per channel, how many consecutive samples repeated the previous value exactly.

    A real sensor's noise never repeats a float bit for bit for long; a frozen (stuck, dead,
    latched) one does. ``update`` returns the longest current run over the channels, so
    ``update(x) >= n`` means some channel held its value for ``n`` more samples.
    """

    def __init__(self, n_channels: int) -> None:
        # Python lists: a sample has a few channels and comes at the sensor's rate, where
        # numpy's per-call overhead would cost more than the comparison itself.
        self._last = [math.nan] * n_channels
        self._repeats = [0] * n_channels

    def update(self, values: np.ndarray | list[float] | tuple[float, ...]) -> int:
        """Feed one sample of every channel (one value each); the longest run of repeats."""
        x = values.tolist() if isinstance(values, np.ndarray) else [float(v) for v in values]
        if len(x) != len(self._last):
            raise ValueError(f'expected {len(self._last)} channels, got {len(x)}')
        repeats = self._repeats
        longest = 0
        for i, (value, last) in enumerate(zip(x, self._last, strict=True)):
            run = repeats[i] + 1 if value == last else 0
            repeats[i] = run
            longest = max(longest, run)
        self._last = x
        return longest

    def reset(self) -> None:
        """Forget the history (after a restart of the stream)."""
        self._last = [math.nan] * len(self._last)
        self._repeats = [0] * len(self._repeats)
