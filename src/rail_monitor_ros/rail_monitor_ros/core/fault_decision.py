"""The suspension IMM's fault decision: hypotheses (spring, damper ratio snapped to the mode
grid) declared when their smoothed probability holds above a threshold for a time; a fault
clears by the same rule. No ROS import."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
import math

import numpy as np

from rail_monitor_ros.core.suspension_modes import RATIO_DECIMALS

FAULT_COMPONENTS = ('', 'spring', 'damper', 'spring+damper')


@dataclass(frozen=True)
class FaultStatus:
    """The decision at one sample.

    Attributes:
        detected: a non-normal hypothesis is declared.
        component: one of :data:`FAULT_COMPONENTS` ('' when none).
        spring_ratio: the declared hypothesis's spring ratio (snapped to the mode grid), 1.
        damper_ratio: the declared hypothesis's damper ratio, 1.
        probability: the declared hypothesis's smoothed probability.
    """

    detected: bool
    component: str
    spring_ratio: float
    damper_ratio: float
    probability: float


NO_FAULT = FaultStatus(False, '', 1.0, 1.0, 0.0)
# The (spring, damper) ratios of the healthy suspension.
NORMAL_HYPOTHESIS = (1.0, 1.0)


def fault_component(spring_ratio: float, damper_ratio: float) -> str:
    """'', 'spring', 'damper' or 'spring+damper' for ratios snapped to the mode grid."""
    spring = round(spring_ratio, RATIO_DECIMALS) != 1.0
    damper = round(damper_ratio, RATIO_DECIMALS) != 1.0
    return {(False, False): '', (True, False): 'spring', (False, True): 'damper',
            (True, True): 'spring+damper'}[(spring, damper)]


class FaultDecision:
    """Declares the hypothesis whose smoothed probability held above a threshold for a time.

    Symmetric: the normal hypothesis is declared (the fault cleared) by the same rule, and a
    change from one fault hypothesis to another (spring -> spring+damper) too.
    """

    def __init__(self, threshold: float, hold_time_s: float, dt: float) -> None:
        if not 0.0 < threshold < 1.0:
            raise ValueError(f'threshold must be in (0, 1), got {threshold}')
        if not (math.isfinite(hold_time_s) and hold_time_s >= 0.0):
            raise ValueError(f'hold_time_s must be finite and >= 0, got {hold_time_s}')
        self.threshold = threshold
        self.hold_samples = int(round(hold_time_s / dt))
        self.reset()

    def reset(self) -> None:
        """Back to normal with nothing pending."""
        self._declared: tuple[float, float] = NORMAL_HYPOTHESIS
        self._pending: tuple[float, float] | None = None
        self._held = 0

    @property
    def state(self) -> tuple[tuple[float, float], tuple[float, float] | None, int]:
        """(declared, pending, samples held): to go back to with :meth:`load_state`."""
        return self._declared, self._pending, self._held

    def load_state(self, state: tuple[tuple[float, float], tuple[float, float] | None,
                                      int]) -> None:
        """Back to a :attr:`state`."""
        self._declared, self._pending, self._held = state

    def update(self, keys: Sequence[tuple[float, float]],
               probabilities: np.ndarray) -> FaultStatus:
        """One sample: hypothesis keys (spring, damper) and their smoothed probabilities."""
        best = int(np.argmax(probabilities))
        if probabilities[best] > self.threshold:
            key = keys[best]
            if key == self._pending:
                self._held += 1
            else:
                self._pending, self._held = key, 1
            if self._held > self.hold_samples:
                self._declared = key
        else:
            self._pending, self._held = None, 0
        if self._declared == NORMAL_HYPOTHESIS:
            return NO_FAULT
        # The adaptive step may have moved the bank off the declared hypothesis: probability 0.
        probability = (float(probabilities[keys.index(self._declared)])
                       if self._declared in keys else 0.0)
        return FaultStatus(True, fault_component(*self._declared), self._declared[0],
                           self._declared[1], probability)
