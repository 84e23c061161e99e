"""Two-inertia torsional tire model (Umeno et al. 1997, eq. 1-3): the one source of its matrices.

The road simulator integrates it as truth and the stiffness observer builds its observer from it
with its own parameters. Per wheel, rim inertia J1 (with hub, disc), belt/tread inertia J2,
torsional stiffness K and damping D between them::

    J1 w1' = -K th - D (w1 - w2) + T_rim      (T_rim: drive/brake torque on the rim)
    J2 w2' =  K th + D (w1 - w2) - T_d        (T_d: road torque on the belt)
    th'    =  w1 - w2                         (th = theta1 - theta2, torsion)

State x = [w1, w2, th], inputs u = [T_rim, T_d]. No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vehicle_monitor_common.parameters import param


@dataclass(frozen=True)
class TorsionalTire:
    """Parameters of one tire's torsional model.

    Defaults give a 40 Hz rim/belt resonance, as the paper's car at 200 kPa.
    """

    # The paper's symbols (J1, J2, K, D) name the fields; the units are in the descriptions.
    j1: float = param(0.8, 'rim-side inertia J1, kg m^2', low=1e-3, high=100.0)
    j2: float = param(0.6, 'belt-side inertia J2, kg m^2', low=1e-3, high=100.0)
    k: float = param(21656.0, 'torsional stiffness K at nominal pressure, N m/rad (21656 with '
                     'the inertias above: 40 Hz)', low=1.0, high=1e7)
    d: float = param(8.0, 'torsional damping D, N m s/rad', low=0.0, high=1e4)

    def __post_init__(self) -> None:
        for name in ('j1', 'j2', 'k'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'TorsionalTire.{name} must be > 0, got {getattr(self, name)}')
        if not self.d >= 0.0:
            raise ValueError(f'TorsionalTire.d must be >= 0, got {self.d}')

    @property
    def reduced_inertia(self) -> float:
        """J1 J2 / (J1 + J2): the inertia of the relative (torsional) mode, kg m^2."""
        return self.j1 * self.j2 / (self.j1 + self.j2)

    @property
    def resonance_hz(self) -> float:
        """Undamped natural frequency of the torsional mode, Hz."""
        return float(np.sqrt(self.k / self.reduced_inertia) / (2.0 * np.pi))

    def with_resonance(self, frequency_hz: float) -> TorsionalTire:
        """The same inertias and damping with K chosen for the given resonance."""
        k = (2.0 * np.pi * frequency_hz) ** 2 * self.reduced_inertia
        return TorsionalTire(self.j1, self.j2, float(k), self.d)

    def state_space(self) -> tuple[np.ndarray, np.ndarray]:
        """Continuous (A, B) for x = [w1, w2, th], u = [T_rim, T_d]."""
        j1, j2, k, d = self.j1, self.j2, self.k, self.d
        a = np.array([
            [-d / j1, d / j1, -k / j1],
            [d / j2, -d / j2, k / j2],
            [1.0, -1.0, 0.0],
        ])
        b = np.array([
            [1.0 / j1, 0.0],
            [0.0, -1.0 / j2],
            [0.0, 0.0],
        ])
        return a, b
