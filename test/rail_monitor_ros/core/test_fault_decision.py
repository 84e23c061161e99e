"""The suspension IMM's fault decision: confirmation, hysteresis on the declaration, near-nominal
ratios, compound only after a declared spring fault."""

from __future__ import annotations

import numpy as np
import pytest

from rail_monitor_ros.core.fault_decision import FaultDecision

NORMAL, SPRING_150, SPRING_110 = (1.0, 1.0), (1.5, 1.0), (1.1, 1.0)
DAMPER_50, COMPOUND_120_50, COMPOUND_150_50 = (1.0, 0.5), (1.2, 0.5), (1.5, 0.5)


def _run(decision: FaultDecision, keys: list[tuple[float, float]], probabilities: list[float],
         samples: int) -> list[str]:
    row = np.array(probabilities)
    return [decision.update(keys, row).component for _ in range(samples)]


def test_declared_after_the_hold_time_and_cleared_after_the_clear_time() -> None:
    """Declared once held above threshold for hold_time_s; cleared once normal held it for
    clear_time_s (longer: the declaration has hysteresis)."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01, clear_time_s=0.1)
    keys = [NORMAL, SPRING_150]
    assert _run(decision, keys, [0.2, 0.8], 7) == [''] * 5 + ['spring'] * 2
    assert _run(decision, keys, [0.8, 0.2], 12) == ['spring'] * 10 + [''] * 2


def test_a_flickering_fault_is_declared_and_a_short_excursion_is_not() -> None:
    """The hold is counted net of dips (up-down): a damper fault whose probability is above
    the threshold 3 samples in 4 is declared after about twice the hold time (a count that
    restarted at every dip never would); excursions of 4 samples with 6 between them never
    add up to the hold of 5."""
    keys = [NORMAL, DAMPER_50]
    flicker = [[0.2, 0.8]] * 3 + [[0.5, 0.5]]
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    components = [decision.update(keys, np.array(p)).component for p in flicker * 4]
    assert components.index('damper') == 9             # the count reaches 6 at sample 10
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    excursions = [[0.2, 0.8]] * 4 + [[0.9, 0.1]] * 6
    assert {decision.update(keys, np.array(p)).component for p in excursions * 20} == {''}


def test_a_declared_fault_holds_through_a_probability_dip() -> None:
    """The declared component drops below the threshold (probability spread over modes, or
    normal ahead) for longer than the hold time: still declared; only confirmed normal clears
    it. The size follows the component's most probable hypothesis."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01, clear_time_s=0.5)
    keys = [NORMAL, SPRING_150, (1.4, 1.0)]
    assert _run(decision, keys, [0.1, 0.9, 0.0], 10)[-1] == 'spring'
    # Nobody above threshold for 1 s, normal briefly ahead for 0.3 s (< clear time).
    assert set(_run(decision, keys, [0.45, 0.3, 0.25], 100)) == {'spring'}
    assert set(_run(decision, keys, [0.7, 0.3, 0.0], 30)) == {'spring'}
    status = decision.update(keys, np.array([0.45, 0.3, 0.25]))
    assert (status.spring_ratio, status.probability) == (1.5, pytest.approx(0.55))
    status = decision.update(keys, np.array([0.1, 0.2, 0.7]))
    assert (status.component, status.spring_ratio) == ('spring', 1.4)


def test_a_fault_between_grid_points_is_declared_by_its_component() -> None:
    """Damper 66 %: its probability split over the 70 % and 80 % modes, neither above the
    threshold, the damper component is: declared, sized at the larger."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    keys = [NORMAL, (1.0, 0.7), (1.0, 0.8)]
    components = _run(decision, keys, [0.2, 0.45, 0.35], 7)
    assert components == [''] * 5 + ['damper'] * 2
    assert decision.update(keys, np.array([0.2, 0.45, 0.35])).damper_ratio == 0.7


def test_near_nominal_ratios_count_as_normal() -> None:
    """With min_deviation 0.15 spring 110 % is normal for the decision, 150 % is not."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01, min_deviation=0.15)
    keys = [NORMAL, SPRING_110, SPRING_150]
    assert set(_run(decision, keys, [0.1, 0.9, 0.0], 50)) == {''}
    assert _run(decision, keys, [0.1, 0.2, 0.7], 7)[-1] == 'spring'
    plain = FaultDecision(0.6, 0.05, 0.01)
    assert _run(plain, keys, [0.1, 0.9, 0.0], 7)[-1] == 'spring'


def test_a_compound_hypothesis_without_a_declared_spring_fault_is_a_damper_fault() -> None:
    """Damper modes that drifted to spring 120 % (the adaptive step after a damper fault) are
    declared 'damper' at their damper ratio, not 'spring+damper'."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    keys = [NORMAL, DAMPER_50, COMPOUND_120_50]
    components = _run(decision, keys, [0.1, 0.3, 0.6], 50)
    assert set(components[5:]) == {'damper'}
    status = decision.update(keys, np.array([0.1, 0.3, 0.6]))
    assert (status.spring_ratio, status.damper_ratio) == (1.0, 0.5)
    assert status.probability == pytest.approx(0.9)


def test_compound_after_a_declared_spring_fault() -> None:
    """Spring 150 % declared first, then damper 50 % on top: 'spring+damper' (the shipped
    rail_imm_spring_damper_fault sequence)."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    keys = [NORMAL, SPRING_150, COMPOUND_150_50]
    assert _run(decision, keys, [0.1, 0.9, 0.0], 7)[-1] == 'spring'
    assert _run(decision, keys, [0.1, 0.1, 0.8], 7)[-1] == 'spring+damper'


def test_a_declared_compound_stands_when_the_bank_holds_no_compound() -> None:
    """'spring+damper' declared, then the adaptive step moves the damper modes' spring back near
    nominal, so no hypothesis is a compound any more (the main job's compound bag crashed here
    with the 0.05 s smoothing): the declaration and its last size stand; confirmed normal
    still clears it."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01, clear_time_s=0.1,
                             min_deviation=0.15)
    keys = [NORMAL, SPRING_150, COMPOUND_150_50]
    _run(decision, keys, [0.1, 0.9, 0.0], 7)
    assert _run(decision, keys, [0.1, 0.1, 0.8], 7)[-1] == 'spring+damper'
    moved = [NORMAL, SPRING_150, (1.1, 0.5)]
    status = decision.update(moved, np.array([0.1, 0.1, 0.8]))
    assert (status.component, status.spring_ratio, status.damper_ratio) == (
        'spring+damper', 1.5, 0.5)
    assert status.probability == 0.0
    assert _run(decision, moved, [0.9, 0.05, 0.05], 12)[-1] == ''


def test_state_round_trip_and_bad_arguments() -> None:
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    keys = [NORMAL, SPRING_150]
    _run(decision, keys, [0.1, 0.9], 3)
    saved = decision.state
    _run(decision, keys, [0.1, 0.9], 5)
    decision.load_state(saved)
    assert _run(decision, keys, [0.1, 0.9], 3) == ['', '', 'spring']
    for kwargs in ({'threshold': 1.0}, {'clear_time_s': -1.0}, {'min_deviation': float('nan')}):
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            FaultDecision(**{'threshold': 0.6, 'hold_time_s': 0.05, 'dt': 0.01, **kwargs})
