"""YAML launch files read by the composed runner: one file for `ros2 launch` and the runner."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from vehicle_monitor_common.graph_spec import GraphSpec, load_graph
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.runner import Graph

ROOT = Path(__file__).resolve().parents[2]


def _flatten(mapping: dict[str, Any], prefix: str = '') -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for key, value in mapping.items():
        out += (_flatten(value, f'{prefix}{key}.') if isinstance(value, dict)
                else [(f'{prefix}{key}', value)])
    return out


def _write(path: Path, data: Any) -> Path:
    path.write_text(yaml.safe_dump(data))
    return path


def _recorder_launch(tmp_path: Path, value: float) -> Path:
    params = _write(tmp_path / 'recorder.yaml',
                    {'/**': {'ros__parameters': {'discovery_period': value}}})
    return _write(tmp_path / 'rec.launch.yaml', {'launch': [
        {'arg': {'name': 'namespace', 'default': ''}},
        {'node': {'pkg': 'vehicle_monitor_common', 'exec': 'graph_recorder',
                  'namespace': '$(var namespace)', 'param': [{'from': str(params)}]}}]})


def test_one_file_brings_up_two_vehicles_each_configured(tmp_path: Path,
                                                         ros_context: Any) -> None:
    """The same launch file under two namespaces gives two independent nodes, each with the
    value of the /**-keyed params file (a file keyed by the bare node name would be ignored
    under a namespace: the default would stay, silently)."""
    path = _recorder_launch(tmp_path, 0.42)
    specs = [load_graph(path, {'namespace': ns}) for ns in ('car1', '/car2')]
    graph = Graph(GraphSpec(nodes=specs[0].nodes + specs[1].nodes), ros_context)
    try:
        names = sorted(n.get_fully_qualified_name() for n in graph.nodes)
        assert names == ['/car1/graph_recorder', '/car2/graph_recorder']
        for node in graph.nodes:
            assert node.get_parameter('discovery_period').value == 0.42
    finally:
        graph.destroy()


@pytest.mark.parametrize('launch,args,message', [
    ({'launch': [{'group': {}}]}, {}, "action 'group' is not supported"),
    ({'launch': [{'arg': {'name': 'a'}}]}, {}, r'launch argument\(s\) a required'),
    ({'launch': [{'arg': {'name': 'a', 'default': 'x'}}]}, {'b': '1'},
     r'unknown launch argument\(s\) b'),
    ({'launch': [{'node': {'pkg': 'p', 'exec': 'e', 'namespace': '$(var nope)'}}]}, {},
     r'\$\(var nope\) names no declared arg'),
    ({'launch': [{'node': {'pkg': 'p', 'exec': 'e', 'namespace': '$(eval 1)'}}]}, {},
     r'unsupported substitution \$\(eval 1\)'),
    ({'launch': [{'node': {'pkg': 'p', 'exec': 'e', 'param': [{'from': '/no/such.yaml'}]}}]},
     {}, 'parameter file /no/such.yaml not found'),
    ({'launch': [{'node': {'pkg': 'p', 'exec': 'e', 'output': 'screen'}}]}, {},
     "node key 'output' is not supported"),
])
def test_what_is_not_understood_is_refused(tmp_path: Path, launch: Any, args: dict[str, str],
                                           message: str) -> None:
    """A launch file the runner cannot honour exactly is refused with the reason, never run
    half-understood."""
    path = _write(tmp_path / 'x.launch.yaml', launch)
    with pytest.raises(ConfigurationError, match=message):
        load_graph(path, args)


@pytest.mark.parametrize('package,file', [('tpms_ros', 'road_monitor.launch.yaml'),
                                          ('rail_monitor_ros', 'rail_monitor.launch.yaml')])
def test_shipped_launch_files_resolve(package: str, file: str) -> None:
    """The shipped launch files name registered nodes and existing params files, in the
    namespace given."""
    from vehicle_monitor_common.runner import node_class

    spec = load_graph(ROOT / 'src' / package / 'launch' / file, {'namespace': 'v7'})
    assert spec.nodes and all(n.namespace == '/v7' for n in spec.nodes)
    for node in spec.nodes:
        node_class(node.plugin)
        assert node.param_files and all(Path(f).is_file() for f in node.param_files)
        assert node.parameters['use_sim_time'] is False


@pytest.mark.parametrize('package,launch_file,graph_file', [
    ('tpms_ros', 'road_monitor.launch.yaml', 'road_graph.yaml'),
    ('rail_monitor_ros', 'rail_monitor.launch.yaml', 'rail_graph.yaml')])
def test_shipped_launch_files_and_graphs_set_the_estimators_alike(
        package: str, launch_file: str, graph_file: str) -> None:
    """A setting beyond a node's params file (the IMU creep estimator's pattern D and the
    track's delays) is written twice: in the launch file a vehicle starts and in the graph
    the main job, the evaluation and the offline engine run. Every launch node's inline value
    is its graph node's, so what is measured is what a vehicle runs."""
    launch = load_graph(ROOT / 'src' / package / 'launch' / launch_file)
    graph = {node.name: node for node in
             load_graph(ROOT / 'src' / package / 'config' / graph_file).nodes}
    inline_values = 0
    for node in launch.nodes:
        name = node.name or node.plugin.split('/')[-1]     # unnamed: the executable's default
        assert name in graph, name
        inline = {k: v for k, v in node.parameters.items() if k != 'use_sim_time'}
        assert {k: graph[name].parameters.get(k) for k in inline} == inline, name
        inline_values += len(inline)
    assert inline_values == (2 if package == 'rail_monitor_ros' else 0)


def test_shipped_road_launch_file_gives_two_independent_vehicles(ros_context: Any) -> None:
    """The shipped road launch file under /car1 and /car2 in one process (as two `ros2 launch`
    would on one computer): every node comes up configured by its /**-keyed params file, and
    each calibrating node of each vehicle keeps its calibration in a file of its own."""
    import os

    path = ROOT / 'src' / 'tpms_ros' / 'launch' / 'road_monitor.launch.yaml'
    specs = [load_graph(path, {'namespace': ns}) for ns in ('car1', 'car2')]
    graph = Graph(GraphSpec(nodes=specs[0].nodes + specs[1].nodes), ros_context)
    try:
        names = sorted(n.get_fully_qualified_name() for n in graph.nodes)
        assert names == sorted(f'/{car}/{node}' for car in ('car1', 'car2') for node in (
            'tire_stiffness_observer', 'vibration_analyzer', 'wheel_radius_analyzer',
            'tpms_voter', 'lateral_force_observer'))
        files = {n.get_fully_qualified_name(): n.processor.calibration_file
                 for n in graph.nodes if hasattr(n.processor, 'calibration_file')}
        assert len(files) == 6 and len(set(files.values())) == 6
        home = os.environ['ROS_HOME']
        for fqn, file in files.items():
            assert file == os.path.join(home, 'vehicle_monitor', 'calibration',
                                        fqn.lstrip('/') + '.yaml')
        # every node got its params file under its namespace (a file keyed by the bare node
        # name would have been ignored there): the file's values are the node's overrides
        for node in graph.nodes:
            config = yaml.safe_load(
                (ROOT / 'src' / 'tpms_ros' / 'config' / f'{node.get_name()}.yaml').read_text())
            given = dict(_flatten(config['/**']['ros__parameters']))
            assert given and set(given) <= set(node._parameter_overrides), node.get_name()
    finally:
        graph.destroy()
