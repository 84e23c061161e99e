"""The vehicle inputs the road processors that align several streams read (the lateral-force
observer and the wheel-radius analyzer): topics, message types, and the driver inputs' wheel
torques read the same way by both."""

from __future__ import annotations

from typing import Any

import numpy as np

from tpms_ros.core.tires import N_TIRES
from tpms_ros.processing.wheel_speeds import WHEEL_SPEEDS_TYPE
from vehicle_monitor_common.processing import Input

IMU = 'vehicle/imu'
WHEEL_SPEEDS = 'vehicle/wheel_speeds'
DRIVER_INPUTS = 'vehicle/driver_inputs'
VEHICLE_INPUTS = {IMU: Input('sensor_msgs/msg/Imu'),
                  WHEEL_SPEEDS: Input(WHEEL_SPEEDS_TYPE, raw=True),
                  DRIVER_INPUTS: Input('vehicle_monitor_msgs/msg/DriverInputs')}


def wheel_torques(msg: Any) -> np.ndarray | None:
    """A DriverInputs' wheel torques FL, FR, RL, RR, N m; None when the field is not four
    numbers (a malformed message)."""
    try:
        torque = np.asarray(msg.wheel_torque, dtype=float)
    except (TypeError, ValueError):
        return None
    return torque if torque.shape == (N_TIRES,) else None
