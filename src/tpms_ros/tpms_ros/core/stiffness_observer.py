"""Tire stiffness by disturbance observer and least squares (Umeno et al. 1997): estimator core.

Per wheel the chain is (paper Fig. 4, docs/methods/tire_stiffness_observer.md)::

    omega_1 --tooth correction--> band-pass --> reduced-order observer --> [th, th_dot, w]
            --LS/RLS--> dK, dD   (driven axle: the partner's lagged speed as nuisance)

* **Encoder tooth-error correction** (:mod:`~tpms_ros.core.tooth_correction`): each ring's
  tooth-spacing error, learned online and divided out.
* **Observer** (:mod:`~tpms_ros.core.torsional_observer`, eq. 5-8): a reduced-order
  disturbance observer on the two-inertia tire gives ``[th, th_dot, w]`` from the rim speed.
* **Least squares** (:mod:`~tpms_ros.core.block_least_squares`, eq. 9-11): block sums, RLS with
  forgetting or a windowed batch LS, ``w = zeta^T [dK, dD] - T_d`` with ``zeta = [th, th_dot]``.
* **Drive-wheel compensation.** On a driven axle a driveline torque, common to both
  wheels, reaches the rims. The paper (eq. 12-14) regresses ``wL - wR`` on
  ``[thL, thR, th_dotL, th_dotR]`` with coefficients ``[dKL, -dKR, dDL, -dDR]``
  (``drive_compensation: difference``): exact for a common torque on the *belts*. On the rims
  it is not: the torque also twists both observers' ``th`` alike, and once one tire is soft it
  reaches the two rims through different dynamics (the rim path passes the belt
  anti-resonance ``sqrt(K / J2)``, ~26-30 Hz, next to the ~25 Hz fore-aft mode). On the road
  simulator that left 6-13 kPa on the soft driven wheel and ~10-12 kPa of cross-talk on its
  unchanged partner. The default (``partner``) instead gives each driven wheel its own LS with
  the partner wheel's band-passed speed at lags within +-``partner_lag_s`` as extra
  regressors. The road torques of the two wheels are independent, so what the lags can
  explain is the shared driveline part; by the Frisch-Waugh theorem the ``[th, th_dot]``
  coefficients are those of the wheel with that part projected out, as on an undriven
  wheel, and the same consistency map applies. Limit: the partner's speed carries no
  driveline information at the partner's own belt anti-resonance, so once it is soft the
  unchanged wheel keeps a small residual there (5-10 kPa low on the simulator).
* **Encoder noise** (``encoder_noise_removal``,
  :class:`~tpms_ros.core.wheel_encoder.QuantisationNoise`): the ECU timer's quantisation of the
  speed is in the regressors too and biases the least squares by an amount that depends on
  the road's excitation; a synthetic realisation of it goes through the same filters and its
  second moments are subtracted from each block's normal equations (bias-compensated least
  squares). The timer is ``encoder_timer_s`` or, when that is 0, read from the held
  tooth-period speeds themselves (:class:`~tpms_ros.core.wheel_encoder.TimerLattice`); the
  calibration waits for it.
* **Model-consistency correction** (:class:`~tpms_ros.core.torsional_observer.ConsistencyMap`):
  the raw LS coefficient is mapped to the true K through the model and filters.
* **Calibration** learns each tire's nominal K and the block-to-block noise of its estimate;
  pressure follows from ``K / K_nominal`` (see :class:`PressureRelation`).
* **Gating**: non-finite, negative or absurd speeds, dead and stuck sensors, out-of-order
  stamps, gaps and sample-rate mismatches reset (or hold) the affected wheel's filters and
  mask it; speed band, acceleration, wheel slip and wheel torque gates mask samples where the
  method is not valid. A masked wheel is reported *unknown*, never *low*.

Wheel order FL, FR, RL, RR. No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
import math
from typing import Any, Literal

from numba import njit, types
import numpy as np
import scipy.signal as sig
from scipy.special import ndtr

from tpms_ros.core.block_least_squares import (
    BlockLeastSquares,
    LsFamily,
    ls_families,
    solve_normal,
)
from tpms_ros.core.filter_kernels import lfilter_columns, normalised, sosfilt_columns
from tpms_ros.core.nominal_calibration import StoredCalibrationCheck, StoredCalibrationCheckParams
from tpms_ros.core.tire_model import TorsionalTire
from tpms_ros.core.tires import N_TIRES, TIRE_NAMES
from tpms_ros.core.tooth_correction import ToothErrorCorrector
from tpms_ros.core.torsional_observer import (
    ConsistencyMap,
    ObserverDesign,
    consistency_map,
    design_observer,
)
from tpms_ros.core.wheel_encoder import SPEED_METHODS, QuantisationNoise, TimerLattice
from vehicle_monitor_common.parameters import group, param
from vehicle_monitor_common.validation import require_positive

N_WHEELS = N_TIRES  # the wheel axis of every array here
AXLES: dict[str, tuple[int, int]] = {'front': (0, 1), 'rear': (2, 3)}
CALIBRATION_VERSION = 1

# Per-sample reason codes; a lower code wins when several apply (the most specific cause).
OK = 0
REASONS: tuple[str, ...] = (
    'ok', 'invalid_sample', 'dead_sensor', 'stuck_sensor', 'timing', 'settling',
    'axle_partner', 'wheel_slip', 'wheel_torque', 'cornering', 'acceleration', 'speed_band',
    'tooth_learning',
)
_CODE = {name: code for code, name in enumerate(REASONS)}
CHECKING = 'checking_calibration'
"""A tire's status while a stored calibration is checked against the tires (unknown)."""
_NO_REASON = len(REASONS)  # sentinel above every code, for min-reductions
# The encoder noise's products carried per sample beside the filter outputs, as (row, column)
# of [th, th_dot, w]: th th, th th_dot, th_dot th_dot, th w, th_dot w.
_NOISE_PRODUCTS = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2))
# The step the synthetic noise runs on while the timer is being read from the data: the
# noise is linear in the step to within step / tooth period (< 1 %), its products quadratic.
_REFERENCE_TIMER_S = 1e-6


@dataclass(frozen=True)
class PressureRelation:
    """The tire's stiffness-pressure law, ``K / K0`` as a function of ``p / p0``.

    ``law: line`` (default, paper Fig. 3): ``K / K0 = 1 - slope (1 - p / p0)``, ``slope`` the
    relative stiffness change per relative pressure change. The default slope comes from the
    paper's car: 40 Hz at 200 kPa and 35 Hz at 120 kPa with ``K`` proportional to ``f**2``
    give ``K120 / K200 = (35 / 40)**2 = 0.765625``, so
    ``slope = (1 - 0.765625) / (1 - 120 / 200) = 0.234375 / 0.4 = 0.5859``.
    Inverted: ``p = p0 (1 - (1 - K / K0) / slope)``.

    ``law: power``: ``K / K0 = (p / p0) ** exponent``, inverted ``p = p0 (K / K0) ** (1 /
    exponent)``. Both are tire data (a stiffness or resonance measured at two or more
    pressures); a calibration at one pressure cannot tell them apart, so the law must be given
    for absolute pressures away from placard (docs/methods/tire_stiffness_observer.md). Near
    placard the two agree to first order when ``slope == exponent``.
    """

    law: Literal['line', 'power'] = param(
        'line', "form of the stiffness-pressure law: 'line' (K/K0 = 1 - slope (1 - p/p0), the "
        "paper's) or 'power' (K/K0 = (p/p0)^exponent)", choices=('line', 'power'))
    slope: float = param(0.234375 / 0.4, 'relative stiffness change per relative pressure change '
                         '(law line: K/K0 = 1 - slope (1 - p/p0))', low=0.01, high=10.0)
    exponent: float = param(0.6, 'exponent n of the power law (law power: K/K0 = (p/p0)^n)',
                            low=0.05, high=5.0)

    def __post_init__(self) -> None:
        require_positive(self, ('slope', 'exponent'))
        if self.law not in ('line', 'power'):
            raise ValueError("PressureRelation.law must be 'line' or 'power', "
                             f'got {self.law!r}')

    def describe(self) -> str:
        """The law in words, and whether it is the default (the paper's tire), for
        ``/diagnostics``: away from placard the absolute pressure is only as right as the law."""
        law = (f'power, exponent {self.exponent:.3g}' if self.law == 'power'
               else f'line, slope {self.slope:.3g}')
        if self == PressureRelation():
            return (f"{law} (the default, the paper's tire: pressures away from placard need "
                    "this tire's law, set pressure_relation)")
        return law

    def pressure_ratio(self, stiffness_ratio: np.ndarray) -> np.ndarray:
        """p / p0 for the given K / K0."""
        ratio = np.asarray(stiffness_ratio, dtype=float)
        if self.law == 'power':
            # A stiffness at or below zero has no pressure on this law: pressure 0.
            with np.errstate(invalid='ignore'):
                return np.where(ratio > 0.0, np.maximum(ratio, 0.0) ** (1.0 / self.exponent),
                                np.where(np.isnan(ratio), np.nan, 0.0))
        return 1.0 - (1.0 - ratio) / self.slope

    def pressure_ratio_per_stiffness_ratio(self, stiffness_ratio: np.ndarray | float = 1.0,
                                           ) -> np.ndarray:
        """d(p / p0) / d(K / K0) at the given K / K0 (default placard): converts a
        stiffness-ratio std into a pressure-ratio std."""
        ratio = np.asarray(stiffness_ratio, dtype=float)
        if self.law == 'power':
            with np.errstate(invalid='ignore', divide='ignore'):
                return np.where(ratio > 0.0, np.maximum(ratio, 1e-12) ** (
                    1.0 / self.exponent - 1.0) / self.exponent, np.nan)
        return np.full(ratio.shape, 1.0 / self.slope)


@dataclass(frozen=True)
class StiffnessObserverParams(StoredCalibrationCheckParams):
    """Parameters of :class:`TireStiffnessObserver`, each its ROS parameter of the same name.

    Defaults from the paper and docs/methods/tire_stiffness_observer.md. The ``tire`` group is the
    estimator's nominal model
    (``tire.j1`` ...), ``pressure_relation`` the tire's K <-> pressure law
    (``pressure_relation.law``, ``.slope``, ``.exponent``).
    """

    # --- input and the estimator's model ---
    sample_rate_hz: float = param(
        1000.0, 'wheel-speed sample rate the filters are built for, Hz (a change rebuilds the '
        'estimator, keeping its calibration)', low=50.0, high=20000.0)
    tire: TorsionalTire = group(
        TorsionalTire, "the estimator's nominal tire model, all wheels (a change of tire.k "
        'invalidates the calibration)')
    # --- pre-filter and observer ---
    band_low_hz: float = param(25.0, 'pre-filter pass band around the torsional resonance, '
                               'lower edge, Hz (paper: 25-60 Hz)', low=0.1, high=10000.0)
    band_high_hz: float = param(60.0, 'pre-filter pass band, upper edge, Hz', low=0.1,
                                high=10000.0)
    band_order: int = param(2, 'Butterworth order of each band edge (the band-pass has twice '
                            'this order)', low=1, high=8)
    observer_pole_factor: float = param(
        3.0, 'observer pole radius as a multiple of the model resonance', low=1.0, high=50.0)
    # --- least squares ---
    block_s: float = param(0.25, 'least-squares block length (one RLS update), s', low=0.01,
                           high=10.0)
    forgetting_factor: float = param(
        0.98, 'RLS forgetting factor rho per LS block (paper: 0.95-0.99; memory '
        'block_s / (1 - rho))', low=0.5, high=0.9999)
    ls_mode: Literal['rls', 'batch'] = param(
        'rls', "least squares: 'rls' (eq. 11, recursive with forgetting) or 'batch' (eq. 10 over "
        'the last batch_window_blocks)', choices=('rls', 'batch'))
    # The warning has to follow a loss within the paper's memory; the reading of the pressure
    # does not have to, and over the paper's 12.5 s its spread at placard is what fails the
    # car family's 5 kPa (issue 21; docs/methods/tire_stiffness_observer.md, "Two memories").
    steady_forgetting_factor: float = param(
        0.995, 'RLS forgetting factor of the published reading (stiffness, pressure): a longer '
        'memory than forgetting_factor, which the warning keeps (at or below it: one memory; '
        "ls_mode 'rls' only)", low=0.5, high=0.9999)
    steady_max_sigmas: float = param(
        3.0, "the reading's memory restarts from the warning's where their stiffnesses part by "
        "more than this many sigmas of the warning's estimate (the spread of its blocks) and "
        'is that estimate for the next three memories: a change of pressure is read as the '
        'warning sees it', low=0.0, high=100.0)
    batch_window_blocks: int = param(100, 'batch LS window, valid blocks', low=2, high=100000)
    min_block_fraction: float = param(
        0.9, 'fraction of valid samples a block needs to count for a wheel', low=0.01, high=1.0)
    # --- drive-wheel compensation (see the module notes) ---
    driven_axle: Literal['front', 'rear', 'none', 'all'] = param(
        'none', 'axle(s) with drive-wheel compensation', choices=('front', 'rear', 'none', 'all'))
    # 'partner': each driven wheel's w is regressed on its own [th, th_dot] together with the
    # partner wheel's band-passed speed at lags within +-partner_lag_s; the lags absorb what the
    # two wheels share (the driveline torque: the road torques are independent) and the
    # [th, th_dot] coefficients are the partial regression, as on an undriven wheel.
    # 'difference': the paper's eq. 12-14, one LS per axle of wL - wR on
    # [thL, thR, th_dotL, th_dotR].
    drive_compensation: Literal['partner', 'difference'] = param(
        'partner', "driven-axle compensation: 'partner' (the partner wheel's lagged speed as "
        "nuisance regressors) or 'difference' (the paper's wL - wR regression)",
        choices=('partner', 'difference'))
    # Two-sided, so the estimates wait this long for the partner's later samples.
    partner_lag_s: float = param(
        0.048, 'partner compensation: half-width of the two-sided lag window (output delay), s',
        low=0.0, high=1.0)
    # The band-passed speed carries nothing much faster, and closer lags are nearly collinear.
    partner_lag_step_s: float = param(
        0.004, 'partner compensation: lag spacing, s (>= one sample)', low=1e-5, high=0.1)
    consistency_correction: bool = param(
        True, 'map the raw LS coefficient to K through the model (see the method notes)')
    # --- calibration, pressure and warning ---
    calibration_s: float = param(60.0, 'valid data per tire a calibration collects, s',
                                 low=1.0, high=3600.0)
    nominal_pressure_kpa: tuple[float, float, float, float] = param(
        (200.0, 200.0, 200.0, 200.0), 'placard pressure of each tire FL, FR, RL, RR, kPa '
        '(gauge); the p0 of the pressure relation and the pressure at calibration')
    pressure_relation: PressureRelation = group(
        PressureRelation, "the tire's stiffness-pressure law (tire data; default: the paper's "
        'line)')
    warning_pressure_ratio: float = param(
        0.9, 'a tire is flagged when its estimated p / p0 is below this', low=0.01, high=0.999)
    # Issue 21: on cars it was not built for, the estimate at placard is off by more than its
    # noise (rings, speed, excitation): rms 4.0 % of placard over 48 tire-windows (tuning cars
    # 21500, 21503, 21504, 21506, 21507, 21509, two drives each, 95-150 s). The confidence
    # counts it so that such an offset alone does not reach a warning threshold.
    model_error_ratio: float = param(
        0.04, "1-sigma error of the estimate that its noise does not show (the method's error "
        'on unseen cars), as a fraction of placard; added to the noise in the confidence',
        low=0.0, high=1.0)
    # --- validity gates (the data are fine, the method is not valid there) ---
    rolling_radius_m: float = param(
        0.3, 'nominal rolling radius, for the speed and acceleration gates, m', low=0.05,
        high=2.0)
    speed_min_kmh: float = param(
        30.0, 'lower edge of the vehicle speed band where the estimate is updated, km/h',
        low=0.0, high=500.0)
    speed_max_kmh: float = param(
        160.0, 'upper edge of the valid speed band, km/h', low=0.0, high=500.0)
    max_accel_mps2: float = param(
        2.5, '|wheel acceleration| above this (hard braking/traction) masks samples, m/s^2',
        low=0.01, high=50.0)
    max_slip: float = param(
        0.05, '|wheel speed / median wheel speed - 1| above this masks the wheel', low=1e-3,
        high=1.0)
    max_wheel_torque_nm: float = param(
        1000.0, '|drive/brake torque| above this masks the wheel (if torque given), N m',
        low=1.0, high=1e5)
    # Sustained cornering moves the estimates (measured on the road simulator: turns of
    # 2.5 m/s^2 kinematic, 1.5 m/s^2 actual, at 104 km/h read all four tires 10-30 kPa low and
    # raised a false warning). 2 m/s^2 lets gentle weaving through: masking at 1 m/s^2 left
    # 35 % of the shipped puncture drive and pushed the calibration past the puncture.
    max_lateral_accel_mps2: float = param(
        2.0, 'kinematic lateral acceleration v^2 tan(delta) / wheelbase above this masks every '
        'wheel (if the steering angle is given), m/s^2', low=0.01, high=50.0)
    # Vehicle-specific; an understeering car corners with less, so the gate errs on the safe
    # side.
    wheelbase_m: float = param(
        2.7, 'wheelbase for the kinematic lateral acceleration, m', low=0.5, high=20.0)
    gate_lowpass_hz: float = param(
        2.0, 'low-pass corner of the speed used by the speed/accel/slip gates, Hz', low=0.01,
        high=100.0)
    # --- sensor faults and timing ---
    max_omega_rad_s: float = param(
        400.0, 'wheel speeds above this are non-physical and rejected, rad/s', low=1.0,
        high=10000.0)
    dead_omega_rad_s: float = param(
        1.0, 'a wheel below this while another wheel is in the speed band is dead, rad/s',
        low=1e-3, high=100.0)
    stuck_s: float = param(
        0.05, 'a wheel reading exactly the same value for this long, and for three tooth '
        'periods of that reading, is a stuck sensor, s',
        low=1e-3, high=10.0)
    settle_s: float = param(
        0.2, 'time after a filter reset during which samples are not used, s', low=1e-3,
        high=60.0)
    timing_tolerance: float = param(
        0.25, 'relative deviation of a sample interval from 1 / sample_rate_hz beyond which the '
        'sample breaks continuity (gap or rate change): filters are reset', low=1e-3, high=1.0)
    # --- encoder tooth-error correction (see tooth_correction.ToothErrorCorrector) ---
    tooth_correction: bool = param(
        True, "learn and remove each encoder ring's tooth-spacing error (needs the ECU's held "
        'tooth-period speed as input)')
    encoder_teeth: int = param(48, 'teeth per encoder ring (paper: 48)', low=2, high=1000)
    tooth_learning_s: float = param(
        30.0, 'memory time constant of the per-tooth error learning, s', low=0.1, high=3600.0)
    # Every sample lands on some tooth, so a tooth gets fs / teeth samples per second at any
    # speed. A ring learned over 1 s correlated 0.91-0.98 with the true one on the simulated
    # rings, but a calibration on such a pattern read a tire 18 kPa low for a whole drive
    # (issue 21, tuning car 21504); after a reset the kept pattern is usually found again
    # after 2 s (docs/methods/tire_stiffness_observer.md, "The encoder ring's tooth pattern").
    tooth_learned_s: float = param(
        15.0, "in-band samples a wheel's tooth pattern learns from before the wheel's samples "
        'are used, s (after a reset: unless the pattern learned before it is found again)',
        low=0.0, high=600.0)
    tooth_phase_s: float = param(
        0.5, 'memory time constant of the tooth-edge phase tracker, s', low=1e-3, high=60.0)
    # With 48 teeth at 1 kHz and 0.9: 113 rad/s. A window average (the tooth correction's
    # angle domain) has no tooth count to lose and averages the ring over its window's teeth,
    # so it stays in use (tooth_correction, Fast wheels).
    max_tooth_rate_fraction: float = param(
        0.9, 'tooth-edge rate (speed x teeth / 2 pi) above this fraction of the sample rate '
        "masks a held-period wheel ('speed_band'): edges can then fall between samples",
        low=0.01, high=1.0)
    # --- encoder noise: the ECU timer's quantisation of the speed, taken out of the least
    # squares (docs/methods/tire_stiffness_observer.md, "Encoder noise") ---
    # The regressors carry the noise too (errors in variables), so the least squares read a
    # bias that shrinks as the road excites the tire more: calibrated on one road, the tires
    # read low on a rougher one. Its second moments follow from the ECU's timer and way of
    # forming the speed and are subtracted from each block's normal equations.
    encoder_noise_removal: bool = param(
        True, "take the ECU timer's quantisation noise out of the least squares (the timer: "
        'encoder_timer_s, or read from the wheel speeds when that is 0)')
    encoder_timer_s: float = param(
        0.0, 'resolution of the ECU timer that stamps the tooth edges, s (ABS ECU data, often '
        "1-4 us); 0: read from the wheel speeds, which works for held tooth periods "
        "('tooth_period': their values lie on a lattice of timer steps); window averages need "
        'it given', low=0.0, high=1e-3)
    encoder_speed_method: Literal['tooth_period', 'window_average'] = param(
        'tooth_period', "how the ECU forms the speed: 'tooth_period' (pitch over the last "
        "tooth period, held) or 'window_average' (teeth over the edge-to-edge time across "
        'encoder_window_s)', choices=SPEED_METHODS)
    encoder_window_s: float = param(
        0.005, "averaging window of 'window_average', s", low=1e-4, high=0.1)
    # --- trust: a calibrated tire whose estimate rests on blocks unlike the calibration's is
    # reported uncertain (not valid), never low (docs/methods/tire_stiffness_observer.md) ---
    trust_check: bool = param(
        True, "report a tire 'uncertain_*' (unknown) when the blocks behind its estimate do not "
        "look like its calibration's")
    trust_max_spread_ratio: float = param(
        2.0, "'uncertain_noisy': robust spread of the last memory's block stiffnesses above this "
        "multiple of the calibration's", low=1.0, high=100.0)


    def __post_init__(self) -> None:
        require_positive(self, (
            'sample_rate_hz', 'observer_pole_factor', 'block_s', 'calibration_s',
            'rolling_radius_m', 'max_accel_mps2', 'max_slip', 'max_wheel_torque_nm',
            'max_lateral_accel_mps2', 'wheelbase_m', 'gate_lowpass_hz', 'max_omega_rad_s',
            'dead_omega_rad_s', 'stuck_s', 'settle_s', 'timing_tolerance',
            'warning_pressure_ratio', 'tooth_learning_s', 'tooth_phase_s',
            'trust_max_spread_ratio', 'encoder_window_s'))
        if not (isinstance(self.encoder_teeth, int) and self.encoder_teeth >= 2):
            raise ValueError('StiffnessObserverParams.encoder_teeth must be an int >= 2, '
                             f'got {self.encoder_teeth!r}')
        if not 0.0 < self.max_tooth_rate_fraction <= 1.0:
            raise ValueError('StiffnessObserverParams.max_tooth_rate_fraction must be in '
                             f'(0, 1], got {self.max_tooth_rate_fraction}')
        nyquist = 0.5 * self.sample_rate_hz
        low, high = self.band_hz
        if not (0.0 < low < high < nyquist):
            raise ValueError(f'StiffnessObserverParams.band_hz (band_low_hz, band_high_hz) must '
                             f'satisfy 0 < low < high < {nyquist} Hz (Nyquist), got '
                             f'{self.band_hz}')
        if not (isinstance(self.band_order, int) and 1 <= self.band_order <= 8):
            raise ValueError(f'StiffnessObserverParams.band_order must be an int in 1..8, '
                             f'got {self.band_order!r}')
        if not 0.5 <= self.forgetting_factor < 1.0:
            raise ValueError('StiffnessObserverParams.forgetting_factor must be in [0.5, 1), '
                             f'got {self.forgetting_factor}')
        if self.ls_mode not in ('rls', 'batch'):
            raise ValueError(f"StiffnessObserverParams.ls_mode must be 'rls' or 'batch', "
                             f'got {self.ls_mode!r}')
        if not (isinstance(self.batch_window_blocks, int) and self.batch_window_blocks >= 2):
            raise ValueError('StiffnessObserverParams.batch_window_blocks must be an int >= 2, '
                             f'got {self.batch_window_blocks!r}')
        if not 0.0 < self.min_block_fraction <= 1.0:
            raise ValueError('StiffnessObserverParams.min_block_fraction must be in (0, 1], '
                             f'got {self.min_block_fraction}')
        if self.encoder_speed_method not in SPEED_METHODS:
            raise ValueError(f'StiffnessObserverParams.encoder_speed_method must be one of '
                             f'{SPEED_METHODS}, got {self.encoder_speed_method!r}')
        if self.driven_axle not in ('front', 'rear', 'none', 'all'):
            raise ValueError("StiffnessObserverParams.driven_axle must be 'front', 'rear', "
                             f"'none' or 'all', got {self.driven_axle!r}")
        if self.drive_compensation not in ('partner', 'difference'):
            raise ValueError("StiffnessObserverParams.drive_compensation must be 'partner' or "
                             f"'difference', got {self.drive_compensation!r}")
        require_positive(self, ('partner_lag_s', 'encoder_timer_s'), allow_zero=True)
        if not (math.isfinite(self.partner_lag_step_s)
                and self.partner_lag_step_s * self.sample_rate_hz >= 1.0 - 1e-9):
            raise ValueError('StiffnessObserverParams.partner_lag_step_s must be at least one '
                             f'sample ({1.0 / self.sample_rate_hz} s), got '
                             f'{self.partner_lag_step_s!r}')
        if len(self.nominal_pressure_kpa) != N_WHEELS or not all(
                math.isfinite(p) and p > 0 for p in self.nominal_pressure_kpa):
            raise ValueError('StiffnessObserverParams.nominal_pressure_kpa must be 4 finite '
                             f'values > 0, got {self.nominal_pressure_kpa!r}')
        if not self.warning_pressure_ratio < 1.0:
            raise ValueError('StiffnessObserverParams.warning_pressure_ratio must be < 1, '
                             f'got {self.warning_pressure_ratio}')
        vmin, vmax = self.speed_band_kmh
        if not 0.0 <= vmin < vmax:
            raise ValueError('StiffnessObserverParams.speed_band_kmh (speed_min_kmh, '
                             f'speed_max_kmh) must satisfy 0 <= min < max, got '
                             f'{self.speed_band_kmh}')
        pole_hz = self.observer_pole_factor * self.tire.resonance_hz
        if not pole_hz < 0.5 * self.sample_rate_hz:
            raise ValueError(f'StiffnessObserverParams.observer_pole_factor '
                             f'{self.observer_pole_factor:g} puts the observer poles at '
                             f'{pole_hz:.0f} Hz, above the Nyquist frequency '
                             f'{0.5 * self.sample_rate_hz:g} Hz')
        if self.block_samples < 10:
            raise ValueError('StiffnessObserverParams.block_s must hold >= 10 samples, '
                             f'got {self.block_s} s at {self.sample_rate_hz} Hz')

    @property
    def block_samples(self) -> int:
        """Samples per least-squares block (one update)."""
        return int(round(self.block_s * self.sample_rate_hz))

    @property
    def partner_lags(self) -> np.ndarray:
        """Partner lags in samples, symmetric about 0 (positive: the partner's earlier
        samples); empty unless 'partner' compensation is on for some axle."""
        if not self.driven_axles or self.drive_compensation != 'partner':
            return np.zeros(0, dtype=int)
        step = int(round(self.partner_lag_step_s * self.sample_rate_hz))
        half = int(math.floor(self.partner_lag_s / self.partner_lag_step_s + 1e-9))
        return step * np.arange(-half, half + 1)

    @property
    def band_hz(self) -> tuple[float, float]:
        """Pre-filter pass band (low, high), Hz."""
        return (self.band_low_hz, self.band_high_hz)

    @property
    def speed_band_kmh(self) -> tuple[float, float]:
        """(min, max) vehicle speed where the estimate is updated, km/h."""
        return (self.speed_min_kmh, self.speed_max_kmh)

    @property
    def forgetting_factors(self) -> tuple[float, float]:
        """RLS forgetting factors of the two memories: the warning's, the reading's (never
        shorter)."""
        return (self.forgetting_factor,
                max(self.forgetting_factor, self.steady_forgetting_factor))

    @property
    def effective_blocks(self) -> np.ndarray:
        """Number of equally informative blocks each memory (the warning's, the reading's)
        averages over (sets its noise)."""
        if self.ls_mode == 'batch':
            return np.full(2, float(self.batch_window_blocks))
        rho = np.asarray(self.forgetting_factors)
        return (1.0 + rho) / (1.0 - rho)

    @property
    def memory_blocks(self) -> int:
        """Blocks of one LS memory: ``1 / (1 - rho)`` for RLS, the window for batch."""
        if self.ls_mode == 'batch':
            return self.batch_window_blocks
        return int(round(1.0 / (1.0 - self.forgetting_factor)))

    @property
    def driven_axles(self) -> tuple[str, ...]:
        """Names of the compensated axles."""
        if self.driven_axle == 'all':
            return ('front', 'rear')
        if self.driven_axle == 'none':
            return ()
        return (self.driven_axle,)


@dataclass(frozen=True)
class StiffnessEstimate:
    """Estimator output after one :meth:`TireStiffnessObserver.update` (arrays are FL..RR).

    The reading (``delta_k`` to ``pressure_std_kpa``) is the least squares' longer memory
    (``steady_forgetting_factor``); ``underinflated`` and ``confidence`` (the warning) are the
    paper's memory's (``forgetting_factor``), as is the convergence in ``status``.

    Attributes:
        stamp: time of the last accepted sample, s (NaN when no stamps were given).
        delta_k: stiffness change from the model, ``stiffness - K_model``, N m/rad.
        delta_d: damping change from the model (bias-removed raw LS coefficient), N m s/rad;
            its gain is not corrected (it does not feed the pressure).
        stiffness: estimated torsional stiffness K, N m/rad.
        stiffness_ratio: K / K_nominal (K_model until calibrated).
        pressure_kpa: pressure from the stiffness ratio and the pressure relation.
        pressure_std_kpa: 1-sigma noise of ``pressure_kpa`` (its memory's, once full): the
            calibration's block noise, or the recent blocks' where they spread wider, over the
            memory's effective blocks (NaN before calibration).
        valid: the wheel's estimate is current, converged and its input healthy.
        status: per wheel 'ok' or the reason it is unknown.
        calibrated: all four tires calibrated.
        wheel_calibrated: per tire.
        underinflated: flag t_i: valid, calibrated and the warning's pressure ratio below the
            threshold.
        confidence: c_i in 0..1, the probability that the pressure is below the threshold
            given the warning's estimate, its noise and ``model_error_ratio`` (normal CDF); 0
            for unknown or uncalibrated tires.
        calibrating: a calibration is in progress.
    """

    stamp: float
    delta_k: np.ndarray
    delta_d: np.ndarray
    stiffness: np.ndarray
    stiffness_ratio: np.ndarray
    pressure_kpa: np.ndarray
    pressure_std_kpa: np.ndarray
    valid: np.ndarray
    status: tuple[str, ...]
    calibrated: bool
    wheel_calibrated: np.ndarray
    underinflated: np.ndarray
    confidence: np.ndarray
    calibrating: bool


# Streaming estimator

# After a change of pressure the reading is the warning's estimate for this many of its
# memories (then it averages longer): the longer memory would otherwise keep the blocks from
# before the change, which the restart copied from the warning's memory, for its own memory
# time (5 % of them left after three memories).
READING_HOLD_MEMORIES = 3.0


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


# Rows of _gate_chunk's tallies after the reason codes' counts.
_TORQUE_INVALID, _STEERING_INVALID = len(REASONS), len(REASONS) + 1
_EMPTY_1D, _EMPTY_2D = np.zeros(0), np.zeros((0, 0))
# The gates' codes as plain ints (compile-time constants to numba).
_SPEED_BAND, _ACCELERATION, _WHEEL_TORQUE, _CORNERING, _WHEEL_SLIP, _TOOTH_LEARNING = (
    _CODE['speed_band'], _CODE['acceleration'], _CODE['wheel_torque'], _CODE['cornering'],
    _CODE['wheel_slip'], _CODE['tooth_learning'])
_AXLE_PARTNER = _CODE['axle_partner']


@njit(types.float64(types.float64[:], types.boolean[:]), cache=True, error_model='numpy')
def _good_median(values: np.ndarray, good: np.ndarray) -> float:
    """The median of the good, finite ``values`` (NaN if none): the mean of the middle two
    of an even count (an insertion sort: a handful of values, and numba's sort took seconds
    to compile)."""
    picked = np.empty(values.shape[0])
    count = 0
    for w in range(values.shape[0]):
        value = values[w]
        if good[w] and np.isfinite(value):
            slot = count
            while slot > 0 and picked[slot - 1] > value:
                picked[slot] = picked[slot - 1]
                slot -= 1
            picked[slot] = value
            count += 1
    if count == 0:
        return np.nan
    return 0.5 * (picked[(count - 1) // 2] + picked[count // 2])


@njit(types.void(types.float64[:, :], types.float64[:], types.boolean[:, :],
                 types.int64[:, :], types.float64[:, :], types.float64[:],
                 types.boolean[:, :], types.float64[:], types.int64[:, :], types.int64[:, :]),
      cache=True, error_model='numpy')
def _gate_chunk(lowpass: np.ndarray, previous: np.ndarray, good: np.ndarray, code: np.ndarray,
                torque: np.ndarray, steering: np.ndarray, learned: np.ndarray,
                limits: np.ndarray, axles: np.ndarray, tallies: np.ndarray) -> None:
    """The validity gates of :meth:`TireStiffnessObserver._process`, compiled (numba): per
    sample, the first gate that applies to a wheel whose code is still OK sets it (speed band,
    acceleration, wheel torque, cornering, wheel slip against the median of the good wheels,
    tooth learning: last, so that a wheel whose tooth pattern is being learned tells the other
    reasons its data would not count where they apply too), then a driven axle's wheel whose
    partner is masked is masked too.

    Why compiled: as numpy it was some forty array calls per chunk, a third of the cost of
    the small chunk that answers an output. Only the same comparisons and arithmetic (tan is
    the C library's, numpy's own vector version before: it is only compared with a limit).

    Args:
        lowpass: (n, 4) low-passed speeds; ``previous``: (4,) the one before the chunk.
        good: (n, 4) valid sensor samples; ``code``: (n, 4) reason codes, updated in place.
        torque: (n, 4) wheel torques, or (0, 0) without; ``steering``: (n,) or (0,) without.
        learned: (n, 4) samples whose tooth pattern is learned.
        limits: sample rate, rolling radius, speed band low and high (km/h), max acceleration,
            max wheel torque, max lateral acceleration, wheelbase, max slip.
        axles: (k, 2) the driven axles' wheels.
        tallies: (len(REASONS) + 2, 4), incremented: the codes' counts per wheel, then the
            invalid torques per wheel and the invalid steering angles (on every wheel).
    """
    fs, radius, band_low, band_high, max_accel, max_torque, max_lateral, wheelbase, max_slip = (
        limits[0], limits[1], limits[2], limits[3], limits[4], limits[5], limits[6], limits[7],
        limits[8])
    n, n_wheels = lowpass.shape
    with_torque, with_steering = torque.shape[0] > 0, steering.shape[0] > 0
    masked = np.empty(n_wheels, dtype=np.bool_)
    for i in range(n):
        ref = _good_median(lowpass[i], good[i])
        cornering = False
        if with_steering:
            angle = steering[i]
            if not np.isfinite(angle):
                for w in range(n_wheels):
                    tallies[_STEERING_INVALID, w] += 1
                angle = 0.0
            speed_mps = ref * radius
            lateral = speed_mps ** 2 * abs(math.tan(angle)) / wheelbase
            cornering = not math.isnan(lateral) and lateral > max_lateral
        for w in range(n_wheels):
            low = lowpass[i, w]
            before = previous[w] if i == 0 else lowpass[i - 1, w]
            speed_kmh = low * radius * 3.6
            torque_hit = False
            if with_torque:
                if np.isfinite(torque[i, w]):
                    torque_hit = abs(torque[i, w]) > max_torque
                else:
                    tallies[_TORQUE_INVALID, w] += 1
            slip = abs(low / ref - 1.0)
            if code[i, w] != OK:
                continue
            if speed_kmh < band_low or speed_kmh > band_high:
                code[i, w] = _SPEED_BAND
            elif abs((low - before) * fs * radius) > max_accel:
                code[i, w] = _ACCELERATION
            elif torque_hit:
                code[i, w] = _WHEEL_TORQUE
            elif cornering:
                code[i, w] = _CORNERING
            elif np.isfinite(slip) and slip > max_slip:
                code[i, w] = _WHEEL_SLIP
            elif not learned[i, w]:
                code[i, w] = _TOOTH_LEARNING
        for w in range(n_wheels):
            masked[w] = code[i, w] != OK
        for k in range(axles.shape[0]):
            left, right = axles[k, 0], axles[k, 1]
            if masked[left] != masked[right]:
                code[i, right if masked[left] else left] = _AXLE_PARTNER
        for w in range(n_wheels):
            tallies[code[i, w], w] += 1


# The codes the sensor kernel sets, as plain ints (compile-time constants to numba); a tooth-rate
# overrun reads as 'speed_band'.
_INVALID, _DEAD, _STUCK = _CODE['invalid_sample'], _CODE['dead_sensor'], _CODE['stuck_sensor']
_TIMING, _SETTLING, _OVERRUN = _CODE['timing'], _CODE['settling'], _CODE['speed_band']
# A held reading lasts until the next tooth edge, a tooth period of its own speed: at 3 km/h
# that is longer than stuck_s. A reading is stuck only when it also outlasts this many of those
# periods (the next tooth is longer when braking, never by this much). A stuck reading resets
# the wheel and its tooth pattern, which a slow crawl must not (issue 21: 50 resets in 10 min
# of urban driving, each followed by a pattern learned anew from 1 s).
STUCK_TOOTH_PERIODS = 3.0
_F1, _F2 = types.float64[:], types.float64[:, :]
_B1, _B2 = types.boolean[:], types.boolean[:, :]
_I1, _I2 = types.int64[:], types.int64[:, :]


@njit(types.void(_F2, _B1, _F1, types.int64, types.int64, _B1, types.boolean,
                 _F1, _I1, _B1, _I1, _F1, _I1, _I1, _I2, _B2, _B2, _F2, _I2),
      cache=True, error_model='numpy')
def _sensor_chunk(omega: np.ndarray, timing_break: np.ndarray, limits: np.ndarray,
                  stuck_samples: int, settle_samples: int, counted: np.ndarray,
                  tooth_correction: bool,
                  last_value: np.ndarray, run: np.ndarray, prev_good: np.ndarray,
                  prev_code: np.ndarray, hold: np.ndarray, since_reset: np.ndarray,
                  reset_cause: np.ndarray, code: np.ndarray, good: np.ndarray,
                  reset: np.ndarray, filled: np.ndarray, counts: np.ndarray) -> None:
    """The per-sample sensor checks of :meth:`TireStiffnessObserver._process`, compiled
    (numba): validity, dead and stuck sensors, tooth-rate overrun, filter resets and their
    causes, the hold of bad samples and the settling after a reset; states updated in place.

    Why compiled: as numpy these were some fifty small-array calls per chunk (run lengths and
    last-index fills by accumulate, per-wheel maxima of the other wheels), most of each call's
    cost overhead. Only comparisons, copies and integer counts: the same results as numpy's.

    Args:
        omega: (n, 4) wheel speeds as received.
        timing_break: (n,) samples that break the time line (gap, rate change).
        limits: max_omega_rad_s, dead_omega_rad_s, the speed another wheel must reach for a
            slow wheel to be dead, rad/s, teeth per radian, the tooth-edge rate limit, 1/s,
            the sample rate, Hz.
        stuck_samples, settle_samples: run of equal readings that is a stuck sensor (and
            :data:`STUCK_TOOTH_PERIODS` tooth periods of a non-zero reading); samples not used
            after a reset.
        counted: (4,) wheels whose tooth count an overrun loses (held periods).
        tooth_correction: the tooth-rate overrun check is on.
        last_value, run, prev_good, prev_code, hold, since_reset, reset_cause: (4,) carried
            per wheel: last reading, its run of equal readings, last sample good and its code
            (before settling), held speed, samples since the last reset and its cause.
        code: (n, 4) out, reason codes after settling (the gates come later).
        good: (n, 4) out, valid sensor samples (before settling).
        reset: (n, 4) out, filter resets.
        filled: (n, 4) out, speeds with bad samples held at the last good one.
        counts: (4, 4) out, per wheel invalid, dead, stuck and settling samples.
    """
    max_omega, dead_omega, others_min = limits[0], limits[1], limits[2]
    teeth_per_rad, tooth_limit, fs = limits[3], limits[4], limits[5]
    plausible = np.empty(N_WHEELS)
    invalid = np.empty(N_WHEELS, dtype=np.bool_)
    for w in range(N_WHEELS):
        if not math.isfinite(hold[w]):
            hold[w] = 0.0
    for i in range(omega.shape[0]):
        for w in range(N_WHEELS):
            value = omega[i, w]
            invalid[w] = not (math.isfinite(value) and 0.0 <= value <= max_omega)
            plausible[w] = 0.0 if invalid[w] else value
        for w in range(N_WHEELS):
            value = omega[i, w]
            others_max = -math.inf
            for other in range(N_WHEELS):
                if other != w and plausible[other] > others_max:
                    others_max = plausible[other]
            dead = not invalid[w] and value < dead_omega and others_max >= others_min
            # Stuck: identical consecutive readings for stuck_s (a quantised ABS speed holds a
            # value only for one tooth period, a few ms at speed).
            run[w] = run[w] + 1 if value == last_value[w] else 0
            last_value[w] = value
            stuck_limit = float(stuck_samples)
            if plausible[w] > 0.0:
                stuck_limit = max(stuck_limit, STUCK_TOOTH_PERIODS * fs / (value * teeth_per_rad))
            sample_code = OK
            if invalid[w]:
                sample_code = _INVALID
                counts[0, w] += 1
            elif dead:
                sample_code = _DEAD
                counts[1, w] += 1
            elif run[w] >= stuck_limit:
                sample_code = _STUCK
                counts[2, w] += 1
            elif tooth_correction and counted[w] and plausible[w] * teeth_per_rad > tooth_limit:
                # Edges faster than the samples: the tooth count (and the correction) is lost, so
                # the wheel is treated as unusable and its tracking restarts when it slows down.
                sample_code = _OVERRUN
            is_good = sample_code == OK
            is_reset = is_good and (not prev_good[w] or timing_break[i])
            if is_reset:
                since_reset[w] = 0
                reset_cause[w] = (_TIMING if timing_break[i] else
                                  _SETTLING if prev_code[w] == OK else prev_code[w])
            else:
                since_reset[w] += 1
            prev_good[w] = is_good
            prev_code[w] = sample_code
            if is_good:
                hold[w] = value
                if since_reset[w] < settle_samples:
                    sample_code = reset_cause[w]
                    counts[3, w] += 1
            code[i, w] = sample_code
            good[i, w] = is_good
            reset[i, w] = is_reset
            filled[i, w] = hold[w]


def sensor_state() -> tuple[np.ndarray, ...]:
    """The per-wheel state :func:`sensor_checks` carries, at a start: last reading (none), its
    run of equal readings, last sample good, its code, held speed (none), samples since the
    last reset and its cause (settling)."""
    return (np.full(N_WHEELS, np.nan), np.zeros(N_WHEELS, dtype=np.int64),
            np.zeros(N_WHEELS, dtype=bool), np.full(N_WHEELS, _CODE['settling']),
            np.full(N_WHEELS, np.nan), np.zeros(N_WHEELS, dtype=np.int64),
            np.full(N_WHEELS, _CODE['settling']))


def sensor_checks(p: StiffnessObserverParams, omega: np.ndarray, timing_break: np.ndarray,
                  carried: tuple[np.ndarray, ...], counted: np.ndarray) -> tuple[np.ndarray, ...]:
    """The per-sample sensor checks of a chunk (:func:`_sensor_chunk` with the parameters'
    limits).

    Args:
        p: the observer's parameters.
        omega: (n, 4) wheel speeds as received; timing_break: (n,) samples that break the
            time line.
        carried: the per-wheel state carried across chunks (:func:`sensor_state`), updated in
            place.
        counted: (4,) wheels whose tooth correction counts teeth (held periods, not the angle
            domain): only these overrun.

    Returns:
        code, good, reset, filled (each (n, 4)) and the (4, 4) counts of invalid, dead, stuck
        and settling samples per wheel.
    """
    n = omega.shape[0]
    fs = p.sample_rate_hz
    code = np.empty((n, N_WHEELS), dtype=np.int64)
    good = np.empty((n, N_WHEELS), dtype=bool)
    reset = np.empty((n, N_WHEELS), dtype=bool)
    filled = np.empty((n, N_WHEELS))
    counts = np.zeros((4, N_WHEELS), dtype=np.int64)
    speed_min = p.speed_band_kmh[0] / 3.6 / p.rolling_radius_m
    last_value, run, prev_good, prev_code, hold, since_reset, reset_cause = carried
    _sensor_chunk(omega, timing_break, np.array([
        p.max_omega_rad_s, p.dead_omega_rad_s, max(speed_min, 1e-9),
        p.encoder_teeth / (2.0 * np.pi), p.max_tooth_rate_fraction * fs, fs]),
        int(round(p.stuck_s * fs)), int(round(p.settle_s * fs)), counted, p.tooth_correction,
        last_value, run, prev_good, prev_code, hold, since_reset, reset_cause, code, good,
        reset, filled, counts)
    return code, good, reset, filled, counts


def _robust_spread(values: np.ndarray) -> float:
    """1.4826 times the median absolute deviation: the std of normal data, robust to the odd
    poorly excited block."""
    return 1.4826 * float(np.median(np.abs(values - np.median(values))))


class _TrustWindow:
    """The last ``size`` counted block stiffnesses of each wheel, for the trust measure (how
    the blocks behind the estimate compare with the calibration's) and the reading's restart
    (how far the warning's estimate may be from the reading's)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.k = np.full((size, N_WHEELS), np.nan)
        self.count = np.zeros(N_WHEELS, dtype=np.int64)   # blocks ever added per wheel
        self._spread: np.ndarray | None = None            # :meth:`spread` until the next add

    def add(self, block_k: np.ndarray, usable: np.ndarray) -> None:
        """Append each wheel's usable blocks (B, 4) in order."""
        for w in range(N_WHEELS):
            rows = np.flatnonzero(usable[:, w])
            slots = (self.count[w] + np.arange(rows.size)) % self.size
            self.k[slots, w] = block_k[rows, w]
            self.count[w] += rows.size
        self._spread = None

    def held(self) -> np.ndarray:
        """(4,) blocks held per wheel (up to ``size``)."""
        return np.minimum(self.count, self.size)

    def spread(self) -> np.ndarray:
        """(4,) robust spread of each wheel's held blocks (NaN with fewer than 4)."""
        if self._spread is None:
            self._spread = np.array([
                _robust_spread(self.last(w, self.size)) if held >= 4 else np.nan
                for w, held in enumerate(self.held())])
        return self._spread

    def last(self, wheel: int, n: int) -> np.ndarray:
        """The wheel's last min(n, held) block stiffnesses, oldest first."""
        held = int(min(n, self.count[wheel], self.size))
        slots = (self.count[wheel] - held + np.arange(held)) % self.size
        return self.k[slots, wheel]


@dataclass
class _Calibration:
    """Accumulators of a running calibration (raw, uncorrected LS sums)."""

    gram: list[np.ndarray]    # per LS family: (P, n, n) pooled normal matrices
    rhs: list[np.ndarray]     # per LS family: (P, n)
    block_k: list[list[float]]
    blocks: np.ndarray        # (4,) valid blocks collected
    needed_blocks: int


class TireStiffnessObserver:
    """Four-wheel tire stiffness and pressure estimator (Umeno et al. 1997), streaming.

    Args:
        params: estimator parameters.
        tires: the estimator's nominal model per wheel (FL..RR), or one for all wheels;
            default ``params.tire``.
    """

    def __init__(self, params: StiffnessObserverParams | None = None,
                 tires: TorsionalTire | Sequence[TorsionalTire] | None = None) -> None:
        self.params = params if params is not None else StiffnessObserverParams()
        if tires is None:
            tires = self.params.tire
        if isinstance(tires, TorsionalTire):
            tires = (tires,) * N_WHEELS
        if len(tires) != N_WHEELS or not all(isinstance(t, TorsionalTire) for t in tires):
            raise ValueError(f'tires must be one TorsionalTire or {N_WHEELS} of them')
        self.tires: tuple[TorsionalTire, ...] = tuple(tires)
        p = self.params
        fs = p.sample_rate_hz
        self._band_sos = sig.butter(p.band_order, p.band_hz, 'bandpass', fs=fs, output='sos')
        self._lowpass_sos = sig.butter(2, p.gate_lowpass_hz, 'lowpass', fs=fs, output='sos')
        # Group wheels by model so identical tires share one vectorised filter call.
        self._groups: list[tuple[np.ndarray, ObserverDesign, ConsistencyMap]] = []
        for model in dict.fromkeys(self.tires):
            wheels = np.array([i for i, t in enumerate(self.tires) if t == model])
            design = design_observer(model, p.observer_pole_factor, fs)
            cmap = consistency_map(model, design, self._band_sos, fs)
            self._groups.append((wheels, design, cmap))
        # The observer filters' coefficients as the compiled lfilter takes them, per group.
        self._observer_filters = [[normalised(b, design.denominator)
                                   for b in design.numerators]
                                  for _, design, _ in self._groups]
        # The ECU timer: given, or read from the held tooth periods. Until it is read the
        # synthetic noise runs on a reference step (its products scale with the step squared)
        # and the blocks are not used, so that the least squares and the calibration start
        # with the noise removed. The lattice, the sample count and the sample at which the
        # timer was read survive a reset (the timer is the ECU's).
        self._timer_lattice = (TimerLattice(p.encoder_teeth, p.sample_rate_hz,
                                            fast_edge_rate=p.max_tooth_rate_fraction)
                               if p.encoder_noise_removal and p.encoder_timer_s == 0.0
                               and p.encoder_speed_method == 'tooth_period' else None)
        if not p.encoder_noise_removal:
            self._noise_timer_s = 0.0
        elif p.encoder_timer_s > 0.0:
            self._noise_timer_s = p.encoder_timer_s
        else:
            self._noise_timer_s = _REFERENCE_TIMER_S if self._timer_lattice is not None else 0.0
        # What the products of the noise as generated are multiplied by: (timer / generated
        # step)^2; 0 while the timer is unknown or when it cannot be read.
        self._noise_scale = 1.0 if p.encoder_noise_removal and p.encoder_timer_s > 0.0 else 0.0
        self._samples = 0
        # Blocks beginning before this sample are not used (the timer was being read).
        self._timer_read_at = math.inf if self._timer_lattice is not None else -math.inf
        # Blocks beginning at or after this sample keep the noise in: the timer was read from
        # held periods, and the speeds turned out to be window averages after all (a window
        # longer than a tooth period holds one tooth at low speeds).
        self._noise_until = math.inf
        # Per sample and wheel: [th, th_dot, w, band-passed speed] and, when the encoder
        # noise is (or may be) removed, the noise's products.
        self._channels = 4 + (len(_NOISE_PRODUCTS) if self._noise_timer_s > 0.0 else 0)
        self._model_k = np.array([t.k for t in self.tires])
        self._axles = [AXLES[name] for name in p.driven_axles]
        self._axle_pairs = np.array(self._axles, dtype=np.int64).reshape(-1, 2)
        self._gate_limits = np.array([
            p.sample_rate_hz, p.rolling_radius_m, p.speed_band_kmh[0], p.speed_band_kmh[1],
            p.max_accel_mps2, p.max_wheel_torque_nm, p.max_lateral_accel_mps2, p.wheelbase_m,
            p.max_slip], dtype=float)
        self._partner = np.arange(N_WHEELS)
        for left, right in self._axles:
            self._partner[[left, right]] = right, left
        lags = p.partner_lags
        # The partner lags as a window: every ``_lag_step``-th sample within +-``_lag_reach``.
        self._lag_reach = int(lags.max()) if lags.size else 0
        self._lag_step = int(lags[1] - lags[0]) if lags.size > 1 else 1
        self._families = ls_families(self._axles, p.drive_compensation, lags.size)
        self._counters: dict[str, np.ndarray] = {}
        self._calibration: _Calibration | None = None
        self._wheel_calibrated = np.zeros(N_WHEELS, dtype=bool)
        self._k_nominal = np.full(N_WHEELS, np.nan)
        self.calibration_check = StoredCalibrationCheck(N_WHEELS)
        self._k_block_std = np.full(N_WHEELS, np.nan)
        self.reset()

    # ---------------------------------------------------------------- state management

    def reset(self) -> None:
        """Forget all filter and LS state (the calibration is kept)."""
        p = self.params
        n_sec = self._band_sos.shape[0]
        self._band_zi = np.zeros((n_sec, 2, N_WHEELS))
        self._lowpass_zi = np.zeros((self._lowpass_sos.shape[0], 2, N_WHEELS))
        self._obs_zi = [np.zeros((3, design.denominator.size - 1, wheels.size))
                        for wheels, design, _ in self._groups]
        self._prev_lowpass = np.zeros(N_WHEELS)
        (self._last_value, self._run, self._prev_good, self._prev_code, self._hold,
         self._since_reset, self._reset_cause) = sensor_state()
        self._last_stamp = -math.inf
        self._timing_pending = False
        # Partial block carried between chunks: per-sample arrays of the unfinished block
        # (and, with partner lags, the samples the last block's lags reach into).
        self._partial: list[np.ndarray] = []
        # The band-passed speeds just before the carried samples, for the partner lags.
        self._band_history = np.zeros((self._lag_reach, N_WHEELS))
        self._noise = (QuantisationNoise(N_WHEELS, p.encoder_teeth, p.sample_rate_hz,
                                         self._noise_timer_s, p.encoder_speed_method,
                                         p.encoder_window_s)
                       if self._noise_timer_s > 0.0 and (self._noise_scale > 0.0
                                                         or self._timer_read_at == math.inf)
                       else None)
        self._noise_band_zi: np.ndarray = np.zeros_like(self._band_zi)
        self._noise_obs_zi: list[np.ndarray] = [np.zeros_like(zi) for zi in self._obs_zi]
        # Sample index of the first sample of the next block (a reset drops the partial one).
        self._block_start = self._samples
        self._tooth = ToothErrorCorrector(N_WHEELS, p.encoder_teeth, p.sample_rate_hz,
                                          p.tooth_learning_s, p.tooth_phase_s, p.block_samples,
                                          p.tooth_learned_s,
                                          fast_edge_rate=p.max_tooth_rate_fraction)
        self._ls = [BlockLeastSquares(f.wheels.shape[0], f.n_params, p.forgetting_factors,
                                    p.batch_window_blocks,
                                    p.min_block_fraction * p.block_samples)
                    for f in self._families]
        self._last_block_code = np.full(N_WHEELS, -1)
        self._trust = _TrustWindow(p.memory_blocks)
        self._stamp = math.nan
        # The estimate only changes when a block completes or the calibration changes; caching
        # it keeps small streaming chunks cheap.
        self._cached: StiffnessEstimate | None = None
        # The least squares' coefficients after the last block, when the restart check solved
        # them (:meth:`raw_coefficients` otherwise).
        self._coef: np.ndarray | None = None
        for name in (*REASONS[1:], 'out_of_order', 'timing_breaks', 'resets',
                     'torque_invalid', 'steering_invalid'):
            self._counters[name] = np.zeros(N_WHEELS, dtype=np.int64)

    @property
    def encoder_noise(self) -> str:
        """How the encoder's quantisation noise is handled, for diagnostics."""
        p = self.params
        if not p.encoder_noise_removal:
            return 'not removed (encoder_noise_removal false)'
        lattice = self._timer_lattice
        if lattice is None:
            if p.encoder_timer_s > 0.0:
                return f'removed (timer {p.encoder_timer_s * 1e6:.4g} us, given)'
            return "not removed: 'window_average' speeds need encoder_timer_s given"
        if lattice.timer_s is None:
            return (f'reading the ECU timer from the wheel speeds ({lattice.collected} distinct '
                    'readings so far); the estimate and the calibration wait for it')
        if lattice.timer_s > 0.0 and self._noise_until < math.inf:
            return (f'removed until sample {self._noise_until}, then not: the speeds looked '
                    f'like held periods on a {lattice.timer_s * 1e6:.4g} us timer, but they are '
                    'window averages (a window holds one tooth at low speeds; give '
                    'encoder_timer_s, encoder_speed_method and encoder_window_s)')
        if lattice.timer_s > 0.0:
            return (f'removed (timer {lattice.timer_s * 1e6:.4g} us, read from the wheel '
                    'speeds)')
        return ('not removed: the wheel speeds are not held tooth periods on a timer lattice '
                '(give encoder_timer_s and encoder_speed_method)')

    def _read_timer(self, omega: np.ndarray, code: np.ndarray) -> None:
        """Feed the timer lattice the readings the method uses; once it decides, scale the
        noise to the timer read (or stop it) and note the sample; after that, note the sample
        from which the readings are seen to be window averages (the noise then stays in)."""
        lattice = self._timer_lattice
        assert lattice is not None
        valid = code == OK
        start = 0
        if self._timer_read_at == math.inf:
            row = lattice.add(omega, valid)
            if row is None:
                return
            assert lattice.timer_s is not None
            self._timer_read_at = self._samples + row + 1
            self._noise_scale = (lattice.timer_s / self._noise_timer_s) ** 2
            if lattice.timer_s == 0.0:
                self._noise = None
            start = row + 1
        row = lattice.watch(omega[start:], valid[start:])
        if row is not None:
            self._noise_until = self._samples + start + row

    @property
    def counters(self) -> dict[str, tuple[int, ...]]:
        """Cumulative per-wheel counts.

        Rejected samples by sensor fault ('invalid_sample', 'dead_sensor', 'stuck_sensor');
        samples refused for a wrong ``dt`` ('timing'); samples masked while settling after a
        reset ('settling') or by each gate ('axle_partner', 'wheel_slip', 'wheel_torque',
        'cornering', 'acceleration', 'speed_band'); events: 'out_of_order' samples dropped,
        'timing_breaks' (gaps/rate jumps), filter 'resets', non-finite torque and steering
        samples ('torque_invalid', 'steering_invalid': that gate is then skipped).
        """
        return {name: tuple(int(v) for v in values) for name, values in self._counters.items()}

    @property
    def tooth_angle_mode(self) -> np.ndarray:
        """(4,) wheels whose speeds are not held tooth periods (a window average, say): their
        tooth correction works in the angle domain (a copy)."""
        return self._tooth.angle_mode

    @property
    def tooth_pattern(self) -> np.ndarray:
        """(4, teeth) each wheel's learned log speed error per encoder tooth, in the order its
        tooth count runs (a copy; zeros without the tooth correction)."""
        return self._tooth.pattern

    @property
    def observer_designs(self) -> tuple[ObserverDesign, ...]:
        """The observer design of each wheel (FL..RR)."""
        by_wheel: list[ObserverDesign | None] = [None] * N_WHEELS
        for wheels, design, _ in self._groups:
            for w in wheels:
                by_wheel[w] = design
        return tuple(d for d in by_wheel if d is not None)

    # ---------------------------------------------------------------- calibration

    def start_calibration(self, duration_s: float | None = None) -> None:
        """Start (or restart) learning each tire's nominal K over ``duration_s`` of valid data.

        Args:
            duration_s: valid-data time per tire; default ``params.calibration_s``.
        """
        duration = self.params.calibration_s if duration_s is None else duration_s
        if not (math.isfinite(duration) and duration > 0):
            raise ValueError(f'duration_s must be finite and > 0, got {duration}')
        needed = max(2, int(math.ceil(duration / self.params.block_s)))
        self.calibration_check.cancel()
        self._calibration = _Calibration(
            [np.zeros((f.wheels.shape[0], f.n_params, f.n_params)) for f in self._families],
            [np.zeros((f.wheels.shape[0], f.n_params)) for f in self._families],
            [[] for _ in range(N_WHEELS)], np.zeros(N_WHEELS, dtype=int), needed)
        self._wheel_calibrated = np.zeros(N_WHEELS, dtype=bool)
        self._cached = None

    @property
    def calibrating(self) -> bool:
        """A calibration is running."""
        return self._calibration is not None

    def calibration_complete(self) -> bool:
        """Every tire has finished its calibration (its ``calibration_s`` of valid data): the
        run counts valid data per tire itself, so a :class:`CalibrationManager` asks here
        rather than counting data time."""
        return bool(np.all(self._wheel_calibrated))

    def calibration_missing(self) -> str:
        """The tires still collecting their valid data in the running calibration ('' when
        none), with the valid data they have."""
        cal = self._calibration
        if cal is None:
            return ''
        if self._timer_read_at == math.inf:
            return self.encoder_noise
        block_s = self.params.block_s
        short = [f'{TIRE_NAMES[w]} {cal.blocks[w] * block_s:.1f}'
                 for w in np.flatnonzero(~self._wheel_calibrated)]
        return (f'{", ".join(short)} of {cal.needed_blocks * block_s:g} s of valid data'
                if short else '')

    def finish_calibration(self) -> None:
        """Confirm a finished run (each tire's calibration went into force as it completed).

        Raises:
            ValueError: a tire has not collected its valid data yet.
        """
        if not self.calibration_complete():
            missing = [TIRE_NAMES[w] for w in np.flatnonzero(~self._wheel_calibrated)]
            raise ValueError(f'calibration not finished: {", ".join(missing)} lack valid data')

    def calibration_state(self) -> dict[str, Any]:
        """The learned calibration as a plain dict (JSON/YAML-safe) for persisting.

        Raises:
            ValueError: when not all four tires are calibrated.
        """
        if not np.all(self._wheel_calibrated):
            raise ValueError('calibration_state: not all tires are calibrated')
        return {
            'version': CALIBRATION_VERSION,
            'k_nominal': [float(v) for v in self._k_nominal],
            'k_block_std': [float(v) for v in self._k_block_std],
            'block_s': float(self.params.block_s),
            'model_k': [float(v) for v in self._model_k],
        }

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Install a calibration from :meth:`calibration_state` output, after validating it.

        Raises:
            ValueError: naming the offending key when the dict is corrupt or does not fit the
                current model (the current calibration is then left unchanged).
        """
        if not isinstance(state, Mapping):
            raise ValueError(f'calibration must be a mapping, got {type(state).__name__}')
        if state.get('version') != CALIBRATION_VERSION:
            raise ValueError(f"calibration 'version' must be {CALIBRATION_VERSION}, "
                             f"got {state.get('version')!r}")
        arrays = {}
        for key in ('k_nominal', 'k_block_std', 'model_k'):
            value = state.get(key)
            try:
                arr = np.asarray(value, dtype=float)
            except (TypeError, ValueError):
                raise ValueError(f'calibration {key!r} is not numeric: {value!r}') from None
            # The block spread is a median absolute deviation: 0 when the calibration's blocks
            # agree (or were clipped alike), which a restart must be able to reload.
            low_ok = arr >= 0 if key == 'k_block_std' else arr > 0
            if arr.shape != (N_WHEELS,) or not np.all(np.isfinite(arr)) or not np.all(low_ok):
                bound = '>= 0' if key == 'k_block_std' else '> 0'
                raise ValueError(f'calibration {key!r} must be {N_WHEELS} finite values '
                                 f'{bound}, got {value!r}')
            arrays[key] = arr
        block_s = state.get('block_s')
        if not (isinstance(block_s, (int, float)) and math.isfinite(block_s) and block_s > 0):
            raise ValueError(f"calibration 'block_s' must be finite and > 0, got {block_s!r}")
        if not np.allclose(arrays['model_k'], self._model_k, rtol=1e-9):
            raise ValueError("calibration 'model_k' does not match the estimator's tire model "
                             f"{self._model_k.tolist()}: recalibrate")
        ratio = arrays['k_nominal'] / self._model_k
        if np.any((ratio < 0.25) | (ratio > 3.0)):
            raise ValueError(f"calibration 'k_nominal' is implausible (K/K_model = "
                             f'{ratio.tolist()}, allowed 0.25..3)')
        self._k_nominal = arrays['k_nominal']
        # Block noise scales as 1/sqrt(block length) when the block length changed.
        self._k_block_std = arrays['k_block_std'] * math.sqrt(block_s / self.params.block_s)
        self._wheel_calibrated = np.ones(N_WHEELS, dtype=bool)
        self._calibration = None
        self._cached = None
        self.calibration_check.start(self.params)

    def _check_calibration(self, samples: int) -> None:
        """Add the estimate after ``samples`` new samples to the pending check of a stored
        calibration (tires that would be 'ok'; the resonance ratio sqrt(K / K0)); refuse the
        calibration when the tires do not fit it: the tires are then uncalibrated."""
        est = self.estimate()
        checked = np.array([status == CHECKING for status in est.status])
        with np.errstate(invalid='ignore'):
            ratio = np.where(checked, np.sqrt(est.stiffness_ratio), np.nan)
        decided = self.calibration_check.add(ratio[None, :],
                                             samples / self.params.sample_rate_hz, self.params)
        if decided is None:
            return
        self._cached = None
        if self.calibration_check.fits(decided[0], self.params):
            return
        median_ratio, mean = decided
        k0 = self._k_nominal
        measured = ', '.join(f'{TIRE_NAMES[w]} {m * m * k:.0f}' for w, (m, k) in
                             enumerate(zip(mean, k0, strict=True)) if np.isfinite(m))
        stored = ', '.join(f'{k:.0f}' for k in k0)
        self.calibration_check.refuse(f'stiffness {measured}', f'{stored} N m/rad', median_ratio,
                                      self.params)
        self._k_nominal = np.full(N_WHEELS, np.nan)
        self._wheel_calibrated = np.zeros(N_WHEELS, dtype=bool)

    def _collect_calibration(self, block_k: np.ndarray, good: np.ndarray,
                             sums: Sequence[tuple[np.ndarray, np.ndarray]]) -> None:
        """Add completed blocks to a running calibration; finish the tires that have enough.

        Args:
            block_k: (B, 4) per-block stiffness estimates per wheel.
            good: (B, 4) blocks that count per wheel.
            sums: per LS family, the block normal equations (gram (B, P, n, n), rhs (B, P, n)).
        """
        cal = self._calibration
        if cal is None:
            return
        usable = good & np.isfinite(block_k)
        for f, family in enumerate(self._families):
            for problem, wheels in enumerate(family.wheels):
                first = wheels[0]
                if self._wheel_calibrated[first]:
                    continue
                take = usable[:, wheels].all(axis=1)
                take &= np.cumsum(take) <= cal.needed_blocks - cal.blocks[first]
                cal.gram[f][problem] += sums[f][0][take, problem].sum(axis=0)
                cal.rhs[f][problem] += sums[f][1][take, problem].sum(axis=0)
                for w in wheels:
                    cal.block_k[w].extend(block_k[take, w].tolist())
                    cal.blocks[w] += int(take.sum())
                if cal.blocks[first] < cal.needed_blocks:
                    continue
                solution = np.full((family.wheels.shape[0], family.n_params), np.nan)
                solution[problem] = solve_normal(cal.gram[f][problem], cal.rhs[f][problem])
                pooled = np.full((N_WHEELS, 2), np.nan)
                family.to_wheels(solution, pooled)    # only this problem's wheels are read
                k_pooled = self._stiffness_from_raw(pooled[:, 0])
                for w in wheels:
                    ks = np.asarray(cal.block_k[w])
                    self._k_nominal[w] = float(k_pooled[w])
                    self._k_block_std[w] = _robust_spread(ks)
                    self._wheel_calibrated[w] = bool(np.isfinite(k_pooled[w]))
        if np.all(self._wheel_calibrated):
            self._calibration = None

    # ---------------------------------------------------------------- helpers

    def _stiffness_from_raw(self, raw_dk: np.ndarray) -> np.ndarray:
        """(..., 4) raw dK coefficients -> K estimates."""
        out = np.empty_like(raw_dk, dtype=float)
        for wheels, _, cmap in self._groups:
            if self.params.consistency_correction:
                out[..., wheels] = cmap.stiffness_from_raw(raw_dk[..., wheels])
            else:
                out[..., wheels] = self._model_k[wheels] + raw_dk[..., wheels]
        return np.where(np.isfinite(raw_dk), out, np.nan)

    def _delta_d(self, raw_dd: np.ndarray, stiffness: np.ndarray) -> np.ndarray:
        out = raw_dd.copy()
        if self.params.consistency_correction:
            for wheels, _, cmap in self._groups:
                out[wheels] = raw_dd[wheels] - cmap.expected_raw_dd(stiffness[wheels])
        return out

    def _reset_wheels(self, wheels: np.ndarray, values: np.ndarray) -> None:
        """Reset the filter states of ``wheels`` to steady state at speed ``values``."""
        self._band_zi[:, :, wheels] = (sig.sosfilt_zi(self._band_sos)[:, :, None]
                                       * values[None, None, :])
        self._lowpass_zi[:, :, wheels] = (sig.sosfilt_zi(self._lowpass_sos)[:, :, None]
                                          * values[None, None, :])
        # The encoder noise's filters start from rest: the noise has zero mean.
        self._noise_band_zi[:, :, wheels] = 0.0
        for (group_wheels, _, _), zi, noise_zi in zip(self._groups, self._obs_zi,
                                                      self._noise_obs_zi, strict=True):
            cols = np.isin(group_wheels, wheels)
            zi[:, :, cols] = 0.0
            noise_zi[:, :, cols] = 0.0
        self._tooth.reset(wheels)
        if self._noise is not None:
            self._noise.reset(wheels)
        self._counters['resets'][wheels] += 1

    def _filter(self, omega: np.ndarray, good: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Run gate low-pass, tooth correction, band-pass and observer on a continuous segment.

        Args:
            omega: (n, 4) wheel speeds, bad samples held.
            good: (n, 4) valid sensor samples (the tooth pattern learns from these only).

        Returns:
            (outputs (n, 4, 4) = [th, th_dot, w, band-passed speed], low-passed speed (n, 4),
            (n, 4) samples whose wheel's tooth pattern is learned (all without the correction)).
        """
        low = np.empty_like(omega)
        sosfilt_columns(self._lowpass_sos, omega, self._lowpass_zi, low)
        learned = np.ones(omega.shape, dtype=bool)
        if self.params.tooth_correction:
            # The pattern learns in the speed band only: below it the low-passed reference
            # lags a crawl by far more than a tooth's error (issue 21: a 0.5 km/h crawl put
            # ratios of order 1 into a few teeth, and the tires read +190 kPa for a minute).
            in_band = low * (3.6 * self.params.rolling_radius_m) >= self.params.speed_min_kmh
            omega, learned = self._tooth.process(omega, low, good & in_band)
        out = np.empty(omega.shape + (4,))
        out[:, :, 3], out[:, :, :3] = self._observe(omega, self._band_zi, self._obs_zi)
        return out, low, learned

    def _observe(self, speed: np.ndarray, band_zi: np.ndarray,
                 obs_zi: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
        """Band-pass and observer of (n, 4) speeds from the given filter states (``band_zi``
        and ``obs_zi``, one per tire group, updated in place).

        Returns:
            (band-passed speed (n, 4), observer outputs [th, th_dot, w] (n, 4, 3)).
        """
        band = np.empty_like(speed)
        sosfilt_columns(self._band_sos, speed, band_zi, band)
        out = np.empty(speed.shape + (3,))
        for (wheels, _, _), filters, zi in zip(self._groups, self._observer_filters, obs_zi,
                                               strict=True):
            x = band[:, wheels]
            y = np.empty_like(x)
            for k, (b, a) in enumerate(filters):
                lfilter_columns(b, a, x, zi[k], y)
                out[:, wheels, k] = y
        return band, out

    def _noise_products(self, speed: np.ndarray) -> np.ndarray:
        """(n, 4, 5) products of the synthetic quantisation noise's filtered [th, th_dot, w]
        per sample, at the wheels' (low-passed) speeds (n, 4)."""
        assert self._noise is not None
        _, filtered = self._observe(self._noise.process(speed), self._noise_band_zi,
                                    self._noise_obs_zi)
        rows, cols = zip(*_NOISE_PRODUCTS, strict=True)
        return filtered[..., rows] * filtered[..., cols]

    def _remove_noise(self, family: LsFamily, out: np.ndarray, problem_mask: np.ndarray,
                      scale: np.ndarray, gram: np.ndarray, rhs: np.ndarray) -> None:
        """Subtract the synthetic noise's products over the counted samples from a family's
        block sums, in place: each wheel's own [th, th_dot] rows and its w. The partner lags
        carry the partner's noise, independent of this wheel's; subtracting their own moments
        too left the driven wheels' normal equations ill-conditioned (docs/methods/
        tpms_family_evaluation.md, "2026-12-02"), so they are left as they are.

        Args:
            family: the LS problems; ``out`` (B, L, 4, C) the block samples; ``problem_mask``
                (B, L, P) where a problem's sample counts (:meth:`_regressors`); ``scale``
                (B,) what each block's products are multiplied by ((timer / the step the noise
                was generated on)^2, or 0).
        """
        for j in range(family.wheels.shape[1]):
            wheels = family.wheels[:, j]
            k_th, k_dot = family.coef_index[j]
            sign = family.coef_sign[j]
            sums = scale[:, None, None] * np.einsum('blp,blpk->bpk', problem_mask,
                                                    out[:, :, wheels, 4:])
            gram[..., k_th, k_th] -= sums[..., 0]
            gram[..., k_th, k_dot] -= sums[..., 1]
            gram[..., k_dot, k_th] -= sums[..., 1]
            gram[..., k_dot, k_dot] -= sums[..., 2]
            rhs[..., k_th] -= sign * sums[..., 3]
            rhs[..., k_dot] -= sign * sums[..., 4]

    # ---------------------------------------------------------------- streaming update

    def update(self, omega: np.ndarray, *, stamps: np.ndarray | None = None,
               dt: float | None = None,
               wheel_torque: np.ndarray | None = None,
               steering_angle: np.ndarray | None = None) -> StiffnessEstimate:
        """Process a chunk of wheel speeds and return the current estimate.

        Args:
            omega: (N, 4) wheel angular speeds, rad/s, FL..RR. Bad values are rejected per
                sample and counted.
            stamps: (N,) sample times, s. Repeated or out-of-order samples are dropped; gaps
                and interval changes beyond ``timing_tolerance`` reset the filters.
            dt: sample interval of the whole chunk, s, when no stamps are given (a mismatch
                with ``sample_rate_hz`` rejects the chunk). Neither: nominal rate assumed.
            wheel_torque: optional (N, 4) drive/brake torque per wheel, N m, for the gate.
            steering_angle: optional (N,) front road-wheel angle, rad, for the cornering gate
                (non-finite: unknown, the gate is skipped for that sample and counted).

        Raises:
            ValueError: on wrong shapes or a non-positive ``dt`` (caller errors, not data).
        """
        p = self.params
        omega = np.asarray(omega, dtype=float)
        if omega.ndim != 2 or omega.shape[1] != N_WHEELS:
            raise ValueError(f'omega must have shape (N, {N_WHEELS}), got {omega.shape}')
        n = omega.shape[0]
        if wheel_torque is not None:
            wheel_torque = np.asarray(wheel_torque, dtype=float)
            if wheel_torque.shape != omega.shape:
                raise ValueError(f'wheel_torque must have shape {omega.shape}, '
                                 f'got {wheel_torque.shape}')
        if steering_angle is not None:
            steering_angle = np.asarray(steering_angle, dtype=float)
            if steering_angle.shape != (n,):
                raise ValueError(f'steering_angle must have shape ({n},), '
                                 f'got {steering_angle.shape}')
        timing_break = np.zeros(n, dtype=bool)
        if stamps is not None:
            stamps = np.asarray(stamps, dtype=float)
            if stamps.shape != (n,):
                raise ValueError(f'stamps must have shape ({n},), got {stamps.shape}')
            # A sample is kept when its stamp is later than every earlier one.
            prior_max = np.maximum.accumulate(np.concatenate(([self._last_stamp], stamps)))
            keep = np.isfinite(stamps) & (stamps > prior_max[:-1])
            self._counters['out_of_order'] += int(np.count_nonzero(~keep))
            omega, stamps = omega[keep], stamps[keep]
            if wheel_torque is not None:
                wheel_torque = wheel_torque[keep]
            if steering_angle is not None:
                steering_angle = steering_angle[keep]
            n = omega.shape[0]
            if n:
                interval = np.diff(np.concatenate(([self._last_stamp], stamps)))
                timing_break = np.abs(interval * p.sample_rate_hz - 1.0) > p.timing_tolerance
                if not math.isfinite(self._last_stamp):
                    timing_break[0] = False  # the first sample ever: a plain start
                self._last_stamp = float(stamps[-1])
                self._stamp = float(stamps[-1])
        elif dt is not None:
            if not (math.isfinite(dt) and dt > 0):
                raise ValueError(f'dt must be finite and > 0, got {dt}')
            if abs(dt * p.sample_rate_hz - 1.0) > p.timing_tolerance:
                # Samples at another rate cannot go through filters designed for this one.
                self._counters['timing'] += n
                self._timing_pending = True
                self._prev_good[:] = False
                self._prev_code[:] = _CODE['timing']
                return self.estimate()
        if n == 0:
            return self.estimate()
        if self._timing_pending:
            timing_break[0] = True
            self._timing_pending = False
        self._counters['timing_breaks'] += int(np.count_nonzero(timing_break))
        self._process(omega, timing_break, wheel_torque, steering_angle)
        if self.calibration_check.pending:
            self._check_calibration(n)
        return self.estimate()

    def _process(self, omega: np.ndarray, timing_break: np.ndarray,
                 wheel_torque: np.ndarray | None, steering_angle: np.ndarray | None) -> None:
        p = self.params
        n = omega.shape[0]

        # --- per-sample sensor validity, resets, hold of bad samples, settling ---------------
        # Held values for bad samples keep the filters finite; they are masked and the wheel
        # is reset when good data resumes, so they never reach an estimate.
        code, good, reset, filled, counts = sensor_checks(p, omega, timing_break, (
            self._last_value, self._run, self._prev_good, self._prev_code, self._hold,
            self._since_reset, self._reset_cause), counted=~self.tooth_angle_mode)
        for row, name in enumerate(('invalid_sample', 'dead_sensor', 'stuck_sensor',
                                    'settling')):
            self._counters[name] += counts[row]

        # --- filters, split at reset rows ----------------------------------------------------
        outputs = np.empty((n, N_WHEELS, self._channels))
        lowpass = np.empty((n, N_WHEELS))
        learned = np.empty((n, N_WHEELS), dtype=bool)
        reset_rows = np.flatnonzero(reset.any(axis=1))
        bounds = np.union1d(reset_rows, [0, n])
        for s, e in zip(bounds[:-1], bounds[1:], strict=True):
            wheels = np.flatnonzero(reset[s])
            if wheels.size:
                self._reset_wheels(wheels, omega[s, wheels])
            outputs[s:e, :, :4], lowpass[s:e], learned[s:e] = self._filter(filled[s:e],
                                                                            good[s:e])
            if self._noise is not None:
                outputs[s:e, :, 4:] = self._noise_products(lowpass[s:e])
            else:
                outputs[s:e, :, 4:] = 0.0

        # --- validity gates (the data are fine, the method is not valid here) ---------------
        # Driven axles need both wheels: a wheel whose partner is masked is masked too. The
        # acceleration differences from the low-passed speed before the chunk, from before any
        # reset, so the chunking cannot matter (the derivative at a reset row is masked by the
        # settling anyway).
        tallies = np.zeros((len(REASONS) + 2, N_WHEELS), dtype=np.int64)
        _gate_chunk(lowpass, self._prev_lowpass, good, code,
                    _EMPTY_2D if wheel_torque is None else wheel_torque,
                    _EMPTY_1D if steering_angle is None else steering_angle, learned,
                    self._gate_limits, self._axle_pairs, tallies)
        self._prev_lowpass = lowpass[-1].copy()
        for name in ('axle_partner', 'wheel_slip', 'wheel_torque', 'cornering', 'acceleration',
                     'speed_band', 'tooth_learning'):
            self._counters[name] += tallies[_CODE[name]]
        if wheel_torque is not None:
            self._counters['torque_invalid'] += tallies[_TORQUE_INVALID]
        if steering_angle is not None:
            self._counters['steering_invalid'] += tallies[_STEERING_INVALID]

        if self._timer_lattice is not None:
            self._read_timer(omega, code)
        self._samples += n
        self._accumulate(outputs, code)

    def _accumulate(self, outputs: np.ndarray, code: np.ndarray) -> None:
        """Cut the chunk into LS blocks (carrying the partial one, and the samples the partner
        lags of the last block reach into) and update the LS problems.

        Args:
            outputs: (n, 4, C) per sample and wheel [th, th_dot, w, band-passed speed] and,
                with ``encoder_timer_s``, the noise's products (:meth:`_noise_products`).
            code: (n, 4) reason codes (OK: the sample counts).
        """
        block_len = self.params.block_samples
        reach = self._lag_reach
        if self._partial:
            outputs = np.concatenate((self._partial[0], outputs))
            code = np.concatenate((self._partial[1], code))
        n_blocks = max(outputs.shape[0] - reach, 0) // block_len
        cut = n_blocks * block_len
        band = np.concatenate((self._band_history, outputs[:, :, 3]))
        self._partial = [outputs[cut:], code[cut:]]
        self._band_history = band[cut:cut + reach]
        if n_blocks == 0:
            return
        self._cached = None
        self._coef = None
        out = outputs[:cut].reshape(n_blocks, block_len, N_WHEELS, self._channels)
        blk_code = code[:cut].reshape(n_blocks, block_len, N_WHEELS)
        mask = (blk_code == OK).astype(float)
        # Blocks that began before the timer was read carry no (or unscaled) noise removal.
        block_start = self._block_start + block_len * np.arange(n_blocks)
        self._block_start += cut
        mask[block_start < self._timer_read_at] = 0.0
        noise_scale = np.where(block_start < self._noise_until, self._noise_scale, 0.0)
        good = np.zeros((n_blocks, N_WHEELS), dtype=bool)
        block_raw = np.full((n_blocks, N_WHEELS, 2), np.nan)
        sums = []
        problems_good = []
        for family, ls in zip(self._families, self._ls, strict=True):
            regressors, target, problem_mask = self._regressors(family, out, mask, band)
            gram, rhs, count = ls.block_sums(regressors, target, problem_mask)
            if np.any(noise_scale > 0.0):
                self._remove_noise(family, out, problem_mask, noise_scale, gram, rhs)
            problem_good = ls.good_blocks(count)
            good[:, family.wheels] = problem_good[:, :, None]
            sums.append((gram, rhs))
            problems_good.append(problem_good)
            family.to_wheels(solve_normal(gram, rhs), block_raw)
        block_k = self._stiffness_from_raw(block_raw[..., 0])
        if self._calibration is not None:
            self._collect_calibration(block_k, good, sums)
        usable = good & np.isfinite(block_k)
        for b in range(n_blocks):
            for ls, (gram, rhs), problem_good in zip(self._ls, sums, problems_good, strict=True):
                ls.update(gram[b:b + 1], rhs[b:b + 1], problem_good[b:b + 1])
            self._trust.add(block_k[b:b + 1], usable[b:b + 1])
            self._restart_parted_readings()
        # Status follows each wheel's last block: 'ok' when it counted, else its most
        # specific reason.
        last = blk_code[-1]
        worst = np.where(last == OK, _NO_REASON, last).min(axis=0)
        self._last_block_code = np.where(good[-1] | (worst == _NO_REASON), OK, worst)

    def _regressors(self, family: LsFamily, out: np.ndarray, mask: np.ndarray,
                    band: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A family's (regressors (B, L, P, n), target (B, L, P), mask (B, L, P)).

        Args:
            family: the LS problems.
            out: (B, L, 4, 4) block samples [th, th_dot, w, band-passed speed].
            mask: (B, L, 4) 1 where a sample counts.
            band: (reach + B L + ..., 4) band-passed speeds from ``reach`` samples before the
                first block on (the partner lags' source).
        """
        first = family.wheels[:, 0]
        zeta, w = out[..., :2], out[..., 2]
        if family.kind == 'difference':
            left, right = family.wheels[:, 0], family.wheels[:, 1]
            regressors = np.concatenate((zeta[:, :, left, :1], zeta[:, :, right, :1],
                                         zeta[:, :, left, 1:], zeta[:, :, right, 1:]), axis=-1)
            return regressors, w[:, :, left] - w[:, :, right], mask[:, :, left] * mask[:, :, right]
        regressors = zeta[:, :, first]
        if family.kind == 'partner':
            n_blocks, block_len = out.shape[:2]
            # Row i of the blocks is band row reach + i; its lag l sample is band row
            # reach + i - l, for l from -reach to reach.
            windows = np.lib.stride_tricks.sliding_window_view(
                band[:n_blocks * block_len + 2 * self._lag_reach, self._partner[first]],
                2 * self._lag_reach + 1, axis=0)[:, :, ::self._lag_step]
            lagged = windows.reshape(n_blocks, block_len, first.size, family.n_params - 2)
            regressors = np.concatenate((regressors, lagged), axis=-1)
        return regressors, w[:, :, first], mask[:, :, first]

    def _restart_parted_readings(self) -> None:
        """Restart the reading's memory from the warning's on the wheels where the two parted:
        their stiffnesses differ by more than ``steady_max_sigmas`` of the warning's noise (the
        robust spread of its memory's blocks over its effective blocks). A change of pressure
        is then read as the warning sees it; at a steady pressure the reading keeps averaging."""
        p = self.params
        rho = p.forgetting_factors
        if p.ls_mode == 'batch' or rho[1] == rho[0]:
            return
        coef = self.raw_coefficients()
        stiffness = self._stiffness_from_raw(coef[..., 0])
        sigma = self._trust.spread() / math.sqrt(p.effective_blocks[0])
        with np.errstate(invalid='ignore'):
            parted = np.abs(stiffness[1] - stiffness[0]) > p.steady_max_sigmas * sigma
        for family, ls in zip(self._families, self._ls, strict=True):
            problems = parted[family.wheels].any(axis=1)
            if problems.any():
                ls.restart(problems, round(READING_HOLD_MEMORIES * p.memory_blocks))
                wheels = family.wheels[problems].ravel()
                coef[1, wheels] = coef[0, wheels]   # the restarted memory's solution now
        self._coef = coef

    # ---------------------------------------------------------------- output

    def raw_coefficients(self) -> np.ndarray:
        """(2, 4, 2) raw LS coefficients [dK, dD] per memory (the warning's, the reading's)
        and wheel (driven axles: compensated)."""
        coef = np.full((2, N_WHEELS, 2), np.nan)
        for family, ls in zip(self._families, self._ls, strict=True):
            if self.params.ls_mode == 'batch':
                family.to_wheels(np.broadcast_to(ls.batch(), (2, *ls.rhs.shape[1:])), coef)
            else:
                family.to_wheels(ls.rls(), coef)
        return coef

    def _converged(self) -> np.ndarray:
        """(4,): the warning's memory of each wheel has filled to 1 - 1/e of its blocks."""
        p = self.params
        fill = np.zeros(N_WHEELS)
        for family, ls in zip(self._families, self._ls, strict=True):
            fill[family.wheels] = (ls.window_fill if p.ls_mode == 'batch'
                                   else ls.n_eff[0])[:, None]
        if p.ls_mode == 'batch':
            need = float(p.batch_window_blocks)
        else:
            need = (1.0 - math.exp(-1.0)) / (1.0 - p.forgetting_factor)
        return fill >= need - 1e-9

    def trust_features(self) -> dict[str, np.ndarray]:
        """Per tire: ``blocks``, the counted blocks behind the trust measure (up to one RLS
        memory, or the batch window), and ``spread_ratio``, their robust spread of block
        stiffness over the calibration's (NaN until calibrated)."""
        known = self._wheel_calibrated & (self._k_block_std > 0)
        spread_ratio = np.where(known, self._trust.spread()
                                / np.where(known, self._k_block_std, 1.0), np.nan)
        return {'blocks': self._trust.held().astype(float), 'spread_ratio': spread_ratio}

    def _untrusted(self, calibrated: np.ndarray, features: dict[str, np.ndarray]) -> list[str]:
        """Per tire: the 'uncertain_*' reason its estimate is not trusted, or ''.

        Args:
            calibrated: (4,) tires with a calibration in force.
            features: :meth:`trust_features` now.
        """
        p = self.params
        reasons = [''] * N_WHEELS
        if not p.trust_check:
            return reasons
        for w in range(N_WHEELS):
            if not calibrated[w]:
                continue
            if features['spread_ratio'][w] > p.trust_max_spread_ratio:
                reasons[w] = 'uncertain_noisy'
        return reasons

    def estimate(self) -> StiffnessEstimate:
        """The current estimate (no new data)."""
        if self._cached is None:
            self._cached = self._compute_estimate()
        return replace(self._cached, stamp=self._stamp)

    def _compute_estimate(self) -> StiffnessEstimate:
        p = self.params
        # Rows: the warning's memory, the reading's (the two memories of the least squares).
        coef = self.raw_coefficients() if self._coef is None else self._coef
        stiffness = self._stiffness_from_raw(coef[..., 0])
        calibrated = self._wheel_calibrated.copy()
        k_nominal = np.where(calibrated, self._k_nominal, self._model_k)
        ratio = stiffness / k_nominal
        p0 = np.asarray(p.nominal_pressure_kpa)
        pressure = p0 * p.pressure_relation.pressure_ratio(ratio)
        # The noise of the blocks behind the estimate: the calibration's, or the recent blocks'
        # where they spread wider.
        features = self.trust_features()
        block_std = np.fmax(self._k_block_std, features['spread_ratio'] * self._k_block_std)
        sigma_ratio = block_std / np.sqrt(p.effective_blocks)[:, None] / k_nominal
        # The noise is that of the stiffness ratio, through the law's local slope (at placard
        # while the ratio is unknown).
        gain = p.pressure_relation.pressure_ratio_per_stiffness_ratio(
            np.where(np.isfinite(ratio), ratio, 1.0))
        pressure_std = np.where(calibrated, p0 * sigma_ratio * gain, np.nan)
        converged = self._converged()
        untrusted = self._untrusted(calibrated, features)
        sigma_total = np.hypot(pressure_std[0], p.model_error_ratio * p0)
        delta_d = self._delta_d(coef[1, :, 1], np.where(np.isfinite(stiffness[1]), stiffness[1],
                                                        self._model_k))
        status = []
        for w in range(N_WHEELS):
            code = int(self._last_block_code[w])
            if code < 0:
                status.append('no_data')
            elif code != OK:
                status.append(REASONS[code])
            elif not np.isfinite(stiffness[0, w]):
                status.append('no_excitation')
            elif not converged[w]:
                status.append('converging')
            elif untrusted[w]:
                status.append(untrusted[w])
            elif calibrated[w] and self.calibration_check.pending:
                status.append(CHECKING)
            else:
                status.append('ok')
        valid = np.array([s == 'ok' for s in status])
        flag_ok = valid & calibrated
        threshold = p.warning_pressure_ratio * p0
        with np.errstate(invalid='ignore', divide='ignore'):
            sigmas_below = (threshold - pressure[0]) / np.maximum(sigma_total, 1e-12)
        confidence = np.where(flag_ok, ndtr(np.where(flag_ok, sigmas_below, 0.0)), 0.0)
        underinflated = flag_ok & (pressure[0] < threshold)
        stiffness, ratio, pressure, pressure_std = (
            stiffness[1], ratio[1], pressure[1], pressure_std[1])
        arrays = [stiffness, delta_d, ratio, pressure, pressure_std, valid, calibrated,
                  underinflated, confidence]
        for array in arrays:
            array.flags.writeable = False  # the cached arrays are shared between estimates
        return StiffnessEstimate(
            stamp=self._stamp,
            delta_k=_read_only(stiffness - self._model_k),
            delta_d=delta_d,
            stiffness=stiffness,
            stiffness_ratio=ratio,
            pressure_kpa=pressure,
            pressure_std_kpa=pressure_std,
            valid=valid,
            status=tuple(status),
            calibrated=bool(np.all(calibrated)),
            wheel_calibrated=calibrated,
            underinflated=underinflated,
            confidence=confidence,
            calibrating=self.calibrating,
        )
