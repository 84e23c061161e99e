"""Simulator nodes find the recordings their package ships, from any directory."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from rclpy.parameter import Parameter

from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.runner import node_class


@pytest.mark.parametrize('plugin,name', [
    ('tpms_ros/vehicle_simulator', 'road_kim_huh_lateral'),
    ('tpms_ros/vehicle_simulator', 'bags/road_kim_huh_lateral'),
    ('rail_monitor_ros/rail_simulator', 'rail_creep_steps'),
])
def test_shipped_bag_by_name_from_anywhere(plugin: str, name: str, tmp_path: Path,
                                           monkeypatch: pytest.MonkeyPatch,
                                           make_node: Callable[..., Any]) -> None:
    """`-p bag:=<name>` (or the repository-relative path) works outside the repository: the
    bags are installed to share/<package>/bags."""
    monkeypatch.chdir(tmp_path)
    node = make_node(node_class(plugin), parameter_overrides=[Parameter('bag', value=name)])
    assert Path(node.bag).is_dir() and Path(node.bag).name == Path(name).name
    assert (Path(node.bag) / 'metadata.yaml').is_file()


def test_unknown_bag_names_what_is_shipped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                           make_node: Callable[..., Any]) -> None:
    """A bag that is neither a path nor shipped is refused, listing the shipped ones."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigurationError, match=r"no such bag.*rail_creep_steps"):
        make_node(node_class('rail_monitor_ros/rail_simulator'),
                  parameter_overrides=[Parameter('bag', value='nope')])
