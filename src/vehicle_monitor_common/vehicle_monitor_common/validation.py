"""Parameter checks the estimator cores share (no ROS import).

Every core validates its parameter dataclass in ``__post_init__``: a bad value is refused with
the class, the field and the value named, before it can corrupt an estimate.
"""

from __future__ import annotations

from collections.abc import Iterable
import math


def require_positive(owner: object, names: Iterable[str], *, allow_zero: bool = False) -> None:
    """Each named attribute of ``owner`` must be a finite real number > 0 (>= 0 with
    ``allow_zero``).

    Raises:
        ValueError: naming ``<class>.<field>``, the bound and the value, for the first field
            that is not (booleans are refused: a flag is no quantity).
    """
    for name in names:
        value = getattr(owner, name)
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not (number and math.isfinite(value) and (value >= 0.0 if allow_zero
                                                     else value > 0.0)):
            bound = '>= 0' if allow_zero else '> 0'
            raise ValueError(f'{type(owner).__name__}.{name} must be finite and {bound}, got '
                             f'{value!r}')
