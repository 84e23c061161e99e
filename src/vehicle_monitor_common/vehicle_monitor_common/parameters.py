"""One definition per parameter, ROS-free: dataclass fields that carry description and range.

A parameter is a field of a frozen dataclass declared with :func:`param`: its default, its
description (with the unit), its range or choices live there and nowhere else. Estimator cores
declare their own parameters this way (they import this module only, never rclpy); a node
declares its ROS parameters from the same dataclasses (``node_helpers.TypedParameters``), so the
descriptor, the range and the default a user sees under ``ros2 param describe`` are the core's.

A field whose default is itself such a dataclass is a group: its parameters are named
``<field>.<name>`` (a nested mapping in a params file), e.g. ``tire.j1``.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
import dataclasses
from dataclasses import dataclass
from typing import Any

import yaml


class ConfigurationError(ValueError):
    """A user error in a node's or a graph's configuration: reported in one line, exit code 2."""


def param(default: Any, description: str, *, low: float | None = None,
          high: float | None = None, choices: Sequence[str] | None = None,
          read_only: bool = False) -> Any:
    """A dataclass field that is also a ROS parameter.

    Args:
        default: default value (its type is the parameter type; use a tuple for arrays).
        description: what the parameter means, with its unit.
        low, high: inclusive range enforced by ROS (numbers only).
        choices: allowed values of a string parameter (checked on declare and on set).
        read_only: the value cannot change after start (model structure, topics, files).
    """
    meta = {'description': description, 'low': low, 'high': high,
            'choices': tuple(choices) if choices else None, 'read_only': read_only}
    if isinstance(default, (list, tuple)):
        return dataclasses.field(default_factory=lambda: tuple(default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def group(cls: type[Any], description: str = '') -> Any:
    """A dataclass field holding a nested parameter dataclass (its defaults)."""
    return dataclasses.field(default_factory=cls, metadata={'group': description or True})


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter as declared: dotted name, default and its field's metadata."""

    name: str
    default: Any
    description: str
    low: float | None
    high: float | None
    choices: tuple[str, ...] | None
    read_only: bool


def default_of(f: dataclasses.Field[Any]) -> Any:
    """A field's default value (calling its factory)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    raise TypeError(f'parameter {f.name} needs a default')


def _is_group(f: dataclasses.Field[Any]) -> bool:
    return 'group' in f.metadata


def parameter_specs(cls: type[Any], prefix: str = '') -> Iterator[ParameterSpec]:
    """Every parameter of ``cls``, groups flattened to dotted names, in declaration order.

    Raises:
        TypeError: a field declared without :func:`param` or :func:`group` (every parameter
            has a description: there is no undocumented one).
    """
    for f in dataclasses.fields(cls):
        if f.name.startswith('_') or not f.init:
            continue
        name = prefix + f.name
        if _is_group(f):
            yield from parameter_specs(type(default_of(f)), name + '.')
            continue
        if 'description' not in f.metadata:
            raise TypeError(f'{cls.__name__}.{f.name} is not declared with param(): every '
                            'parameter needs a description')
        meta = f.metadata
        yield ParameterSpec(name=name, default=default_of(f), description=meta['description'],
                            low=meta['low'], high=meta['high'], choices=meta['choices'],
                            read_only=bool(meta['read_only']))


def build(cls: type[Any], values: Mapping[str, Any], prefix: str = '') -> Any:
    """An instance of ``cls`` from flat dotted values (missing ones take their defaults).

    ``__post_init__`` checks run as usual (ValueError for a bad combination).
    """
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if f.name.startswith('_') or not f.init:
            continue
        name = prefix + f.name
        if _is_group(f):
            kwargs[f.name] = build(type(default_of(f)), values, name + '.')
        elif name in values:
            kwargs[f.name] = values[name]
    return cls(**kwargs)


def flatten(instance: Any, prefix: str = '') -> dict[str, Any]:
    """Dotted name -> value of every parameter of a parameter dataclass instance."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(instance):
        if f.name.startswith('_') or not f.init:
            continue
        value = getattr(instance, f.name)
        if _is_group(f):
            out.update(flatten(value, prefix + f.name + '.'))
        else:
            out[prefix + f.name] = value
    return out


def with_values(instance: Any, values: Mapping[str, Any]) -> Any:
    """A copy of a parameter dataclass instance with some of its dotted values replaced (an
    evaluation's ``--...-set NAME=VALUE`` ablations).

    Raises:
        ConfigurationError: a name that is not one of the instance's parameters (a typo must
            not pass for a run with the defaults), or a value its checks refuse.
    """
    current = flatten(instance)
    unknown = sorted(set(values) - set(current))
    if unknown:
        raise ConfigurationError(f'{type(instance).__name__} has no parameter '
                                 f'{", ".join(unknown)}')
    try:
        return build(type(instance), {**current, **values})
    except (TypeError, ValueError) as exc:
        raise ConfigurationError(f'{type(instance).__name__}: {exc}') from None


def parse_assignment(text: str) -> tuple[str, Any]:
    """``NAME=VALUE`` from a command line, the value read as YAML (numbers, booleans, lists).

    Raises:
        ConfigurationError: no ``=`` or no name.
    """
    name, sep, value = text.partition('=')
    if not sep or not name.strip():
        raise ConfigurationError(f'{text!r}: expected NAME=VALUE')
    return name.strip(), yaml.safe_load(value)


def parse_assignments(texts: Iterable[str], instance: Any) -> dict[str, Any]:
    """Command-line ``NAME=VALUE`` assignments (:func:`parse_assignment`) for parameters of
    ``instance``, checked as :func:`with_values` would apply them.

    Raises:
        ConfigurationError: a malformed assignment, a name that is not a parameter, or a value
            its checks refuse.
    """
    values = dict(parse_assignment(text) for text in texts)
    with_values(instance, values)
    return values


def check_choice(spec: ParameterSpec, value: Any) -> str | None:
    """Why ``value`` is not one of the parameter's choices, or None."""
    if spec.choices and value not in spec.choices:
        return f'{spec.name} must be one of {", ".join(spec.choices)}, got {value!r}'
    return None
