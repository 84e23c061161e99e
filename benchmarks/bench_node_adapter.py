"""What the nodes' adapter costs over their processors, without DDS in the way.

At real rate the estimators' CPU (``bench_graph.py``, section 4) is the processors' work, the
adapter's (``ProcessorNode.deliver``: arrival bookkeeping, filling and publishing the outputs)
and rclpy's executor and DDS threads; on this shared host one run of it drifts by more than a
change of the adapter is worth. This measures the adapter alone: each bag's input messages,
decoded once beforehand (rclpy decodes each once per subscription, outside the callbacks), are
handed to the graph's estimator nodes composed in one process through ``deliver`` in recorded
order, and, in the same run, to the same processors without nodes (as the offline engine would,
without its reading and routing). CPU time per second of data, best of ``--rounds``
alternations; the difference is the adapter's.

Run: ``source tools/env.sh && python benchmarks/bench_node_adapter.py [--rounds 3] [bags...]``
(default: one road and one rail bag).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
import dataclasses
from pathlib import Path
import tempfile
import time
from typing import Any

import rclpy
from rclpy.serialization import deserialize_message

from vehicle_monitor_common.bag_io import bag_topics, iter_raw
from vehicle_monitor_common.evaluation import domain_of_bag, domains
from vehicle_monitor_common.graph_spec import GraphSpec, load_graph
from vehicle_monitor_common.offline_engine import OfflineGraph
from vehicle_monitor_common.processor_node import ProcessorNode, message_class
from vehicle_monitor_common.resources import workspace_bags
from vehicle_monitor_common.runner import Graph

DEFAULT_BAGS = ('road_kim_huh_lateral', 'rail_healthy')
# (receiver, relative topic, payload): the bytes for a raw input, else the rclpy message
Feed = list[tuple[Any, str, Any]]


def estimators(bag: Path, scratch: Path) -> tuple[GraphSpec, dict[str, dict[str, Any]]]:
    """The bag's domain graph without player and recorder, on system time, with the main job's
    per-run parameters (calibration files in ``scratch``)."""
    domain = domain_of_bag(bag, domains())
    spec = load_graph(domain.graph)
    parameters = domain.run_parameters(scratch)
    nodes = tuple(dataclasses.replace(n, parameters={**n.parameters, **parameters.get(n.name, {})})
                  for n in spec.nodes if n.name not in (domain.player, domain.recorder))
    return dataclasses.replace(spec, nodes=nodes, use_sim_time=False), parameters


def feed(messages: list[tuple[str, str, int, bytes]],
         receivers: dict[str, list[tuple[Any, str, bool, Any]]]) -> Feed:
    """Every delivery in recorded order, each message decoded once (a typed input)."""
    out: Feed = []
    for topic, _, _, data in messages:
        decoded: dict[Any, Any] = {}
        for receiver, name, raw, cls in receivers.get(topic, ()):
            if not raw and cls not in decoded:
                decoded[cls] = deserialize_message(data, cls)
            out.append((receiver, name, data if raw else decoded[cls]))
    return out


def cpu_of(run: Callable[[Feed], None], deliveries: Feed) -> float:
    started = time.process_time()
    run(deliveries)
    return time.process_time() - started


def through_nodes(spec: GraphSpec, messages: list[tuple[str, str, int, bytes]]) -> float:
    graph = Graph(spec)
    try:
        receivers: dict[str, list[tuple[Any, str, bool, Any]]] = {}
        for node in graph.of_type(ProcessorNode):
            for name, spec_in in node.processor.inputs.items():
                receivers.setdefault(node.resolve_topic_name(name), []).append(
                    (node, name, spec_in.raw, message_class(spec_in.msgtype)))

        def run(deliveries: Feed) -> None:
            for node, name, payload in deliveries:
                node.deliver(name, payload)

        return cpu_of(run, feed(messages, receivers))
    finally:
        graph.destroy()


def processors_alone(spec: GraphSpec, parameters: dict[str, dict[str, Any]],
                     messages: list[tuple[str, str, int, bytes]]) -> float:
    graph = OfflineGraph.from_spec(spec, parameters)
    receivers: dict[str, list[tuple[Any, str, bool, Any]]] = {}
    for node in graph.nodes:
        for name, spec_in in node.processor.inputs.items():
            receivers.setdefault(node.topic(name), []).append(
                (node.processor, name, spec_in.raw, message_class(spec_in.msgtype)))

    def run(deliveries: Feed) -> None:
        for processor, name, payload in deliveries:
            processor.process(name, payload)

    return cpu_of(run, feed(messages, receivers))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bags', nargs='*', type=Path)
    parser.add_argument('--rounds', type=int, default=3)
    args = parser.parse_args()
    bags = args.bags or [workspace_bags() / name for name in DEFAULT_BAGS]
    rclpy.init()
    try:
        print('| bag | data s | processors alone, CPU-s per s | through the nodes | the adapter |')
        print('| --- | --- | --- | --- | --- |')
        for bag in bags:
            with tempfile.TemporaryDirectory(prefix='bench-adapter-') as scratch:
                spec, parameters = estimators(bag, Path(scratch))
                messages = list(iter_raw(bag, sorted(bag_topics(bag))))
                data_s = (messages[-1][2] - messages[0][2]) * 1e-9
                # First calls compile and cache (numba, discretisations): not counted.
                processors_alone(spec, parameters, messages)
                alone, nodes = [], []
                for _ in range(args.rounds):
                    alone.append(processors_alone(spec, parameters, messages) / data_s)
                    nodes.append(through_nodes(spec, messages) / data_s)
            print(f'| {bag.name} | {data_s:.0f} | {min(alone):.4f} | {min(nodes):.4f} | '
                  f'{min(nodes) - min(alone):+.4f} |', flush=True)
    finally:
        rclpy.shutdown()


if __name__ == '__main__':
    main()
