"""``vibration_analyzer``: TPMS by tire torsional resonance (Persson 2002,
docs/methods/vibration_analyzer.md) on ROS.

A transport adapter around
:class:`tpms_ros.processing.vibration_analyzer.VibrationAnalyzerProcessor`, which holds the
node's logic (stamp checks and time jumps, blocks, output timing in data time, calibration,
sensor faults, status) and is run by the offline engine too; the shared part of the two
calibrating TPMS nodes is :class:`tpms_ros.nodes.calibrating_tpms_node.CalibratingTpmsNode`.

Topics (relative, so a namespace moves them): in ``vehicle/wheel_speeds`` (WheelSpeeds, ~1 kHz,
raw); out ``tpms/tire_resonance`` (TireResonance) and ``tpms/indication/vibration``
(TpmsIndication), both stamped with the last wheel-speed sample of the block they answer, and
``/diagnostics`` (input silence after ``silence_timeout_s`` is an ERROR naming the input).
Service ``~/calibrate`` (std_srvs/Trigger) learns each tire's nominal resonance over
``calibration_duration_s`` of data; the result is saved to the calibration file (empty
``calibration_file``: ``$ROS_HOME/vehicle_monitor/calibration/<namespace>/<node>.yaml``;
``none``: not persisted) and reloaded at start.
"""

from __future__ import annotations

from typing import Any

from tpms_ros.core.vibration_analysis import VibrationParams
from tpms_ros.nodes.calibrating_tpms_node import CalibratingTpmsNode
from tpms_ros.processing.vibration_analyzer import (
    VibrationAnalyzerNodeParams,
    VibrationAnalyzerProcessor,
)
from vehicle_monitor_common.node_helpers import run_node

__all__ = ['VibrationAnalyzerNode', 'VibrationAnalyzerNodeParams', 'main']


class VibrationAnalyzerNode(CalibratingTpmsNode[VibrationParams, VibrationAnalyzerNodeParams,
                                                VibrationAnalyzerProcessor]):
    """The ``vibration_analyzer`` node (see the module docstring)."""

    def __init__(self, node_name: str = 'vibration_analyzer', **kwargs: Any) -> None:
        super().__init__(node_name, 'tpms/vibration', VibrationParams,
                         VibrationAnalyzerNodeParams, VibrationAnalyzerProcessor, **kwargs)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``vibration_analyzer`` executable."""
    raise SystemExit(run_node(VibrationAnalyzerNode, args))


if __name__ == '__main__':
    main()
