"""``wheel_radius_analyzer``: TPMS by relative rolling radii (Persson 2002,
docs/methods/wheel_radius_analyzer.md) on ROS.

A transport adapter around
:class:`tpms_ros.processing.wheel_radius_analyzer.WheelRadiusAnalyzerProcessor`, which holds the
node's logic (input alignment, stamp checks and time jumps, chunking, output timing in data
time, calibration, sensor faults, status) and is run by the offline engine too; the shared part
of the two calibrating TPMS nodes is
:class:`tpms_ros.nodes.calibrating_tpms_node.CalibratingTpmsNode`.

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

from typing import Any

from tpms_ros.core.wheel_radius_analysis import WheelRadiusParams
from tpms_ros.nodes.calibrating_tpms_node import CalibratingTpmsNode
from tpms_ros.processing.wheel_radius_analyzer import (
    WheelRadiusAnalyzerNodeParams,
    WheelRadiusAnalyzerProcessor,
)
from vehicle_monitor_common.node_helpers import run_node

__all__ = ['WheelRadiusAnalyzerNode', 'WheelRadiusAnalyzerNodeParams', 'main']


class WheelRadiusAnalyzerNode(CalibratingTpmsNode[WheelRadiusParams,
                                                  WheelRadiusAnalyzerNodeParams,
                                                  WheelRadiusAnalyzerProcessor]):
    """The ``wheel_radius_analyzer`` node (see the module docstring)."""

    def __init__(self, node_name: str = 'wheel_radius_analyzer', **kwargs: Any) -> None:
        super().__init__(node_name, 'tpms/wheel_radius', WheelRadiusParams,
                         WheelRadiusAnalyzerNodeParams, WheelRadiusAnalyzerProcessor, **kwargs)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``wheel_radius_analyzer`` executable."""
    raise SystemExit(run_node(WheelRadiusAnalyzerNode, args))


if __name__ == '__main__':
    main()
