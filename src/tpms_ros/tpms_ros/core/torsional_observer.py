"""Reduced-order disturbance observer of the tire stiffness method (Umeno et al. 1997, eq. 5-8)
and its model-consistency map; :mod:`tpms_ros.core.stiffness_observer` runs the chain.

The two-inertia model of :class:`~tpms_ros.core.tire_model.TorsionalTire`
is extended by the disturbance ``w = dK th + dD th_dot - T_d`` acting on the belt equation
and modelled as constant (eq. 6), giving the state ``[w1 | w2, th, w]`` (eq. 7). A Gopinath
reduced-order observer estimates the unmeasured states ``x_b = [w2, th, w]`` from the measured
one, ``x_a = w1`` (filterpy's words: state ``x = [x_a | x_b]``, measurement ``z = w1``)::

    x_b_hat = v + G w1,   v' = F v + (F G + A21 - G A11) w1,   F = A22 - G A12

which is eq. 8's structure: ``w1'`` is used implicitly through ``G w1``, never differentiated.
``G`` puts the eigenvalues of ``F`` on a Butterworth pattern of radius
``observer_pole_factor`` x the model resonance (``scipy.signal.place_poles``). The observer is
LTI, so it is discretised with the **bilinear (Tustin) transform** (stable for any stable
continuous design, no half-sample delay on the sampled input; the 0.5 % frequency warping at
40 Hz / 1 kHz is common to every tire and cancels in the calibration) and run as one
transfer function per output (``scipy.signal.lfilter`` with carried ``zi``) on the band-passed
wheel speed. The drive torque on the rim is not fed to the observer: it varies far below the
25-60 Hz band, which the pre-filter removes; it is used for gating only.

**Model-consistency correction.** The paper estimates only the belt-row disturbance (the
rim row also carries ``-dK th``, but with one measurement the two are not separable), and the
band-pass colours ``T_d`` so that it correlates with ``zeta``. Both bias the raw LS
coefficient: with the default design it reads about -2000 N m/rad on a nominal tire and
moves about 1.3x the true dK. Under the paper's own assumption (white road torque) the
expected raw coefficient for a true stiffness ``K`` follows from the estimator's model and
filters alone (frequency-domain Gram matrices); that monotone map is inverted, so
``stiffness`` is an estimate of the true K and ``delta_k = stiffness - K_model``. The
calibration then removes what is left (road spectrum not white, sensor noise, model error).

No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.signal as sig

from tpms_ros.core.tire_model import TorsionalTire


@dataclass(frozen=True)
class ObserverDesign:
    """Continuous and discrete reduced-order disturbance observer for one tire model.

    Attributes:
        gain: observer gain G, (3,) for the unmeasured states x_b = [w2, th, w].
        error_matrix: ``A'22 - G A'12`` (eq. 8); its eigenvalues are the observer poles.
        numerators: (3, n+1) discrete numerators for the outputs [th, th_dot, w] from w1.
        denominator: (n+1,) common discrete denominator.
    """

    gain: np.ndarray
    error_matrix: np.ndarray
    numerators: np.ndarray
    denominator: np.ndarray


def extended_system(tire: TorsionalTire) -> tuple[np.ndarray, np.ndarray]:
    """Extended system of eq. 7: state [w1, w2, th, w], w constant, acting like -T_d.

    Returns:
        (A_ext (4, 4), B_ext (4, 1)) with the rim torque as the only input (eq. 7's B').
    """
    a, b = tire.state_space()
    a_ext = np.zeros((4, 4))
    a_ext[:3, :3] = a
    # w = dK th + dD th_dot - T_d enters where -T_d does: minus the road-torque input column.
    a_ext[:3, 3] = -b[:, 1]
    b_ext = np.zeros((4, 1))
    b_ext[:3, 0] = b[:, 0]
    return a_ext, b_ext


def design_observer(tire: TorsionalTire, pole_factor: float,
                    sample_rate_hz: float) -> ObserverDesign:
    """Gopinath observer for x_b = [w2, th, w] from the measurement z = w1, discretised by the
    bilinear transform.

    Args:
        tire: the estimator's nominal model.
        pole_factor: observer pole radius as a multiple of the model resonance.
        sample_rate_hz: sample rate of the discrete filters.

    Returns:
        The design; outputs are ordered [th, th_dot = w1 - w2_hat, w].
    """
    radius = 2.0 * np.pi * pole_factor * tire.resonance_hz
    if not radius < np.pi * sample_rate_hz:
        raise ValueError(f'observer_pole_factor {pole_factor} puts the observer poles at '
                         f'{radius / 2 / np.pi:.1f} Hz, above the Nyquist frequency '
                         f'{sample_rate_hz / 2} Hz')
    a_ext, _ = extended_system(tire)
    a11 = a_ext[:1, :1]
    a12 = a_ext[:1, 1:]
    a21 = a_ext[1:, :1]
    a22 = a_ext[1:, 1:]
    # Third-order Butterworth pattern: distinct poles (place_poles needs them distinct for a
    # single measured output) with 50 % damping for the complex pair, so no ringing.
    poles = radius * np.array([-1.0, np.exp(1j * 2 * np.pi / 3), np.exp(-1j * 2 * np.pi / 3)])
    placed = sig.place_poles(a22.T, a12.T, poles)
    gain = placed.gain_matrix.T  # (3, 1): duality, eig(A22 - G A12) = eig(A22^T - A12^T G^T)
    error_matrix = a22 - gain @ a12
    input_matrix = error_matrix @ gain + a21 - gain @ a11
    # x_b_hat = v + G w1; outputs th = x_b[1], th_dot = w1 - x_b[0], w = x_b[2].
    select = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    c_out = select
    d_out = select @ gain + np.array([[0.0], [1.0], [0.0]])
    ad, bd, cd, dd, _ = sig.cont2discrete((error_matrix, input_matrix, c_out, d_out),
                                          1.0 / sample_rate_hz, method='bilinear')
    numerators, denominator = sig.ss2tf(ad, bd, cd, dd)
    return ObserverDesign(gain[:, 0], error_matrix, np.asarray(numerators),
                          np.asarray(denominator))


@dataclass(frozen=True)
class ConsistencyMap:
    """Expected raw LS coefficients vs true stiffness for one model and filter design.

    Attributes:
        stiffness: (M,) true K grid, increasing, N m/rad.
        raw_dk: (M,) expected raw dK coefficient at each K (increasing over the grid).
        raw_dd: (M,) expected raw dD coefficient at each K (model damping).
    """

    stiffness: np.ndarray
    raw_dk: np.ndarray
    raw_dd: np.ndarray

    def stiffness_from_raw(self, raw_dk: np.ndarray) -> np.ndarray:
        """Invert the map (clipped to the grid); NaN stays NaN."""
        return np.interp(raw_dk, self.raw_dk, self.stiffness)

    def expected_raw_dd(self, stiffness: np.ndarray) -> np.ndarray:
        """Expected raw dD coefficient at the given K with the model damping."""
        return np.interp(stiffness, self.stiffness, self.raw_dd)


def consistency_map(tire: TorsionalTire, design: ObserverDesign, band_sos: np.ndarray,
                    sample_rate_hz: float, n_freq: int = 16384) -> ConsistencyMap:
    """Expected LS coefficients under white road torque for true K over 0.25..3 x K_model.

    All regressors and the target are filters of the same wheel speed, so their covariances
    are ``integral |P_K|^2 |BP|^2 Re(O_i conj O_j)`` over frequency, with P_K the road-torque to
    wheel-speed response of a tire with stiffness K, BP the band-pass and O the observer.
    Only |P_K| matters (phase cancels), so the continuous response is used.
    """
    omega_d = np.linspace(0.0, np.pi, n_freq)[1:]
    _, band_resp = sig.sosfreqz(band_sos, worN=omega_d)
    obs_resp = np.stack([sig.freqz(num, design.denominator, worN=omega_d)[1]
                         for num in design.numerators], axis=1)  # (F, 3)
    filt = band_resp[:, None] * obs_resp
    cross = np.real(filt.conj()[:, :, None] * filt[:, None, :]).reshape(len(omega_d), 9)
    stiffness = tire.k * np.geomspace(0.25, 3.0, 161)
    weights = np.empty((stiffness.size, omega_d.size))
    for i, k in enumerate(stiffness):
        a, b = TorsionalTire(tire.j1, tire.j2, float(k), tire.d).state_space()
        num, den = sig.ss2tf(a, b[:, 1:2], np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 1)))
        _, resp = sig.freqs(num[0], den, worN=omega_d * sample_rate_hz)
        weights[i] = np.abs(resp) ** 2
    gram = (weights @ cross).reshape(stiffness.size, 3, 3)
    coef = np.linalg.solve(gram[:, :2, :2], gram[:, :2, 2:3])[:, :, 0]
    raw_dk, raw_dd = coef[:, 0], coef[:, 1]
    # Keep the monotone branch through the model stiffness so the inverse is unique.
    increasing = np.diff(raw_dk) > 0
    centre = int(np.argmin(np.abs(stiffness - tire.k)))
    lo = centre
    while lo > 0 and increasing[lo - 1]:
        lo -= 1
    hi = centre
    while hi < increasing.size and increasing[hi]:
        hi += 1
    keep = slice(lo, hi + 1)
    return ConsistencyMap(stiffness[keep], raw_dk[keep], raw_dd[keep])

