"""What every TPMS node whose core calibrates does the same way, written once.

The vibration and wheel-radius nodes differ in their inputs and in how they feed their core;
the rest is shared and lives here: the method's parameters declared from the core's ``*Params``
dataclass (handed to the core as they are) beside the node's own ``*NodeParams``, the
calibration contract (``CalibrationManager``: load at start, ``calibrate_on_start``, the
``~/calibrate`` service), the indication output, and the part of the diagnostics about
calibration and tires. A subclass builds its core from :attr:`core_parameters`, subscribes
its inputs and calls :meth:`_start_diagnostics` last.
"""

from __future__ import annotations

from collections.abc import Callable
import math
from typing import Any, Generic, Protocol, TypeVar

from builtin_interfaces.msg import Time
import numpy as np
from rclpy.node import Node
from std_srvs.srv import Trigger
from vehicle_monitor_msgs.msg import TpmsIndication as IndicationMsg

from tpms_ros.core.tires import N_TIRES, TIRE_NAMES, TpmsIndication
from vehicle_monitor_common.calibration_store import Calibratable, CalibrationManager
from vehicle_monitor_common.node_helpers import (
    OUTPUT_QOS,
    WARN,
    Diagnostics,
    ProcessAhead,
    TypedParameters,
)


class _CoreParams(Protocol):
    @property
    def calibration_duration_s(self) -> float: ...


class _NodeParams(Protocol):
    @property
    def calibrate_on_start(self) -> bool: ...

    @property
    def calibration_file(self) -> str: ...

    @property
    def diagnostics_period_s(self) -> float: ...


class _Core(Calibratable, Protocol):
    params: Any

    def indication(self, stamp_s: float) -> TpmsIndication: ...


C = TypeVar('C', bound=_CoreParams)     # the core's parameter dataclass
N = TypeVar('N', bound=_NodeParams)     # the node's own parameter dataclass
E = TypeVar('E', bound=_Core)           # the core estimator


class CalibratingTpmsNode(Node, Generic[C, N, E]):
    """Base of a TPMS node around a calibrating core (see the module docstring).

    Args:
        node_name: ROS node name.
        method: the indication's method name (``tpms/indication/<method>``, calibration label).
        core_params: the core's parameter dataclass (its fields are ROS parameters); it has
            ``calibration_duration_s``.
        node_params: the node-only parameter dataclass; it has ``calibrate_on_start``,
            ``calibration_file`` and ``diagnostics_period_s``.
        make_core: builds the core estimator from the core parameters.
    """

    def __init__(self, node_name: str, method: str, core_params: type[C], node_params: type[N],
                 make_core: Callable[[C], E], **kwargs: Any) -> None:
        super().__init__(node_name, **kwargs)
        self._method = method
        self._core_params = TypedParameters(self, core_params, on_change=self._on_core_change)
        self._typed = TypedParameters(self, node_params, on_change=self._on_change)
        self._analyzer = make_core(self._core_params.value)
        self._last_publish_s = -math.inf
        self._ahead = ProcessAhead()
        self._last_stamp_s = math.nan
        self._last_known = np.zeros(N_TIRES, dtype=bool)
        self._last_flags = np.zeros(N_TIRES, dtype=bool)

        p = self._typed.value
        self._calibration = CalibrationManager(self._analyzer, p.calibration_file, method)
        self._calibration.load()
        if self._calibration.state == 'file_corrupt':
            self.get_logger().warning(self._calibration.detail)
        if p.calibrate_on_start:
            self._calibration.request(self._calibration_duration_s())
        self._indication_pub = self.create_publisher(
            IndicationMsg, f'tpms/indication/{method}', OUTPUT_QOS)
        self.create_service(Trigger, '~/calibrate', self._on_calibrate)

    def _start_diagnostics(self) -> None:
        """Start the /diagnostics timer (the subclass's state is complete by now)."""
        period_s = float(self._typed.value.diagnostics_period_s)
        self._diagnostics = Diagnostics(self, f'tpms/{self._method}', period_s,
                                        update=self._update_diagnostics)
        self._update_diagnostics()

    # -- parameters ----------------------------------------------------------------------------

    @property
    def parameters(self) -> N:
        """The current, validated node-only parameters."""
        return self._typed.value

    @property
    def core_parameters(self) -> C:
        """The current, validated parameters of the method."""
        return self._core_params.value

    @property
    def analyzer(self) -> E:
        """The core estimator (read access for tests and tools)."""
        return self._analyzer

    def _on_core_change(self, core: C) -> None:
        # Only the parameters the core reads per call can change (the rest are read-only).
        self._analyzer.params = core

    def _on_change(self, p: N) -> None:
        """A node-only parameter changed (nothing to do unless a subclass says so)."""

    # -- calibration ---------------------------------------------------------------------------

    def _calibration_duration_s(self) -> float:
        return float(self._core_params.value.calibration_duration_s)

    def _on_calibrate(self, _: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        response.success, response.message = self._calibration.request(
            self._calibration_duration_s())
        return response

    @property
    def calibration_state(self) -> str:
        """uncalibrated, loaded, calibrating, calibrated, failed or file_corrupt."""
        return self._calibration.state

    # -- output and diagnostics ----------------------------------------------------------------

    def _publish_indication(self, stamp: Time, indication: TpmsIndication,
                            known: np.ndarray) -> None:
        """Publish the core's indication with the tires ``known`` (a tire not known is never
        flagged and has confidence 0) and keep it for the diagnostics."""
        msg = IndicationMsg()
        msg.header.stamp = stamp
        msg.method = self._method
        msg.underinflated = (indication.underinflated & known).tolist()
        msg.confidence = np.where(known, indication.confidence, 0.0).tolist()
        msg.known = known.tolist()
        self._indication_pub.publish(msg)
        self._last_known = known.copy()
        self._last_flags = indication.underinflated & known

    def _tire_diagnostics(self, received: bool) -> tuple[dict[str, Any],
                                                         list[tuple[int, str]]]:
        """Diagnostic values and problems about calibration and tires, common to the nodes."""
        cal = self._calibration
        low = [TIRE_NAMES[i] for i in np.flatnonzero(self._last_flags)]
        values: dict[str, Any] = {
            'known': self._last_known.tolist(),
            'calibration_state': cal.state,
            'calibration': cal.detail,
            'low_tires': low,
            'last_stamp_s': self._last_stamp_s,
        }
        problems: list[tuple[int, str]] = []
        if cal.state in ('file_corrupt', 'failed', 'uncalibrated', 'calibrating'):
            problems.append((WARN, cal.detail))
        elif received and not self._last_known.all():
            unknown = [TIRE_NAMES[i] for i in np.flatnonzero(~self._last_known)]
            problems.append((WARN, f'tires unknown: {", ".join(unknown)}'))
        if self._last_flags.any():
            problems.append((WARN, f'low tires indicated: {", ".join(low)}'))
        return values, problems

    def _update_diagnostics(self) -> None:
        raise NotImplementedError
