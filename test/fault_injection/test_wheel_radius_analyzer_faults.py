"""Fault injection on the wheel-radius analyzer's processor (issue 20, finding 3).

The first 88 s of ``bags/road_puncture_15pct_fl`` (every tire at its nominal pressure there:
the puncture comes at ~90 s), wheel speeds, IMU and driver inputs, with the car's values and
the calibration of road_graph.yaml (80 s) learned on the same data and loaded, as after a
restart of the node. Each fault class is spliced into the wheel speeds at 60-63 s of
data time (value faults on the FL wheel only), clean data follow; a stuck gyro and malformed
driver inputs are injected too. Per class: no exception; the status names the fault at its
level; no under-inflation flag; nothing non-finite published; the learned state (the four pair
offsets and the gyro offset) never off the clean run by more than ``FALSE`` while the fault
lasts or after (finding 3: a dead FL sensor took delta_12 from -0.016 to -1.99 and the gyro
offset to -24.7 rad/s), and back within ``TOL`` (the clean estimate's own swing over the
fault's 3 s) with every tire known again within
``RECOVERY_S`` after the fault ends; the status clear again at the end. The measured times are
printed (``-s``) and documented in docs/methods/wheel_radius_analyzer.md.
"""

from __future__ import annotations

import copy
from typing import Any

from harness import (
    BAGS,
    TIMING_FAULTS,
    Run,
    Sample,
    learned_calibration,
    loop,
    on_wheel,
    recorded_stream,
    restarted,
    run,
    shift_stamps,
    stamp_of,
    stuck,
    truncated_payload,
    value_faults,
    window,
)
import numpy as np
import pytest

from tpms_ros.processing.wheel_radius_analyzer import (
    RADIUS,
    WheelRadiusAnalyzerProcessor,
    make_processor,
)
from vehicle_monitor_common.processing import ERROR, WARN

BAG = BAGS / 'road_puncture_15pct_fl'
TOPICS = {'/vehicle/wheel_speeds': 'vehicle/wheel_speeds', '/vehicle/imu': 'vehicle/imu',
          '/vehicle/driver_inputs': 'vehicle/driver_inputs'}
WHEELS, IMU, DRIVER = 'vehicle/wheel_speeds', 'vehicle/imu', 'vehicle/driver_inputs'
INDICATION = 'tpms/indication/wheel_radius'
# The car of road_graph.yaml; a calibration over 40 s of data (the default is 120 s).
FAST = {'driven_axle': 'rear', 'nominal_radius_m': 0.305, 'track_front_m': 1.568,
        'track_rear_m': 1.52, 'static_load_n': [5340.7, 5340.7, 3553.9, 3553.9],
        'wheel_inertia_kgm2': 2.0, 'cg_height_m': 0.55, 'wheelbase_m': 2.693,
        'calibration_duration_s': 80.0, 'calibration_file': 'none'}
SECONDS = 88.0
FAULT_START_S, FAULT_S = 60.0, 3.0
OFFSETS = ('delta_13', 'delta_24', 'delta_12', 'delta_34', 'gyro_offset')
# Frozen through a fault, the learned state is the one from before it: what the filters would
# have learned during it is lost until the next manoeuvre that makes it observable. Between
# 60 and 63 s the clean run's own estimate swings by 2.3e-3 (delta_34) and 0.026 rad/s (gyro
# offset), so "back" is: every tire known again and within TOL of the clean run (that swing);
# never further off than FALSE (finding 3: delta_12 -1.99 and the gyro offset -24.7 rad/s).
TOL = np.array([3e-3, 3e-3, 3e-3, 3e-3, 4e-2])
FALSE = np.array([5e-3, 5e-3, 5e-3, 5e-3, 5e-2])
# Documented bound (method page): the filters are frozen while a wheel is bad and for
# wheel_recover_s (1 s) after, then back within the tolerance.
RECOVERY_S = 10.0


@pytest.fixture(scope='module')
def stream() -> list[Sample]:
    """The clean input stream."""
    return recorded_stream(BAG, TOPICS, seconds=SECONDS)


@pytest.fixture(scope='module')
def calibration(stream: list[Sample]) -> dict[str, Any]:
    """The calibration learned on the clean stream's first 80 s (road_graph.yaml's)."""
    return learned_calibration(make_processor, FAST, '/wheel_radius_analyzer', stream)


def calibrated(calibration: dict[str, Any]) -> WheelRadiusAnalyzerProcessor:
    """A processor with the calibration loaded, as after a restart of the node."""
    return restarted(make_processor, FAST, '/wheel_radius_analyzer', calibration)


@pytest.fixture(scope='module')
def clean(stream: list[Sample], calibration: dict[str, Any]) -> Run:
    """The clean run (the reference)."""
    return run(calibrated(calibration), stream, status_every=10**9)




def wrong_torque_size(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """Driver inputs with three wheel torques (a wrong array size in a message)."""
    out = list(stream)
    for i in indices:
        sample = copy.deepcopy(stream[i])
        sample.message.wheel_torque = np.asarray(sample.message.wheel_torque)[:3]
        out[i] = sample
    return out


VALUE = value_faults('omega', 60.0)
# fault class -> (fault, input it hits, status text, status level)
CASES: dict[str, tuple[Any, str, str, int]] = {
    'nan': (on_wheel(VALUE['nan']), WHEELS, 'FL (invalid)', ERROR),
    'inf': (on_wheel(VALUE['inf']), WHEELS, 'FL (invalid)', ERROR),
    'negative': (on_wheel(VALUE['negative']), WHEELS, 'FL (invalid)', ERROR),
    'absurd': (on_wheel(VALUE['absurd']), WHEELS, 'FL (invalid)', ERROR),
    'dead': (on_wheel(VALUE['dead']), WHEELS, 'FL (stuck or dead)', ERROR),
    'stuck': (on_wheel(VALUE['stuck']), WHEELS, 'FL (stuck or dead)', ERROR),
    'implausible': (on_wheel(VALUE['negative']), WHEELS, 'FL', ERROR),  # replaced below
    'repeated_stamps': (TIMING_FAULTS['repeated_stamps'], WHEELS, 'repeated', WARN),
    'out_of_order': (TIMING_FAULTS['out_of_order'], WHEELS, 'out_of_order', WARN),
    'future_stamp': (shift_stamps(10_000.0), WHEELS, 'future_stamp', WARN),
    'backward_jump': (loop, WHEELS, 'time jump', WARN),
    'gap': (TIMING_FAULTS['gap'], WHEELS, 'bad wheel speeds', ERROR),   # empty bins
    'rate_burst': (TIMING_FAULTS['rate_burst'], WHEELS, 'rate bursts', WARN),
    'wrong_size': (truncated_payload, WHEELS, 'malformed', WARN),
    'gyro_stuck': (stuck('angular_velocity.z'), IMU, 'gyro stopped', WARN),
    'imu_nan': (value_faults('angular_velocity.z', 0.1)['nan'], IMU, 'non-finite yaw', WARN),
    'torque_wrong_size': (wrong_torque_size, DRIVER, 'wrong_size', WARN),
}


def _scale_fl(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """FL reads 40 % high (a broken sensor: plausible values, off the other three)."""
    out = list(stream)
    for i in indices:
        sample = copy.deepcopy(stream[i])
        omega = np.array(sample.message.omega, dtype=float)
        omega[0] *= 1.4
        sample.message.omega = omega
        out[i] = sample
    return out


CASES['implausible'] = (_scale_fl, WHEELS, 'FL (implausible)', ERROR)


def _series(outputs: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    stamps = np.array([o.stamp_ns for o in outputs], dtype=np.int64)
    values = np.array([[o.fields[k] for k in OFFSETS] for o in outputs], dtype=float)
    return stamps, values


@pytest.mark.parametrize('name', list(CASES))
def test_fault_is_named_never_a_tire_fault_and_recovers(
        name: str, stream: list[Sample], calibration: dict[str, Any], clean: Run) -> None:
    """One fault class over 3 s, then clean data (see the module docstring)."""
    fault, topic, text, level = CASES[name]
    indices = window(stream, topic, FAULT_START_S, FAULT_S)
    t0 = stream[0].log_ns
    if name == 'backward_jump':
        indices = list(range(indices[0], len(stream)))
    elif name == 'future_stamp':
        indices = indices[:1]
    faulted = fault(stream, indices)
    result = run(calibrated(calibration), faulted, status_every=20)
    far = t0 + 10**12
    start_ns = t0 + round(FAULT_START_S * 1e9)
    end_ns = t0 + round((FAULT_START_S + FAULT_S) * 1e9) if len(indices) > 1 else start_ns
    if name == 'backward_jump':
        start_ns = end_ns = stamp_of(faulted[indices[0]].message)
        named = [s for ns, s in result.statuses if ns >= start_ns]
        after = [o for o in result.of(RADIUS) if o.stamp_ns >= start_ns]
    else:
        named = [s for ns, s in result.statuses
                 if start_ns <= ns <= end_ns + 2_000_000_000 or ns > far]
        after = [o for o in result.of(RADIUS) if start_ns < o.stamp_ns < far]
    if text:
        assert any(text in s.message and s.level >= level for s in named), (
            name, {s.message for s in named})
    assert not any(any(o.fields['underinflated']) for o in result.of(INDICATION)), name
    for o in result.of(RADIUS):
        values = [o.fields[k] for k in OFFSETS] + list(o.fields['std_dev'])
        assert np.all(np.isfinite(values)), (name, o.stamp_ns, values)

    ref_stamps, ref = _series(clean.of(RADIUS))
    stamps, values = _series(after)
    if name == 'backward_jump':
        # The replayed data again: the learned offsets kept, compared with the clean run at the
        # same stamps (which had learned less by then: the pair offsets only).
        ref_by_stamp = dict(zip(ref_stamps.tolist(), ref, strict=True))
        matched = [(s, v) for s, v in zip(stamps.tolist(), values, strict=True)
                   if s in ref_by_stamp and s - start_ns >= 20e9]
        assert matched, name
        off = np.array([np.abs(v - ref_by_stamp[s]) for s, v in matched])
        assert np.all(off[:, :4] <= FALSE[:4]), (name, off.max(axis=0))
        known = [o.fields['known'] for o in result.of(INDICATION) if o.stamp_ns >= start_ns]
        first_known = next(i for i, k in enumerate(known) if all(k))
        print(f'{name}: status {text!r} level {level}; every tire known again after '
              f'{first_known} outputs; final {result.statuses[-1][1].message!r}')
        assert result.statuses[-1][1].level == 0, (name, result.statuses[-1][1].message)
        return
    nearest = np.clip(np.searchsorted(ref_stamps, stamps), 0, len(ref_stamps) - 1)
    close = np.abs(ref_stamps[nearest] - stamps) <= 50_000_000
    off = np.abs(values - ref[nearest])
    false = close[:, None] & (off > FALSE)
    assert not false.any(), (name, off[false.any(axis=1)].max(axis=0))
    known = {o.stamp_ns: all(o.fields['known']) for o in result.of(INDICATION)}
    good = close & np.all(off <= TOL, axis=1) & np.array([known[s] for s in stamps])
    bad_after = np.flatnonzero(~good)
    first_back = bad_after[-1] + 1 if bad_after.size else 0
    assert first_back < len(stamps), f'{name}: never back within {TOL}'
    recovery = max((stamps[first_back] - end_ns) * 1e-9, 0.0)
    final = result.statuses[-1][1]
    print(f'{name}: status {text!r} level {level}; max off {off.max(axis=0)}; back '
          f'{recovery:.2f} s after the fault; final status {final.level} {final.message!r}')
    assert recovery <= RECOVERY_S, (name, recovery)
    assert final.level == 0, (name, final.message)


def _later(stream: list[Sample], topic: str, positions: int) -> list[Sample]:
    """The stream with every message of ``topic`` delivered ``positions`` messages of the
    other topics later (a topic that the transport delivers late)."""
    out: list[Sample] = []
    held: list[list[Any]] = []
    for sample in stream:
        if sample.topic == topic:
            held.append([sample, positions])
            continue
        out.append(sample)
        for entry in held:
            entry[1] -= 1
        while held and held[0][1] <= 0:
            out.append(held.pop(0)[0])
    return out + [entry[0] for entry in held]


@pytest.mark.parametrize('late', [WHEELS, IMU, DRIVER])
def test_outputs_do_not_depend_on_the_order_the_topics_arrive_in(late: str) -> None:
    """A topic delivered 30 messages late (as a loaded live graph may): the same outputs to
    the bit. Before bins waited for a driver input past their stamp and chunks were decided
    bin by bin, 120 of the 121 offset outputs of this recording differed (the engine against
    live graph test failed so once under load)."""
    stream = recorded_stream(BAGS / 'road_kim_huh_relation_check', TOPICS)
    values = {**FAST, 'calibration_duration_s': 40.0, 'calibrate_on_start': True}
    outputs = [run(make_processor(values, '/wheel_radius_analyzer'), s,
                   status_every=10**9).outputs for s in (stream, _later(stream, late, 30))]
    assert len(outputs[0]) == len(outputs[1]) > 0
    for first, second in zip(*outputs, strict=True):
        assert (first.topic, first.stamp_ns) == (second.topic, second.stamp_ns)
        for name, value in first.fields.items():
            if isinstance(value, (float, list, tuple)):
                np.testing.assert_array_equal(np.asarray(value, dtype=float),
                                              np.asarray(second.fields[name], dtype=float))

