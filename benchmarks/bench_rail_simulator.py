"""Real-time factor of the rail simulator: 60 s of the healthy scenario at 200 Hz output.

Run: ``PYTHONPATH=src/vehicle_monitor_common:src/rail_monitor_ros python
benchmarks/bench_rail_simulator.py [--repeat N] [--scenario NAME]``. Prints the best of N runs
for the simulation and for the conversion to topic series.
"""

from __future__ import annotations

import os

# Small matrices: OpenBLAS threads only contend on a busy 2-core machine (the matrix
# exponentials get 100x slower), so run single-threaded unless told otherwise. Must be set
# before numpy loads.
os.environ.setdefault('OPENBLAS_NUM_THREADS', '1')

import argparse  # noqa: E402
import time  # noqa: E402

from rail_monitor_ros.simulation.rail_scenario import shipped_scenario  # noqa: E402
from rail_monitor_ros.simulation.rail_simulator import simulate, to_topic_series  # noqa: E402


def main() -> None:
    """Time the simulator and print the real-time factors."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeat', type=int, default=3, help='runs; the best is reported')
    parser.add_argument('--scenario', default='rail_healthy', help='shipped scenario name')
    args = parser.parse_args()
    scenario = shipped_scenario(args.scenario)
    sim_times, series_times = [], []
    for _ in range(max(1, args.repeat)):
        start = time.perf_counter()
        result = simulate(scenario)
        sim_times.append(time.perf_counter() - start)
        start = time.perf_counter()
        to_topic_series(result)
        series_times.append(time.perf_counter() - start)
    sim, series = min(sim_times), min(series_times)
    print(f'scenario {scenario.name}: {scenario.duration:.0f} s simulated, '
          f'{result.time.size} samples at {scenario.output_rate:.0f} Hz '
          f'(internal {scenario.internal_rate:.0f} Hz, warm-up {scenario.warm_up:.0f} s)')
    print(f'simulate:        {sim * 1e3:8.1f} ms  real-time factor '
          f'{scenario.duration / sim:8.0f}x')
    print(f'to_topic_series: {series * 1e3:8.1f} ms')
    print(f'total:           {(sim + series) * 1e3:8.1f} ms  real-time factor '
          f'{scenario.duration / (sim + series):8.0f}x')


if __name__ == '__main__':
    main()
