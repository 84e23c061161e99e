"""What the calibrating TPMS nodes (vibration, wheel radius) do the same way, written once.

Both are transport adapters (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`)
around a processor (:class:`tpms_ros.processing.calibrating_tpms.CalibratingTpmsProcessor`),
which holds the logic and is run by the offline engine too. Here: the method's parameters
declared from the core's ``*Params`` dataclass beside the node's own ``*NodeParams`` (one
definition each, ``TypedParameters``), the calibration file (``node_helpers.calibration_path``:
empty = per node and namespace under ``$ROS_HOME``, ``none`` = not persisted), parameter changes
forwarded to the processor, and the processor's calibration events logged.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Generic, Protocol, TypeVar

from vehicle_monitor_common.node_helpers import TypedParameters, calibration_path
from vehicle_monitor_common.processing import Processor
from vehicle_monitor_common.processor_node import ProcessorNode


class _NodeParams(Protocol):
    @property
    def calibration_file(self) -> str: ...

    @property
    def diagnostics_period_s(self) -> float: ...

    @property
    def silence_timeout_s(self) -> float: ...


class _Processor(Processor, Protocol):
    core: Any
    events: list[str]

    @property
    def calibration(self) -> Any: ...

    def set_params(self, params: Any) -> None: ...

    def set_node_params(self, node_params: Any) -> None: ...


C = TypeVar('C')                          # the core's parameter dataclass
N = TypeVar('N', bound=_NodeParams)       # the node's own parameter dataclass
P = TypeVar('P', bound=_Processor)        # the processor


class CalibratingTpmsNode(ProcessorNode, Generic[C, N, P]):
    """Base of a calibrating TPMS node (see the module docstring).

    Args:
        node_name: ROS node name.
        hardware_id: the /diagnostics hardware id.
        core_params: the core's parameter dataclass (its fields are ROS parameters).
        node_params: the node-only parameter dataclass.
        make_processor: builds the processor from (core parameters, node parameters,
            resolved calibration file).
    """

    processor: P

    def __init__(self, node_name: str, hardware_id: str, core_params: type[C],
                 node_params: type[N], make_processor: Callable[[C, N, str], P],
                 **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._core_params = TypedParameters(self, core_params,
                                            on_change=self._on_core_change)
        self._typed = TypedParameters(self, node_params, on_change=self._on_change)
        n = self._typed.value
        processor = make_processor(self._core_params.value, n,
                                   calibration_path(self, n.calibration_file))
        self.attach(processor, hardware_id, n.diagnostics_period_s, n.silence_timeout_s)
        self._log_events()

    @property
    def parameters(self) -> N:
        """The current, validated node-only parameters."""
        return self._typed.value

    @property
    def core_parameters(self) -> C:
        """The current, validated parameters of the method."""
        return self._core_params.value

    @property
    def analyzer(self) -> Any:
        """The core estimator (read access for tests and tools)."""
        return self.processor.core

    @property
    def calibration_state(self) -> str:
        """uncalibrated, loaded, calibrating, calibrated, failed or file_corrupt."""
        return str(self.processor.calibration.state)

    def _on_core_change(self, core: C) -> None:
        self.processor.set_params(core)

    def _on_change(self, p: N) -> None:
        self.processor.set_node_params(p)

    def deliver(self, topic: str, message: Any) -> None:
        """Hand one message over, then log what the calibration did."""
        super().deliver(topic, message)
        if self.processor.events:
            self._log_events()

    def _log_events(self) -> None:
        for event in self.processor.events:
            self.get_logger().info(event)
        self.processor.events.clear()
