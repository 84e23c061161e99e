"""The ideal test and the information rate of benchmarks/imm_detection_limit.py: the rate is the
mean log-likelihood ratio the filters actually gain on data drawn from the model, and the
ideal test's delay is the first sample its posterior on the correct hypotheses passes 0.5."""

from __future__ import annotations

import importlib
import math
from pathlib import Path
import sys

import numpy as np
import pytest

BENCHMARKS = Path(__file__).resolve().parents[2] / 'benchmarks'
sys.path.insert(0, str(BENCHMARKS))    # the script imports eval_rail_family beside it
limit = importlib.import_module('imm_detection_limit')


def test_the_ideal_delay_is_the_first_sample_the_correct_posterior_passes_a_half() -> None:
    """Three hypotheses, the correct one gaining 0.1 nat a sample from the onset: its posterior
    e^(0.1 k) / (e^(0.1 k) + 2) passes 0.5 at the seventh sample after the onset."""
    log_lik = np.zeros((30, 3))
    log_lik[10:, 1] = 0.1
    log_lik[:10, 0] = 5.0          # before the onset: not counted
    correct = np.array([False, True, False])
    assert limit.ideal_delay(log_lik, 10, correct, 0.005) == pytest.approx(6 * 0.005)
    assert limit.ideal_delay(log_lik[:15], 10, correct, 0.005) == math.inf


@pytest.fixture(scope='module')
def imm():
    car = limit.family(limit.DEVELOPMENT_SEEDS)[1]
    return limit.SuspensionImm(limit.imm_params(car, 40.0))


def test_the_information_rate_is_the_log_likelihood_ratio_gained_on_model_draws(imm) -> None:
    """On six records of 60 s drawn from the nominal model, the nominal filter gains over the
    spring-110 % filter what the spectral computation says (each record's mean wanders by about
    15 % with the car's slow modes, their average within 10 %); a model against itself gains
    nothing."""
    known = imm._known_sizes[-1]
    nominal, spring = (1.0, 1.0), (1.1, 1.0)
    rate = limit.hypothesis_information(imm, nominal, spring, known)
    assert abs(limit.hypothesis_information(imm, nominal, nominal, known)) < 1e-4 * rate
    bank = limit.FilterBank(imm, [nominal, spring], known)
    gained = []
    for seed in range(6):
        record = limit.model_record(imm, nominal, known, 13000, 1, np.random.default_rng(seed))
        log_lik = bank.log_likelihoods(record, 0, 0)[1000:]    # each on its own, settled
        gained.append(float(np.mean(log_lik[:, 0] - log_lik[:, 1])))
    assert np.mean(gained) * imm.params.sample_rate_hz == pytest.approx(rate, rel=0.1)


def test_the_information_of_a_vehicle_from_its_params_file() -> None:
    """The shipped suspension_monitor.yaml: at 30 m/s four rates, each larger with an exact
    track than with the map's stated accuracy; at 150 m/s the car hunts."""
    params_file = (Path(__file__).resolve().parents[2] / 'src' / 'rail_monitor_ros' / 'config'
                   / 'suspension_monitor.yaml')
    header, _, row = limit.vehicle_information_table(str(params_file), '/suspension_monitor',
                                                     [30.0, 150.0])
    assert header == '| 30 m/s | 150 m/s |'
    at_30, at_150 = (cell.strip() for cell in row.strip('|').split('|'))
    with_map, exact = (tuple(float(v) for v in side.split(',')) for side in at_30.split('/'))
    assert all(0.0 < m < e for m, e in zip(with_map, exact, strict=True))
    assert at_150 == 'unstable'


def test_a_params_file_that_cannot_be_used_is_one_line(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    """A missing file and a refused value: exit status 2 and one line naming the problem."""
    refused = tmp_path / 'car.yaml'
    refused.write_text('/**:\n  ros__parameters:\n    vehicle:\n      speed: -5.0\n')
    for path, says in ((tmp_path / 'missing.yaml', 'cannot read params file'),
                       (refused, 'speed must be > 0')):
        with pytest.raises(SystemExit) as exited:
            limit.main(['--information', '30', '--params-file', str(path)])
        assert exited.value.code == 2
        error = capsys.readouterr().err
        assert says in error and error.count('\n') == 1
