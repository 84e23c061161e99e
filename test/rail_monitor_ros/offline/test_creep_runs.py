"""Offline creep runs (offline.creep_runs): simulated inputs, step metrics, the figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rail_monitor_ros.core.creep_ekf import CreepEkfParams, CreepRun
from rail_monitor_ros.offline.creep_runs import (
    plot_creep,
    run_on_simulation,
    simulation_inputs,
    step_metrics,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import RailSimulationResult, simulate


@pytest.fixture(scope='module')
def short_drop() -> RailSimulationResult:
    """2 s at 40 m/s, c 1.0 -> 0.5 at 1 s (seeded)."""
    return simulate(rail_scenario_from_dict({
        'duration': 2.0, 'seed': 5, 'warm_up': 1.0,
        'events': [{'time': 1.0, 'creep_factor': 0.5}]}))


def test_simulation_inputs_shapes(short_drop: RailSimulationResult) -> None:
    """Measurements per pattern (end model: A 16 channels ... D 3), track with its rate, speed."""
    n = short_drop.time.size
    for pattern, width in (('A', 16), ('B', 6), ('C', 4), ('D', 3)):
        z, track, speed = simulation_inputs(short_drop, pattern)
        assert z.shape == (n, width) and track.shape == (n, 4) and speed.shape == (n,)
    _, track, _ = simulation_inputs(short_drop, 'C', track_rate=False)
    assert track.shape == (n, 2)
    with pytest.raises(ValueError, match='front bogie'):
        simulation_inputs(short_drop, 'D', bogie='rear')


def test_step_metrics_on_a_known_run() -> None:
    """A run that jumps to the truth 0.2 s after the step of the truth settles in 0.2 s, with
    no error after the window (one segment per change of the truth)."""
    t = np.arange(400) * 0.005
    truth = np.where(t < 1.0, 1.0, 0.5)
    estimate = np.where(t < 1.2, 1.0, 0.5)
    run = CreepRun('C', t, estimate, np.zeros(400), estimate < 0.6, np.zeros(400),
                   np.full(400, 'ok', dtype=object), {}, {}, 0, truth)
    (second,) = step_metrics(run, window_s=0.5, steady_s=0.5)
    assert second.time == 1.0 and second.steady_error == 0.0
    assert second.value == 0.5 and second.settling_time == pytest.approx(0.2)
    assert second.max_error_after_window == 0.0


def test_plot_creep_writes_png(short_drop: RailSimulationResult, tmp_path: Path) -> None:
    """plot_creep writes a PNG with one panel per run."""
    runs = {f'pattern {p}': run_on_simulation(short_drop, CreepEkfParams(pattern=p))
            for p in 'CD'}
    path = plot_creep(runs, tmp_path / 'c.png')
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert path.stat().st_size > 10_000
