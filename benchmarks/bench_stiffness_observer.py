"""Offline throughput of the tire stiffness observer core (Umeno 1997).

Prints wheel-samples per second and the real-time factor for four wheels at 1 kHz, for one
chunk and for streaming chunk sizes, and the speed-up over the plainest per-sample Python
implementation of the same math (band-pass biquads, discrete observer, LS sums, RLS update).

Run: PYTHONPATH=src/tpms_ros python benchmarks/bench_stiffness_observer.py
"""

from __future__ import annotations

import time

import numpy as np
import scipy.signal as sig

from tpms_ros.core.stiffness_observer import StiffnessObserverParams, TireStiffnessObserver
from tpms_ros.core.tire_model import TorsionalTire

FS = 1000.0


def synthetic_speeds(seconds: float, seed: int = 0) -> np.ndarray:
    """(N, 4) wheel speeds from the tire model driven by seeded high-passed white torque."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    tire = TorsionalTire()
    a, b = tire.state_space()
    ad, bd, cd, dd, _ = sig.cont2discrete((a, b, np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 2))),
                                          1.0 / FS, method='zoh')
    num, den = sig.ss2tf(ad, bd, cd, dd, input=1)
    highpass = sig.butter(2, 5.0, 'highpass', fs=FS, output='sos')
    road = sig.sosfilt(highpass, rng.normal(0.0, 20.0, (n, 4)), axis=0)
    return 55.0 + sig.lfilter(num[0], den, road, axis=0) + rng.normal(0.0, 0.01, (n, 4))


def plain_python(omega: np.ndarray, observer: TireStiffnessObserver) -> np.ndarray:
    """Per-sample reference: same filters and RLS, no gating, written as a plain loop."""
    params = observer.params
    sos = sig.butter(params.band_order, params.band_hz, 'bandpass', fs=FS, output='sos')
    design = observer.observer_designs[0]
    ad, bd, cd, dd = sig.tf2ss(design.numerators, design.denominator)
    rho = params.forgetting_factor
    block = params.block_samples
    n_wheels = omega.shape[1]
    zi = [[[0.0, 0.0] for _ in range(sos.shape[0])] for _ in range(n_wheels)]
    state = [np.zeros(ad.shape[0]) for _ in range(n_wheels)]
    info = [np.zeros((2, 2)) for _ in range(n_wheels)]
    rhs = [np.zeros(2) for _ in range(n_wheels)]
    gram_b = [np.zeros((2, 2)) for _ in range(n_wheels)]
    rhs_b = [np.zeros(2) for _ in range(n_wheels)]
    coef = np.zeros((n_wheels, 2))
    offset = omega[0]
    for i in range(omega.shape[0]):
        for w in range(n_wheels):
            x = omega[i, w] - offset[w]
            for s in range(sos.shape[0]):
                b0, b1, b2, _, a1, a2 = sos[s]
                z = zi[w][s]
                y = b0 * x + z[0]
                z[0] = b1 * x - a1 * y + z[1]
                z[1] = b2 * x - a2 * y
                x = y
            out = cd @ state[w] + dd[:, 0] * x
            state[w] = ad @ state[w] + bd[:, 0] * x
            zeta = out[:2]
            gram_b[w] += np.outer(zeta, zeta)
            rhs_b[w] += zeta * out[2]
        if (i + 1) % block == 0:
            for w in range(n_wheels):
                info[w] = rho * info[w] + gram_b[w]
                rhs[w] = rho * rhs[w] + rhs_b[w]
                gram_b[w][:] = 0.0
                rhs_b[w][:] = 0.0
                coef[w] = np.linalg.solve(info[w], rhs[w])
    return coef


def throughput(omega: np.ndarray, chunk: int, params: StiffnessObserverParams) -> float:
    """Wheel-samples per second through ``update`` with the given chunk size."""
    observer = TireStiffnessObserver(params)
    start = time.perf_counter()
    for s in range(0, omega.shape[0], chunk):
        observer.update(omega[s:s + chunk])
    return omega.size / (time.perf_counter() - start)


def node_cpu_per_input_second(omega: np.ndarray, params: StiffnessObserverParams,
                              chunk: int = 250) -> float:
    """Process CPU time of ``update`` per second of four-wheel input, as the node feeds it.

    Stamps are passed as the node does; CPU (not wall) time, so other load on the machine
    does not count.
    """
    observer = TireStiffnessObserver(params)
    stamps = np.arange(omega.shape[0]) / FS
    start = time.process_time()
    for s in range(0, omega.shape[0], chunk):
        observer.update(omega[s:s + chunk], stamps=stamps[s:s + chunk])
    return (time.process_time() - start) / (omega.shape[0] / FS)


def main() -> None:
    """Print the throughput table."""
    omega = synthetic_speeds(120.0)
    realtime = 4 * FS   # wheel-samples per second of input for four wheels at 1 kHz
    start = time.perf_counter()
    TireStiffnessObserver()
    print(f'construction (observer design + consistency map): '
          f'{time.perf_counter() - start:.3f} s')
    print(f'{"configuration":<36}{"wheel-samples/s":>16}{"x real time":>13}')
    for label, chunk, params in [
        ('one chunk, non-driven', omega.shape[0], StiffnessObserverParams()),
        ('one chunk, rear compensated', omega.shape[0],
         StiffnessObserverParams(driven_axle='rear')),
        ('chunks of 1000 samples (1 s)', 1000, StiffnessObserverParams(driven_axle='rear')),
        ('chunks of 250 samples (the node)', 250, StiffnessObserverParams(driven_axle='rear')),
        ('node chunks, no tooth correction', 250,
         StiffnessObserverParams(driven_axle='rear', tooth_correction=False)),
        ('chunks of 100 samples (0.1 s)', 100, StiffnessObserverParams(driven_axle='rear')),
        ('chunks of 10 samples (10 ms)', 10, StiffnessObserverParams(driven_axle='rear')),
    ]:
        rate = throughput(omega, chunk, params)
        print(f'{label:<36}{rate:>16.3e}{rate / realtime:>13.1f}')
    node_cpu = node_cpu_per_input_second(omega, StiffnessObserverParams(driven_axle='rear'))
    print(f'node chunking (250 samples per update at 1 kHz, rear compensated): core CPU '
          f'{node_cpu * 1e3:.2f} ms per second of input ({1.0 / node_cpu:.0f}x real time)')
    short = omega[:5000]
    start = time.perf_counter()
    plain_python(short, TireStiffnessObserver())
    plain_rate = short.size / (time.perf_counter() - start)
    fast_rate = throughput(omega, omega.shape[0], StiffnessObserverParams())
    print(f'{"plain per-sample Python":<36}{plain_rate:>16.3e}{plain_rate / realtime:>13.1f}')
    print(f'speed-up of the vectorised core over plain Python: {fast_rate / plain_rate:.0f}x')


if __name__ == '__main__':
    main()
