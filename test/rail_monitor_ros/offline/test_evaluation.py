"""Rail evaluation (offline.evaluation) on small synthetic recordings with known answers.

Detection delays, false alarms and creep settling times are built into the outputs, so every
metric is checked against a number that a wrong implementation would miss.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rail_monitor_ros.offline.evaluation import (
    MODES,
    TRUTH_CREEP,
    TRUTH_SUSPENSION,
    evaluate,
    settling_times,
)
from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.evaluation import Metric, read_stamped_series
from vehicle_monitor_common.series import TopicSeries, stamps_from_seconds

PKG = 'vehicle_monitor_msgs/msg/'
times = np.arange(0.0, 10.0, 0.005)  # 200 Hz, as the rail sensors
MODE_NAMES = ['normal', 'spring_150', 'damper_50']


def _suspension_truth(spring_at: float | None, damper_at: float | None) -> TopicSeries:
    spring = np.ones((times.size, 2))
    damper = np.ones((times.size, 2))
    if spring_at is not None:
        spring[times >= spring_at, 0] = 1.5
    if damper_at is not None:
        damper[times >= damper_at, 0] = 0.5
    return TopicSeries(PKG + 'SuspensionState', stamps_from_seconds(times),
                       {'spring_ratio': spring, 'damper_ratio': damper})


def _modes(switch_to_spring: float, switch_to_damper: float,
           declared_from: list[tuple[float, float]]) -> TopicSeries:
    """Three modes; the probability moves wholesale at the given times."""
    winner = np.where(times >= switch_to_damper, 2, np.where(times >= switch_to_spring, 1, 0))
    probability = np.eye(3)[winner]
    declared = np.zeros(times.size, dtype=bool)
    for start, end in declared_from:
        declared |= (times >= start) & (times < end)
    n = times.size
    names = np.empty(n, dtype=object)  # string[]: one list of names per message
    for i in range(n):
        names[i] = MODE_NAMES
    return TopicSeries(PKG + 'ModeProbabilities', stamps_from_seconds(times), {
        'modes': names,
        'probability': probability, 'smoothed_probability': probability,
        'mode_spring_ratio': np.tile([1.0, 1.5, 1.5], (n, 1)),
        'mode_damper_ratio': np.tile([1.0, 1.0, 0.5], (n, 1)),
        'most_likely': winner.astype(np.uint32),
        'spring_ratio': np.array([1.0, 1.5, 1.5])[winner],
        'damper_ratio': np.array([1.0, 1.0, 0.5])[winner],
        'fault_detected': declared,
        'fault_component': np.array(['', 'spring', 'spring+damper'])[winner]})


def _by_figure(metrics: tuple[Metric, ...]) -> dict[str, Metric]:
    return {m.figure: m for m in metrics}


def test_imm_detection_delays_through_a_bag(tmp_path: Path) -> None:
    """Spring found 0.3 s after its onset (pass), damper 1.5 s after (fail the 1 s target)."""
    path = write_bag(tmp_path / 'run', {
        TRUTH_SUSPENSION: _suspension_truth(3.0, 6.0),
        MODES: _modes(3.3, 7.5, [(3.5, 10.0)])})
    evaluation = evaluate(read_stamped_series(path), 'imm', tmp_path, ('imm',))
    result = _by_figure(evaluation.metrics)
    spring = result['spring fault detection delay']
    assert spring.value == pytest.approx(0.3, abs=1e-6)
    assert spring.passed is True
    assert 'spring_150' in spring.detail
    damper = result['damper fault detection delay']
    assert damper.value == pytest.approx(1.5, abs=1e-6)
    assert damper.passed is False
    assert (tmp_path / 'mori_fig5_mode_probabilities.png').stat().st_size > 10_000


def test_imm_false_alarm_before_the_fault_fails_the_detection(tmp_path: Path) -> None:
    """A fault declared at 1 s, before any true fault, fails an otherwise timely detection."""
    series = {TRUTH_SUSPENSION: _suspension_truth(3.0, None),
              MODES: _modes(3.1, 99.0, [(1.0, 1.2), (3.2, 10.0)])}
    metric = evaluate(series, 'imm', tmp_path, ('imm',)).metrics[0]
    assert metric.value == pytest.approx(0.1, abs=1e-6)
    assert metric.passed is False and '1 false alarm' in metric.detail


def test_imm_healthy_run_counts_false_alarms(tmp_path: Path) -> None:
    """No true fault: the score is the number of faults declared (target 0)."""
    quiet = evaluate({TRUTH_SUSPENSION: _suspension_truth(None, None),
                      MODES: _modes(99.0, 99.0, [])}, 'h', tmp_path, ('imm',)).metrics[0]
    assert quiet.value == 0 and quiet.passed is True
    noisy = evaluate({TRUTH_SUSPENSION: _suspension_truth(None, None),
                      MODES: _modes(99.0, 99.0, [(2.0, 2.5), (4.0, 4.1)])}, 'h', tmp_path,
                     ('imm',)).metrics[0]
    assert noisy.value == 2 and noisy.passed is False


def _creep_run(tau: float) -> dict[str, TopicSeries]:
    """Truth 1.0 -> 0.4 at 5 s -> 0.6 at 10 s; the estimate follows with a first-order lag."""
    t = np.arange(0.0, 15.0, 0.005)
    truth = np.where(t >= 10.0, 0.6, np.where(t >= 5.0, 0.4, 1.0))
    estimate = np.empty_like(truth)
    estimate[0] = truth[0]
    alpha = 1.0 - np.exp(-0.005 / tau)
    for k in range(1, t.size):  # a first-order lag, the reference the settling time is read on
        estimate[k] = estimate[k - 1] + alpha * (truth[k] - estimate[k - 1])
    stamps = stamps_from_seconds(t)
    return {TRUTH_CREEP: TopicSeries(PKG + 'CreepFactor', stamps, {'creep_factor': truth}),
            '/rail/creep_factor': TopicSeries(PKG + 'CreepFactor', stamps,
                                              {'creep_factor': estimate})}


def test_creep_settling_time_matches_the_first_order_lag(tmp_path: Path) -> None:
    """tau 0.2 s: +/-5 % reached tau ln(0.6/0.02) = 0.68 s after the 1.0 -> 0.4 step (pass);
    tau 0.4 s doubles it (fail)."""
    fast = evaluate(_creep_run(0.2), 'c', tmp_path, ('creep',)).metrics[0]
    assert fast.value == pytest.approx(0.2 * np.log(0.6 / 0.02), abs=0.01)
    assert fast.passed is True
    slow = evaluate(_creep_run(0.4), 'c', tmp_path, ('creep',)).metrics[0]
    assert slow.value == pytest.approx(0.4 * np.log(0.6 / 0.02), abs=0.01)
    assert slow.passed is False
    assert (tmp_path / 'chonan_fig7_creep.png').is_file()


def test_settling_never_reached_is_reported_as_none() -> None:
    """An estimate stuck at 1.0 never settles on the 0.4 step."""
    t = np.arange(0.0, 10.0, 0.01)
    truth = np.where(t >= 5.0, 0.4, 1.0)
    steps = settling_times(t, np.ones_like(t), t, truth, 0.05)
    assert steps == [(5.0, 0.4, None)]


def test_without_truth_reports_the_estimates(tmp_path: Path) -> None:
    """No truth: first fault declared and the last creep factor, without verdicts."""
    series = {MODES: _modes(3.3, 7.5, [(3.5, 10.0)]),
              '/rail/creep_factor': _creep_run(0.2)['/rail/creep_factor']}
    evaluation = evaluate(series, 'field', tmp_path)
    assert not evaluation.has_truth
    assert all(m.passed is None for m in evaluation.metrics)
    first = _by_figure(evaluation.metrics)['first fault declared']
    assert first.value == pytest.approx(3.5) and 'spring' in first.detail
    assert _by_figure(evaluation.metrics)['last creep factor'].value == pytest.approx(0.6, 1e-3)
