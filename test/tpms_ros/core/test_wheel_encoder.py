"""The synthetic quantisation noise of the ECU's timer (tpms_ros.core.wheel_encoder)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.signal as sig

from tpms_ros.core.wheel_encoder import QuantisationNoise, TimerLattice, encoder_wheel_speed

FS = 1000.0
TEETH = 48
TIMER_S = 4e-6
WINDOW_S = 0.005


def _vibrating_wheel(seconds: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(t (N + 1,), rim speed (N + 1,)): 55 rad/s with a 40 Hz torsional vibration and a
    slow speed change, as a wheel on the road turns."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * FS) + 1) / FS
    rim = (55.0 + 2.0 * np.sin(2 * np.pi * 0.05 * t) + 0.3 * np.sin(2 * np.pi * 40.0 * t)
           + 0.05 * rng.standard_normal(t.size))
    return t, rim


@pytest.mark.parametrize('method', ['tooth_period', 'window_average'])
def test_quantisation_noise_is_the_ecu_timers_error(method):
    """On the same wheel, the synthetic noise has the size and the spectrum in the stiffness
    method's band (25-60 Hz) of the error the simulator's encoder gets from the same timer
    (measured: sd ratio 0.99 / 0.98, band power ratio 0.97-1.05)."""
    t, rim = _vibrating_wheel(60.0, seed=2)
    ring = np.zeros(TEETH)
    actual = (encoder_wheel_speed(t, rim, t[1:], ring, 0.0, TIMER_S, method, WINDOW_S)
              - encoder_wheel_speed(t, rim, t[1:], ring, 0.0, 0.0, method, WINDOW_S))
    noise = QuantisationNoise(1, TEETH, FS, TIMER_S, method, WINDOW_S)
    # The encoder integrates the rim speed by the trapezoid rule, the noise model per sample.
    synthetic = noise.process(0.5 * (rim[:-1] + rim[1:])[:, None])[:, 0]
    actual, synthetic = actual[100:], synthetic[100:]
    assert synthetic.std() == pytest.approx(actual.std(), rel=0.06)
    freq, p_actual = sig.welch(actual, fs=FS, nperseg=2048)
    _, p_synthetic = sig.welch(synthetic, fs=FS, nperseg=2048)
    band = (freq >= 25.0) & (freq <= 60.0)
    assert p_synthetic[band].mean() == pytest.approx(p_actual[band].mean(), rel=0.15)


def test_quantisation_noise_does_not_depend_on_the_chunking():
    """The edges and their draws carry across chunks: any chunking gives the same noise."""
    _, rim = _vibrating_wheel(20.0, seed=3)
    speed = np.column_stack([rim[1:], rim[1:] + 10.0])
    whole = QuantisationNoise(2, TEETH, FS, TIMER_S, 'window_average', WINDOW_S).process(speed)
    noise = QuantisationNoise(2, TEETH, FS, TIMER_S, 'window_average', WINDOW_S)
    rng = np.random.default_rng(4)
    parts, start = [], 0
    while start < speed.shape[0]:
        step = int(rng.integers(1, 600))
        parts.append(noise.process(speed[start:start + step]))
        start += step
    np.testing.assert_allclose(np.concatenate(parts), whole, atol=1e-9)


class NumpyQuantisationNoise(QuantisationNoise):
    """The numpy form of ``QuantisationNoise.process`` that the compiled edge times and speed
    error replaced (the reference they are held to)."""

    def process(self, speed: np.ndarray) -> np.ndarray:
        n = speed.shape[0]
        t = (self._samples + np.arange(n + 1)) * self._dt
        self._samples += n
        error = np.zeros(speed.shape)
        for w in range(speed.shape[1]):
            angle = self._angle[w] + np.concatenate(([0.0], np.cumsum(speed[:, w] * self._dt)))
            tooth = np.floor(angle / self._pitch)
            crossed = np.maximum(tooth[1:] - tooth[:-1], 0.0).astype(int)
            rows = np.repeat(np.arange(n), crossed)
            starts = np.repeat(tooth[:-1] + 1, crossed)
            edge_tooth = starts + (np.arange(crossed.sum())
                                   - np.repeat(np.cumsum(crossed) - crossed, crossed))
            frac = (edge_tooth * self._pitch - angle[rows]) / np.maximum(
                angle[rows + 1] - angle[rows], 1e-300)
            new = t[rows] + frac * self._dt
            exact = np.concatenate((self._exact[w], new))
            stamped = np.concatenate((self._stamped[w],
                                      new - self._rng[w].uniform(0.0, self._timer, new.size)))
            if exact.size >= 2:
                last = np.searchsorted(exact, t[1:], side='right') - 1
                first = np.searchsorted(exact, t[1:] - self._window, side='right') - 1
                first = np.minimum(first, last - 1)
                ok = first >= 0
                last, first = last[ok], first[ok]
                count = self._pitch * (last - first)
                error[ok, w] = (count / np.maximum(stamped[last] - stamped[first], 1e-12)
                                - count / (exact[last] - exact[first]))
            keep = max(int(np.searchsorted(exact, t[-1] - self._window, side='right')) - 2, 0)
            self._exact[w], self._stamped[w] = exact[keep:], stamped[keep:]
            self._angle[w] = angle[-1] - tooth[-1] * self._pitch
        return error


@pytest.mark.parametrize('method', ['tooth_period', 'window_average'])
def test_quantisation_noise_is_its_numpy_form(method):
    """The compiled edges and errors are the numpy form's, over any chunking, a standstill,
    speeds that turn the ring backwards and a reset: to the bit on this project's machines,
    held to rounding (a compiler that fuses multiply-adds may differ in the last bit)."""
    _, rim = _vibrating_wheel(6.0, seed=5)
    speed = np.column_stack([rim[1:], rim[1:] + 30.0, 0.02 * rim[1:], rim[1:] - 55.5])
    speed[2000:2300, 0] = 0.0
    compiled = QuantisationNoise(4, TEETH, FS, TIMER_S, method, WINDOW_S)
    reference = NumpyQuantisationNoise(4, TEETH, FS, TIMER_S, method, WINDOW_S)
    rng = np.random.default_rng(6)
    start, errors = 0, []
    while start < speed.shape[0]:
        step = int(rng.integers(0, 400))
        if start <= 3000 < start + step:
            compiled.reset(np.array([1]))
            reference.reset(np.array([1]))
        chunk = speed[start:start + step]
        errors.append(compiled.process(chunk))
        np.testing.assert_allclose(errors[-1], reference.process(chunk), rtol=1e-12,
                                   atol=1e-9)
        start += step
    assert np.all(np.count_nonzero(np.concatenate(errors), axis=0) > 1000)


def test_quantisation_noise_waits_for_edges_after_a_reset():
    """A reset wheel reads no noise until it has two new edges; the other wheel goes on."""
    speed = np.full((400, 2), 55.0)
    noise = QuantisationNoise(2, TEETH, FS, TIMER_S, 'tooth_period', WINDOW_S)
    noise.process(speed)
    noise.reset(np.array([0]))
    after = noise.process(speed[:10])
    assert np.all(after[:2, 0] == 0.0)      # one edge every ~2.4 samples at 55 rad/s
    assert np.any(after[:, 1] != 0.0)
    assert np.any(after[5:, 0] != 0.0)


def _measured(method: str, timer_s: float, teeth: int, window_s: float = WINDOW_S,
              seconds: float = 20.0, seed: int = 5) -> np.ndarray:
    """(N, 4) speeds of four vibrating wheels as an ECU measures them, rings with 0.2 % rms
    tooth-spacing error."""
    rng = np.random.default_rng(seed)
    columns = []
    for w in range(4):
        t, rim = _vibrating_wheel(seconds, seed=seed + w)
        ring = rng.normal(0.0, 0.002 * 2 * np.pi / teeth, teeth)
        columns.append(encoder_wheel_speed(t, rim + 2.0 * w, t[1:], ring, 0.3 * w, timer_s,
                                           method, window_s))
    return np.column_stack(columns)


@pytest.mark.parametrize(('timer_s', 'teeth'), [(1e-6, 48), (2.5e-6, 43), (4e-6, 60)])
def test_timer_lattice_reads_the_timer_of_held_tooth_periods(timer_s, teeth):
    """Held tooth periods are whole timer steps, whatever the ring's error: the step is read
    exactly, within the first 3 s of four wheels (measured: 0.24, 1.7, 0.61 s)."""
    speed = _measured('tooth_period', timer_s, teeth)
    lattice = TimerLattice(teeth, FS)
    row = lattice.add(speed, np.ones(speed.shape, dtype=bool))
    assert lattice.timer_s == pytest.approx(timer_s, rel=1e-6)
    assert row is not None and row < 3000


@pytest.mark.parametrize('case', ['window_average', 'two_tooth_window', 'exact', 'low_passed'])
def test_timer_lattice_refuses_speeds_that_are_not_held_tooth_periods(case):
    """A window average over several teeth (here ~3-4), exact speeds and a filtered signal
    lie on no lattice of timer steps; a window of about two teeth does (half the timer's
    step), but its reading changes about twice per tooth. Each: 0, not read (the noise is then
    not removed)."""
    if case == 'window_average':
        speed = _measured('window_average', TIMER_S, TEETH, window_s=0.008)
    elif case == 'two_tooth_window':
        speed = _measured('window_average', TIMER_S, TEETH, window_s=0.003)
    elif case == 'exact':
        speed = _measured('tooth_period', 0.0, TEETH)
    else:
        speed = sig.sosfilt(sig.butter(2, 100.0, fs=FS, output='sos'),
                            _measured('tooth_period', TIMER_S, TEETH), axis=0)[200:]
    lattice = TimerLattice(TEETH, FS)
    assert lattice.add(speed, np.ones(speed.shape, dtype=bool)) is not None
    assert lattice.timer_s == 0.0


def test_timer_lattice_decides_at_the_same_reading_however_chunked():
    """The decision falls on a reading, not on a chunk's end."""
    speed = _measured('tooth_period', TIMER_S, TEETH)
    valid = speed > 56.0   # some readings left out, as the method's gates do
    whole = TimerLattice(TEETH, FS)
    decided_at = whole.add(speed, valid)
    chunked = TimerLattice(TEETH, FS)
    rng = np.random.default_rng(6)
    start, decided = 0, None
    while decided is None and start < speed.shape[0]:
        step = int(rng.integers(1, 300))
        row = chunked.add(speed[start:start + step], valid[start:start + step])
        decided = None if row is None else start + row
        start += step
    assert decided == decided_at
    assert chunked.timer_s == whole.timer_s


def test_timer_lattice_decides_on_a_steady_drive_with_a_coarse_timer():
    """A coarse timer at a steady speed gives few distinct readings; once it has waited its
    readings (10 s of four wheels) it decides on those (here 24) rather than keep the
    calibration waiting."""
    speed = _measured('tooth_period', 16e-6, TEETH, seconds=40.0)
    lattice = TimerLattice(TEETH, FS)
    row = lattice.add(speed, np.ones(speed.shape, dtype=bool))
    assert row is not None and lattice.collected < 40
    assert lattice.timer_s == pytest.approx(16e-6, rel=1e-6)


def test_timer_lattice_keeps_a_held_timer_through_a_stop():
    """Once read, the timer stays: a held period changes at most once per tooth, and the
    readings of a stopping wheel (which fall sample by sample with no edge) are outside the
    speeds the method uses, so the watch never sees a window average."""
    t = np.arange(int(60.0 * FS) + 1) / FS
    rim = np.interp(t, [0.0, 20.0, 28.0, 32.0, 40.0, 60.0], [55.0, 55.0, 0.0, 0.0, 55.0, 55.0])
    rim = rim + 0.3 * np.sin(2 * np.pi * 40.0 * t) * (rim > 5.0)
    speed = np.column_stack([encoder_wheel_speed(t, rim, t[1:], np.zeros(TEETH), 0.2 * w,
                                                 TIMER_S) for w in range(4)])
    lattice = TimerLattice(TEETH, FS)
    valid = speed > 28.0       # the method's speed band (30 km/h at 0.3 m)
    row = lattice.add(speed, valid)
    assert row is not None and lattice.timer_s == pytest.approx(TIMER_S, rel=1e-6)
    assert lattice.watch(speed[row + 1:], valid[row + 1:]) is None
    assert not lattice.window_seen
