"""Node-graph benchmarks: replay speed, input-to-warning latency, CPU per node, composition.

Prints (figures, not timed tests; docs/targets.md targets in brackets):

1. Replay as fast as possible of each registered scenario through its domain's graph, composed
   in one process on the EventsExecutor: real-time factor over wall time and over the process's
   CPU time (the machine is shared: CPU time is what the graph itself costs), messages
   published vs received by the recorder [>= 10x, no message dropped]; and the CPU time per
   node, measured around every callback (subscriptions, timers, services), the player's thread
   and the rest (executor, deserialisation, middleware). Next to it, the ceiling: the same
   topology (each estimator's subscriptions and publishers with their types and QoS, the same
   executor and use_sim_time, the real player and recorder) with every estimator replaced by a
   no-op node that publishes as many (default) outputs as the real one did, stamped with its
   input, so the pacing and the message count are the real replay's: what rclpy and the
   middleware reach on this machine when estimator work costs nothing.
2. The same graph with one process per node (each on its own executor, DDS between processes)
   vs composed: real-time factor and the CPU of each process.
3. End-to-end latency at real rate: from a wheel-speed sample to the first ``/tpms/warning``
   stamped with it, p50/p99 [p99 < 5 ms], the player (the vehicle's sensors) in a process of
   its own and the estimators composed in one process or one process each, every node on
   system time and no ``/clock``, as on the vehicle.
   The sample's publish time is its bag time plus the player's schedule offset (the smallest
   receive-minus-stamp delay of any wheel-speed sample).
4. The CPU the estimators need per second of data at real rate, as on the vehicle: the
   graph's estimators composed in one process, the player in its own, the estimators'
   process CPU time (executor and middleware included) over each replay, and the part of it
   spent in the nodes' callbacks [<= 0.15].
5. Each estimator's offline throughput vs the plainest per-sample implementation of the same
   maths, collected from the estimator benchmarks (benchmarks/bench_*.py, run as they are).

Run under tools/env.sh: ``python benchmarks/bench_graph.py [--quick] [--skip-ceiling]
[--skip-latency] [--skip-processes] [--skip-real-rate-cpu] [--skip-offline]``; ``--quick``
leaves out the 240 s puncture scenario.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Callable
import dataclasses
import functools
import multiprocessing
from pathlib import Path
import re
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any

from builtin_interfaces.msg import Time
import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.task import Future
import yaml

from vehicle_monitor_common.bag_io import bag_topics
from vehicle_monitor_common.evaluation import Domain, Scenario, domains
from vehicle_monitor_common.main_job import (
    bag_duration_s,
    run_graph_on_bag,
    use_private_domain,
    with_parameters,
)
from vehicle_monitor_common.player import ScenarioPlayer, raw_header_stamp
from vehicle_monitor_common.processor_node import ProcessorNode
from vehicle_monitor_common.recorder import GraphRecorder
from vehicle_monitor_common.runner import (
    EXECUTORS,
    Graph,
    GraphSpec,
    NodeSpec,
    load_graph,
    node_class,
)

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------------------------------------
# 1. composed replay with CPU per node


class CallbackClock:
    """Accumulates the thread CPU time spent in each node's callbacks."""

    def __init__(self) -> None:
        self.cpu_s: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)

    def instrument(self, graph: Graph) -> None:
        """Wrap every subscription, timer and service callback of the graph's nodes; for an
        estimator node its ``deliver`` instead of its subscriptions, as one subscription may
        deliver to several of them (``share_inputs``)."""
        for node in graph.nodes:
            name = node.get_name()
            entities: list[Any] = [*node.timers, *node.services]
            if isinstance(node, ProcessorNode):
                node.deliver = self._timed(name, node.deliver)  # type: ignore[method-assign]
            else:
                entities += node.subscriptions
            for entity in entities:
                entity.callback = self._timed(name, entity.callback)

    def _timed(self, name: str, callback: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(callback)
        def timed(*args: Any) -> Any:
            started = time.thread_time()
            try:
                return callback(*args)
            finally:
                self.cpu_s[name] += time.thread_time() - started
                self.calls[name] += 1
        return timed


def _thread_cpu_s(native_id: int | None) -> float:
    """CPU time (user + system) of one thread of this process, from /proc."""
    if native_id is None:
        return 0.0
    try:
        fields = Path(f'/proc/self/task/{native_id}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return 0.0
    import os
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


class ThreadCpuSampler:
    """Samples one thread's CPU time from /proc while it lives (it ends with the replay)."""

    def __init__(self) -> None:
        self.native_id: int | None = None
        self.cpu_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def start(self, native_id: int | None) -> None:
        """Watch the thread with this native id."""
        self.native_id = native_id
        self._thread.start()

    def stop(self) -> None:
        """Stop sampling."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            self.cpu_s = max(self.cpu_s, _thread_cpu_s(self.native_id))


def composed_replay(domain: Domain, scenario: Scenario, work: Path) -> dict[str, Any]:
    """Replay one scenario through the composed graph; print speed and CPU per node.

    Returns the figures, the recording (``'recorded'``) and the estimators' topology
    (``'topology'``, read from the live graph) for the ceiling run.
    """
    clock = CallbackClock()
    player_cpu = ThreadCpuSampler()
    topology: list[NodeTopology] = []

    def on_graph(graph: Graph) -> None:
        topology.extend(NodeTopology.of(node, graph.spec.use_sim_time) for node in graph.nodes
                        if not isinstance(node, ScenarioPlayer | GraphRecorder))
        clock.instrument(graph)
        player = graph.of_type(ScenarioPlayer)[0]
        player_cpu.start(player._thread.native_id)  # noqa: SLF001 (benchmark probe)

    try:
        recorded, stats = run_graph_on_bag(domain, scenario.bag, work / scenario.name,
                                           label=scenario.name, log=lambda line: None,
                                           on_graph=on_graph)
    finally:
        player_cpu.stop()
    total_cpu = stats.cpu_s
    print(f'  {domain.name} graph on {scenario.name}: {stats.bag_duration_s:.0f} s of bag in '
          f'{stats.wall_s:.1f} s = {stats.real_time_factor:.1f}x real time wall, '
          f'{stats.cpu_real_time_factor:.1f}x per CPU second [>= 10x]; '
          f'{stats.published} published, {stats.dropped} dropped [0]')
    nodes_cpu = sum(clock.cpu_s.values())
    rows = sorted(clock.cpu_s.items(), key=lambda item: -item[1])
    for name, cpu in rows:
        print(f'      {name:<28} {cpu:7.2f} s CPU  {100 * cpu / total_cpu:5.1f} %  '
              f'{clock.calls[name]:>8} callbacks  {1e6 * cpu / max(clock.calls[name], 1):7.0f}'
              f' us/callback')
    rest = total_cpu - nodes_cpu - player_cpu.cpu_s
    print(f'      {"player thread (publishing)":<28} {player_cpu.cpu_s:7.2f} s CPU  '
          f'{100 * player_cpu.cpu_s / total_cpu:5.1f} %')
    print(f'      {"executor, middleware, rest":<28} {rest:7.2f} s CPU  '
          f'{100 * rest / total_cpu:5.1f} %   (replay: {total_cpu:.1f} s CPU)')
    return {'rtf': stats.real_time_factor, 'cpu_rtf': stats.cpu_real_time_factor,
            'dropped': stats.dropped, 'recorded': recorded, 'topology': topology}


@dataclasses.dataclass(frozen=True)
class Endpoint:
    """A subscription or publisher as the node created it (resolved topic, effective QoS)."""

    topic: str
    msg_type: Any
    qos: QoSProfile
    raw: bool = False


@dataclasses.dataclass(frozen=True)
class NodeTopology:
    """What a node puts on the graph: its name, subscriptions and publishers."""

    name: str
    namespace: str
    subscriptions: tuple[Endpoint, ...]
    publishers: tuple[Endpoint, ...]

    @classmethod
    def of(cls, node: Node, use_sim_time: bool) -> NodeTopology:
        """Read a live node. Left out: what every rclpy node creates itself
        (``/parameter_events``; ``/rosout`` is not listed) and, with use_sim_time, the time
        source's ``/clock`` subscription, which the null node's own use_sim_time recreates."""
        return cls(
            node.get_name(), node.get_namespace(),
            tuple(Endpoint(s.topic_name, s.msg_type, s.qos_profile, bool(s.raw))
                  for s in node.subscriptions
                  if not (use_sim_time and s.topic_name == '/clock')),
            tuple(Endpoint(p.topic_name, p.msg_type, p.qos_profile) for p in node.publishers
                  if p.topic_name != '/parameter_events'))


@dataclasses.dataclass(frozen=True)
class NullPlan:
    """A null node's topology and how many outputs it publishes per input.

    ``outputs[i]`` messages go out on publisher ``i`` over ``trigger_count`` messages of the
    ``trigger`` input (the busiest one), spread evenly (Bresenham): the real node's output
    count, at its mean rate in data time.
    """

    topology: NodeTopology
    trigger: str
    trigger_count: int
    outputs: tuple[int, ...]


# Null node plans by node name: the graph file names the class, not its arguments.
_NULL_PLANS: dict[str, NullPlan] = {}


class NullNode(Node):
    """A no-op stand-in for an estimator: its subscriptions and publishers, none of its work.

    Every input is received (deserialised, or raw where the real node subscribes raw) and
    dropped. Per message of the trigger input, the outputs due by then are published: a message
    built once (default values), its ``header.stamp`` set to the latest input stamp, as every
    output of this product is stamped with the input it answers; the player's pacing on the
    sync topics therefore advances as with the real node.
    """

    def __init__(self, node_name: str, **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        plan = _NULL_PLANS[node_name]
        self._plan = plan
        self._received = 0
        self._sent = [0] * len(plan.outputs)
        self._stamp: Any = None
        self._outputs = [(self.create_publisher(p.msg_type, p.topic, p.qos), p.msg_type())
                         for p in plan.topology.publishers]
        for endpoint in plan.topology.subscriptions:
            callback = self._on_trigger if endpoint.topic == plan.trigger else self._on_input
            self.create_subscription(endpoint.msg_type, endpoint.topic, callback, endpoint.qos,
                                     raw=endpoint.raw)

    def _on_input(self, msg: Any) -> None:
        if isinstance(msg, bytes):
            # a raw subscription: stamped messages start with header.stamp (as the real node
            # reads it, from the bytes)
            sec, nanosec = raw_header_stamp(msg)
            self._stamp = Time(sec=sec, nanosec=nanosec)
            return
        header = getattr(msg, 'header', None)
        if header is not None:
            self._stamp = header.stamp

    def _on_trigger(self, msg: Any) -> None:
        self._on_input(msg)
        self._received += 1
        plan = self._plan
        for index, (publisher, output) in enumerate(self._outputs):
            due = self._received * plan.outputs[index] // plan.trigger_count
            while self._sent[index] < due:
                if self._stamp is not None and hasattr(output, 'header'):
                    output.header.stamp = self._stamp
                publisher.publish(output)
                self._sent[index] += 1


def null_plans(topology: list[NodeTopology], counts: dict[str, int]) -> list[NullPlan]:
    """Plans reproducing a real run's message counts (``counts`` by topic, as recorded).

    A topic several nodes publish (``/diagnostics``) is shared evenly between them.
    """
    publishers: dict[str, int] = defaultdict(int)
    for node in topology:
        for endpoint in node.publishers:
            publishers[endpoint.topic] += 1
    plans = []
    for node in topology:
        trigger = max(node.subscriptions, key=lambda s: counts.get(s.topic, 0)).topic
        outputs = tuple(counts.get(p.topic, 0) // publishers[p.topic] for p in node.publishers)
        plans.append(NullPlan(node, trigger, max(counts.get(trigger, 0), 1), outputs))
    return plans


def ceiling_replay(domain: Domain, scenario: Scenario, work: Path, real: dict[str, Any],
                   ) -> dict[str, Any]:
    """Replay the scenario through the real graph's topology with no-op estimators.

    The same graph file with each estimator's plugin replaced by :class:`NullNode` (player,
    recorder, executor, use_sim_time unchanged), run through the same ``run_graph_on_bag``
    as the real graph, its output counts taken from the real run's recording (``real``, from
    :func:`composed_replay`).
    """
    counts = {topic: info.count for topic, info in bag_topics(real['recorded']).items()}
    plans = null_plans(real['topology'], counts)
    _NULL_PLANS.clear()
    _NULL_PLANS.update({plan.topology.name: plan for plan in plans})
    spec = load_graph(domain.graph)
    keep = {domain.player, domain.recorder}
    nodes = []
    for node in spec.nodes:
        name = node.name or node.plugin.split('/')[-1]
        if name in keep:
            nodes.append(dataclasses.asdict(node))
        else:
            # Parameters (the run's calibration files) stay: the null node ignores them.
            nodes.append({'plugin': f'{__name__}:NullNode', 'name': name,
                          'namespace': node.namespace, 'parameters': dict(node.parameters)})
    graph_file = work / f'{scenario.name}_null_graph.yaml'
    graph_file.write_text(yaml.safe_dump({'executor': spec.executor,
                                          'use_sim_time': spec.use_sim_time, 'nodes': nodes}))
    _, stats = run_graph_on_bag(dataclasses.replace(domain, graph=graph_file), scenario.bag,
                                work / f'{scenario.name}_null', label=scenario.name,
                                log=lambda line: None)
    print(f'  ceiling, {domain.name} graph topology with no-op nodes on {scenario.name}: '
          f'{stats.bag_duration_s:.0f} s of bag in {stats.wall_s:.1f} s = '
          f'{stats.real_time_factor:.1f}x real time wall, {stats.cpu_real_time_factor:.1f}x '
          f'per CPU second; {stats.published} published, {stats.dropped} dropped; the real '
          f'graph reaches {100 * real["rtf"] / stats.real_time_factor:.0f} % of it (wall), '
          f'{100 * real["cpu_rtf"] / stats.cpu_real_time_factor:.0f} % (CPU)')
    return {'rtf': stats.real_time_factor, 'cpu_rtf': stats.cpu_real_time_factor,
            'dropped': stats.dropped}


# ---------------------------------------------------------------------------------------------
# 2. one process per node


def _node_process(node_spec: NodeSpec, use_sim_time: bool, executor: str,
                  stop: Any, results: Any, expected: dict[str, int]) -> None:
    """Child: one node on its own executor until ``stop`` (or, for a player, its end).

    The player's acknowledgement wait is switched off here (``ack_every: 0``): across
    processes a reliable reader acknowledges on the writer's DDS heartbeat (seconds apart with
    the Fast DDS defaults), which would pace the replay at a few hundred messages per second.
    The sync topics still pace it; drops, if any, are counted.
    """
    if issubclass(node_class(node_spec.plugin), ScenarioPlayer):  # type: ignore[arg-type]
        node_spec = dataclasses.replace(
            node_spec, parameters={**node_spec.parameters, 'ack_every': 0})
    context = rclpy.Context()
    rclpy.init(context=context)
    graph = Graph(GraphSpec((node_spec,), executor, use_sim_time), context)
    node = graph.nodes[0]
    finished: Future = Future()
    first: list[float] = []
    complete: list[float] = []
    last_total = [0, 0.0]  # recorder: total received, when it last grew

    def watch() -> None:
        while not finished.done():
            if isinstance(node, ScenarioPlayer) and node.done.is_set() or stop.is_set():
                finished.set_result(True)
            if isinstance(node, GraphRecorder):
                counts = {t: s.count for t, s in list(node.stats.items())}
                total = sum(counts.values())
                if total and not first:
                    first.append(time.monotonic())
                if total != last_total[0]:
                    last_total[:] = [total, time.monotonic()]
                if not complete and all(counts.get(t, 0) >= n for t, n in expected.items()):
                    complete.append(time.monotonic())
                    results.put(('recorder_complete', None))
            time.sleep(0.01)

    thread = threading.Thread(target=watch, daemon=True)
    thread.start()
    cpu_start = time.process_time()
    try:
        while not finished.done():
            graph.executor.spin_until_future_complete(finished, timeout_sec=0.5)
        report: dict[str, Any] = {'name': node.get_name(),
                                  'cpu_s': time.process_time() - cpu_start}
        if isinstance(node, GraphRecorder):
            report['received'] = {t: s.count for t, s in node.stats.items()}
            report['span_s'] = (complete[0] if complete else last_total[1]) - (
                first[0] if first else last_total[1])
        if isinstance(node, ScenarioPlayer):
            report['published'] = dict(node.published)
            results.put(('player_done', None))
        results.put(('report', report))
    finally:
        graph.destroy()
        rclpy.try_shutdown(context=context)


def _composed_process(spec: GraphSpec, stop: Any, results: Any = None) -> None:
    """Child: the nodes of ``spec`` composed on one executor until ``stop``; with ``results``,
    the process's CPU time and the CPU time spent in the nodes' callbacks, sampled every
    ``CPU_SAMPLE_S`` as (monotonic s, process CPU s, callback CPU s), put there as
    ('cpu', samples) at the end."""
    context = rclpy.Context()
    rclpy.init(context=context)
    graph = Graph(spec, context)
    never: Future = Future()
    cpu: list[tuple[float, float, float]] = []
    clock = CallbackClock()

    def sample() -> None:
        while not stop.is_set():
            cpu.append((time.monotonic(), time.process_time(), sum(clock.cpu_s.values())))
            time.sleep(CPU_SAMPLE_S)

    if results is not None:
        clock.instrument(graph)
        threading.Thread(target=sample, daemon=True).start()
    try:
        while not stop.is_set():
            graph.executor.spin_until_future_complete(never, timeout_sec=0.2)
    finally:
        graph.destroy()
        rclpy.try_shutdown(context=context)
        if results is not None:
            results.put(('cpu', cpu))


def _node_processes(spec: GraphSpec, player: str, expected: dict[str, int],
                    ) -> tuple[list[NodeSpec], list[Any], Any, Any]:
    """One (unstarted) process per node of ``spec``, the player last so the others are up
    when it starts: (nodes in that order, processes, stop event, results queue)."""
    spawn = multiprocessing.get_context('spawn')
    stop = spawn.Event()
    results = spawn.Queue()
    ordered = sorted(spec.nodes, key=lambda n: n.name == player)
    processes = [spawn.Process(target=_node_process, args=(
        n, spec.use_sim_time, spec.executor, stop, results, expected), daemon=True)
        for n in ordered]
    return ordered, processes, stop, results


def process_per_node(domain: Domain, scenario: Scenario) -> dict[str, Any]:
    """Run the domain's graph with every node in its own process; print speed and CPU."""
    spec = with_parameters(load_graph(domain.graph), {
        domain.player: {'bag': str(scenario.bag)}, domain.recorder: {'bag': ''}})
    expected = {t: info.count for t, info in bag_topics(scenario.bag).items()}
    ordered, processes, stop, results = _node_processes(spec, domain.player, expected)
    for process in processes:
        process.start()
    reports: list[dict[str, Any]] = []
    events: set[str] = set()
    deadline = time.monotonic() + 60.0 + 20.0 * bag_duration_s(scenario.bag)
    while len(reports) < len(processes) and time.monotonic() < deadline:
        try:
            kind, payload = results.get(timeout=0.5)
        except Exception:  # queue.Empty: keep waiting
            continue
        if kind == 'report':
            reports.append(payload)
        else:
            events.add(kind)
        if {'player_done', 'recorder_complete'} <= events or (
                'player_done' in events and time.monotonic() > deadline - 30):
            stop.set()
        if 'player_done' in events and not stop.is_set():
            # Give the recorder a moment for the tail, then stop everyone.
            threading.Timer(5.0, stop.set).start()
    stop.set()
    for process in processes:
        process.join(timeout=10.0)
    duration = bag_duration_s(scenario.bag)
    missing = sorted({n.name or n.plugin for n in ordered} - {r['name'] for r in reports})
    if missing:
        print(f'  {scenario.name}: no report from {", ".join(missing)} (failed to start or '
              'hung; see its traceback above): the figures below lack it')
    recorder = next((r for r in reports if 'received' in r), None)
    player = next((r for r in reports if 'published' in r), None)
    if recorder is None or player is None:
        print(f'  {scenario.name}: one process per node did not finish')
        return {}
    dropped = sum(max(0, n - recorder['received'].get(t, 0))
                  for t, n in player['published'].items())
    span = recorder['span_s']
    total_cpu = sum(r['cpu_s'] for r in reports)
    print(f'  {domain.name} graph on {scenario.name}, one process per node: {duration:.0f} s of '
          f'bag in {span:.1f} s = {duration / span:.1f}x real time wall, '
          f'{duration / total_cpu:.1f}x per CPU second (all processes); {dropped} dropped')
    if dropped:
        print('      (without the acknowledgement wait the player\'s writer history overruns a '
              'reader that no sync topic paces, here the recorder)')
    for report in sorted(reports, key=lambda r: -r['cpu_s']):
        print(f'      {report["name"]:<28} {report["cpu_s"]:7.2f} s CPU (process)')
    return {'rtf': duration / span, 'cpu_rtf': duration / total_cpu, 'dropped': dropped}


# ---------------------------------------------------------------------------------------------
# 3. latency at real rate


class LatencyProbe(Node):
    """Receive times of wheel-speed samples and of the first output stamped with each."""

    OUTPUTS = ('tpms/warning', 'tpms/indication/stiffness', 'tpms/indication/vibration',
               'tpms/indication/wheel_radius')

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('latency_probe', **kwargs)
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from vehicle_monitor_msgs.msg import TpmsIndication, TpmsWarning, WheelSpeeds

        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.samples: dict[int, float] = {}
        self.outputs: dict[str, dict[int, float]] = {topic: {} for topic in self.OUTPUTS}
        self.create_subscription(WheelSpeeds, 'vehicle/wheel_speeds', self._on_sample, qos)
        for topic in self.OUTPUTS:
            self.create_subscription(TpmsWarning if topic == 'tpms/warning' else TpmsIndication,
                                     topic, functools.partial(self._on_output, topic), qos)

    @staticmethod
    def _stamp(msg: Any) -> int:
        return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)

    def _on_sample(self, msg: Any) -> None:
        self.samples.setdefault(self._stamp(msg), time.monotonic())

    def _on_output(self, topic: str, msg: Any) -> None:
        self.outputs[topic].setdefault(self._stamp(msg), time.monotonic())


LATENCY_LAYOUTS = {
    'composed': 'estimators composed in one process',
    'per_process': 'one process per estimator',
    'no_estimators': 'no estimators (transport floor: player process -> probe)',
}


LATENCY_WARM_UP_S = 2.0


def _real_rate_graph(domain: Domain, scenario: Scenario, work: Path,
                     replay: dict[str, Any]) -> GraphSpec:
    """The domain's graph without its recorder, the player replaying the scenario at real rate
    (with ``replay`` on top), every node with the run's own parameters (calibration files
    under ``work``, never the user's ``$ROS_HOME``), as in the main job."""
    spec = load_graph(domain.graph)
    spec = dataclasses.replace(spec, nodes=tuple(n for n in spec.nodes
                                                 if n.name != domain.recorder))
    names = {n.name for n in spec.nodes}
    parameters = {node: dict(values) for node, values in domain.run_parameters(work).items()
                  if node in names}
    parameters[domain.player] = {**parameters.get(domain.player, {}), 'bag': str(scenario.bag),
                                 'as_fast_as_possible': False, 'rate': 1.0, **replay}
    return with_parameters(spec, parameters)


def _player_apart(spec: GraphSpec, player: str) -> tuple[GraphSpec, GraphSpec]:
    """(the player alone, every other node): for a player process beside the estimators'."""
    def part(keep: Callable[[NodeSpec], bool]) -> GraphSpec:
        return dataclasses.replace(spec, nodes=tuple(n for n in spec.nodes if keep(n)))

    return part(lambda n: n.name == player), part(lambda n: n.name != player)


def latency(seconds: float, layout: str, work: Path) -> None:
    """Road graph at real rate: wheel-speed sample -> tpms/warning (and indications), p50/p99.

    The player runs in a process of its own, as the sensor drivers of a vehicle do (in the
    estimators' process its publishing thread would compete with their executor for the
    GIL), and the probe in this one, as a consumer of the warning (a dashboard, a logger)
    would. Composed: every estimator on one executor in one process (a sample's callbacks,
    and any chunk work due with it, run one after the other). Per process: each estimator in
    its own process. No estimators: the player and the probe alone, what the transport and
    the scheduling of this machine add before any estimator work. Outputs stamped within
    ``LATENCY_WARM_UP_S`` of the first sample are left out (start-up, not steady state).
    """
    road = next(d for d in domains() if d.name == 'road')
    # On the vehicle nothing publishes /clock and the nodes run on system time: so here too,
    # as in real_rate_cpu (the replay's 200 Hz /clock to every node competed with the samples
    # for the estimators' executor).
    replay: dict[str, Any] = {
        'topics': ['/vehicle/wheel_speeds', '/vehicle/imu', '/vehicle/driver_inputs'],
        'publish_clock': False}
    if layout == 'no_estimators':
        replay['wait_timeout'] = 1.0     # no estimator subscribes, no sync topic will appear
    spec = _real_rate_graph(road, road.scenarios[0], work / f'latency_{layout}', replay)
    spec = dataclasses.replace(spec, use_sim_time=False)
    context = rclpy.Context()
    rclpy.init(context=context)
    player, estimators = _player_apart(spec, road.player)
    if layout == 'per_process':
        _, processes, stop, _ = _node_processes(spec, road.player, {})
    else:
        _, processes, stop, _ = _node_processes(player, road.player, {})
    if layout == 'composed':
        processes.insert(0, multiprocessing.get_context('spawn').Process(
            target=_composed_process, args=(estimators, stop), daemon=True))
    executor: Any = EXECUTORS[spec.executor](context)
    probe = LatencyProbe(context=context)
    executor.add_node(probe)
    for process in processes:
        process.start()
    never: Future = Future()
    try:
        deadline = time.monotonic() + 60.0
        while not probe.samples and time.monotonic() < deadline:
            executor.spin_until_future_complete(never, timeout_sec=0.2)
        stop_at = time.monotonic() + seconds
        while time.monotonic() < stop_at:
            executor.spin_until_future_complete(never, timeout_sec=0.5)
    finally:
        stop.set()
        for process in processes:
            process.join(timeout=10.0)
        executor.remove_node(probe)
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
    if not probe.samples:
        print('  no wheel-speed sample reached the probe')
        return
    stamps = np.array(sorted(probe.samples), dtype=np.int64)
    received = np.array([probe.samples[s] for s in stamps])
    offset = float(np.min(received - stamps * 1e-9))  # the player's schedule: stamp -> wall
    arrival_ms = 1e3 * (received - stamps * 1e-9 - offset)
    # Steady state: the first outputs also wait for discovery between the processes.
    steady_ns = int(stamps[0]) + int(LATENCY_WARM_UP_S * 1e9)
    p50, p99 = np.percentile(arrival_ms, [50, 99])
    print(f'  road graph at real rate for {seconds:.0f} s, {LATENCY_LAYOUTS[layout]}; a '
          f'wheel-speed sample reaches the probe after p50 {p50:.2f} ms, p99 {p99:.2f} ms')
    if layout == 'no_estimators':
        return
    for topic in LatencyProbe.OUTPUTS:
        matched = [(s, t) for s, t in probe.outputs[topic].items()
                   if s in probe.samples and s >= steady_ns]
        if not matched:
            print(f'    {topic}: nothing stamped with a wheel-speed sample')
            continue
        delays_ms = np.array([1e3 * (t - (s * 1e-9 + offset)) for s, t in matched])
        p50, p99 = np.percentile(delays_ms, [50, 99])
        target = ' [p99 < 5 ms]' if topic == 'tpms/warning' else ''
        print(f'    sample -> {topic:<30} {len(matched):>5} updates: p50 {p50:7.2f} ms, '
              f'p99 {p99:7.2f} ms, max {delays_ms.max():7.2f} ms{target}')


# ---------------------------------------------------------------------------------------------
# 4. CPU of the estimators at real rate

CPU_SAMPLE_S = 0.25
CPU_WARM_UP_S = 2.0


def real_rate_cpu(domain: Domain, scenario: Scenario, work: Path) -> float | None:
    """CPU the domain's estimators need per second of data at real rate, as on the vehicle:
    every estimator node composed in one process (no recorder), the player in a process of its
    own (the sensors), every node on system time and no ``/clock``, the estimators' process
    CPU time over the replay after ``CPU_WARM_UP_S`` (start-up and first-call compilation
    left out). Includes the executor, deserialisation and middleware of that process:
    everything but player and recorder. The run's own parameters (calibration files under
    ``work``) as in the main job."""
    duration = bag_duration_s(scenario.bag)
    # No recorder: wait for the estimators' outputs (sync topics) only, not for a subscriber
    # of every recorded topic (ground truth has none then).
    # On the vehicle nothing publishes /clock and the nodes run on system time: so here too
    # (at 200 Hz /clock reaches every node of the graph, about 0.07-0.1 CPU-s per s of data on
    # this machine, which the vehicle never pays).
    spec = _real_rate_graph(domain, scenario, work / f'real_rate_{scenario.name}',
                            {'wait_for_subscribers': 0, 'publish_clock': False})
    spec = dataclasses.replace(spec, use_sim_time=False)
    player, estimators = _player_apart(spec, domain.player)
    _, processes, stop, results = _node_processes(player, domain.player, {})
    composed = multiprocessing.get_context('spawn').Process(
        target=_composed_process, args=(estimators, stop, results), daemon=True)
    composed.start()
    for process in processes:
        process.start()
    done_at: float | None = None
    cpu: list[tuple[float, float, float]] = []
    deadline = time.monotonic() + 120.0 + 3.0 * duration
    while time.monotonic() < deadline and not cpu:
        try:
            kind, payload = results.get(timeout=0.5)
        except Exception:  # queue.Empty: keep waiting
            continue
        if kind == 'player_done':
            done_at = time.monotonic()
            stop.set()
        elif kind == 'cpu':
            cpu = payload
    stop.set()
    for process in [*processes, composed]:
        process.join(timeout=10.0)
    if done_at is None or len(cpu) < 2:
        print(f'  {domain.name} graph on {scenario.name}: the replay did not finish')
        return None
    times, used, in_callbacks = (np.array(column) for column in zip(*cpu, strict=True))
    start, end = done_at - duration + CPU_WARM_UP_S, min(done_at, float(times[-1]))
    window = end - start

    def rate(series: np.ndarray) -> float:
        return float(np.interp(end, times, series) - np.interp(start, times, series)) / window

    per_s, callbacks = rate(used), rate(in_callbacks)
    print(f'  {domain.name} graph on {scenario.name} at real rate: the estimators\' process '
          f'{per_s:.3f} CPU-s per s of data over {window:.1f} s [<= 0.15]: the nodes\' '
          f'callbacks {callbacks:.3f}, executor, DDS threads and the rest {per_s - callbacks:.3f}')
    return per_s


# ---------------------------------------------------------------------------------------------
# 5. offline throughput vs the plainest implementation


OFFLINE = [
    ('stiffness observer', ['bench_stiffness_observer.py']),
    ('vibration, wheel radius, voter', ['bench_tpms_cores.py', '--seconds', '30']),
    ('lateral force observer', ['bench_lateral_force_observer.py', 'bench']),
    ('IMM suspension monitor', ['bench_suspension_imm.py', '--skip-long', '--skip-sweep']),
    ('creep EKF', ['bench_creep_ekf.py', '--repeat', '1']),
]
_RATIO_LINE = re.compile(r'(ratio|speed-?up|faster|plain|filterpy|reference|real.time|rtf|'
                         r'steps/s|us/sample|x\b)', re.IGNORECASE)


def offline() -> None:
    """Run each estimator benchmark and show its throughput and ratio lines."""
    for label, command in OFFLINE:
        started = time.monotonic()
        try:
            result = subprocess.run([sys.executable, str(ROOT / 'benchmarks' / command[0]),
                                     *command[1:]], capture_output=True, text=True,
                                    timeout=900, cwd=ROOT)
        except subprocess.TimeoutExpired:
            print(f'  {label}: {command[0]} did not finish within 900 s')
            continue
        lines = [line for line in result.stdout.splitlines() if _RATIO_LINE.search(line)]
        status = '' if result.returncode == 0 else f' (exit {result.returncode})'
        print(f'  {label} ({command[0]}, {time.monotonic() - started:.0f} s){status}:')
        for line in lines[:12]:
            print(f'      {line.strip()}')


def main() -> None:
    """Run the benchmarks and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--quick', action='store_true',
                        help='leave out the long (240 s) puncture scenario')
    parser.add_argument('--skip-ceiling', action='store_true',
                        help='leave out the no-op topology replay of section 1')
    parser.add_argument('--skip-latency', action='store_true')
    parser.add_argument('--skip-processes', action='store_true')
    parser.add_argument('--skip-real-rate-cpu', action='store_true')
    parser.add_argument('--skip-offline', action='store_true')
    parser.add_argument('--latency-seconds', type=float, default=30.0)
    args = parser.parse_args()
    # A DDS domain of our own (the child processes inherit it): another graph on this machine
    # in the default domain would hear the replay and pace it (the player waits for every
    # reliable reader's acknowledgement), and feed the recorder.
    use_private_domain()
    registered = domains()
    selected = [(d, s) for d in registered for s in d.scenarios
                if not (args.quick and bag_duration_s(s.bag) > 60.0)]
    with tempfile.TemporaryDirectory(prefix='bench_graph_') as work:
        print('1. replay as fast as possible, composed in one process (EventsExecutor)')
        for domain, scenario in selected:
            real = composed_replay(domain, scenario, Path(work))
            if not args.skip_ceiling:
                ceiling_replay(domain, scenario, Path(work), real)
    if not args.skip_processes:
        print('2. one process per node (same graph, same executor per process)')
        for domain in registered:
            short = min(domain.scenarios, key=lambda s: bag_duration_s(s.bag))
            process_per_node(domain, short)
    if not args.skip_latency:
        print('3. input-to-warning latency at real rate')
        with tempfile.TemporaryDirectory(prefix='bench_graph_') as work:
            for layout in LATENCY_LAYOUTS:
                latency(args.latency_seconds, layout, Path(work))
    if not args.skip_real_rate_cpu:
        print('4. CPU of the estimators at real rate (composed, no player or recorder)')
        with tempfile.TemporaryDirectory(prefix='bench_graph_') as work:
            for domain, scenario in selected:
                real_rate_cpu(domain, scenario, Path(work))
    if not args.skip_offline:
        print('5. offline throughput of each estimator vs its plainest implementation')
        offline()


if __name__ == '__main__':
    main()
