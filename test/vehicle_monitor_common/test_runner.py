"""Composed runner: graph files, plugin lookup, a replay graph end to end, overrides."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from vehicle_monitor_common.graph_spec import load_graph, parse_graph
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.player import ScenarioPlayer
from vehicle_monitor_common.recorder import GraphRecorder
from vehicle_monitor_common.runner import Graph, _apply_overrides, node_class
from vehicle_monitor_common.series import TopicSeries


def test_registered_plugins_resolve() -> None:
    """Package/executable names of the vehicle_monitor.nodes group load their classes."""
    assert node_class('vehicle_monitor_common/scenario_player') is ScenarioPlayer
    assert node_class('vehicle_monitor_common/graph_recorder') is GraphRecorder
    assert node_class('vehicle_monitor_common.recorder:GraphRecorder') is GraphRecorder
    with pytest.raises(ConfigurationError, match='unknown node plugin'):
        node_class('nope/nothing')


@pytest.mark.parametrize('data, match', [
    ([], 'expected a mapping'),
    ({'nodes': [], 'executor': 'single'}, 'at least one node'),
    ({'nodes': [{'name': 'x'}]}, r'nodes\[0\]: needs a plugin'),
    ({'nodes': [{'plugin': 'a/b', 'params': {}}]}, "unknown key 'params'"),
    ({'nodes': [{'plugin': 'a/b'}], 'executor': 'many'}, 'executor must be one of events'),
    ({'nodes': [{'plugin': 'a/b'}], 'extra': 1}, "unknown key 'extra'"),
])
def test_bad_graph_files_are_refused(data: Any, match: str) -> None:
    """Malformed graph descriptions are refused with the offending key."""
    with pytest.raises(ConfigurationError, match=match):
        parse_graph(data)


def test_unreadable_graph_file(tmp_path: Path) -> None:
    """A missing or invalid YAML file is a one-line ConfigurationError."""
    with pytest.raises(ConfigurationError, match='cannot read graph file'):
        load_graph(tmp_path / 'missing.yaml')
    (tmp_path / 'bad.yaml').write_text('nodes: [')
    with pytest.raises(ConfigurationError, match='not valid YAML'):
        load_graph(tmp_path / 'bad.yaml')


def test_overrides_target_nodes_by_name() -> None:
    """NODE.PARAM:=VALUE overrides parse YAML values; unknown nodes are refused."""
    spec = parse_graph({'nodes': [{'plugin': 'vehicle_monitor_common/scenario_player',
                                   'name': 'player', 'parameters': {'rate': 1.0}}]})
    updated = _apply_overrides(spec, ['player.rate:=4.5', 'player.loop:=true'])
    assert updated.nodes[0].parameters == {'rate': 4.5, 'loop': True}
    with pytest.raises(ConfigurationError, match='bad override'):
        _apply_overrides(spec, ['other.rate:=1.0'])


def test_replay_graph_records_every_message(
        ros_context: Any, small_bag: tuple[Path, dict[str, TopicSeries]]) -> None:
    """A player + recorder graph on sim time: the recorder counts every message of the bag."""
    path, series = small_bag
    spec = parse_graph({'use_sim_time': True, 'nodes': [
        {'plugin': 'vehicle_monitor_common/scenario_player', 'name': 'player',
         'parameters': {'bag': str(path), 'rate': 20.0, 'wait_for_subscribers': 1}},
        {'plugin': 'vehicle_monitor_common/graph_recorder', 'name': 'recorder'}]})
    graph = Graph(spec, ros_context)
    try:
        (player,) = graph.of_type(ScenarioPlayer)
        (recorder,) = graph.of_type(GraphRecorder)
        assert recorder.get_parameter('use_sim_time').value is True
        assert player.get_parameter('use_sim_time').value is False
        expected = {topic: len(s) for topic, s in series.items()}
        assert graph.spin_until(
            lambda: player.done.is_set()
            and {t: s.count for t, s in recorder.stats.items()} == expected, timeout_s=20.0), \
            {t: s.count for t, s in recorder.stats.items()}
        assert '/vehicle/wheel_speeds' in recorder.summary()
    finally:
        graph.destroy()
    assert graph.nodes == []
