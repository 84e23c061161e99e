"""The transport adapter around a processor: inputs in, outputs out, silence on /diagnostics."""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import entry_points
import inspect
import textwrap
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
import pytest
from rclpy.parameter import Parameter
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import CreepFactor

from vehicle_monitor_common import processing
from vehicle_monitor_common.node_helpers import ERROR, OK, WARN
from vehicle_monitor_common.parameters import ConfigurationError, param
from vehicle_monitor_common.processing import (
    Input,
    Output,
    ParameterGroup,
    ProcessorParams,
    ProcessorSpec,
    Status,
)
from vehicle_monitor_common.processor_node import ProcessorNode


class Echo:
    """Publishes ay of each IMU sample as a creep factor; a silent optional second input."""

    inputs = {'imu': Input('sensor_msgs/msg/Imu'),
              'extra': Input('sensor_msgs/msg/Imu', optional=True)}
    outputs = {'factor': 'vehicle_monitor_msgs/msg/CreepFactor'}

    def process(self, topic: str, message: Any) -> list[Output]:
        stamp = message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec
        return [Output('factor', stamp, {'creep_factor': message.linear_acceleration.y,
                                         'header': {'frame_id': 'track'}})]

    def status(self, now_ns: int) -> Status:
        return Status(processing.OK, 'ok', {'n': 1})


class EchoNode(ProcessorNode):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__('echo', **kwargs)
        self.attach(Echo(), 'test', diagnostics_period_s=0.05, silence_timeout_s=0.3)


def test_adapter_publishes_outputs_and_reports_silence(
        make_node: Callable[..., Any], spin_until: Callable[..., bool]) -> None:
    """An input goes through the processor to its output topic (stamp and nested fields
    filled); a required input never seen is WARN, silent after flowing ERROR naming it, and
    the status clears when it flows again."""
    node = make_node(EchoNode)
    probe = make_node('probe')
    factors: list[CreepFactor] = []
    statuses: list[Any] = []
    probe.create_subscription(CreepFactor, 'factor', factors.append, 10)
    probe.create_subscription(DiagnosticArray, '/diagnostics',
                              lambda m: statuses.extend(m.status), 10)
    imu_pub = probe.create_publisher(Imu, 'imu', 10)

    assert spin_until(lambda: any(s.level == WARN for s in statuses), 5.0)
    assert 'waiting for imu' in statuses[-1].message

    def send(ay: float) -> None:
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 12, 345
        msg.linear_acceleration.y = ay
        imu_pub.publish(msg)

    assert spin_until(lambda: (send(0.25), bool(factors))[1], 5.0)
    assert factors[0].creep_factor == 0.25 and factors[0].header.frame_id == 'track'
    assert (factors[0].header.stamp.sec, factors[0].header.stamp.nanosec) == (12, 345)
    statuses.clear()
    assert spin_until(lambda: any(s.level == ERROR for s in statuses), 5.0)
    silent = next(s for s in statuses if s.level == ERROR)
    assert 'imu silent for' in silent.message and 'extra' not in silent.message
    values = {kv.key: kv.value for kv in silent.values}
    assert values['extra.age_s'] == 'never' and float(values['imu.age_s']) > 0.3
    statuses.clear()
    assert spin_until(lambda: (send(0.5), any(s.level == OK for s in statuses))[1],
                      5.0)
    assert node.processor.status(0).values == {'n': 1}


def test_backward_ros_time_jump_restarts_the_silence_watch(
        make_node: Callable[..., Any], spin_until: Callable[..., bool],
        publish_clock: Callable[[int], None]) -> None:
    """With use_sim_time, /clock going back (a replay restarted) is counted and reported, and
    the inputs are not reported silent for it."""
    node = make_node(EchoNode, parameter_overrides=[Parameter('use_sim_time', value=True)])
    assert spin_until(lambda: (publish_clock(100), node.get_clock().now().nanoseconds
                               == 100 * 10**9)[1], 5.0)
    node.deliver('imu', _imu(0.1))
    assert spin_until(lambda: (publish_clock(40), node.time_jumps >= 1)[1], 5.0)
    node._update_diagnostics()
    status = node._diagnostics._status
    values = {kv.key: kv.value for kv in status.values}
    assert values['ros_time_jumps'] == '1' and float(values['last_ros_time_jump_s']) == -60.0
    assert status.level != ERROR and float(values['imu.age_s']) == 0.0


def test_arrivals_are_timed_on_the_node_clock_in_either_time(
        make_node: Callable[..., Any], spin_until: Callable[..., bool],
        publish_clock: Callable[[int], None]) -> None:
    """On system time an arrival is timed without a Clock.now() call (time.time_ns: the same
    clock); once use_sim_time is switched on, on /clock's time, and back again."""
    node = make_node(EchoNode)
    node.deliver('imu', _imu(0.1))
    assert abs(node._last_arrival_ns['imu'] - node.get_clock().now().nanoseconds) < 10**9
    node.set_parameters([Parameter('use_sim_time', value=True)])
    assert spin_until(lambda: (publish_clock(100), node.get_clock().now().nanoseconds
                               == 100 * 10**9)[1], 5.0)
    node.deliver('imu', _imu(0.2))
    assert node._last_arrival_ns['imu'] == 100 * 10**9
    node.set_parameters([Parameter('use_sim_time', value=False)])
    node.deliver('imu', _imu(0.3))
    assert abs(node._last_arrival_ns['imu'] - node.get_clock().now().nanoseconds) < 10**9


def _imu(ay: float) -> Any:
    msg = Imu()
    msg.linear_acceleration.y = ay
    return msg


@dataclass(frozen=True)
class GainParams:
    gain: float = param(2.0, 'output gain', low=0.0, high=10.0)

    def __post_init__(self) -> None:
        # The range is the ROS descriptor's; a value built offline is checked here, as the
        # cores check theirs.
        if not 0.0 <= self.gain <= 10.0:
            raise ValueError(f'gain must be in [0, 10], got {self.gain}')


@dataclass(frozen=True)
class ScaleNodeParams(ProcessorParams):
    limit: float = param(5.0, 'largest gain the output range allows', low=0.0, high=100.0)
    channel: str = param('a', 'channel name, in the hardware id')


class Scale(Echo):
    """Echo with parameters: a gain its changes go to, node parameters given once."""

    def __init__(self, params: GainParams, node_params: ScaleNodeParams) -> None:
        self.params, self.node_params = params, node_params

    def set_params(self, params: GainParams) -> None:
        self.params = params


def _gain_within_limit(values: Mapping[str, Any]) -> str:
    return 'gain above limit' if values['gain'] > values['limit'] else ''


SCALE = ProcessorSpec(
    'scale', 'test/scale/{channel}', make=Scale, cross_check=_gain_within_limit,
    groups=(ParameterGroup(GainParams, 'set_params'), ParameterGroup(ScaleNodeParams)))


class ScaleNode(ProcessorNode, spec=SCALE):
    """A node declared by its processing module's spec only."""


def test_spec_builds_the_processor_from_its_groups() -> None:
    """The default make_processor gives make one instance of each group built from the flat
    values (defaults for the missing ones); a refused value is a ConfigurationError naming the
    node; a hand-written factory is used as it is."""
    made = SCALE.make_processor({'gain': 4.0, 'channel': 'b'}, '/car/scale')
    assert isinstance(made, Scale)
    assert (made.params.gain, made.node_params.channel, made.node_params.limit) == (4.0, 'b', 5.0)
    with pytest.raises(ConfigurationError, match='^/car/scale: invalid parameters: .*gain'):
        SCALE.make_processor({'gain': -1.0}, '/car/scale')

    def factory(values: Mapping[str, Any], fqn: str) -> Scale:
        return Scale(GainParams(gain=float(len(fqn))), ScaleNodeParams())

    spec = ProcessorSpec('scale', 'test', groups=SCALE.groups, factory=factory)
    assert spec.make_processor is factory


def test_spec_without_factory_needs_dataclass_groups() -> None:
    """A group defined by a function of other values cannot be built without the values
    declared before it: such a spec must bring its own factory."""
    with pytest.raises(TypeError, match='factory='):
        ProcessorSpec('votes', 'test', make=Scale,
                      groups=(ParameterGroup(lambda values: GainParams),))
    with pytest.raises(TypeError, match='make='):
        ProcessorSpec('scale', 'test', groups=SCALE.groups)


def test_node_declared_by_spec(make_node: Callable[..., Any]) -> None:
    """A node declared ``spec=`` takes its default name and hardware id from the spec,
    declares each group's parameters, forwards a change to the group's method and refuses a
    combination the cross-group rule refuses (the processor keeps the value in force)."""
    node = make_node(ScaleNode, parameter_overrides=[Parameter('channel', value='rear')])
    assert node.get_name() == 'scale'
    assert node._diagnostics._status.hardware_id == 'test/scale/rear'
    assert node.processor.params == GainParams() and node.processor.node_params.channel == 'rear'
    assert node.parameter_values['limit'] == 5.0
    assert node.set_parameters([Parameter('gain', value=3.0)])[0].successful
    assert node.processor.params.gain == 3.0
    refused = node.set_parameters([Parameter('gain', value=7.0)])[0]
    assert not refused.successful and refused.reason == 'gain above limit'
    assert node.processor.params.gain == 3.0


def _assigned_attributes(cls: type) -> set[str]:
    """The ``self.<name>`` a class's own methods assign."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
    targets = [t for node in ast.walk(tree) for t in (
        node.targets if isinstance(node, ast.Assign)
        else [node.target] if isinstance(node, (ast.AnnAssign, ast.AugAssign)) else [])]
    return {target.attr for assigned in targets for target in ast.walk(assigned)
            if isinstance(target, ast.Attribute) and isinstance(target.value, ast.Name)
            and target.value.id == 'self'}


def test_no_node_overwrites_what_the_adapter_holds() -> None:
    """No installed node class assigns an attribute that ProcessorNode (or a base between)
    assigns: the voter once replaced the adapter's clock jump handle, which rclpy's clock
    still pointed to, with its own (a use-after-free at the next /clock jump)."""
    checked = []
    for entry in entry_points(group='vehicle_monitor.nodes'):
        cls = entry.load()
        if not (isinstance(cls, type) and issubclass(cls, ProcessorNode)):
            continue
        chain = cls.__mro__[:cls.__mro__.index(ProcessorNode) + 1]   # the node .. the adapter
        assigned = [_assigned_attributes(klass) for klass in chain]
        for i, klass in enumerate(chain[:-1]):
            clash = assigned[i] & set().union(*assigned[i + 1:])
            assert not clash, (klass.__name__, clash)
        checked.append(entry.name)
    assert 'tpms_voter' in checked and len(checked) >= 6
