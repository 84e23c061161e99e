"""Tests of the SKFMEC tire lateral force observer (Kim & Huh 2000,
docs/methods/lateral_force_observer.md).

Truth: the 14-DOF vehicle of ``tpms_ros.simulation.vehicle_dynamics`` (combined-slip Magic
Formula tires), through the scenario builders of ``benchmarks/bench_lateral_force_observer.py``.
"""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path
import sys
from typing import Any

import numpy as np
import pytest
from scipy import signal
from scipy.stats import multivariate_normal

from tpms_ros.core.lateral_force_kernel import G, derivative, filter_step, imm_step
from tpms_ros.core.lateral_force_observer import (
    LateralForceObserver,
    ObserverTuningParams,
    ObserverVehicleParams,
    differentiator_coefficients,
    split_lateral,
)
from tpms_ros.offline.lateral_force_tuning import (
    TuningCase,
    fy_error_percent,
)
from vehicle_monitor_common.parameters import build

_BENCH = Path(__file__).resolve().parents[3] / 'benchmarks' / 'bench_lateral_force_observer.py'
_spec = importlib.util.spec_from_file_location('bench_lateral_force_observer', _BENCH)
assert _spec is not None and _spec.loader is not None
bench = importlib.util.module_from_spec(_spec)
sys.modules['bench_lateral_force_observer'] = bench
_spec.loader.exec_module(bench)


@pytest.fixture(scope='module')
def paper_case() -> TuningCase:
    """The paper's worst case: the shipped kim_huh_lateral.yaml through the road simulator."""
    return bench.paper_case()


@pytest.fixture(scope='module')
def nominal_mass_case() -> TuningCase:
    """The same scenario with the truth at the model's mass (for model-mass errors)."""
    return bench.paper_case(added_mass=0.0)


@pytest.fixture(scope='module')
def relation_truth():
    """0 -> 4 deg steer ramp over 10 s at 70 km/h (paper Figs. 3-4)."""
    return bench.relation_truth()


def _axle_error_percent(track, fy_true: np.ndarray) -> np.ndarray:
    return bench.axle_error_percent(track, fy_true)


@pytest.mark.parametrize(('field', 'value'), [('m', -1.0), ('kphi_f', math.nan),
                                              ('rw', 0.0), ('e', math.inf),
                                              ('split_exponent', 1.5)])
def test_params_reject_non_physical(field: str, value: float) -> None:
    """A non-physical vehicle parameter raises ValueError naming it."""
    with pytest.raises(ValueError, match=field):
        ObserverVehicleParams(**{field: value})


def test_params_reject_sprung_above_total_mass() -> None:
    """ms > m is refused."""
    with pytest.raises(ValueError, match='ms'):
        ObserverVehicleParams(ms=2000.0)


@pytest.mark.parametrize(('field', 'value'), [('q_diag', (1.0,) * 6), ('r_std', (0.1,) * 4),
                                              ('gp', (1.0, math.nan)), ('max_dt_s', -1.0)])
def test_tuning_rejects_bad_values(field: str, value: Any) -> None:
    """Wrong sizes or non-finite filter settings raise ValueError naming the field."""
    with pytest.raises(ValueError, match=field):
        ObserverTuningParams(**{field: value})


def test_params_build_from_flat_values() -> None:
    """Flat values (a params file) set the named fields and leave the rest at the contract
    defaults."""
    params = build(ObserverVehicleParams, {'m': 2000.0, 'unknown': 1.0})
    assert params.m == 2000.0 and params.ms == 1661.0


def test_zeta_is_the_model_steady_state() -> None:
    """In a steady turn with Fyf = z1 phi, Fyr = z2 phi the model's r', p' and vy'+r vx vanish
    consistently: the roll row balances exactly at the zeta the model reports."""
    obs = LateralForceObserver(tuning=ObserverTuningParams(scaled=False))
    params = obs.params
    z1, z2 = params.zeta
    phi = 0.02
    fyf, fyr = z1 * phi, z2 * phi
    assert params.lf * fyf == pytest.approx(params.lr * fyr, rel=1e-12)  # yaw balance
    x = np.array([20.0, 0.0, 0.0, phi, 0.0, fyf, fyr])
    g, jacobian = np.empty(7), np.empty((7, 7))
    derivative(x, np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0]), obs._model, obs._se_inv,
               obs._s_inv, g, jacobian)
    # with r = 0 the lateral row is 2(Fyf + Fyr)/m, and the roll row must then give p' = 0
    # zeta linearises sin(phi): the residual is the phi^3 term, ~1e-5 rad/s^2
    assert g[4] == pytest.approx(0.0, abs=1e-4)
    assert g[2] == pytest.approx(0.0, abs=1e-9)


def _numpy_step(obs: LateralForceObserver, x: np.ndarray, p: np.ndarray, u: np.ndarray,
                dt: float, z: np.ndarray, fx: np.ndarray, c: float, s: float, q: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """One filter step written out with numpy, as the module docstring states it (the
    observer's numpy implementation before the kernel)."""
    v = obs.params
    mse, kphi, cphi = v.ms * v.e, v.kphi_f + v.kphi_r, v.cphi_f + v.cphi_r
    z1, z2 = obs.zeta
    vx, vy, r, phi, pr, fyf, fyr = obs._s_inv * x
    fx1, fx2, fx3, fx4, uc, us, drho = u
    sum_front = us * (fx1 + fx2) + 2.0 * uc * fyf
    f = np.array([
        uc * (fx1 + fx2) - 2.0 * us * fyf + fx3 + fx4 + v.m * r * vy - mse * pr * r,
        sum_front + 2.0 * fyr - v.m * r * vx,
        v.lf * sum_front - 2.0 * v.lr * fyr + v.tf * uc * (fx2 - fx1) + v.tf * us * drho * fyf
        + v.tr * (fx4 - fx3),
        pr,
        v.hf * sum_front + 2.0 * v.hr * fyr - kphi * phi - cphi * pr + mse * G * math.sin(phi)
        + mse * r * vx,
        z1 * pr, z2 * pr])
    jac = np.zeros((7, 7))
    jac[0, [1, 2, 4, 5]] = v.m * r, v.m * vy - mse * pr, -mse * r, -2.0 * us
    jac[1, [0, 2, 5, 6]] = -v.m * r, -v.m * vx, 2.0 * uc, 2.0
    jac[2, [5, 6]] = 2.0 * v.lf * uc + v.tf * us * drho, -2.0 * v.lr
    jac[3, 4] = 1.0
    jac[4, [0, 2, 3, 4, 5, 6]] = (mse * r, mse * vx, -kphi + mse * G * math.cos(phi), -cphi,
                                  2.0 * v.hf * uc, 2.0 * v.hr)
    jac[5, 4], jac[6, 4] = z1, z2
    g = obs._se_inv @ f
    a_dt = (obs._se_inv @ jac) * obs._s_inv[None, :] * dt
    x = x + dt * (g + 0.5 * (a_dt @ g))
    transition = np.eye(7) + a_dt + 0.5 * (a_dt @ a_dt)
    p = transition @ p @ transition.T + q * dt
    xp = obs._s_inv * x
    h = np.zeros((5, 7))
    h[0, 5], h[1, 5], h[1, 6] = -2.0 * s / v.m, 2.0 * c / v.m, 2.0 / v.m
    h[1, 3] = G * math.cos(xp[3])
    h[2, 2] = h[3, 4] = h[4, 0] = 1.0
    z_hat = np.array([(c * (fx[0] + fx[1]) - 2.0 * s * xp[5] + fx[2] + fx[3]) / v.m,
                      (s * (fx[0] + fx[1]) + 2.0 * c * xp[5] + 2.0 * xp[6]) / v.m
                      + G * math.sin(xp[3]), xp[2], xp[4], xp[0]])
    h = h * obs._s_inv[None, :]
    pht = p @ h.T
    gain = np.linalg.solve(h @ pht + obs._r, pht.T).T
    y = z - z_hat
    log_likelihood = multivariate_normal(np.zeros(5), h @ pht + obs._r).logpdf(y)
    i_kh = np.eye(7) - gain @ h
    p = i_kh @ p @ i_kh.T + gain @ obs._r @ gain.T
    return x + gain @ y + (dt * y[2]) * obs._gp, 0.5 * (p + p.T), y, log_likelihood


def _random_step_inputs(obs: LateralForceObserver, rng: np.random.Generator
                        ) -> tuple[np.ndarray, ...]:
    """A state, covariance, held inputs, measurement and Fx of a turn with braking."""
    x = obs._s * np.array([25.0, 0.3, 0.2, 0.03, 0.05, 2500.0, 2200.0]) * (
        1.0 + 0.2 * rng.standard_normal(7))
    root = rng.standard_normal((7, 7))
    p = 0.1 * root @ root.T + np.eye(7)
    u = np.array([*rng.normal(-800.0, 200.0, 4), math.cos(0.05), math.sin(0.05), 0.12])
    z = np.array([-2.0, 4.0, 0.2, 0.05, 25.0]) + 0.1 * rng.standard_normal(5)
    fx = rng.normal(-800.0, 200.0, 4)
    return x, p, u, z, fx


def test_compiled_step_is_the_models_numpy_step() -> None:
    """The compiled EKF step (lateral_force_kernel.filter_step) is the module docstring's
    filter written with numpy: the same state, covariance, residual and its log-likelihood on
    random states in a turn with braking (every term of the model non-zero)."""
    obs = LateralForceObserver()
    rng = np.random.default_rng(17)
    q = obs._qs[-1]
    for _ in range(20):
        x, p, u, z, fx = _random_step_inputs(obs, rng)
        expected_x, expected_p, expected_y, expected_ll = _numpy_step(
            obs, x, p, u, 0.01, z, fx, math.cos(0.06), math.sin(0.06), q)
        y, log_likelihood = np.empty(5), np.empty(1)
        restarted = filter_step(x, p, u, True, 0.01, z, fx, math.cos(0.06), math.sin(0.06),
                                obs._model, obs._se_inv, obs._s, obs._s_inv, q, obs._r,
                                obs._gp, True, obs._p0, y, log_likelihood)
        assert restarted == 0
        np.testing.assert_allclose(x, expected_x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(p, expected_p, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(y, expected_y, rtol=1e-10, atol=1e-12)
        assert log_likelihood[0] == pytest.approx(expected_ll, rel=1e-9)


def test_compiled_imm_cycle_is_the_textbook_one() -> None:
    """lateral_force_kernel.imm_step against the IMM cycle written out with numpy (Blom and
    Bar-Shalom: mix by the switching matrix, filter each mode, weigh by the residuals'
    likelihood, combine), on two modes in random states; and with one mode it is filter_step
    to the bit."""
    obs = LateralForceObserver()
    assert obs._qs.shape[0] == 2 and obs._qs[0, 5, 5] < obs._qs[1, 5, 5]
    rng = np.random.default_rng(23)
    switch = 0.1
    c, s = math.cos(0.06), math.sin(0.06)
    for _ in range(10):
        x0, p0, u, z, fx = _random_step_inputs(obs, rng)
        x1, p1, _, _, _ = _random_step_inputs(obs, rng)
        mu = np.array([0.3, 0.7])
        xs, ps = np.array([x0, x1]), np.array([p0, p1])
        pi = np.array([[1.0 - switch, switch], [switch, 1.0 - switch]])
        prior = pi.T @ mu
        weights = pi * mu[:, None] / prior[None, :]          # [i, j]: mode i's share in j
        expected_x, expected_y, likelihood = [], [], []
        for j in range(2):
            mixed_x = weights[:, j] @ xs
            mixed_p = sum(weights[i, j] * (ps[i] + np.outer(xs[i] - mixed_x, xs[i] - mixed_x))
                          for i in range(2))
            xj, _, yj, llj = _numpy_step(obs, mixed_x, mixed_p, u, 0.01, z, fx, c, s,
                                         obs._qs[j])
            expected_x.append(xj)
            expected_y.append(yj)
            likelihood.append(math.exp(llj))
        expected_mu = prior * np.array(likelihood) / (prior @ np.array(likelihood))
        y, combined = np.empty(5), np.empty(7)
        restarted = imm_step(xs, ps, mu, u, True, 0.01, z, fx, c, s, obs._model, obs._se_inv,
                             obs._s, obs._s_inv, obs._qs, obs._r, obs._gp, True, obs._p0, y,
                             switch, combined)
        assert restarted == 0
        np.testing.assert_allclose(mu, expected_mu, rtol=1e-8)
        np.testing.assert_allclose(combined, expected_mu @ np.array(expected_x), rtol=1e-9)
        np.testing.assert_allclose(y, expected_mu @ np.array(expected_y), rtol=1e-9,
                                   atol=1e-12)
    single = LateralForceObserver(tuning=ObserverTuningParams(quiet_force_q=0.0))
    x, p, u, z, fx = _random_step_inputs(single, rng)
    xs, ps, mu = x[None].copy(), p[None].copy(), np.ones(1)
    y_imm, y_one, combined, log_likelihood = np.empty(5), np.empty(5), np.empty(7), np.empty(1)
    imm_step(xs, ps, mu, u, True, 0.01, z, fx, c, s, single._model, single._se_inv, single._s,
             single._s_inv, single._qs, single._r, single._gp, True, single._p0, y_imm, 0.5,
             combined)
    filter_step(x, p, u, True, 0.01, z, fx, c, s, single._model, single._se_inv, single._s,
                single._s_inv, single._qs[0], single._r, single._gp, True, single._p0, y_one,
                log_likelihood)
    assert np.array_equal(combined, x) and np.array_equal(ps[0], p)
    assert np.array_equal(y_imm, y_one) and mu[0] == 1.0


def test_split_preserves_axle_sum() -> None:
    """Both splits keep Fy_left + Fy_right = 2 Fy_axle_mean; the load-sensitive one gives the
    loaded wheel less than the proportional one, and exponent 0 splits evenly."""
    fz = np.array([[3000.0, 5000.0, 2500.0, 4500.0]])
    for beta in (0.0, 0.6, 1.0):
        fy = split_lateral(fz, np.array([1000.0]), np.array([700.0]), beta)
        np.testing.assert_allclose(fy[0, :2].sum(), 2000.0)
        np.testing.assert_allclose(fy[0, 2:].sum(), 1400.0)
    proportional = split_lateral(fz[0], 1000.0, 700.0, 1.0)
    sensitive = split_lateral(fz[0], 1000.0, 700.0, 0.6)
    assert proportional[1] == pytest.approx(1250.0) and sensitive[1] < proportional[1]
    np.testing.assert_allclose(split_lateral(fz[0], 1000.0, 700.0, 0.0),
                               [1000.0, 1000.0, 700.0, 700.0])


def test_differentiator_is_scipy_bilinear() -> None:
    """The closed-form differentiator equals scipy.signal.bilinear of s/(tau s + 1)."""
    b, a = signal.bilinear([1.0, 0.0], [0.02, 1.0], fs=100.0)
    b0, b1, a1 = differentiator_coefficients(0.02, 0.01)
    np.testing.assert_allclose([b0, b1], b / a[0], rtol=1e-12)
    assert a1 == pytest.approx(a[1] / a[0], rel=1e-12)


def test_batch_equals_streaming(paper_case: TuningCase) -> None:
    """run() (vectorised differentiator, tight loop) gives the same estimates as step()."""
    n = 400
    batch = LateralForceObserver().run(paper_case.dt, paper_case.ax[:n], paper_case.ay[:n],
                                       paper_case.r[:n], paper_case.p[:n],
                                       paper_case.omega[:n], paper_case.wheel_torque[:n],
                                       paper_case.steer[:n])
    stream = LateralForceObserver()
    rows = []
    for k in range(n):
        est = stream.step(paper_case.ax[k], paper_case.ay[k], paper_case.r[k], paper_case.p[k],
                          paper_case.omega[k], paper_case.wheel_torque[k], paper_case.steer[k],
                          paper_case.dt)
        assert est is not None
        rows.append(est.fy)
    fy = np.array(rows)
    np.testing.assert_allclose(batch.fy, fy, rtol=1e-9, atol=1e-6)


def test_paper_scenario_accuracy(paper_case: TuningCase) -> None:
    """Paper case (mass +200 kg, friction 1.1 -> 0.2): every wheel under the 10 % target with
    the tire's load-sensitive split (measured 7.5 / 7.8 / 4.6 / 8.2 %), axle means under 7 %
    (6.8, 5.7). The agile filter alone (``quiet_force_q`` 0, the paper's one filter) is within
    the target too (worst 9.5 %): the quiet filter beside it costs this manoeuvre nothing and
    keeps the gyro's noise out of ordinary driving (the family, docs/methods/
    lateral_force_observer.md). The paper's proportional split on the same filter misses the
    target (15.0 / 13.9 % on the inner wheels), and so does a passenger-car tire's 0.6 (11.1 %):
    relation 2 overstates the split on Magic Formula tires."""
    track = paper_case.run()
    err = fy_error_percent(track, paper_case.fy_true)
    assert np.all(err < 9.0), err
    assert np.all(_axle_error_percent(track, paper_case.fy_true) < 7.0)
    agile = paper_case.run(tuning=ObserverTuningParams(quiet_force_q=0.0))
    assert np.all(fy_error_percent(agile, paper_case.fy_true) < 10.0)
    for exponent in (1.0, 0.6):
        other = paper_case.run(ObserverVehicleParams(split_exponent=exponent))
        assert np.max(fy_error_percent(other, paper_case.fy_true)) > 10.5


def test_skfmec_versus_plain_ekf(paper_case: TuningCase, nominal_mass_case: TuningCase) -> None:
    """Measured, not assumed; each filter with its own tuning. Paper case: a tie on the worst
    wheel (SKFMEC 8.2 %, plain EKF 8.0 %), the plain EKF is better on the axle means (5.5, 5.3
    vs 6.8, 5.7 %). The compensator makes no measurable difference with these defaults (the
    same filters without it: 8.26 % on the paper case, 14.46 % on the axles at +20 % model
    mass against 14.44 %); with the paper's single filter and ay noise of 1 m/s^2 it had
    lowered the worst wheel (9.0 vs 9.3 %). Model mass 20 % too high: the scaled filters are
    far better than the plain EKF (axle 14.4 vs 29.8 %)."""
    skf = paper_case.run()
    plain = paper_case.run(tuning=ObserverTuningParams.plain())
    no_mec = paper_case.run(tuning=ObserverTuningParams(mec=False))
    skf_worst = np.max(fy_error_percent(skf, paper_case.fy_true))
    plain_worst = np.max(fy_error_percent(plain, paper_case.fy_true))
    assert abs(skf_worst - plain_worst) < 1.0, (skf_worst, plain_worst)
    assert abs(skf_worst - np.max(fy_error_percent(no_mec, paper_case.fy_true))) < 0.5
    axle_skf = _axle_error_percent(skf, paper_case.fy_true)
    axle_plain = _axle_error_percent(plain, paper_case.fy_true)
    assert np.all(axle_plain < axle_skf) and np.all(axle_skf - axle_plain < 2.0)
    heavy = ObserverVehicleParams(m=1814.0 * 1.2, ms=1661.0 * 1.2)
    skf_heavy = _axle_error_percent(nominal_mass_case.run(heavy), nominal_mass_case.fy_true)
    plain_heavy = _axle_error_percent(nominal_mass_case.run(heavy, ObserverTuningParams.plain()),
                                      nominal_mass_case.fy_true)
    assert np.all(skf_heavy < plain_heavy - 8.0), (skf_heavy, plain_heavy)


def test_relations_on_truth(relation_truth) -> None:
    """Relation 1: zeta = Fy_axle_mean / phi nearly constant below 0.5 g (measured spread
    < 2 %); relation 2: the load-sensitive split (exponent 0.6) is closer to the truth's
    Fy2/Fyf than the paper's Fz2/Fzf, which overstates it (paper Figs. 3-4)."""
    truth = relation_truth
    mask = (np.abs(truth.ay) > 1.0) & (np.abs(truth.ay) < 0.5 * 9.81)
    fyf = truth.fy[mask, :2].mean(axis=1)
    fyr = truth.fy[mask, 2:].mean(axis=1)
    zeta1, zeta2 = fyf / truth.roll[mask], fyr / truth.roll[mask]
    assert np.std(zeta1) / np.mean(zeta1) < 0.05
    assert np.std(zeta2) / np.mean(zeta2) < 0.05
    x = truth.fz[mask, 1] / truth.fz[mask, :2].mean(axis=1)
    fy_ratio = truth.fy[mask, 1] / fyf
    sensitive = 2.0 * x ** 0.6 / (x ** 0.6 + (2.0 - x) ** 0.6)
    assert np.mean(np.abs(sensitive - fy_ratio)) < 0.6 * np.mean(np.abs(x - fy_ratio))
    assert np.all(x - fy_ratio > 0.0)   # the paper's relation always overstates it here


@pytest.mark.parametrize('factor', [0.7, 1.3])
def test_robust_to_friction_error(factor: float) -> None:
    """+/-30 % road friction (the observer has no friction input): every wheel stays under
    the 10 % target (measured worst 7.3 % at x0.7, 9.8 % at x1.3)."""
    case = bench.paper_case(friction_factor=factor)
    track = case.run()
    assert np.all(fy_error_percent(track, case.fy_true) < 10.0)
    assert np.all(_axle_error_percent(track, case.fy_true) < 8.0)


@pytest.mark.parametrize('factor', [0.8, 1.2])
def test_mass_error_bias_is_bounded(factor: float, nominal_mass_case: TuningCase) -> None:
    """+/-20 % model mass (truth nominal): the force sum follows m_model ay, so the errors
    grow with the mass error (measured worst wheel 14.7 % at x0.8, 20.4 % at x1.2; axles
    12.5 %, 14.5 %); bounded at 23 % per wheel and 18 % per axle."""
    case = nominal_mass_case
    params = ObserverVehicleParams(m=1814.0 * factor, ms=1661.0 * factor)
    track = case.run(params)
    assert np.all(fy_error_percent(track, case.fy_true) < 23.0)
    assert np.all(_axle_error_percent(track, case.fy_true) < 18.0)


def test_diverging_tuning_resets_instead_of_crashing(paper_case: TuningCase) -> None:
    """An unstable tuning (plain EKF with huge roll-state noise) makes the prediction blow up;
    the filter restarts (counted) and never outputs non-finite forces."""
    tuning = ObserverTuningParams.plain(q_diag=(0.01, 0.1, 0.1, 1e5, 1e5, 3.0, 3.0))
    observer = LateralForceObserver(tuning=tuning)
    c = paper_case
    with np.errstate(all='ignore'):
        track = observer.run(c.dt, c.ax, c.ay, c.r, c.p, c.omega, c.wheel_torque, c.steer)
    assert observer.health.covariance_resets > 0
    assert np.all(np.isfinite(track.fy))


def test_real_time_factor() -> None:
    """Offline at 100 Hz the batch path needs well under 1 % of real time on one core
    (CPU time; measured ~190x). Bounded at 100x, the contract target."""
    factors = bench.bench(repeats=2)
    assert factors['rtf_run_cpu'] > 100.0, factors


def test_bad_samples_rejected_without_corrupting(paper_case: TuningCase) -> None:
    """NaN, saturated IMU, wrong shapes and bad dt are rejected and counted; the estimate is
    held and the filter afterwards agrees with a run that never saw them."""
    n, c = 500, paper_case
    clean, dirty = LateralForceObserver(), LateralForceObserver()
    for k in range(n):
        args = [c.ax[k], c.ay[k], c.r[k], c.p[k], c.omega[k], c.wheel_torque[k], c.steer[k], c.dt]
        ref = clean.step(*args)
        if k in (100, 200, 300, 400):
            bad = list(args)
            bad[{100: 1, 200: 0, 300: 4, 400: 7}[k]] = {100: math.nan, 200: 500.0,
                                                         300: np.ones(3), 400: -1.0}[k]
            held = dirty.step(*bad)
            assert held is not None and not held.accepted
            continue
        out = dirty.step(*args)
    assert ref is not None and out is not None
    assert sum(dirty.health.rejected.values()) == 4
    assert set(dirty.health.rejected) == {'non_finite', 'accel_saturated', 'shape', 'dt'}
    assert out.accepted and np.all(np.isfinite(out.fy))
    np.testing.assert_allclose(out.fy, ref.fy, rtol=0.05, atol=30.0)


def test_gap_restarts_filter(paper_case: TuningCase) -> None:
    """A time gap longer than max_dt_s restarts the filter (counted) instead of predicting."""
    obs, c = LateralForceObserver(), paper_case
    for k in range(50):
        obs.step(c.ax[k], c.ay[k], c.r[k], c.p[k], c.omega[k], c.wheel_torque[k], c.steer[k],
                 c.dt if k != 30 else 1.0)
    assert obs.health.gap_restarts == 1


def test_covariance_stays_spd_over_long_run() -> None:
    """Ten minutes of seeded slalom at 100 Hz: P stays symmetric positive definite, no reset."""
    rng = np.random.default_rng(7)
    dt, n = 0.01, 60_000
    t = np.arange(n) * dt
    vx = 20.0
    ay = 3.0 * np.sin(0.5 * t)
    r = ay / vx
    p = 0.0043 * 3.0 * 0.5 * np.cos(0.5 * t)
    omega = np.full((n, 4), vx / 0.305) + rng.normal(0.0, 0.02, (n, 4))
    obs = LateralForceObserver()
    obs.run(dt, rng.normal(0.0, 0.05, n), ay + rng.normal(0.0, 0.05, n),
            r + rng.normal(0.0, 0.002, n), p + rng.normal(0.0, 0.002, n), omega,
            np.zeros((n, 4)), 0.05 * np.sin(0.5 * t))
    cov = obs.scaled_covariance
    assert np.allclose(cov, cov.T)
    assert np.min(np.linalg.eigvalsh(cov)) > 0.0
    assert obs.health.covariance_resets == 0
