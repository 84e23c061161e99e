"""``tpms_voter``: voting fusion of the TPMS methods' indications (Persson 2002,
docs/methods/tpms_voter.md).

A transport adapter (:class:`~vehicle_monitor_common.processor_node.ProcessorNode`) around
:class:`tpms_ros.processing.tpms_voter.TpmsVoterProcessor`, which holds the logic (indication
checks and time jumps, voting in data time, the warning, the status) and is run by the offline
engine too. Here: the parameters (the read-only ``methods``; per method ``<method>.enabled``
and ``<method>.threshold``; the rule, :class:`VotingRuleParams`), changes forwarded to the
processor, and what only ROS has: the timer of the periodic ``tpms/warning`` between
indications (``publish_rate_hz``, data time extrapolated with the node clock) and the node
clock's jump callback (a ``/clock`` reset re-anchors that extrapolation).

Topics: in ``tpms/indication/<method>`` (TpmsIndication) per method; out ``tpms/warning``
(TpmsWarning), ``/diagnostics`` (an indication topic silent for ``silence_timeout_s`` is an
ERROR naming it).
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import JumpThreshold, TimeJump
from rclpy.duration import Duration
from rclpy.parameter import Parameter

from tpms_ros.core.tpms_voting import (
    TpmsVoter,
    VoterParams,
    VotingRuleParams,
    method_votes_params,
)
from tpms_ros.processing.tpms_voter import TpmsVoterNodeParams, TpmsVoterProcessor
from vehicle_monitor_common.node_helpers import TypedParameters, run_node
from vehicle_monitor_common.parameters import flatten
from vehicle_monitor_common.processor_node import ProcessorNode

__all__ = ['TpmsVoterNode', 'TpmsVoterNodeParams', 'main']


class TpmsVoterNode(ProcessorNode):
    """Wraps :class:`TpmsVoterProcessor`: indication topics in, warnings and diagnostics out."""

    processor: TpmsVoterProcessor

    def __init__(self, node_name: str = 'tpms_voter', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._node_params = TypedParameters(self, TpmsVoterNodeParams)
        n = self._node_params.value
        self._rule = TypedParameters(self, VotingRuleParams, on_change=self._sync)
        self._votes = TypedParameters(self, method_votes_params(n.methods),
                                      on_change=self._sync)
        processor = TpmsVoterProcessor(self._rule.value, self._votes.value, n,
                                       clock=lambda: self.get_clock().now().nanoseconds)
        # The rule across the groups (every h_i > h0) is the core's: checked on the candidate.
        self.add_on_set_parameters_callback(self._validate_votes)
        self.attach(processor, 'tpms/voter', n.diagnostics_period_s, n.silence_timeout_s)
        self.create_timer(1.0 / n.publish_rate_hz, self._on_timer)
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=Duration(seconds=n.jump_horizon_s),
                          min_backward=Duration(nanoseconds=-1)),
            post_callback=self._on_clock_jump)

    @property
    def parameters(self) -> VotingRuleParams:
        """The voting rule's current, validated parameters."""
        return self._rule.value

    @property
    def node_parameters(self) -> TpmsVoterNodeParams:
        """The node's own current, validated parameters."""
        return self._node_params.value

    @property
    def voter(self) -> TpmsVoter:
        """The core voter (read access for tests and tools)."""
        return self.processor.voter

    def _validate_votes(self, parameters: list[Parameter]) -> SetParametersResult:
        rule, votes = flatten(self._rule.value), flatten(self._votes.value)
        for prm in parameters:
            for values in (rule, votes):
                if prm.name in values:
                    values[prm.name] = prm.value
        thresholds = {name[:-len('.threshold')]: float(value) for name, value in votes.items()
                      if name.endswith('.threshold')}
        try:
            VoterParams(**rule, method_thresholds=thresholds)
        except (TypeError, ValueError) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _sync(self, _: Any = None) -> None:
        self.processor.set_params(self._rule.value, self._votes.value)

    def _on_timer(self) -> None:
        for output in self.processor.tick(self.get_clock().now().nanoseconds):
            self.publish_output(output)

    def _on_clock_jump(self, _: TimeJump) -> None:
        self.processor.clock_jumped(self.get_clock().now().nanoseconds)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``tpms_voter`` executable."""
    raise SystemExit(run_node(TpmsVoterNode, args))


if __name__ == '__main__':
    main()
