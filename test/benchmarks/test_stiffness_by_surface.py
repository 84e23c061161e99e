"""The stiffness-by-surface diagnosis labels each estimate with the road it was made on and
names the calibration's road (benchmarks/stiffness_by_surface.py)."""

from __future__ import annotations

import importlib
from pathlib import Path
import sys

import numpy as np

BENCHMARKS = Path(__file__).resolve().parents[2] / 'benchmarks'
sys.path.insert(0, str(BENCHMARKS))    # the scripts import eval_tpms_family beside them
by_surface = importlib.import_module('stiffness_by_surface')


def test_estimates_are_grouped_by_the_road_they_were_made_on() -> None:
    """Asphalt until 60 s, concrete until 200 s, asphalt again: the calibration window (first
    90 s) is mostly asphalt; estimates before 100 s are not judged; a NaN is not counted."""
    stamps = np.arange(0.0, 300.0, 0.25)
    error = np.where(stamps < 200.0, -3.0, 1.0)[:, None].repeat(2, axis=1)
    error[(stamps >= 60.0) & (stamps < 100.0)] = 50.0      # concrete, but not judged yet
    error[stamps >= 290.0, 1] = np.nan
    calibrated_on, means = by_surface.surface_means(
        stamps, error, [0.0, 60.0, 200.0], ['asphalt', 'concrete', 'asphalt'])
    assert calibrated_on == 'asphalt'
    assert means == {'asphalt': 1.0, 'concrete': -3.0}


def test_a_surface_with_too_few_estimates_is_left_out() -> None:
    """Concrete for 5 s only: fewer valid estimates than the minimum, no figure."""
    stamps = np.arange(0.0, 200.0, 0.25)
    error = np.zeros((stamps.size, 1))
    _, means = by_surface.surface_means(stamps, error, [0.0, 150.0, 155.0],
                                        ['asphalt', 'concrete', 'asphalt'])
    assert by_surface.MIN_ESTIMATES > 4 * 5
    assert set(means) == {'asphalt'}
