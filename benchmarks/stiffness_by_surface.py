"""The stiffness observer's error at placard by road surface, against the calibration's surface.

A diagnosis of the car family's false lows (docs/methods/tpms_family_evaluation.md, section
"2026-12-02"): the stiffness core alone is run, as ``eval_tpms_family.py`` feeds it (0.25 s
chunks, the calibration from the start of the drive), over drives that evaluation simulated and
kept (``--sim-cache``). Every estimate of a healthy tire is labelled with the road surface the
car was on; the calibration's surface is the one it drove most during the calibration window.
Printed: per drive, the mean error (% of placard) on each surface; then the mean, median and
mean absolute value of those per-drive figures, grouped by (calibration surface, surface now).

``python benchmarks/stiffness_by_surface.py --sim-cache DIR [--glob PATTERN] [--workers N]``
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from multiprocessing import Pool
from pathlib import Path

from eval_tpms_family import (
    DRIVER_MAX_AGE_S,
    STIFFNESS_CHUNK_S,
    Settings,
    kept_drive,
    method_params,
)
import numpy as np

from tpms_ros.core.stiffness_observer import TireStiffnessObserver
from tpms_ros.core.wheel_radius_analysis import sample_and_hold
from tpms_ros.simulation.road_simulator import to_topic_series

# Estimates before this are in or right after the calibration window (eval_tpms_family's 90 s).
JUDGED_FROM_S = 100.0
# A (drive, surface) pair needs this many valid estimates of healthy tires to be counted.
MIN_ESTIMATES = 40


def surface_errors(path: Path) -> tuple[str, str, dict[str, float]]:
    """(drive name, calibration surface, {surface: mean error % of placard}) of one drive."""
    result, car = kept_drive(path)
    params = method_params(car, Settings())[2]
    observer = TireStiffnessObserver(params)
    observer.start_calibration()
    driver = to_topic_series(result)['/vehicle/driver_inputs']
    t_driver = driver.stamps_ns * 1e-9
    t, omega = result.wheel_speed_t, result.wheel_speed
    torque = sample_and_hold(t_driver, driver.fields['wheel_torque'], t, DRIVER_MAX_AGE_S)
    steer = sample_and_hold(t_driver, driver.fields['steering_angle'], t, DRIVER_MAX_AGE_S)
    chunk = round(STIFFNESS_CHUNK_S * params.sample_rate_hz)
    n = t.size // chunk
    stamps, pressure = np.empty(n), np.full((n, 4), np.nan)
    for k in range(n):
        part = slice(k * chunk, (k + 1) * chunk)
        est = observer.update(omega[part], stamps=t[part], wheel_torque=torque[part],
                              steering_angle=steer[part])
        counted = np.asarray(est.valid) & np.asarray(est.wheel_calibrated) & (not est.calibrating)
        pressure[k] = np.where(counted, est.pressure_kpa, np.nan)
        stamps[k] = t[(k + 1) * chunk - 1]
    truth = np.column_stack([np.interp(stamps, result.handling.t, result.pressure_kpa[:, w])
                             for w in range(4)])
    placard = np.asarray(params.nominal_pressure_kpa)
    healthy = truth[-1] >= 0.95 * placard
    error = ((pressure - truth) / placard * 100.0)[:, healthy]
    segments = result.scenario.road_segments
    calibrated_on, per_surface = surface_means(
        stamps, error, [s.at_s for s in segments], [s.surface for s in segments])
    return path.stem, calibrated_on, per_surface


def surface_means(stamps: np.ndarray, error: np.ndarray, starts: list[float],
                  surfaces: list[str]) -> tuple[str, dict[str, float]]:
    """(the surface driven most in the calibration window, {surface: mean error}) of one drive.

    Args:
        stamps: (N,) data time of each estimate, s.
        error: (N, W) error of each estimate of the W tires judged (NaN: not valid).
        starts, surfaces: the road's segments: start time, s, and surface from there on.
    """
    label = np.asarray(surfaces)[np.searchsorted(np.asarray(starts), stamps, side='right') - 1]
    names, counts = np.unique(label[stamps < Settings().calibration_s], return_counts=True)
    per_surface = {}
    for name in np.unique(label):
        rows = (stamps >= JUDGED_FROM_S) & (label == name)
        if np.isfinite(error[rows]).sum() >= MIN_ESTIMATES:
            per_surface[str(name)] = float(np.nanmean(error[rows]))
    return str(names[np.argmax(counts)]), per_surface


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--sim-cache', type=Path, required=True,
                        help="eval_tpms_family.py's directory of simulated drives")
    parser.add_argument('--glob', default='car*.pkl', help='which drives (default: all)')
    parser.add_argument('--workers', type=int, default=2)
    args = parser.parse_args()
    paths = sorted(p for p in args.sim_cache.glob(args.glob) if 'ring0' not in p.name)
    groups: dict[tuple[str, str], list[float]] = defaultdict(list)
    with Pool(args.workers) as pool:
        for name, calibrated_on, per_surface in pool.imap(surface_errors, paths):
            cells = ' '.join(f'{s} {e:+.1f} %' for s, e in sorted(per_surface.items()))
            print(f'{name}: calibrated on {calibrated_on}; {cells}', flush=True)
            for surface, mean in per_surface.items():
                groups[(calibrated_on, surface)].append(mean)
    print('\n| calibrated on | driving on | drives | mean | median | mean abs |')
    print('| --- | --- | --- | --- | --- | --- |')
    for (calibrated_on, surface), means in sorted(groups.items()):
        values = np.array(means)
        print(f'| {calibrated_on} | {surface} | {values.size} | {values.mean():+.2f} % | '
              f'{np.median(values):+.2f} % | {np.abs(values).mean():.2f} % |')


if __name__ == '__main__':
    main()
