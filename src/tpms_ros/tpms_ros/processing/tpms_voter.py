"""The TPMS voter's logic, ROS-free: indication checks, voting in data time, warnings, status.

Wraps :class:`tpms_ros.core.tpms_voting.TpmsVoter` (Persson 2002, docs/methods/tpms_voter.md); the
node
(``tpms_ros.nodes.tpms_voter_node``) and the offline engine both run it.

Inputs: ``tpms/indication/<method>`` (TpmsIndication) for each name in ``methods``. Output:
``tpms/warning`` (TpmsWarning), one per accepted indication; the node adds the periodic one
between indications (:meth:`TpmsVoterProcessor.tick`, driven by its timer).

Time. The voter runs in *data time*, the stamps of the indications: an indication is voted at
its own stamp, so hold-off, set-off and staleness are measured on the data and a replay at any
speed decides the same. Between indications, :meth:`~TpmsVoterProcessor.tick` extrapolates data
time with the node clock (the newest stamp plus the clock time since it arrived), so a method
that falls silent ages out after ``max_age_s``. Each warning is stamped with the newest
indication the decision used (the evaluation time if none was fresh).

Time jumps (per method, :class:`vehicle_monitor_common.input_health.StampCheck`): a single
indication stamped more than ``jump_horizon_s`` ahead is dropped and counted, never adopted as
"now" (it would make every other method stale); a confirmed jump forward or back (a looped or
repeated replay, a clock reset) restarts the vote from the new time line: the held indications,
timers and warnings of the old one are dropped, the other methods' stamp checks follow, and the
status says so until every enabled method has been voted again.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass
import math
import re
from typing import Any

import numpy as np

from tpms_ros.core.tires import TIRE_NAMES, TpmsIndication
from tpms_ros.core.tpms_voting import (
    TpmsVoter,
    TpmsWarningResult,
    VoterParams,
    VotingRuleParams,
    method_votes_params,
)
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.parameters import ConfigurationError, build, flatten, param
from vehicle_monitor_common.processing import (
    ERROR,
    OK,
    WARN,
    Input,
    Output,
    ParameterGroup,
    ProcessorParams,
    ProcessorSpec,
    Status,
    header_stamp_ns,
)

WARNING = 'tpms/warning'
INDICATION_TYPE = 'vehicle_monitor_msgs/msg/TpmsIndication'

_METHOD_NAME = re.compile(r'^[a-z][a-z0-9_]*$')


def indication_topic(method: str) -> str:
    """The relative topic a method's indications arrive on."""
    return f'tpms/indication/{method}'


@dataclass(frozen=True)
class TpmsVoterNodeParams(ProcessorParams):
    """The node's own parameters (the rule's are :class:`VotingRuleParams`, each method's
    ``<method>.enabled`` and ``<method>.threshold`` a :class:`MethodVoteParams` group)."""

    methods: tuple[str, ...] = param(('stiffness', 'vibration', 'wheel_radius'),
                                     'methods voted: subscribes tpms/indication/<method>; each '
                                     'has <method>.enabled and <method>.threshold',
                                     read_only=True)
    publish_rate_hz: float = param(2.0, 'rate of the periodic tpms/warning between '
                                   'indications, Hz', low=0.01, high=100.0, read_only=True)
    silence_timeout_s: float = param(2.0, 'an indication topic silent this long after it '
                                     'flowed is an error on /diagnostics, s', low=0.01,
                                     high=3600.0, read_only=True)

    def __post_init__(self) -> None:
        if not self.methods:
            raise ValueError('methods must name at least one TPMS method')
        for name in self.methods:
            if not _METHOD_NAME.match(name):
                raise ValueError(f'methods: {name!r} is not a valid method name '
                                 '([a-z][a-z0-9_]*, it becomes a topic name)')
        if len(set(self.methods)) != len(self.methods):
            raise ValueError(f'methods: duplicate names in {list(self.methods)}')


def voter_params(rule: VotingRuleParams, votes: Any) -> VoterParams:
    """The core's parameters from the rule and the per-method groups."""
    return VoterParams(**flatten(rule), method_thresholds={
        m: vote.threshold for m, vote in vars(votes).items()}, method_support={
        m: vote.support for m, vote in vars(votes).items()})


class TpmsVoterProcessor:
    """What the TPMS voter does with the indications (see the module docstring).

    Args:
        rule: the voting rule's parameters.
        votes: the per-method groups (an instance of ``method_votes_params(methods)``).
        node_params: the methods, output rate, time checks.
        clock: the node clock (ns), to extrapolate data time between indications; offline
            there is none (no periodic output).
    """

    outputs = {WARNING: 'vehicle_monitor_msgs/msg/TpmsWarning'}

    def __init__(self, rule: VotingRuleParams, votes: Any, node_params: TpmsVoterNodeParams,
                 clock: Callable[[], int] | None = None) -> None:
        self.node_params = node_params
        methods = node_params.methods
        self.inputs = {indication_topic(m): Input(INDICATION_TYPE) for m in methods}
        self._method_of = {indication_topic(m): m for m in methods}
        try:
            self.voter = TpmsVoter(voter_params(rule, votes))
        except ValueError as exc:
            raise ConfigurationError(f'invalid parameters: {exc}') from None
        self._clock = clock or (lambda: 0)
        self.set_params(rule, votes)
        self._checks = {m: self._stamp_check() for m in methods}
        self.received = dict.fromkeys(methods, 0)
        self._rates = {m: RateMeter() for m in methods}
        self.rejected: Counter[str] = Counter(dict.fromkeys(
            ('invalid', 'method_mismatch', 'out_of_order', 'repeated', 'future_stamp'), 0))
        self._rejected_at_last_status: Counter[str] = Counter()
        # data-time anchor: newest indication stamp and the node-clock time it arrived
        self._anchor: tuple[float, int] | None = None
        self._last_eval_s = -math.inf
        self.last_result: TpmsWarningResult | None = None
        self._latest_stamp: dict[str, float] = {}
        self.time_jumps = 0
        self._last_jump_s = 0.0
        self._awaiting: set[str] = set()   # enabled methods not voted since the last jump

    def _stamp_check(self) -> StampCheck:
        return StampCheck(max_gap_s=math.inf, jump_horizon_s=self.node_params.jump_horizon_s)

    # -- parameters ----------------------------------------------------------------------------

    def set_params(self, rule: VotingRuleParams, votes: Any) -> None:
        """New rule or per-method values (the voter reads them at each evaluation; the method
        set is fixed)."""
        self._votes = votes
        self.voter.params = voter_params(rule, votes)
        for method, enabled in self.enabled().items():
            self.voter.set_enabled(method, enabled)

    def enabled(self) -> dict[str, bool]:
        """Method -> switched on."""
        return {m: getattr(self._votes, m).enabled for m in self.node_params.methods}

    # -- voting --------------------------------------------------------------------------------

    def process(self, topic: str, message: Any) -> list[Output]:
        """One indication; the warning it makes (none when it is rejected)."""
        method = self._method_of[topic]
        self.received[method] += 1
        self._rates[method].tick()
        if message.method != method:
            self.rejected['method_mismatch'] += 1
            return []
        stamp = header_stamp_ns(message)
        verdict = self._checks[method].check(stamp)
        if verdict in ('out_of_order', 'repeated', 'future_stamp'):
            self.rejected[verdict] += 1
            return []
        if verdict == 'jump':
            self._restart(method)
        try:
            indication = TpmsIndication(
                method=method, stamp_s=stamp * 1e-9,
                underinflated=np.asarray(message.underinflated, dtype=bool),
                confidence=np.asarray(message.confidence, dtype=float),
                known=np.asarray(message.known, dtype=bool))
        except ValueError:
            # NaN or out-of-range confidence, wrong sizes: the method counts as silent
            self.rejected['invalid'] += 1
            return []
        if not self.voter.submit(indication):
            return []
        self._latest_stamp[method] = indication.stamp_s
        self._awaiting.discard(method)
        now_ns = self._clock()
        if self._anchor is None or indication.stamp_s >= self._anchor[0]:
            self._anchor = (indication.stamp_s, now_ns)
        return [self._evaluate(max(indication.stamp_s, self._last_eval_s))]

    def _restart(self, method: str) -> None:
        """A confirmed time jump on ``method``'s stream: vote afresh from the new time line."""
        self.time_jumps += 1
        self._last_jump_s = self._checks[method].last_jump_s
        self.voter.reset()
        self._anchor = None
        self._last_eval_s = -math.inf
        self._latest_stamp.clear()
        # The other methods move with it: their next stamp starts their new time line.
        for other in self._checks:
            if other != method:
                self._checks[other] = self._stamp_check()
        self._awaiting = {m for m, on in self.enabled().items() if on}

    def tick(self, now_ns: int) -> list[Output]:
        """The periodic warning between indications, at data time extrapolated with the node
        clock (none before the first indication): the voter's preview, which leaves its
        timers alone, so the warnings answering the indications are the same however often
        and whenever the node's timer runs (live graph and offline engine alike)."""
        if self._anchor is None:
            return []       # no data time yet: nothing to decide on
        stamp_s, arrived_ns = self._anchor
        now_s = stamp_s + (now_ns - arrived_ns) * 1e-9
        # What the node last said, for its status; the vote itself is not moved.
        self.last_result = self.voter.preview(max(now_s, self._last_eval_s))
        return [self._output(self.last_result)]

    def clock_jumped(self, now_ns: int) -> None:
        """The node clock jumped (``/clock`` reset, a step): extrapolate from now on."""
        if self._anchor is not None:
            self._anchor = (self._anchor[0], now_ns)

    def _evaluate(self, now_s: float) -> Output:
        result = self.voter.evaluate(now_s)
        self._last_eval_s = now_s
        self.last_result = result
        return self._output(result)

    def _output(self, result: TpmsWarningResult) -> Output:
        """The warning message of a vote, stamped with the newest indication it used."""
        now_s = result.stamp_s
        used = [self._latest_stamp[m] for m in result.methods_used]
        stamp_s = max(used) if used else now_s
        return Output(WARNING, round(stamp_s * 1e9), {
            'warning': result.warning.tolist(),
            'active': result.active,
            'confidence': result.confidence.tolist(),
            'reasons': list(result.reasons),
            'methods': list(result.methods_used),
        })

    # -- status --------------------------------------------------------------------------------

    def status(self, now_ns: int) -> Status:
        """Health: which methods are fresh, active warnings, rejected input, time jumps."""
        enabled_map = self.enabled()
        values: dict[str, Any] = {f'input_rate_hz.{m}': meter.read(now_ns)
                                  for m, meter in self._rates.items()}
        values.update({f'received.{m}': n for m, n in self.received.items()})
        values.update({f'enabled.{m}': e for m, e in enabled_map.items()})
        values.update({f'rejected_{k}': v for k, v in self.rejected.items()})
        values.update({f'rejected_core_{k}': v for k, v in self.voter.rejected.items()})
        values['time_jumps'] = self.time_jumps
        # Rejections are a warning while recent (since the previous status); counts stay.
        recent = self.rejected - self._rejected_at_last_status
        self._rejected_at_last_status = Counter(self.rejected)
        notes = []
        if sum(recent.values()):
            notes.append('indications rejected: ' + ', '.join(
                f'{n} {reason}' for reason, n in sorted(recent.items()) if n))
        if self._awaiting:
            notes.append(f'time jump of {self._last_jump_s:+.3g} s: vote restarted, waiting '
                         f'for {", ".join(sorted(self._awaiting))}')
        result = self.last_result
        enabled = [m for m, e in enabled_map.items() if e]
        if result is None:
            return Status(WARN, '; '.join(['waiting for indications', *notes]), values)
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
        if not result.methods_used and not self._awaiting:
            level, message = ERROR, 'no fresh indication from any enabled method'
        elif warned:
            level, message = WARN, f'tire pressure warning: {", ".join(warned)}'
        elif result.stale_methods and not self._awaiting:
            level, message = WARN, f'stale methods: {", ".join(result.stale_methods)}'
        else:
            level, message = OK, 'ok'
        if notes:
            level = max(level, WARN)
            message = '; '.join(notes) if message == 'ok' else '; '.join([message, *notes])
        return Status(level, message, values)


def votes_params(values: Mapping[str, Any]) -> type[Any]:
    """The per-method group (``<method>.enabled``, ``<method>.threshold``) of the ``methods``
    among the values."""
    return method_votes_params(values['methods'])


def threshold_problem(values: Mapping[str, Any]) -> str:
    """Why the values are refused across the groups (every threshold above the rule's ``h0``:
    the core's check); '' when they are not."""
    try:
        voter_params(build(VotingRuleParams, values), build(votes_params(values), values))
    except (TypeError, ValueError) as exc:
        return str(exc)
    return ''


def make_processor(values: Mapping[str, Any], fqn: str,
                   clock: Callable[[], int] | None = None) -> TpmsVoterProcessor:
    """The processor from flat parameter values. Offline (the engine's way in) there is no
    clock, so one warning per accepted indication and no periodic one; the node passes its
    clock, with which the warning is also repeated between indications."""
    del fqn
    node_params = build(TpmsVoterNodeParams, values)
    rule = build(VotingRuleParams, values)
    votes = build(method_votes_params(node_params.methods), values)
    return TpmsVoterProcessor(rule, votes, node_params, clock=clock)


# The node, declared once: the live node (nodes/tpms_voter_node.py, which adds the clock and the
# periodic warning's timer) and the offline engine (make_processor) build it from this. The
# per-method group's fields depend on ``methods``, declared before it.
SPEC = ProcessorSpec(
    'tpms_voter', 'tpms/voter', factory=make_processor, cross_check=threshold_problem,
    groups=(ParameterGroup(TpmsVoterNodeParams),
            ParameterGroup(VotingRuleParams, 'set_params'),
            ParameterGroup(votes_params, 'set_params')))
