"""Scoring a road graph's recording against ground truth (docs/targets.md), and the road figures.

ROS-free: works on the column-wise series of a recording
(:func:`vehicle_monitor_common.evaluation.read_stamped_series`, header stamps). Registered for
the main job and the evaluation CLI under ``vehicle_monitor.evaluations`` as ``road``
(:func:`domain`).

Key figures, each against its docs/targets.md floor:

- TPMS (the fused ``tpms/warning``, and each method alone: its recorded
  ``tpms/indication/<method>`` voted by the voter core with that method only -- its own
  threshold h_i and the same hold-off, the paper's "time to warning per method"; the raw
  per-sample flags t_i are the voter's input, not a warning): detection time, from the start of
  the true pressure loss to the first output that flags every tire that is truly low (loss >=
  ``LOW_LOSS``) -- target 60 s; the verdict also requires the right tires (none other flagged
  then) and no false warning (a flag raised on a tire whose true loss is below ``FALSE_LOSS``)
  during the whole run.
- Stiffness observer (``tpms/tire_stiffness``): steady-state pressure error, the RMS of
  estimated - true pressure per tire over the calibrated, valid estimates at which the true
  pressure has not changed for ``STEADY_S``; the worst tire -- target < 10 kPa.
- Lateral force observer (``vehicle/tire_forces``): per tire, RMS(Fy - Fy_true) over the run
  as a percentage of the peak |Fy_true|; the worst tire -- target < 10 %.

Without truth the same methods report what they said: first warning and its tires, last
pressure estimates, peak lateral force; no target, no verdict.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from tpms_ros.core.tires import TIRE_NAMES, TpmsIndication
from tpms_ros.core.tpms_voting import TpmsVoter, VoterParams
from tpms_ros.simulation.road_scenario import load_scenario
from tpms_ros.simulation.road_simulator import scenario_topics
from vehicle_monitor_common.evaluation import (
    Domain,
    Evaluation,
    MethodScoring,
    Metric,
    Scenario,
    hold_at,
    loads_as_scenario,
    rising_edges,
    score_methods,
    seconds,
)
from vehicle_monitor_common.figures import pyplot, save_figure
from vehicle_monitor_common.resources import share_dir, workspace_bags
from vehicle_monitor_common.series import TopicSeries

TPMS_METHODS = ('stiffness', 'vibration', 'wheel_radius')
# A tire is "low" (must be warned) from this true loss on, and a flag on a tire that lost less
# than FALSE_LOSS is a false warning; in between, a warning is neither required nor false.
LOW_LOSS = 0.10
FALSE_LOSS = 0.05
# The loss starts when the true pressure first leaves its initial value by this fraction.
ONSET_LOSS = 0.005
DETECTION_TARGET_S = 60.0
PRESSURE_ERROR_TARGET_KPA = 10.0
# True pressure unchanged (within 1 kPa) this long before a sample counts as steady state, s
# (more than twice the stiffness observer's least-squares memory at its defaults, 12.5 s).
STEADY_S = 30.0
FY_RMS_TARGET_PERCENT = 10.0

TRUTH_PRESSURE = '/truth/tire_pressure'
TRUTH_FORCES = '/truth/tire_forces'
WARNING = '/tpms/warning'
STIFFNESS = '/tpms/tire_stiffness'
FORCES = '/vehicle/tire_forces'
READ_TOPICS = (TRUTH_PRESSURE, TRUTH_FORCES, WARNING, STIFFNESS, FORCES,
               *(f'/tpms/indication/{m}' for m in TPMS_METHODS))



# ---------------------------------------------------------------------------------------------
# TPMS detection


def pressure_loss(truth: TopicSeries) -> np.ndarray:
    """True fractional loss per tire (N, 4) from the initial pressure."""
    pressure = np.asarray(truth.fields['pressure_kpa'], dtype=float)
    return 1.0 - pressure / pressure[0]


def detection_metric(method: str, t_flags: np.ndarray, flags: np.ndarray,
                     t_truth: np.ndarray | None, loss: np.ndarray | None) -> Metric:
    """Detection time of one TPMS output (flags (N, 4) at t_flags) against the true loss.

    Without truth (``loss`` None): the first flag and its tires.
    """
    flags = np.asarray(flags, dtype=bool)
    if loss is None or t_truth is None:
        first = np.flatnonzero(flags.any(axis=1))
        if not first.size:
            return Metric(method, 'first warning', None, 's', detail='no tire flagged')
        k = int(first[0])
        tires = ', '.join(TIRE_NAMES[j] for j in np.flatnonzero(flags[k]))
        return Metric(method, 'first warning', float(t_flags[k]), 's',
                      detail=f'{tires} flagged at {t_flags[k]:.1f} s')
    target = f'<= {DETECTION_TARGET_S:.0f} s'
    if not len(t_flags):
        return Metric(method, 'detection time', None, 's', target, False, 'no output recorded')
    loss_at = hold_at(t_truth, loss, t_flags)
    false_edges = rising_edges(flags) & (loss_at < FALSE_LOSS)
    false_count = int(false_edges.sum())
    false_text = (f'{false_count} false warning(s) ('
                  + ', '.join(f'{TIRE_NAMES[j]} at {t_flags[k]:.1f} s'
                              for k, j in zip(*np.nonzero(false_edges), strict=True))[:120]
                  + ')') if false_count else 'no false warning'
    low_final = loss[-1] >= LOW_LOSS
    if not low_final.any():
        return Metric(method, 'false warnings', float(false_count), '', '0 (no loss)',
                      false_count == 0, false_text)
    onset_index = np.flatnonzero((loss >= ONSET_LOSS).any(axis=1))
    onset = float(t_truth[onset_index[0]])
    low_now = loss_at >= LOW_LOSS
    caught = (t_flags >= onset) & np.all(flags | ~low_now, axis=1) & low_now.any(axis=1)
    low_names = ', '.join(TIRE_NAMES[j] for j in np.flatnonzero(low_final))
    if not caught.any():
        return Metric(method, 'detection time', None, 's', target, False,
                      f'{low_names} never flagged (loss from {onset:.1f} s); {false_text}')
    k = int(np.flatnonzero(caught)[0])
    delay = float(t_flags[k] - onset)
    right_tires = bool(np.array_equal(flags[k], low_now[k]))
    flagged = ', '.join(TIRE_NAMES[j] for j in np.flatnonzero(flags[k]))
    passed = delay <= DETECTION_TARGET_S and right_tires and false_count == 0
    return Metric(method, 'detection time', delay, 's', target, passed,
                  f'{flagged} flagged at {t_flags[k]:.1f} s (loss from {onset:.1f} s, '
                  f'low: {low_names}, {"right" if right_tires else "WRONG"} tires); '
                  f'{false_text}')


def voted_alone(method: str, t: np.ndarray, indication: TopicSeries,
                params: VoterParams | None = None) -> np.ndarray:
    """(N, 4) warnings of the voter fed one method's recorded indications (at times t, s)
    with that method only: its own threshold, the voter's hold-off and hysteresis."""
    voter = TpmsVoter((params if params is not None else VoterParams()).only([method]))
    flags = np.asarray(indication.fields['underinflated'], dtype=bool)
    confidence = np.asarray(indication.fields['confidence'], dtype=float)
    known = np.asarray(indication.fields['known'], dtype=bool)
    return np.array([voter.evaluate(float(t[k]), [TpmsIndication(
        method, float(t[k]), flags[k], confidence[k], known[k])]).warning
        for k in range(len(t))], dtype=bool).reshape(len(t), len(TIRE_NAMES))


def tpms_metrics(series: Mapping[str, TopicSeries], t0: int) -> list[Metric]:
    """Detection metrics of the fused warning and of each method voted alone."""
    truth = series.get(TRUTH_PRESSURE)
    t_truth = seconds(truth, t0) if truth is not None and len(truth) else None
    loss = pressure_loss(truth) if t_truth is not None and truth is not None else None
    metrics = []
    if WARNING in series:
        s = series[WARNING]
        metrics.append(detection_metric('tpms fused', seconds(s, t0), s.fields['warning'],
                                        t_truth, loss))
    else:
        metrics.append(Metric('tpms fused', 'detection time', None, 's',
                              f'<= {DETECTION_TARGET_S:.0f} s' if loss is not None else '',
                              False if loss is not None else None, 'no tpms/warning recorded'))
    for m in TPMS_METHODS:
        topic = f'/tpms/indication/{m}'
        if topic in series:
            t = seconds(series[topic], t0)
            metrics.append(detection_metric(f'tpms {m}', t, voted_alone(m, t, series[topic]),
                                            t_truth, loss))
    return metrics


# ---------------------------------------------------------------------------------------------
# Stiffness observer pressure


def steady_mask(t_truth: np.ndarray, pressure: np.ndarray, t_query: np.ndarray,
                steady_s: float = STEADY_S, tolerance_kpa: float = 1.0) -> np.ndarray:
    """(M, 4): the true pressure at each query time is within ``tolerance_kpa`` of what it was
    ``steady_s`` before (a step or a fast leak in that window is not steady state)."""
    now = hold_at(t_truth, pressure, t_query)
    then = hold_at(t_truth, pressure, t_query - steady_s)
    return np.asarray(np.abs(now - then) <= tolerance_kpa)


def pressure_metric(series: Mapping[str, TopicSeries], t0: int) -> Metric | None:
    """Steady-state pressure error of the stiffness observer (None if it did not publish)."""
    if STIFFNESS not in series or not len(series[STIFFNESS]):
        return None
    s = series[STIFFNESS]
    t = seconds(s, t0)
    estimate = np.asarray(s.fields['pressure_kpa'], dtype=float)
    usable = (np.asarray(s.fields['valid'], dtype=bool)
              & np.asarray(s.fields['calibrated'], dtype=bool)[:, None])
    truth = series.get(TRUTH_PRESSURE)
    method = 'stiffness observer'
    if truth is None or not len(truth):
        last = np.flatnonzero(usable.all(axis=1))
        if not last.size:
            return Metric(method, 'last pressure', None, 'kPa', detail='never calibrated/valid')
        k = int(last[-1])
        return Metric(method, 'last pressure (min)', float(estimate[k].min()), 'kPa',
                      detail='last estimates ' + ', '.join(
                          f'{n} {p:.0f}' for n, p in zip(TIRE_NAMES, estimate[k], strict=True))
                      + ' kPa')
    target = f'< {PRESSURE_ERROR_TARGET_KPA:.0f} kPa'
    t_truth = seconds(truth, t0)
    true_pressure = np.asarray(truth.fields['pressure_kpa'], dtype=float)
    steady = steady_mask(t_truth, true_pressure, t) & usable
    if not steady.any(axis=0).all():
        missing = ', '.join(TIRE_NAMES[j] for j in np.flatnonzero(~steady.any(axis=0)))
        return Metric(method, 'steady-state pressure error', None, 'kPa', target, False,
                      f'no calibrated steady-state estimate for {missing}')
    error = estimate - hold_at(t_truth, true_pressure, t)
    rms = np.sqrt(np.array([np.mean(error[steady[:, j], j] ** 2) for j in range(4)]))
    worst = int(np.argmax(rms))
    return Metric(method, 'steady-state pressure error', float(rms[worst]), 'kPa', target,
                  bool(rms[worst] < PRESSURE_ERROR_TARGET_KPA),
                  'RMS per tire ' + ', '.join(f'{n} {e:.1f}' for n, e in
                                              zip(TIRE_NAMES, rms, strict=True))
                  + f' kPa over {int(steady.sum(axis=0).min())}+ steady samples')


# ---------------------------------------------------------------------------------------------
# Lateral forces


def lateral_force_metric(series: Mapping[str, TopicSeries], t0: int) -> Metric | None:
    """Per-wheel Fy RMS error in % of the peak true |Fy| (None if the observer did not publish)."""
    if FORCES not in series or not len(series[FORCES]):
        return None
    s = series[FORCES]
    fy = np.asarray(s.fields['fy'], dtype=float)
    truth = series.get(TRUTH_FORCES)
    method = 'lateral force'
    if truth is None or not len(truth):
        peak = np.abs(fy).max(axis=0)
        return Metric(method, 'peak |Fy| (max)', float(peak.max()), 'N',
                      detail='peak per tire ' + ', '.join(
                          f'{n} {p:.0f}' for n, p in zip(TIRE_NAMES, peak, strict=True)) + ' N')
    t = seconds(s, t0)
    t_truth = seconds(truth, t0)
    fy_true = np.column_stack([np.interp(t, t_truth, np.asarray(truth.fields['fy'])[:, j])
                               for j in range(4)])
    peak = np.abs(np.asarray(truth.fields['fy'], dtype=float)).max(axis=0)
    percent = 100.0 * np.sqrt(np.mean((fy - fy_true) ** 2, axis=0)) / np.maximum(peak, 1e-9)
    worst = int(np.argmax(percent))
    return Metric(method, 'Fy RMS error / peak', float(percent[worst]), '%',
                  f'< {FY_RMS_TARGET_PERCENT:.0f} %',
                  bool(percent[worst] < FY_RMS_TARGET_PERCENT),
                  'per tire ' + ', '.join(f'{n} {e:.1f}' for n, e in
                                          zip(TIRE_NAMES, percent, strict=True))
                  + f' % of peak ({", ".join(f"{p:.0f}" for p in peak)} N), {len(t)} samples')


# ---------------------------------------------------------------------------------------------
# Figures


def _plot_per_tire(path: Path, title: str, ylabel: str, t: np.ndarray, estimate: np.ndarray,
                   truth: tuple[np.ndarray, np.ndarray] | None, *, panel: str = '{}',
                   sharey: bool = False, truth_lw: float | None = None) -> Path:
    """Estimate (dashed: truth) of one quantity, one panel per tire, FL FR over RL RR."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(10, 6), sharex=True, sharey=sharey)
    for j, ax in enumerate(axes.flat):
        ax.plot(t, estimate[:, j], label='estimate', lw=1)
        if truth is not None:
            ax.plot(truth[0], truth[1][:, j], 'k--', lw=truth_lw, label='truth')
        ax.set_title(panel.format(TIRE_NAMES[j]))
        ax.grid(True, alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel('time (s)')
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)
    axes[0, 0].legend()
    fig.suptitle(title)
    return save_figure(fig, path)


def plot_pressure(series: Mapping[str, TopicSeries], path: Path, t0: int = 0) -> Path:
    """Umeno Fig. 11 style: estimated vs true pressure per tire over time."""
    s = series[STIFFNESS]
    estimate = np.asarray(s.fields['pressure_kpa'], dtype=float)
    usable = (np.asarray(s.fields['valid'], dtype=bool)
              & np.asarray(s.fields['calibrated'], dtype=bool)[:, None])
    truth = series.get(TRUTH_PRESSURE)
    return _plot_per_tire(
        path, 'Tire stiffness observer: pressure from torsional stiffness (cf. Umeno Fig. 11)',
        'pressure (kPa)', seconds(s, t0), np.where(usable, estimate, np.nan),
        None if truth is None else (seconds(truth, t0), truth.fields['pressure_kpa']),
        sharey=True)


def plot_warnings(series: Mapping[str, TopicSeries], path: Path, t0: int = 0) -> Path:
    """Persson Fig. 9 style: each method's flags, the fused warning and the true loss."""
    plt = pyplot()

    rows = [(f'/tpms/indication/{m}', 'underinflated', 'confidence', m) for m in TPMS_METHODS
            if f'/tpms/indication/{m}' in series]
    if WARNING in series:
        rows.append((WARNING, 'warning', 'confidence', 'fused warning'))
    truth = series.get(TRUTH_PRESSURE)
    fig, axes = plt.subplots(len(rows) + (truth is not None), 1, figsize=(10, 1.8 * (
        len(rows) + 1)), sharex=True, squeeze=False)
    colors = ('C0', 'C1', 'C2', 'C3')
    for ax, (topic, flag_field, confidence_field, label) in zip(axes[:, 0], rows, strict=False):
        s = series[topic]
        t = seconds(s, t0)
        confidence = np.asarray(s.fields[confidence_field], dtype=float)
        flags = np.asarray(s.fields[flag_field], dtype=bool)
        for j in range(4):
            ax.plot(t, confidence[:, j], color=colors[j], lw=0.8, label=TIRE_NAMES[j])
            ax.fill_between(t, 0, 1, where=flags[:, j], color=colors[j], alpha=0.15, step='post')
        ax.set_ylim(0, 1.05)
        ax.set_ylabel(label, fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[0, 0].legend(ncol=4, fontsize=8, loc='upper left')
    if truth is not None:
        ax = axes[-1, 0]
        loss = 100 * pressure_loss(truth)
        for j in range(4):
            ax.plot(seconds(truth, t0), loss[:, j], color=colors[j])
        ax.set_ylabel('true loss (%)', fontsize=8)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel('time (s)')
    fig.suptitle('TPMS confidence (lines) and flags (shaded) per method, fused warning '
                 '(cf. Persson Fig. 9)')
    return save_figure(fig, path)


def plot_lateral_forces(series: Mapping[str, TopicSeries], path: Path, t0: int = 0) -> Path:
    """Kim & Huh Figs. 5-6 style: estimated vs true lateral force per tire."""
    s = series[FORCES]
    truth = series.get(TRUTH_FORCES)
    return _plot_per_tire(
        path, 'Tire lateral forces by SKFMEC (cf. Kim & Huh Figs. 5-6)', 'lateral force (N)',
        seconds(s, t0), np.asarray(s.fields['fy'], dtype=float),
        None if truth is None else (seconds(truth, t0), truth.fields['fy']),
        panel='{} Fy', truth_lw=1.0)


# ---------------------------------------------------------------------------------------------
# The domain


def _tpms_outputs_recorded(series: Mapping[str, TopicSeries], _: Sequence[Metric]) -> bool:
    return any(f'/tpms/indication/{m}' in series for m in TPMS_METHODS) or WARNING in series


# The methods in scoreboard order, each with the paper figure it reproduces.
SCORINGS = (
    MethodScoring('tpms', tpms_metrics, plot_warnings, 'persson_fig9_warnings.png',
                  drawn=_tpms_outputs_recorded),
    MethodScoring('stiffness', pressure_metric, plot_pressure, 'umeno_fig11_pressure.png'),
    MethodScoring('lateral_force', lateral_force_metric, plot_lateral_forces,
                  'kim_huh_fig5_6_lateral_forces.png'))


def evaluate(series: Mapping[str, TopicSeries], scenario: str, figure_dir: Path,
             methods: Sequence[str] = ()) -> Evaluation:
    """Score a road recording (``methods``: of ``tpms``, ``stiffness``, ``lateral_force``;
    empty: all present); figures into ``figure_dir`` (see ``score_methods``)."""
    return score_methods(series, scenario, figure_dir, methods, SCORINGS,
                         (TRUTH_PRESSURE, TRUTH_FORCES))


def _run_parameters(run_dir: Path) -> dict[str, dict[str, str]]:
    # Calibrations are learned in the run and kept beside its recording, not in ~/.ros.
    return {node: {'calibration_file': str(run_dir / f'{node}_calibration.yaml')}
            for node in ('tire_stiffness_observer', 'vibration_analyzer',
                         'wheel_radius_analyzer')}


def domain() -> Domain:
    """The road domain for the main job and the evaluation CLI."""
    bags = workspace_bags()
    return Domain(
        name='road',
        graph=share_dir('tpms_ros', 'config') / 'road_graph.yaml',
        player='vehicle_simulator',
        recorder='road_recorder',
        input_topics=('/vehicle/wheel_speeds', '/vehicle/imu', '/vehicle/driver_inputs'),
        sync_topics=('/tpms/tire_stiffness', '/tpms/tire_resonance', '/tpms/wheel_radius',
                     '/vehicle/tire_forces'),
        scenarios=(
            Scenario('road_puncture_15pct_fl', bags / 'road_puncture_15pct_fl',
                     'FL loses 15 % (200 -> 170 kPa in 10 s) at 90 s, 70 km/h, 240 s: the TPMS '
                     'methods calibrate on the first 60-80 s, then must find FL.',
                     ('tpms', 'stiffness')),
            Scenario('road_kim_huh_lateral', bags / 'road_kim_huh_lateral',
                     'Kim & Huh test: 70 km/h braking in a turn, steer 1 -> 2 deg, friction '
                     '1.1 -> 0.2, car 200 kg heavier than the observer model, 10 s.',
                     ('lateral_force',)),
        ),
        evaluate=evaluate,
        synthesize=scenario_topics,
        is_scenario=loads_as_scenario(load_scenario, (ValueError, OSError)),
        run_parameters=_run_parameters,
        read_topics=READ_TOPICS,
    )
