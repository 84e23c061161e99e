"""How well the creep factor can be known at all: its Cramér-Rao bound per pattern, car and speed.

The creep rows of the rail scoreboard are far from their targets: pattern D (the IMUs) without a
track input never within ±10 % in 2 s after a step, pattern C with the exact track ±5 % in 1 s
on 10 of 24 held-out cases, failing at low speed (docs/methods/rail_family_evaluation.md).
Issue 19 asks to state the measured distribution where a target is not reached; this script
measures what the sensors carry about c, whatever the estimator.

**The bound.** The full-car model of the family's simulator (the suspension IMM's model: the
14-DOF car, the line's track spectrum as a shaping filter with the wheelsets' delays) at creep
factor c and at c (1 + delta) gives two stationary output processes; the Kullback-Leibler rate
between them (``imm_detection_limit.information_rate``: one Lyapunov equation) is
J delta^2 / 2 for small delta, J the Fisher information about ln c per second. No unbiased
estimate of c from T seconds of stationary data has a relative standard deviation below
1 / sqrt(J T): the bound assumes everything else known (the car, the sensor offsets, the track
spectrum), so a real estimator does worse. Where 1.96 / sqrt(J T) exceeds the target's band,
no estimator meets it on most such cases.

**Patterns** (the car's own sensor noise, ``SensorConfig``):

- ``D/none``: bogie lateral acceleration, bogie yaw rate, body lateral acceleration; the track
  unknown (the shaping filter driven by noise).
- ``D/exact``: the same with the alignment under the four wheelsets known (1e-5 m noise).
- ``D/none+roughness``: as ``D/none`` with the track's roughness level a second unknown (the
  bound on c once the information shared with it is taken out).
- ``C/exact``: the contract's pattern C fields (front bogie lateral displacement and velocity,
  body lateral displacement and velocity) with the exact track.

Run: ``source tools/env.sh && python benchmarks/creep_information.py [--seeds held-out|
development] [--cars N] [--speeds K] [--patterns D/none,D/exact,C/exact]``. Speeds as the
evaluation draws them for the creep cases (``--speeds`` per car in 20-70 m/s).
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import replace  # noqa: E402
import math  # noqa: E402

from eval_rail_family import imm_params  # noqa: E402
from imm_detection_limit import SEED_SETS, information_rate  # noqa: E402
import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

from rail_monitor_ros.core.suspension_imm import ModeModel, SuspensionImm  # noqa: E402
from rail_monitor_ros.simulation.rail_family import (  # noqa: E402
    CREEP_STEPS,
    SPEED_RANGE,
    FamilyCar,
    family,
    sample_speeds,
)

PATTERNS = ('D/none', 'D/none+roughness', 'D/exact', 'C/exact')
#: Relative change of c (and of the roughness) between the two models of a rate: small enough
#: that J delta^2 / 2 holds (0.05 and 0.1 give J within 6 % of each other), large enough that
#: the rate stands above the rounding of the Riccati and Lyapunov solutions (at 0.01 and below
#: the slow track states make some rates negative).
DELTA = 0.05
EXACT_TRACK_STD_M = 1e-5
#: Known track: the alignment under the front bogie's two wheelsets (as the creep estimator
#: takes it; the rear bogie's inputs follow through the model's delays).
KNOWN_WHEELSETS = 2
#: Pattern C's fields: states of the full car (the front bogie) and their noise kind.
C_FIELDS = (('y_b1', 'displacement_noise'), ('dy_b1', 'velocity_noise'),
            ('y_v', 'displacement_noise'), ('dy_v', 'velocity_noise'))
#: The targets: pattern -> (band, seconds after the step).
TARGETS = {'D/none': (0.10, 2.0), 'D/none+roughness': (0.10, 2.0),
           'D/exact': (0.10, 2.0), 'C/exact': (0.05, 1.0)}


def _model_at(imm: SuspensionImm, creep_factor: float) -> ModeModel:
    """The nominal suspension's discrete model at this creep factor, unsnapped (the IMM's
    ``set_creep_factor`` rounds to its resolution)."""
    imm.creep_factor = creep_factor
    imm._discretized.clear()
    return imm._discretize(1.0, 1.0)


def _measurement(imm: SuspensionImm, model: ModeModel, car: FamilyCar, pattern: str,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(H, R) of the pattern on the model's augmented state."""
    channels, track = pattern.split('/')
    known = 0 if track == 'none' else KNOWN_WHEELSETS
    if channels == 'D':
        return model.h[known], imm._r[known]
    n_aug = model.f.shape[0]
    rows = np.zeros((len(C_FIELDS), n_aug))
    for row, (state, _) in enumerate(C_FIELDS):
        rows[row, imm.state_names.index(state)] = 1.0
    noise = np.array([getattr(car.sensors, kind) for _, kind in C_FIELDS]) ** 2
    track_rows = model.h[known][model.h[0].shape[0]:]
    r_track = imm._r[known][imm._r[0].shape[0]:, imm._r[0].shape[0]:]
    return np.vstack([rows, track_rows]), scipy.linalg.block_diag(np.diag(noise), r_track)


def _rate(car: FamilyCar, speed: float, pattern: str, truth: tuple[float, float],
          other: tuple[float, float]) -> float:
    """Information rate of (creep factor, track roughness scale) ``truth`` over ``other``."""
    std = EXACT_TRACK_STD_M if pattern.endswith('exact') else car.map_error_rms
    models, measurements = [], []
    for creep_factor, roughness_scale in (truth, other):
        params = imm_params(car, speed, {'known_track_std_m': std})
        imm = SuspensionImm(replace(params, track_roughness_m_rad=(
            params.track_roughness_m_rad * roughness_scale)))
        model = _model_at(imm, creep_factor)
        models.append(model)
        measurements.append(_measurement(imm, model, car, pattern))
    (h_true, r), (h_other, _) = measurements
    return information_rate(models[0], models[1], h_true, h_other, r,
                            imm.params.sample_rate_hz)


def fisher_rate(car: FamilyCar, speed: float, creep_factor: float, pattern: str,
                roughness_unknown: bool = False) -> float:
    """Fisher information about ln c per second at this creep factor, 1/s; with
    ``roughness_unknown`` what is left of it when the track's roughness level is a second
    unknown (J_cc - J_ca^2 / J_aa; the track's spectrum shape still known)."""
    def information(dc: float, da: float) -> float:
        # both sides: the mean cancels the third-order term
        return float(np.mean([_rate(car, speed, pattern, (creep_factor, 1.0),
                                    (creep_factor * (1.0 + s * dc), 1.0 + s * da))
                              for s in (1.0, -1.0)])) * 2.0 / DELTA ** 2

    j_cc = information(DELTA, 0.0)
    if not roughness_unknown:
        return j_cc
    j_aa = information(0.0, DELTA)
    j_ca = 0.5 * (information(DELTA, DELTA) - j_cc - j_aa)
    return j_cc - j_ca ** 2 / j_aa


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', choices=sorted(SEED_SETS), default='held-out')
    parser.add_argument('--cars', type=int, default=0, help='first N cars (0: all)')
    parser.add_argument('--speeds', type=int, default=2)
    parser.add_argument('--patterns', default=','.join(PATTERNS))
    args = parser.parse_args(argv)
    cars = family(SEED_SETS[args.seeds])
    if args.cars:
        cars = cars[:args.cars]
    patterns = [p for p in args.patterns.split(',') if p]
    factors = sorted({c for _, c in CREEP_STEPS})
    bound: dict[str, list[tuple[float, float]]] = {p: [] for p in patterns}
    print('| car | speed | ' + ' | '.join(
        f'{p}: 1.96 sigma in {TARGETS[p][1]:g} s at c = '
        + ', '.join(f'{c:g}' for c in factors) for p in patterns) + ' |')
    print('| --- | --- |' + ' --- |' * len(patterns))
    for car in cars:
        for speed in sample_speeds(car, args.speeds, *SPEED_RANGE):
            cells = []
            for pattern in patterns:
                seconds = TARGETS[pattern][1]
                name, _, nuisance = pattern.partition('+')
                rates = [fisher_rate(car, speed, c, name, bool(nuisance)) for c in factors]
                halfwidths = [1.96 / math.sqrt(j * seconds) if j > 0.0 else math.inf
                              for j in rates]
                bound[pattern].append((speed, max(halfwidths)))
                cells.append(', '.join(f'{100 * w:.1f} %' for w in halfwidths))
            print(f'| {car.seed} | {speed:.1f} m/s | ' + ' | '.join(cells) + ' |', flush=True)
    print('\n| pattern | target band | cases whose bound (worst c) is within the band | '
          'bound, median / largest |\n| --- | --- | --- | --- |')
    for pattern in patterns:
        band = TARGETS[pattern][0]
        widths = [w for _, w in bound[pattern]]
        print(f'| {pattern} | ±{100 * band:g} % in {TARGETS[pattern][1]:g} s | '
              f'{sum(w <= band for w in widths)}/{len(widths)} | '
              f'{100 * float(np.median(widths)):.1f} / {100 * max(widths):.1f} % |')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
