"""``wheel_radius_analyzer``: TPMS by relative rolling radii (Persson 2002,
docs/methods/wheel_radius_analyzer.md) on ROS.

A transport adapter around
:class:`tpms_ros.processing.wheel_radius_analyzer.WheelRadiusAnalyzerProcessor`, which holds the
node's logic (input alignment, stamp checks and time jumps, chunking, output timing in data
time, calibration, sensor faults, status) and is run by the offline engine too; its module
declares the node (``SPEC``: the parameter groups, the core's ``WheelRadiusParams`` and the
node's ``WheelRadiusAnalyzerNodeParams``, and the processor's factory). The calibration file, its
events in the log and ``~/calibrate`` are
:class:`~vehicle_monitor_common.processor_node.ProcessorNode`'s, as for every calibrating node.

Topics (relative, so a namespace moves them): in ``vehicle/wheel_speeds`` (WheelSpeeds, ~1 kHz,
raw), ``vehicle/imu`` (sensor_msgs/Imu, ``angular_velocity.z`` = yaw rate, REP 103),
``vehicle/driver_inputs`` (DriverInputs: wheel torques, steering angle); out
``tpms/wheel_radius`` (WheelRadiusOffsets), ``tpms/indication/wheel_radius`` (TpmsIndication)
and ``/diagnostics`` (input silence after ``silence_timeout_s`` is an ERROR naming the input).
Service ``~/calibrate`` (std_srvs/Trigger) learns the nominal pair offsets over
``calibration_duration_s`` of data, saved to the calibration file (empty ``calibration_file``:
``$ROS_HOME/vehicle_monitor/calibration/<namespace>/<node>.yaml``; ``none``: not persisted) and
reloaded at start.
"""

from __future__ import annotations

from tpms_ros.processing import wheel_radius_analyzer
from vehicle_monitor_common.processor_node import ProcessorNode


class WheelRadiusAnalyzerNode(ProcessorNode, spec=wheel_radius_analyzer.SPEC):
    """The ``wheel_radius_analyzer`` node (see the module docstring)."""


main = WheelRadiusAnalyzerNode.main
