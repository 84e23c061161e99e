"""What both rail processors do with their inputs before their method sees a sample: the
bogie/body IMU pairing and saturation limits (node parameters of the same meaning in both), the
input-rate meters, the stamp check of every input, whose confirmed time jump restarts the
processor (``_restart``) and whose corrupt stamps it counts (``_reject_stamp``), and what their
statuses report alike: how long the input has been silent and the rejections since the previous
status.

An IMU pair's measurement is (bogie lateral acceleration, bogie yaw rate, body lateral
acceleration), as :class:`vehicle_monitor_common.imu_pairing.ImuPairer` pairs them in both.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
import math
from typing import Any, Generic, TypeVar

import numpy as np

from vehicle_monitor_common.imu_pairing import ImuPairer
from vehicle_monitor_common.input_health import RateMeter, StampCheck
from vehicle_monitor_common.parameters import param
from vehicle_monitor_common.processing import Input, ProcessorParams, header_stamp_ns


@dataclass(frozen=True)
class RailImuNodeParams(ProcessorParams):
    """The node parameters both rail processors have for their IMU inputs."""

    pair_tolerance_s: float = param(1e-3, 'largest stamp difference of a bogie/body IMU pair '
                                    '(and of the parts of one sample), s', low=0.0, high=1.0)
    pair_timeout_s: float = param(0.1, 'an IMU sample still unpaired when the newest stamp is '
                                  'this much later is given up, s', low=1e-3, high=10.0)
    accel_limit_mps2: float = param(50.0, 'an IMU acceleration at or beyond this is saturated, '
                                    'm/s^2', low=0.1, high=1e4)
    gyro_limit_rad_s: float = param(5.0, 'an IMU yaw rate at or beyond this is saturated, rad/s',
                                    low=0.01, high=1e3)

    def imu_saturated(self, pair: np.ndarray) -> bool:
        """Whether an IMU pair (bogie ay, bogie yaw rate, body ay) reaches a sensor's limit."""
        return bool(abs(pair[0]) >= self.accel_limit_mps2
                    or abs(pair[2]) >= self.accel_limit_mps2
                    or abs(pair[1]) >= self.gyro_limit_rad_s)


P = TypeVar('P', bound=RailImuNodeParams)


class RailImuInputs(Generic[P]):
    """The input side shared by the rail processors (see the module docstring).

    Args:
        node_params: the node's parameters.
        inputs: the processor's inputs by topic.
    """

    def __init__(self, node_params: P, inputs: Mapping[str, Input]) -> None:
        self.node_params = node_params
        self.inputs = inputs
        self._pairer = ImuPairer(node_params.pair_tolerance_s, node_params.pair_timeout_s)
        self._stamp_checks = self._new_stamp_checks()
        self._rates = {topic: RateMeter() for topic in inputs}
        # Silence: the count of handled samples and the status time it last changed.
        self._progress: tuple[int, int | None] = (0, None)
        self._reported: dict[str, int] = {}     # rejections already in a status

    def _new_stamp_checks(self) -> dict[str, StampCheck]:
        # Gaps are the core's (max_gap_s infinite here); jumps are everybody's.
        return {topic: StampCheck(max_gap_s=math.inf,
                                  jump_horizon_s=self.node_params.jump_horizon_s)
                for topic in self.inputs}

    def update_node_params(self, node_params: P) -> None:
        """The node's runtime-settable parameters changed."""
        self.node_params = node_params
        self._pairer.tolerance_s = node_params.pair_tolerance_s
        self._pairer.timeout_s = node_params.pair_timeout_s

    def _received(self, topic: str, message: Any) -> int | None:
        """One input message counted at its topic's rate: its stamp, or None when the stamp
        is refused (repeated, out of order, in the future)."""
        self._rates[topic].tick()
        stamp = header_stamp_ns(message)
        check = self._stamp_checks[topic]
        verdict = check.check(stamp)
        if verdict == 'jump':
            self._restart(stamp, f'time jump of {check.last_jump_s:+.3f} s on {topic}')
            self._stamp_checks[topic].check(stamp)
        elif verdict in ('repeated', 'out_of_order', 'future_stamp'):
            self._reject_stamp(topic, verdict)
            return None
        return stamp

    def _input_rates(self, now_ns: int) -> dict[str, float]:
        """Each input's rate, Hz, by topic."""
        return {topic: meter.read(now_ns) for topic, meter in self._rates.items()}

    def _silent_s(self, handled: int, now_ns: int) -> float:
        """How long (status time, s) the count of handled samples has not changed."""
        count, since = self._progress
        if handled != count or since is None:
            self._progress = (handled, now_ns)
            return 0.0
        return (now_ns - since) * 1e-9

    def _new_rejections(self, counts: Mapping[str, int], sample_rate_hz: float) -> str:
        """The rejections since the previous status, by reason (a warning that clears), from
        the counts so far."""
        new = {k: v - self._reported.get(k, 0) for k, v in counts.items()
               if v > self._reported.get(k, 0)}
        self._reported = dict(counts)
        rate = f' (faster than {sample_rate_hz:g} Hz)'
        return ', '.join(f'{k}{rate if k == "rate_burst" else ""} {v}'
                         for k, v in sorted(new.items()))

    def _restart(self, stamp: int, why: str) -> None:
        """Data time jumped: the processor starts again (calling ``_new_stamp_checks``)."""
        raise NotImplementedError

    def _reject_stamp(self, topic: str, verdict: str) -> None:
        """Count an input refused for its stamp (``verdict``: StampCheck's reason)."""
        raise NotImplementedError
