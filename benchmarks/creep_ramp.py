"""The creep estimator on a ramp of c: how settings judged on the family's steps follow a
gradual adhesion change.

The family's creep runs (``eval_rail_family.py``) step c (1 -> 0.5 -> 0.75), which the CUSUM
alarm and the onset search follow; a gradual change (a rail getting wet or greasy over a few
hundred metres) is followed by the ln c walk alone. This runs each car of a development set
once: c = 1 for 5 s, a ramp to ``--to`` over ``--ramp-s``, then 10 s at it (the simulator's
``ramp`` event), pattern C with the exact track or a 0.3 mm map (``--track``), the car at its
first family creep speed, and prints per setting the relative error during the ramp (from 1 s
after it begins: rms median, largest median and worst) and the largest error from 1 s after it
ends. Never on held-out cars: settings are judged here.

Run: ``source tools/env.sh && python benchmarks/creep_ramp.py [--seeds development]
[--settings shipped creep_walk_std_per_sqrt_s=0.02,change_log_std=0.8] [--ramp-s 15]
[--to 0.5] [--track exact] [--plot ramp.png]``: each setting is ``shipped`` or comma-separated
creep estimator parameters (``NAME=VALUE``, as ``eval_rail_family.py --creep-set``) over the
shipped ones; ``--plot`` draws the first car's run per setting.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any

from eval_rail_family import (
    MAP_ERROR,
    case_seed,
    creep_inputs,
    creep_params,
    creep_track,
    sample_speeds,
    simulate,
)
import numpy as np

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams
from rail_monitor_ros.simulation.rail_family import (
    DEVELOPMENT_SEEDS,
    WIDE_DEVELOPMENT_SEEDS,
    FamilyCar,
    family,
    scenario_mapping,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from vehicle_monitor_common.figures import pyplot, save_figure
from vehicle_monitor_common.parameters import ConfigurationError, parse_assignments

SEED_SETS = {'development': DEVELOPMENT_SEEDS, 'development-wide': WIDE_DEVELOPMENT_SEEDS}
#: c before the ramp, and how long it is held before and after it, s.
START, BEFORE_S, AFTER_S = 1.0, 5.0, 10.0


def parse_setting(text: str) -> dict[str, Any]:
    """``shipped`` -> {}; ``NAME=VALUE,NAME=VALUE`` -> those creep estimator parameters.

    Raises:
        ConfigurationError: a malformed assignment, a name that is not a parameter, or a value
            its checks refuse.
    """
    if text == 'shipped':
        return {}
    return parse_assignments(text.split(','), CreepEkfParams())


def ramp_runs(car: FamilyCar, settings: Mapping[str, Mapping[str, Any]], ramp_s: float,
              to: float, track_kind: str) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The car's ramp once simulated, filtered per setting (its name -> its parameters over the
    shipped ones, :func:`parse_setting`): (time, the true c, per setting the estimate)."""
    speed = sample_speeds(car, 2)[0]
    events = [{'time': BEFORE_S, 'creep_factor': to, 'ramp': ramp_s}]
    map_error = MAP_ERROR if track_kind == 'map0.3' else 0.0
    result = simulate(rail_scenario_from_dict(scenario_mapping(
        car, f'family_{car.seed}_ramp_{speed:g}', speed, case_seed(car, 300),
        BEFORE_S + ramp_s + AFTER_S, events, {'creep_factor': START}, map_error)))
    z = creep_inputs(result, 'C', True)
    track = creep_track(result)
    estimates = {}
    for setting, overrides in settings.items():
        params = creep_params(car, speed, f'C-spec/{track_kind}', 'spectrum', True, overrides)
        estimates[setting] = CreepEkf(params).run(z, track, result.speed).creep_factor
    return result.time, result.creep_factor, estimates


def ramp_errors(car: FamilyCar, settings: Mapping[str, Mapping[str, Any]], ramp_s: float,
                to: float, track_kind: str) -> dict[str, tuple[float, float, float]]:
    """Per setting (:func:`ramp_runs`): (rms relative error during the ramp, its largest, the
    largest after it)."""
    return run_errors(*ramp_runs(car, settings, ramp_s, to, track_kind), ramp_s)


def run_errors(time: np.ndarray, truth: np.ndarray, estimates: Mapping[str, np.ndarray],
               ramp_s: float) -> dict[str, tuple[float, float, float]]:
    """:func:`ramp_errors` of runs already made."""
    during = (time >= BEFORE_S + 1.0) & (time <= BEFORE_S + ramp_s)
    after = time > BEFORE_S + ramp_s + 1.0
    out = {}
    for setting, estimate in estimates.items():
        error = np.abs(estimate - truth) / truth
        out[setting] = (float(np.sqrt(np.nanmean(error[during] ** 2))),
                        float(np.nanmax(error[during])), float(np.nanmax(error[after])))
    return out


def plot_ramp(path: str, car: FamilyCar, time: np.ndarray, truth: np.ndarray,
              estimates: Mapping[str, np.ndarray], ramp_s: float, to: float,
              track_kind: str) -> None:
    """The true c and each setting's estimate on one car's ramp (:func:`ramp_runs`), one line
    per setting."""
    plt = pyplot()
    fig, axis = plt.subplots(figsize=(8.0, 4.0))
    axis.plot(time, truth, color='k', linewidth=1.5, label='true c')
    for setting, estimate in estimates.items():
        axis.plot(time, estimate, linewidth=0.9, label=setting)
    axis.set_xlabel('time, s')
    axis.set_ylabel('creep factor c')
    axis.set_ylim(0.3, 1.3)
    axis.grid(alpha=0.3)
    axis.legend(fontsize=7)
    axis.set_title(f'Creep estimator, pattern C ({track_kind} track), car {car.seed}: '
                   f'c {START:g} -> {to:g} over {ramp_s:g} s')
    print(f'wrote {save_figure(fig, path)}')


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', choices=tuple(SEED_SETS), default='development')
    parser.add_argument('--cars', type=int, default=0, help='first N cars (0: all)')
    parser.add_argument('--settings', nargs='+', default=['shipped'],
                        help="'shipped', or creep estimator parameters over the shipped "
                             "ones: name=value,name=value")
    parser.add_argument('--ramp-s', type=float, default=15.0)
    parser.add_argument('--to', type=float, default=0.5, help='c at the end of the ramp')
    parser.add_argument('--track', choices=('exact', 'map0.3'), default='exact')
    parser.add_argument('--plot', metavar='PNG',
                        help="also draw the first car's run per setting into this file")
    args = parser.parse_args(argv)
    settings = {}
    for setting in args.settings:
        try:
            settings[setting] = parse_setting(setting)     # refused before the runs
        except ConfigurationError as exc:
            parser.error(f'--settings {setting}: {exc}')
    cars = family(SEED_SETS[args.seeds])
    if args.cars:
        cars = cars[:args.cars]
    rows: dict[str, list[tuple[float, float, float]]] = {s: [] for s in args.settings}
    for car in cars:
        runs = ramp_runs(car, settings, args.ramp_s, args.to, args.track)
        if args.plot and car is cars[0]:
            plot_ramp(args.plot, car, *runs, args.ramp_s, args.to, args.track)
        errors = run_errors(*runs, args.ramp_s)
        for setting, figures in errors.items():
            rows[setting].append(figures)
        print(f'car {car.seed} done', flush=True)
    print(f'\n| setting | {args.ramp_s:g} s ramp {START:g} -> {args.to:g} ({args.track} track): '
          'error during it, rms median; largest, median / worst | largest from 1 s after it, '
          'worst |')
    print('| --- | --- | --- |')
    for setting in args.settings:
        table = 100.0 * np.array(rows[setting])
        print(f'| {setting} | {np.median(table[:, 0]):.1f} %; {np.median(table[:, 1]):.1f} / '
              f'{table[:, 1].max():.1f} % | {table[:, 2].max():.1f} % |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
