"""The creep EKF's per-sample update and prediction as compiled kernels (numba).

Why compiled: the augmented state has about 30 entries and a sample takes some thirty small
array operations (the update's products and Cholesky solve, the Joseph form, the Taylor-stepped
transition, the covariance propagation); as numpy calls they cost about 95 us a sample, mostly
call overhead, in each of the two estimators of the rail graph. Here the same maths runs in two
calls (the update, then the prediction: between them the filter may reset on divergence and
builds the estimate). The large products (F P F^T) stay BLAS calls; the small ones are loops.
:mod:`rail_monitor_ros.core.creep_ekf` keeps the model, the cache of discretisations and every
decision; the tests hold the kernels to the numpy formulas.

Compiled when this module is first imported (explicit signatures: C-contiguous float64 arrays),
not on the first sample, and cached beside this file (``cache=True``), as
:mod:`rail_monitor_ros.core.imm_kernel`.
"""

from __future__ import annotations

import math

from numba import njit, types
import numpy as np

VECTOR, MATRIX = types.float64[::1], types.float64[:, ::1]
TENSOR, INDICES = types.float64[:, :, ::1], types.int64[::1]

#: :func:`ekf_update` outcomes.
UPDATED, OUTLIER, SINGULAR = 0, 1, 2


@njit(types.void(VECTOR, MATRIX, MATRIX, types.float64, types.float64, types.int64, TENSOR,
                 INDICES, VECTOR, MATRIX),
      cache=True)
def augmented_transition(x: np.ndarray, fg: np.ndarray, dfg: np.ndarray, c: float,
                         c_grid: float, i_theta: int, sens: np.ndarray, i_sens: np.ndarray,
                         x_next: np.ndarray, jac: np.ndarray) -> None:
    """The augmented transition x -> f(x) and its Jacobian, F Taylor-stepped from a grid point.

    F(c, delta) = F(c_grid) + (c - c_grid) dF/dc + sum_j delta_j dF/d delta_j, where the
    delta_j = x[i_sens[j]] are parameters carried in the state (the full model's suspension
    ratio errors): first order in each, as in c.

    The states from ln c on (ln c, and its rate when the filter carries one) step linearly
    with a constant matrix: the rows from ``i_theta`` on of ``jac``, which the caller's buffer
    holds.

    Args:
        x: (n,) state, the model's states before ln c (index ``i_theta``).
        fg, dfg: (i_theta, i_theta) F and dF/dc at the grid point ``c_grid``.
        c: e^(x[i_theta]).
        sens: (k, n - 1, n - 1) dF/d delta_j at the grid point (k may be 0).
        i_sens: (k,) the states delta_j.
        x_next: (n,) output: [F(c, delta) x_q, the rows of ln c and its rate].
        jac: (n, n) output, its rows from ``i_theta`` on left as they are (the caller's buffer
            holds them).
    """
    dc = c - c_grid
    n = i_theta
    f = fg + dc * dfg
    for j in range(i_sens.shape[0]):
        f += x[i_sens[j]] * sens[j]
    x_q = x[:n]
    x_next[:n] = np.dot(f, x_q)
    jac[:n, :n] = f
    # d/d(ln c) = c d/dc of the Taylor-stepped transition actually used.
    jac[:n, i_theta] = c * np.dot(dfg, x_q)
    for j in range(i_sens.shape[0]):
        jac[:n, i_sens[j]] += np.dot(sens[j], x_q)
    for r in range(n, x.shape[0]):
        acc = 0.0
        for col in range(n, x.shape[0]):
            acc += jac[r, col] * x[col]
        x_next[r] = acc


@njit(types.void(VECTOR, MATRIX, MATRIX, MATRIX, types.float64, types.float64, TENSOR,
                 INDICES, MATRIX, types.int64, MATRIX),
      cache=True)
def ekf_predict(x: np.ndarray, p: np.ndarray, fg: np.ndarray, dfg: np.ndarray, c: float,
                c_grid: float, sens: np.ndarray, i_sens: np.ndarray, q: np.ndarray,
                i_theta: int, jac: np.ndarray) -> None:
    """x <- f(x), P <- J P J^T + Q symmetrised, in place (``jac``: the (n, n) buffer of
    :func:`augmented_transition`)."""
    x_next = np.empty_like(x)
    augmented_transition(x, fg, dfg, c, c_grid, i_theta, sens, i_sens, x_next, jac)
    x[:] = x_next
    propagated = np.dot(np.dot(jac, p), jac.T)
    n = x.shape[0]
    for r in range(n):
        for col in range(r + 1):
            value = 0.5 * ((propagated[r, col] + q[r, col])
                           + (propagated[col, r] + q[col, r]))
            p[r, col] = value
            p[col, r] = value


@njit(types.int64(VECTOR, MATRIX, MATRIX, VECTOR, VECTOR, types.int64, types.float64,
                  types.int64, VECTOR),
      cache=True)
def ekf_update(x: np.ndarray, p: np.ndarray, h: np.ndarray, r: np.ndarray, z: np.ndarray,
               n_gated: int, gate2: float, i_theta: int, out: np.ndarray) -> int:
    """The measurement update with diagonal noise, x and P in place.

    S = H P H^T + diag(r), y = z - H x. A residual beyond the gate in one of the first
    ``n_gated`` channels (y_i^2 > gate2 S_ii) is an outlier: nothing changes. Otherwise
    K = P H^T S^-1 (one Cholesky factorisation of S), x += K y and the Joseph form
    P - K H P - (K H P)^T + K S K^T.

    Returns:
        :data:`UPDATED`, :data:`OUTLIER` or :data:`SINGULAR` (S not positive definite:
        nothing changes). When updated, ``out`` holds [y^T S^-1 y, the correction of
        x[i_theta] (K y)_theta, its predicted variance (K S K^T)_theta, ln det S].
    """
    m, n = h.shape
    hp = np.dot(h, p)                                 # H P, (m, n)
    s = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            acc = 0.0
            for k in range(n):
                acc += hp[a, k] * h[b, k]
            s[a, b] = acc
        s[a, a] += r[a]
    y = np.empty(m)
    for a in range(m):
        acc = 0.0
        for k in range(n):
            acc += h[a, k] * x[k]
        y[a] = z[a] - acc
    for a in range(n_gated):
        if y[a] * y[a] > gate2 * s[a, a]:
            return OUTLIER
    # Cholesky S = L L^T (lower triangle of S), then S^-1 [H P, y] by two triangular solves.
    chol = np.zeros((m, m))
    for a in range(m):
        for b in range(a + 1):
            acc = s[a, b]
            for k in range(b):
                acc -= chol[a, k] * chol[b, k]
            if a == b:
                if not acc > 0.0:        # also catches NaN
                    return SINGULAR
                chol[a, a] = math.sqrt(acc)
            else:
                chol[a, b] = acc / chol[b, b]
    solved = np.empty((m, n + 1))                    # S^-1 [H P, y]
    solved[:, :n] = hp
    solved[:, n] = y
    for col in range(n + 1):
        for a in range(m):
            acc = solved[a, col]
            for k in range(a):
                acc -= chol[a, k] * solved[k, col]
            solved[a, col] = acc / chol[a, a]
        for a in range(m - 1, -1, -1):
            acc = solved[a, col]
            for k in range(a + 1, m):
                acc -= chol[k, a] * solved[k, col]
            solved[a, col] = acc / chol[a, a]
    nis = correction = spread = 0.0
    for a in range(m):
        nis += y[a] * solved[a, n]
        correction += hp[a, i_theta] * solved[a, n]
        spread += hp[a, i_theta] * solved[a, i_theta]
    log_det = 0.0
    for a in range(m):
        log_det += math.log(chol[a, a])
    out[0], out[1], out[2], out[3] = nis, correction, spread, 2.0 * log_det
    # gain[k, a] = solved[a, k]: x += K y; K S as rows for the last term of the Joseph form.
    gain_s = np.empty((n, m))
    for k in range(n):
        acc = 0.0
        for a in range(m):
            acc += solved[a, k] * y[a]
        x[k] += acc
        for b in range(m):
            acc = 0.0
            for a in range(m):
                acc += solved[a, k] * s[a, b]
            gain_s[k, b] = acc
    gain_t = np.ascontiguousarray(solved[:, :n])     # K^T, (m, n)
    kkp = np.dot(gain_t.T, hp)                       # K H P
    ksk = np.dot(gain_s, gain_t)                     # K S K^T
    for a in range(n):
        for b in range(n):
            p[a, b] = p[a, b] - kkp[a, b] - kkp[b, a] + ksk[a, b]
    return UPDATED
