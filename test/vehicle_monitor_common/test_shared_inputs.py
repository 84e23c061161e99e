"""One subscription per input topic for the estimator nodes of one process (shared_inputs)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import CreepFactor

from vehicle_monitor_common import processing
from vehicle_monitor_common.graph_spec import GraphSpec, NodeSpec, parse_graph
from vehicle_monitor_common.processing import Input, Output, Status
from vehicle_monitor_common.processor_node import ProcessorNode
from vehicle_monitor_common.runner import Graph
from vehicle_monitor_common.shared_inputs import SharedInputs


class Echo:
    """Publishes ay of each IMU sample on ``factor``."""

    inputs = {'imu': Input('sensor_msgs/msg/Imu')}
    outputs = {'factor': 'vehicle_monitor_msgs/msg/CreepFactor'}

    def process(self, topic: str, message: Any) -> list[Output]:
        return [Output('factor', 0, {'creep_factor': message.linear_acceleration.y})]

    def status(self, now_ns: int) -> Status:
        return Status(processing.OK, 'ok', {})


class EchoNode(ProcessorNode):
    def __init__(self, node_name: str = 'echo', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self.attach(Echo(), 'test', diagnostics_period_s=1.0, silence_timeout_s=5.0)


def _subscriptions(node: Node, topic: str) -> int:
    return sum(1 for s in node.subscriptions if s.topic_name == topic)


def _send(publisher: Any, ay: float) -> None:
    message = Imu()
    message.linear_acceleration.y = ay
    publisher.publish(message)


def test_nodes_of_a_process_share_one_subscription_and_each_gets_every_message(
        ros_context: Any, executor: Any, make_node: Callable[..., Any],
        spin_until: Callable[..., bool]) -> None:
    """Three nodes on /imu: one subscription in all, every node processes every message (its
    own arrival count and output); a node in another namespace keeps its own; destroying the
    owner moves the subscription to a node that shares it, and the input keeps flowing."""
    hub = SharedInputs()
    first = EchoNode('echo0', context=ros_context, shared_inputs=hub)   # destroyed below
    executor.add_node(first)
    nodes = [first] + [make_node(EchoNode, node_name=f'echo{i}', shared_inputs=hub)
                       for i in (1, 2)]
    apart = make_node(EchoNode, node_name='echo_apart', namespace='/car2', shared_inputs=hub)
    probe = make_node('probe')
    publisher = probe.create_publisher(Imu, '/imu', 10)
    received: list[float] = []
    probe.create_subscription(CreepFactor, '/factor', lambda m: received.append(m.creep_factor),
                              100)

    assert [_subscriptions(n, '/imu') for n in nodes] == [1, 0, 0]
    assert _subscriptions(apart, '/car2/imu') == 1
    assert spin_until(lambda: (_send(publisher, 0.5), all(n._arrivals['imu'] for n in nodes))[1],
                      5.0)
    assert len({n._arrivals['imu'] for n in nodes}) == 1      # the same messages, each node
    assert apart._arrivals['imu'] == 0

    executor.remove_node(first)
    first.destroy_node()
    assert [_subscriptions(n, '/imu') for n in nodes[1:]] == [1, 0]
    before = {n: n._arrivals['imu'] for n in nodes[1:]}
    assert spin_until(lambda: (_send(publisher, 1.0),
                               all(n._arrivals['imu'] > b for n, b in before.items()))[1], 5.0)
    assert spin_until(lambda: 1.0 in received, 5.0)     # and the outputs are published


def test_runner_shares_on_single_callback_executors_only(ros_context: Any) -> None:
    """The composed runner shares inputs by default, not with the multi-threaded executor
    (where a node's callback group keeps its callbacks apart) or when the graph says no."""
    nodes = tuple(NodeSpec(plugin=f'{__name__}:EchoNode', name=f'echo{i}') for i in range(2))

    def counts(spec: GraphSpec) -> list[int]:
        graph = Graph(spec, ros_context)
        try:
            return [_subscriptions(n, '/imu') for n in graph.nodes]
        finally:
            graph.destroy()

    assert counts(GraphSpec(nodes)) == [1, 0]
    assert counts(GraphSpec(nodes, executor='multi')) == [1, 1]
    assert counts(GraphSpec(nodes, share_inputs=False)) == [1, 1]
    graph = parse_graph({'share_inputs': False,
                         'nodes': [{'plugin': f'{__name__}:EchoNode', 'name': 'echo0'}]})
    assert not graph.share_inputs
