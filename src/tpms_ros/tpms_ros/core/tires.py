"""Message-free types shared by the road cores, the voter and the nodes: tire order and names,
and one method's per-tire indication (the content of ``/tpms/indication/<method>``). No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

N_TIRES = 4
TIRE_NAMES = ('FL', 'FR', 'RL', 'RR')


@dataclass(frozen=True)
class TpmsIndication:
    """One method's per-tire indication (the content of ``/tpms/indication/<method>``).

    Attributes:
        method: method name, e.g. ``'vibration'``, ``'wheel_radius'``, ``'stiffness'``.
        stamp_s: time of the input sample the indication answers, s.
        underinflated: (4,) bool flags t_i, wheel order FL, FR, RL, RR.
        confidence: (4,) confidence c_i in 0..1 that the tire is low.
        known: (4,) bool; False where the method has no valid information on the tire (not
            calibrated, bad sensor, not observable). An unknown tire is never counted as low.
    """

    method: str
    stamp_s: float
    underinflated: np.ndarray
    confidence: np.ndarray
    known: np.ndarray = field(default_factory=lambda: np.ones(N_TIRES, dtype=bool))

    def __post_init__(self) -> None:
        if not self.method:
            raise ValueError('TpmsIndication.method must be a non-empty string')
        if not math.isfinite(self.stamp_s):
            raise ValueError(f'TpmsIndication.stamp_s must be finite, got {self.stamp_s}')
        flags = np.asarray(self.underinflated, dtype=bool).copy()
        conf = np.asarray(self.confidence, dtype=float).copy()
        known = np.asarray(self.known, dtype=bool).copy()
        for name, arr in (('underinflated', flags), ('confidence', conf), ('known', known)):
            if arr.shape != (N_TIRES,):
                raise ValueError(f'TpmsIndication.{name} must have shape (4,), got {arr.shape}')
        if not np.all(np.isfinite(conf)) or np.any(conf < 0.0) or np.any(conf > 1.0):
            raise ValueError(f'TpmsIndication.confidence must be finite in 0..1, got {conf}')
        for arr in (flags, conf, known):
            arr.flags.writeable = False
        # frozen dataclass: store the validated read-only copies
        object.__setattr__(self, 'underinflated', flags)
        object.__setattr__(self, 'confidence', conf)
        object.__setattr__(self, 'known', known)
