"""Tire lateral force observer: scaled Kalman filter with model error compensator (SKFMEC).

Kim & Huh (2000), docs/methods/lateral_force_observer.md. No ROS import: the node converts
messages to the arrays used
here. Wheel order FL, FR, RL, RR; frame x forward, y left, z up (REP 103), so a left turn gives
positive lateral acceleration, yaw rate and roll angle (the right side goes down).

Monitoring model (paper eq. 29-37), state x = [vx, vy, r, phi, p, Fyf, Fyr] where Fyf and Fyr are
the *average per-tire* lateral forces of the front and rear axle (the paper's definition)::

    E x' = [SFx + m r vy - ms e p r,  SFy - m r vx,  SMz,  p,  SMx + ms e r vx,  z1 p,  z2 p]

with the sums of the Appendix: front forces rotated by the steer angle d, per-wheel lateral
forces from the load split (relation 2, ``split_lateral``) and::

    SMx = hf (front lateral sum) + hr (rear lateral sum) - kphi phi - cphi p + ms g e sin(phi)

The last term (gravity acting on the rolled sprung mass) is not in the paper; it is the standard
roll equation and costs nothing. Relation 1 (Fyf = z1 phi) gives Fyf' = z1 p; z1, z2 are the
steady-state ratios Fy/phi of this same model (see ``ObserverVehicleParams.zeta``) so that the
model is self-consistent; the paper treats them as constants read off its Fig. 3.

Longitudinal tire forces come from the wheel equation Fxi = (Ti - Iw wi')/rw with wi' from a
first-order filtered differentiator s/(tau s + 1) (bilinear transform, tau = 20 ms by default).
Vertical loads come from Smith & Starkey (paper eq. 39), written from a roll moment balance with
the half tracks tf, tr (the paper's transfer term divides by 2 tf, which halves the transfer
when tf is the half track as its nomenclature says)::

    Fz(FL,FR) = m g lr/(2 l) - m h ax/(2 l) -/+ [kf/(kf+kr) (m h ay + ms g e sin phi)/(2 tf)
                + Gy_f (ay - ay_hat)]

and the rear likewise with lf, +ax, kr/(kf+kr), tr and Gy_r.

Measurements z = [ax, ay, r, p] (paper) plus vx from the mean wheel speed times rw (added: the
paper's measurements leave vx unobservable; vy stays unobservable but feeds nothing back into the
forces, roll or yaw). ax_hat = SFx/m, ay_hat = SFy/m + g sin(phi): the specific force of the
centre of mass as an IMU fixed to the rolling body reads it (``imu_gravity_tilt``).

Filter (paper eq. 26-28): an EKF on the scaled state x* = S x, F* = S F S^-1, H* = H S^-1, with
the model error compensator added to the correction (eq. 21, 38)::

    x*+ = x*- + K y + dt Gp (r - r_hat),  y = z - h(x*-)   (Gp acts on Fyf*, Fyr* only)

and Gy (ay - ay_hat) added to the lateral load transfer. Discretisation at each sample of length
dt: state x*(k+1) = x* + dt (I + A* dt/2) g(x*), i.e. a second-order (linearised Heun) step of
the continuous model g = S E^-1 f; transition Phi = I + A* dt + (A* dt)^2/2; process noise
Qd = Q* dt (Q* a continuous spectral density in scaled units). Covariance update in Joseph form,
then symmetrised; a covariance that loses positive definiteness resets the filter (counted).

Relation 2, the left/right split: the paper's Fyi/Fyf = Fzi/Fzf (``split_exponent`` 1)
overstates the split on real tires, whose cornering stiffness grows less than in proportion to
load (load sensitivity): both wheels of an axle run at nearly the same slip angle, so in the
linear range Fyi ~ C(Fzi). The improvement (default) splits by Fzi^b with b the local load
exponent of the tire's cornering stiffness at the car's static wheel load. For a PAC2002 tire,
C ~ sin(2 atan(Fz / (pKy2 Fz0))) gives b = (pKy2^2 - 1)/(pKy2^2 + 1) at the nominal load Fz0
(0.6 for the CommonRoad passenger-car tire, pKy2 = 2.0012); for the Bakker-Nyborg-Pacejka
tire, C = a3 sin(a4 atan(a5 Fz)), ``offline.lateral_force_tuning.split_exponent_from_tire``
gives it, and the default 0.2 is that tire's (the simulator's) under this model's car (1814 kg:
4.45 kN a wheel, b = 0.195). The same tire under a heavier car has a smaller b (0 from 5.6 kN),
so b belongs to the car as much as to the tire: a user takes it from the own tire's data at
the own car's load (on the family of cars, the paper's manoeuvre with the default 0.6 is within
10 % on 9 of 16 tuning cars, with the tire's b on 15 of 16; docs/methods/
lateral_force_observer.md). Near saturation the split tends back towards proportional (D ~ Fz).

Two filters, an IMM: the paper's filter, tuned for its worst case (a friction drop in a
braking turn), gives the forces a process noise that lets them follow the gyro's noise in
ordinary driving (a 2-4 mrad/s yaw-rate noise made 50-130 N of force noise, 14-31 % of the
peak force of a rural drive). Beside it (the agile mode, ``q_diag``) runs the same filter with
a quiet process noise on the forces (``quiet_force_q``); an interacting multiple model (Blom
and Bar-Shalom 1988) mixes them by a Markov switching rate (``mode_switch_per_s``), weighs them
by the likelihood of their residuals and publishes the combination
(``lateral_force_kernel.imm_step``). ``quiet_force_q`` 0 is the paper's single filter.

Relation 1, zeta: by default the model's own steady state (``ObserverVehicleParams.zeta``);
``tpms_ros.offline.lateral_force_tuning.calibrate_zeta`` identifies it instead from the paper's
Fig. 3 manoeuvre (a slow steer ramp) with the IMU alone, which captures the roll the model
leaves out (tire vertical compliance).

The plain EKF is the same code with ``ObserverTuningParams(scaled=False, mec=False)``: S = I, no
compensator; ``ObserverTuningParams.plain()`` adds its own Q from the same tuning search (a fair
comparison).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
import math
import sys
from typing import Any

import numpy as np
from scipy import signal

from tpms_ros.core.lateral_force_kernel import MODEL_FIELDS, G, imm_step, initial_state
from tpms_ros.core.lateral_force_kernel import N_X as _N_X
from tpms_ros.core.lateral_force_kernel import N_Z as _N_Z
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.validation import require_positive

STATE_NAMES = ('vx', 'vy', 'r', 'phi', 'p', 'fyf', 'fyr')
MEASUREMENT_NAMES = ('ax', 'ay', 'r', 'p', 'vx_wheel')
PAPER_SCALING = (1e-1, 10.0, 10.0, 1e3, 1e2, 1e-3, 1e-3)
# Q of the plain EKF (physical units per s) and its R, from the same search as the SKFMEC's
# first defaults (one filter, the paper's tire split).
PLAIN_Q_DIAG = (1e-2, 1e-1, 1e-1, 1e-1, 1e3, 3.0, 3.0)
PLAIN_R_STD = (0.3, 1.0, 0.005, 0.005, 0.5)
_SPD_CHECK_EVERY = 10
# Memory of the gyro residuals' mean square (gyro_residual_ratio), s: long against a
# manoeuvre's transient, whose model error also shows in the residuals, short against a drive.
_RESIDUAL_TAU_S = 10.0


@dataclass(frozen=True)
class ObserverVehicleParams:
    """The observer's own belief about the vehicle (docs/methods/lateral_force_observer.md
    defaults, Ford FC/HVE).

    Deliberately separate from the simulator's ``VehicleParams``: the observer's model is a
    design choice that robustness studies perturb independently of the truth, and the core must
    not depend on the simulator. Its fields are the node's ROS parameters; from flat values
    (a params file) ``vehicle_monitor_common.parameters.build`` makes one.
    """

    m: float = param(1814.0, 'total vehicle mass, kg', low=1.0, high=1e5)
    ms: float = param(1661.0, 'sprung mass, kg (<= m)', low=1.0, high=1e5)
    iz: float = param(2560.0, 'yaw inertia, kg m^2', low=1.0, high=1e6)
    ix: float = param(580.0, 'roll inertia of the sprung mass about its CG, kg m^2', low=1.0,
                      high=1e6)
    iw: float = param(2.0, 'wheel spin inertia, kg m^2', low=1e-3, high=100.0)
    lf: float = param(1.076, 'CG to front axle, m', low=0.1, high=10.0)
    lr: float = param(1.617, 'CG to rear axle, m', low=0.1, high=10.0)
    h: float = param(0.55, 'CG height, m', low=0.05, high=5.0)
    hf: float = param(0.114, 'front roll centre height, m', low=-2.0, high=5.0)
    hr: float = param(0.004, 'rear roll centre height, m', low=-2.0, high=5.0)
    e: float = param(0.48, 'roll axis to sprung-mass CG, m', low=-2.0, high=5.0)
    rw: float = param(0.305, 'wheel rolling radius, m', low=0.05, high=2.0)
    tf: float = param(0.784, 'front HALF track, m', low=0.1, high=3.0)
    tr: float = param(0.760, 'rear HALF track, m', low=0.1, high=3.0)
    kphi_f: float = param(108205.8, 'front roll stiffness, N m/rad', low=1.0, high=1e8)
    kphi_r: float = param(81436.7, 'rear roll stiffness, N m/rad', low=1.0, high=1e8)
    cphi_f: float = param(826.8, 'front roll damping, N m s/rad', low=0.0, high=1e7)
    cphi_r: float = param(658.9, 'rear roll damping, N m s/rad', low=0.0, high=1e7)
    # Tire data, see the module docstring.
    split_exponent: float = param(
        0.2, 'left/right split of each axle force by Fz^exponent: 1 is the '
        "paper's proportional split, below 1 follows the tires' load sensitivity (tire data)",
        low=0.0, high=1.0)

    def __post_init__(self) -> None:
        positive = ('m', 'ms', 'iz', 'ix', 'iw', 'lf', 'lr', 'h', 'rw', 'tf', 'tr',
                    'kphi_f', 'kphi_r')
        require_positive(self, positive)
        for name in ('hf', 'hr', 'e', 'cphi_f', 'cphi_r'):
            value = getattr(self, name)
            if not math.isfinite(value):
                raise ValueError(f'ObserverVehicleParams.{name} must be finite, got {value}')
        if not (math.isfinite(self.split_exponent) and 0.0 <= self.split_exponent <= 1.0):
            raise ValueError('ObserverVehicleParams.split_exponent must be in [0, 1], '
                             f'got {self.split_exponent}')
        if self.cphi_f < 0.0 or self.cphi_r < 0.0:
            raise ValueError('ObserverVehicleParams.cphi_f/cphi_r must be >= 0')
        if self.ms > self.m:
            raise ValueError(f'ObserverVehicleParams.ms ({self.ms}) must not exceed m ({self.m})')
        if self.kphi_f + self.kphi_r <= self.ms * G * self.e:
            raise ValueError('ObserverVehicleParams: kphi_f + kphi_r must exceed ms g e '
                             '(otherwise the body has no static roll stability)')

    @property
    def wheelbase(self) -> float:
        """Axle distance l = lf + lr, m."""
        return self.lf + self.lr

    @property
    def zeta(self) -> tuple[float, float]:
        """Steady-state (z1, z2) = (Fyf/phi, Fyr/phi) of the monitoring model, N/rad.

        In a steady turn 2 Fyf = m ay lr/l, 2 Fyr = m ay lf/l, and the roll row gives
        (kphi - ms g e) phi = ay [ms e + m (hf lr + hr lf)/l]. Small steer and no Fx assumed.
        """
        wb = self.wheelbase
        roll_gain = (self.ms * self.e + self.m * (self.hf * self.lr + self.hr * self.lf) / wb) / (
            self.kphi_f + self.kphi_r - self.ms * G * self.e)
        return (self.m * self.lr / (2.0 * wb) / roll_gain,
                self.m * self.lf / (2.0 * wb) / roll_gain)


@dataclass(frozen=True)
class ObserverTuningParams:
    """Filter settings. Defaults: the agile filter's were chosen by ``tune_gains`` on the
    paper's worst case (the shipped ``kim_huh_lateral.yaml``: 14-DOF truth, mass +200 kg,
    friction drop; ``benchmarks/bench_lateral_force_observer.py tune``): Q on the force states
    10, Gp (20, -20) and Gy (1000, 300) kg (the search found no measurable gain from changing
    either); worst wheel 8.95 % with the proportional-to-0.6 split, ay noise 1 m/s^2 and one
    filter. The quiet filter (``quiet_force_q`` 0.1, switching 3 per s) and ay noise 0.3 m/s^2
    were chosen on 16 tuning cars of the road family (``benchmarks/
    eval_lateral_force_family.py``, the paper's manoeuvre and 60 s urban, rural and motorway
    drives on each) under the condition that the paper's case and its robustness variants
    (seed 7, friction x0.7, x1.3) stay within 10 %: tuning cars within 10 % on every case
    (64 / 64, against 32 / 64 with the single filter), the paper's case 8.3 % (with the tire's
    split 0.2). ``plain()`` carries the result of the first search for the plain EKF (Q on the
    roll rate 1000, forces 3; 8.79 %), so the two are compared each at its best.

    Q and P0 are given in the filter's coordinates: scaled (x* = S x) when ``scaled`` is true,
    physical otherwise.
    """

    scaled: bool = param(True, 'EKF on the scaled state x* = S x (false with mec false: the '
                         'plain EKF)')
    mec: bool = param(True, 'model error compensator (Gp on yaw rate, Gy on ay)')
    scaling: tuple[float, ...] = param(PAPER_SCALING, 'state scaling S for [vx, vy, r, phi, p, '
                                       'Fyf, Fyr]')
    q_diag: tuple[float, ...] = param((1e-2, 1e-1, 1e-1, 1e-1, 1e1, 10.0, 10.0),
                                      'process noise spectral density per state, filter '
                                      'coordinates, per s')
    p0_diag: tuple[float, ...] = param((1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0), 'initial '
                                       'covariance per state, filter coordinates')
    r_std: tuple[float, ...] = param((0.3, 0.3, 0.005, 0.005, 0.5), 'measurement noise std: '
                                     'ax, ay (m/s^2), r, p (rad/s), vx from wheel speeds (m/s)')
    gp: tuple[float, ...] = param((20.0, -20.0), 'MEC gain yaw-rate error -> (Fyf*, Fyr*), '
                                  'scaled units per (rad/s) per s')
    gy: tuple[float, ...] = param((1000.0, 300.0), 'MEC gain ay error -> load transfer '
                                  '(front, rear), kg')
    zeta: tuple[float, ...] = param((), 'relation 1 (z1, z2) = (Fyf/phi, Fyr/phi), N/rad, e.g. '
                                    'from offline.lateral_force_tuning.calibrate_zeta; empty: '
                                    "the vehicle model's own steady state")
    imu_gravity_tilt: bool = param(True, 'the IMU is fixed to the rolling body (its ay reads '
                                   'g sin(phi))')
    wheel_accel_tau_s: float = param(0.02, 'time constant of the wheel-acceleration '
                                     'differentiator, s', low=1e-3, high=1.0)
    validity_ay_mps2: float = param(0.5 * G, 'the load-ratio relations hold below this |ay| '
                                    '(0.5 g), m/s^2', low=0.5, high=20.0)
    max_accel_mps2: float = param(3.0 * G, '|ax| or |ay| above this is a saturated sensor: '
                                  'the sample is rejected, m/s^2', low=1.0, high=1000.0)
    max_rate_rad_s: float = param(3.0, '|r| or |p| above this is rejected, rad/s', low=0.1,
                                  high=100.0)
    max_wheel_speed_rad_s: float = param(400.0, 'a wheel speed above this (about 440 km/h at '
                                         'rw 0.3 m) is rejected, rad/s', low=1.0, high=5000.0)
    max_steer_rad: float = param(0.8, '|steering angle| above this is rejected, rad', low=0.01,
                                 high=10.0)
    max_torque_nm: float = param(2.0e4, '|wheel torque| above this is rejected, N m per wheel',
                                 low=1.0, high=1e6)
    max_dt_s: float = param(0.2, 'an IMU gap longer than this restarts the filter, s',
                            low=0.011, high=10.0)
    quiet_force_q: float = param(0.1, "IMM: a second filter whose force states' process noise "
                                 "is this (filter coordinates, per s) beside q_diag's; 0: one "
                                 'filter', low=0.0, high=1e6)
    mode_switch_per_s: float = param(3.0, 'IMM: rate of switching between the quiet and the '
                                     'agile filter, per s', low=1e-6, high=50.0)

    def __post_init__(self) -> None:
        for name, size in (('scaling', _N_X), ('q_diag', _N_X), ('p0_diag', _N_X),
                           ('r_std', _N_Z), ('gp', 2), ('gy', 2)):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != (size,) or not np.all(np.isfinite(value)):
                raise ValueError(f'ObserverTuningParams.{name} must be {size} finite numbers, '
                                 f'got {getattr(self, name)}')
        for name in ('scaling', 'p0_diag', 'r_std'):
            if not np.all(np.asarray(getattr(self, name)) > 0.0):
                raise ValueError(f'ObserverTuningParams.{name} must be > 0')
        if not np.all(np.asarray(self.q_diag) >= 0.0):
            raise ValueError('ObserverTuningParams.q_diag must be >= 0')
        if self.zeta and (len(self.zeta) != 2 or not all(
                math.isfinite(z) and z > 0.0 for z in self.zeta)):
            raise ValueError(f'ObserverTuningParams.zeta must be two finite numbers > 0, '
                             f'got {self.zeta}')
        require_positive(self, ('wheel_accel_tau_s', 'validity_ay_mps2', 'max_accel_mps2',
                                'max_rate_rad_s', 'max_wheel_speed_rad_s', 'max_steer_rad',
                                'max_torque_nm', 'max_dt_s'))

    @classmethod
    def plain(cls, **overrides: Any) -> ObserverTuningParams:
        """The plain EKF: no scaling (S = I) and no compensator, with its own tuned Q
        (``PLAIN_Q_DIAG``, physical units; the same search as the SKFMEC's defaults)."""
        overrides.setdefault('q_diag', PLAIN_Q_DIAG)
        overrides.setdefault('r_std', PLAIN_R_STD)
        overrides.setdefault('quiet_force_q', 0.0)
        return cls(scaled=False, mec=False, **overrides)


@dataclass(frozen=True)
class LateralForceEstimate:
    """One output sample. Forces in N, wheel order FL, FR, RL, RR.

    ``fy_front``/``fy_rear`` are the paper's Fyf, Fyr: the average lateral force per tire of the
    axle, i.e. (fy[0] + fy[1])/2 and (fy[2] + fy[3])/2.
    """

    fx: np.ndarray
    fy: np.ndarray
    fz: np.ndarray
    fy_front: float
    fy_rear: float
    within_validity: bool       # |ay| below the relations' validity limit (0.5 g)
    state: np.ndarray           # [vx, vy, r, phi, p, Fyf, Fyr], physical units
    accepted: bool              # False: the sample was rejected and the last estimate is held


@dataclass(frozen=True)
class LateralForceTrack:
    """A batch of outputs (``run``), one row per sample; fields as ``LateralForceEstimate``."""

    t: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    fz: np.ndarray
    fy_front: np.ndarray
    fy_rear: np.ndarray
    within_validity: np.ndarray
    state: np.ndarray
    accepted: np.ndarray


@dataclass
class ObserverHealth:
    """Counters for diagnostics."""

    samples: int = 0
    accepted: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    gap_restarts: int = 0
    covariance_resets: int = 0


def differentiator_coefficients(tau: float, dt: float) -> tuple[float, float, float]:
    """(b0, b1, a1) of s/(tau s + 1) by the bilinear transform at step dt.

    y[k] = b0 u[k] + b1 u[k-1] - a1 y[k-1]; the same filter as ``scipy.signal.bilinear``.
    """
    k = 2.0 / dt
    den = tau * k + 1.0
    return k / den, -k / den, (1.0 - tau * k) / den


class LateralForceObserver:
    """SKFMEC tire lateral force observer (or the plain EKF, from the same code).

    Args:
        params: the observer's vehicle model.
        tuning: filter settings; ``ObserverTuningParams.plain()`` for the plain EKF.

    Stream samples with ``step``; evaluate offline with ``run``.
    """

    def __init__(self, params: ObserverVehicleParams | None = None,
                 tuning: ObserverTuningParams | None = None) -> None:
        self.params = params or ObserverVehicleParams()
        self.tuning = tuning or ObserverTuningParams()
        p, tn = self.params, self.tuning
        self._s = np.asarray(tn.scaling if tn.scaled else (1.0,) * _N_X, dtype=float)
        self._s_inv = 1.0 / self._s
        agile = np.diag(np.asarray(tn.q_diag, dtype=float))
        quiet = agile.copy()
        quiet[5, 5] = quiet[6, 6] = tn.quiet_force_q
        # The modes: the agile filter alone, or quiet and agile interacting (IMM).
        self._qs = np.ascontiguousarray([agile] if tn.quiet_force_q == 0.0 else [quiet, agile])
        self._p0 = np.diag(np.asarray(tn.p0_diag, dtype=float))
        self._r = np.diag(np.asarray(tn.r_std, dtype=float) ** 2)
        e_mat = np.zeros((_N_X, _N_X))
        np.fill_diagonal(e_mat, [p.m, p.m, p.iz, 1.0, p.ix + p.ms * p.e ** 2, 1.0, 1.0])
        e_mat[1, 4] = e_mat[4, 1] = -p.ms * p.e
        # S E^-1: maps the force/moment vector f straight to the scaled derivative.
        self._se_inv = self._s[:, None] * np.linalg.inv(e_mat)
        self._zeta = tn.zeta or p.zeta
        self._kphi = p.kphi_f + p.kphi_r
        self._cphi = p.cphi_f + p.cphi_r
        self._share_f = p.kphi_f / self._kphi
        self._gp = np.zeros(_N_X)
        self._gy = (0.0, 0.0)
        if tn.mec:
            self._gp[5], self._gp[6] = tn.gp
            self._gy = (float(tn.gy[0]), float(tn.gy[1]))
        constants = {'m': p.m, 'mse': p.ms * p.e, 'lf': p.lf, 'lr': p.lr, 'tf': p.tf,
                     'tr': p.tr, 'hf': p.hf, 'hr': p.hr, 'kphi': self._kphi,
                     'cphi': self._cphi, 'zeta_f': self._zeta[0], 'zeta_r': self._zeta[1]}
        self._model = np.array([constants[name] for name in MODEL_FIELDS], dtype=float)
        self._no_inputs = np.zeros(_N_X)    # the first sample predicts nothing
        self._y = np.zeros(_N_Z)            # the last residual z - h(x-)
        self.health = ObserverHealth()
        self.reset()

    # ------------------------------------------------------------------ state handling
    def reset(self) -> None:
        """Forget the estimate; the next accepted sample initialises the filter."""
        self._x: np.ndarray | None = None       # scaled state (the modes combined)
        n_modes = self._qs.shape[0]
        self._xs = np.zeros((n_modes, _N_X))     # each mode's scaled state
        self._ps = np.repeat(self._p0[None], n_modes, axis=0)   # and its covariance
        self._mu = np.full(n_modes, 1.0 / n_modes)   # the modes' probabilities
        self._u_prev: np.ndarray | None = None   # the held inputs of the next prediction
        self._omega_prev = np.zeros(4)
        self._omega_dot = np.zeros(4)
        self._pending_dt = 0.0
        self._spd_countdown = _SPD_CHECK_EVERY
        self._last: LateralForceEstimate | None = None
        self._residual_ms = np.zeros(2)   # yaw-rate and roll-rate residuals' mean square
        self._residual_s = 0.0            # data time the mean square has seen

    @property
    def covariance(self) -> np.ndarray:
        """Error covariance of the state in physical units."""
        return self.scaled_covariance * (self._s_inv[:, None] * self._s_inv[None, :])

    @property
    def scaled_covariance(self) -> np.ndarray:
        """Error covariance in the filter's own (scaled) coordinates (of the modes combined:
        each mode's covariance and its spread about the combined state, weighed by the mode
        probabilities)."""
        if self._ps.shape[0] == 1:
            return self._ps[0].copy()
        mean = self._mu @ self._xs
        spread = self._xs - mean
        return (np.einsum('j,jkl->kl', self._mu, self._ps)
                + np.einsum('j,jk,jl->kl', self._mu, spread, spread))

    @property
    def gyro_residual_ratio(self) -> tuple[float, float] | None:
        """The yaw-rate and roll-rate residuals' RMS over about the last 10 s, each over its
        ``r_std``; None before 10 s of data. About 1 or below when ``r_std`` covers the gyro's
        noise (0.3-1.0 on the road family); a gyro 2-4 times noisier than ``r_std`` reads
        2.4-6 here, and then the forces follow its noise (a family car's rural drive: 6 % of
        the peak force at 4 mrad/s, 26 % at 10, 130 % at 20, and 10 and 13 % with ``r_std``
        set to the noise)."""
        if self._residual_s < _RESIDUAL_TAU_S:
            return None
        r_std = self.tuning.r_std
        return (math.sqrt(self._residual_ms[0]) / r_std[2],
                math.sqrt(self._residual_ms[1]) / r_std[3])

    @property
    def mode_probabilities(self) -> np.ndarray:
        """(quiet, agile) probabilities of the IMM, or (1,) with one filter."""
        return self._mu.copy()

    @property
    def zeta(self) -> tuple[float, float]:
        """The (z1, z2) the model uses, N/rad."""
        return (float(self._zeta[0]), float(self._zeta[1]))

    # ------------------------------------------------------------------ model
    def _loads(self, ax: float, ay: float, phi: float, ay_res: float) -> tuple[float, ...]:
        """Smith & Starkey vertical loads (eq. 39) with the ay compensator, N."""
        p = self.params
        wb = p.wheelbase
        long_transfer = p.m * p.h * ax / (2.0 * wb)
        roll_moment = p.m * p.h * ay + p.ms * G * p.e * math.sin(phi)
        mean_f = p.m * G * p.lr / (2.0 * wb) - long_transfer
        mean_r = p.m * G * p.lf / (2.0 * wb) + long_transfer
        d_f = self._share_f * roll_moment / (2.0 * p.tf) + self._gy[0] * ay_res
        d_r = (1.0 - self._share_f) * roll_moment / (2.0 * p.tr) + self._gy[1] * ay_res
        # A lifted wheel carries no load; keep a small floor so the split ratio stays finite.
        floor_f, floor_r = 0.01 * abs(mean_f) + 1.0, 0.01 * abs(mean_r) + 1.0
        return (max(mean_f - d_f, floor_f), max(mean_f + d_f, floor_f),
                max(mean_r - d_r, floor_r), max(mean_r + d_r, floor_r))

    # ------------------------------------------------------------------ filter core
    def _filter_sample(self, dt: float, ax: float, ay: float, r: float, pr: float,
                       fx: tuple[float, float, float, float], steer: float,
                       vx_wheel: float) -> tuple[tuple[float, ...], np.ndarray]:
        """Predict over dt with the held inputs, correct with this sample (the compiled
        :func:`tpms_ros.core.lateral_force_kernel.imm_step` over the modes); returns (loads,
        x)."""
        c, s = math.cos(steer), math.sin(steer)
        z = np.array([ax, ay, r, pr, vx_wheel])
        # a start (first sample, or after a gap restart) predicts nothing
        held = self._u_prev if self._x is not None else None
        predict = held is not None
        if held is None:
            held = self._no_inputs
            initial_state(ay, r, pr, vx_wheel, self._model, self._s, self._xs[0])
            self._xs[:] = self._xs[0]
            self._ps[:] = self._p0
            self._mu[:] = 1.0 / self._mu.size
        x = np.empty(_N_X)
        # stay >= switch: a mode keeps at least the share it gives away
        switch = min(self.tuning.mode_switch_per_s * dt, 1.0 / self._mu.size)
        restarted = imm_step(
            self._xs, self._ps, self._mu, held, predict, dt, z, np.array(fx), c, s,
            self._model, self._se_inv, self._s, self._s_inv, self._qs, self._r, self._gp,
            self.tuning.imu_gravity_tilt, self._p0, self._y, switch, x)
        self._x = x
        if predict:
            weight = min(1.0, dt / _RESIDUAL_TAU_S)
            self._residual_ms += weight * (self._y[2:4] ** 2 - self._residual_ms)
            self._residual_s += dt
        # a diverged prediction (e.g. an unstable tuning) or a singular residual covariance
        # restarted the filter from this sample rather than publish or propagate NaN
        self.health.covariance_resets += bin(restarted).count('1')
        if not self._covariance_ok():
            self.health.covariance_resets += 1
            self._ps[:] = self._p0
        xp = self._s_inv * x
        phi = float(xp[3])
        # The load transfer follows the kinematic lateral acceleration, not the IMU's tilt.
        ay_kin = ay - G * math.sin(phi) if self.tuning.imu_gravity_tilt else ay
        loads = self._loads(ax, ay_kin, phi, float(self._y[1]))
        # The yaw moment of the steered front forces needs the left/right split of relation 2.
        w_left = loads[0] ** self.params.split_exponent
        w_right = loads[1] ** self.params.split_exponent
        self._u_prev = np.array([fx[0], fx[1], fx[2], fx[3], c, s,
                                 2.0 * (w_left - w_right) / (w_left + w_right)])
        return loads, xp

    def _covariance_ok(self) -> bool:
        """Every sample a cheap test (finite trace, positive diagonal); every
        ``_SPD_CHECK_EVERY`` samples a Cholesky factorisation (the full test costs as much as
        the rest of the update, and Joseph form plus symmetrisation rarely fail)."""
        diagonals = np.diagonal(self._ps, axis1=1, axis2=2)
        if not (math.isfinite(float(diagonals.sum())) and diagonals.min() > 0.0):
            return False
        self._spd_countdown -= 1
        if self._spd_countdown > 0:
            return True
        self._spd_countdown = _SPD_CHECK_EVERY
        try:
            np.linalg.cholesky(self._ps)
        except np.linalg.LinAlgError:
            return False
        return True

    def _estimate(self, loads: tuple[float, ...], xp: np.ndarray, fx: Sequence[float],
                  ay: float) -> LateralForceEstimate:
        fy = _split_sample(loads, float(xp[5]), float(xp[6]), self.params.split_exponent)
        return LateralForceEstimate(
            fx=np.array(fx, dtype=float), fy=np.array(fy), fz=np.array(loads),
            fy_front=float(xp[5]),
            fy_rear=float(xp[6]), within_validity=abs(ay) < self.tuning.validity_ay_mps2,
            state=xp.copy(), accepted=True)

    def _reject_reason(self, ax: float, ay: float, r: float, pr: float, omega: np.ndarray,
                       torque: np.ndarray, steer: float) -> str | None:
        tn = self.tuning
        if omega.shape != (4,) or torque.shape != (4,):
            return 'shape'
        # Plain Python on the few values: numpy's per-call overhead cost more than the tests.
        values = (ax, ay, r, pr, steer, *omega.tolist(), *torque.tolist())
        if not all(map(math.isfinite, values)):
            return 'non_finite'
        if abs(ax) > tn.max_accel_mps2 or abs(ay) > tn.max_accel_mps2:
            return 'accel_saturated'
        if abs(r) > tn.max_rate_rad_s or abs(pr) > tn.max_rate_rad_s:
            return 'rate_saturated'
        if max(map(abs, values[5:9])) > tn.max_wheel_speed_rad_s:
            return 'wheel_speed'
        if abs(steer) > tn.max_steer_rad:
            return 'steer'
        if max(map(abs, values[9:])) > tn.max_torque_nm:
            return 'torque'
        return None

    def _reject(self, reason: str) -> None:
        self.health.rejected[reason] = self.health.rejected.get(reason, 0) + 1

    # ------------------------------------------------------------------ public API
    def step(self, ax: float, ay: float, r: float, p: float, omega: Sequence[float],
             wheel_torque: Sequence[float], steer: float,
             dt: float) -> LateralForceEstimate | None:
        """Process one time-aligned sample.

        Args:
            ax, ay: measured accelerations, m/s^2.
            r, p: yaw and roll rate, rad/s.
            omega: the four wheel speeds, rad/s.
            wheel_torque: the four drive (+) / brake (-) torques, N m.
            steer: front road-wheel angle, rad, left positive.
            dt: time since the previous call, s (the first call's dt is ignored).

        Returns:
            The estimate (``accepted`` False and the last estimate held when the sample is
            rejected), or None when rejected before any sample was accepted.
        """
        self.health.samples += 1
        try:
            ax, ay, r, p, steer, dt = (float(v) for v in (ax, ay, r, p, steer, dt))
            omega_a = np.asarray(omega, dtype=float).reshape(-1)
            torque_a = np.asarray(wheel_torque, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            self._reject('type')
            return self._held()
        reason = self._reject_reason(ax, ay, r, p, omega_a, torque_a, steer)
        if reason is None and not (math.isfinite(dt) and dt > 0.0) and self._x is not None:
            reason = 'dt'
        if reason is not None:
            self._reject(reason)
            # The skipped sample's time still passes: the next prediction spans it.
            if math.isfinite(dt) and dt > 0.0:
                self._pending_dt += dt
            return self._held()
        dt_total = dt + self._pending_dt
        self._pending_dt = 0.0
        if self._x is not None and dt_total > self.tuning.max_dt_s:
            self.health.gap_restarts += 1
            self._x = None
        if self._x is None:
            self._omega_prev = omega_a.copy()
            self._omega_dot = np.zeros(4)
        else:
            b0, b1, a1 = differentiator_coefficients(self.tuning.wheel_accel_tau_s, dt_total)
            self._omega_dot = b0 * omega_a + b1 * self._omega_prev - a1 * self._omega_dot
            self._omega_prev = omega_a.copy()
        fx_a = (torque_a - self.params.iw * self._omega_dot) / self.params.rw
        fx = (float(fx_a[0]), float(fx_a[1]), float(fx_a[2]), float(fx_a[3]))
        vx_wheel = float(np.mean(omega_a)) * self.params.rw
        loads, xp = self._filter_sample(dt_total, ax, ay, r, p, fx, steer, vx_wheel)
        self.health.accepted += 1
        self._last = self._estimate(loads, xp, fx, ay)
        return self._last

    def _held(self) -> LateralForceEstimate | None:
        return None if self._last is None else replace(self._last, accepted=False)

    def run(self, dt: float, ax: np.ndarray, ay: np.ndarray, r: np.ndarray, p: np.ndarray,
            omega: np.ndarray, wheel_torque: np.ndarray, steer: np.ndarray) -> LateralForceTrack:
        """Offline evaluation over uniformly sampled arrays (N,) and (N, 4), continuing the state.

        Clean batches take a fast path: validation, the wheel differentiator (scipy lfilter
        with carried state) and the wheel equation are vectorised, and only the EKF recursion
        loops. A batch with any bad sample goes through ``step`` sample by sample, so both
        paths reject and hold exactly the same way.
        """
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'dt must be finite and > 0, got {dt}')
        ax, ay, r, p, steer = (np.asarray(v, dtype=float).reshape(-1)
                               for v in (ax, ay, r, p, steer))
        omega = np.asarray(omega, dtype=float)
        wheel_torque = np.asarray(wheel_torque, dtype=float)
        n = ax.size
        for name, arr in (('ay', ay), ('r', r), ('p', p), ('steer', steer)):
            if arr.size != n:
                raise ValueError(f'{name} has {arr.size} samples, ax has {n}')
        for name, arr in (('omega', omega), ('wheel_torque', wheel_torque)):
            if arr.shape != (n, 4):
                raise ValueError(f'{name} must have shape ({n}, 4), got {arr.shape}')
        out_fx, out_fy, out_fz = np.zeros((n, 4)), np.zeros((n, 4)), np.zeros((n, 4))
        out_state = np.zeros((n, _N_X))
        accepted = np.zeros(n, dtype=bool)
        tn = self.tuning
        clean = (np.all(np.isfinite(np.column_stack([ax, ay, r, p, steer])))
                 and np.all(np.isfinite(omega)) and np.all(np.isfinite(wheel_torque))
                 and np.all(np.abs(np.column_stack([ax, ay])) <= tn.max_accel_mps2)
                 and np.all(np.abs(np.column_stack([r, p])) <= tn.max_rate_rad_s)
                 and np.all(np.abs(omega) <= tn.max_wheel_speed_rad_s)
                 and np.all(np.abs(steer) <= tn.max_steer_rad)
                 and np.all(np.abs(wheel_torque) <= tn.max_torque_nm)
                 and self._pending_dt == 0.0 and dt <= tn.max_dt_s)
        if not clean:
            for k in range(n):
                est = self.step(ax[k], ay[k], r[k], p[k], omega[k], wheel_torque[k], steer[k], dt)
                if est is not None:
                    out_fx[k], out_fy[k], out_fz[k] = est.fx, est.fy, est.fz
                    out_state[k], accepted[k] = est.state, est.accepted
        elif n > 0:
            b0, b1, a1 = differentiator_coefficients(tn.wheel_accel_tau_s, dt)
            if self._x is None:
                # The first sample initialises the filter with a zero wheel acceleration.
                omega_prev, omega_dot_prev = omega[0], np.zeros(4)
            else:
                omega_prev, omega_dot_prev = self._omega_prev, self._omega_dot
            # Direct-form II transposed state of the first-order filter from the last sample.
            zi = (b1 * omega_prev - a1 * omega_dot_prev)[None, :]
            omega_dot = signal.lfilter([b0, b1], [1.0, a1], omega, axis=0, zi=zi)[0]
            if self._x is None:
                omega_dot[0] = 0.0
                if n > 1:
                    zi = (b1 * omega[0])[None, :]
                    omega_dot[1:] = signal.lfilter([b0, b1], [1.0, a1], omega[1:], axis=0,
                                                   zi=zi)[0]
            fx_all = (wheel_torque - self.params.iw * omega_dot) / self.params.rw
            vx_wheel = omega.mean(axis=1) * self.params.rw
            out_fx[:] = fx_all
            fx_list = fx_all.tolist()
            for k in range(n):
                fxk = fx_list[k]
                loads, xp = self._filter_sample(dt, float(ax[k]), float(ay[k]), float(r[k]),
                                                float(p[k]), (fxk[0], fxk[1], fxk[2], fxk[3]),
                                                float(steer[k]), float(vx_wheel[k]))
                out_fz[k] = loads
                out_state[k] = xp
            accepted[:] = True
            out_fy = split_lateral(out_fz, out_state[:, 5], out_state[:, 6],
                                   self.params.split_exponent)
            self._omega_prev = omega[-1].copy()
            self._omega_dot = omega_dot[-1].copy()
            self.health.samples += n
            self.health.accepted += n
            k = n - 1
            self._last = LateralForceEstimate(
                fx=out_fx[k].copy(), fy=out_fy[k].copy(), fz=out_fz[k].copy(),
                fy_front=float(out_state[k, 5]), fy_rear=float(out_state[k, 6]),
                within_validity=bool(abs(ay[k]) < tn.validity_ay_mps2), state=out_state[k].copy(),
                accepted=True)
        return LateralForceTrack(
            t=np.arange(n) * dt, fx=out_fx, fy=out_fy, fz=out_fz, fy_front=out_state[:, 5].copy(),
            fy_rear=out_state[:, 6].copy(), within_validity=np.abs(ay) < tn.validity_ay_mps2,
            state=out_state, accepted=accepted)


def split_lateral(fz: np.ndarray, fyf: np.ndarray | float, fyr: np.ndarray | float,
                  exponent: float = 1.0) -> np.ndarray:
    """Per-wheel lateral forces from the axle means and the wheel loads (relation 2).

    Fyi = Fy_axle_mean * 2 w_i / (w_left + w_right) with the split weight w = Fz^exponent, so the
    axle sum is preserved (Fy1 + Fy2 = 2 Fyf) whatever the weights. ``exponent`` 1 is the
    paper's relation (eq. 36-37, Fyi/Fyf = Fzi/Fzf); a smaller one is the load-sensitive split
    (``ObserverVehicleParams.split_exponent``). The paper divides by the static axle load; the
    current axle mean keeps the axle sum under longitudinal load transfer (braking).

    Args:
        fz: wheel loads (4,) or (N, 4), N, all > 0.
        fyf, fyr: axle-mean lateral forces, scalars or (N,), N.
        exponent: load exponent of the split weight, in [0, 1].

    Returns:
        Lateral forces with the shape of ``fz``, N.
    """
    weight = np.asarray(fz, dtype=float) if exponent == 1.0 else np.power(fz, exponent)
    front = weight[..., 0] + weight[..., 1]
    rear = weight[..., 2] + weight[..., 3]
    with np.errstate(invalid='ignore', divide='ignore'):
        out = np.stack([2.0 * fyf * weight[..., 0] / front, 2.0 * fyf * weight[..., 1] / front,
                        2.0 * fyr * weight[..., 2] / rear, 2.0 * fyr * weight[..., 3] / rear],
                       axis=-1)
    return np.nan_to_num(out)


def _split_sample(fz: tuple[float, ...], fyf: float, fyr: float,
                  exponent: float) -> list[float]:
    """:func:`split_lateral` of one sample in plain Python, the same arithmetic (numpy's
    per-call overhead on four values was a fifth of a filter step)."""
    # numpy's power, not Python's: its vectorised pow differs from libm's in the last bit
    weight = fz if exponent == 1.0 else np.power(fz, exponent).tolist()
    front = weight[0] + weight[1]
    rear = weight[2] + weight[3]
    forces = [2.0 * fyf * weight[0] / front if front else math.nan,
              2.0 * fyf * weight[1] / front if front else math.nan,
              2.0 * fyr * weight[2] / rear if rear else math.nan,
              2.0 * fyr * weight[3] / rear if rear else math.nan]
    # as np.nan_to_num: NaN -> 0, +-inf -> the largest finite float of its sign
    return [force if math.isfinite(force) else
            0.0 if math.isnan(force) else math.copysign(sys.float_info.max, force)
            for force in forces]
