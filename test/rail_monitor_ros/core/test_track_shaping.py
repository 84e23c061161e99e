"""The full-car IMM's track model: the alignment spectrum's variance, delays between
wheelsets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rail_monitor_ros.core.rail_model import RailVehicleParams
from rail_monitor_ros.core.track_shaping import map_error_roughness, track_shaping_model
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA, TrackSpectrum


def test_track_shaping_model_has_the_track_spectrum_and_delays() -> None:
    """The track model's variance is the spectrum's integral and its outputs are the first
    wheelset's alignment delayed by distance / speed (gain 1, phase within 2 degrees at 4 Hz
    and 40 m/s, a 10 m wavelength)."""
    import scipy.linalg

    v = RailVehicleParams()
    roughness, omega_c, omega_r = 2.119e-7, 0.8246, 0.0206
    track = track_shaping_model(roughness, omega_c, omega_r, 40.0, v.wheelset_offsets, 5.0)
    cov = scipy.linalg.solve_continuous_lyapunov(
        track.a, -track.noise_density * np.outer(track.g, track.g))
    variance = math.pi * roughness * omega_c / (2 * omega_r * (omega_r + omega_c))
    np.testing.assert_allclose(np.diag(track.c @ cov @ track.c.T), variance, rtol=1e-6)
    omega = 2 * math.pi * 4.0
    response = track.c @ np.linalg.solve(1j * omega * np.eye(track.a.shape[0]) - track.a,
                                         track.g)
    ratio = response / response[0]
    np.testing.assert_allclose(np.abs(ratio), 1.0, atol=1e-9)
    phase_error = np.angle(ratio * np.exp(1j * omega * v.wheelset_offsets / 40.0))
    assert np.max(np.abs(phase_error)) < math.radians(2.0)
    with pytest.raises(ValueError, match='speed'):
        track_shaping_model(roughness, omega_c, omega_r, 0.0, v.wheelset_offsets, 5.0)


def test_map_error_roughness_gives_the_stated_rms_in_its_band() -> None:
    """A map error of 0.3 mm rms over wavelengths up to 120 m: the error spectrum, the
    track's scaled, integrates to (0.3 mm)^2 over that band, and its whole-spectrum variance is
    larger in the track's ratio (about 4.5 times for the German spectra)."""
    spectrum = TRACK_SPECTRA['german_low']
    args = (spectrum.roughness, spectrum.omega_c, spectrum.omega_r)
    roughness = map_error_roughness(*args, 3e-4, 120.0)
    error = TrackSpectrum('error', roughness, spectrum.omega_c, spectrum.omega_r)
    assert error.variance(1e-3, 120.0) == pytest.approx(9e-8, rel=1e-9)
    ratio = error.variance(1e-3, 1e9) / error.variance(1e-3, 120.0)
    assert ratio == pytest.approx(spectrum.variance(1e-3, 1e9) / spectrum.variance(1e-3, 120.0))
    assert 4.0 < ratio < 5.0
    with pytest.raises(ValueError, match='error_rms'):
        map_error_roughness(*args, 0.0, 120.0)
