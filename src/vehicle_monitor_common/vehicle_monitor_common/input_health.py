"""Input plumbing every node shares, ROS-free: stamp checks, rate meter, frozen-sensor detector.

A node keeps one :class:`StampCheck` and one :class:`RateMeter` per input stream and a
:class:`FrozenDetector` per sensor whose channels can freeze; it reports their counts on its
diagnostics. Cores may use them too (no ROS import here).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np


@dataclass
class StampCheck:
    """Classifies each incoming header stamp of one input stream.

    Out-of-order and repeated stamps are rejected (the filters assume increasing time); a gap
    longer than ``max_gap_s`` is accepted but flagged so the caller can restart its filters.
    """

    max_gap_s: float
    last_ns: int | None = None
    rejected: dict[str, int] = dataclasses.field(default_factory=dict)

    def check(self, stamp_ns: int) -> str:
        """'ok', 'gap' (accepted, filters should restart), 'repeated' or 'out_of_order'."""
        if self.last_ns is not None:
            if stamp_ns == self.last_ns:
                return self._reject('repeated')
            if stamp_ns < self.last_ns:
                return self._reject('out_of_order')
            gap = (stamp_ns - self.last_ns) * 1e-9 > self.max_gap_s
            self.last_ns = stamp_ns
            return 'gap' if gap else 'ok'
        self.last_ns = stamp_ns
        return 'ok'

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
        self._last = np.full(n_channels, np.nan)
        self._repeats = np.zeros(n_channels, dtype=np.int64)

    def update(self, values: np.ndarray | list[float] | tuple[float, ...]) -> int:
        """Feed one sample of every channel; the longest run of repeats."""
        x = np.asarray(values, dtype=float)
        same = x == self._last
        self._repeats = np.where(same, self._repeats + 1, 0)
        self._last = x
        return int(self._repeats.max(initial=0))

    def reset(self) -> None:
        """Forget the history (after a restart of the stream)."""
        self._last[:] = np.nan
        self._repeats[:] = 0
