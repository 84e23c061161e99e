"""The ECU timer as the stiffness observer reads it from held tooth periods, on the car family.

For the first simulated drive of each car kept by ``eval_tpms_family.py --sim-cache``, the
readings of the four wheels inside the method's speed band go through
:class:`~tpms_ros.core.wheel_encoder.TimerLattice` in 0.25 s chunks (what it reads and after how
many seconds of driving), and the stiffness observer, with the car's user parameters, runs over
the first ``--seconds`` of the drive (what it says then of the encoder noise: the lattice's read
stands unless the tooth correction has recognised window averages meanwhile). Printed per car,
then a count of cars whose noise removal is right at the end (held periods: removed with the
car's timer; window averages: not removed, or no longer)
(docs/methods/tpms_family_evaluation.md, "2026-12-02 (third session)").

``python benchmarks/encoder_timer_family.py --sim-cache DIR [--glob PATTERN]``
"""

from __future__ import annotations

import argparse
from pathlib import Path
import pickle
import re

from eval_tpms_family import Settings, method_params

from tpms_ros.core.stiffness_observer import StiffnessObserverParams, TireStiffnessObserver
from tpms_ros.core.wheel_encoder import TimerLattice
from tpms_ros.simulation.car_family import sample_car

CHUNK_S = 0.25


def read_timer(path: Path, seconds: float) -> tuple[int, dict, float, float | None, str]:
    """(seed, the car's ECU data, the lattice's timer (0: none), seconds of driving it took,
    the observer's ``encoder_noise`` after ``seconds``)."""
    with path.open('rb') as f:
        result = pickle.load(f)
    seed = int(re.search(r'car(\d+)', path.name).group(1))   # type: ignore[union-attr]
    car = sample_car(seed)
    observer = TireStiffnessObserver(method_params(car, Settings())[2])
    end = int(seconds * observer.params.sample_rate_hz)
    for start in range(0, min(end, result.wheel_speed.shape[0]), 250):
        observer.update(result.wheel_speed[start:start + 250],
                        stamps=result.wheel_speed_t[start:start + 250])
    user = car.user_parameters()
    defaults = StiffnessObserverParams()
    radius = user['nominal_radius_m']
    low, high = (v / 3.6 / radius for v in (defaults.speed_min_kmh, defaults.speed_max_kmh))
    lattice = TimerLattice(user['encoder_teeth'], defaults.sample_rate_hz)
    speed = result.wheel_speed
    chunk = round(CHUNK_S * defaults.sample_rate_hz)
    for start in range(0, speed.shape[0], chunk):
        part = speed[start:start + chunk]
        row = lattice.add(part, (part > low) & (part < high))
        if row is not None:
            return seed, car.ecu_parameters(), float(lattice.timer_s or 0.0), \
                (start + row + 1) / defaults.sample_rate_hz, observer.encoder_noise
    return seed, car.ecu_parameters(), 0.0, None, observer.encoder_noise


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--sim-cache', type=Path, required=True,
                        help="eval_tpms_family.py's directory of simulated drives")
    parser.add_argument('--glob', default='car*.pkl', help='which drives (default: all)')
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='driving the observer gets before its state is printed')
    args = parser.parse_args()
    first: dict[str, Path] = {}
    for path in sorted(args.sim_cache.glob(args.glob)):
        if 'ring0' not in path.name:
            first.setdefault(path.name.split('_')[0], path)
    right = wrong = waiting = 0
    print(f'| car | ECU | timer, us | window, ms | lattice read, us | after, s | observer after '
          f'{args.seconds:g} s |')
    print('| --- | --- | --- | --- | --- | --- | --- |')
    for path in first.values():
        seed, ecu, timer_s, after_s, noise = read_timer(path, args.seconds)
        if ecu['encoder_speed_method'] == 'tooth_period':
            ok = noise == (f"removed (timer {ecu['encoder_timer_s'] * 1e6:.4g} us, read from "
                           'the wheel speeds)')
        else:
            ok = noise.startswith(('not removed', 'removed until'))
        reading = noise.startswith('reading')
        right += ok
        waiting += reading
        wrong += not (ok or reading)
        print(f"| {seed} | {ecu['encoder_speed_method']} | {1e6 * ecu['encoder_timer_s']:g} | "
              f"{1e3 * ecu['encoder_window_s']:.1f} | {1e6 * timer_s:.4g} | "
              f"{'undecided' if after_s is None else f'{after_s:.2f}'} | {noise} |"
              + ('' if ok or reading else ' (wrong)'))
    print(f'\n{right} cars right at the end (held periods: removed with their timer; window '
          f'averages: not removed, or no longer), {waiting} still reading, {wrong} wrong')


if __name__ == '__main__':
    main()
