"""Benchmark of the road simulator: real-time factor of a 60 s scenario with 1 kHz wheel speeds.

Runs the full pipeline (14-DOF handling at the scenario's handling rate, torsional vibration of
four tires with driveline resonances, 48-tooth encoders, IMU, topic series) and prints the
real-time factor (simulated seconds per wall-clock second) overall and per stage.

    PYTHONPATH=src/vehicle_monitor_common:src/tpms_ros python benchmarks/bench_road_simulator.py
"""

from __future__ import annotations

import argparse
from pathlib import Path
import time

from tpms_ros.simulation import road_simulator
from tpms_ros.simulation.road_scenario import load_scenario, parse_scenario
from tpms_ros.simulation.vehicle_dynamics import (
    HandlingInputs,
    HandlingResult,
    VehicleParams,
    simulate_handling,
)

DEFAULT_SCENARIO = """
name: bench_60s
seed: 1
duration_s: 60
rates: {wheel_speed_hz: 1000}
speed:
  initial_kmh: 60
  segments:
    - {type: hold, duration_s: 15}
    - {type: ramp, to_kmh: 90, duration_s: 15}
    - {type: hold, duration_s: 30}
steering:
  segments:
    - {type: hold, duration_s: 10}
    - {type: sine, amplitude_deg: 1.5, frequency_hz: 0.2, duration_s: 20}
    - {type: lane_change, amplitude_deg: 1.0, period_s: 4, duration_s: 10}
road:
  segments:
    - {at_s: 0, surface: smooth_asphalt}
    - {at_s: 30, surface: rough_concrete}
events:
  - {type: pressure_step, at_s: 20, tires: [FR, RL], to_kpa: 140, duration_s: 5}
"""


def main() -> None:
    """Run the benchmark and print the real-time factors."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('scenario', nargs='?', type=Path,
                        help='scenario YAML (default: a built-in 60 s mixed drive)')
    parser.add_argument('--repeat', type=int, default=1, help='runs to time (best is kept)')
    args = parser.parse_args()
    scenario = load_scenario(args.scenario) if args.scenario \
        else parse_scenario(DEFAULT_SCENARIO, source='<bench>')

    handling_time: list[float] = []

    def timed_handling(params: VehicleParams, inputs: HandlingInputs,
                       initial_speed: float) -> HandlingResult:
        start = time.perf_counter()
        result = simulate_handling(params, inputs, initial_speed)
        handling_time.append(time.perf_counter() - start)
        return result

    best_total = best_handling = best_topics = float('inf')
    for _ in range(max(1, args.repeat)):
        start = time.perf_counter()
        result = road_simulator.simulate_scenario(scenario, timed_handling)
        simulated = time.perf_counter()
        road_simulator.to_topic_series(result)
        done = time.perf_counter()
        if done - start < best_total:
            best_total = done - start
            best_handling = handling_time[-1]
            best_topics = done - simulated
    duration = scenario.duration_s
    rest = best_total - best_handling - best_topics
    print(f'scenario {scenario.name}: {duration:g} s simulated, wheel speeds at '
          f'{scenario.rates.wheel_speed_hz:g} Hz, handling at {scenario.rates.handling_hz:g} Hz, '
          f'torsion at {scenario.rates.torsion_hz:g} Hz')
    for label, seconds in (('handling model', best_handling), ('vibration + sensors', rest),
                           ('topic series', best_topics), ('total', best_total)):
        print(f'  {label:20s} {seconds:7.2f} s  ({duration / seconds:7.1f}x real time)')
    print(f'real-time factor: {duration / best_total:.1f}')


if __name__ == '__main__':
    main()
