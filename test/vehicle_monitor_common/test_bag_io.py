"""Bag module: round trips through rosbags and an independent MCAP reader; atomic writes."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest

from vehicle_monitor_common.bag_io import (
    BagError,
    BagWriter,
    bag_topics,
    default_message,
    msg_definition_dir,
    read_series,
    typestore,
    write_bag,
)
from vehicle_monitor_common.series import TopicSeries


def test_every_msg_file_is_registered() -> None:
    """The typestore holds every message of msg_defs, built from the .msg files themselves."""
    names = {p.stem for p in msg_definition_dir().glob('*.msg')}
    assert {'WheelSpeeds', 'TpmsWarning', 'ModeProbabilities', 'TirePressure'} <= names
    for name in names:
        assert f'vehicle_monitor_msgs/msg/{name}' in typestore().types


def test_round_trip_with_rosbags(small_bag: tuple[Path, dict[str, TopicSeries]]) -> None:
    """What write_bag wrote, rosbags reads back identically: stamps, values, frame ids."""
    path, written = small_bag
    read = read_series(path)
    assert set(read) == set(written)
    for topic, series in written.items():
        np.testing.assert_array_equal(read[topic].stamps_ns, series.stamps_ns)
        assert read[topic].frame_id == series.frame_id
        for name, values in series.fields.items():
            if values.dtype == object:
                assert [list(v) for v in read[topic].fields[name]] == [list(v) for v in values]
            else:
                np.testing.assert_array_equal(read[topic].fields[name], values)


def test_round_trip_with_independent_mcap_reader(
        small_bag: tuple[Path, dict[str, TopicSeries]]) -> None:
    """The mcap + mcap-ros2-support reader decodes the same content from the embedded schemas."""
    path, written = small_bag
    (mcap_file,) = path.glob('*.mcap')
    decoded: dict[str, list[Any]] = {}
    with open(mcap_file, 'rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages(log_time_order=True):
            decoded.setdefault(channel.topic, []).append((message.log_time, msg))
    wheels = decoded['/vehicle/wheel_speeds']
    assert [t for t, _ in wheels] == list(written['/vehicle/wheel_speeds'].stamps_ns)
    np.testing.assert_array_equal(np.array([m.omega for _, m in wheels]),
                                  written['/vehicle/wheel_speeds'].fields['omega'])
    assert all(m.header.frame_id == 'base_link' for _, m in wheels)
    imu = decoded['/vehicle/imu']
    np.testing.assert_array_equal([m.linear_acceleration.y for _, m in imu],
                                  written['/vehicle/imu'].fields['linear_acceleration.y'])
    (_, warning), = decoded['/tpms/warning']
    assert list(warning.warning) == [False, True, False, False]
    assert list(warning.reasons) == ['FR: two methods agree']
    assert warning.header.stamp.sec == 1000 and warning.header.stamp.nanosec == 500_000_000


def test_sqlite3_storage_reads_back(tmp_path: Path) -> None:
    """sqlite3 storage is written and read by the same API."""
    series = {'/vehicle/wheel_speeds': TopicSeries(
        'vehicle_monitor_msgs/msg/WheelSpeeds', np.arange(5, dtype=np.int64) * 1000,
        {'omega': np.arange(20.0).reshape(5, 4)})}
    write_bag(tmp_path / 'b', series, storage='sqlite3')
    assert list((tmp_path / 'b').glob('*.db3'))
    np.testing.assert_array_equal(
        read_series(tmp_path / 'b')['/vehicle/wheel_speeds'].fields['omega'],
        series['/vehicle/wheel_speeds'].fields['omega'])


def test_failed_write_leaves_nothing(tmp_path: Path) -> None:
    """An exception inside the writer leaves neither the bag nor its temporary directory."""
    with pytest.raises(RuntimeError), BagWriter(tmp_path / 'bag') as writer:
        writer.write('/vehicle/wheel_speeds', 'vehicle_monitor_msgs/msg/WheelSpeeds', 1,
                     default_message('vehicle_monitor_msgs/msg/WheelSpeeds'))
        raise RuntimeError('simulated failure')
    assert list(tmp_path.iterdir()) == []


def test_existing_bag_is_not_overwritten_by_default(
        small_bag: tuple[Path, dict[str, TopicSeries]]) -> None:
    """Writing onto an existing bag needs overwrite=True."""
    path, series = small_bag
    with pytest.raises(BagError, match='exists'):
        write_bag(path, series)
    write_bag(path, series, overwrite=True)
    assert bag_topics(path)['/vehicle/wheel_speeds'].count == 200


@pytest.mark.parametrize('make, match', [
    (lambda d: d / 'missing', 'no such bag'),
    (lambda d: (d / 'file.txt').write_text('x') and d / 'file.txt', 'not a rosbag2 bag'),
    (lambda d: (d / 'empty').mkdir() or d / 'empty', 'no metadata.yaml'),
    (lambda d: ((d / 'bad').mkdir(), (d / 'bad' / 'metadata.yaml').write_text('a: [1'))
     and d / 'bad', 'cannot read bag'),
])
def test_unusable_paths_give_one_line_errors(tmp_path: Path, make: Any, match: str) -> None:
    """Missing, non-bag and corrupt paths raise BagError naming the problem in one line."""
    with pytest.raises(BagError, match=match) as info:
        bag_topics(make(tmp_path))
    assert '\n' not in str(info.value)


def test_series_field_errors_name_the_field(tmp_path: Path) -> None:
    """A column of the wrong width or an unknown field is refused with its name."""
    stamps = np.arange(2, dtype=np.int64)
    with pytest.raises(ValueError, match='omega'):
        write_bag(tmp_path / 'never', {'/w': TopicSeries(
            'vehicle_monitor_msgs/msg/WheelSpeeds', stamps, {'omega': np.zeros((2, 3))})})
    with pytest.raises(ValueError, match='speed'):
        write_bag(tmp_path / 'never', {'/w': TopicSeries(
            'vehicle_monitor_msgs/msg/WheelSpeeds', stamps, {'speed': np.zeros(2)})})
    assert not (tmp_path / 'never').exists()
