"""The lateral force observer's EKF step as one compiled kernel (numba).

Why compiled: a step of the 7-state filter is some forty small array operations (the model's
derivative and Jacobian, the second-order transition, F P F^T, the measurement Jacobian, the
gain's solve, the Joseph form); as numpy calls they cost about 80 us a step at 100 Hz, most of
it call overhead, which made the observer the road graph's costliest node per second of data.
Here the same maths runs as loops in one call.

The model is that of :class:`tpms_ros.core.lateral_force_observer.LateralForceObserver` (its
module docstring has the equations); the observer keeps every decision that is not arithmetic
(initialisation, gap restarts, the covariance check, the loads and the held inputs) and the
tests hold this kernel to the numpy formulas. Compiled when the module is first imported (the
explicit signature), not on the first sample, and cached beside this file (``cache=True``).
"""

from __future__ import annotations

import math

from numba import njit, types
import numpy as np

G = 9.81
N_X, N_Z = 7, 5

#: Layout of the ``model`` vector: the vehicle constants the step uses.
MODEL_FIELDS = ('m', 'mse', 'lf', 'lr', 'tf', 'tr', 'hf', 'hr', 'kphi', 'cphi', 'zeta_f',
                'zeta_r')
#: Bits of the step's result: what had to restart (each counted by the observer).
DIVERGED, SINGULAR = 1, 2

_V, _M, _A = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1]


@njit(types.void(_V, _V, _V, _M, _V, _V, _M), cache=True)
def derivative(xp: np.ndarray, u: np.ndarray, model: np.ndarray, se_inv: np.ndarray,
                s_inv: np.ndarray, g: np.ndarray, a_s: np.ndarray) -> None:
    """g = S E^-1 f(x, u) and its scaled Jacobian A* = S E^-1 (df/dx) S^-1 (split ratios
    frozen), for the physical state ``xp`` and the held inputs
    u = (Fx1..Fx4, cos d, sin d, front split ratio)."""
    m, mse, lf, lr, tf, tr, hf, hr, kphi, cphi, zeta_f, zeta_r = model
    vx, vy, r, phi, pr, fyf, fyr = xp
    fx1, fx2, fx3, fx4, c, s, drho_f = u
    fxf = fx1 + fx2
    sum_fy_front = s * fxf + 2.0 * c * fyf
    f = np.empty(N_X)
    f[0] = c * fxf - 2.0 * s * fyf + fx3 + fx4 + m * r * vy - mse * pr * r
    f[1] = sum_fy_front + 2.0 * fyr - m * r * vx
    f[2] = (lf * sum_fy_front - 2.0 * lr * fyr + tf * c * (fx2 - fx1)
            + tf * s * drho_f * fyf + tr * (fx4 - fx3))
    f[3] = pr
    f[4] = (hf * sum_fy_front + 2.0 * hr * fyr - kphi * phi - cphi * pr
            + mse * G * math.sin(phi) + mse * r * vx)
    f[5] = zeta_f * pr
    f[6] = zeta_r * pr
    jac = np.zeros((N_X, N_X))
    jac[0, 1] = m * r
    jac[0, 2] = m * vy - mse * pr
    jac[0, 4] = -mse * r
    jac[0, 5] = -2.0 * s
    jac[1, 0] = -m * r
    jac[1, 2] = -m * vx
    jac[1, 5] = 2.0 * c
    jac[1, 6] = 2.0
    jac[2, 5] = 2.0 * lf * c + tf * s * drho_f
    jac[2, 6] = -2.0 * lr
    jac[3, 4] = 1.0
    jac[4, 0] = mse * r
    jac[4, 2] = mse * vx
    jac[4, 3] = -kphi + mse * G * math.cos(phi)
    jac[4, 4] = -cphi
    jac[4, 5] = 2.0 * hf * c
    jac[4, 6] = 2.0 * hr
    jac[5, 4] = zeta_f
    jac[6, 4] = zeta_r
    for i in range(N_X):
        acc = 0.0
        for k in range(N_X):
            acc += se_inv[i, k] * f[k]
        g[i] = acc
        for j in range(N_X):
            acc = 0.0
            for k in range(N_X):
                acc += se_inv[i, k] * jac[k, j]
            a_s[i, j] = acc * s_inv[j]


@njit(types.void(_V, _V, types.float64, types.float64, types.float64, _V, _V, _M, types.boolean),
      cache=True)
def measure(xp: np.ndarray, fx: np.ndarray, c: float, s: float, m: float, s_inv: np.ndarray,
             z_hat: np.ndarray, h: np.ndarray, tilt: bool) -> None:
    """Predicted measurement [ax, ay, r, p, vx] and its Jacobian in scaled coordinates
    H* = H S^-1 (``h``, written whole)."""
    fxf = fx[0] + fx[1]
    h[:, :] = 0.0
    z_hat[0] = (c * fxf - 2.0 * s * xp[5] + fx[2] + fx[3]) / m
    z_hat[1] = (s * fxf + 2.0 * c * xp[5] + 2.0 * xp[6]) / m
    if tilt:
        # A body-fixed IMU on the rolled sprung mass also reads g sin(phi).
        z_hat[1] += G * math.sin(xp[3])
        h[1, 3] = G * math.cos(xp[3])
    z_hat[2] = xp[2]
    z_hat[3] = xp[4]
    z_hat[4] = xp[0]
    h[0, 5] = -2.0 * s / m
    h[1, 5] = 2.0 * c / m
    h[1, 6] = 2.0 / m
    h[2, 2] = h[3, 4] = h[4, 0] = 1.0
    for j in range(N_X):
        for i in range(N_Z):
            h[i, j] *= s_inv[j]


@njit(types.void(types.float64, types.float64, types.float64, types.float64, _V, _V, _V),
      cache=True)
def initial_state(ay: float, r: float, pr: float, vx: float, model: np.ndarray,
                  scaling: np.ndarray, x: np.ndarray) -> None:
    """Steady-turn start in scaled coordinates: forces from ay, roll angle from relation 1."""
    m, lf, lr, zeta_f = model[0], model[2], model[3], model[10]
    wb = lf + lr
    fyf = m * ay * lr / (2.0 * wb)
    fyr = m * ay * lf / (2.0 * wb)
    x[0] = scaling[0] * vx
    x[1] = 0.0
    x[2] = scaling[2] * r
    x[3] = scaling[3] * (fyf / zeta_f)
    x[4] = scaling[4] * pr
    x[5] = scaling[5] * fyf
    x[6] = scaling[6] * fyr


@njit(types.float64(_V, _M), cache=True)
def gaussian_log_density(y: np.ndarray, cov: np.ndarray) -> float:
    """log N(y; 0, cov) from one Cholesky factor L of ``cov`` (y^T cov^-1 y = |L^-1 y|^2,
    log det cov = 2 sum log L_ii); -inf when ``cov`` is not positive definite."""
    try:
        lower = np.linalg.cholesky(cov)
    except Exception:  # noqa: BLE001 - numba raises LinAlgError as a plain exception
        return -math.inf
    n = y.size
    whitened = np.empty(n)
    quadratic = log_det = 0.0
    for i in range(n):
        acc = y[i]
        for k in range(i):
            acc -= lower[i, k] * whitened[k]
        whitened[i] = acc / lower[i, i]
        quadratic += whitened[i] * whitened[i]
        log_det += 2.0 * math.log(lower[i, i])
    return -0.5 * (quadratic + log_det + n * math.log(2.0 * math.pi))


@njit(types.int64(_V, _M, _V, types.boolean, types.float64, _V, _V, types.float64,
                  types.float64, _V, _M, _V, _V, _M, _M, _V, types.boolean, _M, _V, _V),
      cache=True)
def filter_step(x: np.ndarray, p: np.ndarray, u_prev: np.ndarray, predict: bool, dt: float,
                z: np.ndarray, fx: np.ndarray, c: float, s: float, model: np.ndarray,
                se_inv: np.ndarray, scaling: np.ndarray, s_inv: np.ndarray, q: np.ndarray,
                r: np.ndarray, gp: np.ndarray, tilt: bool, p0: np.ndarray,
                y: np.ndarray, log_likelihood: np.ndarray) -> int:
    """One step of the scaled EKF with the model error compensator, x* and P in place.

    Predict over ``dt`` with the held inputs ``u_prev`` (when ``predict``): x* += dt (g +
    A* dt g / 2), F = I + A* dt + (A* dt)^2 / 2, P = F P F^T + Q dt. Correct with z = [ax, ay,
    r, p, vx] (this sample's ``fx`` and steer cos/sin ``c``, ``s``): K = P H^T (H P H^T + R)^-1,
    Joseph form, symmetrised, x* += K y + dt y_r Gp.

    A prediction that is not finite, or an innovation covariance that cannot be solved,
    restarts the state from this sample's :func:`initial_state` and ``p0``, and the step goes
    on from there. ``z`` is [ax, ay, r, p, vx].

    Returns:
        0, or the bits :data:`DIVERGED` and :data:`SINGULAR` of the restarts made. ``y`` holds
        the residual z - h(x*-), ``log_likelihood[0]`` its Gaussian log density under the
        residual covariance H P H^T + R (what an IMM weighs the modes by).
    """
    restarted = 0
    if predict:
        xp = x * s_inv
        g = np.empty(N_X)
        a_s = np.empty((N_X, N_X))
        derivative(xp, u_prev, model, se_inv, s_inv, g, a_s)
        a_dt = a_s * dt
        a_dt_g = a_dt @ g
        for i in range(N_X):
            x[i] = x[i] + dt * (g[i] + 0.5 * a_dt_g[i])
        f = np.eye(N_X) + a_dt + 0.5 * (a_dt @ a_dt)
        p[:, :] = f @ p @ f.T + q * dt
        if not math.isfinite(x.sum() + p.sum()):
            initial_state(z[1], z[2], z[3], z[4], model, scaling, x)
            p[:, :] = p0
            restarted |= DIVERGED
    z_hat = np.empty(N_Z)
    h = np.empty((N_Z, N_X))
    measure(x * s_inv, fx, c, s, model[0], s_inv, z_hat, h, tilt)
    pht = p @ h.T
    residual_cov = h @ pht + r
    try:
        gain = np.linalg.solve(residual_cov, pht.T).T
    except Exception:  # noqa: BLE001 - numba raises LinAlgError as a plain exception
        # Numerically singular residual covariance (P blown up): restart.
        initial_state(z[1], z[2], z[3], z[4], model, scaling, x)
        p[:, :] = p0
        restarted |= SINGULAR
        measure(x * s_inv, fx, c, s, model[0], s_inv, z_hat, h, tilt)
        pht = p @ h.T
        residual_cov = h @ pht + r
        gain = np.linalg.solve(residual_cov, pht.T).T
    for i in range(N_Z):
        y[i] = z[i] - z_hat[i]
    log_likelihood[0] = gaussian_log_density(y, residual_cov)
    i_kh = np.eye(N_X) - gain @ h
    joseph = i_kh @ p @ i_kh.T + gain @ r @ gain.T
    for i in range(N_X):
        for j in range(N_X):
            p[i, j] = 0.5 * (joseph[i, j] + joseph[j, i])
    correction = gain @ y
    for i in range(N_X):
        x[i] = x[i] + correction[i] + (dt * y[2]) * gp[i]
    return restarted


@njit(types.int64(_M, _A, _V, _V, types.boolean, types.float64, _V, _V, types.float64,
                  types.float64, _V, _M, _V, _V, _A, _M, _V, types.boolean, _M, _V,
                  types.float64, _V),
      cache=True)
def imm_step(xs: np.ndarray, ps: np.ndarray, mu: np.ndarray, u_prev: np.ndarray,
             predict: bool, dt: float, z: np.ndarray, fx: np.ndarray, c: float, s: float,
             model: np.ndarray, se_inv: np.ndarray, scaling: np.ndarray, s_inv: np.ndarray,
             qs: np.ndarray, r: np.ndarray, gp: np.ndarray, tilt: bool, p0: np.ndarray,
             y: np.ndarray, switch: float, x_out: np.ndarray) -> int:
    """One interacting multiple model cycle (Blom and Bar-Shalom 1988) over filters that
    differ only in their process noise ``qs[j]``: mix the modes' states and covariances by the
    Markov switching probability ``switch`` (per step, to each other mode), run
    :func:`filter_step` on each, weigh the modes by their residuals' likelihood, and combine.

    ``xs`` (modes, 7), ``ps`` (modes, 7, 7) and the mode probabilities ``mu`` are updated in
    place; ``x_out`` receives the combined state and ``y`` the probability-weighted residual.
    Without ``predict`` (a start) nothing is mixed. With one mode this is :func:`filter_step`
    to the bit (its weights are exactly 1).

    Returns:
        The restart bits of every mode's step, or-ed.
    """
    n_modes = xs.shape[0]
    prior = mu.copy()
    if predict and n_modes > 1:
        stay = 1.0 - switch * (n_modes - 1)
        # share[i, j]: the probability of mode i before and j now, then as a weight of j's mix
        share = np.empty((n_modes, n_modes))
        for j in range(n_modes):
            prior[j] = 0.0
            for i in range(n_modes):
                share[i, j] = (stay if i == j else switch) * mu[i]
                prior[j] += share[i, j]
            for i in range(n_modes):
                share[i, j] /= prior[j]
        mixed_x = np.zeros((n_modes, N_X))
        mixed_p = np.zeros((n_modes, N_X, N_X))
        for j in range(n_modes):
            for i in range(n_modes):
                mixed_x[j] += share[i, j] * xs[i]
            for i in range(n_modes):
                spread = xs[i] - mixed_x[j]
                mixed_p[j] += share[i, j] * (ps[i] + np.outer(spread, spread))
        xs[:, :] = mixed_x
        ps[:, :, :] = mixed_p
    restarted = 0
    log_likelihood = np.empty(n_modes)
    one = np.empty(1)
    residuals = np.empty((n_modes, N_Z))
    for j in range(n_modes):
        restarted |= filter_step(xs[j], ps[j], u_prev, predict, dt, z, fx, c, s, model,
                                 se_inv, scaling, s_inv, qs[j], r, gp, tilt, p0, residuals[j],
                                 one)
        log_likelihood[j] = one[0]
    best = log_likelihood.max()
    total = 0.0
    for j in range(n_modes):
        mu[j] = prior[j] * (math.exp(log_likelihood[j] - best) if math.isfinite(best) else 1.0)
        total += mu[j]
    for j in range(n_modes):
        mu[j] = mu[j] / total if total > 0.0 else 1.0 / n_modes
    x_out[:] = 0.0
    y[:] = 0.0
    for j in range(n_modes):
        x_out += mu[j] * xs[j]
        y += mu[j] * residuals[j]
    return restarted
