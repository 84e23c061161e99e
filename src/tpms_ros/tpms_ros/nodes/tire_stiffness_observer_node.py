"""``tire_stiffness_observer``: TPMS by tire stiffness (Umeno 1997) on the ROS graph.

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.tire_stiffness_observer.TireStiffnessObserverProcessor`, which holds
the node's logic (stamp checks and time jumps, chunking, output timing in data time,
calibration, gating, status) and is run by the offline engine too; its module declares the node
(``SPEC``: the parameter groups, the core's ``StiffnessObserverParams`` and the node's
``TireStiffnessObserverNodeParams``, the rule across them, a chunk holds at least one sample,
and the processor's factory). The calibration file
(``node_helpers.calibration_path``: empty = per node and namespace under
``$ROS_HOME``, ``none`` = not persisted), its events in the log and ``~/calibrate`` are
:class:`~vehicle_monitor_common.processor_node.ProcessorNode`'s, as for every calibrating node.

Topics (relative, so a namespace moves them): in ``vehicle/wheel_speeds`` (WheelSpeeds, raw),
``vehicle/driver_inputs`` (DriverInputs, optional); out ``tpms/tire_stiffness``
(TireStiffness), ``tpms/indication/stiffness`` (TpmsIndication), ``/diagnostics`` (input
silence after ``silence_timeout_s`` is an ERROR naming the input). Service ``~/calibrate``
(std_srvs/Trigger): learn every tire's nominal stiffness over the next ``calibration_s`` of
*valid* data (the tires must be at ``nominal_pressure_kpa``).
"""

from __future__ import annotations

from tpms_ros.processing import tire_stiffness_observer
from vehicle_monitor_common.processor_node import ProcessorNode


class TireStiffnessObserverNode(ProcessorNode, spec=tire_stiffness_observer.SPEC):
    """The ``tire_stiffness_observer`` node (see the module docstring)."""


main = TireStiffnessObserverNode.main
