"""The compiled steady-state IMM cycle against its definition, written out with full matrices."""

from __future__ import annotations

import numpy as np
import pytest

from rail_monitor_ros.core.imm_kernel import (
    LOG_2PI,
    posterior_probabilities,
    smooth_probabilities,
    steady_imm_cycle,
)

M, N, K, P = 4, 7, 4, 3     # modes, states, vehicle states (the rest shared inputs), outputs


def _random_bank(seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    f = 0.3 * rng.standard_normal((M, N, N))
    f[:, K:, :K] = 0.0
    f[:, K:, K:] = f[0, K:, K:]           # the input block is shared by the modes
    h = rng.standard_normal((P, N))
    a = rng.standard_normal((M, N, N))
    prior = a @ a.transpose(0, 2, 1) + 0.1 * np.eye(N)      # steady-state P-_j
    r = np.diag(rng.uniform(0.1, 0.5, P))
    transition = rng.uniform(0.01, 0.1, (M, M)) + np.eye(M)
    transition /= transition.sum(axis=1, keepdims=True)
    mu = rng.dirichlet(np.ones(M))
    return {'f': f, 'h': h, 'prior': prior, 'r': r, 'transition': transition, 'mu': mu,
            'x': rng.standard_normal((M, N)), 'z': rng.standard_normal(P)}


def _reference(b: dict[str, np.ndarray], floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The IMM cycle with full matrices: mixing, P-_j = P-ss_j + F_j Spread_j F_j^T, the
    Kalman update, Gaussian likelihoods, posterior probabilities."""
    f, h, x, mu, t = b['f'], b['h'], b['x'], b['mu'], b['transition']
    cbar = mu @ t
    w = (t * mu[:, None]).T / cbar[:, None]
    x_new = np.empty_like(x)
    log_post = np.empty(M)
    for j in range(M):
        x0 = w[j] @ x
        spread = sum(w[j, i] * np.outer(x[i] - x0, x[i] - x0) for i in range(M))
        prior = b['prior'][j] + f[j] @ spread @ f[j].T
        s = h @ prior @ h.T + b['r']
        residual = b['z'] - h @ f[j] @ x0
        gain = prior @ h.T @ np.linalg.inv(s)
        x_new[j] = f[j] @ x0 + gain @ residual
        log_post[j] = (-0.5 * (residual @ np.linalg.solve(s, residual)
                               + np.log(np.linalg.det(s)) + P * LOG_2PI) + np.log(cbar[j]))
    mu_new = np.exp(log_post - log_post.max())
    mu_new /= mu_new.sum()
    mu_new = np.maximum(mu_new, floor)
    return x_new, mu_new / mu_new.sum()


def _kernel(b: dict[str, np.ndarray], z: np.ndarray, floor: float,
            ) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray]:
    f, h = b['f'], b['h']
    prior_ht = b['prior'] @ h.T
    s_ss = h @ prior_ht + b['r']
    hf_rows = np.ascontiguousarray((h @ f).reshape(M * P, N))
    x_out, mu_out, cbar = np.empty((M, N)), np.empty(M), np.empty(M)
    valid = steady_imm_cycle(b['x'], b['mu'], b['transition'], np.ascontiguousarray(f[:, :K]),
                             np.ascontiguousarray(f[0, K:, K:].T), hf_rows,
                             np.ascontiguousarray(prior_ht), s_ss, z, floor, x_out, mu_out,
                             cbar)
    return valid, x_out, mu_out, cbar


@pytest.mark.parametrize('seed', [1, 2, 3])
@pytest.mark.parametrize('floor', [0.0, 0.05])
def test_the_kernel_is_the_imm_cycle_with_steady_state_priors_plus_the_spread(
        seed: int, floor: float) -> None:
    b = _random_bank(seed)
    valid, x_out, mu_out, cbar = _kernel(b, b['z'], floor)
    x_ref, mu_ref = _reference(b, floor)
    assert valid
    np.testing.assert_allclose(x_out, x_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(mu_out, mu_ref, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(cbar, b['mu'] @ b['transition'], rtol=1e-12)


def test_without_a_measurement_the_kernel_predicts() -> None:
    b = _random_bank(4)
    valid, x_out, mu_out, _ = _kernel(b, np.empty(0), 0.0)
    t = b['transition']
    w = (t * b['mu'][:, None]).T / (b['mu'] @ t)[:, None]
    assert valid
    np.testing.assert_allclose(x_out, np.einsum('mij,mj->mi', b['f'], w @ b['x']), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(mu_out, b['mu'] @ t, rtol=1e-12)


def test_a_non_finite_state_is_reported_not_propagated() -> None:
    b = _random_bank(5)
    b['x'][2, 1] = np.nan
    valid, *_ = _kernel(b, b['z'], 0.0)
    assert not valid


def test_posterior_probabilities_survive_likelihoods_that_underflow() -> None:
    out = np.empty(3)
    posterior_probabilities(np.array([-1e4, -1e4 - 2.0, -2e4]), 0.0, out)
    np.testing.assert_allclose(out, np.array([1.0, np.exp(-2.0), 0.0]) / (1.0 + np.exp(-2.0)))
    posterior_probabilities(np.array([-1e4, -1e4 - 2.0, -2e4]), 1e-3, out)
    assert out.min() >= 1e-3 / (1.0 + 1e-3) and out.sum() == pytest.approx(1.0)


def test_smoothing_is_the_moving_average_and_only_leading_modes_vote() -> None:
    rng = np.random.default_rng(6)
    samples = rng.dirichlet(np.ones(M), size=25)
    size = 7
    window, window_sum = np.zeros((size, M)), np.zeros(M)
    ratios_by_mode = np.array([[1.0, 1.5, 1.0, 1.0], [1.0, 1.0, 0.5, 0.3]])
    smoothed, ratios = np.empty(M), np.empty(2)
    for count, mu in enumerate(samples):
        smooth_probabilities(mu, window, window_sum, count, smoothed, ratios_by_mode, 0.5,
                             ratios)
        expected = samples[max(0, count + 1 - size):count + 1].mean(axis=0)
        np.testing.assert_allclose(smoothed, expected, rtol=1e-12)
        voting = expected * (expected >= 0.5 * expected.max())
        np.testing.assert_allclose(ratios, ratios_by_mode @ voting / voting.sum(), rtol=1e-12)
