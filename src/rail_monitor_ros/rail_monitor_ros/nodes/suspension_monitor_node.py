"""``suspension_monitor``: secondary-suspension fault detection by IMM
(docs/methods/suspension_monitor.md) on ROS 2.

Subscribes ``rail/bogie/imu``, ``rail/body/imu`` and, when enabled, ``rail/track_irregularity``,
``rail/creep_factor`` and ``rail/speed`` (geometry_msgs/TwistStamped: the model's speed);
publishes ``rail/suspension/modes`` (ModeProbabilities) and
``/diagnostics``. Its logic (IMU pairing, input checks, data time, outputs, status) is
:class:`rail_monitor_ros.processing.suspension_monitor.SuspensionMonitorProcessor`, which the
offline engine runs too; that module declares the node (``SPEC``: its parameter groups
``SuspensionImmParams`` and ``SuspensionMonitorNodeParams``, hardware id, factory), this one names
that declaration, and :class:`~vehicle_monitor_common.processor_node.ProcessorNode` does the
rest.
"""

from __future__ import annotations

from rail_monitor_ros.processing import suspension_monitor
from vehicle_monitor_common.processor_node import ProcessorNode


class SuspensionMonitorNode(ProcessorNode, spec=suspension_monitor.SPEC):
    """IMM suspension monitor node (see the module docstring)."""


main = SuspensionMonitorNode.main
