"""The compiled creep EKF update and prediction against their numpy formulas."""

from __future__ import annotations

import numpy as np
import pytest

from rail_monitor_ros.core.creep_kernel import (
    OUTLIER,
    SINGULAR,
    UPDATED,
    ekf_predict,
    ekf_update,
)

N, M = 9, 4          # states (ln c last), measurements


def _spd(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.standard_normal((n, n))
    return a @ a.T + 0.1 * np.eye(n)


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_update_is_the_joseph_form_update(seed: int) -> None:
    """x + K y and P - KHP - (KHP)^T + K S K^T, the NIS, the ln c correction and spread, and
    ln det S."""
    rng = np.random.default_rng(seed)
    x, p = rng.standard_normal(N), _spd(rng, N)
    h, r, z = rng.standard_normal((M, N)), rng.uniform(0.5, 1.0, M), rng.standard_normal(M)
    s = h @ p @ h.T + np.diag(r)
    y = z - h @ x
    gain = p @ h.T @ np.linalg.inv(s)
    x_kernel, p_kernel, out = x.copy(), p.copy(), np.empty(4)
    assert ekf_update(x_kernel, p_kernel, h, r, z, M, 1e12, N - 1, out) == UPDATED
    np.testing.assert_allclose(x_kernel, x + gain @ y, rtol=1e-10, atol=1e-12)
    a = gain @ h @ p
    np.testing.assert_allclose(p_kernel, p - a - a.T + gain @ s @ gain.T, rtol=1e-10,
                               atol=1e-12)
    ksk = gain @ s @ gain.T
    np.testing.assert_allclose(out, [y @ np.linalg.solve(s, y), (gain @ y)[-1], ksk[-1, -1],
                                     np.linalg.slogdet(s)[1]], rtol=1e-10)


def test_update_gates_outliers_and_refuses_a_singular_innovation() -> None:
    """A residual beyond the gate in a gated channel, or S not positive definite: x, P kept."""
    rng = np.random.default_rng(3)
    x, p = rng.standard_normal(N), _spd(rng, N)
    h, r = rng.standard_normal((M, N)), np.ones(M)
    z = h @ x
    z[0] += 1e3
    x_kernel, p_kernel, out = x.copy(), p.copy(), np.empty(4)
    assert ekf_update(x_kernel, p_kernel, h, r, z, 1, 9.0, N - 1, out) == OUTLIER
    # The same residual in a channel that is not gated is used.
    assert ekf_update(x_kernel, p_kernel, np.roll(h, -1, axis=0), np.roll(r, -1),
                      np.roll(z, -1), 1, 9.0, N - 1, out) == UPDATED
    x_kernel, p_kernel = x.copy(), np.zeros((N, N))
    assert ekf_update(x_kernel, p_kernel, h, -np.ones(M), h @ x, 0, 9.0, N - 1,
                      out) == SINGULAR
    np.testing.assert_array_equal(x_kernel, x)


@pytest.mark.parametrize('i_sens', [(), (2, 5)])
def test_predict_is_the_taylor_stepped_transition(i_sens: tuple[int, ...]) -> None:
    """x <- [F(c, delta) x_q, ln c] with F(c, delta) = F + (c - c_k) dF + sum_j delta_j S_j
    (delta_j = x[i_sens[j]]), P <- sym(J P J^T + Q)."""
    rng = np.random.default_rng(4)
    x, p, q = rng.standard_normal(N), _spd(rng, N), _spd(rng, N)
    fg, dfg = rng.standard_normal((N - 1, N - 1)), rng.standard_normal((N - 1, N - 1))
    sens = rng.standard_normal((len(i_sens), N - 1, N - 1))
    c, c_grid = 0.71, 0.7
    f = fg + (c - c_grid) * dfg + sum((x[i] * s for i, s in zip(i_sens, sens, strict=True)),
                                      np.zeros_like(fg))
    jac = np.eye(N)
    jac[:-1, :-1] = f
    jac[:-1, -1] = c * (dfg @ x[:-1])
    for i, s in zip(i_sens, sens, strict=True):
        jac[:-1, i] += s @ x[:-1]
    expected = jac @ p @ jac.T + q
    x_kernel, p_kernel, buffer = x.copy(), p.copy(), np.eye(N)
    ekf_predict(x_kernel, p_kernel, fg, dfg, c, c_grid, sens, np.array(i_sens, dtype=np.int64),
                q, N - 1, buffer)
    np.testing.assert_allclose(x_kernel, np.append(f @ x[:-1], x[-1]), rtol=1e-12)
    np.testing.assert_allclose(p_kernel, 0.5 * (expected + expected.T), rtol=1e-12)
    np.testing.assert_array_equal(p_kernel, p_kernel.T)
    np.testing.assert_allclose(buffer, jac, rtol=1e-12)
