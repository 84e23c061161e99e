"""``lateral_force_observer``: tire forces by SKFMEC (Kim & Huh 2000) on the ROS graph.

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.lateral_force_observer.LateralForceObserverProcessor`, which holds
the node's logic (input alignment, input checks, time jumps, status) and is run by the offline
engine too, and which declares the node (``SPEC``): the parameter groups (the method's
``ObserverVehicleParams`` and ``ObserverTuningParams``, the node's
``LateralForceObserverNodeParams``, each declared once) and the processor methods their changes
go to (a model change restarts the filter).

Topics (relative, so a namespace moves them): in ``vehicle/imu`` (sensor_msgs/Imu, 100 Hz, drives
the filter), ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz, raw), ``vehicle/driver_inputs``
(DriverInputs, 100 Hz); out ``vehicle/tire_forces`` (TireForces), ``/diagnostics`` (input
silence after ``silence_timeout_s`` is an ERROR naming the input).
"""

from __future__ import annotations

from tpms_ros.processing import lateral_force_observer
from vehicle_monitor_common.processor_node import ProcessorNode


class LateralForceObserverNode(ProcessorNode, spec=lateral_force_observer.SPEC):
    """The ``lateral_force_observer`` node (see the module docstring)."""


main = LateralForceObserverNode.main
