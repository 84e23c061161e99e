"""``lateral_force_observer``: tire forces by SKFMEC (Kim & Huh 2000) on the ROS graph.

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.lateral_force_observer.LateralForceObserverProcessor`, which holds
the node's logic (input alignment, input checks, time jumps, status) and is run by the offline
engine too. Here: the parameters (the method's :class:`ObserverVehicleParams` and
:class:`ObserverTuningParams`, the node's :class:`LateralForceObserverNodeParams`, each
declared once) and their changes forwarded to the processor (a model change restarts the
filter).

Topics (relative, so a namespace moves them): in ``vehicle/imu`` (sensor_msgs/Imu, 100 Hz, drives
the filter), ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz, raw), ``vehicle/driver_inputs``
(DriverInputs, 100 Hz); out ``vehicle/tire_forces`` (TireForces), ``/diagnostics`` (input
silence after ``silence_timeout_s`` is an ERROR naming the input).
"""

from __future__ import annotations

from typing import Any

from tpms_ros.core.lateral_force_observer import (
    LateralForceObserver,
    ObserverTuningParams,
    ObserverVehicleParams,
)
from tpms_ros.processing.lateral_force_observer import (
    LateralForceObserverNodeParams,
    LateralForceObserverProcessor,
)
from vehicle_monitor_common.node_helpers import TypedParameters, run_node
from vehicle_monitor_common.processor_node import ProcessorNode

__all__ = ['LateralForceObserverNode', 'LateralForceObserverNodeParams', 'main']


class LateralForceObserverNode(ProcessorNode):
    """The ``lateral_force_observer`` node (see the module docstring)."""

    processor: LateralForceObserverProcessor

    def __init__(self, node_name: str = 'lateral_force_observer', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._vehicle = TypedParameters(self, ObserverVehicleParams,
                                        on_change=self._on_model_change)
        self._tuning = TypedParameters(self, ObserverTuningParams,
                                       on_change=self._on_model_change)
        self._typed = TypedParameters(self, LateralForceObserverNodeParams,
                                      on_change=self._on_node_change)
        n = self._typed.value
        self.attach(LateralForceObserverProcessor(self._vehicle.value, self._tuning.value, n),
                    'vehicle_imu', n.diagnostics_period_s, n.silence_timeout_s)

    @property
    def parameters(self) -> LateralForceObserverNodeParams:
        """The current, validated node-only parameters."""
        return self._typed.value

    @property
    def vehicle_parameters(self) -> ObserverVehicleParams:
        """The observer's current vehicle model."""
        return self._vehicle.value

    @property
    def tuning_parameters(self) -> ObserverTuningParams:
        """The observer's current filter settings."""
        return self._tuning.value

    @property
    def observer(self) -> LateralForceObserver:
        """The estimator core in use."""
        return self.processor.observer

    @property
    def received(self) -> dict[str, int]:
        """Messages received per input."""
        return self.processor.received

    @property
    def rejected(self) -> dict[str, int]:
        """Rejected input messages by reason (the core's own: observer.health.rejected)."""
        return self.processor.rejected

    @property
    def skipped(self) -> dict[str, int]:
        """IMU samples skipped by reason (stale inputs, frozen IMU)."""
        return self.processor.skipped

    @property
    def published(self) -> int:
        """Outputs published."""
        return self.processor.published

    def _on_model_change(self, _: Any) -> None:
        self.processor.set_model(self._vehicle.value, self._tuning.value)

    def _on_node_change(self, n: LateralForceObserverNodeParams) -> None:
        self.processor.set_node_params(n)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``lateral_force_observer`` executable."""
    raise SystemExit(run_node(LateralForceObserverNode, args))


if __name__ == '__main__':
    main()
