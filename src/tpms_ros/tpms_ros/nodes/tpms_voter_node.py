"""``tpms_voter``: voting fusion of the TPMS methods' indications (Persson 2002,
docs/methods/tpms_voter.md).

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.tpms_voter.TpmsVoterProcessor`, which holds the logic (indication
checks and time jumps, voting in data time, the warning, the status) and is run by the offline
engine too; its module declares the node (``SPEC``: the parameter groups, i.e. the read-only
``methods``, per method ``<method>.enabled`` and ``<method>.threshold``, the rule
``VotingRuleParams``; and the rule across them, every threshold above ``h0``: the core's).
Here, what only ROS has: the node clock the processor extrapolates data time with, the timer of
the periodic ``tpms/warning`` between indications (``publish_rate_hz``) and the node clock's
jump callback (a ``/clock`` reset re-anchors that extrapolation).

Topics: in ``tpms/indication/<method>`` (TpmsIndication) per method; out ``tpms/warning``
(TpmsWarning), ``/diagnostics`` (an indication topic silent for ``silence_timeout_s`` is an
ERROR naming it).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rclpy.clock import TimeJump

from tpms_ros.processing import tpms_voter
from tpms_ros.processing.tpms_voter import TpmsVoterNodeParams, TpmsVoterProcessor
from vehicle_monitor_common.processor_node import ProcessorNode


class TpmsVoterNode(ProcessorNode, spec=tpms_voter.SPEC):
    """Wraps :class:`TpmsVoterProcessor`: indication topics in, warnings and diagnostics out."""

    processor: TpmsVoterProcessor

    def __init__(self, node_name: str = '', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        n = self.parameters_of(TpmsVoterNodeParams)
        self.create_timer(1.0 / n.publish_rate_hz, self._on_timer)
        self.watch_time_jumps(n.jump_horizon_s, self._on_clock_jump)

    def create_processor(self, values: Mapping[str, Any]) -> TpmsVoterProcessor:
        """The processor with the node clock, which the offline engine's has not: live, the
        warning is also repeated between indications, in extrapolated data time."""
        return tpms_voter.make_processor(values, self.get_fully_qualified_name(),
                                         clock=lambda: self.get_clock().now().nanoseconds)

    def _on_timer(self) -> None:
        for output in self.processor.tick(self.get_clock().now().nanoseconds):
            self.publish_output(output)

    def _on_clock_jump(self, _: TimeJump) -> None:
        self.processor.clock_jumped(self.get_clock().now().nanoseconds)


main = TpmsVoterNode.main
