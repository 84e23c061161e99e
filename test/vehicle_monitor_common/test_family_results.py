"""Held-out family result files: the row schema, reading them back, and the table the main
job's scoreboard, report and README section show (also when a file is missing)."""

from __future__ import annotations

from pathlib import Path

import pytest

from vehicle_monitor_common.evaluation import (
    Evaluation,
    Metric,
    render_scoreboard,
    update_readme,
    write_report,
    write_results,
)
from vehicle_monitor_common.family_results import (
    FAMILY_FILES,
    FamilyFile,
    FamilyResults,
    FamilyRow,
    load_family_results,
    load_family_tables,
    render_family_markdown,
    seeds_text,
    write_family_results,
)

FILES = (FamilyFile('TPMS on held-out cars', 'tpms_family.json', 'python eval_tpms.py',
                    'docs/tpms_why.md'),
         FamilyFile('Rail on held-out cars', 'rail_family.json', 'python eval_rail.py'))

RESULTS = FamilyResults(
    'benchmarks/eval_tpms_family.py', '3835691f73ce6e494ff6acb7baa38164e5862980', '2026-11-29',
    (21000, 21001, 21002, 21005), True, (
        FamilyRow('fused: 25 % puncture', 'fused warning names a 25 % puncture within 60 s',
                  23, 24, 'runs', 1.0, None, 's', 'missed: 21004 puncture25 motorway', False),
        FamilyRow('fused: 15 % on 1-2 tires', 'a 15 % loss within 60 s', 22, 24, 'runs', 0.9,
                  46.4, 's', '21023 puncture15 rural', True),
        FamilyRow('stiffness at placard', '|mean error| < 10 kPa', 40, 72, 'runs', 0.95, 84.6,
                  'kPa', '|mean|, 21008 diffusion20 motorway RR', False,
                  '25 tires read more than 10 kPa low'),
    ), {'fault_s': 150.0})

EVALUATIONS = [Evaluation('road_x', True, (
    Metric('tpms fused', 'detection time', 31.5, 's', '<= 60 s', True),))]


def _write_tpms_only(directory: Path) -> None:
    write_family_results(directory / 'tpms_family.json', RESULTS)


def test_result_file_round_trip(tmp_path: Path) -> None:
    """A written result file reads back to the same results."""
    path = write_family_results(tmp_path / 'results' / 'tpms_family.json', RESULTS)
    assert load_family_results(path) == RESULTS


@pytest.mark.parametrize(('passed', 'cases', 'required', 'met'), [
    (9, 10, 0.9, True), (8, 10, 0.9, False), (24, 24, 1.0, True), (23, 24, 1.0, False),
    (0, 0, 0.9, False)])
def test_share_met(passed: int, cases: int, required: float, met: bool) -> None:
    """The required share is reached at equality; no case judged is not a pass."""
    row = FamilyRow('t', 't', passed, cases, 'runs', required, None, '', '', met)
    assert row.share_met() is met


def test_table_from_fixture_and_missing_file(tmp_path: Path) -> None:
    """The present file gives its rows under a heading with commit, date, cars and command; the
    missing one says it was not measured and how to measure it."""
    _write_tpms_only(tmp_path)
    tables = load_family_tables(tmp_path, FILES)
    text = render_family_markdown(tables)
    assert ('TPMS on held-out cars: held-out cars 21000-21002, 21005 (4 cars), measured at '
            'commit 3835691 on 2026-11-29; 1 of 3 targets met. Why, per car: '
            'docs/tpms_why.md. Regenerate: `python eval_tpms.py`') in text
    assert ('| fused warning names a 25 % puncture within 60 s | every | 23 / 24 runs (96 %) '
            '| missed: 21004 puncture25 motorway | **FAIL** | - |') in text
    assert ('| \\|mean error\\| < 10 kPa | >= 95 % | 40 / 72 runs (56 %) '
            '| 84.6 kPa (\\|mean\\|, 21008 diffusion20 motorway RR) | **FAIL** '
            '| 25 tires read more than 10 kPa low |') in text
    assert '| a 15 % loss within 60 s | >= 90 % | 22 / 24 runs (92 %) | 46.4 s' in text
    assert (f'Rail on held-out cars: not measured yet: no {tmp_path / "rail_family.json"}. '
            'Regenerate: `python eval_rail.py`') in text


def test_each_shipped_family_names_a_page_of_this_repository() -> None:
    """The scoreboard's pointer from each family table to its analysis is a page that exists."""
    root = Path(__file__).resolve().parents[2]
    for source in FAMILY_FILES:
        assert source.analysis, source.title
        assert (root / source.analysis).is_file(), source.analysis


def test_unreadable_file_is_reported_not_raised(tmp_path: Path) -> None:
    """A file of another schema or broken JSON gives a table saying so."""
    (tmp_path / 'tpms_family.json').write_text('{"schema": 99}')
    (tmp_path / 'rail_family.json').write_text('{not json')
    tables = load_family_tables(tmp_path, FILES)
    assert [t.results for t in tables] == [None, None]
    assert 'not a family result file of schema 1' in tables[0].problem
    assert tables[1].problem.startswith('unreadable:')


def test_scoreboard_report_and_readme_show_the_family(tmp_path: Path) -> None:
    """The printed scoreboard, report.md and the README section carry the family tables."""
    _write_tpms_only(tmp_path)
    tables = load_family_tables(tmp_path, FILES)
    printed = render_scoreboard(EVALUATIONS, (), tables)
    row = next(line for line in printed.splitlines() if line.startswith('fused: 25 % puncture'))
    assert 'every' in row and '23 / 24 runs' in row and row.endswith('FAIL')
    assert 'Rail on held-out cars: not measured yet' in printed
    report = write_report(tmp_path / 'report.md', EVALUATIONS, families=tables).read_text()
    assert '## Held-out family' in report and render_family_markdown(tables) in report
    readme = tmp_path / 'README.md'
    readme.write_text('# Title\n')
    results = write_results(tmp_path / 'out' / 'results.json', EVALUATIONS)
    assert update_readme(readme, results, tables) is True
    section = readme.read_text()
    assert '### Held-out family' in section and render_family_markdown(tables) in section


@pytest.mark.parametrize(('seeds', 'text'), [
    ([21000], '21000 (1 car)'), ([3, 1, 2, 7, 9, 8], '1-3, 7-9 (6 cars)'),
    ([190001, 190003], '190001, 190003 (2 cars)')])
def test_seeds_text(seeds: list[int], text: str) -> None:
    """Consecutive seeds are joined into ranges."""
    assert seeds_text(seeds) == text
