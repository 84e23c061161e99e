"""The compiled ``sosfilt`` and ``lfilter`` held to scipy's, state carried over chunks.

The kernels do scipy's operations in scipy's order, so they agree to rounding: to the bit on
this project's machines, held here to 1e-12 (a compiler that fuses multiply-adds in one of them,
as on a CPU with them in its base set, may differ in the last bit).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from tpms_ros.core.filter_kernels import lfilter_columns, normalised, sosfilt_columns

CHUNKS = (1, 7, 250, 3, 1000)


def _signal(rng: np.random.Generator, columns: int) -> np.ndarray:
    return 80.0 + np.cumsum(rng.normal(0.0, 0.3, (sum(CHUNKS), columns)), axis=0)


def test_sosfilt_columns_is_scipys_over_any_chunking() -> None:
    rng = np.random.default_rng(20261204)
    sos = signal.butter(4, [40.0, 60.0], btype='bandpass', fs=1000.0, output='sos')
    x = _signal(rng, 4)
    zi_scipy = signal.sosfilt_zi(sos)[:, :, None] * x[0][None, None, :]
    zi_kernel = zi_scipy.copy()
    start = 0
    for size in CHUNKS:
        chunk = x[start:start + size]
        expected, zi_scipy = signal.sosfilt(sos, chunk, axis=0, zi=zi_scipy)
        actual = np.empty_like(chunk)
        sosfilt_columns(sos, chunk, zi_kernel, actual)
        np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(zi_kernel, zi_scipy, rtol=1e-12, atol=1e-12)
        start += size


@pytest.mark.parametrize('order_b, order_a', [(3, 3), (1, 3), (3, 1), (0, 0)])
def test_lfilter_columns_is_scipys_over_any_chunking(order_b: int, order_a: int) -> None:
    rng = np.random.default_rng(order_b * 10 + order_a)
    b = rng.normal(0.0, 1.0, order_b + 1)
    a = np.concatenate(([1.7], 0.2 * rng.normal(0.0, 1.0, order_a)))  # stable, a[0] != 1
    x = _signal(rng, 3)
    size = max(b.size, a.size)
    zi_scipy = rng.normal(0.0, 1.0, (size - 1, 3))
    zi_kernel = zi_scipy.copy()
    b_n, a_n = normalised(b, a)
    start = 0
    for chunk_size in CHUNKS:
        chunk = x[start:start + chunk_size]
        actual = np.empty_like(chunk)
        lfilter_columns(b_n, a_n, chunk, zi_kernel, actual)
        if size == 1:
            expected = signal.lfilter(b, a, chunk, axis=0)
        else:
            expected, zi_scipy = signal.lfilter(b, a, chunk, axis=0, zi=zi_scipy)
            np.testing.assert_allclose(zi_kernel, zi_scipy, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(actual, expected, rtol=1e-12, atol=1e-12)
        start += chunk_size
