"""The paper's truth model for the suspension IMM: the 7-DOF half car on a given track, its
noisy sensor signals and the wheelset inputs (Mori, Tsunashima, Marumo's validation setup)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rail_monitor_ros.core.rail_model import (
    SENSOR_OUTPUT_NAMES,
    RailVehicleParams,
    half_car_state_space,
    wheelset_inputs_from_track,
)

N_OUTPUTS = len(SENSOR_OUTPUT_NAMES)


@dataclass(frozen=True)
class HalfCarSensorData:
    """Sensor signals of the paper's truth model (see :func:`half_car_sensor_data`).

    Attributes:
        time: (N,) s.
        measurements: (N, 3) noisy [bogie lateral accel, bogie yaw rate, body lateral accel].
        known_inputs: (N, 4) wheelset inputs from the track (``wheelset_inputs_from_track``).
        spring_ratio: (N,) true spring ratio.
        damper_ratio: (N,) true damper ratio.
    """

    time: np.ndarray
    measurements: np.ndarray
    known_inputs: np.ndarray
    spring_ratio: np.ndarray
    damper_ratio: np.ndarray


def half_car_sensor_data(time: np.ndarray, track_alignment: np.ndarray,
                         track_alignment_rate: np.ndarray, spring_ratio: np.ndarray,
                         damper_ratio: np.ndarray, vehicle: RailVehicleParams | None = None,
                         noise_std: Sequence[float] = (0.02, 1e-3, 0.02),
                         seed: int = 0, creep_factor: float = 1.0) -> HalfCarSensorData:
    """The paper's validation setup: the 7-DOF half car as truth on a given track.

    Mori et al. simulate the half car of their Fig. 1 (two wheelsets, bogie, body lateral) and
    estimate with the reduced model; the wheelset motion is what the estimator does not have.
    This runs :func:`half_car_state_space` (exact zero-order hold between samples, the
    parameters piecewise constant) on the track alignment under the two wheelsets, e.g. the
    rail simulator's ``track_alignment[:, :2]``, and adds white sensor noise.

    Args:
        time: (N,) uniformly sampled, s.
        track_alignment: (N, 2) alignment under the leading and trailing wheelset, m.
        track_alignment_rate: (N, 2) its rate, m/s (for the known inputs).
        spring_ratio, damper_ratio: (N,) the truth's secondary lateral spring and damper.
        vehicle: truth parameters (speed included).
        noise_std: sensor noise std (m/s^2, rad/s, m/s^2).
        seed: noise seed.
        creep_factor: the truth's creep factor.
    """
    t = np.asarray(time, dtype=float)
    y_r = np.asarray(track_alignment, dtype=float)
    rate = np.asarray(track_alignment_rate, dtype=float)
    springs = np.broadcast_to(np.asarray(spring_ratio, dtype=float), t.shape)
    dampers = np.broadcast_to(np.asarray(damper_ratio, dtype=float), t.shape)
    if t.ndim != 1 or t.size < 2 or y_r.shape != (t.size, 2) or rate.shape != y_r.shape:
        raise ValueError('time must be (N,), track_alignment and its rate (N, 2)')
    dt = float(np.mean(np.diff(t)))
    params = vehicle if vehicle is not None else RailVehicleParams()
    models: dict[tuple[float, float], tuple[np.ndarray, ...]] = {}
    n_states = half_car_state_space(params).a.shape[0]
    x = np.zeros(n_states)
    out = np.empty((t.size, N_OUTPUTS))
    # The recursion is sequential; one small matrix-vector product per sample.
    for k in range(t.size):
        key = (float(springs[k]), float(dampers[k]))
        if key not in models:
            model = half_car_state_space(params, creep_factor, *key).discretize(dt)
            models[key] = (model.f, model.g, model.h, model.l)
        f, g, h, l = models[key]  # noqa: E741
        out[k] = h @ x + l @ y_r[k]
        x = f @ x + g @ y_r[k]
    rng = np.random.default_rng(seed)
    measurements = out + rng.standard_normal(out.shape) * np.asarray(noise_std, dtype=float)
    known = wheelset_inputs_from_track(y_r, rate, params.speed)
    return HalfCarSensorData(t, measurements, known, springs.copy(), dampers.copy())
