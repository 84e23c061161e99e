"""``parameter_docs``: the parameter reference (docs/parameters.md) generated from the definitions.

Every registered node (``vehicle_monitor.nodes`` entry points) is created in a private rclpy
context with its defaults; the parameters it declares through ``TypedParameters`` are listed
with default, range or choices, read-only flag and description, straight from the dataclass
fields that define them. ``--check`` exits 1 when the file is out of date (the test suite runs
it), so the reference cannot drift from the code.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterator
from importlib.metadata import entry_points
import math
from pathlib import Path
import sys
from typing import Any

from vehicle_monitor_common.parameters import ParameterSpec
from vehicle_monitor_common.resources import workspace_bags

NODE_GROUP = 'vehicle_monitor.nodes'
# Players need a recording to start; a shipped bag of their domain serves.
PLAYER_BAGS = {'tpms_ros/vehicle_simulator': 'road_kim_huh_lateral',
               'rail_monitor_ros/rail_simulator': 'rail_creep_steps',
               'vehicle_monitor_common/scenario_player': 'rail_creep_steps'}
HEADER = """# Node parameters

Generated from the parameter definitions by `tools/ros2run vehicle_monitor_common
parameter_docs` (do not edit: the tests check that it is current). Each node declares these
with descriptors: ROS enforces the ranges and choices, read-only ones cannot change after
start. Dotted names are nested mappings in a params file.
"""


def plugins() -> dict[str, Any]:
    """``package/name`` -> entry point of every registered node class."""
    return {f'{ep.dist.name if ep.dist else "?"}/{ep.name}': ep
            for ep in entry_points(group=NODE_GROUP)}


def node_specs(node: Any) -> list[ParameterSpec]:
    """The parameter definitions a node declared through TypedParameters, in declaration order."""
    from vehicle_monitor_common.node_helpers import TypedParameters

    # A processor node keeps its groups in a list; a player holds its one group directly.
    held = [item for v in vars(node).values() for item in (v if isinstance(v, list) else [v])]
    return [spec for v in held if isinstance(v, TypedParameters) for spec in v.specs.values()]


def collect() -> Iterator[tuple[str, list[ParameterSpec]]]:
    """(plugin, its parameter definitions) for every registered node, sorted by plugin."""
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    context = Context()
    rclpy.init(context=context, args=[])
    try:
        for name, ep in sorted(plugins().items()):
            overrides = []
            if name in PLAYER_BAGS:
                bag = workspace_bags() / PLAYER_BAGS[name]
                overrides = [Parameter('bag', value=str(bag))]
            node = ep.load()(context=context, parameter_overrides=overrides)
            try:
                yield name, node_specs(node)
            finally:
                node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


def _value(spec: ParameterSpec) -> str:
    default = spec.default
    if isinstance(default, tuple):
        return '`[' + ', '.join(_scalar(v) for v in default) + ']`'
    return f'`{_scalar(default)}`'


def _scalar(value: Any) -> str:
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        # Written as a float (200.0, not 200): ROS refuses an integer for a double parameter.
        text = f'{value:.6g}'
        return text if any(c in text for c in '.ein') else text + '.0'
    if isinstance(value, str):
        return repr(value)
    return str(value)


def _allowed(spec: ParameterSpec) -> str:
    if spec.choices:
        return ', '.join(f'`{c}`' for c in spec.choices)
    if spec.low is None and spec.high is None:
        return ''
    low = '-inf' if spec.low is None or spec.low == -math.inf else _scalar(spec.low)
    high = 'inf' if spec.high is None or spec.high == math.inf else _scalar(spec.high)
    return f'[{low}, {high}]'


def render(items: list[tuple[str, list[ParameterSpec]]]) -> str:
    """The Markdown reference of the given nodes' parameters."""
    lines = [HEADER]
    for plugin, specs in items:
        package, name = plugin.split('/')
        lines += [f'## `{name}` ({package})', '',
                  '| parameter | default | allowed | read-only | description |',
                  '| --- | --- | --- | --- | --- |']
        for spec in specs:
            description = spec.description.replace('|', '\\|')
            lines.append(f'| `{spec.name}` | {_value(spec)} | {_allowed(spec)} | '
                         f'{"yes" if spec.read_only else ""} | {description} |')
        lines.append('')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    """Write (or with --check, compare) the parameter reference."""
    parser = argparse.ArgumentParser(prog='parameter_docs', description=__doc__.splitlines()[0])
    parser.add_argument('--out', type=Path, default=Path('docs/parameters.md'),
                        help='reference file (default: docs/parameters.md)')
    parser.add_argument('--check', action='store_true',
                        help='only compare: exit 1 when the file is not current')
    args = parser.parse_args(argv)
    text = render(list(collect()))
    if args.check:
        current = args.out.read_text(encoding='utf-8') if args.out.is_file() else ''
        if current != text:
            print(f'{args.out} is out of date: run parameter_docs', file=sys.stderr)
            return 1
        return 0
    args.out.write_text(text, encoding='utf-8')
    print(f'{args.out}: written')
    return 0


if __name__ == '__main__':
    sys.exit(main())
