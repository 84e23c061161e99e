"""The IMU pairer the rail nodes share: pairs by stamp, in order, gives up on missing partners."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle_monitor_common.imu_pairing import ImuPair, ImuPairer

MS = 1_000_000
PERIOD = 5 * MS


def _feed(pairer: ImuPairer, events: list[tuple[str, int]]) -> list[ImuPair]:
    out: list[ImuPair] = []
    for stream, stamp in events:
        out += pairer.add(stream, stamp, (stream, stamp))
    return out


def test_interleaved_streams_pair_one_to_one_in_order() -> None:
    """Bogie then body (or body then bogie) at the same instants: one pair each, in order,
    stamped with the bogie stamp, body within the tolerance."""
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.1)
    events = []
    for k in range(10):
        first, second = ('bogie', 'body') if k % 2 else ('body', 'bogie')
        offset = {'bogie': 0, 'body': 300_000 if k == 4 else 0}
        events += [(first, k * PERIOD + offset[first]), (second, k * PERIOD + offset[second])]
    out = _feed(pairer, events)
    assert [p.stamp_ns for p in out] == [k * PERIOD for k in range(10)]
    assert all(p.body is not None and p.bogie[0] == 'bogie' for p in out)
    assert out[4].body == ('body', 4 * PERIOD + 300_000)
    assert pairer.unpaired == {'bogie': 0, 'body': 0} and pairer.pending == 0


def test_missing_body_sample_comes_back_alone_once_the_body_stream_passes() -> None:
    """A bogie sample whose body sample never comes is given back with body None as soon as
    a later body sample arrives, before the later pair (stamp order)."""
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.1)
    assert _feed(pairer, [('bogie', 0)]) == []
    out = _feed(pairer, [('bogie', PERIOD), ('body', PERIOD)])
    assert [(p.stamp_ns, p.body is None) for p in out] == [(0, True), (PERIOD, False)]
    assert pairer.unpaired == {'bogie': 1, 'body': 0}


def test_missing_bogie_sample_drops_the_body_sample() -> None:
    """A body sample whose bogie sample never comes is dropped and counted, not paired with
    the next bogie sample (outside the tolerance)."""
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.1)
    out = _feed(pairer, [('body', 0), ('body', PERIOD), ('bogie', PERIOD)])
    assert [(p.stamp_ns, p.body) for p in out] == [(PERIOD, ('body', PERIOD))]
    assert pairer.unpaired == {'bogie': 0, 'body': 1}


def test_dead_body_imu_times_out() -> None:
    """With the body IMU silent, bogie samples wait at most the timeout (in stamp time)."""
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.02)
    out = _feed(pairer, [('bogie', k * PERIOD) for k in range(10)])
    # Sample k is given up when sample k + 5 (25 ms later > 20 ms) arrives.
    assert [p.stamp_ns for p in out] == [k * PERIOD for k in range(5)]
    assert all(p.body is None for p in out)
    assert pairer.pending == 5


@pytest.mark.parametrize('stream', ['bogie', 'body'])
@pytest.mark.parametrize('stamps, reason', [([0, 0], 'repeated'), ([PERIOD, 0], 'out_of_order')])
def test_repeated_and_out_of_order_samples_are_refused(stream: str, stamps: list[int],
                                                       reason: str) -> None:
    """A stamp not newer than the previous one of its stream is refused and counted by
    stream and reason."""
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.1)
    _feed(pairer, [(stream, s) for s in stamps])
    assert pairer.rejected == {f'{stream}_{reason}': 1}
    assert pairer.pending == 1


def test_random_losses_keep_every_surviving_pair() -> None:
    """Seeded random losses on both streams: every instant with both samples is paired, every
    bogie-only instant comes back alone, all in stamp order; nothing is left behind once the
    streams move on."""
    rng = np.random.default_rng(3)
    n = 500
    bogie_ok = rng.random(n) > 0.1
    body_ok = rng.random(n) > 0.1
    jitter = rng.integers(-200_000, 200_000, n)
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.1)
    out: list[ImuPair] = []
    for k in range(n):
        order = ['bogie', 'body'] if rng.random() < 0.5 else ['body', 'bogie']
        for stream in order:
            if stream == 'bogie' and bogie_ok[k]:
                out += pairer.add('bogie', k * PERIOD, k)
            elif stream == 'body' and body_ok[k]:
                out += pairer.add('body', k * PERIOD + int(jitter[k]), k)
    out += pairer.add('bogie', (n + 100) * PERIOD, n + 100)
    out += pairer.add('body', (n + 100) * PERIOD, n + 100)
    stamps = [p.stamp_ns for p in out]
    assert stamps == sorted(stamps)
    paired = [p.bogie for p in out if p.body is not None]
    assert paired == [k for k in range(n) if bogie_ok[k] and body_ok[k]] + [n + 100]
    assert all(p.body == p.bogie for p in out if p.body is not None)
    alone = [p.bogie for p in out if p.body is None]
    assert alone == [k for k in range(n) if bogie_ok[k] and not body_ok[k]]
    assert pairer.unpaired['body'] == int(np.sum(body_ok & ~bogie_ok))


def test_bad_settings_are_refused() -> None:
    """A negative tolerance or a non-positive timeout raises ValueError naming it."""
    with pytest.raises(ValueError, match='tolerance_s'):
        ImuPairer(tolerance_s=-1.0, timeout_s=0.1)
    with pytest.raises(ValueError, match='timeout_s'):
        ImuPairer(tolerance_s=0.0, timeout_s=0.0)


def test_reset_starts_a_new_time_line() -> None:
    """After reset (a time jump), samples stamped before the old ones pair again; waiting
    samples are forgotten, the counters kept."""
    pairer = ImuPairer(tolerance_s=1e-3, timeout_s=0.1)
    _feed(pairer, [('bogie', 100 * PERIOD), ('body', 100 * PERIOD), ('bogie', 101 * PERIOD)])
    assert pairer.add('bogie', PERIOD, 'old') == []          # behind: refused
    pairer.reset()
    assert pairer.pending == 0
    out = _feed(pairer, [('bogie', PERIOD), ('body', PERIOD)])
    assert [p.stamp_ns for p in out] == [PERIOD]
    assert pairer.rejected == {'bogie_out_of_order': 1}
