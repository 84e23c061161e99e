"""Lateral force observer (SKFMEC): scenarios on the 14-DOF truth, tuning, figures, speed.

Usage (from the repository root, with the venv and PYTHONPATH=src/tpms_ros)::

    python benchmarks/bench_lateral_force_observer.py bench          # real-time factor
    python benchmarks/bench_lateral_force_observer.py tune           # worst-case gain search
    python benchmarks/bench_lateral_force_observer.py report --out /tmp/lfo   # table + PNGs

The scenario builders here are the single source of the paper's scenarios for the tests too.
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np

from tpms_ros.lateral_force_observer import (
    LateralForceObserver,
    ObserverTuning,
    ObserverVehicleParams,
    TuningCase,
    fy_error_percent,
    plot_lateral_forces,
    tune_gains,
)
from tpms_ros.vehicle_dynamics import (
    HandlingInputs,
    HandlingResult,
    VehicleParams,
    simulate_handling,
)

DEG = math.pi / 180.0
SIM_DT = 1e-3        # truth integration step, s
OBS_DECIMATION = 10  # observer at 100 Hz
# Sensor noise (1 sigma): stability-control IMU and ABS wheel speeds.
ACCEL_NOISE = 0.05   # m/s^2
RATE_NOISE = 0.002   # rad/s
WHEEL_NOISE = 0.02   # rad/s


def _ramp(t: np.ndarray, t0: float, t1: float, a: float, b: float) -> np.ndarray:
    return a + (b - a) * np.clip((t - t0) / (t1 - t0), 0.0, 1.0)


def paper_truth(added_mass: float = 200.0, friction_factor: float = 1.0,
                duration: float = 10.0) -> HandlingResult:
    """Paper's worst case on the 14-DOF truth: 70 km/h, steer 1 -> 2 deg, brake 60/40 N m per
    wheel front/rear, friction 1.1 -> 0.2 (times ``friction_factor``), truth mass + added_mass.
    Timeline (not given in the paper): steer 1 deg from 0.5 s, 2 deg from 3 s, brakes from 1 s,
    friction ramps down over 6.0-6.5 s. Speed controller off (the brakes slow the car)."""
    t = np.arange(0.0, duration, SIM_DT)
    steer = _ramp(t, 0.5, 0.8, 0.0, DEG) + _ramp(t, 3.0, 3.3, 0.0, DEG)
    torque = np.where((t >= 1.0)[:, None], np.array([-60.0, -60.0, -40.0, -40.0]), 0.0)
    friction = friction_factor * _ramp(t, 6.0, 6.5, 1.1, 0.2)
    params = VehicleParams()
    inputs = HandlingInputs(t=t, steer=steer, speed_target=np.full(t.size, np.nan),
                            torque_offset=torque, friction_scale=friction,
                            rolling_radius=np.full((t.size, 4), params.rw),
                            added_mass=added_mass)
    return simulate_handling(params, inputs, initial_speed=70.0 / 3.6)


def relation_truth(duration: float = 10.0) -> HandlingResult:
    """Relation check (paper Figs. 3-4): 70 km/h held, steer ramped 0 -> 4 deg over 10 s."""
    t = np.arange(0.0, duration, SIM_DT)
    params = VehicleParams()
    inputs = HandlingInputs(t=t, steer=4.0 * DEG * t / duration,
                            speed_target=np.full(t.size, 70.0 / 3.6),
                            torque_offset=np.zeros((t.size, 4)),
                            friction_scale=np.full(t.size, 1.1),
                            rolling_radius=np.full((t.size, 4), params.rw))
    return simulate_handling(params, inputs, initial_speed=70.0 / 3.6)


def to_case(truth: HandlingResult, name: str, seed: int = 0) -> TuningCase:
    """Decimate the truth to the observer rate and add seeded sensor noise."""
    rng = np.random.default_rng(seed)
    k = slice(None, None, OBS_DECIMATION)
    n = truth.t[k].size
    return TuningCase(
        name=name, dt=SIM_DT * OBS_DECIMATION,
        ax=truth.ax[k] + rng.normal(0.0, ACCEL_NOISE, n),
        ay=truth.ay[k] + rng.normal(0.0, ACCEL_NOISE, n),
        r=truth.yaw_rate[k] + rng.normal(0.0, RATE_NOISE, n),
        p=truth.roll_rate[k] + rng.normal(0.0, RATE_NOISE, n),
        omega=truth.omega[k] + rng.normal(0.0, WHEEL_NOISE, (n, 4)),
        wheel_torque=truth.wheel_torque[k], steer=truth.steer[k], fy_true=truth.fy[k])


def bench(repeats: int = 3) -> dict[str, float]:
    """Real-time factors at 100 Hz of the batch path and of step() per sample, best of repeats."""
    case = to_case(paper_truth(), 'paper')
    span = case.ax.size * case.dt
    best_run, best_step = math.inf, math.inf
    for _ in range(repeats):
        observer = LateralForceObserver()
        start = time.perf_counter()
        observer.run(case.dt, case.ax, case.ay, case.r, case.p, case.omega,
                     case.wheel_torque, case.steer)
        best_run = min(best_run, time.perf_counter() - start)
        observer = LateralForceObserver()
        start = time.perf_counter()
        for i in range(case.ax.size):
            observer.step(case.ax[i], case.ay[i], case.r[i], case.p[i], case.omega[i],
                          case.wheel_torque[i], case.steer[i], case.dt)
        best_step = min(best_step, time.perf_counter() - start)
    return {'rtf_run': span / best_run, 'rtf_step': span / best_step,
            'run_over_step': best_step / best_run}


def tune(base: ObserverTuning | None = None) -> None:
    """The reproducible gain search on the paper's worst case (mass + 200 kg, friction drop)."""
    case = to_case(paper_truth(), 'paper')
    for label, start in (('SKFMEC', base or ObserverTuning()),
                         ('plain EKF', ObserverTuning.plain())):
        result = tune_gains([case], base=start)
        tn = result.tuning
        print(f'{label}: worst-wheel error {result.score:.2f} % q_diag={tn.q_diag} '
              f'r_std={tn.r_std} gp={tn.gp} gy={tn.gy} ({len(result.trials)} trials)')


def report(out: str | None) -> None:
    """Error table for the paper case, the robustness cases and the variants; PNGs to out."""
    variants = {'SKFMEC': ObserverTuning(), 'scaled EKF, no MEC': ObserverTuning(mec=False),
                'plain EKF': ObserverTuning.plain()}
    cases = [('paper (+200 kg)', paper_truth(), ObserverVehicleParams())]
    for factor in (0.7, 1.3):
        cases.append((f'friction x{factor}', paper_truth(friction_factor=factor),
                      ObserverVehicleParams()))
    nominal = paper_truth(added_mass=0.0)
    for factor in (0.8, 1.2):
        cases.append((f'model mass x{factor}', nominal,
                      ObserverVehicleParams(m=1814.0 * factor, ms=1661.0 * factor)))
    for title, truth, params in cases:
        case = to_case(truth, title)
        tracks = {}
        for name, tn in variants.items():
            tracks[name] = case.run(params, tn)
            err = fy_error_percent(tracks[name], case.fy_true)
            print(f'{title:22s} {name:20s} FL {err[0]:5.1f}  FR {err[1]:5.1f}  '
                  f'RL {err[2]:5.1f}  RR {err[3]:5.1f} %')
        if out is not None:
            slug = ''.join(ch if ch.isalnum() else '_' for ch in title).strip('_')
            path = f'{out}_{slug}.png'
            plot_lateral_forces(path, np.arange(case.ax.size) * case.dt, case.fy_true, tracks,
                                title=f'Tire lateral forces: {title}')
            print('wrote', path)


def main() -> None:
    """Command line entry point."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('what', choices=('bench', 'tune', 'report'))
    parser.add_argument('--out', default=None, help='PNG path prefix for report')
    args = parser.parse_args()
    if args.what == 'bench':
        for key, value in bench().items():
            print(f'{key}: {value:.1f}')
    elif args.what == 'tune':
        tune()
    else:
        report(args.out)


if __name__ == '__main__':
    main()
