"""Bag module: round trips through rosbags and an independent MCAP reader; atomic writes; the
format (zstd-compressed MCAP chunks, older file-compressed bags still read); bag comparison."""

from __future__ import annotations

import dataclasses
from pathlib import Path
import re
from typing import Any

from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
import yaml

from vehicle_monitor_common.bag_io import (
    BAG_RTOL,
    BagError,
    BagWriter,
    bag_topics,
    compare_bags,
    default_message,
    iter_raw,
    message_from_fields,
    msg_definition_dir,
    read_series,
    series_messages,
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


def test_written_as_plain_mcap_with_zstd_chunks(
        small_bag: tuple[Path, dict[str, TopicSeries]]) -> None:
    """One plain .mcap file whose chunks are zstd-compressed: no rosbag2 file compression."""
    path, _ = small_bag
    assert sorted(f.name for f in path.iterdir()) == ['metadata.yaml', 'small_bag.mcap']
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['storage_identifier'] == 'mcap'
    assert info['compression_mode'] == '' and info['relative_file_paths'] == ['small_bag.mcap']
    with open(path / 'small_bag.mcap', 'rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.chunk_indexes
        assert {chunk.compression for chunk in summary.chunk_indexes} == {'zstd'}
        raw = [(c.topic, m.log_time, m.data) for _, c, m in reader.iter_messages(
            log_time_order=True)]
    assert raw == [(topic, stamp, bytes(data)) for topic, _, stamp, data in iter_raw(path)]
    # A streaming reader (no seeking, no index: as a pipe or a data-loader reads it) too.
    with open(path / 'small_bag.mcap', 'rb') as stream:
        streamed = [(c.topic, m.log_time, m.data) for _, c, m in NonSeekingReader(
            stream, validate_crcs=True).iter_messages()]
    assert sorted(streamed, key=lambda item: item[1]) == raw


def _write_file_compressed(path: Path, series: dict[str, TopicSeries]) -> None:
    """A bag as this package wrote them before: rosbag2 file compression (.mcap.zstd)."""
    store = typestore()
    messages = sorted(
        ((int(stamp), order, topic, s.msgtype, msg)
         for order, (topic, s) in enumerate(series.items())
         for stamp, msg in zip(s.stamps_ns, series_messages(s, store), strict=True)),
        key=lambda item: item[:2])
    writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    writer.set_compression(CompressionMode.FILE, CompressionFormat.ZSTD)
    with writer:
        connections = {topic: writer.add_connection(topic, s.msgtype, typestore=store)
                       for topic, s in series.items()}
        for stamp, _, topic, msgtype, msg in messages:
            writer.write(connections[topic], stamp, store.serialize_cdr(msg, msgtype))


def test_file_compressed_bags_are_still_read(
        small_bag: tuple[Path, dict[str, TopicSeries]], tmp_path: Path) -> None:
    """An older .mcap.zstd bag reads back as the same messages as its chunk-compressed twin."""
    path, written = small_bag
    old = tmp_path / 'old'
    _write_file_compressed(old, written)
    assert [f.name for f in old.glob('*.mcap*')] == ['old.mcap.zstd']
    assert bag_topics(old) == bag_topics(path)
    read = read_series(old)
    np.testing.assert_array_equal(read['/vehicle/wheel_speeds'].fields['omega'],
                                  written['/vehicle/wheel_speeds'].fields['omega'])
    assert compare_bags(old, path, rtol=0.0) == []
    assert [m[:3] for m in iter_raw(old)] == [m[:3] for m in iter_raw(path)]


def test_same_process_writes_the_same_bytes(
        small_bag: tuple[Path, dict[str, TopicSeries]], tmp_path: Path) -> None:
    """The writer is deterministic: the same series written twice give identical files."""
    _, written = small_bag
    write_bag(tmp_path / 'a' / 'bag', written)
    write_bag(tmp_path / 'b' / 'bag', written)
    assert ((tmp_path / 'a' / 'bag' / 'bag.mcap').read_bytes()
            == (tmp_path / 'b' / 'bag' / 'bag.mcap').read_bytes())


def test_sqlite3_cannot_be_compressed(tmp_path: Path) -> None:
    """Compression is of MCAP chunks; asking for it on sqlite3 is refused before writing."""
    with pytest.raises(BagError, match='sqlite3 storage cannot be compressed'):
        BagWriter(tmp_path / 'b', storage='sqlite3', compress=True)
    assert not (tmp_path / 'b').exists()


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


def _rewritten(written: dict[str, TopicSeries], topic: str, **changes: Any,
               ) -> dict[str, TopicSeries]:
    return {**written, topic: dataclasses.replace(written[topic], **changes)}


def test_compare_bags_agrees_across_storage_and_rounding(
        small_bag: tuple[Path, dict[str, TopicSeries]], tmp_path: Path) -> None:
    """Same messages in another storage, or floats off by 1e-12 of themselves: no difference."""
    path, written = small_bag
    assert compare_bags(path, path) == []
    write_bag(tmp_path / 'sqlite', written, storage='sqlite3')
    assert compare_bags(path, tmp_path / 'sqlite', rtol=0.0) == []
    omega = written['/vehicle/wheel_speeds'].fields['omega']
    rng = np.random.default_rng(3)
    rounded = _rewritten(written, '/vehicle/wheel_speeds', fields={
        'omega': omega * (1.0 + 1e-12 * rng.choice([-1.0, 1.0], omega.shape))})
    write_bag(tmp_path / 'rounded', rounded)
    assert compare_bags(path, tmp_path / 'rounded') == []
    (problem,) = compare_bags(path, tmp_path / 'rounded', rtol=1e-14)
    assert problem.startswith('/vehicle/wheel_speeds omega: message ')


def test_tolerance_is_relative_to_the_field_peak(tmp_path: Path) -> None:
    """A field crossing zero is held to rtol of its peak, not of each value; NaN matches NaN."""
    stamps = np.arange(3, dtype=np.int64)
    base = np.array([[100.0, 0.0, np.nan, -1.0]] * 3)
    near = base + np.array([0.0, 1e-8, 0.0, 0.0])  # 1e-10 of the peak 100, on a zero
    far = base + np.array([0.0, 1e-6, 0.0, 0.0])   # 1e-8 of the peak
    for name, omega in (('base', base), ('near', near), ('far', far)):
        write_bag(tmp_path / name, {'/w': TopicSeries(
            'vehicle_monitor_msgs/msg/WheelSpeeds', stamps, {'omega': omega})})
    assert compare_bags(tmp_path / 'base', tmp_path / 'near') == []
    (problem,) = compare_bags(tmp_path / 'base', tmp_path / 'far')
    assert problem == ('/w omega: message 0 has 1e-06, expected 0.0 (3 values differ by more '
                       f'than {BAG_RTOL:g} of the peak 100)')


@pytest.mark.parametrize('change, match', [
    (lambda w: _rewritten(w, '/tpms/warning', stamps_ns=w['/tpms/warning'].stamps_ns + 1),
     r'message \d+: .*expected .*log time'),
    (lambda w: _rewritten(w, '/vehicle/imu', frame_id='imu_link'),
     '/vehicle/imu header.frame_id: message 0 has .imu_link., expected .base_link.'),
    (lambda w: _rewritten(w, '/tpms/warning', fields={
        **w['/tpms/warning'].fields, 'reasons': np.array([['FL: two methods agree']],
                                                         dtype=object)}),
     '/tpms/warning reasons: message 0'),
    (lambda w: _rewritten(w, '/tpms/warning', fields={
        **w['/tpms/warning'].fields, 'warning': np.array([[True, True, False, False]])}),
     '/tpms/warning warning: message 0 has True, expected False'),
    (lambda w: {t: w[t] for t in ('/vehicle/wheel_speeds', '/vehicle/imu')},
     'topic /tpms/warning: None, expected'),
    (lambda w: {t: w[t] for t in ('/vehicle/imu', '/vehicle/wheel_speeds', '/tpms/warning')}
     | {'/vehicle/imu': dataclasses.replace(
         w['/vehicle/imu'], stamps_ns=w['/vehicle/imu'].stamps_ns - 1_000_000)},
     r'message 0: .*/vehicle/imu'),
])
def test_compare_bags_names_exact_differences(
        small_bag: tuple[Path, dict[str, TopicSeries]], tmp_path: Path,
        change: Any, match: str) -> None:
    """Stamps, order, frame ids, strings, booleans and topics must match exactly."""
    path, written = small_bag
    write_bag(tmp_path / 'changed', change(written))
    problems = compare_bags(path, tmp_path / 'changed')
    assert len(problems) == 1
    assert re.search(match, problems[0]), problems[0]
    assert '\n' not in problems[0]


def test_message_from_fields_converts_as_the_field_types_say() -> None:
    """Each field's value is converted once by its type: numpy scalars to Python numbers, an int
    in range kept, arrays to the field's dtype and length, nested messages built, the rest
    defaulted; a value the type refuses is an error naming the field, never a silent NaN."""
    store = typestore()
    msg = message_from_fields(store, 'vehicle_monitor_msgs/msg/TpmsWarning', {
        'header': {'stamp': {'sec': np.int64(3), 'nanosec': 7}},
        'warning': [1, 0, 0, 1], 'active': np.bool_(True),
        'confidence': np.array([0.5, 0.25, 0.0, 1.0], dtype=np.float32),
        'reasons': ['FL: low'],
    })
    assert msg.header.stamp.sec == 3 and type(msg.header.stamp.sec) is int
    assert msg.header.stamp.nanosec == 7 and msg.header.frame_id == ''
    assert msg.warning.dtype == np.bool_ and msg.warning.tolist() == [True, False, False, True]
    assert msg.active is True
    assert msg.confidence.dtype == np.float64 and msg.confidence.tolist() == [0.5, 0.25, 0.0, 1.0]
    assert msg.reasons == ['FL: low'] and msg.methods == []
    offsets = message_from_fields(store, 'vehicle_monitor_msgs/msg/WheelRadiusOffsets',
                                  {'delta_13': np.float32(0.5), 'longitudinal_valid': 1})
    assert type(offsets.delta_13) is float and offsets.delta_13 == 0.5
    assert offsets.longitudinal_valid is True
    for fields, match in (
            ({'delta_13': None}, 'WheelRadiusOffsets.delta_13'),
            ({'nominal': [1.0, 2.0]}, 'WheelRadiusOffsets.nominal: expected 4 values'),
            ({'header': {'stamp': {'sec': 2 ** 40}}}, 'Time.sec'),
            ({'no_such_field': 1.0}, "no field 'no_such_field'")):
        with pytest.raises(ValueError, match=match):
            message_from_fields(store, 'vehicle_monitor_msgs/msg/WheelRadiusOffsets', fields)
