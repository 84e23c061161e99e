"""``tire_stiffness_observer``: TPMS by tire stiffness (Umeno 1997) on the ROS graph.

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.tire_stiffness_observer.TireStiffnessObserverProcessor`, which holds
the node's logic (stamp checks and time jumps, chunking, output timing in data time,
calibration, gating, status) and is run by the offline engine too. Here: the parameters
(:class:`StiffnessObserverParams`, the core's, and :class:`TireStiffnessObserverNodeParams`),
the calibration file (``node_helpers.calibration_path``: empty = per node and namespace under
``$ROS_HOME``, ``none`` = not persisted), parameter changes forwarded to the processor.

Topics (relative, so a namespace moves them): in ``vehicle/wheel_speeds`` (WheelSpeeds, raw),
``vehicle/driver_inputs`` (DriverInputs, optional); out ``tpms/tire_stiffness``
(TireStiffness), ``tpms/indication/stiffness`` (TpmsIndication), ``/diagnostics`` (input
silence after ``silence_timeout_s`` is an ERROR naming the input). Service ``~/calibrate``
(std_srvs/Trigger): learn every tire's nominal stiffness over the next ``calibration_s`` of
*valid* data (the tires must be at ``nominal_pressure_kpa``).
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.parameter import Parameter

from tpms_ros.core.stiffness_observer import StiffnessObserverParams, TireStiffnessObserver
from tpms_ros.processing.tire_stiffness_observer import (
    TireStiffnessObserverNodeParams,
    TireStiffnessObserverProcessor,
    chunk_problem,
)
from vehicle_monitor_common.node_helpers import TypedParameters, calibration_path, run_node
from vehicle_monitor_common.processor_node import ProcessorNode

__all__ = ['TireStiffnessObserverNode', 'TireStiffnessObserverNodeParams', 'main']


class TireStiffnessObserverNode(ProcessorNode):
    """The ``tire_stiffness_observer`` node (see the module docstring)."""

    processor: TireStiffnessObserverProcessor

    def __init__(self, node_name: str = 'tire_stiffness_observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._method_params = TypedParameters(self, StiffnessObserverParams,
                                              on_change=self._on_change)
        self._node_params = TypedParameters(self, TireStiffnessObserverNodeParams,
                                            on_change=self._on_node_change)
        n = self._node_params.value
        processor = TireStiffnessObserverProcessor(
            self._method_params.value, n, calibration_path(self, n.calibration_file))
        self.add_on_set_parameters_callback(self._validate_chunk)
        self.attach(processor, 'wheel_speed_sensors', n.diagnostics_period_s,
                    n.silence_timeout_s)
        self._log_events()

    @property
    def parameters(self) -> StiffnessObserverParams:
        """The method's current, validated parameters (the core's)."""
        return self._method_params.value

    @property
    def node_parameters(self) -> TireStiffnessObserverNodeParams:
        """The node's own current, validated parameters."""
        return self._node_params.value

    @property
    def observer(self) -> TireStiffnessObserver:
        """The estimator core in use."""
        return self.processor.observer

    @property
    def calibration_state(self) -> str:
        """uncalibrated, loaded, calibrating, calibrated, failed or file_corrupt."""
        return self.processor.calibration.state

    @property
    def calibration_file_problem(self) -> str:
        """Why the calibration file was unusable ('' if it was not, or once one is saved)."""
        return self.processor.calibration.file_problem

    @property
    def received(self) -> int:
        """Wheel-speed messages received."""
        return self.processor.received

    @property
    def processed(self) -> int:
        """Wheel-speed samples the core processed."""
        return self.processor.processed

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected wheel-speed messages by reason."""
        return dict(self.processor.rejected)

    def _validate_chunk(self, parameters: list[Parameter]) -> SetParametersResult:
        # The one rule across the two parameter classes: a chunk holds at least one sample.
        values = {prm.name: prm.value for prm in parameters}
        problem = chunk_problem(
            float(values.get('process_period_s', self.node_parameters.process_period_s)),
            float(values.get('sample_rate_hz', self.parameters.sample_rate_hz)))
        return SetParametersResult(successful=not problem, reason=problem)

    def _on_change(self, p: StiffnessObserverParams) -> None:
        self.processor.set_params(p)

    def _on_node_change(self, n: TireStiffnessObserverNodeParams) -> None:
        self.processor.set_node_params(n)

    def deliver(self, topic: str, message: Any) -> None:
        """Hand one message over, then log what the calibration did."""
        super().deliver(topic, message)
        if self.processor.events:
            self._log_events()

    def _log_events(self) -> None:
        for event in self.processor.events:
            self.get_logger().info(event)
        self.processor.events.clear()


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``tire_stiffness_observer`` executable."""
    raise SystemExit(run_node(TireStiffnessObserverNode, args))
