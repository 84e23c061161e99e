"""Tests of the road simulator: torsional wheel-speed truth, encoder, topics, determinism.

The spectral checks use a kinematic stand-in for the handling model (wheel spin = speed /
rolling radius, straight running), defined here, so they test the vibration and sensor layer
alone and stay fast; determinism and the topic layout run the real 14-DOF model.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
import re

import numpy as np
import pytest
from scipy.signal import cont2discrete, dlsim

from tpms_ros.core.tire_model import TorsionalTire
from tpms_ros.core.wheel_encoder import encoder_wheel_speed
from tpms_ros.offline.wheel_speed_spectra import plot_wheel_speed_psd, wheel_speed_psd
from tpms_ros.simulation.road_scenario import Scenario, parse_scenario
from tpms_ros.simulation.road_simulator import (
    RoadSimulationResult,
    _leaky_rigid_mode,
    run_piecewise_lti,
    simulate_scenario,
    to_topic_series,
)
from tpms_ros.simulation.vehicle_dynamics import HandlingInputs, HandlingResult, VehicleParams

MSG_DIR = Path(__file__).resolve().parents[3] / 'msg_defs' / 'msg'


def kinematic_handling(params: VehicleParams, inputs: HandlingInputs,
                       initial_speed: float) -> HandlingResult:
    """Straight running at the target speed, wheels rolling without slip (test stand-in)."""
    t = np.asarray(inputs.t)
    speed = np.where(np.isnan(inputs.speed_target), initial_speed, inputs.speed_target)
    zeros = np.zeros(t.size)
    zeros4 = np.zeros((t.size, 4))
    mass = params.m + inputs.added_mass
    return HandlingResult(
        t=t, omega=speed[:, None] / inputs.rolling_radius, wheel_torque=inputs.torque_offset,
        steer=inputs.steer, vx=speed, vy=zeros, yaw_rate=zeros, roll=zeros, roll_rate=zeros,
        ax=np.gradient(speed, t), ay=zeros, fx=zeros4, fy=zeros4,
        fz=np.tile(params.static_wheel_loads(inputs.added_mass), (t.size, 1)), mass=mass,
        pitch=zeros, yaw=zeros, slip_ratio=zeros4, slip_angle=zeros4)


def _scenario(body: str, duration: float, seed: int = 7) -> Scenario:
    return parse_scenario(f'seed: {seed}\nduration_s: {duration}\n' + body, source='test.yaml')


def _peak_hz(result: RoadSimulationResult, wheel: int, low: float = 28.0,
             high: float = 50.0) -> float:
    frequency, psd = wheel_speed_psd(result, wheel, start_s=1.0)
    # 2 Hz moving average: the peak of the resonance, not of one encoder line.
    smooth = np.convolve(psd, np.ones(5) / 5.0, mode='same')
    band = (frequency >= low) & (frequency <= high)
    return float(frequency[band][np.argmax(smooth[band])])


def _band(result: RoadSimulationResult, wheel: int | tuple[int, int], centre: float,
          half_width: float = 3.5) -> float:
    frequency, psd = wheel_speed_psd(result, wheel, start_s=1.0)
    band = np.abs(frequency - centre) <= half_width
    return float(psd[band].mean())


def test_piecewise_lti_matches_scipy_with_carried_state() -> None:
    """The modal piecewise filter equals scipy's ZOH discretisation run piece by piece with
    the state handed over (two pieces with different dynamics)."""
    rng = np.random.default_rng(1)
    dt = 1e-3
    a1 = np.array([[0.0, 1.0], [-(2 * np.pi * 30) ** 2, -20.0]])
    a2 = np.array([[0.0, 1.0], [-(2 * np.pi * 20) ** 2, -5.0]])
    b = np.array([[0.0], [1.0]])
    u = rng.standard_normal((500, 1))
    x0 = np.array([0.01, -0.3])
    states = run_piecewise_lti(np.stack([a1, a2]), np.stack([b, b]), u, np.array([0, 200]),
                               dt, x0)
    reference = []
    x = x0
    for a, piece in ((a1, u[:200]), (a2, u[200:])):
        ad, bd, *_ = cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt, method='zoh')
        _, _, xout = dlsim((ad, bd, np.eye(2), np.zeros((2, 1)), dt), piece, x0=x)
        reference.append(xout)
        x = ad @ xout[-1] + bd @ piece[-1]
    np.testing.assert_allclose(states, np.vstack(reference), rtol=1e-8, atol=1e-10)


def test_rigid_mode_leak_keeps_the_torsional_mode() -> None:
    """Making the common-spin mode leaky leaves the torsional eigenvalues of TorsionalTire
    unchanged and moves only the zero eigenvalue."""
    a, _ = TorsionalTire().state_space()
    leaky = _leaky_rigid_mode(a[None], 2.0 * np.pi)[0]
    before = np.sort_complex(np.linalg.eigvals(a))
    after = np.sort_complex(np.linalg.eigvals(leaky))
    # sorted by real part: the torsional pair (-11.7 +- 251j /s) first, the rigid mode last
    np.testing.assert_allclose(after[:2], before[:2], rtol=1e-9)
    assert abs(after[2] + 2.0 * np.pi) < 1e-9 and abs(before[2]) < 1e-9


def test_encoder_reads_constant_speed_exactly_and_stops() -> None:
    """A perfect ring at constant speed reads that speed; tooth errors repeat every
    revolution and average out over whole revolutions; a stopping wheel reads zero."""
    t = np.arange(0.0, 2.0, 1e-4)
    t_out = np.arange(0.05, 2.0, 1e-3)
    perfect = encoder_wheel_speed(t, np.full(t.size, 50.0), t_out, np.zeros(48), 0.3, 0.0)
    np.testing.assert_allclose(perfect, 50.0, rtol=1e-9)

    errors = np.random.default_rng(2).normal(0.0, 0.002 * 2 * np.pi / 48, 48)
    errors -= errors.mean()
    speed = 16.0 * np.pi           # one revolution = 125 output samples exactly
    measured = encoder_wheel_speed(t, np.full(t.size, speed), t_out, errors, 0.3, 1e-6)
    whole = t_out < 0.05 + 1.25    # ten revolutions
    assert np.std(measured) > 0.05                         # the ring's pattern is visible
    assert abs(np.mean(measured[whole]) - speed) < 0.02    # ... and averages out
    one_later = measured[125:][: int(whole.sum())]
    assert np.mean(np.abs(one_later - measured[whole]) < 1e-3) > 0.9  # repeats per revolution

    slowing = np.clip(30.0 * (1.0 - t / 1.5), 0.0, None)
    stopped = encoder_wheel_speed(t, slowing, t_out, np.zeros(48), 0.0, 1e-6)
    assert stopped[t_out > 1.9].max() < 1.0
    assert abs(stopped[np.searchsorted(t_out, 0.5)] - 20.0) < 0.5


@pytest.mark.parametrize(('speed', 'surface'), [(60, 'smooth_asphalt'),
                                                (90, 'rough_concrete')])
def test_torsional_peak_follows_pressure(speed: int, surface: str) -> None:
    """Non-driven wheels: the PSD peak sits at each tire's torsional resonance (40 Hz at
    200 kPa, 35 Hz at 120 kPa) within 1.5 Hz, and moves down by 5 +- 1.5 Hz (Umeno Fig. 1)."""
    scenario = _scenario(f"""
speed: {{initial_kmh: {speed}}}
road: {{segments: [{{at_s: 0, surface: {surface}}}]}}
tire: {{initial_pressure_kpa: [200, 120, 200, 200]}}
""", duration=30.0)
    result = simulate_scenario(scenario, kinematic_handling)
    nominal, low = _peak_hz(result, 0), _peak_hz(result, 1)
    assert abs(nominal - result.resonance_hz[0, 0]) <= 1.5
    assert abs(low - result.resonance_hz[0, 1]) <= 1.5
    assert 3.5 <= nominal - low <= 6.5


def test_driveline_peaks_on_driven_axle_cancel_in_left_right_difference() -> None:
    """Rear drive: around each driveline mode the rear wheels carry several times the power
    of the front ones, and the rear left-right difference brings it back to the level of the
    front difference (the common torque cancels, Umeno Fig. 8)."""
    scenario = _scenario('speed: {initial_kmh: 70}\n', duration=40.0)
    result = simulate_scenario(scenario, kinematic_handling)
    for mode in scenario.driveline.modes:
        centre = mode.frequency_hz     # wander stays within +-2.75 Hz of it at 70 km/h
        assert _band(result, 2, centre) > 3.0 * _band(result, 0, centre)
        assert _band(result, 3, centre) > 3.0 * _band(result, 1, centre)
        assert _band(result, (2, 3), centre) < 1.5 * _band(result, (0, 1), centre)
    spread = np.ptp(result.driveline_frequency_hz, axis=0)
    assert np.all(spread > 0.5)
    assert np.all(spread <= scenario.driveline.wander_span_hz)


def test_rolling_radius_follows_pressure_and_reaches_the_wheel_speed() -> None:
    """30 % pressure loss shrinks the rolling radius by 0.3 %, and the measured wheel speed
    rises accordingly (tire-to-tire spread included)."""
    scenario = _scenario("""
speed: {initial_kmh: 80}
events: [{type: pressure_step, at_s: 5, tires: RR, to_kpa: 140, duration_s: 1}]
""", duration=20.0)
    result = simulate_scenario(scenario, kinematic_handling)
    radius = result.rolling_radius
    np.testing.assert_allclose(radius[-1, 3] / radius[0, 3], 0.997, rtol=1e-12)
    np.testing.assert_allclose(radius[-1, :3], radius[0, :3])
    assert np.std(result.radius_offset) > 0.0
    late = result.wheel_speed_t > 10.0
    measured_ratio = result.wheel_speed[late, 3].mean() / result.wheel_speed[late, 2].mean()
    assert measured_ratio == pytest.approx(radius[-1, 2] / radius[-1, 3], abs=3e-4)


def _digest(result: RoadSimulationResult) -> str:
    digest = hashlib.sha256()
    for array in (result.wheel_speed, result.rim_speed, result.imu_accel, result.imu_gyro,
                  result.pressure_kpa, np.asarray(result.handling.fy)):
        digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


SHORT_RUN = """
speed: {initial_kmh: 50, segments: [{type: ramp, to_kmh: 60, duration_s: 2}]}
steering: {segments: [{type: step, to_deg: 1.5, rise_s: 0.3, duration_s: 3}]}
events: [{type: pressure_step, at_s: 1, tires: FL, to_kpa: 150, duration_s: 1}]
"""


@pytest.fixture(scope='module')
def full_run() -> RoadSimulationResult:
    """A 3 s run of the real 14-DOF model with every topic populated."""
    return simulate_scenario(_scenario(SHORT_RUN, duration=3.0))


def test_same_seed_gives_identical_arrays(full_run: RoadSimulationResult) -> None:
    """Same scenario and seed -> bit-identical arrays; another seed -> different ones."""
    again = simulate_scenario(_scenario(SHORT_RUN, duration=3.0))
    assert _digest(again) == _digest(full_run)
    other = simulate_scenario(_scenario(SHORT_RUN, duration=3.0, seed=8))
    assert _digest(other) != _digest(full_run)


def test_vehicle_seed_keeps_the_car_across_drives(full_run: RoadSimulationResult) -> None:
    """Drives of one car (its ``vehicle_seed``) share its tires and rings, not the road; the
    car's seed equal to the drive's reproduces a run without one."""
    body = SHORT_RUN + 'tire: {stiffness_spread: 0.03}\n'
    drives = [simulate_scenario(_scenario(f'vehicle_seed: 11\n{body}', 3.0, seed=seed))
              for seed in (7, 8)]
    np.testing.assert_array_equal(drives[0].radius_offset, drives[1].radius_offset)
    np.testing.assert_array_equal(drives[0].tooth_error, drives[1].tooth_error)
    np.testing.assert_array_equal(drives[0].stiffness[0], drives[1].stiffness[0])
    assert not np.array_equal(drives[0].wheel_speed, drives[1].wheel_speed)
    own = simulate_scenario(_scenario(f'vehicle_seed: 7\n{SHORT_RUN}', 3.0, seed=7))
    assert _digest(own) == _digest(full_run)


def _msg_fields(name: str) -> dict[str, str]:
    fields = {}
    for line in (MSG_DIR / f'{name}.msg').read_text().splitlines():
        line = line.split('#', 1)[0].strip()
        if line:
            kind, field = line.split()[:2]
            fields[field] = kind
    return fields


IMU_FIELDS = {'linear_acceleration.x', 'linear_acceleration.y', 'linear_acceleration.z',
              'angular_velocity.x', 'angular_velocity.y', 'angular_velocity.z',
              'orientation_covariance', 'angular_velocity_covariance',
              'linear_acceleration_covariance'}


def test_topic_series_match_message_definitions(full_run: RoadSimulationResult) -> None:
    """Each topic has its message type, rate, stamps, and fields named and shaped as in the
    .msg files (float64[4] -> (N, 4), scalars -> (N,), bool -> bool)."""
    topics = to_topic_series(full_run)
    rates = full_run.scenario.rates
    expected = {
        '/vehicle/wheel_speeds': ('WheelSpeeds', rates.wheel_speed_hz),
        '/vehicle/imu': ('sensor_msgs/msg/Imu', rates.imu_hz),
        '/vehicle/driver_inputs': ('DriverInputs', rates.driver_inputs_hz),
        '/truth/tire_pressure': ('TirePressure', rates.pressure_hz),
        '/truth/tire_forces': ('TireForces', rates.truth_hz),
        '/truth/vehicle_state': ('VehicleState', rates.truth_hz),
    }
    assert set(topics) == set(expected)
    for topic, (msg, rate) in expected.items():
        series = topics[topic]
        count = int(round(3.0 * rate)) + 1
        assert len(series) == count, topic
        assert series.stamps_ns[0] == 0 and np.all(np.diff(series.stamps_ns) > 0)
        assert series.frame_id == 'base_link'
        if msg.startswith('sensor_msgs'):
            assert series.msgtype == msg
            assert set(series.fields) <= IMU_FIELDS
            continue
        assert series.msgtype == f'vehicle_monitor_msgs/msg/{msg}'
        definition = _msg_fields(msg)
        definition.pop('header')
        assert set(series.fields) == set(definition), topic
        for name, kind in definition.items():
            values = np.asarray(series.fields[name])
            match = re.fullmatch(r'(\w+)\[(\d+)\]', kind)
            shape = (count, int(match.group(2))) if match else (count,)
            assert values.shape == shape, (topic, name)
            assert (values.dtype == bool) == (kind == 'bool'), (topic, name)
            assert np.all(np.isfinite(values)), (topic, name)
    pressure = topics['/truth/tire_pressure'].fields['pressure_kpa']
    np.testing.assert_allclose(pressure[-1], [150.0, 200.0, 200.0, 200.0])
    imu = topics['/vehicle/imu'].fields
    yaw_truth = topics['/truth/vehicle_state'].fields['yaw_rate']
    gyro_error = imu['angular_velocity.z'] - np.interp(full_run.imu_t, np.arange(301) / 100.0,
                                                       yaw_truth)
    assert np.mean(gyro_error) == pytest.approx(full_run.scenario.sensors.gyro_yaw_offset_rad_s,
                                                abs=1e-3)


def test_real_model_wheel_speed_tracks_the_car(full_run: RoadSimulationResult) -> None:
    """With the 14-DOF model the measured wheel speeds follow vx / r to within 2 %."""
    handling = full_run.handling
    t = full_run.wheel_speed_t
    expected = np.interp(t, handling.t, handling.vx)[:, None] / np.column_stack(
        [np.interp(t, handling.t, full_run.rolling_radius[:, w]) for w in range(4)])
    window = t > 0.5
    relative = np.abs(full_run.wheel_speed[window] / expected[window] - 1.0)
    assert np.median(relative) < 0.02


def test_plot_writes_png(tmp_path: Path) -> None:
    """The PSD plot function writes a PNG file."""
    scenario = _scenario('speed: {initial_kmh: 60}\n', duration=6.0)
    result = simulate_scenario(scenario, kinematic_handling)
    path = plot_wheel_speed_psd({'run': result}, tmp_path / 'psd.png',
                                wheels=(2, (2, 3)))
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
