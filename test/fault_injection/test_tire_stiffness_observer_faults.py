"""Fault injection on the tire stiffness observer's processor (issue 20).

The first 24 s of ``bags/road_puncture_15pct_fl`` (the puncture comes at ~95 s: every tire at
its nominal pressure here), wheel speeds and driver inputs, with a short-memory configuration
(``FAST``: the defaults are for minutes of driving) and a calibration learned on the same data.
Each fault class is spliced into 8-11 s of data time, clean data follow. Per class: no
exception; the status names the fault at its level; no under-inflation flag; nothing
non-finite published as valid; nothing published as valid off the clean run's pressure by more
than ``FALSE_KPA``; and the estimate back within ``TOL_KPA`` of the clean run (every tire valid
again) within ``RECOVERY_MEMORIES`` LS memories (``recovery_s``) after the fault ends. The
measured times are printed (``-s``) and documented in docs/methods/tire_stiffness_observer.md.
"""

from __future__ import annotations

import math
from typing import Any

from harness import (
    BAGS,
    TIMING_FAULTS,
    Run,
    Sample,
    loop,
    non_finite_valid,
    on_wheel,
    recorded_stream,
    run,
    shift_stamps,
    stamp_of,
    truncated_payload,
    value_faults,
    window,
)
import numpy as np
import pytest

from tpms_ros.processing.tire_stiffness_observer import (
    INDICATION,
    STIFFNESS,
    TireStiffnessObserverProcessor,
    make_processor,
    recovery_s,
)
from vehicle_monitor_common.processing import ERROR, WARN

BAG = BAGS / 'road_puncture_15pct_fl'
TOPICS = {'/vehicle/wheel_speeds': 'vehicle/wheel_speeds',
          '/vehicle/driver_inputs': 'vehicle/driver_inputs'}
WHEELS = 'vehicle/wheel_speeds'
# Short memory (RLS memory 3.3 s) so a 24 s run calibrates, converges and recovers; the car's
# values as in road_graph.yaml, but no driven axle (with block_s 0.1 a calibration on the rear
# axle's difference problem gets k_block_std 0, which load_calibration_state refuses: reported).
FAST = {'block_s': 0.1, 'forgetting_factor': 0.97, 'calibration_s': 4.0, 'tooth_learned_s': 1.0,
        'rolling_radius_m': 0.305, 'wheelbase_m': 2.693, 'calibration_file': 'none',
        # the loaded calibration is this data's own: used at once (the check of a stored
        # calibration has its own tests)
        'calibration_check_s': 0.0,
        # one memory: each output is compared with the clean run's, and with 3.3 s memories
        # a reading restarted by the fault differs from a long-averaged clean one by the short
        # memory's noise (up to 11 kPa); the reading's memory has its own test
        # (test_the_reading_averages_longer_and_the_warning_is_unchanged)
        'steady_forgetting_factor': 0.97}
FAULT_START_S, FAULT_S = 8.0, 3.0
TOL_KPA = 3.0      # back: within this of the clean run (1.5 % of nominal)
FALSE_KPA = 10.0   # never published as valid further off than this (half the 10 % threshold)
# Documented bound (method page): three LS memories (recovery_s) after the fault ends: the
# recovery window, then the blocks around the fault forgotten to within TOL_KPA.
RECOVERY_MEMORIES = 3.0


@pytest.fixture(scope='module')
def stream() -> list[Sample]:
    """The clean input stream."""
    return recorded_stream(BAG, TOPICS, seconds=24.0)


@pytest.fixture(scope='module')
def calibration(stream: list[Sample]) -> dict[str, Any]:
    """The calibration learned on the clean stream."""
    processor = make_processor({**FAST, 'calibrate_on_start': True}, '/tire_stiffness_observer')
    run(processor, stream, status_every=1000)
    state = processor.calibration_state()
    assert state is not None
    return state


def calibrated(calibration: dict[str, Any]) -> TireStiffnessObserverProcessor:
    """A processor with the calibration loaded, as after a restart of the node."""
    processor = make_processor(FAST, '/tire_stiffness_observer')
    processor.load_calibration_state(calibration)
    return processor


@pytest.fixture(scope='module')
def clean(stream: list[Sample], calibration: dict[str, Any]) -> Run:
    """The clean run (the reference)."""
    return run(calibrated(calibration), stream, status_every=100)



VALUE = value_faults('omega', 60.0)
# fault class -> (fault, status text, status level)
CASES: dict[str, tuple[Any, str, int]] = {
    'nan': (VALUE['nan'], 'FL: invalid_sample', ERROR),
    'inf': (VALUE['inf'], 'FL: invalid_sample', ERROR),
    'negative': (VALUE['negative'], 'FL: invalid_sample', ERROR),
    'absurd': (VALUE['absurd'], 'FL: invalid_sample', ERROR),
    'dead': (VALUE['dead'], 'FL: dead_sensor', ERROR),
    'stuck': (VALUE['stuck'], 'FL: stuck_sensor', ERROR),
    'repeated_stamps': (TIMING_FAULTS['repeated_stamps'], 'repeated', WARN),
    'out_of_order': (TIMING_FAULTS['out_of_order'], 'out_of_order', WARN),
    'future_stamp': (shift_stamps(10_000.0), 'future_stamp', WARN),
    'backward_jump': (loop, 'time jump', WARN),
    'gap': (TIMING_FAULTS['gap'], 'timing', ERROR),
    'rate_burst': (TIMING_FAULTS['rate_burst'], 'input rate', ERROR),
    'wrong_size': (truncated_payload, 'malformed', WARN),
}



def _pressures(outputs: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    stamps = np.array([o.stamp_ns for o in outputs], dtype=np.int64)
    pressure = np.array([o.fields['pressure_kpa'] for o in outputs], dtype=float)
    valid = np.array([o.fields['valid'] for o in outputs], dtype=bool)
    return stamps, pressure, valid


@pytest.mark.parametrize('name', list(CASES))
def test_fault_is_named_never_a_tire_fault_and_recovers(
        name: str, stream: list[Sample], calibration: dict[str, Any], clean: Run) -> None:
    """One fault class over 3 s, then clean data (see the module docstring)."""
    fault, text, level = CASES[name]
    if name in VALUE:
        fault = on_wheel(fault)
    indices = window(stream, WHEELS, FAULT_START_S, FAULT_S)
    t0 = stream[0].log_ns
    if name == 'backward_jump':
        indices = list(range(indices[0], len(stream)))
    elif name == 'future_stamp':
        indices = indices[:1]
    faulted = fault(stream, indices)
    processor = calibrated(calibration)
    result = run(processor, faulted, status_every=100)

    start_ns = t0 + round(FAULT_START_S * 1e9)
    end_ns = t0 + round((FAULT_START_S + FAULT_S) * 1e9) if len(indices) > 1 else start_ns
    reference, ref_indications = clean.of(STIFFNESS), clean.of(INDICATION)
    if name == 'backward_jump':
        # The replay is the recording again from its start: the filters restarted on it, so the
        # reference is a fresh start (calibration loaded) on the replayed samples after the
        # jump was confirmed (StampCheck.confirm_samples wheel-speed samples).
        replay = faulted[indices[0]:]
        wheel = [i for i, s in enumerate(replay) if s.topic == WHEELS]
        fresh = run(calibrated(calibration), replay[wheel[4]:], status_every=10**9)
        reference, ref_indications = fresh.of(STIFFNESS), fresh.of(INDICATION)
        start_ns = end_ns = stamp_of(replay[0].message)
        named = [s for ns, s in result.statuses if ns >= start_ns]
        after = [o for o in result.of(STIFFNESS) if o.stamp_ns >= start_ns][1:]
    else:
        # (a far-future sample's status is taken at its own log time)
        named = [s for ns, s in result.statuses
                 if start_ns <= ns <= end_ns + 2_000_000_000 or ns > t0 + 10**12]
        after = [o for o in result.of(STIFFNESS) if o.stamp_ns > start_ns and
                 o.stamp_ns < t0 + 10**12]
    assert any(text in s.message and s.level >= level for s in named), (
        name, {s.message for s in named})

    assert not non_finite_valid(result.of(STIFFNESS), 'pressure_kpa', 'valid'), name

    ref_stamps, ref_p, ref_valid = _pressures(reference)
    stamps, pressure, valid = _pressures(after)
    # Each output against the clean run's output nearest in data time (within one period).
    after_i = np.clip(np.searchsorted(ref_stamps, stamps), 0, len(ref_stamps) - 1)
    before_i = np.clip(after_i - 1, 0, len(ref_stamps) - 1)
    nearer = np.abs(ref_stamps[before_i] - stamps) < np.abs(ref_stamps[after_i] - stamps)
    nearest = np.where(nearer, before_i, after_i)
    close = np.abs(ref_stamps[nearest] - stamps) <= 125_000_000
    # No flag the clean run does not raise (the short calibration's noise flags RR at times).
    flags = {o.stamp_ns: np.asarray(o.fields['underinflated'], dtype=bool)
             for o in result.of(INDICATION)}
    ref_flags = {o.stamp_ns: np.asarray(o.fields['underinflated'], dtype=bool)
                 for o in ref_indications}
    for stamp, near in zip(stamps, ref_stamps[nearest], strict=True):
        raised = flags[stamp] & ~ref_flags.get(int(near), np.zeros(4, dtype=bool))
        assert not raised.any(), (name, stamp, raised)
    # Block boundaries may shift by a sample or a block (a dropped or added sample): the
    # distance to the clean run's outputs within one output period either side.
    around = [np.clip(nearest + k, 0, len(ref_stamps) - 1) for k in (-1, 0, 1)]
    off = np.fmin.reduce(np.stack([np.abs(pressure - ref_p[i]) for i in around]), axis=0)
    false = valid & close[:, None] & ~(off <= FALSE_KPA)
    assert not false.any(), (name, off[false.any(axis=1)])
    back = close[:, None] & valid & ref_valid[nearest] & (off <= TOL_KPA)
    good = back.all(axis=1)
    # Recovered: from the first output on which every later one is back.
    bad_after = np.flatnonzero(~good)
    first_back = bad_after[-1] + 1 if bad_after.size else 0
    assert first_back < len(stamps), f'{name}: never back within {TOL_KPA} kPa'
    recovery = max((stamps[first_back] - end_ns) * 1e-9, 0.0)
    print(f'{name}: status {text!r} level {level}; back within {TOL_KPA} kPa '
          f'{recovery:.2f} s after the fault (recovery_s {recovery_s(processor.params):.2f} s)')
    assert recovery <= RECOVERY_MEMORIES * recovery_s(processor.params), (name, recovery)
    # Warnings clear once their cause has cleared.
    final = result.statuses[-1][1]
    assert final.level == 0 or 'calibrat' in final.message, (name, final.message)
    assert math.isfinite(recovery)


@pytest.mark.parametrize('seed', range(3))
def test_random_fault_sequences(seed: int, stream: list[Sample], calibration: dict[str, Any],
                                clean: Run) -> None:
    """Three fault classes drawn at random (seeded; Hypothesis is not in the environment),
    each over 0.5-2 s somewhere in 5-14 s: no exception, nothing non-finite or far off
    published as valid, no flag the clean run does not raise, back at the end (24 s, ten
    seconds after the last fault: three memories)."""
    rng = np.random.default_rng(seed)
    names = [n for n in CASES if n != 'backward_jump']
    chosen = rng.choice(names, size=3, replace=False)
    starts = np.sort(rng.uniform(5.0, 12.0, size=3))
    faulted = list(stream)
    # Latest first, so the earlier windows' indices still hold after a fault changes the length.
    for name, start in sorted(zip(chosen, starts, strict=True), key=lambda c: -c[1]):
        fault = CASES[str(name)][0]
        fault = on_wheel(fault) if name in VALUE else fault
        indices = window(faulted, WHEELS, float(start), float(rng.uniform(0.5, 2.0)))
        faulted = fault(faulted, indices[:1] if name == 'future_stamp' else indices)
    result = run(calibrated(calibration), faulted, status_every=500)
    outputs = [o for o in result.of(STIFFNESS) if o.stamp_ns < stream[0].log_ns + 10**12]
    assert not non_finite_valid(outputs, 'pressure_kpa', 'valid')
    ref_stamps, ref_p, _ = _pressures(clean.of(STIFFNESS))
    ref_flags = {o.stamp_ns: np.asarray(o.fields['underinflated'], dtype=bool)
                 for o in clean.of(INDICATION)}
    stamps, pressure, valid = _pressures(outputs)
    nearest = np.argmin(np.abs(ref_stamps[None, :] - stamps[:, None]), axis=1)
    around = [np.clip(nearest + k, 0, len(ref_stamps) - 1) for k in (-1, 0, 1)]
    off = np.fmin.reduce(np.stack([np.abs(pressure - ref_p[i]) for i in around]), axis=0)
    assert not (valid & ~(off <= FALSE_KPA)).any(), (seed, list(chosen))
    for o in result.of(INDICATION):
        if o.stamp_ns in ref_flags:
            assert not (np.asarray(o.fields['underinflated']) & ~ref_flags[o.stamp_ns]).any()
    assert valid[-1].all() and (off[-1] <= TOL_KPA).all(), (seed, list(chosen), off[-1])
