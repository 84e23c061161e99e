"""Lateral track alignment spectra (published PSDs) used by the estimators and the simulator.

Spectrum: the German track spectra for high-speed lines (ORE B176 / DB), lateral alignment

    S_a(Omega) = A_a Omega_c^2 / ((Omega^2 + Omega_r^2) (Omega^2 + Omega_c^2))   [m^2 / (rad/m)]

with Omega the spatial angular frequency (rad/m), Omega_c = 0.8246 rad/m, Omega_r = 0.0206 rad/m
and A_a = 2.119e-7 m rad ("low interference", good track) or 6.125e-7 m rad ("high
interference"), a one-sided density (tabulated e.g. in Zhai, Vehicle-Track Coupled Dynamics,
Springer 2020, ch. 3, and widely used in European vehicle dynamics studies).

Seeded profile synthesis from these spectra lives in
:mod:`rail_monitor_ros.simulation.track_profile`. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from vehicle_monitor_common.validation import require_positive


@dataclass(frozen=True)
class TrackSpectrum:
    """One-sided lateral alignment PSD of the German form (module docstring).

    Attributes:
        name: key used in scenario files.
        roughness: A_a, m rad.
        omega_c: Omega_c, rad/m.
        omega_r: Omega_r, rad/m.
    """

    name: str
    roughness: float
    omega_c: float
    omega_r: float

    def __post_init__(self) -> None:
        require_positive(self, ('roughness', 'omega_c', 'omega_r'))

    def psd(self, omega: np.ndarray) -> np.ndarray:
        """S_a(Omega), m^2/(rad/m), at spatial angular frequencies Omega (rad/m)."""
        w2 = np.asarray(omega, dtype=float) ** 2
        return self.roughness * self.omega_c ** 2 / (
            (w2 + self.omega_r ** 2) * (w2 + self.omega_c ** 2))

    def variance(self, min_wavelength: float, max_wavelength: float) -> float:
        """Alignment variance in a wavelength band, m^2 (closed-form integral of the PSD)."""
        lo, hi = 2.0 * math.pi / max_wavelength, 2.0 * math.pi / min_wavelength
        r, c = self.omega_r, self.omega_c

        # Partial fractions: 1/((w^2+r^2)(w^2+c^2)) = (1/(w^2+r^2) - 1/(w^2+c^2)) / (c^2 - r^2)
        def primitive(w: float) -> float:
            return (math.atan(w / r) / r - math.atan(w / c) / c) / (c * c - r * r)

        return self.roughness * c * c * (primitive(hi) - primitive(lo))


TRACK_SPECTRA: dict[str, TrackSpectrum] = {
    'german_low': TrackSpectrum('german_low', 2.119e-7, 0.8246, 0.0206),
    'german_high': TrackSpectrum('german_high', 6.125e-7, 0.8246, 0.0206),
}
