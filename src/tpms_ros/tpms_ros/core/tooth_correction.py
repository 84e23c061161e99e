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

import numpy as np
import scipy.signal as sig


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
      drift. Each sample belongs to the tooth of the last change.
    * **Pattern.** Per tooth, the exponentially weighted mean (``learning_s`` memory) of
      ``log(speed / low-passed speed)`` over valid samples; the torsional vibration is not
      synchronous with the ring and averages out, the pattern is made zero-mean over the ring
      (the spacing errors close the circle). Speed is corrected as ``speed * exp(-pattern[k])``.
    * **Chunk invariance.** The pattern applied to a sample is the one of the last refresh, on
      a fixed clock of ``refresh_samples`` processed samples, and the learning sums forget per
      sample, so chunking a stream differently cannot change the output.

    A :meth:`reset` (gap, rate change, resumed after bad data) loses the ring angle, so that
    wheel's count and pattern start over.

    Args:
        n_wheels: number of wheels (columns).
        teeth: teeth per ring.
        sample_rate_hz: sample rate of the speeds.
        learning_s: memory time constant of the pattern learning, s.
        phase_s: memory time constant of the tooth-phase tracker, s.
        refresh_samples: the applied pattern is refreshed every this many samples.
    """

    def __init__(self, n_wheels: int, teeth: int, sample_rate_hz: float, learning_s: float,
                 phase_s: float, refresh_samples: int) -> None:
        self.teeth = teeth
        self._cycle = 1.0 / (2.0 * np.pi / teeth * sample_rate_hz)  # teeth per (rad/s) sample
        self._learn_decay = math.exp(-1.0 / (learning_s * sample_rate_hz))
        self._phase_decay = math.exp(-1.0 / (phase_s * sample_rate_hz))
        self._refresh = refresh_samples
        self._count = 0
        self._phase = np.zeros(n_wheels)               # tooth phase x at the last sample
        self._phasor = np.zeros(n_wheels, complex)     # running sum of exp(2 pi i x) at changes
        self._offset = np.zeros(n_wheels)              # unwrapped edge offset, teeth
        self._tooth = np.zeros(n_wheels, dtype=np.int64)
        self._previous = np.full(n_wheels, np.nan)
        self._sum = np.zeros((n_wheels, teeth))
        self._weight = np.zeros((n_wheels, teeth))
        self._pattern = np.zeros((n_wheels, teeth))

    @property
    def pattern(self) -> np.ndarray:
        """(wheels, teeth) learned log speed error per tooth, in tooth-count order (a copy)."""
        return self._pattern.copy()

    def reset(self, wheels: np.ndarray) -> None:
        """Forget the ring angle and pattern of ``wheels``."""
        for array in (self._phase, self._phasor, self._offset, self._tooth, self._sum,
                      self._weight, self._pattern):
            array[wheels] = 0
        self._previous[wheels] = np.nan

    def process(self, speed: np.ndarray, reference: np.ndarray,
                learn: np.ndarray) -> np.ndarray:
        """Correct a segment of held tooth speeds (n, wheels) and learn from it.

        Args:
            speed: reported wheel speeds, rad/s (finite; bad samples already held).
            reference: the same speeds low-passed well below the rotation frequency.
            learn: samples that may be learned from (valid sensor data).

        Returns:
            (n, wheels) corrected speeds.
        """
        out = np.empty_like(speed)
        start = 0
        while start < speed.shape[0]:
            stop = min(speed.shape[0], start + self._refresh - self._count % self._refresh)
            out[start:stop] = self._segment(speed[start:stop], reference[start:stop],
                                            learn[start:stop])
            self._count += stop - start
            if self._count % self._refresh == 0:
                self._refresh_pattern()
            start = stop
        return out

    def _segment(self, speed: np.ndarray, reference: np.ndarray,
                 learn: np.ndarray) -> np.ndarray:
        n, n_wheels = speed.shape
        phase = self._phase + np.cumsum(speed, axis=0) * self._cycle
        previous = np.concatenate((self._previous[None], speed[:-1]))
        change = speed != previous
        unit = np.where(change, np.exp(2j * np.pi * phase), 0.0)
        decay = self._phase_decay
        phasor, _ = sig.lfilter([1.0], [1.0, -decay], unit, axis=0,
                                zi=decay * self._phasor[None])
        wrapped = np.angle(phasor) / (2.0 * np.pi)
        step = np.diff(np.concatenate((self._offset[None], wrapped)), axis=0)
        offset = self._offset + np.cumsum(step - np.round(step), axis=0)
        counted = np.round(phase - offset).astype(np.int64)
        rows = np.arange(n)[:, None]
        last = np.maximum.accumulate(np.where(change, rows, -1), axis=0)
        tooth = np.where(last >= 0, np.take_along_axis(counted, np.maximum(last, 0), axis=0),
                         self._tooth[None])
        index = tooth % self.teeth
        corrected = speed * np.exp(-np.take_along_axis(self._pattern, index.T, axis=1).T)

        # Learn: per-sample exponential forgetting, scattered into the teeth by bincount.
        usable = learn & (speed > 0.0) & (reference > 0.0)
        ratio = np.log(np.where(usable, speed, 1.0) / np.where(usable, reference, 1.0))
        weight = (self._learn_decay ** (n - 1 - rows)) * usable
        slot = (index + self.teeth * np.arange(n_wheels)[None]).ravel()
        size = n_wheels * self.teeth
        fade = self._learn_decay ** n
        self._sum = fade * self._sum + np.bincount(
            slot, (weight * ratio).ravel(), size).reshape(n_wheels, self.teeth)
        self._weight = fade * self._weight + np.bincount(
            slot, weight.ravel(), size).reshape(n_wheels, self.teeth)

        # Carry the state; shift phase and offset together by whole rings (keeps them small).
        ring = np.floor(offset[-1] / self.teeth) * self.teeth
        self._phase = phase[-1] - ring
        self._offset = offset[-1] - ring
        self._phasor = phasor[-1]
        self._tooth = tooth[-1] - ring.astype(np.int64)
        self._previous = speed[-1].copy()
        return corrected

    def _refresh_pattern(self) -> None:
        seen = self._weight > 0.0
        mean = np.where(seen, self._sum / np.where(seen, self._weight, 1.0), 0.0)
        count = seen.sum(axis=1, keepdims=True)
        centre = mean.sum(axis=1, keepdims=True) / np.maximum(count, 1)
        self._pattern = np.where(seen, mean - centre, 0.0)

