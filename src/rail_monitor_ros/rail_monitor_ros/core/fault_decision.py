"""The suspension IMM's fault decision: what turns smoothed hypothesis probabilities into a
declared fault. No ROS import.

The rule (docs/methods/suspension_monitor.md, "The decision"):

* Hypotheses are the modes' (spring, damper) ratios snapped to the mode grid. For the decision
  a ratio within ``min_deviation`` of nominal counts as nominal: the neighbours of the normal
  mode (spring 110 %, damper 90 % on the default grid) still size a fault, but are not one by
  themselves (on healthy development runs they won most of the samples where normal lost).
* A **compound** hypothesis (spring and damper both off) is only one when a spring fault was
  declared before it (the declared fault is 'spring' or 'spring+damper'). Otherwise its
  evidence counts for the damper-only hypothesis of the same damper ratio. Why: with the
  adaptive step the damper modes carry the spring ratio the bank estimates, and the spring
  modes measure the spring only while the damper is healthy; after a damper fault their
  residual weight, all on spring ratios above 1, pulls the estimate upwards (measured on
  development cars: 1.0 -> 1.19 within 5 s of a damper-49 % fault, declared 'spring+damper').
  So a spring part that appears after the damper failed is not evidence of a spring fault.
* **Declare** a fault *component* ('spring', 'damper', 'spring+damper': the summed probability
  of its hypotheses) once it has led above ``threshold`` for ``hold_time_s`` *net*: an
  up-down count per component, one up for each sample it leads above the threshold, one down
  for each sample it does not (never below zero). A dip takes back what it lasts instead of
  restarting the count, so a fault whose probability flickers about the threshold is still
  declared, while a healthy excursion must last ``hold_time_s`` to be one. Measured on the 68
  development-wide cases per kind (docs/methods/rail_family_evaluation.md): a count that
  restarts at every dip needed 0.5 s to declare every fault by the end of its 8 s, and then
  one healthy run in 17 hours declared a fault; with the up-down count and 1 s every fault is
  declared and no healthy run (the largest healthy excursion: 0.69 s net). Another
  component replaces a declared one by the same rule. The size reported is the component's most
  probable hypothesis at each sample. By component, not by single hypothesis: a fault between
  two grid points spreads its probability over both neighbours (a damper at 66 % on 70 % and
  80 %), and no single one may reach the threshold (development: 1 of 24 damper faults never
  declared by hypothesis, 0 by component).
* **Hysteresis on the decision**: a declared fault is cleared only when the *normal*
  hypothesis stays above ``threshold`` for ``clear_time_s`` without a break; a dip of the declared
  component's probability (nobody above the threshold, or normal ahead for less than
  ``clear_time_s``) does not clear it.
"""

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
        probability: the declared hypothesis's grouped smoothed probability.
    """

    detected: bool
    component: str
    spring_ratio: float
    damper_ratio: float
    probability: float


NO_FAULT = FaultStatus(False, '', 1.0, 1.0, 0.0)
# The (spring, damper) ratios of the healthy suspension.
NORMAL_HYPOTHESIS = (1.0, 1.0)
Hypothesis = tuple[float, float]
# The fault components a decision counts evidence for, in the order of its counts.
_FAULTS = FAULT_COMPONENTS[1:]
# What FaultDecision.state returns: (declared hypothesis, samples normal has led without a
# break, each fault component's up-down count).
DecisionState = tuple[Hypothesis, int, tuple[int, ...]]
# How a list of hypotheses groups for the decision: each hypothesis's group, the groups'
# decision hypotheses (in the order first seen) and their fault components.
Grouping = tuple[list[int], list[Hypothesis], list[str]]


def fault_component(spring_ratio: float, damper_ratio: float) -> str:
    """'', 'spring', 'damper' or 'spring+damper' for ratios snapped to the mode grid."""
    spring = round(spring_ratio, RATIO_DECIMALS) != 1.0
    damper = round(damper_ratio, RATIO_DECIMALS) != 1.0
    return {(False, False): '', (True, False): 'spring', (False, True): 'damper',
            (True, True): 'spring+damper'}[(spring, damper)]


class FaultDecision:
    """Declares a fault component with confirmation, clears it only on confirmed normal.

    Args:
        threshold: grouped smoothed probability a component must exceed, in (0, 1).
        hold_time_s: how long, net of its dips, a fault component must lead above it to be
            declared, s.
        dt: sample period, s.
        clear_time_s: how long normal must stay above it to clear a declared fault, s
            (default: ``hold_time_s``, the symmetric rule).
        min_deviation: ratios within this of 1 count as nominal for the decision, >= 0.
    """

    def __init__(self, threshold: float, hold_time_s: float, dt: float,
                 clear_time_s: float | None = None, min_deviation: float = 0.0) -> None:
        if not 0.0 < threshold < 1.0:
            raise ValueError(f'threshold must be in (0, 1), got {threshold}')
        clear = hold_time_s if clear_time_s is None else clear_time_s
        for name, value in (('hold_time_s', hold_time_s), ('clear_time_s', clear),
                            ('min_deviation', min_deviation)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f'{name} must be finite and >= 0, got {value}')
        self.threshold = threshold
        self.hold_samples = int(round(hold_time_s / dt))
        self.clear_samples = int(round(clear / dt))
        self.min_deviation = min_deviation
        # The grouping of each list of hypotheses seen, with and without a declared spring
        # fault (the only state it depends on): the bank's hypotheses change only when it
        # adapts, and the decision runs at every sample.
        self._groupings: dict[tuple[tuple[Hypothesis, ...], bool], Grouping] = {}
        self.reset()

    def reset(self) -> None:
        """Back to normal with nothing pending."""
        self._declared: Hypothesis = NORMAL_HYPOTHESIS
        self.forget_pending()

    def forget_pending(self) -> None:
        """Keep the declared fault, drop the evidence counted towards a change."""
        self._clearing = 0
        self._evidence = dict.fromkeys(_FAULTS, 0)

    @property
    def state(self) -> DecisionState:
        """(declared hypothesis, normal's unbroken lead, the fault components' counts): to go
        back to with :meth:`load_state`."""
        return self._declared, self._clearing, tuple(self._evidence.values())

    def load_state(self, state: DecisionState) -> None:
        """Back to a :attr:`state`."""
        self._declared, self._clearing, counts = state
        self._evidence = dict(zip(_FAULTS, counts, strict=True))

    def _decision_key(self, key: Hypothesis, spring_declared: bool) -> Hypothesis:
        """The hypothesis as the decision sees it (module docstring): near-nominal ratios
        nominal; a compound without a declared spring fault before it: damper only."""
        spring, damper = key
        if abs(spring - 1.0) < self.min_deviation + 10.0 ** -RATIO_DECIMALS:
            spring = 1.0
        if abs(damper - 1.0) < self.min_deviation + 10.0 ** -RATIO_DECIMALS:
            damper = 1.0
        if spring != 1.0 and damper != 1.0 and not spring_declared:
            spring = 1.0
        return spring, damper

    def _grouping(self, keys: Sequence[Hypothesis], declared: str) -> Grouping:
        """How ``keys`` group for the decision with the component ``declared``."""
        spring_declared = declared in ('spring', 'spring+damper')
        cache_key = (tuple(keys), spring_declared)
        grouping = self._groupings.get(cache_key)
        if grouping is None:
            order: dict[Hypothesis, int] = {}
            index = [order.setdefault(self._decision_key(key, spring_declared), len(order))
                     for key in keys]
            grouping = (index, list(order), [fault_component(*key) for key in order])
            self._groupings[cache_key] = grouping
        return grouping

    def _totals(self, grouping: Grouping, probabilities: np.ndarray) -> list[float]:
        index, group_keys, _ = grouping
        totals = [0.0] * len(group_keys)
        for group, probability in zip(index, probabilities.tolist(), strict=True):
            totals[group] += probability
        return totals

    def grouped(self, keys: Sequence[Hypothesis], probabilities: np.ndarray,
                ) -> dict[Hypothesis, float]:
        """The probabilities summed per decision hypothesis (in the order first seen)."""
        grouping = self._grouping(keys, fault_component(*self._declared))
        return dict(zip(grouping[1], self._totals(grouping, probabilities), strict=True))

    def update(self, keys: Sequence[Hypothesis], probabilities: np.ndarray) -> FaultStatus:
        """One sample: hypothesis keys (spring, damper) and their smoothed probabilities."""
        declared = fault_component(*self._declared)
        grouping = self._grouping(keys, declared)
        _, group_keys, group_components = grouping
        totals = self._totals(grouping, probabilities)
        components: dict[str, float] = {}
        for component, probability in zip(group_components, totals, strict=True):
            components[component] = components.get(component, 0.0) + probability
        best = max(components, key=components.__getitem__)
        leader = best if components[best] > self.threshold and best != declared else None
        self._clearing = self._clearing + 1 if leader == '' else 0
        for component, count in self._evidence.items():
            self._evidence[component] = count + 1 if component == leader else max(count - 1, 0)
        if (self._clearing > self.clear_samples
                or (leader and self._evidence[leader] > self.hold_samples)):
            declared = leader or ''
            self.forget_pending()
        if declared == '':
            self._declared = NORMAL_HYPOTHESIS
            return NO_FAULT
        # Sized by the most probable hypothesis of the declared component, every sample. The
        # bank may hold none for a while (the adaptive step moved the damper modes' spring
        # back near nominal, so no hypothesis is a compound): the declaration and its last
        # size stand, as through any other dip.
        carrying = [g for g, component in enumerate(group_components) if component == declared]
        if carrying:
            self._declared = group_keys[max(carrying, key=totals.__getitem__)]
        return FaultStatus(True, declared, self._declared[0], self._declared[1],
                           components.get(declared, 0.0))
