"""The unknown-input models of the suspension IMM, built once per speed and mode.

Full car: the track alignment under the four wheelsets as white noise through the published
alignment spectrum, with Pade delays between wheelsets (:func:`track_shaping_model`), and the
car driven by it (:func:`track_driven_model`). Half car: the wheelset motion as second-order
Gauss-Markov input combinations (:func:`primary_input_combination`,
:func:`input_shaped_model`). Each returns the exact discretisation (F, Q, H) of the augmented
state. No ROS import.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np
import scipy.linalg

from rail_monitor_ros.core.rail_model import REDUCED_INPUT_NAMES, RailVehicleParams, StateSpace
from rail_monitor_ros.core.track_spectra import TrackSpectrum

# Known inputs of the monitored bogie's two wheelsets (wheelset_inputs_from_track).
N_BOGIE_INPUTS = len(REDUCED_INPUT_NAMES)


def van_loan_discretization(a: np.ndarray, spectral: np.ndarray, dt: float,
                            ) -> tuple[np.ndarray, np.ndarray]:
    """(F, Q) of dx = A x dt + dw, E[dw dw^T] = spectral dt, over dt: Van Loan's one matrix
    exponential of [[-A, spectral], [0, A^T]] dt; Q symmetrised."""
    size = a.shape[0]
    van_loan = np.zeros((2 * size, 2 * size))
    van_loan[:size, :size] = -a
    van_loan[:size, size:] = spectral
    van_loan[size:, size:] = a.T
    e = scipy.linalg.expm(van_loan * dt)
    f = e[size:, size:].T
    q = f @ e[:size, size:]
    return f, 0.5 * (q + q.T)


def primary_input_combination(vehicle: RailVehicleParams,
                              input_names: Sequence[str]) -> np.ndarray:
    """The combinations through which a bogie's two wheelsets act on it: T, (2 per bogie, m).

    The primary springs put the wheelsets into the bogie equations only as
    2 Ky (y_lead + y_trail) / 2 (lateral) and Ky a0 (y_lead - y_trail) + Kp (psi_lead +
    psi_trail) (yaw), so per bogie the inputs are exactly u_lat = (y_lead + y_trail) / 2 and
    u_yaw = (Ky a0 (y_lead - y_trail) + Kp (psi_lead + psi_trail)) / (2 Kp), an equivalent
    wheelset yaw angle. ``input_names`` come in groups of four per bogie,
    [y_lead, y_trail, psi_lead, psi_trail] (``REDUCED_INPUT_NAMES`` order).
    """
    m = len(input_names)
    if m % N_BOGIE_INPUTS:
        raise ValueError(f'input_names must come in groups of {N_BOGIE_INPUTS}, got {m}')
    lever = (vehicle.primary_lateral_stiffness * vehicle.semi_wheelbase
             / (2.0 * vehicle.primary_yaw_stiffness))
    block = np.array([[0.5, 0.5, 0.0, 0.0], [lever, -lever, 0.5, 0.5]])
    return scipy.linalg.block_diag(*[block] * (m // N_BOGIE_INPUTS))


def input_shaped_model(model: StateSpace, combination: np.ndarray, combination_std: np.ndarray,
                     correlation_time: float, bandwidth_hz: float, dt: float,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of [x; w] with the input combinations w second-order Gauss-Markov.

    u enters only through w = T u (:func:`primary_input_combination`): B u = (B T^+) w exactly
    (checked). Each w_j has states [w_j, w_j'] and the spectrum of white noise through two
    first-order lags, poles 1 / tau and 2 pi f_b: flat below 1 / tau (long track
    wavelengths), -40 dB/decade above f_b like the wheelset motion, so its increments over a
    sample are smooth rather than white-noise steps. The noise density is set for the
    stationary std. Van Loan's matrix exponential gives F and Q together.

    Returns:
        (F, Q, H) with H = [C, D T^+ on the w positions].
    """
    t_pinv = np.linalg.pinv(combination)
    b_w = model.b @ t_pinv
    d_w = model.d @ t_pinv
    scale = max(float(np.abs(model.b).max()), 1.0)
    if not (np.allclose(b_w @ combination, model.b, atol=1e-9 * scale)
            and np.allclose(d_w @ combination, model.d, atol=1e-9 * scale)):
        raise ValueError('the model inputs do not enter through primary_input_combination')
    n, k = model.a.shape[0], combination.shape[0]
    w1, w2 = 1.0 / correlation_time, 2.0 * math.pi * bandwidth_hz
    size = n + 2 * k
    a_aug = np.zeros((size, size))
    a_aug[:n, :n] = model.a
    spectral = np.zeros((size, size))
    pos = n + 2 * np.arange(k)
    a_aug[:n, pos] = b_w
    a_aug[pos, pos + 1] = 1.0
    a_aug[pos + 1, pos] = -w1 * w2
    a_aug[pos + 1, pos + 1] = -(w1 + w2)
    spectral[pos + 1, pos + 1] = 2.0 * w1 * w2 * (w1 + w2) * combination_std ** 2
    f, q = van_loan_discretization(a_aug, spectral, dt)
    h = np.zeros((model.c.shape[0], size))
    h[:, :n] = model.c
    h[:, pos] = d_w
    return f, q, h


def _pade_section(tau: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(A, B, C, D) of the [2/2] Pade approximant of e^{-s tau}, in the section's own time.

    (1 - s tau/2 + (s tau)^2/12) / (1 + s tau/2 + (s tau)^2/12): all-pass (exact magnitude),
    phase error below 2 degrees for omega tau <= 2. With sigma = s tau it is
    1 - 12 sigma / (sigma^2 + 6 sigma + 12), realised in sigma (controllable form) and run at
    1 / tau: A and B scale with 1 / tau, C does not, and the states carry the input's unit.
    So A is linear in the speed (tau = distance / v), which the creep EKF's first-order step
    in speed relies on; in the controllable form in s the states scaled with tau^2 and the
    transition moved 1 % for a 0.05 m/s change of speed.
    """
    a = np.array([[0.0, 1.0], [-12.0, -6.0]]) / tau
    b = np.array([[0.0], [1.0]]) / tau
    c = np.array([[0.0, -12.0]])
    return a, b, c, 1.0


@dataclass(frozen=True)
class TrackShapingModel:
    """The track alignment under the wheelsets as the output of a linear system driven by
    white noise (see :func:`track_shaping_model`).

    Attributes:
        a: (n, n) state matrix.
        g: (n,) noise input vector (the noise has spectral density ``noise_density``).
        c: (k, n) alignment under each wheelset, front to rear.
        noise_density: white-noise spectral density, m^2 s^-3 (on the alignment rate state).
    """

    a: np.ndarray
    g: np.ndarray
    c: np.ndarray
    noise_density: float


def track_shaping_model(roughness: float, corner_wavenumber: float, long_wavenumber: float,
                        speed: float, offsets: Sequence[float] | np.ndarray,
                        delay_min_wavelength_m: float) -> TrackShapingModel:
    """Alignment under wheelsets at the given distances behind the first, at a speed.

    The alignment spectrum A Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2)) is white
    noise through two first-order lags in distance; at speed v the lags are in time with
    poles Omega_r v and Omega_c v, and the variance is the spectrum's integral
    pi A Omega_c / (2 Omega_r (Omega_r + Omega_c)), independent of v. The states are the
    alignment under the first wheelset and its rate. A wheelset d behind the previous one sees
    that alignment delayed by d / v: a cascade of [2/2] Pade sections of d / v / n each, n =
    ceil(pi d / delay_min_wavelength_m), so every section stays within omega tau <= 2 down to
    that wavelength at any speed (the state count does not change with speed).

    Args:
        roughness: A, m rad.
        corner_wavenumber: Omega_c, rad/m.
        long_wavenumber: Omega_r, rad/m.
        speed: v, m/s.
        offsets: distance of each wheelset behind the first, m, non-decreasing, first 0.
        delay_min_wavelength_m: shortest wavelength the delays are accurate for, m.
    """
    for name, value in (('roughness', roughness), ('corner_wavenumber', corner_wavenumber),
                        ('long_wavenumber', long_wavenumber), ('speed', speed),
                        ('delay_min_wavelength_m', delay_min_wavelength_m)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f'{name} must be finite and > 0, got {value}')
    d = np.asarray(offsets, dtype=float)
    if d.ndim != 1 or d.size < 1 or d[0] != 0.0 or np.any(np.diff(d) < 0.0):
        raise ValueError(f'offsets must start at 0 and not decrease, got {d}')
    r, c = long_wavenumber * speed, corner_wavenumber * speed
    variance = (math.pi * roughness * corner_wavenumber
                / (2.0 * long_wavenumber * (long_wavenumber + corner_wavenumber)))
    blocks_a = [np.array([[0.0, 1.0], [-r * c, -(r + c)]])]
    # Each block's input comes from the previous output row: a lower block-triangular A.
    outputs = [np.array([1.0, 0.0])]
    size = 2
    couplings: list[tuple[int, np.ndarray]] = []
    source = outputs[0]
    for gap in np.diff(d):
        n = max(1, math.ceil(math.pi * gap / delay_min_wavelength_m)) if gap > 0.0 else 0
        for _ in range(n):
            sa, sb, sc, sd = _pade_section(gap / speed / n)
            blocks_a.append(sa)
            couplings.append((size, sb[:, 0][:, None] * np.pad(source, (0, 2))[None, :]))
            out = np.zeros(size + 2)
            out[:size] = sd * source
            out[size:] = sc[0]
            size += 2
            source = out
        outputs.append(source)
    a = np.zeros((size, size))
    at = 0
    for block in blocks_a:
        k = block.shape[0]
        a[at:at + k, at:at + k] = block
        at += k
    for row, coupling in couplings:
        a[row:row + 2, :coupling.shape[1]] += coupling
    c_out = np.array([np.pad(o, (0, size - o.size)) for o in outputs])
    g = np.zeros(size)
    g[1] = 1.0
    return TrackShapingModel(a, g, c_out, 2.0 * r * c * (r + c) * variance)


def map_error_roughness(roughness: float, corner_wavenumber: float, long_wavenumber: float,
                        error_rms: float, max_wavelength: float) -> float:
    """Roughness A of a track map's error with the alignment spectrum's shape and an rms of
    ``error_rms`` over wavelengths up to ``max_wavelength`` (m): the error spectrum is the
    track's times error_rms^2 / (the track's variance in that band).

    The band matters: the spectrum's variance is mostly at wavelengths of hundreds of metres,
    which a map's stated accuracy does not cover and the vehicle does not feel. Scaled to the
    whole spectrum's variance, a 0.3 mm map would be modelled 2.1 times too accurate in the
    band of the vehicle's modes (the German spectra up to 120 m).
    """
    if not (math.isfinite(error_rms) and error_rms > 0.0):
        raise ValueError(f'error_rms must be finite and > 0, got {error_rms}')
    spectrum = TrackSpectrum('track', roughness, corner_wavenumber, long_wavenumber)
    # The shortest wavelengths carry a negligible share; 1 mm stands for zero.
    band_variance = spectrum.variance(1e-3, max_wavelength)
    return roughness * error_rms ** 2 / band_variance


def track_driven_matrix(model: StateSpace, track: TrackShapingModel) -> np.ndarray:
    """The continuous A of [x; track states]: the car driven by the track model's outputs."""
    n, k = model.a.shape[0], track.a.shape[0]
    a_aug = np.zeros((n + k, n + k))
    a_aug[:n, :n] = model.a
    a_aug[:n, n:] = model.b @ track.c
    a_aug[n:, n:] = track.a
    return a_aug


def track_driven_model(model: StateSpace, track: TrackShapingModel, dt: float,
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact discretisation of [x; track states] with the track noise (Van Loan).

    Returns:
        (F, Q, H) with H the sensor rows over the augmented state.
    """
    g = np.concatenate([np.zeros(model.a.shape[0]), track.g])
    f, q = van_loan_discretization(track_driven_matrix(model, track),
                                   track.noise_density * np.outer(g, g), dt)
    return f, q, np.hstack([model.c, model.d @ track.c])
