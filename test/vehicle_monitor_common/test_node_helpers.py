"""Start-up errors of every node: one line and exit code 2, never a traceback or a silent
default."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from vehicle_monitor_common.graph_spec import parse_graph
from vehicle_monitor_common.node_helpers import run_node
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.recorder import GraphRecorder
from vehicle_monitor_common.runner import Graph


def test_unknown_parameter_in_a_params_file_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A params file naming a parameter the node does not declare (a typo) stops the node with
    the list of unknown names."""
    params = tmp_path / 'params.yaml'
    params.write_text('/**:\n  ros__parameters:\n    discovery_period: 0.5\n    bogus: 1\n'
                      '    qos_overrides./x.subscription.depth: 5\n')
    code = run_node(GraphRecorder, ['graph_recorder', '--ros-args', '--params-file', str(params)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count('\n') == 1 and 'unknown parameter(s) bogus' in err
    assert 'discovery_period' not in err and 'qos_overrides' not in err


@pytest.mark.parametrize('content,expected', [
    ('/**:\n  ros__parameters:\n    a: [1, 2\n', "Couldn't parse params file"),
    (None, "Couldn't parse params file"),
])
def test_malformed_or_missing_params_file_is_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], content: str | None,
        expected: str) -> None:
    """A malformed or missing params file: one line naming the file, exit code 2."""
    params = tmp_path / 'params.yaml'
    if content is not None:
        params.write_text(content)
    code = run_node(GraphRecorder, ['graph_recorder', '--ros-args', '--params-file', str(params)])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith('error: ') and expected in err and str(params) in err
    assert 'Traceback' not in err and '/project/src' not in err


def test_unknown_parameter_in_a_graph_is_refused(ros_context: Any) -> None:
    """A graph file setting an undeclared parameter fails to come up, naming it."""
    spec = parse_graph({'nodes': [{'plugin': 'vehicle_monitor_common/graph_recorder',
                                   'name': 'rec', 'parameters': {'bag_typo': 'x'}}]})
    with pytest.raises(ConfigurationError, match=r'/rec: unknown parameter\(s\) bag_typo'):
        Graph(spec, ros_context)


def test_calibration_path_is_per_node_and_namespace(make_node: Any, tmp_path: Path) -> None:
    """Empty: the default under $ROS_HOME, one file per node and namespace; 'none': not
    persisted; a path: that path, expanded."""
    import os

    from vehicle_monitor_common.node_helpers import calibration_path

    car1 = make_node('stiffness', namespace='/car1')
    car2 = make_node('stiffness', namespace='/car2')
    home = Path(os.environ['ROS_HOME'])
    assert calibration_path(car1, '') == str(
        home / 'vehicle_monitor' / 'calibration' / 'car1' / 'stiffness.yaml')
    assert calibration_path(car2, '') != calibration_path(car1, '')
    assert calibration_path(car1, 'none') == ''
    assert calibration_path(car1, '$ROS_HOME/x.yaml') == str(home / 'x.yaml')
