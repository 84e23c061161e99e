"""The creep estimator's processor, ROS-free: built from parameter values, fed a recording's
messages as the offline engine feeds them."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rail_monitor_ros.core.creep_ekf import CreepEkf, CreepEkfParams, lateral_states_measurement
from rail_monitor_ros.processing.creep_estimator import (
    CREEP,
    LATERAL_FIELDS,
    LATERAL_STATES,
    TRACK,
    make_processor,
)
from vehicle_monitor_common.bag_io import read_messages
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.processing import ERROR, OK, WARN

BAG = Path(__file__).resolve().parents[3] / 'bags' / 'rail_creep_steps'
N = 600        # 3 s of the recording


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)


def _recording(topics: list[str]) -> list[tuple[str, Any]]:
    out, count = [], 0
    for topic, _, _, msg in read_messages(BAG, topics):
        count += topic in ('/rail/lateral_states', '/rail/bogie/imu')
        if count > N:
            break
        out.append((topic.lstrip('/'), msg))
    return out


def test_processor_is_the_core_on_the_recorded_samples() -> None:
    """Pattern C: one output per lateral-states sample with its stamp, equal to the core fed
    the same measurement and track vectors (the track of a sample paired by stamp; the first
    sample is recorded before the first track message, when the track stream is not yet
    alive, so it goes on without)."""
    processor = make_processor({}, '/creep_estimator')
    messages = _recording(['/rail/lateral_states', '/rail/track_irregularity'])
    outputs = [o for topic, msg in messages for o in processor.process(topic, msg)]
    lateral = [m for t, m in messages if t == LATERAL_STATES]
    tracks = {_stamp(m): m for t, m in messages if t == TRACK}
    assert [o.stamp_ns for o in outputs] == [_stamp(m) for m in lateral]
    assert all(o.topic == CREEP for o in outputs)
    ekf = CreepEkf(CreepEkfParams())
    expected = []
    for k, msg in enumerate(lateral):
        fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                  for name in LATERAL_FIELDS}
        z = lateral_states_measurement(fields, 'C')[0]
        track = tracks.get(_stamp(msg)) if k > 0 else None
        u = None if track is None else np.concatenate(
            [track.lateral_alignment[:2], track.lateral_alignment_rate[:2]])
        expected.append(ekf.step(z, u).creep_factor)
    np.testing.assert_allclose([o.fields['creep_factor'] for o in outputs], expected,
                               rtol=1e-12)
    counts = processor.counts
    assert counts['known_input'] == len(lateral) - 1 and counts['unpaired'] == 0
    assert processor.status(0).values['track_input'] == 'known'


def test_pattern_d_pairs_the_imus() -> None:
    """Pattern D: bogie and body IMU paired by stamp (imu_pairing), one output per bogie
    sample, none unpaired, the track known."""
    processor = make_processor({'pattern': 'D'}, '/creep_estimator_imu')
    messages = _recording(['/rail/bogie/imu', '/rail/body/imu', '/rail/track_irregularity'])
    outputs = [o for topic, msg in messages for o in processor.process(topic, msg)]
    bogie = [_stamp(m) for t, m in messages if t == 'rail/bogie/imu']
    # The last sample waits for a later stamp of the body stream.
    assert [o.stamp_ns for o in outputs] == bogie[:len(outputs)] and len(outputs) >= N - 1
    assert processor.counts['unpaired'] == 0 and processor.counts['unknown_input'] <= 1
    assert all(0.05 <= o.fields['creep_factor'] <= 2.0 for o in outputs)


def test_missing_samples_bridged_and_long_gap_resets() -> None:
    """Data time is the core's: 5 missing samples are predicted through, a 1 s gap resets."""
    processor = make_processor({'use_track_input': False}, '/creep_estimator')
    lateral = [m for t, m in _recording(['/rail/lateral_states'])]
    for k, msg in enumerate(lateral):
        if 100 <= k < 105:
            continue
        if k >= 300:
            msg.header.stamp.sec += 1
        processor.process(LATERAL_STATES, msg)
    counts = processor.counts
    assert counts['predicted_missing'] == 5 and counts['gap_resets'] == 1
    assert counts['processed'] == len(lateral) - 5


def test_bad_values_are_refused() -> None:
    """A value its definition refuses, or an inconsistent set, is a ConfigurationError naming
    the node and the parameter."""
    with pytest.raises(ConfigurationError, match='/creep_estimator.*min_creep_factor'):
        make_processor({'min_creep_factor': 1.5, 'max_creep_factor': 1.0}, '/creep_estimator')
    with pytest.raises(ConfigurationError, match='/creep_estimator.*wheelset_mass must be > 0'):
        make_processor({'vehicle.wheelset_mass': -1.0}, '/creep_estimator')


def _with_nan(msg: Any, **fields: Any) -> Any:
    out = copy.deepcopy(msg)
    for name, index in fields.items():
        if index is None:
            setattr(out, name, math.nan)
        else:
            values = np.array(getattr(out, name), dtype=float)
            values[index] = math.nan
            setattr(out, name, values)
    return out


def test_pattern_without_its_fields_is_an_error_until_they_return() -> None:
    """Pattern C (SPEC section 6: bogie and body lateral displacement and velocity): NaN in a
    field it does not read (bogie and body yaw) changes nothing; NaN in one it reads rejects the
    sample and the status is ERROR naming the pattern and the missing fields; once they arrive
    again the status recovers (WARN while the std stays widened, then OK)."""
    messages = _recording(['/rail/lateral_states', '/rail/track_irregularity'])
    clean = make_processor({}, '/creep_estimator')
    unread = make_processor({}, '/creep_estimator')
    missing = make_processor({}, '/creep_estimator')
    levels: list[tuple[int, str]] = []
    index = 0
    for topic, msg in messages:
        clean_out = clean.process(topic, msg)
        if topic != LATERAL_STATES:
            unread.process(topic, msg)
            missing.process(topic, msg)
            continue
        index += 1
        other = _with_nan(msg, bogie_yaw=[0, 1], bogie_yaw_rate=[0, 1], body_yaw=None,
                          body_yaw_rate=None, wheelset_lateral=[0, 1, 2, 3])
        assert [o.fields for o in unread.process(topic, other)] == \
            [o.fields for o in clean_out]
        fed = msg if not 200 <= index < 300 else _with_nan(msg, bogie_lateral=[0],
                                                           body_lateral_rate=None)
        missing.process(topic, fed)
        if index % 50 == 0:
            status = missing.status(_stamp(msg))
            levels.append((status.level, status.message))
    assert unread.status(0).level == OK
    # Statuses after every 50th sample; the last one in is processed once the next arrives.
    assert all(level == OK for level, _ in levels[:4])         # samples 50-200
    for level, message in levels[4:6]:                         # samples 250, 300
        assert level == ERROR
        assert 'pattern C' in message and 'bogie_lateral[0]' in message
        assert 'body_lateral_rate' in message and 'body_yaw' not in message
    assert all(level == WARN for level, _ in levels[6:9])      # rejections, recovering
    assert 'recovering' in levels[7][1]
    assert all(level == OK for level, _ in levels[9:])         # samples 500 on
    assert missing.counts['missing_fields'] == 100


@pytest.mark.parametrize('model, pair', [('full', slice(0, 2)), ('end', slice(2, 4))])
def test_the_rear_bogie_takes_the_track_its_model_needs(model: str, pair: slice) -> None:
    """Monitoring the rear bogie, the end model takes the rear pair's published track; the
    full model the front pair's, whose track the rear wheelsets run on a wheelbase later
    (core.creep_ekf.track_wheelsets)."""
    processor = make_processor({'bogie': 'rear', 'model': model}, '/creep_estimator')
    messages = _recording(['/rail/lateral_states', '/rail/track_irregularity'])
    outputs = [o for topic, msg in messages for o in processor.process(topic, msg)]
    lateral = [m for t, m in messages if t == LATERAL_STATES]
    tracks = {_stamp(m): m for t, m in messages if t == TRACK}
    ekf = CreepEkf(CreepEkfParams(bogie='rear', model=model))
    expected = []
    for k, msg in enumerate(lateral):
        fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                  for name in LATERAL_FIELDS}
        z = lateral_states_measurement(fields, 'C', 'rear', model=model)[0]
        track = tracks.get(_stamp(msg)) if k > 0 else None
        u = None if track is None else np.concatenate(
            [track.lateral_alignment[pair], track.lateral_alignment_rate[pair]])
        expected.append(ekf.step(z, u).creep_factor)
    np.testing.assert_allclose([o.fields['creep_factor'] for o in outputs], expected,
                               rtol=1e-12)
