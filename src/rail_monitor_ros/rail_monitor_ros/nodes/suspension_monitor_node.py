"""``suspension_monitor``: secondary-suspension fault detection by IMM
(docs/methods/suspension_monitor.md) on ROS 2.

Subscribes ``rail/bogie/imu``, ``rail/body/imu`` and, when enabled, ``rail/track_irregularity``
and ``rail/creep_factor``; publishes ``rail/suspension/modes`` (ModeProbabilities) and
``/diagnostics``. Its logic (IMU pairing, input checks, data time, outputs, status) is
:class:`rail_monitor_ros.processing.suspension_monitor.SuspensionMonitorProcessor`, which the
offline engine runs too; this node declares the parameters from their definitions
(``SuspensionImmParams``, ``SuspensionMonitorNodeParams``), builds the processor and attaches
it.
"""

from __future__ import annotations

from typing import Any

from rail_monitor_ros.core.suspension_imm import SuspensionImmParams
from rail_monitor_ros.processing.suspension_monitor import (
    SuspensionMonitorNodeParams,
    SuspensionMonitorProcessor,
)
from vehicle_monitor_common.node_helpers import TypedParameters
from vehicle_monitor_common.processor_node import ProcessorNode


class SuspensionMonitorNode(ProcessorNode):
    """IMM suspension monitor node (see the processor for what it does)."""

    processor: SuspensionMonitorProcessor

    def __init__(self, node_name: str = 'suspension_monitor', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._typed = TypedParameters(self, SuspensionImmParams,
                                      on_change=lambda p: self.processor.update_params(p))
        self._node_typed = TypedParameters(
            self, SuspensionMonitorNodeParams,
            on_change=lambda n: self.processor.update_node_params(n))
        n = self._node_typed.value
        self.attach(SuspensionMonitorProcessor(self._typed.value, n), 'rail_suspension_imm',
                    n.diagnostics_period_s, n.silence_timeout_s)

    @property
    def params(self) -> SuspensionImmParams:
        """The method's current validated parameters."""
        return self._typed.value

    @property
    def node_params(self) -> SuspensionMonitorNodeParams:
        """The node's current validated parameters."""
        return self._node_typed.value


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``suspension_monitor`` executable."""
    import sys

    from vehicle_monitor_common.node_helpers import run_node

    sys.exit(run_node(SuspensionMonitorNode, args))


if __name__ == '__main__':
    main()
