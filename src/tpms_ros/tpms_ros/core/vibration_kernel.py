"""The vibration analysis of one chunk of wheel speeds as one compiled kernel (numba).

Why compiled: per chunk, the analysis is some sixty small array operations (stuck-sensor run
lengths, hold of bad samples, tooth-error correction with 43 harmonics by default, band-pass, RLS
sums, AR(2) solve); as numpy calls they cost about 0.5 ms per chunk whatever its length, most of
it call overhead. That fixed cost is what a node pays when an output falls due, so it set the
node's output latency. Here the same recursions run sample by sample in one call.

The maths is that of :class:`tpms_ros.core.vibration_analysis.VibrationAnalyzer` (see its module
docstring): every state is carried across calls, so the result does not depend on the
chunking. Compiled when this module is first imported (the explicit signature), not on the
first chunk: a node compiles while it starts, not while data waits. The result is cached beside
this file (``cache=True``), so later starts load it in a fraction of a second.
"""

from __future__ import annotations

import math

from numba import njit, types, vectorize
import numpy as np

_F1, _F2, _F3 = types.float64[:], types.float64[:, :], types.float64[:, :, :]
_B1, _B2, _I1 = types.boolean[:], types.boolean[:, :], types.int64[:]
_SIGNATURE = types.void(
    _F2, _B2, types.int64, types.int64, _F1, _I1, _I1,     # omega, beat, keep, limits, counts,
                                                           # driven
    _F2, _F2, _F3, _F2, _F2, _F3,                          # band-pass, low-pass
    types.boolean, types.complex128[:, :], _F1,            # tooth correction
    _F2, _B1, _I1, _I1,                                    # per-wheel state and counts
    _F2, _B2, _F2, _F2, _F2, _B1)                          # regression state and outputs


@vectorize([types.float64(types.float64, types.float64, types.float64)], cache=True)
def resonance_frequency(a1: float, a2: float, fs: float) -> float:
    """Resonance of the AR(2) model 1 / (1 + a1 q^-1 + a2 q^-2), Hz; NaN for real poles.

    The pole angle w = arccos(-a1 / (2 sqrt(a2))) of the complex pair sqrt(a2) exp(+-i w)
    gives f = fs w / (2 pi). A ufunc: the kernel calls it per sample, Python on arrays.
    """
    if not (a2 > 0.0 and a1 * a1 < 4.0 * a2):
        return math.nan
    cos_w = min(max(-a1 / (2.0 * math.sqrt(a2)), -1.0), 1.0)
    return fs / (2.0 * math.pi) * math.acos(cos_w)


@njit(cache=True)
def _biquads(sos: np.ndarray, state: np.ndarray, wheel: int, x: float) -> float:
    """One sample through second-order sections (scipy's sosfilt: transposed direct form II)
    with the state of ``wheel`` (state: (sections, 2, wheels))."""
    for s in range(sos.shape[0]):
        y = sos[s, 0] * x + state[s, 0, wheel]
        state[s, 0, wheel] = sos[s, 1] * x - sos[s, 4] * y + state[s, 1, wheel]
        state[s, 1, wheel] = sos[s, 2] * x - sos[s, 5] * y
        x = y
    return x


@njit(_SIGNATURE, cache=True, error_model='numpy')
def vibration_chunk(omega: np.ndarray, beat: np.ndarray, first_keep: int, decimation: int,
                    limits: np.ndarray, counts: np.ndarray, driven: np.ndarray,
                    sos: np.ndarray, sos_zi_unit: np.ndarray, sos_state: np.ndarray,
                    lp_sos: np.ndarray, lp_zi_unit: np.ndarray, lp_state: np.ndarray,
                    tooth: bool, tooth_sum: np.ndarray, angle: np.ndarray,
                    wheel_state: np.ndarray, wheel_started: np.ndarray,
                    rejected: np.ndarray, gated: np.ndarray,
                    y_hist: np.ndarray, v_hist: np.ndarray, ls_state: np.ndarray,
                    trace_hz: np.ndarray, latest_a: np.ndarray, latest_known: np.ndarray,
                    ) -> None:
    """Analyse a chunk of wheel speeds; every state array is updated in place.

    Args:
        omega: (N, W) wheel speeds at the sample rate.
        beat: (N, W) samples gated for the beat of their tooth edges with the sampling
            (:meth:`tpms_ros.core.vibration_analysis.VibrationAnalyzer.process`), as those
            below the minimum speed are; they are not counted in ``gated``.
        first_keep, decimation: rows first_keep, first_keep + decimation, ... go to the
            regression (the decimation's phase, carried by the caller).
        limits: [max_wheel_speed_rad_s, min_wheel_speed_rad_s, sample interval s, tooth forgetting,
            RLS forgetting, analysis rate Hz, min_valid_fraction].
        counts: [stuck samples, guard samples].
        driven: the driven axles' wheels whose common driveline vibration is removed, as
            left-right pairs (a0, b0, a1, b1 ...; an axle of -1s is not compensated).
        sos, sos_zi_unit, sos_state: the band-pass, its unit steady state, its (S, 2, W) state.
        lp_sos, lp_zi_unit, lp_state: the same for the tooth-error smoothing low-pass.
        tooth: learn and divide out the tooth-error pattern.
        tooth_sum: (K + 1, W) complex exponential sums of deviation x conj(harmonic k) and of
            the learning weight (last row). angle: (W,) integrated wheel angle.
        wheel_state: (4, W) rows: previous input, its repeat count, the held good value (NaN
            before the first), samples since the last bad or gated one.
        wheel_started: (W,) a good sample has been seen (the filters run).
        rejected, gated: (W,) counts of bad and of gated (too slow) samples.
        y_hist, v_hist: (2, W) the last two decimated outputs and their validity.
        ls_state: (6, W) the RLS sums' filter states (lambda x the sums).
        trace_hz: (M, W) output, the resonance at each kept row (NaN where unknown).
        latest_a, latest_known: (2, W), (W,) outputs, the AR(2) coefficients and knownness
            at the last kept row (left alone when no row is kept).
    """
    n, wheels = omega.shape
    max_speed, min_speed, dt, tooth_lambda, lam, fs_eff, min_valid = (
        limits[0], limits[1], limits[2], limits[3], limits[4], limits[5], limits[6])
    stuck_samples, guard_samples = counts[0], counts[1]
    harmonics = tooth_sum.shape[0] - 1

    # Pass 1: bad and gated samples (the stuck run length is carried across chunks).
    bad = np.zeros((n, wheels), dtype=np.bool_)
    slow = np.zeros((n, wheels), dtype=np.bool_)
    for w in range(wheels):
        previous, repeats = wheel_state[0, w], wheel_state[1, w]
        for i in range(n):
            value = omega[i, w]
            repeats = 0.0 if value != previous else repeats + 1.0
            previous = value
            is_bad = (not math.isfinite(value) or value < 0.0 or value > max_speed
                      or repeats >= stuck_samples)
            bad[i, w] = is_bad
            slow[i, w] = not is_bad and (value < min_speed or beat[i, w])
            if is_bad:
                rejected[w] += 1
            elif value < min_speed:
                gated[w] += 1
        wheel_state[0, w], wheel_state[1, w] = previous, repeats

    # A wheel without a good sample yet starts its filters in the steady state of its first
    # good one (so the large DC does not ring) and holds that value before it.
    first_good = np.zeros(wheels)
    has_good = np.zeros(wheels, dtype=np.bool_)
    for w in range(wheels):
        if wheel_started[w]:
            continue
        for i in range(n):
            if not bad[i, w]:
                first_good[w], has_good[w] = omega[i, w], True
                break
        if has_good[w]:
            for s in range(sos.shape[0]):
                for k in range(2):
                    sos_state[s, k, w] = sos_zi_unit[s, k] * first_good[w]
            for s in range(lp_sos.shape[0]):
                for k in range(2):
                    lp_state[s, k, w] = lp_zi_unit[s, k] * first_good[w]
            wheel_started[w] = True

    # Pass 2: sample by sample, all wheels (the driveline compensation couples two of them).
    y_row = np.zeros(wheels)
    valid_row = np.zeros(wheels, dtype=np.bool_)
    products = np.zeros((6, wheels))
    sums = np.empty(6)
    kept = 0
    for i in range(n):
        for w in range(wheels):
            if not bad[i, w]:
                wheel_state[2, w] = omega[i, w]
            x = wheel_state[2, w]
            started = not math.isnan(x)
            if not started:
                x = first_good[w] if has_good[w] else 0.0
            if tooth:
                learn = started and not bad[i, w] and not slow[i, w]
                angle[w] += dt * x
                smooth = _biquads(lp_sos, lp_state, w, x)
                deviation = x / smooth - 1.0 if learn and smooth > 0.0 else 0.0
                tooth_sum[harmonics, w] = (tooth_lambda * tooth_sum[harmonics, w]
                                           + (1.0 - tooth_lambda) * (1.0 if learn else 0.0))
                filled = tooth_sum[harmonics, w].real
                # One pass over the harmonics (43 by default): learn each and add its share of
                # the pattern. Written in real arithmetic, the whole analyzer runs 1.4 times as
                # fast as with numba's complex numbers, with the same results to the bit.
                cos_a, sin_a = math.cos(angle[w]), math.sin(angle[w])
                h_re, h_im = cos_a, sin_a
                learned = (1.0 - tooth_lambda) * deviation
                pattern = 0.0
                for k in range(harmonics):
                    sum_re = tooth_lambda * tooth_sum[k, w].real + learned * h_re
                    sum_im = tooth_lambda * tooth_sum[k, w].imag - learned * h_im
                    tooth_sum[k, w] = complex(sum_re, sum_im)
                    if filled > 0.0:
                        pattern += 2.0 * sum_re / filled * h_re - 2.0 * sum_im / filled * h_im
                    h_re, h_im = h_re * cos_a - h_im * sin_a, h_re * sin_a + h_im * cos_a
                x = x / (1.0 + min(max(filled, 0.0), 1.0) * pattern)
            y_row[w] = _biquads(sos, sos_state, w, x)
            disturbed = bad[i, w] or slow[i, w]
            wheel_state[3, w] = 0.0 if disturbed else wheel_state[3, w] + 1.0
            valid_row[w] = wheel_state[3, w] >= guard_samples and not disturbed
        if i < first_keep or (i - first_keep) % decimation != 0:
            continue

        # A kept row: the regressor products, the exponentially weighted sums, the AR(2).
        for w in range(wheels):
            products[5, w] = 1.0 if valid_row[w] and v_hist[1, w] and v_hist[0, w] else 0.0
        for axle in range(0, driven.size, 2):
            a, b = driven[axle], driven[axle + 1]
            if a >= 0:
                pair = products[5, a] * products[5, b]
                products[5, a] = products[5, b] = pair
        for w in range(wheels):
            weight, y0, y1, y2 = products[5, w], y_row[w], y_hist[1, w], y_hist[0, w]
            products[0, w] = weight * y1 * y1
            products[1, w] = weight * y1 * y2
            products[2, w] = weight * y2 * y2
            products[3, w] = weight * y1 * y0
            products[4, w] = weight * y2 * y0
        for axle in range(0, driven.size, 2):
            a, b = driven[axle], driven[axle + 1]
            if a < 0:
                continue
            pair = products[5, a]
            y0a, y1a, y2a = y_row[a], y_hist[1, a], y_hist[0, a]
            y0b, y1b, y2b = y_row[b], y_hist[1, b], y_hist[0, b]
            cross = (pair * (y1a * y1b), pair * (0.5 * (y1a * y2b + y1b * y2a)),
                     pair * (y2a * y2b), pair * (0.5 * (y1a * y0b + y1b * y0a)),
                     pair * (0.5 * (y2a * y0b + y2b * y0a)))
            for m in range(5):
                products[m, a] -= cross[m]
                products[m, b] -= cross[m]
        for w in range(wheels):
            for m in range(6):
                sums[m] = products[m, w] + ls_state[m, w]
                ls_state[m, w] = lam * sums[m]
            r11, r12, r22, q1, q2, count = sums[0], sums[1], sums[2], sums[3], sums[4], sums[5]
            det = r11 * r22 - r12 * r12
            trace = r11 + r22
            a1 = (r12 * q2 - r22 * q1) / det
            a2 = (r12 * q1 - r11 * q2) / det
            freq = resonance_frequency(a1, a2, fs_eff)
            known = (det > 1e-9 * trace * trace and count * (1.0 - lam) >= min_valid
                     and math.isfinite(freq))
            trace_hz[kept, w] = freq if known else math.nan
            latest_a[0, w], latest_a[1, w], latest_known[w] = a1, a2, known
            y_hist[0, w], y_hist[1, w] = y_hist[1, w], y_row[w]
            v_hist[0, w], v_hist[1, w] = v_hist[1, w], valid_row[w]
        kept += 1

    if tooth:
        for w in range(wheels):
            angle[w] = angle[w] % (2.0 * math.pi)
