"""Scenario player: replays a rosbag2 onto its topics, like ``ros2 bag play``.

The replay half of ``vehicle_simulator`` and ``rail_simulator``. Messages are published as the
recorded CDR bytes (no deserialisation), with the original timing times a rate factor, or as fast
as the graph keeps up. ``/clock`` carries bag time, so nodes with ``use_sim_time`` run on it.

Topic names: a bag's absolute topics are published relative to the player's namespace, so
``--ros-args -r __ns:=/car1`` replays ``/vehicle/wheel_speeds`` as ``/car1/vehicle/wheel_speeds``;
standard ROS remapping (``-r vehicle/wheel_speeds:=other``) renames single topics. ``/clock``
stays global.

Flow control in as-fast-as-possible mode: publishing is paced by the graph's progress. Every
output of this product is stamped with the input sample it answers, so the player watches the
``sync_topics`` (outputs of the slowest nodes) and never leads the slowest of them by more than
``max_lead`` seconds of bag time. With subscriber queues deeper than max_lead x input rate, no
subscriber drops a message. A sync topic that stalls for ``sync_timeout`` s is reported and
dropped from the pacing rather than hanging the replay.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
import functools
import importlib
import struct
import sys
import threading
import time
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg

from vehicle_monitor_common.bag_io import BagError, bag_topics, iter_raw, open_reader
from vehicle_monitor_common.node_helpers import TypedParameters, run_main
from vehicle_monitor_common.parameters import ConfigurationError, param

# Reliable with a deep queue: a replay must not lose messages to a slow reader.
REPLAY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE)
ACK_TIMEOUT = Duration(seconds=5.0)
PROGRESS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                          reliability=ReliabilityPolicy.RELIABLE)
# CDR: 4-byte encapsulation header, then std_msgs/Header.stamp (int32 sec, uint32 nanosec).
_STAMP = struct.Struct('<iI')


@dataclass(frozen=True)
class PlayerParameters:
    """Parameters of the replay mode."""

    bag: str = param('', 'rosbag2 to replay: a directory holding metadata.yaml (MCAP or sqlite3)',
                     read_only=True)
    rate: float = param(1.0, 'playback speed factor over recorded time (ignored when '
                        'as_fast_as_possible)', low=1e-3, high=1e4)
    as_fast_as_possible: bool = param(False, 'publish as fast as the graph keeps up (flow '
                                      'control by sync_topics) instead of in recorded time')
    start_offset: float = param(0.0, 'bag time to skip from the start, s', low=0.0)
    loop: bool = param(False, 'replay again from the start when the bag ends (time jumps back)')
    topics: tuple[str, ...] = param((), 'topics to replay; empty: every topic of the bag',
                                    read_only=True)
    publish_clock: bool = param(True, 'publish bag time on /clock')
    clock_rate: float = param(200.0, '/clock publishing rate in bag time, Hz', low=1.0,
                              high=100000.0)
    wait_for_subscribers: int = param(0, 'before the first message, wait until every replayed '
                                      'topic has this many subscribers', low=0, high=1000)
    wait_timeout: float = param(10.0, 'longest wait for subscribers and sync topics, s (then '
                                'start anyway, with a warning)', low=0.0, high=3600.0)
    sync_topics: tuple[str, ...] = param((), 'output topics (stamped with their input time) '
                                         'that pace an as-fast-as-possible replay',
                                         read_only=True)
    max_lead: float = param(0.5, 'how far in bag time the replay may run ahead of the slowest '
                            'sync topic, s', low=1e-3, high=60.0)
    sync_timeout: float = param(10.0, 'a sync topic silent this long (wall time, s) no longer '
                                'paces the replay', low=0.1, high=3600.0)
    exit_when_done: bool = param(True, 'the executable exits when the replay ends')
    # Backpressure: waiting for the reliable readers' acknowledgements keeps the writer's
    # history (REPLAY_QOS depth) from overwriting a sample a loaded reader has not received yet.
    # In one process acknowledgements come at once; across processes Fast DDS acknowledges on
    # the writer's heartbeat (seconds apart by default), so there set 0 and rely on sync_topics.
    ack_every: int = param(100, 'every this many messages on a topic, wait until its reliable '
                           'readers acknowledged them (0: never)', low=0, high=1000)


def raw_header_stamp(data: bytes) -> tuple[int, int]:
    """(sec, nanosec) of a serialised (little-endian CDR) message that starts with a header."""
    sec, nanosec = _STAMP.unpack_from(data, 4)
    return sec, nanosec


def message_class(msgtype: str) -> Any:
    """The rclpy class of ``pkg/msg/Name``, or BagError when this install lacks it."""
    parts = msgtype.split('/')
    if len(parts) != 3:
        raise BagError(f'unknown message type {msgtype!r}')
    package, kind, name = parts
    try:
        return getattr(importlib.import_module(f'{package}.{kind}'), name)
    except (ImportError, AttributeError):
        raise BagError(f'unknown message type {msgtype!r} (no ROS package provides it '
                       'here)') from None


class ScenarioPlayer(Node):
    """Replays a bag; ``done`` is set when it ended, ``error`` holds a failure to report.

    Subclasses (the simulators) extend ``parameters_class`` and override :meth:`_prepare_bag`
    to produce the bag they replay.
    """

    parameters_class: type[PlayerParameters] = PlayerParameters

    def __init__(self, node_name: str = 'scenario_player', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, self.parameters_class, on_change=self._on_change)
        p = self._typed.value
        self.bag = self._prepare_bag(p)
        try:
            available = bag_topics(self.bag)
            reader = open_reader(self.bag)
            self._bag_start_ns = reader.start_time
            reader.close()
            missing = [t for t in p.topics if t not in available]
            if missing:
                raise BagError(f'topic {missing[0]} is not in bag {self.bag} '
                               f'(it has: {", ".join(sorted(available))})')
            selected = {name: info for name, info in available.items()
                        if not p.topics or name in p.topics}
            if not selected:
                raise BagError(f'bag {self.bag} holds no messages')
            classes = {name: message_class(info.msgtype) for name, info in selected.items()}
        except BagError as exc:
            raise ConfigurationError(str(exc)) from None
        self.topic_counts = {name: info.count for name, info in selected.items()}
        self._replay_publishers = {
            name: self.create_publisher(cls, name.lstrip('/'), REPLAY_QOS)
            for name, cls in classes.items()}
        self._clock_publisher = self.create_publisher(ClockMsg, '/clock', REPLAY_QOS)

        self.published: Counter[str] = Counter()
        self.done = threading.Event()
        self.error: str | None = None
        self._stop = threading.Event()
        self._progress_lock = threading.Condition()
        self._progress: dict[str, int] = {}
        self._sync_subscriptions: dict[str, Any] = {}
        self._stalled: set[str] = set()
        self._re_anchor = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f'{node_name}_replay',
                                        daemon=True)
        self._thread.start()

    # -- parameters --------------------------------------------------------------------------

    def _prepare_bag(self, p: PlayerParameters) -> str:
        """The bag to replay."""
        if not p.bag:
            raise ConfigurationError('parameter bag is required (path of a rosbag2 directory)')
        return p.bag

    def _on_change(self, _: PlayerParameters) -> None:
        # A new rate applies from now: restart the wall-clock schedule at the current message.
        self._re_anchor.set()

    @property
    def parameters(self) -> PlayerParameters:
        """The current, validated parameters."""
        return self._typed.value

    # -- flow control ------------------------------------------------------------------------

    def _resolve_sync_topics(self) -> bool:
        """Subscribe to every sync topic whose type the graph now knows; True when all are."""
        graph = dict(self.get_topic_names_and_types())
        for topic in self.parameters.sync_topics:
            name = self.resolve_topic_name(topic.lstrip('/'))
            if topic in self._sync_subscriptions or name not in graph:
                continue
            cls = message_class(graph[name][0])
            self._sync_subscriptions[topic] = self.create_subscription(
                cls, name, functools.partial(self._on_progress, topic), PROGRESS_QOS, raw=True)
        return len(self._sync_subscriptions) == len(self.parameters.sync_topics)

    def _on_progress(self, topic: str, data: bytes) -> None:
        sec, nanosec = raw_header_stamp(data)
        with self._progress_lock:
            stamp = sec * 1_000_000_000 + nanosec
            if stamp > self._progress.get(topic, -1):
                self._progress[topic] = stamp
                self._progress_lock.notify_all()

    def _wait_for_graph(self) -> None:
        p = self.parameters
        deadline = time.monotonic() + p.wait_timeout
        while not self._stop.is_set():
            subscribers_ok = all(pub.get_subscription_count() >= p.wait_for_subscribers
                                 for pub in self._replay_publishers.values())
            if subscribers_ok and self._resolve_sync_topics():
                return
            if time.monotonic() > deadline:
                self.get_logger().warning(
                    f'starting after {p.wait_timeout:g} s without every subscriber/sync topic '
                    f'(sync topics found: {sorted(self._sync_subscriptions)})')
                return
            self._stop.wait(0.02)

    def _wait_for_progress(self, stamp_ns: int, start_ns: int) -> None:
        """Block until the slowest sync topic is within max_lead of ``stamp_ns``."""
        p = self.parameters
        lead_ns = int(p.max_lead * 1e9)
        with self._progress_lock:
            while not self._stop.is_set():
                active = [t for t in self._sync_subscriptions if t not in self._stalled]
                if not active:
                    return
                slowest = min(self._progress.get(t, start_ns) for t in active)
                if stamp_ns <= slowest + lead_ns:
                    return
                if not self._progress_lock.wait(timeout=p.sync_timeout):
                    for topic in active:
                        if self._progress.get(topic, start_ns) == slowest:
                            self._stalled.add(topic)
                            self.get_logger().warning(
                                f'sync topic {topic} silent for {p.sync_timeout:g} s: '
                                'it no longer paces the replay')

    # -- replay ------------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._wait_for_graph()
            while not self._stop.is_set():
                last = self._play_once()
                if not self.parameters.loop:
                    break
            if self.parameters.as_fast_as_possible and not self._stop.is_set():
                # Let the graph finish the tail (outputs within max_lead of the last input: a
                # node publishing at a lower rate never stamps the very last one) before
                # declaring the replay done; the runner's drain collects what is in flight.
                self._wait_for_progress(last, last)
        except BagError as exc:
            self.error = str(exc)
        except Exception as exc:  # the node must report, not die silently in a thread
            if not self._stop.is_set():
                self.error = f'replay failed: {exc!r}'
        finally:
            self.done.set()

    def _play_once(self) -> int:
        p = self.parameters
        start_ns = self._bag_start_ns + int(p.start_offset * 1e9)
        clock_period_ns = int(1e9 / p.clock_rate)
        next_clock_ns = start_ns
        anchor_wall, anchor_bag = time.monotonic(), start_ns
        stamp = start_ns
        for topic, _, stamp, data in iter_raw(self.bag, self.topic_counts, start_ns=start_ns):
            if self._stop.is_set():
                break
            p = self.parameters
            if p.as_fast_as_possible:
                self._wait_for_progress(stamp, start_ns)
            else:
                if self._re_anchor.is_set():
                    self._re_anchor.clear()
                    anchor_wall, anchor_bag = time.monotonic(), stamp
                delay = anchor_wall + (stamp - anchor_bag) * 1e-9 / p.rate - time.monotonic()
                if delay > 0 and self._stop.wait(delay):
                    break
            if p.publish_clock and stamp >= next_clock_ns:
                clock = ClockMsg()
                clock.clock.sec, clock.clock.nanosec = divmod(stamp, 1_000_000_000)
                self._clock_publisher.publish(clock)
                next_clock_ns = stamp + clock_period_ns
            publisher = self._replay_publishers[topic]
            publisher.publish(bytes(data))
            self.published[topic] += 1
            if (p.ack_every and self.published[topic] % p.ack_every == 0
                    and not publisher.wait_for_all_acked(ACK_TIMEOUT)):
                self.get_logger().warning(
                    f'{topic}: a subscriber did not acknowledge within '
                    f'{ACK_TIMEOUT.nanoseconds * 1e-9:g} s; replay goes on', once=True)
        return stamp

    def destroy_node(self) -> None:
        """Stop the replay thread before the publishers go away."""
        self._stop.set()
        with self._progress_lock:
            self._progress_lock.notify_all()
        self._thread.join(timeout=5.0)
        super().destroy_node()


def run_player(factory: Callable[[], ScenarioPlayer], args: list[str] | None = None) -> int:
    """main() of a player/simulator executable: play, exit 0 when done, 1 on a replay error."""

    def body(cleanups: list[Callable[[], None]]) -> int:
        player = factory()
        cleanups.append(player.destroy_node)
        executor = SingleThreadedExecutor()
        executor.add_node(player)
        started = time.monotonic()
        while rclpy.ok() and not (player.done.is_set() and player.parameters.exit_when_done):
            executor.spin_once(timeout_sec=0.05)
        if player.error:
            print(f'error: {player.error}', file=sys.stderr)
            return 1
        if player.done.is_set():
            total = sum(player.published.values())
            player.get_logger().info(
                f'replayed {total} messages on {len(player.published)} topics in '
                f'{time.monotonic() - started:.2f} s')
        return 0

    return run_main(body, args)
