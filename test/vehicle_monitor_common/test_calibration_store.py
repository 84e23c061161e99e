"""Calibration persistence: atomic YAML round trip, corrupt files reported, never raised."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from vehicle_monitor_common.calibration_store import (
    CalibrationManager,
    load_calibration,
    save_calibration,
)


def test_round_trip_is_exact_and_leaves_no_temp_file(tmp_path: Path) -> None:
    """A saved mapping loads back equal (floats bit-exact); only the target file remains."""
    rng = np.random.default_rng(3)
    state = {'version': 1, 'method': 'vibration',
             'nominal_frequency_hz': rng.uniform(38.0, 46.0, 4).tolist(),
             'nested': {'a': [1, 2], 'b': True}}
    path = tmp_path / 'sub' / 'cal.yaml'
    assert save_calibration(path, state, comment='test\nsecond line') == ''
    loaded = load_calibration(path)
    assert loaded.exists and loaded.problem == '' and loaded.state == state
    assert path.read_text().startswith('# test\n# second line\n')
    assert sorted(os.listdir(path.parent)) == ['cal.yaml']


def test_overwrite_replaces_the_previous_content(tmp_path: Path) -> None:
    """A second save replaces the file completely."""
    path = tmp_path / 'cal.yaml'
    save_calibration(path, {'x': 1, 'old': 2})
    save_calibration(path, {'x': 3})
    assert load_calibration(path).state == {'x': 3}


def test_missing_file_is_not_a_problem(tmp_path: Path) -> None:
    """No file: no state, no problem, exists False (a first start)."""
    loaded = load_calibration(tmp_path / 'none.yaml')
    assert loaded.state is None and loaded.problem == '' and not loaded.exists


@pytest.mark.parametrize('content, match', [
    ('version: [1, 2\n', 'not valid YAML'),
    ('- just\n- a list\n', 'does not hold a mapping'),
    ('', 'does not hold a mapping'),
    (b'\xff\xfe\x00garbage', 'cannot read'),
])
def test_corrupt_file_is_reported_not_raised(tmp_path: Path, content: str | bytes,
                                             match: str) -> None:
    """Truncated YAML, a non-mapping, an empty or binary file: state None and a reason."""
    path = tmp_path / 'cal.yaml'
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    loaded = load_calibration(path)
    assert loaded.state is None and loaded.exists
    assert match in loaded.problem


def test_unwritable_target_returns_reason_and_keeps_old_file(tmp_path: Path) -> None:
    """Saving into a path whose parent is a file fails with a reason; nothing raises."""
    blocker = tmp_path / 'file'
    blocker.write_text('x')
    problem = save_calibration(blocker / 'cal.yaml', {'a': 1})
    assert 'cannot write' in problem
    assert save_calibration(tmp_path / 'c.yaml', {'a': object()}).startswith(
        'calibration state is not plain data')
    assert blocker.read_text() == 'x'


class _FakeEstimator:
    """Records the calibration calls the manager makes."""

    def __init__(self, enough: bool) -> None:
        self.enough = enough
        self.calls: list[str] = []
        self.state: dict | None = None

    def start_calibration(self) -> None:
        self.calls.append('start')

    def finish_calibration(self) -> None:
        self.calls.append('finish')
        if not self.enough:
            raise ValueError('calibration too short')
        self.state = {'value': 42.0}

    def calibration_state(self) -> dict:
        assert self.state is not None
        return self.state

    def load_calibration_state(self, state: dict) -> None:
        if state.get('value') != 42.0:
            raise ValueError('bad value')
        self.state = dict(state)


def test_manager_window_in_data_time_saves_and_reloads(tmp_path: Path) -> None:
    """The run ends after its duration of data stamps, is saved, and a new manager loads it."""
    path = str(tmp_path / 'cal.yaml')
    estimator = _FakeEstimator(enough=True)
    manager = CalibrationManager(estimator, path, 'fake')
    manager.load()
    assert manager.state == 'uncalibrated'
    assert manager.request(5.0)[0] and not manager.request(5.0)[0]
    manager.before_chunk()
    assert manager.update(100.0, 102.0) == '' and manager.calibrating
    manager.before_chunk()
    assert 'saved' in manager.update(102.0, 105.0)
    assert estimator.calls == ['start', 'finish'] and manager.state == 'calibrated'
    again = CalibrationManager(_FakeEstimator(enough=True), path, 'fake')
    again.load()
    assert again.state == 'loaded'


def test_manager_failed_run_and_rejected_file(tmp_path: Path) -> None:
    """Too little data -> 'failed'; a file the estimator rejects -> 'file_corrupt'."""
    manager = CalibrationManager(_FakeEstimator(enough=False), '', 'fake')
    manager.request(1.0)
    manager.before_chunk()
    assert 'too short' in manager.update(0.0, 2.0) and manager.state == 'failed'
    path = tmp_path / 'cal.yaml'
    save_calibration(path, {'value': 1.0})
    rejecting = CalibrationManager(_FakeEstimator(enough=True), str(path), 'fake')
    rejecting.load()
    assert rejecting.state == 'file_corrupt' and 'recalibration required' in rejecting.detail


class _SelfTimedEstimator(_FakeEstimator):
    """Counts its own window (valid data per tire): done once ``complete`` is set."""

    def __init__(self) -> None:
        super().__init__(enough=True)
        self.complete = False

    def calibration_missing(self) -> str:
        return '' if self.complete else 'FL 3.0 of 10 s of valid data'


def test_manager_self_timed_run_ends_when_the_estimator_says(tmp_path: Path) -> None:
    """A self-timed estimator's run does not end on data time alone, only once it is complete
    too (the status says what is missing); a file problem found at load is kept until a
    calibration is saved over the file."""
    path = tmp_path / 'cal.yaml'
    path.write_text('- not\n- a mapping\n')
    estimator = _SelfTimedEstimator()
    manager = CalibrationManager(estimator, str(path), 'fake')
    manager.load()
    assert manager.state == 'file_corrupt' and 'mapping' in manager.file_problem
    manager.request(1.0)
    manager.before_chunk()
    assert manager.update(0.0, 50.0) == '' and manager.state == 'calibrating'
    assert manager.detail == ('calibrating: 50.0 / 1 s of data; still missing: FL 3.0 of 10 s '
                              'of valid data')
    assert 'mapping' in manager.file_problem
    estimator.complete = True
    manager.before_chunk()
    assert 'saved' in manager.update(50.0, 51.0)
    assert estimator.calls == ['start', 'finish'] and manager.state == 'calibrated'
    assert manager.file_problem == ''


def test_manager_replace_estimator_keeps_or_drops_the_calibration(tmp_path: Path) -> None:
    """After a rebuild a calibration in force is carried over if the new estimator accepts it
    (else uncalibrated), and a running one starts over on the new estimator."""
    path = tmp_path / 'cal.yaml'
    save_calibration(path, {'value': 42.0})
    manager = CalibrationManager(_FakeEstimator(enough=True), str(path), 'fake')
    manager.load()
    kept = _FakeEstimator(enough=True)
    manager.replace_estimator(kept)
    assert manager.state == 'loaded' and kept.state == {'value': 42.0}
    refusing = _FakeEstimator(enough=True)
    refusing.load_calibration_state = _refuse  # type: ignore[method-assign]
    manager.replace_estimator(refusing)
    assert manager.state == 'uncalibrated' and 'dropped' in manager.detail
    manager.request(1.0)
    manager.before_chunk()
    manager.update(0.0, 0.5)
    fresh = _FakeEstimator(enough=True)
    manager.replace_estimator(fresh)
    manager.before_chunk()
    assert fresh.calls == ['start']
    assert 'saved' in manager.update(10.0, 11.0) and fresh.calls == ['start', 'finish']


def _refuse(state: dict) -> None:
    raise ValueError('model changed')
