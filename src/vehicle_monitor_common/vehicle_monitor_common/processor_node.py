"""The transport adapter every estimator node is: a :class:`~rclpy.node.Node` around a processor.

A node subclass declares its parameters (``TypedParameters``), builds its processor
(:mod:`vehicle_monitor_common.processing`) and calls :meth:`ProcessorNode.attach`; from then on
this class subscribes every input of the processor (sensor QoS, overridable), hands each message
over, publishes the outputs it returns (reliable, depth 10), publishes its status on
``/diagnostics`` from a timer, and serves ``~/calibrate`` when the processor can calibrate.

Input silence is watched here, once for every node: each input's message count and the age of
its last message (node clock) go on the diagnostics; an input silent for longer than
``silence_timeout_s`` after it was flowing raises the status to ERROR naming it, and the status
returns to the processor's own as soon as messages flow again. A required input never received
is a WARN ("waiting for ..."); an optional one is only listed. A jump of the node's ROS time
(``/clock`` going backwards, or stepping forward past the silence timeout: a replay restarted
or looped with ``use_sim_time``) restarts the silence watch instead of reporting every input
silent or none, and is counted and reported on the diagnostics; the estimates follow the data
stamps, which the processors check for jumps of their own.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import importlib
from typing import Any

import numpy as np
from rclpy.clock import JumpThreshold, TimeJump
from rclpy.duration import Duration
from rclpy.node import Node
from std_srvs.srv import Trigger

from vehicle_monitor_common.node_helpers import (
    OUTPUT_QOS,
    Diagnostics,
    sensor_subscription,
    time_msg,
)
from vehicle_monitor_common.processing import ERROR, WARN, Output, Processor


def message_class(msgtype: str) -> Any:
    """The rclpy message class of ``package/msg/Name``."""
    package, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


def fill_message(message: Any, fields: Mapping[str, Any]) -> Any:
    """Set a message's fields from a mapping (nested mappings for nested messages)."""
    for name, value in fields.items():
        if isinstance(value, Mapping):
            fill_message(getattr(message, name), value)
        else:
            setattr(message, name, value.tolist() if isinstance(value, np.ndarray) else value)
    return message


class ProcessorNode(Node):
    """A node whose logic is a processor (see the module docstring)."""

    processor: Processor

    def attach(self, processor: Processor, hardware_id: str, diagnostics_period_s: float,
               silence_timeout_s: float) -> None:
        """Wire the processor to the graph: inputs, outputs, diagnostics, ``~/calibrate``."""
        self.processor = processor
        self.silence_timeout_s = silence_timeout_s
        self._last_arrival_ns: dict[str, int] = {}
        self._arrivals = dict.fromkeys(processor.inputs, 0)
        self.time_jumps = 0
        self._last_time_jump_s = 0.0
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=Duration(seconds=silence_timeout_s),
                          min_backward=Duration(nanoseconds=-1)),
            post_callback=self._on_time_jump)
        self._message_classes = {topic: message_class(msgtype)
                                 for topic, msgtype in processor.outputs.items()}
        self._publishers_by_topic = {
            topic: self.create_publisher(cls, topic, OUTPUT_QOS)
            for topic, cls in self._message_classes.items()}
        for topic, spec in processor.inputs.items():
            sensor_subscription(self, message_class(spec.msgtype), topic,
                                self._input_callback(topic), raw=spec.raw)
        if hasattr(processor, 'request_calibration'):
            self.create_service(Trigger, '~/calibrate', self._on_calibrate)
        self._diagnostics = Diagnostics(self, hardware_id, diagnostics_period_s,
                                        update=self._update_diagnostics)
        self._update_diagnostics()

    def _input_callback(self, topic: str) -> Callable[[Any], None]:
        return lambda message: self.deliver(topic, message)

    def deliver(self, topic: str, message: Any) -> None:
        """Hand one input message to the processor and publish what it returns."""
        self._arrivals[topic] += 1
        self._last_arrival_ns[topic] = self.get_clock().now().nanoseconds
        for output in self.processor.process(topic, message):
            self.publish_output(output)

    def publish_output(self, output: Output) -> None:
        """Fill the output's message and publish it, stamped with the sample it answers."""
        message = fill_message(self._message_classes[output.topic](), output.fields)
        message.header.stamp = time_msg(output.stamp_ns)
        self._publishers_by_topic[output.topic].publish(message)

    def _on_time_jump(self, jump: TimeJump) -> None:
        now_ns = self.get_clock().now().nanoseconds
        if now_ns == jump.delta.nanoseconds:
            return  # the first /clock message: simulated time starts, nothing jumped
        self.time_jumps += 1
        self._last_time_jump_s = jump.delta.nanoseconds * 1e-9
        for topic in self._last_arrival_ns:
            self._last_arrival_ns[topic] = now_ns

    def _on_calibrate(self, _: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self.processor.request_calibration()  # type: ignore[attr-defined]
        return response

    def _update_diagnostics(self) -> None:
        now_ns = self.get_clock().now().nanoseconds
        status = self.processor.status(now_ns)
        level, problems = status.level, []
        values = dict(status.values)
        for topic, spec in self.processor.inputs.items():
            last = self._last_arrival_ns.get(topic)
            values[f'{topic}.received'] = self._arrivals[topic]
            if last is None:
                values[f'{topic}.age_s'] = 'never'
                if not spec.optional:
                    level = max(level, WARN)
                    problems.append(f'waiting for {topic}')
                continue
            age_s = (now_ns - last) * 1e-9
            values[f'{topic}.age_s'] = age_s
            if age_s > self.silence_timeout_s:
                level = ERROR
                problems.append(f'{topic} silent for {age_s:.1f} s')
        if self.time_jumps:
            values['ros_time_jumps'] = self.time_jumps
            values['last_ros_time_jump_s'] = self._last_time_jump_s
        message = '; '.join(problems + [status.message]) if problems else status.message
        self._diagnostics.set(level, message, values)
