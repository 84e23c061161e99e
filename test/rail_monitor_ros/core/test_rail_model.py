"""Tests of the lateral rail vehicle models (rail_model) and the track spectrum."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest
import scipy.signal

from rail_monitor_ros.core.rail_model import (
    RailVehicleParams,
    critical_speed,
    discretize_zoh,
    discretize_zoh_sensitivity,
    free_wheelset_state_space,
    full_car_state_space,
    half_car_creep_sensitivity,
    half_car_state_space,
    klingel_frequency,
    max_real_eigenvalue,
    modal_frequencies,
    reduced_bogie_body_model,
    vehicle_modes,
    wheelset_inputs_from_track,
)
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from rail_monitor_ros.simulation.track_profile import generate_track_profile

PARAMS = RailVehicleParams()


@pytest.mark.parametrize('creep_factor', [1.0, 0.6, 0.4])
@pytest.mark.parametrize('model', ['half', 'full'])
def test_stable_at_the_papers_speed(model: str, creep_factor: float) -> None:
    """At 40 m/s every eigenvalue of the half and full car lies in the left half plane."""
    assert max_real_eigenvalue(PARAMS, creep_factor, model) < -0.5


def test_free_wheelset_kinematic_frequency_matches_klingel() -> None:
    """The free wheelset's oscillation is Klingel's v/(2 pi) sqrt(lambda/(r0 l0)).

    With the paper's creep coefficients inertia lowers it by about 2 %; with ten times the creep
    stiffness (the kinematic limit) it converges to the formula.
    """
    klingel = klingel_frequency(PARAMS)
    assert klingel == pytest.approx(4.6805, rel=1e-4)
    nominal, _ = modal_frequencies(free_wheelset_state_space(PARAMS, 1.0).a)
    stiff, stiff_damping = modal_frequencies(free_wheelset_state_space(PARAMS, 10.0).a)
    # Pick the mode nearest the formula (the other pair is a fast, heavily damped creep mode).
    nominal_mode = nominal[np.argmin(np.abs(nominal - klingel))]
    stiff_mode = stiff[np.argmin(np.abs(stiff - klingel))]
    assert nominal_mode == pytest.approx(klingel, rel=0.03)
    assert stiff_mode == pytest.approx(klingel, rel=1e-3)
    # The unsuspended wheelset is unstable (negative damping): inertia feeds the hunting.
    assert np.min(stiff_damping) < 0.0


def test_kinematic_frequency_scales_with_speed() -> None:
    """Doubling the speed doubles the kinematic frequency: the kinematic wavelength is fixed."""
    slow = PARAMS.with_speed(20.0)
    fast = PARAMS.with_speed(40.0)
    f_slow = modal_frequencies(free_wheelset_state_space(slow, 10.0).a)[0]
    f_fast = modal_frequencies(free_wheelset_state_space(fast, 10.0).a)[0]
    k_slow = f_slow[np.argmin(np.abs(f_slow - klingel_frequency(slow)))]
    k_fast = f_fast[np.argmin(np.abs(f_fast - klingel_frequency(fast)))]
    assert k_fast / k_slow == pytest.approx(2.0, rel=2e-3)


def test_critical_speed_of_the_bogie() -> None:
    """The bogie hunts above a finite critical speed, well above the paper's 40 m/s.

    The crossing is real: 1 % below it the model is stable, 1 % above unstable.
    """
    v_half = critical_speed(PARAMS, model='half', tolerance=1e-3)
    v_full = critical_speed(PARAMS, model='full', tolerance=1e-3)
    assert 45.0 < v_half < 150.0
    assert v_full == pytest.approx(v_half, rel=0.03)
    assert max_real_eigenvalue(PARAMS.with_speed(0.99 * v_half)) < 0.0
    assert max_real_eigenvalue(PARAMS.with_speed(1.01 * v_half)) > 0.0


def test_body_modes_where_the_parameters_put_them() -> None:
    """The body lateral mode sits near sqrt(Ksy_total / M) and the body yaw mode near
    sqrt(2 Ksy lv^2 / Iv) (rigid bogies; the primary suspension in series lowers them a little).
    """
    modes = vehicle_modes(full_car_state_space(PARAMS), PARAMS)
    lateral = [m for m in modes if m.coordinate == 'y_v']
    yaw = [m for m in modes if m.coordinate == 'psi_v']
    assert len(lateral) == 1 and len(yaw) == 1
    ksy = PARAMS.secondary_lateral_stiffness
    f_lateral = math.sqrt(2.0 * ksy / PARAMS.full_body_mass) / (2.0 * math.pi)
    f_yaw = math.sqrt(2.0 * ksy * PARAMS.bogie_pivot_semi_spacing ** 2
                      / PARAMS.body_yaw_inertia) / (2.0 * math.pi)
    undamped = lateral[0].frequency_hz / math.sqrt(1.0 - lateral[0].damping_ratio ** 2)
    assert undamped == pytest.approx(f_lateral, rel=0.06)
    undamped_yaw = yaw[0].frequency_hz / math.sqrt(1.0 - yaw[0].damping_ratio ** 2)
    assert undamped_yaw == pytest.approx(f_yaw, rel=0.06)
    # A stiffer secondary spring raises the body lateral mode.
    stiff = vehicle_modes(full_car_state_space(PARAMS, 1.0, (1.5, 1.5)), PARAMS)
    assert [m for m in stiff if m.coordinate == 'y_v'][0].frequency_hz > lateral[0].frequency_hz


def test_full_car_is_two_half_cars_at_unit_dynamic_index() -> None:
    """With body yaw inertia M lv^2 and no anti-yaw coupling, the full car splits into two half
    cars: its eigenvalues are the half car's, each twice. Checks both assemblies agree."""
    p = dataclasses.replace(
        PARAMS, body_yaw_inertia=2.0 * PARAMS.body_mass * PARAMS.bogie_pivot_semi_spacing ** 2,
        anti_yaw_damping_left=0.0, anti_yaw_damping_right=0.0)
    full = np.linalg.eigvals(full_car_state_space(p, 0.7, (1.3, 1.3), (0.6, 0.6)).a)
    half = np.linalg.eigvals(half_car_state_space(p, 0.7, 1.3, 0.6).a)
    doubled = np.concatenate([half, half])

    def ordered(values: np.ndarray) -> np.ndarray:
        # Rounded keys, so pairs equal to rounding error sort the same way.
        return values[np.lexsort((np.round(values.imag, 5), np.round(values.real, 5)))]

    np.testing.assert_allclose(ordered(full), ordered(doubled), rtol=1e-7, atol=1e-7)


def test_half_car_follows_the_spec_equations() -> None:
    """Spot checks of the assembled half car against docs/methods/creep_estimator.md, term by
    term."""
    c, sr, dr = 0.8, 1.2, 0.7
    model = half_car_state_space(PARAMS, c, sr, dr)
    a, b, names = model.a, model.b, model.state_names
    p = PARAMS

    def coef(row: str, col: str) -> float:
        return float(a[names.index(row), names.index(col)])

    assert coef('dy_w1', 'dy_w1') == pytest.approx(-2 * c * p.lateral_creep_coefficient
                                                   / p.speed / p.wheelset_mass)
    assert coef('dy_w1', 'psi_w1') == pytest.approx(2 * c * p.lateral_creep_coefficient
                                                    / p.wheelset_mass)
    assert coef('dy_w1', 'psi_b') == pytest.approx(p.primary_lateral_stiffness
                                                   * p.semi_wheelbase / p.wheelset_mass)
    assert coef('dy_w2', 'psi_b') == pytest.approx(-p.primary_lateral_stiffness
                                                   * p.semi_wheelbase / p.wheelset_mass)
    yaw_creep = (2 * c * p.longitudinal_creep_coefficient * p.conicity * p.half_gauge
                 / p.wheel_radius)
    assert coef('dpsi_w1', 'y_w1') == pytest.approx(-yaw_creep / p.wheelset_yaw_inertia)
    assert b[names.index('dpsi_w1'), 0] == pytest.approx(yaw_creep / p.wheelset_yaw_inertia)
    assert b[names.index('dpsi_w1'), 1] == 0.0
    assert coef('dy_b', 'y_v') == pytest.approx(sr * p.secondary_lateral_stiffness / p.bogie_mass)
    assert coef('dy_v', 'dy_b') == pytest.approx(dr * p.secondary_lateral_damping / p.body_mass)
    assert coef('dpsi_b', 'psi_b') == pytest.approx(
        -(2 * p.primary_lateral_stiffness * p.semi_wheelbase ** 2 + 2 * p.primary_yaw_stiffness)
        / p.bogie_yaw_inertia)
    assert coef('dpsi_b', 'dpsi_b') == pytest.approx(-p.anti_yaw_damping / p.bogie_yaw_inertia)


def test_creep_sensitivity_is_exact() -> None:
    """A(c) = A(1) + (c - 1) dA/dc and B(c) = c dB/dc; the discrete derivative matches central
    differences of the ZOH model."""
    da, db = half_car_creep_sensitivity(PARAMS, 1.1, 0.9)
    one = half_car_state_space(PARAMS, 1.0, 1.1, 0.9)
    low = half_car_state_space(PARAMS, 0.4, 1.1, 0.9)
    np.testing.assert_allclose(low.a, one.a - 0.6 * da, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(low.b, 0.4 * db, rtol=1e-12)
    dt, eps = 0.005, 1e-6
    f, g, df, dg = discretize_zoh_sensitivity(one.a, one.b, da, db, dt)
    f_hi, g_hi = discretize_zoh(one.a + eps * da, one.b + eps * db, dt)
    f_lo, g_lo = discretize_zoh(one.a - eps * da, one.b - eps * db, dt)
    np.testing.assert_allclose(df, (f_hi - f_lo) / (2 * eps), rtol=1e-5, atol=1e-8)
    np.testing.assert_allclose(dg, (g_hi - g_lo) / (2 * eps), rtol=1e-5, atol=1e-10)
    np.testing.assert_allclose(f, discretize_zoh(one.a, one.b, dt)[0])


def test_zoh_matches_scipy_cont2discrete() -> None:
    """discretize_zoh and StateSpace.discretize agree with scipy.signal.cont2discrete."""
    model = reduced_bogie_body_model(PARAMS, 1.5, 0.5)
    disc = model.discretize(0.005)
    f_ref, g_ref, *_ = scipy.signal.cont2discrete((model.a, model.b, model.c, model.d), 0.005,
                                                  method='zoh')
    np.testing.assert_allclose(disc.f, f_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(disc.g, g_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(disc.h, model.c)


def test_reduced_model_reproduces_the_half_car_bogie_and_body_rows() -> None:
    """With the wheelset states as inputs, the reduced IMM model gives exactly the half car's
    bogie/body derivatives and sensor outputs, for any state."""
    rng = np.random.default_rng(4)
    sr, dr = 1.4, 0.6
    half = half_car_state_space(PARAMS, 0.9, sr, dr, pattern='D')
    reduced = reduced_bogie_body_model(PARAMS, sr, dr)
    for _ in range(5):
        x = rng.normal(size=14) * 1e-3
        u_track = rng.normal(size=2) * 1e-3
        x_dot = half.a @ x + half.b @ u_track
        y_half = half.c @ x + half.d @ u_track
        xr = x[[half.state_index(n) for n in reduced.state_names]]
        ur = x[[half.state_index(n) for n in reduced.input_names]]
        xr_dot = reduced.a @ xr + reduced.b @ ur
        np.testing.assert_allclose(
            xr_dot, x_dot[[half.state_index(n) for n in reduced.state_names]], rtol=1e-10)
        np.testing.assert_allclose(reduced.c @ xr + reduced.d @ ur, y_half, rtol=1e-10)


def test_observation_patterns() -> None:
    """Patterns A-C select the papers' states; D gives the sensors (no direct track term)."""
    sizes = {p: half_car_state_space(PARAMS, pattern=p).c.shape for p in 'ABCD'}
    assert sizes == {'A': (14, 14), 'B': (6, 14), 'C': (4, 14), 'D': (3, 14)}
    c_pattern = half_car_state_space(PARAMS, pattern='C')
    assert c_pattern.output_names == ('y_b', 'dy_b', 'y_v', 'dy_v')
    d_pattern = half_car_state_space(PARAMS, pattern='D')
    assert np.all(d_pattern.d == 0.0)
    with pytest.raises(ValueError, match='pattern'):
        half_car_state_space(PARAMS, pattern='E')


def test_wheelset_inputs_from_track() -> None:
    """Kinematic following: y_w = y_r, psi_w = y_r' / v; without rates the yaw inputs are 0."""
    y = np.array([[1e-3, -2e-3], [0.0, 5e-4]])
    rate = np.array([[4e-2, 0.0], [-8e-2, 2e-2]])
    u = wheelset_inputs_from_track(y, rate, 40.0)
    np.testing.assert_allclose(u, [[1e-3, -2e-3, 1e-3, 0.0], [0.0, 5e-4, -2e-3, 5e-4]])
    assert np.all(wheelset_inputs_from_track(y, None, 40.0)[:, 2:] == 0.0)
    with pytest.raises(ValueError, match='speed'):
        wheelset_inputs_from_track(y, rate, 0.0)


@pytest.mark.parametrize('field, value', [
    ('wheelset_mass', -1.0), ('bogie_mass', 0.0), ('body_yaw_inertia', 0.0),
    ('primary_lateral_stiffness', -4e6), ('secondary_lateral_stiffness_left', 0.0),
    ('conicity', 0.0), ('conicity', -0.1), ('speed', 0.0), ('speed', -40.0),
    ('secondary_lateral_damping_left', -1.0), ('wheel_radius', math.nan),
])
def test_non_physical_parameters_are_refused(field: str, value: float) -> None:
    """Non-physical parameters raise ValueError naming the field."""
    with pytest.raises(ValueError, match=field):
        RailVehicleParams(**{field: value})


@pytest.mark.parametrize('kwargs, name', [
    ({'creep_factor': 0.0}, 'creep_factor'), ({'creep_factor': 2.5}, 'creep_factor'),
    ({'spring_ratio': 0.0}, 'spring_ratio'), ({'spring_ratio': 5.5}, 'spring_ratio'),
    ({'damper_ratio': -0.5}, 'damper_ratio'), ({'damper_ratio': math.inf}, 'damper_ratio'),
])
def test_ratios_outside_the_sane_range_are_refused(kwargs: dict[str, Any], name: str) -> None:
    """Creep factor outside (0, 2] and suspension ratios outside (0, 5] are refused by name."""
    with pytest.raises(ValueError, match=name):
        half_car_state_space(PARAMS, **kwargs)
    with pytest.raises(ValueError, match='spring_ratio'):
        full_car_state_space(PARAMS, spring_ratio=(1.0, 1.0, 1.0))


def test_track_profile_has_the_published_spectrum() -> None:
    """The generated alignment has the German low-interference PSD in the band and its variance
    (closed form), and the same seed gives the same profile."""
    spectrum = TRACK_SPECTRA['german_low']
    profile = generate_track_profile(spectrum, 0.0, 20000.0, np.random.default_rng(1))
    again = generate_track_profile(spectrum, 0.0, 20000.0, np.random.default_rng(1))
    np.testing.assert_array_equal(profile.alignment, again.alignment)
    freq, psd = scipy.signal.welch(profile.alignment, fs=1.0 / profile.spacing, nperseg=4096)
    omega = 2.0 * math.pi * freq
    band = (omega > 0.2) & (omega < 5.0)
    # Welch gives a density per cycle/m; the spectrum is per rad/m.
    ratio = psd[band] / (2.0 * math.pi) / spectrum.psd(omega[band])
    assert np.exp(np.mean(np.log(ratio))) == pytest.approx(1.0, rel=0.1)
    sigma = math.sqrt(spectrum.variance(1.0, 120.0))
    assert sigma == pytest.approx(1.86e-3, rel=0.01)
    assert np.std(profile.alignment) == pytest.approx(sigma, rel=0.15)
