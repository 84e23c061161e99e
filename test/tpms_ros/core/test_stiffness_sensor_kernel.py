"""The tire stiffness observer's compiled sensor checks held to their numpy form.

``_sensor_chunk`` replaced the numpy per-sample checks of ``TireStiffnessObserver._process``
(validity, dead and stuck sensors, tooth-rate overrun, resets and their causes, hold of bad
samples, settling); the reference below is that implementation. The kernel makes the same
comparisons and copies, so the two agree exactly, over any chunking.
"""

from __future__ import annotations

import numpy as np

from tpms_ros.core.stiffness_observer import (
    _CODE,
    N_WHEELS,
    OK,
    STUCK_TOOTH_PERIODS,
    StiffnessObserverParams,
    sensor_checks,
    sensor_state,
)

COUNTED = ('invalid_sample', 'dead_sensor', 'stuck_sensor', 'settling')


class NumpySensorChecks:
    """The numpy form of the sensor checks (state carried between chunks)."""

    def __init__(self, p: StiffnessObserverParams) -> None:
        self.p = p
        (self.last_value, self.run, self.prev_good, self.prev_code, self.hold,
         self.since_reset, self.reset_cause) = sensor_state()
        # Wheels that count teeth (RR: a window average in the angle domain, never overruns).
        self.counted = np.array([True, True, True, False])

    def __call__(self, omega: np.ndarray, timing_break: np.ndarray,
                 ) -> tuple[np.ndarray, ...]:
        p = self.p
        n = omega.shape[0]
        idx = np.arange(n)[:, None]
        fs = p.sample_rate_hz
        code = np.zeros((n, N_WHEELS), dtype=np.int64)
        finite = np.isfinite(omega)
        invalid = ~finite | (np.where(finite, omega, 0.0) < 0.0) | (
            np.where(finite, omega, 0.0) > p.max_omega_rad_s)
        speed_min = p.speed_band_kmh[0] / 3.6 / p.rolling_radius_m
        plausible = np.where(invalid, 0.0, omega)
        others_max = np.stack([np.delete(plausible, w, axis=1).max(axis=1)
                               for w in range(N_WHEELS)], axis=1)
        dead = ~invalid & (omega < p.dead_omega_rad_s) & (others_max >= max(speed_min, 1e-9))
        prev = np.concatenate((self.last_value[None], omega[:-1]))
        change = np.where(omega == prev, -1, idx)
        last_change = np.maximum.accumulate(change, axis=0)
        run = np.where(last_change >= 0, idx - last_change, idx + 1 + self.run[None])
        with np.errstate(divide='ignore', invalid='ignore'):
            tooth_periods = np.where(~invalid & (omega > 0.0), STUCK_TOOTH_PERIODS * fs / (
                omega * (p.encoder_teeth / (2.0 * np.pi))), 0.0)
        stuck = ~invalid & ~dead & (run >= np.maximum(int(round(p.stuck_s * fs)),
                                                       tooth_periods))
        self.run = run[-1].copy()
        self.last_value = omega[-1].copy()
        code[stuck] = _CODE['stuck_sensor']
        code[dead] = _CODE['dead_sensor']
        code[invalid] = _CODE['invalid_sample']
        if p.tooth_correction:
            tooth_rate = plausible * (p.encoder_teeth / (2.0 * np.pi))
            overrun = ((code == OK) & self.counted[None]
                       & (tooth_rate > p.max_tooth_rate_fraction * fs))
            code[overrun] = _CODE['speed_band']
        counts = [(code == _CODE[name]).sum(axis=0) for name in COUNTED[:3]]
        good = code == OK
        prev_good = np.concatenate((self.prev_good[None], good[:-1]))
        prev_code = np.concatenate((self.prev_code[None], code[:-1]))
        reset = good & ((good & ~prev_good) | timing_break[:, None])
        cause = np.where(timing_break[:, None], _CODE['timing'],
                         np.where(prev_code == OK, _CODE['settling'], prev_code))
        self.prev_good = good[-1].copy()
        self.prev_code = code[-1].copy()
        last_good_idx = np.maximum.accumulate(np.where(good, idx, -1), axis=0)
        hold = np.where(np.isfinite(self.hold), self.hold, 0.0)
        filled = np.where(last_good_idx >= 0,
                          np.take_along_axis(omega, np.maximum(last_good_idx, 0), axis=0),
                          hold[None])
        self.hold = filled[-1].copy()
        last_reset = np.maximum.accumulate(np.where(reset, idx, -1), axis=0)
        since = np.where(last_reset >= 0, idx - last_reset, idx + 1 + self.since_reset[None])
        settle_cause = np.where(last_reset >= 0,
                                np.take_along_axis(cause, np.maximum(last_reset, 0), axis=0),
                                self.reset_cause[None])
        self.since_reset = since[-1].copy()
        self.reset_cause = settle_cause[-1].copy()
        settling = good & (since < int(round(p.settle_s * fs)))
        code = np.where(settling, settle_cause, code)
        counts.append(settling.sum(axis=0))
        return code, good, reset, filled, np.array(counts)


class KernelSensorChecks(NumpySensorChecks):
    """The same state, through the compiled kernel."""

    def __call__(self, omega: np.ndarray, timing_break: np.ndarray,
                 ) -> tuple[np.ndarray, ...]:
        return sensor_checks(self.p, omega, timing_break, (
            self.last_value, self.run, self.prev_good, self.prev_code, self.hold,
            self.since_reset, self.reset_cause), counted=self.counted)


def _faulty_speeds(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Held tooth speeds around 60 rad/s with every kind of fault, and some timing breaks."""
    omega = np.round(60.0 + np.cumsum(rng.normal(0.0, 0.05, (n, N_WHEELS)), axis=0), 2)
    omega[100:160, 0] = 61.0                      # stuck
    omega[300:420, 1] = 0.2                       # dead while the others roll
    omega[500:505, 2] = np.nan                    # dropout
    omega[700, 3] = -1.0                          # negative
    omega[800:803, 0] = 1e4                       # absurd
    omega[900:1000, 2:] += 70.0                   # tooth edges faster than the samples
    omega[1200:1400, :] = 0.1                     # all wheels crawling: not dead
    omega[1600:1700, 1] = 2.0                     # a slow tooth (65 ms) held: not stuck
    omega[:30, 3] = np.inf                        # bad from the start
    timing_break = rng.random(n) < 0.001
    timing_break[1500] = True
    return omega, timing_break


def test_sensor_kernel_equals_numpy_over_any_chunking() -> None:
    rng = np.random.default_rng(3)
    omega, timing_break = _faulty_speeds(rng, 2500)
    for p in (StiffnessObserverParams(settle_s=0.05),
              StiffnessObserverParams(tooth_correction=False, settle_s=0.05)):
        reference, kernel = NumpySensorChecks(p), KernelSensorChecks(p)
        seen: set[int] = set()
        start = 0
        while start < omega.shape[0]:
            stop = min(omega.shape[0], start + int(rng.integers(1, 300)))
            expected = reference(omega[start:stop], timing_break[start:stop])
            got = kernel(omega[start:stop], timing_break[start:stop])
            for e, g in zip(expected, got, strict=True):
                np.testing.assert_array_equal(g, e)
            start = stop
            seen.update(np.unique(got[0]).tolist())
        for name in ('prev_good', 'prev_code', 'hold', 'last_value', 'run', 'since_reset',
                     'reset_cause'):
            np.testing.assert_array_equal(getattr(kernel, name), getattr(reference, name))
        # Every sample code the kernel sets was exercised.
        assert {OK, *(_CODE[name] for name in (*COUNTED, 'timing'))} <= seen
        assert (_CODE['speed_band'] in seen) == p.tooth_correction


def test_a_slow_wheel_holding_its_tooth_period_is_not_stuck() -> None:
    """At 2 rad/s a 48-tooth ring's reading is held 65 ms, beyond ``stuck_s``: still a live
    sensor (its tooth count must survive a crawl); the same reading held past three of its own
    tooth periods is stuck."""
    p = StiffnessObserverParams()
    omega = np.full((400, N_WHEELS), 60.0) + np.arange(400)[:, None] * 1e-3
    omega[:, 1] = 2.0
    code, good, _, _, counts = KernelSensorChecks(p)(omega, np.zeros(400, dtype=bool))
    tooth_period = 2.0 * np.pi / (p.encoder_teeth * 2.0) * p.sample_rate_hz   # samples
    first_stuck = int(np.ceil(STUCK_TOOTH_PERIODS * tooth_period))  # run of equal readings
    assert first_stuck > p.stuck_s * p.sample_rate_hz
    assert good[:first_stuck, 1].all() and not good[first_stuck:, 1].any()
    assert (code[first_stuck:, 1] == _CODE['stuck_sensor']).all()
    assert counts[2, 1] == 400 - first_stuck
