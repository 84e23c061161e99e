"""Property-based layer of the fault injection (Hypothesis): random sequences of clean and
faulty input on the cores (vibration, wheel radius, suspension IMM and its fault decision,
creep EKF, lateral force observer), the stamp check and the TPMS voter. Whatever the
sequence, nothing raises, nothing non-finite is reported as known, probabilities stay
probabilities, and no tire is warned that no method knew and flagged."""

from __future__ import annotations

from functools import cache
import math

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np

from rail_monitor_ros.core.fault_decision import FAULT_COMPONENTS, FaultDecision, fault_component
from vehicle_monitor_common.input_health import StampCheck

MS = 1_000_000
SETTINGS = settings(max_examples=40, deadline=None, derandomize=True)

# One step of a stamp stream: a regular sample, a repeat, a late one, a lone far-future one,
# or the start of a new time line (a jump) of some length.
STAMP_EVENTS = st.lists(st.one_of(
    st.just(('next', 0)), st.just(('repeat', 0)), st.just(('late', 0)),
    st.tuples(st.just('future'), st.integers(11, 10**6)),
    st.tuples(st.just('jump'), st.integers(-10**4, 10**4))), min_size=1, max_size=60)


@SETTINGS
@given(STAMP_EVENTS)
def test_stamp_check_never_adopts_a_lone_outlier(events: list[tuple[str, int]]) -> None:
    """Accepted stamps increase between confirmed jumps; a stamp beyond the jump horizon is
    never taken as the new 'now' on its own; every rejection is counted."""
    check = StampCheck(max_gap_s=0.5, confirm_samples=3)
    t, accepted = 10**12, []
    for kind, arg in events:
        if kind == 'next':
            t += MS
            stamp = t
        elif kind == 'repeat':
            stamp = t
        elif kind == 'late':
            stamp = t - 5 * MS
        elif kind == 'future':
            stamp = t + arg * 10**9
        else:
            t += arg * 10**9
            stamp = t
        before = check.last_ns
        verdict = check.check(stamp)
        if verdict in ('ok', 'gap'):
            assert before is None or stamp > before
            accepted.append(stamp)
        elif verdict == 'jump':
            accepted = [stamp]
        else:
            assert check.last_ns == before
        if before is not None and abs(stamp - before) > check.jump_horizon_s * 1e9:
            # beyond the horizon, a stamp is only ever taken as a confirmed jump
            assert verdict not in ('ok', 'gap')
    assert sum(check.rejected.values()) <= len(events)
    assert accepted == sorted(accepted)


# A block of four wheel speeds at 1 kHz: clean road excitation around 60 rad/s, or a fault
# (NaN, inf, negative, zero, absurd, stuck) on some wheels.
FAULT_KINDS = ('clean', 'nan', 'inf', 'negative', 'dead', 'absurd', 'stuck')
FAULTS = st.sampled_from(FAULT_KINDS)
BLOCKS = st.lists(st.tuples(FAULTS, st.integers(0, 15), st.integers(0, 2**16)),
                  min_size=1, max_size=12)


def _block(kind: str, wheels: int, seed: int, n: int = 100) -> np.ndarray:
    rng = np.random.default_rng(seed)
    omega = 60.0 + 0.3 * rng.standard_normal((n, 4))
    mask = np.array([(wheels >> w) & 1 for w in range(4)], dtype=bool)
    value = {'nan': math.nan, 'inf': math.inf, 'negative': -60.0, 'dead': 0.0,
             'absurd': 1e9}.get(kind)
    if kind == 'stuck':
        omega[:, mask] = omega[0, mask]
    elif value is not None:
        omega[:, mask] = value
    return omega


@SETTINGS
@given(BLOCKS)
def test_vibration_analysis_reports_nothing_nonfinite_as_known(
        blocks: list[tuple[str, int, int]]) -> None:
    """Any sequence of clean and faulty blocks: the resonance of a known tire is finite and
    positive, and a tire whose latest block was faulty is not known."""
    from tpms_ros.core.vibration_analysis import VibrationAnalyzer

    analyzer = VibrationAnalyzer()
    for kind, wheels, seed in blocks:
        estimate = analyzer.process(_block(kind, wheels, seed))
        known = np.asarray(estimate.known, dtype=bool)
        frequency = np.asarray(estimate.frequency_hz, dtype=float)
        assert np.all(np.isfinite(frequency[known]) & (frequency[known] > 0))
        if kind in ('nan', 'inf', 'negative', 'dead', 'absurd'):
            faulty = np.array([(wheels >> w) & 1 for w in range(4)], dtype=bool)
            assert not np.any(known & faulty)


@cache
def _imm_and_clean() -> tuple[object, np.ndarray]:
    from rail_monitor_ros.core.suspension_imm import SuspensionImm

    rng = np.random.default_rng(5)
    clean = np.column_stack([0.05 * rng.standard_normal(400), 0.002 * rng.standard_normal(400),
                             0.03 * rng.standard_normal(400)])
    return SuspensionImm(), clean


IMM_SAMPLES = st.lists(st.tuples(
    st.sampled_from(['clean', 'nan', 'inf', 'short', 'missing', 'absurd']),
    st.integers(0, 399)), min_size=1, max_size=40)


@SETTINGS
@given(IMM_SAMPLES)
def test_imm_probabilities_stay_probabilities(samples: list[tuple[str, int]]) -> None:
    """Any sequence of clean and faulty IMU samples: a faulty one is not used, the mode
    probabilities stay finite, in [0, 1] and sum to 1, the state stays finite."""
    imm, clean = _imm_and_clean()
    for kind, index in samples:
        z: object = clean[index].copy()
        if kind == 'nan':
            z = np.array([math.nan, 0.0, 0.0])
        elif kind == 'inf':
            z = np.array([0.0, math.inf, 0.0])
        elif kind == 'short':
            z = clean[index][:2]
        elif kind == 'missing':
            z = None
        elif kind == 'absurd':
            z = clean[index] * 1e12
        step = imm.step(z)  # type: ignore[attr-defined]
        if kind in ('nan', 'inf', 'short', 'missing'):
            assert not step.accepted
        for p in (step.probability, step.smoothed_probability):
            assert np.all(np.isfinite(p)) and np.all((p >= 0) & (p <= 1 + 1e-12))
            assert abs(p.sum() - 1.0) < 1e-9
        assert np.all(np.isfinite(step.state))


# One sample of the suspension decision: the bank's hypotheses (normal first, then ratios on
# the default grid, changing as the adaptive step moves the damper modes) and weights that
# become their smoothed probabilities.
SPRING_GRID = [round(1.0 + 0.1 * k, 1) for k in range(8)]
DAMPER_GRID = [round(1.0 - 0.1 * k, 1) for k in range(8)]
DECISION_SAMPLES = st.lists(st.tuples(
    st.lists(st.tuples(st.sampled_from(SPRING_GRID), st.sampled_from(DAMPER_GRID)),
             min_size=1, max_size=5),
    st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    st.integers(1, 40)), min_size=1, max_size=30)


@SETTINGS
@given(DECISION_SAMPLES)
def test_fault_decision_always_names_a_component_it_can_size(
        samples: list[tuple[list[tuple[float, float]], list[float], int]]) -> None:
    """Whatever hypotheses the bank holds from one sample to the next and whatever their
    probabilities, the decision never raises, and a declared fault is sized by a hypothesis of
    its own component (the compound bank once crashed it when its compound vanished)."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01, clear_time_s=0.1,
                             min_deviation=0.15)
    for keys, weights, repeats in samples:
        hypotheses = list(dict.fromkeys([(1.0, 1.0), *keys]))
        w = np.array(weights[:len(hypotheses)])
        probabilities = w / w.sum() if w.sum() > 0 else np.full(w.size, 1.0 / w.size)
        for _ in range(repeats):
            status = decision.update(hypotheses, probabilities)
            assert status.component in FAULT_COMPONENTS
            assert status.detected == (status.component != '')
            if status.detected:
                assert fault_component(status.spring_ratio, status.damper_ratio) == (
                    status.component)
            assert 0.0 <= status.probability <= 1.0 + 1e-9


# One indication reaching the voter: its method, the time step since the last evaluation, and
# per tire flag, confidence and known (a tire some method never knows is tire 3, RR).
INDICATIONS = st.lists(st.tuples(
    st.sampled_from(['vibration', 'wheel_radius', 'stiffness', 'other']),
    st.sampled_from([0.0, 0.05, 0.5, 3.0, -1.0]),
    st.lists(st.booleans(), min_size=4, max_size=4),
    st.lists(st.floats(0.0, 1.0), min_size=4, max_size=4),
    st.lists(st.booleans(), min_size=4, max_size=4)), min_size=1, max_size=60)


@SETTINGS
@given(INDICATIONS)
def test_voter_never_warns_a_tire_no_method_knows_or_flags(
        indications: list[tuple[str, float, list[bool], list[float], list[bool]]]) -> None:
    """Any sequence of indications (unconfigured methods, repeats, time going back, unknown
    tires, the vibration method needing support): the voter never raises, its output keeps
    its shapes and ranges, and a tire that no method ever flagged while knowing it (here RR,
    never known, and any tire never flagged) is never warned."""
    from tpms_ros.core.tires import TpmsIndication
    from tpms_ros.core.tpms_voting import TpmsVoter, VoterParams

    voter = TpmsVoter(VoterParams(set_on_s=0.0, set_off_s=0.5))
    now, flagged = 0.0, np.zeros(4, dtype=bool)
    for method, step, flags, confidence, known in indications:
        now += step
        known_tires = np.array(known[:3] + [False])
        flagged |= np.array(flags) & known_tires
        result = voter.evaluate(now, [TpmsIndication(method, now, np.array(flags),
                                                     np.array(confidence), known_tires)])
        assert result.warning.shape == result.confidence.shape == (4,)
        assert np.all((result.confidence >= 0.0) & (result.confidence <= 1.0))
        assert result.active == bool(result.warning.any())
        assert not np.any(result.warning & ~flagged)


# One sample of the lateral force observer's inputs: clean driving, or one input broken
# (non-finite, absurd, wrong shape, a zero, negative or huge time step).
OBSERVER_SAMPLES = st.lists(st.tuples(
    st.sampled_from(['clean', 'nan_accel', 'inf_omega', 'absurd_rate', 'short_omega',
                     'zero_dt', 'negative_dt', 'gap_dt', 'absurd_torque', 'nan_steer']),
    st.integers(0, 2**16)), min_size=1, max_size=80)


@SETTINGS
@given(OBSERVER_SAMPLES)
def test_lateral_force_observer_publishes_only_finite_forces(
        samples: list[tuple[str, int]]) -> None:
    """Any sequence of clean and broken samples: the observer never raises, a broken sample
    is not accepted (the last estimate is held), and every estimate it returns is finite."""
    from tpms_ros.core.lateral_force_observer import LateralForceObserver

    observer = LateralForceObserver()
    accepted_any = False
    for kind, seed in samples:
        rng = np.random.default_rng(seed)
        ax, ay, r, p = 0.2 * rng.standard_normal(4)
        omega: list[float] = list(60.0 + 0.2 * rng.standard_normal(4))
        torque, steer, dt = [40.0, 40.0, 0.0, 0.0], 0.01 * rng.standard_normal(), 0.01
        if kind == 'nan_accel':
            ay = math.nan
        elif kind == 'inf_omega':
            omega[2] = math.inf
        elif kind == 'absurd_rate':
            r = 1e6
        elif kind == 'short_omega':
            omega = omega[:3]
        elif kind == 'zero_dt':
            dt = 0.0
        elif kind == 'negative_dt':
            dt = -0.01
        elif kind == 'gap_dt':
            dt = 30.0
        elif kind == 'absurd_torque':
            torque = [1e9, 0.0, 0.0, 0.0]
        elif kind == 'nan_steer':
            steer = math.nan
        estimate = observer.step(ax, ay, r, p, omega, torque, steer, dt)
        broken = kind not in ('clean', 'gap_dt', 'zero_dt', 'negative_dt')
        if estimate is None:
            assert not accepted_any
            continue
        accepted_any = accepted_any or estimate.accepted
        if broken:
            assert not estimate.accepted
        for values in (estimate.fx, estimate.fy, estimate.fz, estimate.state):
            assert np.all(np.isfinite(values))
        assert math.isfinite(estimate.fy_front) and math.isfinite(estimate.fy_rear)


# One sample of the creep estimator (pattern C): a clean measurement, a broken one, a missing
# one, and the track sample beside it clean, broken or absent; now and then a new speed.
CREEP_SAMPLES = st.lists(st.tuples(
    st.sampled_from(['clean', 'nan', 'inf', 'short', 'missing', 'absurd']),
    st.sampled_from(['none', 'clean', 'nan', 'short']),
    st.sampled_from([None, None, None, 25.0, 40.0, 65.0]),
    st.integers(0, 2**16)), min_size=1, max_size=60)


@SETTINGS
@given(CREEP_SAMPLES)
def test_creep_estimator_keeps_a_finite_bounded_factor(
        samples: list[tuple[str, str, float | None, int]]) -> None:
    """Any sequence of clean, broken and missing measurements and track samples, with speed
    changes: the creep EKF never raises, a broken measurement is named as such and not used,
    and the factor and its uncertainty stay finite, the factor within its bounds."""
    from rail_monitor_ros.core.creep_ekf import CreepEkf, measurement_channels

    ekf = CreepEkf()
    n = len(measurement_channels(ekf.params.pattern, ekf.params.model))
    low, high = ekf.params.min_creep_factor, ekf.params.max_creep_factor
    for kind, track_kind, speed, seed in samples:
        rng = np.random.default_rng(seed)
        clean = 1e-4 * rng.standard_normal(n)
        z = {'clean': clean, 'nan': np.where(np.arange(n) == 0, math.nan, clean),
             'inf': np.where(np.arange(n) == n - 1, -math.inf, clean), 'short': clean[:-1],
             'missing': None, 'absurd': np.full(n, 1e6)}[kind]
        track = {'none': None, 'clean': 1e-3 * rng.standard_normal(2),
                 'nan': np.array([math.nan, 0.0]), 'short': np.zeros(1)}[track_kind]
        estimate = ekf.step(z, track, speed)
        if kind in ('nan', 'inf'):
            assert estimate.status == 'non_finite'
        elif kind == 'short':
            assert estimate.status == 'wrong_shape'
        elif kind == 'missing':
            assert estimate.status == 'predicted'
        assert math.isfinite(estimate.creep_factor) and low <= estimate.creep_factor <= high
        assert math.isfinite(estimate.std_dev) and estimate.std_dev >= 0.0


# A chunk of the wheel radius analysis at 100 Hz: clean straight driving, or a fault on some
# wheels (as the vibration blocks), a bad gyro or a bad torque.
RADIUS_CHUNKS = st.lists(st.tuples(
    st.sampled_from(['clean', 'nan', 'inf', 'negative', 'dead', 'absurd', 'stuck',
                     'gyro_nan', 'torque_inf']),
    st.integers(0, 15), st.integers(0, 2**16)), min_size=1, max_size=12)


@SETTINGS
@given(RADIUS_CHUNKS)
def test_wheel_radius_analysis_keeps_finite_offsets(
        chunks: list[tuple[str, int, int]]) -> None:
    """Any sequence of clean and faulty chunks: the wheel radius analysis never raises, counts
    every bad wheel speed, gyro and torque sample it refuses, and its offsets, their
    uncertainties and the gyro offset stay finite."""
    from tpms_ros.core.wheel_radius_analysis import WheelRadiusAnalyzer

    analyzer = WheelRadiusAnalyzer()
    t, n = 0.0, 100
    refused = {'bad_wheel_speed': 0, 'bad_gyro': 0, 'bad_torque': 0}
    for kind, wheels, seed in chunks:
        omega = _block(kind if kind in FAULT_KINDS else 'clean', wheels, seed, n)
        stamps = t + 0.01 * np.arange(1, n + 1)
        t = stamps[-1]
        gyro = 1e-3 * np.random.default_rng(seed).standard_normal(n)
        torque = np.zeros((n, 4))
        if kind == 'gyro_nan':
            gyro[:] = math.nan
        elif kind == 'torque_inf':
            torque[:, 0] = math.inf
        estimate = analyzer.process(stamps, omega, gyro, torque)
        reason = {'nan': 'bad_wheel_speed', 'inf': 'bad_wheel_speed', 'absurd': 'bad_wheel_speed',
                  'negative': 'bad_wheel_speed', 'gyro_nan': 'bad_gyro',
                  'torque_inf': 'bad_torque'}.get(kind)
        if reason is not None:
            # counted per wheel for the wheel speeds, per sample for gyro and torque
            refused[reason] += n * (bin(wheels).count('1') if reason == 'bad_wheel_speed'
                                    else 1)
        for name, count in refused.items():
            assert estimate.counts[name] == count, name
        assert np.all(np.isfinite(estimate.offsets))
        assert np.all(np.isfinite(estimate.offsets_std))
        assert math.isfinite(estimate.gyro_offset)
