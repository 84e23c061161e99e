"""``tpms_voter``: voting fusion of the TPMS methods' indications (Persson 2002,
docs/methods/tpms_voter.md).

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.tpms_voter.TpmsVoterProcessor`, which holds the logic (indication
checks and time jumps, voting in data time, the warning, the status) and is run by the offline
engine too. Here: the parameter groups (the read-only ``methods``; per method
``<method>.enabled`` and ``<method>.threshold``; the rule, :class:`VotingRuleParams`) and the
rule across them (every threshold above ``h0``: the core's), and what only ROS has: the node
clock the processor extrapolates data time with, the timer of the periodic ``tpms/warning``
between indications (``publish_rate_hz``) and the node clock's jump callback (a ``/clock``
reset re-anchors that extrapolation).

Topics: in ``tpms/indication/<method>`` (TpmsIndication) per method; out ``tpms/warning``
(TpmsWarning), ``/diagnostics`` (an indication topic silent for ``silence_timeout_s`` is an
ERROR naming it).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from rclpy.clock import JumpThreshold, TimeJump
from rclpy.duration import Duration

from tpms_ros.core.tpms_voting import VotingRuleParams, method_votes_params
from tpms_ros.processing.tpms_voter import TpmsVoterNodeParams, TpmsVoterProcessor, voter_params
from vehicle_monitor_common.parameters import build
from vehicle_monitor_common.processor_node import ParameterGroup, ProcessorNode


def _votes_params(values: Mapping[str, Any]) -> type[Any]:
    return method_votes_params(values['methods'])


def _threshold_problem(values: Mapping[str, Any]) -> str:
    try:
        voter_params(build(VotingRuleParams, values), build(_votes_params(values), values))
    except (TypeError, ValueError) as exc:
        return str(exc)
    return ''


class TpmsVoterNode(
        ProcessorNode, name='tpms_voter', hardware_id='tpms/voter',
        cross_check=_threshold_problem,
        groups=(ParameterGroup(TpmsVoterNodeParams),
                ParameterGroup(VotingRuleParams, 'set_params'),
                ParameterGroup(_votes_params, 'set_params'))):
    """Wraps :class:`TpmsVoterProcessor`: indication topics in, warnings and diagnostics out."""

    processor: TpmsVoterProcessor

    def __init__(self, node_name: str = '', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        n = self.parameters_of(TpmsVoterNodeParams)
        self.create_timer(1.0 / n.publish_rate_hz, self._on_timer)
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=Duration(seconds=n.jump_horizon_s),
                          min_backward=Duration(nanoseconds=-1)),
            post_callback=self._on_clock_jump)

    def create_processor(self, values: Mapping[str, Any]) -> TpmsVoterProcessor:
        """The processor with the node clock, which the offline engine's factory has not:
        live, the warning is also repeated between indications, in extrapolated data time."""
        return TpmsVoterProcessor(
            build(VotingRuleParams, values), build(_votes_params(values), values),
            build(TpmsVoterNodeParams, values), clock=lambda: self.get_clock().now().nanoseconds)

    def _on_timer(self) -> None:
        for output in self.processor.tick(self.get_clock().now().nanoseconds):
            self.publish_output(output)

    def _on_clock_jump(self, _: TimeJump) -> None:
        self.processor.clock_jumped(self.get_clock().now().nanoseconds)


main = TpmsVoterNode.main
