"""Detection matrix of the TPMS voting fusion (Persson, Gustafsson, Drevö 2002) on the simulator.

Issue 6 / docs/methods/, §8. Each case of the matrix is a seeded road scenario built from a shipped
base scenario (its vehicle, tire, drive and sensor sections are kept; speed, steering, road and
events are replaced): the car drives at the case's speed with mild cornering (sine steering
scaled to ~1.5 m/s^2 peak lateral acceleration) and speed changes (-15 % and back), all tires
at placard pressure for the first ``FAULT_S`` s, then the case's tires lose ``loss`` percent by
a puncture-like step (``STEP_S`` long) or a slow leak (``LEAK_KPA_PER_MIN``); four tires lose it
by diffusion at the leak rate.

Every method is fed the way its node feeds it: vibration in
0.1 s blocks, wheel radius on 10 ms wheel-speed means closed at the IMU stamps with the driver
inputs held, the stiffness observer in 0.25 s chunks with held torques and steering. All three
calibrate over [0, ``CALIBRATION_END_S``] (nominal pressure, a production system's "reset"
button). The voter (core defaults) runs at 10 Hz; "time to warning" of one method is the same
voter fed that method alone (its own h_i and the same hold-off).

Detection time is counted from the moment the true loss reaches the case's level (end of the
step, or when the leak gets there; negative: warned before). A method is "applicable" where it
can see the case (the radius analysis compares tires, so it cannot see four equal losses).

Run: ``PYTHONPATH=src/tpms_ros:src/vehicle_monitor_common python benchmarks/eval_tpms_fusion.py
--quick --out /tmp/tpms_eval`` (``--full`` for the whole matrix of the issue: 360 cases, about
2 h of CPU per 20 cases on this machine, so hours).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import asdict, dataclass
import itertools
import json
import math
import multiprocessing
from pathlib import Path
import time

import numpy as np
import yaml

from tpms_ros.core.stiffness_observer import StiffnessObserverParams, TireStiffnessObserver
from tpms_ros.core.tires import TIRE_NAMES, TpmsIndication
from tpms_ros.core.tpms_voting import TpmsVoter, VoterParams
from tpms_ros.core.vibration_analysis import VibrationAnalyzer, VibrationParams
from tpms_ros.core.wheel_radius_analysis import (
    WheelRadiusAnalyzer,
    WheelRadiusParams,
    bin_wheel_speeds,
    sample_and_hold,
)
from tpms_ros.simulation.road_scenario import Scenario, parse_scenario
from tpms_ros.simulation.road_simulator import (
    RoadSimulationResult,
    simulate_scenario,
    to_topic_series,
)
from vehicle_monitor_common.figures import pyplot, save_figure

SCENARIOS = Path(__file__).resolve().parents[1] / 'src' / 'tpms_ros' / 'scenarios'
BASE_SCENARIO = SCENARIOS / 'puncture_15pct_fl.yaml'
CALIBRATION_END_S = 90.0
FAULT_S = 100.0
STEP_S = 2.0
LEAK_KPA_PER_MIN = 30.0
OBSERVE_S = 90.0          # run this long after the loss reaches its level
PEAK_LATERAL_ACC = 1.5    # m/s^2 of the sine steering at the case's speed
STEER_PERIOD_S = 25.0
PRESSURE_KPA = 200.0
WHEELBASE_M = 2.693       # only to scale the steering amplitude (kinematic, approximate)

METHODS = ('vibration', 'wheel_radius', 'stiffness')
# the nodes' defaults for the feed (vibration_analyzer block_s, tire_stiffness_observer
# publish period, driver-input staleness of both input-holding nodes)
VIBRATION_BLOCK_S = 0.1
STIFFNESS_CHUNK_S = 0.25
DRIVER_MAX_AGE_S = 0.1
TICK_S = 0.1              # voter evaluation period (the vibration node's output rate)
GRAVITY = 9.80665


@dataclass(frozen=True)
class MethodParams:
    """Parameters of the three cores for one car (vehicle data from the scenario)."""

    vibration: VibrationParams
    wheel_radius: WheelRadiusParams
    stiffness: StiffnessObserverParams


def method_params(scenario: Scenario) -> MethodParams:
    """Core defaults plus the car's own data (radius, tracks, static loads, driven axle)."""
    v = scenario.vehicle
    wheelbase = v.lf + v.lr
    front = v.m * GRAVITY * v.lr / wheelbase / 2.0
    rear = v.m * GRAVITY * v.lf / wheelbase / 2.0
    rates = scenario.rates
    return MethodParams(
        vibration=VibrationParams(sample_rate_hz=rates.wheel_speed_hz,
                                  driveline_compensation=v.driven_axle),
        wheel_radius=WheelRadiusParams(
            nominal_radius_m=v.rw, track_front_m=2.0 * v.tf, track_rear_m=2.0 * v.tr,
            static_load_n=(front, front, rear, rear), driven_axle=v.driven_axle,
            sample_rate_hz=rates.imu_hz,
            wheel_inertia_kgm2=v.iw, cg_height_m=v.h, wheelbase_m=wheelbase),
        stiffness=StiffnessObserverParams(sample_rate_hz=rates.wheel_speed_hz,
                                          driven_axle=v.driven_axle, rolling_radius_m=v.rw,
                                          wheelbase_m=wheelbase))


@dataclass(frozen=True)
class ReplayTraces:
    """What the methods and voters said at each voter tick.

    Attributes:
        t: (T,) tick times, s.
        confidence: method -> (T, 4) confidence (0 where unknown).
        flags: method -> (T, 4) flag t_i.
        known: method -> (T, 4) known.
        warnings: signal -> (T, 4) voter warning: each method alone, 'fused' (all three) and
            'fused_no_stiffness' (vibration + wheel radius, the paper's pair).
        resonance_hz: (T, 4) vibration frequency estimate (NaN unknown).
        calibration_errors: method -> message, for a calibration that failed.
    """

    t: np.ndarray
    confidence: dict[str, np.ndarray]
    flags: dict[str, np.ndarray]
    known: dict[str, np.ndarray]
    warnings: dict[str, np.ndarray]
    resonance_hz: np.ndarray
    calibration_errors: dict[str, str]


def _voters(voter_params: VoterParams) -> dict[str, TpmsVoter]:
    make = {m: (m,) for m in METHODS}
    make['fused'] = METHODS
    make['fused_no_stiffness'] = ('vibration', 'wheel_radius')
    return {name: TpmsVoter(voter_params.only(methods)) for name, methods in make.items()}


def replay_methods(result: RoadSimulationResult, calibration_end_s: float,
                   params: MethodParams | None = None,
                   voter_params: VoterParams | None = None) -> ReplayTraces:
    """Feed a simulated run through the three cores as their nodes do, and vote.

    Vibration: blocks of ``VIBRATION_BLOCK_S``, an indication after each. Wheel radius: the
    wheel speeds averaged over each IMU bin (:func:`bin_wheel_speeds`) with the driver inputs
    held at the IMU stamp (:func:`sample_and_hold`), an indication per tick. Stiffness:
    ``STIFFNESS_CHUNK_S`` chunks with held torques. Vibration and radius calibrate over
    [0, calibration_end_s]; the stiffness observer over its own ``calibration_s`` of valid data
    from 0. Voters evaluate every ``TICK_S`` with the latest indications.
    """
    p = params if params is not None else method_params(result.scenario)
    vp = voter_params if voter_params is not None else VoterParams()
    topics = to_topic_series(result)
    driver = topics['/vehicle/driver_inputs']
    t_driver = driver.stamps_ns * 1e-9
    t_w, omega = result.wheel_speed_t, result.wheel_speed
    imu_t, yaw = result.imu_t, result.imu_gyro[:, 1]
    rp = p.wheel_radius
    bins = bin_wheel_speeds(t_w, omega, imu_t, 1.0 / rp.sample_rate_hz, rp.max_wheel_speed_rad_s)
    torque_bins = sample_and_hold(t_driver, driver.fields['wheel_torque'], imu_t,
                                  DRIVER_MAX_AGE_S)
    steer_bins = sample_and_hold(t_driver, driver.fields['steering_angle'], imu_t,
                                 DRIVER_MAX_AGE_S)
    torque_w = sample_and_hold(t_driver, driver.fields['wheel_torque'], t_w, DRIVER_MAX_AGE_S)
    steer_w = sample_and_hold(t_driver, driver.fields['steering_angle'], t_w, DRIVER_MAX_AGE_S)

    vib = VibrationAnalyzer(p.vibration)
    rad = WheelRadiusAnalyzer(rp)
    stiff = TireStiffnessObserver(p.stiffness)
    vib.start_calibration()
    rad.start_calibration()
    stiff.start_calibration()
    voters = _voters(vp)
    fs = p.vibration.sample_rate_hz
    block = max(1, round(VIBRATION_BLOCK_S * fs))
    chunk = max(1, round(STIFFNESS_CHUNK_S * fs))
    n_ticks = t_w.size // block
    conf = {m: np.zeros((n_ticks, 4)) for m in METHODS}
    flags = {m: np.zeros((n_ticks, 4), dtype=bool) for m in METHODS}
    known = {m: np.zeros((n_ticks, 4), dtype=bool) for m in METHODS}
    warnings = {s: np.zeros((n_ticks, 4), dtype=bool) for s in voters}
    resonance = np.full((n_ticks, 4), np.nan)
    ticks = np.empty(n_ticks)
    errors: dict[str, str] = {}
    calibrated = False
    imu_pos = stiff_pos = 0
    latest: dict[str, TpmsIndication] = {}
    for k in range(n_ticks):
        end = (k + 1) * block
        now = float(t_w[end - 1])
        ticks[k] = now
        est = vib.process(omega[k * block:end])
        resonance[k] = np.where(est.known, est.frequency_hz, np.nan)
        imu_end = int(np.searchsorted(imu_t, now, side='right'))
        if imu_end > imu_pos:
            sl = slice(imu_pos, imu_end)
            rad.process(imu_t[sl], bins[sl], yaw[sl], torque_bins[sl], steer_bins[sl])
            imu_pos = imu_end
        while stiff_pos + chunk <= end:
            sl = slice(stiff_pos, stiff_pos + chunk)
            s_est = stiff.update(omega[sl], stamps=t_w[sl], wheel_torque=torque_w[sl],
                                 steering_angle=steer_w[sl])
            s_known = np.asarray(s_est.valid) & np.asarray(s_est.wheel_calibrated)
            latest['stiffness'] = TpmsIndication(
                'stiffness', float(t_w[stiff_pos + chunk - 1]),
                np.asarray(s_est.underinflated) & s_known,
                np.where(s_known, s_est.confidence, 0.0), s_known)
            stiff_pos += chunk
        if not calibrated and now >= calibration_end_s:
            calibrated = True
            for name, analyzer in (('vibration', vib), ('wheel_radius', rad)):
                try:
                    analyzer.finish_calibration()
                except ValueError as exc:
                    errors[name] = str(exc)
            if stiff.calibrating:
                errors['stiffness'] = 'calibration not finished at the end of the window'
        latest['vibration'] = vib.indication(now)
        if imu_pos:
            latest['wheel_radius'] = rad.indication(float(imu_t[imu_pos - 1]))
        for m in METHODS:
            ind = latest.get(m)
            if ind is not None:
                conf[m][k] = np.where(ind.known, ind.confidence, 0.0)
                flags[m][k] = ind.underinflated & ind.known
                known[m][k] = ind.known
        for name, voter in voters.items():
            use = [latest[m] for m in voter.params.method_thresholds if m in latest]
            warnings[name][k] = voter.evaluate(now, use).warning
    return ReplayTraces(ticks, conf, flags, known, warnings, resonance, errors)


TIRE_SETS: dict[str, tuple[str, ...]] = {
    'FL': ('FL',), 'FR': ('FR',), 'RL': ('RL',), 'RR': ('RR',),
    'front axle': ('FL', 'FR'), 'rear axle': ('RL', 'RR'),
    'left side': ('FL', 'RL'), 'right side': ('FR', 'RR'),
    'diagonal FL-RR': ('FL', 'RR'), 'diagonal FR-RL': ('FR', 'RL'),
    'three (not FL)': ('FR', 'RL', 'RR'), 'three (not FR)': ('FL', 'RL', 'RR'),
    'three (not RL)': ('FL', 'FR', 'RR'), 'three (not RR)': ('FL', 'FR', 'RL'),
    'four': ('FL', 'FR', 'RL', 'RR'),
}


@dataclass(frozen=True)
class Case:
    """One cell of the detection matrix.

    Attributes:
        tire_set: key of ``TIRE_SETS``.
        loss_pct: pressure loss, percent of placard.
        kind: 'step' or 'leak' (four tires: diffusion, i.e. a leak of all four).
        speed_kmh: cruise speed.
        surface: road surface name.
        seed: scenario seed.
    """

    tire_set: str
    loss_pct: float
    kind: str
    speed_kmh: float
    surface: str
    seed: int

    @property
    def tires(self) -> tuple[str, ...]:
        """Names of the tires that lose pressure."""
        return TIRE_SETS[self.tire_set]

    @property
    def name(self) -> str:
        """Short unique label."""
        return (f'{self.tire_set.replace(" ", "_")}_{self.loss_pct:g}pct_{self.kind}_'
                f'{self.speed_kmh:g}kmh_{self.surface}')

    @property
    def loss_reached_s(self) -> float:
        """Time the true loss reaches its level, s."""
        if self.kind == 'step':
            return FAULT_S + STEP_S
        return FAULT_S + 60.0 * PRESSURE_KPA * self.loss_pct / 100.0 / LEAK_KPA_PER_MIN


def _speed_segments(speed_kmh: float, duration_s: float) -> list[dict]:
    """Cruise with a -15 % dip every 50 s (ramp down 10 s, hold 10 s, ramp up 10 s)."""
    low = round(0.85 * speed_kmh, 1)
    cycle = [{'type': 'hold', 'duration_s': 20.0},
             {'type': 'ramp', 'to_kmh': low, 'duration_s': 10.0},
             {'type': 'hold', 'duration_s': 10.0},
             {'type': 'ramp', 'to_kmh': float(speed_kmh), 'duration_s': 10.0}]
    return cycle * int(math.ceil(duration_s / 50.0))


def steer_amplitude_deg(speed_kmh: float, lateral_acc: float = PEAK_LATERAL_ACC) -> float:
    """Kinematic front-wheel angle for a lateral acceleration at a speed, degrees."""
    v = speed_kmh / 3.6
    return math.degrees(math.atan(WHEELBASE_M * lateral_acc / (v * v)))


def build_scenario(case: Case, base_path: Path = BASE_SCENARIO) -> Scenario:
    """The case's scenario: the base file's car with the case's drive, road and events."""
    base = yaml.safe_load(base_path.read_text())
    duration = case.loss_reached_s + OBSERVE_S
    doc = {key: base[key] for key in ('vehicle', 'tire', 'drive', 'sensors', 'rates')
           if key in base}
    doc.update({
        'name': case.name,
        'description': f'{case.tires} lose {case.loss_pct:g} % by {case.kind} at {FAULT_S} s',
        'seed': case.seed,
        'duration_s': float(math.ceil(duration)),
        'speed': {'initial_kmh': float(case.speed_kmh),
                  'segments': _speed_segments(case.speed_kmh, duration)},
        'steering': {'segments': [{'type': 'sine', 'duration_s': float(math.ceil(duration)),
                                   'amplitude_deg': round(steer_amplitude_deg(case.speed_kmh),
                                                          3),
                                   'frequency_hz': 1.0 / STEER_PERIOD_S}]},
        'road': {'segments': [{'at_s': 0.0, 'surface': case.surface}]},
    })
    tires = list(case.tires)
    if case.kind == 'step':
        event = {'type': 'pressure_step', 'at_s': FAULT_S, 'tires': tires,
                 'drop_percent': case.loss_pct, 'duration_s': STEP_S}
    elif len(tires) == 4:
        event = {'type': 'diffusion', 'at_s': FAULT_S, 'rate_kpa_per_min': LEAK_KPA_PER_MIN,
                 'drop_percent': case.loss_pct}
    else:
        event = {'type': 'slow_leak', 'at_s': FAULT_S, 'tires': tires,
                 'rate_kpa_per_min': LEAK_KPA_PER_MIN,
                 'to_kpa': PRESSURE_KPA * (1.0 - case.loss_pct / 100.0)}
    doc['events'] = [event]
    return parse_scenario(yaml.safe_dump(doc, sort_keys=False), f'<{case.name}>')


def applicable(method: str, case: Case) -> bool:
    """Whether a method can see the case at all (radius: relative, not four equal losses)."""
    return not (method == 'wheel_radius' and len(case.tires) == 4)


@dataclass(frozen=True)
class Outcome:
    """Detection result of one warning signal in one case.

    Attributes:
        first_warning_s: time of the first warning after the fault started, relative to the
            loss reaching its level, s (None: never warned).
        correct: the tires warned at the end of the run are exactly the faulty ones.
        wrong_tires: healthy tires warned at any time after calibration.
        false_before_fault: any warning between calibration and the fault.
    """

    first_warning_s: float | None
    correct: bool
    wrong_tires: tuple[str, ...]
    false_before_fault: bool


def outcome(t: np.ndarray, warning: np.ndarray, case: Case) -> Outcome:
    """Score one (T, 4) warning signal."""
    truth = np.array([name in case.tires for name in TIRE_NAMES])
    after_cal = t >= CALIBRATION_END_S
    before = after_cal & (t < FAULT_S)
    during = t >= FAULT_S
    any_warn = warning.any(axis=1) & during
    first = float(t[np.argmax(any_warn)] - case.loss_reached_s) if any_warn.any() else None
    wrong = warning[after_cal][:, ~truth].any(axis=0)
    wrong_names = tuple(n for n, w in zip(np.array(TIRE_NAMES)[~truth], wrong, strict=True)
                        if w)
    return Outcome(first, bool(np.array_equal(warning[-1], truth)), wrong_names,
                   bool(warning[before].any()))


def run_case(case: Case) -> dict:
    """Simulate and replay one case; returns a JSON-ready record (runs in a worker)."""
    t0 = time.perf_counter()
    scenario = build_scenario(case)
    result = simulate_scenario(scenario)
    t_sim = time.perf_counter() - t0
    traces = replay_methods(result, calibration_end_s=CALIBRATION_END_S)
    record = {'case': asdict(case), 'name': case.name, 'loss_reached_s': case.loss_reached_s,
              'sim_wall_s': t_sim, 'replay_wall_s': time.perf_counter() - t0 - t_sim,
              'calibration_errors': traces.calibration_errors, 'signals': {}}
    for signal_name, warning in traces.warnings.items():
        out = outcome(traces.t, warning, case)
        record['signals'][signal_name] = asdict(out)
    record['trace'] = compact_trace(traces)
    return record


def compact_trace(traces: ReplayTraces, step: int = 5) -> dict:
    """A 2 Hz copy of the traces for the figures (confidences and warnings)."""
    sl = slice(None, None, step)
    return {'t': traces.t[sl].round(2).tolist(),
            'confidence': {m: np.round(c[sl], 3).tolist() for m, c in traces.confidence.items()},
            'flags': {m: f[sl].astype(int).tolist() for m, f in traces.flags.items()},
            'warnings': {s: w[sl].astype(int).tolist() for s, w in traces.warnings.items()}}


def quick_cases() -> list[Case]:
    """A representative subset (~20 cases, ~10 min on 2 workers)."""
    cases: list[Case] = []
    seed = itertools.count(100)
    for loss in (15.0, 25.0):
        for tire_set in ('FL', 'RR', 'rear axle', 'left side', 'diagonal FL-RR',
                         'three (not RR)', 'four'):
            kind = 'leak' if tire_set == 'four' else 'step'
            cases.append(Case(tire_set, loss, kind, 90.0, 'smooth_asphalt', next(seed)))
    for tire_set, kind in (('FL', 'leak'), ('front axle', 'leak')):
        cases.append(Case(tire_set, 15.0, kind, 90.0, 'smooth_asphalt', next(seed)))
    for speed in (50.0, 130.0):
        for tire_set in ('FR', 'RL', 'four'):
            kind = 'leak' if tire_set == 'four' else 'step'
            cases.append(Case(tire_set, 15.0, kind, speed, 'rough_concrete', next(seed)))
    return cases


def full_cases() -> list[Case]:
    """The whole matrix of issue 6: 2 losses x 15 tire sets x 2 kinds x 3 speeds x 2 roads."""
    cases = []
    seed = itertools.count(1000)
    for loss, tire_set, kind, speed, surface in itertools.product(
            (15.0, 25.0), TIRE_SETS, ('step', 'leak'), (50.0, 90.0, 130.0),
            ('smooth_asphalt', 'rough_concrete')):
        cases.append(Case(tire_set, loss, kind, speed, surface, next(seed)))
    return cases


def _fmt(value: float | None) -> str:
    return '   miss' if value is None else f'{value:7.1f}'


def print_table(records: Sequence[dict]) -> None:
    """Time to warning (s after the loss reached its level) per signal, ✓ = right tires."""
    signals = ['vibration', 'wheel_radius', 'stiffness', 'fused', 'fused_no_stiffness']
    header = f'{"case":58s}' + ''.join(f'{s[:14]:>16s}' for s in signals)
    print(header)
    print('-' * len(header))
    for rec in sorted(records, key=lambda r: r['name']):
        case = Case(**rec['case'])
        row = f'{rec["name"]:58s}'
        for s in signals:
            out = rec['signals'][s]
            method_na = s in METHODS and not applicable(s, case)
            if method_na:
                row += f'{"n/a":>16s}'
                continue
            mark = 'ok' if out['correct'] else ('WRONG' if out['wrong_tires'] else '--')
            if out['false_before_fault']:
                mark += '!FA'
            row += f'{_fmt(out["first_warning_s"])} {mark:>8s}'
        print(row)


def summarise(records: Sequence[dict]) -> dict:
    """Worst detection times per signal and loss, misses and wrong-tire counts."""
    summary: dict = {}
    for rec in records:
        case = Case(**rec['case'])
        for s, out in rec['signals'].items():
            if s in METHODS and not applicable(s, case):
                continue
            key = f'{s} {case.loss_pct:g}%'
            entry = summary.setdefault(key, {'cases': 0, 'missed': 0, 'wrong_tires': 0,
                                             'not_correct_at_end': 0, 'false_before_fault': 0,
                                             'times': []})
            entry['cases'] += 1
            if out['first_warning_s'] is None:
                entry['missed'] += 1
            else:
                entry['times'].append(out['first_warning_s'])
            entry['wrong_tires'] += bool(out['wrong_tires'])
            entry['not_correct_at_end'] += not out['correct']
            entry['false_before_fault'] += out['false_before_fault']
    for entry in summary.values():
        times = entry.pop('times')
        entry['median_s'] = float(np.median(times)) if times else None
        entry['max_s'] = float(np.max(times)) if times else None
    return summary


def plot_fig9(record: dict, path: Path) -> Path:
    """Paper Fig. 9 style: each method's warning (0/1) and confidence, and the fused warning."""
    plt = pyplot()

    trace = record['trace']
    t = np.asarray(trace['t'])
    truth = [TIRE_NAMES.index(n) for n in Case(**record['case']).tires]
    rows = [('wheel_radius', 'wheel radius'), ('vibration', 'vibration'),
            ('stiffness', 'stiffness observer'), ('fused', 'fused (voting)')]
    figure, axes = plt.subplots(len(rows), 1, figsize=(8.0, 8.5), sharex=True)
    for axis, (key, label) in zip(axes, rows, strict=True):
        warning = np.asarray(trace['warnings'][key])
        axis.step(t, warning[:, truth].max(axis=1), where='post', color='k', lw=1.8,
                  label='warning (faulty tires)')
        healthy = [j for j in range(4) if j not in truth]
        if healthy:
            axis.step(t, warning[:, healthy].max(axis=1) * 0.95, where='post', color='r',
                      lw=1.0, label='warning (healthy tires)')
        if key in trace['confidence']:
            conf = np.asarray(trace['confidence'][key])
            for j in truth:
                axis.plot(t, conf[:, j], lw=0.8, alpha=0.7, label=f'confidence {TIRE_NAMES[j]}')
        axis.axvline(FAULT_S, color='grey', ls='--', lw=0.8)
        axis.axvline(record['loss_reached_s'], color='grey', ls=':', lw=0.8)
        axis.axvspan(0, CALIBRATION_END_S, color='0.9')
        axis.set_ylim(-0.05, 1.1)
        axis.set_ylabel(label)
        axis.legend(loc='upper left', fontsize=7)
    axes[-1].set_xlabel('time (s)   [grey: calibration; dashed: loss starts; dotted: reached]')
    figure.suptitle(f'Warning signals, {record["name"]}')
    return save_figure(figure, path, dpi=110)


def main() -> None:
    """Run the matrix (quick or full) and write the table, JSON and figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument('--quick', action='store_true', help='representative subset (default)')
    group.add_argument('--full', action='store_true', help='the whole matrix (hours)')
    parser.add_argument('--only', default='', help='run only cases whose name contains this')
    parser.add_argument('--workers', type=int, default=2, help='processes (at most 2 here)')
    parser.add_argument('--out', type=Path, default=Path('/tmp/tpms_eval'))
    args = parser.parse_args()
    cases = full_cases() if args.full else quick_cases()
    if args.only:
        cases = [c for c in cases if args.only in c.name]
    args.out.mkdir(parents=True, exist_ok=True)
    workers = max(1, min(args.workers, 2))
    t0 = time.perf_counter()
    records = []
    with multiprocessing.get_context('fork').Pool(workers, maxtasksperchild=4) as pool:
        for rec in pool.imap_unordered(run_case, cases):
            records.append(rec)
            fused = rec['signals']['fused']
            print(f'[{len(records)}/{len(cases)} {time.perf_counter() - t0:6.0f} s] '
                  f'{rec["name"]}: fused {_fmt(fused["first_warning_s"])} s, '
                  f'correct={fused["correct"]}', flush=True)
            # keep what is done on disk: a long matrix can be looked at while it runs
            (args.out / 'fusion_results.json').write_text(json.dumps({'cases': records}))
    print_table(records)
    summary = summarise(records)
    print(json.dumps(summary, indent=1))
    (args.out / 'fusion_results.json').write_text(json.dumps(
        {'cases': records, 'summary': summary}, indent=None))
    for rec in records:
        if rec['case']['speed_kmh'] == 90.0 and rec['case']['kind'] == 'step' and \
                rec['case']['tire_set'] in ('FL', 'four', 'rear axle'):
            plot_fig9(rec, args.out / f'fig9_{rec["name"]}.png')
    print(f'wrote {args.out}; {time.perf_counter() - t0:.0f} s wall')


if __name__ == '__main__':
    main()
