"""The wheel radius analysis's compiled wheel-acceleration low-pass held to numpy and scipy.

``_wheel_acceleration_filter`` replaced a numpy forward fill, ``scipy.signal.sosfilt`` and a
difference; the reference below is that implementation. The kernel does the same operations in
the same order, so the two agree to rounding (here to the bit; a compiler that fuses
multiply-adds in one of them may differ in the last bit), over any chunking and across
restarts.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from tpms_ros.core.tires import N_TIRES
from tpms_ros.core.wheel_radius_analysis import WheelRadiusAnalyzer, WheelRadiusParams


class NumpyWheelAcceleration:
    """The numpy form of ``WheelRadiusAnalyzer._wheel_acceleration`` (state carried)."""

    def __init__(self, params: WheelRadiusParams) -> None:
        self.sos = signal.butter(2, params.accel_filter_hz, fs=params.sample_rate_hz,
                                 output='sos')
        self.zi_unit = signal.sosfilt_zi(self.sos)
        self.restart()

    def restart(self) -> None:
        self.state: np.ndarray | None = None
        self.last_smooth = np.zeros(N_TIRES)
        self.last_good = np.full(N_TIRES, np.nan)

    def __call__(self, omega: np.ndarray, wheel_ok: np.ndarray, dt: np.ndarray) -> np.ndarray:
        x = np.vstack([self.last_good[None, :], np.where(wheel_ok, omega, np.nan)])
        idx = np.where(np.isnan(x), 0, np.arange(x.shape[0])[:, None])
        np.maximum.accumulate(idx, axis=0, out=idx)
        x = np.take_along_axis(x, idx, axis=0)
        self.last_good = x[-1].copy()
        x = np.nan_to_num(x[1:], nan=0.0)
        if self.state is None:
            self.state = self.zi_unit[:, :, None] * x[0]
            self.last_smooth = x[0].copy()
        smooth, self.state = signal.sosfilt(self.sos, x, axis=0, zi=self.state)
        previous = np.vstack([self.last_smooth[None, :], smooth[:-1]])
        self.last_smooth = smooth[-1].copy()
        return (smooth - previous) / dt[:, None]


def test_wheel_acceleration_kernel_equals_numpy() -> None:
    """Noisy wheel speeds with bad samples (a wheel bad from the start, dropouts, a wheel that
    stays bad over a chunk end), irregular steps, chunks of 1 to 40 samples, two restarts."""
    rng = np.random.default_rng(7)
    params = WheelRadiusParams()
    n = 3000
    dt = 0.01 + rng.uniform(-2e-3, 2e-3, n)
    omega = 60.0 + np.cumsum(rng.normal(0.0, 0.05, (n, N_TIRES)), axis=0)
    wheel_ok = rng.random((n, N_TIRES)) > 0.05
    wheel_ok[:25, 1] = False                    # no good sample yet: reads 0
    wheel_ok[1000:1300, 3] = False              # a long dropout over several chunks
    omega[~wheel_ok] = np.where(rng.random(int((~wheel_ok).sum())) > 0.5, np.nan, -1.0)
    core = WheelRadiusAnalyzer(params)
    reference = NumpyWheelAcceleration(params)
    restarts = [1000, 2000]                     # a time jump: the filter starts again
    start = 0
    while start < n:
        stop = min(n, start + int(rng.integers(1, 41)))
        if restarts and start >= restarts[0]:
            restarts.pop(0)
            core.restart_time()
            reference.restart()
        chunk = slice(start, stop)
        expected = reference(omega[chunk], wheel_ok[chunk], dt[chunk])
        got = core._wheel_acceleration(omega[chunk].copy(), wheel_ok[chunk].copy(),
                                       dt[chunk].copy())
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9,
                                   err_msg=f'chunk {start}:{stop}')
        start = stop
    assert np.array_equal(core._last_good_w, reference.last_good, equal_nan=True)
    np.testing.assert_allclose(core._last_smooth, reference.last_smooth, rtol=1e-12)
