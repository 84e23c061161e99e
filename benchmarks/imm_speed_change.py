"""The suspension IMM on a healthy car that brakes and accelerates: does a speed change look
like a suspension fault?

Each car of the family (the development cars unless ``--seeds``) at its first IMM family speed
v (30-60 m/s, below 0.9 of its critical speed) runs 70 s healthy: v until 10 s, down to v -
``--delta`` over 20 s, back to v over 20 s from 40 s (``--delta 0``: constant speed, the
reference). The IMM as the evaluation configures it (``eval_rail_family.imm_params``,
``--imm-set`` for a setting), the speed given each sample (as a node is given ``rail/speed``).
Per car: fault declarations, the share of time the normal hypothesis' smoothed probability is
below 0.5, the IMM's CPU time. docs/methods/suspension_monitor.md, "Limits".

Run: ``source tools/env.sh && python benchmarks/imm_speed_change.py [--delta 10]
[--seeds development|held-out] [--cars 12] [--imm-set speed_resolution_mps=0.5]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
import time

from eval_rail_family import HALF_STEP, IMM_SPEED_RANGE, SEED_SETS, imm_params
import numpy as np

from rail_monitor_ros.core.suspension_imm import SuspensionImm, SuspensionImmParams
from rail_monitor_ros.simulation.rail_family import (
    case_seed,
    sample_car,
    sample_speeds,
    scenario_mapping,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import simulate
from vehicle_monitor_common.parameters import parse_assignments

DURATION_S = 70.0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--delta', type=float, default=10.0, help='speed drop and rise, m/s')
    parser.add_argument('--seeds', choices=tuple(SEED_SETS), default='development',
                        help='the family\'s cars to run (held-out: report only, tune nothing)')
    parser.add_argument('--cars', type=int, default=12, help='the first N cars of the set')
    parser.add_argument('--imm-set', action='append', default=[], metavar='NAME=VALUE')
    args = parser.parse_args(argv)
    overrides = parse_assignments(args.imm_set, SuspensionImmParams())
    declared_total = 0
    print('| car | speed | declared | normal below 0.5 | CPU |\n| --- | --- | --- | --- | --- |')
    for seed in SEED_SETS[args.seeds][:args.cars]:
        car = sample_car(seed)
        speed = sample_speeds(car, 1, *IMM_SPEED_RANGE)[0]
        events = [] if not args.delta else [
            {'time': 10.0, 'speed': speed - args.delta, 'ramp': 20.0},
            {'time': 40.0, 'speed': speed, 'ramp': 20.0}]
        result = simulate(rail_scenario_from_dict(scenario_mapping(
            car, f'family_{seed}_imm_speed_change', speed, case_seed(car, 500), DURATION_S,
            events, {'creep_factor': 1.0}, 0.0)))
        z = np.column_stack([result.bogie_lateral_accel, result.bogie_yaw_rate,
                             result.body_lateral_accel])
        imm = SuspensionImm(imm_params(car, speed, overrides))
        detected = np.zeros(z.shape[0], dtype=bool)
        p_normal = np.zeros(z.shape[0])
        began = time.process_time()
        for k in range(z.shape[0]):
            imm.set_speed(float(result.speed[k]))
            imm.advance(z[k], result.measured_track_alignment[k])
            detected[k] = imm.fault.detected
            normal = ((np.abs(imm._mode_spring_used - 1.0) <= HALF_STEP)   # noqa: SLF001
                      & (np.abs(imm.mode_damper_ratio - 1.0) <= HALF_STEP))
            p_normal[k] = imm.smoothed[normal].sum()
        seconds = time.process_time() - began
        declared = int(np.count_nonzero(detected[1:] & ~detected[:-1]) + detected[0])
        declared_total += declared
        print(f'| {seed} | {speed:.1f} m/s | {declared} | {100 * np.mean(p_normal < 0.5):.1f} % '
              f'| {seconds:.1f} s |', flush=True)
    print(f'\ndeclared in all: {declared_total}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
