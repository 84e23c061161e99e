"""TPMS by vibration analysis (Persson, Gustafsson, Drevö, SAE 2002;
docs/methods/vibration_analyzer.md).

The tire's torsional mode (40-50 Hz; the vertical mode is at 10-20 Hz) is excited by road
roughness and shows in the wheel speed. Its frequency drops with pressure. Per wheel:

1. pre-processing: tooth-error correction (the 48-tooth ring's spacing errors modulate the
   measured speed periodically in wheel angle, lines at k x the rotation rate sweep through
   the band with speed and pull the AR(2); Persson 2002 pre-processes for this): the pattern
   is learned online per wheel by synchronous averaging of the relative speed deviation
   against the integrated wheel angle (Fourier coefficients up to the passband's top at the
   slowest wheel analysed, :attr:`VibrationParams.tooth_harmonics`; exponential memory
   ``TOOTH_MEMORY_S``) and divided out; then de-trend and band-pass around the mode
   (Butterworth second-order sections, as ``sosfilt``, with carried state; the filter's
   initial state is the steady state of the first sample, so the large DC of the wheel speed
   does not ring), then decimation to ``analysis_rate_hz`` (the
   band-pass is the anti-alias filter);
2. AR(2) fit ``y_t = -a1 y_{t-1} - a2 y_{t-2} + e_t`` by recursive least squares with
   exponential forgetting lambda. RLS with forgetting is *exactly* the exponentially weighted
   least-squares solution theta_t = R_t^-1 r_t with R_t = lambda R_{t-1} + phi phi^T and
   r_t = lambda r_{t-1} + phi y_t (R_t = P_t^-1; R_0 = P_0^-1 = ``rls_regularization`` I), so
   R and r are first-order IIR filters of the regressor products with carried state, and
   theta follows from the closed-form 2x2 solve; :func:`ar2_rls_reference` is the textbook
   per-sample recursion it equals (tested);
   On a driven axle (``driveline_compensation``) each driven wheel's regression sums are
   taken less the symmetrised left-right cross products, which remove the driveline modes
   both rims share (see :class:`VibrationParams`);
3. resonance f = fs/(2 pi) arccos(-a1 / (2 sqrt(a2))) for complex poles (a1^2 < 4 a2)
   (:func:`tpms_ros.core.vibration_kernel.resonance_frequency`);
4. calibration: each tire's nominal frequency and the noise of its estimate; a stored one is
   checked against the tires before it is used (``calibration_check_s``: a calibration made
   on other tires is refused, not used);
5. indication: z = (f_nominal - f) / sigma in units of the noise, flag at ``z_flag``,
   confidence = clip(z / z_full, 0, 1).

Steps 1-3 run sample by sample in one compiled call per chunk
(:func:`tpms_ros.core.vibration_kernel.vibration_chunk`, numba): as some sixty numpy operations per
chunk they cost about 0.5 ms of call overhead whatever the chunk's length, the latency of a node
whose output falls due; compiled, a 20-sample chunk costs about 0.02 ms.

Input is a uniformly sampled (N, 4) wheel speed array (rad/s, FL, FR, RL, RR); the node handles
stamps and gaps (a gap: :meth:`VibrationAnalyzer.reset_filters`). Bad samples (non-finite,
negative, above ``max_wheel_speed_rad_s``) are rejected and counted: the filter input holds
the last good value and the regression ignores the samples the hold disturbs, so the state is
not corrupted. Samples below ``min_wheel_speed_rad_s`` (too little road excitation) are gated
out the same way, and so are the samples of a wheel reporting held tooth periods while its tooth
edges beat with the sampling inside the passband (``encoder_teeth``; docs/methods/
vibration_analyzer.md, "Edge beat"). No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any

import numpy as np
from scipy import signal

from tpms_ros.core.nominal_calibration import (
    CalibratedCore,
    StoredCalibrationCheck,
    StoredCalibrationCheckParams,
    check_calibration_window,
)
from tpms_ros.core.tires import N_TIRES, TIRE_NAMES, TpmsIndication
from tpms_ros.core.tooth_correction import SpeedForm
from tpms_ros.core.vibration_kernel import vibration_chunk
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.validation import require_positive

TORSIONAL_MODE_HZ = (40.0, 50.0)
"""The paper's torsional tire mode band, Hz (used by the paper)."""
VERTICAL_MODE_HZ = (10.0, 20.0)
"""The paper's vertical tire mode band, Hz."""

CALIBRATION_VERSION = 1

MAX_TOOTH_HARMONICS = 96
"""At most this many harmonics are learned (a gate at a crawl would ask for hundreds; each costs
about a dozen multiplications and two divisions per sample and wheel in the kernel)."""
TOOTH_MEMORY_S = 20.0
"""Memory of the synchronous averaging that learns the tooth-error pattern, s: long against
the torsional vibration (not phase-locked to the wheel angle, it averages out), short against
tyre or sensor changes."""
TOOTH_SMOOTH_HZ = 3.0
"""Corner of the low-pass giving the smooth wheel speed the tooth errors are relative to, Hz."""
FORM_JUDGE_S = 0.1
"""The ECU's speed form (:class:`~tpms_ros.core.tooth_correction.SpeedForm`) is decided on a
clock of this much data, s (a fixed clock: the chunking cannot change the result)."""


@dataclass(frozen=True)
class VibrationParams(StoredCalibrationCheckParams):
    """Parameters of the vibration analysis (each field is also the node's ROS parameter).

    Read-only ones shape the filters at construction; the others are read at each call and may
    change at runtime. Why some values are what they are:

    - ``band_margin``: a 30 % pressure loss (frequency about 10 % lower) stays well inside the
      passband and the filter edges do not pull the AR(2) peak.
    - ``analysis_rate_hz`` (integer decimation, rounded down): lower means a better-conditioned
      AR(2) (pole angle far from 0) and fewer samples; it must keep the passband below 0.45 of
      it. The RLS forgetting is lambda = exp(-1 / (memory_s * analysis rate)).
    - ``stuck_s``: an ABS speed held between tooth edges repeats for milliseconds only.
    - ``guard_s``: after a rejected or gated input sample the band-pass output is disturbed for
      about its impulse-response length.
    - ``rel_noise_floor``: the frequency also wanders with road, speed and temperature, which a
      short calibration does not see.
    - ``calibration_check_s``, ``calibration_fit_ratio``: the check of a stored calibration
      against the tires (:class:`~tpms_ros.core.nominal_calibration.StoredCalibrationCheckParams`);
      the resonance ratio is the estimate over the stored nominal.
    - ``driveline_compensation`` (VEHICLE-SPECIFIC): driveline and suspension-member modes
      (e.g. 25 and 52 Hz, moving with speed) reach both driven rims in phase and pull each
      driven wheel's AR(2) by several Hz, a bias a calibration at one speed does not absorb.
      Their contribution to each wheel's covariances is the left-right cross-covariance (the
      road excites the two tires independently), so the regression sums of each driven wheel
      are taken less the symmetrised left-right cross products, the covariance form of Umeno's
      left-right difference. It needs both driven wheels: a bad sample on one leaves both out.
      ``all`` (all-wheel drive: the driveline reaches all four rims) does so on each axle.
    """

    sample_rate_hz: float = param(1000.0, 'wheel-speed sample rate, Hz', low=50.0,
                                  high=20000.0, read_only=True)
    mode_band_hz: tuple[float, ...] = param(
        TORSIONAL_MODE_HZ, '[low, high] band of the torsional tire mode at nominal '
        'pressure, Hz', read_only=True)
    band_margin: float = param(0.35, 'relative widening of mode_band_hz for the band-pass',
                               low=0.01, high=0.99, read_only=True)
    filter_order: int = param(4, 'Butterworth order of the band-pass', low=1, high=8,
                              read_only=True)
    analysis_rate_hz: float = param(200.0, 'rate of the AR(2) fit after decimation, Hz',
                                    low=10.0, high=20000.0, read_only=True)
    memory_s: float = param(5.0, 'RLS memory (forgetting), s', low=0.1, high=600.0,
                            read_only=True)
    rls_regularization: float = param(1e-6, 'RLS initial regularisation P0^-1, (rad/s)^2',
                                      low=1e-15, high=1.0, read_only=True)
    min_wheel_speed_rad_s: float = param(10.0, 'below this wheel speed the road excitation is too '
                                         'weak: samples are gated, rad/s', low=0.0, high=1000.0)
    max_wheel_speed_rad_s: float = param(600.0, 'wheel speeds above this are non-physical and '
                                         'rejected, rad/s', low=1.0, high=5000.0)
    encoder_teeth: int = param(48, 'teeth per encoder ring (paper: 48): with the sample rate '
                               'it gives the tooth-edge rate, whose beat with the sampling a '
                               'held tooth period carries into the band', low=2, high=1000,
                               read_only=True)
    stuck_s: float = param(0.1, 'an exactly repeated wheel speed for this long is a stuck '
                           'sensor, s', low=1e-3, high=60.0, read_only=True)
    guard_s: float = param(0.05, 'the regression skips this long after a bad sample (filter '
                           'transient), s', low=0.0, high=5.0, read_only=True)
    min_valid_fraction: float = param(0.5, 'a tire is known only if this fraction of the RLS '
                                      'memory is valid', low=0.01, high=1.0)
    calibration_settle_s: float = param(15.0, 'first part of a calibration window not used, s',
                                        low=0.0, high=3600.0)
    min_calibration_s: float = param(10.0, 'least seconds of known estimates per tire for a '
                                     'calibration, s', low=0.1, high=3600.0)
    calibration_duration_s: float = param(60.0, 'length of a calibration run, s of data',
                                          low=0.1, high=36000.0)
    z_flag: float = param(3.0, 'flag a tire when its frequency drop exceeds this many noise '
                          'sigmas', low=0.1, high=100.0)
    z_full: float = param(8.0, 'frequency drop in sigmas at which the confidence reaches 1',
                          low=0.1, high=100.0)
    rel_noise_floor: float = param(0.005, 'floor of the frequency noise relative to the '
                                   'nominal frequency', low=1e-5, high=0.5)
    driveline_compensation: str = param('none', "driven axle(s) whose common driveline "
                                        "vibration is removed by the left-right "
                                        "cross-covariance ('all': each axle, all-wheel drive)",
                                        choices=('none', 'front', 'rear', 'all'),
                                        read_only=True)

    def __post_init__(self) -> None:
        positive = ('sample_rate_hz', 'band_margin', 'analysis_rate_hz', 'memory_s',
                    'rls_regularization', 'max_wheel_speed_rad_s', 'z_flag', 'z_full',
                    'rel_noise_floor', 'min_calibration_s', 'stuck_s')
        require_positive(self, positive)
        require_positive(self, ('min_wheel_speed_rad_s', 'guard_s', 'calibration_settle_s',
                                'calibration_check_s'), allow_zero=True)
        if len(self.mode_band_hz) != 2:
            raise ValueError(f'VibrationParams.mode_band_hz must be [low, high], got '
                             f'{list(self.mode_band_hz)}')
        low, high = self.mode_band_hz
        if not (math.isfinite(low) and math.isfinite(high) and 0.0 < low < high):
            raise ValueError(f'VibrationParams.mode_band_hz must be 0 < low < high, got '
                             f'{self.mode_band_hz}')
        if not self.band_margin < 1.0:
            raise ValueError(f'VibrationParams.band_margin must be < 1, got {self.band_margin}')
        if not 1 <= self.filter_order <= 8:
            raise ValueError(f'VibrationParams.filter_order must be in 1..8, got '
                             f'{self.filter_order}')
        if not (isinstance(self.encoder_teeth, int) and self.encoder_teeth >= 2):
            raise ValueError('VibrationParams.encoder_teeth must be an int >= 2, '
                             f'got {self.encoder_teeth!r}')
        if not self.min_wheel_speed_rad_s < self.max_wheel_speed_rad_s:
            raise ValueError('VibrationParams.min_wheel_speed_rad_s must be < '
                             'max_wheel_speed_rad_s')
        if not 0.0 < self.min_valid_fraction <= 1.0:
            raise ValueError(f'VibrationParams.min_valid_fraction must be in (0, 1], got '
                             f'{self.min_valid_fraction}')
        if not self.z_flag < self.z_full:
            raise ValueError('VibrationParams.z_flag must be < z_full')
        if self.driveline_compensation not in ('none', 'front', 'rear', 'all'):
            raise ValueError(f"VibrationParams.driveline_compensation must be 'none', 'front', "
                             f"'rear' or 'all', got {self.driveline_compensation!r}")
        if self.analysis_rate_hz > self.sample_rate_hz:
            raise ValueError(f'VibrationParams.analysis_rate_hz ({self.analysis_rate_hz}) must '
                             f'be <= sample_rate_hz ({self.sample_rate_hz})')
        if self.passband_hz[1] >= 0.45 * self.effective_rate_hz:
            raise ValueError(
                f'VibrationParams.analysis_rate_hz: the decimated rate {self.effective_rate_hz} '
                f'Hz must exceed the passband top {self.passband_hz[1]:.1f} Hz / 0.45')
        check_calibration_window(self)

    @property
    def passband_hz(self) -> tuple[float, float]:
        """Band-pass edges: the mode band widened by ``band_margin``, Hz."""
        low, high = self.mode_band_hz
        return low * (1.0 - self.band_margin), high * (1.0 + self.band_margin)

    @property
    def decimation(self) -> int:
        """Integer decimation factor from the input to the analysis rate."""
        return max(1, int(self.sample_rate_hz // self.analysis_rate_hz))

    @property
    def effective_rate_hz(self) -> float:
        """Actual rate of the AR(2) fit, Hz."""
        return self.sample_rate_hz / self.decimation

    @property
    def tooth_harmonics(self) -> int:
        """Harmonics of the wheel revolution the tooth-error correction learns.

        The ring's spacing errors repeat every revolution: lines at k x the rotation rate, and
        as many of them fall in the passband as its top divided by the rotation rate. They must
        all be learned down to the slowest wheel analysed (``min_wheel_speed_rad_s``): an
        unlearned line inside the band is read as the resonance (issue 21: 16 harmonics, a
        0.37 m wheel at 33 km/h, a 0.22 % ring; lines 17 and up at 63-67 Hz pulled a true
        40 Hz to 50-53 Hz, and the calibration's noise to 3-5 Hz). Fixed when the analyzer is
        built (the learned sums' size), from the minimum speed then in force.
        """
        if self.min_wheel_speed_rad_s <= 0.0:
            return MAX_TOOTH_HARMONICS
        revolution_hz = self.min_wheel_speed_rad_s / (2.0 * math.pi)
        return min(MAX_TOOTH_HARMONICS, math.ceil(self.passband_hz[1] / revolution_hz))

    @property
    def forgetting(self) -> float:
        """RLS forgetting factor lambda."""
        return math.exp(-1.0 / (self.memory_s * self.effective_rate_hz))


@dataclass(frozen=True)
class ResonanceEstimate:
    """Result of one processed chunk.

    Attributes:
        frequency_hz: (4,) latest resonance estimate, NaN where not known.
        a1: (4,) latest AR(2) coefficient a1.
        a2: (4,) latest AR(2) coefficient a2.
        known: (4,) bool: enough recent valid data and complex poles.
        trace_hz: (M, 4) estimate at each decimated sample of the chunk (NaN where unknown).
        trace_index: (M,) index into the chunk's input samples of each trace row.
        rejected: (4,) cumulative count of rejected (bad) input samples per wheel.
        gated: (4,) cumulative count of input samples gated out (below min speed).
    """

    frequency_hz: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    known: np.ndarray
    trace_hz: np.ndarray
    trace_index: np.ndarray
    rejected: np.ndarray
    gated: np.ndarray


@dataclass(frozen=True)
class VibrationCalibration:
    """Nominal resonance of each tire, as learned by calibration.

    Attributes:
        nominal_frequency_hz: (4,) nominal resonance per tire, Hz.
        noise_hz: (4,) standard deviation of the estimate at nominal pressure, Hz.
        duration_s: (4,) seconds of known estimates that went into each tire's nominal.
    """

    nominal_frequency_hz: np.ndarray
    noise_hz: np.ndarray
    duration_s: np.ndarray

    def to_dict(self) -> dict[str, Any]:
        """Plain, JSON/YAML-serialisable state."""
        return {
            'version': CALIBRATION_VERSION,
            'method': 'vibration',
            'nominal_frequency_hz': [float(v) for v in self.nominal_frequency_hz],
            'noise_hz': [float(v) for v in self.noise_hz],
            'duration_s': [float(v) for v in self.duration_s],
        }

    @classmethod
    def from_dict(cls, state: Mapping[str, Any]) -> VibrationCalibration:
        """Rebuild from :meth:`to_dict` output; raises ValueError on anything corrupt."""
        if not isinstance(state, Mapping):
            raise ValueError(f'calibration state must be a mapping, got {type(state).__name__}')
        if state.get('version') != CALIBRATION_VERSION or state.get('method') != 'vibration':
            raise ValueError(f'calibration state: expected version {CALIBRATION_VERSION} of '
                             f'method vibration, got {state.get("version")!r}/'
                             f'{state.get("method")!r}')
        arrays = {}
        for key in ('nominal_frequency_hz', 'noise_hz', 'duration_s'):
            if key not in state:
                raise ValueError(f'calibration state: missing {key!r}')
            try:
                arr = np.asarray(state[key], dtype=float)
            except (TypeError, ValueError) as exc:
                raise ValueError(f'calibration state: {key!r} is not numeric') from exc
            if arr.shape != (N_TIRES,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
                raise ValueError(f'calibration state: {key!r} must be 4 finite values > 0, '
                                 f'got {state[key]!r}')
            arrays[key] = arr
        return cls(arrays['nominal_frequency_hz'], arrays['noise_hz'], arrays['duration_s'])


def ar2_rls_reference(y: np.ndarray, forgetting: float, regularization: float) -> np.ndarray:
    """Textbook per-sample RLS of an AR(2) model on one signal: the plain reference.

    Used by the tests (the vectorised analyzer must equal it) and the benchmark (the ratio).

    Args:
        y: (M,) pre-processed signal.
        forgetting: lambda in (0, 1].
        regularization: P_0 = I / regularization.

    Returns:
        (M, 2) theta = (a1, a2) after each sample (the first two rows stay at 0).
    """
    theta = np.zeros(2)
    p = np.eye(2) / regularization
    out = np.zeros((len(y), 2))
    for t in range(2, len(y)):
        phi = np.array([-y[t - 1], -y[t - 2]])
        p_phi = p @ phi
        gain = p_phi / (forgetting + phi @ p_phi)
        theta = theta + gain * (y[t] - phi @ theta)
        p = (p - np.outer(gain, p_phi)) / forgetting
        out[t] = theta
    return out


class VibrationAnalyzer(CalibratedCore[VibrationCalibration]):
    """Recursive AR(2) resonance estimate, calibration and indication for four tires.

    Args:
        params: the parameters (defaults: :class:`VibrationParams`).
        tooth_correction: learn and divide out the encoder's tooth-error pattern; off, the
            band-pass sees the raw speed (e.g. to compare with the textbook RLS).
    """

    def __init__(self, params: VibrationParams | None = None, *,
                 tooth_correction: bool = True) -> None:
        self.params = params if params is not None else VibrationParams()
        self._tooth_correction = tooth_correction
        p = self.params
        self._sos = signal.butter(p.filter_order, p.passband_hz, btype='bandpass',
                                  fs=p.sample_rate_hz, output='sos')
        self._sos_zi_unit = signal.sosfilt_zi(self._sos)              # (sections, 2)
        self._lp_sos = signal.butter(2, TOOTH_SMOOTH_HZ, fs=p.sample_rate_hz, output='sos')
        self._lp_zi_unit = signal.sosfilt_zi(self._lp_sos)
        self._tooth_lambda = math.exp(-1.0 / (TOOTH_MEMORY_S * p.sample_rate_hz))
        self._harmonics = p.tooth_harmonics
        self._lambda = p.forgetting
        self._driven = np.array({'none': (-1, -1), 'front': (0, 1), 'rear': (2, 3),
                                 'all': (0, 1, 2, 3)}[p.driveline_compensation],
                                dtype=np.int64)
        # tooth edges per sample of a wheel turning at 1 rad/s, and the ECU's speed form
        self._edge_rate_per_rad_s = p.encoder_teeth / (2.0 * math.pi * p.sample_rate_hz)
        self._form = SpeedForm(N_TIRES, p.sample_rate_hz)
        self._form_clock = max(1, int(round(FORM_JUDGE_S * p.sample_rate_hz)))
        self._form_count = 0
        self._guard_samples = int(math.ceil(p.guard_s * p.sample_rate_hz))
        self._counts = np.array([max(2, int(math.ceil(p.stuck_s * p.sample_rate_hz))),
                                 self._guard_samples], dtype=np.int64)
        self._calibration: VibrationCalibration | None = None
        self._calibrating = False
        self.calibration_check = StoredCalibrationCheck(N_TIRES)
        self.rejected = np.zeros(N_TIRES, dtype=np.int64)
        self.gated = np.zeros(N_TIRES, dtype=np.int64)
        self.beat_gated = np.zeros(N_TIRES, dtype=np.int64)
        self.reset_filters()

    # ---------------------------------------------------------------- state
    def reset_filters(self) -> None:
        """Restart pre-processing and RLS (after a gap in the data); keeps the calibration."""
        self._sos_state = np.zeros((self._sos.shape[0], 2, N_TIRES))
        # tooth-error correction: integrated wheel angle, smooth-speed low-pass, and the
        # exponentially weighted sums of (deviation x conj(exp(i k angle))) and of the weights.
        # The learned pattern is tied to the angle origin, so a gap restarts it too.
        self._angle = np.zeros(N_TIRES)
        self._lp_state = np.zeros((self._lp_sos.shape[0], 2, N_TIRES))
        self._tooth_sum = np.zeros((self._harmonics + 1, N_TIRES), dtype=complex)
        self._wheel_started = np.zeros(N_TIRES, dtype=bool)
        # previous input and its repeat count (stuck sensor), held good input (NaN before
        # the first), samples since the last bad or gated one
        self._wheel_state = np.stack([np.full(N_TIRES, np.nan), np.zeros(N_TIRES),
                                      np.full(N_TIRES, np.nan),
                                      np.full(N_TIRES, float(self._guard_samples))])
        self._phase = 0                                 # next chunk index to keep
        self._previous = np.full(N_TIRES, np.nan)       # last input (speed form's changes)
        self._y_hist = np.zeros((2, N_TIRES))           # y_{t-2}, y_{t-1}
        self._v_hist = np.zeros((2, N_TIRES), dtype=bool)
        # exponentially weighted sums R11, R12, R22, q1, q2, n as filter states (lambda x)
        reg = self.params.rls_regularization
        self._ls_state = np.zeros((6, N_TIRES))
        self._ls_state[0] = self._lambda * reg
        self._ls_state[2] = self._lambda * reg
        self._latest = np.full(N_TIRES, np.nan)
        self._latest_a = np.zeros((2, N_TIRES))
        self._latest_known = np.zeros(N_TIRES, dtype=bool)
        self._cal_sum = np.zeros((3, N_TIRES))          # count, sum f, sum f^2
        self._cal_seen = 0

    def reset_wheel(self, wheel: int) -> None:
        """Restart one wheel's pre-processing and RLS (its sensor recovered from a fault: the
        tooth-error pattern was learned against a wheel angle integrated from held values, and
        the band-pass and regression sums hold the fault's transient); keeps the calibration and
        the other wheels. On a compensated driven axle the partner's cross products restart with
        it on the next kept sample (the pair's weight needs both wheels valid)."""
        w = wheel
        self._sos_state[:, :, w] = 0.0
        self._angle[w] = 0.0
        self._lp_state[:, :, w] = 0.0
        self._tooth_sum[:, w] = 0.0
        self._wheel_started[w] = False
        self._wheel_state[:, w] = (np.nan, 0.0, np.nan, float(self._guard_samples))
        self._previous[w] = np.nan
        self._y_hist[:, w] = 0.0
        self._v_hist[:, w] = False
        reg = self.params.rls_regularization
        self._ls_state[:, w] = 0.0
        self._ls_state[0, w] = self._lambda * reg
        self._ls_state[2, w] = self._lambda * reg
        self._latest[w] = np.nan
        self._latest_a[:, w] = 0.0
        self._latest_known[w] = False

    @property
    def held_tooth_periods(self) -> np.ndarray:
        """(4,) wheels whose speeds read as held tooth periods (not yet judged: held), the
        ones the edge-beat gate applies to."""
        return ~self._form.angle_mode

    def known_wheels(self) -> np.ndarray:
        """(4,) whether each wheel's latest resonance estimate is known."""
        return self._latest_known.copy()

    def start_calibration(self) -> None:
        """Start learning the nominal frequencies from the data processed from now on."""
        self._calibrating = True
        self.calibration_check.cancel()
        self._cal_sum[:] = 0.0
        self._cal_seen = 0

    calibration_counts = 'known estimates per tire'
    calibration_channels = TIRE_NAMES

    @property
    def calibration_rate_hz(self) -> float:
        """Estimates are counted at the analysis rate."""
        return self.params.effective_rate_hz

    def _calibration_from(self, mean: np.ndarray, std: np.ndarray,
                          duration_s: np.ndarray) -> VibrationCalibration:
        # a floor on the stored noise keeps a perfectly clean calibration from dividing by ~0
        return VibrationCalibration(mean, np.maximum(std, 1e-6 * mean), duration_s)

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Put a persisted calibration in force; raises ValueError if it is corrupt."""
        calibration = VibrationCalibration.from_dict(state)
        low, high = self.params.passband_hz
        f = calibration.nominal_frequency_hz
        if np.any(f <= low) or np.any(f >= high):
            raise ValueError(f'calibration state: nominal_frequency_hz {f} outside the '
                             f'passband {low:.1f}..{high:.1f} Hz')
        self._calibration = calibration
        self.calibration_check.start(self.params)

    def _check_calibration(self, trace_hz: np.ndarray) -> None:
        """Add the chunk's estimates to the pending check; refuse the calibration when the
        tires' resonances do not fit it."""
        cal = self._calibration
        assert cal is not None
        decided = self.calibration_check.add(trace_hz / cal.nominal_frequency_hz,
                                             1.0 / self.params.effective_rate_hz, self.params)
        if decided is None or self.calibration_check.fits(decided[0], self.params):
            return
        median, mean = decided
        resonance = ', '.join(f'{TIRE_NAMES[w]} {m * f0:.1f} Hz' for w, (m, f0) in
                              enumerate(zip(mean, cal.nominal_frequency_hz, strict=True))
                              if np.isfinite(m))
        stored = ', '.join(f'{f0:.1f}' for f0 in cal.nominal_frequency_hz)
        self.calibration_check.refuse(f'resonance {resonance}', f'{stored} Hz', median,
                                      self.params)
        self._calibration = None

    # ---------------------------------------------------------- processing
    def process(self, omega: np.ndarray) -> ResonanceEstimate:
        """Process a chunk of uniformly sampled wheel speeds.

        Args:
            omega: (N, 4) wheel angular speeds, rad/s, at ``sample_rate_hz``.

        Returns:
            The estimate at the end of the chunk and its trace at the analysis rate.
        """
        omega = np.ascontiguousarray(omega, dtype=float)
        if omega.ndim != 2 or omega.shape[1] != N_TIRES:
            raise ValueError(f'omega must have shape (N, 4), got {omega.shape}')
        p = self.params
        n = omega.shape[0]
        # the decimation's phase carried across chunks
        keep = np.arange(self._phase, n, p.decimation)
        self._phase = int(keep[-1] + p.decimation - n) if keep.size else self._phase - n
        trace_hz = np.empty((keep.size, N_TIRES))
        beat = self._edge_beat(omega)
        # The runtime parameters (limits) are read at each call.
        limits = np.array([p.max_wheel_speed_rad_s, p.min_wheel_speed_rad_s,
                           1.0 / p.sample_rate_hz,
                           self._tooth_lambda, self._lambda, p.effective_rate_hz,
                           p.min_valid_fraction])
        vibration_chunk(omega, beat, int(keep[0]) if keep.size else n, p.decimation, limits,
                        self._counts, self._driven, self._sos, self._sos_zi_unit,
                        self._sos_state, self._lp_sos, self._lp_zi_unit, self._lp_state,
                        self._tooth_correction, self._tooth_sum, self._angle,
                        self._wheel_state, self._wheel_started, self.rejected, self.gated,
                        self._y_hist, self._v_hist, self._ls_state, trace_hz,
                        self._latest_a, self._latest_known)
        if keep.size:
            self._latest = trace_hz[-1].copy()
            if self._calibrating:
                self._accumulate_calibration(trace_hz)
            elif self.calibration_check.pending:
                self._check_calibration(trace_hz)
        return self._estimate(trace_hz, keep)

    def _edge_beat(self, omega: np.ndarray) -> np.ndarray:
        """(N, 4) samples of held-tooth-period wheels whose tooth edges beat with the sampling
        inside the passband (docs/methods/vibration_analyzer.md, "Edge beat"); the speed form
        is learned from the chunk on the way.

        A held period reports the last tooth's speed at each sample. At ``e`` tooth edges per
        sample the tooth it reports advances by ``e`` per sample, so which tooth is seen, and
        with it the ring's per-tooth spacing error, is modulated at the beat
        ``|e - round(e)| fs`` and its harmonics. Near ``e = 1`` (a 48-tooth ring on a 0.3 m
        wheel at 1 kHz: about 130-150 km/h) that beat sweeps through the tire's band and the
        AR(2) takes it for the resonance (issue 21, eight tuning cars: healthy tires'
        confidence at 0.5 or more on 1.5-14 % of the time with the beat below the passband's
        top, the more the lower the beat, 0.5-1.3 % above it). A window average spreads
        each reading over several teeth and shows no such rise, so only held-period wheels are
        gated.
        """
        p = self.params
        n = omega.shape[0]
        usable = (np.isfinite(omega) & (omega >= p.min_wheel_speed_rad_s)
                  & (omega <= p.max_wheel_speed_rad_s))
        edge_rate = np.where(usable, omega * self._edge_rate_per_rad_s, 0.0)
        change = omega != np.concatenate((self._previous[None], omega[:-1]))
        held = np.empty((n, N_TIRES), dtype=bool)
        start = 0
        while start < n:
            stop = min(n, start + self._form_clock - self._form_count % self._form_clock)
            held[start:stop] = ~self._form.angle_mode
            self._form.add(change[start:stop], edge_rate[start:stop], usable[start:stop])
            self._form_count += stop - start
            if self._form_count % self._form_clock == 0:
                self._form.judge()
            start = stop
        if n:
            self._previous = omega[-1].copy()
        nearest = np.round(edge_rate)
        beat = (held & usable & (nearest >= 1.0)
                & (np.abs(edge_rate - nearest) * p.sample_rate_hz < p.passband_hz[1]))
        self.beat_gated += beat.sum(axis=0)
        return beat

    def _accumulate_calibration(self, trace_hz: np.ndarray) -> None:
        settle = int(round(self.params.calibration_settle_s * self.params.effective_rate_hz))
        skip = max(0, min(settle - self._cal_seen, trace_hz.shape[0]))
        self._cal_seen += trace_hz.shape[0]
        used = trace_hz[skip:]
        ok = np.isfinite(used)
        vals = np.where(ok, used, 0.0)
        self._cal_sum += np.stack([ok.sum(axis=0), vals.sum(axis=0), (vals * vals).sum(axis=0)])

    def _estimate(self, trace_hz: np.ndarray, keep: np.ndarray) -> ResonanceEstimate:
        return ResonanceEstimate(
            frequency_hz=self._latest.copy(),
            a1=self._latest_a[0].copy(),
            a2=self._latest_a[1].copy(),
            known=self._latest_known.copy(),
            trace_hz=trace_hz,
            trace_index=keep,
            rejected=self.rejected.copy(),
            gated=self.gated.copy(),
        )

    # ---------------------------------------------------------- indication
    def frequency_sigma_hz(self) -> np.ndarray:
        """(4,) the noise the indication divides by: the calibration's, at least
        ``rel_noise_floor`` of the nominal frequency (NaN without a calibration), Hz."""
        cal = self._calibration
        if cal is None:
            return np.full(N_TIRES, np.nan)
        return np.maximum(cal.noise_hz, self.params.rel_noise_floor * cal.nominal_frequency_hz)

    def frequency_drop_sigma(self) -> np.ndarray:
        """(4,) frequency drop below nominal in noise sigmas (NaN where unknown)."""
        cal = self._calibration
        if cal is None or self.calibration_check.pending:
            return np.full(N_TIRES, np.nan)
        return np.where(self._latest_known,
                        (cal.nominal_frequency_hz - self._latest) / self.frequency_sigma_hz(),
                        np.nan)

    def indication(self, stamp_s: float) -> TpmsIndication:
        """Per-tire flag and confidence from the latest estimate (unknown if uncalibrated)."""
        z = self.frequency_drop_sigma()
        known = np.isfinite(z)
        z = np.where(known, z, 0.0)
        p = self.params
        return TpmsIndication(
            method='vibration',
            stamp_s=stamp_s,
            underinflated=known & (z >= p.z_flag),
            confidence=np.clip(z / p.z_full, 0.0, 1.0),
            known=known,
        )
