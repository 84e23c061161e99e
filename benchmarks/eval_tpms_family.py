"""TPMS methods on the held-out car family (issue 21): stiffness errors, detection, false alarms.

Each car of the family (``tpms_ros.simulation.car_family``, held-out seeds by default) is driven
on a drawn drive (urban / rural / motorway in turn) in up to three cases:

* ``diffusion20``: all four tires lose 20 % by diffusion starting at ``--fault-s``
  (``--diffusion-pct-per-min`` of placard per minute, 15 %/min = 30 kPa/min on a 200 kPa car);
* ``puncture25``: one tire (drawn) loses 25 % over 2 s at ``--fault-s``;
* ``puncture15``: one or two tires (drawn) lose 15 % over 2 s at ``--fault-s``;
* ``nominal`` (not run by default): no fault; [``--calibration-s``, ``--fault-s``] is the
  nominal driving judged for false warnings (``--cases nominal --fault-s 1890 --observe-s 0``:
  the issue's 30 minutes per car).

Every case starts with all tires at placard: the three methods calibrate at the start of the
drive (vibration and wheel radius over [0, ``--calibration-s``], the stiffness observer over its
own 60 s of valid data), then [``--calibration-s``, ``--fault-s``] is nominal driving. After
the loss reached its level the drive goes on for ``--observe-s`` or the case's detection window
where that is longer (``DETECTION_LIMIT_S``: the diffusion's 2 minutes). Each
method gets only what a user of the car can know (``FamilyCar.user_parameters``): placard
(stiffness ``nominal_pressure_kpa``), driven axle (``driven_axle``, vibration
``driveline_compensation``: front, rear or all), nominal radius, track,
wheelbase, the encoder's teeth; everything else at the core defaults (the nodes' defaults:
the stiffness observer reads the ECU's timer from held tooth periods; ``--ecu-given`` gives it
how the ECU forms the speed instead, ``FamilyCar.ecu_parameters``). The
methods are fed as their nodes feed them (vibration in 0.1 s blocks, wheel radius on IMU-rate
bins, the stiffness observer in 0.25 s chunks with held driver inputs; the voter at 10 Hz).

Printed per car and case: the stiffness observer's mean error and std per tire at nominal
(after calibration; ``unk`` where it reported the tire not valid), the correlation of one
tire's error with speed, the reading after the 20 % four-tire loss, the fused warning's
detection time (s after the loss reached its level; all faulty tires named), the stiffness
method's own time for the diffusion, false warnings (a healthy tire warned after calibration),
and the highest confidence of each method in nominal driving with its margin to its threshold.

Run (reduced first): ``python benchmarks/eval_tpms_family.py --cars 4 --cases diffusion20``;
``--workers 2`` at most on this machine; results also in ``--out`` (JSON). ``--scoreboard PATH``
also writes one row per target of the issue (pass rate, worst case) as the main job's
scoreboard shows them (``vehicle_monitor_common.family_results``; committed as
``docs/results/tpms_family.json``), after a run or from saved runs:
``python benchmarks/eval_tpms_family.py --report RUNS.json [MORE.json] --scoreboard PATH
[--commit SHA]``. ``--stiffness-set NAME=VALUE`` and ``--vibration-set NAME=VALUE``
(repeatable) set a stiffness observer or vibration analyzer parameter in every run, for
ablations on the tuning cars (``--tuning``).
``--traces DIR`` keeps each run's indications as the voter got them, tick by tick, so another
voting rule can be judged on the same runs without replaying them (:func:`load_trace`,
:func:`revote`, :func:`score`).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass, field, replace
import json
import math
import multiprocessing
import os
from pathlib import Path
import pickle
import re
import time
from typing import Any

import numpy as np

from tpms_ros.core.stiffness_observer import (
    PressureRelation,
    StiffnessObserverParams,
    TireStiffnessObserver,
)
from tpms_ros.core.tires import TIRE_NAMES, TpmsIndication
from tpms_ros.core.tpms_voting import TpmsVoter, VoterParams
from tpms_ros.core.vibration_analysis import VibrationAnalyzer, VibrationParams
from tpms_ros.core.wheel_radius_analysis import (
    WheelRadiusAnalyzer,
    WheelRadiusParams,
    bin_wheel_speeds,
    sample_and_hold,
)
from tpms_ros.simulation.car_family import (
    DRIVE_KINDS,
    HELD_OUT_SEEDS,
    TUNING_SEEDS,
    FamilyCar,
    car_scenario,
    pressure_event,
    sample_car,
)
from tpms_ros.simulation.road_simulator import (
    RoadSimulationResult,
    simulate_scenario,
    to_topic_series,
)
from vehicle_monitor_common.family_results import (
    FamilyResults,
    FamilyRow,
    current_commit,
    today,
    write_family_results,
)
from vehicle_monitor_common.parameters import ConfigurationError, parse_assignments, with_values

METHODS = ('vibration', 'wheel_radius', 'stiffness')
# Issue 21's detection targets: the fused warning within this long after the loss reached its
# level, s.
DETECTION_LIMIT_S = {'puncture25': 60.0, 'puncture15': 60.0, 'diffusion20': 120.0}
CASES = ('diffusion20', 'puncture25', 'puncture15', 'nominal')
# The fault cases (the scoreboard's rows); 'nominal' is a drive without a fault, every
# second of it after the calibration nominal driving (--fault-s sets its length).
FAULT_CASES = CASES[:3]
VIBRATION_BLOCK_S = 0.1
STIFFNESS_CHUNK_S = 0.25
DRIVER_MAX_AGE_S = 0.1
STEP_S = 2.0


@dataclass(frozen=True)
class Settings:
    """Run settings (command line)."""

    calibration_s: float = 90.0
    fault_s: float = 150.0
    # Driving after the loss reached its level; a case whose target allows longer (the 20 %
    # diffusion: 2 minutes) is observed that long (observed_s).
    observe_s: float = 60.0
    diffusion_pct_per_min: float = 15.0
    tooth_correction: bool = True
    # The tire's stiffness-pressure law given to the stiffness observer as tire data
    # (FamilyCar.tire_law_parameters); default: not known, the core's default (the paper's line).
    law_given: bool = False
    # Where simulated drives are kept ('' = not kept): a replay with other method settings
    # then costs ~6 s instead of ~46 s (the drive depends only on the car, case and timing).
    sim_cache: str = ''
    # Where each run's traces are written ('' = not written): the methods' indications as the
    # voter saw them at each tick, so voting rules can be compared without replaying
    # (:func:`revote`).
    traces: str = ''
    # Each car's encoder tooth-spacing error times this (0: perfect rings). The drives are
    # otherwise the same: the ring's draw only scales, every random stream stays where it was.
    ring_scale: float = 1.0
    # Stiffness observer parameters set for every run (dotted name -> value), for ablations.
    stiffness_set: dict[str, Any] = field(default_factory=dict)
    # Vibration analyzer parameters set for every run, likewise.
    vibration_set: dict[str, Any] = field(default_factory=dict)
    # How the car's ABS ECU forms the speed (FamilyCar.ecu_parameters) given to the stiffness
    # observer; default: not known, the observer reads the timer from held tooth periods.
    ecu_given: bool = False


@dataclass(frozen=True)
class Job:
    """One simulated drive: a car, a case, a drive kind."""

    seed: int
    case: str
    drive: str
    settings: Settings


def case_events(job: Job, car: FamilyCar) -> tuple[list, tuple[int, ...], float, float]:
    """(events, faulty tire indices, loss percent, time the loss reaches its level)."""
    s = job.settings
    rng = np.random.default_rng([23, job.seed, CASES.index(job.case)])
    if job.case == 'nominal':
        return [], (), 0.0, s.fault_s
    if job.case == 'diffusion20':
        loss = 20.0
        event = pressure_event('diffusion', s.fault_s, drop_percent=loss,
                               rate_kpa_per_min=s.diffusion_pct_per_min / 100.0
                               * car.placard_kpa)
        return [event], (0, 1, 2, 3), loss, s.fault_s + 60.0 * loss / s.diffusion_pct_per_min
    loss = 25.0 if job.case == 'puncture25' else 15.0
    count = 1 if job.case == 'puncture25' else int(rng.integers(1, 3))
    tires = tuple(sorted(int(t) for t in rng.choice(4, size=count, replace=False)))
    event = pressure_event('pressure_step', s.fault_s, tires=tires, drop_percent=loss,
                           duration_s=STEP_S)
    return [event], tires, loss, s.fault_s + STEP_S


def observed_s(job: Job) -> float:
    """How long the run drives on after its loss reached its level: the settings' time, or
    the case's detection limit where that is longer (a run shorter than its target's window
    would count a detection inside the window as a miss)."""
    return max(job.settings.observe_s, DETECTION_LIMIT_S.get(job.case, 0.0))


def method_params(car: FamilyCar, settings: Settings) -> tuple[VibrationParams,
                                                               WheelRadiusParams,
                                                               StiffnessObserverParams]:
    """Core defaults plus only what the user of this car knows."""
    user = car.user_parameters()
    axle = car.layout
    vibration = with_values(VibrationParams(driveline_compensation=axle,
                                            encoder_teeth=user['encoder_teeth']),
                            settings.vibration_set)
    radius = WheelRadiusParams(nominal_radius_m=user['nominal_radius_m'],
                               track_front_m=user['track_front_m'],
                               track_rear_m=user['track_rear_m'], driven_axle=axle,
                               wheelbase_m=user['wheelbase_m'])
    stiffness = StiffnessObserverParams(
        driven_axle=car.layout, rolling_radius_m=user['nominal_radius_m'],
        wheelbase_m=user['wheelbase_m'], nominal_pressure_kpa=(user['nominal_pressure_kpa'],) * 4,
        encoder_teeth=user['encoder_teeth'], tooth_correction=settings.tooth_correction,
        pressure_relation=(PressureRelation(**car.tire_law_parameters()) if settings.law_given
                           else PressureRelation()),
        **(car.ecu_parameters() if settings.ecu_given else {}))
    return vibration, radius, with_values(stiffness, settings.stiffness_set)


def _voters(voter_params: VoterParams) -> dict[str, TpmsVoter]:
    make: dict[str, tuple[str, ...]] = {m: (m,) for m in METHODS}
    make['fused'] = METHODS
    return {name: TpmsVoter(voter_params.only(methods)) for name, methods in make.items()}


def replay(result: RoadSimulationResult, car: FamilyCar, settings: Settings) -> dict[str, Any]:
    """Feed the run through the three cores as their nodes do, vote; traces at 10 Hz."""
    vib_p, rad_p, stiff_p = method_params(car, settings)
    vp = VoterParams()
    topics = to_topic_series(result)
    driver = topics['/vehicle/driver_inputs']
    t_driver = driver.stamps_ns * 1e-9
    t_w, omega = result.wheel_speed_t, result.wheel_speed
    imu_t, yaw = result.imu_t, result.imu_gyro[:, 1]
    bins = bin_wheel_speeds(t_w, omega, imu_t, 1.0 / rad_p.sample_rate_hz,
                            rad_p.max_wheel_speed_rad_s)
    torque_bins = sample_and_hold(t_driver, driver.fields['wheel_torque'], imu_t,
                                  DRIVER_MAX_AGE_S)
    steer_bins = sample_and_hold(t_driver, driver.fields['steering_angle'], imu_t,
                                 DRIVER_MAX_AGE_S)
    torque_w = sample_and_hold(t_driver, driver.fields['wheel_torque'], t_w, DRIVER_MAX_AGE_S)
    steer_w = sample_and_hold(t_driver, driver.fields['steering_angle'], t_w, DRIVER_MAX_AGE_S)

    vib = VibrationAnalyzer(vib_p)
    rad = WheelRadiusAnalyzer(rad_p)
    stiff = TireStiffnessObserver(stiff_p)
    vib.start_calibration()
    rad.start_calibration()
    stiff.start_calibration()
    voters = _voters(vp)
    fs = vib_p.sample_rate_hz
    block = max(1, round(VIBRATION_BLOCK_S * fs))
    chunk = max(1, round(STIFFNESS_CHUNK_S * fs))
    n_ticks = t_w.size // block
    # the indications as the voter got them (stamp, flags, confidences, known), per tick
    seen = {m: {'stamp': np.full(n_ticks, np.nan), 'flags': np.zeros((n_ticks, 4), bool),
                'conf': np.zeros((n_ticks, 4)), 'known': np.zeros((n_ticks, 4), bool)}
            for m in METHODS}
    warnings = {s: np.zeros((n_ticks, 4), dtype=bool) for s in voters}
    pressure = np.full((n_ticks, 4), np.nan)
    valid = np.zeros((n_ticks, 4), dtype=bool)
    trust: dict[str, np.ndarray] = {}
    s_trust: dict[str, np.ndarray] = {}
    ticks = np.empty(n_ticks)
    errors: dict[str, str] = {}
    statuses: dict[str, int] = {}
    calibrated_at: dict[str, float] = {}
    imu_pos = stiff_pos = 0
    latest: dict[str, TpmsIndication] = {}
    s_est = None
    for k in range(n_ticks):
        end = (k + 1) * block
        now = float(t_w[end - 1])
        ticks[k] = now
        vib.process(omega[k * block:end])
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
            s_trust = stiff.trust_features()
        for name, values in s_trust.items():
            trust.setdefault(name, np.full((n_ticks, 4), np.nan))[k] = values
        if s_est is not None:
            known = np.asarray(s_est.valid) & np.asarray(s_est.wheel_calibrated) \
                & (not s_est.calibrating)
            valid[k] = known
            pressure[k] = np.where(known, s_est.pressure_kpa, np.nan)
            if now >= settings.calibration_s:
                for st in s_est.status:
                    statuses[st] = statuses.get(st, 0) + 1
        if now >= settings.calibration_s:
            # as the nodes' calibration windows: they last calibration_s at least and go on
            # until every channel has its valid data (the stiffness observer counts its own)
            for name, analyzer in (('vibration', vib), ('wheel_radius', rad)):
                if analyzer.calibrating and analyzer.calibration_complete():
                    analyzer.finish_calibration()
                    calibrated_at[name] = now
            if 'stiffness' not in calibrated_at and not stiff.calibrating:
                calibrated_at['stiffness'] = now
        latest['vibration'] = vib.indication(now)
        if imu_pos:
            latest['wheel_radius'] = rad.indication(float(imu_t[imu_pos - 1]))
        for m in METHODS:
            ind = latest.get(m)
            if ind is not None:
                row = seen[m]
                row['stamp'][k] = ind.stamp_s
                row['flags'][k], row['conf'][k], row['known'][k] = (
                    ind.underinflated, ind.confidence, ind.known)
        for name, voter in voters.items():
            use = [latest[m] for m in voter.params.method_thresholds if m in latest]
            warnings[name][k] = voter.evaluate(now, use).warning
    for name, missing in (('vibration', vib.calibration_missing()),
                          ('wheel_radius', rad.calibration_missing()),
                          ('stiffness', stiff.calibration_missing())):
        if name not in calibrated_at:
            errors[name] = f'calibration not complete at the end of the run: {missing}'
    truth = np.column_stack([np.interp(ticks, result.handling.t, result.pressure_kpa[:, w])
                             for w in range(4)])
    speed = np.interp(ticks, result.handling.t, np.asarray(result.handling.vx))
    # each method's confidence where it knew the tire (0 where not, or before its first)
    conf = {m: np.where(seen[m]['known'], seen[m]['conf'], 0.0) for m in METHODS}
    return {'t': ticks, 'conf': conf, 'warnings': warnings, 'pressure': pressure,
            'valid': valid, 'truth': truth, 'speed': speed, 'errors': errors,
            'calibrated_at_s': calibrated_at, 'trust': trust,
            'statuses': statuses, 'thresholds': dict(vp.method_thresholds), 'h0': vp.h0,
            'indications': seen, 'encoder_noise': stiff.encoder_noise}


def load_trace(path: Path) -> tuple[Job, tuple[int, ...], float, dict[str, Any]]:
    """A run's traces written with ``--traces``: (job, faulty tires, time the loss reached its
    level, the :func:`replay` traces), as :func:`score` takes them."""
    with path.open('rb') as f:
        saved = pickle.load(f)
    job = dict(saved['job'])
    job['settings'] = Settings(**job['settings'])
    return Job(**job), tuple(saved['tires']), float(saved['reached_s']), saved['trace']


BEAT_EDGES_HZ = (0.0, 10.0, 20.0, 26.0, 40.0, 55.0, 67.5, 80.0, 100.0, 150.0, 250.0)


def beat_table(directories: list[Path]) -> None:
    """Print how often the vibration method is confident on a healthy tire (0.5 or more), by
    the beat of the tooth edges with the sampling, |e - round(e)| fs (e: edges per sample), on
    the cars whose ECU holds tooth periods (docs/methods/vibration_analyzer.md, "Edge beat"):
    every tick of the traces written with ``--traces`` in ``directories``, after the
    calibration, before the fault (after it, the healthy tires only). The edge rate is the
    vehicle speed over the nominal radius, a few per cent off each wheel's."""
    fs = VibrationParams().sample_rate_hz     # the rate every family car's ECU reports at
    ticks = np.zeros(len(BEAT_EDGES_HZ) - 1, dtype=np.int64)
    confident = np.zeros_like(ticks)
    runs = 0
    for path in sorted(p for d in directories for p in d.glob('*.pkl')):
        job, tires, _, tr = load_trace(path)
        car = family_car(job)
        if car.sensors.speed_method != 'tooth_period':
            continue
        runs += 1
        user = car.user_parameters()
        edges = (tr['speed'] / user['nominal_radius_m'] * car.sensors.teeth
                 / (2.0 * np.pi * fs))
        beat = np.abs(edges - np.round(edges)) * fs
        t = tr['t']
        used = (t >= job.settings.calibration_s) & (edges >= 0.75)
        if tires:
            used &= t < job.settings.fault_s
        healthy = [w for w in range(4) if w not in tires]
        conf = tr['conf']['vibration'][:, healthy]
        band = np.digitize(beat, BEAT_EDGES_HZ) - 1
        for k in range(ticks.size):
            rows = used & (band == k)
            ticks[k] += conf[rows].size
            confident[k] += int((conf[rows] >= 0.5).sum())
    print(f'{runs} runs with held tooth periods, from 0.75 edges per sample; healthy tires')
    bands = zip(BEAT_EDGES_HZ[:-1], BEAT_EDGES_HZ[1:], strict=True)
    print('| beat (Hz) | ' + ' | '.join(f'{a:g}-{b:g}' for a, b in bands) + ' |')
    print('| --- ' * (ticks.size + 1) + '|')
    print('| tire-ticks | ' + ' | '.join(str(n) for n in ticks) + ' |')
    print('| confidence >= 0.5 | ' + ' | '.join(
        f'{100.0 * c / n:.1f} %' if n else '-'
        for c, n in zip(confident, ticks, strict=True)) + ' |')


def revote(tr: dict[str, Any], params: VoterParams) -> np.ndarray:
    """(ticks, 4) warnings of a voter with ``params`` on a run's recorded indications (the
    ``indications`` of :func:`replay`): what that voter would have warned in the run."""
    voter = TpmsVoter(params)
    seen = tr['indications']
    out = np.zeros((tr['t'].size, 4), dtype=bool)
    for k, now in enumerate(tr['t']):
        use = [TpmsIndication(m, float(seen[m]['stamp'][k]), seen[m]['flags'][k],
                              seen[m]['conf'][k], seen[m]['known'][k])
               for m in params.method_thresholds if np.isfinite(seen[m]['stamp'][k])]
        out[k] = voter.evaluate(float(now), use).warning
    return out


def _first_all(t: np.ndarray, warn: np.ndarray, tires: tuple[int, ...], after: float
               ) -> float | None:
    """First time >= after at which every tire in ``tires`` is warned."""
    hit = (t >= after) & warn[:, list(tires)].all(axis=1)
    return float(t[np.argmax(hit)]) if hit.any() else None


def score(job: Job, car: FamilyCar, tr: dict[str, Any], tires: tuple[int, ...],
          reached_s: float) -> dict[str, Any]:
    """The figures of one run."""
    s = job.settings
    t = tr['t']
    nominal = (t >= s.calibration_s) & (t < s.fault_s)
    err = tr['pressure'] - tr['truth']
    rec: dict[str, Any] = {'seed': job.seed, 'case': job.case, 'drive': job.drive,
                           'tires': [TIRE_NAMES[i] for i in tires],
                           'calibration_errors': tr['errors'],
                           'calibrated_at_s': tr['calibrated_at_s'], 'statuses': tr['statuses'],
                           'encoder_noise': tr.get('encoder_noise', '')}
    mean, std, valid_frac = [], [], []
    for w in range(4):
        rows = nominal & tr['valid'][:, w]
        valid_frac.append(float(rows.sum() / max(1, nominal.sum())))
        if rows.sum() >= 20:
            mean.append(float(np.mean(err[rows, w])))
            std.append(float(np.std(err[rows, w])))
        else:
            mean.append(math.nan)
            std.append(math.nan)
    rec['nominal_mean_err_kpa'] = mean
    rec['nominal_std_kpa'] = std
    rec['nominal_valid_frac'] = valid_frac
    rows = nominal & tr['valid'][:, 0]
    rec['speed_corr_fl'] = float(np.corrcoef(err[rows, 0], tr['speed'][rows])[0, 1]) \
        if rows.sum() > 20 and np.std(tr['speed'][rows]) > 0 else math.nan
    end = t > t[-1] - 20.0
    rec['end_truth_kpa'] = tr['truth'][-1].tolist()
    rec['end_reading_kpa'] = [float(np.nanmean(tr['pressure'][end, w]))
                              if tr['valid'][end, w].any() else math.nan for w in range(4)]
    healthy = [w for w in range(4) if w not in tires]
    after_cal = t >= s.calibration_s
    fused = tr['warnings']['fused']
    # (a nominal drive has no faulty tire: nothing to detect)
    first = _first_all(t, fused, tires, s.fault_s) if tires else None
    rec['fused_detect_s'] = None if first is None else first - reached_s
    first_st = _first_all(t, tr['warnings']['stiffness'], tires, s.fault_s) if tires else None
    rec['stiffness_detect_s'] = None if first_st is None else first_st - reached_s
    rec['false_warning_tires'] = [TIRE_NAMES[w] for w in range(4)
                                  if fused[after_cal & (t < s.fault_s), w].any()
                                  or (w in healthy and fused[after_cal, w].any())]
    rec['false_warning_s'] = float(np.sum(fused[after_cal & (t < s.fault_s)].any(axis=1))
                                   * VIBRATION_BLOCK_S)
    peaks = {}
    for m in METHODS:
        c = tr['conf'][m]
        nominal_peak = float(c[nominal].max()) if nominal.any() else math.nan
        healthy_peak = float(c[after_cal][:, healthy].max()) if healthy else math.nan
        peaks[m] = {'nominal_max_conf': nominal_peak, 'healthy_max_conf': healthy_peak,
                    'threshold': tr['thresholds'][m],
                    'margin': tr['thresholds'][m] - max(nominal_peak, healthy_peak
                                                        if healthy else -1.0)}
    rec['confidence'] = peaks
    rec['h0'] = tr['h0']
    return rec


def simulate_job(job: Job, car: FamilyCar, events: list, duration: float
                 ) -> RoadSimulationResult:
    """The job's drive, from the cache when it holds it (keyed by everything the drive
    depends on)."""
    s = job.settings
    name = f'car{job.seed}_{job.case}_{job.drive}'
    if s.ring_scale != 1.0:
        name += f'_ring{s.ring_scale:g}'
    path = None
    if s.sim_cache:
        key = f'{name}_f{s.fault_s:g}_o{observed_s(job):g}_d{s.diffusion_pct_per_min:g}.pkl'
        path = Path(s.sim_cache) / key
        if path.exists():
            with path.open('rb') as f:
                cached: RoadSimulationResult = pickle.load(f)
            return cached
    scenario = car_scenario(car, job.drive, duration, events,
                            seed=job.seed * 10 + CASES.index(job.case), name=name)
    result = simulate_scenario(scenario)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(f'.{os.getpid()}.tmp')
        with partial.open('wb') as f:
            pickle.dump(result, f, protocol=pickle.HIGHEST_PROTOCOL)
        partial.replace(path)
    return result


def kept_drive(path: Path) -> tuple[RoadSimulationResult, FamilyCar]:
    """A drive that ``--sim-cache`` kept, and its car as sampled from the seed in the file's
    name (``car<seed>_...``; the ring's error as sampled, whatever ``--ring-scale`` the drive
    was made with)."""
    with path.open('rb') as f:
        result: RoadSimulationResult = pickle.load(f)
    seed = int(re.search(r'car(\d+)', path.name).group(1))   # type: ignore[union-attr]
    return result, sample_car(seed)


def family_car(job: Job) -> FamilyCar:
    """The job's car, its rings' tooth-spacing error scaled as the settings say."""
    car = sample_car(job.seed)
    ring = job.settings.ring_scale * car.sensors.tooth_error_rms
    return replace(car, sensors=replace(car.sensors, tooth_error_rms=ring))


def run_job(job: Job) -> dict[str, Any]:
    """Simulate (or load) and replay one job (worker)."""
    t0 = time.perf_counter()
    car = family_car(job)
    events, tires, _, reached = case_events(job, car)
    result = simulate_job(job, car, events, reached + observed_s(job))
    t_sim = time.perf_counter() - t0
    tr = replay(result, car, job.settings)
    rec = score(job, car, tr, tires, reached)
    if job.settings.traces:
        path = Path(job.settings.traces) / f'car{job.seed}_{job.case}_{job.drive}.pkl'
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open('wb') as f:
            # plain data (no class of this script), so any process can load it: load_trace
            pickle.dump({'job': asdict(job), 'tires': tires, 'reached_s': reached,
                         'trace': tr}, f, protocol=pickle.HIGHEST_PROTOCOL)
    rec['car'] = car.describe()
    rec['wall_s'] = [t_sim, time.perf_counter() - t0 - t_sim]
    return rec


def _f(x: float | None, fmt: str = '6.1f', none: str = 'miss') -> str:
    if x is None:
        return f'{none:>{fmt.split(".")[0]}}'
    if isinstance(x, float) and math.isnan(x):
        return f'{"unk":>{fmt.split(".")[0]}}'
    return format(x, fmt)


def print_record(rec: dict[str, Any]) -> None:
    """One block of lines per run."""
    mean = ' '.join(_f(m, '6.1f') for m in rec['nominal_mean_err_kpa'])
    std = ' '.join(_f(m, '5.1f') for m in rec['nominal_std_kpa'])
    line = (f'{rec["seed"]} {rec["case"]:<11} {rec["drive"]:<8} nominal err [{mean}] '
            f'std [{std}] corr(FL,v) {_f(rec["speed_corr_fl"], "5.2f")}')
    if rec['case'] == 'diffusion20':
        reading = ' '.join(_f(m, '5.0f') for m in rec['end_reading_kpa'])
        line += (f' | -20%: truth {rec["end_truth_kpa"][0]:.0f} read [{reading}]'
                 f' stiff {_f(rec["stiffness_detect_s"])}')
    line += (f' | fused {"+".join(rec["tires"])} {_f(rec["fused_detect_s"])} s'
             f' | false {",".join(rec["false_warning_tires"]) or "-"}')
    conf = ' '.join(f'{m[:3]} {p["nominal_max_conf"]:.2f}/{p["margin"]:+.2f}'
                    for m, p in rec['confidence'].items())
    line += f' | max conf/margin {conf}'
    if rec['calibration_errors']:
        line += f' | cal errors {rec["calibration_errors"]}'
    print(line, flush=True)


def summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    """The issue's targets (the scoreboard's rows: pass rate, worst case, verdict) and the
    figures behind them: tires at placard, highest confidences and margins to the thresholds."""
    out: dict[str, Any] = {
        row.target: f'{row.pass_text()}, worst {row.worst_text()}: '
                    f'{"met" if row.met else "not met"}' for row in scoreboard_rows(records)}
    known = [(m, s) for r in records for m, s in zip(r['nominal_mean_err_kpa'],
                                                     r['nominal_std_kpa'], strict=True)
             if not math.isnan(m)]
    out['stiffness_nominal_tires'] = 4 * len(records)
    out['stiffness_nominal_unknown'] = 4 * len(records) - len(known)
    out['stiffness_nominal_pass'] = sum(abs(m) < 10.0 and s < 5.0 for m, s in known)
    out['stiffness_nominal_low_gt10'] = sum(m < -10.0 for m, _ in known)
    for m in METHODS:
        out[f'{m}_max_nominal_conf'] = max(r['confidence'][m]['nominal_max_conf']
                                           for r in records)
        out[f'{m}_min_margin'] = min(r['confidence'][m]['margin'] for r in records)
    return out


def _md(x: Any, fmt: str = '.1f') -> str:
    if x is None:
        return 'miss'
    if isinstance(x, float) and math.isnan(x):
        return 'unk'
    return format(x, fmt)


def markdown(records: list[dict[str, Any]]) -> str:
    """Per car and case tables (Markdown) for the closing note."""
    lines = ['| car | case | drive | stiffness error at placard, mean (std) FL FR RL RR, kPa '
             '| corr(err FL, v) | -20 %: truth / read, kPa | fused detect, s | stiffness '
             'detect, s | false warning | max conf vib / rad / stiff (margin) |',
             '| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |']
    for r in sorted(records, key=lambda r: (r['seed'], r['case'])):
        err = ' '.join(f'{_md(m, "+.1f")} ({_md(s)})' for m, s in
                       zip(r['nominal_mean_err_kpa'], r['nominal_std_kpa'], strict=True))
        reading = (f'{r["end_truth_kpa"][0]:.0f} / '
                   + ' '.join(_md(x, '.0f') for x in r['end_reading_kpa'])
                   if r['case'] == 'diffusion20' else '')
        conf = ' / '.join(f'{p["nominal_max_conf"]:.2f} ({p["margin"]:+.2f})'
                          for p in r['confidence'].values())
        tires = '+'.join(r['tires'])
        lines.append(f'| {r["seed"]} | {r["case"]} {tires if len(r["tires"]) < 4 else ""} '
                     f'| {r["drive"]} | {err} | {_md(r["speed_corr_fl"], ".2f")} | {reading} '
                     f'| {_md(r["fused_detect_s"])} | '
                     f'{_md(r["stiffness_detect_s"]) if r["case"] == "diffusion20" else ""} '
                     f'| {",".join(r["false_warning_tires"]) or "-"} | {conf} |')
    return '\n'.join(lines)


def _run_name(rec: dict[str, Any]) -> str:
    return f'{rec["seed"]} {rec["case"]} {rec["drive"]}'


def _stiffness_nominal_row(records: list[dict[str, Any]]) -> FamilyRow:
    """Per run: every tire within the bounds; the others must be unknown (NaN), not wrong."""
    within = acceptable = unknown_runs = low = 0
    worst: tuple[float, str] | None = None
    for r in records:
        known = [(w, m, s) for w, (m, s) in enumerate(zip(
            r['nominal_mean_err_kpa'], r['nominal_std_kpa'], strict=True)) if not math.isnan(m)]
        good = all(abs(m) < 10.0 and s < 5.0 for _, m, s in known)
        within += good and len(known) == 4
        acceptable += good
        unknown_runs += len(known) < 4
        low += sum(m < -10.0 for _, m, _ in known)
        for w, m, _ in known:
            if worst is None or abs(m) > worst[0]:
                worst = (abs(m), f'{_run_name(r)} {TIRE_NAMES[w]}')
    row = FamilyRow(
        'stiffness at placard',
        'stiffness observer at placard: |mean error| < 10 kPa and std < 5 kPa on every tire '
        'of a car x drive; in the others the tires out of bounds reported unknown, not low',
        within, len(records), 'runs', 0.95, None if worst is None else worst[0], 'kPa',
        '' if worst is None else f'|mean|, {worst[1]}', False,
        f'{unknown_runs} runs with a tire unknown; every tire within or unknown in '
        f'{acceptable} / {len(records)}; {low} tires read more than 10 kPa low')
    return replace(row, met=row.share_met() and acceptable == len(records))


def _diffusion_reading_row(diffusion: list[dict[str, Any]]) -> FamilyRow:
    errors = [(abs(read - truth), f'{_run_name(r)} {TIRE_NAMES[w]}')
              for r in diffusion for w, (read, truth) in enumerate(zip(
                  r['end_reading_kpa'], r['end_truth_kpa'], strict=True))
              if not math.isnan(read)]
    unknown = 4 * len(diffusion) - len(errors)
    worst = max(errors, default=None)
    row = FamilyRow(
        'stiffness reads -20 %',
        'stiffness observer reads the 20 % four-tire loss within 10 kPa (mean of the last 20 s)',
        sum(e < 10.0 for e, _ in errors), 4 * len(diffusion), 'tires', 1.0,
        None if worst is None else worst[0], 'kPa', '' if worst is None else worst[1], False,
        f'{unknown} tires unknown' if unknown else '')
    return replace(row, met=row.share_met())


def _detection_row(target: str, text: str, runs: list[dict[str, Any]], key: str,
                   limit_s: float, required_share: float) -> FamilyRow:
    """Runs whose detection time (``key``, s after the loss reached its level) is within the
    limit; the worst is the first missed run, else the slowest."""
    times = [(r[key], r) for r in runs]
    missed = [r for t, r in times if t is None]
    passed = sum(t is not None and t <= limit_s for t, _ in times)
    if missed:
        more = f' (and {len(missed) - 1} more missed)' if len(missed) > 1 else ''
        worst_value, worst_case = None, f'missed: {_run_name(missed[0])}{more}'
    elif times:
        slowest = max(times, key=lambda item: item[0])
        worst_value, worst_case = slowest[0], _run_name(slowest[1])
    else:
        worst_value, worst_case = None, ''
    row = FamilyRow(target, text, passed, len(runs), 'runs', required_share, worst_value, 's',
                    worst_case, False)
    return replace(row, met=row.share_met())


def _false_warning_row(records: list[dict[str, Any]]) -> FamilyRow:
    worst = max(records, key=lambda r: len(r['false_warning_tires']), default=None)
    count = 0 if worst is None else len(worst['false_warning_tires'])
    minutes: dict[int, float] = {}
    for r in records:
        minutes[r['seed']] = minutes.get(r['seed'], 0.0) + r.get('nominal_s', 0.0) / 60.0
    row = FamilyRow(
        'no false warning',
        'fused: no false warning (a tire warned in nominal driving, or a healthy tire warned '
        'after calibration in a fault case)',
        sum(not r['false_warning_tires'] for r in records), len(records), 'runs', 1.0,
        float(count) if count else None, 'tires',
        f'{_run_name(worst)}: {",".join(worst["false_warning_tires"])}'
        if worst is not None and count else 'none',
        False,
        f'{sum(minutes.values()):.0f} min of nominal driving, '
        f'{max(minutes.values(), default=0.0):.0f} min at most per car (docs/targets.md: '
        'zero in 30 min)')
    return replace(row, met=row.share_met())


def scoreboard_rows(records: list[dict[str, Any]]) -> list[FamilyRow]:
    """One row per target of issue 21 (the cases present in the records)."""
    by_case = {case: [r for r in records if r['case'] == case] for case in CASES}
    rows = [_stiffness_nominal_row(records)]
    if by_case['diffusion20']:
        rows.append(_diffusion_reading_row(by_case['diffusion20']))
    if by_case['puncture25']:
        rows.append(_detection_row(
            'fused: 25 % puncture', 'fused warning names a 25 % puncture within 60 s, every car',
            by_case['puncture25'], 'fused_detect_s', DETECTION_LIMIT_S['puncture25'], 1.0))
    if by_case['diffusion20']:
        rows.append(_detection_row(
            'fused: 20 % diffusion',
            'fused warning names all four tires of a 20 % diffusion within 2 min of reaching it',
            by_case['diffusion20'], 'fused_detect_s', DETECTION_LIMIT_S['diffusion20'], 1.0))
    if by_case['puncture15']:
        rows.append(_detection_row(
            'fused: 15 % on 1-2 tires',
            'fused warning names a 15 % loss on one or two tires within 60 s',
            by_case['puncture15'], 'fused_detect_s', DETECTION_LIMIT_S['puncture15'], 0.9))
    if by_case['diffusion20']:
        rows.append(_detection_row(
            'stiffness alone: 20 % diffusion',
            'the stiffness method alone warns of all four tires of the 20 % diffusion by the end '
            'of the run', by_case['diffusion20'], 'stiffness_detect_s', math.inf, 0.9))
    rows.append(_false_warning_row(records))
    return rows


def write_scoreboard(path: Path, records: list[dict[str, Any]], commit: str, date: str,
                     settings: dict[str, Any]) -> None:
    """The committed result file the main job's scoreboard shows (without the settings that
    only say where files were kept: they change no result)."""
    seeds = tuple(sorted({int(r['seed']) for r in records}))

    def kept(values: dict[str, Any]) -> dict[str, Any]:
        return {k: kept(v) if isinstance(v, dict) else v for k, v in values.items()
                if k not in ('sim_cache', 'traces')}

    results = FamilyResults('benchmarks/eval_tpms_family.py', commit, date, seeds,
                            all(s in HELD_OUT_SEEDS for s in seeds),
                            tuple(scoreboard_rows(records)), kept(settings))
    write_family_results(path, results)
    print(f'wrote {path}: {results.met_count()} of {len(results.rows)} targets met')


def load_records(paths: list[Path]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Merge result files (later ones override the same car and case); the records and a
    header: the last file's commit and date, and the settings, the files' own when they all
    ran with the same, else per file by the cases it ran (``{'nominal': {...},
    'diffusion20,puncture15': {...}}``: the 30-minute nominal drives run with other timing than
    the fault cases)."""
    merged: dict[tuple[int, str], dict[str, Any]] = {}
    header: dict[str, Any] = {}
    settings_by_cases: dict[str, dict[str, Any]] = {}
    for path in paths:
        data = json.loads(path.read_text())
        header = {k: v for k, v in data.items() if k in ('commit', 'date')}
        header.setdefault('date', time.strftime('%Y-%m-%d', time.gmtime(path.stat().st_mtime)))
        cases = ','.join(sorted({rec['case'] for rec in data['records']}))
        settings_by_cases[cases] = data.get('settings', {})
        for rec in data['records']:
            merged[(rec['seed'], rec['case'])] = rec
    distinct = {json.dumps(v, sort_keys=True) for v in settings_by_cases.values()}
    header['settings'] = (next(iter(settings_by_cases.values()), {}) if len(distinct) <= 1
                          else settings_by_cases)
    return list(merged.values()), header


def report(records: list[dict[str, Any]]) -> None:
    """Print the tables of saved runs."""
    print(markdown(records))
    print()
    for key, value in summary(records).items():
        print(f'- {key}: {value}')


def main() -> None:
    """Command line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--cars', type=int, default=len(HELD_OUT_SEEDS),
                        help='first N cars of the seed pool (held-out; tuning with --tuning)')
    parser.add_argument('--seeds', default='', help='comma-separated seeds instead')
    parser.add_argument('--tuning', action='store_true', help='use the tuning seeds')
    parser.add_argument('--cases', default=','.join(FAULT_CASES),
                        help=f'comma-separated, of {", ".join(CASES)}')
    parser.add_argument('--drives', default='', help='fixed drive kind (default: rotate)')
    parser.add_argument('--calibration-s', type=float, default=Settings.calibration_s)
    parser.add_argument('--fault-s', type=float, default=Settings.fault_s)
    parser.add_argument('--observe-s', type=float, default=Settings.observe_s)
    parser.add_argument('--diffusion-pct-per-min', type=float,
                        default=Settings.diffusion_pct_per_min)
    parser.add_argument('--no-tooth-correction', action='store_true')
    parser.add_argument('--ring-scale', type=float, default=Settings.ring_scale,
                        help="each car's encoder tooth-spacing error times this (0: perfect "
                             'rings; the drives are otherwise the same)')
    parser.add_argument('--law-given', action='store_true',
                        help="give the stiffness observer the tire's stiffness-pressure law "
                             '(tire data) instead of the default line')
    parser.add_argument('--ecu-given', action='store_true',
                        help="give the stiffness observer how the car's ABS ECU forms the speed "
                             '(timer, method, window: ECU data) instead of reading the timer '
                             'from the speeds')
    parser.add_argument('--stiffness-set', action='append', default=[], metavar='NAME=VALUE',
                        help='a stiffness observer parameter for every run (repeatable), e.g. '
                             'forgetting_factor=0.995')
    parser.add_argument('--vibration-set', action='append', default=[], metavar='NAME=VALUE',
                        help='a vibration analyzer parameter for every run (repeatable), e.g. '
                             'rel_noise_floor=0.01')
    parser.add_argument('--sim-cache', default='',
                        help='directory keeping the simulated drives for later replays')
    parser.add_argument('--traces', default='',
                        help="directory for each run's traces (the voter's inputs per tick)")
    parser.add_argument('--workers', type=int, default=1)
    parser.add_argument('--out', type=Path, default=Path('/tmp/tpms_family_eval.json'))
    parser.add_argument('--report', type=Path, nargs='+',
                        help='print Markdown tables from result files instead of running')
    parser.add_argument('--beat-table', type=Path, nargs='+', metavar='TRACES',
                        help="print the vibration method's confidence on healthy tires by the "
                             'edge beat, from --traces directories, instead of running')
    parser.add_argument('--scoreboard', type=Path, default=None,
                        help='also write the per-target result file the main job shows '
                             '(docs/results/tpms_family.json)')
    parser.add_argument('--commit', default='',
                        help="commit the runs were made on (default: the checkout's HEAD; "
                             'with --report, the one the result file saved)')
    args = parser.parse_args()
    if args.beat_table:
        beat_table(args.beat_table)
        return
    if args.report:
        saved, header = load_records(args.report)
        report(saved)
        if args.scoreboard:
            commit = args.commit or header.get('commit', '')
            if not commit:
                parser.error('the result file does not say its commit: give --commit')
            write_scoreboard(args.scoreboard, saved, commit, header['date'],
                             header.get('settings', {}))
        return
    try:
        stiffness_set = parse_assignments(args.stiffness_set, StiffnessObserverParams())
    except ConfigurationError as exc:
        parser.error(f'--stiffness-set: {exc}')
    try:
        vibration_set = parse_assignments(args.vibration_set, VibrationParams())
    except ConfigurationError as exc:
        parser.error(f'--vibration-set: {exc}')
    settings = Settings(args.calibration_s, args.fault_s, args.observe_s,
                        args.diffusion_pct_per_min, not args.no_tooth_correction,
                        args.law_given, args.sim_cache, args.traces, args.ring_scale,
                        stiffness_set, vibration_set, ecu_given=args.ecu_given)
    pool_seeds = TUNING_SEEDS if args.tuning else HELD_OUT_SEEDS
    seeds = [int(x) for x in args.seeds.split(',')] if args.seeds else \
        list(pool_seeds[:args.cars])
    cases = [c for c in args.cases.split(',') if c]
    jobs = []
    for seed in seeds:
        for case in cases:
            # by seed, so a car drives the same drive in any subset run
            drive = args.drives or DRIVE_KINDS[(seed + CASES.index(case)) % len(DRIVE_KINDS)]
            jobs.append(Job(seed, case, drive, settings))
    print(f'{len(jobs)} runs: cars {seeds}, cases {cases}; {settings}', flush=True)
    header = {'settings': settings.__dict__, 'commit': args.commit or current_commit(),
              'date': today()}
    t0 = time.perf_counter()
    records: list[dict[str, Any]] = []
    workers = max(1, min(args.workers, 2))
    with multiprocessing.get_context('fork').Pool(workers, maxtasksperchild=2) as pool:
        for rec in pool.imap_unordered(run_job, jobs):
            rec['nominal_s'] = settings.fault_s - settings.calibration_s
            records.append(rec)
            print(f'[{len(records)}/{len(jobs)} {time.perf_counter() - t0:5.0f} s] '
                  f'{rec["car"]}', flush=True)
            print_record(rec)
            args.out.write_text(json.dumps({**header, 'records': records}))
    records.sort(key=lambda r: (r['seed'], r['case']))
    print('\n=== per car and case ===')
    for rec in records:
        print_record(rec)
    result = summary(records)
    print('\n=== summary ===')
    for key, value in result.items():
        print(f'{key}: {value}')
    args.out.write_text(json.dumps({**header, 'records': records, 'summary': result},
                                   default=str))
    print(f'wrote {args.out}; {time.perf_counter() - t0:.0f} s wall')
    if args.scoreboard:
        write_scoreboard(args.scoreboard, records, header['commit'], header['date'],
                         header['settings'])


if __name__ == '__main__':
    main()
