"""Offline runs of the creep-factor EKF on simulated data: inputs, step metrics and plots.

:func:`simulation_inputs` converts a simulated run as the ``creep_estimator`` node converts the
topics, :func:`run_on_simulation` filters it, :func:`step_metrics` scores the tracking of each
step of the true creep factor and :func:`plot_creep` draws the paper's Figs. 7-9. The filter is
:class:`rail_monitor_ros.core.creep_ekf.CreepEkf`. No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np

from rail_monitor_ros.core.creep_ekf import (
    BOGIES,
    CreepEkf,
    CreepEkfParams,
    CreepRun,
    lateral_states_measurement,
    track_wheelsets,
)
from rail_monitor_ros.core.rail_model import OBSERVATION_PATTERNS, RailVehicleParams
from rail_monitor_ros.simulation.rail_simulator import RailSimulationResult, lateral_states_fields
from vehicle_monitor_common.figures import pyplot, save_figure


def simulation_inputs(result: RailSimulationResult, pattern: str, bogie: str = 'front',
                      body_pivot_offset: float = RailVehicleParams().bogie_pivot_semi_spacing,
                      track_rate: bool = True, model: str = 'end',
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(measurements (N, p), measured track (N, 4) or (N, 2), speed (N,)) of a simulated run.

    The same conversion the node applies to the topics: patterns A-C from the noisy lateral
    states, D from the IMU signals (front bogie only: the simulator's IMUs are there); the
    track alignment at the two wheelsets the model takes (:func:`track_wheelsets`) and, with
    ``track_rate``, its rate (both fields of TrackIrregularity).
    """
    if pattern not in OBSERVATION_PATTERNS:
        raise ValueError(f'pattern must be one of {OBSERVATION_PATTERNS}, got {pattern!r}')
    if bogie not in BOGIES:
        raise ValueError(f'bogie must be one of {BOGIES}, got {bogie!r}')
    j = BOGIES.index(bogie)
    if pattern == 'D':
        if j != 0:
            raise ValueError('pattern D: the simulated IMUs are on the front bogie')
        y = np.column_stack([result.bogie_lateral_accel, result.bogie_yaw_rate,
                             result.body_lateral_accel])
    else:
        fields = lateral_states_fields(result.measured_state, result.state_names)
        y = lateral_states_measurement(fields, pattern, bogie, body_pivot_offset, model)
    pair = track_wheelsets(bogie, model)
    track = result.measured_track_alignment[:, pair]
    if track_rate:
        track = np.column_stack([track, result.measured_track_alignment_rate[:, pair]])
    return y, track, result.speed


def run_on_simulation(result: RailSimulationResult, params: CreepEkfParams,
                      known_input: bool = True, use_speed: bool = True,
                      track_rate: bool = True) -> CreepRun:
    """Run the EKF over a simulated run (truth kept for metrics and plots).

    Args:
        result: the simulation.
        params: filter settings (its own model parameters; the pattern selects the inputs).
        known_input: feed the measured track alignment (the paper's setup) or not.
        use_speed: follow the measured speed (else the model keeps params.vehicle.speed).
        track_rate: known input includes the alignment rate (else the alignment only).
    """
    y, track, speed = simulation_inputs(result, params.pattern, params.bogie,
                                        params.vehicle.bogie_pivot_semi_spacing, track_rate,
                                        params.model)
    return CreepEkf(params).run(y, track if known_input else None,
                                speed if use_speed else None, result.time,
                                result.creep_factor)


@dataclass(frozen=True)
class StepMetrics:
    """Tracking of one segment of constant true c after a change.

    Attributes:
        time: when the true c changed, s.
        value: the true c after the change.
        settling_time: from the change until the estimate stays within tolerance of the truth
            to the end of the segment, s (inf if never).
        max_error_after_window: largest |c_hat - c| / c from change + window to the segment end.
        steady_error: mean (c_hat - c) / c over the last ``steady_s`` of the segment.
    """

    time: float
    value: float
    settling_time: float
    max_error_after_window: float
    steady_error: float


def step_metrics(run: CreepRun, tolerance: float = 0.05, window_s: float = 1.0,
                 steady_s: float = 2.0) -> list[StepMetrics]:
    """Settling and errors after each change of the true creep factor (steps only).

    Segments run from one change of the truth to the next (or the end).
    """
    if run.true_creep_factor is None:
        raise ValueError('the run has no true_creep_factor')
    truth = run.true_creep_factor
    changes = np.flatnonzero(np.abs(np.diff(truth)) > 1e-9) + 1
    bounds = np.append(changes, truth.size)
    rel = (run.creep_factor - truth) / truth
    metrics = []
    for start, end in zip(bounds[:-1], bounds[1:], strict=True):
        t = run.time[start:end]
        err = rel[start:end]
        outside = np.flatnonzero(np.abs(err) > tolerance)
        if outside.size == 0:
            settle = 0.0
        elif outside[-1] == err.size - 1:
            settle = math.inf
        else:
            settle = float(t[outside[-1] + 1] - run.time[start])
        after = t >= run.time[start] + window_s
        steady = t >= t[-1] - steady_s
        metrics.append(StepMetrics(
            float(run.time[start]), float(truth[start]), settle,
            float(np.max(np.abs(err[after]))) if after.any() else math.nan,
            float(np.mean(err[steady]))))
    return metrics


def plot_creep(runs: Mapping[str, CreepRun], path: str | Path, title: str = '') -> Path:
    """Paper Figs. 7-9 style: estimated vs true creep factor, one panel per run.

    Each panel shows the estimate with its +/- 2 sigma band, the truth, and the +/- 5 % band
    around the truth. Writes a PNG.

    Args:
        runs: label -> run (e.g. 'pattern A' -> ...).
        path: PNG path.
        title: figure title.

    Returns:
        The path written.
    """
    plt = pyplot()

    if not runs:
        raise ValueError('runs must not be empty')
    path = Path(path)
    fig, axes = plt.subplots(len(runs), 1, figsize=(8.0, 2.4 * len(runs)), sharex=True,
                             squeeze=False)
    for ax, (label, run) in zip(axes[:, 0], runs.items(), strict=True):
        ax.fill_between(run.time, 100 * (run.creep_factor - 2 * run.std_dev),
                        100 * (run.creep_factor + 2 * run.std_dev), color='C0', alpha=0.2,
                        lw=0, label='±2σ')
        if run.true_creep_factor is not None:
            ax.fill_between(run.time, 95 * run.true_creep_factor, 105 * run.true_creep_factor,
                            color='0.8', lw=0, label='truth ±5 %')
            ax.plot(run.time, 100 * run.true_creep_factor, 'k--', lw=1.2, label='true')
        ax.plot(run.time, 100 * run.creep_factor, 'C0', lw=1.0, label='EKF estimate')
        ax.set_ylabel('creep factor, %')
        ax.set_title(label, fontsize=10)
        ax.set_ylim(0, 140)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc='upper right', fontsize=8, ncol=4)
    axes[-1, 0].set_xlabel('time, s')
    if title:
        fig.suptitle(title)
    return save_figure(fig, path, dpi=110)
