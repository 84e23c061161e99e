"""``vibration_analyzer``: TPMS by tire torsional resonance (Persson 2002,
docs/methods/vibration_analyzer.md) on ROS.

A transport adapter around
:class:`tpms_ros.processing.vibration_analyzer.VibrationAnalyzerProcessor`, which holds the
node's logic (stamp checks and time jumps, blocks, output timing in data time, calibration,
sensor faults, status) and is run by the offline engine too; its module declares the node
(``SPEC``: the parameter groups, the core's ``VibrationParams`` and the node's
``VibrationAnalyzerNodeParams``, and the processor's factory). The calibration file, its
events in the log and ``~/calibrate`` are
:class:`~vehicle_monitor_common.processor_node.ProcessorNode`'s, as for every calibrating node.

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

from tpms_ros.processing import vibration_analyzer
from vehicle_monitor_common.processor_node import ProcessorNode


class VibrationAnalyzerNode(ProcessorNode, spec=vibration_analyzer.SPEC):
    """The ``vibration_analyzer`` node (see the module docstring)."""


main = VibrationAnalyzerNode.main
