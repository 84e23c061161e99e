"""Tests of the Umeno tire-stiffness observer core.

Two kinds of data. (1) Wheel speeds synthesised in the test: each wheel is the two-inertia
model of ``tire_model`` (ZOH-discretised at 1 kHz) driven by seeded white road torque,
high-passed at 5 Hz because the model has no longitudinal tire force (without it the
rigid-body mode would random-walk the wheel speed, which a rolling wheel does not), plus a
small white sensor noise. (2) Seeded road-simulator runs (``road_simulator``: 48-tooth encoder
with tooth-spacing error and tooth-period timing, driveline resonances on the rear axle),
built from the shipped Umeno and diffusion scenarios with a shorter duration and one pressure
level, for the docs/targets.md targets.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Literal

import numpy as np
import pytest
import scipy.signal as sig

from tpms_ros.core.block_least_squares import batch_least_squares
from tpms_ros.core.stiffness_observer import (
    PressureRelation,
    StiffnessObserverParams,
    TireStiffnessObserver,
)
from tpms_ros.core.tire_model import TorsionalTire
from tpms_ros.core.tooth_correction import ToothErrorCorrector
from tpms_ros.core.torsional_observer import design_observer, extended_system
from tpms_ros.core.wheel_encoder import encoder_wheel_speed
from tpms_ros.simulation.road_scenario import ScenarioEvent, load_scenario
from tpms_ros.simulation.road_simulator import RoadSimulationResult, simulate_scenario

FS = 1000.0
BLOCK = 250
MODEL = TorsionalTire()            # 40 Hz: the paper's tire at 200 kPa
OMEGA0 = 55.0                      # rad/s, ~59 km/h with r = 0.3 m
_HIGHPASS = sig.butter(2, 5.0, 'highpass', fs=FS, output='sos')


def synthetic_params(**changes: Any) -> StiffnessObserverParams:
    """The observer's parameters for the synthetic speeds, which come from no encoder ring: its
    tooth pattern (noise) is waited for 1 s, as before the learned gate of issue 21."""
    return StiffnessObserverParams(**{'tooth_learned_s': 1.0, **changes})


def _tire_response(tire: TorsionalTire, road: np.ndarray,
                   rim: np.ndarray | None) -> np.ndarray:
    """Wheel-speed perturbation of one tire for road torque and optional rim torque."""
    a, b = tire.state_space()
    ad, bd, cd, dd, _ = sig.cont2discrete((a, b, np.array([[1.0, 0.0, 0.0]]), np.zeros((1, 2))),
                                          1.0 / FS, method='zoh')
    num, den = sig.ss2tf(ad, bd, cd, dd, input=1)
    out = sig.lfilter(num[0], den, road)
    if rim is not None:
        num, den = sig.ss2tf(ad, bd, cd, dd, input=0)
        out += sig.lfilter(num[0], den, rim)
    return out


def synthesize(stiffness: np.ndarray, seconds: float, seed: int, *, noise: float = 0.01,
               road_std: float = 20.0, driveline: tuple[float, float] | None = None,
               driven: tuple[int, ...] = (2, 3), driveline_on_rim: bool = False) -> np.ndarray:
    """(N, 4) wheel speeds; ``stiffness`` is (4,) or (N, 4) piecewise-constant true K.

    ``driveline = (frequency_hz, torque_std)`` adds one common in-phase resonant torque
    (a differential/suspension-member resonance) to the ``driven`` wheels. It acts where the
    paper's eq. 12 puts it, additively with the road torque on the belt side (the
    suspension's fore-aft motion reaches the tire through the contact patch); the caller can
    put it on the rim instead with ``driveline_on_rim``.
    """
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    k = np.broadcast_to(np.asarray(stiffness, dtype=float), (n, 4))
    common = None
    if driveline is not None:
        f0, std = driveline
        w0, zeta = 2 * np.pi * f0, 0.1
        num, den = sig.bilinear([2 * zeta * w0, 0.0], [1.0, 2 * zeta * w0, w0 ** 2], FS)
        common = sig.lfilter(num, den, rng.normal(0.0, std, n))
    rim = common if driveline_on_rim else None
    omega = np.empty((n, 4))
    for w in range(4):
        road = sig.sosfilt(_HIGHPASS, rng.normal(0.0, road_std, n))
        if common is not None and w in driven and not driveline_on_rim:
            road = road + common
        # Piecewise-constant K: simulate each constant segment and stitch (state restarts are
        # negligible against the test durations; the estimator is told nothing of them).
        values, starts = np.unique(k[:, w], return_index=True)
        order = np.argsort(starts)
        bounds = np.append(starts[order], n)
        pert = np.empty(n)
        for i, kv in enumerate(values[order]):
            s, e = bounds[i], bounds[i + 1]
            tire = TorsionalTire(MODEL.j1, MODEL.j2, float(kv), MODEL.d)
            pert[s:e] = _tire_response(tire, road[s:e],
                                       rim[s:e] if rim is not None and w in driven else None)
        omega[:, w] = OMEGA0 + pert + rng.normal(0.0, noise, n)
    return omega


def run(observer: TireStiffnessObserver, omega: np.ndarray, chunk: int = BLOCK,
        stamps: np.ndarray | None = None) -> list:
    """Feed in chunks, return the estimate after each chunk."""
    out = []
    for s in range(0, omega.shape[0], chunk):
        st = None if stamps is None else stamps[s:s + chunk]
        out.append(observer.update(omega[s:s + chunk], stamps=st))
    return out


def test_pressure_relation_default_matches_paper_figures():
    """Default slope 0.586 maps the paper's 35/40 Hz stiffness ratio to 120/200 kPa."""
    rel = PressureRelation()
    assert rel.slope == pytest.approx(0.5859375)
    assert 200.0 * rel.pressure_ratio(np.array((35.0 / 40.0) ** 2)) == pytest.approx(120.0)
    with pytest.raises(ValueError, match='slope'):
        PressureRelation(slope=0.0)


def test_power_law_relation_inverts_and_gives_its_slope():
    """K/K0 = (p/p0)^n inverted; the local slope d(p/p0)/d(K/K0) = (1/n) r^(1/n - 1)."""
    rel = PressureRelation(law='power', exponent=0.5)
    np.testing.assert_allclose(rel.pressure_ratio(np.array([1.0, 0.9, 0.0, -0.2])),
                               [1.0, 0.81, 0.0, 0.0])
    np.testing.assert_allclose(rel.pressure_ratio_per_stiffness_ratio(np.array([1.0, 0.9])),
                               [2.0, 1.8])
    with pytest.raises(ValueError, match='exponent'):
        PressureRelation(law='power', exponent=0.0)
    with pytest.raises(ValueError, match='law'):
        PressureRelation(law='cubic')  # type: ignore[arg-type]


def test_power_law_tire_read_right_only_with_its_law():
    """A tire whose K follows (p/p0)^0.4 (a law of the car family, not the paper's line).

    Calibrated at 200 kPa, FR at 160 and RL at 180 kPa: with its power law given the
    readings are the truth within 4 kPa (measured 162.0, 180.9; 163.4, 180.3 since the window
    model's learning gate, which starts the calibration 0.5 s later); with the default line
    they read 172.4 and 186.5, the line's law-limited values (1 - (1 - 0.8^0.4) / 0.586 =
    0.854). Read with the warning's memory: the reading's longer one still lags RL's small
    change here (a 4 % stiffness step, below its restart: 185 for 180 over 30-60 s, measured).
    """
    k0 = MODEL.with_resonance(45.0).k
    p_true = np.array([200.0, 160.0, 180.0, 200.0])
    cal = synthesize(np.full(4, k0), 40.0, seed=33)
    test = synthesize(k0 * (p_true / 200.0) ** 0.4, 60.0, seed=34)
    means = {}
    for relation in (PressureRelation(), PressureRelation(law='power', exponent=0.4)):
        observer = TireStiffnessObserver(synthetic_params(
            calibration_s=30.0, pressure_relation=relation, steady_forgetting_factor=0.98))
        observer.start_calibration()
        run(observer, cal)
        est = run(observer, test)
        assert est[-1].valid.all()
        means[relation.law] = np.mean([e.pressure_kpa for e in est[len(est) // 2:]], axis=0)
    np.testing.assert_allclose(means['power'], p_true, atol=4.0)
    law_limited = 200.0 * PressureRelation().pressure_ratio((p_true / 200.0) ** 0.4)
    np.testing.assert_allclose(means['line'], law_limited, atol=4.0)
    assert means['line'][1] - p_true[1] > 8.0


def test_noisy_tire_is_reported_uncertain_not_low():
    """FR loses 30 % of its stiffness but is barely excited (road torque 2 instead of 20, twice
    the sensor noise): its block stiffnesses spread 5.6 times the calibration's (measured)
    and it reads anywhere from 200 to 290 kPa. It is reported 'uncertain_noisy' on every
    update: not valid, never low, confidence 0. The other tires stay 'ok'; without the trust
    check FR would be reported valid."""
    cal = synthesize(np.full(4, MODEL.k), 40.0, seed=51)
    test = synthesize(np.full(4, MODEL.k), 60.0, seed=52)
    test[:, 1] = synthesize(np.full(4, 0.7 * MODEL.k), 60.0, seed=53, road_std=2.0,
                            noise=0.02)[:, 1]
    for trust in (True, False):
        observer = TireStiffnessObserver(synthetic_params(calibration_s=30.0,
                                                          trust_check=trust))
        observer.start_calibration()
        run(observer, cal)
        est = run(observer, test)[40:]     # after the RLS forgot the calibration data
        if not trust:
            assert all(e.status[1] == 'ok' for e in est)
            continue
        assert all(e.status[1] == 'uncertain_noisy' for e in est)
        assert not any(e.valid[1] or e.underinflated[1] or e.confidence[1] for e in est)
        assert all(e.status[w] == 'ok' for e in est for w in (0, 2, 3))
        assert observer.trust_features()['spread_ratio'][1] > 4.0


def test_model_error_keeps_a_biased_healthy_tire_below_the_warning_threshold():
    """FR at placard picks up a 35 Hz disturbance the calibration did not see and reads
    175-183 kPa (threshold 180): its noise alone makes that a confident 'low' (peak confidence
    0.98 with model_error_ratio 0, measured); the default 4 % model error keeps the peak at
    0.71, below the voter's single-method threshold 0.8, and the healthy tires below 0.04."""
    cal = synthesize(np.full(4, MODEL.k), 40.0, seed=51)
    test = synthesize(np.full(4, MODEL.k), 60.0, seed=52)
    test[:, 1] = synthesize(np.full(4, MODEL.k), 60.0, seed=53, driveline=(35.0, 80.0),
                            driven=(1,))[:, 1]
    peaks = {}
    for ratio in (0.0, StiffnessObserverParams().model_error_ratio):
        observer = TireStiffnessObserver(synthetic_params(calibration_s=30.0,
                                                          model_error_ratio=ratio))
        observer.start_calibration()
        run(observer, cal)
        est = run(observer, test)[40:]
        assert min(e.pressure_kpa[1] for e in est) < 180.0
        peaks[ratio] = np.max([e.confidence for e in est], axis=0)
    assert peaks[0.0][1] > 0.9
    assert peaks[0.04][1] < 0.8 and np.all(peaks[0.04][[0, 2, 3]] < 0.1), peaks


def test_observer_structure_and_poles():
    """Extended system comes from the tire model; eq. 8 error poles are where placed."""
    a, b = MODEL.state_space()
    a_ext, b_ext = extended_system(MODEL)
    np.testing.assert_array_equal(a_ext[:3, :3], a)
    np.testing.assert_array_equal(a_ext[:3, 3], -b[:, 1])
    np.testing.assert_array_equal(a_ext[3], 0.0)
    design = design_observer(MODEL, 3.0, FS)
    radius = 2 * np.pi * 3.0 * MODEL.resonance_hz
    eig = np.sort_complex(np.linalg.eigvals(design.error_matrix))
    want = np.sort_complex(radius * np.array([-1.0, np.exp(2j * np.pi / 3),
                                              np.exp(-2j * np.pi / 3)]))
    np.testing.assert_allclose(eig, want, rtol=1e-8)
    # Discrete filters are stable.
    assert np.all(np.abs(np.roots(design.denominator)) < 1.0)
    with pytest.raises(ValueError, match='observer_pole_factor'):
        design_observer(MODEL, 20.0, FS)


def test_params_validation_names_parameter():
    """Non-physical parameters are refused with the parameter's name."""
    with pytest.raises(ValueError, match='forgetting_factor'):
        StiffnessObserverParams(forgetting_factor=1.0)
    with pytest.raises(ValueError, match='band_hz'):
        StiffnessObserverParams(band_low_hz=60.0, band_high_hz=25.0)
    with pytest.raises(ValueError, match='driven_axle'):
        StiffnessObserverParams(driven_axle='middle')  # type: ignore[arg-type]
    with pytest.raises(ValueError, match='drive_compensation'):
        StiffnessObserverParams(drive_compensation='sum')  # type: ignore[arg-type]
    with pytest.raises(ValueError, match='partner_lag_step_s'):
        StiffnessObserverParams(partner_lag_step_s=1e-4)
    with pytest.raises(ValueError, match='partner_lag_s'):
        StiffnessObserverParams(partner_lag_s=-0.01)
    with pytest.raises(ValueError, match='encoder_speed_method'):
        StiffnessObserverParams(encoder_speed_method='median')  # type: ignore[arg-type]
    with pytest.raises(ValueError, match='encoder_timer_s'):
        StiffnessObserverParams(encoder_timer_s=-1e-6)
    with pytest.raises(ValueError, match='omega'):
        TireStiffnessObserver().update(np.zeros((10, 3)))


def test_batch_least_squares_exact_on_noise_free_data():
    """Eq. 10 recovers the coefficients of an exact linear relation for each problem."""
    rng = np.random.default_rng(3)
    zeta = rng.normal(size=(500, 4, 2)) * np.array([1e-4, 3e-2])
    coef = np.array([[-3000.0, 2.0], [0.0, 0.0], [100.0, -1.0], [5.0, 0.5]])
    w = np.einsum('nwp,wp->nw', zeta, coef)
    np.testing.assert_allclose(batch_least_squares(zeta, w), coef, rtol=1e-9, atol=1e-9)


def test_recovers_15pct_stiffness_drop_without_cross_talk():
    """FR 15 % softer than the 200 kPa model: dK within 10 % of the truth, others stay put."""
    k_true = MODEL.k * np.array([1.0, 0.85, 1.0, 1.0])
    omega = synthesize(k_true, 120.0, seed=11)
    est = run(TireStiffnessObserver(synthetic_params()), omega)
    dk = np.array([e.delta_k for e in est[len(est) // 3:]])   # after ~3 time constants
    assert est[-1].valid.all(), est[-1].status
    true_dk = k_true - MODEL.k
    mean_dk = dk.mean(axis=0)
    # measured: FR -3221 vs -3248; others -10, 10, 62 N m/rad (<= 0.3 % of K)
    assert abs(mean_dk[1] - true_dk[1]) < 0.1 * abs(true_dk[1])
    assert np.all(np.abs(mean_dk[[0, 2, 3]]) < 0.02 * MODEL.k)


def test_batch_and_rls_agree_on_stationary_data():
    """Batch LS over 100 blocks and RLS with rho = 0.98 give the same K within noise."""
    k_true = MODEL.k * np.array([1.0, 0.85, 0.9, 1.0])
    omega = synthesize(k_true, 60.0, seed=12)
    rls = run(TireStiffnessObserver(synthetic_params(ls_mode='rls')), omega)[-1]
    batch = run(TireStiffnessObserver(synthetic_params(ls_mode='batch')), omega)[-1]
    assert rls.valid.all() and batch.valid.all()
    # measured: RLS - batch -28..-84 N m/rad (<= 0.4 % of K); batch - truth -101..237
    np.testing.assert_allclose(rls.stiffness, batch.stiffness, atol=0.015 * MODEL.k)
    np.testing.assert_allclose(batch.stiffness, k_true, rtol=0.03)


@pytest.mark.parametrize(('compensation', 'encoder'), [('partner', 'off'), ('difference', 'off'),
                                                     ('partner', 'given'), ('partner', 'read')])
def test_chunked_equals_one_shot_with_bad_samples(compensation, encoder):
    """Random chunk sizes, NaN and gaps included: same result as one chunk to 1e-9 (with the
    encoder noise removed too, its timer given or read from the speeds)."""
    rng = np.random.default_rng(5)
    omega = synthesize(MODEL.k * np.array([1.0, 0.9, 1.0, 0.85]), 40.0, seed=13)
    if encoder == 'read':
        t = np.arange(omega.shape[0]) / FS
        omega = np.column_stack([encoder_wheel_speed(t, omega[:, w], t, np.zeros(48), 0.2 * w,
                                                     2e-6) for w in range(4)])
    omega[7000:7010, 1] = np.nan
    omega[15000, 3] = -1.0
    stamps = np.arange(omega.shape[0]) / FS
    stamps[20000:] += 0.05   # a 50 ms gap
    params = synthetic_params(calibration_s=10.0, driven_axle='rear',
                              drive_compensation=compensation,
                              encoder_noise_removal=encoder != 'off',
                              encoder_timer_s=2e-6 if encoder == 'given' else 0.0)
    one = TireStiffnessObserver(params)
    one.start_calibration()
    whole = one.update(omega, stamps=stamps)
    many = TireStiffnessObserver(params)
    many.start_calibration()
    s = 0
    while s < omega.shape[0]:
        step = int(rng.integers(1, 700))
        part = many.update(omega[s:s + step], stamps=stamps[s:s + step])
        s += step
    np.testing.assert_allclose(part.stiffness, whole.stiffness, rtol=1e-9)
    np.testing.assert_allclose(part.delta_d, whole.delta_d, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(part.pressure_std_kpa, whole.pressure_std_kpa, rtol=1e-9)
    assert part.status == whole.status and part.calibrated and whole.calibrated
    assert one.counters == many.counters
    if encoder == 'read':
        assert one.encoder_noise == many.encoder_noise == \
            'removed (timer 2 us, read from the wheel speeds)'


@pytest.mark.parametrize('method', ['tooth_period', 'window_average'])
def test_encoder_noise_removal_keeps_the_estimate_off_the_road_level(method):
    """The timer's quantisation in the measured speed biases the least squares by an amount
    that shrinks as the road excites the tire more (errors in variables): the same tires read
    ~20 % (tooth period) or ~14 % (window average) stiffer on a road four times smoother.
    With the ECU's timer given, its noise is taken out and the two roads read alike
    (measured, mean of the four tires: 0.7-1.6 % apart, against 14-20 %). Held tooth periods
    need no timer given: it is read from the speeds (here after 10 s: this drive's steady
    speed gives few distinct readings), and the estimates match the given timer's to 0.01 %."""
    timer_s = 4e-6
    t = np.arange(int(60.0 * FS)) / FS
    mean_k = {}
    timers = {'off': 0.0, 'given': timer_s, 'read': 0.0}
    for road_std in (8.0, 30.0):
        true = synthesize(np.full(4, MODEL.k), 60.0, seed=3, noise=0.0, road_std=road_std)
        measured = np.column_stack([
            encoder_wheel_speed(t, true[:, w], t, np.zeros(48), 0.1 * w, timer_s, method,
                                0.005) for w in range(4)])
        for removal, timer in timers.items():
            if removal == 'read' and method == 'window_average':
                continue
            params = synthetic_params(encoder_noise_removal=removal != 'off',
                                      encoder_timer_s=timer,
                                      encoder_speed_method=method,
                                      encoder_window_s=0.005)
            observer = TireStiffnessObserver(params)
            estimate = run(observer, measured)[-1]
            mean_k[road_std, removal] = float(np.mean(estimate.stiffness)) / MODEL.k
            if removal == 'read':
                assert observer.encoder_noise.startswith('removed (timer 4 us, read')
    assert mean_k[8.0, 'off'] - mean_k[30.0, 'off'] > 0.10
    assert abs(mean_k[8.0, 'given'] - mean_k[30.0, 'given']) < 0.04
    assert abs(mean_k[30.0, 'given'] - 1.0) < 0.03
    if method == 'tooth_period':
        assert abs(mean_k[8.0, 'read'] - mean_k[30.0, 'read']) < 0.04
        assert abs(mean_k[30.0, 'read'] - 1.0) < 0.03


def test_a_timer_read_at_low_speed_is_dropped_once_the_speeds_show_window_averages():
    """An ECU averaging over 8 ms reports one tooth period while a tooth takes longer (here
    20 teeth at 30 rad/s): its readings lie on the timer's lattice and change once per tooth,
    so the timer is read. Faster, the reading changes about twice per tooth: the speeds are
    window averages, and from then on the noise is left in (the held model would be wrong),
    which /diagnostics says."""
    seconds = 40.0
    t = np.arange(int(seconds * FS)) / FS
    profile = np.interp(t, [0.0, 15.0, 25.0, seconds], [30.0, 30.0, 55.0, 55.0])
    vibration = synthesize(np.full(4, MODEL.k), seconds, seed=8) - OMEGA0
    measured = np.column_stack([
        encoder_wheel_speed(t, profile + vibration[:, w], t, np.zeros(20), 0.1 * w, 4e-6,
                            'window_average', 0.008) for w in range(4)])
    observer = TireStiffnessObserver(synthetic_params(encoder_teeth=20))
    run(observer, measured[:15000])
    assert observer.encoder_noise == 'removed (timer 4 us, read from the wheel speeds)'
    run(observer, measured[15000:])
    assert observer.encoder_noise.startswith('removed until sample ')
    assert 'window averages' in observer.encoder_noise


def _driven_pressure_error(axle: Literal['none', 'rear'],
                           compensation: Literal['partner', 'difference'] = 'partner',
                           ) -> np.ndarray:
    """Pressure RMS error (kPa) after calibration, RL 15 % softer, driveline changing meanwhile."""
    cal = synthesize(np.full(4, MODEL.k), 60.0, seed=21, driveline=(15.0, 300.0))
    k_test = MODEL.k * np.array([1.0, 1.0, 0.85, 1.0])
    # The driveline resonance wanders with conditions (paper §3.1), so calibration alone
    # cannot absorb it.
    test = synthesize(k_test, 60.0, seed=22, driveline=(19.0, 300.0))
    observer = TireStiffnessObserver(synthetic_params(
        driven_axle=axle, drive_compensation=compensation, calibration_s=40.0))
    observer.start_calibration()
    run(observer, cal)
    assert observer.estimate().calibrated
    est = run(observer, test)
    p_true = 200.0 * PressureRelation().pressure_ratio(k_test / MODEL.k)
    pressure = np.array([e.pressure_kpa for e in est[len(est) // 2:]])
    return np.sqrt(np.mean((pressure - p_true) ** 2, axis=0))


def test_partner_compensation_removes_the_driveline_from_both_driven_wheels():
    """The in-phase driveline torque on the rims fakes pressure changes on both driven wheels;
    with the partner's lagged speed as nuisance regressors both read as if undriven."""
    without = _driven_pressure_error('none')
    with_comp = _driven_pressure_error('rear', 'partner')
    # measured RMS (kPa, FL FR RL RR): without [3.2, 1.2, 15.6, 20.7], with [3.2, 1.2, 6.5, 5.7]
    # The front wheels' estimates are the same blocks, reported up to partner_lag_s later.
    np.testing.assert_allclose(with_comp[:2], without[:2], atol=0.1)
    assert np.all(with_comp[2:] < 8.0)
    assert np.all(without[2:] > 2.0 * with_comp[2:])


def test_difference_compensation_on_unchanged_driven_wheel():
    """The paper's eq. 14 removes the driveline from the unchanged driven wheel.

    Known limit (asserted so a change shows): the softened driven wheel keeps a bias with or
    without it, because the driveline-driven torsion enters the regressor th at ~19 Hz, where
    the paper's ``dK th`` term has a different effective gain than at the tire resonance.
    """
    without = _driven_pressure_error('none')
    with_comp = _driven_pressure_error('rear', 'difference')
    # measured RMS (kPa, FL FR RL RR): without [3.2, 1.2, 15.6, 20.7], with [3.2, 1.2, 25.0, 3.2]
    np.testing.assert_array_equal(without[:2], with_comp[:2])   # front untouched
    assert with_comp[3] < 5.0 and without[3] > 3.0 * with_comp[3]
    assert without[2] > 10.0 and with_comp[2] > 10.0


def test_45hz_tire_after_calibration_flags_low_tires():
    """A 45 Hz tire with the 40 Hz model: after calibration the pressures are right.

    FR and RL drop 15 % in K (-> 148.8 kPa): flagged with high confidence; FL and RR stay at
    200 kPa unflagged. The reported pressure noise matches the observed spread (factor 2).
    """
    k0 = MODEL.with_resonance(45.0).k
    cal = synthesize(np.full(4, k0), 40.0, seed=31)
    k_test = k0 * np.array([1.0, 0.85, 0.85, 1.0])
    test = synthesize(k_test, 60.0, seed=32)
    observer = TireStiffnessObserver(synthetic_params(calibration_s=30.0))
    observer.start_calibration()
    run(observer, cal)
    state = observer.calibration_state()
    np.testing.assert_allclose(state['k_nominal'], k0, rtol=0.02)   # measured within 1.2 %
    est = run(observer, test)
    tail = est[len(est) // 2:]
    pressure = np.array([e.pressure_kpa for e in tail])
    p_true = 200.0 * PressureRelation().pressure_ratio(k_test / k0)
    np.testing.assert_allclose(pressure.mean(axis=0), p_true, atol=10.0)
    last = est[-1]
    assert last.calibrated and last.valid.all()
    np.testing.assert_array_equal(last.underinflated, [False, True, True, False])
    # The confidence counts model_error_ratio (4 % of placard, issue 21): the healthy tires at
    # 197-201 kPa sit ~2 sigma from the 180 kPa threshold (measured 0.013, 0.023; 0.0 before).
    assert np.all(last.confidence[[1, 2]] > 0.99) and np.all(last.confidence[[0, 3]] < 0.05)
    # measured: means 200.8, 149.1, 153.6, 197.1 kPa; spread 1.0-2.1 vs reported 2.0-2.2 kPa
    ratio = pressure.std(axis=0) / last.pressure_std_kpa
    assert np.all((ratio > 0.3) & (ratio < 2.0)), ratio


def test_four_tire_diffusion_is_flagged():
    """Equal 15 % stiffness loss on all four tires (diffusion) flags all four."""
    cal = synthesize(np.full(4, MODEL.k), 40.0, seed=41)
    test = synthesize(np.full(4, 0.85 * MODEL.k), 40.0, seed=42)
    observer = TireStiffnessObserver(synthetic_params(calibration_s=30.0))
    observer.start_calibration()
    run(observer, cal)
    last = run(observer, test)[-1]
    assert last.underinflated.all() and np.all(last.confidence > 0.9)


def test_the_reading_averages_longer_and_the_warning_is_unchanged():
    """The published reading has the longer memory (``steady_forgetting_factor``), the warning
    the paper's. 150 s at placard, then FR 30 % softer: the flags and confidences are those of
    the one-memory observer to the bit; at placard the reading spreads a third to a half as
    much (measured 1.1, 1.0, 0.3, 0.5 kPa against 2.7, 2.0, 1.0, 1.7); once FR is warned its
    reading has restarted from the warning's estimate and stays within 7.1 kPa of it (measured)
    while the loss settles."""
    cal = synthesize(np.full(4, MODEL.k), 40.0, seed=61)
    drive = np.concatenate((synthesize(np.full(4, MODEL.k), 150.0, seed=62),
                            synthesize(MODEL.k * np.array([1.0, 0.7, 1.0, 1.0]), 40.0,
                                       seed=63)))
    runs = {}
    for name, memory in (('one memory', {'steady_forgetting_factor': 0.98}), ('two', {})):
        observer = TireStiffnessObserver(synthetic_params(calibration_s=30.0, **memory))
        observer.start_calibration()
        run(observer, cal)
        runs[name] = run(observer, drive)
    pressure, flags = ({name: np.array([getattr(e, field) for e in est])
                        for name, est in runs.items()} for field in ('pressure_kpa',
                                                                     'underinflated'))
    for name in ('underinflated', 'confidence'):
        np.testing.assert_array_equal(*(np.array([getattr(e, name) for e in est])
                                        for est in runs.values()))
    placard = slice(240, 600)                   # 60-150 s of the drive, 4 updates a second
    spread = {name: p[placard].std(axis=0) for name, p in pressure.items()}
    assert np.all(spread['two'] < 0.6 * spread['one memory']), spread
    np.testing.assert_allclose(pressure['two'][placard].mean(axis=0), 200.0, atol=5.0)
    warned = int(np.argmax(flags['two'][:, 1]))
    assert warned > 600 and not flags['two'][:, [0, 2, 3]].any()
    settling = slice(warned, warned + 80)       # the 20 s after the warning
    assert np.max(np.abs(pressure['two'][settling, 1] - pressure['one memory'][settling, 1])) \
        < 10.0


def test_bad_samples_do_not_corrupt_and_mark_unknown():
    """NaN, negative and absurd samples, a stuck run and a dead end on FR only.

    FR's estimate stays close to the clean run's; the other wheels are unaffected to 1e-9; a
    dead FR at the end is 'unknown' (dead_sensor), not flagged, despite a low-looking value.
    """
    omega = synthesize(MODEL.k * np.array([1.0, 1.0, 0.9, 1.0]), 60.0, seed=51)
    clean = TireStiffnessObserver(synthetic_params())
    clean_est = run(clean, omega)[-1]
    bad = omega.copy()
    bad[5000:5400, 1] = np.nan
    bad[12000, 1] = -3.0
    bad[18000, 1] = np.inf
    bad[25000, 1] = 1e6
    bad[30000:30300, 1] = bad[30000, 1]          # stuck sensor for 0.3 s
    observer = TireStiffnessObserver(synthetic_params())
    est = run(observer, bad)[-1]
    assert est.valid.all(), est.status
    np.testing.assert_allclose(est.stiffness[[0, 2, 3]], clean_est.stiffness[[0, 2, 3]],
                               rtol=1e-9)
    # measured: FR differs from the clean run by 0.6 N m/rad; its noise is ~100
    assert abs(est.stiffness[1] - clean_est.stiffness[1]) < 0.01 * MODEL.k
    counts = observer.counters
    assert counts['invalid_sample'][1] == 403 and counts['invalid_sample'][0] == 0
    assert counts['stuck_sensor'][1] > 0
    # Now calibrate, then the FR sensor dies (reads 0): unknown, never low.
    observer.start_calibration(20.0)
    run(observer, omega[:25000])
    dead = omega[:3000].copy()
    dead[:, 1] = 0.0
    est = run(observer, dead)[-1]
    assert est.calibrated
    assert est.status[1] == 'dead_sensor' and not est.valid[1]
    assert not est.underinflated[1] and est.confidence[1] == 0.0
    nan_tail = omega[:1000].copy()
    nan_tail[:, 1] = np.nan
    est = run(observer, nan_tail)[-1]
    assert est.status[1] == 'invalid_sample' and not est.underinflated.any()


def test_cornering_gate_holds_the_estimate():
    """With a steering angle that means more lateral acceleration than the limit, every wheel
    is paused ('cornering') and the estimate holds; a non-finite angle skips the gate."""
    omega = synthesize(MODEL.k * np.array([1.0, 1.0, 0.9, 1.0]), 40.0, seed=52)
    observer = TireStiffnessObserver(synthetic_params())
    before = run(observer, omega[:20000])[-1]
    p = observer.params
    speed = float(np.median(omega[:20000])) * p.rolling_radius_m
    # v^2 tan(delta) / L = 2x the default limit
    steering = np.full(BLOCK, math.atan(2.0 * p.max_lateral_accel_mps2 * p.wheelbase_m
                                        / speed ** 2))
    for start in range(20000, 30000, BLOCK):
        during = observer.update(omega[start:start + BLOCK], steering_angle=steering)
    assert set(during.status) == {'cornering'}
    np.testing.assert_array_equal(during.stiffness, before.stiffness)
    assert observer.counters['cornering'][0] == 10000
    steering[:] = math.nan
    after = observer.update(omega[30000:30000 + BLOCK], steering_angle=steering)
    assert observer.counters['steering_invalid'][0] == BLOCK
    assert 'cornering' not in set(after.status)
    with pytest.raises(ValueError, match='steering_angle'):
        observer.update(omega[:10], steering_angle=np.zeros(3))


def test_timing_faults_reset_and_are_counted():
    """Out-of-order/repeated stamps are dropped; gaps and a wrong dt hold the wheels unknown."""
    omega = synthesize(np.full(4, MODEL.k), 20.0, seed=61)
    stamps = np.arange(omega.shape[0]) / FS
    stamps[3000] = stamps[2999]                  # repeated
    stamps[4000] = stamps[3990]                  # out of order
    observer = TireStiffnessObserver(synthetic_params())
    est = observer.update(omega, stamps=stamps)
    counts = observer.counters
    # Each dropped sample leaves a 2 ms interval: a timing break (filters reset), not a glitch.
    assert counts['out_of_order'] == (2, 2, 2, 2) and counts['timing_breaks'] == (2,) * 4
    assert est.valid.all()
    # A gap: every wheel resets and settles; the block right after says why.
    est = observer.update(omega[:2 * BLOCK],
                          stamps=stamps[-1] + 1.0 + np.arange(2 * BLOCK) / FS)
    assert observer.counters['timing_breaks'] == (3,) * 4
    assert est.status == ('timing',) * 4 and not est.underinflated.any()
    # Samples at twice the rate are refused (filters are built for 1 kHz).
    before = observer.counters['resets']
    est = observer.update(omega[:BLOCK], dt=0.5e-3)
    assert observer.counters['timing'][0] >= BLOCK and observer.counters['resets'] == before


def test_tooth_rate_above_sample_rate_masks_wheel():
    """Tooth edges faster than 0.9 x the sample rate lose a held period's tooth count:
    'speed_band'. A window average (the angle domain: these synthetic speeds change at every
    sample) has no count to lose and stays in use.

    120 rad/s with 48 teeth is 917 edges/s at 1 kHz (a 0.3 m wheel at 130 km/h); with the
    tooth correction off the same data are used.
    """
    omega = synthesize(np.full(4, MODEL.k), 3.0, seed=81) + (120.0 - OMEGA0)
    # Fast from the start: the speed form is not judged yet (held period until shown not).
    on = run(TireStiffnessObserver(synthetic_params()), omega)[-1]
    assert on.status == ('speed_band',) * 4 and not on.valid.any()
    off = run(TireStiffnessObserver(synthetic_params(tooth_correction=False)), omega)[-1]
    assert 'speed_band' not in off.status
    observer = TireStiffnessObserver(synthetic_params())
    run(observer, synthesize(np.full(4, MODEL.k), 2.0, seed=82))
    assert observer.tooth_angle_mode.all()
    resets = observer.counters['resets']
    assert 'speed_band' not in run(observer, omega)[-1].status
    assert observer.counters['resets'] == resets


def test_calibration_roundtrip_and_corrupt_dict_refused():
    """The calibration survives JSON; corrupt or mismatching dicts raise ValueError."""
    omega = synthesize(np.full(4, MODEL.k), 30.0, seed=71)
    observer = TireStiffnessObserver(synthetic_params(calibration_s=20.0))
    with pytest.raises(ValueError, match='not all tires'):
        observer.calibration_state()
    observer.start_calibration()
    est = run(observer, omega)[-1]
    state = json.loads(json.dumps(observer.calibration_state()))
    other = TireStiffnessObserver(synthetic_params(calibration_s=20.0))
    other.load_calibration_state(state)
    est2 = run(other, omega)[-1]
    np.testing.assert_allclose(est2.pressure_kpa, est.pressure_kpa, rtol=1e-12)
    np.testing.assert_allclose(est2.pressure_std_kpa, est.pressure_std_kpa, rtol=1e-12)
    # Blocks that agree exactly (a spread of 0) are a calibration a restart reloads.
    other.load_calibration_state({**state, 'k_block_std': [0.0] * 4})
    assert other.estimate().calibrated
    corrupt = [
        ({**state, 'k_block_std': [-1.0] * 4}, 'k_block_std'),
        ({**state, 'k_nominal': state['k_nominal'][:3]}, 'k_nominal'),
        ({**state, 'k_nominal': [float('nan')] * 4}, 'k_nominal'),
        ({**state, 'k_block_std': 'abc'}, 'k_block_std'),
        ({**state, 'version': 99}, 'version'),
        ({k: v for k, v in state.items() if k != 'block_s'}, 'block_s'),
        ({**state, 'model_k': [1.0, 1.0, 1.0, 1.0]}, 'model_k'),
        ({**state, 'k_nominal': [v * 10 for v in state['k_nominal']]}, 'k_nominal'),
        (['not', 'a', 'dict'], 'mapping'),
    ]
    fresh = TireStiffnessObserver(synthetic_params())
    for bad, key in corrupt:
        with pytest.raises(ValueError, match=key):
            fresh.load_calibration_state(bad)  # type: ignore[arg-type]
    assert not fresh.estimate().calibrated


# --------------------------------------------------------------------------------------------
# On the road simulator (docs/targets.md targets, issue 5 checks)

SCENARIOS = Path(__file__).resolve().parents[3] / 'src' / 'tpms_ros' / 'scenarios'
CALIBRATION_S = 30.0
# The calibration starts once the rings are learned (tooth_learned_s, 15 s) and takes 30 s.
STEP_AT_S = 50.0
STEADY_S = 15.0


def _simulate(name: str, duration_s: float, events: tuple[ScenarioEvent, ...]
              ) -> RoadSimulationResult:
    """A shipped scenario with a shorter duration and the given pressure events."""
    scenario = load_scenario(SCENARIOS / f'{name}.yaml')
    return simulate_scenario(dataclasses.replace(scenario, duration_s=duration_s,
                                                 events=events))


def _run_simulated(result: RoadSimulationResult, params: StiffnessObserverParams
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list]:
    """Calibrate over the first CALIBRATION_S, feed 250-sample chunks as the node does.

    Returns:
        (update times, estimated pressure (N, 4), true pressure (N, 4), estimates).
    """
    observer = TireStiffnessObserver(params)
    observer.start_calibration(CALIBRATION_S)
    t, omega = result.wheel_speed_t, result.wheel_speed
    est = [observer.update(omega[s:s + BLOCK], stamps=t[s:s + BLOCK])
           for s in range(0, t.size - BLOCK + 1, BLOCK)]
    stamps = np.array([e.stamp for e in est])
    truth = np.column_stack([np.interp(stamps, result.handling.t, result.pressure_kpa[:, w])
                             for w in range(4)])
    return stamps, np.array([e.pressure_kpa for e in est]), truth, est


@pytest.fixture(scope='module')
def umeno_step() -> RoadSimulationResult:
    """Umeno test, one level: 60 km/h smooth asphalt, FR and RL 200 -> 140 kPa at 50-53 s."""
    return _simulate('umeno_step_60kmh_smooth_asphalt', 115.0, (
        ScenarioEvent('pressure_step', STEP_AT_S, (1, 2), to_kpa=140.0, duration_s=3.0),))


def _steady_rms(result: RoadSimulationResult, params: StiffnessObserverParams) -> np.ndarray:
    """(4,) RMS pressure error over the last STEADY_S (about 4 RLS time constants after the
    step); the calibration must have finished before the step."""
    stamps, pressure, truth, est = _run_simulated(result, params)
    calibrated_at = stamps[np.argmax([e.calibrated and not e.calibrating for e in est])]
    assert est[-1].calibrated and calibrated_at < STEP_AT_S
    steady = stamps > stamps[-1] - STEADY_S
    return np.sqrt(np.mean((pressure[steady] - truth[steady]) ** 2, axis=0))


def test_tooth_corrector_learns_the_simulated_ring_and_is_chunk_invariant():
    """The learned per-tooth pattern is the simulated ring's spacing error; chunking is moot.

    The simulator's tooth k spans ``pitch + e_(k+1) - e_k``, so its held speed is off by
    ``-log(1 + (e_(k+1) - e_k) / pitch)``; the learned pattern must match it up to the unknown
    ring angle (a cyclic shift).
    """
    result = _simulate('umeno_step_60kmh_smooth_asphalt', 15.0, ())
    speed = result.wheel_speed
    reference = sig.sosfiltfilt(sig.butter(2, 2.0, fs=FS, output='sos'), speed, axis=0)
    learn = np.ones(speed.shape, dtype=bool)
    whole = ToothErrorCorrector(4, 48, FS, 30.0, 0.5, BLOCK, learned_s=10.0)
    out_whole, learned_whole = whole.process(speed, reference, learn)
    parts = ToothErrorCorrector(4, 48, FS, 30.0, 0.5, BLOCK, learned_s=10.0)
    rng = np.random.default_rng(7)
    cuts = np.sort(rng.choice(np.arange(1, speed.shape[0]), 60, replace=False))
    out_parts, learned_parts = map(np.concatenate, zip(*[
        parts.process(speed[a:b], reference[a:b], learn[a:b])
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, speed.shape[0]], strict=True)],
        strict=True))
    np.testing.assert_allclose(out_parts, out_whole, rtol=1e-12)
    np.testing.assert_array_equal(learned_parts, learned_whole)
    pitch = 2 * np.pi / 48
    for w in range(4):
        error = result.tooth_error[w]
        want = -np.log1p((np.roll(error, -1) - error) / pitch)
        got = whole.pattern[w]
        best = max(np.corrcoef(np.roll(got, k), want)[0, 1] for k in range(48))
        # measured: 0.989-0.998 after 15 s; rms ratio 1.00-1.03
        assert best > 0.97, (w, best)
        assert got.std() == pytest.approx(want.std(), rel=0.1)


RING_TEETH, RING_RADIUS_M = 48, 0.3


def _ring_drive(knots_s: list[float], knots_kmh: list[float]) -> tuple[np.ndarray, np.ndarray]:
    """Held tooth periods (1 us timer) of four 0.2 %-rms rings over a speed profile through the
    knots, with a small 40 Hz wobble: (omega (n, 4), each ring's pattern as a speed error per
    tooth, -log(1 + (e_(k+1) - e_k) / pitch), (4, teeth))."""
    pitch = 2.0 * np.pi / RING_TEETH
    t = np.arange(0.0, knots_s[-1], 5e-5)
    t_out = np.arange(0.01, knots_s[-1], 1.0 / FS)
    rng = np.random.default_rng(21)
    rim = np.interp(t, knots_s, knots_kmh) / 3.6 / RING_RADIUS_M
    errors = rng.normal(0.0, 0.002 * pitch, (4, RING_TEETH))
    errors -= errors.mean(axis=1, keepdims=True)
    omega = np.column_stack([
        encoder_wheel_speed(t, rim * (1.0 + 0.0005 * np.sin(2 * np.pi * 40.0 * t + w)),
                            t_out, errors[w], float(rng.uniform(0.0, pitch)), 1e-6)
        for w in range(4)])
    return omega, -np.log1p((np.roll(errors, -1, axis=1) - errors) / pitch)


def _pattern_match(learned: np.ndarray, want: np.ndarray) -> float:
    """Correlation of a learned pattern with the ring's at the best cyclic shift."""
    return max(np.corrcoef(np.roll(learned, k), want)[0, 1] for k in range(want.size))


def test_the_tooth_pattern_learns_in_the_speed_band_only():
    """Issue 21 (held-out car 21021, urban): below the speed band the low-passed reference the
    pattern is measured against lags the speed, at a crawl by far more than a tooth's error,
    and a few teeth took ratios of order 1. Ten seconds at 10 km/h (below ``speed_min_kmh``)
    teach the pattern nothing; twenty seconds at 60 km/h teach it the ring.
    """
    omega, want = _ring_drive([0.0, 10.0, 12.0, 32.0], [10.0, 10.0, 60.0, 60.0])
    observer = TireStiffnessObserver(StiffnessObserverParams(encoder_teeth=RING_TEETH,
                                                             rolling_radius_m=RING_RADIUS_M))
    slow = int(10.0 * FS)
    run(observer, omega[:slow])
    assert not observer.tooth_pattern.any()
    run(observer, omega[slow:])
    learned = observer.tooth_pattern
    assert observer.counters['resets'] == (1, 1, 1, 1)     # the slow wheels were no stuck ones
    for w in range(4):
        assert _pattern_match(learned[w], want[w]) > 0.95, w


def test_a_crawl_leaves_the_learned_tooth_pattern_alone():
    """Issue 21 (urban drives): a crawl at 2 km/h between two stretches at 60 km/h.

    Each ring's learned pattern must come out of it as it went in: the same tooth count (no
    reset, no slip) and the same pattern. Braking to the crawl, each held reading lasts the
    next, longer tooth period; counted by the held value's integral the count slipped and the
    pattern came out correlated 0.77-0.80 with the ring (measured), two alignments mixed.
    """
    omega, want = _ring_drive([0.0, 20.0, 26.0, 30.0, 38.0, 48.0],
                              [60.0, 60.0, 2.0, 2.0, 60.0, 60.0])
    observer = TireStiffnessObserver(StiffnessObserverParams(encoder_teeth=RING_TEETH,
                                                             rolling_radius_m=RING_RADIUS_M))
    before_crawl = int(20.0 * FS)
    run(observer, omega[:before_crawl])
    before = observer.tooth_pattern
    run(observer, omega[before_crawl:])
    after = observer.tooth_pattern
    assert observer.counters['resets'] == (1, 1, 1, 1)     # the start only
    for w in range(4):
        assert _pattern_match(after[w], want[w]) > 0.98, w      # measured 0.995-0.998
        # the same count before and after: no cyclic shift between the two patterns
        assert np.corrcoef(before[w], after[w])[0, 1] > 0.98, w


def test_umeno_step_non_driven_meets_target_and_tooth_correction_earns_its_place(umeno_step):
    """FR (non-driven) 200 -> 140 kPa on the simulator: steady-state error < 10 kPa.

    FL is unchanged (no cross-talk: within 10 kPa). Without the tooth-error correction the
    ring's spacing error flattens the spectrum and FR reads a fraction of the drop.
    """
    fixed = _steady_rms(umeno_step, StiffnessObserverParams(driven_axle='rear'))
    # measured RMS (kPa, FL FR): 0.8, 1.2
    assert fixed[1] < 10.0 and fixed[0] < 10.0, fixed
    raw = _steady_rms(umeno_step, StiffnessObserverParams(driven_axle='rear',
                                                          tooth_correction=False))
    # measured RMS without tooth correction (FL FR): 2.3, 32.2
    assert raw[1] > 3.0 * fixed[1], raw


def test_umeno_step_driven_wheel_compensation_earns_its_place(umeno_step):
    """RL (driven) 200 -> 140 kPa: with the partner compensation both driven wheels are within
    10 kPa; uncompensated RL is visibly worse.

    Known limit of the paper's difference form (asserted so a change shows): the driveline
    torque acts on the rims, so once RL is soft it reaches the two rims through different
    dynamics and also twists the regressors; ``wL - wR`` then leaves a driven wheel more than
    10 kPa off (RL here; RR ~12 kPa low before the tooth pattern was waited for).
    """
    partner = _steady_rms(umeno_step, StiffnessObserverParams(driven_axle='rear'))
    difference = _steady_rms(umeno_step, StiffnessObserverParams(
        driven_axle='rear', drive_compensation='difference'))
    none = _steady_rms(umeno_step, StiffnessObserverParams(driven_axle='none'))
    # measured RMS (kPa, RL RR): partner 1.7 5.2, difference 13.9 8.1, uncompensated 21.5 7.8
    assert np.all(partner[2:] < 10.0), partner
    assert none[2] > 3.0 * partner[2], none
    assert difference[2:].max() > 10.0, difference


@pytest.mark.parametrize('drop_kpa', [30.0, 50.0])
def test_four_tire_diffusion_flagged_on_all_four_on_simulator(drop_kpa):
    """Equal loss on all four tires (15 % and 25 %), 80 km/h with curves: all four flagged at
    the default threshold (0.9: warn 20 kPa below placard). The relative (radius-comparison)
    methods cannot see an equal loss at all.
    """
    result = _simulate('diffusion_15pct', 90.0, (
        ScenarioEvent('pressure_step', STEP_AT_S, (0, 1, 2, 3), to_kpa=200.0 - drop_kpa,
                      duration_s=5.0),))
    params = StiffnessObserverParams(driven_axle='rear')
    stamps, pressure, truth, est = _run_simulated(result, params)
    before = (stamps > CALIBRATION_S + 1.0) & (stamps < STEP_AT_S)
    after = stamps > stamps[-1] - 10.0
    flags = np.array([e.underinflated for e in est])
    assert not flags[before].any()
    # measured: flagged in every update of the last 10 s on all four tires, first flags
    # 10-20 s after the step starts; mean |error| 0.7-3.5 kPa
    assert flags[after].mean(axis=0).min() > 0.9, flags[after].mean(axis=0)
    assert np.all(np.abs(pressure[after] - truth[after]).mean(axis=0) < 10.0)


def test_stored_calibration_is_checked_and_one_from_other_tires_refused():
    """A loaded calibration is checked over ``calibration_check_s`` of estimates (tires
    'checking_calibration', unknown) before it is used: this data's own is then used; one
    whose stored stiffness is twice these tires' (resonance ratio 0.71, other tires) is
    refused, the tires uncalibrated: never low."""
    params = synthetic_params(calibration_s=20.0, calibration_check_s=5.0)
    omega = synthesize(np.full(4, MODEL.k), 30.0, seed=81)
    observer = TireStiffnessObserver(params)
    observer.start_calibration()
    run(observer, omega)
    state = observer.calibration_state()

    same = TireStiffnessObserver(params)
    same.load_calibration_state(state)
    early = run(same, omega[:int(15 * FS)])[-1]   # converged at ~13 s
    assert same.calibration_check.pending
    assert 'checking_calibration' in early.status and not early.underinflated.any()
    assert not np.any(early.valid & (np.array(early.status) == 'checking_calibration'))
    last = run(same, omega[int(15 * FS):])[-1]
    assert not same.calibration_check.pending and same.calibration_check.misfit == ''
    assert last.calibrated and last.valid.all()

    other = TireStiffnessObserver(params)
    other.load_calibration_state({**state, 'k_nominal': [2.0 * k for k in state['k_nominal']]})
    last = run(other, omega)[-1]
    assert 'does not fit these tires' in other.calibration_check.misfit
    assert 'median resonance ratio 0.7' in other.calibration_check.misfit
    assert not last.wheel_calibrated.any() and not last.underinflated.any()
    assert np.all(last.confidence == 0.0)
