"""Fault injection on the lateral force observer's processor (issue 20).

``bags/road_kim_huh_lateral`` (10 s: the paper's lane change), IMU, wheel speeds and driver
inputs, with the shipped defaults. Each fault class is spliced into 4-5 s of data time (on the
input it concerns), clean data follow. Per class: no exception; the status names the fault at
its level; no ``within_validity`` flag dropped that the clean run keeps; nothing non-finite
published; no force published further off the clean run than ``FALSE`` of its peak; the lateral
forces back within ``TOL`` of the peak within ``RECOVERY_S`` after the fault ends; the status
clear again at the end. The measured times are printed (``-s``) and documented in
docs/methods/lateral_force_observer.md.
"""

from __future__ import annotations

import copy
from typing import Any

from harness import (
    BAGS,
    TIMING_FAULTS,
    Run,
    Sample,
    loop,
    on_wheel,
    recorded_stream,
    run,
    set_values,
    shift_stamps,
    stamp_of,
    truncated_payload,
    value_faults,
    window,
)
import numpy as np
import pytest

from tpms_ros.processing.lateral_force_observer import TIRE_FORCES, make_processor
from vehicle_monitor_common.processing import ERROR, WARN

BAG = BAGS / 'road_kim_huh_lateral'
TOPICS = {'/vehicle/imu': 'vehicle/imu', '/vehicle/wheel_speeds': 'vehicle/wheel_speeds',
          '/vehicle/driver_inputs': 'vehicle/driver_inputs'}
IMU, WHEELS, DRIVER = 'vehicle/imu', 'vehicle/wheel_speeds', 'vehicle/driver_inputs'
FAULT_START_S, FAULT_S = 4.0, 1.0
TOL = 0.05      # back: lateral forces within this fraction of the clean run's peak |fy|
FALSE = 0.25    # never published further off than this fraction of the peak
RECOVERY_S = 2.0


@pytest.fixture(scope='module')
def stream() -> list[Sample]:
    """The clean input stream."""
    return recorded_stream(BAG, TOPICS)


@pytest.fixture(scope='module')
def clean(stream: list[Sample]) -> Run:
    """The clean run (the reference)."""
    return run(make_processor({}, '/lateral_force_observer'), stream, status_every=10**9)




def frozen_imu(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """Every IMU channel holds its value from the window's first sample (a frozen IMU)."""
    if not indices:
        return stream
    first = stream[indices[0]].message
    held = (first.linear_acceleration.x, first.linear_acceleration.y,
            first.angular_velocity.x, first.angular_velocity.z)
    out = list(stream)
    for i in indices:
        sample = copy.deepcopy(stream[i])
        acc, rate = sample.message.linear_acceleration, sample.message.angular_velocity
        acc.x, acc.y, rate.x, rate.z = held
        out[i] = sample
    return out


def wrong_torque_size(stream: list[Sample], indices: list[int]) -> list[Sample]:
    """Driver inputs with three wheel torques (a wrong array size in a message)."""
    return set_values('wheel_torque', lambda old, k: np.asarray(old)[:3])(stream, indices)


WHEEL = value_faults('omega', 60.0)
AY = value_faults('linear_acceleration.y', 3.0)
# fault class -> (fault, input it hits, status text, status level)
CASES: dict[str, tuple[Any, str, str, int]] = {
    'wheel_nan': (on_wheel(WHEEL['nan']), WHEELS, 'bad wheel speeds', ERROR),
    'wheel_inf': (on_wheel(WHEEL['inf']), WHEELS, 'bad wheel speeds', ERROR),
    'wheel_negative': (on_wheel(WHEEL['negative']), WHEELS, 'bad wheel speeds', ERROR),
    'wheel_absurd': (on_wheel(WHEEL['absurd']), WHEELS, 'bad wheel speeds', ERROR),
    'wheel_dead': (on_wheel(WHEEL['dead']), WHEELS, 'bad wheel speeds', ERROR),
    'imu_nan': (AY['nan'], IMU, 'rejected by the filter', WARN),
    'imu_absurd': (AY['absurd'], IMU, 'rejected by the filter', WARN),
    'imu_frozen': (frozen_imu, IMU, 'IMU frozen', ERROR),
    'repeated_stamps': (TIMING_FAULTS['repeated_stamps'], IMU, 'imu_repeated', WARN),
    'out_of_order': (TIMING_FAULTS['out_of_order'], IMU, 'imu_out_of_order', WARN),
    'future_stamp': (shift_stamps(10_000.0), IMU, 'imu_future_stamp', WARN),
    'backward_jump': (loop, IMU, 'time jump', WARN),
    'gap': (TIMING_FAULTS['gap'], WHEELS, 'stale_wheel_speeds', WARN),
    'rate_burst': (TIMING_FAULTS['rate_burst'], WHEELS, 'rate burst', WARN),
    'wrong_size': (truncated_payload, WHEELS, 'wheel_speeds_malformed', WARN),
    'torque_wrong_size': (wrong_torque_size, DRIVER, 'driver_inputs_invalid', WARN),
}


def _fy(outputs: list[Any]) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([o.stamp_ns for o in outputs], dtype=np.int64),
            np.array([o.fields['fy'] for o in outputs], dtype=float))


@pytest.mark.parametrize('name', list(CASES))
def test_fault_is_named_never_false_and_recovers(name: str, stream: list[Sample],
                                                 clean: Run) -> None:
    """One fault class over 1 s, then clean data (see the module docstring)."""
    fault, topic, text, level = CASES[name]
    indices = window(stream, topic, FAULT_START_S, FAULT_S)
    t0 = stream[0].log_ns
    if name == 'backward_jump':
        indices = list(range(indices[0], len(stream)))
    elif name == 'future_stamp':
        indices = indices[:1]
    faulted = fault(stream, indices)
    # the status every IMU period (as the node's timer would see the events)
    result = run(make_processor({}, '/lateral_force_observer'), faulted, status_every=12)
    far = t0 + 10**12
    start_ns = t0 + round(FAULT_START_S * 1e9)
    end_ns = t0 + round((FAULT_START_S + FAULT_S) * 1e9) if len(indices) > 1 else start_ns
    reference = clean.of(TIRE_FORCES)
    if name == 'backward_jump':
        start_ns = end_ns = stamp_of(faulted[indices[0]].message)
        named = [s for ns, s in result.statuses if ns >= start_ns]
        after = [o for o in result.of(TIRE_FORCES) if o.stamp_ns >= start_ns]
    else:
        named = [s for ns, s in result.statuses
                 if start_ns <= ns <= end_ns + 1_000_000_000 or ns > far]
        after = [o for o in result.of(TIRE_FORCES) if start_ns <= o.stamp_ns < far]
    if text:
        assert any(text in s.message and s.level >= level for s in named), (
            name, {s.message for s in named})
    for o in result.of(TIRE_FORCES):
        values = [*o.fields['fx'], *o.fields['fy'], *o.fields['fz'], o.fields['fy_front'],
                  o.fields['fy_rear']]
        assert np.all(np.isfinite(values)), (name, o.stamp_ns)
    ref_stamps, ref_fy = _fy(reference)
    peak = np.abs(ref_fy).max()
    ref_validity = {o.stamp_ns: o.fields['within_validity'] for o in reference}
    assert all(o.fields['within_validity'] or not ref_validity.get(o.stamp_ns, False)
               for o in result.of(TIRE_FORCES) if o.stamp_ns < far), name
    stamps, fy = _fy(after)
    index = {s: i for i, s in enumerate(ref_stamps.tolist())}
    matched = np.array([s in index for s in stamps.tolist()])
    assert matched.any(), name
    off = np.full(len(stamps), np.inf)
    off[matched] = np.abs(fy[matched] - ref_fy[[index[s] for s in stamps[matched].tolist()]]
                          ).max(axis=1) / peak
    assert np.all(off[matched] <= FALSE), (name, off[matched].max())
    good = matched & (off <= TOL)
    bad_after = np.flatnonzero(~good)
    first_back = bad_after[-1] + 1 if bad_after.size else 0
    assert first_back < len(stamps), f'{name}: never back within {TOL}'
    recovery = max((stamps[first_back] - end_ns) * 1e-9, 0.0)
    final = result.statuses[-1][1]
    print(f'{name}: status {text!r} level {level}; max off {off[matched].max():.3f} of peak; '
          f'back {recovery:.2f} s after the fault; final status {final.level} '
          f'{final.message!r}')
    assert recovery <= RECOVERY_S, (name, recovery)
