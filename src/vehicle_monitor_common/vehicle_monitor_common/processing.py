"""Node logic as ROS-free processors, shared by the live node and the offline engine.

A processor is what a node does with its inputs, without the transport: it is given each input
message (decoded, or as the serialised bytes for a raw input) in arrival order and returns the
messages to publish, each as an :class:`Output` (topic, stamp, fields); it reports its health as
a :class:`Status`. All of a node's logic lives there: time checks, buffering and chunking,
calibration, gating, output timing in data time.

Each processing module declares its node once, in a :class:`ProcessorSpec` (``SPEC``): the
node's default name, its ``/diagnostics`` hardware id, its parameter groups (each with the
processor method its changes go to) and how the processor is built from their values
(``SPEC.make_processor``, the module's ``make_processor`` entry point). Then

* the **node** (``processor_node.ProcessorNode``, declared ``spec=<module>.SPEC``) is a
  transport adapter: it declares the parameters, builds the processor with ``make_processor``,
  subscribes the processor's inputs, hands each message over, fills and publishes the outputs,
  publishes the status on ``/diagnostics`` from its timer, and serves ``~/calibrate``;
* the **offline engine** (``offline_engine``) reads a recording, hands every message to the
  processors of a graph in recorded order (outputs that other processors subscribe go to them
  at once), and writes or summarises what they publish: the same outputs as the live graph,
  with no DDS in between.

Input messages are objects with the contract's attribute names (``msg.header.stamp.sec``,
``msg.linear_acceleration.y``): rclpy's messages in the node, rosbags' in the engine; a
processor reads attributes only, so both work.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar, cast

from vehicle_monitor_common.parameters import ConfigurationError, build, param

OK, WARN, ERROR = 0, 1, 2
T = TypeVar('T')


@dataclass(frozen=True)
class ProcessorParams:
    """The node-only parameters every processor has, defined once: each node's ``*NodeParams``
    inherits them (and may give a default of its own where its inputs' rates ask for it)."""

    diagnostics_period_s: float = param(1.0, 'period of /diagnostics, s', low=0.01, high=60.0,
                                        read_only=True)
    silence_timeout_s: float = param(1.0, 'an input silent this long after it flowed is an '
                                     'error on /diagnostics, s', low=0.01, high=3600.0,
                                     read_only=True)
    jump_horizon_s: float = param(10.0, 'an input stamp this far ahead of the last one (or any '
                                  'behind it) is a time jump once confirmed by the following '
                                  'samples (filters restart, calibration kept), else dropped as '
                                  'a corrupt stamp, s', low=0.01, high=1e6, read_only=True)


def header_stamp_ns(message: Any) -> int:
    """``header.stamp`` of an input message (rclpy's or rosbags') in ns."""
    stamp = message.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def build_processor(fqn: str, make: Callable[..., T], values: Mapping[str, Any],
                    *parameter_classes: type[Any]) -> T:
    """``make(*instances)`` with each parameter class built from a node's flat parameter
    values (the definitions the node declares): the body of every ``make_processor``.

    Raises:
        ConfigurationError: naming the node, for a value its definition refuses.
    """
    try:
        return make(*(build(cls, values) for cls in parameter_classes))
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f'{fqn}: invalid parameters: {exc}') from None


@dataclass(frozen=True)
class Input:
    """One input of a processor: its message type, whether it wants the serialised bytes (a
    dense stream whose decoding costs more than its processing) or the decoded message, and
    whether the method works without it (``optional``: its absence is no fault)."""

    msgtype: str
    raw: bool = False
    optional: bool = False


@dataclass
class Output:
    """One message to publish.

    Attributes:
        topic: relative topic name, as the node publishes it (``tpms/tire_stiffness``).
        stamp_ns: ``header.stamp`` of the message: the input sample it answers.
        fields: the message's other fields by name (nested messages as nested mappings;
            arrays as sequences or numpy arrays).
    """

    topic: str
    stamp_ns: int
    fields: dict[str, Any]


@dataclass
class Status:
    """A processor's health for ``/diagnostics``: level (OK, WARN, ERROR), one-line message,
    and key-values."""

    level: int = OK
    message: str = 'starting'
    values: dict[str, Any] = field(default_factory=dict)


class Processor(Protocol):
    """What a node does with its inputs (see the module docstring)."""

    @property
    def inputs(self) -> Mapping[str, Input]:
        """Relative topic -> how it arrives."""

    @property
    def outputs(self) -> Mapping[str, str]:
        """Relative topic -> message type published there."""

    def process(self, topic: str, message: Any) -> list[Output]:
        """Take one input message (bytes for a raw input); the outputs it makes due."""

    def status(self, now_ns: int) -> Status:
        """Health now (``now_ns`` on the node's clock; for rates and silence)."""


class CalibratingProcessor(Processor, Protocol):
    """A processor whose method learns a calibration (the TPMS methods).

    The node serves ``request_calibration`` as ``~/calibrate``, persists the state through
    ``calibration_store`` and logs ``events``; the offline engine carries a vehicle's state from
    one recording to the next in time order, as it would live on the car.
    """

    events: list[str]
    """What the calibration did since the node last looked (loaded, started, done, failed):
    lines for the node's log, which it clears once logged."""

    def request_calibration(self) -> tuple[bool, str]:
        """Start learning over the next calibration window of data; (accepted, message)."""

    def calibration_state(self) -> dict[str, Any] | None:
        """The calibration in force as plain data (None: uncalibrated)."""

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Put a stored calibration in force; ValueError when it does not fit this vehicle."""


P = TypeVar('P', bound=Processor)
ProcessorFactory = Callable[[Mapping[str, Any], str], P]
"""``make_processor(values, fqn)``: a processor from a node's flat parameter values (dotted
names) and the node's fully qualified name (for its messages)."""

CrossCheck = Callable[[Mapping[str, Any]], str]
"""Why a combination of parameter values across groups is refused ('' when it is not)."""


@dataclass(frozen=True)
class ParameterGroup:
    """One parameter dataclass a node declares, and where its changes go.

    Attributes:
        definition: the dataclass; or, for a group whose fields depend on a parameter declared
            before it (the voter's per-method votes), a function of the values declared so far
            that returns it.
        forward_to: the processor method a change of the group is handed to, called with the
            current value of every group forwarded to that method, in declaration order (the
            observer's vehicle and tuning groups go to one ``set_model(vehicle, tuning)``);
            empty: changes are not forwarded.
    """

    definition: type[Any] | Callable[[Mapping[str, Any]], type[Any]]
    forward_to: str = ''


@dataclass(frozen=True)
class ProcessorSpec(Generic[P]):
    """A node, declared once, by its processing module (``SPEC``): what the live node
    (``ProcessorNode``, ``spec=``) and the offline engine (``make_processor``) build it from.

    Attributes:
        name: the node's default name.
        hardware_id: the ``/diagnostics`` hardware id, formatted with the parameter values
            (``rail/creep/{bogie}``).
        groups: the parameter groups, in declaration order.
        make: the processor class (or any callable) given one instance of each group's
            dataclass, in declaration order; unused when ``factory`` is given.
        factory: a hand-written ``make_processor(values, fqn)``, for a processor that is more
            than its parameters (a calibration file to resolve, groups defined by a function).
        cross_check: why a combination of values across the groups is refused ('' when it is
            not), run on every candidate set at runtime (each group checks its own fields).
        make_processor: ``factory``, or by default ``make`` given each group's dataclass built
            from the values (:func:`build_processor`: a refused value is a ConfigurationError
            naming the node). The module's ``make_processor`` entry point
            (``vehicle_monitor.processors``) is this.
    """

    name: str
    hardware_id: str
    groups: tuple[ParameterGroup, ...]
    make: Callable[..., P] | None = None
    factory: ProcessorFactory[P] | None = None
    cross_check: CrossCheck | None = None
    make_processor: ProcessorFactory[P] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        made = self.factory or self._built_from_groups()
        object.__setattr__(self, 'make_processor', made)

    def _built_from_groups(self) -> ProcessorFactory[P]:
        make = self.make
        classes = [group.definition for group in self.groups]
        if make is None or not all(isinstance(cls, type) for cls in classes):
            raise TypeError(f'{self.name}: without factory=, a spec needs make= and groups '
                            'defined by dataclasses (not by a function of other values)')
        parameter_classes = cast(list[type[Any]], classes)

        def make_processor(values: Mapping[str, Any], fqn: str) -> P:
            return build_processor(fqn, make, values, *parameter_classes)

        make_processor.__doc__ = (
            f'The {getattr(make, "__name__", "processor")} from a node\'s parameter values '
            f'(dotted names): {", ".join(cls.__name__ for cls in parameter_classes)}. Raises '
            'ConfigurationError naming the node for a value its definition refuses.')
        return make_processor
