"""The transport adapter every estimator node is: a :class:`~rclpy.node.Node` around a processor.

A node is declared, not written: its class statement names the
:class:`~vehicle_monitor_common.processing.ProcessorSpec` its processing module declares
(``spec=<module>.SPEC``: default name, ``/diagnostics`` hardware id, parameter groups each with
the processor method its changes go to, a rule across groups, and ``make_processor(values,
fqn)``, which the offline engine runs too, so node and engine build the processor the same
way). This class declares the parameters (``TypedParameters``: one definition each), builds the
processor from their values and attaches it (:meth:`ProcessorNode.attach`): it subscribes every
input of the processor (sensor QoS, overridable; composed with other nodes, through the
process's one subscription of that input, ``shared_inputs``), hands each message over,
publishes the outputs it returns (reliable, depth 10), publishes its status on
``/diagnostics`` from a timer, forwards parameter changes, and, for a calibrating processor,
serves ``~/calibrate``, keeps the calibration in the node's own file
(``node_helpers.calibration_path``) and logs the calibration's events.

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
import time
from typing import Any, ClassVar, TypeVar

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import ClockType, JumpHandle, JumpThreshold, TimeJump
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from vehicle_monitor_common.node_helpers import (
    OUTPUT_QOS,
    Diagnostics,
    TypedParameters,
    calibration_path,
    run_node,
    sensor_subscription,
    time_msg,
)
from vehicle_monitor_common.parameters import flatten
from vehicle_monitor_common.processing import ERROR, WARN, Output, Processor, ProcessorSpec
from vehicle_monitor_common.shared_inputs import SharedInputs

P = TypeVar('P')


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
    """A node whose logic is a processor (see the module docstring).

    A subclass declares itself in its class statement (``spec=``, its processing module's
    :class:`~vehicle_monitor_common.processing.ProcessorSpec`) and is built whole by this
    constructor; one that declares nothing (a test's) calls :meth:`attach` itself.
    """

    processor: Processor
    processor_spec: ClassVar[ProcessorSpec[Any] | None] = None

    def __init_subclass__(cls, *, spec: ProcessorSpec[Any] | None = None,
                          **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if spec is not None:
            cls.processor_spec = spec

    def __init__(self, node_name: str = '', *, shared_inputs: SharedInputs | None = None,
                 **kwargs: Any) -> None:
        declared = self.processor_spec
        super().__init__(node_name or (declared.name if declared else ''), **kwargs)
        self._shared_inputs = shared_inputs
        self._jump_handles: list[JumpHandle] = []
        self.typed_parameters: list[TypedParameters[Any]] = []
        if declared is None:
            return
        values: dict[str, Any] = {}
        for group in declared.groups:
            definition = group.definition
            cls = definition if isinstance(definition, type) else definition(values)
            typed = TypedParameters(self, cls, on_change=self._forwarder(group.forward_to))
            self.typed_parameters.append(typed)
            values.update(flatten(typed.value))
        if declared.cross_check is not None:
            self.add_on_set_parameters_callback(self._check_across_groups)
        if 'calibration_file' in values:
            # Live, the calibration is kept per node and namespace (the offline engine keeps
            # a vehicle's calibration itself): the factory gets the resolved file.
            values['calibration_file'] = calibration_path(self, values['calibration_file'])
        self.attach(self.create_processor(values), declared.hardware_id.format_map(values),
                    values['diagnostics_period_s'], values['silence_timeout_s'])

    @classmethod
    def main(cls, args: list[str] | None = None) -> None:
        """Entry point of the node's executable (``ros2 run``)."""
        raise SystemExit(run_node(cls, args))

    def create_processor(self, values: Mapping[str, Any]) -> Processor:
        """The processor from the parameter values: the spec's ``make_processor``, which the
        offline engine runs too."""
        assert self.processor_spec is not None  # only a declared node builds its processor
        return self.processor_spec.make_processor(values, self.get_fully_qualified_name())

    @property
    def parameter_values(self) -> dict[str, Any]:
        """Every parameter of every group, dotted name -> current validated value."""
        return {name: value for typed in self.typed_parameters
                for name, value in flatten(typed.value).items()}

    def parameters_of(self, cls: type[P]) -> P:
        """The current validated value of the group declared from ``cls``."""
        for typed in self.typed_parameters:
            if isinstance(typed.value, cls):
                return typed.value
        raise KeyError(f'{self.get_name()} declares no {cls.__name__} group')

    def _forwarder(self, method: str) -> Callable[[Any], None] | None:
        if not method or self.processor_spec is None:
            return None
        sharing = [i for i, group in enumerate(self.processor_spec.groups)
                   if group.forward_to == method]

        def forward(_: Any) -> None:
            getattr(self.processor, method)(*(self.typed_parameters[i].value for i in sharing))

        return forward

    def _check_across_groups(self, parameters: list[Parameter]) -> SetParametersResult:
        candidate: dict[str, Any] = {}
        for typed in self.typed_parameters:
            candidate.update(typed.candidate_values(parameters))
        declared = self.processor_spec
        assert declared is not None and declared.cross_check is not None
        problem = declared.cross_check(candidate)
        return SetParametersResult(successful=not problem, reason=problem)

    def attach(self, processor: Processor, hardware_id: str, diagnostics_period_s: float,
               silence_timeout_s: float) -> None:
        """Wire the processor to the graph: inputs, outputs, diagnostics, ``~/calibrate``."""
        self.processor = processor
        self.silence_timeout_s = silence_timeout_s
        self._last_arrival_ns: dict[str, int] = {}
        self._follow_ros_time()
        self._arrivals = dict.fromkeys(processor.inputs, 0)
        self.time_jumps = 0
        self._last_time_jump_s = 0.0
        self.watch_time_jumps(silence_timeout_s, self._on_time_jump)
        self._message_classes = {topic: message_class(msgtype)
                                 for topic, msgtype in processor.outputs.items()}
        self._publishers_by_topic = {
            topic: self.create_publisher(cls, topic, OUTPUT_QOS)
            for topic, cls in self._message_classes.items()}
        for topic, spec in processor.inputs.items():
            if self._shared_inputs is None:
                sensor_subscription(self, message_class(spec.msgtype), topic,
                                    self._input_callback(topic), raw=spec.raw)
            else:
                self._shared_inputs.subscribe(self, message_class(spec.msgtype), topic,
                                              self._input_callback(topic), raw=spec.raw)
        self._calibrating = hasattr(processor, 'request_calibration')
        if self._calibrating:
            self.create_service(Trigger, '~/calibrate', self._on_calibrate)
        self._diagnostics = Diagnostics(self, hardware_id, diagnostics_period_s,
                                        update=self._update_diagnostics)
        self._update_diagnostics()
        self._log_calibration_events()

    def watch_time_jumps(self, min_forward_s: float,
                         callback: Callable[[TimeJump], None]) -> None:
        """Call ``callback`` after every jump of the node's clock backwards or more than
        ``min_forward_s`` forwards (and when ROS time is switched on or off).

        The node keeps the handle until it is destroyed: rclpy's clock holds only a borrowed
        pointer to it, so a handle dropped while registered is freed memory that the next
        jump calls into. The voter node once overwrote the attribute that held this class's
        handle with its own; the orphan was a likely cause of a crash seen in
        ``TimeSource.clock_callback`` on a ``/clock`` replay.
        """
        self._jump_handles.append(self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=Duration(seconds=min_forward_s),
                          min_backward=Duration(nanoseconds=-1)),
            post_callback=callback))

    def destroy_node(self) -> None:
        if self._shared_inputs is not None:
            self._shared_inputs.release(self)
        for handle in self._jump_handles:
            handle.unregister()
        self._jump_handles.clear()
        super().destroy_node()

    def _input_callback(self, topic: str) -> Callable[[Any], None]:
        return lambda message: self.deliver(topic, message)

    def _follow_ros_time(self) -> None:
        """Choose how arrivals are timed. Off ROS time the node's clock is the system clock,
        so ``time.time_ns`` (the CLOCK_REALTIME rcl reads) times them in 0.05 us instead of
        ``Clock.now()``'s 2.4 us, which the four road nodes paid on each 1 kHz wheel-speed
        sample; on ROS time (``/clock`` active), the node's clock. Called again at every
        switch of ROS time (the time-jump callback)."""
        clock = self.get_clock()
        self._arrival_ns: Callable[[], int] = (
            (lambda: clock.now().nanoseconds)
            if clock.clock_type != ClockType.ROS_TIME or clock.ros_time_is_active  # type: ignore[attr-defined]
            else time.time_ns)

    def deliver(self, topic: str, message: Any) -> None:
        """Hand one input message to the processor and publish what it returns."""
        self._arrivals[topic] += 1
        self._last_arrival_ns[topic] = self._arrival_ns()
        for output in self.processor.process(topic, message):
            self.publish_output(output)
        self._log_calibration_events()

    def _log_calibration_events(self) -> None:
        if not self._calibrating:
            return
        events: list[str] = self.processor.events  # type: ignore[attr-defined]
        for event in events:
            self.get_logger().info(event)
        events.clear()

    def publish_output(self, output: Output) -> None:
        """Fill the output's message and publish it, stamped with the sample it answers."""
        message = fill_message(self._message_classes[output.topic](), output.fields)
        message.header.stamp = time_msg(output.stamp_ns)
        self._publishers_by_topic[output.topic].publish(message)

    def _on_time_jump(self, jump: TimeJump) -> None:
        self._follow_ros_time()
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
