"""Small processors standing in for the estimators in the fleet job's tests (importable by
module name, so a Ray worker builds them too: plugin ``fleet_fakes:make_tire_warner``).

``TireWarner`` reads the IMU and warns a tire whose calibrated baseline of ``linear_acceleration
.y`` the sample falls below by more than ``drop`` (a leak); it learns the baseline over its first
``calibration_samples`` samples unless a calibration was loaded: the fleet's calibration chain
carries it. ``Creep`` publishes ``angular_velocity.z`` as a creep factor, low below 0.5, and
``Suspension`` reports ``angular_velocity.x`` as the spring ratio, a fault above 1.3.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from vehicle_monitor_common.processing import Input, Output, Status

IMU = 'sensor_msgs/msg/Imu'


def _stamp(message: Any) -> int:
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


class TireWarner:
    inputs = {'vehicle/imu': Input(IMU)}
    outputs = {'tpms/warning': 'vehicle_monitor_msgs/msg/TpmsWarning'}

    def __init__(self, drop: float, calibration_samples: int) -> None:
        self.drop = drop
        self.samples = calibration_samples
        self.seen: list[float] = []
        self.baseline: float | None = None

    def process(self, topic: str, message: Any) -> list[Output]:
        value = float(message.linear_acceleration.y)
        if self.baseline is None:
            self.seen.append(value)
            if len(self.seen) >= self.samples:
                self.baseline = float(np.mean(self.seen))
            return []
        low = value < self.baseline - self.drop
        warning = [low, False, False, False]
        return [Output('tpms/warning', _stamp(message), {
            'warning': warning, 'active': low,
            'confidence': [0.9 if low else 0.1, 0.0, 0.0, 0.0]})]

    def status(self, now_ns: int) -> Status:
        return Status(message='calibrated' if self.baseline is not None else 'calibrating')

    def request_calibration(self) -> tuple[bool, str]:
        self.baseline, self.seen = None, []
        return True, 'calibrating'

    def calibration_state(self) -> dict[str, Any] | None:
        return None if self.baseline is None else {'baseline': self.baseline}

    def load_calibration_state(self, state: Mapping[str, Any]) -> None:
        if 'baseline' not in state:
            raise ValueError('no baseline')
        self.baseline = float(state['baseline'])


class Creep:
    inputs = {'vehicle/imu': Input(IMU)}
    outputs = {'rail/creep_factor': 'vehicle_monitor_msgs/msg/CreepFactor'}

    def process(self, topic: str, message: Any) -> list[Output]:
        value = float(message.angular_velocity.z)
        return [Output('rail/creep_factor', _stamp(message),
                       {'creep_factor': value, 'low_adhesion': value < 0.5})]

    def status(self, now_ns: int) -> Status:
        return Status(message='ok')


class Suspension:
    inputs = {'vehicle/imu': Input(IMU)}
    outputs = {'rail/suspension/modes': 'vehicle_monitor_msgs/msg/ModeProbabilities'}

    def process(self, topic: str, message: Any) -> list[Output]:
        ratio = float(message.angular_velocity.x)
        fault = ratio > 1.3
        return [Output('rail/suspension/modes', _stamp(message), {
            'modes': ['normal', 'spring_150'], 'probability': [0.5, 0.5],
            'smoothed_probability': [0.2, 0.8] if fault else [0.8, 0.2],
            'most_likely': 1 if fault else 0, 'spring_ratio': ratio, 'damper_ratio': 1.0,
            'fault_detected': fault, 'fault_component': 'spring' if fault else ''})]

    def status(self, now_ns: int) -> Status:
        return Status(message='ok')


def make_tire_warner(values: Mapping[str, Any], fqn: str) -> TireWarner:
    return TireWarner(float(values.get('drop', 1.0)), int(values.get('calibration_samples', 10)))


def make_creep(values: Mapping[str, Any], fqn: str) -> Creep:
    return Creep()


def make_suspension(values: Mapping[str, Any], fqn: str) -> Suspension:
    return Suspension()


class Crasher:
    """Kills its process at the first message (a worker dying, e.g. out of memory)."""

    inputs = {'vehicle/imu': Input(IMU)}
    outputs: dict[str, str] = {}

    def process(self, topic: str, message: Any) -> list[Output]:
        import os

        os._exit(3)

    def status(self, now_ns: int) -> Status:
        return Status()


def make_crasher(values: Mapping[str, Any], fqn: str) -> Crasher:
    return Crasher()
