"""The suspension monitor's processor, ROS-free: built from parameter values, fed a recording's
messages as the offline engine feeds them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rail_monitor_ros.processing.suspension_monitor import (
    BODY_IMU,
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
    # The track message of the first instant is recorded after its IMU samples.
    assert processor.known_input_samples == len(stamps) - 1


def test_body_imu_alone_gives_nothing_and_bad_values_are_refused() -> None:
    """Body samples without bogie samples make no output; a value its definition refuses is
    a ConfigurationError naming the node."""
    processor = make_processor({}, '/suspension_monitor')
    msgs = [m for topic, _, _, m in read_messages(BAG, ['/rail/body/imu'])][:50]
    assert [o for m in msgs for o in processor.process(BODY_IMU, m)] == []
    with pytest.raises(ConfigurationError, match='/suspension_monitor.*mean_sojourn_time_s'):
        make_processor({'mean_sojourn_time_s': 0.001}, '/suspension_monitor')
