"""``offline_engine``: a graph's node logic run over a recording, ROS-free (no rclpy, no DDS).

The live graph delivers every message through rclpy and DDS, which bounds a replay at a few
times real time here whatever the estimators cost. The engine runs the same node logic, the
nodes' processors (:mod:`vehicle_monitor_common.processing`), directly: it reads the recording
in log-time order (rosbags), hands each message to the processors that subscribe its topic —
the serialised bytes to a raw input, the decoded message otherwise — and routes what they
publish to the processors that subscribe those topics at once (the voter gets the indications),
as the live graph's executor does, one message at a time. Outputs are built as the messages
the nodes publish (rosbags' types from the same ``msg_defs``), so they can be written to a bag
or compared with what the live graph recorded.

Topic names resolve as in ROS: a relative name is expanded with the node's namespace, then
remapped. Which processor a node plugin has is registered by the packages under the
``vehicle_monitor.processors`` entry-point group (``make_processor(values, fqn)``, with the
node's parameter values as the node would get them); nodes without a processor (simulators,
recorders) are skipped: the recording plays their part.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
import importlib
from importlib.metadata import EntryPoint, entry_points
import os
from pathlib import Path
import tempfile
import time
from typing import Any

from vehicle_monitor_common.bag_io import (
    BAG_RTOL,
    BagWriter,
    bag_topics,
    compare_bags,
    iter_raw,
    message_from_fields,
    typestore,
)
from vehicle_monitor_common.graph_spec import (
    GraphSpec,
    fully_qualified_name,
    node_parameter_values,
)
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.processing import Input, Output, Processor

PROCESSOR_GROUP = 'vehicle_monitor.processors'
ProcessorFactory = Callable[[Mapping[str, Any], str], Processor]
# topic, message type, stamp (ns), rosbags message
Sink = Callable[[str, str, int, Any], None]


def processor_factories() -> dict[str, ProcessorFactory]:
    """``package/node`` -> the function that builds that node's processor.

    Each is imported when first called, so a registration whose module cannot be imported
    fails only the graphs that use it, with its error, not every graph.
    """
    return {f'{ep.dist.name if ep.dist else ""}/{ep.name}': _lazy(ep)
            for ep in entry_points(group=PROCESSOR_GROUP)}


def _lazy(entry_point: EntryPoint) -> ProcessorFactory:
    def factory(values: Mapping[str, Any], fqn: str) -> Processor:
        made: Processor = entry_point.load()(values, fqn)
        return made

    return factory


def factory_for(plugin: str, factories: Mapping[str, ProcessorFactory],
                ) -> ProcessorFactory | None:
    """The processor factory of a node plugin: a registered one (``package/node``), or one
    named by import path (``module.path:function``, for processors not installed as entry
    points, e.g. a test's), or None (the node has no processor)."""
    factory = factories.get(plugin)
    if factory is None and ':' in plugin:
        module, _, attribute = plugin.partition(':')
        factory = getattr(importlib.import_module(module), attribute)
    return factory


def expand_topic(name: str, namespace: str, remappings: Mapping[str, str]) -> str:
    """A node's topic name as ROS resolves it: expanded with the namespace, then remapped."""

    def expand(topic: str) -> str:
        return topic if topic.startswith('/') else f'{namespace.rstrip("/")}/{topic}'

    full = expand(name)
    for source, target in remappings.items():
        if expand(source) == full:
            return expand(target)
    return full


@dataclass
class EngineNode:
    """One node of an offline graph: its processor and where its topics resolve."""

    fqn: str
    processor: Processor
    namespace: str = ''
    remappings: Mapping[str, str] = field(default_factory=dict)

    def topic(self, name: str) -> str:
        """The absolute name of one of its topics."""
        return expand_topic(name, self.namespace, self.remappings)


@dataclass
class EngineStats:
    """What one run did: messages read and published, data and wall time."""

    messages_in: int = 0
    messages_out: int = 0
    first_ns: int | None = None
    last_ns: int | None = None
    wall_s: float = 0.0
    published: dict[str, int] = field(default_factory=dict)

    @property
    def data_s(self) -> float:
        """Recorded time spanned, s."""
        return 0.0 if self.first_ns is None or self.last_ns is None else (
            (self.last_ns - self.first_ns) * 1e-9)

    @property
    def real_time_factor(self) -> float:
        """Recorded time per wall second."""
        return self.data_s / self.wall_s if self.wall_s > 0 else float('inf')


class OfflineGraph:
    """Processors wired by topic, run over recordings."""

    def __init__(self, nodes: Iterable[EngineNode]) -> None:
        self.nodes = list(nodes)
        # absolute topic -> [(node, its relative name, input spec)]
        self._subscribers: dict[str, list[tuple[EngineNode, str, Input]]] = {}
        self._outputs: dict[tuple[int, str], tuple[str, str]] = {}
        for node in self.nodes:
            for name, spec in node.processor.inputs.items():
                self._subscribers.setdefault(node.topic(name), []).append((node, name, spec))
            for name, msgtype in node.processor.outputs.items():
                self._outputs[(id(node), name)] = (node.topic(name), msgtype)
        self._store = typestore()

    @classmethod
    def from_spec(cls, spec: GraphSpec,
                  parameters: Mapping[str, Mapping[str, Any]] | None = None) -> OfflineGraph:
        """The processors of a graph or launch file's nodes (those that have one), each with
        the parameter values the node would get, plus ``parameters[fqn or name]`` on top (a
        vehicle's own values)."""
        factories = processor_factories()
        nodes = []
        for node_spec in spec.nodes:
            factory = factory_for(node_spec.plugin, factories)
            if factory is None:
                continue
            name = node_spec.name or node_spec.plugin.split('/')[-1]
            fqn = fully_qualified_name(node_spec.namespace, name)
            values = node_parameter_values(fqn, node_spec.param_files, node_spec.parameters)
            given = parameters or {}
            values.update(given.get(fqn, given.get(name, {})))
            try:
                processor = factory(values, fqn)
            except (TypeError, ValueError) as exc:
                raise ConfigurationError(f'{fqn}: {exc}') from None
            nodes.append(EngineNode(fqn, processor, node_spec.namespace,
                                    dict(node_spec.remappings)))
        if not nodes:
            raise ConfigurationError('the graph has no node with an offline processor')
        return cls(nodes)

    @property
    def input_topics(self) -> set[str]:
        """Absolute topics the graph reads."""
        return set(self._subscribers)

    def run(self, bag: str | os.PathLike[str], sink: Sink | None = None) -> EngineStats:
        """Feed every message of the recording on a subscribed topic through the graph.

        ``sink(topic, msgtype, stamp_ns, message)`` receives every published message in the
        order of publication. Messages on topics no processor reads are not decoded.
        """
        stats = EngineStats()
        started = time.perf_counter()
        recorded = bag_topics(bag)
        present = sorted(t for t in self.input_topics if t in recorded)
        for topic, msgtype, log_ns, data in iter_raw(bag, present):
            stats.messages_in += 1
            stats.first_ns = log_ns if stats.first_ns is None else stats.first_ns
            stats.last_ns = log_ns
            self._deliver(topic, msgtype, data, None, sink, stats)
        stats.wall_s = time.perf_counter() - started
        return stats

    def _deliver(self, topic: str, msgtype: str, data: bytes | None, message: Any,
                 sink: Sink | None, stats: EngineStats) -> None:
        for node, name, spec in self._subscribers.get(topic, ()):
            if spec.raw:
                if data is None:
                    data = bytes(self._store.serialize_cdr(message, msgtype))
                payload: Any = data
            else:
                if message is None:
                    assert data is not None
                    message = self._store.deserialize_cdr(data, msgtype)
                payload = message
            for output in node.processor.process(name, payload):
                self._publish(node, output, sink, stats)

    def _publish(self, node: EngineNode, output: Output, sink: Sink | None,
                 stats: EngineStats) -> None:
        topic, msgtype = self._outputs[(id(node), output.topic)]
        sec, nanosec = divmod(output.stamp_ns, 1_000_000_000)
        fields = dict(output.fields)
        fields['header'] = {**fields.get('header', {}),
                            'stamp': {'sec': sec, 'nanosec': nanosec}}
        message = message_from_fields(self._store, msgtype, fields)
        stats.messages_out += 1
        stats.published[topic] = stats.published.get(topic, 0) + 1
        if sink is not None:
            sink(topic, msgtype, output.stamp_ns, message)
        self._deliver(topic, msgtype, None, message, sink, stats)


def write_outputs(graph: OfflineGraph, bag: str | os.PathLike[str],
                  out: str | os.PathLike[str]) -> EngineStats:
    """Run the graph over ``bag`` and write everything it publishes to the bag ``out``
    (log time = header stamp, the sample each output answers)."""
    with BagWriter(Path(out), overwrite=True) as writer:
        return graph.run(bag, lambda topic, msgtype, stamp, msg:
                         writer.write(topic, msgtype, stamp, msg))


def compare_outputs(expected: str | os.PathLike[str], actual: str | os.PathLike[str],
                    topics: Iterable[str], *, rtol: float = BAG_RTOL) -> list[str]:
    """What differs between two recordings' messages on ``topics``, each topic on its own and
    by header stamp (empty when they agree), as :func:`bag_io.compare_bags` judges values.

    A live recording logs each output at its arrival, interleaved with the other topics as
    DDS delivered them; the engine logs it at its header stamp. Per topic, in header-stamp
    order, both say the same: this is how the engine's outputs are checked against the live
    graph's.
    """
    store = typestore()
    problems = []
    with tempfile.TemporaryDirectory(prefix='compare-') as scratch:
        for index, topic in enumerate(sorted(topics)):
            rewritten = []
            for side, bag in (('expected', expected), ('actual', actual)):
                path = Path(scratch) / f'{index}_{side}'
                with BagWriter(path) as writer:
                    if topic in bag_topics(bag):
                        for _, msgtype, _, data in iter_raw(bag, [topic]):
                            message: Any = store.deserialize_cdr(data, msgtype)
                            stamp = message.header.stamp
                            writer.write_raw(topic, msgtype,
                                             stamp.sec * 1_000_000_000 + stamp.nanosec, data)
                rewritten.append(path)
            problems += compare_bags(rewritten[0], rewritten[1], rtol=rtol)
    return problems
