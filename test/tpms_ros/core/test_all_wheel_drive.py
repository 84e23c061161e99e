"""``driveline_compensation: all`` (vibration) and ``driven_axle: all`` (wheel radius) on an
all-wheel-drive car of the family (issue 21), against running the car as ``rear`` as before.

The car: the first all-wheel-drive car of ``TUNING_SEEDS`` (never a held-out one), on a
150 s rural drive of its own; the front-left tire loses 20 % at 90 s. Each method is calibrated
on 10-70 s and then judged on the rest: the highest evidence on any tire before the loss (the
margin to a false warning), which tires it flags after the loss, and when the front-left one is
flagged.

In the simulator an all-wheel-drive car's driveline modes reach all four rims (each axle's two
rims in phase) while its traction, and so the wheel torques on ``vehicle/driver_inputs``, stay
on the rear axle: ``all`` for the vibration analysis removes the front axle's driveline modes
too; for the wheel-radius analysis it differs from ``rear`` only by the front wheels' own
inertia torque (the traction model itself is tested on a point-mass drive with drive on both
axles in ``test_wheel_radius_analysis.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from tpms_ros.core.vibration_analysis import VibrationAnalyzer, VibrationParams
from tpms_ros.core.wheel_radius_analysis import (
    WheelRadiusAnalyzer,
    WheelRadiusParams,
    bin_wheel_speeds,
    sample_and_hold,
)
from tpms_ros.simulation.car_family import (
    TUNING_SEEDS,
    FamilyCar,
    car_scenario,
    pressure_event,
    sample_car,
)
from tpms_ros.simulation.road_simulator import (
    RoadSimulationResult,
    simulate_scenario,
    to_topic_series,
)

DURATION_S = 150.0
LOSS_AT_S = 90.0
CALIBRATION_S = (10.0, 70.0)
DRIVER_MAX_AGE_S = 0.1


@dataclass(frozen=True)
class Judged:
    """What one method did on the drive."""

    nominal_max: np.ndarray         # (4,) highest evidence per tire before the loss
    flagged_after: np.ndarray       # (4,) bool: flagged at some time after the loss
    front_left_s: float | None      # first flag of the lost tire, s after the loss


@pytest.fixture(scope='module')
def drive() -> tuple[FamilyCar, RoadSimulationResult]:
    car = next(c for c in map(sample_car, TUNING_SEEDS) if c.layout == 'all')
    scenario = car_scenario(car, 'rural', DURATION_S,
                            events=[pressure_event('pressure_step', LOSS_AT_S, (0,), 20.0)])
    return car, simulate_scenario(scenario)


def _vibration(result: RoadSimulationResult, compensation: str) -> Judged:
    t, omega = result.wheel_speed_t, result.wheel_speed
    analyzer = VibrationAnalyzer(VibrationParams(driveline_compensation=compensation))
    start, stop = np.searchsorted(t, CALIBRATION_S)
    analyzer.process(omega[:start])
    analyzer.start_calibration()
    analyzer.process(omega[start:stop])
    analyzer.finish_calibration()
    nominal, flagged, first = np.zeros(4), np.zeros(4, dtype=bool), None
    for k in range(stop, t.size, 100):               # 0.1 s blocks, as the node's
        analyzer.process(omega[k:k + 100])
        now = float(t[min(k + 100, t.size) - 1])
        indication = analyzer.indication(now)
        if now < LOSS_AT_S:
            nominal = np.fmax(nominal, analyzer.frequency_drop_sigma())
        else:
            flagged |= indication.underinflated
            if first is None and indication.underinflated[0]:
                first = now - LOSS_AT_S
    return Judged(nominal, flagged, first)


def _wheel_radius(car: FamilyCar, result: RoadSimulationResult, axle: str) -> Judged:
    user = car.user_parameters()
    params = WheelRadiusParams(nominal_radius_m=user['nominal_radius_m'],
                               track_front_m=user['track_front_m'],
                               track_rear_m=user['track_rear_m'], wheelbase_m=user['wheelbase_m'],
                               driven_axle=axle)
    driver = to_topic_series(result)['/vehicle/driver_inputs']
    t_driver = driver.stamps_ns * 1e-9
    t = result.imu_t
    omega = bin_wheel_speeds(result.wheel_speed_t, result.wheel_speed, t,
                             1.0 / params.sample_rate_hz, params.max_wheel_speed_rad_s)
    yaw = result.imu_gyro[:, 1]
    torque = sample_and_hold(t_driver, driver.fields['wheel_torque'], t, DRIVER_MAX_AGE_S)
    steer = sample_and_hold(t_driver, driver.fields['steering_angle'], t, DRIVER_MAX_AGE_S)

    def process(part: slice) -> None:
        analyzer.process(t[part], omega[part], yaw[part], torque[part], steer[part])

    analyzer = WheelRadiusAnalyzer(params)
    start, stop = (int(i) for i in np.searchsorted(t, CALIBRATION_S))
    process(slice(0, start))
    analyzer.start_calibration()
    process(slice(start, stop))
    analyzer.finish_calibration()
    nominal, flagged, first = np.zeros(4), np.zeros(4, dtype=bool), None
    for k in range(stop, t.size, 10):
        process(slice(k, k + 10))
        now = float(t[min(k + 10, t.size) - 1])
        indication = analyzer.indication(now)
        if now < LOSS_AT_S:
            nominal = np.fmax(nominal, np.where(indication.known, indication.confidence, 0.0))
        else:
            flagged |= indication.underinflated
            if first is None and indication.underinflated[0]:
                first = now - LOSS_AT_S
    return Judged(nominal, flagged, first)


def test_vibration_all_does_at_least_as_well_as_rear(
        drive: tuple[FamilyCar, RoadSimulationResult]) -> None:
    """Compensating both axles: no healthy tire flagged (before or after the loss), no more
    than as ``rear``, and the lost tire flagged within 30 s."""
    _, result = drive
    rear, both = _vibration(result, 'rear'), _vibration(result, 'all')
    z_flag = VibrationParams().z_flag
    print(f'vibration nominal max z: rear {np.round(rear.nominal_max, 2)}, all '
          f'{np.round(both.nominal_max, 2)}; front-left flagged after {rear.front_left_s} / '
          f'{both.front_left_s} s; flagged after the loss {rear.flagged_after} / '
          f'{both.flagged_after}')
    healthy = [False, True, True, True]

    def false_flags(judged: Judged) -> int:
        return int((judged.nominal_max >= z_flag).sum() + judged.flagged_after[healthy].sum())

    assert false_flags(both) == 0
    assert false_flags(both) <= false_flags(rear)
    assert both.front_left_s is not None and both.front_left_s <= 30.0


def test_wheel_radius_all_does_at_least_as_well_as_rear(
        drive: tuple[FamilyCar, RoadSimulationResult]) -> None:
    """The slip of rear against front by their traction difference: the same tires flagged as
    with ``rear`` (the lost one only), within 30 s, and no more evidence on a healthy tire
    before the loss."""
    car, result = drive
    rear, both = _wheel_radius(car, result, 'rear'), _wheel_radius(car, result, 'all')
    print(f'wheel radius nominal max confidence: rear {np.round(rear.nominal_max, 3)}, all '
          f'{np.round(both.nominal_max, 3)}; front-left flagged after {rear.front_left_s} / '
          f'{both.front_left_s} s')
    np.testing.assert_array_equal(both.flagged_after, [True, False, False, False])
    np.testing.assert_array_equal(both.flagged_after, rear.flagged_after)
    assert both.front_left_s is not None and both.front_left_s <= 30.0
    assert np.all(both.nominal_max <= rear.nominal_max + 0.02)
