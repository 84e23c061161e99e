"""One definition per parameter (docs/architecture.md), checked on every node and shipped YAML.

Every node is created from its plugin entry point; each ROS parameter it declares must come from
exactly one field of a parameter dataclass (``vehicle_monitor_common.parameters.param``) through
``TypedParameters``, with the descriptor (description, range, choices, read-only) generated from
that field; every shipped params file must name declared parameters with valid values.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Iterator
import inspect
import math
from pathlib import Path
from typing import Any

import pytest
import yaml

from vehicle_monitor_common.parameter_docs import (
    PLAYER_BAGS,
    collect,
    node_specs,
    plugins,
    render,
)
from vehicle_monitor_common.parameters import ParameterSpec

ROOT = Path(__file__).resolve().parents[1]
# Declared by rclpy itself, not by the project.
ROS_OWN = ('use_sim_time', 'start_type_description_service')


def _own(name: str) -> bool:
    return name not in ROS_OWN and not name.startswith('qos_overrides.')


def _specs(node: Any) -> dict[str, ParameterSpec]:
    return {s.name: s for s in node_specs(node)}


@pytest.fixture
def created(make_node: Callable[..., Any]) -> Callable[[str], Any]:
    """``created(plugin)``: the node of that plugin, created with its defaults."""

    from rclpy.parameter import Parameter

    def create(plugin: str) -> Any:
        cls = plugins()[plugin].load()
        overrides = ([Parameter('bag', value=str(ROOT / 'bags' / PLAYER_BAGS[plugin]))]
                     if plugin in PLAYER_BAGS else [])
        return make_node(cls, parameter_overrides=overrides)

    return create


def _flatten(mapping: dict[str, Any], prefix: str = '') -> Iterator[tuple[str, Any]]:
    for key, value in mapping.items():
        if isinstance(value, dict):
            yield from _flatten(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def _check_value(spec: ParameterSpec, value: Any) -> str | None:
    """Why ``value`` (as YAML gives it) is not valid for the parameter, or None."""
    default = spec.default
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, (int, float)) and not isinstance(value, bool)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, list)
    if not ok:
        return f'{spec.name}: {value!r} is not of the type of its default {default!r}'
    if spec.choices and value not in spec.choices:
        return f'{spec.name}: {value!r} not one of {spec.choices}'
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    below = number and spec.low is not None and value < spec.low
    above = number and spec.high is not None and value > spec.high
    if below or above:
        return f'{spec.name}: {value!r} outside [{spec.low}, {spec.high}]'
    return None


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) or isinstance(b, float):
        return bool(math.isclose(float(a), float(b), rel_tol=1e-12, abs_tol=0.0))
    return bool(a == b)


@pytest.mark.parametrize('plugin', sorted(plugins()))
def test_every_parameter_has_one_definition(plugin: str, created: Callable[[str], Any]) -> None:
    """Each declared parameter comes from exactly one dataclass field, and ROS describes it
    with that field's description, range, choices and read-only flag."""
    node = created(plugin)
    specs = node_specs(node)
    assert specs, f'{plugin} declares no parameters through TypedParameters'
    sources: dict[str, ParameterSpec] = {}
    for spec in specs:
        assert spec.name not in sources, f'{plugin}: {spec.name} is defined in two dataclasses'
        sources[spec.name] = spec
    declared = [n for n in node._parameters if _own(n)]
    undefined = sorted(set(declared) - set(sources))
    assert not undefined, f'{plugin} declares parameters outside any dataclass: {undefined}'
    for descriptor in node.describe_parameters(declared):
        spec = sources[descriptor.name]
        assert descriptor.description.startswith(spec.description), descriptor.name
        assert descriptor.read_only == spec.read_only, descriptor.name
        ranges = list(descriptor.floating_point_range) + list(descriptor.integer_range)
        if spec.low is None and spec.high is None:
            assert not ranges, f'{descriptor.name}: a range without a definition'
        else:
            (r,) = ranges
            if spec.low is not None:
                assert r.from_value == spec.low, descriptor.name
            if spec.high is not None:
                assert r.to_value == spec.high, descriptor.name
        if spec.choices:
            assert all(c in descriptor.additional_constraints for c in spec.choices)
        unset = isinstance(spec.default, tuple) and not spec.default  # unset until given
        if not unset and not (plugin in PLAYER_BAGS and descriptor.name == 'bag'):
            assert _same(node.get_parameter(descriptor.name).value, spec.default), descriptor.name


@pytest.mark.parametrize('plugin', sorted(plugins()))
def test_node_module_copies_no_definition(plugin: str) -> None:
    """The node's module declares no parameter by hand and keeps no module-level instance of a
    parameter class to copy defaults from (the ``_D = SomeParams()`` pattern)."""
    module = inspect.getmodule(plugins()[plugin].load())
    assert module is not None and module.__file__
    tree = ast.parse(Path(module.__file__).read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr == 'declare_parameter':
            pytest.fail(f'{module.__name__} calls declare_parameter by hand')
    for stmt in tree.body:
        if isinstance(stmt, ast.Assign) and isinstance(stmt.value, ast.Call):
            func = stmt.value.func
            name = func.id if isinstance(func, ast.Name) else getattr(func, 'attr', '')
            assert not name.endswith(('Params', 'Parameters')), (
                f'{module.__name__}: module-level {name}() copies defaults')


def _node_configs() -> list[Path]:
    names = {p.split('/')[1] for p in plugins()}
    return sorted(p for p in ROOT.glob('src/*/config/*.yaml') if p.stem in names)


@pytest.mark.parametrize('path', _node_configs(), ids=lambda p: p.name)
def test_shipped_node_config_matches_definitions(path: Path,
                                                 created: Callable[[str], Any]) -> None:
    """A node's shipped params file names only declared parameters, each with a valid value
    equal to its definition's default (the file documents the defaults), and omits none."""
    package = path.parent.parent.name
    node = created(f'{package}/{path.stem}')
    specs = _specs(node)
    data = yaml.safe_load(path.read_text())
    (key,) = data
    values = dict(_flatten(data[key]['ros__parameters']))
    unknown = sorted(set(values) - set(specs))
    assert not unknown, f'{path.name} sets undeclared parameters {unknown}'
    for name, value in values.items():
        problem = _check_value(specs[name], value)
        assert problem is None, f'{path.name}: {problem}'
        assert _same(value, specs[name].default), (
            f'{path.name}: {name} = {value!r}, its definition says {specs[name].default!r}')
    missing = sorted(n for n in specs if n not in values)
    assert not missing, f'{path.name} leaves out {missing}'


def _graph_nodes() -> list[tuple[str, str, str, dict[str, Any]]]:
    out = []
    for path in sorted(ROOT.glob('src/*/config/*_graph.yaml')):
        for spec in yaml.safe_load(path.read_text())['nodes']:
            out.append((path.name, spec['plugin'], spec.get('name', ''),
                        dict(_flatten(spec.get('parameters') or {}))))
    return out


@pytest.mark.parametrize('graph,plugin,name,values', _graph_nodes(),
                         ids=lambda v: v if isinstance(v, str) else '')
def test_graph_parameters_are_declared(graph: str, plugin: str, name: str,
                                       values: dict[str, Any],
                                       created: Callable[[str], Any]) -> None:
    """Each node entry of a shipped graph sets only parameters its node declares, with valid
    values (qos_overrides are rclpy's own)."""
    node = created(plugin)
    specs = _specs(node)
    for key, value in values.items():
        if key.startswith('qos_overrides.'):
            continue
        assert key in specs, f'{graph}: {name} sets undeclared parameter {key}'
        problem = _check_value(specs[key], value)
        assert problem is None, f'{graph} {name}: {problem}'


def test_parameter_reference_is_current() -> None:
    """docs/parameters.md is what the definitions generate (run ``parameter_docs`` after
    changing a parameter)."""
    expected = render(list(collect()))
    assert (ROOT / 'docs' / 'parameters.md').read_text(encoding='utf-8') == expected
