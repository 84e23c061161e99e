"""``creep_estimator``: wheel-rail creep factor by augmented-state EKF
(docs/methods/creep_estimator.md) on ROS 2.

Subscribes, per the ``pattern`` parameter, ``rail/lateral_states`` (RailLateralStates; patterns
A-C) or ``rail/bogie/imu`` + ``rail/body/imu`` (sensor_msgs/Imu; pattern D), and optionally
``rail/track_irregularity`` (TrackIrregularity); publishes ``rail/creep_factor`` (CreepFactor)
for every processed sample, stamped with that sample's stamp, and ``/diagnostics``. Its logic
(sample assembly, input checks, the EKF, outputs, status) is
:class:`rail_monitor_ros.processing.creep_estimator.CreepEstimatorProcessor`, which the offline
engine runs too; this node declares the parameters from their definitions (``CreepEkfParams``,
``CreepEstimatorNodeParams``), builds the processor and attaches it.
"""

from __future__ import annotations

import sys
from typing import Any

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams
from rail_monitor_ros.processing.creep_estimator import (
    CreepEstimatorNodeParams,
    CreepEstimatorProcessor,
)
from vehicle_monitor_common.node_helpers import TypedParameters, run_node
from vehicle_monitor_common.processor_node import ProcessorNode


class CreepEstimatorNode(ProcessorNode):
    """Creep-factor EKF node (see the processor for what it does)."""

    processor: CreepEstimatorProcessor

    def __init__(self, node_name: str = 'creep_estimator', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, CreepEkfParams,
                                      on_change=lambda p: self.processor.update_params(p))
        self._node_typed = TypedParameters(
            self, CreepEstimatorNodeParams,
            on_change=lambda n: self.processor.update_node_params(n))
        p, n = self._typed.value, self._node_typed.value
        self.attach(CreepEstimatorProcessor(p, n), f'rail/creep/{p.bogie}',
                    n.diagnostics_period_s, n.silence_timeout_s)

    @property
    def params(self) -> CreepEkfParams:
        """The method's current validated parameters."""
        return self._typed.value

    @property
    def node_params(self) -> CreepEstimatorNodeParams:
        """The node's current validated parameters."""
        return self._node_typed.value

    @property
    def estimator(self) -> CreepEkf:
        """The core filter (read access for tests and tools)."""
        return self.processor.ekf

    @property
    def counts(self) -> dict[str, int]:
        """Input, pairing and rejection counters; the core's: ``estimator``."""
        return self.processor.counts


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``creep_estimator`` executable."""
    sys.exit(run_node(CreepEstimatorNode, args))


if __name__ == '__main__':
    main()
