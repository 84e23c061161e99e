"""Rail vehicle simulator: the 14-DOF full car on a random track, with ground truth.

Runs a :class:`~rail_monitor_ros.simulation.rail_scenario.RailScenario` and returns arrays
(:class:`RailSimulationResult`); :func:`to_topic_series` turns them into the topics of
docs/contract.md
for the bag writer and the live node. It draws nothing: the acceleration spectra and their
figure are :mod:`rail_monitor_ros.offline.acceleration_spectra`. No ROS import.

Integration is exact for the linear model: parameters (speed, creep factor, spring and damper
ratios) are held constant over each output interval (value at its midpoint, so steps land on
the nearest output sample; ramps advance in quanta of 0.001 and 0.01 m/s), the track input is
sampled at the internal rate and interpolated linearly between samples (first-order hold), and
each constant-parameter model is discretised with one matrix exponential. The internal
first-order-hold steps of one output interval are lifted into a single step
x[k+1] = Phi x[k] + Psi U[k], so the only loop is one matrix-vector product per output sample.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.signal

from rail_monitor_ros.core.rail_model import StateSpace, full_car_state_space
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from rail_monitor_ros.simulation.rail_scenario import (
    ParameterProfiles,
    RailScenario,
    SensorConfig,
    evaluate_profiles,
    load_rail_scenario,
)
from rail_monitor_ros.simulation.track_profile import generate_track_profile
from vehicle_monitor_common.series import TopicSeries, stamps_from_seconds


@dataclass(frozen=True)
class RailSimulationResult:
    """Everything one run produced, sampled at the output rate from t = 0 to the duration.

    Attributes:
        scenario: the scenario that was run.
        time: (N,) s.
        state: (N, 28) true full-car state, names in ``state_names``.
        state_names: names of the state columns (see ``full_car_state_space``).
        sensor_truth: (N, 6) noise-free [front bogie lateral accel, front bogie yaw rate, body
            lateral accel above the front bogie, the same three for the rear bogie].
        bogie_lateral_accel: (N,) measured front bogie lateral acceleration, m/s^2.
        bogie_yaw_rate: (N,) measured front bogie yaw rate, rad/s.
        body_lateral_accel: (N,) measured body lateral acceleration above the front bogie,
            m/s^2.
        measured_state: (N, 28) state with measurement noise (RailLateralStates).
        track_alignment: (N, 4) true track alignment under wheelsets 1..4, m.
        track_alignment_rate: (N, 4) its time derivative, m/s.
        measured_track_alignment: (N, 4) as published: the track map (the true track plus
            the map error when ``track.map_error_rms`` > 0) with measurement noise, m.
        measured_track_alignment_rate: (N, 4) its rate, likewise, m/s.
        speed: (N,) m/s.
        measured_speed: (N,) as /rail/speed publishes it (``SensorConfig.speed_scale_bias``,
            ``speed_noise``), m/s.
        creep_factor: (N,).
        spring_ratio: (N, 2) front, rear bogie.
        damper_ratio: (N, 2) front, rear bogie.
    """

    scenario: RailScenario
    time: np.ndarray
    state: np.ndarray
    state_names: tuple[str, ...]
    sensor_truth: np.ndarray
    bogie_lateral_accel: np.ndarray
    bogie_yaw_rate: np.ndarray
    body_lateral_accel: np.ndarray
    measured_state: np.ndarray
    track_alignment: np.ndarray
    track_alignment_rate: np.ndarray
    measured_track_alignment: np.ndarray
    measured_track_alignment_rate: np.ndarray
    speed: np.ndarray
    measured_speed: np.ndarray
    creep_factor: np.ndarray
    spring_ratio: np.ndarray
    damper_ratio: np.ndarray

    def state_column(self, name: str) -> np.ndarray:
        """(N,) true state by name, e.g. ``'y_v'`` or ``'dpsi_b1'``."""
        if name not in self.state_names:
            raise ValueError(f'unknown state {name!r}; states: {self.state_names}')
        return self.state[:, self.state_names.index(name)]


@dataclass(frozen=True)
class _LiftedModel:
    model: StateSpace
    phi: np.ndarray   # (n, n) transition over one output interval
    psi: np.ndarray   # (n, (m + 1) p) input matrix over the m + 1 internal input samples


def _lift_foh(model: StateSpace, h: float, substeps: int) -> _LiftedModel:
    """Exact first-order-hold discretisation at step h, lifted over ``substeps`` steps."""
    a, b = model.a, model.b
    n, p = b.shape
    block = np.zeros((n + 2 * p, n + 2 * p))
    block[:n, :n] = a * h
    block[:n, n:n + p] = b * h
    block[n:n + p, n + p:] = np.eye(p)
    e = scipy.linalg.expm(block)
    phi_h = e[:n, :n]
    lam1, lam2 = e[:n, n:n + p], e[:n, n + p:]
    # Linear input between samples: x+ = Phi x + (L1 - L2) u_j + L2 u_{j+1} (Franklin-Powell).
    gamma0, gamma1 = lam1 - lam2, lam2
    powers = [np.eye(n)]
    for _ in range(substeps):
        powers.append(phi_h @ powers[-1])
    psi = np.zeros((n, (substeps + 1) * p))
    for j in range(substeps):
        psi[:, j * p:(j + 1) * p] += powers[substeps - 1 - j] @ gamma0
        psi[:, (j + 1) * p:(j + 2) * p] += powers[substeps - 1 - j] @ gamma1
    return _LiftedModel(model, powers[substeps], psi)


def simulate(scenario: RailScenario) -> RailSimulationResult:
    """Run a scenario; same scenario (seed included) gives identical arrays."""
    output_dt = 1.0 / scenario.output_rate
    substeps = int(round(scenario.internal_rate / scenario.output_rate))
    h = output_dt / substeps
    n_warm = int(round(scenario.warm_up * scenario.output_rate))
    n_run = int(round(scenario.duration * scenario.output_rate))
    n_intervals = n_warm + n_run
    t_grid = (np.arange(n_intervals + 1) - n_warm) * output_dt        # output instants
    mid = t_grid[:-1] + 0.5 * output_dt
    profiles = _quantized(evaluate_profiles(scenario, mid))

    # Distance of the leading wheelset from where the warm-up starts, at every internal sample.
    s_grid = np.concatenate([[0.0], np.cumsum(profiles.speed * output_dt)])
    sub = np.arange(substeps + 1) * h
    s_internal = s_grid[:-1, None] + profiles.speed[:, None] * sub[None, :]   # (K, m + 1)
    params = scenario.vehicle
    offsets = params.wheelset_offsets
    seeds = np.random.SeedSequence(scenario.seed).spawn(2)
    track_rng, noise_rng = (np.random.default_rng(s) for s in seeds)
    margin = 10.0
    track_cfg = scenario.track
    # Whole metres, so the profile (and its random draws) does not hinge on the last bit of a
    # floating-point distance: runs of the same track at other rates see the same track.
    length = float(math.ceil(s_grid[-1] + offsets[-1] + 2.0 * margin))
    profile = generate_track_profile(
        TRACK_SPECTRA[track_cfg.spectrum], start=-offsets[-1] - margin, length=length,
        rng=track_rng,
        min_wavelength=track_cfg.min_wavelength, max_wavelength=track_cfg.max_wavelength,
        scale=track_cfg.scale)
    u_internal = profile.at(s_internal[..., None] - offsets)          # (K, m + 1, 4)
    n_inputs = offsets.size

    # Piecewise-constant models: one per distinct parameter set (steps reuse them).
    keys = np.column_stack([profiles.speed, profiles.creep_factor, profiles.spring_ratio,
                            profiles.damper_ratio])
    unique_keys, key_index = np.unique(keys, axis=0, return_inverse=True)
    key_index = key_index.reshape(-1)
    lifted = [_lift_foh(full_car_state_space(params.with_speed(k[0]), k[1], k[2:4], k[4:6]),
                        h, substeps) for k in unique_keys]
    n_states = lifted[0].phi.shape[0]
    forcing = np.empty((n_intervals, n_states))
    u_flat = u_internal.reshape(n_intervals, (substeps + 1) * n_inputs)
    groups = _rows_by_key(key_index, len(lifted))
    for model, rows in zip(lifted, groups, strict=True):
        forcing[rows] = u_flat[rows] @ model.psi.T
    states = np.zeros((n_intervals + 1, n_states))
    x = states[0]
    phis = [m.phi for m in lifted]
    # The recursion is inherently sequential: one matrix-vector product per output sample.
    for k in range(n_intervals):
        x = phis[key_index[k]] @ x + forcing[k]
        states[k + 1] = x

    # Keep t >= 0. Sample k uses the model of the interval starting there (the last sample,
    # the interval before it), so accelerations jump with the parameters as they do physically.
    keep = slice(n_warm, n_intervals + 1)
    time = t_grid[keep]
    state = states[keep]
    sample_key = np.append(key_index, key_index[-1])[keep]
    s_samples = s_grid[keep]
    u_samples = profile.at(s_samples[:, None] - offsets)
    u_rate = unique_keys[sample_key, 0][:, None] * profile.slope_at(s_samples[:, None] - offsets)
    sensor_truth = np.empty((time.size, lifted[0].model.c.shape[0]))
    for model, rows in zip(lifted, _rows_by_key(sample_key, len(lifted)), strict=True):
        sensor_truth[rows] = state[rows] @ model.model.c.T + u_samples[rows] @ model.model.d.T

    names = lifted[0].model.state_names
    sensors = scenario.sensors
    n = time.size
    imu_noise = noise_rng.standard_normal((n, 3)) * np.array(
        [sensors.bogie_accel_noise, sensors.bogie_gyro_noise, sensors.body_accel_noise])
    imu_bias = np.array([sensors.bogie_accel_bias, sensors.bogie_gyro_bias,
                         sensors.body_accel_bias])
    imu = sensor_truth[:, :3] + imu_bias + imu_noise
    state_noise_std = np.array([_state_sensor_value(name, sensors, 'noise') for name in names])
    measured_state = state + noise_rng.standard_normal(state.shape) * state_noise_std
    state_bias = np.array([_state_sensor_value(name, sensors, 'bias') for name in names])
    if np.any(state_bias != 0.0):    # opt-in: without offsets the arrays stay bit-identical
        measured_state = measured_state + state_bias
    published_u, published_rate = u_samples, u_rate
    if track_cfg.map_error_rms > 0.0:
        # A third stream (children 0 and 1 are unchanged by spawning more), drawn only when asked.
        map_rng = np.random.default_rng(np.random.SeedSequence(scenario.seed).spawn(3)[2])
        spectrum = TRACK_SPECTRA[track_cfg.spectrum]
        band_std = math.sqrt(spectrum.variance(track_cfg.min_wavelength,
                                               track_cfg.max_wavelength))
        error = generate_track_profile(
            spectrum, start=profile.start, length=length, rng=map_rng,
            min_wavelength=track_cfg.min_wavelength, max_wavelength=track_cfg.max_wavelength,
            scale=track_cfg.map_error_rms / band_std)
        positions = s_samples[:, None] - offsets
        published_u = u_samples + error.at(positions)
        published_rate = u_rate + unique_keys[sample_key, 0][:, None] * error.slope_at(positions)
    measured_u = published_u + noise_rng.standard_normal(u_samples.shape) * sensors.track_noise
    measured_u_rate = (published_rate
                       + noise_rng.standard_normal(u_rate.shape) * sensors.track_rate_noise)

    # Truth is the parameter set the model used from each sample on, as for sensor_truth.
    sample_params = unique_keys[sample_key]
    measured_speed = sample_params[:, 0] * (1.0 + sensors.speed_scale_bias)
    if sensors.speed_noise > 0.0:    # drawn last and only when asked: the rest stays the same
        measured_speed = measured_speed + noise_rng.standard_normal(n) * sensors.speed_noise
    return RailSimulationResult(
        scenario=scenario, time=time, state=state, state_names=names,
        sensor_truth=sensor_truth, bogie_lateral_accel=imu[:, 0], bogie_yaw_rate=imu[:, 1],
        body_lateral_accel=imu[:, 2], measured_state=measured_state,
        track_alignment=u_samples, track_alignment_rate=u_rate,
        measured_track_alignment=measured_u, measured_track_alignment_rate=measured_u_rate,
        speed=sample_params[:, 0], measured_speed=measured_speed,
        creep_factor=sample_params[:, 1],
        spring_ratio=sample_params[:, 2:4], damper_ratio=sample_params[:, 4:6])


# Ramps advance in these quanta, so a ramp needs a few hundred models instead of one per
# output sample; steps to values on the grid (1.5, 0.4, 40 m/s) are unaffected.
RATIO_QUANTUM = 1e-3
SPEED_QUANTUM = 1e-2  # m/s


def _quantized(profiles: ParameterProfiles) -> ParameterProfiles:
    def snap(values: np.ndarray, quantum: float) -> np.ndarray:
        return np.round(values / quantum) * quantum

    return ParameterProfiles(
        profiles.time, snap(profiles.speed, SPEED_QUANTUM),
        snap(profiles.creep_factor, RATIO_QUANTUM), snap(profiles.spring_ratio, RATIO_QUANTUM),
        snap(profiles.damper_ratio, RATIO_QUANTUM))


def _rows_by_key(key_index: np.ndarray, n_keys: int) -> list[np.ndarray]:
    """Row indices of each key, in one sort rather than one full scan per key."""
    order = np.argsort(key_index, kind='stable')
    bounds = np.searchsorted(key_index[order], np.arange(n_keys + 1))
    return [order[bounds[i]:bounds[i + 1]] for i in range(n_keys)]


def _state_sensor_value(name: str, sensors: SensorConfig, quantity: str) -> float:
    """A sensor quantity (``'noise'`` or ``'bias'``) of a state by the state's kind: rate or
    not, yaw or lateral (``SensorConfig.displacement_noise``, ``yaw_rate_bias`` ...)."""
    rate = name.startswith('d')
    yaw = 'psi' in name
    kind = {(False, False): 'displacement', (True, False): 'velocity',
            (False, True): 'yaw', (True, True): 'yaw_rate'}[(rate, yaw)]
    return float(getattr(sensors, f'{kind}_{quantity}'))


def lateral_states_fields(state: np.ndarray, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """RailLateralStates fields (message field name -> (N, ...) array) from full-car states.

    Args:
        state: (N, n) states of :func:`full_car_state_space` (true or measured).
        names: their names (``y_w1``, ``dpsi_b2``, ``y_v`` ...).
    """
    def cols(prefix: str, bodies: list[str]) -> np.ndarray:
        return state[:, [names.index(f'{prefix}_{b}') for b in bodies]]

    wheelsets = ['w1', 'w2', 'w3', 'w4']
    bogies = ['b1', 'b2']
    return {
        'wheelset_lateral': cols('y', wheelsets),
        'wheelset_lateral_rate': cols('dy', wheelsets),
        'wheelset_yaw': cols('psi', wheelsets),
        'wheelset_yaw_rate': cols('dpsi', wheelsets),
        'bogie_lateral': cols('y', bogies),
        'bogie_lateral_rate': cols('dy', bogies),
        'bogie_yaw': cols('psi', bogies),
        'bogie_yaw_rate': cols('dpsi', bogies),
        'body_lateral': state[:, names.index('y_v')],
        'body_lateral_rate': state[:, names.index('dy_v')],
        'body_yaw': state[:, names.index('psi_v')],
        'body_yaw_rate': state[:, names.index('dpsi_v')],
    }


def _covariance(n: int, diagonal: tuple[float, float, float]) -> np.ndarray:
    cov = np.zeros((n, 9))
    cov[:, [0, 4, 8]] = diagonal
    return cov


IMU_TYPE = 'sensor_msgs/msg/Imu'
RAIL_LATERAL_STATES_TYPE = 'vehicle_monitor_msgs/msg/RailLateralStates'
TRACK_IRREGULARITY_TYPE = 'vehicle_monitor_msgs/msg/TrackIrregularity'
SUSPENSION_STATE_TYPE = 'vehicle_monitor_msgs/msg/SuspensionState'
CREEP_FACTOR_TYPE = 'vehicle_monitor_msgs/msg/CreepFactor'
SPEED_TYPE = 'geometry_msgs/msg/TwistStamped'
# The forward speed is published at a tachometer's rate, every this many samples (20 Hz at
# 200 Hz): the estimators hold it between messages.
SPEED_DECIMATION = 10


def scenario_topics(path: str | Path, seed: int | None = None) -> dict[str, TopicSeries]:
    """Simulate a scenario file (optionally with another seed) straight to its topics."""
    scenario = load_rail_scenario(path)
    if seed is not None:
        scenario = dataclasses.replace(scenario, seed=seed)
    return to_topic_series(simulate(scenario))


def to_topic_series(result: RailSimulationResult, low_adhesion_threshold: float = 0.5,
                    start_time: float = 0.0) -> dict[str, TopicSeries]:
    """The run as topics: sensors, observation patterns, track input and ground truth.

    Topics: ``/rail/bogie/imu`` and ``/rail/body/imu`` (sensor_msgs/Imu: linear_acceleration.y,
    angular_velocity.z; no orientation, so orientation_covariance[0] = -1 per REP 145),
    ``/rail/lateral_states`` (measured, with noise) and ``/truth/lateral_states`` (true),
    ``/rail/track_irregularity`` (the four wheelsets, front to rear), ``/rail/speed``
    (geometry_msgs/TwistStamped, twist.linear.x: the forward speed as measured, every
    ``SPEED_DECIMATION``-th sample), ``/truth/suspension``, ``/truth/creep_factor``.

    Args:
        result: a simulation result.
        low_adhesion_threshold: truth flag ``low_adhesion`` = creep factor below this.
        start_time: stamp of the first sample, s (e.g. a wall-clock epoch for live runs).
    """
    stamps = stamps_from_seconds(result.time + start_time)
    n = stamps.size
    sensors = result.scenario.sensors
    no_orientation = np.zeros((n, 9))
    no_orientation[:, 0] = -1.0
    bogie_imu = TopicSeries(IMU_TYPE, stamps, {
        'linear_acceleration.y': result.bogie_lateral_accel,
        'angular_velocity.z': result.bogie_yaw_rate,
        'orientation_covariance': no_orientation,
        'linear_acceleration_covariance': _covariance(n, (0.0, sensors.bogie_accel_noise ** 2,
                                                          0.0)),
        'angular_velocity_covariance': _covariance(n, (0.0, 0.0, sensors.bogie_gyro_noise ** 2)),
    }, frame_id='front_bogie')
    body_imu = TopicSeries(IMU_TYPE, stamps, {
        'linear_acceleration.y': result.body_lateral_accel,
        'orientation_covariance': no_orientation,
        'linear_acceleration_covariance': _covariance(n, (0.0, sensors.body_accel_noise ** 2,
                                                          0.0)),
    }, frame_id='body_above_front_bogie')
    measured = TopicSeries(RAIL_LATERAL_STATES_TYPE, stamps,
                           lateral_states_fields(result.measured_state, result.state_names),
                           frame_id='track')
    truth_states = TopicSeries(RAIL_LATERAL_STATES_TYPE, stamps,
                               lateral_states_fields(result.state, result.state_names),
                               frame_id='track')
    track = TopicSeries(TRACK_IRREGULARITY_TYPE, stamps, {
        'lateral_alignment': result.measured_track_alignment,
        'lateral_alignment_rate': result.measured_track_alignment_rate,
    }, frame_id='track')
    suspension = TopicSeries(SUSPENSION_STATE_TYPE, stamps, {
        'spring_ratio': result.spring_ratio,
        'damper_ratio': result.damper_ratio,
    })
    params = result.scenario.vehicle
    creep = TopicSeries(CREEP_FACTOR_TYPE, stamps, {
        'creep_factor': result.creep_factor,
        'std_dev': np.zeros(n),
        'f11': result.creep_factor * params.longitudinal_creep_coefficient,
        'f22': result.creep_factor * params.lateral_creep_coefficient,
        'low_adhesion': result.creep_factor < low_adhesion_threshold,
    })
    speed = TopicSeries(SPEED_TYPE, stamps[::SPEED_DECIMATION], {
        'twist.linear.x': result.measured_speed[::SPEED_DECIMATION]}, frame_id='front_bogie')
    return {
        '/rail/bogie/imu': bogie_imu,
        '/rail/body/imu': body_imu,
        '/rail/lateral_states': measured,
        '/truth/lateral_states': truth_states,
        '/rail/track_irregularity': track,
        '/rail/speed': speed,
        '/truth/suspension': suspension,
        '/truth/creep_factor': creep,
    }
