"""Tests of the rail car family (issue 19 item 3) and the simulator's opt-in track map error and
state offsets."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from rail_monitor_ros.core.rail_model import RailVehicleParams
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from rail_monitor_ros.simulation.rail_family import (
    CONICITY_RANGE,
    DEVELOPMENT_SEEDS,
    HELD_OUT_SEEDS,
    IMM_SPEED_RANGE,
    MASS_FIELDS,
    SPEED_MARGIN,
    WIDE_DEVELOPMENT_SEEDS,
    case_seed,
    creep_steps_scenario,
    family,
    fault_ratio,
    is_stable,
    sample_car,
    sample_speeds,
    scenario_mapping,
    suspension_fault_scenario,
)
from rail_monitor_ros.simulation.rail_scenario import parse_rail_scenario, rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import simulate


def test_cars_are_seeded_within_their_ranges_and_held_out_is_apart() -> None:
    """Same seed, same car; the held-out and development sets are disjoint; every held-out car
    keeps its masses within +/-20 %, its conicity in range and its speeds below the margin of
    its critical speed (stable there, faults included)."""
    assert not set(HELD_OUT_SEEDS) & set(DEVELOPMENT_SEEDS)
    assert not set(HELD_OUT_SEEDS) & set(WIDE_DEVELOPMENT_SEEDS)
    assert not set(DEVELOPMENT_SEEDS) & set(WIDE_DEVELOPMENT_SEEDS)
    assert sample_car(HELD_OUT_SEEDS[0]) == sample_car(HELD_OUT_SEEDS[0])
    assert sample_car(HELD_OUT_SEEDS[0]) != sample_car(HELD_OUT_SEEDS[1])
    nominal = RailVehicleParams()
    cars = family()
    assert len(cars) == len(HELD_OUT_SEEDS)
    for car in cars:
        for name in MASS_FIELDS:
            assert 0.8 <= getattr(car.vehicle, name) / getattr(nominal, name) <= 1.2
        assert CONICITY_RANGE[0] <= car.vehicle.conicity <= CONICITY_RANGE[1]
        assert car.max_speed == pytest.approx(SPEED_MARGIN * car.critical_speed)
        assert 0.0 <= car.map_error_rms <= 1e-3
        for speed in sample_speeds(car, 2) + sample_speeds(car, 2, *IMM_SPEED_RANGE):
            assert 20.0 <= speed <= min(70.0, car.max_speed)
            assert is_stable(car, speed, creep_factor=0.5)
            assert is_stable(car, speed, spring_ratio=fault_ratio(car, 'spring', 0))
    # The family spans the ranges (not one corner of them).
    conicities = [car.vehicle.conicity for car in cars]
    assert min(conicities) < 0.1 and max(conicities) > 0.3
    assert {car.spectrum for car in cars} == {'german_low', 'german_high'}


def test_family_scenario_is_valid_yaml_and_map_error_only_changes_the_published_track() -> None:
    """A family scenario's mapping is valid scenario YAML; the track map error changes the
    published alignment only (true track, IMUs and states identical), by about the stated rms,
    with the track spectrum's shape (long wavelengths dominate: the error's rate is small)."""
    car = sample_car(DEVELOPMENT_SEEDS[0])
    speed = sample_speeds(car, 1)[0]
    text = yaml.safe_dump(scenario_mapping(car, 'x', speed, 5, 60.0, [], map_error_rms=5e-4))
    scenario = parse_rail_scenario(text, 'family.yaml')
    assert scenario.track.map_error_rms == 5e-4
    exact = simulate(replace(scenario, track=replace(scenario.track, map_error_rms=0.0)))
    mapped = simulate(scenario)
    for name in ('state', 'bogie_lateral_accel', 'body_lateral_accel', 'measured_state',
                 'track_alignment', 'track_alignment_rate'):
        np.testing.assert_array_equal(getattr(exact, name), getattr(mapped, name))
    error = mapped.measured_track_alignment - exact.measured_track_alignment
    rms = float(np.sqrt(np.mean(error ** 2)))
    assert 2.5e-4 < rms < 1e-3
    # Same shape as the track: error rms / track rms about as the stated ratio.
    spectrum = TRACK_SPECTRA[car.spectrum]
    ratio = rms / float(np.std(exact.track_alignment))
    expected = 5e-4 / np.sqrt(spectrum.variance(1.0, 120.0))
    assert 0.4 * expected < ratio < 2.5 * expected
    # Wheelset 2 sees the error of wheelset 1 delayed: it is a property of the track, not noise.
    lag = int(round(2 * car.vehicle.semi_wheelbase / speed * 200.0))
    np.testing.assert_allclose(error[lag:, 1], error[:-lag, 0], atol=0.05 * rms)


def test_state_offsets_are_constant_and_opt_in() -> None:
    """Offsets of the lateral states are added as constants; without them the measured states
    are the same arrays as before (the shipped scenarios' bits do not move)."""
    base = {'duration': 5.0, 'seed': 3}
    plain = simulate(rail_scenario_from_dict(base))
    zero = simulate(rail_scenario_from_dict({**base, 'sensors': {'displacement_bias': 0.0}}))
    np.testing.assert_array_equal(plain.measured_state, zero.measured_state)
    biased = simulate(rail_scenario_from_dict(
        {**base, 'sensors': {'displacement_bias': 1e-3, 'yaw_rate_bias': -2e-3}}))
    offset = biased.measured_state - plain.measured_state
    names = plain.state_names
    np.testing.assert_allclose(offset[:, names.index('y_b1')], 1e-3, atol=1e-12)
    np.testing.assert_allclose(offset[:, names.index('dpsi_v')], -2e-3, atol=1e-12)
    np.testing.assert_allclose(offset[:, names.index('dy_v')], 0.0, atol=0.0)


def test_case_scenarios() -> None:
    """The creep case steps c 1 -> 0.5 -> 0.75; the fault case steps the front bogie only."""
    car = sample_car(DEVELOPMENT_SEEDS[1])
    creep = simulate(creep_steps_scenario(car, 30.0, case_seed(car, 1), map_error_rms=0.0))
    assert set(np.round(np.unique(creep.creep_factor), 3)) == {0.5, 0.75, 1.0}
    # The exact track: published = true + the car's small track noise.
    assert np.max(np.abs(creep.measured_track_alignment - creep.track_alignment)) < 1e-4
    ratio = fault_ratio(car, 'damper', 0)
    assert 0.3 <= ratio <= 0.7
    fault = simulate(suspension_fault_scenario(car, 35.0, case_seed(car, 2), 'damper', ratio,
                                               onset=1.0, duration=2.0))
    assert fault.damper_ratio[0, 0] == 1.0 and fault.damper_ratio[-1, 0] == ratio
    assert np.all(fault.damper_ratio[:, 1] == 1.0)
    with pytest.raises(ValueError, match='component'):
        suspension_fault_scenario(car, 35.0, 1, 'wheel', 0.5)
