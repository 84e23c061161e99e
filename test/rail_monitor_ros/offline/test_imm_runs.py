"""Offline IMM runs: the paper's mode-probability figure."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rail_monitor_ros.offline.imm_runs import (
    ImmRunResult,
    plot_mode_probabilities,
    run_suspension_imm,
)
from rail_monitor_ros.simulation.rail_scenario import shipped_scenario
from rail_monitor_ros.simulation.rail_simulator import simulate


def _paper_run() -> ImmRunResult:
    """The paper's scenario on the full-car simulator, full-car model, inputs as noise."""
    r = simulate(shipped_scenario('rail_imm_spring_damper_fault'))
    z = np.column_stack([r.bogie_lateral_accel, r.bogie_yaw_rate, r.body_lateral_accel])
    return run_suspension_imm(z, None, time=r.time, truth_spring_ratio=r.spring_ratio[:, 0],
                              truth_damper_ratio=r.damper_ratio[:, 0])


def test_plot_writes_png(tmp_path: Path) -> None:
    """The Fig. 5-7 style plot is written as a PNG."""
    out = plot_mode_probabilities(_paper_run(), tmp_path / 'imm.png')
    assert out.stat().st_size > 10_000
    assert out.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
