"""The suspension monitor's processor, ROS-free: built from parameter values, fed a recording's
messages as the offline engine feeds them."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rail_monitor_ros.processing.suspension_monitor import (
    BODY_IMU,
    CREEP,
    MODES,
    make_processor,
)
from vehicle_monitor_common.bag_io import read_messages
from vehicle_monitor_common.parameters import ConfigurationError

BAG = Path(__file__).resolve().parents[3] / 'bags' / 'rail_imm_spring_damper_fault'


def test_recording_through_the_processor_detects_the_faults() -> None:
    """The shipped fault recording's IMU and track messages (rosbags' types): one output per
    IMU pair, stamped with the bogie sample, normal before the spring fault at 3 s, spring
    then spring+damper declared after it; the measured track used; nothing rejected."""
    processor = make_processor({'qos_overrides./rail/bogie/imu.subscription.reliability':
                                'reliable'}, '/suspension_monitor')
    outputs = []
    stamps = []
    for topic, _, _, msg in read_messages(BAG, ['/rail/bogie/imu', '/rail/body/imu',
                                                '/rail/track_irregularity']):
        if topic == '/rail/bogie/imu':
            stamps.append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
        outputs += processor.process(topic.lstrip('/'), msg)
    assert [o.stamp_ns for o in outputs] == stamps
    assert all(o.topic == MODES for o in outputs)
    t = (np.array(stamps) - stamps[0]) * 1e-9
    component = np.array([o.fields['fault_component'] for o in outputs])
    assert not (component[t < 3.0] != '').any()
    assert 'spring' in component[(t > 3.0) & (t < 6.0)]
    assert component[-1] == 'spring+damper'
    assert processor.rejected.total() == 0
    status = processor.status(0)
    assert status.message.startswith('suspension fault') and status.level == 2
    # The track message of the first instant, recorded after its IMU samples, is waited for.
    assert processor.known_input_samples == len(stamps)


def test_body_imu_alone_gives_nothing_and_bad_values_are_refused() -> None:
    """Body samples without bogie samples make no output; a value its definition refuses is
    a ConfigurationError naming the node."""
    processor = make_processor({}, '/suspension_monitor')
    msgs = [m for topic, _, _, m in read_messages(BAG, ['/rail/body/imu'])][:50]
    assert [o for m in msgs for o in processor.process(BODY_IMU, m)] == []
    with pytest.raises(ConfigurationError, match='/suspension_monitor.*mean_sojourn_time_s'):
        make_processor({'mean_sojourn_time_s': 0.001}, '/suspension_monitor')


def test_a_creep_estimate_is_not_followed_while_a_fault_is_suspected() -> None:
    """The creep estimator models a healthy suspension, so while the monitor suspects a
    fault it keeps the creep factor it had: on the fault recording, confident estimates
    (std 0.05) of 1.5 before the spring fault (at 3 s) and of 0.6 after it; the bank follows
    the first and holds it through the fault."""
    processor = make_processor({}, '/suspension_monitor')
    factors = {}
    for topic, _, _, msg in read_messages(BAG, ['/rail/bogie/imu', '/rail/body/imu',
                                                '/rail/track_irregularity']):
        stamp = msg.header.stamp
        if topic == '/rail/bogie/imu':
            t = stamp.sec + stamp.nanosec * 1e-9
            factors.setdefault('start', t)
            estimate = SimpleNamespace(header=msg.header, std_dev=0.05,
                                       creep_factor=1.5 if t - factors['start'] < 3.0 else 0.6)
            processor.process(CREEP, estimate)
            factors[round(t - factors['start'], 3)] = processor.imm.creep_factor
        processor.process(topic.lstrip('/'), msg)
    assert factors[2.9] == pytest.approx(1.5, abs=0.05)
    assert processor.imm.creep_factor == factors[2.9]
    assert processor._creep_state.startswith('held while a suspension fault is suspected')


def test_a_car_configured_above_its_critical_speed_declares_no_fault() -> None:
    """The fault recording (spring then spring+damper faults, car at 40 m/s) with the node
    told 70 m/s, above the shipped car's critical speed (63 m/s at creep factor 1): the model
    is unstable, its likelihoods mean nothing, so nothing is declared and the status says why
    at ERROR (before, the mode restarted from the indefinite 'stationary' prior failed its
    next update with a LinAlgError on a car driven past its critical speed)."""
    processor = make_processor({'vehicle.speed': 70.0}, '/suspension_monitor')
    outputs = [o for topic, _, _, msg in read_messages(
        BAG, ['/rail/bogie/imu', '/rail/body/imu', '/rail/track_irregularity'])
        for o in processor.process(topic.lstrip('/'), msg)]
    assert len(outputs) > 1000
    assert not any(o.fields['fault_detected'] for o in outputs)
    status = processor.status(0)
    assert status.level == 2 and 'unstable at 70.0 m/s' in status.message
    assert status.values['model_stable'] is False
    processor.imm.reset_states()     # every mode at the prior
    prior = processor.imm.P[0]
    assert np.linalg.eigvalsh(prior).min() >= -1e-9 * np.linalg.eigvalsh(prior).max()


def test_the_model_follows_the_published_speed() -> None:
    """The fault recording with its rail/speed (40 m/s, 20 Hz) and the node configured for
    30 m/s: the model runs at the published 40 m/s and declares what it declares when
    configured right (spring, then spring+damper at the end); a speed below min_speed_mps
    (the train standing, from 6 s) holds the IMM as an input fault: nothing declared, the
    status says why."""
    topics = ['/rail/bogie/imu', '/rail/body/imu', '/rail/track_irregularity', '/rail/speed']
    following = make_processor({'vehicle.speed': 30.0}, '/suspension_monitor')
    standing = make_processor({'vehicle.speed': 30.0}, '/suspension_monitor')
    outputs, standing_outputs = [], []
    for topic, _, _, msg in read_messages(BAG, topics):
        outputs += following.process(topic.lstrip('/'), msg)
        if topic == '/rail/speed' and msg.header.stamp.sec >= 6:
            msg.twist.linear.x = 2.0
        standing_outputs += standing.process(topic.lstrip('/'), msg)
    assert following.imm.vehicle.speed == 40.0
    assert following.status(0).values['speed_input'] == 'following'
    assert outputs[-1].fields['fault_component'] == 'spring+damper'
    assert not any(o.fields['fault_detected'] for o in standing_outputs
                   if o.stamp_ns * 1e-9 > 6.1)
    assert standing.rejected['below_min_speed'] > 100
    status = standing.status(0)
    assert status.level == 1 and 'input fault (below_min_speed)' in status.message


def test_the_published_speed_is_scaled_by_speed_scale() -> None:
    """The tachometer's scale correction reaches the IMM too: 40 m/s published x 0.75 is a
    bank at 30 m/s (the node configured for 40)."""
    topics = ['/rail/bogie/imu', '/rail/body/imu', '/rail/track_irregularity', '/rail/speed']
    scaled = make_processor({'vehicle.speed': 40.0, 'speed_scale': 0.75}, '/suspension_monitor')
    for topic, _, _, msg in read_messages(BAG, topics):
        if msg.header.stamp.sec >= 1:
            break
        scaled.process(topic.lstrip('/'), msg)
    assert scaled.imm.vehicle.speed == pytest.approx(30.0)
    assert scaled.status(0).values['speed_input'] == 'following x 0.75 (speed_scale)'
