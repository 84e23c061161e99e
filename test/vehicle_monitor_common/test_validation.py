"""The shared parameter check of the estimator cores."""

from dataclasses import dataclass
import math

import pytest

from vehicle_monitor_common.validation import require_positive


@dataclass
class _Params:
    rate: object = 100.0
    hold: object = 0.0


def test_accepts_finite_positive_and_zero_where_allowed() -> None:
    require_positive(_Params(), ('rate',))
    require_positive(_Params(rate=3), ('rate',))
    require_positive(_Params(), ('hold',), allow_zero=True)


@pytest.mark.parametrize('value', [0.0, -1.0, math.nan, math.inf, True, '5', None])
def test_refuses_and_names_the_field(value: object) -> None:
    with pytest.raises(ValueError, match=r'_Params\.rate must be finite and > 0'):
        require_positive(_Params(rate=value), ('rate',))


@pytest.mark.parametrize('value', [-1e-9, math.nan, -math.inf])
def test_allow_zero_still_refuses_negative_and_non_finite(value: float) -> None:
    with pytest.raises(ValueError, match=r'_Params\.hold must be finite and >= 0'):
        require_positive(_Params(hold=value), ('hold',), allow_zero=True)
