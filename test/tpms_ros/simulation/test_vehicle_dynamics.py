"""Tests of the 14-DOF handling truth: steady states against closed-form formulas, energy,
determinism, step-size convergence, bad input and the Kim & Huh seed scenario."""

from __future__ import annotations

from dataclasses import replace
import math

import numpy as np
import pytest

from tpms_ros.simulation.vehicle_dynamics import (
    GRAVITY,
    HandlingInputs,
    HandlingResult,
    VehicleParams,
    max_stable_step,
    simulate_handling,
)

DT = 1e-3
PARAMS = VehicleParams()
# The bicycle model and the static load-transfer formula have no rolling resistance or drag;
# switching them off removes the small yaw moment that rolling resistance makes under lateral
# load transfer (it adds ~4 % understeer at the default f_r = 0.012).
PARAMS_NO_RESIST = replace(PARAMS, rolling_resistance=0.0, drag_area=0.0)


def _inputs(duration: float, steer: np.ndarray | float = 0.0,
            speed_target: np.ndarray | float = math.nan, torque_offset: np.ndarray | None = None,
            friction: np.ndarray | float = 1.0, added_mass: float = 0.0,
            dt: float = DT) -> HandlingInputs:
    """Inputs on a uniform grid; scalars are held constant."""
    t = np.arange(0.0, duration, dt)
    n = t.size
    offset = np.zeros((n, 4)) if torque_offset is None else np.asarray(torque_offset)
    return HandlingInputs(
        t=t, steer=np.broadcast_to(steer, (n,)).astype(float),
        speed_target=np.broadcast_to(speed_target, (n,)).astype(float),
        torque_offset=np.broadcast_to(offset, (n, 4)).astype(float),
        friction_scale=np.broadcast_to(friction, (n,)).astype(float),
        rolling_radius=np.full((n, 4), PARAMS.rw), added_mass=added_mass)


@pytest.fixture(scope='module')
def steady_turns() -> list[tuple[float, HandlingResult]]:
    """Constant-steer runs (0.5 deg) at three speeds, speed held by the controller."""
    runs = []
    for speed in (15.0, 20.0, 25.0):
        res = simulate_handling(PARAMS_NO_RESIST,
                                _inputs(7.0, math.radians(0.5), speed), speed)
        runs.append((math.radians(0.5), res))
    return runs


def test_defaults_are_spec_values() -> None:
    """VehicleParams defaults are the Ford FC/HVE data of
    docs/methods/lateral_force_observer.md."""
    spec = dict(m=1814.0, ms=1661.0, iz=2560.0, ix=580.0, iw=2.0, lf=1.076, lr=1.617, h=0.55,
                hf=0.114, hr=0.004, e=0.48, rw=0.305, tf=0.784, tr=0.760, kphi_f=108205.8,
                kphi_r=81436.7, cphi_f=826.8, cphi_r=658.9)
    for name, value in spec.items():
        assert getattr(PARAMS, name) == value, name
    assert PARAMS.unsprung_corner_masses.sum() == pytest.approx(1814.0 - 1661.0)


def test_straight_run_stays_straight() -> None:
    """Straight at constant target speed: vy and yaw rate stay 0, speed and loads stay put."""
    res = simulate_handling(PARAMS, _inputs(5.0, 0.0, 20.0), 20.0)
    assert np.max(np.abs(res.vy)) < 1e-9
    assert np.max(np.abs(res.yaw_rate)) < 1e-9
    assert np.max(np.abs(res.roll)) < 1e-9
    assert np.max(np.abs(res.vx - 20.0)) < 0.01
    static = PARAMS.static_wheel_loads()
    # Drag at the CG and drive at the ground shift < 1 % of the load front to rear.
    assert np.max(np.abs(res.fz / static - 1.0)) < 0.01
    # Starts in steady state: the first 0.5 s already within 0.2 % of the final wheel speeds.
    np.testing.assert_allclose(res.omega[:500], np.broadcast_to(res.omega[-1], (500, 4)),
                               rtol=2e-3)


def test_understeer_gradient_matches_bicycle_model(
        steady_turns: list[tuple[float, HandlingResult]]) -> None:
    """delta - L/R = K ay with K = m_f / C_f - m_r / C_r from the same tires at static load,
    within 2 % (ay 0.6 ... 1.3 m/s^2)."""
    p = PARAMS_NO_RESIST
    wheelbase = p.lf + p.lr
    c_axle = 2.0 * p.tire.cornering_stiffness(p.static_wheel_loads())
    k_bicycle = (p.m * p.lr / wheelbase / c_axle[0]) - (p.m * p.lf / wheelbase / c_axle[2])
    assert k_bicycle > 0.0  # this car understeers
    for delta, res in steady_turns:
        vx = res.vx[-1000:].mean()
        r = res.yaw_rate[-1000:].mean()
        assert res.yaw_rate[-1000:].std() < 1e-4 * abs(r)  # truly steady
        k_sim = (delta - wheelbase * r / vx) / (vx * r)
        assert k_sim == pytest.approx(k_bicycle, rel=0.02)


def _static_load_transfer(p: VehicleParams, ay: float) -> tuple[float, float]:
    """Per-axle half left-right load difference in a steady turn, from statics.

    Roll moment of the sprung mass about the roll axis (including gravity on the rolled CG)
    balanced by the two axles' roll stiffness acting on body-minus-axle roll; each axle's tire
    load difference = its elastic moment + link force at its roll centre + unsprung inertia;
    the axles roll on the tire vertical stiffness.
    """
    wheelbase = p.lf + p.lr
    mu = p.unsprung_corner_masses
    mu_f, mu_r = 2 * mu[0], 2 * mu[2]
    geo_f = (p.m * ay * p.lr / wheelbase - mu_f * ay) * p.hf + mu_f * ay * p.rw
    geo_r = (p.m * ay * p.lf / wheelbase - mu_r * ay) * p.hr + mu_r * ay * p.rw
    kf, kr = p.kphi_f, p.kphi_r
    # unknowns: body roll phi, front axle roll phi_f, rear axle roll phi_r
    a = np.array([
        [kf + kr - p.ms * GRAVITY * p.e, -kf, -kr],
        [-kf, kf + 2 * p.kt * p.tf**2, 0.0],
        [-kr, 0.0, kr + 2 * p.kt * p.tr**2],
    ])
    b = np.array([p.ms * p.e * ay, geo_f, geo_r])
    _, phi_f, phi_r = np.linalg.solve(a, b)
    return p.kt * p.tf * phi_f, p.kt * p.tr * phi_r


def test_lateral_load_transfer_matches_static_formula(
        steady_turns: list[tuple[float, HandlingResult]]) -> None:
    """Steady-turn load transfer per axle equals the static formula within 0.2 %; the simple
    textbook formula (m ay h / track, split by roll stiffness) holds within 6 % per axle (it
    ignores roll centres and tire roll) and 3 % for the sum of the two axles' moments."""
    p = PARAMS_NO_RESIST
    share_f = p.kphi_f / (p.kphi_f + p.kphi_r)
    for _, res in steady_turns:
        ay = float(np.mean(res.vx[-1000:] * res.yaw_rate[-1000:]))
        fz = res.fz[-1000:].mean(axis=0)
        d_front = 0.5 * (fz[1] - fz[0])  # right (outer in a left turn) minus left
        d_rear = 0.5 * (fz[3] - fz[2])
        exp_front, exp_rear = _static_load_transfer(p, ay)
        assert d_front == pytest.approx(exp_front, rel=2e-3)
        assert d_rear == pytest.approx(exp_rear, rel=2e-3)
        # Half the left-right difference: moment share / half track / 2 wheels.
        simple_f = p.m * ay * p.h * share_f / (2 * p.tf)
        simple_r = p.m * ay * p.h * (1 - share_f) / (2 * p.tr)
        assert d_front == pytest.approx(simple_f, rel=0.06)
        assert d_rear == pytest.approx(simple_r, rel=0.06)
        total_moment = 2 * d_front * p.tf + 2 * d_rear * p.tr
        assert total_moment == pytest.approx(p.m * ay * p.h, rel=0.03)
        # Total vertical load = weight.
        assert fz.sum() == pytest.approx(p.m * GRAVITY, rel=1e-3)


def test_coast_down_loses_energy_monotonically() -> None:
    """No torque from 25 m/s: kinetic energy of car and wheels falls at every step, at a rate
    that matches drag + rolling resistance."""
    res = simulate_handling(PARAMS, _inputs(20.0), 25.0)
    energy = (0.5 * res.mass * (res.vx**2 + res.vy**2) + 0.5 * PARAMS.iz * res.yaw_rate**2
              + 0.5 * PARAMS.iw * np.sum(res.omega**2, axis=1))
    assert np.all(np.diff(energy) < 0.0)
    # Initial deceleration from the resistances alone (inertia incl. the wheels' spin).
    v = float(res.vx[1000])
    resist = 0.5 * PARAMS.air_density * PARAMS.drag_area * v**2 + \
        PARAMS.rolling_resistance * PARAMS.m * GRAVITY
    decel = resist / (PARAMS.m + 4 * PARAMS.iw / PARAMS.rw**2)
    measured = -(res.vx[1500] - res.vx[500]) / 1.0
    assert measured == pytest.approx(decel, rel=0.03)
    assert res.vx[-1] < res.vx[0] and np.all(res.omega > 0.0)


def test_same_inputs_same_output() -> None:
    """Deterministic: two runs of the same inputs are bit-identical."""
    rng = np.random.default_rng(11)
    n = 3000
    steer = np.cumsum(rng.normal(0.0, 2e-4, n))
    inp = _inputs(n * DT, steer, 20.0, friction=np.linspace(1.1, 0.5, n))
    a = simulate_handling(PARAMS, inp, 20.0)
    b = simulate_handling(PARAMS, inp, 20.0)
    for name in ('omega', 'wheel_torque', 'vx', 'vy', 'yaw_rate', 'roll', 'ax', 'ay', 'fx',
                 'fy', 'fz'):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name


def test_step_size_convergence() -> None:
    """A 2 deg step steer at 20 m/s: dt = 1 ms agrees with dt = 0.25 ms within 1 % of the peak
    (yaw rate, lateral acceleration, roll)."""
    steer_fn = lambda t: math.radians(2.0) * (t >= 0.5)  # noqa: E731
    coarse_in = _inputs(3.0, 0.0, 20.0)
    fine_in = _inputs(3.0, 0.0, 20.0, dt=2.5e-4)
    coarse = simulate_handling(PARAMS, replace(coarse_in, steer=steer_fn(coarse_in.t)), 20.0)
    fine = simulate_handling(PARAMS, replace(fine_in, steer=steer_fn(fine_in.t)), 20.0)
    for name in ('yaw_rate', 'ay', 'roll'):
        c = getattr(coarse, name)
        f = getattr(fine, name)[::4]
        assert np.max(np.abs(c - f)) < 0.01 * np.max(np.abs(f)), name


def test_unstable_step_refused() -> None:
    """A step above the stability limit of the fastest mode is refused, naming the step."""
    limit = max_stable_step(PARAMS)
    assert 1e-3 < limit < 0.01
    with pytest.raises(ValueError, match='step'):
        simulate_handling(PARAMS, _inputs(1.0, dt=2.0 * limit), 20.0)


def test_kim_huh_scenario_runs_with_plausible_forces() -> None:
    """70 km/h, steer 1 -> 2 deg, brake 60 N m front / 40 N m rear per wheel, friction
    1.1 -> 0.2, +200 kg: finite, loads sum to the weight, forces within the friction limit,
    cornering builds with the steer step and collapses on ice."""
    v0 = 70.0 / 3.6
    t = np.arange(0.0, 10.0, DT)
    steer = np.radians(np.where(t < 3.0, 1.0, 2.0))
    friction = np.where(t < 6.0, 1.1, 0.2)
    brake = np.array([-60.0, -60.0, -40.0, -40.0])
    inp = _inputs(10.0, steer, math.nan, brake, friction, added_mass=200.0)
    res = simulate_handling(PARAMS, inp, v0)
    assert res.mass == pytest.approx(2014.0)
    for name in ('omega', 'fx', 'fy', 'fz', 'vx', 'ay'):
        assert np.all(np.isfinite(getattr(res, name))), name
    np.testing.assert_allclose(res.wheel_torque, np.broadcast_to(brake, res.wheel_torque.shape))
    assert np.all(res.fz > 0.0)
    np.testing.assert_allclose(res.fz.sum(axis=1).mean(), 2014.0 * GRAVITY, rtol=5e-3)
    # Resultant per tire within the road's peak friction (plus the 6 % combined-slip margin).
    ratio = np.hypot(res.fx, res.fy) / (res.fz * friction[:, None])
    assert ratio.max() < 1.25  # MF peak D/Fz of this tire is up to ~1.1 at light load
    dry1 = slice(2000, 3000)
    dry2 = slice(5000, 6000)
    ice = slice(9000, 10000)
    assert res.yaw_rate[dry2].mean() > 1.7 * res.yaw_rate[dry1].mean() > 0.0
    assert np.abs(res.ay[ice]).mean() < 0.25 * GRAVITY < res.ay[dry2].mean()
    # Braking: every wheel's Fx negative, speed falls.
    assert np.all(res.fx[dry1] < 0.0) and res.vx[-1] < res.vx[0] - 2.0


def test_brake_stops_the_car_without_reversing() -> None:
    """A hard brake torque from 10 m/s stops wheels and car; no wheel spins backwards and the
    car only rocks back (tire deflection / transient slip unwinding) by < 0.15 m/s."""
    brake = np.array([-900.0, -900.0, -500.0, -500.0])
    res = simulate_handling(PARAMS, _inputs(6.0, 0.0, math.nan, brake), 10.0)
    assert np.all(res.omega >= 0.0)
    assert abs(res.vx[-1]) < 1e-3 and np.min(res.vx) > -0.15
    assert res.ax.min() < -0.6 * GRAVITY  # strong deceleration happened


@pytest.mark.parametrize('axle, driven', [('front', [0, 1]), ('rear', [2, 3])])
def test_driven_axle_parameter(axle: str, driven: list[int]) -> None:
    """The controller drives only the chosen axle and reaches the target speed."""
    p = replace(PARAMS, driven_axle=axle)
    res = simulate_handling(p, _inputs(12.0, 0.0, 22.0), 20.0)
    undriven = [i for i in range(4) if i not in driven]
    assert np.all(res.wheel_torque[:, undriven] == 0.0)
    assert np.all(res.wheel_torque[:2000, driven] > 50.0)
    assert res.vx[-1] == pytest.approx(22.0, abs=0.3)


@pytest.mark.parametrize('field_name, value', [
    ('m', -1.0), ('ms', 2000.0), ('kphi_f', 0.0), ('driven_axle', 'all'), ('iw', math.nan),
    ('brake_front_share', 1.5), ('tf', 'wide'),
])
def test_invalid_params_raise(field_name: str, value: object) -> None:
    """Non-physical parameters are refused with the field's name."""
    with pytest.raises(ValueError, match=field_name):
        VehicleParams(**{field_name: value})


def test_invalid_inputs_raise() -> None:
    """Wrong shapes, NaN, non-uniform time, bad friction/radius/speed are refused by name."""
    good = _inputs(0.1)
    n = good.t.size
    with pytest.raises(ValueError, match='steer'):
        replace(good, steer=np.zeros(n - 1))
    with pytest.raises(ValueError, match='torque_offset'):
        replace(good, torque_offset=np.full((n, 4), math.nan))
    with pytest.raises(ValueError, match='friction_scale'):
        replace(good, friction_scale=np.zeros(n))
    with pytest.raises(ValueError, match='rolling_radius'):
        replace(good, rolling_radius=np.zeros((n, 3)))
    with pytest.raises(ValueError, match='t must'):
        replace(good, t=good.t ** 1.5)
    with pytest.raises(ValueError, match='added_mass'):
        replace(good, added_mass=-5.0)
    with pytest.raises(ValueError, match='initial_speed'):
        simulate_handling(PARAMS, good, -1.0)
