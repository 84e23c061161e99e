"""``scipy.signal.sosfilt`` and ``lfilter`` along axis 0 with carried state, compiled (numba).

Why compiled: the tire stiffness observer runs a low-pass, a band-pass and three observer
filters per axle group on every chunk, twice with the encoder's synthetic noise: sixteen
scipy calls of 15-80 us each, most of it argument checks and dispatch, about a fifth of a
chunk's cost. Its outputs are answered one chunk late by that much (the node's latency).
Here each filter is one call that only loops.

Every operation is scipy's, in scipy's order and without fast-math (``sosfilt``: transposed
direct form II per section; ``lfilter``: transposed direct form II with the coefficients
divided by ``a[0]`` first), so the results are scipy's to the bit on this project's machines
(test/tpms_ros/core/test_filter_kernels.py holds them to rounding: a compiler that fuses
multiply-adds in one of them may differ in the last bit).
"""

from __future__ import annotations

from numba import njit, types
import numpy as np

_F1, _F2, _F3 = types.float64[:], types.float64[:, :], types.float64[:, :, :]


@njit(types.void(_F2, _F2, _F3, _F2), cache=True, error_model='numpy')
def sosfilt_columns(sos: np.ndarray, x: np.ndarray, zi: np.ndarray, y: np.ndarray) -> None:
    """``y, zi = scipy.signal.sosfilt(sos, x, axis=0, zi=zi)``, the state updated in place.

    Args:
        sos: (sections, 6) second-order sections.
        x: (n, columns) input; y: (n, columns) output (may be ``x``).
        zi: (sections, 2, columns) filter state.
    """
    for c in range(x.shape[1]):
        for i in range(x.shape[0]):
            value = x[i, c]
            for s in range(sos.shape[0]):
                out = sos[s, 0] * value + zi[s, 0, c]
                zi[s, 0, c] = sos[s, 1] * value - sos[s, 4] * out + zi[s, 1, c]
                zi[s, 1, c] = sos[s, 2] * value - sos[s, 5] * out
                value = out
            y[i, c] = value


@njit(types.void(_F1, _F1, _F2, _F2, _F2), cache=True, error_model='numpy')
def lfilter_columns(b: np.ndarray, a: np.ndarray, x: np.ndarray, zi: np.ndarray,
                    y: np.ndarray) -> None:
    """``y, zi = scipy.signal.lfilter(b, a, x, axis=0, zi=zi)``, the state updated in place.

    Args:
        b, a: numerator and denominator of one length (:func:`normalised`).
        x: (n, columns) input; y: (n, columns) output.
        zi: (len(b) - 1, columns) filter state.
    """
    order = b.shape[0] - 1
    for c in range(x.shape[1]):
        for i in range(x.shape[0]):
            value = x[i, c]
            if order == 0:
                y[i, c] = value * b[0]
                continue
            out = zi[0, c] + b[0] * value
            for k in range(order - 1):
                zi[k, c] = zi[k + 1, c] + value * b[k + 1] - out * a[k + 1]
            zi[order - 1, c] = value * b[order] - out * a[order]
            y[i, c] = out


def normalised(b: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(b, a) as :func:`lfilter_columns` takes them: padded with zeros to one length and
    divided by ``a[0]``, as scipy's ``lfilter`` does before filtering."""
    b = np.atleast_1d(np.asarray(b, dtype=float))
    a = np.atleast_1d(np.asarray(a, dtype=float))
    size = max(b.size, a.size)
    b = np.concatenate((b, np.zeros(size - b.size)))
    a = np.concatenate((a, np.zeros(size - a.size)))
    return b / a[0], a / a[0]
