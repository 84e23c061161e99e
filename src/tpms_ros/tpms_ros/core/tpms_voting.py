"""Voting fusion of TPMS indications (Persson, Gustafsson, Drevö, SAE 2002;
docs/methods/tpms_voter.md).

Neither method estimates absolute pressure, so decisions are fused, not states. Each method
delivers per tire a flag t (this tire looks low) and a confidence c in 0..1. The paper's rule for
two methods, generalised here per tire and to any number of methods:

* a method counts for tire j only if it is enabled, its latest indication is fresh (age at most
  ``max_age_s``) and it knows tire j (an unknown tire is never counted as low);
* no counted method flags j -> no warning condition for j;
* every counted method flags j and there are at least two of them (agreement, t1 = t2) ->
  condition if the mean confidence exceeds h0;
* otherwise (disagreement, or a single method) -> condition if any flagging method's confidence
  exceeds its own h_i, with h_i > h0 so agreement warns on smaller losses;
* with ``agreement: any_two`` (the default), also where two or more methods flag j but a third
  counted one does not: condition if the flagging methods' mean confidence exceeds h0. For two
  methods this is the paper's rule; with three, each pair that flags is an agreement of the
  paper's kind, so one method that cannot see a loss does not veto the two that do (issue 21:
  the wheel radius method rarely flags a 15 % loss, and its silence kept the vibration and
  stiffness methods' agreement from warning; ``all`` is the rule generalised as every counted
  method flagging). Beyond the paper, a
  method may need support to warn alone (its ``support`` s_i > 0): another counted method
  must then show at least s_i for the tire (with no other method counted it warns alone as
  before). It answers a method that is confidently wrong on some cars while the others see
  nothing (issue 21: the vibration method on a driven axle, whose differential couples the
  two rims, warned healthy tires at confidence 1.00 with the wheel radius and stiffness
  methods below 0.6). Unsupported, its evidence cannot set a warning but still holds one it
  helped to set.

The condition is turned into a warning with hold-off and hysteresis: the warning is set once the
condition has held for ``set_on_s`` net (an up/down timer); it clears once the evidence has
stayed below the lower clear threshold (``clear_ratio`` x the threshold in force) for
``set_off_s`` net. A tire with
no counted method keeps its state and both timers pause: a silent method neither raises nor
cancels a warning.

No ROS import: ``tpms_voter`` converts ``TpmsIndication`` messages to :class:`TpmsIndication`.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields, make_dataclass, replace
import math
from typing import Any, Literal

import numpy as np

from tpms_ros.core.tires import N_TIRES, TIRE_NAMES, TpmsIndication
from vehicle_monitor_common.parameters import group, param
from vehicle_monitor_common.validation import require_positive


@dataclass(frozen=True)
class MethodVoteParams:
    """One method's part in the vote; a node declares it as ``<method>.enabled`` and
    ``<method>.threshold`` (see :func:`method_votes_params`)."""

    enabled: bool = param(True, "vote this method's indications")
    threshold: float = param(
        0.8, 'own threshold h_i of the method, used when the methods disagree or only it is '
        'fresh (> h0)', low=0.0, high=1.0)
    support: float = param(
        0.0, 'to warn alone (the counted methods disagree), another counted method must show '
        'at least this confidence for the tire (none counted: no support needed); 0: the '
        "paper's rule", low=0.0, high=1.0)


# The methods voted by default, in the order the voter iterates them.
DEFAULT_METHODS = ('vibration', 'wheel_radius', 'stiffness')
# The vibration method warns alone only with another method's confidence at least this
# (chosen on the car family's tuning cars, docs/methods/tpms_voter.md): on a driven axle it
# can be confidently wrong where the others see nothing. The others need no support: the
# stiffness method alone must warn of diffusion, which the wheel radius method cannot see.
DEFAULT_SUPPORT = {'vibration': 0.3}


def _method_vote_params(method: str) -> type[MethodVoteParams]:
    """:class:`MethodVoteParams` with the method's default support."""
    support = DEFAULT_SUPPORT.get(method, 0.0)
    if support == MethodVoteParams().support:
        return MethodVoteParams
    declared = next(f for f in fields(MethodVoteParams) if f.name == 'support')
    return make_dataclass(
        f'{method.title().replace("_", "")}VoteParams',
        [('support', float, param(support, declared.metadata['description'],
                                  low=declared.metadata['low'],
                                  high=declared.metadata['high']))],
        bases=(MethodVoteParams,), frozen=True)


def method_votes_params(methods: Sequence[str]) -> type[Any]:
    """A parameter class with one :class:`MethodVoteParams` group per method: the method set
    is configuration (the node's ``methods``), so the class is built for it."""
    groups = {m: _method_vote_params(m) for m in methods}
    return make_dataclass(
        'MethodVotesParams',
        [(m, cls, group(cls, f'the {m} method in the vote')) for m, cls in groups.items()],
        frozen=True)


@dataclass(frozen=True)
class VotingRuleParams:
    """The voting rule's thresholds and timing, each a ROS parameter of the same name."""

    h0: float = param(0.5, 'threshold on the mean confidence of the methods that agree (below '
                      'every <method>.threshold)', low=0.01, high=0.99)
    agreement: Literal['any_two', 'all'] = param(
        'any_two', "which flagging methods agree on a tire: 'any_two' (two or more flag it, "
        "whatever the others say; a 2-of-3 vote) or 'all' (every counted method flags it)",
        choices=('any_two', 'all'))
    max_age_s: float = param(2.0, 'an indication older than this (relative to the evaluation '
                             'time, data time) is stale and not voted, s', low=0.01, high=3600.0)
    # Net: the timer counts down while the condition does not hold.
    set_on_s: float = param(3.0, 'hold-off: the warning condition must hold this long (net) '
                            'before a warning, s', low=0.0, high=3600.0)
    set_off_s: float = param(10.0, 'the evidence must stay below the clear threshold this long '
                             '(net) to clear a warning, s', low=0.0, high=3600.0)
    # Lower than the set threshold so that a signal hovering there does not flicker.
    clear_ratio: float = param(0.7, 'clear threshold = clear_ratio x the threshold in force '
                               '(h0 or h_i), in (0, 1] (hysteresis)', low=0.01, high=1.0)

    def __post_init__(self) -> None:
        name = type(self).__name__
        if not 0.0 < self.h0 < 1.0:
            raise ValueError(f'{name}.h0 must be in (0, 1), got {self.h0}')
        require_positive(self, ('max_age_s', 'set_on_s', 'set_off_s'), allow_zero=True)
        if not self.max_age_s > 0.0:
            raise ValueError(f'{name}.max_age_s must be > 0, got {self.max_age_s}')
        if not 0.0 < self.clear_ratio <= 1.0:
            raise ValueError(f'{name}.clear_ratio must be in (0, 1], got {self.clear_ratio}')


@dataclass(frozen=True)
class VoterParams(VotingRuleParams):
    """The voting rule and the methods voted.

    Attributes:
        method_thresholds: method name -> its own threshold h_i (each > h0), used when the
            methods disagree or only one is available. Only these methods are voted.
        method_support: method name -> the confidence another counted method must show for
            it to warn alone (missing or 0: none needed).
    """

    method_thresholds: Mapping[str, float] = field(
        default_factory=lambda: dict.fromkeys(DEFAULT_METHODS, MethodVoteParams().threshold))
    method_support: Mapping[str, float] = field(
        default_factory=lambda: dict(DEFAULT_SUPPORT))

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.method_thresholds:
            raise ValueError('VoterParams.method_thresholds must name at least one method')
        for name, h in self.method_thresholds.items():
            if not (math.isfinite(h) and self.h0 < h < 1.0):
                raise ValueError(
                    f'VoterParams.method_thresholds[{name!r}] must be in (h0={self.h0}, 1), '
                    f'got {h}')
        object.__setattr__(self, 'method_thresholds', dict(self.method_thresholds))
        for name, support in self.method_support.items():
            if not (math.isfinite(support) and 0.0 <= support <= 1.0):
                raise ValueError(f'VoterParams.method_support[{name!r}] must be in [0, 1], '
                                 f'got {support}')
        object.__setattr__(self, 'method_support', dict(self.method_support))

    def only(self, methods: Iterable[str]) -> VoterParams:
        """The same parameters voting only ``methods`` (each with its own threshold): e.g. a
        method alone, as the paper's per-method time to warning."""
        methods = list(methods)
        return replace(self, method_thresholds={m: self.method_thresholds[m] for m in methods},
                       method_support={m: v for m, v in self.method_support.items()
                                       if m in methods})


@dataclass(frozen=True)
class TpmsWarningResult:
    """The voter's output (the content of ``/tpms/warning``).

    Attributes:
        stamp_s: evaluation time, s.
        warning: (4,) bool warning per tire after hold-off/hysteresis.
        active: any tire warned.
        confidence: (4,) the confidence tested for each tire (agreement: mean; otherwise the
            largest confidence of a flagging method; 0 when no method flags).
        condition: (4,) bool raw warning condition before hold-off.
        reasons: human-readable explanation of each flagged or warned tire and of every
            stale, rejected or disabled input.
        methods_used: methods whose fresh indication was voted.
        stale_methods: configured, enabled methods with no fresh indication.
    """

    stamp_s: float
    warning: np.ndarray
    active: bool
    confidence: np.ndarray
    condition: np.ndarray
    reasons: tuple[str, ...]
    methods_used: tuple[str, ...]
    stale_methods: tuple[str, ...]


class TpmsVoter:
    """Fuses TPMS indications by the paper's voting rule with hold-off and hysteresis.

    Feed indications with :meth:`submit` as they arrive, call :meth:`evaluate` at the output
    rate. Streaming input is never allowed to raise: an indication from an unconfigured method,
    or older than the one held for its method, is rejected and counted in :attr:`rejected`.
    """

    def __init__(self, params: VoterParams | None = None) -> None:
        self.params = params if params is not None else VoterParams()
        self._latest: dict[str, TpmsIndication] = {}
        self._enabled = dict.fromkeys(self.params.method_thresholds, True)
        # Per tire, as Python lists: the vote works on a few methods x 4 tires, where numpy's
        # per-call overhead cost ten times the arithmetic.
        self._warning = [False] * N_TIRES
        self._on_time = [0.0] * N_TIRES     # how long the set condition has held, s
        self._off_time = [0.0] * N_TIRES    # how long the evidence has stayed below clear, s
        self._last_eval_s: float | None = None
        self._last_result: TpmsWarningResult | None = None
        self.rejected: dict[str, int] = {'unknown_method': 0, 'out_of_order': 0,
                                         'time_backwards': 0}

    def set_enabled(self, method: str, enabled: bool) -> None:
        """Switch a configured method on or off (off: its indications are ignored)."""
        if method not in self._enabled:
            raise ValueError(f'method {method!r} is not configured in method_thresholds')
        self._enabled[method] = enabled

    def submit(self, indication: TpmsIndication) -> bool:
        """Store the latest indication of its method. Returns False if it was rejected."""
        if indication.method not in self._enabled:
            self.rejected['unknown_method'] += 1
            return False
        held = self._latest.get(indication.method)
        if held is not None and indication.stamp_s < held.stamp_s:
            self.rejected['out_of_order'] += 1
            return False
        self._latest[indication.method] = indication
        return True

    def reset(self) -> None:
        """Forget indications, warnings and timers (e.g. after the driver re-calibrates)."""
        self._latest.clear()
        self._warning = [False] * N_TIRES
        self._on_time = [0.0] * N_TIRES
        self._off_time = [0.0] * N_TIRES
        self._last_eval_s = None
        self._last_result = None

    def evaluate(self, now_s: float, indications: Iterable[TpmsIndication] = ()) -> \
            TpmsWarningResult:
        """Submit ``indications`` (if any) and vote at time ``now_s``.

        A ``now_s`` earlier than the previous evaluation is rejected (counted) and the previous
        result is returned unchanged.
        """
        for indication in indications:
            self.submit(indication)
        if not math.isfinite(now_s):
            raise ValueError(f'now_s must be finite, got {now_s}')
        if self._last_eval_s is not None and now_s < self._last_eval_s:
            self.rejected['time_backwards'] += 1
            assert self._last_result is not None
            return self._last_result
        return self._vote(now_s)

    def preview(self, now_s: float) -> TpmsWarningResult:
        """What :meth:`evaluate` at ``now_s`` would say, with the voter left as it was: the
        periodic output between indications (a node's timer), so that how often it runs
        cannot change the warnings the indications themselves give. A ``now_s`` before the
        last evaluation gives the last result."""
        if not math.isfinite(now_s):
            raise ValueError(f'now_s must be finite, got {now_s}')
        if self._last_eval_s is not None and now_s < self._last_eval_s:
            assert self._last_result is not None
            return self._last_result
        held = (self._warning.copy(), self._on_time.copy(), self._off_time.copy(),
                self._last_eval_s, self._last_result)
        try:
            return self._vote(now_s)
        finally:
            (self._warning, self._on_time, self._off_time, self._last_eval_s,
             self._last_result) = held

    def _supported(self, used: list[str], counted: list[list[bool]],
                   conf: list[list[float]]) -> list[list[bool]]:
        """[method][tire]: where each used method may warn alone: it needs no support, no other
        method is counted for the tire, or another counted one shows at least its support."""
        supported = []
        for i, method in enumerate(used):
            needed = self.params.method_support.get(method, 0.0)
            if not needed > 0.0:
                supported.append([True] * N_TIRES)
                continue
            others = [k for k in range(len(used)) if k != i]
            row = []
            for j in range(N_TIRES):
                shown = [conf[k][j] for k in others if counted[k][j]]
                row.append(not shown or max(shown) >= needed)
            supported.append(row)
        return supported

    def _vote(self, now_s: float) -> TpmsWarningResult:
        """The vote at ``now_s`` (not before the last one): timers advanced, result kept."""
        dt = 0.0 if self._last_eval_s is None else now_s - self._last_eval_s
        self._last_eval_s = now_s

        p = self.params
        reasons: list[str] = []
        used: list[str] = []
        stale: list[str] = []
        for method, enabled in self._enabled.items():
            if not enabled:
                reasons.append(f'{method}: disabled')
                continue
            ind = self._latest.get(method)
            if ind is None:
                stale.append(method)
                reasons.append(f'{method}: no indication received')
            elif now_s - ind.stamp_s > p.max_age_s:
                stale.append(method)
                reasons.append(f'{method}: stale ({now_s - ind.stamp_s:.1f} s old > '
                               f'{p.max_age_s:.1f} s), ignored')
            else:
                used.append(method)
        if any(self.rejected.values()):
            reasons.append('rejected inputs: ' + ', '.join(
                f'{k}={v}' for k, v in self.rejected.items() if v))

        # [method][tire] of the fresh, enabled indications
        latest = [self._latest[m] for m in used]
        conf = [ind.confidence.tolist() for ind in latest]
        counted = [ind.known.tolist() for ind in latest]
        flagging = [[c and f for c, f in zip(known, ind.underinflated.tolist(), strict=True)]
                    for known, ind in zip(counted, latest, strict=True)]
        h_own = [p.method_thresholds[m] for m in used]
        supported = self._supported(used, counted, conf)

        # Per tire, over the methods in order. Sums and maxima are bit for bit numpy's over
        # (methods, 4) arrays: the sum starts at 0.0 and adds a 0.0 for an uncounted method, a
        # tie in the maximum takes the later method (only the sign of a zero can tell).
        n_flagging = [0] * N_TIRES
        informed = [False] * N_TIRES
        agree = [False] * N_TIRES
        partial = [False] * N_TIRES      # 'any_two': two or more flag, a counted one does not
        mean_conf = [0.0] * N_TIRES
        flagging_mean = [0.0] * N_TIRES
        partial_leads = [False] * N_TIRES   # the partial agreement, not one method, is strongest
        confidence = [0.0] * N_TIRES
        condition = [False] * N_TIRES
        strongest = [0] * N_TIRES    # the first method of the largest margin: the reasons name it
        for j in range(N_TIRES):
            n_counted = 0
            conf_sum = flag_conf_sum = 0.0
            max_flag_conf = best_margin = best_set = 0.0
            for i in range(len(used)):
                n_counted += counted[i][j]
                n_flagging[j] += flagging[i][j]
                conf_sum += conf[i][j] if counted[i][j] else 0.0
                # disagreement: each flagging method against its own threshold; the margin c/h
                # tells which method is strongest relative to its threshold (the one the reasons
                # name)
                flag_conf = conf[i][j] if flagging[i][j] else 0.0
                flag_conf_sum += flag_conf
                margin = conf[i][j] / h_own[i] if flagging[i][j] else 0.0
                # a method needing support sets a warning only with it; its evidence holds one
                # anyway
                margin_set = margin if supported[i][j] else 0.0
                if i == 0 or flag_conf >= max_flag_conf:
                    max_flag_conf = flag_conf
                if i == 0 or margin > best_margin:
                    strongest[j] = i
                if i == 0 or margin >= best_margin:
                    best_margin = margin
                if i == 0 or margin_set >= best_set:
                    best_set = margin_set
            informed[j] = n_counted > 0
            agree[j] = n_flagging[j] == n_counted and n_counted >= 2
            partial[j] = p.agreement == 'any_two' and not agree[j] and n_flagging[j] >= 2
            mean_conf[j] = conf_sum / max(n_counted, 1)
            flagging_mean[j] = flag_conf_sum / max(n_flagging[j], 1)
            if agree[j]:
                confidence[j] = mean_conf[j]
            elif n_flagging[j] > 0:
                confidence[j] = max_flag_conf
            # evidence relative to the threshold in force: > 1 sets, < clear_ratio clears. A
            # partial agreement adds its own (the flagging methods' mean against h0) to each
            # flagging method's against its h_i.
            ratio = mean_conf[j] / p.h0 if agree[j] else best_margin
            partial_ratio = flagging_mean[j] / p.h0 if partial[j] else 0.0
            partial_leads[j] = partial[j] and partial_ratio >= best_margin
            condition[j] = n_flagging[j] > 0 and (
                ratio > 1.0 if agree[j] else best_set > 1.0 or partial_ratio > 1.0)
            below_clear = n_flagging[j] == 0 or (
                ratio < p.clear_ratio and partial_ratio < p.clear_ratio)

            # hold-off and hysteresis as up/down timers: they count up while their condition
            # holds and down (not to zero) otherwise, so a noisy confidence that is mostly above
            # the threshold still warns, and one dropping out for a sample does not restart the
            # wait. A tire with no information keeps state and timers.
            if informed[j]:
                on_time = self._on_time[j] + (dt if condition[j] else -dt)
                self._on_time[j] = on_time if on_time > 0.0 else 0.0
                off_time = self._off_time[j] + (dt if below_clear else -dt)
                self._off_time[j] = off_time if off_time > 0.0 else 0.0
            warned = self._warning[j]
            set_now = not warned and condition[j] and self._on_time[j] >= p.set_on_s
            clear_now = warned and below_clear and self._off_time[j] >= p.set_off_s
            self._warning[j] = (warned or set_now) and not clear_now
            if self._warning[j]:
                self._on_time[j] = 0.0
            else:
                self._off_time[j] = 0.0

        for j in range(N_TIRES):
            tire = TIRE_NAMES[j]
            if not informed[j]:
                if self._warning[j]:
                    reasons.append(f'{tire}: warning held, no method has fresh information')
                continue
            if n_flagging[j] == 0:
                if self._warning[j]:
                    reasons.append(f'{tire}: warning held, clearing in '
                                   f'{max(p.set_off_s - self._off_time[j], 0.0):.1f} s')
                continue
            names = [m for i, m in enumerate(used) if flagging[i][j]]
            if agree[j]:
                rule = (f'{tire}: {" + ".join(names)} agree, mean confidence '
                        f'{mean_conf[j]:.2f} vs h0 {p.h0:.2f}')
            elif partial_leads[j]:
                silent = [m for i, m in enumerate(used) if counted[i][j] and not flagging[i][j]]
                rule = (f'{tire}: {" + ".join(names)} agree, {", ".join(silent)} not, mean '
                        f'confidence {flagging_mean[j]:.2f} vs h0 {p.h0:.2f}')
            else:
                i = strongest[j]
                m = used[i]
                rule = (f'{tire}: flagged by {", ".join(names)} only, {m} confidence '
                        f'{conf[i][j]:.2f} vs own h {p.method_thresholds[m]:.2f}')
                if not supported[i][j]:
                    rule += (f', without support (another method at least '
                             f'{p.method_support[m]:.2f} needed)')
            state = 'WARNING' if self._warning[j] else (
                f'condition held {self._on_time[j]:.1f}/{p.set_on_s:.1f} s' if condition[j]
                else 'below threshold')
            reasons.append(f'{rule} -> {state}')

        result = TpmsWarningResult(
            stamp_s=now_s,
            warning=np.array(self._warning),
            active=any(self._warning),
            confidence=np.array(confidence),
            condition=np.array(condition),
            reasons=tuple(reasons),
            methods_used=tuple(used),
            stale_methods=tuple(stale),
        )
        self._last_result = result
        return result
