"""Tests of the road scenario schema: loading, validation errors, and the sampled profiles."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from tpms_ros.simulation.road_scenario import (
    DEFAULT_STIFFNESS_PRESSURE_SLOPE,
    Scenario,
    TireSpec,
    friction_multiplier,
    load_scenario,
    parse_scenario,
    road_surface,
    speed_target,
    steering_angle,
    tire_pressure,
)

SCENARIO_DIR = Path(__file__).resolve().parents[3] / 'src' / 'tpms_ros' / 'scenarios'
SHIPPED = sorted(SCENARIO_DIR.glob('*.yaml'))


def _scenario(body: str, duration: float = 100.0) -> Scenario:
    return parse_scenario(f'seed: 5\nduration_s: {duration}\n' + body, source='test.yaml')


@pytest.mark.parametrize('path', SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_scenarios_load(path: Path) -> None:
    """Every shipped scenario file passes validation and names itself after its file."""
    scenario = load_scenario(path)
    assert scenario.name == path.stem
    assert scenario.duration_s > 0.0


def test_shipped_set_covers_the_brief() -> None:
    """The shipped set has the Umeno, diffusion, puncture and Kim-Huh scenarios with their
    defining settings."""
    names = {p.stem for p in SHIPPED}
    for speed in (60, 90):
        for surface in ('smooth_asphalt', 'rough_concrete'):
            assert f'umeno_step_{speed}kmh_{surface}' in names
    umeno = load_scenario(SCENARIO_DIR / 'umeno_step_60kmh_rough_concrete.yaml')
    end = tire_pressure(umeno, np.array([umeno.duration_s]))[0]
    np.testing.assert_allclose(end, [200.0, 120.0, 120.0, 200.0])
    for pct in (15, 25):
        diffusion = load_scenario(SCENARIO_DIR / f'diffusion_{pct}pct.yaml')
        end = tire_pressure(diffusion, np.array([diffusion.duration_s]))[0]
        np.testing.assert_allclose(end, 200.0 * (1.0 - pct / 100.0))
    puncture = load_scenario(SCENARIO_DIR / 'puncture_15pct_fl.yaml')
    np.testing.assert_allclose(tire_pressure(puncture, np.array([puncture.duration_s]))[0],
                               [170.0, 200.0, 200.0, 200.0])
    kim = load_scenario(SCENARIO_DIR / 'kim_huh_lateral.yaml')
    assert kim.added_mass_kg == 200.0
    assert kim.torque_offset_nm == (-60.0, -60.0, -40.0, -40.0)
    t = np.array([0.5, 9.5])
    np.testing.assert_allclose(np.degrees(steering_angle(kim, t)), [1.0, 2.0])
    _, surface_mu = road_surface(kim, t)
    np.testing.assert_allclose(surface_mu * friction_multiplier(kim, t), [1.1, 0.2])
    relation = load_scenario(SCENARIO_DIR / 'kim_huh_relation_check.yaml')
    np.testing.assert_allclose(np.degrees(steering_angle(relation, np.array([0.0, 5.0, 10.0]))),
                               [0.0, 2.0, 4.0])


def test_tire_pressure_relations_match_the_paper() -> None:
    """Default tire: 40 Hz at 200 kPa, 35 Hz at 120 kPa (Umeno Fig. 1), and a rolling radius
    0.3 % smaller at 30 % pressure loss."""
    tire = TireSpec()
    np.testing.assert_allclose(tire.resonance_hz(np.array([200.0, 120.0])), [40.0, 35.0],
                               atol=1e-9)
    assert abs(DEFAULT_STIFFNESS_PRESSURE_SLOPE - 0.5859375) < 1e-12
    np.testing.assert_allclose(tire.radius_factor(np.array([200.0, 140.0])), [1.0, 0.997])
    assert tire.nominal_tire.resonance_hz == pytest.approx(40.0)


def test_speed_profile_segments() -> None:
    """hold, ramp, stop_and_go (down to its low speed and back) and coast (NaN) in sequence."""
    scenario = _scenario("""
speed:
  initial_kmh: 36
  segments:
    - {type: hold, duration_s: 10}
    - {type: ramp, to_kmh: 72, duration_s: 10}
    - {type: stop_and_go, low_kmh: 0, period_s: 20, duration_s: 40}
    - {type: coast, duration_s: 10}
""")
    v = speed_target(scenario, np.array([5.0, 15.0, 20.0, 30.0, 40.0, 59.9, 65.0]))
    np.testing.assert_allclose(v[:6], [10.0, 15.0, 20.0, 0.0, 20.0, 20.0], atol=0.01)
    assert math.isnan(v[6])


def test_steering_profile_segments() -> None:
    """step, turn (kinematic atan(L/R)), lane change (one period, back to start) and sine."""
    scenario = _scenario("""
steering:
  initial_deg: 0
  segments:
    - {type: step, to_deg: 2, rise_s: 0.5, duration_s: 10}
    - {type: straight, rise_s: 0.5, duration_s: 10}
    - {type: turn, radius_m: -100, rise_s: 1, duration_s: 10}
    - {type: straight, duration_s: 10}
    - {type: lane_change, amplitude_deg: 1, period_s: 4, duration_s: 10}
    - {type: sine, amplitude_deg: 3, frequency_hz: 0.5, duration_s: 10}
""")
    wheelbase = scenario.vehicle.lf + scenario.vehicle.lr
    angle = np.degrees(steering_angle(scenario, np.array(
        [0.25, 5.0, 15.0, 25.0, 35.0, 41.0, 43.0, 45.0, 50.5])))
    expected_turn = -math.degrees(math.atan(wheelbase / 100.0))
    np.testing.assert_allclose(angle, [1.0, 2.0, 0.0, expected_turn, 0.0, 1.0, -1.0, 0.0, 3.0],
                               atol=1e-9)


def test_pressure_events_compose() -> None:
    """A step, a slow leak that a later step overrides, and a diffusion on all tires give the
    piecewise-linear pressures the schema documents."""
    scenario = _scenario("""
tire: {initial_pressure_kpa: [200, 210, 200, 200]}
events:
  - {type: pressure_step, at_s: 10, tires: FL, to_kpa: 150, duration_s: 10}
  - {type: slow_leak, at_s: 20, tires: [FR], rate_kpa_per_min: 60, to_kpa: 100}
  - {type: pressure_step, at_s: 40, tires: [FR], drop_percent: 10}
  - {type: diffusion, at_s: 60, rate_kpa_per_min: 60, drop_percent: 5}
""")
    p = tire_pressure(scenario, np.array([0.0, 15.0, 30.0, 50.0, 100.0]))
    np.testing.assert_allclose(p[:, 0], [200.0, 175.0, 150.0, 150.0, 142.5])
    np.testing.assert_allclose(p[:, 1], [210.0, 210.0, 200.0, 171.0, 162.45])
    np.testing.assert_allclose(p[:, 2], [200.0, 200.0, 200.0, 200.0, 190.0])


def test_surface_and_friction_segments() -> None:
    """Road segments switch roughness and friction; friction events multiply, with a ramp."""
    scenario = _scenario("""
road:
  segments:
    - {at_s: 0, surface: smooth_asphalt}
    - {at_s: 50, surface: snow, roughness_scale: 2}
events:
  - {type: friction, at_s: 10, scale: 0.5, duration_s: 10}
""")
    t = np.array([5.0, 15.0, 40.0, 60.0])
    psd, mu = road_surface(scenario, t)
    np.testing.assert_allclose(psd, [0.5, 0.5, 0.5, 2.0])
    np.testing.assert_allclose(mu * friction_multiplier(scenario, t), [1.0, 0.75, 0.5, 0.15])


def test_vehicle_overrides_reach_vehicle_params() -> None:
    """Vehicle keys override VehicleParams fields; the rest keep the
    docs/methods/lateral_force_observer.md defaults."""
    scenario = _scenario('vehicle: {driven_axle: front, m: 1900}\nadded_mass_kg: 50\n')
    assert scenario.vehicle.driven_axle == 'front'
    assert scenario.vehicle.m == 1900.0
    assert scenario.vehicle.lf == pytest.approx(1.076)
    assert scenario.added_mass_kg == 50.0


BAD_INPUTS = [
    ('unknown top-level key', 'colour: red\n', r'test\.yaml:3: colour: unknown key'),
    ('unknown nested key', 'tire:\n  j1: 0.8\n  jj2: 0.6\n', r':5: tire\.jj2: unknown key'),
    ('unknown vehicle field', 'vehicle: {wings: 2}\n', r'vehicle\.wings: unknown key'),
    ('negative pressure', 'tire: {initial_pressure_kpa: [200, -5, 200, 200]}\n',
     r'tire\.initial_pressure_kpa: values must be > 0'),
    ('negative event pressure',
     'events:\n  - {type: pressure_step, at_s: 1, tires: FL, to_kpa: -20}\n',
     r':4: events\[0\]\.to_kpa: must be > 0'),
    ('unknown surface', 'road:\n  segments:\n    - {at_s: 0, surface: lava}\n',
     r":5: road\.segments\[0\]\.surface: unknown value 'lava'"),
    ('events out of order',
     'events:\n  - {type: friction, at_s: 20, scale: 0.5}\n'
     '  - {type: friction, at_s: 10, scale: 0.9}\n',
     r':5: events\[1\]\.at_s: events must be in time order'),
    ('road out of order',
     'road:\n  segments:\n    - {at_s: 0, surface: wet}\n    - {at_s: 0, surface: snow}\n',
     r'road\.segments\[1\]\.at_s: road segments must be in time order'),
    ('unstable handling step', 'rates: {handling_hz: 100}\n',
     r'rates\.handling_hz: 100 Hz gives an unstable handling step'),
    ('coarse torsion step', 'rates: {torsion_hz: 800, wheel_speed_hz: 500}\n',
     r'rates\.torsion_hz: 800 Hz is too coarse'),
    ('rate above torsion rate', 'rates: {wheel_speed_hz: 8000}\n',
     r'rates\.wheel_speed_hz: must not exceed torsion_hz'),
    ('coast not last', 'speed:\n  segments:\n    - {type: coast, duration_s: 5}\n'
     '    - {type: hold, duration_s: 5}\n', r'speed\.segments\[0\]\.type: coast must be the last'),
    ('unknown tire', 'events:\n  - {type: slow_leak, at_s: 1, tires: [XX], '
     'rate_kpa_per_min: 1, to_kpa: 150}\n', r"events\[0\]\.tires: unknown tire 'XX'"),
    ('event after the end', 'events:\n  - {type: friction, at_s: 500, scale: 0.5}\n',
     r'events\[0\]\.at_s: is after the end'),
    ('not a number', 'tire: {j1: heavy}\n', r"tire\.j1: must be a number, got 'heavy'"),
    ('duplicate key', 'tire: {j1: 0.8}\ntire: {j2: 0.6}\n', r':4: tire: duplicate key'),
    ('leak without floor', 'events:\n  - {type: slow_leak, at_s: 1, tires: FL, '
     'rate_kpa_per_min: 1}\n', r'events\[0\]\.to_kpa: is required'),
    ('tight turn', 'steering:\n  segments:\n    - {type: turn, radius_m: 1, duration_s: 5}\n',
     r'steering\.segments\[0\]\.radius_m: \|radius\| must be >= the wheelbase'),
    ('bad driven axle', 'vehicle: {driven_axle: middle}\n', r"driven_axle must be 'front'"),
]


@pytest.mark.parametrize(('body', 'pattern'), [(b, p) for _, b, p in BAD_INPUTS],
                         ids=[name for name, _, _ in BAD_INPUTS])
def test_bad_input_is_refused_naming_the_key(body: str, pattern: str) -> None:
    """Each kind of bad input raises ValueError whose message names the file, line and key."""
    with pytest.raises(ValueError, match=pattern):
        _scenario(body)


def test_missing_duration_and_non_mapping_are_refused() -> None:
    """A file without duration_s, or one that is not a mapping, is refused."""
    with pytest.raises(ValueError, match='duration_s: is required'):
        parse_scenario('seed: 1\n', source='x.yaml')
    with pytest.raises(ValueError, match='must be a YAML mapping'):
        parse_scenario('- 1\n- 2\n', source='x.yaml')
