"""Real-time factor of the creep-factor EKF at 200 Hz, per observation pattern.

Run: ``PYTHONPATH=src/vehicle_monitor_common:src/rail_monitor_ros python
benchmarks/bench_creep_ekf.py [--repeat N] [--scenario NAME]``. Prints, per pattern, the best of
N runs of :class:`CreepEkf` over the scenario (known track input; wall-clock and, as the
shared machine's load varies, CPU-time real-time factors) and the ratio to the plainest
per-sample implementation: an exact re-discretisation (matrix exponential and its Frechet
derivative) at every sample and a textbook update with an explicit inverse of S. The plain
filter runs on the first ``--plain-seconds`` only (it is slow); both estimates are compared
there. ``--per-sample`` times each call of :meth:`CreepEkf.step` instead and prints the
callbacks a node would see: the median and 99th percentile without an alarm, and each
change alarm's (the onset search filters samples again there).
"""

from __future__ import annotations

import os

# Small matrices: OpenBLAS threads only contend on a busy 2-core machine. Must be set before
# numpy loads.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
import math  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams  # noqa: E402
from rail_monitor_ros.offline.creep_runs import simulation_inputs  # noqa: E402
from rail_monitor_ros.simulation.rail_scenario import shipped_scenario  # noqa: E402
from rail_monitor_ros.simulation.rail_simulator import simulate  # noqa: E402


def plain_run(params: CreepEkfParams, z: np.ndarray, track: np.ndarray) -> np.ndarray:
    """The plainest per-sample EKF on the same model: exact discretisation every sample,
    S inverted explicitly, P = (I - K H) P. Returns the c estimate per sample."""
    ekf = CreepEkf(params)              # for the model matrices, Q and R only
    q = ekf._q_x                        # noqa: SLF001
    x, p = ekf.x.copy(), ekf.P.copy()
    out = np.empty(z.shape[0])
    for k in range(z.shape[0]):
        # The track rows the filter observes (the full model adds the rear pair's from the
        # front track it keeps), assembled as the filter does.
        rows, values = ekf._track_sample(track[k])                    # noqa: SLF001
        observation = ekf._observation(rows)                          # noqa: SLF001
        h, r = observation.h, np.diag(observation.r)
        z_k = np.concatenate([z[k], values])
        s = h @ p @ h.T + r
        gain = p @ h.T @ np.linalg.inv(s)
        x = x + gain @ (z_k - h @ x)
        p = (np.eye(x.size) - gain @ h) @ p
        out[k] = math.exp(x[ekf.i_theta])
        x, jac = ekf.transition(x, exact=True)
        p = jac @ p @ jac.T + q
    return out


def per_sample(params: CreepEkfParams, y: np.ndarray, track: np.ndarray,
               speed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(seconds per step call, whether the call handled a change alarm) over a run."""
    ekf = CreepEkf(params)
    seconds = np.empty(y.shape[0])
    alarm = np.zeros(y.shape[0], dtype=bool)
    for k in range(y.shape[0]):
        alarms = ekf.changes_detected
        start = time.perf_counter()
        ekf.step(y[k], track[k], float(speed[k]))
        seconds[k] = time.perf_counter() - start
        alarm[k] = ekf.changes_detected != alarms
    return seconds, alarm


def main() -> None:
    """Time the filter per pattern and print real-time factors and the speed-up."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=3, help='runs; the best is reported')
    parser.add_argument('--scenario', default='rail_creep_steps', help='shipped scenario name')
    parser.add_argument('--plain-seconds', type=float, default=3.0,
                        help='seconds of data for the plain reference filter')
    parser.add_argument('--per-sample', action='store_true',
                        help="time each step call: a node's callbacks, alarms apart")
    args = parser.parse_args()
    result = simulate(shipped_scenario(args.scenario))
    duration = float(result.time[-1] - result.time[0])
    rate = result.scenario.output_rate
    print(f'scenario {result.scenario.name}: {duration:.0f} s at {rate:.0f} Hz, known input')
    if args.per_sample:
        print('pattern  run  p50 us  p99 us  (no alarm)  alarm callbacks, ms')
        for pattern in 'ABCD':
            params = CreepEkfParams(pattern=pattern, sample_rate_hz=rate)
            inputs = simulation_inputs(result, pattern)
            for run_index in range(max(1, args.repeat)):
                seconds, alarm = per_sample(params, *inputs)
                quiet = seconds[~alarm] * 1e6
                print(f'{pattern:>7}  {run_index:3d}  {np.median(quiet):6.0f}  '
                      f'{np.percentile(quiet, 99):6.0f}  '
                      + ', '.join(f'{t * 1e3:.1f}' for t in seconds[alarm]))
        return
    print('pattern  us/sample  real-time factor (CPU time)  plain us/sample  speed-up  '
          'max |dc| vs plain')
    for pattern in 'ABCD':
        params = CreepEkfParams(pattern=pattern, sample_rate_hz=rate)
        y, track, speed = simulation_inputs(result, pattern)
        times, cpu_times = [], []
        for _ in range(max(1, args.repeat)):
            start, cpu_start = time.perf_counter(), time.process_time()
            run = CreepEkf(params).run(y, track, speed)
            times.append(time.perf_counter() - start)
            cpu_times.append(time.process_time() - cpu_start)
        best, best_cpu = min(times), min(cpu_times)
        n_plain = min(y.shape[0], int(args.plain_seconds * rate))
        start = time.perf_counter()
        plain = plain_run(params, y[:n_plain], track[:n_plain])
        plain_time = time.perf_counter() - start
        fast_us = best / y.shape[0] * 1e6
        plain_us = plain_time / n_plain * 1e6
        difference = float(np.max(np.abs(run.creep_factor[:n_plain] - plain)))
        print(f'{pattern:>7}  {fast_us:9.1f}  {duration / best:15.0f}x '
              f'({duration / best_cpu:5.0f}x)  {plain_us:15.1f}  {plain_us / fast_us:7.1f}x  '
              f'{difference:.2e}')


if __name__ == '__main__':
    main()
