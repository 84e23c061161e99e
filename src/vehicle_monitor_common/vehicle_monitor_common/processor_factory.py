"""A processor's ``make_processor(values, fqn)``, the entry point the node and the offline engine
build it by (group ``vehicle_monitor.processors``), from its class and its parameter classes:
written once for every processor that is nothing more than its parameters."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, TypeVar

from vehicle_monitor_common.processing import build_processor

T = TypeVar('T')


def processor_factory(make: Callable[..., T], *parameter_classes: type[Any]
                      ) -> Callable[[Mapping[str, Any], str], T]:
    """``make_processor(values, fqn)``: ``make`` given each parameter class built from a node's
    flat parameter values (dotted names, as the node gets them).

    The returned function raises ConfigurationError naming the node for a value its definition
    refuses.
    """
    def make_processor(values: Mapping[str, Any], fqn: str) -> T:
        return build_processor(fqn, make, values, *parameter_classes)

    make_processor.__doc__ = (
        f'The {getattr(make, "__name__", "processor")} from a node\'s parameter values (dotted '
        f'names): {", ".join(cls.__name__ for cls in parameter_classes)}. Raises '
        'ConfigurationError naming the node for a value its definition refuses.')
    return make_processor
