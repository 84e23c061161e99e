"""Replay throughput of the scenario player, as fast as possible (prints messages/s).

Cases on a shipped bag, each in one process on one executor:
1. the player alone (publishing cost only);
2. the player paced by flow control: a stand-in estimator subscribes to every wheel-speed
   sample and republishes its stamp on a progress topic that the player syncs on, and a
   recorder counts every topic: the end-to-end rate with no message dropped, once on rclpy's
   SingleThreadedExecutor and once on its EventsExecutor (what the runner uses by default).
Run under tools/env.sh: ``python benchmarks/bench_replay.py [bag]``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from vehicle_monitor_msgs.msg import WheelSpeeds

from vehicle_monitor_common.bag_io import bag_topics
from vehicle_monitor_common.node_helpers import OUTPUT_QOS
from vehicle_monitor_common.player import REPLAY_QOS, ScenarioPlayer
from vehicle_monitor_common.recorder import GraphRecorder


class ProgressEcho(Node):
    """Stand-in for an estimator: answers every wheel-speed sample with its stamp."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('progress_echo', **kwargs)
        self.count = 0
        self._out = self.create_publisher(WheelSpeeds, 'bench/progress', OUTPUT_QOS)
        self.create_subscription(WheelSpeeds, 'vehicle/wheel_speeds', self._on, REPLAY_QOS)

    def _on(self, msg: WheelSpeeds) -> None:
        self.count += 1
        self._out.publish(msg)


def _run(bag: str, paced: bool, events: bool) -> tuple[int, float, dict[str, int]]:
    context = rclpy.Context()
    rclpy.init(context=context)
    executor = (EventsExecutor(context=context) if events
                else SingleThreadedExecutor(context=context))
    nodes: list[Node] = []
    try:
        if paced:
            nodes.append(ProgressEcho(context=context))
            nodes.append(GraphRecorder(context=context))
        params = [Parameter('bag', value=bag), Parameter('as_fast_as_possible', value=True),
                  Parameter('wait_for_subscribers', value=1 if paced else 0)]
        if paced:
            params.append(Parameter('sync_topics', value=['/bench/progress']))
        for node in nodes:
            executor.add_node(node)
        started = time.monotonic()
        player = ScenarioPlayer(context=context, parameter_overrides=params)
        executor.add_node(player)
        nodes.append(player)
        while not player.done.is_set():
            executor.spin_once(timeout_sec=0.01)
        elapsed = time.monotonic() - started
        received: dict[str, int] = {}
        if paced:
            recorder = nodes[1]
            assert isinstance(recorder, GraphRecorder)
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline and sum(
                    s.count for s in recorder.stats.values()) < sum(player.published.values()):
                executor.spin_once(timeout_sec=0.01)
            received = {t: s.count for t, s in recorder.stats.items()
                        if t in player.published}
        return sum(player.published.values()), elapsed, received
    finally:
        for node in reversed(nodes):
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)


def main() -> None:
    """Print the replay rates."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bag', nargs='?', default='bags/road_puncture_15pct_fl')
    args = parser.parse_args()
    topics = bag_topics(args.bag)
    duration = 240.0 if 'puncture' in args.bag else None
    print(f'bag {args.bag}: {sum(t.count for t in topics.values())} messages on '
          f'{len(topics)} topics')
    for paced, events in ((False, True), (True, False), (True, True)):
        count, elapsed, received = _run(args.bag, paced, events)
        label = ('player alone' if not paced else
                 f'paced graph, {"EventsExecutor" if events else "SingleThreadedExecutor"}')
        line = f'{label:<44} {count:>8} msgs in {elapsed:6.2f} s = {count / elapsed:9.0f} msg/s'
        if duration:
            line += f'  ({duration / elapsed:.1f}x real time)'
        print(line)
        if paced:
            dropped = {t: n - received.get(t, 0) for t, n in
                       ((t, i.count) for t, i in topics.items()) if n != received.get(t, 0)}
            print(f'{"":<44} dropped: {dropped or "none"}')


if __name__ == '__main__':
    main()
