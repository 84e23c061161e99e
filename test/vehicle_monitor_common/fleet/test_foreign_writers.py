"""Recordings written by other tools (plain rosbags writers, not the project's BagWriter) are
screened whole: every input message reaches the graph, none is dropped."""

from __future__ import annotations

from pathlib import Path

import pytest
from rosbags.rosbag2 import CompressionFormat, CompressionMode, Reader, StoragePlugin, Writer

from vehicle_monitor_common.bag_io import typestore
from vehicle_monitor_common.fleet.job import LocalExecutor, read_table, run_fleet
from vehicle_monitor_common.fleet.manifest import find_recordings

ROOT = Path(__file__).resolve().parents[3]
SOURCE = ROOT / 'bags' / 'rail_imm_spring_damper_fault'


def _copy(target: Path, storage: StoragePlugin, compression: CompressionMode | None) -> int:
    """The shipped bag's inputs rewritten by rosbags' own Writer; the message count."""
    store = typestore()
    count = 0
    with Reader(SOURCE) as reader:
        writer = Writer(target, version=8, storage_plugin=storage)
        if compression is not None:
            writer.set_compression(compression, CompressionFormat.ZSTD)
        with writer:
            connections = {}
            for connection in reader.connections:
                if connection.topic.startswith('/truth'):
                    continue
                connections[connection.id] = writer.add_connection(
                    connection.topic, connection.msgtype, typestore=store)
            wanted = [c for c in reader.connections if c.id in connections]
            for connection, stamp, data in reader.messages(wanted):
                writer.write(connections[connection.id], stamp, data)
                count += 1
    return count


@pytest.mark.timeout(300)
@pytest.mark.parametrize(('storage', 'compression'), [
    (StoragePlugin.MCAP, None),
    (StoragePlugin.MCAP, CompressionMode.FILE),
    (StoragePlugin.SQLITE3, None),
], ids=['mcap', 'mcap_file_compressed', 'sqlite3'])
def test_every_message_of_a_foreign_bag_is_screened(tmp_path: Path, storage: StoragePlugin,
                                                    compression: CompressionMode | None) -> None:
    """The rail graph reads every input message of a bag rosbags wrote itself (MCAP, rosbag2
    file-compressed MCAP, sqlite3) and publishes its outputs for each."""
    count = _copy(tmp_path / 'drives' / 'other_tool', storage, compression)
    run = run_fleet(find_recordings([str(tmp_path / 'drives')]), tmp_path / 'out',
                    LocalExecutor(), log=lambda _: None)
    assert run.failed == 0, run.errors
    summary = read_table(tmp_path / 'out', 'summary').to_pandas()
    assert set(summary['messages_in']) == {count}
    assert count == 8205     # 2001 samples x 4 topics, 201 speeds
    modes = summary.set_index('method').loc['suspension']
    assert modes['messages'] == 2001
