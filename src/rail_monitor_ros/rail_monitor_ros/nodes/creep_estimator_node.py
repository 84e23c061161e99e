"""``creep_estimator``: wheel-rail creep factor by augmented-state EKF
(docs/methods/creep_estimator.md) on ROS 2.

Subscribes, per the ``pattern`` parameter, ``rail/lateral_states`` (RailLateralStates; patterns
A-C) or ``rail/bogie/imu`` + ``rail/body/imu`` (sensor_msgs/Imu; pattern D), and optionally
``rail/track_irregularity`` (TrackIrregularity) and ``rail/speed`` (geometry_msgs/TwistStamped:
the model's speed); publishes ``rail/creep_factor`` (CreepFactor)
for every processed sample, stamped with that sample's stamp, and ``/diagnostics``. Its logic
(sample assembly, input checks, the EKF, outputs, status) is
:class:`rail_monitor_ros.processing.creep_estimator.CreepEstimatorProcessor`, which the offline
engine runs too; that module declares the node (``SPEC``: its parameter groups
``CreepEkfParams`` and ``CreepEstimatorNodeParams``, hardware id, factory), this one names that
declaration, and :class:`~vehicle_monitor_common.processor_node.ProcessorNode` does the rest.
"""

from __future__ import annotations

from rail_monitor_ros.processing import creep_estimator
from vehicle_monitor_common.processor_node import ProcessorNode


class CreepEstimatorNode(ProcessorNode, spec=creep_estimator.SPEC):
    """Creep-factor EKF node (see the module docstring)."""


main = CreepEstimatorNode.main
