"""The discrete algebraic Riccati equation of the suspension IMM's steady-state filters.

Solved by the structure-preserving doubling algorithm (Chu, Fan, Lin, 2005), which suits these
models better than scipy's generalised-eigenvalue method (``scipy.linalg.solve_discrete_are``):
on the monitor's 60-state full-car modes it took 2.1-2.8 ms where scipy took 13.8-14.6 ms
(each new bank needs up to 16 of them per measurement set: a creep or speed change, a new
adaptive step), and it left residuals of 2e-13 to 2e-11 of the solution where the QZ method
left up to 1.3e-7 (these covariances are nearly singular). Doubling converges when the pair
is stabilisable and detectable; when it does not converge, scipy's solver decides (and raises
what it raises). No ROS import.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

# Relative change of the solution between two doublings at which it has converged; doubling
# converges quadratically, so the last step is far below this.
_TOLERANCE = 1e-13
_MAX_DOUBLINGS = 100


def solve_discrete_riccati(a: np.ndarray, b: np.ndarray, q: np.ndarray, r: np.ndarray,
                           ) -> np.ndarray:
    """X of X = A^T X A - A^T X B (R + B^T X B)^-1 B^T X A + Q, symmetric (scipy's
    ``solve_discrete_are(a, b, q, r)`` convention: a Kalman filter's predicted covariance with
    a = F^T, b = H^T).

    Raises:
        numpy.linalg.LinAlgError, ValueError: no stabilising solution (from scipy's solver,
            which decides when doubling does not converge).
    """
    n = a.shape[0]
    identity = np.eye(n)
    # A_k, G_k, H_k of the doubling: A_0 = A, G_0 = B R^-1 B^T, H_0 = Q; H_k -> X.
    a_k = np.array(a, dtype=float)
    g_k = b @ np.linalg.solve(r, b.T)
    g_k = 0.5 * (g_k + g_k.T)
    h_k = 0.5 * (q + q.T)
    for _ in range(_MAX_DOUBLINGS):
        # Without a stabilising solution the iterates grow without bound: overflow ends it.
        with np.errstate(over='ignore', invalid='ignore'):
            try:
                w_inv_a, w_inv_g = np.split(
                    np.linalg.solve(identity + g_k @ h_k, np.hstack((a_k, g_k))), 2, axis=1)
            except np.linalg.LinAlgError:
                break
            g_next = g_k + a_k @ w_inv_g @ a_k.T
            h_next = h_k + w_inv_a.T @ h_k @ a_k    # = H + A^T H (I + G H)^-1 A
            a_k = a_k @ w_inv_a
        if not np.all(np.isfinite(h_next)):
            break
        change = np.abs(h_next - h_k).max()
        g_k, h_k = 0.5 * (g_next + g_next.T), 0.5 * (h_next + h_next.T)
        if change <= _TOLERANCE * np.abs(h_k).max():
            return h_k
    solution: np.ndarray = scipy.linalg.solve_discrete_are(a, b, q, r)
    return solution
