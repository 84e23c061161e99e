"""ABS encoder tooth-spacing error: learned per tooth and divided out, streaming, per wheel.

The ABS speed is
``pitch / period`` per tooth, so the ring's tooth-spacing error is a fixed per-tooth factor,
lines at the rotation harmonics inside the band. Uncorrected it is the dominant error of the
method on realistic input: the LS fits the spectral shape of omega_1, the lines flatten it,
and the estimate moves only ~1/3 of a true stiffness change (measured on the road
simulator: FR read ~170 kPa for 120 kPa). Each wheel's tooth pattern is learned online and
divided out, as production indirect TPMS do.

Used by the tire stiffness observer (:mod:`tpms_ros.core.stiffness_observer`) ahead of its
band-pass. No ROS import.
"""

from __future__ import annotations

import math

from numba import njit, types
import numpy as np

# A held tooth period changes at most once per edge (<= 1 change per tooth); a window average
# also changes when an edge leaves the window, 1 + (1 - edges per sample) changes per tooth.
ANGLE_MODE_ON = 1.08     # changes per tooth above which the input is not a held tooth period
ANGLE_MODE_OFF = 1.03    # ... and below which it is again
BINS_PER_TOOTH = 4       # angle-domain pattern resolution
MIN_FORM_TEETH = 200.0   # weighted teeth of data before the form is judged
SLOW_HOLD = 4            # samples from which a hold is a slow tooth (see Tooth count)
NO_EDGE = np.iinfo(np.int64).min // 2   # no change seen since a reset
# A reset wheel's kept pattern is looked for in the new learning once this much of it is there,
# and taken when the best circular correlation reaches REFIND_CORRELATION. The largest
# correlation of two unrelated 48-tooth patterns over all shifts is about 0.45.
REFIND_S = 2.0
REFIND_CORRELATION = 0.8
# A window average's pattern per edge rate (see Window model): the bands of edges per sample
# it is learned in, and the averaging windows it is fitted for, in samples (0: no window, one
# pattern at every speed).
RATE_BAND = 0.02
RATE_BANDS = 100
WINDOW_SAMPLES = np.concatenate(([0.0], np.arange(1.0, 12.01, 0.25)))
# The ring's spectrum is fitted with this much of the bands' weight added to each harmonic's
# normal equation (a response below about its square root counts as none).
RESPONSE_FLOOR = 0.01
# A band enters the fit once it holds this many learning samples per angle bin.
BAND_MIN_PER_BIN = 5.0
# The window is fitted from half a wheel's learning on, and a window-average wheel is first
# learned once its window has stayed within WINDOW_STEADY samples over the second half (its
# pattern no longer changes form under the calibration: tuning car 21514's FR read 46 kPa low
# after a calibration made while its window moved from 4.75 to 6 samples).
WINDOW_FIT_SHARE = 0.5
WINDOW_STEADY = 0.5
# ... and a fitted window is replaced only by one whose residual is this much smaller (no
# window, one pattern at every speed, is where every wheel starts: a window must earn its place).
WINDOW_PREFERENCE = 1.1


class SpeedForm:
    """How an ABS ECU forms each wheel's speed, recognised from the speeds (streaming).

    A held tooth period changes value at most once per tooth edge, so at most once per tooth of
    angle; a window average also changes when an edge leaves its window, up to twice. The
    changes per tooth of angle over usable samples slower than ``fast_edge_rate`` edges per
    sample (faster, edges come about as often as samples or more often and a change no longer
    marks one), exponentially weighted over ``form_s``, decide with hysteresis
    (``ANGLE_MODE_ON`` / ``ANGLE_MODE_OFF``) once ``MIN_FORM_TEETH`` of angle are in.
    :meth:`add` takes the samples, :meth:`judge` switches; the caller calls it on a fixed
    sample clock, so the result does not depend on how the stream is chunked. A wheel not yet
    judged counts as held tooth periods.

    Args:
        n_wheels: number of wheels (columns).
        sample_rate_hz: sample rate of the speeds.
        form_s: memory time constant, s.
        fast_edge_rate: edges per sample from which a sample does not count.
    """

    def __init__(self, n_wheels: int, sample_rate_hz: float, form_s: float = 2.0,
                 fast_edge_rate: float = 0.9) -> None:
        self._decay = math.exp(-1.0 / (form_s * sample_rate_hz))
        self._fast_edge_rate = fast_edge_rate
        self._changes = np.zeros(n_wheels)
        self._advance = np.zeros(n_wheels)
        self._angle_mode = np.zeros(n_wheels, dtype=bool)

    @property
    def angle_mode(self) -> np.ndarray:
        """(wheels,) True where the speeds are not held tooth periods (a window average)."""
        return self._angle_mode.copy()

    def add(self, change: np.ndarray, edge_rate: np.ndarray, usable: np.ndarray) -> None:
        """Count a segment's samples (n, wheels): whether each changed from the one before,
        its tooth-edge rate (edges per sample), and whether it is valid data."""
        n = change.shape[0]
        rows = np.arange(n)[:, None]
        weight = (self._decay ** (n - 1 - rows)) * (usable & (edge_rate <= self._fast_edge_rate))
        fade = self._decay ** n
        self._changes = fade * self._changes + (weight * change).sum(axis=0)
        self._advance = fade * self._advance + (weight * edge_rate).sum(axis=0)

    def judge(self) -> None:
        """Decide each wheel's form from the samples added so far (with hysteresis)."""
        judged = self._advance >= MIN_FORM_TEETH
        per_tooth = self._changes / np.maximum(self._advance, 1e-12)
        self._angle_mode = np.where(
            judged & (per_tooth > ANGLE_MODE_ON), True,
            np.where(judged & (per_tooth < ANGLE_MODE_OFF), False, self._angle_mode))


class ToothErrorCorrector:
    """Learns and removes the tooth-spacing error of ABS encoder rings, streaming, per wheel.

    An ABS ECU reports ``pitch / period`` of the last tooth, held until the next edge. A tooth
    ``k`` whose edges are off by ``e_k`` spans ``pitch + e_(k+1) - e_k``, so its reported speed is
    off by the fixed factor ``pitch / (pitch + e_(k+1) - e_k)``, the same on every revolution:
    lines at the wheel's rotation harmonics, several of them inside the 25-60 Hz band. They are
    not road excitation and pull the LS coefficient toward a flat spectrum (a 0.1 %-of-pitch
    ring made the uncorrected estimator read a third of a pressure drop). They are removed the
    way production indirect TPMS do, with a per-tooth correction learned online:

    * **Tooth count.** The held speed changes value exactly at tooth edges. The tooth phase
      ``x = integral(speed) / pitch`` at those changes sits at an integer plus an offset (the
      hold delay and the sub-sample edge timing, less than one tooth while the edge rate is
      below the sample rate); the offset is tracked as the circular mean of ``x`` at the
      changes (``tooth_phase_s`` memory, unwrapped), so the count ``round(x - offset)`` of each
      change is exact even when two consecutive periods read the same value, and it does not
      drift. Each sample belongs to the tooth of the last change. A hold of ``SLOW_HOLD``
      samples or more is a slow tooth, and the new value is that tooth's own period, so over
      it ``x`` advances by the new value, not the one held: braking to a crawl, each hold lasts
      the next, longer period and the held value's integral runs ahead of the wheel (issue 21:
      a crawl to 2 km/h slipped the count and mixed two alignments of the pattern). Shorter
      holds keep the integral, whose sub-sample averaging the count needs at high edge rates.
    * **Pattern.** Per tooth, the exponentially weighted mean (``learning_s`` memory) of
      ``log(speed / low-passed speed)`` over valid samples; the torsional vibration is not
      synchronous with the ring and averages out, the pattern is made zero-mean over the ring
      (the spacing errors close the circle). Speed is corrected as ``speed * exp(-pattern[k])``.
    * **Chunk invariance.** The pattern applied to a sample is the one of the last refresh, on
      a fixed clock of ``refresh_samples`` processed samples, and the learning sums forget per
      sample, so chunking a stream differently cannot change the output.

    * **Speed form.** Not every ECU reports the held last tooth period: some average the tooth
      periods over a window (edge-to-edge over the last few ms). Then the value also changes
      when an edge leaves the window, the edge phase above is meaningless and a per-tooth
      pattern counted from it adds error instead of removing it (issue 21: a 0.24 % ring read
      +11..51 kPa at placard with the correction, +5..20 without). The form is recognised from
      the changes per tooth of angle (held period: at most 1; window average: up to 2),
      exponentially weighted over ``form_s``, with hysteresis (``ANGLE_MODE_ON`` /
      ``ANGLE_MODE_OFF``), switched on the refresh clock. For a wheel that is not a held tooth
      period the pattern is learned and removed in the angle domain instead: ``BINS_PER_TOOTH``
      bins per tooth of the running angle ``x`` (the integrated speed, which an average of
      tooth periods follows closely), with no edge anchoring.

    * **Window model.** A window average over ``W`` samples at ``e`` edges per sample reports
      the ring's error averaged over the last ``m = e W`` teeth, so its angle-domain pattern
      changes with the speed: harmonic ``h`` of the ring's own pattern ``p_h`` is seen as
      ``p_h sinc(h m / N)`` (N teeth; no phase: the running angle integrates the averaged
      speed, so it lags the ring by the same m / 2 teeth as the average's centre). One
      pattern learned over the speeds of an urban drive leaves about half the ring's error in
      (issue 21, tuning car 21510). The angle-domain learning is therefore also kept per band
      of edge rate (``RATE_BAND``), and at each refresh ``p_h`` and ``W`` are fitted to the
      bands together (least squares per harmonic, ``W`` the best of ``WINDOW_SAMPLES``;
      ``W = 0``, where every wheel starts, is the pooled pattern). Every band then applies the
      pattern the model gives at its edge rate: all the data make one ring's estimate, each
      speed sees it as its window does.

    * **Fast wheels.** From ``fast_edge_rate`` edges per sample on, edges come about as often
      as samples or more often: a change no longer marks one edge, and a window average
      changes at every sample, so these samples do not count for the speed form. A window
      average (angle domain: no count to lose) learns from them too, in bands up to 2 edges
      per sample; the stiffness observer masks a fast held-period wheel and resets it when it
      slows down.

    * **Learned.** A wheel's pattern is *learned* once ``learned_s`` of learning samples have
      gone into it; until then :meth:`process` says so per sample and the stiffness observer
      does not use them (issue 21: a calibration on a half-learned pattern read a tire 18 kPa
      low for a whole drive). A window-average wheel's first learning also waits until its
      fitted window has held over the second half of it (see Window model).

    A :meth:`reset` (gap, rate change, resumed after bad data) loses the ring angle, so that
    wheel's count and pattern start over (the recognised speed form is kept). The ring itself
    is unchanged, so a learned pattern is *kept*: once ``REFIND_S`` of new learning is there,
    the kept pattern is looked for in it at every circular shift, and at a correlation of
    ``REFIND_CORRELATION`` or more it is taken, at the new count's alignment, with the weight
    of a full memory; the wheel is learned again at once instead of after ``learned_s``.

    Args:
        n_wheels: number of wheels (columns).
        teeth: teeth per ring.
        sample_rate_hz: sample rate of the speeds.
        learning_s: memory time constant of the pattern learning, s.
        phase_s: memory time constant of the tooth-phase tracker, s.
        refresh_samples: the applied pattern is refreshed every this many samples.
        learned_s: learning samples after which a wheel's pattern counts as learned, s.
        form_s: memory time constant of the speed-form recognition, s.
        fast_edge_rate: edges per sample from which a wheel is fast (see Fast wheels).
    """

    def __init__(self, n_wheels: int, teeth: int, sample_rate_hz: float, learning_s: float,
                 phase_s: float, refresh_samples: int, learned_s: float,
                 form_s: float = 2.0, fast_edge_rate: float = 0.9) -> None:
        self.teeth = teeth
        self._learned_samples = learned_s * sample_rate_hz
        self._refind_samples = REFIND_S * sample_rate_hz
        self._cycle = 1.0 / (2.0 * np.pi / teeth * sample_rate_hz)  # teeth per (rad/s) sample
        self._learn_decay = math.exp(-1.0 / (learning_s * sample_rate_hz))
        # The total weight of a full learning memory (every sample usable).
        self._full_weight = 1.0 / (1.0 - self._learn_decay)
        self._phase_decay = math.exp(-1.0 / (phase_s * sample_rate_hz))
        self._refresh = refresh_samples
        self._fit_samples = WINDOW_FIT_SHARE * min(self._learned_samples,
                                                   0.5 * self._full_weight)
        self._steady_refreshes = math.ceil(WINDOW_FIT_SHARE * self._learned_samples
                                           / refresh_samples)
        self._count = 0
        self._phase = np.zeros(n_wheels)               # integrated speed, teeth (angle bins)
        self._edge_phase = np.zeros(n_wheels)          # tooth phase x at the last sample
        # Row of the last change, relative to the next segment's first row (NO_EDGE: none since
        # the wheel's reset).
        self._edge_row = np.full(n_wheels, NO_EDGE, dtype=np.int64)
        self._phasor = np.zeros(n_wheels, complex)     # running sum of exp(2 pi i x) at changes
        self._offset = np.zeros(n_wheels)              # unwrapped edge offset, teeth
        self._tooth = np.zeros(n_wheels, dtype=np.int64)
        self._previous = np.full(n_wheels, np.nan)
        self._sum = np.zeros((n_wheels, teeth))
        self._weight = np.zeros((n_wheels, teeth))
        self._pattern = np.zeros((n_wheels, teeth))
        bins = BINS_PER_TOOTH * teeth
        self._angle_sum = np.zeros((n_wheels, bins))
        self._angle_weight = np.zeros((n_wheels, bins))
        self._angle_pattern = np.zeros((n_wheels, bins))
        self._band_sum = np.zeros((n_wheels, RATE_BANDS, bins))
        self._band_weight = np.zeros((n_wheels, RATE_BANDS, bins))
        # The pattern each band applies (the window model's); the pooled one until fitted.
        self._band_pattern = np.zeros((n_wheels, RATE_BANDS, bins))
        # Each segment's learning before it is added to the sums (see _segment_kernel).
        self._scratch = tuple(np.zeros(array.size) for array in (
            self._sum, self._weight, self._angle_sum, self._angle_weight, self._band_sum,
            self._band_weight))
        # The window model (see Window model): the fitted window's index in WINDOW_SAMPLES
        # (the ECU's, so a reset keeps it), how many refreshes it has held, and the ring's
        # spectrum p_h where fitted.
        self._window = np.zeros(n_wheels, dtype=np.int64)
        self._window_held = np.zeros(n_wheels, dtype=np.int64)
        self._ring = np.zeros((n_wheels, bins // 2 + 1), complex)
        self._ring_known = np.zeros(n_wheels, dtype=bool)
        self._ring_kept = np.zeros((n_wheels, bins // 2 + 1), complex)
        self._ring_has_kept = np.zeros(n_wheels, dtype=bool)
        harmonics = np.arange(bins // 2 + 1)
        rates = (np.arange(RATE_BANDS) + 0.5) * RATE_BAND
        # (windows, bands, harmonics) responses of the window model at the bands' centres.
        cycles = harmonics[None, None, :] * (WINDOW_SAMPLES[:, None, None] * rates[None, :, None]
                                             / teeth)
        self._window_response = np.sinc(cycles)
        self._form = SpeedForm(n_wheels, sample_rate_hz, form_s, fast_edge_rate)
        self._learned_count = np.zeros(n_wheels)       # learning samples since the reset
        self._learned = np.zeros(n_wheels, dtype=bool)
        self._kept = np.zeros((n_wheels, teeth))       # the pattern before the last reset
        self._angle_kept = np.zeros((n_wheels, bins))
        self._has_kept = np.zeros(n_wheels, dtype=bool)

    @property
    def angle_mode(self) -> np.ndarray:
        """(wheels,) True where the input is not a held tooth period (angle-domain pattern)."""
        return self._form.angle_mode

    @property
    def pattern(self) -> np.ndarray:
        """(wheels, teeth) learned log speed error per tooth, in tooth-count order (a copy)."""
        return self._pattern.copy()

    def reset(self, wheels: np.ndarray) -> None:
        """Forget the ring angle of ``wheels``; a learned pattern is kept to be found again."""
        wheels = np.atleast_1d(wheels)
        keep = wheels[self._learned[wheels]]
        self._kept[keep] = self._pattern[keep]
        self._angle_kept[keep] = self._angle_pattern[keep]
        self._has_kept[keep] = True
        self._ring_kept[keep] = self._ring[keep]
        self._ring_has_kept[keep] = self._ring_known[keep]
        self._ring_known[wheels] = False
        self._learned[wheels] = False
        self._learned_count[wheels] = 0.0
        for array in (self._phase, self._edge_phase, self._phasor, self._offset, self._tooth,
                      self._sum, self._weight, self._pattern, self._angle_sum,
                      self._angle_weight, self._angle_pattern, self._band_sum,
                      self._band_weight, self._band_pattern):
            array[wheels] = 0
        self._edge_row[wheels] = NO_EDGE
        self._previous[wheels] = np.nan

    def process(self, speed: np.ndarray, reference: np.ndarray,
                learn: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Correct a segment of held tooth speeds (n, wheels) and learn from it.

        Args:
            speed: reported wheel speeds, rad/s (finite; bad samples already held).
            reference: the same speeds low-passed well below the rotation frequency.
            learn: samples that may be learned from (valid sensor data).

        Returns:
            (n, wheels) corrected speeds, (n, wheels) whether each sample's wheel had its
            pattern learned (see Learned).
        """
        out = np.empty_like(speed)
        learned = np.empty(speed.shape, dtype=bool)
        start = 0
        while start < speed.shape[0]:
            stop = min(speed.shape[0], start + self._refresh - self._count % self._refresh)
            learned[start:stop] = self._learned
            out[start:stop] = self._segment(speed[start:stop], reference[start:stop],
                                            learn[start:stop])
            self._count += stop - start
            if self._count % self._refresh == 0:
                self._refresh_pattern()
            start = stop
        return out, learned

    def _segment(self, speed: np.ndarray, reference: np.ndarray,
                 learn: np.ndarray) -> np.ndarray:
        corrected = np.empty_like(speed)
        change = np.empty(speed.shape, dtype=bool)
        usable = np.empty(speed.shape, dtype=bool)
        _segment_kernel(
            np.ascontiguousarray(speed), np.ascontiguousarray(reference),
            np.ascontiguousarray(learn), self._form.angle_mode, self._cycle, self._phase_decay,
            self._learn_decay, self._pattern, self._band_pattern.reshape(-1),
            self._phase, self._edge_phase, self._edge_row, self._offset, self._phasor,
            self._tooth, self._previous, self._learned_count,
            (self._sum.reshape(-1), self._weight.reshape(-1), self._angle_sum.reshape(-1),
             self._angle_weight.reshape(-1), self._band_sum.reshape(-1),
             self._band_weight.reshape(-1)),
            self._scratch, corrected, change, usable)
        self._form.add(change, speed * self._cycle, usable)
        return corrected

    @staticmethod
    def _centred(total: np.ndarray, weight: np.ndarray) -> np.ndarray:
        seen = weight > 0.0
        mean = np.where(seen, total / np.where(seen, weight, 1.0), 0.0)
        count = seen.sum(axis=1, keepdims=True)
        centre = mean.sum(axis=1, keepdims=True) / np.maximum(count, 1)
        return np.where(seen, mean - centre, 0.0)

    def _refind(self, wheels: np.ndarray, total: np.ndarray, weight: np.ndarray,
                kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Look for ``kept`` patterns in the new learning of ``wheels``; where found, add them
        to the learning sums (in place) at their best shift with a full memory's weight.

        Returns:
            (len(wheels),) True where found, and the circular shift (bins) found.
        """
        fresh = self._centred(total[wheels], weight[wheels])
        old = kept[wheels]
        # Circular cross-correlation at every shift s: sum_k fresh[k + s] * old[k].
        product = np.fft.irfft(np.fft.rfft(fresh, axis=1)
                               * np.conj(np.fft.rfft(old, axis=1)), fresh.shape[1], axis=1)
        norm = np.linalg.norm(fresh, axis=1) * np.linalg.norm(old, axis=1)
        shift = np.argmax(product, axis=1)
        with np.errstate(invalid='ignore', divide='ignore'):
            correlation = product[np.arange(wheels.size), shift] / norm
        found = np.nan_to_num(correlation) >= REFIND_CORRELATION
        prior = self._full_weight / fresh.shape[1]     # a full memory's weight per tooth (bin)
        for row in np.flatnonzero(found):
            total[wheels[row]] += prior * np.roll(old[row], shift[row])
            weight[wheels[row]] += prior
        return found, shift

    def _fit_window(self, wheel: int) -> None:
        """Fit the window model to a wheel's bands once they hold ``WINDOW_FIT_SHARE`` of its
        learning (see Window model); bands too thinly learned do not enter the fit."""
        weight = self._band_weight[wheel]
        bins = weight.shape[1]
        total = weight.sum(axis=1)
        fitted = total >= BAND_MIN_PER_BIN * bins
        # After a reset the kept ring, found again, is worth more than a few bands' seconds.
        if total[fitted].sum() < self._fit_samples:
            return
        observed = np.fft.rfft(self._centred(self._band_sum[wheel][fitted], weight[fitted]),
                               axis=1)
        w = total[fitted][None, :, None]
        response = self._window_response[:, fitted]                  # (windows, bands, h)
        # A harmonic the fitted bands see only near a zero of its response is not known: the
        # floor keeps its estimate from blowing up and reaching the bands where it shows.
        ring = ((w * response * observed[None]).sum(axis=1)
                / ((w * response ** 2).sum(axis=1) + RESPONSE_FLOOR * w.sum()))  # (windows, h)
        residual = (w * np.abs(observed[None] - ring[:, None] * response) ** 2).sum(axis=(1, 2))
        best = int(np.argmin(residual))
        # The window stays unless another fits clearly better: at one speed every window fits
        # (one band), and the choice would follow the rounding (and the chunking).
        current = int(self._window[wheel])
        energy = float((w * np.abs(observed[None]) ** 2).sum())
        if residual[current] <= WINDOW_PREFERENCE * residual[best] + 1e-9 * energy:
            best = current
        held = abs(WINDOW_SAMPLES[best] - WINDOW_SAMPLES[current]) <= WINDOW_STEADY
        self._window_held[wheel] = self._window_held[wheel] + 1 if held else 0
        self._window[wheel] = best
        self._ring[wheel] = ring[best]
        # No window: the pooled pattern, learned from every sample as before the model.
        self._ring_known[wheel] = best > 0

    @property
    def window_samples(self) -> np.ndarray:
        """(wheels,) the averaging window fitted to each angle-mode wheel, samples (0: one
        pattern at every speed, or not fitted)."""
        return WINDOW_SAMPLES[self._window]

    def _refresh_pattern(self) -> None:
        angle_mode = self._form.angle_mode
        look = np.flatnonzero(self._has_kept & ~self._learned
                              & (self._learned_count >= self._refind_samples))
        angle = look[angle_mode[look]]
        teeth = look[~angle_mode[look]]
        if angle.size:
            found, shift = self._refind(angle, self._angle_sum, self._angle_weight,
                                        self._angle_kept)
            self._learned[angle] = found
            # The kept ring's spectrum, at the new count's alignment (np.roll by the shift).
            take = found & self._ring_has_kept[angle]
            harmonics = np.arange(self._ring.shape[1])
            self._ring[angle[take]] = self._ring_kept[angle[take]] * np.exp(
                -2j * np.pi * harmonics[None] * shift[take][:, None] / self._angle_sum.shape[1])
            self._ring_known[angle[take]] = True
        if teeth.size:
            self._learned[teeth] = self._refind(teeth, self._sum, self._weight, self._kept)[0]
        for wheel in np.flatnonzero(angle_mode).tolist():
            self._fit_window(wheel)
        # Only a wheel's first learning waits for its window: the window is the ECU's, and at
        # motorway edge rates (few, narrow bands) its fit wanders while resets at the tooth-rate
        # limit make the wheels learn again and again (tuning car 21514: a 25 % puncture
        # missed when every relearning waited).
        steady = (~angle_mode | self._has_kept
                  | (self._window_held >= self._steady_refreshes))
        self._learned |= (self._learned_count >= self._learned_samples) & steady
        self._pattern = self._centred(self._sum, self._weight)
        self._angle_pattern = self._centred(self._angle_sum, self._angle_weight)
        self._band_pattern[:] = self._angle_pattern[:, None, :]
        modelled = np.flatnonzero(self._ring_known)
        if modelled.size:
            spectrum = self._ring[modelled, None, :] * self._window_response[
                self._window[modelled]]
            spectrum[..., 0] = 0.0
            self._band_pattern[modelled] = np.fft.irfft(spectrum, self._angle_sum.shape[1],
                                                        axis=-1)
        self._form.judge()


_F1, _F2, _B1, _B2, _I1 = (types.float64[:], types.float64[:, :], types.boolean[:],
                           types.boolean[:, :], types.int64[:])
_SUMS = types.UniTuple(types.float64[:], 6)


@njit(types.void(_F2, _F2, _B2, _B1, types.float64, types.float64, types.float64, _F2, _F1,
                 _F1, _F1, _I1, _F1, types.complex128[:], _I1, _F1, _F1, _SUMS, _SUMS, _F2,
                 _B2, _B2),
      cache=True, error_model='numpy')
def _segment_kernel(speed: np.ndarray, reference: np.ndarray, learn: np.ndarray,
                    angle_mode: np.ndarray, cycle: float, phase_decay: float,
                    learn_decay: float, pattern: np.ndarray, band_pattern: np.ndarray,
                    phase: np.ndarray, edge_phase: np.ndarray, edge_row: np.ndarray,
                    offset: np.ndarray, phasor: np.ndarray, tooth: np.ndarray,
                    previous: np.ndarray, learned_count: np.ndarray,
                    sums: tuple[np.ndarray, ...], scratch: tuple[np.ndarray, ...],
                    corrected: np.ndarray, change: np.ndarray, usable: np.ndarray) -> None:
    """One segment of :meth:`ToothErrorCorrector._segment`, compiled (numba): the tooth count
    and angle per sample, the correction, and the learning sums (faded by the segment, the
    samples scattered into their tooth, angle bin and rate band); the per-wheel state (phase,
    edge phase and row, offset, phasor, tooth, previous speed, learned count) and the sums
    (tooth sum and weight, angle, band: flat) updated in place.

    Why compiled: as numpy it was some sixty array calls per segment (cumulative sums and
    maxima, the phasor's recursion, gathers and six scatters), about 0.3 ms whatever the
    segment's length, a third of the stiffness observer's cost per chunk. The operations are
    the numpy form's, in its order; exp, log and atan2 are the C library's where numpy has
    vector versions of its own, so the two agree to a few units of the last place
    (test/tpms_ros/core/test_tooth_correction.py holds this to the numpy form).

    Args:
        speed, reference, learn: (n, wheels) as :meth:`ToothErrorCorrector.process`.
        scratch: per sum, a zeroed array of its size (left zeroed).
        corrected: (n, wheels) output, the corrected speeds; ``change``: whether each sample
            changed from the one before; ``usable``: whether it was learned from.
    """
    n, n_wheels = speed.shape
    teeth = pattern.shape[1]
    bins = BINS_PER_TOOTH * teeth
    fade = learn_decay ** np.float64(n)
    two_pi = 2.0 * math.pi
    counted = np.empty(n, dtype=np.int64)
    touched = np.empty((3, n, n_wheels), dtype=np.int64)   # each sample's three slots
    for w in range(n_wheels):
        phase_0, wrapped_before, offset_0 = phase[w], offset[w], offset[w]
        shift = edge_phase[w] - phase_0
        advance = catch_up = unwrap = 0.0      # numpy's cumulative sums, added after
        last = edge_row[w]
        held = previous[w]
        z_re, z_im = phase_decay * phasor[w].real, phase_decay * phasor[w].imag
        y_re, y_im = phasor[w].real, phasor[w].imag
        tooth_now, x_phase, x, off = tooth[w], phase_0, 0.0, offset_0
        for i in range(n):
            value = speed[i, w]
            rate = value * cycle
            advance += rate
            x_phase = phase_0 + advance
            moved = value != held
            before = last
            if moved:
                last = max(last, i)
                # over a slow tooth the new value replaces the one held on the hold's earlier
                # samples: the tooth phase is the integral plus those catch-ups
                if before != NO_EDGE and i - before >= SLOW_HOLD:
                    catch_up += (i - before - 1) * (value - held) * cycle
            x = x_phase + shift + catch_up
            # the phasor: y = z + unit, z = decay * y (scipy's lfilter of 1 / (1 - decay z^-1))
            if moved:
                angle = two_pi * x
                y_re, y_im = z_re + math.cos(angle), z_im + math.sin(angle)
            else:
                y_re, y_im = z_re + 0.0, z_im + 0.0
            z_re, z_im = phase_decay * y_re, phase_decay * y_im
            wrapped = math.atan2(y_im, y_re) / two_pi
            step = wrapped - wrapped_before
            wrapped_before = wrapped
            unwrap += step - np.rint(step)
            off = offset_0 + unwrap
            counted[i] = np.int64(np.rint(x - off))
            if last >= 0:
                tooth_now = counted[last]
            index = tooth_now % teeth
            angle_index = np.int64(math.floor(x_phase * BINS_PER_TOOTH)) % bins
            band = min(int(rate / RATE_BAND), RATE_BANDS - 1)
            band_slot = angle_index + bins * (band + RATE_BANDS * w)
            log_error = band_pattern[band_slot] if angle_mode[w] else pattern[w, index]
            corrected[i, w] = value * math.exp(-log_error)
            change[i, w] = moved
            # learning: per-sample exponential forgetting
            ok = learn[i, w] and value > 0.0 and reference[i, w] > 0.0
            usable[i, w] = ok
            ratio = math.log(value / reference[i, w]) if ok else 0.0
            weight = learn_decay ** np.float64(n - 1 - i) if ok else 0.0
            touched[0, i, w] = index + teeth * w
            touched[1, i, w] = angle_index + bins * w
            touched[2, i, w] = band_slot
            for k in range(3):
                scratch[2 * k][touched[k, i, w]] += weight * ratio
                scratch[2 * k + 1][touched[k, i, w]] += weight
            learned_count[w] += 1.0 if ok else 0.0
            held = value
        # carry the state; shift phase and offset together by whole rings (keeps them small)
        ring = math.floor(off / teeth) * teeth
        phase[w] = x_phase - ring
        edge_phase[w] = x - ring
        edge_row[w] = NO_EDGE if last == NO_EDGE else last - n
        offset[w] = off - ring
        phasor[w] = complex(y_re, y_im)
        tooth[w] = tooth_now - np.int64(ring)
        previous[w] = held
    for k in range(6):
        total, added = sums[k], scratch[k]
        for j in range(total.shape[0]):
            total[j] *= fade
        # bincount's order: each slot's samples summed from 0 in sample order, then added
        for w in range(n_wheels):
            for i in range(n):
                slot = touched[k // 2, i, w]
                total[slot] += added[slot]
                added[slot] = 0.0
