"""Fault injection on the rail nodes' processors: suspension monitor and creep estimator
(issue 20).

The first 14 s of ``bags/rail_healthy`` (a healthy car at 40 m/s: nominal suspension, creep
factor 1), every input as recorded. Each fault class is spliced into 4-6 s of data time, clean
data follow. Per class: no exception; the status names the fault at WARN or above; no
``fault_detected`` (suspension) / ``low_adhesion`` (creep) the clean run does not raise; nothing
non-finite published; nothing published as a measured estimate (creep: std_dev below
``UNKNOWN_STD``) further than ``FALSE_*`` off the clean run; and the estimates back within
``TOL_*`` of the clean run within the documented recovery time after the fault ends
(``RECOVERY_S``; docs/methods/suspension_monitor.md, creep_estimator.md). The measured times are
printed (``-s``).
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
    recorded_stream,
    run,
    set_values,
    shift_stamps,
    stamp_of,
    stuck,
    value_faults,
    window,
)
import numpy as np
import pytest

from rail_monitor_ros.processing import creep_estimator, suspension_monitor
from vehicle_monitor_common.processing import ERROR, WARN

BAG = BAGS / 'rail_healthy'
TOPICS = {'/rail/bogie/imu': 'rail/bogie/imu', '/rail/body/imu': 'rail/body/imu',
          '/rail/track_irregularity': 'rail/track_irregularity',
          '/rail/lateral_states': 'rail/lateral_states'}
SECONDS = 14.0
FAULT_START_S, FAULT_S = 4.0, 2.0
BODY, BOGIE, TRACK, LATERAL = ('rail/body/imu', 'rail/bogie/imu', 'rail/track_irregularity',
                               'rail/lateral_states')
# Back: within this of the clean run (suspension: spring and damper ratio; creep: c).
TOL = {'suspension_monitor': 0.05, 'creep_estimator': 0.03, 'creep_estimator_imu': 0.05}
# Never published as a measurement further off than this.
FALSE = {'suspension_monitor': 0.2, 'creep_estimator': 0.1, 'creep_estimator_imu': 0.1}
# Documented recovery bounds after the fault ends, s (the method pages).
DETECTION_S = {'suspension_monitor': 0.1, 'creep_estimator': 0.025,
               'creep_estimator_imu': 0.025}
SLACK_S = 0.05
RECOVERY_S = {'suspension_monitor': 2.0, 'creep_estimator': 1.0, 'creep_estimator_imu': 1.0}


def _make(node: str) -> Any:
    if node == 'suspension_monitor':
        return suspension_monitor.make_processor({}, '/suspension_monitor')
    values = {'pattern': 'D'} if node == 'creep_estimator_imu' else {}
    return creep_estimator.make_processor(values, f'/{node}')


@pytest.fixture(scope='module')
def stream() -> list[Sample]:
    """The clean input stream (every rail input)."""
    return recorded_stream(BAG, TOPICS, seconds=SECONDS)


def _for(node: str, stream: list[Sample]) -> list[Sample]:
    inputs = _make(node).inputs
    return [s for s in stream if s.topic in inputs]


_CLEAN: dict[str, Run] = {}


def _clean(node: str, stream: list[Sample]) -> Run:
    if node not in _CLEAN:
        _CLEAN[node] = run(_make(node), _for(node, stream), status_every=10**9)
    return _CLEAN[node]



def _burst(topics: tuple[str, ...]) -> Any:
    """Each sample of the window's topics comes with 9 more, stamped a tenth of that topic's
    period apart (a rate burst: ten times the rate; both IMUs of a pair together)."""
    def apply(stream: list[Sample], indices: list[int]) -> list[Sample]:
        chosen = set(indices)
        t_first, t_last = (stream[indices[0]].log_ns, stream[indices[-1]].log_ns)
        out: list[Sample] = []
        for i, sample in enumerate(stream):
            out.append(sample)
            if sample.topic in topics and (i in chosen or t_first <= sample.log_ns <= t_last):
                nxt = next((s for s in stream[i + 1:] if s.topic == sample.topic), None)
                if nxt is None:
                    continue
                step = (stamp_of(nxt.message) - stamp_of(sample.message)) // 10
                for k in range(1, 10):
                    extra = copy.deepcopy(sample)
                    extra.message.header.stamp.sec, extra.message.header.stamp.nanosec = \
                        divmod(stamp_of(sample.message) + k * step, 1_000_000_000)
                    out.append(extra)
        return out
    return apply


def _one_element(path: str) -> Any:
    """The array at ``path`` has one element only (a wrong array size in the message)."""
    return set_values(path, lambda old, k: np.asarray(old, dtype=float)[:1].copy())


def _cases(node: str) -> dict[str, tuple[str, Any, str]]:
    """fault class -> (topic it hits, fault, text the status names it by)."""
    if node == 'creep_estimator':
        main, path, typical = LATERAL, 'bogie_lateral', 0.005
        value_text = {'nan': 'not fed', 'inf': 'non_finite', 'negative': 'frozen',
                      'absurd': 'rejected', 'dead': 'frozen', 'stuck': 'frozen'}
        wrong_size: tuple[str, Any, str] = (LATERAL, _one_element('bogie_lateral'),
                                            'wrong_size')
    else:
        main, path, typical = BODY, 'linear_acceleration.y', 0.3
        value_text = {'nan': 'non_finite', 'inf': 'non_finite', 'negative': 'frozen',
                      'absurd': 'saturated', 'dead': 'frozen', 'stuck': 'frozen'}
        wrong_size = (TRACK, _one_element('lateral_alignment'), 'track')
    if node == 'creep_estimator_imu':
        # NaN in a channel is the channel not measured: the pattern is not fed (issue 19).
        value_text['nan'] = 'not fed'
    values = value_faults(path, typical)
    cases = {name: (main, fault, value_text[name]) for name, fault in values.items()}
    cases.update({
        'repeated_stamps': (main, TIMING_FAULTS['repeated_stamps'], 'repeated'),
        'out_of_order': (main, TIMING_FAULTS['out_of_order'], 'out_of_order'),
        'future_stamp': (main, shift_stamps(10_000.0), 'future_stamp'),
        'backward_jump': (main, loop, 'time jump'),
        # (pattern D: a silent body IMU leaves the bogie samples unpaired: missing)
        'gap': (main, TIMING_FAULTS['gap'], 'unpaired' if node == 'creep_estimator_imu'
                else 'no '),
        'rate_burst': (main, _burst((main,) if main == LATERAL else (BOGIE, BODY)),
                       'rate_burst (faster than 200 Hz)'),
        'wrong_size': wrong_size,
        'track_stale': (TRACK, TIMING_FAULTS['gap'], 'track'),
        'track_frozen': (TRACK, stuck('lateral_alignment'), 'track'),
    })
    return cases


NODES = ('suspension_monitor', 'creep_estimator', 'creep_estimator_imu')
CASE_NAMES = list(_cases('suspension_monitor'))


def _series(node: str, outputs: list[Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                    np.ndarray]:
    """stamps, estimates (n, k), flags, measured (published as a measurement)."""
    stamps = np.array([o.stamp_ns for o in outputs], dtype=np.int64)
    if node == 'suspension_monitor':
        est = np.array([[o.fields['spring_ratio'], o.fields['damper_ratio']] for o in outputs])
        flags = np.array([o.fields['fault_detected'] for o in outputs], dtype=bool)
        measured = np.ones(len(outputs), dtype=bool)
        every = np.array([np.concatenate([o.fields['probability'],
                                          o.fields['smoothed_probability']])
                          for o in outputs])
        assert np.all(np.isfinite(every))
    else:
        est = np.array([[o.fields['creep_factor']] for o in outputs])
        flags = np.array([o.fields['low_adhesion'] for o in outputs], dtype=bool)
        std = np.array([o.fields['std_dev'] for o in outputs])
        assert np.all(np.isfinite(std))
        measured = std < creep_estimator.UNKNOWN_STD
    assert np.all(np.isfinite(est))
    return stamps, est.reshape(len(outputs), -1), flags, measured


@pytest.mark.parametrize('name', CASE_NAMES)
@pytest.mark.parametrize('node', NODES)
def test_fault_is_named_never_a_vehicle_fault_and_recovers(
        node: str, name: str, stream: list[Sample]) -> None:
    """One fault class over 2 s on one input of one node, then clean data (see the module
    docstring)."""
    clean = _clean(node, stream)
    topic, fault, text = _cases(node)[name]
    inputs = _for(node, stream)
    if topic not in _make(node).inputs:
        pytest.skip(f'{node} has no input {topic}')
    indices = window(inputs, topic, FAULT_START_S, FAULT_S)
    t0 = inputs[0].log_ns
    if name == 'backward_jump':
        indices = list(range(indices[0], len(inputs)))
    elif name == 'future_stamp':
        indices = indices[:1]
    faulted = fault(inputs, indices)
    processor = _make(node)
    result = run(processor, faulted, status_every=1)
    out_topic = next(iter(processor.outputs))
    start_ns = t0 + round(FAULT_START_S * 1e9)
    end_ns = start_ns + round(FAULT_S * 1e9) if len(indices) > 1 else start_ns
    reference = clean.of(out_topic)
    if name == 'backward_jump':
        # The replay is the recording again from its start: the filters restarted on it, so
        # the reference is a fresh start on the replay after the jump was confirmed.
        replay = faulted[indices[0]:]
        driving = [i for i, s in enumerate(replay) if s.topic == topic]
        fresh = run(_make(node), replay[driving[4]:], status_every=10**9)
        reference = fresh.of(out_topic)
        start_ns = end_ns = stamp_of(replay[0].message)
        named = [st for ns, st in result.statuses[indices[0]:]]
        # From the first output after the jump (its stamp goes back); not the run's own start.
        outputs = result.of(out_topic)
        after = outputs[next(i for i in range(1, len(outputs))
                             if outputs[i].stamp_ns < outputs[i - 1].stamp_ns):]
    else:
        named = [st for ns, st in result.statuses
                 if start_ns <= ns <= end_ns + 2_000_000_000 or ns > t0 + 10**12]
        after = [o for o in result.of(out_topic) if start_ns < o.stamp_ns < t0 + 10**12]
    assert any(text in st.message and st.level >= WARN for st in named), (
        node, name, sorted({st.message for st in named}))

    ref_stamps, ref_est, ref_flags, _ = _series(node, reference)
    stamps, est, flags, measured = _series(node, after)
    nearest = np.clip(np.searchsorted(ref_stamps, stamps), 0, len(ref_stamps) - 1)
    close = np.abs(ref_stamps[nearest] - stamps) <= 5_000_000
    # No flag the clean run does not raise.
    assert not (flags & close & ~ref_flags[nearest]).any(), (node, name)
    off = np.abs(est - ref_est[nearest]).max(axis=1)
    # A frozen value is found after frozen_samples (suspension, 0.1 s) / frozen_s (creep,
    # 0.02 s): what was published before is not checked (no flag: the decision's hold time is
    # longer, and the IMM goes back to before the run once it is found).
    found_ns = start_ns + round(DETECTION_S[node] * 1e9) if text == 'frozen' else start_ns
    wrong = measured & close & (off > FALSE[node]) & ~((stamps >= start_ns) & (stamps < found_ns))
    assert not wrong.any(), (node, name, (stamps[wrong][:3] - t0) * 1e-9, off[wrong].max())
    good = close & measured & (off <= TOL[node])
    bad = np.flatnonzero(~good)
    first_back = bad[-1] + 1 if bad.size else 0
    assert first_back < len(stamps), f'{node} {name}: never back within {TOL[node]}'
    recovery = max((stamps[first_back] - end_ns) * 1e-9, 0.0)
    # The estimate itself (published as unknown or not) back within TOL: the filter's settling.
    unsettled = np.flatnonzero(~(close & (off <= TOL[node])))
    first_settled = unsettled[-1] + 1 if unsettled.size else 0
    settle = max((stamps[min(first_settled, len(stamps) - 1)] - end_ns) * 1e-9, 0.0)
    level = max((st.level for st in named if text in st.message), default=-1)
    message = next(st.message for st in named if text in st.message)
    if text == 'not fed':
        # A pattern whose fields are missing is an error (issue 19), never a mere warning.
        assert level == ERROR, (node, name, message)
    print(f'RESULT {node} {name}: level {level} {message!r}; estimate within {TOL[node]} '
          f'{settle:.2f} s, published as measured again {recovery:.2f} s after the fault')
    # (+ SLACK_S: a time jump is confirmed by StampCheck.confirm_samples samples, 5 periods; a
    # burst holds the filter for BURST_PERIODS more periods)
    assert recovery <= RECOVERY_S[node] + SLACK_S, (node, name, recovery)
    # Warnings clear once their cause has cleared.
    final = result.statuses[-1][1]
    assert final.level == 0, (node, name, final.message)


@pytest.mark.parametrize('seed', range(2))
@pytest.mark.parametrize('node', ['suspension_monitor', 'creep_estimator'])
def test_random_fault_sequences(node: str, seed: int, stream: list[Sample]) -> None:
    """Three fault classes drawn at random (seeded; Hypothesis is not in the environment), each
    over 0.3-1 s somewhere in 2-8 s: no exception, nothing non-finite published, no flag the
    clean run does not raise, and at the end (14 s) the estimate within tolerance of the clean
    run and the status OK."""
    rng = np.random.default_rng(seed)
    cases = _cases(node)
    names = [n for n in cases if n != 'backward_jump']
    chosen = rng.choice(names, size=3, replace=False)
    starts = np.sort(rng.uniform(2.0, 8.0, size=3))
    faulted = _for(node, stream)
    # Latest first, so the earlier windows' indices still hold after a fault changes the length.
    for name, start in sorted(zip(chosen, starts, strict=True), key=lambda c: -c[1]):
        topic, fault, _ = cases[str(name)]
        indices = window(faulted, topic, float(start), float(rng.uniform(0.3, 1.0)))
        faulted = fault(faulted, indices[:1] if name == 'future_stamp' else indices)
    processor = _make(node)
    result = run(processor, faulted, status_every=1)
    out_topic = next(iter(processor.outputs))
    t0 = faulted[0].log_ns
    outputs = [o for o in result.of(out_topic) if o.stamp_ns < t0 + 10**12]
    stamps, est, flags, measured = _series(node, outputs)
    ref_stamps, ref_est, ref_flags, _ = _series(node, _clean(node, stream).of(out_topic))
    nearest = np.clip(np.searchsorted(ref_stamps, stamps), 0, len(ref_stamps) - 1)
    assert not (flags & ~ref_flags[nearest]).any(), (seed, list(chosen))
    assert measured[-1] and np.abs(est[-1] - ref_est[nearest[-1]]).max() <= TOL[node], (
        seed, list(chosen))
    assert result.statuses[-1][1].level == 0, (seed, list(chosen), result.statuses[-1][1])
