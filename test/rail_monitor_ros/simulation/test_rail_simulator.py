"""Tests of the rail simulator: scenarios, exact integration, spectra, faults, topics."""

from __future__ import annotations

import copy
import dataclasses
import math
import os
from pathlib import Path
import time
from typing import Any

import numpy as np
import pytest
import scipy.signal

from rail_monitor_ros.core.rail_model import full_car_state_space, vehicle_modes
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from rail_monitor_ros.offline.acceleration_spectra import acceleration_psd, plot_acceleration_psd
from rail_monitor_ros.simulation.rail_scenario import (
    SCENARIO_DIR,
    evaluate_profiles,
    load_rail_scenario,
    rail_scenario_from_dict,
    shipped_scenario,
)
from rail_monitor_ros.simulation.rail_simulator import (
    SPEED_DECIMATION,
    RailSimulationResult,
    simulate,
    to_topic_series,
)


def _run(duration: float = 60.0, seed: int = 1, **extra: Any) -> RailSimulationResult:
    return simulate(rail_scenario_from_dict({'duration': duration, 'seed': seed, **extra}))


@pytest.fixture(scope='module')
def healthy() -> RailSimulationResult:
    """120 s healthy run (the PSD checks need the averages)."""
    return _run(120.0, seed=1)


@pytest.fixture(scope='module')
def faults() -> dict[str, RailSimulationResult]:
    """60 s runs on the same track (same seed): healthy, front spring 150 %, front damper 50 %."""
    return {
        'healthy': _run(60.0, seed=2),
        'spring': _run(60.0, seed=2, initial={'spring_ratio': [1.5, 1.0]}),
        'damper': _run(60.0, seed=2, initial={'damper_ratio': [0.5, 1.0]}),
    }


def test_same_seed_identical_output_other_seed_not() -> None:
    """Same scenario and seed give bit-identical arrays and topics; another seed does not."""
    scenario = shipped_scenario('rail_imm_spring_damper_fault')
    first, second = simulate(scenario), simulate(scenario)
    for name in ('state', 'bogie_lateral_accel', 'body_lateral_accel', 'measured_state',
                 'track_alignment', 'spring_ratio', 'damper_ratio'):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
    topics_a, topics_b = to_topic_series(first), to_topic_series(second)
    for topic, series in topics_a.items():
        np.testing.assert_array_equal(series.stamps_ns, topics_b[topic].stamps_ns)
        for field, values in series.fields.items():
            np.testing.assert_array_equal(values, topics_b[topic].fields[field])
    other = simulate(rail_scenario_from_dict({**_as_dict(scenario), 'seed': 4}))
    assert not np.allclose(other.body_lateral_accel, first.body_lateral_accel)


def _as_dict(scenario: Any) -> dict[str, Any]:
    return {'duration': scenario.duration, 'seed': scenario.seed,
            'events': [{'time': e.time, e.quantity: e.value,
                        'bogie': {(0,): 'front', (1,): 'rear', (0, 1): 'both'}[e.bogies]}
                       for e in scenario.events]}


def test_integration_is_exact() -> None:
    """The lifted first-order-hold recursion equals scipy.signal.lsim (linear input
    interpolation) at the internal rate, and a 200 Hz run is every fifth sample of a 1 kHz run
    on the same track."""
    fine = _run(2.0, seed=7, output_rate=1000.0, internal_rate=1000.0)
    coarse = _run(2.0, seed=7, output_rate=200.0, internal_rate=1000.0)
    np.testing.assert_allclose(coarse.state, fine.state[::5], rtol=1e-9, atol=1e-12)
    model = full_car_state_space(fine.scenario.vehicle)
    _, _, x_ref = scipy.signal.lsim((model.a, model.b, np.eye(28), np.zeros((28, 4))),
                                    fine.track_alignment, fine.time, X0=fine.state[0],
                                    interp=True)
    scale = np.max(np.abs(fine.state), axis=0)
    assert np.max(np.abs(x_ref - fine.state) / scale) < 1e-8


def test_body_accel_psd_matches_the_model_and_track_spectrum(healthy: RailSimulationResult,
                                                             ) -> None:
    """The simulated body and bogie acceleration PSDs equal |H(jw)|^2 times the track's temporal
    PSD, with H summing the four wheelsets' delayed inputs: checks track generation, delays and
    integration together (band averages within sampling scatter)."""
    p = healthy.scenario.vehicle
    fs = healthy.scenario.output_rate
    freq, body = scipy.signal.welch(healthy.sensor_truth[:, 2], fs=fs, nperseg=2000)
    _, bogie = scipy.signal.welch(healthy.sensor_truth[:, 0], fs=fs, nperseg=2000)
    model = full_car_state_space(p)
    delays = p.wheelset_offsets / p.speed
    omega = 2.0 * math.pi * freq
    spatial = omega / p.speed
    in_band = (spatial >= 2.0 * math.pi / 120.0) & (spatial <= 2.0 * math.pi / 1.0)
    track_psd = np.where(in_band, TRACK_SPECTRA['german_low'].psd(spatial) * 2 * math.pi
                         / p.speed, 0.0)
    response = np.array([
        (model.c @ np.linalg.solve(1j * w * np.eye(28) - model.a, model.b) + model.d)
        @ np.exp(-1j * w * delays) for w in omega])
    for measured, column in ((body, 2), (bogie, 0)):
        theory = np.abs(response[:, column]) ** 2 * track_psd
        for lo, hi in ((0.5, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0), (4.0, 5.0), (5.0, 7.0),
                       (7.0, 10.0)):
            band = (freq >= lo) & (freq < hi)
            ratio = measured[band].mean() / theory[band].mean()
            assert 0.7 < ratio < 1.4, f'column {column}, {lo}-{hi} Hz: ratio {ratio:.2f}'
        total = (freq >= 0.5) & (freq < 10.0)
        assert measured[total].sum() / theory[total].sum() == pytest.approx(1.0, rel=0.15)


def _transmissibility(result: RailSimulationResult) -> tuple[np.ndarray, np.ndarray]:
    """|H1| from front bogie to body lateral acceleration above it, by cross spectra."""
    fs = result.scenario.output_rate
    freq, p_bb = scipy.signal.welch(result.bogie_lateral_accel, fs=fs, nperseg=2000)
    _, p_bv = scipy.signal.csd(result.bogie_lateral_accel, result.body_lateral_accel, fs=fs,
                               nperseg=2000)
    return freq, np.abs(p_bv) / p_bb


def _peak(freq: np.ndarray, values: np.ndarray, lo: float, hi: float) -> float:
    band = (freq >= lo) & (freq <= hi)
    return float(freq[band][np.argmax(values[band])])


def _centroid(freq: np.ndarray, values: np.ndarray, lo: float, hi: float) -> float:
    band = (freq >= lo) & (freq <= hi)
    return float(np.sum(freq[band] * values[band]) / np.sum(values[band]))


def test_body_suspension_mode_shows_where_the_parameters_put_it(healthy: RailSimulationResult,
                                                                ) -> None:
    """The transmissibility from the mean bogie lateral acceleration to the body centre's
    (half-sum of the two above-bogie signals, which cancels body yaw) peaks at the body lateral
    mode of the eigenanalysis (1.42 Hz damped, 1.45 Hz undamped)."""
    p = healthy.scenario.vehicle
    body_mode = [m for m in vehicle_modes(full_car_state_space(p), p) if m.coordinate == 'y_v']
    truth = healthy.sensor_truth
    fs = healthy.scenario.output_rate
    bogies = 0.5 * (truth[:, 0] + truth[:, 3])
    body = 0.5 * (truth[:, 2] + truth[:, 5])
    freq, p_bb = scipy.signal.welch(bogies, fs=fs, nperseg=2000)
    _, p_bv = scipy.signal.csd(bogies, body, fs=fs, nperseg=2000)
    assert body_mode[0].frequency_hz == pytest.approx(1.42, abs=0.01)
    assert _peak(freq, np.abs(p_bv) / p_bb, 0.5, 3.0) == pytest.approx(
        body_mode[0].frequency_hz, abs=0.12)


def test_faults_shift_the_acceleration_psd_the_expected_way(
        faults: dict[str, RailSimulationResult]) -> None:
    """Paper Fig. 4: the signals look alike, the PSDs do not.

    Stiffer front spring (150 %): body mode and transmission rise, so the body acceleration
    gains power across 1-5 Hz and the bogie-to-body transmissibility moves up in frequency.
    Softer front damper (50 %): the body resonance grows sharper (more power at 1.2-1.7 Hz)
    while isolation above it improves (less power at 2.5-5 Hz). The RMS changes stay modest
    (< 25 %), as in the paper.
    """
    def band_power(result: RailSimulationResult, lo: float, hi: float) -> float:
        freq, psd = acceleration_psd(result, 'body', segment_seconds=10.0)
        band = (freq >= lo) & (freq < hi)
        return float(psd[band].sum())

    healthy, spring, damper = faults['healthy'], faults['spring'], faults['damper']
    assert band_power(spring, 1.0, 5.0) > 1.3 * band_power(healthy, 1.0, 5.0)
    f_h, t_h = _transmissibility(healthy)
    f_s, t_s = _transmissibility(spring)
    assert _centroid(f_s, t_s, 0.8, 2.5) > _centroid(f_h, t_h, 0.8, 2.5) + 0.05
    assert band_power(damper, 1.2, 1.7) > 1.5 * band_power(healthy, 1.2, 1.7)
    assert band_power(damper, 2.5, 5.0) < 0.8 * band_power(healthy, 2.5, 5.0)
    rms = {k: float(np.std(r.body_lateral_accel)) for k, r in faults.items()}
    assert abs(rms['spring'] / rms['healthy'] - 1.0) < 0.25
    assert abs(rms['damper'] / rms['healthy'] - 1.0) < 0.25


def test_imm_scenario_truth_and_events() -> None:
    """The IMM run: front spring 150 % from 3 s, front damper 50 % from 6 s, rear untouched;
    the sensors see the change in the model (bogie acceleration follows the spring step)."""
    result = simulate(shipped_scenario('rail_imm_spring_damper_fault'))
    t = result.time
    assert t[0] == 0.0 and t[-1] == pytest.approx(10.0) and np.allclose(np.diff(t), 0.005)
    np.testing.assert_array_equal(result.spring_ratio[:, 0], np.where(t >= 3.0, 1.5, 1.0))
    np.testing.assert_array_equal(result.damper_ratio[:, 0], np.where(t >= 6.0, 0.5, 1.0))
    assert np.all(result.spring_ratio[:, 1] == 1.0) and np.all(result.damper_ratio[:, 1] == 1.0)
    assert np.all(result.creep_factor == 1.0) and np.all(result.speed == 40.0)
    # Noise on the IMU: measured minus truth has the configured standard deviation.
    residual = result.body_lateral_accel - result.sensor_truth[:, 2]
    assert np.std(residual) == pytest.approx(result.scenario.sensors.body_accel_noise, rel=0.1)


def test_creep_scenario_and_ramps() -> None:
    """The creep run steps 1 -> 0.4 at 5 s -> 0.6 at 10 s at 40 m/s; ramps are linear."""
    result = simulate(shipped_scenario('rail_creep_steps'))
    t = result.time
    expected = np.where(t >= 10.0, 0.6, np.where(t >= 5.0, 0.4, 1.0))
    np.testing.assert_allclose(result.creep_factor, expected, atol=1e-12)
    scenario = rail_scenario_from_dict({
        'duration': 10.0,
        'events': [{'time': 2.0, 'creep_factor': 0.5, 'ramp': 4.0},
                   {'time': 3.0, 'spring_ratio': 2.0, 'bogie': 'rear'},
                   {'time': 6.0, 'speed': 30.0, 'ramp': 2.0}]})
    profiles = evaluate_profiles(scenario, np.array([1.0, 2.0, 4.0, 6.0, 7.0, 9.0]))
    np.testing.assert_allclose(profiles.creep_factor, [1.0, 1.0, 0.75, 0.5, 0.5, 0.5])
    np.testing.assert_allclose(profiles.speed, [40.0, 40.0, 40.0, 40.0, 35.0, 30.0])
    np.testing.assert_allclose(profiles.spring_ratio[:, 1], [1.0, 1.0, 2.0, 2.0, 2.0, 2.0])
    np.testing.assert_allclose(profiles.spring_ratio[:, 0], 1.0)


def test_topic_series() -> None:
    """to_topic_series gives the docs/contract.md topics with matching stamps, types and values."""
    result = simulate(shipped_scenario('rail_creep_steps'))
    topics = to_topic_series(result, low_adhesion_threshold=0.5)
    assert set(topics) == {'/rail/bogie/imu', '/rail/body/imu', '/rail/lateral_states',
                           '/truth/lateral_states', '/rail/track_irregularity',
                           '/rail/speed', '/truth/suspension', '/truth/creep_factor'}
    n = result.time.size
    for topic, series in topics.items():
        every = SPEED_DECIMATION if topic == '/rail/speed' else 1
        assert len(series) == len(range(0, n, every))
        np.testing.assert_array_equal(series.stamps_ns, np.round(result.time[::every] * 1e9))
    np.testing.assert_array_equal(topics['/rail/speed'].fields['twist.linear.x'],
                                  result.speed[::SPEED_DECIMATION])
    # A tachometer 0.2 % high with 0.05 m/s noise: /rail/speed only, the rest unchanged.
    scenario = shipped_scenario('rail_creep_steps')
    biased = simulate(dataclasses.replace(scenario, sensors=dataclasses.replace(
        scenario.sensors, speed_scale_bias=0.002, speed_noise=0.05)))
    error = biased.measured_speed - biased.speed * 1.002
    assert abs(error.mean()) < 0.01 and 0.04 < error.std() < 0.06
    np.testing.assert_array_equal(biased.bogie_lateral_accel, result.bogie_lateral_accel)
    assert topics['/rail/bogie/imu'].msgtype == 'sensor_msgs/msg/Imu'
    np.testing.assert_array_equal(topics['/rail/bogie/imu'].fields['angular_velocity.z'],
                                  result.bogie_yaw_rate)
    creep = topics['/truth/creep_factor'].fields
    np.testing.assert_allclose(creep['f22'], result.creep_factor * 6.79e6)
    np.testing.assert_array_equal(creep['low_adhesion'], result.creep_factor < 0.5)
    states = topics['/truth/lateral_states'].fields
    np.testing.assert_array_equal(states['bogie_yaw_rate'][:, 0],
                                  result.state_column('dpsi_b1'))
    assert states['wheelset_lateral'].shape == (n, 4)
    # The measured states carry the configured noise, the truth does not.
    measured = topics['/rail/lateral_states'].fields['body_lateral']
    assert np.std(measured - states['body_lateral']) == pytest.approx(1e-4, rel=0.1)


@pytest.mark.skipif(not os.environ.get('AMENT_PREFIX_PATH'),
                    reason='bag_io.typestore needs the workspace environment (tools/env.sh)')
def test_topic_series_build_valid_messages() -> None:
    """Every series turns into messages through the project's bag layer, values intact."""
    from vehicle_monitor_common.bag_io import series_messages

    result = simulate(rail_scenario_from_dict({'duration': 1.0, 'seed': 3}))
    topics = to_topic_series(result)
    for series in topics.values():
        first = next(series_messages(series))
        assert first.header.stamp.sec == 0
    msg = list(series_messages(topics['/rail/track_irregularity']))[100]
    np.testing.assert_allclose(msg.lateral_alignment, result.measured_track_alignment[100])
    imu = list(series_messages(topics['/rail/body/imu']))[7]
    assert imu.linear_acceleration.y == result.body_lateral_accel[7]
    assert imu.orientation_covariance[0] == -1.0
    suspension = next(series_messages(topics['/truth/suspension']))
    np.testing.assert_array_equal(suspension.spring_ratio, [1.0, 1.0])


BASE: dict[str, Any] = {'duration': 10.0, 'seed': 1,
                        'events': [{'time': 3.0, 'spring_ratio': 1.5, 'bogie': 'front'},
                                   {'time': 6.0, 'damper_ratio': 0.5}]}


def _with(path: tuple[Any, ...], value: Any) -> dict[str, Any]:
    data = copy.deepcopy(BASE)
    target: Any = data
    for key in path[:-1]:
        target = target.setdefault(key, {}) if isinstance(key, str) else target[key]
    target[path[-1]] = value
    return data


@pytest.mark.parametrize('data, match', [
    (_with(('colour',), 'red'), 'colour: unknown key'),
    (_with(('vehicle', 'wheel_mass'), 1.0), 'vehicle.wheel_mass: unknown key'),
    (_with(('vehicle', 'wheelset_mass'), -1250.0), 'wheelset_mass'),
    (_with(('vehicle', 'primary_lateral_stiffness'), 0.0), 'primary_lateral_stiffness'),
    (_with(('vehicle', 'conicity'), 0.0), 'conicity'),
    (_with(('vehicle', 'speed'), 40.0), 'vehicle.speed'),
    (_with(('initial', 'speed'), 0.0), 'initial.speed'),
    (_with(('initial', 'speed'), -10.0), 'initial.speed'),
    (_with(('initial', 'spring_ratio'), 6.0), 'initial.spring_ratio'),
    (_with(('initial', 'damper_ratio'), [1.0, 0.0]), 'initial.damper_ratio'),
    (_with(('sensors', 'gyro_noise'), 0.1), 'sensors.gyro_noise: unknown key'),
    (_with(('sensors', 'body_accel_noise'), -0.1), 'sensors.body_accel_noise'),
    (_with(('track', 'spectrum'), 'fra_class_9'), 'track.spectrum'),
    (_with(('track', 'max_wavelength'), 0.5), 'track.max_wavelength'),
    (_with(('events', 0, 'colour'), 1), 'events\\[0\\].colour: unknown key'),
    (_with(('events', 0, 'time'), 7.0), 'events\\[1\\].time'),
    (_with(('events', 0, 'spring_ratio'), 0.0), 'events\\[0\\].spring_ratio'),
    (_with(('events', 0, 'spring_ratio'), 5.5), 'events\\[0\\].spring_ratio'),
    (_with(('events', 1, 'time'), 11.0), 'events\\[1\\].time'),
    (_with(('events', 0, 'bogie'), 'middle'), 'events\\[0\\].bogie'),
    (_with(('events', 0, 'ramp'), 4.0), 'during the ramp'),
    (_with(('events', 1, 'creep_factor'), 0.5), 'exactly one'),
    (_with(('duration',), -1.0), 'duration'),
    (_with(('seed',), 1.5), 'seed'),
    (_with(('internal_rate',), 1100.0), 'internal_rate'),
    ({'seed': 1}, 'duration: is required'),
    ([1, 2], 'mapping'),
])
def test_bad_scenarios_are_refused(data: Any, match: str) -> None:
    """Unknown keys, non-physical values, out-of-order or overlapping events and ratios outside
    (0, 5] are refused with a message naming the key."""
    if match == 'during the ramp':
        data['events'][1] = {'time': 5.0, 'spring_ratio': 1.2, 'bogie': 'front'}
    with pytest.raises(ValueError, match=match):
        rail_scenario_from_dict(data)


def test_creep_events_out_of_range_and_bogie_misuse() -> None:
    """Creep factor outside (0, 2] and a bogie on a creep event are refused by key."""
    with pytest.raises(ValueError, match='events\\[0\\].creep_factor'):
        rail_scenario_from_dict({'duration': 5.0, 'events': [{'time': 1.0, 'creep_factor': 3.0}]})
    with pytest.raises(ValueError, match='events\\[0\\].bogie'):
        rail_scenario_from_dict({'duration': 5.0, 'events': [
            {'time': 1.0, 'creep_factor': 0.5, 'bogie': 'front'}]})


def test_shipped_scenarios_load(tmp_path: Path) -> None:
    """Every shipped YAML validates; the healthy run has no events and lasts 60 s."""
    names = sorted(p.stem for p in SCENARIO_DIR.glob('*.yaml'))
    assert {'rail_healthy', 'rail_imm_spring_damper_fault', 'rail_creep_steps'} <= set(names)
    for name in names:
        load_rail_scenario(SCENARIO_DIR / f'{name}.yaml')
    healthy = shipped_scenario('rail_healthy')
    assert healthy.duration == 60.0 and healthy.events == ()
    with pytest.raises(ValueError, match='nor one of that name in rail_monitor_ros/scenarios'):
        shipped_scenario('nope')
    bad = tmp_path / 'bad.yaml'
    bad.write_text('duration: 5\nevents:\n  - {time: 1, speed: 0}\n')
    with pytest.raises(ValueError, match='events\\[0\\].speed'):
        load_rail_scenario(bad)


def test_scenario_errors_name_file_and_line(tmp_path: Path) -> None:
    """A scenario file's errors carry its path and the line of the offending key (the reader
    shared with the road domain, vehicle_monitor_common.scenario_yaml)."""
    bad = tmp_path / 'bad.yaml'
    bad.write_text('duration: 5\nvehicle:\n  conicity: 0.15\n  wheel_mass: 1\nevents:\n'
                   '  - time: 1\n    spring_ratio: 1.2\n  - time: 0.5\n    damper_ratio: 0.5\n')
    with pytest.raises(ValueError, match=f'^{bad}:4: vehicle.wheel_mass: unknown key$'):
        load_rail_scenario(bad)
    bad.write_text('duration: 5\nevents:\n  - time: 1\n    spring_ratio: 1.2\n'
                   '  - time: 0.5\n    damper_ratio: 0.5\n')
    with pytest.raises(ValueError, match=f'^{bad}:5: events\\[1\\].time: .*time order'):
        load_rail_scenario(bad)
    bad.write_text('duration: 5\nvehicle:\n  wheelset_mass: -3\n')
    with pytest.raises(ValueError, match=f'^{bad}:3: vehicle.wheelset_mass: .*> 0'):
        load_rail_scenario(bad)
    bad.write_text('duration: 5\nduration: 6\n')
    with pytest.raises(ValueError, match=f'^{bad}:2: duration: duplicate key'):
        load_rail_scenario(bad)


def test_plot_writes_png(faults: dict[str, RailSimulationResult], tmp_path: Path) -> None:
    """The Fig. 4 style plot writes a PNG file."""
    path = plot_acceleration_psd(faults, tmp_path / 'psd.png')
    assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_sixty_seconds_simulate_far_faster_than_real_time() -> None:
    """60 s at 200 Hz output takes well under 6 s (> 10x real time) even on a busy machine."""
    scenario = shipped_scenario('rail_healthy')
    start = time.perf_counter()
    simulate(scenario)
    assert time.perf_counter() - start < 6.0
