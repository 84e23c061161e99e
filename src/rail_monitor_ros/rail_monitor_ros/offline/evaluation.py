"""Scoring a rail graph's recording against ground truth (docs/targets.md), and the rail figures.

ROS-free: works on the column-wise series of a recording
(:func:`vehicle_monitor_common.evaluation.read_stamped_series`, header stamps). Registered for
the main job and the evaluation CLI under ``vehicle_monitor.evaluations`` as ``rail``
(:func:`domain`).

Key figures, each against its docs/targets.md floor:

- IMM (``rail/suspension/modes``), per fault onset in the truth of the monitored (front) bogie:
  detection delay, from the onset to the first sample at which the smoothed probability of the
  correct hypothesis exceeds 0.5 -- target 0.5 s for a spring fault, 1 s for a damper fault.
  The correct hypothesis is every mode whose assumed spring and damper ratios are both within
  half a grid step (0.05) of the truth (with the adaptive mode set a damper mode also carries
  the estimated spring ratio, so a spring fault may be held by two modes). The verdict also
  requires no fault declared (``fault_detected`` rising) before the first onset; a run without
  a fault scores its false alarms (target 0).
- Creep estimator (``rail/creep_factor``, and ``rail/creep_factor_imu`` for the IMU-only pattern
  D), per step of the true creep factor: settling time, after which the estimate stays within
  +/-5 % (pattern D: +/-10 %) of the truth until the next step -- target 1 s; the worst step.

Without truth: the first fault declared and its component; the last creep factor.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from rail_monitor_ros.simulation.rail_scenario import load_rail_scenario
from rail_monitor_ros.simulation.rail_simulator import scenario_topics
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
    stack_column,
)
from vehicle_monitor_common.figures import pyplot, save_figure
from vehicle_monitor_common.resources import share_dir, workspace_bags
from vehicle_monitor_common.series import TopicSeries

MODES = '/rail/suspension/modes'
TRUTH_SUSPENSION = '/truth/suspension'
TRUTH_CREEP = '/truth/creep_factor'
# Creep outputs scored: topic -> (method name, tolerance). Pattern D (accelerometers and gyro
# only) has the looser target.
CREEP_OUTPUTS = {'/rail/creep_factor': ('creep factor', 0.05),
                 '/rail/creep_factor_imu': ('creep factor (IMU, D)', 0.10)}
READ_TOPICS = (MODES, TRUTH_SUSPENSION, TRUTH_CREEP, *CREEP_OUTPUTS)

MONITORED_BOGIE = 0           # front bogie, as the suspension monitor's model
DETECTION_PROBABILITY = 0.5
SPRING_TARGET_S = 0.5
DAMPER_TARGET_S = 1.0
HALF_STEP = 0.05 + 1e-9       # half the 10 % grid of the mode set
SETTLE_TARGET_S = 1.0
# A truth change larger than this starts a fault or a creep step.
CHANGE = 0.01



# ---------------------------------------------------------------------------------------------
# IMM


def fault_onsets(t: np.ndarray, spring: np.ndarray, damper: np.ndarray,
                 ) -> list[tuple[str, float, int]]:
    """(component, onset time, truth index) of each change of the true ratios, in time order."""
    onsets = []
    for component, ratio in (('spring', spring), ('damper', damper)):
        changed = np.flatnonzero(np.abs(np.diff(ratio)) > CHANGE) + 1
        onsets += [(component, float(t[k]), int(k)) for k in changed]
    return sorted(onsets, key=lambda item: item[1])


def imm_metrics(series: Mapping[str, TopicSeries], t0: int) -> list[Metric]:
    """Detection delay per fault onset and false alarms of the IMM monitor."""
    if MODES not in series or not len(series[MODES]):
        return []
    s = series[MODES]
    t = seconds(s, t0)
    declared = np.asarray(s.fields['fault_detected'], dtype=bool)
    truth = series.get(TRUTH_SUSPENSION)
    if truth is None or not len(truth):
        first = np.flatnonzero(declared)
        if not first.size:
            return [Metric('IMM', 'first fault declared', None, 's', detail='no fault declared')]
        k = int(first[0])
        component = s.fields['fault_component'][k] if 'fault_component' in s.fields else ''
        return [Metric('IMM', 'first fault declared', float(t[k]), 's',
                       detail=f'{component or "fault"} declared at {t[k]:.2f} s, spring ratio '
                              f'{s.fields["spring_ratio"][k]:.2f}, damper ratio '
                              f'{s.fields["damper_ratio"][k]:.2f}')]
    t_truth = seconds(truth, t0)
    spring = np.asarray(truth.fields['spring_ratio'], dtype=float)[:, MONITORED_BOGIE]
    damper = np.asarray(truth.fields['damper_ratio'], dtype=float)[:, MONITORED_BOGIE]
    onsets = fault_onsets(t_truth, spring, damper)
    first_onset = onsets[0][1] if onsets else np.inf
    false_alarms = int((rising_edges(declared) & (t < first_onset)).sum())
    if not onsets:
        return [Metric('IMM', 'false alarms (healthy suspension)', float(false_alarms), '', '0',
                       false_alarms == 0,
                       f'fault declared {false_alarms} time(s)' if false_alarms
                       else 'no fault declared')]
    smoothed = stack_column(s.fields['smoothed_probability'])
    mode_spring = stack_column(s.fields['mode_spring_ratio'])
    mode_damper = stack_column(s.fields['mode_damper_ratio'])
    true_spring = hold_at(t_truth, spring, t)
    true_damper = hold_at(t_truth, damper, t)
    correct = ((np.abs(mode_spring - true_spring[:, None]) <= HALF_STEP)
               & (np.abs(mode_damper - true_damper[:, None]) <= HALF_STEP))
    correct_probability = np.where(correct, smoothed, 0.0).sum(axis=1)
    names = np.asarray(s.fields['modes'][-1], dtype=object) if 'modes' in s.fields else None
    metrics = []
    for index, (component, onset, k_truth) in enumerate(onsets):
        end = onsets[index + 1][1] if index + 1 < len(onsets) else np.inf
        window = (t >= onset) & (t < end)
        hit = np.flatnonzero(window & (correct_probability > DETECTION_PROBABILITY))
        target_s = SPRING_TARGET_S if component == 'spring' else DAMPER_TARGET_S
        label = (f'{component} {100 * (spring if component == "spring" else damper)[k_truth]:.0f}'
                 f' % at {onset:.2f} s')
        alarms = f'; {false_alarms} false alarm(s) before the first fault'
        if not hit.size:
            best = float(correct_probability[window].max()) if window.any() else 0.0
            metrics.append(Metric('IMM', f'{component} fault detection delay', None, 's',
                                  f'<= {target_s:g} s', False,
                                  f'{label}: correct mode never > {DETECTION_PROBABILITY} '
                                  f'(best {best:.2f}){alarms}'))
            continue
        k = int(hit[0])
        delay = float(t[k] - onset)
        modes = ', '.join(str(names[j]) for j in np.flatnonzero(correct[k])) if (
            names is not None and len(names) == correct.shape[1]) else ''
        metrics.append(Metric('IMM', f'{component} fault detection delay', delay, 's',
                              f'<= {target_s:g} s', delay <= target_s and false_alarms == 0,
                              f'{label}: {modes or "correct mode"} > {DETECTION_PROBABILITY} '
                              f'at {t[k]:.2f} s{alarms}'))
    return metrics


# ---------------------------------------------------------------------------------------------
# Creep


def settling_times(t: np.ndarray, estimate: np.ndarray, t_truth: np.ndarray,
                   truth: np.ndarray, tolerance: float) -> list[tuple[float, float, float | None]]:
    """(step time, true factor after it, settling time or None) for each step of the truth.

    Settling time: from the step to the first estimate after which every estimate until the
    next step is within ``tolerance`` (relative) of the truth.
    """
    steps = np.flatnonzero(np.abs(np.diff(truth)) > CHANGE) + 1
    true_at = hold_at(t_truth, truth, t)
    inside = np.abs(estimate / true_at - 1.0) <= tolerance
    results: list[tuple[float, float, float | None]] = []
    for index, k in enumerate(steps):
        step_t = float(t_truth[k])
        end = float(t_truth[steps[index + 1]]) if index + 1 < len(steps) else np.inf
        window = np.flatnonzero((t >= step_t) & (t < end))
        if not window.size:
            results.append((step_t, float(truth[k]), None))
            continue
        outside = np.flatnonzero(~inside[window])
        if not outside.size:
            results.append((step_t, float(truth[k]), float(t[window[0]] - step_t)))
        elif outside[-1] + 1 < window.size:
            results.append((step_t, float(truth[k]),
                            float(t[window[outside[-1] + 1]] - step_t)))
        else:
            results.append((step_t, float(truth[k]), None))
    return results


def creep_metrics(series: Mapping[str, TopicSeries], t0: int) -> list[Metric]:
    """Settling time of each creep output present (worst step)."""
    truth = series.get(TRUTH_CREEP)
    metrics = []
    for topic, (method, tolerance) in CREEP_OUTPUTS.items():
        if topic not in series or not len(series[topic]):
            continue
        s = series[topic]
        t = seconds(s, t0)
        estimate = np.asarray(s.fields['creep_factor'], dtype=float)
        if truth is None or not len(truth):
            metrics.append(Metric(method, 'last creep factor', float(estimate[-1]), '',
                                  detail=f'c = {estimate[-1]:.3f} at {t[-1]:.1f} s'))
            continue
        figure = f'settling within +/-{100 * tolerance:.0f} %'
        target = f'<= {SETTLE_TARGET_S:g} s'
        steps = settling_times(t, estimate, seconds(truth, t0),
                               np.asarray(truth.fields['creep_factor'], dtype=float), tolerance)
        if not steps:
            continue  # a constant creep factor has nothing to settle to
        text = '; '.join(f'step to {c:.2f} at {ts:.1f} s: '
                         + (f'{settle:.2f} s' if settle is not None else 'never')
                         for ts, c, settle in steps)
        if any(settle is None for _, _, settle in steps):
            metrics.append(Metric(method, figure, None, 's', target, False, text))
            continue
        worst = max(settle for _, _, settle in steps if settle is not None)
        metrics.append(Metric(method, figure, worst, 's', target, worst <= SETTLE_TARGET_S,
                              text))
    return metrics


# ---------------------------------------------------------------------------------------------
# Figures


def plot_mode_probabilities(series: Mapping[str, TopicSeries], path: Path, t0: int = 0) -> Path:
    """Mori Fig. 5 style: smoothed mode probabilities over time, with the true ratios."""
    plt = pyplot()

    s = series[MODES]
    t = seconds(s, t0)
    smoothed = stack_column(s.fields['smoothed_probability'])
    names = list(s.fields['modes'][-1]) if 'modes' in s.fields else [
        f'mode {j + 1}' for j in range(smoothed.shape[1])]
    truth = series.get(TRUTH_SUSPENSION)
    fig, axes = plt.subplots(2 if truth is not None else 1, 1, figsize=(10, 6), sharex=True,
                             squeeze=False)
    ax = axes[0, 0]
    shown = np.flatnonzero(smoothed.max(axis=0) > 0.1)
    for j in range(smoothed.shape[1]):
        ax.plot(t, smoothed[:, j], lw=1.5 if j in shown else 0.5,
                label=f'{j + 1}: {names[j]}' if j in shown else None,
                color=None if j in shown else '0.8')
    ax.set_ylabel('smoothed probability')
    ax.set_ylim(-0.02, 1.02)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8, loc='center right')
    if truth is not None:
        ax = axes[1, 0]
        t_truth = seconds(truth, t0)
        ax.plot(t_truth, truth.fields['spring_ratio'][:, MONITORED_BOGIE], 'k--',
                label='true spring')
        ax.plot(t_truth, truth.fields['damper_ratio'][:, MONITORED_BOGIE], 'r--',
                label='true damper')
        ax.plot(t, s.fields['spring_ratio'], 'k', lw=1, label='estimated spring')
        ax.plot(t, s.fields['damper_ratio'], 'r', lw=1, label='estimated damper')
        ax.set_ylabel('ratio to nominal')
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8, ncol=2)
    axes[-1, 0].set_xlabel('time (s)')
    fig.suptitle('IMM secondary-suspension monitor: mode probabilities (cf. Mori Fig. 5)')
    return save_figure(fig, path)


def plot_creep(series: Mapping[str, TopicSeries], path: Path, t0: int = 0) -> Path:
    """Chonan Fig. 7 style: estimated creep factor vs the true one, with the tolerance band."""
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(10, 4))
    truth = series.get(TRUTH_CREEP)
    if truth is not None:
        t_truth = seconds(truth, t0)
        c = np.asarray(truth.fields['creep_factor'], dtype=float)
        ax.plot(t_truth, c, 'k--', label='truth')
        ax.fill_between(t_truth, 0.95 * c, 1.05 * c, color='k', alpha=0.1, label='+/-5 %')
    for topic, (method, _) in CREEP_OUTPUTS.items():
        if topic in series:
            ax.plot(seconds(series[topic], t0), series[topic].fields['creep_factor'], lw=1,
                    label=method)
    ax.set_xlabel('time (s)')
    ax.set_ylabel('creep factor c')
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title('Creep factor by augmented EKF (cf. Chonan Fig. 7)')
    return save_figure(fig, path)


# ---------------------------------------------------------------------------------------------
# The domain


# The methods in scoreboard order, each with the paper figure it reproduces.
SCORINGS = (
    MethodScoring('imm', imm_metrics, plot_mode_probabilities,
                  'mori_fig5_mode_probabilities.png'),
    MethodScoring('creep', creep_metrics, plot_creep, 'chonan_fig7_creep.png'))


def evaluate(series: Mapping[str, TopicSeries], scenario: str, figure_dir: Path,
             methods: Sequence[str] = ()) -> Evaluation:
    """Score a rail recording (``methods``: of ``imm``, ``creep``; empty: all present);
    figures into ``figure_dir`` (see ``score_methods``)."""
    return score_methods(series, scenario, figure_dir, methods, SCORINGS,
                         (TRUTH_SUSPENSION, TRUTH_CREEP))


def domain() -> Domain:
    """The rail domain for the main job and the evaluation CLI."""
    bags = workspace_bags()
    return Domain(
        name='rail',
        graph=share_dir('rail_monitor_ros', 'config') / 'rail_graph.yaml',
        player='rail_simulator',
        recorder='rail_recorder',
        input_topics=('/rail/bogie/imu', '/rail/body/imu', '/rail/lateral_states'),
        sync_topics=(MODES, *CREEP_OUTPUTS),
        scenarios=(
            Scenario('rail_imm_spring_damper_fault', bags / 'rail_imm_spring_damper_fault',
                     'Mori et al. run: straight track, front bogie secondary lateral spring '
                     '150 % at 3 s, damper also 50 % at 6 s, 10 s.', ('imm',)),
            Scenario('rail_creep_steps', bags / 'rail_creep_steps',
                     'Chonan & Tsunashima run: 144 km/h, creep factor 1.0 -> 0.4 at 5 s -> 0.6 '
                     'at 10 s, 15 s; healthy suspension (the IMM must stay quiet).',
                     ('creep', 'imm')),
            Scenario('rail_speed_change', bags / 'rail_speed_change',
                     'A train braking 44 -> 36 m/s over 2-12 s (its speed on rail/speed), '
                     'creep factor 1.0 -> 0.6 at 6 s, 14 s; healthy suspension.',
                     ('creep', 'imm')),
        ),
        evaluate=evaluate,
        synthesize=scenario_topics,
        is_scenario=loads_as_scenario(load_rail_scenario,
                                      (ValueError, OSError, TypeError, KeyError)),
        read_topics=READ_TOPICS,
    )
