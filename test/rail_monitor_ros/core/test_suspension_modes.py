"""The suspension IMM's mode set (the paper's numbering) and Markov transition matrix."""

from __future__ import annotations

import numpy as np
import pytest

from rail_monitor_ros.core.suspension_modes import generate_mode_set, markov_transition_matrix


def test_mode_set_is_generated_with_the_papers_numbering() -> None:
    """Default config: 16 modes, 1 normal, 2-8 spring 110..170 %, 9-16 damper 100..30 %."""
    modes = generate_mode_set()
    assert len(modes) == 16
    assert [m.number for m in modes] == list(range(1, 17))
    assert modes[0].name == 'normal' and modes[0].kind == 'normal'
    assert [m.name for m in modes[1:8]] == [f'spring_{p}' for p in range(110, 171, 10)]
    assert [m.name for m in modes[8:]] == [f'damper_{p}' for p in range(100, 29, -10)]
    assert modes[5].name == 'spring_150' and modes[5].number == 6       # the paper's mode 6
    assert modes[13].name == 'damper_50' and modes[13].number == 14     # the paper's mode 14
    assert len(generate_mode_set(1.2, 2.0, 0.2, 0.8, 0.4, 0.2)) == 1 + 5 + 3


@pytest.mark.parametrize('n, tau, dt', [(16, 10.0, 0.005), (3, 0.1, 0.01), (2, 1.0, 0.5)])
def test_transition_matrix_rows_are_from_mode_and_sum_to_one(n: int, tau: float,
                                                             dt: float) -> None:
    """Pi[i, j] = P(j | i): rows sum to 1, the diagonal is 1 - dt / tau."""
    pi = markov_transition_matrix(n, tau, dt)
    np.testing.assert_allclose(pi.sum(axis=1), 1.0, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.diag(pi), 1.0 - dt / tau)
    assert np.all(pi > 0.0)
