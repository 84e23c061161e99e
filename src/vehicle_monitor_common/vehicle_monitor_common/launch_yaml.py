"""ROS 2 YAML launch files, read by the composed runner: one file for ``ros2 launch`` on a real
Jazzy install and for the in-process runner here (``launch``/``launch_ros`` are not on PyPI).

The YAML launch frontend is plain data; this reads the part of it a vehicle's graph needs and
refuses the rest with the reason, so a file that works here means the same under ``ros2 launch``::

    launch:
      - arg: {name: namespace, default: ''}
      - node:
          pkg: tpms_ros
          exec: tire_stiffness_observer
          name: tire_stiffness_observer          # optional
          namespace: $(var namespace)            # optional; relative names get a leading /
          param:
            - from: $(find-pkg-share tpms_ros)/config/tire_stiffness_observer.yaml
            - {name: use_sim_time, value: $(var use_sim_time)}
          remap:
            - {from: vehicle/imu, to: imu/data}

Substitutions: ``$(var NAME)``, ``$(find-pkg-share PACKAGE)``, ``$(env NAME [DEFAULT])``.
A node's executable is found among the registered node plugins (``<pkg>/<exec>``: the packages
register every executable under the same name). Parameter files are applied as rcl applies
``--params-file`` (node-name keys, ``/**`` wildcards), then the inline values, which win; in
``ros2 launch`` the later entry wins, so list files first.
"""

from __future__ import annotations

from collections.abc import Mapping
import os
from pathlib import Path
import re
from typing import Any

import yaml

from vehicle_monitor_common.parameters import ConfigurationError

_SUBSTITUTION = re.compile(r'\$\(([^)]*)\)')
NODE_KEYS = {'pkg', 'exec', 'name', 'namespace', 'param', 'remap'}


def is_launch_file(data: Any) -> bool:
    """Whether parsed YAML is a launch file (a mapping with the single key ``launch``)."""
    return isinstance(data, dict) and set(data) == {'launch'}


def _package_share(package: str, source: str) -> str:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        return str(get_package_share_directory(package))
    except PackageNotFoundError:
        raise ConfigurationError(f'{source}: package {package!r} not found') from None


def _substitute(text: Any, args: Mapping[str, str], source: str) -> Any:
    if not isinstance(text, str):
        return text

    def one(match: re.Match[str]) -> str:
        kind, *rest = match.group(1).split()
        if kind == 'var' and len(rest) == 1:
            if rest[0] not in args:
                raise ConfigurationError(f'{source}: $(var {rest[0]}) names no declared arg')
            return args[rest[0]]
        if kind == 'find-pkg-share' and len(rest) == 1:
            return _package_share(rest[0], source)
        if kind == 'env' and len(rest) in (1, 2):
            value = os.environ.get(rest[0], rest[1] if len(rest) == 2 else None)
            if value is None:
                raise ConfigurationError(f'{source}: environment variable {rest[0]} is not set')
            return value
        raise ConfigurationError(f'{source}: unsupported substitution $({match.group(1)})')

    whole = _SUBSTITUTION.fullmatch(text)
    result = _SUBSTITUTION.sub(one, text)
    # A value that is one substitution is typed as the launch frontends do (YAML scalars).
    return yaml.safe_load(result) if whole and result else result


def _namespace(value: str) -> str:
    value = value.strip()
    return '' if value in ('', '/') else ('/' + value.lstrip('/')).rstrip('/')


def parse_launch(data: Any, launch_args: Mapping[str, str], source: str) -> list[dict[str, Any]]:
    """The nodes of a launch file as runner node entries (plugin, name, namespace, parameters,
    param_files, remappings), with the arguments substituted.

    Raises:
        ConfigurationError: an unknown action or key, an undeclared or unknown argument, a
            missing package, an unsupported substitution.
    """
    actions = data['launch']
    if not isinstance(actions, list):
        raise ConfigurationError(f'{source}: launch must hold a list of actions')
    declared: dict[str, str | None] = {}
    nodes: list[dict[str, Any]] = []
    for index, action in enumerate(actions):
        where = f'{source}: launch[{index}]'
        if not isinstance(action, dict) or len(action) != 1:
            raise ConfigurationError(f'{where}: each action is a mapping with one key')
        ((kind, body),) = action.items()
        if kind == 'arg':
            if not isinstance(body, dict) or 'name' not in body:
                raise ConfigurationError(f'{where}: arg needs a name')
            default = body.get('default')
            declared[str(body['name'])] = None if default is None else str(default)
        elif kind == 'node':
            nodes.append({'where': where, **_node_entry(body, where)})
        else:
            raise ConfigurationError(f'{where}: action {kind!r} is not supported here '
                                     '(arg and node are)')
    unknown = sorted(set(launch_args) - set(declared))
    if unknown:
        raise ConfigurationError(f'{source}: unknown launch argument(s) {", ".join(unknown)} '
                                 f'(declared: {", ".join(declared) or "none"})')
    values = {**{k: v for k, v in declared.items() if v is not None}, **launch_args}
    missing = sorted(set(declared) - set(values))
    if missing:
        raise ConfigurationError(f'{source}: launch argument(s) {", ".join(missing)} required '
                                 '(give NAME:=VALUE)')
    return [_resolve(node, values) for node in nodes]


def _node_entry(body: Any, where: str) -> dict[str, Any]:
    if not isinstance(body, dict) or not {'pkg', 'exec'} <= set(body):
        raise ConfigurationError(f'{where}: node needs pkg and exec')
    bad = sorted(set(body) - NODE_KEYS)
    if bad:
        raise ConfigurationError(f'{where}: node key {bad[0]!r} is not supported here')
    return dict(body)


def _resolve(node: dict[str, Any], values: Mapping[str, str]) -> dict[str, Any]:
    where = node['where']

    def sub(value: Any) -> Any:
        return _substitute(value, values, where)

    parameters: dict[str, Any] = {}
    files: list[str] = []
    for entry in node.get('param') or []:
        if isinstance(entry, dict) and set(entry) == {'from'}:
            path = str(sub(entry['from']))
            if not Path(path).is_file():
                raise ConfigurationError(f'{where}: parameter file {path} not found')
            files.append(path)
        elif isinstance(entry, dict) and set(entry) == {'name', 'value'}:
            parameters[str(sub(entry['name']))] = sub(entry['value'])
        else:
            raise ConfigurationError(f'{where}: param entries are {{from: FILE}} or '
                                     '{name: N, value: V}')
    remappings: dict[str, str] = {}
    for entry in node.get('remap') or []:
        if not isinstance(entry, dict) or set(entry) != {'from', 'to'}:
            raise ConfigurationError(f'{where}: remap entries are {{from: A, to: B}}')
        remappings[str(sub(entry['from']))] = str(sub(entry['to']))
    name = sub(node.get('name'))
    return {'plugin': f'{sub(node["pkg"])}/{sub(node["exec"])}',
            'name': str(name) if name else None,
            'namespace': _namespace(str(sub(node.get('namespace') or ''))),
            'parameters': parameters, 'param_files': files, 'remappings': remappings}
