"""``tpms_voter``: voting fusion of the TPMS methods' indications (Persson 2002, SPEC §3.3).

Subscribes ``tpms/indication/<method>`` (TpmsIndication) for each name in the read-only
``methods`` parameter and publishes ``tpms/warning`` (TpmsWarning) on each accepted indication
and at ``publish_rate_hz``, plus ``/diagnostics``. Per method ``<method>.enabled`` switches it
on/off and ``<method>.threshold`` is its own h_i (> ``h0``); the rule, hold-off and hysteresis
are the core's (:class:`tpms_ros.core.tpms_voting.TpmsVoter`).

Time. The voter runs in *data time*, the stamps of the indications: an indication is voted at
its own stamp, so hold-off, set-off and staleness are measured on the data and a replay at any
speed decides the same. Between indications, the periodic output extrapolates data time with
the node clock (the newest stamp plus the clock time since it arrived), so a method that falls
silent ages out after ``max_age_s`` (and the warning keeps being published). Each warning is
stamped with the newest indication the decision used (the evaluation time if none was fresh).
"""

from __future__ import annotations

from dataclasses import dataclass
import functools
import math
import re
from typing import Any

import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from vehicle_monitor_msgs.msg import TpmsIndication as IndicationMsg
from vehicle_monitor_msgs.msg import TpmsWarning

from tpms_ros.core.tires import TIRE_NAMES, TpmsIndication
from tpms_ros.core.tpms_voting import (
    TpmsVoter,
    VoterParams,
    VotingRuleParams,
    method_votes_params,
)
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.node_helpers import (
    ERROR,
    OK,
    OUTPUT_QOS,
    WARN,
    ConfigurationError,
    Diagnostics,
    TypedParameters,
    run_node,
    sensor_subscription,
    stamp_ns,
    time_msg,
)
from vehicle_monitor_common.parameters import flatten, param

_METHOD_NAME = re.compile(r'^[a-z][a-z0-9_]*$')


@dataclass(frozen=True)
class TpmsVoterNodeParams:
    """The node's own parameters (the rule's are :class:`VotingRuleParams`, each method's
    ``<method>.enabled`` and ``<method>.threshold`` a :class:`MethodVoteParams` group)."""

    methods: tuple[str, ...] = param(('stiffness', 'vibration', 'wheel_radius'),
                                     'methods voted: subscribes tpms/indication/<method>; each '
                                     'has <method>.enabled and <method>.threshold',
                                     read_only=True)
    publish_rate_hz: float = param(2.0, 'rate of the periodic tpms/warning between '
                                   'indications, Hz', low=0.01, high=100.0, read_only=True)
    diagnostics_period_s: float = param(1.0, 'period of /diagnostics, s', low=0.01,
                                        high=60.0, read_only=True)

    def __post_init__(self) -> None:
        if not self.methods:
            raise ValueError('methods must name at least one TPMS method')
        for name in self.methods:
            if not _METHOD_NAME.match(name):
                raise ValueError(f'methods: {name!r} is not a valid method name '
                                 '([a-z][a-z0-9_]*, it becomes a topic name)')
        if len(set(self.methods)) != len(self.methods):
            raise ValueError(f'methods: duplicate names in {list(self.methods)}')


class TpmsVoterNode(Node):
    """Wraps :class:`TpmsVoter`: indication topics in, warnings and diagnostics out."""

    def __init__(self, node_name: str = 'tpms_voter', **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._node_params = TypedParameters(self, TpmsVoterNodeParams)
        methods = self._node_params.value.methods
        self._rule = TypedParameters(self, VotingRuleParams, on_change=self._sync)
        self._votes = TypedParameters(self, method_votes_params(methods), on_change=self._sync)
        try:
            self._voter = TpmsVoter(self._voter_params(self._rule.value, self._votes.value))
        except ValueError as exc:
            raise ConfigurationError(f'invalid parameters: {exc}') from None
        self._sync()
        # The rule across the groups (every h_i > h0) is the core's: checked on the candidate.
        self.add_on_set_parameters_callback(self._validate_votes)

        self._checks = {m: StampCheck(max_gap_s=math.inf) for m in methods}
        self._received = dict.fromkeys(methods, 0)
        now_ns = self.get_clock().now().nanoseconds
        self._rates = {m: RateMeter(since_ns=now_ns) for m in methods}
        self._rejected = dict.fromkeys(('invalid', 'method_mismatch', 'out_of_order',
                                        'repeated'), 0)
        # data-time anchor: newest indication stamp and the node-clock time it arrived
        self._anchor: tuple[float, int] | None = None
        self._last_eval_s = -math.inf
        self._last_result: Any = None
        self._latest_stamp: dict[str, float] = {}
        self._publisher = self.create_publisher(TpmsWarning, 'tpms/warning', OUTPUT_QOS)
        for method in methods:
            sensor_subscription(self, IndicationMsg, f'tpms/indication/{method}',
                                functools.partial(self._on_indication, method))
        p = self.node_parameters
        self.create_timer(1.0 / p.publish_rate_hz, self._on_timer)
        self._diagnostics = Diagnostics(self, 'tpms/voter', p.diagnostics_period_s,
                                        update=self._update_diagnostics)
        self._update_diagnostics()

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
        return self._voter

    # -- parameters ----------------------------------------------------------------------------

    def _enabled(self) -> dict[str, bool]:
        return {m: getattr(self._votes.value, m).enabled for m in self.node_parameters.methods}

    @staticmethod
    def _voter_params(rule: VotingRuleParams, votes: Any) -> VoterParams:
        return VoterParams(**flatten(rule), method_thresholds={
            m: vote.threshold for m, vote in vars(votes).items()})

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
        # the voter reads its params at each evaluation; the method set is read-only
        self._voter.params = self._voter_params(self._rule.value, self._votes.value)
        for method, enabled in self._enabled().items():
            self._voter.set_enabled(method, enabled)

    # -- voting --------------------------------------------------------------------------------

    def _on_indication(self, method: str, msg: IndicationMsg) -> None:
        self._received[method] += 1
        self._rates[method].tick()
        if msg.method != method:
            self._rejected['method_mismatch'] += 1
            return
        stamp = stamp_ns(msg.header.stamp)
        verdict = self._checks[method].check(stamp)
        if verdict in ('out_of_order', 'repeated'):
            self._rejected[verdict] += 1
            return
        try:
            indication = TpmsIndication(
                method=method, stamp_s=stamp * 1e-9,
                underinflated=np.asarray(msg.underinflated, dtype=bool),
                confidence=np.asarray(msg.confidence, dtype=float),
                known=np.asarray(msg.known, dtype=bool))
        except ValueError:
            # NaN or out-of-range confidence, wrong sizes: the method counts as silent
            self._rejected['invalid'] += 1
            return
        if not self._voter.submit(indication):
            return
        self._latest_stamp[method] = indication.stamp_s
        now_ns = self.get_clock().now().nanoseconds
        if self._anchor is None or indication.stamp_s >= self._anchor[0]:
            self._anchor = (indication.stamp_s, now_ns)
        self._evaluate(max(indication.stamp_s, self._last_eval_s))

    def _on_timer(self) -> None:
        if self._anchor is None:
            return           # no data time yet: nothing to decide on
        stamp_s, arrived_ns = self._anchor
        now_s = stamp_s + (self.get_clock().now().nanoseconds - arrived_ns) * 1e-9
        self._evaluate(max(now_s, self._last_eval_s))

    def _evaluate(self, now_s: float) -> None:
        result = self._voter.evaluate(now_s)
        self._last_eval_s = now_s
        self._last_result = result
        used = [self._latest_stamp[m] for m in result.methods_used]
        stamp_s = max(used) if used else now_s
        msg = TpmsWarning()
        msg.header.stamp = time_msg(round(stamp_s * 1e9))
        msg.warning = result.warning.tolist()
        msg.active = result.active
        msg.confidence = result.confidence.tolist()
        msg.reasons = list(result.reasons)
        msg.methods = list(result.methods_used)
        self._publisher.publish(msg)

    # -- diagnostics ---------------------------------------------------------------------------

    def _update_diagnostics(self) -> None:
        now = self.get_clock().now().nanoseconds
        values: dict[str, Any] = {f'input_rate_hz.{m}': meter.read(now)
                                  for m, meter in self._rates.items()}
        values.update({f'received.{m}': n for m, n in self._received.items()})
        values.update({f'enabled.{m}': e for m, e in self._enabled().items()})
        values.update({f'rejected_{k}': v for k, v in self._rejected.items()})
        values.update({f'rejected_core_{k}': v for k, v in self._voter.rejected.items()})
        result = self._last_result
        enabled = [m for m, e in self._enabled().items() if e]
        if result is None:
            self._diagnostics.set(WARN, 'waiting for indications', values)
            return
        warned = [TIRE_NAMES[i] for i in np.flatnonzero(result.warning)]
        values.update({
            'fresh_methods': list(result.methods_used),
            'stale_methods': list(result.stale_methods),
            'active_warnings': warned,
            'confidence': result.confidence.tolist(),
            'evaluated_at_s': result.stamp_s,
        })
        for method in enabled:
            held = self._latest_stamp.get(method)
            values[f'age_s.{method}'] = result.stamp_s - held if held is not None else math.inf
        if not result.methods_used:
            level, message = ERROR, 'no fresh indication from any enabled method'
        elif warned:
            level, message = WARN, f'tire pressure warning: {", ".join(warned)}'
        elif result.stale_methods:
            level, message = WARN, f'stale methods: {", ".join(result.stale_methods)}'
        else:
            level, message = OK, 'ok'
        self._diagnostics.set(level, message, values)


def main(args: list[str] | None = None) -> None:
    """Entry point of the ``tpms_voter`` executable."""
    raise SystemExit(run_node(TpmsVoterNode, args))


if __name__ == '__main__':
    main()
