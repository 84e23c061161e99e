"""Graph descriptions, ROS-free: the nodes of a graph file or a YAML launch file, and the
parameter values each node gets from its params files and inline values.

The composed runner (``runner``) brings a :class:`GraphSpec` up as rclpy nodes; the offline
engine (``offline_engine``) runs the same nodes' logic over a recording; both read graphs here.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
import os
from typing import Any

import yaml

from vehicle_monitor_common.launch_yaml import is_launch_file, parse_launch
from vehicle_monitor_common.parameters import ConfigurationError

# How the runner may execute a graph (runner.EXECUTORS holds the executors themselves).
EXECUTOR_NAMES = ('events', 'single', 'multi')


@dataclass(frozen=True)
class NodeSpec:
    """One node of a graph."""

    plugin: str
    name: str | None = None
    namespace: str = ''
    parameters: dict[str, Any] = field(default_factory=dict)
    remappings: dict[str, str] = field(default_factory=dict)
    param_files: tuple[str, ...] = ()


@dataclass(frozen=True)
class GraphSpec:
    """A graph: its nodes and how they are executed."""

    nodes: tuple[NodeSpec, ...]
    executor: str = 'events'
    use_sim_time: bool = False
    # The estimator nodes take each input through one subscription per process
    # (vehicle_monitor_common.shared_inputs); never on the 'multi' executor.
    share_inputs: bool = True

    def __post_init__(self) -> None:
        if self.executor not in EXECUTOR_NAMES:
            raise ConfigurationError(
                f'executor must be one of {", ".join(EXECUTOR_NAMES)}, got {self.executor!r}')
        if not self.nodes:
            raise ConfigurationError('a graph needs at least one node')


def parse_graph(data: Any, source: str = 'graph') -> GraphSpec:
    """Validate a graph description (the YAML's content) into a GraphSpec."""
    if not isinstance(data, dict):
        raise ConfigurationError(f'{source}: expected a mapping with a nodes list')
    unknown = set(data) - {'executor', 'use_sim_time', 'share_inputs', 'nodes'}
    if unknown:
        raise ConfigurationError(f'{source}: unknown key {sorted(unknown)[0]!r}')
    nodes = []
    for index, entry in enumerate(data.get('nodes') or []):
        where = f'{source}: nodes[{index}]'
        if not isinstance(entry, dict) or 'plugin' not in entry:
            raise ConfigurationError(f'{where}: needs a plugin')
        bad = set(entry) - {'plugin', 'name', 'namespace', 'parameters', 'remappings'}
        if bad:
            raise ConfigurationError(f'{where}: unknown key {sorted(bad)[0]!r}')
        nodes.append(NodeSpec(plugin=str(entry['plugin']), name=entry.get('name'),
                              namespace=str(entry.get('namespace') or ''),
                              parameters=dict(entry.get('parameters') or {}),
                              remappings={str(k): str(v) for k, v in
                                          (entry.get('remappings') or {}).items()}))
    return GraphSpec(nodes=tuple(nodes), executor=str(data.get('executor', 'events')),
                     use_sim_time=bool(data.get('use_sim_time', False)),
                     share_inputs=bool(data.get('share_inputs', True)))


def read_yaml_file(path: str | os.PathLike[str], what: str) -> Any:
    """The content of a YAML file the user gave (``what`` it is: ``graph file``, ...).

    Raises:
        ConfigurationError: in one line, when it cannot be read or is not valid YAML.
    """
    try:
        with open(path, encoding='utf-8') as stream:
            return yaml.safe_load(stream)
    except OSError as exc:
        raise ConfigurationError(f'cannot read {what} {path}: {exc.strerror}') from None
    except yaml.YAMLError as exc:
        raise ConfigurationError(f'{path}: not valid YAML ({str(exc).splitlines()[0]})') from None


def load_graph(path: str | os.PathLike[str],
               launch_args: Mapping[str, str] | None = None) -> GraphSpec:
    """Read and validate a graph YAML file or a YAML launch file (with its arguments)."""
    data = read_yaml_file(path, 'graph file')
    if is_launch_file(data):
        nodes = parse_launch(data, launch_args or {}, str(path))
        return GraphSpec(nodes=tuple(
            NodeSpec(plugin=n['plugin'], name=n['name'], namespace=n['namespace'],
                     parameters=n['parameters'], remappings=n['remappings'],
                     param_files=tuple(n['param_files'])) for n in nodes))
    if launch_args:
        raise ConfigurationError(f'{path}: launch arguments given, but this is a graph file')
    return parse_graph(data, str(path))


def dotted_items(mapping: Mapping[str, Any], prefix: str = '') -> Iterator[tuple[str, Any]]:
    """(dotted name, value) of every leaf of a nested mapping (``{'a': {'b': 1}}``: ``a.b``):
    how ROS names the parameters of a params file, and how a message's fields are addressed."""
    for key, value in mapping.items():
        if isinstance(value, Mapping):
            yield from dotted_items(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def _key_matches(key: str, fqn: str) -> bool:
    """Whether a params-file key applies to the node ``fqn`` (rcl's rules: the fully qualified
    name, the bare name at the root, ``/**`` for every node, ``/**/name`` in any namespace)."""
    key = key if key.startswith('/') else '/' + key
    name = fqn.rsplit('/', 1)[-1]
    return key in ('/**', fqn, f'/**/{name}')


def node_parameter_values(fqn: str, param_files: tuple[str, ...],
                          inline: Mapping[str, Any]) -> dict[str, Any]:
    """The parameter values a node of fully qualified name ``fqn`` starts with: its params
    files in order (later wins, a key matching the node exactly over ``/**``) and then the
    inline values, as rcl applies ``--params-file`` and overrides.

    Raises:
        ConfigurationError: a file that cannot be read or is not a params file.
    """
    values: dict[str, Any] = {}
    for path in param_files:
        data = read_yaml_file(path, 'params file')
        if not isinstance(data, dict):
            raise ConfigurationError(f'{path}: not a params file (expected node keys)')
        # wildcards first, so the node's own key wins
        for key in sorted(data, key=lambda k: '*' not in k):
            body = data[key]
            if not _key_matches(str(key), fqn):
                continue
            if not isinstance(body, dict) or 'ros__parameters' not in body:
                raise ConfigurationError(f'{path}: {key} holds no ros__parameters')
            values.update(dotted_items(body['ros__parameters'] or {}))
    values.update(inline)
    return values


def fully_qualified_name(namespace: str, name: str) -> str:
    """``/ns/name`` (``/name`` at the root)."""
    return f'{namespace.rstrip("/")}/{name}'
