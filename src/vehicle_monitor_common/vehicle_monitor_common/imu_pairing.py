"""Pairs the samples of two IMUs by stamp (ROS-free): the one pairer the rail nodes share.

A rail estimator measures with a bogie IMU and a body IMU sampled at the same instants but
published on two topics, so one measurement is two messages. :class:`ImuPairer` takes the
samples of both streams as they arrive and gives back the pairs in stamp order:

* A bogie sample and a body sample whose stamps differ by at most ``tolerance_s`` form one
  pair, stamped with the bogie sample's stamp (the bogie IMU is the driving stream).
* A bogie sample whose partner cannot come any more is given back alone (``body`` is None),
  so the caller can treat the sample as missing: when the body stream has delivered a later
  stamp (each stream arrives in stamp order), or when the newest stamp seen on either stream
  is more than ``timeout_s`` ahead (a dead body IMU). A body sample without a partner is
  dropped the same way. Both are counted in :attr:`ImuPairer.unpaired`.
* A sample not newer than the previous one of its stream is refused and counted in
  :attr:`ImuPairer.rejected` by stream and reason (``bogie_repeated``, ``body_out_of_order``).

The values are opaque to the pairer (numbers or arrays: whatever the node read from each
message).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

BOGIE = 'bogie'
BODY = 'body'
STREAMS = (BOGIE, BODY)


@dataclass(frozen=True)
class ImuPair:
    """One measurement instant.

    Attributes:
        stamp_ns: the bogie sample's stamp, ns.
        bogie: the bogie sample's value.
        body: the body sample's value, or None (no partner: the body sample is missing).
    """

    stamp_ns: int
    bogie: Any
    body: Any | None


@dataclass
class ImuPairer:
    """Pairs bogie and body IMU samples by stamp (see the module docstring).

    Args:
        tolerance_s: largest stamp difference of the two samples of one pair, s.
        timeout_s: a sample still unpaired when the newest stamp is this much later is given
            up, s.
    """

    tolerance_s: float
    timeout_s: float
    unpaired: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STREAMS, 0))
    rejected: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.tolerance_s >= 0.0:
            raise ValueError(f'tolerance_s must be >= 0, got {self.tolerance_s}')
        if not self.timeout_s > 0.0:
            raise ValueError(f'timeout_s must be > 0, got {self.timeout_s}')
        self._queues: dict[str, deque[tuple[int, Any]]] = {s: deque() for s in STREAMS}
        self._latest: dict[str, int | None] = dict.fromkeys(STREAMS)

    def reset(self) -> None:
        """Forget the waiting samples and the streams' last stamps (after a time jump: the
        next samples start a new time line). The counters are kept."""
        for queue in self._queues.values():
            queue.clear()
        self._latest = dict.fromkeys(STREAMS)

    @property
    def pending(self) -> int:
        """Samples waiting for a partner (both streams)."""
        return sum(len(q) for q in self._queues.values())

    def add(self, stream: str, stamp_ns: int, value: Any) -> list[ImuPair]:
        """A sample of ``stream`` ('bogie' or 'body'); the pairs it completes, in stamp order
        (bogie samples given up come back with ``body`` None)."""
        if stream not in self._queues:
            raise ValueError(f'stream must be one of {STREAMS}, got {stream!r}')
        latest = self._latest[stream]
        if latest is not None and stamp_ns <= latest:
            reason = f"{stream}_{'repeated' if stamp_ns == latest else 'out_of_order'}"
            self.rejected[reason] = self.rejected.get(reason, 0) + 1
            return []
        self._latest[stream] = stamp_ns
        self._queues[stream].append((stamp_ns, value))
        return self._drain()

    def _drain(self) -> list[ImuPair]:
        tolerance = int(self.tolerance_s * 1e9)
        timeout = int(self.timeout_s * 1e9)
        newest = max(s for s in self._latest.values() if s is not None)
        bogie, body = self._queues[BOGIE], self._queues[BODY]
        out: list[ImuPair] = []
        while bogie or body:
            # Body samples too old for the oldest waiting bogie sample (or for any later one).
            if body:
                oldest = body[0][0]
                bogie_next = bogie[0][0] if bogie else self._latest[BOGIE]
                passed = bogie_next is not None and bogie_next - tolerance > oldest
                if passed or newest - oldest > timeout:
                    body.popleft()
                    self.unpaired[BODY] += 1
                    continue
            if not bogie:
                break
            stamp, value = bogie[0]
            if body and abs(body[0][0] - stamp) <= tolerance:
                bogie.popleft()
                out.append(ImuPair(stamp, value, body.popleft()[1]))
                continue
            body_latest = self._latest[BODY]
            if (body_latest is not None and body_latest > stamp + tolerance) or (
                    newest - stamp > timeout):
                bogie.popleft()
                self.unpaired[BOGIE] += 1
                out.append(ImuPair(stamp, value, None))
                continue
            break
        return out
