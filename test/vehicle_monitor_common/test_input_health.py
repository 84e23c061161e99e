"""Input plumbing: stamp checks through time jumps, rate meter, frozen-sensor detector."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle_monitor_common.input_health import FrozenDetector, RateMeter, StampCheck

MS = 1_000_000
S = 1_000_000_000


def _run(check: StampCheck, stamps: list[int]) -> list[str]:
    return [check.check(s) for s in stamps]


def test_clean_stream_and_transport_faults() -> None:
    """Increasing stamps pass; a repeated or late one is rejected; a long step is a gap."""
    check = StampCheck(max_gap_s=0.5)
    verdicts = _run(check, [0, 1 * MS, 1 * MS, 0, 2 * MS, 2 * MS + 1 * S])
    assert verdicts == ['ok', 'ok', 'repeated', 'out_of_order', 'ok', 'gap']
    assert check.rejected == {'repeated': 1, 'out_of_order': 1}


def test_single_future_stamp_is_dropped_not_adopted() -> None:
    """One message stamped 10 000 s ahead is dropped and counted; the stream goes on at its own
    time (before, it became "now" and every later sample was rejected as out of order)."""
    check = StampCheck(max_gap_s=0.5)
    stamps = [k * MS for k in range(10)] + [10_000 * S] + [k * MS for k in range(10, 30)]
    verdicts = _run(check, stamps)
    assert verdicts[10] == 'future_stamp'
    assert verdicts[11:] == ['ok'] * 20
    assert check.jumps == 0 and check.last_ns == 29 * MS


@pytest.mark.parametrize('offset_s', [-200.0, -0.5, 60.0, 10_000.0])
def test_confirmed_jump_restarts_the_stream(offset_s: float) -> None:
    """A replay looping back (or the clock stepping) is followed after confirm_samples stamps:
    the last confirming one is 'jump', everything after it is accepted again."""
    check = StampCheck(max_gap_s=0.5, confirm_samples=5)
    base = 300 * S
    first = [base + k * MS for k in range(100)]
    jumped = [base + 99 * MS + int(offset_s * S) + k * MS for k in range(1, 50)]
    verdicts = _run(check, first + jumped)
    after = verdicts[100:]
    assert after[:4] == ['out_of_order' if offset_s < 0 else 'future_stamp'] * 4
    assert after[4] == 'jump' and after[5:] == ['ok'] * 44
    assert check.jumps == 1 and check.last_jump_s == pytest.approx(offset_s + 0.005, abs=1e-3)


def test_scattered_outliers_never_confirm_a_jump() -> None:
    """Outliers that do not continue each other (random corrupt stamps) are each dropped."""
    rng = np.random.default_rng(3)
    check = StampCheck(max_gap_s=0.5, confirm_samples=3)
    stamps, t = [], 0
    for _ in range(500):
        t += MS
        stamps.append(t)
        if rng.random() < 0.2:
            stamps.append(int(rng.uniform(-1e6, 1e6)) * S)
    verdicts = _run(check, stamps)
    assert 'jump' not in verdicts
    assert check.last_ns == t


def test_rate_meter() -> None:
    """Messages per second between reads, on the caller's clock."""
    meter = RateMeter()
    assert meter.read(0) == 0.0
    meter.tick(50)
    assert meter.read(S // 2) == pytest.approx(100.0)
    assert meter.read(S) == 0.0


def test_frozen_detector_counts_exact_repeats_per_channel() -> None:
    """The longest run of bit-identical values over the channels; noise resets a channel."""
    detector = FrozenDetector(2)
    runs = [detector.update([1.0, float(k)]) for k in range(5)]
    assert runs == [0, 1, 2, 3, 4]
    assert detector.update([2.0, 4.0]) == 1
    detector.reset()
    assert detector.update([2.0, 4.0]) == 0
