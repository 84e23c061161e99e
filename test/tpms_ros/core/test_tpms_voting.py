"""Tests of the TPMS voting fusion core (tpms_ros.core.tpms_voting)."""

from __future__ import annotations

import numpy as np
import pytest

from tpms_ros.core.tires import TpmsIndication
from tpms_ros.core.tpms_voting import TpmsVoter, VoterParams, method_votes_params
from vehicle_monitor_common.parameters import parameter_specs

H0, H_VIB, H_RAD = 0.5, 0.8, 0.7


def make_voter(**kw: float) -> TpmsVoter:
    """Voter with two methods by the paper's rule (no method needs support), no hold-off
    unless asked."""
    params = dict(h0=H0, method_thresholds={'vibration': H_VIB, 'wheel_radius': H_RAD},
                  method_support={}, max_age_s=2.0, set_on_s=0.0, set_off_s=0.0,
                  clear_ratio=0.7)
    params.update(kw)
    return TpmsVoter(VoterParams(**params))  # type: ignore[arg-type]


def ind(method: str, stamp: float, flags: list[int], conf: list[float],
        known: list[int] | None = None) -> TpmsIndication:
    """Shorthand for an indication."""
    return TpmsIndication(method, stamp, np.array(flags, bool), np.array(conf),
                          np.ones(4, bool) if known is None else np.array(known, bool))


# (vibration flag, conf), (radius flag, conf) on FL -> expected warning on FL
TRUTH_TABLE = [
    ((1, 0.6), (1, 0.6), True),     # agree, mean 0.6 > h0
    ((1, 0.45), (1, 0.52), False),  # agree, mean 0.485 < h0
    ((1, 0.3), (1, 0.9), True),     # agree, mean 0.6 > h0 though vibration alone is weak
    ((1, 0.75), (0, 0.0), False),   # disagree: vibration 0.75 < its h 0.8
    ((1, 0.85), (0, 0.0), True),    # disagree: vibration 0.85 > 0.8
    ((0, 0.0), (1, 0.75), True),    # disagree: radius 0.75 > its h 0.7
    ((0, 0.0), (1, 0.65), False),   # disagree: radius 0.65 < 0.7
    ((0, 0.95), (0, 0.95), False),  # no flag -> no warning, whatever the confidence
]


@pytest.mark.parametrize(('vib', 'rad', 'expected'), TRUTH_TABLE)
def test_truth_table_of_the_paper_rule(vib: tuple[int, float], rad: tuple[int, float],
                                       expected: bool) -> None:
    """Agreement tests the mean against h0, disagreement each against its own h_i."""
    voter = make_voter()
    result = voter.evaluate(10.0, [
        ind('vibration', 10.0, [vib[0], 0, 0, 0], [vib[1], 0, 0, 0]),
        ind('wheel_radius', 10.0, [rad[0], 0, 0, 0], [rad[1], 0, 0, 0]),
    ])
    assert bool(result.warning[0]) is expected
    assert not result.warning[1:].any()
    assert result.active is expected
    assert set(result.methods_used) == {'vibration', 'wheel_radius'}


# (vibration, radius, stiffness) as (flag, conf) on FL, the agreement rule -> warning on FL
THREE_METHODS = [
    ((1, 0.55), (0, 0.3), (1, 0.75), 'any_two', True),   # two agree, mean 0.65 > h0
    ((1, 0.55), (0, 0.3), (1, 0.75), 'all', False),      # the radius method vetoes
    ((1, 0.45), (0, 0.3), (1, 0.52), 'any_two', False),  # two agree, mean 0.485 < h0
    ((1, 0.55), (0, 0.0), (0, 0.4), 'any_two', False),   # one flags, below its own h_i
    ((0, 0.1), (0, 0.3), (1, 0.85), 'any_two', True),    # one flags, above its own h_i
    ((1, 0.6), (1, 0.2), (1, 0.2), 'any_two', False),    # all three: their mean 0.33 < h0
]


@pytest.mark.parametrize(('vib', 'rad', 'stiff', 'agreement', 'expected'), THREE_METHODS)
def test_two_of_three_methods_agree(vib: tuple[int, float], rad: tuple[int, float],
                                    stiff: tuple[int, float], agreement: str,
                                    expected: bool) -> None:
    """With three methods, two that flag a tire agree whatever the third says ('any_two'): the
    mean of their confidences against h0; 'all' needs every counted method to flag it."""
    voter = make_voter(method_thresholds={'vibration': H_VIB, 'wheel_radius': H_RAD,
                                          'stiffness': H_VIB}, agreement=agreement)
    result = voter.evaluate(1.0, [
        ind(m, 1.0, [v[0], 0, 0, 0], [v[1], 0, 0, 0])
        for m, v in (('vibration', vib), ('wheel_radius', rad), ('stiffness', stiff))])
    assert bool(result.warning[0]) is expected
    assert not result.warning[1:].any()
    # the reasons name what decides: the pair's mean, or a method above its own h_i
    pair = any('vibration + stiffness agree, wheel_radius not' in r for r in result.reasons)
    if agreement == 'all' or stiff[1] > H_VIB:
        assert not pair
    elif expected:
        assert pair


def test_two_of_three_agreement_clears_below_both_thresholds() -> None:
    """The warning set by two agreeing methods is held while their mean stays above the clear
    threshold (clear_ratio x h0) and clears once it and each method's own evidence are below."""
    voter = make_voter(method_thresholds={'vibration': H_VIB, 'wheel_radius': H_RAD,
                                          'stiffness': H_VIB}, set_off_s=1.0)

    def vote(t: float, vib: float, stiff: float) -> bool:
        return bool(voter.evaluate(t, [
            ind('vibration', t, [1, 0, 0, 0], [vib, 0, 0, 0]),
            ind('wheel_radius', t, [0] * 4, [0.2, 0, 0, 0]),
            ind('stiffness', t, [1, 0, 0, 0], [stiff, 0, 0, 0])]).warning[0])

    assert vote(1.0, 0.6, 0.7)
    assert vote(2.0, 0.4, 0.4) and vote(3.5, 0.4, 0.4)   # mean 0.4 > clear 0.35: held
    assert vote(4.0, 0.3, 0.3)                            # below: the clear timer starts
    assert not vote(5.5, 0.3, 0.3)


@pytest.mark.parametrize(('radius', 'expected'), [
    ((0, 0.1, 1), False),   # counted and confidently not low: no support
    ((0, 0.29, 1), False),  # just below the support
    ((0, 0.35, 1), True),   # some evidence, though it does not flag the tire
    ((0, 0.0, 0), True),    # the tire unknown to the other method: vibration decides alone
])
def test_a_method_needing_support_warns_alone_only_with_it(
        radius: tuple[int, float, int], expected: bool) -> None:
    """Vibration at 0.95 (> its h 0.8) against the wheel radius method's view of the tire,
    with vibration's support 0.3."""
    voter = make_voter(method_support={'vibration': 0.3})
    flag, conf, known = radius
    result = voter.evaluate(1.0, [
        ind('vibration', 1.0, [1, 0, 0, 0], [0.95, 0, 0, 0]),
        ind('wheel_radius', 1.0, [flag, 0, 0, 0], [conf, 0, 0, 0], [known, 1, 1, 1])])
    assert bool(result.warning[0]) is expected
    assert result.confidence[0] == pytest.approx(0.95)
    assert any('without support' in r for r in result.reasons) is not expected


def test_only_the_vibration_method_needs_support_by_default() -> None:
    """The node's per-method parameters and the core's defaults say the same."""
    specs = {p.name: p.default for p in parameter_specs(
        method_votes_params(['stiffness', 'vibration', 'wheel_radius']))}
    assert specs['vibration.support'] == 0.3
    assert specs['stiffness.support'] == specs['wheel_radius.support'] == 0.0
    assert VoterParams().method_support == {'vibration': 0.3}
    assert VoterParams().only(['stiffness']).method_support == {}


def test_support_sets_a_warning_it_need_not_hold() -> None:
    """Once set with support, the warning is held by the method's own evidence when the
    support goes (no flickering as the other method's confidence wanders), and the method
    needing no support (radius) still warns alone."""
    voter = make_voter(method_support={'vibration': 0.3}, set_off_s=1.0)
    vib = [1, 0, 0, 0], [0.95, 0, 0, 0]
    assert voter.evaluate(1.0, [ind('vibration', 1.0, *vib),
                                ind('wheel_radius', 1.0, [0] * 4, [0.4, 0, 0, 0])]).warning[0]
    for t in (2.0, 3.0, 4.0, 5.0):
        held = voter.evaluate(t, [ind('vibration', t, *vib),
                                  ind('wheel_radius', t, [0] * 4, [0.05, 0, 0, 0])])
        assert held.warning[0]
    alone = voter.evaluate(6.0, [ind('vibration', 6.0, [0] * 4, [0.0] * 4),
                                 ind('wheel_radius', 6.0, [0, 1, 0, 0], [0, 0.75, 0, 0])])
    assert alone.warning[1]


def test_agreement_warns_on_smaller_losses_than_either_alone() -> None:
    """With h_i > h0, two agreeing moderate confidences warn where one alone does not."""
    voter = make_voter()
    single = voter.evaluate(1.0, [ind('vibration', 1.0, [0, 1, 0, 0], [0, 0.6, 0, 0])])
    assert not single.warning[1]
    both = voter.evaluate(1.5, [ind('wheel_radius', 1.5, [0, 1, 0, 0], [0, 0.6, 0, 0])])
    assert both.warning[1] and both.confidence[1] == pytest.approx(0.6)
    assert any('agree' in r for r in both.reasons)


def test_unknown_tire_is_not_counted() -> None:
    """A tire unknown to a method is neither low nor a vote against: the other decides alone."""
    voter = make_voter()
    result = voter.evaluate(1.0, [
        ind('vibration', 1.0, [0, 0, 1, 0], [0, 0, 0.6, 0], known=[1, 1, 1, 1]),
        # radius says "low" with conf 0.9 on RL but does not know it: ignored
        ind('wheel_radius', 1.0, [0, 0, 1, 0], [0, 0, 0.9, 0], known=[1, 1, 0, 1]),
    ])
    # only vibration counts on RL: 0.6 < its own h 0.8
    assert not result.warning[2]
    result = voter.evaluate(2.0, [
        ind('vibration', 2.0, [0, 0, 0, 0], [0, 0, 0, 0], known=[1, 1, 0, 1]),
        ind('wheel_radius', 2.0, [0, 0, 0, 0], [0, 0, 0, 0], known=[1, 1, 0, 1]),
    ])
    assert not result.warning.any()


def test_hysteresis_no_flicker_and_clears() -> None:
    """A confidence hovering at the threshold never flickers; mostly above it warns; it clears
    set_off_s after the evidence is gone."""
    voter = make_voter(set_on_s=3.0, set_off_s=5.0)
    rng = np.random.default_rng(7)
    warnings = []
    t = 0.0
    for mean in (H_VIB, H_VIB + 0.04):       # 60 s at the threshold, 60 s just above, 10 Hz
        for _ in range(600):
            t += 0.1
            c = float(np.clip(mean + 0.05 * rng.standard_normal(), 0, 1))
            warnings.append(voter.evaluate(t, [ind('vibration', t, [1, 0, 0, 0],
                                                     [c, 0, 0, 0])]).warning[0])
    toggles = int(np.count_nonzero(np.diff(np.array(warnings, int))))
    assert toggles <= 1
    assert warnings[-1]
    t_end = t
    cleared_at = None
    for _ in range(100):
        t += 0.1
        r = voter.evaluate(t, [ind('vibration', t, [0, 0, 0, 0], [0.1, 0, 0, 0])])
        if not r.warning[0] and cleared_at is None:
            cleared_at = t
    assert cleared_at is not None
    assert 4.9 <= cleared_at - t_end <= 5.2


def test_hold_off_needs_the_condition_net() -> None:
    """A condition present less than half the time never accumulates set_on_s."""
    voter = make_voter(set_on_s=2.0)
    t = 0.0
    for k in range(300):                     # on 0.9 s, off 1.1 s, repeatedly
        t += 0.1
        on = (k % 20) < 9
        r = voter.evaluate(t, [ind('vibration', t, [int(on), 0, 0, 0], [0.9 * on, 0, 0, 0])])
        assert not r.warning[0]


def test_stale_input_ignored_and_reported() -> None:
    """An indication older than max_age_s does not vote and is named in the result."""
    voter = make_voter()
    voter.submit(ind('wheel_radius', 0.0, [1, 0, 0, 0], [0.95, 0, 0, 0]))
    fresh = voter.evaluate(1.0)
    assert fresh.warning[0] and fresh.methods_used == ('wheel_radius',)
    voter2 = make_voter()
    voter2.submit(ind('wheel_radius', 0.0, [1, 0, 0, 0], [0.95, 0, 0, 0]))
    stale = voter2.evaluate(5.0)
    assert not stale.warning.any()
    assert 'wheel_radius' in stale.stale_methods and 'vibration' in stale.stale_methods
    assert any('stale' in r for r in stale.reasons)


def test_silent_methods_hold_state_not_latch() -> None:
    """With every method stale the warning is held; fresh evidence of no loss clears it."""
    voter = make_voter(set_off_s=3.0)
    assert voter.evaluate(1.0, [ind('vibration', 1.0, [1, 0, 0, 0], [0.9, 0, 0, 0])]).warning[0]
    held = voter.evaluate(20.0)
    assert held.warning[0] and any('held' in r for r in held.reasons)
    for t in np.arange(21.0, 25.0, 0.5):
        r = voter.evaluate(float(t), [ind('vibration', float(t), [0] * 4, [0.0] * 4)])
    assert not r.warning[0]


def test_disabled_method_and_rejections() -> None:
    """A disabled method is ignored; unknown methods, old stamps and time reversal are counted."""
    voter = make_voter()
    voter.set_enabled('vibration', False)
    r = voter.evaluate(1.0, [ind('vibration', 1.0, [1, 0, 0, 0], [1.0, 0, 0, 0])])
    assert not r.warning.any() and any('disabled' in s for s in r.reasons)
    assert not voter.submit(ind('magic', 1.0, [1, 0, 0, 0], [1.0, 0, 0, 0]))
    assert voter.submit(ind('wheel_radius', 2.0, [0] * 4, [0.0] * 4))
    assert not voter.submit(ind('wheel_radius', 1.5, [1] * 4, [1.0] * 4))
    previous = voter.evaluate(3.0)
    assert voter.evaluate(2.5) is previous
    assert voter.rejected == {'unknown_method': 1, 'out_of_order': 1, 'time_backwards': 1}
    with pytest.raises(ValueError, match='not configured'):
        voter.set_enabled('magic', True)


@pytest.mark.parametrize(('kwargs', 'match'), [
    ({'h0': 0.5, 'method_thresholds': {'vibration': 0.4}}, r'method_thresholds\[.vibration.\]'),
    ({'h0': 1.2}, 'h0'),
    ({'clear_ratio': 0.0}, 'clear_ratio'),
    ({'max_age_s': 0.0}, 'max_age_s'),
    ({'set_on_s': float('nan')}, 'set_on_s'),
])
def test_params_validation(kwargs: dict, match: str) -> None:
    """Thresholds h_i must exceed h0; ratios and times must be sane."""
    with pytest.raises(ValueError, match=match):
        VoterParams(**kwargs)


def test_indication_validation() -> None:
    """Wrong shapes and confidences outside 0..1 are refused."""
    with pytest.raises(ValueError, match='confidence'):
        ind('vibration', 0.0, [0] * 4, [0, 0, 1.2, 0])
    with pytest.raises(ValueError, match='underinflated'):
        ind('vibration', 0.0, [0] * 3, [0.0] * 4)
