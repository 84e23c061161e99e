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
    UNKNOWN_STD,
    make_processor,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import simulate, to_topic_series
from vehicle_monitor_common.bag_io import read_messages, series_messages
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
    sample, recorded before the first track message, waits for the speed stream, not heard
    yet, for ``pair_timeout_s`` of data time, and has its track by then)."""
    processor = make_processor({}, '/creep_estimator')
    messages = _recording(['/rail/lateral_states', '/rail/track_irregularity'])
    outputs = [o for topic, msg in messages for o in processor.process(topic, msg)]
    lateral = [m for t, m in messages if t == LATERAL_STATES]
    tracks = {_stamp(m): m for t, m in messages if t == TRACK}
    assert [o.stamp_ns for o in outputs] == [_stamp(m) for m in lateral]
    assert all(o.topic == CREEP for o in outputs)
    ekf = CreepEkf(CreepEkfParams())
    expected = []
    for msg in lateral:
        fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                  for name in LATERAL_FIELDS}
        z = lateral_states_measurement(fields, 'C')[0]
        track = tracks.get(_stamp(msg))
        u = None if track is None else np.concatenate(
            [track.lateral_alignment[:2], track.lateral_alignment_rate[:2]])
        expected.append(ekf.step(z, u).creep_factor)
    np.testing.assert_allclose([o.fields['creep_factor'] for o in outputs], expected,
                               rtol=1e-12)
    counts = processor.counts
    assert counts['known_input'] == len(lateral) and counts['unpaired'] == 0
    values = processor.status(0).values
    assert values['track_input'] == 'known'
    assert (values['changes_detected'], values['changes_dropped']) == (ekf.changes_detected,
                                                                       ekf.changes_dropped)


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
    for msg in lateral:
        fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                  for name in LATERAL_FIELDS}
        z = lateral_states_measurement(fields, 'C', 'rear', model=model)[0]
        track = tracks.get(_stamp(msg))
        u = None if track is None else np.concatenate(
            [track.lateral_alignment[pair], track.lateral_alignment_rate[pair]])
        expected.append(ekf.step(z, u).creep_factor)
    np.testing.assert_allclose([o.fields['creep_factor'] for o in outputs], expected,
                               rtol=1e-12)


def _speed_ramp_messages(topics: tuple[str, ...]) -> tuple[list[tuple[str, Any]], Any]:
    """A car accelerating from 30 to 35 m/s over 3-6 s (c = 1, the track measured), its
    messages in stamp order (the speed, at 20 Hz, before the samples of its stamp), and the
    simulation."""
    result = simulate(rail_scenario_from_dict({
        'duration': 7.0, 'seed': 3, 'initial': {'speed': 30.0},
        'events': [{'time': 3.0, 'speed': 35.0, 'ramp': 3.0}]}))
    series = to_topic_series(result, low_adhesion_threshold=0.5)
    stamped = [(stamp, rank, topic.lstrip('/'), msg)
               for rank, topic in enumerate(topics)
               for stamp, msg in zip(series[topic].stamps_ns, series_messages(series[topic]),
                                     strict=True)]
    stamped.sort(key=lambda item: (item[0], item[1]))
    return [(topic, msg) for _, _, topic, msg in stamped], result


def test_the_model_follows_the_published_speed() -> None:
    """rail/speed (20 Hz) on a car accelerating by 5 m/s: the processor gives the core each
    sample's held speed (outputs equal to the core's, set_speed per sample), and its estimate
    stays right where the same processor without the speed topic, its model at the
    configured 30 m/s, reads the creep factor wrong by the speed's share and more (on nine
    samples in ten at least: its alarms move it across the truth)."""
    messages, result = _speed_ramp_messages(('/rail/speed', '/rail/track_irregularity',
                                             '/rail/lateral_states'))
    config = {'vehicle.speed': 30.0, 'track_map_error_m': 1.0e-5}
    following = make_processor(config, '/creep_estimator')
    fixed = make_processor(config, '/creep_estimator')
    outputs = [o for topic, msg in messages for o in following.process(topic, msg)]
    fixed_outputs = [o for topic, msg in messages if topic != 'rail/speed'
                     for o in fixed.process(topic, msg)]
    ekf = CreepEkf(following.params)
    expected, speed = [], 30.0
    tracks = {_stamp(m): m for t, m in messages if t == TRACK}
    for topic, msg in messages:
        if topic == 'rail/speed':
            speed = msg.twist.linear.x
            continue
        if topic != LATERAL_STATES:
            continue
        ekf.set_speed(speed)
        fields = {name: np.asarray(getattr(msg, name), dtype=float)[None, ...]
                  for name in LATERAL_FIELDS}
        track = tracks[_stamp(msg)]
        expected.append(ekf.step(lateral_states_measurement(fields, 'C')[0], np.concatenate(
            [track.lateral_alignment[:2], track.lateral_alignment_rate[:2]])).creep_factor)
    c = np.array([o.fields['creep_factor'] for o in outputs])
    np.testing.assert_allclose(c, expected, rtol=1e-12)
    assert following.ekf.speed == pytest.approx(35.0)
    assert following.status(0).values['speed_input'] == 'following'
    late = result.time[:c.size] > 5.0          # the speed 33-35 m/s, the estimates settled
    c_fixed = np.array([o.fields['creep_factor'] for o in fixed_outputs])
    assert np.abs(c[late] - 1.0).max() < 0.05
    assert np.mean(np.abs(c_fixed[late] - 1.0) > 0.08) > 0.9


def test_speed_below_the_minimum_holds_and_a_stale_speed_is_reported() -> None:
    """A speed below min_speed_mps (a train standing) holds the estimate as an input fault
    (std widened, status WARN); a speed stream that stops leaves the model at its last speed,
    reported stale; a negative or absurd speed is refused and counted. Not subscribed
    (use_speed_input false), the status says 'disabled'."""
    messages, _ = _speed_ramp_messages(('/rail/speed', '/rail/track_irregularity',
                                        '/rail/lateral_states'))
    processor = make_processor({'vehicle.speed': 30.0}, '/creep_estimator')
    statuses, stds = [], []
    for topic, msg in messages:
        stamp_s = _stamp(msg) * 1e-9
        if topic == 'rail/speed':
            if 1.0 <= stamp_s < 2.0:
                msg.twist.linear.x = 2.0                 # standing
            elif stamp_s >= 4.0:
                if stamp_s < 4.01:
                    msg.twist.linear.x = -1.0            # refused
                elif stamp_s < 4.06:
                    msg.twist.linear.x = 1e6             # refused: beyond the models' range
                else:
                    continue                             # the stream stops
        outputs = processor.process(topic, msg)
        if outputs:
            statuses.append((stamp_s, processor.status(0)))
            stds += [(stamp_s, o.fields['std_dev']) for o in outputs]
    standing = [s for t, s in statuses if 1.1 < t < 2.0]
    assert all('input fault (below_min_speed)' in s.message and s.level == WARN
               for s in standing)
    assert all(std >= UNKNOWN_STD for t, std in stds if 1.1 < t < 2.0)
    assert processor.counts['below_min_speed'] > 150
    assert processor._rejections()['speed_invalid'] == 2
    last = statuses[-1][1]
    assert last.level == WARN and last.message.startswith('speed input stale')
    assert last.values['model_speed'] == pytest.approx(processor.ekf.speed)
    unsubscribed = make_processor({'use_speed_input': False}, '/creep_estimator')
    assert 'rail/speed' not in unsubscribed.inputs
    assert unsubscribed.status(0).values['speed_input'] == 'disabled'


def test_the_published_speed_is_scaled_by_speed_scale() -> None:
    """A tachometer's scale correction: the model runs at rail/speed x speed_scale, and the
    standing check applies to the scaled speed."""
    messages, _ = _speed_ramp_messages(('/rail/speed', '/rail/track_irregularity',
                                        '/rail/lateral_states'))
    processor = make_processor({'vehicle.speed': 30.0, 'speed_scale': 0.99,
                                'min_speed_mps': 34.0}, '/creep_estimator')
    for topic, msg in messages:
        processor.process(topic, msg)
    assert processor.ekf.speed == pytest.approx(0.99 * 35.0)
    assert processor.status(0).values['speed_input'] == 'following x 0.99 (speed_scale)'
    # 35 m/s published is 34.65 scaled: above the minimum; 34 published (33.66) was below.
    assert processor.counts['below_min_speed'] > 0
