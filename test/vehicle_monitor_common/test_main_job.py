"""The main job's shared parts: scoreboard, results file, README section, domain discovery, and
one end-to-end run of the rail graph on the shipped IMM bag with no message dropped."""

from __future__ import annotations

from pathlib import Path

import pytest

from vehicle_monitor_common.evaluation import (
    README_BEGIN,
    README_END,
    Evaluation,
    Metric,
    RunStats,
    domain_of_bag,
    domains,
    load_results,
    render_markdown_table,
    render_scoreboard,
    update_readme,
    write_report,
    write_results,
)

ROOT = Path(__file__).resolve().parents[2]

EVALUATIONS = [
    Evaluation('road_x', True, (
        Metric('tpms fused', 'detection time', 31.5, 's', '<= 60 s', True, 'FL at 121.5 s'),
        Metric('lateral force', 'Fy RMS error / peak', 12.25, '%', '< 10 %', False),
        Metric('tpms wheel_radius', 'detection time', None, 's', '<= 60 s', False)),
        ('road_x/persson_fig9_warnings.png',)),
    Evaluation('field_bag', False, (Metric('IMM', 'first fault declared', 3.5, 's'),)),
]
RUNS = [RunStats('road_x', 'road', 240.0, 48.0, 40.0, 1000, 0)]


def test_scoreboard_rows_verdicts_and_speed() -> None:
    """One row per metric with value, target and verdict; the count of met targets; the RTF."""
    text = render_scoreboard(EVALUATIONS, RUNS)
    lines = text.splitlines()
    row = next(line for line in lines if 'tpms fused' in line)
    assert '31.5 s' in row and '<= 60 s' in row and row.rstrip().endswith('PASS')
    assert next(line for line in lines if 'lateral force' in line).rstrip().endswith('FAIL')
    assert 'n/a' in next(line for line in lines if 'wheel_radius' in line)
    no_truth = next(line for line in lines if 'field_bag' in line)
    assert no_truth.rstrip().endswith('-')
    assert '1 of 3 targets met' in text
    assert '5.0x real time' in text and '6.0x per CPU second' in text and '0 dropped' in text


def test_results_round_trip_and_report(tmp_path: Path) -> None:
    """results.json reads back to the same metrics; the report embeds the figures."""
    path = write_results(tmp_path / 'results.json', EVALUATIONS, RUNS)
    evaluations, runs = load_results(path)
    assert evaluations == EVALUATIONS
    assert runs == RUNS
    report = write_report(tmp_path / 'report.md', EVALUATIONS, RUNS).read_text()
    assert '![persson_fig9_warnings](road_x/persson_fig9_warnings.png)' in report
    assert '| road_x | tpms fused | detection time | 31.5 s | <= 60 s | **pass** |' in report


def test_readme_section_is_regenerated_between_markers(tmp_path: Path) -> None:
    """The section is appended once, then replaced in place; the text around it is kept."""
    readme = tmp_path / 'README.md'
    readme.write_text('# Title\n\nintro\n')
    results = write_results(tmp_path / 'out' / 'results.json', EVALUATIONS, RUNS)
    figure = tmp_path / 'out' / 'road_x' / 'persson_fig9_warnings.png'
    figure.parent.mkdir(parents=True)
    figure.write_bytes(b'png bytes')
    assert update_readme(readme, results) is True
    first = readme.read_text()
    assert first.startswith('# Title\n\nintro\n')
    assert render_markdown_table(EVALUATIONS) in first
    # The figure is copied beside the README, so the link works without the run's output.
    assert '(docs/figures/road_x/persson_fig9_warnings.png)' in first
    assert (tmp_path / 'docs' / 'figures' / 'road_x' / 'persson_fig9_warnings.png'
            ).read_bytes() == b'png bytes'
    assert update_readme(readme, results) is False  # nothing changed
    figure.write_bytes(b'new png bytes')
    assert update_readme(readme, results) is True  # a new figure is a change
    readme.write_text(first.replace('intro', 'new intro') + '\ntail\n')
    write_results(results, EVALUATIONS[:1], RUNS)
    assert update_readme(readme, results) is True
    text = readme.read_text()
    assert text.count(README_BEGIN) == 1 and text.count(README_END) == 1
    assert 'new intro' in text and text.endswith('tail\n') and 'field_bag' not in text


def test_domains_are_discovered_and_recognise_their_bags() -> None:
    """Both domain packages register; a shipped bag maps to its domain; scenarios exist."""
    registered = {d.name: d for d in domains()}
    assert set(registered) >= {'road', 'rail'}
    assert domain_of_bag(ROOT / 'bags' / 'rail_creep_steps', registered.values()).name == 'rail'
    assert domain_of_bag(ROOT / 'bags' / 'road_kim_huh_lateral',
                         registered.values()).name == 'road'
    for domain in registered.values():
        assert domain.graph.is_file()
        assert all(s.bag.is_dir() for s in domain.scenarios)


def test_rail_graph_end_to_end_on_the_imm_bag(tmp_path: Path) -> None:
    """The rail graph replays the shipped IMM bag as fast as possible, drops nothing, and the
    recording scores the IMM (both fault onsets) and holds every estimator's output."""
    from vehicle_monitor_common.evaluation import read_stamped_series
    from vehicle_monitor_common.main_job import evaluate_recording, run_graph_on_bag

    rail = next(d for d in domains() if d.name == 'rail')
    scenario = next(s for s in rail.scenarios if s.name == 'rail_imm_spring_damper_fault')
    recorded, stats = run_graph_on_bag(rail, scenario.bag, tmp_path / 'run',
                                       executor='single', log=lambda line: None,
                                       timeout_s=240.0)
    assert stats.dropped == 0
    assert stats.published == 14208
    assert stats.bag_duration_s == pytest.approx(10.0)
    outputs = read_stamped_series(recorded, ['/rail/suspension/modes', '/rail/creep_factor',
                                             '/rail/creep_factor_imu', '/rail/bogie/imu'])
    # One output per input sample, each stamped with the sample it answers.
    for topic in ('/rail/suspension/modes', '/rail/creep_factor', '/rail/creep_factor_imu'):
        assert len(outputs[topic]) == 2001, topic
        assert (outputs[topic].stamps_ns == outputs['/rail/bogie/imu'].stamps_ns).all()
    evaluation = evaluate_recording(rail, recorded, scenario.name, tmp_path, scenario.methods)
    figures = {m.figure for m in evaluation.metrics}
    assert figures == {'spring fault detection delay', 'damper fault detection delay'}
    assert evaluation.figures == ('mori_fig5_mode_probabilities.png',)
