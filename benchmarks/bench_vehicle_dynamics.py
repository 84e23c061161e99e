"""Real-time factor of the 14-DOF handling model: 60 s simulated at dt = 1 ms.

Run: PYTHONPATH=src/tpms_ros python benchmarks/bench_vehicle_dynamics.py [--repeat N]
The scenario mixes speed changes (controller), sine steering, a brake pulse and a friction
drop, so every branch of the step runs. Prints the best of N wall (and CPU) times and the factors.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from tpms_ros.simulation.vehicle_dynamics import HandlingInputs, VehicleParams, simulate_handling


def make_inputs(duration: float = 60.0, dt: float = 1e-3) -> HandlingInputs:
    """A 60 s mixed manoeuvre on the integration grid."""
    t = np.arange(0.0, duration, dt)
    n = t.size
    speed = np.interp(t, [0.0, 10.0, 20.0, 30.0, 40.0, 60.0], [20.0, 25.0, 25.0, 12.0, 20.0, 20.0])
    steer = np.radians(2.0) * np.sin(2.0 * np.pi * 0.2 * t)
    offset = np.zeros((n, 4))
    offset[(t > 45.0) & (t < 47.0)] = [-300.0, -300.0, -200.0, -200.0]
    friction = np.where(t < 50.0, 1.0, 0.5)
    radius = np.full((n, 4), 0.305)
    return HandlingInputs(t=t, steer=steer, speed_target=speed, torque_offset=offset,
                          friction_scale=friction, rolling_radius=radius)


def main() -> None:
    """Time the run and print the real-time factor."""
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument('--repeat', type=int, default=2, help='runs; the best is reported')
    args = parser.parse_args()
    params = VehicleParams()
    inputs = make_inputs()
    simulated = float(inputs.t[-1] - inputs.t[0] + inputs.dt)
    best = best_cpu = float('inf')
    for _ in range(max(args.repeat, 1)):
        start, start_cpu = time.perf_counter(), time.process_time()
        result = simulate_handling(params, inputs, 20.0)
        best = min(best, time.perf_counter() - start)
        best_cpu = min(best_cpu, time.process_time() - start_cpu)
    assert np.all(np.isfinite(result.omega))
    print(f'simulated {simulated:.1f} s at dt = {inputs.dt * 1e3:.1f} ms '
          f'({inputs.t.size} steps) in {best:.2f} s wall: '
          f'real-time factor {simulated / best:.1f}x, {best / inputs.t.size * 1e6:.1f} us/step '
          f'(CPU time {best_cpu:.2f} s: {simulated / best_cpu:.1f}x; the two differ when other '
          f'processes share the cores)')


if __name__ == '__main__':
    main()
