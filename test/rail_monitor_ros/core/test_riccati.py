"""The Riccati solver of the suspension IMM's steady-state filters, against the equation and
against scipy's solver."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg

from rail_monitor_ros.core.riccati import solve_discrete_riccati
from rail_monitor_ros.core.suspension_imm import SuspensionImm


def _residual(x: np.ndarray, a: np.ndarray, b: np.ndarray, q: np.ndarray,
              r: np.ndarray) -> float:
    """Largest element of the equation's residual over the largest of the solution."""
    axb = a.T @ x @ b
    rest = a.T @ x @ a - x - axb @ np.linalg.solve(r + b.T @ x @ b, axb.T) + q
    return float(np.abs(rest).max() / np.abs(x).max())


@pytest.mark.parametrize('seed', range(5))
def test_solves_random_filters_as_scipy_does(seed: int) -> None:
    """Random observable filters, stable and unstable: the equation holds and the solution is
    scipy's."""
    rng = np.random.default_rng(seed)
    n, p = 8, 3
    f = rng.normal(size=(n, n)) * (1.1 if seed % 2 else 0.5) / np.sqrt(n)
    h = rng.normal(size=(p, n))
    g = rng.normal(size=(n, n))
    q, r = g @ g.T / n + 1e-3 * np.eye(n), np.diag(rng.uniform(0.1, 1.0, p))
    x = solve_discrete_riccati(f.T, h.T, q, r)
    assert _residual(x, f.T, h.T, q, r) < 1e-12
    np.testing.assert_allclose(x, x.T, rtol=0.0, atol=0.0)
    expected = scipy.linalg.solve_discrete_are(f.T, h.T, q, r)
    np.testing.assert_allclose(x, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())


def test_solves_the_monitors_models_at_least_as_well_as_scipy() -> None:
    """The full car's modes (nearly singular covariances): a residual no larger than scipy's,
    and the same solution to its accuracy."""
    imm = SuspensionImm()
    for j in (0, 7, 15):
        model = imm._mode_models[j]
        for known, r in imm._r.items():
            h = model.h[known]
            x = solve_discrete_riccati(model.f.T, h.T, model.q, r)
            expected = scipy.linalg.solve_discrete_are(model.f.T, h.T, model.q, r)
            ours = _residual(x, model.f.T, h.T, model.q, r)
            assert ours <= max(_residual(expected, model.f.T, h.T, model.q, r), 1e-12)
            assert np.abs(x - expected).max() < 1e-6 * np.abs(expected).max()


def test_no_stabilising_solution_raises() -> None:
    """An unstable mode that the measurement cannot see: no stabilising solution; the caller
    (the monitor keeps that bank exact) gets scipy's error."""
    f = np.diag([1.5, 0.5])
    h = np.array([[0.0, 1.0]])
    with pytest.raises((np.linalg.LinAlgError, ValueError)):
        solve_discrete_riccati(f.T, h.T, np.eye(2), np.eye(1))
