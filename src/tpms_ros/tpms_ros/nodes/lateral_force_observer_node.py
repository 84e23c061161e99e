"""``lateral_force_observer``: tire forces by SKFMEC (Kim & Huh 2000) on the ROS graph.

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.lateral_force_observer.LateralForceObserverProcessor`, which holds
the node's logic (input alignment, input checks, time jumps, status) and is run by the offline
engine too. Here: the parameter groups (the method's :class:`ObserverVehicleParams` and
:class:`ObserverTuningParams`, the node's :class:`LateralForceObserverNodeParams`, each
declared once) and the processor methods their changes go to (a model change restarts the
filter).

Topics (relative, so a namespace moves them): in ``vehicle/imu`` (sensor_msgs/Imu, 100 Hz, drives
the filter), ``vehicle/wheel_speeds`` (WheelSpeeds, 1 kHz, raw), ``vehicle/driver_inputs``
(DriverInputs, 100 Hz); out ``vehicle/tire_forces`` (TireForces), ``/diagnostics`` (input
silence after ``silence_timeout_s`` is an ERROR naming the input).
"""

from __future__ import annotations

from tpms_ros.core.lateral_force_observer import ObserverTuningParams, ObserverVehicleParams
from tpms_ros.processing.lateral_force_observer import (
    LateralForceObserverNodeParams,
    make_processor,
)
from vehicle_monitor_common.processor_node import ParameterGroup, ProcessorNode


class LateralForceObserverNode(
        ProcessorNode, name='lateral_force_observer', factory=make_processor,
        hardware_id='vehicle_imu',
        groups=(ParameterGroup(ObserverVehicleParams, 'set_model'),
                ParameterGroup(ObserverTuningParams, 'set_model'),
                ParameterGroup(LateralForceObserverNodeParams, 'set_node_params'))):
    """The ``lateral_force_observer`` node (see the module docstring)."""


main = LateralForceObserverNode.main
