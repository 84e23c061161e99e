"""Node helpers shared by every node: typed parameters, diagnostics, input checks, main().

Parameters are declared from a frozen dataclass whose fields carry their description and range
(:func:`param`), so each node states its parameters once, ROS enforces the ranges (an
out-of-range ``-p`` or ``--params-file`` value is refused with the reason, never clamped), and
the node reads them back as one typed object.
"""

from __future__ import annotations

from collections.abc import Callable
import math
import os
import sys
from typing import Any, Generic, TypeVar

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions

from vehicle_monitor_common.parameters import (
    ConfigurationError,
    ParameterSpec,
    build,
    check_choice,
    flatten,
    parameter_specs,
)

P = TypeVar('P')

OK = DiagnosticStatus.OK
WARN = DiagnosticStatus.WARN
ERROR = DiagnosticStatus.ERROR
STALE = DiagnosticStatus.STALE

# Sensor inputs: best effort, keep last (robot_localization's split); the depth is deep enough
# for a 1 kHz stream across a scheduling hiccup. Replays that must not drop a sample override
# reliability/depth through the standard qos_overrides parameters.
SENSOR_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=1000,
    reliability=qos_profile_sensor_data.reliability,
    durability=qos_profile_sensor_data.durability)
# Outputs: reliable, depth 10.
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                        reliability=ReliabilityPolicy.RELIABLE)


def sensor_subscription(node: Node, msg_type: Any, topic: str,
                        callback: Callable[[Any], None], raw: bool = False) -> Any:
    """Subscribe a sensor input: SENSOR_QOS, overridable through the standard
    ``qos_overrides.<topic>.subscription.*`` parameters (how a replay makes inputs reliable);
    ``raw``: the callback gets the serialised bytes."""
    return node.create_subscription(
        msg_type, topic, callback, SENSOR_QOS, raw=raw,
        qos_overriding_options=QoSOverridingOptions.with_default_policies())


def _descriptor(spec: ParameterSpec) -> ParameterDescriptor:
    text = spec.description
    if spec.choices:
        text += f" (one of: {', '.join(spec.choices)})"
    descriptor = ParameterDescriptor(name=spec.name, description=text, read_only=spec.read_only)
    if spec.choices:
        descriptor.additional_constraints = f"one of: {', '.join(spec.choices)}"
    if spec.low is not None or spec.high is not None:
        if isinstance(spec.default, bool):
            raise TypeError(f'{spec.name}: a bool parameter has no range')
        if isinstance(spec.default, int):
            descriptor.integer_range = [IntegerRange(
                from_value=int(spec.low if spec.low is not None else -2**63),
                to_value=int(spec.high if spec.high is not None else 2**63 - 1), step=0)]
        else:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(spec.low if spec.low is not None else -math.inf),
                to_value=float(spec.high if spec.high is not None else math.inf), step=0.0)]
    return descriptor


def _ros_value(default: Any) -> Any:
    return list(default) if isinstance(default, tuple) else default


def _from_ros(default: Any, value: Any) -> Any:
    if isinstance(default, tuple):
        return tuple(value) if value is not None else ()
    if isinstance(default, float) and isinstance(value, int):
        return float(value)
    return value


class TypedParameters(Generic[P]):
    """Declares a node's parameters from a parameter dataclass and keeps a validated typed copy.

    The dataclass is the single definition (``parameters.param``): an estimator core's own
    parameter class, or a node's class for its node-only parameters (topics, rates, files).
    Nested groups are declared under dotted names. The dataclass's ``__post_init__`` may raise
    ``ValueError`` for cross-field rules; such a value is refused at start (ConfigurationError)
    and at runtime (the set is rejected with the reason, the previous values stay).
    Every declared name and its definition are kept in :attr:`specs` (what the parameter test
    checks the node's descriptors against).
    """

    def __init__(self, node: Node, cls: type[P], *,
                 on_change: Callable[[P], None] | None = None) -> None:
        self._node = node
        self._cls = cls
        self.specs: dict[str, ParameterSpec] = {s.name: s for s in parameter_specs(cls)}
        self._on_change = on_change
        values: dict[str, Any] = {}
        for name, spec in self.specs.items():
            # ROS cannot infer the type of an empty array: those are string arrays.
            typed_empty = isinstance(spec.default, tuple) and not spec.default
            try:
                node.declare_parameter(
                    name, Parameter.Type.STRING_ARRAY if typed_empty
                    else _ros_value(spec.default), _descriptor(spec))
            except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
                raise ConfigurationError(
                    f'parameter {name}: {str(exc).splitlines()[0]}') from None
            # An empty typed array stays unset until given: read it as empty.
            value = node.get_parameter_or(
                name, Parameter(name, value=_ros_value(spec.default))).value
            values[name] = _from_ros(spec.default, value)
            problem = check_choice(spec, values[name])
            if problem:
                raise ConfigurationError(f'parameter {problem}')
        try:
            self.value: P = build(cls, values)
        except (TypeError, ValueError) as exc:
            raise ConfigurationError(f'invalid parameters: {exc}') from None
        node.add_on_set_parameters_callback(self._validate)
        node.add_post_set_parameters_callback(self._apply)

    def candidate_values(self, parameters: list[Parameter]) -> dict[str, Any]:
        """Dotted name -> value of this group's parameters were ``parameters`` set (unchecked)."""
        values = flatten(self.value)
        values.update({p.name: _from_ros(self.specs[p.name].default, p.value)
                       for p in parameters if p.name in self.specs})
        return values

    def _candidate(self, parameters: list[Parameter]) -> P:
        return build(self._cls, self.candidate_values(parameters))  # type: ignore[no-any-return]

    def _validate(self, parameters: list[Parameter]) -> SetParametersResult:
        for p in parameters:
            spec = self.specs.get(p.name)
            if spec is not None:
                problem = check_choice(spec, p.value)
                if problem:
                    return SetParametersResult(successful=False, reason=problem)
        try:
            self._candidate(parameters)
        except (TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply(self, parameters: list[Parameter]) -> None:
        if not any(p.name in self.specs for p in parameters):
            return
        self.value = self._candidate(parameters)
        if self._on_change is not None:
            self._on_change(self.value)


class Diagnostics:
    """Publishes one DiagnosticStatus for a node on ``/diagnostics`` at a fixed period.

    The status name is the node's fully qualified name, so graphs in several namespaces stay
    apart in an aggregator. Values are replaced by each :meth:`set`; ``update``, if given, is
    called before each periodic publication to refresh them (one timer for both).
    """

    def __init__(self, node: Node, hardware_id: str, period_s: float = 1.0,
                 update: Callable[[], None] | None = None) -> None:
        self._node = node
        self._update = update
        self._publisher = node.create_publisher(DiagnosticArray, '/diagnostics', OUTPUT_QOS)
        self._status = DiagnosticStatus(
            level=STALE, name=node.get_fully_qualified_name(), hardware_id=hardware_id,
            message='starting')
        self._timer = node.create_timer(period_s, self._tick)

    def _tick(self) -> None:
        if self._update is not None:
            self._update()
        self.publish()

    def set(self, level: bytes | int, message: str, values: dict[str, Any]) -> None:
        """Replace the current status."""
        self._status.level = bytes([level]) if isinstance(level, int) else level
        self._status.message = message
        self._status.values = [KeyValue(key=str(k), value=_format(v)) for k, v in values.items()]

    def publish(self) -> None:
        """Publish the current status now."""
        array = DiagnosticArray()
        array.header.stamp = self._node.get_clock().now().to_msg()
        array.status = [self._status]
        self._publisher.publish(array)


def _format(value: Any) -> str:
    if isinstance(value, float):
        return f'{value:.6g}'
    if isinstance(value, (list, tuple, np.ndarray)):
        return '[' + ', '.join(_format(v) for v in value) + ']'
    return str(value)


NOT_PERSISTED = 'none'


def calibration_path(node: Node, configured: str) -> str:
    """Where a calibrating node keeps its calibration (one scheme for every such node).

    ``configured`` is the node's ``calibration_file`` parameter: a path (``~`` and environment
    variables expanded), ``'none'`` for not persisted (returns ``''``), or empty for the
    default: ``$ROS_HOME/vehicle_monitor/calibration/<namespace>/<node>.yaml`` (``ROS_HOME``
    defaults to ``~/.ros``, as for every ROS 2 tool), so each node of each vehicle on one
    computer has its own file and a restart finds what was learned.
    """
    if configured == NOT_PERSISTED:
        return ''
    if configured:
        return os.path.expandvars(os.path.expanduser(configured))
    ros_home = os.environ.get('ROS_HOME') or os.path.join(os.path.expanduser('~'), '.ros')
    relative = node.get_fully_qualified_name().lstrip('/')
    return os.path.join(ros_home, 'vehicle_monitor', 'calibration', relative + '.yaml')


def stamp_ns(stamp: Any) -> int:
    """builtin_interfaces/Time -> int nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def time_msg(ns: int) -> Time:
    """int nanoseconds -> builtin_interfaces/Time (negative stamps floor to the second)."""
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return Time(sec=sec, nanosec=nanosec)


def refuse_unknown_parameters(node: Node) -> None:
    """Refuse the parameters given to a node (params file, ``-p``, a graph file) that it does
    not declare: a typo or a file meant for another node would otherwise leave a default in
    force without a word. ``qos_overrides.*`` are rclpy's own, declared per subscription.

    Raises:
        ConfigurationError: naming every unknown parameter.
    """
    unknown = sorted(name for name in node._parameter_overrides  # noqa: SLF001 (no public API)
                     if name not in node._parameters  # noqa: SLF001
                     and not name.startswith('qos_overrides.'))
    if unknown:
        raise ConfigurationError(
            f'{node.get_fully_qualified_name()}: unknown parameter(s) {", ".join(unknown)} '
            '(not declared by this node: see docs/parameters.md)')


def ros_init_error(exc: Exception) -> str:
    """rcl's error on bad command-line arguments (a malformed or missing params file, a bad
    remapping) as one line, without rcl's source locations."""
    text = str(exc).replace('failed to initialize rcl: ', '')
    return text.split(', at /')[0].strip()


def run_main(body: Callable[[list[Callable[[], None]]], int],
             args: list[str] | None = None) -> int:
    """The main() skeleton every executable shares (ros2/examples): rclpy init, ``body``, and
    the teardown of what it created (``body`` appends the cleanups to the list it is given,
    run in reverse) and rclpy shutdown, whatever happened.

    Bad ROS arguments (a malformed or missing params file) and a ConfigurationError (a bad or
    unknown parameter, a missing file) print one line and exit with 2; Ctrl-C and external
    shutdown end quietly.
    """
    try:
        rclpy.init(args=args)
    except RCLError as exc:
        print(f'error: {ros_init_error(exc)}', file=sys.stderr)
        return 2
    cleanups: list[Callable[[], None]] = []
    try:
        return body(cleanups)
    except ConfigurationError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        for cleanup in reversed(cleanups):
            cleanup()
        rclpy.try_shutdown()


def run_node(factory: Callable[..., Node], args: list[str] | None = None) -> int:
    """main() of a node executable: the node, spun until Ctrl-C (see :func:`run_main`)."""

    def body(cleanups: list[Callable[[], None]]) -> int:
        node = factory()
        cleanups.append(node.destroy_node)
        refuse_unknown_parameters(node)
        rclpy.spin(node)
        return 0

    return run_main(body, args)
