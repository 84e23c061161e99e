"""Rail secondary-suspension fault detection by Interacting Multiple Models
(docs/methods/suspension_monitor.md).

Mori, Tsunashima, Marumo: one Kalman filter per suspension mode on the reduced bogie-body model
(bogie lateral and yaw, body lateral, with rates; :func:`reduced_bogie_body_model`), sensors
bogie lateral acceleration, bogie yaw rate and body lateral acceleration. Modes: normal, the
secondary lateral spring at 110 ... 170 %, the secondary lateral damper at 100 ... 30 %. The
IMM cycle (mixing, mode-matched filtering, mode probabilities, combined estimate) runs over all
modes at once: the bank is a stack of arrays with a leading mode axis, and each step is a fixed
number of batched matrix products, not a loop over filter objects. No ROS import.

Beyond the paper:

* Likelihoods in log space (log-sum-exp), so a mode far from the data does not underflow to
  zero and vanish for good; a small probability floor (``probability_floor``) keeps every mode
  able to come back within a bounded number of samples.
* Estimation model (``estimation_model``): 'full_car' by default, the 14-DOF full car of
  :func:`full_car_state_space` (four wheelsets with their creep forces and primary suspension,
  both bogies, the body with yaw; 28 states) driven by the track. The wheelset motion is what
  the bogie feels, and it is not the track: the wheelsets deviate from the alignment by about
  as much as the alignment itself (kinematic motion, creep dynamics). Earlier versions removed
  the wheelsets and modelled their motion as coloured noise; no input spectrum made that
  consistent on a full car (healthy runs false-alarmed), while the true wheelset motion as
  input made it clean. So the wheelsets are modelled, and the unknown input is the track:
  :func:`track_shaping_model`, the published alignment spectrum as a second-order
  Gauss-Markov process in distance (poles Omega_r v and Omega_c v: the time-domain bandwidth
  scales with speed), the other wheelsets seeing the same track delayed by their distance
  over the speed (cascades of Pade sections, accurate down to ``delay_min_wavelength_m``; the
  front-rear delay of 0.5 s matters: the rear bogie drives the body the sensors sit on). With
  ``/rail/track_irregularity`` the alignment under the wheelsets is measured directly (extra
  measurement rows, noise ``known_track_std_m``). 'half_car' is the paper's model
  (:func:`reduced_bogie_body_model`, wheelset inputs as coloured noise or known from the
  track), right only for the paper's half-car truth.
* The adaptive compound-fault step: the damper modes use the estimated spring ratio once it
  is a spring fault for the decision (before, 1: :meth:`SuspensionImm._adapt`),
  re-discretised when it moves by ``adaptation_resolution`` (discretisations are cached on
  that grid). The estimate weighs every mode with real evidence (smoothed probability at
  least ``estimate_min_probability`` of the largest), damper modes at their current spring
  ratio.
  The paper's literal reading (spring modes 2-8 only) lost the spring once the damper failed
  (measured with the earlier reduced model without wheelsets): all spring-only modes then fit
  badly and their relative weights wander. With the full-car model the estimate holds 1.50
  after the damper fault.
* Decision (:class:`rail_monitor_ros.core.fault_decision.FaultDecision`): modes are grouped
  into hypotheses by their current ratios snapped to the mode grid (with the adaptive step the
  damper-100 % mode *is* the spring-only hypothesis at the estimated spring ratio), ratios
  within ``min_fault_deviation`` of 1 counted nominal, a compound counted as a damper fault
  unless a spring fault was declared first; a fault component is declared when its summed
  smoothed probability leads above ``fault_threshold`` for ``hold_time_s`` net of its dips
  (an up-down count), and cleared only when normal leads for ``clear_time_s`` without a break
  (hysteresis on the decision). The adaptive step is frozen while the damper-fault modes
  dominate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
import math

import numpy as np
import scipy.linalg

from rail_monitor_ros.core.fault_decision import (
    NO_FAULT,
    DecisionState,
    FaultDecision,
    FaultStatus,
)
from rail_monitor_ros.core.imm_kernel import (
    CBAR_FLOOR,
    LOG_2PI,
    posterior_probabilities,
    smooth_probabilities,
    steady_imm_cycle,
)
from rail_monitor_ros.core.rail_model import (
    MAX_CREEP_FACTOR,
    MAX_SUSPENSION_RATIO,
    SENSOR_OUTPUT_NAMES,
    SPEED_DIFFERENCE,
    RailVehicleParams,
    StateSpace,
    discretize_zoh_sensitivity,
    full_car_state_space,
    reduced_bogie_body_model,
)
from rail_monitor_ros.core.riccati import solve_discrete_riccati
from rail_monitor_ros.core.suspension_modes import (
    RATIO_DECIMALS,
    SuspensionMode,
    generate_mode_set,
    markov_transition_matrix,
)
from rail_monitor_ros.core.track_shaping import (
    N_BOGIE_INPUTS,
    TrackShapingModel,
    input_shaped_model,
    primary_input_combination,
    track_driven_matrix,
    track_driven_model,
    track_shaping_model,
)
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from vehicle_monitor_common.input_health import all_finite
from vehicle_monitor_common.parameters import group, param

N_OUTPUTS = len(SENSOR_OUTPUT_NAMES)
ESTIMATION_MODELS = ('full_car', 'half_car')
# The steady-state kernel's measurement argument for a sample without one.
_NO_MEASUREMENT = np.empty(0)


@dataclass(frozen=True)
class SteadyStateGain:
    """A mode-matched filter's steady state for one measurement set (sensors + k known).

    Attributes:
        prior_ht: (n, p) P- H^T of the steady-state predicted covariance P-.
        innovation: (p, p) S = H P- H^T + R.
        posterior: (n, n) updated covariance P- - P- H^T S^-1 H P-.
    """

    prior_ht: np.ndarray
    innovation: np.ndarray
    posterior: np.ndarray


@dataclass
class ModeModel:
    """One mode's discrete model: transition, process noise, measurement matrices per known
    input count, and its steady-state gains (solved on first use)."""

    f: np.ndarray
    q: np.ndarray
    h: dict[int, np.ndarray]
    steady: dict[int, SteadyStateGain] = field(default_factory=dict)

    def steady_state(self, known: int, r: np.ndarray) -> SteadyStateGain:
        """The steady-state gain with ``known`` known inputs and measurement noise r.

        Raises:
            numpy.linalg.LinAlgError, ValueError: no stabilising solution
                (:func:`rail_monitor_ros.core.riccati.solve_discrete_riccati`).
        """
        if known not in self.steady:
            h = self.h[known]
            prior = solve_discrete_riccati(self.f.T, h.T, self.q, r)
            prior = 0.5 * (prior + prior.T)
            prior_ht = prior @ h.T
            s = h @ prior_ht + r
            s = 0.5 * (s + s.T)
            posterior = prior - prior_ht @ np.linalg.solve(s, prior_ht.T)
            # The full-car covariances are nearly singular: rounding leaves eigenvalues of
            # order -1e-9 of the largest; clip them (computed once per model).
            eig, vec = np.linalg.eigh(0.5 * (posterior + posterior.T))
            posterior = (vec * np.maximum(eig, 0.0)) @ vec.T
            self.steady[known] = SteadyStateGain(prior_ht, s, 0.5 * (posterior + posterior.T))
        return self.steady[known]


@dataclass(frozen=True)
class ProbabilitySnapshot:
    """:meth:`SuspensionImm.snapshot`: the learned suspension state, without the motion."""

    mu: np.ndarray
    smoothed: np.ndarray
    smoothing: np.ndarray
    smoothing_sum: np.ndarray
    smoothing_count: int
    decision: DecisionState
    fault: FaultStatus
    spring_ratio: float
    damper_ratio: float
    damper_spring: float


# Mode discretisations shared by all instances with the same configuration and vehicle (a
# sweep or a test suite builds many; one full-car mode costs a 120 x 120 matrix exponential).
# Bounded: the oldest entry goes first. Only memoised results of pure functions of the key (read-
# only arrays); what an instance does with them (when its steady-state gains take over) is
# decided by what it solved itself, so outputs do not depend on earlier runs in the process
# (tested bit for bit).
_SHARED_DISCRETIZATIONS: dict[tuple[object, ...], ModeModel] = {}
_SHARED_DISCRETIZATIONS_MAX = 512
# The decision's defaults (core/fault_decision.py), chosen on the development family
# (docs/methods/rail_family_evaluation.md, 2026-11-25): the longest excursion of a fault
# component above 0.6 in 24 healthy development minutes was 0.315 s, so a fault must hold 0.5 s
# (0.25 s: 6 false declarations there); clearing takes 1 s of confirmed normal (0.25-2 s gave
# the same development figures: the margin is a choice); spring 110 % and damper 90 % are no
# fault by themselves (min deviation 0, 0.1, 0.15 or 0.2: 49, 0, 0, 0 false declarations;
# 0.15 sits between the grid's 0.1 steps); nor, since 2026-12-01, spring 120 % and damper 80 %
# (0.25: in 6 healthy development hours 1 -> 0 declarations, held out 6 -> 2; the faults the
# targets name, spring 130-160 % and damper 30-70 %, are all still declared).
HOLD_TIME_S = 1.0
CLEAR_TIME_S = 1.0
MIN_FAULT_DEVIATION = 0.25
# Relative eigenvalue below which a bank covariance counts as broken (not rounding).
_SPD_TOLERANCE = 1e-9


@dataclass(frozen=True)
class SuspensionImmParams:
    """Parameters of the IMM suspension monitor (defaults: paper, Table 1,
    docs/methods/suspension_monitor.md); each
    field is also the node's ROS parameter of that name (``parameters.param``).

    Attributes:
        sample_rate_hz: IMU sample rate, Hz (the models are discretised at 1 / sample_rate_hz).
        estimation_model: 'full_car' (the 14-DOF full car driven by the track, the body
            accelerometer above the front bogie; right for the sensors where a real car has
            them) or 'half_car' (the paper's :func:`reduced_bogie_body_model`, right only for
            the paper's half-car truth).
        spring_start, spring_stop, spring_step: spring-mode ratios (see generate_mode_set).
        damper_start, damper_stop, damper_step: damper-mode ratios.
        mean_sojourn_time_s: expected time in a mode before a switch, s (sets Pi). Shorter
            switches faster and false-alarms more.
        probability_floor: lower bound on every mode probability after each update (then
            renormalised), so a mode can come back within a bounded time; 0 disables it.
        smoothing_window_s: moving-average window of the mode probabilities, s.
        adaptive: the paper's compound-fault step (damper modes take the estimated spring).
        adaptation_resolution: the damper modes' spring ratio moves in these quanta; a new
            discretisation is computed (and cached) when the quantised estimate changes.
        track_roughness_m_rad: full car: A_a of the lateral alignment spectrum
            S(Omega) = A_a Omega_c^2 / ((Omega^2 + Omega_r^2)(Omega^2 + Omega_c^2)), m rad.
            Default: the German high-speed "low interference" track (ORE B176), a published
            class, not the simulator's draw; the monitor does not know the track quality (the
            sweep runs it on "high interference" track too).
        track_corner_wavenumber_rad_per_m: Omega_c, rad/m (above it the alignment falls as
            Omega^-4).
        track_long_wavenumber_rad_per_m: Omega_r, rad/m.
        delay_min_wavelength_m: full car: the wheelset-to-wheelset delays (distance / speed)
            are Pade cascades accurate down to this track wavelength, m. Speed-independent
            state count; 5 m is below the spectrum's corner wavelength 2 pi / Omega_c = 7.6 m.
        known_track_std_m: full car, known-input mode: std of the measured alignment under a
            wheelset, m (track recording accuracy).
        creep_resolution: full car: :meth:`SuspensionImm.set_creep_factor` snaps the creep
            factor to multiples of this and re-discretises the bank when the estimate is more
            than 3/4 of a step from the model's (hysteresis: a noisy estimate does not toggle;
            the grid lets the banks and their Riccati solutions be reused).
        speed_resolution_mps: full car: :meth:`SuspensionImm.set_speed` re-discretises the bank
            when the speed moved by at least this much, m/s; within it the bank's transitions
            are stepped to each sample's speed (F + dv dF/dv).
        wheelset_lateral_std_m: half car: stationary std of the wheelset lateral displacement,
            m (the bogie's mean wheelset lateral input).
        wheelset_yaw_std_rad: half car: stationary std of the wheelset yaw angle, rad. The bogie's
            equivalent yaw input (:func:`primary_input_combination`) gets
            wheelset_yaw_std_rad (1 + Ky a0^2 / Kp): wheelsets following the track have
            y_lead - y_trail = 2 a0 psi.
        input_correlation_time_s: half car: slow pole of the wheelset motion model, s.
        input_bandwidth_hz: half car: fast pole of the wheelset motion model, Hz (-40 dB/decade
            above it: the wheelset motion is smooth).
        known_input_lateral_std_m: half car, known-input mode: std of the wheelset's lateral
            deviation from the track alignment, m.
        known_input_yaw_std_rad: half car, known-input mode: std of the wheelset yaw deviation
            from alignment rate / speed, rad.
        bogie_accel_noise_mps2: bogie lateral accelerometer noise std, m/s^2.
        bogie_gyro_noise_rad_s: bogie yaw-rate gyro noise std, rad/s.
        body_accel_noise_mps2: body lateral accelerometer noise std, m/s^2.
        model_lateral_accel_noise_mps2, model_yaw_accel_noise_rad_s2: std of unmodelled
            lateral and yaw accelerations (white, on every rate state of the model); 0 trusts
            the model's structure.
        initial_displacement_std_m, initial_velocity_std_mps: half car: initial lateral state
            std, m, m/s (the full car starts from its stationary covariance on the modelled
            track).
        initial_yaw_std_rad, initial_yaw_rate_std_rad_s: half car: initial yaw state std, rad,
            rad/s.
        estimate_min_probability: modes below this fraction of the largest smoothed
            probability do not vote in the spring and damper estimates (nor in the adaptive
            step): the Markov prior's background mass is not evidence.
        fault_threshold: summed smoothed probability of a fault component to declare it (of
            normal to clear it; :class:`rail_monitor_ros.core.fault_decision.FaultDecision`).
        hold_time_s: how long, net of its dips (an up-down count), a fault component must
            lead above the threshold to be declared (or to replace the declared one), s.
        clear_time_s: how long the normal hypothesis must stay above the threshold to clear a
            declared fault, s (hysteresis on the decision: a dip of the declared hypothesis
            does not clear it).
        min_fault_deviation: spring and damper ratios within this of 1 count as nominal for
            the decision (the modes still size the fault), 1.
        spd_check_interval: full eigenvalue check of the bank covariances every so many
            steps (the innovation covariances are checked every step).
        steady_state_gains: after ``warmup_time_s`` of exact IMM cycles, every mode-matched
            filter runs on its steady-state covariance (the discrete algebraic Riccati
            equation of its model, solved once per model and cached) plus the mixing's spread
            of means, kept exactly as a low-rank term (:meth:`SuspensionImm._steady_cycle`):
            the covariance propagation, nine tenths of a full-car cycle, goes away; mixing of
            the states, likelihoods, probabilities and the decision are unchanged. False: the
            exact IMM every step (the cycle of filterpy's IMMEstimator).
        warmup_time_s: exact IMM cycles after every (re)start of the bank states and after
            every change of the bank to models not solved before (adaptive step, speed), s:
            the states start from the stationary prior, far from the steady-state covariance,
            and frozen gains would mis-weigh the first residuals; and while the adaptive step
            moves the damper modes through intermediate springs (a new bank every few samples
            during a fault) the Riccati equations are solved only for the bank it settles on;
            banks seen before use their cached solutions at once (measured: 0.5 s, 1 s and 3 s
            give the same detections on the paper's run).
        max_gap_s: a gap in the data longer than this restarts the bank's states (mode
            probabilities kept); a shorter one is bridged by
            :meth:`SuspensionImm.predict_through_gap`.
        vehicle: the estimation model's vehicle (the rail model's :class:`RailVehicleParams`,
            the same definition the creep estimator and the simulator use); only its speed
            may change at run time (the full car is re-discretised).
    """

    sample_rate_hz: float = param(200.0, 'IMU sample rate (the models are discretised at its '
                                  'period), Hz', low=1.0, high=10000.0, read_only=True)
    estimation_model: str = param('full_car', 'IMM model: full_car (14-DOF car driven by the '
                                  'track; body IMU above the front bogie) or half_car (the '
                                  'paper)', choices=ESTIMATION_MODELS, read_only=True)
    spring_start: float = param(1.1, 'first spring-mode ratio, 1', low=0.01,
                                high=MAX_SUSPENSION_RATIO, read_only=True)
    spring_stop: float = param(1.7, 'last spring-mode ratio, 1', low=0.01,
                               high=MAX_SUSPENSION_RATIO, read_only=True)
    spring_step: float = param(0.1, 'spring-mode ratio step, 1', low=0.001,
                               high=MAX_SUSPENSION_RATIO, read_only=True)
    damper_start: float = param(1.0, 'first damper-mode ratio, 1', low=0.01,
                                high=MAX_SUSPENSION_RATIO, read_only=True)
    damper_stop: float = param(0.3, 'last damper-mode ratio, 1', low=0.01,
                               high=MAX_SUSPENSION_RATIO, read_only=True)
    damper_step: float = param(0.1, 'damper-mode ratio step, 1', low=0.001,
                               high=MAX_SUSPENSION_RATIO, read_only=True)
    mean_sojourn_time_s: float = param(10.0, 'mean time in a mode (sets the Markov matrix), s',
                                       low=0.01, high=1e6, read_only=True)
    probability_floor: float = param(1e-9, 'lower bound of every mode probability, 1',
                                     low=0.0, high=0.009, read_only=True)
    smoothing_window_s: float = param(0.05, 'moving-average window of the probabilities (at '
                                      'least one sample), s', low=1e-6, high=60.0,
                                      read_only=True)
    adaptive: bool = param(True, 'damper modes take the estimated spring ratio (compound '
                           'faults)', read_only=True)
    adaptation_resolution: float = param(0.02, 'quantum of the damper modes\' spring ratio '
                                         '(adaptive step), 1', low=1e-4, high=1.0,
                                         read_only=True)
    track_roughness_m_rad: float = param(TRACK_SPECTRA['german_low'].roughness,
                                         'full car: track alignment spectrum A_a (German '
                                         '"low interference" track), m rad', low=1e-12,
                                         high=1e-3, read_only=True)
    track_corner_wavenumber_rad_per_m: float = param(TRACK_SPECTRA['german_low'].omega_c,
                                                     'full car: alignment spectrum Omega_c, '
                                                     'rad/m', low=1e-4, high=100.0,
                                                     read_only=True)
    track_long_wavenumber_rad_per_m: float = param(TRACK_SPECTRA['german_low'].omega_r,
                                                   'full car: alignment spectrum Omega_r, rad/m',
                                                   low=1e-5, high=100.0, read_only=True)
    delay_min_wavelength_m: float = param(5.0, 'full car: wheelset-to-wheelset delays '
                                          'accurate down to this track wavelength, m',
                                          low=0.1, high=100.0, read_only=True)
    known_track_std_m: float = param(5e-4, 'full car: measured track alignment std, m',
                                     low=1e-9, high=1.0, read_only=True)
    speed_resolution_mps: float = param(2.0, 'full car: a speed change re-discretises the '
                                        'bank from this size (within it the transitions are '
                                        'stepped to the speed), m/s', low=1e-3, high=50.0,
                                        read_only=True)
    creep_resolution: float = param(0.1, 'full car: the model\'s creep factor moves in these '
                                    'steps (with 3/4-step hysteresis), 1', low=1e-3, high=1.0,
                                    read_only=True)
    wheelset_lateral_std_m: float = param(3e-3, 'half car: wheelset lateral std, m', low=1e-9,
                                          high=1.0, read_only=True)
    wheelset_yaw_std_rad: float = param(2e-3, 'half car: wheelset yaw std, rad', low=1e-9,
                                        high=1.0, read_only=True)
    input_correlation_time_s: float = param(1.0, 'half car: wheelset motion model slow pole '
                                            '(time constant), s', low=1e-3, high=100.0,
                                            read_only=True)
    input_bandwidth_hz: float = param(3.0, 'half car: wheelset motion model fast pole, Hz',
                                      low=0.01, high=100.0, read_only=True)
    known_input_lateral_std_m: float = param(1.5e-3, 'half car: wheelset deviation from the '
                                             'track alignment, m', low=1e-9, high=1.0,
                                             read_only=True)
    known_input_yaw_std_rad: float = param(1.5e-3, 'half car: wheelset yaw deviation from '
                                           'alignment rate / speed, rad', low=1e-9, high=1.0,
                                           read_only=True)
    bogie_accel_noise_mps2: float = param(0.02, 'bogie lateral accelerometer noise std, m/s^2',
                                          low=1e-9, high=100.0, read_only=True)
    bogie_gyro_noise_rad_s: float = param(1e-3, 'bogie yaw-rate gyro noise std, rad/s',
                                          low=1e-9, high=10.0, read_only=True)
    body_accel_noise_mps2: float = param(0.02, 'body lateral accelerometer noise std, m/s^2',
                                         low=1e-9, high=100.0, read_only=True)
    model_lateral_accel_noise_mps2: float = param(0.0, 'std of unmodelled lateral '
                                                  'accelerations (0: trust the model), m/s^2',
                                                  low=0.0, high=100.0, read_only=True)
    model_yaw_accel_noise_rad_s2: float = param(0.0, 'std of unmodelled yaw accelerations (0: '
                                                'trust the model), rad/s^2', low=0.0,
                                                high=100.0, read_only=True)
    initial_displacement_std_m: float = param(5e-3, 'half car: initial lateral displacement '
                                              'std, m', low=1e-9, high=1.0, read_only=True)
    initial_velocity_std_mps: float = param(5e-2, 'half car: initial lateral velocity std, m/s',
                                            low=1e-9, high=10.0, read_only=True)
    initial_yaw_std_rad: float = param(2e-3, 'half car: initial yaw std, rad', low=1e-9,
                                       high=1.0, read_only=True)
    initial_yaw_rate_std_rad_s: float = param(2e-2, 'half car: initial yaw rate std, rad/s',
                                              low=1e-9, high=10.0, read_only=True)
    estimate_min_probability: float = param(0.05, 'modes below this fraction of the largest '
                                            'smoothed probability do not vote in the ratio '
                                            'estimates, 1', low=1e-6, high=1.0,
                                            read_only=True)
    fault_threshold: float = param(0.6, 'summed smoothed probability of a fault component to '
                                   'declare it (of normal to clear it), 1', low=0.01,
                                   high=0.99)
    hold_time_s: float = param(HOLD_TIME_S, 'time a fault component leads above the threshold, '
                               'net of its dips, before it is declared, s', low=0.0, high=600.0)
    clear_time_s: float = param(CLEAR_TIME_S, 'time the normal hypothesis stays above the '
                                'threshold before a declared fault clears, s', low=0.0,
                                high=600.0)
    min_fault_deviation: float = param(MIN_FAULT_DEVIATION, 'spring and damper ratios within '
                                       'this of 1 count as nominal for the decision, 1',
                                       low=0.0, high=0.9)
    spd_check_interval: int = param(200, 'full eigenvalue check of the bank covariances every '
                                    'so many exact steps', low=1, high=1000000, read_only=True)
    steady_state_gains: bool = param(True, 'after the warm-up, each mode runs on its '
                                     'steady-state covariance plus the mixing spread (about 8x '
                                     'faster on the full car); false: the exact IMM',
                                     read_only=True)
    warmup_time_s: float = param(1.0, 'exact IMM cycles after every start of the states, s',
                                 low=0.005, high=600.0, read_only=True)
    max_gap_s: float = param(0.5, 'a longer gap in the data restarts the filter states (a '
                             'shorter one is bridged by prediction), s', low=1e-3, high=3600.0)
    vehicle: RailVehicleParams = group(RailVehicleParams,
                                       'the estimation model\'s vehicle (Table 1)')

    _NON_NEGATIVE = frozenset({'probability_floor', 'model_lateral_accel_noise_mps2',
                               'model_yaw_accel_noise_rad_s2', 'min_fault_deviation'})

    def __post_init__(self) -> None:
        for spec in fields(self):
            value = getattr(self, spec.name)
            if spec.name == 'vehicle':
                continue
            if spec.name in ('adaptive', 'steady_state_gains'):
                if not isinstance(value, bool):
                    raise ValueError(f'{spec.name} must be a bool, got {value!r}')
                continue
            if spec.name == 'estimation_model':
                if value not in ESTIMATION_MODELS:
                    raise ValueError(f'estimation_model must be one of {ESTIMATION_MODELS}, '
                                     f'got {value!r}')
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
                    value):
                raise ValueError(f'{spec.name} must be a finite number, got {value!r}')
            if spec.name in self._NON_NEGATIVE or spec.name.startswith(('spring_', 'damper_')):
                if value < 0.0:
                    raise ValueError(f'{spec.name} must be >= 0, got {value}')
            elif value <= 0.0:
                raise ValueError(f'{spec.name} must be > 0, got {value}')
        if not 0.0 < self.fault_threshold < 1.0:
            raise ValueError(f'fault_threshold must be in (0, 1), got {self.fault_threshold}')
        if self.probability_floor >= 0.01:
            raise ValueError(f'probability_floor must be < 0.01, got {self.probability_floor}')
        # Validates the ratio grids and the sojourn time against the sample period.
        modes = self.modes()
        markov_transition_matrix(len(modes), self.mean_sojourn_time_s, self.dt)
        if self.smoothing_samples < 1:
            raise ValueError('smoothing_window_s must be at least one sample')

    @property
    def dt(self) -> float:
        """Sample period, s."""
        return 1.0 / self.sample_rate_hz

    @property
    def warmup_samples(self) -> int:
        """Exact IMM cycles before the steady-state gains take over."""
        return max(1, int(round(self.warmup_time_s * self.sample_rate_hz)))

    @property
    def smoothing_samples(self) -> int:
        """Moving-average length in samples (>= 1)."""
        return max(1, int(round(self.smoothing_window_s * self.sample_rate_hz)))

    def modes(self) -> tuple[SuspensionMode, ...]:
        """The configured mode set."""
        return generate_mode_set(self.spring_start, self.spring_stop, self.spring_step,
                                 self.damper_start, self.damper_stop, self.damper_step)


@dataclass(frozen=True)
class ImmStep:
    """What one IMM step produced (arrays over the modes are copies).

    Attributes:
        accepted: the measurement was used (False: predict only, see ``reason``).
        reason: '' or why the sample was not used.
        known_input: the known-input model was used for this sample.
        probability: (M,) posterior mode probabilities.
        smoothed_probability: (M,) moving average of ``probability``.
        mode_spring_ratio: (M,) spring ratio each mode assumed at this sample.
        mode_damper_ratio: (M,) damper ratio each mode assumed.
        most_likely: index of the largest smoothed probability.
        spring_ratio: smoothed-probability-weighted spring ratio.
        damper_ratio: smoothed-probability-weighted damper ratio.
        state: (n,) combined state estimate (``SuspensionImm.state_names``; its covariance:
            :meth:`SuspensionImm.combined`).
        fault: the decision.
    """

    accepted: bool
    reason: str
    known_input: bool
    probability: np.ndarray
    smoothed_probability: np.ndarray
    mode_spring_ratio: np.ndarray
    mode_damper_ratio: np.ndarray
    most_likely: int
    spring_ratio: float
    damper_ratio: float
    state: np.ndarray
    fault: FaultStatus


def _log_likelihood(y: np.ndarray, s_inv_y: np.ndarray, chol: np.ndarray) -> np.ndarray:
    """(M,) Gaussian log-likelihoods of the residuals y (M, p), given S^-1 y (M, p) and
    the Cholesky factors (M, p, p) of their covariances S."""
    maha = np.einsum('mi,mi->m', y, s_inv_y)
    log_det = 2.0 * np.log(np.diagonal(chol, axis1=1, axis2=2)).sum(axis=1)
    return -0.5 * (maha + log_det + y.shape[1] * LOG_2PI)


class SuspensionImm:
    """The batched IMM bank with smoothing, the adaptive step and the fault decision.

    Streaming use: :meth:`step` per sample; offline:
    :func:`rail_monitor_ros.offline.imm_runs.run_suspension_imm`.

    Args:
        params: the IMM's parameters (defaults: ``SuspensionImmParams()``).
        vehicle: the model's vehicle parameters in place of ``params.vehicle`` (offline
            studies of a vehicle other than the configured one). Full car: its
            speed sets the creep forces, the track bandwidth and the delays (change it with
            :meth:`set_speed`); the half car does not use it.

    ``model_stable`` says whether the nominal model is stable at the model's speed and creep
    factor (False above the configured car's critical speed: the modes' likelihoods then mean
    nothing, and the suspension monitor declares no fault).
    """

    def __init__(self, params: SuspensionImmParams | None = None,
                 vehicle: RailVehicleParams | None = None) -> None:
        self.params = params if params is not None else SuspensionImmParams()
        self.vehicle = vehicle if vehicle is not None else self.params.vehicle
        self.creep_factor = 1.0
        params = self.params
        self.modes = params.modes()
        self.n_modes = len(self.modes)
        self.transition = markov_transition_matrix(self.n_modes, params.mean_sojourn_time_s,
                                                   params.dt)
        nominal = self._model(1.0, 1.0)
        self.state_names = nominal.state_names
        self.input_names = nominal.input_names
        self.n_states = len(self.state_names)
        self.n_inputs = len(self.input_names)
        self._is_damper = np.array([m.kind == 'damper' for m in self.modes])
        self._base_spring = np.array([m.spring_ratio for m in self.modes])
        self.mode_damper_ratio = np.array([m.damper_ratio for m in self.modes])
        # The modes of a damper fault (the damper-100 % mode is the spring-only hypothesis).
        self._damper_fault_mode = self._is_damper & (
            np.round(self.mode_damper_ratio, RATIO_DECIMALS) != 1.0)
        self._spring_grid = np.unique(np.round(
            [1.0, *[m.spring_ratio for m in self.modes if m.kind == 'spring']], RATIO_DECIMALS))
        self._damper_grid = np.unique(np.round(
            [1.0, *[m.damper_ratio for m in self.modes if m.kind == 'damper']], RATIO_DECIMALS))
        self._r_sensor = np.diag(np.array(
            [params.bogie_accel_noise_mps2, params.bogie_gyro_noise_rad_s,
             params.body_accel_noise_mps2]) ** 2)
        self._full_car = params.estimation_model == 'full_car'
        self._track_cache: tuple[tuple[float, tuple[float, ...]], TrackShapingModel] | None = None
        if self._full_car:
            # Known inputs: the measured alignment under the front bogie's wheelsets or all
            # four, extra measurements of the track model's outputs.
            self._known_sizes: tuple[int, ...] = (0, 2, self.n_inputs)
            self._t_known = {k: np.eye(k) for k in self._known_sizes}
            known_std = np.full(self.n_inputs, params.known_track_std_m)
            n_aug = self.n_states + self._track_model().a.shape[0]
        else:
            v = self.vehicle
            self._combination = primary_input_combination(v, self.input_names)
            n_bogies = self.n_inputs // N_BOGIE_INPUTS
            yaw_gain = 1.0 + (v.primary_lateral_stiffness * v.semi_wheelbase ** 2
                              / v.primary_yaw_stiffness)
            self._combination_std = np.tile([params.wheelset_lateral_std_m,
                                             params.wheelset_yaw_std_rad * yaw_gain], n_bogies)
            n_aug = self.n_states + 2 * self._combination.shape[0]
            yaw_input = np.array([name.startswith('psi') for name in self.input_names])
            known_std = np.where(yaw_input, params.known_input_yaw_std_rad,
                                 params.known_input_lateral_std_m)
            # Known inputs: the monitored bogie's wheelsets, measured as combinations.
            self._known_sizes = tuple(sorted({0, N_BOGIE_INPUTS, self.n_inputs}))
            self._t_known = {k: self._combination[:k // 2, :k] for k in self._known_sizes}
        self._r = {k: scipy.linalg.block_diag(
            self._r_sensor, t @ np.diag(known_std[:k] ** 2) @ t.T)
            for k, t in self._t_known.items()}
        # Unmodelled accelerations as white noise on the rate states, integrated over a step.
        dt = params.dt
        q_model = np.zeros((n_aug, n_aug))
        lateral_std = params.model_lateral_accel_noise_mps2
        yaw_std = params.model_yaw_accel_noise_rad_s2
        for k, name in enumerate(self.state_names):
            if name.startswith('d'):
                std = yaw_std if 'psi' in name else lateral_std
                q_model[k - 1:k + 1, k - 1:k + 1] = std ** 2 * np.array(
                    [[dt ** 4 / 4, dt ** 3 / 2], [dt ** 3 / 2, dt ** 2]])
        self._q_model = q_model
        self._discretized: dict[tuple[float, float], ModeModel] = {}
        # dF/dv per mode key (_speed_slopes), and the samples' speed less the bank's.
        self._slopes: dict[tuple[object, ...], np.ndarray] = {}
        self._speed_offset = 0.0
        self._solved: set[tuple[tuple[object, ...], int]] = set()
        self._p0 = self._prior()
        self.decision = _fault_decision(params, dt)
        self.covariance_repairs = 0
        self.rediscretizations = 0
        self.steady_state_failures = 0
        # Data time (stamps given to step): the core decides what a gap means.
        self._period_ns = 1e9 / params.sample_rate_hz
        self._last_stamp_ns: int | None = None
        self._max_gap_s = params.max_gap_s
        self.gap_restarts = 0
        self.missing_samples = 0
        self._damper_spring = 1.0
        self._build_bank(1.0)
        self.reset()

    # ----------------------------------------------------------------------- model bank
    def _model(self, spring: float, damper: float,
               vehicle: RailVehicleParams | None = None) -> StateSpace:
        if self.params.estimation_model == 'full_car':
            full = full_car_state_space(vehicle or self.vehicle, self.creep_factor,
                                        (spring, 1.0), (damper, 1.0))
            # The monitored (front) bogie's sensors only.
            return replace(full, c=full.c[:N_OUTPUTS], d=full.d[:N_OUTPUTS],
                           output_names=full.output_names[:N_OUTPUTS])
        return reduced_bogie_body_model(self.vehicle, spring, damper)

    def _track_model(self) -> TrackShapingModel:
        """The track model at the vehicle's speed, built once per speed: every mode of a new
        bank uses it (measured: rebuilt per mode it was an eighth of the monitor's CPU on the
        shipped fault bag, where the adaptive step makes about 100 banks)."""
        key = (self.vehicle.speed, tuple(self.vehicle.wheelset_offsets))
        if self._track_cache is None or self._track_cache[0] != key:
            self._track_cache = (key, self._track_model_at(self.vehicle.speed))
        return self._track_cache[1]

    def _track_model_at(self, speed: float) -> TrackShapingModel:
        """The configured track spectrum and delays at ``speed`` (not cached)."""
        params = self.params
        return track_shaping_model(
            params.track_roughness_m_rad, params.track_corner_wavenumber_rad_per_m,
            params.track_long_wavenumber_rad_per_m, speed, self.vehicle.wheelset_offsets,
            params.delay_min_wavelength_m)

    def _prior(self) -> np.ndarray:
        """Initial covariance: full car, the nominal model's stationary covariance on the
        modelled track (the car is running when monitoring starts); half car, the configured
        initial stds and the input states at their stationary variance. Sets
        ``model_stable``: whether the nominal model is stable at the model's speed."""
        nominal = self._discretize(1.0, 1.0)
        self.model_stable = bool(np.max(np.abs(np.linalg.eigvals(nominal.f))) < 1.0)
        if self._full_car:
            p = scipy.linalg.solve_discrete_lyapunov(nominal.f, nominal.q)
            p = 0.5 * (p + p.T)
            if not self.model_stable:
                # Above the configured car's critical speed no stationary covariance exists:
                # the Lyapunov solution is indefinite, and a mode restarted from it failed its
                # next update (a LinAlgError, measured on a car accelerated past its critical
                # speed). Its eigenvalues' magnitudes keep the states' scale.
                eig, vec = np.linalg.eigh(p)
                p = (vec * np.abs(eig)) @ vec.T
            return p
        params = self.params
        initial_std = [_initial_std(name, params) for name in self.state_names]
        # Input states w and w' (var(w') = w1 w2 var(w)).
        poles = (1.0 / params.input_correlation_time_s) * 2.0 * math.pi * params.input_bandwidth_hz
        input_var = np.column_stack([self._combination_std ** 2,
                                     poles * self._combination_std ** 2]).ravel()
        return np.diag(np.concatenate([np.square(initial_std), input_var]))

    def _discretize(self, spring: float, damper: float) -> ModeModel:
        key = (round(spring, RATIO_DECIMALS), round(damper, RATIO_DECIMALS))
        shared_key = (self.params, self.vehicle, self.creep_factor, key)
        cached = self._discretized.get(key, _SHARED_DISCRETIZATIONS.get(shared_key))
        if cached is None:
            params = self.params
            if self._full_car:
                track = self._track_model()
                f, q, h = track_driven_model(self._model(*key), track, params.dt)
                rows = np.hstack([np.zeros((self.n_inputs, self.n_states)), track.c])
                h_known = {k: np.vstack([h, rows[:k]]) for k in self._known_sizes}
            else:
                f, q, h = input_shaped_model(self._model(*key), self._combination,
                                           self._combination_std, params.input_correlation_time_s,
                                           params.input_bandwidth_hz, params.dt)
                # Known inputs are extra measurements of the first k // 2 input combinations.
                eye = np.eye(f.shape[0])
                h_known = {k: np.vstack([h, eye[self.n_states + 2 * np.arange(k // 2)]])
                           for k in self._known_sizes}
            cached = ModeModel(f, q + self._q_model, h_known)
            # Shared between instances: memoised results of pure functions of the key (the
            # discretisation, and its Riccati solutions once solved), never written after;
            # read-only so that no instance can change another's model.
            for array in (cached.f, cached.q, *cached.h.values()):
                array.flags.writeable = False
            if len(_SHARED_DISCRETIZATIONS) >= _SHARED_DISCRETIZATIONS_MAX:
                del _SHARED_DISCRETIZATIONS[next(iter(_SHARED_DISCRETIZATIONS))]
            _SHARED_DISCRETIZATIONS[shared_key] = cached
        self._discretized[key] = cached
        return cached

    def update_runtime_params(self, params: SuspensionImmParams) -> None:
        """The parameters settable at run time changed (``fault_threshold``, ``hold_time_s``,
        ``clear_time_s``, ``min_fault_deviation``, ``max_gap_s``, ``vehicle.speed``; the others
        are read-only): a new decision rule (the declared fault kept, nothing pending), the new
        gap limit, the new speed (:meth:`set_speed`)."""
        state = self.decision.state
        self.decision = _fault_decision(params, self.params.dt)
        # A declared fault stays declared (hysteresis on the decision): only what was pending
        # is dropped (counted against the old hold and clear times).
        self.decision.load_state(state)
        self.decision.forget_pending()
        self._max_gap_s = params.max_gap_s
        self.set_speed(params.vehicle.speed)

    def set_speed(self, speed: float) -> None:
        """The forward speed changed (full car: creep forces, track bandwidth and delays
        depend on it): re-discretise the bank, keeping states and probabilities. Ignored when
        it moved by less than ``speed_resolution_mps`` since the last re-discretisation."""
        if not (math.isfinite(speed) and speed > 0.0):
            raise ValueError(f'speed must be finite and > 0, got {speed}')
        if not self._full_car:
            self.vehicle = self.vehicle.with_speed(speed)   # not used by the half car
            return
        offset = speed - self.vehicle.speed
        if abs(offset) < self.params.speed_resolution_mps:
            if offset != self._speed_offset:
                self._speed_offset = offset
                self._step_transitions()
            return
        self.vehicle = self.vehicle.with_speed(speed)
        self._speed_offset = 0.0
        self._rediscretize()

    def _step_transitions(self) -> None:
        """The bank's transitions at the samples' speed: each mode's F stepped from the
        bank's speed to first order, F + dv dF/dv (Q and the steady-state gains stay the
        bank's: the track noise's density moves by dv / v, at most 5 % for the 2 m/s of
        ``speed_resolution_mps`` at 40 m/s, a covariance's share, where F carries the means the
        likelihoods are made of)."""
        if self._speed_offset == 0.0:
            self._set_transitions(self._f_bank)
        else:
            self._set_transitions(self._f_bank + self._speed_offset * self._speed_slopes())

    def _speed_slopes(self) -> np.ndarray:
        """dF/dv of every mode at the bank's speed, exact to the difference of A: the Frechet
        derivative of the matrix exponential at A dt in the direction dA/dv dt, dA/dv by
        central differences of two models beside the bank's (A is smooth in v through the
        creep coefficients' 1/v, the track's poles and the Pade sections). Built when a
        sample at another speed first needs them (at constant speed never), kept per mode."""
        missing = [k for k, key in enumerate(self._mode_keys) if key not in self._slopes]
        if missing:
            v = self.vehicle.speed
            step = SPEED_DIFFERENCE * v
            beside = [(self.vehicle.with_speed(v + sign * step),
                       self._track_model_at(v + sign * step)) for sign in (1.0, -1.0)]
            track = self._track_model()
            for k in missing:
                spring = float(self.mode_spring_ratio[k])
                damper = float(self.mode_damper_ratio[k])
                up, down = (track_driven_matrix(self._model(spring, damper, vehicle), shaping)
                            for vehicle, shaping in beside)
                a = track_driven_matrix(self._model(spring, damper), track)
                no_input = np.zeros((a.shape[0], 0))
                self._slopes[self._mode_keys[k]] = discretize_zoh_sensitivity(
                    a, no_input, (up - down) / (2.0 * step), no_input, self.params.dt)[2]
        return np.stack([self._slopes[key] for key in self._mode_keys])

    def set_creep_factor(self, creep_factor: float) -> None:
        """The wheel-rail creep factor changed (full car: the wheelsets' creep forces, e.g.
        from the creep estimator): re-discretise the bank, keeping states and probabilities.
        Unmodelled, a creep change looks like a suspension change (measured: two false faults
        on ``rail_creep_steps``). The model's factor is snapped to multiples of
        ``creep_resolution``; it moves only when the estimate is more than 3/4 of a step from
        it. The half car (no wheelsets) ignores it."""
        if not (math.isfinite(creep_factor) and 0.0 < creep_factor <= MAX_CREEP_FACTOR):
            raise ValueError(f'creep_factor must be in (0, {MAX_CREEP_FACTOR}], got '
                             f'{creep_factor}')
        step = self.params.creep_resolution
        if not self._full_car or abs(creep_factor - self.creep_factor) <= 0.75 * step:
            return
        self.creep_factor = round(max(step, round(creep_factor / step) * step),
                                  RATIO_DECIMALS)
        self._rediscretize()

    def _rediscretize(self) -> None:
        """The model's vehicle or creep factor changed: new discretisations, prior and bank
        (states and probabilities kept)."""
        self._discretized.clear()
        self._slopes.clear()
        self._p0 = self._prior()
        self._build_bank(self._damper_spring)

    def _build_bank(self, damper_spring: float) -> None:
        """Stack the mode models; damper modes at spring ratio ``damper_spring``."""
        self._damper_spring = damper_spring
        self.mode_spring_ratio = np.where(self._is_damper, damper_spring, self._base_spring)
        self._mode_ratios = np.stack([self.mode_spring_ratio, self.mode_damper_ratio])
        pairs = list(zip(self.mode_spring_ratio.tolist(), self.mode_damper_ratio.tolist(),
                         strict=True))
        self._mode_models = [self._discretize(s, d) for s, d in pairs]
        # What this instance solved itself decides when the steady-state gains take over,
        # never what another instance left in the shared models: so two instances (the node
        # and the offline engine, a second run in one process) give the same outputs.
        self._mode_keys = [(self.vehicle, self.creep_factor, round(s, RATIO_DECIMALS),
                            round(d, RATIO_DECIMALS)) for s, d in pairs]
        self._f_bank = np.stack([m.f for m in self._mode_models])
        n = self.n_states
        if not (np.all(self._f_bank[:, n:, :n] == 0.0)
                and np.all(self._f_bank[:, n:, n:] == self._f_bank[0, n:, n:])):
            raise RuntimeError('input states must be shared and independent of the vehicle')
        self._step_transitions()
        self._q = np.stack([m.q for m in self._mode_models])
        self._h = {k: np.stack([m.h[k] for m in self._mode_models]) for k in self._known_sizes}
        self._steady_bank: dict[int, tuple[np.ndarray, ...] | None] = {}
        self._bank_age = 0   # samples since the bank last changed
        self._ht = {k: np.ascontiguousarray(v.transpose(0, 2, 1)) for k, v in self._h.items()}
        snapped_s = self._spring_grid[np.argmin(
            np.abs(self.mode_spring_ratio[:, None] - self._spring_grid[None, :]), axis=1)]
        snapped_d = self._damper_grid[np.argmin(
            np.abs(self.mode_damper_ratio[:, None] - self._damper_grid[None, :]), axis=1)]
        keys = list(zip(snapped_s.tolist(), snapped_d.tolist(), strict=True))
        self.hypotheses: list[tuple[float, float]] = list(dict.fromkeys(keys))
        self._hypothesis_index = np.array([self.hypotheses.index(k) for k in keys])

    # ----------------------------------------------------------------------- state
    def _set_transitions(self, f: np.ndarray) -> None:
        """The bank's transitions, by blocks: F = [[F_x, F_xw], [0, F_w]], the input (track)
        states independent of the vehicle and F_w the same for every mode, so F P F^T is
        computed by blocks (exact, about half the products)."""
        n = self.n_states
        self._f = f
        self._f_top = np.ascontiguousarray(f[:, :n, :])
        self._f_top_t = np.ascontiguousarray(self._f_top.transpose(0, 2, 1))
        self._f_input = np.ascontiguousarray(f[0, n:, n:])
        self._f_input_t = np.ascontiguousarray(self._f_input.T)
        self._hf_rows: dict[int, np.ndarray] = {}

    def _measured_transitions(self, known: int) -> np.ndarray:
        """H F of every mode with ``known`` known inputs, as rows (the steady cycle's)."""
        if known not in self._hf_rows:
            self._hf_rows[known] = np.matmul(self._h[known], self._f).reshape(
                -1, self._f.shape[2])
        return self._hf_rows[known]

    def reset(self) -> None:
        """Restart: mode 1 (normal) with probability 1, states at rest with the prior P; data
        time starts again with the next stamp (after a time jump)."""
        params = self.params
        self._last_stamp_ns = None
        if self.params.adaptive and self._damper_spring != 1.0:
            self._build_bank(1.0)
        self.mu = np.zeros(self.n_modes)
        self.mu[0] = 1.0
        self._smoothing = np.zeros((params.smoothing_samples, self.n_modes))
        self._smoothing_sum = np.zeros(self.n_modes)
        self._smoothing_count = 0
        self.smoothed = self.mu.copy()
        self.decision.reset()
        self.fault = NO_FAULT
        self.spring_ratio = 1.0
        self.damper_ratio = 1.0
        self.reset_states()

    def snapshot(self) -> ProbabilitySnapshot:
        """What the monitor has learned about the suspension (mode probabilities, their
        smoothing, the decision, the adaptive bank's spring ratio), cheap to take every
        sample: :meth:`restore` goes back to it when the samples since turn out to be bad."""
        return ProbabilitySnapshot(
            self.mu.copy(), self.smoothed.copy(), self._smoothing.copy(),
            self._smoothing_sum.copy(), self._smoothing_count, self.decision.state, self.fault,
            self.spring_ratio, self.damper_ratio, self._damper_spring)

    def restore(self, snapshot: ProbabilitySnapshot) -> None:
        """Back to a :meth:`snapshot` (an input found faulty after it had been used): the
        probabilities, smoothing and decision as they were, the bank's states restarted (the
        motion since is unknown; data time is kept, the next sample follows as after a gap)."""
        s = snapshot
        if s.damper_spring != self._damper_spring:
            self._build_bank(s.damper_spring)
        self.mu, self.smoothed = s.mu.copy(), s.smoothed.copy()
        self._smoothing, self._smoothing_sum = s.smoothing.copy(), s.smoothing_sum.copy()
        self._smoothing_count = s.smoothing_count
        self.decision.load_state(s.decision)
        self.fault, self.spring_ratio, self.damper_ratio = s.fault, s.spring_ratio, \
            s.damper_ratio
        self.reset_states()

    def reset_states(self) -> None:
        """Re-initialise the bank's states and covariances, keeping the mode probabilities
        (after a gap in the data the motion is unknown, the suspension is not)."""
        n_aug = self._p0.shape[0]
        self.x = np.zeros((self.n_modes, n_aug))
        self.P = np.broadcast_to(self._p0, (self.n_modes, n_aug, n_aug)).copy()
        self._steps = 0

    def _steady_state_bank(self, known: int) -> tuple[np.ndarray, ...] | None:
        """Stacked steady-state (P- H^T, S, posterior) of every mode with
        ``known`` known inputs, or None when a mode has no stabilising Riccati solution (the
        bank then stays exact; counted in ``steady_state_failures``)."""
        if known not in self._steady_bank:
            try:
                gains = []
                for key, m in zip(self._mode_keys, self._mode_models, strict=True):
                    gains.append(m.steady_state(known, self._r[known]))
                    self._solved.add((key, known))
            except (np.linalg.LinAlgError, ValueError):
                self.steady_state_failures += 1
                self._steady_bank[known] = None
            else:
                self._steady_bank[known] = (
                    np.stack([g.prior_ht for g in gains]),
                    np.stack([g.innovation for g in gains]),
                    np.stack([g.posterior for g in gains]))
        return self._steady_bank[known]

    # ----------------------------------------------------------------------- IMM cycle
    def _mixing_weights(self) -> np.ndarray:
        """omega^T: row j holds mu_i|j over i; also sets the predicted probabilities cbar."""
        weighted = self.transition * self.mu[:, None]
        self._cbar = cbar = weighted.sum(axis=0)
        return weighted.T / cbar[:, None]

    def _mix_and_predict(self) -> None:
        if self._steps == 0:
            self._cbar = self.mu @ self.transition
            return   # the prior is for the first sample: nothing to propagate
        w = self._mixing_weights()
        x, p = self.x, self.P
        m, n = x.shape
        x0 = w @ x                                                    # (M, n)
        # Mixed covariance from the mixed second moments: sum_i w_ji (P_i + x_i x_i^T)
        # - x0_j x0_j^T (one product instead of the spread of every pair i, j).
        second = p + x[:, :, None] * x[:, None, :]
        p0 = (w @ second.reshape(m, -1)).reshape(m, n, n) - x0[:, :, None] * x0[:, None, :]
        self.x = np.einsum('mij,mj->mi', self._f, x0)
        k = self.n_states
        top = self._f_top @ p0                                        # (F P)[:k], (M, k, n)
        p = np.empty_like(p0)
        p[:, :k, :k] = top @ self._f_top_t
        p[:, :k, k:] = top[:, :, k:] @ self._f_input.T
        p[:, k:, :k] = p[:, :k, k:].transpose(0, 2, 1)
        p[:, k:, k:] = self._f_input @ p0[:, k:, k:] @ self._f_input.T
        self.P = p + self._q

    def _update(self, z: np.ndarray, known: int, r: np.ndarray) -> np.ndarray:
        """Mode-matched update with z: the 3 sensors then ``known`` known inputs (as
        combinations), noise r; log-likelihoods."""
        h, ht = self._h[known], self._ht[known]
        y = z - np.einsum('mij,mj->mi', h, self.x)                    # residuals
        pht = self.P @ ht                                             # (M, n, p)
        s = h @ pht + r
        s = 0.5 * (s + s.transpose(0, 2, 1))
        try:
            chol = np.linalg.cholesky(s)
        except np.linalg.LinAlgError:
            self._repair_covariances(force=True)
            pht = self.P @ ht
            s = h @ pht + r
            s = 0.5 * (s + s.transpose(0, 2, 1))
            chol = np.linalg.cholesky(s)
        # S^-1 [H P, y] in one batched solve: the gain's transpose and S^-1 y.
        solved = np.linalg.solve(s, np.concatenate(
            [pht.transpose(0, 2, 1), y[:, :, None]], axis=2))
        s_inv_y = solved[:, :, -1]
        self.x = self.x + np.einsum('mij,mj->mi', pht, s_inv_y)
        # P - K S K^T, symmetrised (half the products of the Joseph form on the batch);
        # positive definiteness is checked every step through S and periodically in full.
        p = self.P - pht @ solved[:, :, :-1]
        self.P = 0.5 * (p + p.transpose(0, 2, 1))
        return _log_likelihood(y, s_inv_y, chol)

    def _steady_cycle(self, z: np.ndarray | None, known: int,
                      steady: tuple[np.ndarray, ...]) -> None:
        """The IMM cycle on the steady-state covariances plus the mixing's spread of means
        (:func:`rail_monitor_ros.core.imm_kernel.steady_imm_cycle`): sets ``x``, ``mu``,
        ``_cbar``; the mode covariances left in ``P`` are the steady-state posteriors.

        Exact IMM: P-_j = F_j (sum_i w_ji P_i) F_j^T + Q_j + F_j Spread_j F_j^T with
        Spread_j = sum_i w_ji (x_i - x0_j)(x_i - x0_j)^T. Here the first two terms are the
        mode's steady-state prior P-ss_j, and the spread is kept exactly but never formed: it
        is low-rank (at most M columns), so it costs O(M^2 n) per mode instead of the O(n^3)
        covariance propagation. The spread is what lets the mismatched modes follow a change
        (measured: with known inputs, which make P-ss small, dropping it delayed the damper
        detection from 0.12 s to 1.5 s).
        """
        prior_ht, s_ss, posterior = steady
        hf_rows = self._measured_transitions(known)
        x = np.empty_like(self.x)
        mu = np.empty(self.n_modes)
        self._cbar = np.empty(self.n_modes)
        valid = steady_imm_cycle(self.x, self.mu, self.transition, self._f_top, self._f_input_t,
                                 hf_rows, prior_ht, s_ss, _NO_MEASUREMENT if z is None else z,
                                 self.params.probability_floor, x, mu, self._cbar)
        self.P = posterior
        if valid:
            self.x, self.mu = x, mu
        else:
            # Only non-finite states make S lose definiteness: restart the states (exact
            # cycles first), keep the predicted probabilities.
            self.covariance_repairs += 1
            self.reset_states()
            self.mu = self._cbar / self._cbar.sum()

    def _repair_covariances(self, force: bool = False) -> None:
        """Detect and repair a bank covariance that lost positive semi-definiteness.

        The full-car covariances are semi-definite by nature (the Pade delay states are nearly
        deterministic functions of the track state: condition numbers ~1e26), so rounding
        leaves eigenvalues of order -1e-20 of the largest; those are not a loss. A covariance
        with an eigenvalue below -``_SPD_TOLERANCE`` of its largest, or non-finite, is
        broken and restarts from the prior; ``force`` (an innovation covariance failed its
        Cholesky factorisation) also clips every mode's eigenvalues to a small positive floor.
        """
        finite = np.all(np.isfinite(self.P), axis=(1, 2))
        p = np.where(finite[:, None, None], self.P, self._p0)
        eig, vec = np.linalg.eigh(p)
        scale = np.maximum(eig.max(axis=1), 1e-30)
        broken = ~finite | (eig.min(axis=1) < -_SPD_TOLERANCE * scale)
        if not (force or broken.any()):
            return
        if force:
            clipped = np.maximum(eig, 1e-12 * scale[:, None])
            p = vec @ (clipped[:, :, None] * vec.transpose(0, 2, 1))
        self.P = np.where(broken[:, None, None], self._p0, p)
        self.covariance_repairs += int(max(1, broken.sum()))

    def _adapt(self) -> None:
        """Damper modes take the estimated spring ratio (the voting modes' weighted ratio,
        :func:`rail_monitor_ros.core.imm_kernel.smooth_probabilities`) when it is a spring
        fault for the decision (at least ``min_fault_deviation`` from 1), and 1 otherwise;
        once the damper-fault modes hold more than half the smoothed probability the spring
        ratio they carry is frozen.

        Why 1 within the band: the spring grid holds nominal and ratios above it, so on a
        healthy spring the estimate leans upwards (development car 1043: 1.08), and damper
        modes carrying that lean are not the hypothesis of a damper-only fault (there, the
        correct one never led after a damper-40 % fault; docs/methods/rail_family_evaluation.md).
        Why frozen under a damper fault: the spring modes (damper 100 %) measure the spring
        only while the damper is healthy; after a damper fault they all fit badly and their
        residual weight, every one at a spring ratio above 1, pulled the estimate upwards
        (development cars: 1.0 -> 1.19 within 5 s of a damper-49 % fault, which then read as
        spring+damper)."""
        if self.smoothed[self._damper_fault_mode].sum() > 0.5:
            return
        if abs(self.spring_ratio - 1.0) < self.params.min_fault_deviation:
            snapped = 1.0
        else:
            quantum = self.params.adaptation_resolution
            snapped = round(round(self.spring_ratio / quantum) * quantum, RATIO_DECIMALS)
        if snapped != self._damper_spring:
            self._build_bank(snapped)
            self.rediscretizations += 1

    def _check_input(self, measurement: np.ndarray | Sequence[float] | None,
                     known_input: np.ndarray | Sequence[float] | None,
                     ) -> tuple[np.ndarray | None, np.ndarray | None, str]:
        reason = ''
        z: np.ndarray | None = None
        if measurement is not None:
            z = np.asarray(measurement, dtype=float)
            if z.shape != (N_OUTPUTS,):
                reason, z = f'measurement shape {z.shape}, expected ({N_OUTPUTS},)', None
            elif not all_finite(z):
                reason, z = 'non-finite measurement', None
        else:
            reason = 'no measurement'
        u: np.ndarray | None = None
        if known_input is not None:
            candidate = np.asarray(known_input, dtype=float)
            if (candidate.ndim == 1 and candidate.size in self._known_sizes[1:]
                    and all_finite(candidate)):
                u = candidate
            elif not reason:
                reason = 'bad known input (process-noise model used)'
        return z, u, reason

    def advance(self, z: np.ndarray | None, u: np.ndarray | None = None) -> None:
        """One sample on checked input (the fast path of :meth:`step`): updates ``mu``,
        ``smoothed``, ``spring_ratio``, ``damper_ratio`` and ``fault`` in place.

        Args:
            z: (3,) finite measurement or None (predict only).
            u: known inputs (see :meth:`step`) or None.
        """
        known = 0 if u is None or z is None else u.size
        if known and z is not None and u is not None:
            z = np.concatenate([z, self._t_known[known] @ u])
        steady = None
        warm = self.params.warmup_samples
        if self.params.steady_state_gains and self._steps >= warm and (
                self._bank_age >= warm or known in self._steady_bank
                or all((key, known) in self._solved for key in self._mode_keys)):
            steady = self._steady_state_bank(known)
        if steady is not None:
            self._steady_cycle(z, known, steady)
        else:
            self._mix_and_predict()
            if z is None:
                self.mu = self._cbar / self._cbar.sum()
            else:
                log_lik = self._update(z, known, self._r[known])
                mu = np.empty(self.n_modes)
                posterior_probabilities(log_lik + np.log(np.maximum(self._cbar, CBAR_FLOOR)),
                                        self.params.probability_floor, mu)
                self.mu = mu
        self._steps += 1
        self._bank_age += 1
        if (steady is None and self.params.spd_check_interval
                and self._steps % self.params.spd_check_interval == 0):
            self._repair_covariances()
        self._smooth_and_decide()
        if self.params.adaptive and z is not None:
            self._adapt()

    def _smooth_and_decide(self) -> None:
        self.smoothed = np.empty(self.n_modes)
        ratios = np.empty(2)
        smooth_probabilities(self.mu, self._smoothing, self._smoothing_sum,
                             self._smoothing_count, self.smoothed, self._mode_ratios,
                             self.params.estimate_min_probability, ratios)
        self._smoothing_count += 1
        self._mode_spring_used = self.mode_spring_ratio
        self.spring_ratio, self.damper_ratio = ratios.tolist()
        hyp = np.bincount(self._hypothesis_index, weights=self.smoothed,
                          minlength=len(self.hypotheses))
        self.fault = self.decision.update(self.hypotheses, hyp)

    def predict_through_gap(self, gap_s: float) -> int:
        """Bridge a gap of ``gap_s`` between the last sample and the next by predict-only
        cycles, one per missing sample (round(gap_s / dt) - 1), each updating the
        probabilities, their smoothing and the decision as a missing sample does (no result is
        built). Returns the number of samples predicted."""
        return self._predict_samples(int(round(gap_s * self.params.sample_rate_hz)) - 1)

    def _predict_samples(self, n: int) -> int:
        for _ in range(max(0, n)):
            self.advance(None)
        self.missing_samples += max(0, n)
        return max(0, n)

    def _follow_time(self, stamp_ns: int) -> None:
        """Data time: a gap of up to ``max_gap_s`` since the last sample is bridged by
        prediction (the models are discretised at the nominal rate); a longer one restarts the
        states (the motion is unknown, the suspension is not: probabilities kept)."""
        last, self._last_stamp_ns = self._last_stamp_ns, stamp_ns
        if last is None:
            return
        if (stamp_ns - last) * 1e-9 > self._max_gap_s:
            self.gap_restarts += 1
            self.reset_states()
        else:
            self._predict_samples(int(round((stamp_ns - last) / self._period_ns)) - 1)

    def step(self, measurement: np.ndarray | Sequence[float] | None,
             known_input: np.ndarray | Sequence[float] | None = None,
             stamp_ns: int | None = None) -> ImmStep:
        """One sample.

        Args:
            measurement: (3,) [bogie lateral accel m/s^2, bogie yaw rate rad/s, body lateral
                accel m/s^2], or None (sample missing: predict only). A non-finite or
                wrongly shaped measurement is not used (predict only, reported in
                ``reason``), so the state is not corrupted.
            known_input: the measured track, or None (track / wheelset motion as process
                noise). Full car: the alignment under the front bogie's two wheelsets, (2,),
                or under all four, (4,), m, front to rear. Half car: (4,) the wheelset inputs
                [y_w1, y_w2, psi_w1, psi_w2] (``wheelset_inputs_from_track``).
            stamp_ns: the sample's stamp, ns, increasing (the caller rejects repeated and
                out-of-order stamps); the gap since the previous stamped sample is bridged or
                restarts the states (``max_gap_s``). None: the sample follows the previous one.
        """
        if stamp_ns is not None:
            self._follow_time(stamp_ns)
        z, u, reason = self._check_input(measurement, known_input)
        self.advance(z, u)
        return ImmStep(
            accepted=z is not None, reason=reason, known_input=z is not None and u is not None,
            probability=self.mu.copy(), smoothed_probability=self.smoothed.copy(),
            mode_spring_ratio=self._mode_spring_used.copy(),
            mode_damper_ratio=self.mode_damper_ratio.copy(),
            most_likely=int(np.argmax(self.smoothed)), spring_ratio=self.spring_ratio,
            damper_ratio=self.damper_ratio, state=self.combined_state(), fault=self.fault)

    def combined_state(self) -> np.ndarray:
        """Combined estimate of the model's states (the input states left out)."""
        return self.mu @ self.x[:, :self.n_states]

    def combined(self) -> tuple[np.ndarray, np.ndarray]:
        """Combined estimate and covariance of the model's states (inputs left out)."""
        n = self.n_states
        xs = self.x[:, :n]
        x = self.mu @ xs
        d = xs - x
        cov = np.tensordot(self.mu, self.P[:, :n, :n], axes=1) + (self.mu[:, None] * d).T @ d
        return x, 0.5 * (cov + cov.T)


def _fault_decision(params: SuspensionImmParams, dt: float) -> FaultDecision:
    """The decision rule of the parameters (core/fault_decision.py), at sample period dt."""
    return FaultDecision(params.fault_threshold, params.hold_time_s, dt, params.clear_time_s,
                         params.min_fault_deviation)


def _initial_std(name: str, params: SuspensionImmParams) -> float:
    """Prior std of a model state by its kind (lateral or yaw, displacement or rate)."""
    rate = name.startswith('d')
    yaw = 'psi' in name
    return {(False, False): params.initial_displacement_std_m,
            (True, False): params.initial_velocity_std_mps,
            (False, True): params.initial_yaw_std_rad,
            (True, True): params.initial_yaw_rate_std_rad_s}[(rate, yaw)]
