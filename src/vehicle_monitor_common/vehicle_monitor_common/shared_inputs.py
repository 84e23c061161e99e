"""One subscription per input topic for the estimator nodes composed in one process.

Four road nodes read the 1 kHz ``vehicle/wheel_speeds``; composed in one process, each of their
subscriptions costs the process a DDS delivery and an executor event per message, although the
four deliveries carry the same bytes. rclpy has no intra-process transport (rclcpp's composition
shares one delivery among the nodes of a container; rclpy does not), so the composed runner
does it here: the first node to subscribe a topic keeps its subscription, and a later node
whose subscription is the same (resolved topic name, so namespaces and remappings are kept
apart; message type; raw or decoded; the QoS after that node's ``qos_overrides`` parameters)
is handed the same messages by that one subscription instead of its own. Each node keeps
everything else: its name, parameters (the QoS override parameters too), publishers, services,
diagnostics and arrival counts. Measured on this machine (four nodes, 1 kHz, EventsExecutor):
0.085-0.112 CPU-s per s of data with four subscriptions, 0.050-0.086 with one shared.

Sharing changes what ``ros2 node info`` shows: only the first node lists the subscription. The
receivers of one message run one after the other inside its callback, in the order the nodes
subscribed, so it is only for executors that run one callback at a time (the runner's
``events`` and ``single``; never ``multi``, where a node's own callback group would no longer
keep its callbacks apart). A node that is destroyed leaves the others their input: its
receivers are removed, and a subscription it owned moves to the next node that shares it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from rclpy.node import Node

from vehicle_monitor_common.node_helpers import sensor_subscription


@dataclass(eq=False)
class _Receiver:
    node: Node
    callback: Callable[[Any], None]


@dataclass(eq=False)
class _Shared:
    """One subscription (its first receiver's node owns it) and the nodes it delivers to."""

    subscription: Any = None
    receivers: list[_Receiver] = field(default_factory=list)

    def __call__(self, message: Any) -> None:
        for receiver in self.receivers:
            receiver.callback(message)


class SharedInputs:
    """The input subscriptions of one process's nodes, one per distinct subscription."""

    def __init__(self) -> None:
        self._shared: list[_Shared] = []

    def subscribe(self, node: Node, msg_type: Any, topic: str,
                  callback: Callable[[Any], None], raw: bool = False) -> None:
        """Subscribe ``node`` to a sensor input (as :func:`sensor_subscription` does), through
        an equal subscription of another node when there is one."""
        shared = _Shared()
        subscription = sensor_subscription(node, msg_type, topic, shared, raw=raw)
        for existing in self._shared:
            kept = existing.subscription
            if (kept.topic_name == subscription.topic_name and kept.msg_type is msg_type
                    and kept.raw == raw and kept.qos_profile == subscription.qos_profile):
                # The node's own subscription declared its QoS override parameters; its
                # deliveries are the existing one's.
                node.destroy_subscription(subscription)
                existing.receivers.append(_Receiver(node, callback))
                return
        shared.subscription = subscription
        shared.receivers.append(_Receiver(node, callback))
        self._shared.append(shared)

    def release(self, node: Node) -> None:
        """Before ``node`` is destroyed: drop its receivers; move what it owned to the next
        node that shares it."""
        for shared in list(self._shared):
            owned = shared.receivers[0].node is node
            shared.receivers = [r for r in shared.receivers if r.node is not node]
            if not owned:
                continue
            old = shared.subscription
            topic = old.topic_name     # read from the handle: not after it is destroyed
            node.destroy_subscription(old)
            if not shared.receivers:
                self._shared.remove(shared)
                continue
            # The QoS as resolved when it was created: the override parameters are declared
            # on every sharing node already.
            shared.subscription = shared.receivers[0].node.create_subscription(
                old.msg_type, topic, shared, old.qos_profile, raw=old.raw)
