"""Evaluation of the tire stiffness observer core (Umeno 1997) on the road simulator.

Runs the seeded scenarios offline through :class:`TireStiffnessObserver` (no ROS) and compares
the estimated pressure of all four tires with the simulator's truth:

* Umeno test (FR non-driven and RL driven stepped 200 -> 120 kPa in 20 kPa steps, 60 and
  90 km/h, smooth asphalt and rough concrete, rear-drive car): each scenario without
  drive-wheel compensation (``driven_axle: none``), with the paper's difference form and
  with the partner form (``rear``). Steady-state
  RMS error per tire per case (last ``STEADY_S`` of each 40 s level, after calibration); PNG per
  scenario like the paper's Figs. 11-12 and a cross-talk PNG like Fig. 13 (the unchanged FL and
  RR estimates).
* Four-tire diffusion 15 % and 25 %: flag state of every tire at the end and when each was first
  flagged (the relative methods cannot see an equal loss).

Every run calibrates over the first ``CALIBRATION_S`` of data (tires at 200 kPa); the estimator
parameters are the core's defaults otherwise (encoder tooth-error correction on).

Run: PYTHONPATH=src/tpms_ros:src/vehicle_monitor_common \
    python benchmarks/eval_stiffness_observer.py --out /tmp/stiffness_eval
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from tpms_ros.core.stiffness_observer import StiffnessObserverParams, TireStiffnessObserver
from tpms_ros.simulation.road_simulator import RoadSimulationResult, simulate_file
from vehicle_monitor_common.figures import pyplot, save_figure

SCENARIOS = Path(__file__).resolve().parents[1] / 'src' / 'tpms_ros' / 'scenarios'
UMENO = [f'umeno_step_{speed}kmh_{surface}' for speed in (60, 90)
         for surface in ('smooth_asphalt', 'rough_concrete')]
DIFFUSION = ['diffusion_15pct', 'diffusion_25pct']
WHEELS = ('FL', 'FR', 'RL', 'RR')
# The calibration starts once the rings are learned (tooth_learned_s, 15 s of data) and must end
# before the Umeno scenarios' first step at 40 s.
CALIBRATION_S = 20.0
CHUNK = 250          # samples per update (0.25 s at 1 kHz), as the node feeds the core
LEVEL_S = 40.0       # Umeno scenarios: each pressure level is held 40 s
STEADY_S = 15.0      # steady-state window at the end of each level
PARTNER = 'rear, partner'
COMPENSATIONS = {
    'none': StiffnessObserverParams(driven_axle='none'),
    'rear, difference': StiffnessObserverParams(driven_axle='rear',
                                                drive_compensation='difference'),
    PARTNER: StiffnessObserverParams(driven_axle='rear', drive_compensation='partner'),
}


@dataclass(frozen=True)
class Track:
    """Estimates of one run, one row per update.

    Attributes:
        t: update times, s.
        pressure: (N, 4) estimated pressure, kPa (NaN before the first estimate).
        truth: (N, 4) true pressure at the same times, kPa.
        underinflated: (N, 4) warning flags.
        calibrated: (N,) all four tires calibrated.
    """

    t: np.ndarray
    pressure: np.ndarray
    truth: np.ndarray
    underinflated: np.ndarray
    calibrated: np.ndarray


def run_core(result: RoadSimulationResult, params: StiffnessObserverParams) -> Track:
    """Feed the simulated wheel speeds through a calibrating core in CHUNK-sample updates."""
    observer = TireStiffnessObserver(params)
    observer.start_calibration(CALIBRATION_S)
    t_all, omega = result.wheel_speed_t, result.wheel_speed
    rows = []
    for start in range(0, t_all.size - CHUNK + 1, CHUNK):
        est = observer.update(omega[start:start + CHUNK], stamps=t_all[start:start + CHUNK])
        rows.append((est.stamp, est.pressure_kpa.copy(), est.underinflated.copy(),
                     est.calibrated and not observer.calibrating))
    t = np.array([r[0] for r in rows])
    truth = np.column_stack([np.interp(t, result.handling.t, result.pressure_kpa[:, w])
                             for w in range(4)])
    return Track(t, np.array([r[1] for r in rows]), truth, np.array([r[2] for r in rows]),
                 np.array([r[3] for r in rows]))


def steady_mask(track: Track, duration_s: float) -> np.ndarray:
    """Update rows in the last STEADY_S of each 40 s level, after the calibration."""
    phase = np.mod(track.t, LEVEL_S)
    mask = (phase >= LEVEL_S - STEADY_S) & (track.t < duration_s - 0.5) & track.calibrated
    return mask & (track.t > CALIBRATION_S)


def rms_error(track: Track, mask: np.ndarray) -> np.ndarray:
    """(4,) RMS of estimated minus true pressure over the rows in ``mask``, kPa."""
    diff = track.pressure[mask] - track.truth[mask]
    return np.sqrt(np.nanmean(diff ** 2, axis=0))


def plot_umeno(name: str, tracks: dict[str, Track], path: Path) -> None:
    """PNG like Figs. 11-12: estimated vs true pressure, one panel per tire, per mode."""
    plt = pyplot()

    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True, sharey=True)
    for w, ax in enumerate(axes.ravel()):
        first = next(iter(tracks.values()))
        ax.plot(first.t, first.truth[:, w], 'k', lw=1.5, label='truth')
        for label, track in tracks.items():
            shown = np.where(track.calibrated, track.pressure[:, w], np.nan)
            ax.plot(track.t, shown, lw=0.8, label=label)
        ax.set_title(f'{WHEELS[w]}{" (driven)" if w >= 2 else ""}')
        ax.set_ylim(80, 260)
        ax.grid(alpha=0.3)
    for ax in axes[1]:
        ax.set_xlabel('t, s')
    for ax in axes[:, 0]:
        ax.set_ylabel('pressure, kPa')
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f'{name}: estimated vs true pressure (calibrated over the first '
                 f'{CALIBRATION_S:g} s)')
    save_figure(fig, path)


def plot_crosstalk(tracks: dict[str, Track], path: Path) -> None:
    """PNG like Fig. 13: the unchanged tires (FL, RR) while FR and RL drop, every scenario."""
    plt = pyplot()

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, w in zip(axes, (0, 3), strict=True):
        for label, track in tracks.items():
            ax.plot(track.t, np.where(track.calibrated, track.pressure[:, w] - track.truth[:, w],
                                      np.nan), lw=0.8, label=label)
        ax.axhline(0.0, color='k', lw=1)
        ax.set_title(f'{WHEELS[w]} (unchanged, 200 kPa): estimate - truth')
        ax.set_xlabel('t, s')
        ax.grid(alpha=0.3)
    axes[0].set_ylabel('kPa')
    axes[0].legend(fontsize=7)
    save_figure(fig, path)


def level_means(track: Track, duration_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Steady-state mean of the estimate and of the truth per level: ((L, 4), (L, 4))."""
    mask = steady_mask(track, duration_s)
    level = np.floor(track.t / LEVEL_S)
    est, truth = [], []
    for lvl in np.unique(level[mask]):
        rows = mask & (level == lvl)
        est.append(np.nanmean(track.pressure[rows], axis=0))
        truth.append(track.truth[rows].mean(axis=0))
    return np.array(est), np.array(truth)


def plot_estimated_vs_true(levels: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]],
                           path: Path) -> None:
    """PNG like Figs. 11-12: steady-state estimate vs true pressure per level and scenario.

    Panels: FR (non-driven, Fig. 11), RL without compensation (Fig. 12 a), with the paper's
    difference compensation (Fig. 12 b) and with the partner compensation.

    Args:
        levels: scenario -> mode label -> (estimate (L, 4), truth (L, 4)) from level_means.
        path: PNG file to write.
    """
    plt = pyplot()

    panels = [('FR (non-driven)', PARTNER, 1),
              ('RL (driven), no compensation', 'none', 2),
              ("RL (driven), paper's difference", 'rear, difference', 2),
              ('RL (driven), partner compensation', PARTNER, 2)]
    fig, axes = plt.subplots(2, 2, figsize=(10, 9), sharex=True, sharey=True)
    axes = axes.ravel()
    for ax, (title, mode, wheel) in zip(axes, panels, strict=True):
        for name, modes in levels.items():
            est, truth = modes[mode]
            ax.plot(truth[:, wheel], est[:, wheel], 'o-', ms=5,
                    label=name.replace('umeno_step_', ''))
        ax.plot([100, 220], [100, 220], 'k', lw=1)
        for offset in (-10, 10):
            ax.plot([100, 220], [100 + offset, 220 + offset], 'k:', lw=0.8)
        ax.set_title(title)
        ax.set_xlabel('true pressure, kPa')
        ax.set_xlim(110, 210)
        ax.set_ylim(110, 210)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel('estimated pressure (steady state), kPa')
    axes[0].legend(fontsize=8)
    fig.suptitle('Estimated vs true pressure per level (dotted: +-10 kPa target)')
    save_figure(fig, path)


def evaluate_umeno(out: Path, names: list[str]) -> None:
    """Umeno scenarios: RMS table and figures."""
    print(f'Steady-state RMS error of the pressure estimate, kPa (last {STEADY_S:g} s of each '
          f'{LEVEL_S:g} s level; FR non-driven and RL driven deflated, FL/RR unchanged)')
    print(f'{"scenario":<34}{"compensation":<18}' + ''.join(f'{w:>8}' for w in WHEELS))
    crosstalk: dict[str, Track] = {}
    levels: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]] = {}
    for name in names:
        result = simulate_file(SCENARIOS / f'{name}.yaml')
        tracks = {}
        for label, params in COMPENSATIONS.items():
            track = run_core(result, params)
            tracks[label] = track
            levels.setdefault(name, {})[label] = level_means(track, result.scenario.duration_s)
            error = rms_error(track, steady_mask(track, result.scenario.duration_s))
            print(f'{name:<34}{label:<18}' + ''.join(f'{e:8.1f}' for e in error))
        crosstalk[name.replace('umeno_step_', '')] = tracks[PARTNER]
        plot_umeno(name, tracks, out / f'{name}.png')
    plot_crosstalk(crosstalk, out / 'umeno_crosstalk.png')
    plot_estimated_vs_true(levels, out / 'umeno_estimated_vs_true.png')


def evaluate_diffusion(out: Path, names: list[str]) -> None:
    """Four-tire diffusion: flagged tires at the end, first flag time, final estimates.

    Each run is scored against the default warning threshold (0.85 x nominal, on which a 15 %
    loss sits exactly) and against 0.9 x nominal (warn 20 kPa below placard).
    """
    print(f'\nFour-tire diffusion (starts at 60 s, 30 kPa/min), {PARTNER}')
    print(f'{"scenario":<18}{"threshold":>10}{"tire":>6}{"truth end":>10}{"est end":>9}'
          f'{"flagged end":>13}{"first flag s":>14}')
    for name in names:
        result = simulate_file(SCENARIOS / f'{name}.yaml')
        for ratio in (0.85, 0.9):
            track = run_core(result, replace(COMPENSATIONS[PARTNER],
                                             warning_pressure_ratio=ratio))
            end = track.t > track.t[-1] - 20.0
            for w in range(4):
                flagged = np.flatnonzero(track.underinflated[:, w])
                first = f'{track.t[flagged[0]]:.1f}' if flagged.size else '-'
                print(f'{name:<18}{ratio:>10.2f}{WHEELS[w]:>6}{track.truth[-1, w]:10.1f}'
                      f'{np.nanmean(track.pressure[end, w]):9.1f}'
                      f'{track.underinflated[end, w].mean():13.0%}{first:>14}')
            if ratio == 0.85:
                plot_umeno(name, {PARTNER: track}, out / f'{name}.png')


def main() -> None:
    """Command line: evaluate, print tables, write PNGs under --out."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--out', required=True, type=Path, help='directory for the PNGs')
    parser.add_argument('--only', choices=('umeno', 'diffusion'), help='run one part only')
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.only != 'diffusion':
        evaluate_umeno(args.out, UMENO)
    if args.only != 'umeno':
        evaluate_diffusion(args.out, DIFFUSION)
    print(f'\nfigures in {args.out}')


if __name__ == '__main__':
    main()
