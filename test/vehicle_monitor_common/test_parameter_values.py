"""Parameter sets changed by name from a command line (the evaluations' ``--...-set`` options)."""

from __future__ import annotations

import pytest

from tpms_ros.core.stiffness_observer import StiffnessObserverParams
from vehicle_monitor_common.parameters import (
    ConfigurationError,
    parse_assignment,
    parse_assignments,
    with_values,
)


def test_assignment_value_is_yaml() -> None:
    assert parse_assignment('forgetting_factor=0.995') == ('forgetting_factor', 0.995)
    assert parse_assignment(' trust_check = false') == ('trust_check', False)
    assert parse_assignment('nominal_pressure_kpa=[230, 230, 250, 250]') == (
        'nominal_pressure_kpa', [230, 230, 250, 250])


@pytest.mark.parametrize('text', ['forgetting_factor', '=0.9', ''])
def test_assignment_without_name_or_value_is_refused(text: str) -> None:
    with pytest.raises(ConfigurationError, match='expected NAME=VALUE'):
        parse_assignment(text)


def test_values_replace_only_what_is_named() -> None:
    base = StiffnessObserverParams(encoder_teeth=43)
    changed = with_values(base, {'forgetting_factor': 0.995, 'pressure_relation.slope': 0.7})
    assert changed.forgetting_factor == 0.995
    assert changed.pressure_relation.slope == 0.7
    assert changed.encoder_teeth == 43          # the instance's own value, not the default
    assert with_values(base, {}) == base


def test_unknown_name_is_an_error_not_a_default() -> None:
    with pytest.raises(ConfigurationError, match='no parameter forgeting_factor'):
        with_values(StiffnessObserverParams(), {'forgeting_factor': 0.995})


def test_refused_value_names_the_parameter_class() -> None:
    with pytest.raises(ConfigurationError, match='StiffnessObserverParams'):
        with_values(StiffnessObserverParams(), {'forgetting_factor': 2.0})


def test_assignments_are_checked_against_the_parameters() -> None:
    """What the evaluations' ``--...-set`` options take: a typo is an error, not a default."""
    assert parse_assignments(['forgetting_factor=0.99', 'trust_check=false'],
                             StiffnessObserverParams()) == {'forgetting_factor': 0.99,
                                                            'trust_check': False}
    assert parse_assignments([], StiffnessObserverParams()) == {}
    for texts, match in ((['forgeting_factor=0.99'], 'no parameter forgeting_factor'),
                         (['forgetting_factor=2.0'], 'StiffnessObserverParams'),
                         (['forgetting_factor'], 'expected NAME=VALUE')):
        with pytest.raises(ConfigurationError, match=match):
            parse_assignments(texts, StiffnessObserverParams())
