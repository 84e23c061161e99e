"""The steady-state IMM cycle as one compiled kernel (numba).

Why compiled: the cycle is a few hundred thousand multiply-adds spread over some forty small
array operations; as numpy calls it took about 120 us per sample, most of it call overhead,
which caps the monitor at about 40x real time at 200 Hz. Here the same maths runs in one
call, in the cheaper order a loop allows (mix the means first, then one product per mode,
instead of F_j x_i for every pair i, j). The exact cycle (mode-matched covariances) stays in
numpy in :mod:`rail_monitor_ros.core.suspension_imm`; the tests hold the two to the same results.

Compiled when this module is first imported (explicit signatures: C-contiguous float64 arrays,
what the monitor passes), not on the first sample: a node compiles while it starts (about 9 s
the first time), not while data waits, which would stall a replay's pacing. The result is
cached beside this file (``cache=True``), so later starts load it in under a second.
"""

from __future__ import annotations

import math

from numba import njit, types
import numpy as np

LOG_2PI = math.log(2.0 * math.pi)
# Predicted mode probabilities below this are treated as this (log of zero).
CBAR_FLOOR = 1e-300


# C-contiguous float64 arrays of one, two and three dimensions (what the monitor passes).
VECTOR, MATRIX, STACK = types.float64[::1], types.float64[:, ::1], types.float64[:, :, ::1]

# Reassociation lets the reductions vectorise; no 'nnan'/'ninf': the definiteness test must
# see a NaN.
_FASTMATH = {'reassoc', 'contract'}


@njit(types.void(VECTOR, types.float64, VECTOR), cache=True)
def posterior_probabilities(log_post: np.ndarray, probability_floor: float,
                            out: np.ndarray) -> None:
    """out = normalised exp(log_post) (log-sum-exp: no mode underflows to an undefined
    ratio), then floored at ``probability_floor`` (0: none) and renormalised."""
    peak = log_post.max()
    total = 0.0
    for j in range(log_post.shape[0]):
        out[j] = math.exp(log_post[j] - peak)
        total += out[j]
    if probability_floor > 0.0:
        floored = 0.0
        for j in range(out.shape[0]):
            out[j] = max(out[j] / total, probability_floor)
            floored += out[j]
        total = floored
    for j in range(out.shape[0]):
        out[j] /= total


@njit(types.boolean(MATRIX, VECTOR, MATRIX, STACK, MATRIX, MATRIX, STACK, STACK, VECTOR,
                    types.float64, MATRIX, VECTOR, VECTOR),
      cache=True, fastmath=_FASTMATH)
def steady_imm_cycle(x: np.ndarray, mu: np.ndarray, transition: np.ndarray,
                     f_top: np.ndarray, f_input_t: np.ndarray, hf_rows: np.ndarray,
                     prior_ht: np.ndarray, s_ss: np.ndarray, z: np.ndarray,
                     probability_floor: float, x_out: np.ndarray, mu_out: np.ndarray,
                     cbar: np.ndarray) -> bool:
    """One IMM cycle on steady-state covariances plus the mixing's spread of means.

    With the mixing weights w_ji = T_ij mu_i / cbar_j, mixed means x0_j = sum_i w_ji x_i and
    spread columns e_ij = F_j (x_i - x0_j), the mode-matched filter j uses
    S_j = S_ss,j + sum_i w_ji (H e_ij)(H e_ij)^T and P-_j H^T = P-ss_j H^T
    + sum_i w_ji e_ij (H e_ij)^T: the exact IMM's mixed covariance with the modes' own
    covariances replaced by their steady state, the spread kept exactly as a low-rank term.
    The update is then x_j = F_j (x0_j + d_j) + P-ss_j H^T S_j^-1 r_j with
    d_j = sum_i c_ji (x_i - x0_j), c_ji = w_ji (H e_ij)^T S_j^-1 r_j: no gain is formed.

    Args:
        x: (M, n) mode states. mu: (M,) mode probabilities. transition: (M, M) T_ij.
        f_top: (M, k, n) each mode's vehicle rows of F. f_input_t: (n - k, n - k) the
            transposed input-state block of F (shared by the modes; F = [[F_top], [0, F_in]]).
        hf_rows: (M p, n) H F_j, mode-major. prior_ht: (M, n, p) P-ss_j H^T.
        s_ss: (M, p, p) S_ss,j.
        z: (p,) measurement, or an empty array (predict only).
        probability_floor: floor on the posterior probabilities (0: none).
        x_out, mu_out, cbar: (M, n), (M,), (M,) outputs: states, posterior (predicted when
            z is empty) probabilities, predicted probabilities.

    Returns:
        False when an innovation covariance is not positive definite (only non-finite states
        do this: S_ss is positive definite, the spread semi-definite); outputs then invalid.
    """
    m, n = x.shape
    k = f_top.shape[1]
    p = z.shape[0]
    w = np.empty((m, m))
    for j in range(m):
        acc = 0.0
        for i in range(m):
            acc += transition[i, j] * mu[i]
        cbar[j] = acc
        for i in range(m):
            w[j, i] = transition[i, j] * mu[i] / acc
    mixed = np.dot(w, x)                                  # x0_j, then x0_j + d_j
    if p == 0:
        total = cbar.sum()
        for j in range(m):
            mu_out[j] = cbar[j] / total
    else:
        measured = np.dot(hf_rows, x.T)                   # row j p + r, column i: H F_j x_i
        spread_h = np.empty((m, p))
        predicted = np.empty(p)
        s = np.empty((p, p))
        chol = np.empty((p, p))
        sol = np.empty((m, p))
        c_mix = np.empty((m, m))
        log_post = np.empty(m)
        for j in range(m):
            for r in range(p):
                acc = 0.0
                for i in range(m):
                    acc += w[j, i] * measured[j * p + r, i]
                predicted[r] = acc
                for i in range(m):
                    spread_h[i, r] = measured[j * p + r, i] - acc
            for a in range(p):
                for b in range(a + 1):
                    acc = s_ss[j, a, b]
                    for i in range(m):
                        acc += w[j, i] * spread_h[i, a] * spread_h[i, b]
                    s[a, b] = acc
            # Cholesky S = L L^T, then S^-1 r by two triangular solves.
            log_det = 0.0
            for a in range(p):
                for b in range(a + 1):
                    acc = s[a, b]
                    for c in range(b):
                        acc -= chol[a, c] * chol[b, c]
                    if a == b:
                        if not acc > 0.0:    # also catches NaN
                            return False
                        chol[a, a] = math.sqrt(acc)
                        log_det += 2.0 * math.log(chol[a, a])
                    else:
                        chol[a, b] = acc / chol[b, b]
            maha = 0.0
            for a in range(p):
                acc = z[a] - predicted[a]
                for c in range(a):
                    acc -= chol[a, c] * sol[j, c]
                sol[j, a] = acc / chol[a, a]
                maha += sol[j, a] * sol[j, a]
            for a in range(p - 1, -1, -1):
                acc = sol[j, a]
                for c in range(a + 1, p):
                    acc -= chol[c, a] * sol[j, c]
                sol[j, a] = acc / chol[a, a]
            log_post[j] = (-0.5 * (maha + log_det + p * LOG_2PI)
                           + math.log(max(cbar[j], CBAR_FLOOR)))
            c_sum = 0.0
            for i in range(m):
                acc = 0.0
                for r in range(p):
                    acc += spread_h[i, r] * sol[j, r]
                c_mix[j, i] = w[j, i] * acc
                c_sum += c_mix[j, i]
            for c in range(n):
                mixed[j, c] -= c_sum * mixed[j, c]
        mixed += np.dot(c_mix, x)
        posterior_probabilities(log_post, probability_floor, mu_out)
    # x_out = F_j (x0_j + d_j) by blocks: the vehicle rows per mode, the shared input rows
    # for all modes in one product.
    for j in range(m):
        for r in range(k):
            acc = 0.0
            for c in range(n):
                acc += f_top[j, r, c] * mixed[j, c]
            x_out[j, r] = acc
    x_out[:, k:] = np.dot(np.ascontiguousarray(mixed[:, k:]), f_input_t)
    if p > 0:
        for j in range(m):
            for c in range(n):
                acc = 0.0
                for r in range(p):
                    acc += prior_ht[j, c, r] * sol[j, r]
                x_out[j, c] += acc
    return True


@njit(types.void(VECTOR, MATRIX, VECTOR, types.int64, VECTOR, MATRIX, types.float64, VECTOR),
      cache=True)
def smooth_probabilities(mu: np.ndarray, window: np.ndarray, window_sum: np.ndarray,
                         count: int, smoothed: np.ndarray, mode_ratios: np.ndarray,
                         min_fraction: float, ratios: np.ndarray) -> None:
    """Moving-average smoothing of the mode probabilities and the weighted ratio estimates.

    Args:
        mu: (M,) this sample's probabilities, entering the window as sample ``count``.
        window: (W, M) the last W samples (ring buffer, updated).
        window_sum: (M,) their running sum (updated; re-summed once per wrap so rounding
            cannot drift).
        count: samples entered before this one.
        smoothed: (M,) output: the mean over the samples in the window.
        mode_ratios: (R, M) each mode's ratios (spring, damper).
        min_fraction: only modes holding at least this fraction of the largest smoothed
            probability vote. The Markov prior keeps a little mass on every mode; weighing
            all modes would pull the estimate toward the middle of the grid (and, fed back by
            the adaptive step, walk the damper modes away from the truth).
        ratios: (R,) output: the smoothed-probability-weighted ratios of the voting modes.
    """
    size, m = window.shape
    slot = count % size
    for j in range(m):
        window_sum[j] += mu[j] - window[slot, j]
        window[slot, j] = mu[j]
    if slot == size - 1:
        for j in range(m):
            acc = 0.0
            for t in range(size):
                acc += window[t, j]
            window_sum[j] = acc
    filled = min(count + 1, size)
    for j in range(m):
        smoothed[j] = window_sum[j] / filled
    cutoff = min_fraction * smoothed.max()
    for q in range(mode_ratios.shape[0]):
        weighted = 0.0
        total = 0.0
        for j in range(m):
            if smoothed[j] >= cutoff:
                weighted += smoothed[j] * mode_ratios[q, j]
                total += smoothed[j]
        ratios[q] = weighted / total
