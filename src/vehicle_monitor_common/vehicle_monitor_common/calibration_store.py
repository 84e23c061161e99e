"""Persistence of calibration state: a plain dict as a YAML file, written atomically.

Shared by every node that learns a calibration (nominal tire resonances, radius offsets,
stiffness). The nodes must survive whatever they find on disk: a missing file is a first start,
an unreadable or corrupt one is reported with its reason and ignored (the node then runs
uncalibrated and asks for a recalibration), never an exception out of a callback. Writes go to a
temporary file in the same directory, are flushed to disk and then renamed over the target with
``os.replace``, so a crash or power loss mid-write leaves the previous file intact, never a
half-written one.

Whether the *content* is a valid calibration is the estimator's business (its
``load_calibration_state`` raises ValueError); this module only guarantees a mapping.
"""

from __future__ import annotations

from collections.abc import Mapping
import contextlib
from dataclasses import dataclass
import os
from pathlib import Path
import tempfile
from typing import Any, Protocol, runtime_checkable

import yaml


@dataclass(frozen=True)
class LoadedCalibration:
    """Outcome of :func:`load_calibration`.

    Attributes:
        state: the stored mapping, or None (no file, or a problem).
        problem: why the file could not be used ('' when it loaded or did not exist).
        exists: a file was found at the path.
    """

    state: dict[str, Any] | None
    problem: str
    exists: bool


def resolve_path(path: str | os.PathLike[str]) -> Path:
    """The calibration path with ``~`` and environment variables expanded."""
    return Path(os.path.expandvars(os.path.expanduser(os.fspath(path))))


def load_calibration(path: str | os.PathLike[str]) -> LoadedCalibration:
    """Read a calibration mapping from a YAML file; never raises.

    Args:
        path: the file; ``~`` and ``$VARS`` are expanded.

    Returns:
        The mapping, or the reason it is unusable (unreadable, not YAML, not a mapping).
        A missing file is not a problem: ``state`` None, ``problem`` '', ``exists`` False.
    """
    file = resolve_path(path)
    if not file.exists():
        return LoadedCalibration(None, '', False)
    try:
        text = file.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as exc:
        return LoadedCalibration(None, f'cannot read {file}: {exc}', True)
    try:
        state = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        return LoadedCalibration(None, f'{file} is not valid YAML: {first}', True)
    if not isinstance(state, Mapping):
        return LoadedCalibration(
            None, f'{file} does not hold a mapping (got {type(state).__name__})', True)
    return LoadedCalibration(dict(state), '', True)


def save_calibration(path: str | os.PathLike[str], state: Mapping[str, Any],
                     comment: str = '') -> str:
    """Write ``state`` as YAML atomically (temp file, fsync, ``os.replace``); never raises.

    Args:
        path: the target file; missing parent directories are created.
        state: plain data (str, int, float, bool, lists and mappings of these).
        comment: optional text written as ``#`` comment lines at the top.

    Returns:
        '' on success, else the reason the file was not written (the previous file, if any,
        is left untouched).
    """
    file = resolve_path(path)
    try:
        text = yaml.safe_dump(dict(state), sort_keys=False, default_flow_style=None)
    except (yaml.YAMLError, TypeError, ValueError) as exc:
        return f'calibration state is not plain data: {exc}'
    if comment:
        text = ''.join(f'# {line}\n' for line in comment.splitlines()) + text
    tmp_name = ''
    try:
        file.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f'.{file.name}.', suffix='.tmp', dir=file.parent)
        with os.fdopen(fd, 'w', encoding='utf-8') as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp_name, file)
        tmp_name = ''
    except OSError as exc:
        return f'cannot write {file}: {exc}'
    finally:
        if tmp_name:
            with contextlib.suppress(OSError):
                os.unlink(tmp_name)
    return ''


class Calibratable(Protocol):
    """What a calibrating estimator offers (the TPMS cores' method names).

    By default the calibration window is data time, counted by :class:`CalibrationManager`; an
    estimator that also counts valid data itself offers ``calibration_missing``
    (:class:`SelfTimedCalibratable`): its window goes on, collecting valid data as it comes,
    until nothing is missing.
    """

    def start_calibration(self) -> None:
        """Start learning from the data processed from now on."""

    def finish_calibration(self) -> Any:
        """Put the learned calibration in force; ValueError when there was not enough data."""

    def calibration_state(self) -> dict[str, Any]:
        """The calibration in force as plain data."""

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Put a persisted calibration in force; ValueError when it is corrupt."""


@runtime_checkable
class SelfTimedCalibratable(Calibratable, Protocol):
    """A calibrating estimator that decides itself when its run has enough valid data."""

    def calibration_missing(self) -> str:
        """What the running calibration still lacks, for the status ('' when complete)."""


class CalibrationManager:
    """Runs an estimator's calibration over a window of *data* time and persists the result.

    The window is measured on the stamps of the processed input, not on a clock, so a replay at
    any speed (or with ``use_sim_time``) calibrates on the same data. No ROS import: the node
    wires :meth:`request` to its ``~/calibrate`` service and calls :meth:`update` after each
    processed chunk.

    States: ``uncalibrated``, ``loaded`` (from the file), ``calibrating``, ``calibrated`` (by a
    run in this process), ``failed`` (the last run had too little valid data; the previous
    calibration, if any, stays in force), ``file_corrupt`` (the file was unusable: the node runs
    uncalibrated and a recalibration is required), ``refused`` (a loaded calibration that the
    estimator found not to fit the data, e.g. made on other tires: the node runs uncalibrated
    and a recalibration is required). Why the file was unusable or refused stays in
    :attr:`file_problem` until a calibration is saved over it, whatever the state.

    The run ends after ``duration_s`` of data; for a :class:`SelfTimedCalibratable` not before
    the estimator says it has collected enough valid data either (an ordinary drive with stops,
    curves and speed changes: the window goes on, and the status says what is still missing).
    """

    def __init__(self, estimator: Calibratable, path: str, label: str) -> None:
        self._estimator = estimator
        self.path = path
        self._label = label
        self.state = 'uncalibrated'
        self.detail = 'no calibration: call ~/calibrate with nominal tire pressures'
        self.save_problem = ''
        self.file_problem = ''
        self._duration_s = 0.0
        self._start_s: float | None = None
        self._pending = False

    @property
    def calibrating(self) -> bool:
        """A run was requested or is in progress."""
        return self._pending

    def load(self) -> None:
        """Load the file at ``path`` (if set) into the estimator; problems go to ``detail``."""
        if not self.path:
            return
        loaded = load_calibration(self.path)
        if loaded.state is None:
            if loaded.problem:
                self.state = 'file_corrupt'
                self.file_problem = loaded.problem
                self.detail = (f'calibration file unusable ({loaded.problem}): running '
                               'uncalibrated, recalibration required (~/calibrate)')
            return
        try:
            self._estimator.load_calibration_state(loaded.state)
        except ValueError as exc:
            self.state = 'file_corrupt'
            self.file_problem = f'{self.path} rejected: {exc}'
            self.detail = (f'calibration file {self.path} rejected ({exc}): running '
                           'uncalibrated, recalibration required (~/calibrate)')
            return
        self.state = 'loaded'
        self.detail = f'calibration loaded from {self.path}'

    def put_in_force(self, state: Mapping[str, Any]) -> None:
        """Put a calibration kept elsewhere than the file in force (the fleet job's per-vehicle
        chain); ValueError, and nothing changed, when the estimator refuses it."""
        self._estimator.load_calibration_state(state)
        self.state = 'loaded'
        self.detail = 'calibration loaded'

    def refuse(self, why: str, recalibrate_s: float | None) -> str:
        """The estimator dropped the loaded calibration as not fitting the data (``why``);
        with ``recalibrate_s`` a new run over that much data is requested at once (it starts
        with the next chunk). Returns the event for the node's log."""
        self.state = 'refused'
        self.file_problem = why
        self.detail = f'{why}: not used, recalibrate at nominal tire pressures (~/calibrate)'
        event = self.detail
        if recalibrate_s is not None:
            self.request(recalibrate_s)
        return event

    def request(self, duration_s: float) -> tuple[bool, str]:
        """Ask for a calibration over the next ``duration_s`` of data; (accepted, message)."""
        if self._pending:
            return False, f'{self._label}: a calibration is already running'
        self._pending = True
        self._duration_s = duration_s
        self._start_s = None
        self.state = 'calibrating'
        self.detail = f'calibration requested over {duration_s:g} s of data'
        return True, f'{self._label}: calibration started over {duration_s:g} s of data'

    def before_chunk(self) -> None:
        """Call before processing a chunk: a requested run starts on the estimator here."""
        if self._pending and self._start_s is None:
            self._estimator.start_calibration()

    def update(self, first_stamp_s: float, last_stamp_s: float) -> str:
        """Call after processing a chunk spanning these stamps; returns an event or ''."""
        if not self._pending:
            return ''
        if self._start_s is None:
            self._start_s = first_stamp_s
        elapsed = last_stamp_s - self._start_s
        missing = (self._estimator.calibration_missing()
                   if isinstance(self._estimator, SelfTimedCalibratable) else '')
        if elapsed < self._duration_s or missing:
            self.detail = f'calibrating: {elapsed:.1f} / {self._duration_s:g} s of data'
            if missing:
                self.detail += f'; still missing: {missing}'
            return ''
        self._pending = False
        try:
            self._estimator.finish_calibration()
        except ValueError as exc:
            self.state = 'failed'
            self.detail = f'calibration failed: {exc}'
            return self.detail
        self.state = 'calibrated'
        self.detail = 'calibrated'
        if self.path:
            self.save_problem = save_calibration(
                self.path, self._estimator.calibration_state(),
                comment=f'{self._label} calibration (written by the node; delete to forget)')
            self.detail = (f'calibrated, NOT saved: {self.save_problem}' if self.save_problem
                           else f'calibrated, saved to {self.path}')
            if not self.save_problem:
                self.file_problem = ''
        return self.detail

    def replace_estimator(self, estimator: Calibratable) -> None:
        """The node rebuilt its estimator (new parameters): a running calibration starts over
        on the new one, a calibration in force is carried over if the new one accepts it."""
        old, self._estimator = self._estimator, estimator
        if self._pending:
            self._start_s = None
        elif self.state in ('loaded', 'calibrated'):
            try:
                estimator.load_calibration_state(old.calibration_state())
                self.detail += ' (kept across a parameter change)'
            except ValueError as exc:
                self.state = 'uncalibrated'
                self.detail = (f'calibration dropped by a parameter change ({exc}): '
                               'recalibration required (~/calibrate)')

    def restart(self) -> None:
        """The estimator restarted its filters (data gap): a running window starts again."""
        if self._pending:
            self._start_s = None
