"""The tachometer's scale learned from the creep estimator's likelihood, on the rail family.

Each car of the set (the development cars unless ``--seeds``) at one of its family speeds
(alternating between its first two), c = 1, 30 s, the track published with the given map
error (``--map-errors``, metres rms; 0 = exact, as the survey's 0.01 mm); its tachometer reads
high or low by a bias of the list (``--biases``, cycled over the cars). Pattern C (the
contract's fields, the full model), configured as the family evaluation does, each speed
filtered with a model built at it (``speed_tolerance_mps`` 1e-4: with the shipped 0.5 m/s the
speeds near the configured one are first-order steps of its model, and the likelihood then
peaks at the configured speed whatever the data say). The summed log-likelihood of the vehicle
channels given the track rows (``CreepEkf.vehicle_likelihood``, as ``rail_speed_scale`` sums
it) from 5 s on is taken over a grid of scales (+-2 % by 0.25 %) and fitted by the tool's
``fit_scale``; printed per case: the learned scale's error, its spread, and the creep factor's
rms error with the biased speed, the learned scale and the true speed. The benchmark runs the
core directly (the tool runs the node's processor by the offline engine over a bag): the
family's cases need no bag. docs/methods/creep_estimator.md, "The tachometer's scale".

Run: ``source tools/env.sh && python benchmarks/creep_speed_scale.py [--seeds development]
[--cars 6] [--map-errors 0,5e-5,1e-4,3e-4] [--biases 0.008,-0.013,0.004,-0.006]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from eval_rail_family import SEED_SETS, creep_inputs, creep_params, creep_track
import numpy as np

from rail_monitor_ros.core.creep_ekf import CreepEkf
from rail_monitor_ros.offline.speed_scale import fit_scale
from rail_monitor_ros.simulation.rail_family import (
    FamilyCar,
    case_seed,
    sample_car,
    sample_speeds,
    scenario_mapping,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import RailSimulationResult, simulate

DURATION_S, SKIP_S = 30.0, 5.0
GRID = 0.0025 * np.arange(-8, 9)
EXACT_MODEL_TOLERANCE_MPS = 1e-4


def run(car: FamilyCar, speed: float, result: RailSimulationResult, map_error: float,
        speed_factor: float) -> tuple[float, float]:
    """(log-likelihood summed from SKIP_S, rms relative error of c from SKIP_S) with the
    model's speed the true one times ``speed_factor``."""
    # Every speed its own exact model: within speed_tolerance_mps of the configured speed the
    # filter would step the configured model's transition to first order (its noise left at
    # the configured speed), which favours the configured speed itself.
    overrides = {'speed_tolerance_mps': EXACT_MODEL_TOLERANCE_MPS}
    if map_error:
        overrides['track_map_error_m'] = map_error
    params = creep_params(car, speed, 'C-spec/map0.3' if map_error else 'C-spec/exact',
                          'spectrum', True, overrides)
    ekf = CreepEkf(params)
    ekf.vehicle_likelihood = True
    z = creep_inputs(result, 'C', True)
    track = creep_track(result)
    total, errors = 0.0, []
    for k in range(z.shape[0]):
        estimate = ekf.step(z[k], track[k], float(result.speed[k]) * speed_factor)
        if result.time[k] >= SKIP_S:
            total += ekf.sample_log_likelihood
            errors.append(estimate.creep_factor / result.creep_factor[k] - 1.0)
    return total, float(np.sqrt(np.mean(np.square(errors))))


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', choices=tuple(SEED_SETS), default='development',
                        help='the family\'s cars to run (held-out: report only, tune nothing)')
    parser.add_argument('--cars', type=int, default=6, help='the first N cars of the set')
    parser.add_argument('--map-errors', default='0,5e-5,1e-4,3e-4')
    parser.add_argument('--biases', default='0.008,-0.013,0.004,-0.006')
    args = parser.parse_args(argv)
    biases = [float(b) for b in args.biases.split(',')]
    print('| map error, mm | car | speed, m/s | tachometer bias | learned scale error | spread '
          '| c rms: biased speed | learned scale | true speed |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for map_error in (float(m) for m in args.map_errors.split(',')):
        for i, seed in enumerate(SEED_SETS[args.seeds][:args.cars]):
            car = sample_car(seed)
            speed = sample_speeds(car, 2)[i % 2]
            bias = biases[i % len(biases)]
            result = simulate(rail_scenario_from_dict(scenario_mapping(
                car, f'family_{seed}_speed_scale', speed, case_seed(car, 500), DURATION_S, [],
                {'creep_factor': 1.0}, map_error)))
            # The tachometer reads (1 + bias) v; the grid's scales multiply that reading.
            sums = [run(car, speed, result, map_error, (1.0 + bias) * (1.0 + g))[0]
                    for g in GRID]
            fit = fit_scale(1.0 + GRID, sums, 0)
            scale, std, problem = fit.scale, fit.std, fit.problem
            biased = run(car, speed, result, map_error, 1.0 + bias)[1]
            truth = run(car, speed, result, map_error, 1.0)[1]
            if problem:
                learned, error, spread = '-', f'none: {problem}', '-'
            else:
                scaled = (1.0 + bias) * scale
                learned = f'{100 * run(car, speed, result, map_error, scaled)[1]:.2f} %'
                error, spread = f'{100 * (scaled - 1.0):+.3f} %', f'{100 * std:.3f} %'
            print(f'| {1e3 * map_error:g} | {seed} | {speed:.1f} | {100 * bias:+.1f} % | {error} '
                  f'| {spread} | {100 * biased:.2f} % | {learned} | {100 * truth:.2f} % |',
                  flush=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
