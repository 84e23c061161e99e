"""Wheel-rail creep factor by an augmented-state EKF (Chonan & Tsunashima; SPEC §6). No ROS.

Estimation model: the 7-DOF half car of :func:`rail_monitor_ros.rail_model.half_car_state_space`
(two wheelsets lateral + yaw, bogie lateral + yaw, body lateral), with the creep factor c (f11
and f22 scaled together) appended to the state as a random walk (the paper's eq. 11)::

    z = [x (14), y_r1, y_r2, theta],   theta = ln c
    x[k+1] = F(c) x[k] + G(c) u[k],    u = [y_r1, y_r2] (track alignment at the two wheelsets)
    u[k+1] = u[k] + w_u,               theta[k+1] = theta[k] + w_theta

Choices and why:

* **ln c as the state**: c stays positive without a constraint, and a random walk in ln c is a
  relative change, which is how adhesion drops (a 60 % loss is as fast from c = 1 as a 60 % loss
  from c = 0.5). The output std of c is c sqrt(P_theta) (delta method). ln c is also clipped to
  [min_creep_factor, max_creep_factor]: each clip is counted, and an estimate pinned to a bound
  for ``bound_hold_s`` counts as divergence (reset and reported), so the clip never hides it.
* **Track input as states**: the track alignment u is part of the state, a random walk whose
  step follows the track's slope at the current speed. When ``/rail/track_irregularity`` is
  given (the paper's known-input setup), it is observed with ``track_noise`` in the same update
  as the vehicle measurements, so u follows it within that noise; when it is missing or stale,
  the same filter runs on, u is then process noise (unknown-input mode) and its variance grows.
  One filter covers both modes and switches between them without a transient.
* **Exact discretisation with a cache**: A(c) = A0 + c dA and B(c) = c dB exactly (the creep
  forces are linear in c), so F, G and their exact derivatives dF/dc, dG/dc come from one
  Frechet derivative of the matrix exponential (:func:`discretize_zoh_sensitivity`). They are
  computed at grid points c_k spaced ``rediscretize_tolerance`` apart in ln c and cached;
  between grid points F(c) = F(c_k) + (c - c_k) dF(c_k) (first-order Taylor, error of order
  (tolerance c)^2 d2F/dc2, far below the process noise). The Jacobian is that of the
  transition actually used, so the filter is consistent with its own model.
* **Covariance**: Joseph-form update plus symmetrisation keeps P symmetric positive definite.
* **Bad samples**: non-finite or wrongly sized measurements are rejected and counted; time still
  advances (prediction only), so the state is not corrupted. A measurement with an innovation
  beyond ``gate_sigma`` standard deviations in any channel is rejected as an outlier. A
  divergence detector (innovation consistency over a window, a run of outliers, or the
  estimate pinned at a bound) resets the filter and counts the reset with its reason.

Observation patterns (SPEC §6): 'A' wheelset, bogie and body lateral/yaw states, 'B' bogie
lateral and yaw with rates and body lateral with rate, 'C' bogie and body lateral displacement
and velocity, 'D' the IMU only (bogie lateral acceleration, bogie yaw rate, body lateral
acceleration). The body measurement is the car body above the monitored bogie (y_v +/- lv psi_v
from RailLateralStates), which is what the half car's body stands for.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg.lapack import dposv as _cholesky_solve

from rail_monitor_ros.rail_model import (
    MAX_CREEP_FACTOR,
    OBSERVATION_PATTERNS,
    RailVehicleParams,
    discretize_zoh_sensitivity,
    half_car_creep_sensitivity,
    half_car_state_space,
)

if TYPE_CHECKING:
    from rail_monitor_ros.rail_simulator import RailSimulationResult

N_X = 14           # half-car states
N_U = 2            # track alignment at the leading and trailing wheelset
I_THETA = N_X + N_U
N_Z = I_THETA + 1  # augmented state size
BOGIES = ('front', 'rear')

# Kind of each measured channel per pattern: selects its noise parameter.
_PATTERN_KINDS = {
    'A': ('displacement', 'velocity', 'yaw', 'yaw_rate') * 3 + ('body', 'body_rate'),
    'B': ('displacement', 'velocity', 'yaw', 'yaw_rate', 'body', 'body_rate'),
    'C': ('displacement', 'velocity', 'body', 'body_rate'),
    'D': ('accel', 'gyro', 'accel'),
}
PATTERN_SIZES = {pattern: len(kinds) for pattern, kinds in _PATTERN_KINDS.items()}


@dataclass(frozen=True)
class CreepEkfParams:
    """Settings of the creep-factor EKF. Model parameters are the estimator's own (Table 1).

    Attributes:
        vehicle: the estimation model's vehicle parameters (speed = nominal speed).
        pattern: observation pattern 'A', 'B', 'C' or 'D'.
        sample_rate_hz: measurement rate, Hz.
        initial_creep_factor: c at start and after a reset.
        initial_log_creep_std: initial standard deviation of ln c.
        creep_walk_std: random-walk intensity of ln c, 1/sqrt(s): how fast c may change. The
            default lets the filter follow a halving of c within a fraction of a second.
        min_creep_factor: lower bound of c (clip, counted).
        max_creep_factor: upper bound of c (clip, counted), at most the model's 2.0.
        lateral_accel_process_std: model error as white lateral acceleration on the wheelsets
            and the bogie, m/s^2 (unmodelled forces).
        yaw_accel_process_std: the same on the yaw coordinates, rad/s^2.
        body_accel_process_std: the same on the body, m/s^2. Larger: the half car's body
            ignores the other bogie and the body yaw of the real car, the largest model error.
        track_slope_std: standard deviation of the track alignment's slope, rad: the track
            states' random walk has a step std of track_slope_std * speed * dt.
        initial_track_std: initial standard deviation of the track alignment states, m.
        displacement_noise: measurement noise std of lateral displacements, m.
        velocity_noise: of lateral velocities, m/s.
        yaw_noise: of yaw angles, rad.
        yaw_rate_noise: of yaw rates in patterns A-B, rad/s.
        accel_noise: of the lateral accelerometers (pattern D), m/s^2.
        gyro_noise: of the bogie yaw-rate gyro (pattern D), rad/s.
        track_noise: of the measured track alignment (known-input mode), m.
        rediscretize_tolerance: spacing of the cached discretisation grid in ln c.
        speed_tolerance: a speed change beyond this rebuilds the model, m/s.
        cache_size: most discretisations kept.
        gate_sigma: an innovation beyond this many standard deviations in any channel rejects
            the sample as an outlier.
        divergence_window_s: averaging time of the innovation consistency test, s.
        divergence_nis_ratio: the test fires when the averaged NIS / (channels) exceeds this.
        max_outlier_run_s: this long of consecutive outliers counts as divergence, s.
        bound_hold_s: the estimate pinned at a bound this long counts as divergence, s.
        low_adhesion_threshold: low_adhesion turns on when c falls below this.
        low_adhesion_hysteresis: and off when c rises above threshold + hysteresis.
    """

    vehicle: RailVehicleParams = field(default_factory=RailVehicleParams)
    pattern: str = 'C'
    sample_rate_hz: float = 200.0
    initial_creep_factor: float = 1.0
    initial_log_creep_std: float = 0.3
    creep_walk_std: float = 0.15
    min_creep_factor: float = 0.05
    max_creep_factor: float = MAX_CREEP_FACTOR
    lateral_accel_process_std: float = 0.5
    yaw_accel_process_std: float = 1.0
    body_accel_process_std: float = 0.5
    track_slope_std: float = 5e-4
    initial_track_std: float = 5e-3
    displacement_noise: float = 2e-4
    velocity_noise: float = 2e-3
    yaw_noise: float = 2e-4
    yaw_rate_noise: float = 2e-3
    accel_noise: float = 0.05
    gyro_noise: float = 2e-3
    track_noise: float = 2e-4
    rediscretize_tolerance: float = 0.01
    speed_tolerance: float = 0.05
    cache_size: int = 256
    gate_sigma: float = 10.0
    divergence_window_s: float = 1.0
    divergence_nis_ratio: float = 30.0
    max_outlier_run_s: float = 0.5
    bound_hold_s: float = 2.0
    low_adhesion_threshold: float = 0.5
    low_adhesion_hysteresis: float = 0.05

    def __post_init__(self) -> None:
        if not isinstance(self.vehicle, RailVehicleParams):
            raise ValueError('vehicle must be a RailVehicleParams')
        if self.pattern not in OBSERVATION_PATTERNS:
            raise ValueError(f'pattern must be one of {OBSERVATION_PATTERNS}, '
                             f'got {self.pattern!r}')
        positive = ('sample_rate_hz', 'initial_creep_factor', 'initial_log_creep_std',
                    'creep_walk_std', 'min_creep_factor', 'max_creep_factor',
                    'lateral_accel_process_std', 'yaw_accel_process_std',
                    'body_accel_process_std', 'track_slope_std',
                    'initial_track_std', 'displacement_noise', 'velocity_noise', 'yaw_noise',
                    'yaw_rate_noise', 'accel_noise', 'gyro_noise', 'track_noise',
                    'rediscretize_tolerance', 'speed_tolerance', 'gate_sigma',
                    'divergence_window_s', 'divergence_nis_ratio', 'max_outlier_run_s',
                    'bound_hold_s', 'low_adhesion_threshold')
        for name in positive:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be finite and > 0, got {value!r}')
        if not (self.low_adhesion_hysteresis >= 0.0
                and math.isfinite(self.low_adhesion_hysteresis)):
            raise ValueError('low_adhesion_hysteresis must be finite and >= 0, '
                             f'got {self.low_adhesion_hysteresis}')
        if not self.min_creep_factor < self.max_creep_factor <= MAX_CREEP_FACTOR:
            raise ValueError(f'need min_creep_factor < max_creep_factor <= {MAX_CREEP_FACTOR}, '
                             f'got {self.min_creep_factor}, {self.max_creep_factor}')
        if not self.min_creep_factor <= self.initial_creep_factor <= self.max_creep_factor:
            raise ValueError('initial_creep_factor must lie within [min_creep_factor, '
                             f'max_creep_factor], got {self.initial_creep_factor}')
        if not (isinstance(self.cache_size, int) and self.cache_size >= 1):
            raise ValueError(f'cache_size must be an integer >= 1, got {self.cache_size!r}')

    @property
    def dt(self) -> float:
        """Sample period, s."""
        return 1.0 / self.sample_rate_hz


@dataclass(frozen=True)
class CreepEstimate:
    """The filter's answer to one sample.

    Attributes:
        creep_factor: c estimate.
        std_dev: one-sigma uncertainty of c.
        f11: c * f11 nominal, N.
        f22: c * f22 nominal, N.
        low_adhesion: c below the threshold (with hysteresis).
        status: 'ok', 'predicted' (no usable measurement) or the rejection reason
            ('non_finite', 'wrong_shape', 'outlier').
        nis: normalised innovation squared of the update (NaN without update).
        reset: the divergence detector reset the filter at this sample.
    """

    creep_factor: float
    std_dev: float
    f11: float
    f22: float
    low_adhesion: bool
    status: str
    nis: float
    reset: bool


@dataclass(frozen=True)
class CreepRun:
    """An offline run over arrays.

    Attributes:
        pattern: observation pattern.
        time: (N,) s.
        creep_factor: (N,) estimate.
        std_dev: (N,) one-sigma.
        low_adhesion: (N,) flag.
        nis: (N,) NIS per sample (NaN without update).
        status: (N,) per-sample status strings.
        rejected: reason -> count.
        resets: reason -> count.
        discretizations: matrix-exponential evaluations made.
        true_creep_factor: (N,) ground truth when known, else None.
    """

    pattern: str
    time: np.ndarray
    creep_factor: np.ndarray
    std_dev: np.ndarray
    low_adhesion: np.ndarray
    nis: np.ndarray
    status: np.ndarray
    rejected: dict[str, int]
    resets: dict[str, int]
    discretizations: int
    true_creep_factor: np.ndarray | None = None


@dataclass(frozen=True)
class Discretization:
    """The discrete half car at one creep factor, inputs appended: x+ = [F G] [x; u].

    Attributes:
        creep_factor: c where it was evaluated.
        fg: (14, 16) [F G].
        dfg: (14, 16) [dF/dc dG/dc], exact (Frechet derivative of the matrix exponential).
    """

    creep_factor: float
    fg: np.ndarray
    dfg: np.ndarray


class _SpeedModel:
    """A0, dA, dB and the output matrices of the half car at one speed."""

    def __init__(self, params: CreepEkfParams, speed: float) -> None:
        vehicle = params.vehicle.with_speed(speed)
        self.speed = float(speed)
        nominal = half_car_state_space(vehicle, 1.0, pattern=params.pattern)
        self.da, self.db = half_car_creep_sensitivity(vehicle)
        self.a0 = nominal.a - self.da           # A(c) = A0 + c dA, B(c) = c dB, exactly
        half = half_car_state_space(vehicle, 0.5, pattern=params.pattern)
        # Output rows (pattern D: accelerations are rows of A) could depend on c; for the half
        # car they do not (the creep forces act on the wheelsets, the sensors sit on the bogie
        # and body), which the filter relies on: checked here rather than assumed.
        if not (np.allclose(nominal.c, half.c, rtol=0, atol=1e-12)
                and np.allclose(nominal.d, half.d, rtol=0, atol=1e-12)):
            raise ValueError(f'pattern {params.pattern}: outputs depend on the creep factor')
        self.h = nominal.c
        self.l = nominal.d  # noqa: E741 - the papers' name for the feedthrough


class CreepEkf:
    """Augmented-state EKF for the creep factor; one :meth:`step` per sample.

    Args:
        params: filter settings.
    """

    def __init__(self, params: CreepEkfParams | None = None) -> None:
        self.params = params if params is not None else CreepEkfParams()
        p = self.params
        self._dt = p.dt
        self._theta_bounds = (math.log(p.min_creep_factor), math.log(p.max_creep_factor))
        kinds = _PATTERN_KINDS[p.pattern]
        # The body above the bogie is y_v +/- lv psi_v: the body yaw's noise enters times lv
        # (1e-4 rad at lv = 9.5 m is 1 mm, five times the displacement noise).
        lv = p.vehicle.bogie_pivot_semi_spacing
        noise = {'displacement': p.displacement_noise, 'velocity': p.velocity_noise,
                 'yaw': p.yaw_noise, 'yaw_rate': p.yaw_rate_noise, 'accel': p.accel_noise,
                 'gyro': p.gyro_noise, 'body': math.hypot(p.displacement_noise, lv * p.yaw_noise),
                 'body_rate': math.hypot(p.velocity_noise, lv * p.yaw_rate_noise)}
        self._r_meas = np.array([noise[k] ** 2 for k in kinds])
        self._n_meas = len(kinds)
        self._cache: OrderedDict[int, Discretization] = OrderedDict()
        self.discretizations = 0
        self._model = _SpeedModel(p, p.vehicle.speed)
        self._build_observation()
        self._q_x = self._state_process_noise()
        self._jacobian = np.eye(N_Z)
        self._eye = np.eye(N_Z)
        self.rejected: dict[str, int] = {}
        self.resets: dict[str, int] = {}
        self.clipped = 0
        self.last_reset_reason = ''
        self._low_adhesion = False
        self.reset()

    # -- state ---------------------------------------------------------------------------------

    def reset(self, creep_factor: float | None = None) -> None:
        """Start over: half-car states 0, track states 0, c = creep_factor (or initial)."""
        p = self.params
        c0 = p.initial_creep_factor if creep_factor is None else float(creep_factor)
        if not p.min_creep_factor <= c0 <= p.max_creep_factor:
            raise ValueError(f'creep_factor must lie within [{p.min_creep_factor}, '
                             f'{p.max_creep_factor}], got {c0}')
        self.z = np.zeros(N_Z)
        self.z[I_THETA] = math.log(c0)
        # States start at rest with the spread of a running vehicle: a few mm, a few cm/s.
        scale = np.tile([5e-3, 5e-2], N_X // 2)
        self.P = np.diag(np.concatenate([scale ** 2, np.full(N_U, p.initial_track_std ** 2),
                                         [p.initial_log_creep_std ** 2]]))
        self._nis_average = 1.0
        self._outlier_run = 0
        self._pinned_run = 0

    @property
    def creep_factor(self) -> float:
        """Current estimate of c."""
        return math.exp(self.z[I_THETA])

    @property
    def std_dev(self) -> float:
        """One-sigma uncertainty of c (delta method on ln c)."""
        return self.creep_factor * math.sqrt(max(self.P[I_THETA, I_THETA], 0.0))

    @property
    def speed(self) -> float:
        """Speed of the current model, m/s."""
        return self._model.speed

    def set_speed(self, speed: float) -> None:
        """Use the model at another speed (rebuilt only beyond speed_tolerance)."""
        if not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f'speed must be finite and > 0, got {speed}')
        if abs(speed - self._model.speed) > self.params.speed_tolerance:
            self._model = _SpeedModel(self.params, speed)
            self._cache.clear()
            self._build_observation()
            self._q_x = self._state_process_noise()

    # -- model ---------------------------------------------------------------------------------

    def _build_observation(self) -> None:
        """H over z for the measurements alone, and stacked with the track observation."""
        m = self._model
        h = np.zeros((self._n_meas, N_Z))
        h[:, :N_X] = m.h
        h[:, N_X:I_THETA] = m.l
        h_track = np.zeros((N_U, N_Z))
        h_track[:, N_X:I_THETA] = np.eye(N_U)
        self._h = {False: h, True: np.vstack([h, h_track])}
        self._h_track = h_track
        self._r_track = np.full(N_U, self.params.track_noise ** 2)
        # Diagonal measurement noise, kept as vectors (added on the diagonal of S).
        self._r = {False: self._r_meas, True: np.concatenate([self._r_meas, self._r_track])}
        self._diag_index = {k: np.diag_indices(v.size) for k, v in self._r.items()}
        self._gate2 = self.params.gate_sigma ** 2

    def _state_process_noise(self) -> np.ndarray:
        """Constant process noise: white accelerations on the coordinates, track, ln c."""
        p, dt = self.params, self._dt
        q = np.zeros((N_Z, N_Z))
        # Discrete white-noise acceleration per coordinate (position, rate) pair.
        block = np.array([[dt ** 4 / 4.0, dt ** 3 / 2.0], [dt ** 3 / 2.0, dt ** 2]])
        names = half_car_state_space(p.vehicle).state_names
        for i in range(0, N_X, 2):
            if names[i] == 'y_v':
                sigma = p.body_accel_process_std
            elif 'psi' in names[i]:
                sigma = p.yaw_accel_process_std
            else:
                sigma = p.lateral_accel_process_std
            q[i:i + 2, i:i + 2] = block * sigma ** 2
        track_step = p.track_slope_std * self._model.speed * dt
        q[N_X:I_THETA, N_X:I_THETA] = np.eye(N_U) * track_step ** 2
        q[I_THETA, I_THETA] = p.creep_walk_std ** 2 * dt
        return q

    def discretization(self, creep_factor: float, exact: bool = False) -> Discretization:
        """(F, G, dF/dc, dG/dc) at a grid point near c (cached), or exactly at c."""
        if exact:
            return self._discretize(creep_factor)
        tol = self.params.rediscretize_tolerance
        key = round(math.log(creep_factor) / tol)
        entry = self._cache.get(key)
        if entry is None:
            entry = self._discretize(math.exp(key * tol))
            self._cache[key] = entry
            if len(self._cache) > self.params.cache_size:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        return entry

    def _discretize(self, c: float) -> Discretization:
        m = self._model
        f, g, df, dg = discretize_zoh_sensitivity(m.a0 + c * m.da, c * m.db, m.da, m.db,
                                                  self._dt)
        self.discretizations += 1
        return Discretization(c, np.hstack((f, g)), np.hstack((df, dg)))

    def transition(self, z: np.ndarray, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The augmented transition z -> f(z) and its Jacobian df/dz at z.

        Args:
            z: (17,) augmented state [x, y_r1, y_r2, ln c].
            exact: discretise exactly at c (no grid, no Taylor step), for checks.

        Returns:
            (f(z), Jacobian (17, 17)).
        """
        z = np.asarray(z, dtype=float)
        if z.shape != (N_Z,):
            raise ValueError(f'z must have shape ({N_Z},), got {z.shape}')
        z_next, jac = self._transition(z, exact)
        return z_next, jac.copy()

    def _transition(self, z: np.ndarray, exact: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`transition`, returning the internal Jacobian buffer (no copy)."""
        c = math.exp(z[I_THETA])
        d = self.discretization(c, exact)
        xu = z[:I_THETA]
        fg = d.fg + (c - d.creep_factor) * d.dfg
        jac = self._jacobian
        jac[:N_X, :I_THETA] = fg
        # d/d(ln c) = c d/dc; the derivative of the Taylor-stepped transition actually used.
        jac[:N_X, I_THETA] = c * (d.dfg @ xu)
        z_next = z.copy()
        z_next[:N_X] = fg @ xu
        return z_next, jac

    # -- filter --------------------------------------------------------------------------------

    def step(self, measurement: np.ndarray | None, track: np.ndarray | None = None,
             speed: float | None = None) -> CreepEstimate:
        """Update with the sample at time k, then predict to k + 1.

        Args:
            measurement: (p,) the pattern's measurement vector, or None when the sample is
                missing (prediction only).
            track: (2,) measured track alignment at the leading and trailing wheelset, m, or
                None (unknown-input mode for this sample). A non-finite track sample is
                ignored and counted.
            speed: forward speed, m/s, or None to keep the current model.

        Returns:
            The estimate after the update at time k.
        """
        if speed is not None:
            self.set_speed(speed)
        status = 'predicted'
        nis = math.nan
        y = None
        if measurement is not None:
            y = np.asarray(measurement, dtype=float)
            if y.shape != (self._n_meas,):
                status, y = self._reject('wrong_shape'), None
            elif not np.isfinite(y).all():
                status, y = self._reject('non_finite'), None
        u_meas = None
        if track is not None:
            u_meas = np.asarray(track, dtype=float)
            if u_meas.shape != (N_U,):
                self._reject('track_wrong_shape')
                u_meas = None
            elif not np.isfinite(u_meas).all():
                self._reject('track_non_finite')
                u_meas = None
        reset = False
        if y is not None:
            status, nis = self._update(y, u_meas)
            reset = self._check_divergence(status, nis)
        elif u_meas is not None:
            self._update_track(u_meas)
        estimate = self._estimate(status, nis, reset)
        self._predict()
        return estimate

    def _reject(self, reason: str) -> str:
        self.rejected[reason] = self.rejected.get(reason, 0) + 1
        return reason

    def _update(self, y: np.ndarray, u_meas: np.ndarray | None) -> tuple[str, float]:
        with_track = u_meas is not None
        obs = y if u_meas is None else np.concatenate((y, u_meas))
        h, r = self._h[with_track], self._r[with_track]
        hp = h @ self.P
        s = hp @ h.T
        s[self._diag_index[with_track]] += r
        innovation = obs - h @ self.z
        n = self._n_meas
        if (innovation[:n] ** 2 > self._gate2 * s.diagonal()[:n]).any():
            # The vehicle measurement is an outlier; the track sample (if any) is still used.
            if u_meas is not None:
                self._update_track(u_meas)
            return self._reject('outlier'), math.nan
        # One Cholesky solve (LAPACK dposv: S is SPD; numpy.linalg.solve costs 5x more in
        # call overhead at this size) gives the gain K = (S^-1 H P)^T and S^-1 innovation.
        _, solved, info = _cholesky_solve(s, np.column_stack((hp, innovation)))
        if info != 0:
            return self._reject('singular_innovation'), math.nan
        gain = solved[:, :N_Z].T
        nis = float(innovation @ solved[:, N_Z])
        self.z += gain @ innovation
        self._joseph(gain, hp, s)
        self._clip()
        return 'ok', nis / obs.size

    def _update_track(self, u_meas: np.ndarray) -> None:
        h, r = self._h_track, self._r_track
        hp = h @ self.P
        s = hp @ h.T + np.diag(r)
        _, solved, info = _cholesky_solve(s, hp)
        if info != 0:
            self._reject('singular_innovation')
            return
        gain = solved.T
        self.z += gain @ (u_meas - h @ self.z)
        self._joseph(gain, hp, s)
        self._clip()

    def _joseph(self, gain: np.ndarray, hp: np.ndarray, s: np.ndarray) -> None:
        """Joseph form (I - KH) P (I - KH)^T + K R K^T, expanded to save products.

        With A = K (H P): P - A - A^T + K S K^T, S = H P H^T + R; equal to the Joseph form for
        any gain, so P stays symmetric positive definite even if K is slightly off-optimal.
        The symmetrisation happens once per sample, after the prediction.
        """
        a = gain @ hp
        self.P = self.P - a - a.T + gain @ s @ gain.T

    def _clip(self) -> None:
        low, high = self._theta_bounds
        theta = self.z[I_THETA]
        if theta < low or theta > high:
            self.z[I_THETA] = min(max(theta, low), high)
            self.clipped += 1
            self._pinned_run += 1
        else:
            self._pinned_run = 0

    def _predict(self) -> None:
        self.z, jac = self._transition(self.z)
        self.P = jac @ self.P @ jac.T + self._q_x
        self.P = 0.5 * (self.P + self.P.T)

    def _check_divergence(self, status: str, nis_per_channel: float) -> bool:
        p = self.params
        alpha = min(1.0, self._dt / p.divergence_window_s)
        if status == 'outlier':
            self._outlier_run += 1
        else:
            self._outlier_run = 0
            self._nis_average += alpha * (nis_per_channel - self._nis_average)
        reason = ''
        if self._nis_average > p.divergence_nis_ratio:
            reason = 'innovation_inconsistent'
        elif self._outlier_run * self._dt > p.max_outlier_run_s:
            reason = 'outlier_run'
        elif self._pinned_run * self._dt > p.bound_hold_s:
            reason = 'pinned_at_bound'
        if not reason:
            return False
        self.resets[reason] = self.resets.get(reason, 0) + 1
        self.last_reset_reason = reason
        self.reset()
        return True

    def _estimate(self, status: str, nis: float, reset: bool) -> CreepEstimate:
        p = self.params
        c = self.creep_factor
        if self._low_adhesion:
            self._low_adhesion = c <= p.low_adhesion_threshold + p.low_adhesion_hysteresis
        else:
            self._low_adhesion = c < p.low_adhesion_threshold
        vehicle = p.vehicle
        return CreepEstimate(c, self.std_dev, c * vehicle.longitudinal_creep_coefficient,
                             c * vehicle.lateral_creep_coefficient, self._low_adhesion, status,
                             nis, reset)

    def run(self, measurements: np.ndarray, track: np.ndarray | None = None,
            speed: np.ndarray | None = None, time: np.ndarray | None = None,
            true_creep_factor: np.ndarray | None = None) -> CreepRun:
        """Filter a whole record, one sample per row (the recursion forces the loop).

        Args:
            measurements: (N, p) pattern measurements; rows with NaN are rejected and counted.
            track: (N, 2) track alignment at the two wheelsets, m, or None (unknown input).
            speed: (N,) m/s or None (the model's speed throughout).
            time: (N,) s; default k / sample_rate_hz.
            true_creep_factor: (N,) ground truth to keep with the run (for plots and metrics).
        """
        y = np.asarray(measurements, dtype=float)
        if y.ndim != 2 or y.shape[1] != self._n_meas:
            raise ValueError(f'measurements must have shape (N, {self._n_meas}) for pattern '
                             f'{self.params.pattern}, got {y.shape}')
        n = y.shape[0]
        u = None if track is None else np.asarray(track, dtype=float)
        if u is not None and u.shape != (n, N_U):
            raise ValueError(f'track must have shape ({n}, {N_U}), got {u.shape}')
        v = None if speed is None else np.broadcast_to(np.asarray(speed, dtype=float), (n,))
        t = np.arange(n) * self._dt if time is None else np.asarray(time, dtype=float)
        out_c, out_std, out_nis = np.empty(n), np.empty(n), np.empty(n)
        out_low = np.zeros(n, dtype=bool)
        out_status = np.empty(n, dtype=object)
        for k in range(n):
            est = self.step(y[k], None if u is None else u[k],
                            None if v is None else float(v[k]))
            out_c[k], out_std[k], out_nis[k] = est.creep_factor, est.std_dev, est.nis
            out_low[k], out_status[k] = est.low_adhesion, est.status
        truth = None if true_creep_factor is None else np.asarray(true_creep_factor, float)
        return CreepRun(self.params.pattern, t, out_c, out_std, out_low, out_nis, out_status,
                        dict(self.rejected), dict(self.resets), self.discretizations, truth)


# -- measurement assembly (shared by the node and the offline tools) ----------------------------

def lateral_states_measurement(states: Mapping[str, np.ndarray], pattern: str,
                               bogie: str = 'front',
                               body_pivot_offset: float = RailVehicleParams().
                               bogie_pivot_semi_spacing) -> np.ndarray:
    """Pattern A-C measurement rows from RailLateralStates fields.

    Args:
        states: field name -> array with first dimension N (the message's field names:
            ``wheelset_lateral`` (N, 4), ``bogie_lateral`` (N, 2), ``body_lateral`` (N,) ...).
        pattern: 'A', 'B' or 'C'.
        bogie: the monitored bogie, 'front' (wheelsets 1-2) or 'rear' (wheelsets 3-4).
        body_pivot_offset: lv, body centre to bogie centre, m: the body measurement is taken
            above the bogie, y_v +/- lv psi_v.

    Returns:
        (N, p) in the order of the half car's pattern states.
    """
    if pattern not in ('A', 'B', 'C'):
        raise ValueError(f"pattern must be 'A', 'B' or 'C' for lateral states, got {pattern!r}")
    if bogie not in BOGIES:
        raise ValueError(f'bogie must be one of {BOGIES}, got {bogie!r}')
    j = BOGIES.index(bogie)
    sign = 1.0 if j == 0 else -1.0

    def col(name: str, index: int | None = None) -> np.ndarray:
        if name not in states:
            raise ValueError(f'lateral states lack field {name!r}')
        values = np.asarray(states[name], dtype=float)
        return values if index is None else values[:, index]

    body = col('body_lateral') + sign * body_pivot_offset * col('body_yaw')
    body_rate = col('body_lateral_rate') + sign * body_pivot_offset * col('body_yaw_rate')
    bogie_cols = [col('bogie_lateral', j), col('bogie_lateral_rate', j)]
    bogie_yaw = [col('bogie_yaw', j), col('bogie_yaw_rate', j)]
    columns: list[np.ndarray] = []
    if pattern == 'A':
        for w in (2 * j, 2 * j + 1):
            columns += [col('wheelset_lateral', w), col('wheelset_lateral_rate', w),
                        col('wheelset_yaw', w), col('wheelset_yaw_rate', w)]
    columns += bogie_cols
    if pattern in ('A', 'B'):
        columns += bogie_yaw
    columns += [body, body_rate]
    return np.column_stack(columns)


def simulation_inputs(result: RailSimulationResult, pattern: str, bogie: str = 'front',
                      body_pivot_offset: float = RailVehicleParams().bogie_pivot_semi_spacing,
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(measurements (N, p), measured track (N, 2), speed (N,)) of a simulated run.

    The same conversion the node applies to the topics: patterns A-C from the noisy lateral
    states, D from the IMU signals (front bogie only: the simulator's IMUs are there).
    """
    from rail_monitor_ros.rail_simulator import _lateral_states_fields

    if pattern not in OBSERVATION_PATTERNS:
        raise ValueError(f'pattern must be one of {OBSERVATION_PATTERNS}, got {pattern!r}')
    if bogie not in BOGIES:
        raise ValueError(f'bogie must be one of {BOGIES}, got {bogie!r}')
    j = BOGIES.index(bogie)
    if pattern == 'D':
        if j != 0:
            raise ValueError('pattern D: the simulated IMUs are on the front bogie')
        y = np.column_stack([result.bogie_lateral_accel, result.bogie_yaw_rate,
                             result.body_lateral_accel])
    else:
        fields = _lateral_states_fields(result.measured_state, result.state_names)
        y = lateral_states_measurement(fields, pattern, bogie, body_pivot_offset)
    track = result.measured_track_alignment[:, 2 * j:2 * j + 2]
    return y, track, result.speed


def run_on_simulation(result: RailSimulationResult, params: CreepEkfParams,
                      known_input: bool = True, use_speed: bool = True,
                      bogie: str = 'front') -> CreepRun:
    """Run the EKF over a simulated run (truth kept for metrics and plots).

    Args:
        result: the simulation.
        params: filter settings (its own model parameters; the pattern selects the inputs).
        known_input: feed the measured track alignment (the paper's setup) or not.
        use_speed: follow the measured speed (else the model keeps params.vehicle.speed).
        bogie: 'front' or 'rear' (patterns A-C).
    """
    y, track, speed = simulation_inputs(result, params.pattern, bogie,
                                        params.vehicle.bogie_pivot_semi_spacing)
    return CreepEkf(params).run(y, track if known_input else None,
                                speed if use_speed else None, result.time,
                                result.creep_factor)


# -- evaluation -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class StepMetrics:
    """Tracking of one segment of constant true c after a change.

    Attributes:
        time: when the true c changed, s.
        value: the true c after the change.
        settling_time: from the change until the estimate stays within tolerance of the truth
            to the end of the segment, s (inf if never).
        max_error_after_window: largest |c_hat - c| / c from change + window to the segment end.
        steady_error: mean (c_hat - c) / c over the last ``steady_s`` of the segment.
    """

    time: float
    value: float
    settling_time: float
    max_error_after_window: float
    steady_error: float


def step_metrics(run: CreepRun, tolerance: float = 0.05, window_s: float = 1.0,
                 steady_s: float = 2.0) -> list[StepMetrics]:
    """Settling and errors after each change of the true creep factor (steps only).

    Segments run from one change of the truth to the next (or the end).
    """
    if run.true_creep_factor is None:
        raise ValueError('the run has no true_creep_factor')
    truth = run.true_creep_factor
    changes = np.flatnonzero(np.abs(np.diff(truth)) > 1e-9) + 1
    bounds = np.append(changes, truth.size)
    rel = (run.creep_factor - truth) / truth
    metrics = []
    for start, end in zip(bounds[:-1], bounds[1:], strict=True):
        t = run.time[start:end]
        err = rel[start:end]
        outside = np.flatnonzero(np.abs(err) > tolerance)
        if outside.size == 0:
            settle = 0.0
        elif outside[-1] == err.size - 1:
            settle = math.inf
        else:
            settle = float(t[outside[-1] + 1] - run.time[start])
        after = t >= run.time[start] + window_s
        steady = t >= t[-1] - steady_s
        metrics.append(StepMetrics(
            float(run.time[start]), float(truth[start]), settle,
            float(np.max(np.abs(err[after]))) if after.any() else math.nan,
            float(np.mean(err[steady]))))
    return metrics


def plot_creep(runs: Mapping[str, CreepRun], path: str | Path, title: str = '') -> Path:
    """Paper Figs. 7-9 style: estimated vs true creep factor, one panel per run.

    Each panel shows the estimate with its +/- 2 sigma band, the truth, and the +/- 5 % band
    around the truth. Writes a PNG.

    Args:
        runs: label -> run (e.g. 'pattern A' -> ...).
        path: PNG path.
        title: figure title.

    Returns:
        The path written.
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    if not runs:
        raise ValueError('runs must not be empty')
    path = Path(path)
    fig, axes = plt.subplots(len(runs), 1, figsize=(8.0, 2.4 * len(runs)), sharex=True,
                             squeeze=False)
    for ax, (label, run) in zip(axes[:, 0], runs.items(), strict=True):
        ax.fill_between(run.time, 100 * (run.creep_factor - 2 * run.std_dev),
                        100 * (run.creep_factor + 2 * run.std_dev), color='C0', alpha=0.2,
                        lw=0, label='±2σ')
        if run.true_creep_factor is not None:
            ax.fill_between(run.time, 95 * run.true_creep_factor, 105 * run.true_creep_factor,
                            color='0.8', lw=0, label='truth ±5 %')
            ax.plot(run.time, 100 * run.true_creep_factor, 'k--', lw=1.2, label='true')
        ax.plot(run.time, 100 * run.creep_factor, 'C0', lw=1.0, label='EKF estimate')
        ax.set_ylabel('creep factor, %')
        ax.set_title(label, fontsize=10)
        ax.set_ylim(0, 140)
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc='upper right', fontsize=8, ncol=4)
    axes[-1, 0].set_xlabel('time, s')
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
