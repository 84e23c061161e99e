"""What the calibrating TPMS processors (vibration, wheel radius) do the same way, ROS-free.

The vibration and wheel-radius processors differ in their inputs and in how they feed their
core; the rest is shared and lives here: the calibration contract (``CalibrationManager``: load
at start, ``calibrate_on_start`` when nothing usable was loaded, ``request_calibration`` served
as ``~/calibrate`` by the node), the indication output, the part of the status about calibration
and tires, and the time-jump bookkeeping (a confirmed jump restarts the filters, keeps the
calibration, and the status says so until every tire known before it is known again).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
import math
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from tpms_ros.core.nominal_calibration import StoredCalibrationCheck
from tpms_ros.core.tires import N_TIRES, TIRE_NAMES, TpmsIndication
from vehicle_monitor_common.calibration_store import Calibratable, CalibrationManager
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.processing import Output, ProcessorParams
from vehicle_monitor_common.status_report import StatusProblems

INDICATION_TYPE = 'vehicle_monitor_msgs/msg/TpmsIndication'
RESTART_NOTE_S = 1.0
"""A restart stays on the status at least this much data time (a status period sees it)."""


@dataclass(frozen=True)
class CalibratingTpmsParams(ProcessorParams):
    """The node-only parameters the three calibrating TPMS processors (stiffness, vibration,
    wheel radius) share, defined once: calibration and the timing of their chunked outputs."""

    calibrate_on_start: bool = param(False, 'start a calibration with the first data when no '
                                     'usable calibration file was loaded (only if tire '
                                     'pressures are known to be nominal)', read_only=True)
    calibration_file: str = param('', 'YAML file the calibration is saved to and loaded from at '
                                  'start; empty: $ROS_HOME/vehicle_monitor/calibration/'
                                  '<namespace>/<node>.yaml; none: not persisted',
                                  read_only=True)
    process_ahead_s: float = param(0.02, 'the buffered input also goes to the core this long '
                                   '(data time) before each output falls due, so little work is '
                                   'left when it does: lower output latency for one more core '
                                   'call per output, s (0: off)', low=0.0, high=10.0)
    output_phase_s: float = param(0.0, 'the first output comes this much data time later than '
                                  'otherwise, and every later one with it (the period stays): '
                                  'nodes composed in one process take different phases so that '
                                  'the work of their outputs does not coincide, s', low=0.0,
                                  high=10.0)


def offline_calibration_file(configured: str) -> str:
    """Offline (the engine), the calibration is persisted only where ``calibration_file`` names
    a file: the engine carries a vehicle's calibration from one recording to the next itself."""
    return '' if configured in ('', 'none') else configured


class ProcessAhead:
    """When a processor that answers buffered samples in chunks processes its buffer early:
    once per output, at the first sample within ``process_ahead_s`` before it falls due."""

    def __init__(self) -> None:
        self._armed = True

    def due(self, remaining_s: float, lead_s: float) -> bool:
        """True once per output, at the first sample within ``lead_s`` before it falls due."""
        if not self._armed or remaining_s <= 1e-9 or remaining_s > lead_s + 1e-9:
            return False
        self._armed = False
        return True

    def published(self) -> None:
        """An output left: the next one gets its early processing again."""
        self._armed = True


class _CoreParams(Protocol):
    @property
    def calibration_duration_s(self) -> float: ...


class _NodeParams(Protocol):
    @property
    def calibrate_on_start(self) -> bool: ...

    @property
    def calibration_file(self) -> str: ...


class _Core(Calibratable, Protocol):
    params: Any

    @property
    def calibration(self) -> Any: ...

    def indication(self, stamp_s: float) -> TpmsIndication: ...


C = TypeVar('C', bound=_CoreParams)     # the core's parameter dataclass
N = TypeVar('N', bound=_NodeParams)     # the node's own parameter dataclass
E = TypeVar('E', bound=_Core)           # the core estimator


class CalibratingTpmsProcessor(Generic[C, N, E]):
    """Base of a TPMS processor around a calibrating core (see the module docstring).

    Args:
        method: the indication's method name (``tpms/indication/<method>``, calibration label).
        params: the core's parameters, handed to the core as they are.
        node_params: the processor's own parameters (``calibrate_on_start`` among them).
        make_core: builds the core estimator from the core parameters.
        calibration_file: where the calibration is kept (resolved; '' = not persisted).
    """

    def __init__(self, method: str, params: C, node_params: N, make_core: Callable[[C], E],
                 calibration_file: str) -> None:
        self.method = method
        self.indication_topic = f'tpms/indication/{method}'
        self.params = params
        self.node_params = node_params
        self.core = make_core(params)
        self.calibration_file = calibration_file
        self.events: list[str] = []     # calibration events for the node's log
        self._last_publish_s = -math.inf
        self._ahead = ProcessAhead()
        self._last_stamp_s = math.nan
        self._last_known = np.zeros(N_TIRES, dtype=bool)
        self._last_flags = np.zeros(N_TIRES, dtype=bool)
        self.time_jumps = 0
        self._last_jump_s = 0.0
        self._restarted = False
        self._restart_reason = ''
        self._restart_at_s = math.nan
        self._known_at_jump = np.zeros(N_TIRES, dtype=bool)
        self._calibration = CalibrationManager(self.core, calibration_file, method)
        self._calibration.load()
        if self._calibration.state == 'file_corrupt':
            self.events.append(self._calibration.detail)
        # Only when nothing usable was loaded, so a restart keeps what was learned.
        if node_params.calibrate_on_start and self._calibration.state != 'loaded':
            self._calibration.request(self._calibration_duration_s())

    # -- parameters and calibration ----------------------------------------------------------

    def set_params(self, params: C) -> None:
        """New method parameters: only those the core reads per call can change (the rest are
        read-only), so the core takes them as they are."""
        self.params = params
        self.core.params = params

    def set_node_params(self, node_params: N) -> None:
        """New node parameters take effect at once."""
        self.node_params = node_params

    def _calibration_duration_s(self) -> float:
        return float(self.params.calibration_duration_s)

    @property
    def calibration(self) -> CalibrationManager:
        """The calibration manager (state, detail, file problem)."""
        return self._calibration

    def request_calibration(self) -> tuple[bool, str]:
        """Learn the nominal over the next ``calibration_duration_s`` of data."""
        return self._calibration.request(self._calibration_duration_s())

    def calibration_state(self) -> dict[str, Any] | None:
        """The calibration in force as plain data (None: uncalibrated)."""
        if self.core.calibration is None:
            return None
        return self.core.calibration_state()

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        """Put a stored calibration in force; ValueError when it does not fit."""
        self._calibration.put_in_force(state)

    def _calibration_event(self, first_s: float, last_s: float) -> None:
        event = self._calibration.update(first_s, last_s)
        if event:
            self.events.append(event)

    # -- time jumps ----------------------------------------------------------------------------

    def _note_jump(self, jump_s: float) -> None:
        """A confirmed time jump: output timing restarts on the new time line, a running
        calibration window starts again (the calibration in force is kept)."""
        self.time_jumps += 1
        self._last_jump_s = jump_s
        self._note_restart(f'time jump of {jump_s:+.3g} s')
        self._last_publish_s = -math.inf
        self._ahead.published()

    def _note_restart(self, why: str) -> None:
        """The subclass restarted its core's filters (``why``: a time jump, a gap, the input
        rate back to normal): a running calibration window starts again, and the status says
        so until every tire known before is known again."""
        self._restarted = True
        self._restart_reason = why
        self._restart_at_s = math.nan
        self._known_at_jump = self._last_known.copy()
        self._calibration.restart()

    def _follow_restart(self, stamp_s: float) -> None:
        # The restart note stays until every tire known before the jump is known again, and
        # RESTART_NOTE_S at least.
        if not self._restarted:
            return
        if math.isnan(self._restart_at_s):
            self._restart_at_s = stamp_s
        if (np.all(self._last_known | ~self._known_at_jump)
                and stamp_s - self._restart_at_s >= RESTART_NOTE_S):
            self._restarted = False

    # -- output and status -----------------------------------------------------------------------

    def _indication_output(self, stamp_ns: int, indication: TpmsIndication,
                           known: np.ndarray) -> Output:
        """The core's indication with the tires ``known`` (a tire not known is never flagged
        and has confidence 0); kept for the status."""
        self._last_known = known.copy()
        self._last_flags = indication.underinflated & known
        self._follow_restart(stamp_ns * 1e-9)
        return Output(self.indication_topic, stamp_ns, {
            'method': self.method,
            'underinflated': (indication.underinflated & known).tolist(),
            'confidence': np.where(known, indication.confidence, 0.0).tolist(),
            'known': known.tolist(),
        })

    def _tire_status(self, received: bool) -> tuple[dict[str, Any], StatusProblems]:
        """Status values and problems about calibration, tires and time jumps."""
        cal = self._calibration
        low = [TIRE_NAMES[i] for i in np.flatnonzero(self._last_flags)]
        values: dict[str, Any] = {
            'known': self._last_known.tolist(),
            'calibration_state': cal.state,
            'calibration': cal.detail,
            'calibration_file': self.calibration_file or '(not persisted)',
            'low_tires': low,
            'last_stamp_s': self._last_stamp_s,
            'time_jumps': self.time_jumps,
        }
        problems = StatusProblems()
        if cal.file_problem:
            values['calibration_file_problem'] = cal.file_problem
        if cal.state == 'refused':
            problems.error(cal.detail)
        elif cal.state in ('file_corrupt', 'failed', 'uncalibrated', 'calibrating'):
            problems.warn(cal.detail)
        elif received and not self._last_known.all():
            unknown = [TIRE_NAMES[i] for i in np.flatnonzero(~self._last_known)]
            problems.warn(f'tires unknown: {", ".join(unknown)}')
        if self._restarted:
            problems.warn(f'{self._restart_reason}: filters restarted (calibration kept), '
                          'estimating again once converged')
        if self._last_flags.any():
            problems.warn(f'low tires indicated: {", ".join(low)}')
        return values, problems


def follow_calibration_check(manager: CalibrationManager, check: StoredCalibrationCheck,
                             recalibrate_s: float | None) -> str:
    """After a chunk: when the core has just refused the stored calibration in force (made
    on other tires), the manager says so and, with ``recalibrate_s`` (the node's
    ``calibrate_on_start``), starts the recalibration the refusal asks for. Returns the event
    for the node's log ('' when nothing happened). Call it after the manager's ``update`` of
    the chunk, so a new run starts with the next chunk."""
    if not check.misfit or manager.state != 'loaded':
        return ''
    return manager.refuse(check.misfit, recalibrate_s)


P = TypeVar('P', bound=CalibratingTpmsProcessor[Any, Any, Any])


def from_parameters(processor: Callable[[C, N, str], P]) -> Callable[[C, N], P]:
    """How the node and the offline engine build a calibrating processor (its
    ``ProcessorSpec``'s ``make``): from the method's and the node's parameters, with the
    calibration file ``calibration_file`` names, if any (the node resolves an empty one to its
    own file first)."""
    def make(params: C, node_params: N) -> P:
        return processor(params, node_params,
                         offline_calibration_file(node_params.calibration_file))
    return make
