"""Throughput of the TPMS fusion cores (vibration, wheel radius, voter) offline.

Real-time factor = simulated seconds / wall seconds for four wheels: vibration at 1 kHz
input, wheel radius at 100 Hz, and the voter's latency per evaluation. Each estimator is compared
with the plainest per-sample implementation of the same maths:

* vibration: the textbook per-sample RLS (``ar2_rls_reference``, one wheel at a time) on the
  same band-passed, decimated signal (the band-pass itself is scipy in both);
* wheel radius: filterpy ``KalmanFilter`` objects (two longitudinal, one lateral) stepped per
  sample with the same measurements.

Run: ``PYTHONPATH=src/tpms_ros python benchmarks/bench_tpms_cores.py [--seconds 60]``.
"""

from __future__ import annotations

import argparse
import time

from filterpy.kalman import KalmanFilter
import numpy as np
from scipy import signal

from tpms_ros.core.tires import TpmsIndication
from tpms_ros.core.tpms_voting import TpmsVoter, VoterParams
from tpms_ros.core.vibration_analysis import VibrationAnalyzer, VibrationParams, ar2_rls_reference
from tpms_ros.core.wheel_radius_analysis import WheelRadiusAnalyzer, WheelRadiusParams


def best_of(fn: object, repeats: int = 3) -> float:
    """Smallest wall time of ``repeats`` calls, s (the machine is shared)."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()  # type: ignore[operator]
        times.append(time.perf_counter() - t0)
    return min(times)


def bench_vibration(seconds: float, chunk_s: float) -> dict[str, float]:
    """Vibration analysis on a synthetic 40-46 Hz resonance, 4 wheels at 1 kHz."""
    fs = 1000.0
    rng = np.random.default_rng(0)
    n = int(seconds * fs)
    omega = np.empty((n, 4))
    for wheel, f in enumerate((40.0, 42.0, 44.0, 46.0)):
        w = 2 * np.pi * f / fs
        rho = np.exp(-0.05 * w)
        omega[:, wheel] = 70.0 + signal.lfilter(
            [0.01], [1, -2 * rho * np.cos(w), rho * rho], rng.standard_normal(n))
    step = int(chunk_s * fs)

    def run() -> None:
        analyzer = VibrationAnalyzer(VibrationParams(sample_rate_hz=fs))
        for start in range(0, n, step):
            analyzer.process(omega[start:start + step])

    fast = best_of(run)
    p = VibrationParams(sample_rate_hz=fs)
    sos = signal.butter(p.filter_order, p.passband_hz, btype='bandpass', fs=fs, output='sos')

    def run_plain() -> None:
        zi = signal.sosfilt_zi(sos)[:, :, None] * omega[0][None, None, :]
        y, _ = signal.sosfilt(sos, omega, axis=0, zi=zi)
        for wheel in range(4):
            ar2_rls_reference(y[::p.decimation, wheel], p.forgetting, p.rls_regularization)

    plain = best_of(run_plain, 1)
    return {'rt_factor': seconds / fast, 'plain_rt_factor': seconds / plain,
            'speedup': plain / fast}


def bench_radius(seconds: float) -> dict[str, float]:
    """Wheel radius analysis, 4 wheels + gyro + torques at 100 Hz."""
    fs = 100.0
    rng = np.random.default_rng(1)
    n = int(seconds * fs)
    t = np.arange(n) / fs
    v = 22.0 + 6.0 * np.sin(2 * np.pi * t / 47.0)
    yaw = 0.05 * np.sin(2 * np.pi * t / 23.0)
    p = WheelRadiusParams()
    half = p.track_rear_m / 2
    v_w = np.stack([v - yaw * half, v + yaw * half, v - yaw * half, v + yaw * half], axis=1)
    omega = v_w / p.nominal_radius_m + 0.02 * rng.standard_normal((n, 4))
    torque = np.zeros((n, 4))
    torque[:, :2] = 150.0 + 50.0 * np.sin(2 * np.pi * t / 11.0)[:, None]
    gyro = yaw + 0.01 + 0.005 * rng.standard_normal(n)

    def run() -> None:
        analyzer = WheelRadiusAnalyzer(p)
        for start in range(0, n, 100):                     # 1 s chunks
            analyzer.process(t[start:start + 100], omega[start:start + 100],
                             gyro[start:start + 100], torque[start:start + 100])

    fast = best_of(run)

    def run_plain() -> None:
        r_n = p.nominal_radius_m
        lat = KalmanFilter(dim_x=5, dim_z=3)
        lat.F[0, 1] = 1 / fs
        lat.R = np.diag([p.gyro_noise_std_rad_s, p.wheel_yaw_noise_std_rad_s,
                         p.wheel_yaw_noise_std_rad_s]) ** 2
        sides = []
        for _ in range(2):
            kf = KalmanFilter(dim_x=2, dim_z=1)
            kf.Q = np.diag([p.inv_stiffness_rw, p.delta_rw]) ** 2 / fs
            sides.append(kf)
        mu = torque[:, :2] / (r_n * np.array(p.static_load_n[:2]))
        for i in range(n):
            for side in (0, 1):
                kf = sides[side]
                kf.predict()
                kf.H = np.array([[mu[i, side], 1.0]])
                kf.R[0, 0] = 2.0 * (p.wheel_speed_noise_mps / (r_n * omega[i, side + 2])) ** 2
                kf.update(omega[i, side] / omega[i, side + 2] - 1.0)
            lat.predict()
            lat.H = np.array([[1, 0, 1, 0, 0],
                              [1, 0, 0, -r_n * omega[i, 2] / p.track_rear_m, 0],
                              [1, 0, 0, 0, -r_n * omega[i, 0] / p.track_front_m]])
            lat.update(np.array([-gyro[i], r_n * (omega[i, 2] - omega[i, 3]) / p.track_rear_m,
                                 r_n * (omega[i, 0] - omega[i, 1]) / p.track_front_m]))

    plain = best_of(run_plain, 1)
    return {'rt_factor': seconds / fast, 'plain_rt_factor': seconds / plain,
            'speedup': plain / fast}


def bench_voter(n_eval: int) -> dict[str, float]:
    """Latency of one submit-and-evaluate of three methods' indications."""
    voter = TpmsVoter(VoterParams(set_on_s=1.0, set_off_s=5.0))
    rng = np.random.default_rng(2)
    lat = np.empty(n_eval)
    for k in range(n_eval):
        now = 0.1 * k
        conf = rng.uniform(0, 1, (3, 4))
        inds = [TpmsIndication(m, now, conf[i] > 0.5, conf[i])
                for i, m in enumerate(('vibration', 'wheel_radius', 'stiffness'))]
        t0 = time.perf_counter()
        voter.evaluate(now, inds)
        lat[k] = time.perf_counter() - t0
    return {'p50_ms': 1e3 * float(np.percentile(lat, 50)),
            'p99_ms': 1e3 * float(np.percentile(lat, 99))}


def main() -> None:
    """Run all three benchmarks and print a table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=60.0, help='simulated seconds')
    args = parser.parse_args()
    for chunk_s in (1.0, 0.1, 0.01):
        r = bench_vibration(args.seconds, chunk_s)
        print(f'vibration 4x1 kHz, {chunk_s:g} s chunks: {r["rt_factor"]:.0f}x real time; '
              f'per-sample RLS {r["plain_rt_factor"]:.0f}x; speed-up {r["speedup"]:.1f}x')
    r = bench_radius(args.seconds)
    print(f'wheel radius 100 Hz: {r["rt_factor"]:.0f}x real time; filterpy per sample '
          f'{r["plain_rt_factor"]:.0f}x; speed-up {r["speedup"]:.1f}x')
    r = bench_voter(5000)
    print(f'voter 3 methods: evaluate p50 {r["p50_ms"]:.3f} ms, p99 {r["p99_ms"]:.3f} ms')


if __name__ == '__main__':
    main()
