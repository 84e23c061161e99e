"""Graph recorder: subscribes to topics, counts them and optionally writes them to a bag.

How the main job and the evaluation tools capture what a graph published. Subscriptions are
raw (the CDR bytes go to the bag untouched), reliable and deep, so a replay paced by the player
loses nothing here either. The bag is written as the shipped ones are (``BagWriter``'s default):
one plain ``.mcap`` file with zstd-compressed chunks, which every MCAP tool opens.
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import time
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

from vehicle_monitor_common.bag_io import BagWriter
from vehicle_monitor_common.node_helpers import TypedParameters
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.player import message_class

RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5000,
                        reliability=ReliabilityPolicy.RELIABLE)


@dataclass(frozen=True)
class RecorderParameters:
    """Parameters of the graph recorder."""

    topics: tuple[str, ...] = param((), 'topics to record; empty: every topic that appears '
                                    '(but /clock, /rosout, /parameter_events)', read_only=True)
    bag: str = param('', 'write what is received to this rosbag2 (MCAP); empty: count only',
                     read_only=True)
    discovery_period: float = param(0.2, 'how often to look for new topics, s (wall)',
                                    low=0.01, high=60.0)


@dataclass
class TopicStats:
    """What arrived on one topic."""

    msgtype: str
    count: int = 0
    first_wall: float = 0.0
    last_wall: float = 0.0

    @property
    def rate_hz(self) -> float:
        """Mean arrival rate over wall time, Hz (0 with fewer than two messages)."""
        span = self.last_wall - self.first_wall
        return (self.count - 1) / span if self.count > 1 and span > 0 else 0.0


_IGNORED = {'/clock', '/rosout', '/parameter_events'}


class GraphRecorder(Node):
    """Records topics as they appear on the graph."""

    def __init__(self, node_name: str = 'graph_recorder', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, RecorderParameters)
        p = self._typed.value
        self.stats: dict[str, TopicStats] = {}
        self._writer: BagWriter | None = None
        if p.bag:
            self._writer = BagWriter(p.bag, overwrite=True).__enter__()
        self._recorded: dict[str, Any] = {}
        # Discovery on wall time: with use_sim_time the node clock stands still until /clock.
        self._timer = self.create_timer(p.discovery_period, self._discover,
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._discover()

    def _discover(self) -> None:
        wanted = set(self._typed.value.topics)
        for name, types in self.get_topic_names_and_types():
            if name in self._recorded or name in _IGNORED:
                continue
            if wanted and name not in wanted:
                continue
            cls = message_class(types[0])
            self.stats[name] = TopicStats(types[0])
            self._recorded[name] = self.create_subscription(
                cls, name, functools.partial(self._on_message, name), RECORD_QOS, raw=True)

    def _on_message(self, topic: str, data: bytes) -> None:
        now = time.monotonic()
        stats = self.stats[topic]
        if stats.count == 0:
            stats.first_wall = now
        stats.count += 1
        stats.last_wall = now
        if self._writer is not None:
            self._writer.write_raw(topic, stats.msgtype, self.get_clock().now().nanoseconds,
                                   data)

    def summary(self) -> str:
        """A table of topics with message counts and mean rates."""
        width = max((len(t) for t in self.stats), default=5)
        lines = [f'{"topic":<{width}}  {"count":>8}  {"rate (Hz, wall)":>15}  type']
        for topic in sorted(self.stats):
            s = self.stats[topic]
            lines.append(f'{topic:<{width}}  {s.count:>8}  {s.rate_hz:>15.1f}  {s.msgtype}')
        return '\n'.join(lines)

    def destroy_node(self) -> None:
        """Close the bag (moved into place complete) before the node goes."""
        if self._writer is not None:
            self._writer.__exit__(None, None, None)
            self._writer = None
        super().destroy_node()
