"""The creep estimator on a car that accelerates or brakes: the family's runs are at constant
speed, a train's are not.

Each car of the family (the development cars unless ``--seeds``) at its first family speed
changes speed by ``--delta`` m/s over 20 s (from 2 s: 0.5 m/s^2 for 10 m/s), c 1 -> 0.5 at 12
s, the track exact (0.01 mm); the estimator of each pattern as the evaluation configures it
(``eval_rail_family.creep_params``, ``--creep-set`` for a setting). Per pattern: the relative
error over 4-12 s (during the speed change, before the step) as rms median, the largest, and
the range of its mean over the cars; the rms from 14 s (after the step); the filter's CPU time
a sample (median). A negative ``--delta`` brakes (the car starts ``-delta`` faster). ``--delta
0`` is the constant-speed reference. docs/methods/creep_estimator.md, "Speed that varies".

Run: ``source tools/env.sh && python benchmarks/creep_speed_change.py [--delta 10]
[--seeds development|held-out] [--cars 12] [--patterns C-spec/exact,D/exact,D/none]
[--creep-set NAME=VALUE ...]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import time

from eval_rail_family import SEED_SETS, creep_inputs, creep_params, creep_track
import numpy as np

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams
from rail_monitor_ros.simulation.rail_family import (
    case_seed,
    sample_car,
    sample_speeds,
    scenario_mapping,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import simulate
from vehicle_monitor_common.parameters import parse_assignments

#: When the speed changes and over how long, when c steps, how long the run is, s.
CHANGE_AT_S, CHANGE_S, STEP_AT_S, DURATION_S = 2.0, 20.0, 12.0, 24.0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--delta', type=float, default=10.0, help='speed change, m/s')
    parser.add_argument('--seeds', choices=tuple(SEED_SETS), default='development',
                        help='the family\'s cars to run (held-out: report only, tune nothing)')
    parser.add_argument('--cars', type=int, default=12, help='the first N cars of the set')
    parser.add_argument('--patterns', default='C-spec/exact,D/exact,D/none')
    parser.add_argument('--creep-set', action='append', default=[], metavar='NAME=VALUE')
    args = parser.parse_args(argv)
    overrides = parse_assignments(args.creep_set, CreepEkfParams())
    patterns = args.patterns.split(',')
    rows: dict[str, list[tuple[float, float, float, float, float]]] = {p: [] for p in patterns}
    for seed in SEED_SETS[args.seeds][:args.cars]:
        car = sample_car(seed)
        start = sample_speeds(car, 2)[0] + max(0.0, -args.delta)
        events = [{'time': STEP_AT_S, 'creep_factor': 0.5}]
        if args.delta:
            events.insert(0, {'time': CHANGE_AT_S, 'speed': start + args.delta,
                              'ramp': CHANGE_S})
        result = simulate(rail_scenario_from_dict(scenario_mapping(
            car, f'family_{seed}_speed_change', start, case_seed(car, 400), DURATION_S,
            events, {'creep_factor': 1.0}, 0.0)))
        during = (result.time > 4.0) & (result.time < STEP_AT_S)
        after = result.time > STEP_AT_S + 2.0
        for pattern in patterns:
            params = creep_params(car, start, pattern, 'spectrum', True, overrides)
            began = time.process_time()
            run = CreepEkf(params).run(
                creep_inputs(result, pattern[0], pattern.startswith('C-spec')),
                None if pattern.endswith('none') else creep_track(result), result.speed)
            seconds = time.process_time() - began
            error = run.creep_factor / result.creep_factor - 1.0
            rows[pattern].append((float(np.sqrt(np.mean(error[during] ** 2))),
                                  float(np.max(np.abs(error[during]))),
                                  float(np.mean(error[during])),
                                  float(np.sqrt(np.mean(error[after] ** 2))),
                                  seconds / result.time.size))
        print(f'car {seed} done', flush=True)
    print(f'\n| pattern | {args.delta:+g} m/s over {CHANGE_S:g} s: error rms median, largest; '
          'mean range | after the step, rms median | CPU a sample |')
    print('| --- | --- | --- | --- |')
    for pattern in patterns:
        table = np.array(rows[pattern])
        print(f'| {pattern} | {100 * np.median(table[:, 0]):.2f} %, '
              f'{100 * table[:, 1].max():.1f} %; {100 * table[:, 2].min():+.2f}..'
              f'{100 * table[:, 2].max():+.2f} % | {100 * np.median(table[:, 3]):.2f} % | '
              f'{1e6 * np.median(table[:, 4]):.0f} µs |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
