"""Block least squares of the tire stiffness method (Umeno et al. 1997, eq. 9-14), for several
independent problems (wheels, driven axles) solved together.

``w = zeta^T [dK, dD] - T_d`` with ``zeta = [th, th_dot]``
(``th_dot = w1 - w2_hat``). Samples are summed in blocks of ``block_s`` seconds; one *update*
is one block. RLS keeps the information form ``P_k = rho P_(k-1) + sum zeta zeta^T``,
``b_k = rho b_(k-1) + sum w zeta``, ``theta = P^-1 b``, algebraically the same as eq. 11's
covariance recursion with ``Gamma = P^-1`` but exact for a block of samples. Forgetting per
update ``rho`` gives a memory time constant ``tau = block_s / (1 - rho)`` (0.25 s blocks:
rho = 0.98 -> 12.5 s, 0.95 -> 5 s, 0.99 -> 25 s) and an averaging equivalent to
``(1 + rho) / (1 - rho)`` blocks. The sums can be kept with several forgetting factors at
once (one per *memory*: the stiffness observer warns from the paper's and reads the pressure
from a longer one). Batch LS (eq. 10) uses the last ``batch_window_blocks`` valid blocks
instead.

No ROS import.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from tpms_ros.core.tires import N_TIRES


def batch_least_squares(regressors: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Batch LS of eq. 10: ``(sum zeta zeta^T)^-1 sum w zeta``, vectorised over problems.

    Args:
        regressors: (N, ..., p) regressor rows zeta.
        target: (N, ...) disturbance w.

    Returns:
        (..., p) coefficients (NaN where the normal matrix is singular).
    """
    gram = np.einsum('n...p,n...q->...pq', regressors, regressors)
    rhs = np.einsum('n...p,n...->...p', regressors, target)
    return solve_normal(gram, rhs)


def solve_normal(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve batched normal equations with Jacobi scaling (th and th_dot differ ~300x)."""
    diag = np.einsum('...ii->...i', gram)
    ok = np.all(diag > 0, axis=-1)
    scale = np.where(diag > 0, 1.0 / np.sqrt(np.where(diag > 0, diag, 1.0)), 0.0)
    scaled = gram * scale[..., :, None] * scale[..., None, :]
    eye = np.eye(gram.shape[-1])
    scaled = np.where(ok[..., None, None], scaled, eye)
    ok &= np.linalg.cond(scaled) < 1e10
    solution = np.linalg.solve(np.where(ok[..., None, None], scaled, eye),
                               (rhs * scale)[..., None])[..., 0] * scale
    return np.where(ok[..., None], solution, np.nan)


class BlockLeastSquares:
    """Block sums of zeta zeta^T and w zeta for several LS problems, with RLS and batch.

    Problems are independent (wheels or axles) and share the block clock.

    Args:
        n_problems: number of independent problems.
        n_params: regressors per problem.
        forgetting_factors: RLS forgetting factor rho per block of each memory.
        window_blocks: window of the batch LS, in valid blocks.
        min_count: valid samples a block needs to count.
    """

    def __init__(self, n_problems: int, n_params: int, forgetting_factors: Sequence[float],
                 window_blocks: int, min_count: float) -> None:
        self.n_params = n_params
        self._rhos = tuple(forgetting_factors)
        self._window = window_blocks
        self._min_count = min_count
        shape = (len(self._rhos), n_problems, n_params)
        self.info = np.zeros(shape + (n_params,))
        self.rhs = np.zeros(shape)
        self.n_eff = np.zeros(shape[:2])
        # Blocks during which the later memories of a problem still forget like the first
        # (after a restart, :meth:`restart`).
        self.hold = np.zeros(n_problems, dtype=np.int64)
        self.window_gram = np.zeros((self._window, n_problems, n_params, n_params))
        self.window_rhs = np.zeros((self._window, n_problems, n_params))
        self.window_fill = np.zeros(n_problems, dtype=int)
        self._window_pos = np.zeros(n_problems, dtype=int)

    def block_sums(self, regressors: np.ndarray, target: np.ndarray,
                   mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Sums over the sample axis 1 of (B, L, n, p) arrays: gram, rhs, valid count."""
        weighted = regressors * mask[..., None]
        gram = np.einsum('blnp,blnq->bnpq', weighted, regressors, optimize=True)
        rhs = np.einsum('blnp,bln->bnp', weighted, target, optimize=True)
        return gram, rhs, mask.sum(axis=1)

    def update(self, gram: np.ndarray, rhs: np.ndarray, good: np.ndarray) -> None:
        """One update per block (axis 0); a bad block is skipped (estimate held, no forgetting)."""
        for b in range(gram.shape[0]):
            g = good[b]
            held = self.hold[g] > 0
            for m, rho in enumerate(self._rhos):
                r = np.where(held, self._rhos[0], rho)
                self.info[m, g] = r[:, None, None] * self.info[m, g] + gram[b, g]
                self.rhs[m, g] = r[:, None] * self.rhs[m, g] + rhs[b, g]
                self.n_eff[m, g] = r * self.n_eff[m, g] + 1.0
            self.hold[g] = np.maximum(self.hold[g] - 1, 0)
            idx = np.flatnonzero(g)
            pos = self._window_pos[idx]
            self.window_gram[pos, idx] = gram[b, idx]
            self.window_rhs[pos, idx] = rhs[b, idx]
            self._window_pos[idx] = (pos + 1) % self._window
            self.window_fill[idx] = np.minimum(self.window_fill[idx] + 1, self._window)

    def restart(self, problems: np.ndarray, hold_blocks: int) -> None:
        """Restart the later memories of the given problems (bool (n,)) from the first one's
        sums; they forget like it for the next ``hold_blocks`` good blocks (so they are equal
        to it until then)."""
        self.info[1:, problems] = self.info[0, problems]
        self.rhs[1:, problems] = self.rhs[0, problems]
        self.n_eff[1:, problems] = self.n_eff[0, problems]
        self.hold[problems] = hold_blocks

    def good_blocks(self, count: np.ndarray) -> np.ndarray:
        """Blocks with enough valid samples."""
        return count >= self._min_count

    def rls(self) -> np.ndarray:
        """Current RLS coefficients (memories, n, p)."""
        return solve_normal(self.info, self.rhs)

    def batch(self) -> np.ndarray:
        """Batch LS coefficients over the window (n, p)."""
        return solve_normal(self.window_gram.sum(axis=0), self.window_rhs.sum(axis=0))


@dataclass(frozen=True)
class LsFamily:
    """Independent LS problems of one layout, solved together (vectorised).

    Problem p estimates the wheels ``wheels[p]``; wheel j of a problem takes the solution
    entries ``coef_index[j]`` (its raw [dK, dD]) times ``coef_sign[j]``.

    Kinds: 'wheel' (one wheel, regressors ``[th, th_dot]``), 'difference' (a driven axle, the
    paper's eq. 12-14) and 'partner' (a driven wheel, with its partner's lagged speed as
    nuisance regressors); see :class:`~tpms_ros.core.stiffness_observer.StiffnessObserverParams`.
    """

    kind: Literal['wheel', 'difference', 'partner']
    wheels: np.ndarray         # (P, q)
    coef_index: np.ndarray     # (q, 2)
    coef_sign: np.ndarray      # (q,)
    n_params: int

    def to_wheels(self, coef: np.ndarray, out: np.ndarray) -> None:
        """Write each wheel's raw [dK, dD] from solutions (..., P, n) into out (..., 4, 2)."""
        for j in range(self.wheels.shape[1]):
            out[..., self.wheels[:, j], :] = self.coef_sign[j] * coef[..., self.coef_index[j]]


def ls_families(axles: Sequence[tuple[int, int]], compensation: str,
                 n_lags: int) -> tuple[LsFamily, ...]:
    """The LS problems of the four wheels: every wheel in exactly one problem."""
    driven = [w for axle in axles for w in axle]
    plain = [[w] for w in range(N_TIRES) if w not in driven]
    families = []
    if plain:
        families.append(LsFamily('wheel', np.array(plain), np.array([[0, 1]]),
                                  np.array([1.0]), 2))
    if driven and compensation == 'difference':
        families.append(LsFamily('difference', np.array(axles), np.array([[0, 2], [1, 3]]),
                                  np.array([1.0, -1.0]), 4))
    elif driven:
        families.append(LsFamily('partner', np.array([[w] for w in driven]),
                                  np.array([[0, 1]]), np.array([1.0]), 2 + n_lags))
    return tuple(families)

