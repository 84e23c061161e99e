"""Road evaluation (tpms_ros.offline.evaluation) on a small synthetic recording with known answers.

The recording is built column-wise, written to a bag and read back with header stamps, as the
main job does with a graph's recording; every metric is set up so that it could fail.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tpms_ros.core.tpms_voting import VoterParams
from tpms_ros.offline.evaluation import (
    FORCES,
    STIFFNESS,
    TRUTH_FORCES,
    TRUTH_PRESSURE,
    WARNING,
    evaluate,
    steady_mask,
)
from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.evaluation import Metric, read_stamped_series
from vehicle_monitor_common.series import TopicSeries, stamps_from_seconds

PKG = 'vehicle_monitor_msgs/msg/'


def _flags(t: np.ndarray, on: dict[int, tuple[float, float]]) -> np.ndarray:
    """(N, 4) flags: tire -> (from, to) seconds."""
    flags = np.zeros((t.size, 4), dtype=bool)
    for tire, (start, end) in on.items():
        flags[:, tire] = (t >= start) & (t < end)
    return flags


def _indication(t: np.ndarray, method: str, flags: np.ndarray) -> TopicSeries:
    n = t.size
    return TopicSeries(PKG + 'TpmsIndication', stamps_from_seconds(t), {
        'method': np.array([method] * n), 'underinflated': flags,
        'confidence': flags * 0.9, 'known': np.ones((n, 4), dtype=bool)})


def synthetic_run(pressure_offset_kpa: float = 4.0) -> dict[str, TopicSeries]:
    """200 s: FL steps 200 -> 170 kPa at 100 s; outputs with known detection times/errors."""
    t_truth = np.arange(0, 200, 0.1)
    pressure = np.full((t_truth.size, 4), 200.0)
    pressure[t_truth >= 100.0, 0] = 170.0
    truth = TopicSeries(PKG + 'TirePressure', stamps_from_seconds(t_truth),
                        {'pressure_kpa': pressure})
    t_warn = np.arange(0, 200, 0.5)
    warning_flags = _flags(t_warn, {0: (130.0, 1e9)})
    warning = TopicSeries(PKG + 'TpmsWarning', stamps_from_seconds(t_warn), {
        'warning': warning_flags, 'active': warning_flags.any(axis=1),
        'confidence': warning_flags * 0.9})
    t_ind = np.arange(0, 200, 0.1)
    t_stiff = np.arange(0, 200, 0.25)
    estimate = np.where(t_stiff[:, None] >= 100.0, [170.0, 200, 200, 200], 200.0)
    estimate = estimate + pressure_offset_kpa
    calibrated = t_stiff >= 60.0
    t_force = np.arange(0, 10, 0.01)
    fy_true = 2000.0 * np.sin(2 * np.pi * 0.25 * t_force)[:, None] * np.ones(4)
    return {
        TRUTH_PRESSURE: truth,
        WARNING: warning,
        # vibration: FL flagged from 115 s, RR flagged 50-52 s (shorter than the voter's
        # hold-off: no warning) and 60-70 s (a false warning)
        '/tpms/indication/vibration': _indication(
            t_ind, 'vibration', _flags(t_ind, {0: (115.0, 1e9), 3: (50.0, 52.0)})
            | _flags(t_ind, {3: (60.0, 70.0)})),
        # stiffness: FL at 125 s, together with FR (wrong tires)
        '/tpms/indication/stiffness': _indication(
            t_ind, 'stiffness', _flags(t_ind, {0: (125.0, 1e9), 1: (125.0, 1e9)})),
        # wheel radius: never flags
        '/tpms/indication/wheel_radius': _indication(t_ind, 'wheel_radius', _flags(t_ind, {})),
        STIFFNESS: TopicSeries(PKG + 'TireStiffness', stamps_from_seconds(t_stiff), {
            'pressure_kpa': estimate, 'valid': np.ones((t_stiff.size, 4), dtype=bool),
            'calibrated': calibrated}),
        TRUTH_FORCES: TopicSeries(PKG + 'TireForces', stamps_from_seconds(t_force),
                                  {'fy': fy_true}),
        FORCES: TopicSeries(PKG + 'TireForces', stamps_from_seconds(t_force),
                            {'fy': fy_true + 100.0}),
    }


def _by_method(metrics: tuple[Metric, ...]) -> dict[str, Metric]:
    return {m.method: m for m in metrics}


@pytest.fixture(scope='module')
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, TopicSeries]:
    """The synthetic run through a bag and back (header stamps)."""
    path = tmp_path_factory.mktemp('road') / 'run'
    write_bag(path, synthetic_run())
    return read_stamped_series(path)


def test_detection_times_right_tires_and_false_warnings(recorded: dict[str, TopicSeries],
                                                        tmp_path: Path) -> None:
    """Fused 30 s pass. Each method is voted alone (its flags go through the voter's
    hold-off): vibration 15 s + hold-off fails on a false warning; stiffness on wrong tires."""
    result = _by_method(evaluate(recorded, 'synthetic', tmp_path, ('tpms',)).metrics)
    fused = result['tpms fused']
    assert fused.value == pytest.approx(30.0, abs=1e-6)
    assert fused.passed is True
    hold_off = VoterParams().set_on_s
    vibration = result['tpms vibration']
    # the warning comes at the first 0.1 s tick at or after the flag's hold-off
    assert 15.0 + hold_off - 0.1 - 1e-6 <= vibration.value <= 15.0 + hold_off + 0.1
    assert vibration.passed is False
    assert '1 false warning' in vibration.detail and 'RR at 6' in vibration.detail
    stiffness = result['tpms stiffness']
    assert 25.0 + hold_off - 0.1 - 1e-6 <= stiffness.value <= 25.0 + hold_off + 0.1
    assert stiffness.passed is False and 'WRONG tires' in stiffness.detail
    radius = result['tpms wheel_radius']
    assert radius.value is None and radius.passed is False
    assert (tmp_path / 'persson_fig9_warnings.png').stat().st_size > 10_000


def test_steady_state_pressure_error(recorded: dict[str, TopicSeries], tmp_path: Path) -> None:
    """A constant +4 kPa error scores 4 kPa (pass); +12 kPa scores 12 (fail)."""
    metric = _by_method(evaluate(recorded, 's', tmp_path, ('stiffness',)).metrics)[
        'stiffness observer']
    assert metric.value == pytest.approx(4.0, abs=1e-6)
    assert metric.passed is True
    worse = synthetic_run(pressure_offset_kpa=12.0)
    metric = _by_method(evaluate(worse, 's', tmp_path, ('stiffness',)).metrics)[
        'stiffness observer']
    assert metric.value == pytest.approx(12.0, abs=1e-6)
    assert metric.passed is False
    assert (tmp_path / 'umeno_fig11_pressure.png').is_file()


def test_steady_mask_excludes_the_window_after_a_step() -> None:
    """Samples within STEADY_S after the step are not steady; the others are."""
    t = np.arange(0.0, 100.0, 1.0)
    pressure = np.where(t[:, None] >= 50.0, 170.0, 200.0) * np.ones(4)
    mask = steady_mask(t, pressure, np.array([49.0, 50.0, 79.0, 80.5]), steady_s=30.0)
    assert mask[:, 0].tolist() == [True, False, False, True]


def test_lateral_force_rms_percent_of_peak(recorded: dict[str, TopicSeries],
                                           tmp_path: Path) -> None:
    """A 100 N bias on a 2000 N peak is 5 % (target < 10 %)."""
    metric = _by_method(evaluate(recorded, 'k', tmp_path, ('lateral_force',)).metrics)[
        'lateral force']
    assert metric.value == pytest.approx(5.0, abs=0.01)
    assert metric.passed is True
    assert (tmp_path / 'kim_huh_fig5_6_lateral_forces.png').is_file()


def test_without_truth_reports_estimates_without_verdicts(recorded: dict[str, TopicSeries],
                                                          tmp_path: Path) -> None:
    """No /truth topics: first warnings and estimates, no targets, no pass/fail."""
    no_truth = {k: v for k, v in recorded.items() if not k.startswith('/truth')}
    evaluation = evaluate(no_truth, 'field', tmp_path)
    assert not evaluation.has_truth
    assert all(m.passed is None and m.target == '' for m in evaluation.metrics)
    fused = _by_method(evaluation.metrics)['tpms fused']
    assert fused.figure == 'first warning' and fused.value == pytest.approx(130.0)
    assert _by_method(evaluation.metrics)['lateral force'].value == pytest.approx(2100.0, 1e-3)


def test_unknown_method_is_refused(tmp_path: Path) -> None:
    """A typo in the method filter names the known ones."""
    with pytest.raises(ValueError, match='unknown .tmps.'):
        evaluate({}, 's', tmp_path, ('tmps',))
