"""Composed runner: a set of nodes in one process on one executor, from a small YAML file.

The manual-composition counterpart of ``ros2 launch`` (not available from PyPI): the demo, the
benchmarks and the integration tests bring graphs up with it. Nodes are named by plugin,
``<package>/<node>`` as registered under the ``vehicle_monitor.nodes`` entry-point group of the
packages' setup.cfg (like rclcpp_components), or ``module:Class``. A graph file::

    executor: events            # events (rclpy's EventsExecutor, default: ~5x less overhead
                                # per callback), single, or multi (one thread per core)
    use_sim_time: true          # applied to every node but the players, which publish /clock
    share_inputs: true          # default: the estimators take each input topic through one
                                # subscription (vehicle_monitor_common.shared_inputs); not
                                # with the multi executor
    nodes:
      - plugin: tpms_ros/vehicle_simulator
        name: vehicle_simulator
        parameters: {bag: bags/road_nominal, as_fast_as_possible: true}
      - plugin: vehicle_monitor_common/graph_recorder
        namespace: /car1
        remappings: {/tpms/warning: /car1/tpms/warning}

A ROS 2 YAML launch file (``launch:`` with ``arg`` and ``node`` actions, see
:mod:`vehicle_monitor_common.launch_yaml`) is read the same way, so one file serves
``ros2 launch`` on a real install and this runner here.

``run_graph FILE [NAME:=VALUE ...] [-p NODE.PARAM:=VALUE ...] [--timeout S]`` runs it (launch
arguments as ``NAME:=VALUE``) until every player has finished (or Ctrl-C / the timeout; a graph
without players runs until then) and prints what the recorders received.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from dataclasses import replace
import importlib
from importlib.metadata import entry_points
import os
import sys
import time
from typing import Any

from rclpy.context import Context
from rclpy.executors import (
    Executor,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
)
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
import yaml

from vehicle_monitor_common.graph_spec import GraphSpec, NodeSpec, load_graph
from vehicle_monitor_common.node_helpers import refuse_unknown_parameters, run_main
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.player import ScenarioPlayer
from vehicle_monitor_common.processor_node import ProcessorNode
from vehicle_monitor_common.recorder import GraphRecorder
from vehicle_monitor_common.shared_inputs import SharedInputs

NODE_GROUP = 'vehicle_monitor.nodes'
# The EventsExecutor (experimental in Jazzy) costs about a fifth of the SingleThreadedExecutor
# per callback (benchmarks/bench_replay.py): the difference between a 2x and a 12x real-time
# replay of a 1 kHz graph. Tests use the SingleThreadedExecutor, which re-raises callback errors.
EXECUTORS: dict[str, Callable[[Context | None], Executor]] = {
    'events': lambda context: EventsExecutor(context=context),
    'single': lambda context: SingleThreadedExecutor(context=context),
    'multi': lambda context: MultiThreadedExecutor(num_threads=os.cpu_count() or 2,
                                                   context=context),
}


def node_class(plugin: str) -> Callable[..., Node]:
    """The Node subclass a plugin name refers to."""
    if ':' in plugin:
        module, _, attribute = plugin.partition(':')
        try:
            return getattr(importlib.import_module(module), attribute)
        except (ImportError, AttributeError) as exc:
            raise ConfigurationError(f'cannot load node {plugin}: {exc}') from None
    registered = {f'{ep.dist.name if ep.dist else ""}/{ep.name}': ep
                  for ep in entry_points(group=NODE_GROUP)}
    if plugin not in registered:
        raise ConfigurationError(
            f'unknown node plugin {plugin!r} (registered: {", ".join(sorted(registered))})')
    return registered[plugin].load()


class Graph:
    """Nodes of a GraphSpec on one executor; destroy() tears them down in reverse order."""

    def __init__(self, spec: GraphSpec, context: Context | None = None) -> None:
        self.spec = spec
        self.context = context
        self.executor: Executor = EXECUTORS[spec.executor](context)
        # One subscription per input for the estimators, where one callback runs at a time.
        self.shared_inputs = (SharedInputs() if spec.share_inputs and spec.executor != 'multi'
                              else None)
        self.nodes: list[Node] = []
        try:
            for node_spec in spec.nodes:
                self.nodes.append(self._create(node_spec))
                self.executor.add_node(self.nodes[-1])
        except Exception:
            self.destroy()
            raise

    def _create(self, node_spec: NodeSpec) -> Node:
        cls = node_class(node_spec.plugin)
        parameters = dict(node_spec.parameters)
        if self.spec.use_sim_time and not issubclass(cls, ScenarioPlayer):  # type: ignore[arg-type]
            parameters.setdefault('use_sim_time', True)
        cli_args = ['--ros-args']
        for params_file in node_spec.param_files:
            cli_args += ['--params-file', params_file]
        for source, target in node_spec.remappings.items():
            cli_args += ['-r', f'{source}:={target}']
        kwargs: dict[str, Any] = {
            'context': self.context, 'namespace': node_spec.namespace or None,
            'parameter_overrides': [Parameter(k, value=_ros_value(v))
                                    for k, v in parameters.items()],
            'cli_args': cli_args if len(cli_args) > 1 else None,
        }
        if node_spec.name:
            kwargs['node_name'] = node_spec.name
        if issubclass(cls, ProcessorNode):  # type: ignore[arg-type]
            kwargs['shared_inputs'] = self.shared_inputs
        node = cls(**{k: v for k, v in kwargs.items() if v is not None})
        try:
            refuse_unknown_parameters(node)
        except ConfigurationError:
            node.destroy_node()
            raise
        return node

    def of_type(self, cls: type[Any]) -> list[Any]:
        """The graph's nodes that are instances of ``cls``."""
        return [n for n in self.nodes if isinstance(n, cls)]

    def spin_until(self, predicate: Callable[[], bool], timeout_s: float | None = None,
                   ) -> bool:
        """Spin until ``predicate()`` holds (True) or the timeout passes (False)."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while self.context is None or self.context.ok():
            if predicate():
                return True
            if deadline is not None and time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return predicate()

    def players_done(self) -> bool:
        """Every player of the graph has finished its replay."""
        return all(p.done.is_set() for p in self.of_type(ScenarioPlayer))

    def drain(self, quiet_s: float = 0.3, timeout_s: float = 5.0,
              expected: Mapping[str, int] | None = None) -> None:
        """Spin until the recorders hold the ``expected`` count of each topic (what the player
        published) and have received nothing new for ``quiet_s``, or ``timeout_s`` passed.

        Quiet alone is not enough: one long callback (a suspension monitor rebuilding its
        bank) can keep the recorder's queue waiting for longer than ``quiet_s``, and the
        messages behind it would be counted as dropped."""
        recorders = self.of_type(GraphRecorder)
        deadline = time.monotonic() + timeout_s
        last_total, last_change = -1, time.monotonic()
        while time.monotonic() < deadline:
            total = sum(s.count for r in recorders for s in r.stats.values())
            if total != last_total:
                last_total, last_change = total, time.monotonic()
            elif (time.monotonic() - last_change > quiet_s
                  and all(sum(r.stats[topic].count for r in recorders if topic in r.stats)
                          >= count for topic, count in (expected or {}).items())):
                return
            self.executor.spin_once(timeout_sec=0.02)

    def destroy(self) -> None:
        """Remove and destroy the nodes, last created first."""
        for node in reversed(self.nodes):
            self.executor.remove_node(node)
            node.destroy_node()
        self.nodes.clear()
        self.executor.shutdown()


def _ros_value(value: Any) -> Any:
    """YAML value -> a value rclpy can type (lists of ints mixed with floats become floats)."""
    if isinstance(value, list) and any(isinstance(v, float) for v in value):
        return [float(v) for v in value]
    return value


def _apply_overrides(spec: GraphSpec, overrides: list[str]) -> GraphSpec:
    by_name = {(n.name or n.plugin.split('/')[-1].split(':')[-1]): n for n in spec.nodes}
    nodes = list(spec.nodes)
    for text in overrides:
        key, sep, raw = text.partition(':=')
        node_name, dot, param_name = key.partition('.')
        if not sep or not dot or node_name not in by_name:
            raise ConfigurationError(
                f'bad override {text!r}: expected NODE.PARAM:=VALUE with NODE one of '
                f'{", ".join(sorted(by_name))}')
        original = by_name[node_name]
        updated = replace(original, parameters={**original.parameters,
                                                param_name: yaml.safe_load(raw)})
        nodes[nodes.index(original)] = updated
        by_name[node_name] = updated
    return replace(spec, nodes=tuple(nodes))


def main(argv: list[str] | None = None) -> int:
    """``run_graph``: run a graph file until its players finish; print what was recorded."""
    parser = argparse.ArgumentParser(prog='run_graph', description=__doc__.split('\n')[0])
    parser.add_argument('graph', help='graph YAML file or YAML launch file')
    parser.add_argument('launch_args', nargs='*', metavar='NAME:=VALUE',
                        help='launch arguments (launch files)')
    parser.add_argument('-p', '--param', action='append', default=[],
                        metavar='NODE.PARAM:=VALUE', help='override a node parameter')
    parser.add_argument('--timeout', type=float, default=None,
                        help='stop after this many seconds (default: when the players finish)')
    args = parser.parse_args(argv)

    def body(cleanups: list[Callable[[], None]]) -> int:
        launch_args = {}
        for text in args.launch_args:
            name, sep, value = text.partition(':=')
            if not sep or not name:
                raise ConfigurationError(f'launch argument {text!r}: expected NAME:=VALUE')
            launch_args[name] = value
        graph = Graph(_apply_overrides(load_graph(args.graph, launch_args), args.param))
        cleanups.append(graph.destroy)
        started = time.monotonic()
        has_players = bool(graph.of_type(ScenarioPlayer))
        graph.spin_until(graph.players_done if has_players else (lambda: False), args.timeout)
        graph.drain()
        code = 0
        for player in graph.of_type(ScenarioPlayer):
            if player.error:
                print(f'error: {player.get_name()}: {player.error}', file=sys.stderr)
                code = 1
        print(f'graph ran {time.monotonic() - started:.2f} s (wall)')
        for recorder in graph.of_type(GraphRecorder):
            print(recorder.summary())
        return code

    return run_main(body)
