"""How well the creep factor can be known at all: its Cramér-Rao bound per pattern, car and speed.

The creep rows of the rail scoreboard are far from their targets: pattern D (the IMUs) without a
track input never within ±10 % in 2 s after a step, pattern C with the exact track ±5 % in 1 s
on 10 of 24 held-out cases, failing at low speed (docs/methods/rail_family_evaluation.md).
Issue 19 asks to state the measured distribution where a target is not reached; this script
measures what the sensors carry about c, whatever the estimator.

**The bound.** The full-car model of the family's simulator (the suspension IMM's model: the
14-DOF car, the line's track spectrum as a shaping filter with the wheelsets' delays) gives the
measured channels as a stationary Gaussian process with spectral density S(omega) =
H (e^(i omega) - F)^-1 Q (.)^H + R. The Fisher information about ln c per sample is Whittle's
(1 / 2 pi) int_0^pi tr(S^-1 dS S^-1 dS) d omega, dS the derivative of S in ln c (a central
difference of 1 %), on a frequency grid dense around the lightly damped poles (converged: twice
the grid, or differences of 0.5-2 %, move J by less than 0.01 %), with the spectra of
``imm_detection_limit.OutputSpectrum``. (Taken instead from Kullback-Leibler rates between c
and c (1 + delta) solved by Riccati and Lyapunov equations, J was lost in their rounding for
delta below 5 %, and with a track map's coloured error even negative.) No unbiased estimate
of c from T seconds of stationary data has a relative standard deviation below 1 / sqrt(J T):
the bound
assumes everything else known (the car, the sensor offsets, the track spectrum), so a real
estimator does worse. Where 1.96 / sqrt(J T) exceeds the target's band, no estimator meets it
on most such cases.

**Patterns** (the car's own sensor noise, ``SensorConfig``):

- ``D/none``: bogie lateral acceleration, bogie yaw rate, body lateral acceleration; the track
  unknown (the shaping filter driven by noise).
- ``D/exact``: the same with the alignment under the front bogie's two wheelsets known (1e-5 m
  noise), as the creep estimator takes it.
- ``D/none+roughness``: as ``D/none`` with the track's roughness level a second unknown (the
  bound on c once the information shared with it is taken out).
- ``D/none+independent`` (on request): as ``D/none`` with each wheelset's alignment an
  independent process of the spectrum's shape, as a track model without the wheelbase's
  delays (the creep EKF's) takes it.
- ``C/exact``: the contract's pattern C fields (front bogie lateral displacement and velocity,
  body lateral displacement and velocity) with the exact track.
- ``C/map0.3``: the same with a track map of 0.3 mm rms error over 1-120 m, as the simulator
  makes it: the error is a second track-shaped process (the spectrum scaled to that rms in
  that band, ``track_shaping.map_error_roughness``) added to the alignment the map gives.

**The estimator's own view** (``--estimator``): the same bound under the creep EKF's model as
the evaluation configures it (its model, ``full`` by default: the car, its track and map-error
states, the rear wheelsets' track from the front pair's a wheelbase earlier; the end model: the
other bogie's forces as Gauss-Markov states; its process and measurement noise;
``--ekf-set NAME=VALUE`` changes a setting, ``--ekf-set model=end`` the model): how much of the
information its stated model errors leave it. The suspension ratio states do not enter it: at
ratio 0 their effect on the dynamics, linearised, vanishes.

Run: ``source tools/env.sh && python benchmarks/creep_information.py [--seeds held-out|
development] [--cars N] [--speeds K] [--patterns D/none,D/exact,C/exact] [--estimator
[--ekf-set NAME=VALUE ...]]``. Speeds as the evaluation draws them for the creep cases
(``--speeds`` per car in 20-70 m/s).
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import replace  # noqa: E402
import math  # noqa: E402

from eval_rail_family import MAP_ERROR, creep_params, imm_params  # noqa: E402
from imm_detection_limit import SEED_SETS, OutputSpectrum, frequency_grid  # noqa: E402
import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams  # noqa: E402
from rail_monitor_ros.core.suspension_imm import ModeModel, SuspensionImm  # noqa: E402
from rail_monitor_ros.core.track_shaping import (  # noqa: E402
    map_error_roughness,
    track_shaping_model,
    van_loan_discretization,
)
from rail_monitor_ros.simulation.rail_family import (  # noqa: E402
    CREEP_STEPS,
    SPEED_RANGE,
    FamilyCar,
    family,
    sample_speeds,
)
from rail_monitor_ros.simulation.rail_scenario import TrackConfig  # noqa: E402
from vehicle_monitor_common.parameters import ConfigurationError, parse_assignments  # noqa: E402

PATTERNS = ('D/none', 'D/none+roughness', 'D/exact', 'C/exact', 'C/map0.3')
#: Not in the default set: the estimator's track model without the wheelbase's delays.
INDEPENDENT = 'D/none+independent'
#: Relative step of the central differences of the spectrum in ln c and ln(roughness).
DELTA = 0.01
EXACT_TRACK_STD_M = 1e-5
#: Known track: the alignment under the front bogie's two wheelsets (as the creep estimator
#: takes it; the rear bogie's inputs follow through the model's delays).
KNOWN_WHEELSETS = 2
#: Pattern C's fields: states of the full car (the front bogie) and their noise kind.
C_FIELDS = (('y_b1', 'displacement_noise'), ('dy_b1', 'velocity_noise'),
            ('y_v', 'displacement_noise'), ('dy_v', 'velocity_noise'))
#: The targets: pattern -> (band, seconds after the step).
TARGETS = {'D/none': (0.10, 2.0), 'D/none+roughness': (0.10, 2.0), INDEPENDENT: (0.10, 2.0),
           'D/exact': (0.10, 2.0), 'C/exact': (0.05, 1.0), 'C/map0.3': (0.05, 1.0)}


def _model_at(imm: SuspensionImm, creep_factor: float, map_error: float = 0.0) -> ModeModel:
    """The nominal suspension's discrete model at this creep factor, unsnapped (the IMM's
    ``set_creep_factor`` rounds to its resolution); with ``map_error`` (m rms) the map's error
    states appended after the track's."""
    imm.creep_factor = creep_factor
    imm._discretized.clear()
    model = imm._discretize(1.0, 1.0)
    if not map_error:
        return model
    p = imm.params
    error = track_shaping_model(
        map_error_roughness(p.track_roughness_m_rad, p.track_corner_wavenumber_rad_per_m,
                            p.track_long_wavenumber_rad_per_m, map_error,
                            TrackConfig.max_wavelength),
        p.track_corner_wavenumber_rad_per_m, p.track_long_wavenumber_rad_per_m,
        imm.vehicle.speed, imm.vehicle.wheelset_offsets, p.delay_min_wavelength_m)
    f_error, q_error = van_loan_discretization(
        error.a, error.noise_density * np.outer(error.g, error.g), p.dt)
    n_sensors = model.h[0].shape[0]
    h = {}
    for known, rows in model.h.items():
        # the map's alignment is the track's plus its error
        error_rows = np.zeros((rows.shape[0], error.a.shape[0]))
        error_rows[n_sensors:] = error.c[:known]
        h[known] = np.hstack([rows, error_rows])
    return ModeModel(scipy.linalg.block_diag(model.f, f_error),
                     scipy.linalg.block_diag(model.q, q_error), h)


def _measurement(imm: SuspensionImm, model: ModeModel, car: FamilyCar, pattern: str,
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(H, R) of the pattern on the model's augmented state."""
    channels, track = pattern.split('/')
    known = 0 if track == 'none' else KNOWN_WHEELSETS
    if channels == 'D':
        return model.h[known], imm._r[known]
    n_aug = model.f.shape[0]
    rows = np.zeros((len(C_FIELDS), n_aug))     # the car's states come first
    for row, (state, _) in enumerate(C_FIELDS):
        rows[row, imm.state_names.index(state)] = 1.0
    noise = np.array([getattr(car.sensors, kind) for _, kind in C_FIELDS]) ** 2
    track_rows = model.h[known][model.h[0].shape[0]:]
    r_track = imm._r[known][imm._r[0].shape[0]:, imm._r[0].shape[0]:]
    return np.vstack([rows, track_rows]), scipy.linalg.block_diag(np.diag(noise), r_track)


def _independent_tracks_model(imm: SuspensionImm, creep_factor: float) -> ModeModel:
    """As :func:`_model_at` without a track input, but each wheelset's alignment its own
    process of the spectrum's shape (independent noises) instead of the first one's delayed
    copies: what a track model without the wheelbase's delays (the creep EKF's) assumes."""
    imm.creep_factor = creep_factor
    car = imm._model(1.0, 1.0)
    p = imm.params
    one = track_shaping_model(p.track_roughness_m_rad, p.track_corner_wavenumber_rad_per_m,
                              p.track_long_wavenumber_rad_per_m, imm.vehicle.speed, [0.0],
                              p.delay_min_wavelength_m)
    wheelsets = car.b.shape[1]
    a_track = scipy.linalg.block_diag(*[one.a] * wheelsets)
    c_track = scipy.linalg.block_diag(*[one.c] * wheelsets)
    n, m = car.a.shape[0], a_track.shape[0]
    a = np.zeros((n + m, n + m))
    a[:n, :n], a[:n, n:], a[n:, n:] = car.a, car.b @ c_track, a_track
    spectral = np.zeros((n + m, n + m))
    for wheelset in range(wheelsets):
        g = np.zeros(n + m)
        g[n + 2 * wheelset:n + 2 * wheelset + 2] = one.g
        spectral += one.noise_density * np.outer(g, g)
    f, q = van_loan_discretization(a, spectral, p.dt)
    return ModeModel(f, q, {0: np.hstack([car.c, car.d @ c_track])})


def _imm(car: FamilyCar, speed: float, pattern: str, roughness_scale: float) -> SuspensionImm:
    """The suspension IMM whose full-car model the pattern's spectra come from (the map's
    stated accuracy, the track's roughness scaled)."""
    std = EXACT_TRACK_STD_M if pattern.endswith(('exact', 'map0.3')) else car.map_error_rms
    params = imm_params(car, speed, {'known_track_std_m': std})
    return SuspensionImm(replace(params, track_roughness_m_rad=(
        params.track_roughness_m_rad * roughness_scale)))


def _spectrum(imm: SuspensionImm, car: FamilyCar, pattern: str, creep_factor: float,
              independent_tracks: bool = False) -> OutputSpectrum:
    if independent_tracks:
        model = _independent_tracks_model(imm, creep_factor)
    else:
        model = _model_at(imm, creep_factor, MAP_ERROR if pattern.endswith('map0.3') else 0.0)
    return OutputSpectrum(model, *_measurement(imm, model, car, pattern))


def whittle_information(spectrum: np.ndarray, derivatives: Sequence[np.ndarray],
                        omegas: np.ndarray) -> np.ndarray:
    """Whittle's Fisher information matrix per sample of a stationary Gaussian process:
    J_ij = (1 / 2 pi) int_0^pi tr(S^-1 dS_i S^-1 dS_j) d omega.

    Args:
        spectrum: (N, p, p) S at the frequencies ``omegas`` (rad/sample, increasing in (0, pi]).
        derivatives: (N, p, p) each dS/d theta_i at the same frequencies.
    """
    scaled = [np.linalg.solve(spectrum, d) for d in derivatives]
    size = len(scaled)
    out = np.empty((size, size))
    for i in range(size):
        for j in range(i, size):
            integrand = np.real(np.einsum('nab,nba->n', scaled[i], scaled[j]))
            out[i, j] = out[j, i] = float(np.trapezoid(integrand, omegas)) / (2.0 * math.pi)
    return out


def fisher_rate(car: FamilyCar, speed: float, creep_factor: float, pattern: str,
                variant: str = '') -> float:
    """Fisher information about ln c per second at this creep factor, 1/s. ``variant``
    'roughness': what is left of it when the track's roughness level is a second unknown
    (J_cc - J_ca^2 / J_aa; the track's spectrum shape still known); 'independent': the
    wheelsets' alignments independent (no track input only)."""
    roughness_unknown = variant == 'roughness'
    independent = variant == 'independent'
    if independent and not pattern.endswith('none'):
        raise ValueError('independent wheelset tracks are for patterns without a track input')
    # One IMM per roughness scale: building it discretises its whole bank
    imms = {scale: _imm(car, speed, pattern, scale)
            for scale in ((1.0, math.exp(DELTA), math.exp(-DELTA)) if roughness_unknown
                          else (1.0,))}
    centre = _spectrum(imms[1.0], car, pattern, creep_factor, independent)
    omegas = frequency_grid(centre.poles)
    steps = [(DELTA, 0.0), (0.0, DELTA)] if roughness_unknown else [(DELTA, 0.0)]
    derivatives = []
    for dc, da in steps:
        plus, minus = (_spectrum(imms[math.exp(sign * da)], car, pattern,
                                 creep_factor * math.exp(sign * dc), independent).at(omegas)
                       for sign in (1.0, -1.0))
        derivatives.append((plus - minus) / (2.0 * DELTA))
    j = whittle_information(centre.at(omegas), derivatives, omegas)
    j *= imms[1.0].params.sample_rate_hz
    return float(j[0, 0] - (j[0, 1] ** 2 / j[1, 1] if roughness_unknown else 0.0))


def _ekf_spectrum(ekf: CreepEkf, creep_factor: float, known: int) -> OutputSpectrum:
    """The creep EKF's own model of its measurements at a fixed creep factor (its state
    without ln c: the car, track and map-error states, other-bogie forces, offsets), with the
    full model's rear track rows, as it runs once it has kept a wheelbase's time of track."""
    n = ekf.i_theta
    model = ModeModel(ekf._discretize(creep_factor).fg[:n, :n], ekf._q_x[:n, :n], {})
    h, r = ekf.measurement_model(known, rear=True)
    return OutputSpectrum(model, h[:, :n], np.diag(r))


def estimator_fisher_rate(params: CreepEkfParams, creep_factor: float, known: int) -> float:
    """Fisher information about ln c per second that the creep EKF's own model (its process
    and measurement noise as set) says its channels carry, 1/s; ``known``: track columns
    (0, or 4: alignment and rate under the front bogie's wheelsets)."""
    ekf = CreepEkf(params)
    centre = _ekf_spectrum(ekf, creep_factor, known)
    omegas = frequency_grid(centre.poles)
    plus, minus = (_ekf_spectrum(ekf, creep_factor * math.exp(sign * DELTA), known).at(omegas)
                   for sign in (1.0, -1.0))
    j = whittle_information(centre.at(omegas), [(plus - minus) / (2.0 * DELTA)], omegas)
    return float(j[0, 0]) * params.sample_rate_hz


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', choices=sorted(SEED_SETS), default='held-out')
    parser.add_argument('--cars', type=int, default=0, help='first N cars (0: all)')
    parser.add_argument('--speeds', type=int, default=2)
    parser.add_argument('--patterns', default=','.join(PATTERNS))
    parser.add_argument('--estimator', action='store_true',
                        help="the bound under the creep EKF's own model as the evaluation "
                             "configures it (patterns D/none, D/exact, C/exact, C/map0.3)")
    parser.add_argument('--ekf-set', action='append', default=[], metavar='NAME=VALUE',
                        help='with --estimator: a creep EKF parameter for every case')
    args = parser.parse_args(argv)
    try:
        ekf_overrides = parse_assignments(args.ekf_set, CreepEkfParams())
    except ConfigurationError as exc:
        parser.exit(2, f'creep_information: {exc}\n')
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
                name, _, variant = pattern.partition('+')
                if args.estimator:
                    config = name.replace('C/', 'C-spec/')
                    params = replace(creep_params(car, speed, config, 'spectrum'),
                                     **ekf_overrides)
                    known = 0 if name.endswith('none') else 4
                    rates = [estimator_fisher_rate(params, c, known) for c in factors]
                else:
                    rates = [fisher_rate(car, speed, c, name, variant) for c in factors]
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
