"""The ABS wheel-speed encoder: how an ECU forms a wheel speed from a toothed ring, and a
synthetic realisation of the noise its timer's quantisation leaves in that speed.

One definition for both sides: the road simulator measures its rim speeds with
:func:`encoder_wheel_speed`, and the stiffness observer
(:mod:`tpms_ros.core.stiffness_observer`) passes :class:`QuantisationNoise` through its filters
to take the quantisation noise's second moments out of its least squares
(``encoder_timer_s``; docs/methods/tire_stiffness_observer.md, "Encoder noise"). When the
timer is not given, :class:`TimerLattice` reads it from the speeds themselves.

No ROS import.
"""

from __future__ import annotations

import bisect
import math

from numba import njit, types
import numpy as np

from tpms_ros.core.filter_kernels import lfilter_columns, normalised
from tpms_ros.core.tooth_correction import ANGLE_MODE_ON, MIN_FORM_TEETH

_F1 = types.float64[:]

SPEED_METHODS = ('tooth_period', 'window_average')
"""How an ECU forms the speed from the tooth edges (:func:`encoder_wheel_speed`)."""


def encoder_wheel_speed(t: np.ndarray, rim_speed: np.ndarray, t_out: np.ndarray,
                        tooth_error: np.ndarray, phase: float,
                        timer_resolution_s: float, method: str = 'tooth_period',
                        window_s: float = 0.005) -> np.ndarray:
    """Wheel speed as an ABS ECU measures it from a toothed ring, for one wheel.

    Tooth edges are where the rim angle crosses ``k * pitch + tooth_error[k mod teeth]``; the
    ECU stamps them with its timer (floored to ``timer_resolution_s``) and reports
    ``pitch / period`` of the last completed tooth, assuming a perfect ring, until the next edge.
    When no edge comes for 1.5 periods the report falls as ``1.5 pitch / elapsed``, so a
    stopping wheel reads zero.

    With ``method='window_average'`` the ECU instead reports the teeth passed between the last
    edge before ``t_out - window_s`` and the last edge before ``t_out`` over the time between
    them (the mean of the tooth periods over the window, at least one period): a tooth's
    spacing error then enters only through the two end edges, divided by the teeth counted.

    Args:
        t: (N,) fine time grid, s.
        rim_speed: (N,) true rim angular speed on that grid, rad/s.
        t_out: (M,) output sample times, s.
        tooth_error: (teeth,) edge angle error of each tooth, rad.
        phase: ring angle at t[0], rad.
        timer_resolution_s: ECU timer resolution, s (0: exact).
        method: ``tooth_period`` or ``window_average`` (see above).
        window_s: averaging window of ``window_average``, s.

    Returns:
        (M,) measured wheel speed, rad/s.
    """
    teeth = tooth_error.size
    pitch = 2.0 * np.pi / teeth
    dt = np.diff(t)
    angle = phase + np.concatenate([[0.0], np.cumsum(0.5 * (rim_speed[1:] + rim_speed[:-1])
                                                     * dt)])
    # The ring only counts edges; a wheel rocking backwards at standstill does not re-count.
    angle = np.maximum.accumulate(angle)
    first_tooth = int(math.floor(angle[0] / pitch)) - 1
    last_tooth = int(math.ceil(angle[-1] / pitch)) + 1
    tooth = np.arange(first_tooth, last_tooth + 1)
    edge_angle = tooth * pitch + tooth_error[tooth % teeth]
    edge_angle = edge_angle[(edge_angle > angle[0]) & (edge_angle < angle[-1])]
    after = np.searchsorted(angle, edge_angle, side='right')
    before = after - 1
    frac = (edge_angle - angle[before]) / (angle[after] - angle[before])
    edge_t = t[before] + frac * (t[after] - t[before])
    if timer_resolution_s > 0.0:
        edge_t = np.floor(edge_t / timer_resolution_s) * timer_resolution_s
    if edge_t.size < 2:
        return np.zeros(t_out.size)
    last_edge = np.searchsorted(edge_t, t_out, side='right') - 1
    if method == 'window_average':
        return _window_average_speed(edge_t, t_out, last_edge, pitch, timer_resolution_s,
                                     window_s)
    period = np.maximum(np.diff(edge_t), max(timer_resolution_s, 1e-12))
    tooth_speed = pitch / period                      # valid from edge 1 on
    # Before the second edge the ECU has no period yet: report the first one (start-up).
    held = tooth_speed[np.clip(last_edge - 1, 0, tooth_speed.size - 1)]
    held_period = pitch / held
    elapsed = t_out - edge_t[np.clip(last_edge, 0, edge_t.size - 1)]
    stale = (last_edge >= 0) & (elapsed > 1.5 * held_period)
    out = np.where(stale, 1.5 * pitch / np.maximum(elapsed, 1e-12), held)
    return out


def _window_average_speed(edge_t: np.ndarray, t_out: np.ndarray, last_edge: np.ndarray,
                          pitch: float, timer_resolution_s: float,
                          window_s: float) -> np.ndarray:
    """Edge-to-edge mean speed over the window ending at each output time (see above)."""
    last = np.clip(last_edge, 1, edge_t.size - 1)
    first = np.searchsorted(edge_t, t_out - window_s, side='right') - 1
    first = np.clip(np.minimum(first, last - 1), 0, edge_t.size - 2)
    span = np.maximum(edge_t[last] - edge_t[first], max(timer_resolution_s, 1e-12))
    held = pitch * (last - first) / span
    held_period = span / (last - first)
    elapsed = t_out - edge_t[np.clip(last_edge, 0, edge_t.size - 1)]
    stale = (last_edge >= 0) & (elapsed > 1.5 * held_period)
    return np.where(stale, 1.5 * pitch / np.maximum(elapsed, 1e-12), held)



class QuantisationNoise:
    """The speed error an ECU timer leaves on wheels turning at given speeds, streaming: a
    synthetic realisation of the quantisation noise, for its second moments.

    Per wheel, the ring turns by ``speed / sample_rate_hz`` per sample (a perfect ring: the
    tooth-spacing error is the tooth correction's business); tooth edges fall where its
    angle crosses a tooth, at times interpolated within the sample; each is stamped early by
    a uniform draw in ``[0, timer_s)``, as a timer floors it; the speed is formed as
    :func:`encoder_wheel_speed` forms it, from the stamped and from the exact edges, and the
    difference is the error. The draws stand for where each edge falls on the timer's grid:
    on the road the torsional vibration moves the edges by tens of microseconds, far more
    than a timer step, so that position is random from edge to edge. (Floored stamps of the
    low-passed speed give a pattern set by the speed's ratio to the timer step instead: in
    ``test_encoder_noise_removal_keeps_the_estimate_off_the_road_level`` they took a 20 % bias
    to 12 %, the draws to 1.6 %; floored stamps of the measured speed, whose values already
    sit on the timer's lattice, gave an error of two thirds the size.)
    Only the moments of the noise over many blocks are used, never its values.

    Args:
        n_wheels: wheels.
        teeth: teeth per ring.
        sample_rate_hz: the wheel-speed rate, Hz.
        timer_s: ECU timer resolution, s (> 0).
        method: one of :data:`SPEED_METHODS`.
        window_s: averaging window of ``window_average``, s.
        seed: seed of the draws.
    """

    def __init__(self, n_wheels: int, teeth: int, sample_rate_hz: float, timer_s: float,
                 method: str, window_s: float, seed: int = 0) -> None:
        self._pitch = 2.0 * math.pi / teeth
        self._dt = 1.0 / sample_rate_hz
        self._timer = timer_s
        self._window = window_s if method == 'window_average' else 0.0
        self._samples = 0
        self._angle = np.zeros(n_wheels)
        # One stream per wheel, so the draws do not depend on how the samples are chunked.
        self._rng = [np.random.default_rng([seed, w]) for w in range(n_wheels)]
        empty = np.zeros(0)
        self._exact = [empty] * n_wheels
        self._stamped = [empty] * n_wheels

    def reset(self, wheels: np.ndarray) -> None:
        """Forget the edges of ``wheels`` (the next readings wait for new ones)."""
        for w in wheels:
            self._exact[w] = self._stamped[w] = np.zeros(0)

    def process(self, speed: np.ndarray) -> np.ndarray:
        """(n, wheels) smooth speeds, rad/s -> (n, wheels) quantisation error, rad/s."""
        n = speed.shape[0]
        error = np.zeros(speed.shape)
        for w in range(speed.shape[1]):
            new = np.empty(_max_edges(speed[:, w], self._dt, self._pitch))
            count, self._angle[w] = _edge_times(speed[:, w], self._angle[w], self._samples,
                                                self._dt, self._pitch, new)
            new = new[:count]
            exact = np.concatenate((self._exact[w], new))
            stamped = np.concatenate((self._stamped[w],
                                      new - self._rng[w].uniform(0.0, self._timer, new.size)))
            keep = _speed_error(exact, stamped, self._samples, self._dt, self._window,
                                self._pitch, error[:, w])
            # Keep the edges a later reading can reach back to.
            self._exact[w], self._stamped[w] = exact[keep:], stamped[keep:]
        self._samples += n
        return error


def _max_edges(speed: np.ndarray, dt: float, pitch: float) -> int:
    """At least the number of tooth edges ``speed`` (rad/s, one wheel) crosses in its samples:
    the size :func:`_edge_times` may fill."""
    return int(np.sum(np.maximum(speed, 0.0)) * dt / pitch) + speed.size + 1


@njit(types.Tuple((types.int64, types.float64))(_F1, types.float64, types.int64,
                                                types.float64, types.float64, _F1),
      cache=True, error_model='numpy')
def _edge_times(speed: np.ndarray, angle: float, samples: int, dt: float, pitch: float,
                edges: np.ndarray) -> tuple[int, float]:
    """The exact times of the tooth edges one wheel's ring crosses over a chunk, compiled
    (numba): the ring turns by ``speed * dt`` per sample from ``angle`` (rad past its last
    tooth), and an edge falls where the angle crosses a tooth, at the time interpolated within
    its sample (sample ``i`` of the chunk ends at ``(samples + i + 1) * dt``).

    Why compiled: as numpy (a cumulative angle, the teeth crossed per sample repeated into
    edges) it was some fifteen array calls per wheel and chunk; with the speed error below,
    a fifth of the stiffness observer's cost per chunk. The operations are numpy's, in its order
    (the same to the bit on this project's machines; test/tpms_ros/core/test_wheel_encoder.py
    holds the two to rounding).

    Returns:
        (edges written to ``edges``, the angle past the last tooth at the chunk's end).
    """
    count = 0
    total = 0.0             # numpy's cumsum: a running sum, then added to the start angle
    before = angle
    tooth_before = math.floor(before / pitch)
    for i in range(speed.shape[0]):
        total += speed[i] * dt
        after = angle + total
        tooth_after = math.floor(after / pitch)
        crossed = int(max(tooth_after - tooth_before, 0.0))
        if crossed:
            start = (samples + i) * dt
            span = max(after - before, 1e-300)
            for k in range(crossed):
                frac = ((tooth_before + 1.0 + k) * pitch - before) / span
                edges[count] = start + frac * dt
                count += 1
        before, tooth_before = after, tooth_after
    return count, before - tooth_before * pitch


@njit(types.int64(_F1, _F1, types.int64, types.float64, types.float64, types.float64, _F1),
      cache=True, error_model='numpy')
def _speed_error(exact: np.ndarray, stamped: np.ndarray, samples: int, dt: float,
                 window: float, pitch: float, error: np.ndarray) -> int:
    """One wheel's speed from its stamped edges minus the speed from its exact ones at each
    sample of a chunk, as :func:`encoder_wheel_speed` forms it (the edges in the last
    ``window`` s, at least two; 0 where there are fewer), compiled (numba) with
    :func:`_edge_times`.

    Returns:
        The index of the first edge a later chunk can still reach back to.
    """
    end = samples * dt
    for i in range(error.shape[0]):
        end = (samples + i + 1) * dt
        if exact.shape[0] < 2:
            continue
        last = np.searchsorted(exact, end, side='right') - 1
        first = min(np.searchsorted(exact, end - window, side='right') - 1, last - 1)
        if first < 0:
            continue
        count = pitch * (last - first)
        error[i] = (count / max(stamped[last] - stamped[first], 1e-12)
                    - count / (exact[last] - exact[first]))
    return max(int(np.searchsorted(exact, end - window, side='right')) - 2, 0)


class TimerLattice:
    """The ECU timer's resolution read from held tooth-period speeds.

    A held tooth period is a whole number of timer steps, so ``pitch / speed = k * timer_s``
    for an integer ``k``: the distinct readings of every wheel lie on one lattice, whatever the
    ring's tooth-spacing error (the ECU assumes a perfect ring). Adjacent distinct values are
    a multiple of the step apart and, once the road's vibration spreads the periods over many
    steps, mostly the step itself. The lattice is taken when 98 % of the distinct values lie
    on it and its multiples hold their fair shares of the values (``k`` divisible by ``m`` for
    about 1 / m of them): a window average over ``n`` teeth gives ``k * timer_s / n``, values on
    finer lattices whose multiples hold too many, and filtered signals lie on none; the result
    is then 0, not read. A window average that spans about two teeth at most speeds would
    pass (``k * timer_s / 2`` is a lattice); it is told by how often the reading changes: a
    held period at most once per tooth, a window average also when an edge leaves the window
    (the test the tooth correction makes, :data:`~tpms_ros.core.tooth_correction.ANGLE_MODE_ON`).
    A window longer than a tooth period holds one tooth at low speeds, so a slow start can
    pass all of it; :meth:`watch` goes on testing the changes per tooth after the timer was
    read (over ``form_s``, as the tooth correction does) and says when the readings turn out to
    be window averages.

    Args:
        teeth: teeth per ring.
        sample_rate_hz: the wheel-speed rate, Hz.
        distinct: distinct readings (all wheels) that decide.
        coarse_distinct: fewer that decide once the readings repeat ``repeats`` times each on
            average (a coarse timer at high speed has few steps in the range the speed covers).
        repeats: see ``coarse_distinct``.
        max_readings: readings after which it decides on what it has (0 below 3 distinct
            ones), so that a steady drive on a coarse timer does not keep it waiting.
        form_s: memory of :meth:`watch`'s changes per tooth, s.
        fast_edge_rate: edges per sample from which the changes are not counted (they no
            longer mark single edges).
    """

    def __init__(self, teeth: int, sample_rate_hz: float, distinct: int = 150,
                 coarse_distinct: int = 40, repeats: int = 50,
                 max_readings: int = 40_000, form_s: float = 2.0,
                 fast_edge_rate: float = 0.9) -> None:
        self._fast_edge_rate = fast_edge_rate
        self._pitch = 2.0 * math.pi / teeth
        self._form_decay = math.exp(-1.0 / (form_s * sample_rate_hz))
        self._form = np.zeros((1, 2))     # watch's decaying sums of changes and teeth passed
        self._form_filter = normalised(np.array([1.0]), np.array([1.0, -self._form_decay]))
        self.window_seen = False
        """The readings turned out to be window averages after the timer was read."""
        self._teeth_per_sample = 1.0 / (self._pitch * sample_rate_hz)   # per rad/s
        self._distinct = distinct
        self._coarse_distinct = coarse_distinct
        self._repeats = repeats
        self._max_readings = max_readings
        self._periods = np.zeros(0)
        self._readings = 0
        # Changes of the reading between valid samples, and the teeth passed meanwhile.
        self._previous: np.ndarray | None = None
        self._changes = 0.0
        self._teeth_passed = 0.0
        self.timer_s: float | None = None
        """The step, s; 0 when the readings are not on a lattice; None while collecting."""

    @property
    def collected(self) -> int:
        """Distinct readings collected so far."""
        return self._periods.size

    def add(self, speed: np.ndarray, valid: np.ndarray) -> int | None:
        """Collect the readings of a chunk, row by row, until enough are in to decide.

        Args:
            speed: (n, wheels) readings, rad/s.
            valid: (n, wheels) the readings to use (valid samples of a turning wheel).

        Returns:
            The row at which :attr:`timer_s` was decided, or None (undecided, or decided
            before). Deciding at a row, not at the chunk's end, keeps the result and its
            moment independent of how the readings are chunked.
        """
        if self.timer_s is not None:
            return None
        row_changes, row_teeth = self._changes_and_teeth(speed, valid)
        changes = self._changes + np.cumsum(row_changes)
        passed = self._teeth_passed + np.cumsum(row_teeth)
        periods: list[float] = self._periods.tolist()
        for row in range(speed.shape[0]):
            for value in (self._pitch / speed[row, valid[row]]).tolist():
                self._readings += 1
                # Values within 1e-6 (relative) are one: float rounding on the way from the
                # ECU is far below that, any timer step far above.
                at = bisect.bisect_left(periods, value)
                near = [periods[i] for i in (at - 1, at) if 0 <= i < len(periods)]
                if all(abs(value - other) > 1e-6 * value for other in near):
                    periods.insert(at, value)
            n = len(periods)
            if n >= self._distinct or (n >= self._coarse_distinct
                                       and self._readings >= self._repeats * n):
                self.timer_s = lattice_step(np.array(periods))
            elif self._readings >= self._max_readings:
                self.timer_s = lattice_step(np.array(periods)) if n >= 3 else 0.0
            if self.timer_s is not None:
                self._periods = np.array(periods)
                self._previous = np.where(valid[row], speed[row], np.nan)
                if changes[row] > ANGLE_MODE_ON * passed[row]:
                    self.timer_s = 0.0
                return row
        self._periods = np.array(periods)
        self._changes, self._teeth_passed = float(changes[-1]), float(passed[-1])
        return None

    def watch(self, speed: np.ndarray, valid: np.ndarray) -> int | None:
        """After the timer was read, go on testing the changes per tooth of the readings
        (the rows after the one :meth:`add` decided at, then every chunk).

        Returns:
            The row at which the readings were first seen to be window averages (more than
            ``ANGLE_MODE_ON`` changes per tooth over ``form_s``, once ``MIN_FORM_TEETH`` teeth
            are in it), or None.
        """
        if not self.timer_s or self.window_seen or speed.shape[0] == 0:
            return None
        counts = np.column_stack(self._changes_and_teeth(speed, valid))
        form = np.empty_like(counts)
        lfilter_columns(*self._form_filter, counts, self._form_decay * self._form, form)
        self._form = form[-1:]
        seen = (form[:, 1] >= MIN_FORM_TEETH) & (form[:, 0] > ANGLE_MODE_ON * form[:, 1])
        if not seen.any():
            return None
        self.window_seen = True
        return int(np.argmax(seen))

    def _changes_and_teeth(self, speed: np.ndarray, valid: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        """Per row: the readings that changed since the wheel's previous valid sample (both
        valid, the wheel not fast: ``fast_edge_rate``), and the teeth the wheels passed
        meanwhile; the last row is kept for the next call."""
        previous = np.concatenate((speed[:1] * np.nan if self._previous is None
                                   else self._previous[None], speed[:-1]))
        valid_previous = np.concatenate((np.isfinite(previous[:1]), valid[:-1]))
        pair = valid & valid_previous & (speed * self._teeth_per_sample <= self._fast_edge_rate)
        self._previous = np.where(valid[-1], speed[-1], np.nan)
        return ((pair & (speed != previous)).sum(axis=1).astype(float),
                np.where(pair, speed, 0.0).sum(axis=1) * self._teeth_per_sample)


def lattice_step(periods: np.ndarray, tolerance: float = 0.02, required_share: float = 0.98,
                 share_margin: float = 0.15) -> float:
    """The step of the lattice the sorted distinct ``periods`` lie on (:class:`TimerLattice`),
    or 0 when there is none.

    Args:
        periods: sorted distinct tooth periods, s.
        tolerance: how far from a lattice point a value may lie, in steps.
        required_share: share of the values that must lie on the lattice.
        share_margin: how much more than 1 / m of the values the multiples of m (2..12) may
            hold.
    """
    gaps = np.diff(periods)
    if gaps.size < 2:
        return 0.0
    step = float(np.quantile(gaps, 0.02))
    k = np.round(periods / step)
    step = float(np.sum(periods * k) / np.sum(k * k))   # least squares over the whole range
    k = np.round(periods / step)
    if np.mean(np.abs(periods / step - k) <= tolerance) < required_share:
        return 0.0
    for m in range(2, 13):
        if np.mean(k % m == 0) > 1.0 / m + share_margin:
            return 0.0
    return step
