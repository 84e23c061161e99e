"""The IMM's suspension modes: the mode set (normal, spring and damper ratios on a grid) and
the Markov transition matrix between them (Mori, Tsunashima, Marumo). No ROS import."""

from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

from rail_monitor_ros.core.rail_model import MAX_SUSPENSION_RATIO

MODE_KINDS = ('normal', 'spring', 'damper')
# Ratios on the mode grid are compared after rounding to this many decimals (0.1 steps are not
# exact in binary).
RATIO_DECIMALS = 6


@dataclass(frozen=True)
class SuspensionMode:
    """One IMM mode: a secondary lateral spring and damper ratio hypothesis.

    Attributes:
        name: 'normal', 'spring_150', 'damper_50' (percent of nominal).
        kind: one of :data:`MODE_KINDS`.
        spring_ratio: Ksy / nominal of the mode as generated (damper modes: 1; the adaptive
            step moves their spring ratio at run time).
        damper_ratio: Csy / nominal.
        number: the paper's mode number (1 normal, 2-8 spring, 9-16 damper by default).
    """

    name: str
    kind: str
    spring_ratio: float
    damper_ratio: float
    number: int


def _ratio_grid(start: float, stop: float, step: float, name: str) -> tuple[float, ...]:
    """Ratios from start to stop (inclusive, either direction) in steps of |step|."""
    for key, value in ((f'{name}_start', start), (f'{name}_stop', stop), (f'{name}_step', step)):
        if not math.isfinite(value):
            raise ValueError(f'{key} must be finite, got {value}')
    if step <= 0.0:
        raise ValueError(f'{name}_step must be > 0, got {step}')
    for key, value in ((f'{name}_start', start), (f'{name}_stop', stop)):
        if not 0.0 < value <= MAX_SUSPENSION_RATIO:
            raise ValueError(f'{key} must be in (0, {MAX_SUSPENSION_RATIO}], got {value}')
    count = int(math.floor(abs(stop - start) / step + 1e-9)) + 1
    direction = 1.0 if stop >= start else -1.0
    return tuple(round(start + direction * k * step, RATIO_DECIMALS) for k in range(count))


def generate_mode_set(spring_start: float = 1.1, spring_stop: float = 1.7,
                      spring_step: float = 0.1, damper_start: float = 1.0,
                      damper_stop: float = 0.3, damper_step: float = 0.1,
                      ) -> tuple[SuspensionMode, ...]:
    """The mode set: normal, then spring modes, then damper modes (the paper's numbering).

    Defaults give the paper's 16 modes: 1 normal; 2-8 spring 110 ... 170 %; 9-16 damper
    100 ... 30 %. A damper mode at 100 % is kept: with the adaptive step it carries the
    estimated spring ratio (spring-only hypothesis at that ratio).

    Raises:
        ValueError: a non-finite, non-positive or out-of-range bound or step (named).
    """
    springs = _ratio_grid(spring_start, spring_stop, spring_step, 'spring')
    dampers = _ratio_grid(damper_start, damper_stop, damper_step, 'damper')
    modes = [SuspensionMode('normal', 'normal', 1.0, 1.0, 1)]
    for ratio in springs:
        modes.append(SuspensionMode(f'spring_{round(100 * ratio)}', 'spring', ratio, 1.0,
                                    len(modes) + 1))
    for ratio in dampers:
        modes.append(SuspensionMode(f'damper_{round(100 * ratio)}', 'damper', 1.0, ratio,
                                    len(modes) + 1))
    names = [m.name for m in modes]
    if len(set(names)) != len(names):
        raise ValueError(f'mode set has duplicate names: {names}')
    return tuple(modes)


def markov_transition_matrix(n_modes: int, mean_sojourn_time_s: float, dt: float) -> np.ndarray:
    """Mode transition matrix Pi: Pi[i, j] = P(mode j at k+1 | mode i at k); rows sum to 1.

    A mode is left with probability dt / tau per step (mean sojourn time tau, geometric), to
    any other mode alike (the paper gives no prior on which fault follows which).

    Args:
        n_modes: number of modes, >= 2.
        mean_sojourn_time_s: tau, s, > dt.
        dt: sample period, s.
    """
    if n_modes < 2:
        raise ValueError(f'n_modes must be >= 2, got {n_modes}')
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be finite and > 0, got {dt}')
    if not (math.isfinite(mean_sojourn_time_s) and mean_sojourn_time_s > dt):
        raise ValueError(f'mean_sojourn_time_s must be finite and > dt = {dt}, '
                         f'got {mean_sojourn_time_s}')
    leave = dt / mean_sojourn_time_s
    matrix = np.full((n_modes, n_modes), leave / (n_modes - 1))
    np.fill_diagonal(matrix, 1.0 - leave)
    return matrix
