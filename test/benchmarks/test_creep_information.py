"""The spectral machinery of the creep factor's Cramér-Rao bound (benchmarks/creep_information.py,
benchmarks/imm_detection_limit.py): output spectra that integrate to the outputs' covariance, and
Whittle's Fisher information where it is known in closed form."""

from __future__ import annotations

from dataclasses import replace
import importlib
import math
from pathlib import Path
import sys

import numpy as np
import pytest
import scipy.linalg

from rail_monitor_ros.core.suspension_imm import ModeModel
from rail_monitor_ros.simulation.rail_family import (
    HELD_OUT_SEEDS,
    SPEED_RANGE,
    family,
    sample_speeds,
)

BENCHMARKS = Path(__file__).resolve().parents[2] / 'benchmarks'
sys.path.insert(0, str(BENCHMARKS))    # the scripts import each other beside them
creep = importlib.import_module('creep_information')
limit = importlib.import_module('imm_detection_limit')
evaluation = importlib.import_module('eval_rail_family')


def test_the_output_spectrum_integrates_to_the_outputs_covariance() -> None:
    """A stable three-state model with a lightly damped pair: (1 / 2 pi) int S over
    (-pi, pi] is H P H^T + R, P the state's stationary covariance."""
    rng = np.random.default_rng(3)
    rotation = 0.98 * np.array([[math.cos(0.3), -math.sin(0.3)], [math.sin(0.3), math.cos(0.3)]])
    f = scipy.linalg.block_diag(rotation, [[0.5]])
    q = np.diag([1.0, 0.5, 2.0])
    h = rng.normal(size=(2, 3))
    r = np.diag([0.1, 0.2])
    spectrum = limit.OutputSpectrum(ModeModel(f, q, {}), h, r)
    omegas = limit.frequency_grid(spectrum.poles)
    s = spectrum.at(omegas)
    covariance = h @ scipy.linalg.solve_discrete_lyapunov(f, q) @ h.T + r
    # S(-omega) is the conjugate of S(omega): twice the real part over (0, pi]
    integral = np.trapezoid(np.real(s), omegas, axis=0) / math.pi
    np.testing.assert_allclose(integral, covariance, rtol=1e-3)


@pytest.mark.parametrize('a', [0.3, 0.9, 0.99])
def test_whittle_gives_the_ar1_coefficients_information(a: float) -> None:
    """y' = a y + w observed exactly: the Fisher information about a is 1 / (1 - a^2) per
    sample."""
    def spectrum(coefficient: float) -> limit.OutputSpectrum:
        return limit.OutputSpectrum(ModeModel(np.array([[coefficient]]), np.eye(1), {}),
                                    np.eye(1), np.zeros((1, 1)))

    centre = spectrum(a)
    omegas = limit.frequency_grid(centre.poles)
    step = 1e-5
    derivative = (spectrum(a + step).at(omegas) - spectrum(a - step).at(omegas)) / (2 * step)
    information = creep.whittle_information(centre.at(omegas), [derivative], omegas)
    assert information[0, 0] == pytest.approx(1.0 / (1.0 - a * a), rel=1e-3)


@pytest.fixture(scope='module')
def held_out_case():
    car = family(HELD_OUT_SEEDS)[1]
    return car, sample_speeds(car, 2, *SPEED_RANGE)[0]


def test_the_wheelbase_delay_carries_information_without_a_track(held_out_case) -> None:
    """Pattern D without a track: independent wheelset alignments carry less about c than the
    same alignment reaching the wheelsets a wheelbase apart (held-out car 190002 at 23.5 m/s:
    about 30 times less)."""
    car, speed = held_out_case
    delayed = creep.fisher_rate(car, speed, 0.75, 'D/none')
    independent = creep.fisher_rate(car, speed, 0.75, 'D/none', 'independent')
    assert 0.0 < independent < delayed / 10.0
    with pytest.raises(ValueError):
        creep.fisher_rate(car, speed, 0.75, 'C/exact', 'independent')


@pytest.mark.parametrize('model, names', [
    ('end', ('lateral_accel_process_std_mps2', 'yaw_accel_process_std_rad_s2',
             'body_accel_process_std_mps2', 'other_bogie_force_std_n',
             'other_bogie_moment_std_nm')),
    ('full', ('full_car_process_std',))])
def test_the_ekfs_information_falls_as_its_model_errors_grow(held_out_case, model: str,
                                                             names: tuple[str, ...]) -> None:
    """The creep EKF's own model, pattern C with the exact track: ten times its model-error
    noise leaves less information than as shipped, a tenth more (each model's own noise)."""
    car, speed = held_out_case
    shipped = replace(evaluation.creep_params(car, speed, 'C-spec/exact', 'spectrum'),
                      model=model)

    def scaled(factor: float) -> float:
        params = replace(shipped, **{n: getattr(shipped, n) * factor for n in names})
        return creep.estimator_fisher_rate(params, 0.75, 4)

    assert 0.0 < scaled(10.0) < scaled(1.0) < scaled(0.1)
