"""What a recording's outputs say, summarised while they stream out of the offline engine.

One :class:`Summarizer` per published output topic, chosen by its message type (the contract's
outputs, docs/contract.md): it sees every message once, in publication order, keeps a few
numbers and the open episodes, and never the messages themselves, so a task's memory does not
grow with the recording. At the end it gives one summary row (the recording x method table)
and its episodes (the events table: each warning, fault or low-adhesion episode with start,
end and peak).

Times in the rows are seconds from the recording's first input message; event start and end
are also given as absolute stamps (ns).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
import math
from typing import Any

from vehicle_monitor_common.processing import header_stamp_ns

TIRES = ('fl', 'fr', 'rl', 'rr')

#: Columns of the summary table besides the recording's identification (in this order).
SUMMARY_FIELDS: dict[str, type] = {
    'method': str, 'topic': str, 'messages': int,
    'warnings_raised': int, 'max_confidence': float,
    **{f'first_warning_s_{tire}': float for tire in TIRES},
    'fault_episodes': int, 'fault_modes': str,
    'spring_ratio_mean': float, 'spring_ratio_last': float,
    'damper_ratio_mean': float, 'damper_ratio_last': float,
    'min_creep_factor': float, 'low_adhesion_s': float,
}

#: Columns of the events table besides the recording's identification.
EVENT_FIELDS: dict[str, type] = {
    'method': str, 'topic': str, 'kind': str, 'subject': str,
    'start_ns': int, 'end_ns': int, 'start_s': float, 'end_s': float, 'duration_s': float,
    'peak': float, 'open_at_end': bool,
}


@dataclass
class _Episode:
    start_ns: int
    end_ns: int
    peak: float


@dataclass
class _Episodes:
    """Episodes of a flag per subject (tire, component): rising edge to falling edge."""

    kind: str
    lower_is_worse: bool = False
    open: dict[str, _Episode] = field(default_factory=dict)
    closed: list[tuple[str, _Episode]] = field(default_factory=list)

    def update(self, subject: str, flag: bool, stamp_ns: int, value: float) -> bool:
        """Feed one sample; True on a rising edge."""
        episode = self.open.get(subject)
        if flag:
            if episode is None:
                self.open[subject] = _Episode(stamp_ns, stamp_ns, value)
                return True
            episode.end_ns = stamp_ns
            if math.isfinite(value):
                worse = value < episode.peak if self.lower_is_worse else value > episode.peak
                if worse or not math.isfinite(episode.peak):
                    episode.peak = value
        elif episode is not None:
            episode.end_ns = stamp_ns
            self.closed.append((subject, self.open.pop(subject)))
        return False

    def events(self, origin_ns: int) -> list[dict[str, Any]]:
        rows = []
        every = [(s, e, False) for s, e in self.closed] + [
            (s, e, True) for s, e in self.open.items()]
        for subject, episode, still_open in sorted(every, key=lambda x: x[1].start_ns):
            rows.append({'kind': self.kind, 'subject': subject,
                         'start_ns': episode.start_ns, 'end_ns': episode.end_ns,
                         'start_s': (episode.start_ns - origin_ns) * 1e-9,
                         'end_s': (episode.end_ns - origin_ns) * 1e-9,
                         'duration_s': (episode.end_ns - episode.start_ns) * 1e-9,
                         'peak': episode.peak, 'open_at_end': still_open})
        return rows


class Summarizer:
    """Summary of one output topic (see the module docstring)."""

    method = ''

    def __init__(self, topic: str) -> None:
        self.topic = topic
        self.messages = 0
        self.episodes: _Episodes | None = None

    def add(self, message: Any) -> None:
        """Take one published message."""
        self.messages += 1

    def row(self, origin_ns: int) -> dict[str, Any]:
        """The summary row (columns of SUMMARY_FIELDS that apply)."""
        return {'method': self.method, 'topic': self.topic, 'messages': self.messages}

    def events(self, origin_ns: int) -> list[dict[str, Any]]:
        """The episodes (columns of EVENT_FIELDS)."""
        if self.episodes is None:
            return []
        return [{'method': self.method, 'topic': self.topic, **event}
                for event in self.episodes.events(origin_ns)]


class _TireFlags(Summarizer):
    """Per-tire flags with a confidence: the voter's warnings, a method's indications."""

    kind = ''
    flag_field = ''

    def __init__(self, topic: str) -> None:
        super().__init__(topic)
        self.episodes = _Episodes(self.kind)
        self.raised = 0
        self.first_ns: dict[str, int] = {}
        self.max_confidence = math.nan

    def add(self, message: Any) -> None:
        super().add(message)
        stamp = header_stamp_ns(message)
        flags = getattr(message, self.flag_field)
        confidence = message.confidence
        assert self.episodes is not None
        for i, tire in enumerate(TIRES):
            value = float(confidence[i])
            if self.episodes.update(tire, bool(flags[i]), stamp, value):
                self.raised += 1
                self.first_ns.setdefault(tire, stamp)
            if bool(flags[i]) and not value <= self.max_confidence:
                self.max_confidence = value if math.isfinite(value) else self.max_confidence

    def row(self, origin_ns: int) -> dict[str, Any]:
        row = super().row(origin_ns)
        row['warnings_raised'] = self.raised
        row['max_confidence'] = self.max_confidence
        for tire in TIRES:
            first = self.first_ns.get(tire)
            row[f'first_warning_s_{tire}'] = math.nan if first is None else (
                (first - origin_ns) * 1e-9)
        return row


class WarningSummary(_TireFlags):
    """``tpms/warning`` (TpmsWarning): the voter's warnings per tire."""

    method = 'tpms_warning'
    kind = 'tire_warning'
    flag_field = 'warning'


class IndicationSummary(_TireFlags):
    """``tpms/indication/<method>`` (TpmsIndication): one method's under-inflation flags."""

    kind = 'tire_indication'
    flag_field = 'underinflated'

    def __init__(self, topic: str) -> None:
        super().__init__(topic)
        self.method = 'indication_' + topic.rstrip('/').rsplit('/', 1)[-1]


class SuspensionSummary(Summarizer):
    """``rail/suspension/modes`` (ModeProbabilities): fault episodes by component, the
    probability-weighted spring and damper ratios (their mean is the trend point)."""

    method = 'suspension'

    def __init__(self, topic: str) -> None:
        super().__init__(topic)
        self.episodes = _Episodes('suspension_fault')
        self.components: set[str] = set()
        self.sums = [0.0, 0.0]
        self.finite = [0, 0]
        self.last = [math.nan, math.nan]
        self.fault_episodes = 0

    def add(self, message: Any) -> None:
        super().add(message)
        stamp = header_stamp_ns(message)
        for i, value in enumerate((float(message.spring_ratio), float(message.damper_ratio))):
            if math.isfinite(value):
                self.sums[i] += value
                self.finite[i] += 1
                self.last[i] = value
        fault = bool(message.fault_detected)
        component = str(message.fault_component) or 'unknown'
        assert self.episodes is not None
        # the peak of a fault episode: the smoothed probability of the most likely mode
        smoothed = list(message.smoothed_probability)
        index = int(message.most_likely)
        peak = float(smoothed[index]) if 0 <= index < len(smoothed) else math.nan
        for open_component in list(self.episodes.open):
            if not fault or open_component != component:
                self.episodes.update(open_component, False, stamp, peak)
        if fault:
            self.components.add(component)
            if self.episodes.update(component, True, stamp, peak):
                self.fault_episodes += 1

    def row(self, origin_ns: int) -> dict[str, Any]:
        row = super().row(origin_ns)
        row['fault_episodes'] = self.fault_episodes
        row['fault_modes'] = ','.join(sorted(self.components))
        row['spring_ratio_mean'] = self.sums[0] / self.finite[0] if self.finite[0] else math.nan
        row['damper_ratio_mean'] = self.sums[1] / self.finite[1] if self.finite[1] else math.nan
        row['spring_ratio_last'], row['damper_ratio_last'] = self.last
        return row


class CreepSummary(Summarizer):
    """``rail/creep_factor*`` (CreepFactor): the lowest creep factor and the time the
    estimator flagged low adhesion (from each flagged message to the next)."""

    def __init__(self, topic: str) -> None:
        super().__init__(topic)
        self.method = topic.rstrip('/').rsplit('/', 1)[-1]
        self.episodes = _Episodes('low_adhesion', lower_is_worse=True)
        self.minimum = math.nan
        self.low_ns = 0
        self._previous: tuple[int, bool] | None = None

    def add(self, message: Any) -> None:
        super().add(message)
        stamp = header_stamp_ns(message)
        value = float(message.creep_factor)
        if math.isfinite(value) and not value >= self.minimum:
            self.minimum = value
        low = bool(message.low_adhesion)
        if self._previous is not None and self._previous[1]:
            self.low_ns += max(0, stamp - self._previous[0])
        self._previous = (stamp, low)
        assert self.episodes is not None
        self.episodes.update('adhesion', low, stamp, value)

    def row(self, origin_ns: int) -> dict[str, Any]:
        row = super().row(origin_ns)
        row['min_creep_factor'] = self.minimum
        row['low_adhesion_s'] = self.low_ns * 1e-9
        return row


SUMMARIZERS: dict[str, Callable[[str], Summarizer]] = {
    'vehicle_monitor_msgs/msg/TpmsWarning': WarningSummary,
    'vehicle_monitor_msgs/msg/TpmsIndication': IndicationSummary,
    'vehicle_monitor_msgs/msg/ModeProbabilities': SuspensionSummary,
    'vehicle_monitor_msgs/msg/CreepFactor': CreepSummary,
}


class RecordingSummary:
    """The engine's sink for one recording: a summarizer per summarised output topic."""

    def __init__(self) -> None:
        self.topics: dict[str, Summarizer | None] = {}

    def __call__(self, topic: str, msgtype: str, stamp_ns: int, message: Any) -> None:
        if topic not in self.topics:
            factory = SUMMARIZERS.get(msgtype)
            self.topics[topic] = factory(topic) if factory else None
        summarizer = self.topics[topic]
        if summarizer is not None:
            summarizer.add(message)

    def rows(self, origin_ns: int) -> list[dict[str, Any]]:
        """Summary rows, one per summarised topic (sorted by method)."""
        rows = [s.row(origin_ns) for s in self.topics.values() if s is not None]
        return sorted(rows, key=lambda r: r['method'])

    def events(self, origin_ns: int) -> list[dict[str, Any]]:
        """Every episode of every topic."""
        events = []
        for summarizer in self.topics.values():
            if summarizer is not None:
                events += summarizer.events(origin_ns)
        return sorted(events, key=lambda e: (e['start_ns'], e['method'], e['subject']))
