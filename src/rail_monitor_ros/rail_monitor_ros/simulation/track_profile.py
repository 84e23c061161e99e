"""Random lateral track alignment from a published spectrum, as a seeded spatial profile.

The spectra are in :mod:`rail_monitor_ros.core.track_spectra`. The profile is a function of
distance along the track, so every wheelset sees the same track, delayed by its distance behind
the leading wheelset over the speed. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from rail_monitor_ros.core.track_spectra import TrackSpectrum


@dataclass(frozen=True)
class TrackProfile:
    """Lateral alignment sampled along the track.

    Attributes:
        start: position of the first sample, m.
        spacing: sample spacing, m.
        alignment: (N,) lateral alignment, m (y left).
    """

    start: float
    spacing: float
    alignment: np.ndarray

    @property
    def positions(self) -> np.ndarray:
        """(N,) sample positions, m."""
        return self.start + self.spacing * np.arange(self.alignment.size)

    def at(self, position: np.ndarray) -> np.ndarray:
        """Alignment at arbitrary positions (linear interpolation), m.

        Raises:
            ValueError: a position outside the generated profile.
        """
        s = np.asarray(position, dtype=float)
        end = self.start + self.spacing * (self.alignment.size - 1)
        if s.size and (np.min(s) < self.start - 1e-9 or np.max(s) > end + 1e-9):
            raise ValueError(f'position outside the track profile [{self.start}, {end}] m')
        return np.interp(s, self.positions, self.alignment)

    def slope_at(self, position: np.ndarray) -> np.ndarray:
        """d(alignment)/ds at positions, 1 (the rate seen at speed v is v times this)."""
        slope = np.gradient(self.alignment, self.spacing)
        s = np.asarray(position, dtype=float)
        return np.interp(s, self.positions, slope)


def generate_track_profile(spectrum: TrackSpectrum, start: float, length: float,
                           rng: np.random.Generator, min_wavelength: float = 1.0,
                           max_wavelength: float = 120.0, scale: float = 1.0) -> TrackProfile:
    """Gaussian alignment profile with the given spectrum in a wavelength band.

    Spectral synthesis with random complex Fourier coefficients (not random phases only, so the
    amplitude is Gaussian as well), on a grid of min_wavelength / 10 spacing; the FFT length
    exceeds the profile by two longest wavelengths so the periodic wrap does not correlate the
    ends.

    Args:
        spectrum: the PSD.
        start: first position, m (negative to cover wheelsets behind the leading one).
        length: profile length, m, > 0.
        rng: seeded generator; same seed, same profile.
        min_wavelength: shortest wavelength kept, m.
        max_wavelength: longest wavelength kept, m.
        scale: amplitude multiplier (1 = the published spectrum).

    Returns:
        The profile.
    """
    if not (math.isfinite(length) and length > 0.0):
        raise ValueError(f'length must be finite and > 0, got {length}')
    if not (math.isfinite(start)):
        raise ValueError(f'start must be finite, got {start}')
    if not (0.0 < min_wavelength < max_wavelength and math.isfinite(max_wavelength)):
        raise ValueError(
            f'need 0 < min_wavelength < max_wavelength, got {min_wavelength}, {max_wavelength}')
    if not (math.isfinite(scale) and scale >= 0.0):
        raise ValueError(f'scale must be finite and >= 0, got {scale}')
    spacing = min_wavelength / 10.0
    n = int(math.ceil(length / spacing)) + 1
    n_fft = 1 << int(math.ceil(math.log2(n + 2.0 * max_wavelength / spacing)))
    omega = 2.0 * math.pi * np.fft.rfftfreq(n_fft, d=spacing)
    d_omega = omega[1]
    in_band = (omega >= 2.0 * math.pi / max_wavelength) & (omega <= 2.0 * math.pi / min_wavelength)
    amplitude = np.where(in_band, np.sqrt(spectrum.psd(omega) * d_omega), 0.0)
    coefficients = rng.standard_normal(omega.size) + 1j * rng.standard_normal(omega.size)
    # irfft(X)[n] = (2/N) sum_k Re(X_k e^{i Omega_k s_n}) for 0 < k < N/2, so X_k = N/2 a_k z_k
    # gives sum_k a_k (Re z cos - Im z sin) with variance sum_k S_k dOmega.
    profile = np.fft.irfft(0.5 * n_fft * amplitude * coefficients, n=n_fft)[:n]
    return TrackProfile(float(start), float(spacing), scale * profile)
