"""``suspension_monitor``: secondary-suspension fault detection by IMM
(docs/methods/suspension_monitor.md) on ROS 2.

Subscribes ``rail/bogie/imu``, ``rail/body/imu`` and, when enabled, ``rail/track_irregularity``
and ``rail/creep_factor``; publishes ``rail/suspension/modes`` (ModeProbabilities) and
``/diagnostics``. Its logic (IMU pairing, input checks, data time, outputs, status) is
:class:`rail_monitor_ros.processing.suspension_monitor.SuspensionMonitorProcessor`, which the
offline engine runs too; this node names the parameters' definitions (``SuspensionImmParams``,
``SuspensionMonitorNodeParams``) and the processor's factory, and
:class:`~vehicle_monitor_common.processor_node.ProcessorNode` does the rest.
"""

from __future__ import annotations

from rail_monitor_ros.core.suspension_imm import SuspensionImmParams
from rail_monitor_ros.processing.suspension_monitor import (
    SuspensionMonitorNodeParams,
    make_processor,
)
from vehicle_monitor_common.processor_node import ParameterGroup, ProcessorNode


class SuspensionMonitorNode(
        ProcessorNode, name='suspension_monitor', factory=make_processor,
        hardware_id='rail_suspension_imm',
        groups=(ParameterGroup(SuspensionImmParams, 'update_params'),
                ParameterGroup(SuspensionMonitorNodeParams, 'update_node_params'))):
    """IMM suspension monitor node (see the module docstring)."""


main = SuspensionMonitorNode.main
