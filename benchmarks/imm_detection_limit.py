"""How fast the suspension faults can be told apart at all: an ideal test on the IMM's own models.

The IMM's spring row misses its target at 30-33 m/s (docs/methods/rail_family_evaluation.md).
Issue 19 asks for detection that does not degrade at low speed *or, where physics sets a limit,
the limit measured per speed*. This script measures that limit.

**The ideal test.** It has every advantage the IMM lacks: it knows the fault's onset, holds the
same prior on every hypothesis from that instant (no Markov switching, no normal mode to
overcome), and uses each hypothesis' exact steady-state Kalman filter. Each hypothesis of the
IMM's grid (normal, spring 110-170 %, damper 90-30 %, as ``SuspensionImmParams.modes``) runs its
filter from the start of the run; from the onset the test accumulates their log-likelihoods
and gives the posterior exp(L_m) / sum exp(L). Its delay is the first time the hypotheses
within half a grid step of the truth hold more than 0.5 (the evaluation's "correct
hypothesis"). No detector that uses the same models and sensors does better on average, so
where the ideal test is slower than the target the target is beyond the model's information.

**Data.** Two sources per case (car, speed, fault size, as ``eval_rail_family`` draws them):

- ``model``: drawn from the IMM's own discretised model (the nominal mode before the onset, the
  fault's model after; process and sensor noise as the IMM assumes them, the published track
  as its noisy measurement): the information the model says the sensors carry. ``--draws``
  realisations per case.
- ``simulator``: the family simulator's run of the case (the evaluation's scenario and seed),
  through the same ideal test: the model's information minus what the model gets wrong.

With ``--imm`` the IMM itself is run on the simulator's data as the evaluation runs it, for the
comparison. Development cars by default (``--seeds held-out`` to measure the held-out cases:
nothing is tuned here). Speeds: the evaluation's (``--speeds K`` per car) or a sweep
(``--sweep 30,35,40,50,60``, each below 0.9 x the car's critical speed).

**Your vehicle.** ``--information 30,40,50 --params-file my_car.yaml [--node /ns/name]`` prints
the information rates for the suspension monitor as that params file configures it (its
``vehicle.*``, track spectrum, sensor noise and map accuracy): how fast faults can be told
apart on that car at those speeds, before any recording exists.

Run: ``source tools/env.sh && python benchmarks/imm_detection_limit.py [--seeds ...]
[--cars N] [--speeds K | --sweep V,V,...] [--kinds spring,damper] [--draws N] [--imm]
[--json PATH]``.
"""

from __future__ import annotations

import os

os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
from collections.abc import Sequence  # noqa: E402
from dataclasses import asdict, dataclass, field, replace  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

from eval_rail_family import (  # noqa: E402
    DAMPER_TARGET_S,
    FAULT_DURATION_S,
    FAULT_ONSET_S,
    HALF_STEP,
    SPRING_TARGET_S,
    _correct_probability,
    imm_params,
    run_imm,
)
import numpy as np  # noqa: E402
import scipy.linalg  # noqa: E402

from rail_monitor_ros.core.rail_model import full_car_state_space  # noqa: E402
from rail_monitor_ros.core.suspension_imm import (  # noqa: E402
    N_OUTPUTS,
    ModeModel,
    SuspensionImm,
    SuspensionImmParams,
)
from rail_monitor_ros.offline.imm_runs import ImmRunResult, run_suspension_imm  # noqa: E402
from rail_monitor_ros.simulation.rail_family import (  # noqa: E402
    DEVELOPMENT_SEEDS,
    HELD_OUT_SEEDS,
    IMM_SPEED_RANGE,
    SPEED_RANGE,
    FamilyCar,
    case_seed,
    family,
    fault_ratio,
    sample_speeds,
    suspension_fault_scenario,
)
from rail_monitor_ros.simulation.rail_simulator import simulate  # noqa: E402
from vehicle_monitor_common.graph_spec import node_parameter_values  # noqa: E402
from vehicle_monitor_common.parameters import ConfigurationError, build  # noqa: E402

SEED_SETS = {'development': DEVELOPMENT_SEEDS, 'held-out': HELD_OUT_SEEDS}
TARGET_S = {'spring': SPRING_TARGET_S, 'damper': DAMPER_TARGET_S}
#: Seconds of healthy data before the onset in the model's draws: the filters start at rest and
#: their slowest error modes decay in about 0.7 s, so they have settled at the onset.
MODEL_LEAD_S = 5.0
#: Seconds after the onset the test is followed.
FOLLOW_S = 5.0
#: The published track's error in the information table's exact-track column, m rms.
EXACT_TRACK_STD_M = 1e-5


class FilterBank:
    """The steady-state Kalman filter of each hypothesis, run side by side on one record."""

    def __init__(self, imm: SuspensionImm, ratios: Sequence[tuple[float, float]],
                 known: int) -> None:
        r = imm._r[known]
        models = [imm._discretize(s, d) for s, d in ratios]
        steady = [m.steady_state(known, r) for m in models]
        self.f = np.stack([m.f for m in models])
        self.h = np.stack([m.h[known] for m in models])
        s = np.stack([g.innovation for g in steady])
        self.s_inv = np.linalg.inv(s)
        self.gain = np.stack([g.prior_ht for g in steady]) @ self.s_inv
        _, logdet = np.linalg.slogdet(s)
        self.log_norm = -0.5 * (logdet + s.shape[1] * math.log(2.0 * math.pi))

    def log_likelihoods(self, z: np.ndarray, onset: int, nominal: int) -> np.ndarray:
        """(N, M) each hypothesis' log-likelihood of each sample of z (N, p).

        Before ``onset`` every filter takes the state estimate of hypothesis ``nominal`` after
        each sample (as the IMM's mixing does while the normal mode holds the probability), so
        at the onset all start from the best estimate of the state, not from a past they
        mis-tracked.
        """
        m, n = self.f.shape[0], self.f.shape[1]
        x = np.zeros((m, n))
        out = np.empty((z.shape[0], m))
        for k, zk in enumerate(z):
            e = zk[None, :] - np.einsum('mij,mj->mi', self.h, x)
            out[k] = self.log_norm - 0.5 * np.einsum('mi,mij,mj->m', e, self.s_inv, e)
            x = np.einsum('mij,mj->mi', self.f, x + np.einsum('mij,mj->mi', self.gain, e))
            if k + 1 < onset:
                x[:] = x[nominal]
        return out


def ideal_delay(log_lik: np.ndarray, onset: int, correct: np.ndarray, dt: float) -> float:
    """Seconds from the onset until the correct hypotheses' posterior (equal priors at the
    onset, log-likelihoods summed from it) exceeds 0.5; inf if never."""
    total = np.cumsum(log_lik[onset:], axis=0)
    total -= total.max(axis=1, keepdims=True)
    weight = np.exp(total)
    share = weight[:, correct].sum(axis=1) / weight.sum(axis=1)
    hit = np.flatnonzero(share > 0.5)
    return float(hit[0] * dt) if hit.size else math.inf


def model_record(imm: SuspensionImm, ratio: tuple[float, float], known: int, n_lead: int,
                 n_after: int, rng: np.random.Generator) -> np.ndarray:
    """Measurements drawn from the IMM's models: nominal for n_lead samples, then the fault."""
    r = imm._r[known]
    r_root = np.linalg.cholesky(r)
    chunks = []
    x = None
    for (s, d), count in (((1.0, 1.0), n_lead), (ratio, n_after)):
        model = imm._discretize(s, d)
        eig, vec = np.linalg.eigh(0.5 * (model.q + model.q.T))
        q_root = vec * np.sqrt(np.maximum(eig, 0.0))
        if x is None:     # the nominal model's stationary state (the IMM's prior)
            eig0, vec0 = np.linalg.eigh(imm._p0)
            x = (vec0 * np.sqrt(np.maximum(eig0, 0.0))) @ rng.standard_normal(eig0.size)
        h = model.h[known]
        z = np.empty((count, h.shape[0]))
        for k in range(count):
            z[k] = h @ x + r_root @ rng.standard_normal(h.shape[0])
            x = model.f @ x + q_root @ rng.standard_normal(q_root.shape[1])
        chunks.append(z)
    return np.vstack(chunks)


@dataclass
class LimitCase:
    """One case: the ideal test's delays on the model's draws and on the simulator's run, and
    the IMM's delay on the same run (when run)."""

    car: int
    speed: float
    kind: str
    ratio: float
    model_delays: list[float]
    simulator_delay: float
    imm_delay: float = math.nan
    imm_model_delays: list[float] = field(default_factory=list)
    information: float = math.nan      # a 10 % change of the component against normal, nats/s


def limit_case(car: FamilyCar, speed: float, kind: str, key: int, draws: int, with_imm: bool,
               imm_draws: int) -> LimitCase:
    """One fault case of the evaluation: the ideal test on ``draws`` model records and on the
    simulator's run; the IMM on the first ``imm_draws`` records and (``with_imm``) on the run."""
    ratio = fault_ratio(car, kind, key)
    imm = SuspensionImm(imm_params(car, speed))
    dt = imm.params.dt
    grid = imm.hypotheses      # the distinct (spring, damper) pairs of the bank
    truth = (ratio, 1.0) if kind == 'spring' else (1.0, ratio)
    spring = np.array([g[0] for g in grid])
    damper = np.array([g[1] for g in grid])
    correct = (np.abs(spring - truth[0]) <= HALF_STEP) & (np.abs(damper - truth[1]) <= HALF_STEP)
    scenario = suspension_fault_scenario(car, speed, case_seed(car, 200 + key), kind, ratio,
                                         FAULT_ONSET_S, FAULT_DURATION_S)
    result = simulate(scenario)
    u = result.measured_track_alignment
    known = u.shape[1]
    bank = FilterBank(imm, grid, known)
    z = np.column_stack([result.bogie_lateral_accel, result.bogie_yaw_rate,
                         result.body_lateral_accel, u @ imm._t_known[known].T])
    onset = int(np.searchsorted(result.time, FAULT_ONSET_S))
    end = min(z.shape[0], onset + int(round(FOLLOW_S / dt)))
    nominal = grid.index((1.0, 1.0))
    simulator_delay = ideal_delay(bank.log_likelihoods(z[:end], onset, nominal), onset,
                                  correct, dt)
    rng = np.random.default_rng([car.seed, key, 0 if kind == 'spring' else 1])
    n_lead, n_after = int(round(MODEL_LEAD_S / dt)), int(round(FOLLOW_S / dt))
    model_delays, imm_model_delays = [], []
    for draw in range(draws):
        record = model_record(imm, truth, known, n_lead, n_after, rng)
        model_delays.append(ideal_delay(bank.log_likelihoods(record, n_lead, nominal), n_lead,
                                        correct, dt))
        if draw < imm_draws:
            # the IMM on the same draw (the full car's known inputs are the track itself)
            run = run_suspension_imm(record[:, :N_OUTPUTS], record[:, N_OUTPUTS:],
                                     imm.params)
            imm_model_delays.append(_imm_delay(run, np.full(len(record), truth[0]),
                                               np.full(len(record), truth[1]), n_lead, dt))
    step = (1.1, 1.0) if kind == 'spring' else (1.0, 0.9)
    case = LimitCase(car.seed, speed, kind, ratio, model_delays, simulator_delay,
                     imm_model_delays=imm_model_delays,
                     information=hypothesis_information(imm, step, (1.0, 1.0), known))
    if with_imm:
        run, _ = run_imm(car, speed, result)
        case.imm_delay = _imm_delay(run, result.spring_ratio[:, 0], result.damper_ratio[:, 0],
                                    onset, dt)
    return case


def _imm_delay(run: ImmRunResult, spring: np.ndarray, damper: np.ndarray, onset: int,
               dt: float) -> float:
    """Seconds from the onset until the IMM's correct hypotheses exceed 0.5 (as the
    evaluation measures it); inf if never."""
    hit = np.flatnonzero(_correct_probability(run, spring, damper)[onset:] > 0.5)
    return float(hit[0] * dt) if hit.size else math.inf


class OutputSpectrum:
    """Spectral density of a discrete model's outputs, y = H x + v, x' = F x + w, from the
    Schur form F = Z T Z^H (a triangular solve per frequency)."""

    def __init__(self, model: ModeModel, h: np.ndarray, r: np.ndarray) -> None:
        self._t, z = scipy.linalg.schur(model.f, output='complex')
        self._hz = h @ z
        self._qz = z.conj().T @ model.q @ z
        self._r = r
        self.poles = np.diag(self._t)

    def at(self, omegas: np.ndarray) -> np.ndarray:
        """(N, p, p) S at each frequency, rad/sample."""
        eye = np.eye(self._t.shape[0])
        out = np.empty((omegas.size, *self._r.shape), dtype=complex)
        for index, omega in enumerate(omegas):
            # G = H Z (e^(i omega) - T)^-1: (e^(i omega) - T)^T G^T = (H Z)^T, lower triangular
            g = scipy.linalg.solve_triangular((np.exp(1j * omega) * eye - self._t).T,
                                              self._hz.T, lower=True).T
            out[index] = g @ self._qz @ g.conj().T + self._r
        return out


def frequency_grid(poles: np.ndarray) -> np.ndarray:
    """Frequencies in (0, pi], rad/sample: uniform, log-spaced towards zero (the track's slow
    states), and 241 points across +-30 half-widths of every pole within 0.2 of the unit
    circle (the lightly damped modes)."""
    parts = [np.linspace(1e-4, math.pi, 4000), np.geomspace(1e-7, 1e-1, 1500)]
    for pole in poles:
        half_width = max(1.0 - abs(pole), 1e-7)
        if half_width < 0.2:
            parts.append(np.clip(abs(np.angle(pole)) + half_width * np.linspace(-30, 30, 241),
                                 1e-7, math.pi))
    return np.unique(np.concatenate(parts))


def information_rate(truth: OutputSpectrum, model: OutputSpectrum, sample_rate_hz: float,
                     ) -> float:
    """Expected log-likelihood ratio per second of the true model over another on the true
    model's data: the Kullback-Leibler rate between the two stationary output processes,
    (1 / 2 pi) int_0^pi [tr(S_m^-1 S_t) - p - ln det(S_m^-1 S_t)] d omega per sample, nats/s
    (what the two steady-state Kalman filters' log-likelihoods differ by on average)."""
    omegas = frequency_grid(np.concatenate([truth.poles, model.poles]))
    ratio = np.linalg.solve(model.at(omegas), truth.at(omegas))
    eigenvalues = np.linalg.eigvals(ratio)
    integrand = np.real(np.sum(eigenvalues - 1.0 - np.log(eigenvalues), axis=1))
    return float(np.trapezoid(integrand, omegas)) / (2.0 * math.pi) * sample_rate_hz


def hypothesis_information(imm: SuspensionImm, truth: tuple[float, float],
                           model: tuple[float, float], known: int) -> float:
    """:func:`information_rate` of the IMM's hypothesis ``truth`` over ``model`` with its
    sensors and ``known`` known track inputs, nats/s."""
    r = imm._r[known]
    true_model, other = imm._discretize(*truth), imm._discretize(*model)
    return information_rate(OutputSpectrum(true_model, true_model.h[known], r),
                            OutputSpectrum(other, other.h[known], r),
                            imm.params.sample_rate_hz)


def information_cell(params: SuspensionImmParams, speed: float) -> str:
    """'spring, damper / spring, damper': the information rates (nats/s) of a 10 % spring rise
    and a 10 % damper loss against normal at this speed, with the map's stated accuracy
    (``known_track_std_m``) and with an exact track."""
    vehicle = params.vehicle.with_speed(speed)
    rates = []
    for std in (params.known_track_std_m, EXACT_TRACK_STD_M):
        imm = SuspensionImm(replace(params, known_track_std_m=std), vehicle)
        known = imm._known_sizes[-1]
        rates += [hypothesis_information(imm, (1.1, 1.0), (1.0, 1.0), known),
                  hypothesis_information(imm, (1.0, 0.9), (1.0, 1.0), known)]
    return '{:.0f}, {:.0f} / {:.0f}, {:.0f}'.format(*rates)


def information_table(cars: Sequence[FamilyCar], speeds: Sequence[float]) -> list[str]:
    """Per car and speed: :func:`information_cell` ('-' above 0.9 of its critical speed)."""
    lines = ['| car (map error) | ' + ' | '.join(f'{v:g} m/s' for v in speeds) + ' |',
             '| --- |' + ' --- |' * len(speeds)]
    for car in cars:
        span = car.speed_range(SPEED_RANGE[0], SPEED_RANGE[1])
        cells = [information_cell(imm_params(car, speed), speed)
                 if span is not None and span[0] <= speed <= span[1] else '-'
                 for speed in speeds]
        lines.append(f'| {car.seed} ({1e3 * car.map_error_rms:.2f} mm) | '
                     + ' | '.join(cells) + ' |')
    return lines


def vehicle_information_table(params_file: str, node: str, speeds: Sequence[float],
                              ) -> list[str]:
    """:func:`information_cell` per speed for the suspension monitor as a params file
    configures it (the node's ``vehicle.*``, track spectrum, sensor noise and
    ``known_track_std_m``); 'unstable' where the full car hunts at that speed.

    Raises:
        ConfigurationError: in one line, for a file that cannot be read or a refused value.
    """
    values = node_parameter_values(node, (params_file,), {})
    try:
        params = build(SuspensionImmParams, values)
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f'{params_file}: {node}: invalid parameters: {exc}') from None
    cells = []
    for speed in speeds:
        car = full_car_state_space(params.vehicle.with_speed(speed), 1.0, (1.0, 1.0),
                                   (1.0, 1.0))
        stable = bool(np.max(np.linalg.eigvals(car.a).real) < 0.0)
        cells.append(information_cell(params, speed) if stable else 'unstable')
    return ['| ' + ' | '.join(f'{v:g} m/s' for v in speeds) + ' |',
            '|' + ' --- |' * len(speeds), '| ' + ' | '.join(cells) + ' |']


def _fmt(value: float) -> str:
    return 'never' if math.isinf(value) else f'{value:.3f}'


def summary(cases: Sequence[LimitCase], grouping: str,
            bands: Sequence[tuple[float, float]]) -> list[str]:
    """Per kind and band of ``grouping`` ('speed', m/s, or 'information' of a 10 % change,
    nats/s): the share of cases in time for each source, and the delays."""
    unit = 'm/s' if grouping == 'speed' else 'nats/s'
    lines = [f'| kind | {grouping} band | cases | ideal test on model draws: in time; case '
             'medians, median / worst | IMM on model draws: in time | ideal test on the '
             'simulator: in time, median / worst | IMM on the simulator: in time, median / '
             'worst |', '| --- | --- | --- | --- | --- | --- | --- |']
    for kind in ('spring', 'damper'):
        target = TARGET_S[kind]
        for low, high in bands:
            band = [c for c in cases
                    if c.kind == kind and low <= getattr(c, grouping) < high]
            if not band:
                continue
            medians = [float(np.median(c.model_delays)) for c in band]
            draws = [d for c in band for d in c.model_delays]
            sim = [c.simulator_delay for c in band]
            imm = [c.imm_delay for c in band if not math.isnan(c.imm_delay)]
            imm_text = (f'{sum(d <= target for d in imm)}/{len(imm)}, '
                        f'{_fmt(float(np.median(imm)))} / {_fmt(max(imm))} s' if imm else '-')
            imm_model = [d for c in band for d in c.imm_model_delays]
            imm_model_text = (f'{sum(d <= target for d in imm_model)}/{len(imm_model)}'
                              if imm_model else '-')
            lines.append(
                f'| {kind} (<= {target:g} s) | {low:g}-{high:g} {unit} | {len(band)} | '
                f'{sum(d <= target for d in draws)}/{len(draws)}; '
                f'{_fmt(float(np.median(medians)))} / {_fmt(max(medians))} s | '
                f'{imm_model_text} | '
                f'{sum(d <= target for d in sim)}/{len(sim)}, {_fmt(float(np.median(sim)))} / '
                f'{_fmt(max(sim))} s | {imm_text} |')
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seeds', choices=sorted(SEED_SETS), default='development')
    parser.add_argument('--cars', type=int, default=0, help='first N cars (0: all)')
    parser.add_argument('--speeds', type=int, default=2,
                        help="speeds per car drawn as the evaluation draws them")
    parser.add_argument('--sweep', default='',
                        help='comma-separated speeds instead (each below the car\'s limit)')
    parser.add_argument('--kinds', default='spring,damper')
    parser.add_argument('--draws', type=int, default=20)
    parser.add_argument('--imm', action='store_true',
                        help="also run the IMM on each case's simulator run")
    parser.add_argument('--imm-draws', type=int, default=0,
                        help='also run the IMM on the first N model draws of each case')
    parser.add_argument('--information', default='',
                        help='comma-separated speeds: print the information table instead')
    parser.add_argument('--params-file', default='',
                        help="with --information: a suspension_monitor params file (your "
                             "vehicle) instead of the family's cars")
    parser.add_argument('--node', default='/suspension_monitor',
                        help='the node whose parameters the params file gives')
    parser.add_argument('--json', default='')
    args = parser.parse_args(argv)
    cars = family(SEED_SETS[args.seeds])
    if args.cars:
        cars = cars[:args.cars]
    if args.information:
        table_speeds = [float(v) for v in args.information.split(',')]
        try:
            print('\n'.join(vehicle_information_table(args.params_file, args.node,
                                                      table_speeds)
                            if args.params_file else information_table(cars, table_speeds)))
        except ConfigurationError as exc:
            parser.exit(2, f'imm_detection_limit: {exc}\n')
        return 0
    kinds = [k for k in args.kinds.split(',') if k]
    cases: list[LimitCase] = []
    started = time.perf_counter()
    for car in cars:
        if args.sweep:
            span = car.speed_range(*IMM_SPEED_RANGE)
            speeds: tuple[float, ...] = tuple(
                float(v) for v in args.sweep.split(',')
                if span is not None and span[0] <= float(v) <= span[1])
        else:
            speeds = sample_speeds(car, args.speeds, *IMM_SPEED_RANGE)
        for key, speed in enumerate(speeds):
            for kind in kinds:
                case = limit_case(car, speed, kind, key, args.draws, args.imm,
                                  args.imm_draws)
                cases.append(case)
                model = np.array(case.model_delays)
                print(f'car {car.seed} {speed:5.1f} m/s {kind:6s} {100 * case.ratio:3.0f} %: '
                      f'ideal on model median {_fmt(float(np.median(model)))} s, 90th pct '
                      f'{_fmt(float(np.quantile(model, 0.9)))} s, in time '
                      f'{np.mean(model <= TARGET_S[kind]):.0%}; ideal on simulator '
                      f'{_fmt(case.simulator_delay)} s; IMM {_fmt(case.imm_delay)} s, on '
                      f'model draws {", ".join(_fmt(d) for d in case.imm_model_delays)}; '
                      f'information of a 10 % change {case.information:.0f} nats/s '
                      f'[{time.perf_counter() - started:.0f} s]', flush=True)
    bands = ((20.0, 30.0), (30.0, 35.0), (35.0, 40.0), (40.0, 50.0), (50.0, 60.01),
             (60.01, 80.0))
    print('\n'.join(summary(cases, 'speed', bands)))
    print('\n'.join(summary(cases, 'information', ((0.0, 60.0), (60.0, 150.0),
                                                    (150.0, 500.0), (500.0, math.inf)))))
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as handle:
            json.dump([asdict(c) for c in cases], handle, indent=1)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
