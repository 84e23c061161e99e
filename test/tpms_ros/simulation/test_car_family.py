"""The car family of the road simulator (issue 21): seeded ranges, held-out seeds, new models."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tpms_ros.core.stiffness_observer import PressureRelation
from tpms_ros.core.wheel_encoder import encoder_wheel_speed
from tpms_ros.simulation.car_family import (
    DRIVE_KINDS,
    HELD_OUT_SEEDS,
    TUNING_SEEDS,
    apply_car,
    car_scenario,
    drive_profile,
    held_out_cars,
    pressure_event,
    sample_car,
)
from tpms_ros.simulation.road_scenario import (
    TireSpec,
    parse_scenario,
    speed_target,
    tire_pressure,
)
from tpms_ros.simulation.road_simulator import simulate_scenario

from .test_road_simulator import _band, kinematic_handling


def test_held_out_seeds_are_fixed_and_separate() -> None:
    assert len(HELD_OUT_SEEDS) >= 20
    assert not set(HELD_OUT_SEEDS) & set(TUNING_SEEDS)
    assert HELD_OUT_SEEDS[0] == 21_000 and len(set(HELD_OUT_SEEDS)) == len(HELD_OUT_SEEDS)


def test_same_seed_same_car() -> None:
    assert sample_car(21_003) == sample_car(21_003)
    assert sample_car(21_003) != sample_car(21_004)


def test_family_covers_the_issue_ranges() -> None:
    cars = held_out_cars() + [sample_car(seed) for seed in TUNING_SEEDS]
    resonance = np.array([c.tire.nominal_resonance_hz for c in cars])
    placard = np.array([c.placard_kpa for c in cars])
    tooth = np.array([c.sensors.tooth_error_rms for c in cars])
    exponents = [c.tire.stiffness_pressure_exponent for c in cars
                 if c.tire.stiffness_law == 'power']
    assert resonance.min() >= 32.0 and resonance.max() <= 52.0
    assert np.ptp(resonance) > 15.0
    assert placard.min() >= 180.0 and placard.max() <= 350.0 and np.ptp(placard) > 120.0
    assert tooth.min() >= 0.0 and tooth.max() <= 0.003 and tooth.max() > 0.0025
    assert min(exponents) >= 0.4 and max(exponents) <= 1.0
    assert {c.layout for c in cars} == {'front', 'rear', 'all'}
    assert {c.sensors.speed_method for c in cars} == {'tooth_period', 'window_average'}
    assert {c.body for c in cars} == {'passenger', 'light_truck'}
    assert {c.tire.stiffness_law for c in cars} == {'power', 'linear'}
    shares = [c.tire.j1 / (c.tire.j1 + c.tire.j2) for c in cars]
    assert min(shares) < 0.5 < 0.65 < max(shares)
    for car in cars:   # the resonance is the truth at placard
        assert float(car.tire.resonance_hz(np.array(car.placard_kpa))) == pytest.approx(
            car.tire.nominal_resonance_hz)


def test_power_law_stiffness() -> None:
    tire = TireSpec(stiffness_law='power', stiffness_pressure_exponent=0.6,
                    nominal_pressure_kpa=250.0)
    k0 = tire.nominal_tire.k
    np.testing.assert_allclose(tire.stiffness(np.array([250.0, 200.0])),
                               [k0, k0 * 0.8 ** 0.6])
    parsed = parse_scenario('duration_s: 1\ntire: {stiffness_law: power, '
                            'stiffness_pressure_exponent: 0.7, stiffness_spread: 0.02}\n'
                            'sensors: {encoder: {speed_method: window_average, '
                            'speed_window_s: 0.004}}\ndrive: {driveline: {wheels: all}}\n')
    assert parsed.tire.stiffness_law == 'power' and parsed.tire.stiffness_spread == 0.02
    assert parsed.sensors.speed_method == 'window_average'
    assert parsed.driveline.wheels == 'all'
    with pytest.raises(ValueError, match='speed_method'):
        parse_scenario('duration_s: 1\nsensors: {encoder: {speed_method: counting}}\n')


def test_tire_law_parameters_invert_the_simulated_law_and_stay_out_of_user_parameters(
        ) -> None:
    """The law as the stiffness observer's pressure_relation maps each car's simulated K(p)
    back to p; a user of the car is not given it (nor the ECU's data) by default."""
    laws = set()
    for seed in TUNING_SEEDS[:12]:
        car = sample_car(seed)
        law = car.tire_law_parameters()
        laws.add(law['law'])
        p0 = car.placard_kpa
        pressures = np.array([0.7, 0.8, 1.0]) * p0
        ratio = car.tire.stiffness(pressures) / car.tire.stiffness(np.array([p0]))
        np.testing.assert_allclose(p0 * PressureRelation(**law).pressure_ratio(ratio),
                                   pressures, rtol=1e-9)
        assert not any('law' in key or 'exponent' in key for key in car.user_parameters())
        assert not set(car.ecu_parameters()) & set(car.user_parameters())
    assert laws == {'line', 'power'}


def test_window_average_reads_constant_speed_and_shrinks_the_tooth_error() -> None:
    t = np.arange(0.0, 2.0, 1e-4)
    t_out = np.arange(0.05, 2.0, 1e-3)
    perfect = encoder_wheel_speed(t, np.full(t.size, 50.0), t_out, np.zeros(48), 0.3, 0.0,
                                  'window_average', 0.008)
    np.testing.assert_allclose(perfect, 50.0, rtol=1e-9)
    errors = np.random.default_rng(2).normal(0.0, 0.002 * 2 * np.pi / 48, 48)
    errors -= errors.mean()
    held = encoder_wheel_speed(t, np.full(t.size, 50.0), t_out, errors, 0.3, 1e-6)
    averaged = encoder_wheel_speed(t, np.full(t.size, 50.0), t_out, errors, 0.3, 1e-6,
                                   'window_average', 0.008)
    assert np.std(averaged) < 0.5 * np.std(held)
    assert abs(np.mean(averaged) - 50.0) < 0.05
    slowing = np.clip(30.0 * (1.0 - t / 1.5), 0.0, None)
    stopped = encoder_wheel_speed(t, slowing, t_out, np.zeros(48), 0.0, 1e-6,
                                  'window_average', 0.008)
    assert stopped[t_out > 1.9].max() < 1.0


@pytest.mark.parametrize('kind', DRIVE_KINDS)
def test_drives_vary_speed_within_their_band(kind: str) -> None:
    drive = drive_profile(kind, 300.0, seed=5)
    car = sample_car(21_500)
    scenario = car_scenario(car, drive, 300.0)
    target = speed_target(scenario, np.arange(0.0, 300.0, 0.5)) * 3.6
    low, high = {'urban': (5.0, 60.0), 'rural': (60.0, 100.0),
                 'motorway': (100.0, 140.0)}[kind]
    assert target.min() >= low - 1e-6 and target.max() <= high + 1e-6
    assert np.ptp(target) > 0.3 * (high - low)           # continuous variation
    assert len({s.kind for s in drive.steering}) >= 2
    assert sum(1 for s in drive.road if s.surface == 'rough_concrete') >= 0


def test_car_scenario_events_are_placard_relative() -> None:
    car = sample_car(21_001)
    scenario = car_scenario(car, 'rural', 120.0, [pressure_event('diffusion', 30.0,
                                                                 drop_percent=20.0)])
    end = tire_pressure(scenario, np.array([0.0, 120.0]))
    np.testing.assert_allclose(end[0], car.placard_kpa)
    np.testing.assert_allclose(end[1], 0.8 * car.placard_kpa)


def test_apply_car_keeps_the_drive_and_scales_absolute_pressures() -> None:
    base = parse_scenario('duration_s: 20\nspeed: {initial_kmh: 80}\nevents:\n'
                          '  - {type: pressure_step, at_s: 5, tires: FL, to_kpa: 170}\n')
    car = sample_car(21_002)
    moved = apply_car(base, car)
    assert moved.speed_segments == base.speed_segments
    assert moved.initial_speed_kmh == base.initial_speed_kmh
    assert moved.vehicle == car.vehicle and moved.sensors == car.sensors
    assert moved.events[0].to_kpa == pytest.approx(170.0 * car.placard_kpa / 200.0)


def test_all_wheel_drive_and_tire_spread_reach_the_wheels() -> None:
    """AWD: driveline modes on both axles; tire spread: the four resonances differ."""
    car = next(c for c in (sample_car(s) for s in TUNING_SEEDS + HELD_OUT_SEEDS)
               if c.layout == 'all')
    scenario = car_scenario(car, 'rural', 20.0)
    scenario = dataclasses.replace(scenario, speed_segments=(), steer_segments=())
    result = simulate_scenario(scenario, kinematic_handling)
    assert np.all(np.isfinite(result.wheel_speed))
    assert np.ptp(result.resonance_hz[0]) > 0.0
    rear_only = dataclasses.replace(
        scenario, driveline=dataclasses.replace(scenario.driveline, wheels='driven'))
    rear = simulate_scenario(rear_only, kinematic_handling)
    mode = scenario.driveline.modes[0].frequency_hz
    # The front axle carries a driveline mode only when all four wheels are driven.
    assert _band(result, 0, mode) > 2.0 * _band(rear, 0, mode)
