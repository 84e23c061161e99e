"""TPMS by wheel radius analysis (Persson, Gustafsson, Drevö, SAE 2002;
docs/methods/wheel_radius_analyzer.md).

A soft tire has a smaller effective rolling radius and turns faster. Two Kalman filters estimate
relative radii between wheel pairs; a calibration learns their nominal levels (wear and
manufacturing make them non-zero); a localisation turns the pair offsets into low tires.

Wheel order FL, FR, RL, RR = paper's 1, 2, 3, 4.

**Longitudinal (per side).** Slip of the driven wheel against the non-driven wheel of the same
side, both with the nominal radius: s = omega_driven / omega_nondriven - 1. With
mu = Fx / Fz = T_driven / (r_n Fz_static) the linear slip model is s = mu / k + delta, state
x = (1/k, delta) random walk, measurement s_t = (mu_t, 1) x_t + e_t. Here delta is
1 - r_driven / r_nondriven; it is reported as the paper's delta_13 = 1 - r1 / r3 (left) and
delta_24 = 1 - r2 / r4 (right) whichever axle is driven (exact conversion for rear drive).
All-wheel drive (``driven_axle: all``): no wheel rolls free and each slips under its own
traction, s_i = mu_i / k; with the two tires of a side alike the slip of the rear wheel against
the front one is s = (mu_rear - mu_front) / k + delta, so the regressor is the difference of
the two wheels' traction (each as above, the front's load transfer negative) and delta is the
rear-drive one. Running an all-wheel-drive car as ``rear`` instead leaves the front wheel's
traction out: exact only when the front carries no drive torque.
Deviations, measured on the road simulator's nominal driving: mu counts the wheel's inertia
torque and the longitudinal load transfer, mu = (T - I_w omega_dot) / (r_n (Fz + m h ax /
(2 L))), and the model pauses while |ax| > ``accel_max_longitudinal_mps2`` (braking and hard
acceleration moved delta by 5-10e-3 there). At constant traction 1/k and delta are not
separable, so a calibration on steady cruising cannot know delta alone: it keeps the slip line's
height at its mean traction, and the indication compares the current line at that traction
(the same holds for the lateral pairs and the gyro offset at constant speed; see
:class:`WheelRadiusCalibration`).

**Lateral (both axles and the gyro).** Sign conventions, checked against the physics: in a turn
the outer wheels travel faster. The paper writes psi_dot = (v3 - v4) / L_rear, which is the SAE
J670 convention (z down, yaw rate positive turning right). With delta_34 = r3 / r4 - 1 and
r4 ~ r_n this gives psi_dot_m,rear = r_n (omega3 - omega4) / L_rear
= psi_dot - (r_n omega3 / L_rear) delta_34, hence the method page's H row (1, 0, 0, -r_n omega3 /
L, 0).
Deliberate deviation: the core puts the axle's mean speed (omega3 + omega4) / 2 in place of
omega3 in H (second-order difference), because omega3's noise would otherwise sit in both the
measurement and its regressor and bias delta along the ridge that is unobservable at constant
speed (see ``process``).
The IMU follows REP 103 (z up, yaw rate positive turning left), so the core feeds the filter
psi_dot_gyro = -angular_velocity.z: then F and H are literally the method page's, psi_dot_m =
(v_left -
v_right) / track, and the state's yaw rate and gyro offset are in the SAE sense. The reported
``gyro_offset`` is converted back to the IMU's own REP 103 sign (what to subtract from
angular_velocity.z). Front axle: the front wheels roll along their steered heading, so the left-
right speed difference is psi_dot L_front cos(steer); psi_dot_m,front and its H entry are divided
by cos(steer) (1 without a steering input).

State (psi_dot, psi_ddot, delta_o, delta_34, delta_12); F = [[1, Ts, 0, 0, 0], [0, 1, 0, 0, 0],
I3]; process noise G v with G = (Ts^2/2, Ts, 0, 0, 0) and v white yaw jerk. Deviation from the
paper's model, on purpose: delta_o, delta_34 and delta_12 also get a small random walk. Without
it their covariance goes to zero and the filter stops following a pressure change (the paper's
Fig. 7 shows it following one in about 60 s). Setting the random walks to zero gives the literal
model.

**Kalman filter implementation.** Per sample, a tight loop: the lateral filter does the
predict with F's structure (row 0 += Ts row 1, then column 0 += Ts column 1) and three sequential
scalar updates (R is diagonal, so it equals the joint update; tested against filterpy's
``KalmanFilter``); the two longitudinal 2-state filters run on Python floats in closed form.
filterpy's generic ``predict``/``update`` (dense products, checks) costs several times more per
sample (measured in ``benchmarks/bench_tpms_cores.py``), and at 100 Hz the loop is the cost.
Everything that does not need the recursion (validity, slip, mu, measurements) is computed
vectorised before the loop. The wheel accelerations' low-pass (hold of bad samples,
Butterworth, difference) is a per-sample recursion too and compiled the same way.

No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
import math
from typing import Any

from numba import njit, types
import numpy as np
from scipy import signal

from tpms_ros.core.nominal_calibration import CalibratedCore, check_calibration_window
from tpms_ros.core.tires import N_TIRES, TpmsIndication
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.validation import require_positive

CALIBRATION_VERSION = 3
_EPS = float(np.finfo(np.float64).eps)
PAIR_NAMES = ('delta_13', 'delta_24', 'delta_34', 'delta_12')
GRAVITY = 9.80665
# d(pair offset) / d(relative radius change eps_i of tire i), to first order:
# delta_13 = 1 - r1/r3 ~ eps3 - eps1, delta_24 ~ eps4 - eps2, delta_34 = r3/r4 - 1 ~ eps3 - eps4,
# delta_12 ~ eps1 - eps2
PAIR_SENSITIVITY = np.array([
    [-1.0, 0.0, 1.0, 0.0],
    [0.0, -1.0, 0.0, 1.0],
    [0.0, 0.0, 1.0, -1.0],
    [1.0, -1.0, 0.0, 0.0],
])
PAIR_TIRES = tuple(tuple(int(i) for i in np.flatnonzero(row)) for row in PAIR_SENSITIVITY)


@dataclass(frozen=True)
class WheelRadiusParams:
    """Parameters of the wheel radius analysis (vehicle data, gating, noise, decision).

    Each field is also the node's ROS parameter (description, unit, range in its param()).
    Why some values are what they are:

    Attributes:
        nominal_radius_m: nominal rolling radius r_n, m.
        track_front_m: front track width L_front, m.
        track_rear_m: rear track width L_rear, m.
        static_load_n: (FL, FR, RL, RR) static wheel loads Fz, N.
        driven_axle: 'front', 'rear' or 'all' (all-wheel drive: rear against front slip).
        sample_rate_hz: nominal input rate; the first sample's Ts, Hz.
        max_gap_s: a larger gap between stamps restarts the yaw states, s.
        max_wheel_speed_rad_s: wheel speeds above this (rad/s) are rejected as non-physical.
        min_speed_mps: speed band, lower end: below it the encoder speed is coarse, m/s.
        max_speed_mps: speed band, upper end: above it the radius grows with speed, m/s.
        mu_max: traction limit |Fx/Fz| of the linear slip model.
        slip_max: |s| above this is wheel spin/lock, not the linear model.
        brake_torque_nm: any wheel torque below -this means braking: all wheels slip and the
            non-driven wheel is no speed reference, so the longitudinal model pauses, N m.
        ay_max_longitudinal_mps2: cornering limit |v psi_dot| of the longitudinal model (front and
            rear wheels of a side travel different radii), m/s^2.
        ay_max_lateral_mps2: cornering limit of the lateral model (load transfer changes radii),
            m/s^2.
        accel_max_longitudinal_mps2: longitudinal acceleration limit |ax| of the longitudinal
            model, m/s^2. ax is the filtered derivative of the non-driven wheels' speed. Under
            strong acceleration or braking the slip model's mu is corrupted (wheel inertia, load
            transfer, the non-driven wheel's own brake slip) and delta moves by 5-10e-3 on the
            road simulator's car, several times a 15 % loss; the updates there are skipped.
        accel_max_lateral_mps2: the same limit for the lateral model's updates, m/s^2. Measured on
            the road simulator: at the onset of a 2 m/s^2 braking the lateral offsets swing by
            up to 1.1e-2 for 2-3 s (pitch and brake transients in the wheel-speed difference)
            and settle back, which alone gave a full-confidence false warning.
        accel_filter_hz: corner of the 2nd-order low-pass before differentiating the wheel
            speeds (ax and each wheel's angular acceleration), Hz.
        wheel_inertia_kgm2: spin inertia of a driven wheel (tire, rim, brake, its share of the
            driveline) I_w: the contact force is (T - I_w omega_dot) / r_n, kg m^2.
            VEHICLE-SPECIFIC; 0 ignores the inertia torque.
        cg_height_m: centre-of-gravity height h for the longitudinal load transfer
            +-m h ax / (2 wheelbase) per wheel (rear gains under acceleration), m; the mass is
            sum(static_load_n) / g. VEHICLE-SPECIFIC; 0 ignores the load transfer.
        wheelbase_m: wheelbase, m. VEHICLE-SPECIFIC.
        gyro_stuck_s: a gyro reading repeated exactly this long is a stopped gyro: the lateral
            filter pauses rather than drift, s.
        wheel_recover_s: a tire stays unknown this long after its last bad sample, s.
        wheel_speed_noise_mps: noise of one wheel's speed r_n omega per sample (the mean
            over a bin), m/s. The slip s = omega_d / omega_n - 1 then has the noise std
            sqrt(2) x this / v_n, with v_n the non-driven wheel's speed: 1e-3 at 25 m/s by
            default, 2.2e-3 at 40 km/h. A constant slip noise let the first noisy samples at
            low speed after a pause throw a pair offset by 5e-3 (road simulator, rough
            concrete at 30 km/h, where the slip noise is ~1.5e-2 per sample).
        inv_stiffness_rw: random walk of 1/k, per sqrt(s).
        delta_rw: random walk of the relative radius offsets (both filters), per sqrt(s);
            sets the tracking time of a pressure change (the paper: about 60 s).
        inv_stiffness0_std: initial std of 1/k.
        delta0_std: initial std of the offsets.
        yaw_jerk_std_rad_s3: std of the white yaw jerk v driving (psi_dot, psi_ddot), rad/s^3.
        gyro_noise_std_rad_s: gyro noise per sample, rad/s.
        wheel_yaw_noise_std_rad_s: noise of the wheel-speed yaw rates per sample, rad/s.
        gyro_offset_rw: random walk of the gyro offset, rad/s per sqrt(s) (MEMS bias drift,
            ~0.1 deg/s over 10 min). Larger lets a radius step leak into the offset: at constant
            speed only delta_o + c delta is observable, speed changes separate them.
        gyro_offset0_std_rad_s: initial std of the gyro offset, rad/s.
        calibration_settle_s: first part of a calibration window not used, s.
            The longitudinal nominal is kept as the slip line's height at the calibration's
            mean traction (see :class:`WheelRadiusCalibration`), because at constant traction
            1/k and delta are not separable: delta alone would carry mu * (1/k error).
        min_calibration_s: least seconds of valid updates per pair for a calibration, s.
        noise_block_s: block length of the calibration's noise check, s. The filters assume
            white measurement noise of the stds above; on a real car the slip and wheel-yaw
            errors are larger and coloured (road, load and driveline), and a filter that
            trusts white noise states a radius offset std many times too small. The
            calibration therefore measures each pair's innovation power at low frequency:
            B times the mean square of the means over blocks of B samples of the innovations
            divided by their assumed std (the spectral density near 0, which is what a slow
            estimate averages, relative to the assumed white noise). Its square root (>= 1)
            is the pair's ``noise_scale``: the filter's posterior std of the offset is
            multiplied by it wherever the std is used (the noise part of a steady-state
            posterior scales this way; the random-walk part does not, so the scaled std errs
            on the safe side). Measured on the road simulator's car: 17-22 for the slip
            pairs, 7-10 for the lateral pairs, about the same from a 60 s steady-cruise window
            as from 5 min of mixed driving; blocks of 1-10 s agree within 20 %.
        radius_noise_floor: floor of the per-pair and per-tire radius noise (relative
            radius): wear, temperature and load shifts that neither the filters nor the
            calibration's noise check see.
        informative_std: a pair whose posterior std exceeds this carries no information.
        z_keep: a tire whose estimated drop is below this many sigmas is taken out of the
            localisation fit (noise, not a loss) before the others' sigmas are computed
            (0: never).
        z_flag: flag a tire whose radius drop exceeds this many noise sigmas.
        z_full: radius drop in sigmas at which the confidence reaches 1.
    """

    nominal_radius_m: float = param(0.31, 'nominal rolling radius r_n, m',
                                    low=0.1, high=2.0, read_only=True)
    track_front_m: float = param(1.55, 'front track width, m', low=0.5, high=4.0,
                                 read_only=True)
    track_rear_m: float = param(1.55, 'rear track width, m', low=0.5, high=4.0,
                                read_only=True)
    static_load_n: tuple[float, ...] = param((4200.0, 4200.0, 3300.0, 3300.0),
                                             'static wheel loads FL, FR, RL, RR, N',
                                             read_only=True)
    driven_axle: str = param('front', "driven axle ('all': all-wheel drive, the rear wheel's "
                             "slip against the front one's by their traction difference)",
                             choices=('front', 'rear', 'all'), read_only=True)
    sample_rate_hz: float = param(100.0, 'analysis rate: wheel speeds are '
                                  'averaged into bins of 1 / this, Hz', low=10.0, high=1000.0,
                                  read_only=True)
    max_gap_s: float = param(0.1, 'a larger gap between bins restarts the yaw '
                             'states, s', low=1e-3, high=10.0)
    max_wheel_speed_rad_s: float = param(600.0, 'wheel speeds above this are rejected, '
                                         'rad/s', low=1.0, high=5000.0)
    min_speed_mps: float = param(8.0, 'lower end of the speed band, m/s',
                                 low=0.0, high=100.0)
    max_speed_mps: float = param(45.0, 'upper end of the speed band, m/s',
                                 low=0.1, high=150.0)
    mu_max: float = param(0.15, 'traction limit |Fx/Fz| of the linear slip model',
                          low=1e-3, high=2.0)
    slip_max: float = param(0.03, '|slip| above this is spin/lock', low=1e-4, high=1.0)
    brake_torque_nm: float = param(20.0, 'any wheel torque below -this is '
                                   'braking: the longitudinal model pauses, N m', low=0.0,
                                   high=1e5)
    ay_max_longitudinal_mps2: float = param(2.0, 'cornering limit of the '
                                            'longitudinal model, m/s^2', low=0.01, high=20.0)
    ay_max_lateral_mps2: float = param(4.0, 'cornering limit of the lateral model, '
                                       'm/s^2', low=0.01, high=20.0)
    accel_max_longitudinal_mps2: float = param(0.8, 'longitudinal acceleration limit |ax| '
                                               'of the longitudinal model, m/s^2', low=0.01,
                                               high=20.0)
    accel_max_lateral_mps2: float = param(1.0, 'longitudinal acceleration limit '
                                          '|ax| of the lateral model, m/s^2', low=0.01, high=20.0)
    accel_filter_hz: float = param(2.0, 'low-pass corner before '
                                   'differentiating the wheel speeds, Hz', low=0.01, high=40.0,
                                   read_only=True)
    wheel_inertia_kgm2: float = param(1.0, 'spin inertia of a driven wheel '
                                      '(0: ignored), kg m^2', low=0.0, high=100.0,
                                      read_only=True)
    cg_height_m: float = param(0.55, 'centre-of-gravity height for the load transfer '
                               '(0: ignored), m', low=0.0, high=5.0, read_only=True)
    wheelbase_m: float = param(2.7, 'wheelbase, m', low=0.5, high=10.0,
                               read_only=True)
    gyro_stuck_s: float = param(0.5, 'a yaw rate repeated this long is a stopped '
                                'gyro: the lateral filter pauses, s', low=0.01, high=60.0)
    wheel_recover_s: float = param(1.0, 'a tire stays unknown this long after '
                                   'its last bad wheel speed, s', low=0.0, high=600.0)
    wheel_speed_noise_mps: float = param(0.0177, 'noise of one wheel\'s '
                                         'speed per sample (slip noise sqrt(2) x this / '
                                         'speed), m/s', low=1e-7, high=10.0)
    inv_stiffness_rw: float = param(1e-4, 'random walk of 1/k, per sqrt(s)',
                                    low=0.0, high=1.0)
    delta_rw: float = param(1e-5, 'random walk of the radius offsets, per sqrt(s)',
                            low=0.0, high=1.0)
    inv_stiffness0_std: float = param(0.05, 'initial std of 1/k', low=1e-6,
                                      high=10.0, read_only=True)
    delta0_std: float = param(0.01, 'initial std of the offsets', low=1e-6, high=1.0,
                              read_only=True)
    yaw_jerk_std_rad_s3: float = param(2.0, 'yaw jerk process noise, rad/s^3', low=1e-4,
                                       high=1000.0)
    gyro_noise_std_rad_s: float = param(0.01, 'gyro noise per sample, rad/s', low=1e-6,
                                        high=1.0)
    wheel_yaw_noise_std_rad_s: float = param(0.02, 'noise of the wheel-speed yaw '
                                             'rates per sample, rad/s', low=1e-6, high=1.0)
    gyro_offset_rw: float = param(2e-5, 'random walk of the gyro offset, rad/s '
                                  'per sqrt(s)', low=0.0, high=1.0)
    gyro_offset0_std_rad_s: float = param(0.03, 'initial std of the gyro offset, '
                                          'rad/s', low=1e-6, high=1.0, read_only=True)
    calibration_settle_s: float = param(20.0, 'first part of a calibration '
                                        'window not used, s', low=0.0, high=3600.0)
    min_calibration_s: float = param(20.0, 'least seconds of valid updates '
                                     'per pair for a calibration, s', low=0.1, high=3600.0)
    noise_block_s: float = param(2.0, 'block length of the calibration\'s '
                                 'coloured-noise check, s', low=0.01, high=600.0)
    radius_noise_floor: float = param(2.5e-4, 'floor of the per-tire relative '
                                      'radius noise', low=1e-7, high=0.1)
    informative_std: float = param(2e-3, 'a pair whose posterior std exceeds '
                                   'this carries no information', low=1e-6, high=1.0)
    z_keep: float = param(1.0, 'a tire whose radius drop is below this many sigmas is '
                          'taken out of the localisation fit (noise)', low=0.0, high=100.0)
    z_flag: float = param(3.0, 'flag a tire whose radius drop exceeds this many sigmas',
                          low=0.1, high=100.0)
    z_full: float = param(8.0, 'radius drop in sigmas at which the confidence reaches 1',
                          low=0.1, high=100.0)
    calibration_duration_s: float = param(120.0, 'length of a calibration run, s of data',
                                          low=0.1, high=36000.0)

    def __post_init__(self) -> None:
        positive = ('nominal_radius_m', 'track_front_m', 'track_rear_m', 'sample_rate_hz',
                    'max_gap_s', 'max_wheel_speed_rad_s', 'max_speed_mps', 'mu_max', 'slip_max',
                    'ay_max_longitudinal_mps2', 'ay_max_lateral_mps2', 'gyro_stuck_s',
                    'wheel_speed_noise_mps',
                    'accel_max_longitudinal_mps2', 'accel_max_lateral_mps2', 'accel_filter_hz',
                    'wheelbase_m',
                    'inv_stiffness0_std', 'delta0_std', 'gyro_noise_std_rad_s',
                    'wheel_yaw_noise_std_rad_s', 'gyro_offset0_std_rad_s', 'min_calibration_s',
                    'noise_block_s',
                    'radius_noise_floor', 'informative_std', 'z_flag', 'z_full',
                    'yaw_jerk_std_rad_s3')
        require_positive(self, positive)
        non_negative = ('min_speed_mps', 'brake_torque_nm', 'wheel_recover_s',
                        'inv_stiffness_rw', 'delta_rw', 'gyro_offset_rw',
                        'calibration_settle_s', 'wheel_inertia_kgm2', 'cg_height_m')
        require_positive(self, non_negative, allow_zero=True)
        loads = np.asarray(self.static_load_n, dtype=float)
        if loads.shape != (N_TIRES,) or not np.all(np.isfinite(loads)) or np.any(loads <= 0):
            raise ValueError(f'WheelRadiusParams.static_load_n must be 4 loads > 0 N, got '
                             f'{self.static_load_n}')
        if self.driven_axle not in ('front', 'rear', 'all'):
            raise ValueError(f"WheelRadiusParams.driven_axle must be 'front', 'rear' or 'all', "
                             f'got {self.driven_axle!r}')
        if not self.min_speed_mps < self.max_speed_mps:
            raise ValueError('WheelRadiusParams.min_speed_mps must be < max_speed_mps')
        if not 0.0 <= self.z_keep < self.z_flag < self.z_full:
            raise ValueError('WheelRadiusParams: 0 <= z_keep < z_flag < z_full must hold, got '
                             f'{self.z_keep}, {self.z_flag}, {self.z_full}')
        if not self.accel_filter_hz < 0.5 * self.sample_rate_hz:
            raise ValueError(f'WheelRadiusParams.accel_filter_hz must be below half the sample '
                             f'rate, got {self.accel_filter_hz}')
        check_calibration_window(self)


@dataclass(frozen=True)
class WheelRadiusCalibration:
    """Nominal pair offsets learned by calibration.

    Attributes:
        nominal_offsets: (4,) nominal delta_13, delta_24, delta_34, delta_12 (the mean of the
            estimates over the calibration window).
        noise: (4,) std of each offset estimate over the calibration window.
        duration_s: (4,) seconds of valid updates behind each nominal.
        reference: (4,) the coefficient a of each pair's observable combination
            u = delta + a z over the window, with z its companion state. A calibration drive at
            steady speed and traction cannot separate delta from z: longitudinal pairs see only
            the slip line's height delta + mu / k at the window's mean traction (a = mean mu,
            z = 1/k); lateral pairs see only delta + delta_o / c (a = 1 / mean c, c = r_n
            omega_axle / track, z = the gyro offset delta_o in the filter's SAE sign). The
            nominal is compared with the current filter's u at the same a, so it holds
            whatever split the filter had (0: delta itself, as in version 1 files).
        companion: (4,) mean z of each pair over the window (1/k left, right, delta_o twice).
        noise_scale: (4,) factor >= 1 on each pair's filter std for the measured coloured
            noise (see ``WheelRadiusParams.noise_block_s``; 1 in version 1 and 2 files).
    """

    nominal_offsets: np.ndarray
    noise: np.ndarray
    duration_s: np.ndarray
    reference: np.ndarray = field(default_factory=lambda: np.zeros(4))
    companion: np.ndarray = field(default_factory=lambda: np.zeros(4))
    noise_scale: np.ndarray = field(default_factory=lambda: np.ones(4))

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON/YAML-serialisable state."""
        return {
            'version': CALIBRATION_VERSION,
            'method': 'wheel_radius',
            'nominal_offsets': dict(zip(PAIR_NAMES, self.nominal_offsets.tolist(), strict=True)),
            'noise': dict(zip(PAIR_NAMES, self.noise.tolist(), strict=True)),
            'duration_s': dict(zip(PAIR_NAMES, self.duration_s.tolist(), strict=True)),
            'reference': dict(zip(PAIR_NAMES, self.reference.tolist(), strict=True)),
            'companion': dict(zip(PAIR_NAMES, self.companion.tolist(), strict=True)),
            'noise_scale': dict(zip(PAIR_NAMES, self.noise_scale.tolist(), strict=True)),
        }

    @classmethod
    def from_dict(cls, state: Mapping[str, Any]) -> WheelRadiusCalibration:
        """Rebuild from :meth:`to_dict` output (or an older file); ValueError if corrupt."""
        if not isinstance(state, Mapping):
            raise ValueError(f'calibration state must be a mapping, got {type(state).__name__}')
        version = state.get('version')
        if version not in (1, 2, CALIBRATION_VERSION) or state.get('method') != 'wheel_radius':
            raise ValueError(f'calibration state: expected version 1..{CALIBRATION_VERSION} of '
                             f'method wheel_radius, got {state.get("version")!r}/'
                             f'{state.get("method")!r}')
        tables = [('nominal_offsets', PAIR_NAMES, 0.1), ('noise', PAIR_NAMES, 0.1),
                  ('duration_s', PAIR_NAMES, math.inf)]
        if version >= 2:
            # |mu| and 1 / c (c ~ speed / track) stay below 1; 1/k and a gyro offset below 10
            tables += [('reference', PAIR_NAMES, 1.0), ('companion', PAIR_NAMES, 10.0)]
        if version >= 3:
            tables.append(('noise_scale', PAIR_NAMES, 1e4))
        arrays = []
        for key, names, upper in tables:
            table = state.get(key)
            if not isinstance(table, Mapping) or set(table) != set(names):
                raise ValueError(f'calibration state: {key!r} must map {names}')
            try:
                arr = np.array([float(table[name]) for name in names])
            except (TypeError, ValueError) as exc:
                raise ValueError(f'calibration state: {key!r} is not numeric') from exc
            # offsets of more than 10 % radius are no tire; noise and duration must be > 0
            if key in ('noise', 'duration_s'):
                ok = np.isfinite(arr) & (arr > 0.0) & (arr < upper)
            elif key == 'noise_scale':
                ok = np.isfinite(arr) & (arr >= 1.0) & (arr < upper)
            else:
                ok = np.isfinite(arr) & (np.abs(arr) < upper)
            if not np.all(ok):
                raise ValueError(f'calibration state: {key!r} out of range: {table!r}')
            arrays.append(arr)
        return cls(*arrays)


@dataclass(frozen=True)
class LowTireLocalisation:
    """Which tires are low, from the pair offsets relative to nominal.

    Attributes:
        radius_drop: (4,) estimated relative radius drop rho_i >= 0 per tire.
        sigma: (4,) its noise std: of the tires found low estimated together (the others at
            zero), or of a drop of that tire alone for the others.
        z: (4,) rho / sigma.
        flags: (4,) bool low tires (z >= z_flag).
        confidence: (4,) clip(z / z_full, 0, 1).
        residual: weighted residual of the fit; large = offsets inconsistent with only
            losses (a tire larger than nominal, e.g. changed tire: re-calibrate).
    """

    radius_drop: np.ndarray
    sigma: np.ndarray
    z: np.ndarray
    flags: np.ndarray
    confidence: np.ndarray
    residual: float


@dataclass(frozen=True)
class RadiusEstimate:
    """State of the wheel radius analysis after a processed chunk.

    Attributes:
        offsets: (4,) delta_13, delta_24, delta_34, delta_12 (raw, not relative to nominal).
        offsets_std: (4,) their posterior std.
        gyro_offset: gyro offset in the IMU's REP 103 sign, rad/s.
        inv_stiffness: (2,) 1/k left, right.
        trace_stamps: (M,) stamps of the accepted samples, s.
        trace: (M, 5) delta_13, delta_24, delta_34, delta_12, gyro_offset (REP 103) per
            accepted sample.
        counts: cumulative counters of rejected / gated samples by reason.
        gyro_ok: False while the gyro is stopped (lateral filter paused).
        calibrated: a calibration is in force.
    """

    offsets: np.ndarray
    offsets_std: np.ndarray
    gyro_offset: float
    inv_stiffness: np.ndarray
    trace_stamps: np.ndarray
    trace: np.ndarray
    counts: dict[str, int]
    gyro_ok: bool
    calibrated: bool


def bin_wheel_speeds(wheel_stamps_s: np.ndarray, omega: np.ndarray, bin_ends_s: np.ndarray,
                     bin_s: float, max_wheel_speed_rad_s: float) -> np.ndarray:
    """Mean wheel speed over each bin (max(previous end, end - bin_s), end], vectorised.

    The offline form of the ``wheel_radius_analyzer`` node's alignment: each IMU stamp closes a
    bin of at most ``bin_s``; the wheel speeds stamped in it are averaged. A wheel with a bad
    sample in its bin (non-finite, negative, above ``max_wheel_speed_rad_s``) is NaN there (the
    core rejects it); an empty bin is all NaN.

    Args:
        wheel_stamps_s: (N,) increasing wheel-speed stamps, s.
        omega: (N, 4) wheel speeds, rad/s.
        bin_ends_s: (M,) increasing bin ends (IMU stamps), s.
        bin_s: longest bin, s (1 / the core's sample rate).
        max_wheel_speed_rad_s: wheel speeds above this are bad, rad/s.

    Returns:
        (M, 4) mean wheel speed per bin.
    """
    stamps = np.asarray(wheel_stamps_s, dtype=float)
    omega = np.asarray(omega, dtype=float)
    ends = np.asarray(bin_ends_s, dtype=float)
    if stamps.ndim != 1 or omega.shape != (stamps.size, N_TIRES) or ends.ndim != 1:
        raise ValueError(f'bin_wheel_speeds: expected stamps (N,), omega (N, 4), bin ends '
                         f'(M,); got {stamps.shape}, {omega.shape}, {ends.shape}')
    if not (math.isfinite(bin_s) and bin_s > 0.0):
        raise ValueError(f'bin_wheel_speeds: bin_s must be finite and > 0, got {bin_s}')
    starts = np.maximum(np.concatenate([[-math.inf], ends[:-1]]), ends - bin_s)
    with np.errstate(invalid='ignore'):
        bad = ~np.isfinite(omega) | (omega < 0.0) | (omega > max_wheel_speed_rad_s)
    # cumulative sums over the samples give every bin's sum and bad count in one pass
    csum = np.vstack([np.zeros(N_TIRES), np.cumsum(np.where(bad, 0.0, omega), axis=0)])
    cbad = np.vstack([np.zeros(N_TIRES, dtype=np.int64), np.cumsum(bad, axis=0)])
    lo = np.searchsorted(stamps, starts, side='right')
    hi = np.searchsorted(stamps, ends, side='right')
    count = (hi - lo)[:, None]
    with np.errstate(invalid='ignore', divide='ignore'):
        mean = (csum[hi] - csum[lo]) / count
    return np.where((count > 0) & (cbad[hi] - cbad[lo] == 0), mean, np.nan)


def sample_and_hold(source_stamps_s: np.ndarray, values: np.ndarray, query_s: np.ndarray,
                    max_age_s: float) -> np.ndarray:
    """The newest value stamped at or before each query time; NaN where none or too old.

    The offline form of the nodes' driver-input hold (torque and steering at a bin's stamp).

    Args:
        source_stamps_s: (K,) increasing stamps of the held signal, s.
        values: (K,) or (K, D) values.
        query_s: (M,) query times, s.
        max_age_s: a value older than this at the query is stale (NaN), s.

    Returns:
        (M,) or (M, D) held values.
    """
    src = np.asarray(source_stamps_s, dtype=float)
    vals = np.asarray(values, dtype=float)
    query = np.asarray(query_s, dtype=float)
    if src.ndim != 1 or vals.shape[0] != src.size or query.ndim != 1:
        raise ValueError(f'sample_and_hold: expected stamps (K,), values (K, ...), query (M,); '
                         f'got {src.shape}, {vals.shape}, {query.shape}')
    if not src.size:
        return np.full((query.size,) + vals.shape[1:], np.nan)
    index = np.searchsorted(src, query, side='right') - 1
    safe = np.maximum(index, 0)
    fresh = (index >= 0) & (query - src[safe] <= max_age_s)
    held = vals[safe]
    mask = fresh.reshape((-1,) + (1,) * (vals.ndim - 1))
    return np.where(mask, held, np.nan)


def localise_low_tires(offset_change: np.ndarray, pair_std: np.ndarray,
                       params: WheelRadiusParams) -> LowTireLocalisation:
    """Turn pair offsets relative to nominal into low tires with a confidence.

    Pair offsets only see differences between tires: an equal loss in all four (diffusion) is
    invisible, and "three low" looks like "one high". Tires lose pressure, they do not gain it,
    so the drops rho >= 0 are found by non-negative least squares of
    offset_change = -PAIR_SENSITIVITY @ rho weighted by 1/pair_std, with a tiny ridge that picks
    the fewest/smallest drops among the equal fits (it removes the common mode). This names one
    tire, two (same axle, same side, diagonal) or three.

    Args:
        offset_change: (4,) delta_13, delta_24, delta_34, delta_12 minus their nominals.
        pair_std: (4,) noise std of each (inf or large: pair not informative).
        params: decision parameters (z_flag, z_full, radius_noise_floor).
    """
    change = np.asarray(offset_change, dtype=float)
    std = np.asarray(pair_std, dtype=float)
    if change.shape != (4,) or std.shape != (4,):
        raise ValueError('offset_change and pair_std must have shape (4,)')
    if not np.all(np.isfinite(change)) or np.any(~(std > 0.0)):
        raise ValueError('offset_change must be finite and pair_std > 0')
    weight = 1.0 / np.maximum(std, params.radius_noise_floor)
    design = -PAIR_SENSITIVITY * weight[:, None]
    target = change * weight
    ridge = 1e-6 * float(np.max(weight))

    # Per-tire std of the drop as it was estimated: least squares on the tires found low
    # (the others held at zero). The std from all four columns would be that of a tire's
    # drop relative to the mean of the four (the common mode removed), about half the std
    # of e.g. the rear axle against the front one: a rear-axle drift of 2.5 pair sigmas read
    # as 6 sigmas on the road simulator's nominal driving. A tire not found low gets the std
    # a drop of that tire alone would have.
    # A drop within ``z_keep`` sigmas of zero is noise, not a low tire: left in the fit it
    # would make its axle's (or side's) common level look unknown and inflate the sigma of
    # a real loss beside it (measured: a 0.1-sigma drop on RL turned RR's 25 % loss from 7
    # sigmas into 3). Such tires are taken out and the rest refitted, weakest first.
    drop, sigma = _low_tire_drops(design, target, ridge, params.z_keep,
                                  params.radius_noise_floor)
    residual = float(np.linalg.norm(design @ drop - target))
    z = drop / sigma
    return LowTireLocalisation(
        radius_drop=drop, sigma=sigma, z=z, flags=z >= params.z_flag,
        confidence=np.clip(z / params.z_full, 0.0, 1.0), residual=residual)


class WheelRadiusAnalyzer(CalibratedCore[WheelRadiusCalibration]):
    """Longitudinal and lateral radius filters, calibration and low-tire indication."""

    def __init__(self, params: WheelRadiusParams | None = None) -> None:
        self.params = params if params is not None else WheelRadiusParams()
        p = self.params
        front = p.driven_axle == 'front'
        # (driven, reference) wheel of the left and right side: the reference rolls free, or
        # with all four driven (rear against front) carries traction of its own
        self._driven = np.array([0, 1]) if front else np.array([2, 3])
        self._reference = np.array([2, 3]) if front else np.array([0, 1])
        self._reference_driven = p.driven_axle == 'all'
        # the filter's delta is 1 - r_rear / r_front (reported as the paper's delta_13, delta_24)
        self._rear_over_front = not front
        self._loads = np.asarray(p.static_load_n, dtype=float)
        # longitudinal load transfer per driven wheel and m/s^2 of ax: + on the rear axle
        transfer = float(self._loads.sum()) / GRAVITY * p.cg_height_m / (2.0 * p.wheelbase_m)
        self._load_transfer = transfer if not front else -transfer
        self._accel_sos = signal.butter(2, p.accel_filter_hz, fs=p.sample_rate_hz,
                                        output='sos')
        self._accel_zi_unit = signal.sosfilt_zi(self._accel_sos)
        self._calibration: WheelRadiusCalibration | None = None
        self._calibrating = False
        self.counts: dict[str, int] = dict.fromkeys(
            ('accepted', 'out_of_order', 'gap', 'bad_wheel_speed', 'bad_torque', 'bad_gyro',
             'gyro_stuck', 'long_gated', 'accel_gated', 'lat_gated'), 0)
        self.reset()

    def reset(self) -> None:
        """Restart both filters from their priors; keeps the calibration."""
        p = self.params
        self._long_x = [[0.0, 0.0], [0.0, 0.0]]         # per side: 1/k, delta
        self._long_p = [[p.inv_stiffness0_std ** 2, 0.0, p.delta0_std ** 2] for _ in range(2)]
        self._lat_x = np.zeros(5)
        self._lat_p = np.diag([0.1 ** 2, 0.5 ** 2, p.gyro_offset0_std_rad_s ** 2,
                               p.delta0_std ** 2, p.delta0_std ** 2])
        self._last_stamp: float | None = None
        self._last_gyro = math.nan
        self._gyro_repeat_s = 0.0
        self._last_bad_wheel = np.full(N_TIRES, -math.inf)
        self._cal_sum = np.zeros((3, 4))                # count, sum, sum of squares per pair
        # per pair, in the filter's terms: sums of a, z, z^2, delta z, delta, delta^2 (see
        # WheelRadiusCalibration.reference)
        self._cal_pair = np.zeros((6, 4))
        # noise check per pair: the open block's innovation sum and count; over the closed
        # blocks, the sum of (block sum)^2 / B and their number
        self._noise_block = np.zeros((2, 4))
        self._cal_noise = np.zeros((2, 4))
        self._cal_start: float | None = None
        # wheel-speed low-pass: its (sections, 2, wheels) state, started at the first sample
        self._accel_state = np.zeros((self._accel_sos.shape[0], 2, N_TIRES))
        self._accel_started = False
        self._last_smooth = np.zeros(N_TIRES)
        self._last_good_w = np.full(N_TIRES, np.nan)

    def restart_time(self) -> None:
        """A time jump (a looped replay, a clock reset): restart what depends on time (the yaw
        rate and acceleration states, the wheel-acceleration filter, the stuck-gyro and
        bad-wheel timers, the stamp order) and keep the learned state (1/k, the offsets, the
        gyro offset and their covariances) and the calibration."""
        self._last_stamp = None
        self._lat_x[:2] = 0.0
        self._lat_p[:2, :] = 0.0
        self._lat_p[:, :2] = 0.0
        self._lat_p[0, 0], self._lat_p[1, 1] = 0.1 ** 2, 0.5 ** 2
        self._last_gyro = math.nan
        self._gyro_repeat_s = 0.0
        self._last_bad_wheel[:] = -math.inf
        self._accel_started = False
        self._last_smooth = np.zeros(N_TIRES)
        self._last_good_w = np.full(N_TIRES, np.nan)

    def last_bad_wheel_s(self) -> np.ndarray:
        """(4,) stamp of each wheel's latest bad sample, s (-inf: none since the reset)."""
        return self._last_bad_wheel.copy()

    # ----------------------------------------------------------- calibration
    def start_calibration(self) -> None:
        """Start learning the nominal pair offsets from the data processed from now on."""
        self._calibrating = True
        self._cal_sum[:] = 0.0
        self._cal_pair[:] = 0.0
        self._noise_block[:] = 0.0
        self._cal_noise[:] = 0.0
        self._cal_start = None

    calibration_counts = 'valid updates per tire pair'
    calibration_channels = PAIR_NAMES

    @property
    def calibration_rate_hz(self) -> float:
        """Updates are counted at the analysis rate."""
        return self.params.sample_rate_hz

    def _calibration_from(self, mean: np.ndarray, std: np.ndarray,
                          duration_s: np.ndarray) -> WheelRadiusCalibration:
        count = self._cal_sum[0]
        # the nominal is the observable combination u = delta + a z at the window's mean a;
        # its spread over the window is that of u, not of delta alone
        a_sum, z_sum, z_sq, dz_sum, d_sum, d_sq = self._cal_pair / count
        reference = a_sum.copy()
        reference[2:] = 1.0 / a_sum[2:]                  # lateral: a = 1 / mean(c)
        u_var = (d_sq - d_sum * d_sum + 2.0 * reference * (dz_sum - d_sum * z_sum)
                 + reference * reference * (z_sq - z_sum * z_sum))
        std = np.sqrt(np.maximum(u_var, 0.0))
        if self._rear_over_front:
            std[:2] = std[:2] / (1.0 - d_sum[:2]) ** 2
        std = np.maximum(std, 1e-9)
        return WheelRadiusCalibration(mean, std, duration_s, reference, z_sum,
                                      self._noise_scale())

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Put a persisted calibration in force; raises ValueError if it is corrupt."""
        self._calibration = WheelRadiusCalibration.from_dict(state)

    # ------------------------------------------------------------ processing
    def process(self, stamps_s: np.ndarray, omega: np.ndarray, yaw_rate: np.ndarray,
                wheel_torque: np.ndarray, steering_angle: np.ndarray | None = None
                ) -> RadiusEstimate:
        """Process a chunk of synchronised samples at about ``sample_rate_hz``.

        Args:
            stamps_s: (N,) sample times, s. Samples not later than the latest accepted one are
                rejected (out of order / repeated).
            omega: (N, 4) wheel angular speeds, rad/s (e.g. the mean over each 10 ms).
            yaw_rate: (N,) IMU angular_velocity.z, rad/s, REP 103 (positive turning left).
            wheel_torque: (N, 4) wheel torques, N m, drive +, brake -.
            steering_angle: (N,) front road-wheel angle, rad, or None.
        """
        p = self.params
        stamps = np.asarray(stamps_s, dtype=float)
        n = stamps.shape[0] if stamps.ndim == 1 else -1
        omega = np.asarray(omega, dtype=float)
        gyro = np.asarray(yaw_rate, dtype=float)
        torque = np.asarray(wheel_torque, dtype=float)
        steer = np.zeros(n) if steering_angle is None else np.asarray(steering_angle, float)
        if n < 0 or omega.shape != (n, N_TIRES) or gyro.shape != (n,) or \
                torque.shape != (n, N_TIRES) or steer.shape != (n,):
            raise ValueError(
                f'process: expected stamps_s (N,), omega (N, 4), yaw_rate (N,), wheel_torque '
                f'(N, 4), steering_angle (N,); got {stamps.shape}, {omega.shape}, '
                f'{gyro.shape}, {torque.shape}, {steer.shape}')

        # ---- accept stamps strictly after every earlier one (NaN stamps rejected too)
        last = -math.inf if self._last_stamp is None else self._last_stamp
        finite_stamps = np.where(np.isfinite(stamps), stamps, -math.inf)
        prev_max = np.maximum.accumulate(np.concatenate([[last], finite_stamps]))[:-1]
        accepted = np.isfinite(stamps) & (stamps > prev_max)
        self.counts['out_of_order'] += int(n - accepted.sum())
        stamps, omega, gyro, torque, steer = (stamps[accepted], omega[accepted], gyro[accepted],
                                              torque[accepted], steer[accepted])
        m = stamps.shape[0]
        self.counts['accepted'] += m
        if m == 0:
            return self._estimate(np.zeros(0), np.zeros((0, 5)))
        dt = np.diff(np.concatenate([[stamps[0] - 1.0 / p.sample_rate_hz if
                                      self._last_stamp is None else self._last_stamp],
                                     stamps]))
        gap = dt > p.max_gap_s
        self.counts['gap'] += int(gap.sum())
        self._last_stamp = float(stamps[-1])

        # ---- per-sample validity and measurements, vectorised
        with np.errstate(invalid='ignore'):
            wheel_ok = np.isfinite(omega) & (omega >= 0.0) & (omega <= p.max_wheel_speed_rad_s)
        self.counts['bad_wheel_speed'] += int((~wheel_ok).sum())
        bad_rows = ~wheel_ok
        if bad_rows.any():
            last_bad = np.where(bad_rows, stamps[:, None], -math.inf).max(axis=0)
            self._last_bad_wheel = np.maximum(self._last_bad_wheel, last_bad)
        w = np.where(wheel_ok, omega, 0.0)
        torque_ok = np.all(np.isfinite(torque), axis=1)
        self.counts['bad_torque'] += int((~torque_ok).sum())
        gyro_finite = np.isfinite(gyro)
        self.counts['bad_gyro'] += int((~gyro_finite).sum())
        gyro_stuck = self._gyro_stuck(gyro, dt)
        self.counts['gyro_stuck'] += int(gyro_stuck.sum())
        steer_ok = np.isfinite(steer) & (np.abs(steer) < 1.0)
        cos_steer = np.cos(np.where(steer_ok, steer, 0.0))

        r_n = p.nominal_radius_m
        rear_ok = wheel_ok[:, 2] & wheel_ok[:, 3]
        front_ok = wheel_ok[:, 0] & wheel_ok[:, 1] & steer_ok
        # wheel-based yaw rates, SAE sign (v_left - v_right) / track
        yaw_rear = r_n * (w[:, 2] - w[:, 3]) / p.track_rear_m
        yaw_front = r_n * (w[:, 0] - w[:, 1]) / (p.track_front_m * cos_steer)
        # H's coefficient of delta uses the axle's mean wheel speed, not omega3 / omega1 as
        # written in the paper: the measurement r_n (omega3 - omega4) / L carries omega3's noise
        # too, and with omega3 in H that common noise is an errors-in-variables regressor that
        # drags delta towards -1 along the (delta_o, delta) ridge left unobservable at
        # constant speed (measured: delta_34 = -4.6 % and a gyro offset of -1 rad/s after
        # 90 s of steady cruising on the road simulator). (omega3 + omega4) / 2 has noise
        # uncorrelated with omega3 - omega4 when the two wheels are equally noisy; the
        # difference to the paper's coefficient is second order (delta x psi_dot / 2).
        c_rear = r_n * 0.5 * (w[:, 2] + w[:, 3]) / p.track_rear_m
        c_front = r_n * 0.5 * (w[:, 0] + w[:, 1]) / (p.track_front_m * cos_steer)
        n_ok = wheel_ok.sum(axis=1)
        speed = r_n * w.sum(axis=1) / np.maximum(n_ok, 1)
        yaw_wheels = np.where(rear_ok, yaw_rear, yaw_front)
        lateral_acc = np.abs(speed * yaw_wheels)
        in_band = (n_ok > 0) & (speed >= p.min_speed_mps) & (speed <= p.max_speed_mps)

        # longitudinal: slip of driven vs non-driven wheel per side, mu of the driven wheel
        wd = w[:, self._driven]
        wn = w[:, self._reference]
        side_ok = wheel_ok[:, self._driven] & wheel_ok[:, self._reference] & (wn > 0.0)
        with np.errstate(divide='ignore', invalid='ignore'):
            slip = np.where(side_ok, wd / wn - 1.0, 0.0)
            slip_var = np.where(side_ok, 2.0 * (p.wheel_speed_noise_mps / (r_n * wn)) ** 2,
                                1.0)
        omega_dot = self._wheel_acceleration(omega, wheel_ok, dt)
        ax = r_n * omega_dot[:, self._reference].mean(axis=1)
        mu = self._traction(self._driven, self._load_transfer, torque, torque_ok, omega_dot, ax)
        traction_ok = np.abs(mu) <= p.mu_max
        if self._reference_driven:
            mu_reference = self._traction(self._reference, -self._load_transfer, torque,
                                          torque_ok, omega_dot, ax)
            traction_ok &= np.abs(mu_reference) <= p.mu_max
            mu = mu - mu_reference
        braking = np.any(np.where(torque_ok[:, None], torque, 0.0) < -p.brake_torque_nm, axis=1)
        # a wheel bad within wheel_recover_s leaves its filtered derivative unreliable
        recent_bad = (stamps[:, None] - self._last_bad_wheel < p.wheel_recover_s).any(axis=1)
        steady = (np.abs(ax) <= p.accel_max_longitudinal_mps2) & ~recent_bad
        lat_steady = (np.abs(ax) <= p.accel_max_lateral_mps2) & ~recent_bad
        self.counts['accel_gated'] += int((in_band & ~steady).sum())
        long_cond = (in_band & torque_ok & ~braking & steady
                     & (lateral_acc <= p.ay_max_longitudinal_mps2))[:, None]
        long_valid = side_ok & long_cond & traction_ok & (np.abs(slip) <= p.slip_max)
        self.counts['long_gated'] += int((side_ok & ~long_valid).sum())

        lat_cond = in_band & (lateral_acc <= p.ay_max_lateral_mps2) & ~gyro_stuck & lat_steady
        use_gyro = lat_cond & gyro_finite & (rear_ok | front_ok)
        use_rear = lat_cond & rear_ok
        use_front = lat_cond & front_ok
        self.counts['lat_gated'] += int((~lat_cond & (rear_ok | front_ok)).sum())
        z_gyro = np.where(gyro_finite, -gyro, 0.0)      # REP 103 -> SAE sign

        trace, long_trace, residual = self._run_filters(
            dt, gap, slip, slip_var, mu, long_valid, z_gyro, yaw_rear, yaw_front, c_rear,
            c_front, use_gyro, use_rear, use_front)
        if self._calibrating:
            self._accumulate_calibration(stamps, trace, long_trace, residual, mu, c_rear,
                                         c_front, long_valid, use_rear, use_front)
        trace[:, 4] = -trace[:, 4]                        # gyro offset back to REP 103
        return self._estimate(stamps, trace)

    def _traction(self, wheels: np.ndarray, load_transfer: float, torque: np.ndarray,
                  torque_ok: np.ndarray, omega_dot: np.ndarray, ax: np.ndarray) -> np.ndarray:
        """(N, 2) mu = Fx / Fz at the contact of two wheels: the drive torque less what spins
        the wheel up, over the static load plus the longitudinal load transfer (per wheel and
        m/s^2 of ax)."""
        p = self.params
        drive = np.where(torque_ok[:, None], torque[:, wheels], 0.0)
        force = (drive - p.wheel_inertia_kgm2 * omega_dot[:, wheels]) / p.nominal_radius_m
        load = self._loads[wheels] + load_transfer * ax[:, None]
        return force / np.maximum(load, 0.1 * self._loads[wheels])

    def _wheel_acceleration(self, omega: np.ndarray, wheel_ok: np.ndarray,
                            dt: np.ndarray) -> np.ndarray:
        """(N, 4) low-passed wheel angular accelerations, rad/s^2, state carried.

        Bad samples hold the last good speed (a dead wheel reads 0 acceleration; its own gate
        is ``wheel_recover_s``). The 2nd-order Butterworth starts in the steady state of the
        first good sample so the filter does not ring from zero. The recursion is compiled
        (:func:`_wheel_acceleration_filter`).
        """
        omega_dot = np.empty(omega.shape)
        _wheel_acceleration_filter(omega, wheel_ok, dt, self._accel_sos, self._accel_zi_unit,
                                   not self._accel_started, self._accel_state,
                                   self._last_good_w, self._last_smooth, omega_dot)
        self._accel_started = True
        return omega_dot

    def _gyro_stuck(self, gyro: np.ndarray, dt: np.ndarray) -> np.ndarray:
        """Flag samples where the gyro has repeated the exact same value too long."""
        same = np.concatenate([[self._last_gyro], gyro[:-1]]) == gyro
        # running time of repeats, reset at each change; cumulative sums keep it vectorised
        elapsed = np.cumsum(np.where(same, dt, 0.0))
        reset_at = np.maximum.accumulate(np.where(~same, elapsed, 0.0))
        repeat_time = elapsed - reset_at
        repeat_time = np.where(np.cumsum(~same) == 0, repeat_time + self._gyro_repeat_s,
                               repeat_time)
        stuck = repeat_time >= self.params.gyro_stuck_s
        self._gyro_repeat_s = float(repeat_time[-1])
        self._last_gyro = float(gyro[-1])
        return stuck

    def _run_filters(self, dt: np.ndarray, gap: np.ndarray, slip: np.ndarray,
                     slip_var: np.ndarray, mu: np.ndarray, long_valid: np.ndarray,
                     z_gyro: np.ndarray, yaw_rear: np.ndarray, yaw_front: np.ndarray,
                     c_rear: np.ndarray, c_front: np.ndarray, use_gyro: np.ndarray,
                     use_rear: np.ndarray, use_front: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The recursion: one predict and up to five scalar updates per sample.

        Returns:
            (M, 5) trace as in :class:`RadiusEstimate`; (M, 4) longitudinal states in the
            filter's own terms: delta left, delta right, 1/k left, 1/k right; (M, 4)
            residuals y = z - h x of the measurement behind each pair (slip left, slip right,
            rear and front wheel yaw rate) over the assumed noise std, NaN where it was not
            updated.
        """
        p = self.params
        m = dt.shape[0]
        trace = np.empty((m, 5))
        long_trace = np.empty((m, 4))
        residual = np.full((m, 4), np.nan)
        constants = np.array([p.inv_stiffness_rw ** 2, p.delta_rw ** 2, p.gyro_offset_rw ** 2,
                              p.yaw_jerk_std_rad_s3 ** 2, p.gyro_noise_std_rad_s ** 2,
                              p.wheel_yaw_noise_std_rad_s ** 2,
                              1.0 / p.wheel_yaw_noise_std_rad_s, 0.1 ** 2, 0.5 ** 2])
        long_x, long_p = np.array(self._long_x), np.array(self._long_p)
        _radius_filters(
            np.ascontiguousarray(dt, dtype=float), np.ascontiguousarray(gap, dtype=bool),
            np.ascontiguousarray(slip, dtype=float), np.ascontiguousarray(slip_var, dtype=float),
            np.ascontiguousarray(mu, dtype=float), np.ascontiguousarray(long_valid, dtype=bool),
            np.stack([z_gyro, yaw_rear, yaw_front], axis=1).astype(float),
            np.stack([use_gyro, use_rear, use_front], axis=1).astype(bool),
            np.ascontiguousarray(c_rear, dtype=float), np.ascontiguousarray(c_front, dtype=float),
            constants, long_x, long_p, self._lat_x, self._lat_p, trace, long_trace, residual)
        self._long_x, self._long_p = long_x.tolist(), long_p.tolist()
        if self._rear_over_front:
            # filter delta = 1 - r_rear / r_front; paper's delta_13 = 1 - r1 / r3 = -d / (1 - d)
            trace[:, :2] = -trace[:, :2] / (1.0 - trace[:, :2])
        return trace, long_trace, residual

    def _accumulate_calibration(self, stamps: np.ndarray, trace: np.ndarray,
                                long_trace: np.ndarray, residual: np.ndarray, mu: np.ndarray,
                                c_rear: np.ndarray, c_front: np.ndarray,
                                long_valid: np.ndarray, use_rear: np.ndarray,
                                use_front: np.ndarray) -> None:
        if self._cal_start is None:
            self._cal_start = float(stamps[0])
        settled = stamps >= self._cal_start + self.params.calibration_settle_s
        valid = np.stack([long_valid[:, 0], long_valid[:, 1], use_rear, use_front], axis=1)
        valid &= settled[:, None]
        vals = np.where(valid, trace[:, :4], 0.0)
        self._cal_sum += np.stack([valid.sum(axis=0), vals.sum(axis=0),
                                   (vals * vals).sum(axis=0)])
        # in the filter's terms: a = mu (longitudinal) or c (lateral, inverted at the end)
        delta = np.where(valid, np.column_stack([long_trace[:, :2], trace[:, 2:4]]), 0.0)
        comp = np.where(valid, np.column_stack([long_trace[:, 2:], trace[:, 4], trace[:, 4]]),
                        0.0)
        coef = np.where(valid, np.column_stack([mu, c_rear, c_front]), 0.0)
        self._cal_pair += np.stack([coef.sum(axis=0), comp.sum(axis=0),
                                    (comp * comp).sum(axis=0), (delta * comp).sum(axis=0),
                                    delta.sum(axis=0), (delta * delta).sum(axis=0)])
        self._accumulate_noise(np.where(settled[:, None], residual, np.nan))

    def _accumulate_noise(self, residual: np.ndarray) -> None:
        """Close the blocks of ``noise_block_s`` worth of normalised innovations per pair
        (NaN: no update).

        Blocks count updates, not time, and carry over chunks, so the result does not depend
        on how the data was chunked.
        """
        block = max(1, round(self.params.noise_block_s * self.params.sample_rate_hz))
        for pair in range(4):
            values = residual[:, pair]
            values = values[np.isfinite(values)]
            if not values.size:
                continue
            open_sum, open_count = self._noise_block[:, pair]
            running = open_sum + np.cumsum(values)
            counts = open_count + np.arange(1, values.size + 1)
            ends = np.flatnonzero(counts % block == 0)
            if ends.size:
                sums = np.diff(np.concatenate([[0.0], running[ends]]))
                self._cal_noise[:, pair] += (float(np.sum(sums * sums)) / block, ends.size)
                open_sum = running[-1] - running[ends[-1]]
            else:
                open_sum = running[-1]
            self._noise_block[:, pair] = (open_sum, counts[-1] % block)

    def _noise_scale(self) -> np.ndarray:
        """(4,) per-pair factor >= 1 on the filter std from the calibration's noise check:
        the innovations are normalised by their assumed std, so white noise as assumed has
        a low-frequency power of 1."""
        power, blocks = self._cal_noise
        density = np.divide(power, blocks, out=np.ones(4), where=blocks > 0)
        return np.sqrt(np.maximum(density, 1.0))

    def _offsets_std(self) -> np.ndarray:
        lp = self._long_p
        std = np.sqrt([lp[0][2], lp[1][2], self._lat_p[3, 3], self._lat_p[4, 4]])
        if self._calibration is not None:
            std *= self._calibration.noise_scale
        if self._rear_over_front:
            std[:2] /= (1.0 - np.array([self._long_x[0][1], self._long_x[1][1]])) ** 2
        return std

    def _estimate(self, stamps: np.ndarray, trace: np.ndarray) -> RadiusEstimate:
        offsets = self.offsets()
        return RadiusEstimate(
            offsets=offsets,
            offsets_std=self._offsets_std(),
            gyro_offset=-float(self._lat_x[2]),
            inv_stiffness=np.array([self._long_x[0][0], self._long_x[1][0]]),
            trace_stamps=stamps,
            trace=trace,
            counts=dict(self.counts),
            gyro_ok=self._gyro_repeat_s < self.params.gyro_stuck_s,
            calibrated=self._calibration is not None,
        )

    def offsets(self) -> np.ndarray:
        """(4,) current delta_13, delta_24, delta_34, delta_12 (raw)."""
        d_left, d_right = self._long_x[0][1], self._long_x[1][1]
        if self._rear_over_front:
            d_left, d_right = -d_left / (1.0 - d_left), -d_right / (1.0 - d_right)
        return np.array([d_left, d_right, self._lat_x[3], self._lat_x[4]])

    @property
    def lateral_covariance(self) -> np.ndarray:
        """Copy of the lateral filter's 5x5 covariance (for health checks)."""
        return self._lat_p.copy()

    # ------------------------------------------------------------ indication
    def localise(self) -> LowTireLocalisation | None:
        """Low tires from the current offsets relative to the calibration (None: uncalibrated)."""
        cal = self._calibration
        if cal is None:
            return None
        change, estimate_std = self._offset_change(cal)
        std = np.sqrt(estimate_std ** 2 + cal.noise ** 2)
        return localise_low_tires(change, std, self.params)

    def _offset_change(self, cal: WheelRadiusCalibration) -> tuple[np.ndarray, np.ndarray]:
        """(4,) pair offsets relative to the calibration and (4,) the std of the estimate."""
        ref = cal.reference
        lp, lat_p = self._long_p, self._lat_p
        # current u = delta + a z per pair in the filter's terms, and its posterior std
        delta = np.array([self._long_x[0][1], self._long_x[1][1], self._lat_x[3],
                          self._lat_x[4]])
        comp = np.array([self._long_x[0][0], self._long_x[1][0], self._lat_x[2],
                         self._lat_x[2]])
        var = np.array([lp[0][2] + 2.0 * ref[0] * lp[0][1] + ref[0] ** 2 * lp[0][0],
                        lp[1][2] + 2.0 * ref[1] * lp[1][1] + ref[1] ** 2 * lp[1][0],
                        lat_p[3, 3] + 2.0 * ref[2] * lat_p[2, 3] + ref[2] ** 2 * lat_p[2, 2],
                        lat_p[4, 4] + 2.0 * ref[3] * lat_p[2, 4] + ref[3] ** 2 * lat_p[2, 2]])
        u_now = delta + ref * comp
        std = np.sqrt(np.maximum(var, 0.0)) * cal.noise_scale
        d_cal = cal.nominal_offsets.copy()
        if self._rear_over_front:
            # filter terms back from the paper's delta_13 = -d / (1 - d) (an involution)
            d_cal[:2] = -d_cal[:2] / (1.0 - d_cal[:2])
        u_cal = d_cal + ref * cal.companion
        if self._rear_over_front:
            std[:2] = std[:2] / (1.0 - u_now[:2]) ** 2
            u_now[:2] = -u_now[:2] / (1.0 - u_now[:2])
            u_cal[:2] = -u_cal[:2] / (1.0 - u_cal[:2])
        return u_now - u_cal, std

    def indication(self, stamp_s: float) -> TpmsIndication:
        """Per-tire flag and confidence (all unknown before calibration).

        A tire is unknown while its wheel speed was bad within ``wheel_recover_s`` or when no
        pair it belongs to is informative (posterior std of the compared combination above
        ``informative_std``).
        """
        loc = self.localise()
        cal = self._calibration
        if loc is None or cal is None:
            zeros = np.zeros(N_TIRES)
            return TpmsIndication('wheel_radius', stamp_s, zeros.astype(bool), zeros,
                                  zeros.astype(bool))
        # informative: the std of what is compared (the pair's observable combination)
        informative_pair = self._offset_change(cal)[1] <= self.params.informative_std
        informative = np.zeros(N_TIRES, dtype=bool)
        for pair, tires in enumerate(PAIR_TIRES):
            if informative_pair[pair]:
                informative[list(tires)] = True
        sensor_ok = stamp_s - self._last_bad_wheel >= self.params.wheel_recover_s
        known = informative & sensor_ok
        return TpmsIndication(
            method='wheel_radius',
            stamp_s=stamp_s,
            underinflated=loc.flags & known,
            confidence=np.where(known, loc.confidence, 0.0),
            known=known,
        )


_F1, _F2, _F3 = types.float64[:], types.float64[:, :], types.float64[:, :, :]
_B1, _B2 = types.boolean[:], types.boolean[:, :]


@njit(types.void(_F1, _B1, _F2, _F2, _F2, _B2, _F2, _B2, _F1, _F1, _F1,
                 _F2, _F2, _F1, _F2, _F2, _F2, _F2), cache=True, error_model='numpy')
def _radius_filters(dt: np.ndarray, gap: np.ndarray, slip: np.ndarray, slip_var: np.ndarray,
                    mu: np.ndarray, long_valid: np.ndarray, z: np.ndarray, use: np.ndarray,
                    c_rear: np.ndarray, c_front: np.ndarray, constants: np.ndarray,
                    long_x: np.ndarray, long_p: np.ndarray, x: np.ndarray, cov: np.ndarray,
                    trace: np.ndarray, long_trace: np.ndarray, residual: np.ndarray) -> None:
    """The recursion of :meth:`WheelRadiusAnalyzer._run_filters`, compiled (numba): one
    predict and up to five scalar updates per sample, states updated in place.

    Why compiled: as Python with numpy on the 5-state lateral filter it cost ~80 us a sample
    (some fifteen small-array calls). Every operation is the elementwise one numpy did, in the
    same order (no matrix product, no fast-math), so the results are the same to the bit.

    Args:
        z, use: (M, 3) gyro, rear and front wheel yaw-rate measurements and whether each
            updates the lateral filter.
        constants: q_k, q_d, q_o, q_jerk, r_gyro, r_wheel, 1 / wheel yaw-rate noise std, the
            yaw rate and yaw acceleration prior variances.
        long_x, long_p: (2, 2) per side 1/k, delta; (2, 3) per side p11, p12, p22.
        x, cov: the lateral state (5,) and covariance (5, 5).
        trace, long_trace, residual: (M, 5), (M, 4), (M, 4) outputs (residual NaN-filled).
    """
    q_k, q_d, q_o, q_jerk = constants[0], constants[1], constants[2], constants[3]
    r_gyro, r_wheel, inv_wheel_std = constants[4], constants[5], constants[6]
    rw_diag = np.array([0.0, 0.0, q_o, q_d, q_d])
    n_x = x.shape[0]
    ph = np.empty(n_x)
    for i in range(dt.shape[0]):
        ts = dt[i]
        # ---- longitudinal, per side: x = (1/k, delta), P = [p11, p12, p22]
        for side in range(2):
            long_p[side, 0] += q_k * ts
            long_p[side, 2] += q_d * ts
            if long_valid[i, side]:
                mu_i = mu[i, side]
                ph1 = long_p[side, 0] * mu_i + long_p[side, 1]
                ph2 = long_p[side, 1] * mu_i + long_p[side, 2]
                r_slip = slip_var[i, side]
                s_inv = 1.0 / (mu_i * ph1 + ph2 + r_slip)
                y = slip[i, side] - mu_i * long_x[side, 0] - long_x[side, 1]
                residual[i, side] = y / math.sqrt(r_slip)
                long_x[side, 0] += ph1 * y * s_inv
                long_x[side, 1] += ph2 * y * s_inv
                long_p[side, 0] -= ph1 * ph1 * s_inv
                long_p[side, 1] -= ph1 * ph2 * s_inv
                long_p[side, 2] -= ph2 * ph2 * s_inv
        # ---- lateral predict with F's structure
        if gap[i]:
            # a gap breaks the yaw dynamics: restart yaw rate/acceleration from the prior
            x[0] = x[1] = 0.0
            cov[:2, :] = 0.0
            cov[:, :2] = 0.0
            cov[0, 0], cov[1, 1] = constants[7], constants[8]
        else:
            x[0] += ts * x[1]
            for j in range(n_x):
                cov[0, j] += ts * cov[1, j]
            for j in range(n_x):
                cov[j, 0] += ts * cov[j, 1]
            ts2 = ts * ts
            cov[0, 0] += q_jerk * ts2 * ts2 * 0.25
            cov[0, 1] += q_jerk * ts2 * ts * 0.5
            cov[1, 0] += q_jerk * ts2 * ts * 0.5
            cov[1, 1] += q_jerk * ts2
        for j in range(n_x):
            for k in range(n_x):
                # numpy added the whole diagonal matrix: + 0.0 off the diagonal (-0.0 -> 0.0)
                cov[j, k] += rw_diag[j] * ts if j == k else 0.0
        # ---- sequential scalar updates (R diagonal => equal to the joint update)
        for update in range(3):
            if not use[i, update]:
                continue
            if update == 0:       # h = (1, 0, 1, 0, 0)
                for j in range(n_x):
                    ph[j] = cov[j, 0] + cov[j, 2]
                s = ph[0] + ph[2] + r_gyro
                gain = (z[i, 0] - x[0] - x[2]) / s
            else:                 # h = (1, 0, 0, -c3, 0) rear, (1, 0, 0, 0, -c1) front
                c = c_rear[i] if update == 1 else c_front[i]
                col = 2 + update
                for j in range(n_x):
                    ph[j] = cov[j, 0] - c * cov[j, col]
                s = ph[0] - c * ph[col] + r_wheel
                y = z[i, update] - x[0] + c * x[col]
                residual[i, update + 1] = y * inv_wheel_std
                gain = y / s
            inv_s = 1.0 / s
            for j in range(n_x):
                x[j] += ph[j] * gain
            for j in range(n_x):
                for k in range(n_x):
                    cov[j, k] -= ph[j] * ph[k] * inv_s
        trace[i, 0] = long_trace[i, 0] = long_x[0, 1]
        trace[i, 1] = long_trace[i, 1] = long_x[1, 1]
        long_trace[i, 2] = long_x[0, 0]
        long_trace[i, 3] = long_x[1, 0]
        trace[i, 2] = x[3]
        trace[i, 3] = x[4]
        trace[i, 4] = x[2]


@njit(types.void(_F2, _B2, _F1, _F2, _F2, types.boolean, _F3, _F1, _F1, _F2), cache=True,
      error_model='numpy')
def _wheel_acceleration_filter(omega: np.ndarray, wheel_ok: np.ndarray, dt: np.ndarray,
                               sos: np.ndarray, zi_unit: np.ndarray, start: bool,
                               state: np.ndarray, last_good: np.ndarray,
                               last_smooth: np.ndarray, omega_dot: np.ndarray) -> None:
    """The recursion of :meth:`WheelRadiusAnalyzer._wheel_acceleration`, compiled (numba):
    per wheel, hold the last good speed, low-pass it (scipy's ``sosfilt``: transposed direct
    form II) and difference it over dt; states updated in place.

    Why compiled: as numpy (a forward fill of the bad samples, ``sosfilt``, the difference)
    it was some twenty array calls, ~50 us a chunk of five samples, a quarter of the core's
    time. Every operation is the one numpy and scipy did, in the same order (no fast-math), so
    the results are the same to rounding (bit for bit on this project's machines).

    Args:
        omega, wheel_ok: (N, 4) wheel speeds and whether each is good.
        dt: (N,) sample intervals, s.
        sos, zi_unit: the low-pass's sections and their steady state for a unit input.
        start: start the filter in the steady state of the first sample (held speed).
        state: (sections, 2, 4) the filter's state.
        last_good, last_smooth: (4,) the held speed (NaN: none yet) and the filtered speed of
            the previous sample.
        omega_dot: (N, 4) output, the wheel angular accelerations, rad/s^2.
    """
    for w in range(omega.shape[1]):
        held, previous = last_good[w], last_smooth[w]
        for i in range(omega.shape[0]):
            if wheel_ok[i, w]:
                held = omega[i, w]
            # a wheel without a good sample since the restart reads 0
            x = 0.0 if math.isnan(held) else held
            if start and i == 0:
                for s in range(sos.shape[0]):
                    state[s, 0, w] = zi_unit[s, 0] * x
                    state[s, 1, w] = zi_unit[s, 1] * x
                previous = x
            for s in range(sos.shape[0]):
                y = sos[s, 0] * x + state[s, 0, w]
                state[s, 0, w] = sos[s, 1] * x - sos[s, 4] * y + state[s, 1, w]
                state[s, 1, w] = sos[s, 2] * x - sos[s, 5] * y
                x = y
            omega_dot[i, w] = (x - previous) / dt[i]
            previous = x
        last_good[w], last_smooth[w] = held, previous


@njit(cache=True, error_model='numpy')
def _columns(matrix: np.ndarray, selected: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the indices of the ``selected`` columns, a copy of those columns)."""
    rows, n = matrix.shape
    count = 0
    for j in range(n):
        count += 1 if selected[j] else 0
    index = np.empty(count, dtype=np.int64)
    chosen = np.empty((rows, count))
    c = 0
    for j in range(n):
        if selected[j]:
            index[c] = j
            for i in range(rows):
                chosen[i, c] = matrix[i, j]
            c += 1
    return index, chosen


@njit(cache=True, error_model='numpy')
def _least_squares(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ||a x - b|| for ``a`` of full column rank: Householder QR and back substitution,
    as loops (numba's ``np.linalg.lstsq`` took 5 s to compile at first import)."""
    m, n = a.shape
    r, y, v = a.copy(), b.copy(), np.empty(m)
    for j in range(n):
        norm = 0.0
        for i in range(j, m):
            norm += r[i, j] * r[i, j]
        norm = math.sqrt(norm)
        alpha = -norm if r[j, j] > 0.0 else norm
        length = 0.0
        for i in range(j, m):
            v[i] = r[i, j] - (alpha if i == j else 0.0)
            length += v[i] * v[i]
        if length == 0.0:
            continue
        for k in range(j, n):
            dot = 0.0
            for i in range(j, m):
                dot += v[i] * r[i, k]
            for i in range(j, m):
                r[i, k] -= 2.0 * dot / length * v[i]
        dot = 0.0
        for i in range(j, m):
            dot += v[i] * y[i]
        for i in range(j, m):
            y[i] -= 2.0 * dot / length * v[i]
    x = np.zeros(n)
    for i in range(n - 1, -1, -1):
        total = y[i]
        for k in range(i + 1, n):
            total -= r[i, k] * x[k]
        x[i] = total / r[i, i]
    return x


@njit(cache=True, error_model='numpy')
def _ridge_nnls(design: np.ndarray, target: np.ndarray, ridge: float,
                columns: np.ndarray) -> np.ndarray:
    """The non-negative least squares of ``design[:, columns] @ x = target`` with a ridge
    (rows ``ridge * I`` against zeros); zero outside ``columns``."""
    rows, n = design.shape
    index, chosen = _columns(design, columns)
    k = index.size
    a = np.zeros((rows + k, k))
    b = np.zeros(rows + k)
    for c in range(k):
        for i in range(rows):
            a[i, c] = chosen[i, c]
        a[rows + c, c] = ridge
    for i in range(rows):
        b[i] = target[i]
    solution = _lawson_hanson(a, b)
    drop = np.zeros(n)
    for c in range(k):
        drop[index[c]] = solution[c]
    return drop


@njit(cache=True, error_model='numpy')
def _gradient(a: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """a^T (b - a x)."""
    m, n = a.shape
    residual = b.copy()
    for i in range(m):
        for j in range(n):
            residual[i] -= a[i, j] * x[j]
    gradient = np.zeros(n)
    for j in range(n):
        for i in range(m):
            gradient[j] += a[i, j] * residual[i]
    return gradient


@njit(cache=True, error_model='numpy')
def _lawson_hanson(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """argmin ||a x - b|| over x >= 0 (Lawson and Hanson's active set method, as scipy's
    ``optimize.nnls``; at most 3 n rounds)."""
    m, n = a.shape
    column_sum = 0.0
    for j in range(n):
        total = 0.0
        for i in range(m):
            total += abs(a[i, j])
        column_sum = max(column_sum, total)
    tol = 10.0 * _EPS * column_sum * max(m, n)
    x = np.zeros(n)
    passive = np.zeros(n, dtype=np.bool_)
    gradient = _gradient(a, b, x)
    for _ in range(3 * n):
        entering, best = -1, tol
        for j in range(n):
            if not passive[j] and gradient[j] > best:
                entering, best = j, gradient[j]
        if entering < 0:
            break
        passive[entering] = True
        while True:
            index, sub = _columns(a, passive)
            k = index.size
            solution = _least_squares(sub, b)
            trial = np.zeros(n)
            positive = True
            for c in range(k):
                trial[index[c]] = solution[c]
                positive = positive and solution[c] > 0.0
            if positive:
                x = trial
                break
            step = math.inf
            for c in range(k):
                if trial[index[c]] <= 0.0:
                    step = min(step, x[index[c]] / (x[index[c]] - trial[index[c]]))
            for j in range(n):
                x[j] += step * (trial[j] - x[j])
            for c in range(k):
                if x[index[c]] <= tol:
                    passive[index[c]] = False
                    x[index[c]] = 0.0
        gradient = _gradient(a, b, x)
    return x


@njit(cache=True, error_model='numpy')
def _drop_sigma(design: np.ndarray, active: np.ndarray, noise_floor: float) -> np.ndarray:
    """Each tire's drop std: from the least squares on the ``active`` tires where active,
    of a drop of that tire alone elsewhere; at least ``noise_floor``."""
    rows, n = design.shape
    variance = np.empty(n)
    for j in range(n):
        total = 0.0
        for i in range(rows):
            total += design[i, j] * design[i, j]
        variance[j] = 1.0 / max(total, 1e-300)
    index, chosen = _columns(design, active)
    k = index.size
    if k:
        gram = np.empty((k, k))
        for p in range(k):
            for q in range(k):
                total = 0.0
                for i in range(rows):
                    total += chosen[i, p] * chosen[i, q]
                gram[p, q] = total
        inverse = np.linalg.pinv(gram)
        for c in range(k):
            variance[index[c]] = inverse[c, c]
    sigma = np.empty(n)
    for j in range(n):
        sigma[j] = max(math.sqrt(max(variance[j], 0.0)), noise_floor)
    return sigma


@njit(types.UniTuple(types.float64[:], 2)(types.float64[:, :], types.float64[:], types.float64,
                                          types.float64, types.float64),
      cache=True, error_model='numpy')
def _low_tire_drops(design: np.ndarray, target: np.ndarray, ridge: float, z_keep: float,
                    noise_floor: float) -> tuple[np.ndarray, np.ndarray]:
    """The drops and their sigmas of :func:`localise_low_tires`, compiled (numba): the
    non-negative ridge fit on all four tires, then the weak drops taken out one by one.

    Why compiled: as numpy and scipy (``optimize.nnls`` on the stacked ridge system,
    ``linalg.pinv`` for the sigmas, two or three rounds) it was some 0.5 ms of call overhead
    on 4 x 4 matrices at every wheel-radius indication, most of the indication's cost and of
    its latency. The same fits (Lawson-Hanson, the pseudo-inverse by the SVD): the results
    agree with scipy's to rounding (test/tpms_ros/core/test_wheel_radius_analysis.py).
    """
    n = design.shape[1]
    drop = _ridge_nnls(design, target, ridge, np.ones(n, dtype=np.bool_))
    sigma = _drop_sigma(design, drop > 0.0, noise_floor)
    while True:
        active = drop > 0.0
        weak = active & (drop < z_keep * sigma)
        if not weak.any() or weak.sum() == active.sum():
            return drop, sigma
        weakest, lowest = -1, math.inf
        for i in range(n):
            if weak[i] and drop[i] / sigma[i] < lowest:
                weakest, lowest = i, drop[i] / sigma[i]
        active[weakest] = False
        drop = _ridge_nnls(design, target, ridge, active)
        sigma = _drop_sigma(design, drop > 0.0, noise_floor)
