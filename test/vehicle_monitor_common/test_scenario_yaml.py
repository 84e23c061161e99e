"""The shared scenario-file reader (scenario_yaml): values checked, errors located by line."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest
import yaml

from vehicle_monitor_common.scenario_yaml import (
    key_lines,
    located_error,
    mapping_from_data,
    read_mapping,
)

TEXT = """\
name: demo
duration_s: 5
rates:
  imu_hz: 100
events:
  - at_s: 1.0
    kind: step
  - at_s: 2.0
    kind: ramp
"""


def test_accessors_read_values_and_defaults() -> None:
    """number/integer/text/child/items give the values (defaults when absent), and finish
    accepts a mapping whose keys were all read."""
    root = read_mapping(TEXT, 'demo.yaml')
    assert root.text('name') == 'demo'
    assert root.number('duration_s', low=0.0, low_open=True) == 5.0
    assert root.integer('seed', 7, low=0) == 7
    rates = root.child('rates')
    assert rates.number('imu_hz') == 100.0 and rates.number('gps_hz', 10.0) == 10.0
    rates.finish()
    kinds = [item.text('kind', choices=('step', 'ramp')) for item in root.items('events')]
    assert kinds == ['step', 'ramp']
    assert root.child('absent').values == {} and root.items('absent') == []


@pytest.mark.parametrize('key, call, match', [
    ('duration_s', lambda n: n.number('duration_s', high=4.0), r'^demo.yaml:2: duration_s: '
                                                                r'must be <= 4, got 5$'),
    ('name', lambda n: n.number('name'), r'^demo.yaml:1: name: must be a number'),
    ('missing', lambda n: n.number('missing'), r'^demo.yaml:1: missing: is required$'),
    ('rates', lambda n: n.items('rates'), r'^demo.yaml:3: rates: must be a list$'),
    ('events', lambda n: n.items('events')[1].text('kind', choices=('step',)),
     r"^demo.yaml:9: events\[1\].kind: unknown value 'ramp'"),
])
def test_errors_name_source_line_and_path(key: str, call: Callable[[Any], Any],
                                          match: str) -> None:
    """Each check's error names the file, the key's line and its dotted path."""
    root = read_mapping(TEXT, 'demo.yaml')
    with pytest.raises(ValueError, match=match):
        call(root)


@pytest.mark.parametrize('text, expected', [
    ('ratio: 1.5', (1.5, 1.5)),
    ('ratio: [0.5, 2]', (0.5, 2.0)),
    ('other: 1', (1.0, 1.0)),
])
def test_numbers_one_for_all_or_one_each(text: str, expected: tuple[float, float]) -> None:
    """One number stands for every name, a list gives one each; absent: the default."""
    assert read_mapping(text).numbers('ratio', (1.0, 1.0), ('front', 'rear'), low=0.0,
                                      low_open=True, high=5.0) == expected


@pytest.mark.parametrize('text, match', [
    ('ratio: [1, 2, 3]', r':1: ratio: must be one number or 2 \(front, rear\), got \[1, 2, 3\]$'),
    ('ratio: [1, .nan]', r':1: ratio: must hold finite numbers'),
    ('ratio: [1, true]', r':1: ratio: must hold finite numbers'),
    ('ratio: [0, 1]', r':1: ratio: values must be > 0, got \[0, 1\]$'),
    ('ratio: 6', r':1: ratio: values must be <= 5, got 6$'),
])
def test_numbers_refused_with_line_and_reason(text: str, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        read_mapping(text, 'r.yaml').numbers('ratio', (1.0, 1.0), ('front', 'rear'), low=0.0,
                                             low_open=True, high=5.0)


def test_unknown_and_duplicate_keys_refused() -> None:
    """finish() refuses keys nobody read, at their line; a duplicate key is refused at parse."""
    root = read_mapping(TEXT, 'demo.yaml')
    root.text('name')
    with pytest.raises(ValueError, match=r'^demo.yaml:2: duration_s: unknown key$'):
        root.finish()
    with pytest.raises(ValueError, match=r'^demo.yaml:2: a: duplicate key$'):
        read_mapping('a: 1\na: 2\n', 'demo.yaml')


def test_not_a_mapping_or_not_yaml() -> None:
    """Text that is not a YAML mapping, or not YAML, is refused naming the source."""
    with pytest.raises(ValueError, match='^x.yaml: a scenario must be a YAML mapping'):
        read_mapping('- 1\n- 2\n', 'x.yaml')
    with pytest.raises(ValueError, match='^x.yaml: not valid YAML'):
        read_mapping('a: [1, 2\n', 'x.yaml')
    with pytest.raises(ValueError, match='must be a mapping'):
        mapping_from_data([1, 2])


def test_parsed_data_has_paths_without_lines() -> None:
    """A mapping built in code has no lines: errors name the source and the key path only."""
    root = mapping_from_data({'events': [{'at_s': -1.0}]}, 'code')
    with pytest.raises(ValueError, match=r'^code: events\[0\].at_s: must be >= 0, got -1$'):
        root.items('events')[0].number('at_s', low=0.0)
    assert str(located_error('f.yaml', 0, 'a.b', 'bad')) == 'f.yaml: a.b: bad'
    assert str(located_error('f.yaml', 3, 'a.b', 'bad')) == 'f.yaml:3: a.b: bad'


def test_key_lines_records_every_key_and_item() -> None:
    """key_lines maps dotted paths (list items as [i]) to 1-based lines."""
    lines: dict[str, int] = {}
    key_lines(yaml.compose(TEXT, Loader=yaml.SafeLoader), '', lines)
    assert lines['name'] == 1 and lines['rates.imu_hz'] == 4
    assert lines['events[0]'] == 6 and lines['events[1].kind'] == 9
