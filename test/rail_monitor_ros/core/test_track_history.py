"""The kept front track (core.track_history): what a rear wheelset reads, a delay later."""

from __future__ import annotations

import numpy as np
import pytest

from rail_monitor_ros.core.track_history import TrackHistory


def test_a_delay_between_samples_is_interpolated() -> None:
    history = TrackHistory(2, 10)
    for k in range(6):
        history.push(np.array([float(k), 10.0 * k]))
    # The last sample is k = 5: 2.25 samples before it is k = 2.75.
    assert history.delayed(2.25) == pytest.approx([2.75, 27.5])
    assert history.delayed(0.0) == pytest.approx([5.0, 50.0])


def test_nothing_older_than_what_is_kept() -> None:
    history = TrackHistory(1, 4)
    history.push(np.array([1.0]))
    assert history.delayed(0.5) is None           # one sample: nothing to interpolate with
    for k in range(10):
        history.push(np.array([float(k)]))
    assert history.delayed(2.5) == pytest.approx([6.5])     # the four kept: 9, 8, 7, 6
    assert history.delayed(3.0) == pytest.approx([6.0])
    assert history.delayed(3.5) is None           # needs the sample 4 back: overwritten


def test_missing_samples_and_missing_rates_are_nan() -> None:
    history = TrackHistory(4, 8)
    history.push(np.array([1.0, 2.0]))            # alignment without its rate
    history.push(None)                             # no track sample at all
    history.push(np.array([3.0, 4.0, 0.1, 0.2]))
    assert np.all(np.isnan(history.delayed(1.0)))
    assert np.isnan(history.delayed(0.5)).all()   # one neighbour missing: unknown
    assert history.delayed(2.0)[:2] == pytest.approx([1.0, 2.0])
    assert np.isnan(history.delayed(2.0)[2:]).all()


def test_clear_forgets_and_bad_arguments_are_refused() -> None:
    history = TrackHistory(1, 4)
    for k in range(3):
        history.push(np.array([float(k)]))
    history.clear()
    assert history.delayed(0.0) is None
    with pytest.raises(ValueError, match='delay'):
        history.delayed(-1.0)
    with pytest.raises(ValueError, match='capacity'):
        TrackHistory(1, 1)
