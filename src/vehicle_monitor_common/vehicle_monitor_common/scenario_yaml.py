"""The one scenario-file reader of both domains: YAML mappings read with line numbers.

A scenario file is a YAML mapping validated key by key. :func:`read_mapping` parses the text
and records the line of every key and list item (:func:`key_lines`); the reader then walks it
with :class:`MappingNode`, whose accessors (``number``, ``numbers``, ``integer``, ``text``,
``child``, ``items``) check each value and whose errors name ``source:line: key.path``, so a
user finds the offending line. :func:`mapping_from_data` wraps an already parsed mapping (no
lines: the errors then name the key path only). ROS-free; used by the road and rail scenario
readers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import math
from typing import Any

import yaml


def located_error(source: str, line: int, path: str, message: str) -> ValueError:
    """``source:line: key.path: message`` (without the line when it is unknown, 0)."""
    where = f'{source}:{line}' if line > 0 else source
    return ValueError(f'{where}: {path}: {message}')


class MappingNode:
    """A YAML mapping being read: its values, its key path, and the lines of its keys.

    Every accessor marks its key as read; :meth:`finish` then refuses the keys nobody read
    (typos, unsupported options). Errors are ValueErrors naming ``source:line: key.path``.
    """

    def __init__(self, values: Mapping[str, Any], path: str, lines: Mapping[str, int],
                 source: str, line: int) -> None:
        self.values = values
        self.path = path
        self.lines = lines
        self.source = source
        self.line = line
        self.used: set[str] = set()

    def key_path(self, key: str) -> str:
        """The dotted path of ``key`` in this mapping."""
        return f'{self.path}.{key}' if self.path else key

    def error(self, key: str | None, message: str) -> ValueError:
        """A ValueError located at ``key`` (its line and path), or at this mapping (None)."""
        path = self.key_path(key) if key is not None else (self.path or '<top level>')
        line = self.lines.get(self.key_path(key), self.line) if key is not None else self.line
        return located_error(self.source, line, path, message)

    def has(self, key: str) -> bool:
        """Whether the mapping sets ``key`` (does not mark it read)."""
        return key in self.values

    def raw(self, key: str) -> Any:
        """The value of ``key`` as parsed, marked read (the caller checks it)."""
        self.used.add(key)
        return self.values[key]

    def number(self, key: str, default: float | None = None, *, low: float | None = None,
               high: float | None = None, low_open: bool = False) -> float:
        """A finite float within [low, high] (``low_open``: strictly above low)."""
        if key not in self.values:
            if default is None:
                raise self.error(key, 'is required')
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(key, f'must be a number, got {value!r}')
        number = float(value)
        if not math.isfinite(number):
            raise self.error(key, f'must be finite, got {value!r}')
        if low is not None and (number <= low if low_open else number < low):
            relation = '>' if low_open else '>='
            raise self.error(key, f'must be {relation} {low:g}, got {number:g}')
        if high is not None and number > high:
            raise self.error(key, f'must be <= {high:g}, got {number:g}')
        return number

    def numbers(self, key: str, default: tuple[float, ...], names: Sequence[str], *,
                low: float | None = None, high: float | None = None,
                low_open: bool = False) -> tuple[float, ...]:
        """One number for each of ``names`` (wheels, bogies): one for all, or a list of one
        each in that order; every one finite and within [low, high] (``low_open``: strictly
        above low)."""
        if key not in self.values:
            return default
        raw = self.raw(key)
        values = list(raw) if isinstance(raw, (list, tuple)) else [raw] * len(names)
        if len(values) != len(names):
            raise self.error(key, f'must be one number or {len(names)} ({", ".join(names)}), '
                                  f'got {raw!r}')
        for value in values:
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise self.error(key, f'must hold finite numbers, got {raw!r}')
            if low is not None and (value <= low if low_open else value < low):
                raise self.error(key, f'values must be {">" if low_open else ">="} {low:g}, '
                                      f'got {raw!r}')
            if high is not None and value > high:
                raise self.error(key, f'values must be <= {high:g}, got {raw!r}')
        return tuple(float(value) for value in values)

    def integer(self, key: str, default: int, *, low: int) -> int:
        """An integer >= low (not a bool, not a float)."""
        if key not in self.values:
            return default
        value = self.raw(key)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise self.error(key, f'must be an integer >= {low}, got {value!r}')
        return int(value)

    def text(self, key: str, default: str | None = None,
             choices: Sequence[str] | None = None) -> str:
        """A string, one of ``choices`` when given."""
        if key not in self.values:
            if default is None:
                raise self.error(key, 'is required')
            return default
        value = self.raw(key)
        if not isinstance(value, str):
            raise self.error(key, f'must be a string, got {value!r}')
        if choices is not None and value not in choices:
            raise self.error(key, f'unknown value {value!r}; expected one of {sorted(choices)}')
        return value

    def child(self, key: str) -> MappingNode:
        """The mapping under ``key`` (an empty one when absent)."""
        if key not in self.values:
            return MappingNode({}, self.key_path(key), self.lines, self.source, self.line)
        value = self.raw(key)
        if value is None:
            value = {}
        if not isinstance(value, Mapping):
            raise self.error(key, 'must be a mapping')
        return MappingNode(value, self.key_path(key), self.lines, self.source,
                     self.lines.get(self.key_path(key), self.line))

    def items(self, key: str) -> list[MappingNode]:
        """The list of mappings under ``key`` (empty when absent)."""
        if key not in self.values:
            return []
        value = self.raw(key)
        if value is None:
            return []
        if not isinstance(value, list):
            raise self.error(key, 'must be a list')
        nodes = []
        for index, item in enumerate(value):
            path = f'{self.key_path(key)}[{index}]'
            line = self.lines.get(path, self.line)
            if not isinstance(item, Mapping):
                raise located_error(self.source, line, path, 'must be a mapping')
            nodes.append(MappingNode(item, path, self.lines, self.source, line))
        return nodes

    def finish(self) -> None:
        """Refuse keys nobody read: they are typos or unsupported options."""
        for key in self.values:
            if key not in self.used:
                raise self.error(str(key), 'unknown key')


def key_lines(node: yaml.Node, path: str, lines: dict[str, int]) -> None:
    """Record the 1-based line of every key and list item, keyed by its dotted path."""
    if isinstance(node, yaml.MappingNode):
        seen: set[str] = set()
        for key_node, value_node in node.value:
            key = str(key_node.value)
            child = f'{path}.{key}' if path else key
            if key in seen:
                raise ValueError(f'{key_node.start_mark.line + 1}: {child}: duplicate key')
            seen.add(key)
            lines[child] = key_node.start_mark.line + 1
            key_lines(value_node, child, lines)
    elif isinstance(node, yaml.SequenceNode):
        for index, item in enumerate(node.value):
            child = f'{path}[{index}]'
            lines[child] = item.start_mark.line + 1
            key_lines(item, child, lines)


def read_mapping(text: str, source: str = '<scenario>') -> MappingNode:
    """Parse YAML text that must hold a mapping, keeping the line of every key.

    Raises:
        ValueError: not valid YAML, not a mapping, or a duplicate key (with its line).
    """
    try:
        root_node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ValueError(f'{source}: not valid YAML: {error}') from error
    if not isinstance(data, Mapping) or root_node is None:
        raise ValueError(f'{source}: a scenario must be a YAML mapping')
    lines: dict[str, int] = {}
    try:
        key_lines(root_node, '', lines)
    except ValueError as error:
        raise ValueError(f'{source}:{error}') from None
    return MappingNode(data, '', lines, source, 1)


def mapping_from_data(data: Any, source: str = '<scenario>') -> MappingNode:
    """An already parsed scenario mapping (a dict built in code): no line numbers.

    Raises:
        ValueError: ``data`` is not a mapping.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f'{source}: a scenario must be a mapping, got {type(data).__name__}')
    return MappingNode(data, '', {}, source, 0)
