"""Road vehicle simulator: runs a scenario and returns sensor data with its ground truth.

Pipeline (docs/methods/tire_stiffness_observer.md, §3, §7):

1. The scenario's profiles (speed, steer, pressures, friction) are sampled on the handling grid
   and the 14-DOF handling model (``vehicle_dynamics.simulate_handling``) gives the body motion,
   tire forces and the rigid spin of each wheel. Each tire's rolling radius follows its pressure
   and a seeded tire-to-tire spread (wear).
2. Wheel-speed truth: the rigid spin, interpolated to the torsion grid, plus the rim vibration of
   each wheel's two-inertia torsional tire (``tire_model.TorsionalTire``) driven by a white
   road-roughness torque on the belt whose level follows the surface and speed, and, on the
   driven axle, by driveline/suspension-member resonances that reach both rims in phase with
   wandering frequencies. K and D follow each tire's pressure; the filters run in pieces of
   ``rates.parameter_chunk_s`` with parameters held per piece and the state carried, each
   piece discretised exactly (zero-order hold) and run mode by mode with ``lfilter``.
3. The ABS encoder: tooth edges where the rim angle crosses the (spacing-error) tooth angles,
   stamped by an ECU timer; speed = tooth pitch / tooth period, held until the next edge and
   read at the wheel-speed rate, as an ECU reports it.
4. IMU (offset, noise), driver inputs, and truth topics, as arrays or as
   :class:`~vehicle_monitor_common.series.TopicSeries` (:func:`to_topic_series`).

No ROS import: the ``vehicle_simulator`` node and the bag writer sit on top of this.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
import dataclasses
from dataclasses import dataclass
import math
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from tpms_ros.core.tire_model import TorsionalTire
from tpms_ros.core.wheel_encoder import encoder_wheel_speed
from tpms_ros.simulation.road_scenario import (
    DrivelineSpec,
    Scenario,
    TireSpec,
    friction_multiplier,
    load_scenario,
    road_surface,
    speed_target,
    steering_angle,
    tire_pressure,
)
from tpms_ros.simulation.vehicle_dynamics import (
    HandlingInputs,
    HandlingResult,
    VehicleParams,
    simulate_handling,
)
from vehicle_monitor_common.series import TopicSeries, stamps_from_seconds

GRAVITY = 9.80665
FRAME_ID = 'base_link'
# Kim & Huh 2000: the load-ratio split of the lateral force holds below 0.5 g.
LATERAL_VALIDITY_G = 0.5

HandlingModel = Callable[[VehicleParams, HandlingInputs, float], HandlingResult]

# Independent random streams, one per source, so that changing one (e.g. more teeth) does not
# reshuffle the others. New streams go at the end: a SeedSequence child depends only on its
# index, so the existing ones (and every shipped bag) stay bit-identical.
_STREAMS = ('radius', 'teeth', 'phase', 'road', 'driveline', 'wander', 'imu', 'spread',
            'driveline_front')
#: The streams that draw the car rather than the drive (``Scenario.vehicle_seed``).
_VEHICLE_STREAMS = frozenset({'radius', 'teeth', 'spread'})


@dataclass(frozen=True)
class RoadSimulationResult:
    """Everything one scenario run produced. Wheel order FL, FR, RL, RR.

    Attributes:
        scenario: the scenario that was run.
        handling: the handling model's output on the handling grid.
        pressure_kpa: (N_h, 4) inflation pressure on the handling grid, kPa.
        stiffness: (N_h, 4) torsional stiffness K, N m/rad.
        damping: (N_h, 4) torsional damping D, N m s/rad.
        resonance_hz: (N_h, 4) torsional resonance of each tire, Hz.
        rolling_radius: (N_h, 4) effective rolling radius, m.
        friction_scale: (N_h,) road friction scale given to the handling model.
        radius_offset: (4,) relative tire-to-tire radius offset (wear) of this run.
        wheel_speed_t: (N_w,) wheel-speed sample times, s.
        wheel_speed: (N_w, 4) measured wheel speed (encoder output), rad/s.
        rim_speed: (N_w, 4) true rim speed (rigid spin + torsional vibration), rad/s.
        driveline_t: (C,) start time of each parameter piece, s.
        driveline_frequency_hz: (C, M) instantaneous frequency of each driveline mode.
        tooth_error: (4, teeth) tooth-edge angle errors of each wheel's ring, rad.
        imu_t: (N_i,) IMU sample times, s.
        imu_accel: (N_i, 2) measured ax, ay, m/s^2.
        imu_gyro: (N_i, 2) measured roll rate p, yaw rate r, rad/s.
    """

    scenario: Scenario
    handling: HandlingResult
    pressure_kpa: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    resonance_hz: np.ndarray
    rolling_radius: np.ndarray
    friction_scale: np.ndarray
    radius_offset: np.ndarray
    wheel_speed_t: np.ndarray
    wheel_speed: np.ndarray
    rim_speed: np.ndarray
    driveline_t: np.ndarray
    driveline_frequency_hz: np.ndarray
    tooth_error: np.ndarray
    imu_t: np.ndarray
    imu_accel: np.ndarray
    imu_gyro: np.ndarray


def tire_scales(tire: TireSpec, rng: np.random.Generator
                ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Per-tire factors on K0 and D0 (tire-to-tire spread); None where the spread is 0.

    Drawn from the run's ``spread`` stream: K first, then D, four each.
    """
    k_draw = rng.standard_normal(4)
    d_draw = rng.standard_normal(4)
    stiffness = 1.0 + tire.stiffness_spread * k_draw if tire.stiffness_spread > 0.0 else None
    damping = np.maximum(1.0 + tire.damping_spread * d_draw, 0.05) \
        if tire.damping_spread > 0.0 else None
    return stiffness, damping


def _grid(duration_s: float, rate_hz: float) -> np.ndarray:
    """Sample times 0, 1/rate, ... up to and including the duration (within half a step)."""
    count = int(math.floor(duration_s * rate_hz + 0.5)) + 1
    return np.arange(count) / rate_hz


def _interp_columns(t_dst: np.ndarray, t_src: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Linear interpolation of each column of ``values`` (N_src, ...) onto ``t_dst``."""
    flat = values.reshape(values.shape[0], -1)
    out = np.empty((t_dst.size, flat.shape[1]))
    for column in range(flat.shape[1]):
        out[:, column] = np.interp(t_dst, t_src, flat[:, column])
    return out.reshape((t_dst.size,) + values.shape[1:])


def run_piecewise_lti(a: np.ndarray, b: np.ndarray, u: np.ndarray, starts: np.ndarray,
                      dt: float, x0: np.ndarray | None = None) -> np.ndarray:
    """Simulate x' = A_c x + B_c u with (A_c, B_c) constant over each piece, state carried.

    Each piece is discretised exactly for a zero-order-hold input and run in modal form, one
    first-order ``lfilter`` per mode, so the cost is a few vectorised filters per piece, not a
    Python loop per sample. Each A_c must be diagonalisable (distinct eigenvalues), as the
    damped tire and driveline models are.

    Args:
        a: (C, n, n) continuous state matrix of each piece.
        b: (C, n, m) continuous input matrix of each piece.
        u: (N, m) input samples (held over each step).
        starts: (C,) first sample index of each piece, starting with 0, increasing.
        dt: sample step, s.
        x0: (n,) initial state (zeros when None).

    Returns:
        (N, n) state at each sample time, before that sample's input acts.
    """
    pieces, n, m = b.shape
    if a.shape != (pieces, n, n) or u.ndim != 2 or u.shape[1] != m:
        raise ValueError('run_piecewise_lti: a, b, u shapes do not agree')
    if starts.shape != (pieces,) or starts[0] != 0 or np.any(np.diff(starts) <= 0):
        raise ValueError('run_piecewise_lti: starts must begin at 0 and increase')
    # Exact zero-order-hold discretisation in modal coordinates: with A = V diag(lam) V^-1,
    # each mode advances by exp(lam dt) and takes (exp(lam dt) - 1)/lam of its input. (The
    # stacked eigen-decomposition is far cheaper than an expm per piece.)
    rates, vectors = np.linalg.eig(a)                # (C, n), (C, n, n)
    inverse = np.linalg.inv(vectors)
    poles = np.exp(rates * dt)
    small = np.abs(rates * dt) < 1e-9
    gain = np.where(small, dt, (poles - 1.0) / np.where(small, 1.0, rates))
    modal_input = gain[:, :, None] * (inverse @ b)   # (C, n, m)
    x = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    out = np.empty((u.shape[0], n))
    ends = np.append(starts[1:], u.shape[0])
    for piece in range(pieces):
        first, last = int(starts[piece]), int(ends[piece])
        drive = u[first:last] @ modal_input[piece].T    # (L, n) complex
        q0 = inverse[piece] @ x
        after = np.empty_like(drive)
        for mode in range(n):
            pole = poles[piece, mode]
            # after[k] = modal state after input k: a first-order recursion with the carried
            # state entering through zi.
            after[:, mode] = lfilter([1.0], [1.0, -pole], drive[:, mode],
                                     zi=np.array([pole * q0[mode]]))[0]
        out[first] = x
        out[first + 1:last] = (after[:-1] @ vectors[piece].T).real
        x = (vectors[piece] @ after[-1]).real
    return out


def _piece_starts(count: int, piece_len: int) -> np.ndarray:
    return np.arange(0, count, piece_len)


def _leaky_rigid_mode(a: np.ndarray, leak: float) -> np.ndarray:
    """The free-free torsional A with its zero (rigid, common-spin) eigenvalue moved to -leak.

    The zero-mean road torque would otherwise make the common mode of the vibration filter
    drift like a random walk; the wheel's mean spin is the handling model's (where tire slip
    ties it to the road). Only that eigenvalue changes: the torsional mode keeps exactly the
    frequency and damping of ``TorsionalTire`` (eigenvectors unchanged).
    """
    rates, vectors = np.linalg.eig(a)                        # (C, 3), (C, 3, 3)
    rigid = np.argmin(np.abs(rates), axis=1)
    rates[np.arange(rates.shape[0]), rigid] = -leak
    rebuilt = vectors @ (rates[:, :, None] * np.linalg.inv(vectors))
    return rebuilt.real


def _driveline_torque(spec: DrivelineSpec, count: int, starts: np.ndarray, piece_len: int,
                      rate_hz: float, speed: np.ndarray, speed_factor: np.ndarray,
                      wander_rng: np.random.Generator, noise_rng: np.random.Generator
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Sum of the driveline mode torques on one driven axle's rims and the mode frequencies.

    Returns:
        (torque (N,), frequencies (C, M) of each mode per parameter piece).
    """
    dt = 1.0 / rate_hz
    mid = np.minimum(starts + piece_len // 2, count - 1)
    frequencies = np.zeros((starts.size, len(spec.modes)))
    driveline_torque = np.zeros(count)
    # Ornstein-Uhlenbeck wander sampled per piece (exact discretisation of the OU process).
    piece_dt = piece_len * dt
    decay = math.exp(-piece_dt / spec.wander_time_constant_s)
    kicks = wander_rng.standard_normal(starts.size) * spec.wander_random_std \
        * math.sqrt(1.0 - decay ** 2)
    wander = lfilter([1.0], [1.0, -decay], kicks,
                     zi=np.array([decay * spec.wander_random_std
                                  * wander_rng.standard_normal()]))[0]
    condition = (speed[mid] * 3.6 - spec.wander_reference_speed_kmh) \
        / spec.wander_speed_scale_kmh + wander
    for index, mode in enumerate(spec.modes):
        frequencies[:, index] = mode.frequency_hz \
            + 0.5 * spec.wander_span_hz * np.tanh(condition)
        omega = 2.0 * np.pi * frequencies[:, index]
        a = np.zeros((starts.size, 2, 2))
        a[:, 0, 1] = 1.0
        a[:, 1, 0] = -omega ** 2
        a[:, 1, 1] = -2.0 * mode.damping_ratio * omega
        b = np.zeros((starts.size, 2, 1))
        b[:, 1, 0] = omega ** 2
        # Unit-gain resonator on white noise of one-sided PSD G has variance
        # G * omega_n / (8 zeta); choose G for the mode's rms at its centre frequency.
        omega_0 = 2.0 * np.pi * mode.frequency_hz
        psd = 8.0 * mode.damping_ratio * mode.torque_rms_nm ** 2 / omega_0
        noise = noise_rng.standard_normal(count) \
            * math.sqrt(psd * rate_hz / 2.0) * speed_factor
        states = run_piecewise_lti(a, b, noise[:, None], starts, dt)
        driveline_torque += states[:, 0]
    return driveline_torque, frequencies


def _torsional_vibration(scenario: Scenario, t: np.ndarray, pressure: np.ndarray,
                         speed: np.ndarray, driven: tuple[int, ...],
                         rngs: Mapping[str, np.random.Generator],
                         stiffness_scale: np.ndarray | None = None,
                         damping_scale: np.ndarray | None = None,
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rim-speed vibration of the four wheels on the torsion grid.

    Args:
        t: (N,) torsion grid, s.
        pressure: (N, 4) tire pressures on that grid, kPa.
        speed: (N,) vehicle speed, m/s (sets the excitation level).
        driven: indices of the driven wheels.
        stiffness_scale, damping_scale: (4,) per-tire factors on K and D (tire-to-tire
            spread), None: identical tires.

    Returns:
        (vibration (N, 4) rad/s, piece start times (C,), driveline mode frequencies (C, M)).
    """
    rates = scenario.rates
    tire_spec = scenario.tire
    dt = 1.0 / rates.torsion_hz
    piece_len = max(1, int(round(rates.parameter_chunk_s * rates.torsion_hz)))
    starts = _piece_starts(t.size, piece_len)
    mid = np.minimum(starts + piece_len // 2, t.size - 1)

    # Excitation level grows with speed (no roughness torque at standstill).
    speed_factor = (np.maximum(speed, 0.0) / (scenario.roughness_reference_kmh / 3.6)) \
        ** scenario.roughness_speed_exponent
    roughness_psd, _ = road_surface(scenario, t)
    # One-sided PSD G held over steps dt has variance G * fs / 2 per sample.
    road_std = np.sqrt(roughness_psd * rates.torsion_hz / 2.0) * speed_factor
    road_torque = road_std[:, None] * rngs['road'].standard_normal((t.size, 4))

    spec = scenario.driveline
    frequencies = np.zeros((starts.size, len(spec.modes)))
    driveline_torque = np.zeros(t.size)
    front_torque = np.zeros(t.size)
    if driven and spec.modes:
        driveline_torque, frequencies = _driveline_torque(
            spec, t.size, starts, piece_len, rates.torsion_hz, speed, speed_factor,
            rngs['wander'], rngs['driveline'])
        if spec.wheels == 'all':
            # All-wheel drive: the other axle's differential/member modes, independent.
            front_torque, _ = _driveline_torque(
                spec, t.size, starts, piece_len, rates.torsion_hz, speed, speed_factor,
                rngs['driveline_front'], rngs['driveline_front'])
    rim_torques: list[np.ndarray]
    if spec.wheels == 'all':
        rim_torques = [front_torque, front_torque, driveline_torque, driveline_torque]
    else:
        rim_torques = [driveline_torque if wheel in driven else np.zeros(t.size)
                       for wheel in range(4)]

    # Per-piece torsional parameters from each tire's pressure at the piece middle.
    stiffness = tire_spec.stiffness(pressure[mid])          # (C, 4)
    damping = tire_spec.damping(pressure[mid])
    if stiffness_scale is not None:
        stiffness = stiffness * stiffness_scale
    if damping_scale is not None:
        damping = damping * damping_scale
    leak = 2.0 * np.pi * tire_spec.rigid_mode_corner_hz
    vibration = np.empty((t.size, 4))
    for wheel in range(4):
        a = np.empty((starts.size, 3, 3))
        b = np.empty((starts.size, 3, 2))
        for piece in range(starts.size):
            tire = TorsionalTire(tire_spec.j1, tire_spec.j2, float(stiffness[piece, wheel]),
                                 float(damping[piece, wheel]))
            a[piece], b[piece] = tire.state_space()
        a = _leaky_rigid_mode(a, leak)
        inputs = np.column_stack([rim_torques[wheel], road_torque[:, wheel]])
        vibration[:, wheel] = run_piecewise_lti(a, b, inputs, starts, dt)[:, 0]
    return vibration, t[starts], frequencies


def simulate_scenario(scenario: Scenario,
                      handling_model: HandlingModel | None = None) -> RoadSimulationResult:
    """Run a scenario.

    Args:
        scenario: a validated scenario (``road_scenario.load_scenario``).
        handling_model: the handling simulation to use; ``vehicle_dynamics.simulate_handling``
            when None (tests may pass a cheaper one with the same signature).

    Returns:
        The sensor outputs and ground truth. Same scenario (and seed) -> identical arrays.
    """
    model = simulate_handling if handling_model is None else handling_model
    streams = np.random.SeedSequence(scenario.seed).spawn(len(_STREAMS))
    if scenario.vehicle_seed is not None:
        # the car's own draws from its seed, at the same stream positions, so that drives of
        # one car share its tires and rings while the road and the noise change
        car_streams = np.random.SeedSequence(scenario.vehicle_seed).spawn(len(_STREAMS))
        streams = [car_streams[i] if name in _VEHICLE_STREAMS else seq
                   for i, (name, seq) in enumerate(zip(_STREAMS, streams, strict=True))]
    rngs = {name: np.random.default_rng(seq) for name, seq in zip(_STREAMS, streams, strict=True)}
    params = scenario.vehicle
    rates = scenario.rates
    tire = scenario.tire

    # 1. Handling truth.
    t_h = _grid(scenario.duration_s, rates.handling_hz)
    pressure_h = tire_pressure(scenario, t_h)
    radius_offset = rngs['radius'].normal(0.0, tire.radius_spread, 4)
    rolling_radius = params.rw * (1.0 + radius_offset) * tire.radius_factor(pressure_h)
    _, surface_friction = road_surface(scenario, t_h)
    friction = surface_friction * friction_multiplier(scenario, t_h)
    inputs = HandlingInputs(
        t=t_h, steer=steering_angle(scenario, t_h), speed_target=speed_target(scenario, t_h),
        torque_offset=np.tile(np.asarray(scenario.torque_offset_nm), (t_h.size, 1)),
        friction_scale=friction, rolling_radius=rolling_radius,
        added_mass=scenario.added_mass_kg)
    handling = model(params, inputs, scenario.initial_speed_kmh / 3.6)

    # 2. Rim speed on the torsion grid.
    t_s = _grid(scenario.duration_s, rates.torsion_hz)
    rigid = _interp_columns(t_s, handling.t, np.asarray(handling.omega))
    speed_s = np.interp(t_s, handling.t, np.asarray(handling.vx))
    driven = (0, 1) if params.driven_axle == 'front' else (2, 3)
    stiffness_scale, damping_scale = tire_scales(tire, rngs['spread'])
    vibration, piece_t, frequencies = _torsional_vibration(
        scenario, t_s, tire_pressure(scenario, t_s), speed_s, driven, rngs,
        stiffness_scale, damping_scale)
    rim_s = rigid + vibration

    # 3. Encoder.
    sensors = scenario.sensors
    pitch = 2.0 * np.pi / sensors.teeth
    tooth_error = rngs['teeth'].normal(0.0, sensors.tooth_error_rms * pitch,
                                       (4, sensors.teeth))
    tooth_error -= tooth_error.mean(axis=1, keepdims=True)
    phases = rngs['phase'].uniform(0.0, 2.0 * np.pi, 4)
    t_w = _grid(scenario.duration_s, rates.wheel_speed_hz)
    wheel_speed = np.column_stack([
        encoder_wheel_speed(t_s, rim_s[:, w], t_w, tooth_error[w], float(phases[w]),
                            sensors.timer_resolution_s, sensors.speed_method,
                            sensors.speed_window_s) for w in range(4)])
    rim_w = _interp_columns(t_w, t_s, rim_s)

    # 4. IMU.
    t_i = _grid(scenario.duration_s, rates.imu_hz)
    noise = rngs['imu'].standard_normal((t_i.size, 4))
    accel = _interp_columns(t_i, handling.t, np.column_stack([handling.ax, handling.ay])) \
        + sensors.accel_noise_m_s2 * noise[:, :2]
    gyro = _interp_columns(t_i, handling.t, np.column_stack([handling.roll_rate,
                                                             handling.yaw_rate])) \
        + np.array([sensors.gyro_roll_offset_rad_s, sensors.gyro_yaw_offset_rad_s]) \
        + sensors.gyro_noise_rad_s * noise[:, 2:]

    stiffness_h = tire.stiffness(pressure_h)
    damping_h = tire.damping(pressure_h)
    resonance_h = tire.resonance_hz(pressure_h)
    if stiffness_scale is not None:
        stiffness_h = stiffness_h * stiffness_scale
        resonance_h = resonance_h * np.sqrt(stiffness_scale)
    if damping_scale is not None:
        damping_h = damping_h * damping_scale
    return RoadSimulationResult(
        scenario=scenario, handling=handling, pressure_kpa=pressure_h,
        stiffness=stiffness_h, damping=damping_h,
        resonance_hz=resonance_h, rolling_radius=rolling_radius,
        friction_scale=friction, radius_offset=radius_offset, wheel_speed_t=t_w,
        wheel_speed=wheel_speed, rim_speed=rim_w, driveline_t=piece_t,
        driveline_frequency_hz=frequencies, tooth_error=tooth_error, imu_t=t_i,
        imu_accel=accel, imu_gyro=gyro)


def simulate_file(path: str | Path,
                  handling_model: HandlingModel | None = None) -> RoadSimulationResult:
    """Load a scenario file and run it."""
    return simulate_scenario(load_scenario(path), handling_model)


def scenario_topics(path: str | Path, seed: int | None = None) -> dict[str, TopicSeries]:
    """Simulate a scenario file (optionally with another seed) straight to its topics."""
    scenario = load_scenario(path)
    if seed is not None:
        scenario = dataclasses.replace(scenario, seed=seed)
    return to_topic_series(simulate_scenario(scenario))


def to_topic_series(result: RoadSimulationResult) -> dict[str, TopicSeries]:
    """The run as topics: inputs (``/vehicle/*``) and ground truth (``/truth/*``).

    Rates come from the scenario (``rates``); every topic is stamped on simulation time.
    """
    scenario = result.scenario
    rates = scenario.rates
    handling = result.handling
    t_h = np.asarray(handling.t)
    topics: dict[str, TopicSeries] = {}

    topics['/vehicle/wheel_speeds'] = TopicSeries(
        'vehicle_monitor_msgs/msg/WheelSpeeds', stamps_from_seconds(result.wheel_speed_t),
        {'omega': result.wheel_speed}, FRAME_ID)

    sensors = scenario.sensors
    count = result.imu_t.size
    orientation_cov = np.zeros((count, 9))
    orientation_cov[:, 0] = -1.0        # REP 145: orientation not provided
    gyro_cov = np.zeros((count, 9))
    gyro_cov[:, [0, 4, 8]] = sensors.gyro_noise_rad_s ** 2
    accel_cov = np.zeros((count, 9))
    accel_cov[:, [0, 4, 8]] = sensors.accel_noise_m_s2 ** 2
    topics['/vehicle/imu'] = TopicSeries(
        'sensor_msgs/msg/Imu', stamps_from_seconds(result.imu_t),
        {'linear_acceleration.x': result.imu_accel[:, 0],
         'linear_acceleration.y': result.imu_accel[:, 1],
         'linear_acceleration.z': np.full(count, GRAVITY),
         'angular_velocity.x': result.imu_gyro[:, 0],
         'angular_velocity.z': result.imu_gyro[:, 1],
         'orientation_covariance': orientation_cov,
         'angular_velocity_covariance': gyro_cov,
         'linear_acceleration_covariance': accel_cov}, FRAME_ID)

    t_d = _grid(scenario.duration_s, rates.driver_inputs_hz)
    topics['/vehicle/driver_inputs'] = TopicSeries(
        'vehicle_monitor_msgs/msg/DriverInputs', stamps_from_seconds(t_d),
        {'steering_angle': np.interp(t_d, t_h, handling.steer),
         'wheel_torque': _interp_columns(t_d, t_h, np.asarray(handling.wheel_torque))},
        FRAME_ID)

    t_p = _grid(scenario.duration_s, rates.pressure_hz)
    topics['/truth/tire_pressure'] = TopicSeries(
        'vehicle_monitor_msgs/msg/TirePressure', stamps_from_seconds(t_p),
        {'pressure_kpa': _interp_columns(t_p, t_h, result.pressure_kpa),
         'stiffness': _interp_columns(t_p, t_h, result.stiffness),
         'damping': _interp_columns(t_p, t_h, result.damping),
         'resonance_hz': _interp_columns(t_p, t_h, result.resonance_hz),
         'rolling_radius': _interp_columns(t_p, t_h, result.rolling_radius)}, FRAME_ID)

    t_t = _grid(scenario.duration_s, rates.truth_hz)
    fy = _interp_columns(t_t, t_h, np.asarray(handling.fy))
    ay = np.interp(t_t, t_h, handling.ay)
    topics['/truth/tire_forces'] = TopicSeries(
        'vehicle_monitor_msgs/msg/TireForces', stamps_from_seconds(t_t),
        {'fx': _interp_columns(t_t, t_h, np.asarray(handling.fx)), 'fy': fy,
         'fz': _interp_columns(t_t, t_h, np.asarray(handling.fz)),
         'fy_front': fy[:, 0] + fy[:, 1], 'fy_rear': fy[:, 2] + fy[:, 3],
         'within_validity': np.abs(ay) <= LATERAL_VALIDITY_G * GRAVITY}, FRAME_ID)

    state = {name: np.interp(t_t, t_h, getattr(handling, name))
             for name in ('vx', 'vy', 'yaw_rate', 'roll', 'roll_rate', 'ax')}
    state['ay'] = ay
    state['friction_scale'] = np.interp(t_t, t_h, result.friction_scale)
    state['mass'] = np.full(t_t.size, float(np.asarray(handling.mass).ravel()[0]))
    topics['/truth/vehicle_state'] = TopicSeries(
        'vehicle_monitor_msgs/msg/VehicleState', stamps_from_seconds(t_t), state, FRAME_ID)
    return topics
