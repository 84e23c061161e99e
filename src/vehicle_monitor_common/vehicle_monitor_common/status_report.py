"""A processor's status from every problem it found: all of them listed, the worst sets the level.

The processors whose conditions are independent of each other (a bad wheel, a calibration still
running and rejected messages at once) report each of them on ``/diagnostics`` rather than the
first one only; they collect them here while they build their status, in the order they are to
be read.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from vehicle_monitor_common.processing import ERROR, OK, WARN, Status


class StatusProblems:
    """The problems found while one status is built, in the order found."""

    def __init__(self) -> None:
        self._found: list[tuple[int, str]] = []

    def warn(self, text: str) -> None:
        """A problem the method works around (estimates degraded or paused)."""
        self._found.append((WARN, text))

    def error(self, text: str) -> None:
        """A problem that leaves outputs unknown (bad sensor data, a wrong setting)."""
        self._found.append((ERROR, text))

    def extend(self, other: StatusProblems) -> None:
        """The problems another part of the processor found, after these."""
        self._found += other._found

    def __bool__(self) -> bool:
        return bool(self._found)

    def status(self, values: dict[str, Any], ok_message: str = 'ok') -> Status:
        """At the worst level found, every problem's text joined by '; ' (``ok_message`` at OK
        when there is none)."""
        level = max((found_level for found_level, _ in self._found), default=OK)
        message = '; '.join(text for _, text in self._found) or ok_message
        return Status(level, message, values)


class NewSinceLastStatus:
    """Counts by reason that grew since the previous status: reported while they grow, so the
    warning clears once they stop (the totals stay in the status values)."""

    def __init__(self) -> None:
        self._reported: dict[str, int] = {}

    def text(self, counts: Mapping[str, int]) -> str:
        """``'<n> <reason>, ...'`` of what grew since the previous call ('' if nothing)."""
        grown = {k: v - self._reported.get(k, 0) for k, v in counts.items()}
        self._reported = dict(counts)
        return ', '.join(f'{n} {reason}' for reason, n in sorted(grown.items()) if n)
