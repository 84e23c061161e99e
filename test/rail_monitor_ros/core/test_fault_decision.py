"""The suspension IMM's fault decision: threshold, hold time, symmetric clearing."""

from __future__ import annotations

import numpy as np

from rail_monitor_ros.core.fault_decision import FaultDecision


def test_fault_decision_holds_and_clears_symmetrically() -> None:
    """Declared after the hold time above threshold; cleared the same way by normal."""
    decision = FaultDecision(0.6, hold_time_s=0.05, dt=0.01)
    keys = [(1.0, 1.0), (1.5, 1.0)]
    fault = np.array([0.2, 0.8])
    normal = np.array([0.8, 0.2])
    states = [decision.update(keys, fault).detected for _ in range(7)]
    assert states == [False] * 5 + [True] * 2
    assert decision.update(keys, fault).component == 'spring'
    states = [decision.update(keys, normal).detected for _ in range(7)]
    assert states == [True] * 5 + [False] * 2
