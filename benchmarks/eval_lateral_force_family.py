"""The lateral force observer on the family of cars: the paper's manoeuvre and ordinary drives.

The observer's figures were measured on the shipped car only (docs/methods/
lateral_force_observer.md). Here each car of the road family (``tpms_ros.simulation.
car_family``: passenger cars and light trucks, 1150-2700 kg, other wheelbases, tracks, CG
heights, wheel radii, IMU noise) runs four cases through the road simulator:

* ``kim_huh``: the shipped ``kim_huh_lateral.yaml`` driven by the car (70 km/h, steer 1 -> 2
  deg, braking, friction 1.1 -> 0.2, the car 200 kg heavier than the observer's model), the
  paper's test;
* ``urban``, ``rural``, ``motorway``: 60 s of the family's drives (corners, curves, lane
  changes), where the forces are smaller and the sensors' noise counts for more.

The observer gets what a user of the car can know: its body as measured (every
``ObserverVehicleParams`` field from the car: mass, inertias, geometry, roll stiffness and
damping, as the method's page asks; ``--body datasheet``: only mass, axle positions, tracks,
CG height and wheel, the rest at the defaults) and, with ``--split tire``, relation 2's
``split_exponent`` from the tire's Magic Formula data at the car's mean static wheel load
(``split_exponent_from_tire``; ``--split 0.6`` gives every car that number instead). The
figure is the paper's:
per-wheel Fy RMS error in % of that wheel's peak |Fy|, the worst wheel, target < 10 %.

Cars: ``--seeds tuning`` (``TUNING_SEEDS``; every choice is made there) or ``held-out``
(``HELD_OUT_SEEDS``, reported, never tuned on), or a list. Simulated cases are kept under
``--cache`` (a pickle per car and case) so that settings can be compared on the same drives;
``--set name=value`` overrides the observer's tuning (``ObserverTuningParams``).

``--scoreboard PATH`` also writes one row per case (cars within 10 %, the worst) as the main
job's scoreboard shows them (``vehicle_monitor_common.family_results``; committed as
``docs/results/lateral_force_family.json``); ``--report RUN.json`` writes it from a saved
``--json`` run instead of running. ``--plot PNG RUN.json [RUN.json ...]`` draws saved runs
against each other: per case, each car's worst wheel against its mass, with the 10 % target.

Run under tools/env.sh from the repository root:
``python benchmarks/eval_lateral_force_family.py --seeds tuning --cars 12 [--json F]``;
``python benchmarks/eval_lateral_force_family.py --seeds held-out --json /tmp/lf.json
--scoreboard docs/results/lateral_force_family.json``.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator, Mapping, Sequence
import dataclasses
import json
import math
import multiprocessing
from pathlib import Path
import pickle
import sys
import time
from typing import Any

import numpy as np

from tpms_ros.core.lateral_force_observer import ObserverTuningParams, ObserverVehicleParams
from tpms_ros.offline.lateral_force_tuning import (
    TuningCase,
    fy_error_percent,
    split_exponent_from_tire,
)
from tpms_ros.simulation import car_family
from tpms_ros.simulation.car_family import FamilyCar
from tpms_ros.simulation.road_scenario import load_scenario
from vehicle_monitor_common.family_results import (
    FamilyResults,
    FamilyRow,
    current_commit,
    today,
    write_family_results,
)
from vehicle_monitor_common.figures import pyplot, save_figure
from vehicle_monitor_common.parameters import parse_assignments, with_values

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_lateral_force_observer import SCENARIO, scenario_case  # noqa: E402

CASES = ('kim_huh', 'urban', 'rural', 'motorway')
CASE_TEXT = {
    'kim_huh': "the paper's manoeuvre (braking in a turn, friction 1.1 -> 0.2, model 200 kg "
               'light)',
    'urban': '60 s of urban driving', 'rural': '60 s of rural driving with curves',
    'motorway': '60 s of motorway driving with lane changes'}
DRIVE_S = 60.0
TARGET_PERCENT = 10.0
GRAVITY = 9.81
DEFAULT_MASS_KG = 1814.0   # the simulator's default car, whose wheels the tire is rated for


def with_varied_tire(car: FamilyCar) -> FamilyCar:
    """The car on a tire of its own (``--tires varied``): the simulator's Magic Formula tire
    rated for the car's wheel load (every load coefficient scaled so the tire at s times the
    load behaves as the original at the load, s = the car's mean wheel load over the default
    car's times 0.85-1.15: a light truck gets a truck tire), its cornering stiffness 0.85-1.15
    times, its curve's shape (a4) 0.9-1.1 times and its shape factor C 0.93-1.07 times, drawn
    from a stream of the car's seed apart from the family's (the car itself is unchanged)."""
    rng = np.random.default_rng(np.random.SeedSequence([21, car.seed, 7]))
    v, base = car.vehicle, car.vehicle.tire
    scale = v.m / DEFAULT_MASS_KG * float(rng.uniform(0.85, 1.15))
    tire = dataclasses.replace(
        base, a1=base.a1 / scale, a3=base.a3 * scale * float(rng.uniform(0.85, 1.15)),
        a4=base.a4 * float(rng.uniform(0.9, 1.1)), a5=base.a5 / scale,
        a6=base.a6 / scale ** 2, a7=base.a7 / scale, c_y=base.c_y * float(rng.uniform(0.93, 1.07)),
        b1=base.b1 / scale, b3=base.b3 / scale, b5=base.b5 / scale, b6=base.b6 / scale ** 2,
        b7=base.b7 / scale)
    return dataclasses.replace(car, vehicle=dataclasses.replace(v, tire=tire))


def simulate(car: FamilyCar, case: str) -> TuningCase:
    """One case of one car, simulated."""
    if case == 'kim_huh':
        scenario = car_family.apply_car(load_scenario(SCENARIO), car)
    else:
        scenario = car_family.car_scenario(car, case, DRIVE_S)
    return scenario_case(scenario)


def cached_case(car: FamilyCar, case: str, cache: Path | None, tires: str = 'simulator'
                ) -> TuningCase:
    """The case from the cache, or simulated (and kept there)."""
    suffix = '' if tires == 'simulator' else f'_{tires}'
    path = None if cache is None else cache / f'{car.seed}_{case}{suffix}.pkl'
    if path is not None and path.is_file():
        with path.open('rb') as handle:
            kept: TuningCase = pickle.load(handle)
        return kept
    made = simulate(car, case)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open('wb') as handle:
            pickle.dump(made, handle)
    return made


#: What a data sheet gives without measuring the car: mass, axle positions, tracks, CG height,
#: wheel; the rest (inertias, sprung mass, roll centres, roll stiffness and damping) is left at
#: the observer's defaults (``--body datasheet``).
DATASHEET = ('m', 'lf', 'lr', 'h', 'rw', 'iw', 'tf', 'tr')


def user_parameters(car: FamilyCar, split: str, body: str = 'measured'
                    ) -> ObserverVehicleParams:
    """What the car's user gives the observer: the body as measured (``measured``) or its data
    sheet's part (``datasheet``), and relation 2's exponent (``tire``: from the tire's data at
    the mean static wheel load; else the number given)."""
    v = car.vehicle
    names = [f.name for f in dataclasses.fields(ObserverVehicleParams)
             if f.name != 'split_exponent' and (body == 'measured' or f.name in DATASHEET)]
    values = {name: float(getattr(v, name)) for name in names}
    if body != 'measured':
        values['ms'] = min(ObserverVehicleParams().ms, values['m'])
    if split == 'tire':
        mean_load = v.m * GRAVITY / 4.0
        values['split_exponent'] = split_exponent_from_tire(v.tire.a4, v.tire.a5, mean_load)
    else:
        values['split_exponent'] = float(split)
    return ObserverVehicleParams(**values)


def run_car(seed: int, split: str, body: str, tires: str, tuning: ObserverTuningParams,
            cache: Path | None) -> list[dict[str, Any]]:
    """Every case of one car: per-wheel error, worst wheel, peak force."""
    car = car_family.sample_car(seed)
    if tires == 'varied':
        car = with_varied_tire(car)
    params = user_parameters(car, split, body)
    rows = []
    for case in CASES:
        data = cached_case(car, case, cache, tires)
        errors = fy_error_percent(data.run(params, tuning), data.fy_true)
        rows.append({'seed': seed, 'body': car.body, 'mass_kg': round(car.vehicle.m),
                     'case': case, 'split_exponent': params.split_exponent,
                     'error_percent': [float(e) for e in errors],
                     'worst_percent': float(np.max(errors)),
                     'peak_fy_n': float(np.abs(data.fy_true).max()),
                     'gyro_noise_rad_s': car.sensors.gyro_noise_rad_s})
    return rows


def by_case(rows: Sequence[Mapping[str, Any]]
            ) -> Iterator[tuple[str, list[Mapping[str, Any]], Mapping[str, Any], int]]:
    """Per case that has rows: its rows, the worst car's row, and the cars within 10 %."""
    for case in CASES:
        picked = [r for r in rows if r['case'] == case]
        if picked:
            worst = max(picked, key=lambda r: r['worst_percent'])
            yield case, picked, worst, sum(r['worst_percent'] < TARGET_PERCENT for r in picked)


def summary(rows: Sequence[Mapping[str, Any]]) -> str:
    """Per case: cars within the target, median and worst (Markdown)."""
    lines = ['| case | within 10 % | median worst wheel, % | worst, % (car) |',
             '| --- | --- | --- | --- |']
    for case, picked, worst, passed in by_case(rows):
        lines.append(f'| {case} | {passed} / {len(picked)} | '
                     f'{np.median([r["worst_percent"] for r in picked]):.1f} | '
                     f'{worst["worst_percent"]:.1f} ({worst["seed"]}) |')
    return '\n'.join(lines)


def per_car(rows: Sequence[Mapping[str, Any]]) -> str:
    """One line per car: body, mass, exponent, worst wheel per case (Markdown)."""
    lines = ['| car | body | mass, kg | split exponent | ' + ' | '.join(CASES) + ' |',
             '| --- | --- | --- | --- | ' + ' | '.join('---' for _ in CASES) + ' |']
    seeds = sorted({int(r['seed']) for r in rows})
    for seed in seeds:
        mine = {r['case']: r for r in rows if r['seed'] == seed}
        first = next(iter(mine.values()))
        cells = [f'{mine[c]["worst_percent"]:.1f}' if c in mine else '-' for c in CASES]
        lines.append(f'| {seed} | {first["body"]} | {first["mass_kg"]} | '
                     f'{first["split_exponent"]:.2f} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def scoreboard_rows(rows: Sequence[Mapping[str, Any]]) -> list[FamilyRow]:
    """One row per case: every car's worst wheel within the paper's 10 %."""
    return [FamilyRow(f'lateral force {case}',
                      f'lateral force observer, {CASE_TEXT[case]}: Fy RMS error of every wheel '
                      '< 10 % of its peak |Fy|', passed, len(picked), 'cars', 1.0,
                      float(worst['worst_percent']), '%', f'{worst["seed"]} {worst["body"]}',
                      passed == len(picked))
            for case, picked, worst, passed in by_case(rows)]


def write_scoreboard(path: Path, run: Mapping[str, Any], commit: str) -> None:
    """The committed result file the main job's scoreboard shows, from a ``--json`` run."""
    seeds = tuple(int(s) for s in run['seeds'])
    results = FamilyResults(
        'benchmarks/eval_lateral_force_family.py', commit, str(run.get('date', today())),
        seeds, all(s in car_family.HELD_OUT_SEEDS for s in seeds),
        tuple(scoreboard_rows(run['rows'])),
        {'split': run['split'], 'body': run.get('body', 'measured'),
         'tires': run.get('tires', 'simulator'),
         'overrides': run['overrides'], 'drive_s': DRIVE_S})
    write_family_results(path, results)
    print(f'wrote {path}: {results.met_count()} of {len(results.rows)} rows met',
          file=sys.stderr)


def plot_runs(path: Path, runs: Sequence[tuple[str, Mapping[str, Any]]]) -> Path:
    """Per case a panel: each car's worst wheel (%) against its mass, one marker per run."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(CASES), figsize=(4.2 * len(CASES), 3.8), sharey=True)
    markers = 'os^dv'
    for axis, case in zip(axes, CASES, strict=True):
        for index, (label, run) in enumerate(runs):
            picked = [r for r in run['rows'] if r['case'] == case]
            axis.scatter([r['mass_kg'] for r in picked], [r['worst_percent'] for r in picked],
                         marker=markers[index % len(markers)], s=22, alpha=0.8, label=label)
        axis.axhline(TARGET_PERCENT, color='k', linewidth=0.8, linestyle='--')
        axis.set_title(case)
        axis.set_xlabel('car mass, kg')
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("worst wheel's Fy RMS error, % of peak")
    axes[0].legend(fontsize=7)
    fig.suptitle('Lateral force observer on the family of cars (target < 10 %)')
    return save_figure(fig, path)


def seeds_of(text: str, cars: int | None) -> list[int]:
    """``tuning``, ``held-out`` or a comma-separated list; the first ``cars`` of them."""
    if text == 'tuning':
        seeds = list(car_family.TUNING_SEEDS)
    elif text == 'held-out':
        seeds = list(car_family.HELD_OUT_SEEDS)
    else:
        seeds = [int(s) for s in text.split(',') if s.strip()]
    return seeds[:cars] if cars else seeds


def _job(arguments: tuple[int, str, str, str, ObserverTuningParams, Path | None]
         ) -> list[dict[str, Any]]:
    return run_car(*arguments)


def main() -> None:
    """Command line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', default='tuning',
                        help="'tuning', 'held-out' or a comma-separated list of car seeds")
    parser.add_argument('--cars', type=int, default=None, help='the first N of those cars')
    parser.add_argument('--split', default='tire',
                        help="relation 2's exponent: 'tire' (from the tire's data at the car's "
                        'load) or a number for every car')
    parser.add_argument('--body', choices=('measured', 'datasheet'), default='measured',
                        help="the car's body as measured, or only its data sheet's part "
                        '(mass, axles, tracks, CG height, wheel; the rest at the defaults)')
    parser.add_argument('--tires', choices=('simulator', 'varied'), default='simulator',
                        help="every car on the simulator's tire, or each on a tire of its own "
                        '(rated for its load, other stiffness and shape)')
    parser.add_argument('--set', action='append', default=[], metavar='NAME=VALUE',
                        help='an ObserverTuningParams override (repeatable)')
    parser.add_argument('--cache', type=Path, default=Path('/tmp/lateral_force_family'),
                        help='where simulated cases are kept')
    parser.add_argument('--processes', type=int, default=2)
    parser.add_argument('--json', type=Path, default=None, help='write every row here')
    parser.add_argument('--scoreboard', type=Path, default=None,
                        help='also write the family result file the main job shows')
    parser.add_argument('--report', type=Path, default=None, metavar='RUN.json',
                        help='do not run: write --scoreboard from a saved --json run')
    parser.add_argument('--commit', default=None,
                        help='the commit the saved run was made at (default: HEAD)')
    parser.add_argument('--plot', nargs='+', default=None, metavar=('PNG', 'RUN.json'),
                        help='do not run: draw saved --json runs (label=path or path) to PNG')
    args = parser.parse_args()
    if args.plot is not None:
        if len(args.plot) < 2:
            parser.error('--plot needs a PNG path and at least one saved run')
        runs = []
        for given in args.plot[1:]:
            label, _, name = given.rpartition('=')
            runs.append((label or Path(name).stem, json.loads(Path(name).read_text())))
        print(f'wrote {plot_runs(Path(args.plot[0]), runs)}')
        return
    if args.report is not None:
        if args.scoreboard is None:
            parser.error('--report needs --scoreboard')
        write_scoreboard(args.scoreboard, json.loads(args.report.read_text()),
                         args.commit or current_commit())
        return
    overrides = parse_assignments(args.set, ObserverTuningParams())
    tuning = with_values(ObserverTuningParams(), overrides)
    seeds = seeds_of(args.seeds, args.cars)
    started = time.perf_counter()
    rows: list[dict[str, Any]] = []
    jobs = [(seed, args.split, args.body, args.tires, tuning, args.cache) for seed in seeds]
    with multiprocessing.get_context('spawn').Pool(max(1, args.processes)) as pool:
        for done, car_rows in enumerate(pool.imap(_job, jobs), start=1):
            rows += car_rows
            elapsed = time.perf_counter() - started
            eta = elapsed / done * (len(jobs) - done)
            print(f'[{done}/{len(jobs)}] car {car_rows[0]["seed"]}: '
                  + ', '.join(f'{r["case"]} {r["worst_percent"]:.1f} %' for r in car_rows)
                  + f' ({elapsed:.0f} s, ETA {eta:.0f} s)', file=sys.stderr, flush=True)
    print(f'Lateral force observer on {len(seeds)} cars ({args.seeds}), body {args.body}, '
          f'tires {args.tires}, split {args.split}, overrides {overrides or "none"}: '
          'worst wheel\'s Fy RMS error in % of its peak\n')
    print(summary(rows))
    print()
    print(per_car(rows))
    run = {'seeds': seeds, 'split': args.split, 'body': args.body, 'tires': args.tires,
           'date': today(),
           'overrides': {k: repr(v) for k, v in overrides.items()}, 'rows': rows}
    if args.json is not None:
        args.json.write_text(json.dumps(run, indent=1))
    if args.scoreboard is not None:
        write_scoreboard(args.scoreboard, run, current_commit())
    if not math.isfinite(sum(r['worst_percent'] for r in rows)):
        print('\nsome case produced no finite estimate', file=sys.stderr)


if __name__ == '__main__':
    main()
