"""The kept front track (core.track_history): what a rear wheelset reads, a distance later."""

from __future__ import annotations

import numpy as np
import pytest

from rail_monitor_ros.core.track_history import TrackHistory


def test_a_distance_between_samples_is_interpolated() -> None:
    history = TrackHistory(2, 10)
    for k in range(6):
        history.push(np.array([float(k), 10.0 * k]), 2.0 * k)
    # The last sample is k = 5 at 10 m: 4.5 m before it is 5.5 m, k = 2.75.
    assert history.behind(4.5) == pytest.approx([2.75, 27.5])
    assert history.behind(0.0) == pytest.approx([5.0, 50.0])
    assert history.behind(10.0) == pytest.approx([0.0, 0.0])


def test_an_accelerating_car_reads_where_it_stood_not_a_present_speed_delay() -> None:
    """Samples 1, 2, 3, 4 m apart (accelerating): 5 m before the last (10 m) is 5 m, two thirds
    of the way from sample 2 (3 m) to sample 3 (6 m); the present speed's delay (4 m a sample:
    1.25 samples) would read sample 2.75."""
    history = TrackHistory(1, 8)
    for k, distance in enumerate((0.0, 1.0, 3.0, 6.0, 10.0)):
        history.push(np.array([float(k)]), distance)
    assert history.behind(5.0) == pytest.approx([2.0 + 2.0 / 3.0])


def test_nothing_older_than_what_is_kept() -> None:
    history = TrackHistory(1, 4)
    assert history.behind(0.0) is None            # nothing pushed
    for k in range(10):
        history.push(np.array([float(k)]), float(k))
    assert history.behind(2.5) == pytest.approx([6.5])      # the four kept: 9, 8, 7, 6
    assert history.behind(3.0) == pytest.approx([6.0])
    assert history.behind(3.5) is None            # needs the sample 4 back: overwritten


def test_missing_samples_and_missing_rates_are_nan() -> None:
    history = TrackHistory(4, 8)
    history.push(np.array([1.0, 2.0]), 0.0)       # alignment without its rate
    history.push(None, 1.0)                        # no track sample at all
    history.push(np.array([3.0, 4.0, 0.1, 0.2]), 2.0)
    assert np.all(np.isnan(history.behind(1.0)))
    assert np.isnan(history.behind(0.5)).all()    # one neighbour missing: unknown
    assert history.behind(2.0)[:2] == pytest.approx([1.0, 2.0])
    assert np.isnan(history.behind(2.0)[2:]).all()


def test_clear_forgets_and_bad_arguments_are_refused() -> None:
    history = TrackHistory(1, 4)
    for k in range(3):
        history.push(np.array([float(k)]), float(k))
    history.clear()
    assert history.behind(0.0) is None
    with pytest.raises(ValueError, match='behind'):
        history.behind(-1.0)
    with pytest.raises(ValueError, match='capacity'):
        TrackHistory(1, 1)


def test_between_samples_the_cubic_through_four_is_used() -> None:
    """Values k^2 at samples 1 m apart: between two samples with a neighbour on each side the
    lookup is the quadratic's value (Catmull-Rom reproduces it), where linear interpolation is
    off by f (1 - f); next to the newest sample it is linear."""
    history = TrackHistory(1, 10)
    for k in range(8):
        history.push(np.array([float(k * k)]), float(k))
    # 3.75 m behind the last (7 m) is 3.25 m: between samples 3 and 4, neighbours 2 and 5.
    assert history.behind(3.75) == pytest.approx([3.25 ** 2])
    assert history.behind(2.5) == pytest.approx([4.5 ** 2])
    # Between the two newest (6 and 7) no sample after: linear, 6.5 -> 42.5 against 42.25.
    assert history.behind(0.5) == pytest.approx([42.5])


def test_an_outer_sample_missing_leaves_the_lookup_linear() -> None:
    history = TrackHistory(2, 10)
    for k in range(8):
        history.push(None if k == 2 else np.array([float(k * k), 1.0]), float(k))
    # 3.75 m behind the last is 3.25 m: neighbours 3 and 4 known, the outer 2 missing.
    assert history.behind(3.75) == pytest.approx([0.75 * 9.0 + 0.25 * 16.0, 1.0])
    assert np.isnan(history.behind(4.5)).all()     # between 2 and 3: a neighbour missing
