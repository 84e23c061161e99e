"""Offline studies of the lateral force observer: zeta calibration, gain tuning, figures.

Everything here runs the core (:mod:`tpms_ros.core.lateral_force_observer`) over recorded or
simulated cases with known truth; none of it runs on the vehicle, so it stays out of the core.
``calibrate_zeta`` identifies relation 1 from a ramp-steer run (the paper's Fig. 3 manoeuvre),
``tune_gains`` chooses Q, R, Gp and Gy by coordinate search, and the two plots draw the paper's
Figs. 3-6.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
import math

import numpy as np

from tpms_ros.core.lateral_force_observer import (
    G,
    LateralForceObserver,
    LateralForceTrack,
    ObserverTuningParams,
    ObserverVehicleParams,
)
from vehicle_monitor_common.figures import pyplot, save_figure


@dataclass(frozen=True)
class TuningCase:
    """Measurements and truth of one scenario: arrays as ``LateralForceObserver.run`` takes,
    plus the true per-wheel lateral forces ``fy_true`` (N, 4)."""

    name: str
    dt: float
    ax: np.ndarray
    ay: np.ndarray
    r: np.ndarray
    p: np.ndarray
    omega: np.ndarray
    wheel_torque: np.ndarray
    steer: np.ndarray
    fy_true: np.ndarray

    def run(self, params: ObserverVehicleParams | None = None,
            tuning: ObserverTuningParams | None = None) -> LateralForceTrack:
        """Run a fresh observer over this case."""
        observer = LateralForceObserver(params, tuning)
        return observer.run(self.dt, self.ax, self.ay, self.r, self.p, self.omega,
                            self.wheel_torque, self.steer)


@dataclass(frozen=True)
class ZetaCalibration:
    """Outcome of ``calibrate_zeta``: relation 1 identified from a ramp-steer run."""

    zeta: tuple[float, float]      # (z1, z2) = (Fyf/phi, Fyr/phi), N/rad
    roll_gradient: float           # d phi / d ay (kinematic), rad per m/s^2
    samples: int                   # samples used in the fit
    model_zeta: tuple[float, float]  # what the vehicle model alone predicts, N/rad


def calibrate_zeta(params: ObserverVehicleParams, dt: float, ay: np.ndarray, p: np.ndarray,
                   ay_range: tuple[float, float] = (1.0, 0.5 * G),
                   imu_gravity_tilt: bool = True) -> ZetaCalibration:
    """Relation 1 (Fyf = z1 phi, Fyr = z2 phi) from a ramp-steer calibration run.

    The paper reads z1, z2 off its Fig. 3 (a slow 0 -> 4 deg steer ramp at 70 km/h); on a car
    the same run gives them from the IMU alone. The run must start driving straight (phi = 0)
    with a gyro whose offset was removed at standstill: the roll angle is the integral of the
    roll rate (trapezoidal), the kinematic lateral acceleration is the IMU's minus g sin(phi)
    when the IMU rolls with the body, and the least-squares roll gradient k = phi/ay through the
    origin over ``ay_range`` (|ay|, m/s^2; relation 1 holds below 0.5 g) gives, with the quasi-
    steady axle forces 2 Fyf = m ay lr/l and 2 Fyr = m ay lf/l::

        z1 = m lr / (2 l k),  z2 = m lf / (2 l k)

    This measured roll gradient includes what the model's roll row leaves out (tire vertical
    compliance, suspension geometry), so it is the vehicle's own relation 1 rather than the
    model's (``ObserverVehicleParams.zeta``). Use it as ``ObserverTuningParams(zeta=...)``.

    Args:
        params: the observer's vehicle model (m, lf, lr).
        dt: sample interval, s.
        ay: measured lateral acceleration (N,), m/s^2.
        p: measured roll rate (N,), rad/s.
        ay_range: |ay_kin| window of the fit, m/s^2.
        imu_gravity_tilt: the IMU is fixed to the rolling body (reads g sin(phi)).

    Returns:
        The identified zeta, roll gradient and the sample count.

    Raises:
        ValueError: bad dt, shapes, non-finite data, or fewer than 10 samples in the window.
    """
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be finite and > 0, got {dt}')
    ay = np.asarray(ay, dtype=float).reshape(-1)
    p = np.asarray(p, dtype=float).reshape(-1)
    if ay.shape != p.shape:
        raise ValueError(f'ay and p must have the same length, got {ay.size} and {p.size}')
    if not (np.all(np.isfinite(ay)) and np.all(np.isfinite(p))):
        raise ValueError('ay and p must be finite')
    phi = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * dt)])
    ay_kin = ay - G * np.sin(phi) if imu_gravity_tilt else ay
    mask = (np.abs(ay_kin) >= ay_range[0]) & (np.abs(ay_kin) <= ay_range[1])
    if np.count_nonzero(mask) < 10:
        raise ValueError(f'ay_range {ay_range} holds {np.count_nonzero(mask)} samples, '
                         'need >= 10 (steer further or widen the window)')
    gradient = float(np.dot(phi[mask], ay_kin[mask]) / np.dot(ay_kin[mask], ay_kin[mask]))
    if not gradient > 0.0:
        raise ValueError(f'roll gradient {gradient} rad/(m/s^2) is not positive: check the '
                         'roll-rate sign convention (REP 103: left turn rolls positive)')
    wb = params.wheelbase
    zeta = (params.m * params.lr / (2.0 * wb * gradient),
            params.m * params.lf / (2.0 * wb * gradient))
    return ZetaCalibration(zeta=zeta, roll_gradient=gradient,
                           samples=int(np.count_nonzero(mask)), model_zeta=params.zeta)


def split_exponent_from_tire(a4: float, a5: float, load_n: float) -> float:
    """Relation 2's ``split_exponent`` from a tire's Magic Formula data at a wheel load.

    The left/right split follows the cornering stiffness C(Fz), so its exponent is C's local
    load exponent b = d ln C / d ln Fz at the axle's static wheel load. In the Bakker, Nyborg &
    Pacejka (1987) form C = a3 sin(a4 atan(a5 Fz)) (Fz in kN)::

        b = a4 a5 Fz cos(a4 atan(a5 Fz)) / ((1 + (a5 Fz)^2) sin(a4 atan(a5 Fz)))

    (a3 cancels). Clipped to [0, 1], the parameter's range: past the load of C's maximum b is
    negative, and there the split is taken as even. The same tire carries a heavier car with a
    smaller b (a passenger-car tire: 0.5 at 3 kN, 0.1 at 5 kN, 0 from 5.6 kN), which is why
    the exponent belongs to the car as much as to the tire: pass the mean static wheel load.

    Raises:
        ValueError: a non-positive or non-finite coefficient or load.
    """
    for name, value in (('a4', a4), ('a5', a5), ('load_n', load_n)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f'{name} must be finite and > 0, got {value}')
    fz = load_n / 1000.0
    angle = a4 * math.atan(a5 * fz)
    b = a4 * a5 * fz * math.cos(angle) / ((1.0 + (a5 * fz) ** 2) * math.sin(angle))
    return min(1.0, max(0.0, b))


def fy_error_percent(track: LateralForceTrack, fy_true: np.ndarray) -> np.ndarray:
    """Per-wheel RMS error of Fy as a percentage of that wheel's peak |Fy| (the target figure)."""
    fy_true = np.asarray(fy_true, dtype=float)
    peak = np.max(np.abs(fy_true), axis=0)
    rms = np.sqrt(np.mean((track.fy - fy_true) ** 2, axis=0))
    return 100.0 * rms / np.maximum(peak, 1e-9)


@dataclass(frozen=True)
class TuningResult:
    """Outcome of ``tune_gains``: the chosen tuning, its score and every trial."""

    tuning: ObserverTuningParams
    score: float                                   # worst per-wheel error over cases, %
    trials: tuple[tuple[str, float], ...]          # (description, score) in trial order


def _score(cases: Sequence[TuningCase], params: ObserverVehicleParams | None,
           tuning: ObserverTuningParams) -> float:
    worst = 0.0
    for case in cases:
        error = fy_error_percent(case.run(params, tuning), case.fy_true)
        worst = max(worst, float(np.max(error)) if np.all(np.isfinite(error)) else math.inf)
    return worst


def tune_gains(cases: Sequence[TuningCase], params: ObserverVehicleParams | None = None,
               base: ObserverTuningParams | None = None,
               force_q: Sequence[float] = (0.1, 0.3, 1.0, 3.0, 10.0),
               ay_std: Sequence[float] = (0.1, 0.3, 1.0, 3.0),
               gp: Sequence[float] = (0.0, 10.0, 30.0, 100.0, 300.0),
               gy: Sequence[float] = (-1000.0, -300.0, 0.0, 300.0, 1000.0),
               roll_q: Sequence[float] = (0.1, 10.0, 1e3, 1e5),
               passes: int = 2, min_improvement: float = 0.05) -> TuningResult:
    """Choose Q (force and roll states), R (ay), Gp, Gy by coordinate search on worst cases.

    The score is the worst per-wheel Fy RMS error (% of peak) over all ``cases``: the paper
    tunes its gains "for the largest disturbance", so pass the worst scenario(s) you expect.
    Each pass sweeps one group at a time with the others held: (Q on Fyf, Fyr) and R on ay
    jointly, then Q on (phi, p) as pairs from ``roll_q`` (how far the roll row, whose roll
    stiffness leaves out tire compliance, is trusted), then Gp as (g_f, -g_r) pairs (a positive
    yaw-rate error means too little yaw moment:
    raise front, lower rear force), then Gy (front, rear) pairs. Deterministic for given cases.
    With ``base.mec`` false only Q and R are tuned (the plain EKF gets the same search). A
    candidate replaces the incumbent only if it lowers the score by ``min_improvement``
    percentage points, so gains that do nothing measurable stay at their simpler values.
    """
    if not cases:
        raise ValueError('cases must hold at least one TuningCase')
    if passes < 1:
        raise ValueError(f'passes must be >= 1, got {passes}')
    best = base or ObserverTuningParams()
    best_score = _score(cases, params, best)
    trials: list[tuple[str, float]] = [('base', best_score)]

    def consider(candidate: ObserverTuningParams, label: str) -> None:
        nonlocal best, best_score
        score = _score(cases, params, candidate)
        trials.append((label, score))
        if score < best_score - min_improvement:
            best, best_score = candidate, score

    for _ in range(passes):
        anchor = best
        for q in force_q:
            for ay in ay_std:
                q_diag = tuple(anchor.q_diag[:5]) + (q, q)
                r_std = (anchor.r_std[0], ay) + tuple(anchor.r_std[2:])
                consider(replace(anchor, q_diag=q_diag, r_std=r_std), f'q_force={q} ay_std={ay}')
        anchor = best
        for q_phi in roll_q:
            for q_p in roll_q:
                q_diag = tuple(anchor.q_diag[:3]) + (q_phi, q_p) + tuple(anchor.q_diag[5:])
                consider(replace(anchor, q_diag=q_diag), f'q_phi={q_phi} q_p={q_p}')
        if best.mec:
            anchor = best
            for g_f in gp:
                for g_r in gp:
                    consider(replace(anchor, gp=(g_f, -g_r)), f'gp=({g_f}, {-g_r})')
            anchor = best
            for g_f in gy:
                for g_r in gy:
                    consider(replace(anchor, gy=(g_f, g_r)), f'gy=({g_f}, {g_r})')
    return TuningResult(tuning=best, score=best_score, trials=tuple(trials))


def plot_lateral_forces(path: str, t: np.ndarray, fy_true: np.ndarray,
                        estimates: Mapping[str, LateralForceTrack], title: str = '') -> None:
    """PNG like the paper's Figs. 5-6: per-wheel Fy and axle Fyf, Fyr, estimates vs truth.

    Args:
        path: output PNG file.
        t: sample times, s.
        fy_true: true per-wheel lateral forces (N, 4), N.
        estimates: label -> track (e.g. {'SKFMEC': ..., 'plain EKF': ...}).
        title: figure title.
    """
    plt = pyplot()

    fy_true = np.asarray(fy_true, dtype=float)
    fig, axes = plt.subplots(3, 2, figsize=(11, 9), sharex=True)
    panels = [(axes[0, 0], 'FL', 0), (axes[0, 1], 'FR', 1), (axes[1, 0], 'RL', 2),
              (axes[1, 1], 'RR', 3)]
    for ax, label, i in panels:
        ax.plot(t, fy_true[:, i], 'k', lw=1.5, label='truth')
        for name, track in estimates.items():
            err = fy_error_percent(track, fy_true)[i]
            ax.plot(t, track.fy[:, i], lw=0.9, label=f'{name} ({err:.1f} %)')
        ax.set_title(f'Fy {label}')
        ax.set_ylabel('N')
        ax.legend(fontsize=7)
    for ax, label, cols, attr in ((axes[2, 0], 'Fyf (front mean)', [0, 1], 'fy_front'),
                                  (axes[2, 1], 'Fyr (rear mean)', [2, 3], 'fy_rear')):
        ax.plot(t, fy_true[:, cols].mean(axis=1), 'k', lw=1.5, label='truth')
        for name, track in estimates.items():
            ax.plot(t, getattr(track, attr), lw=0.9, label=name)
        ax.set_title(label)
        ax.set_xlabel('t, s')
        ax.set_ylabel('N')
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    save_figure(fig, path)


def plot_relation_check(path: str, t: np.ndarray, fy: np.ndarray, fz: np.ndarray,
                        roll: np.ndarray, ay: np.ndarray,
                        model_zeta: tuple[float, float] | None = None,
                        calibrated_zeta: tuple[float, float] | None = None,
                        split_exponent: float = 0.6) -> None:
    """PNG like the paper's Figs. 3-4 from a ramp-steer truth run.

    Left: z1 = Fyf/phi and z2 = Fyr/phi over time (relation 1), with the model's and the
    calibrated values as lines. Right: Fy2/Fyf against Fz2/Fzf (relation 2, the paper's
    proportional split) and against (Fz2/Fzf)^split_exponent (the load-sensitive split), front
    right wheel, for |ay| below 0.5 g.

    Args:
        path: output PNG file.
        t: times (N,), s.
        fy, fz: true per-wheel lateral and vertical forces (N, 4), N.
        roll: true roll angle (N,), rad.
        ay: lateral acceleration (N,), m/s^2 (selects |ay| in [1 m/s^2, 0.5 g]).
        model_zeta, calibrated_zeta: reference lines, N/rad.
        split_exponent: exponent of the load-sensitive split shown.
    """
    plt = pyplot()

    fy, fz = np.asarray(fy, dtype=float), np.asarray(fz, dtype=float)
    mask = (np.abs(ay) >= 1.0) & (np.abs(ay) <= 0.5 * G) & (np.abs(roll) > 1e-4)
    fyf, fyr = fy[:, :2].mean(axis=1), fy[:, 2:].mean(axis=1)
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
    ax1.plot(t[mask], fyf[mask] / roll[mask], label='z1 = Fyf/phi (truth)')
    ax1.plot(t[mask], fyr[mask] / roll[mask], label='z2 = Fyr/phi (truth)')
    for zeta, style, label in ((model_zeta, '--', 'model'), (calibrated_zeta, ':',
                                                             'calibrated')):
        if zeta is not None:
            ax1.axhline(zeta[0], color='C0', ls=style, label=f'z1 {label}')
            ax1.axhline(zeta[1], color='C1', ls=style, label=f'z2 {label}')
    ax1.set_xlabel('t, s')
    ax1.set_ylabel('N/rad')
    ax1.set_title('Relation 1: axle force / roll angle')
    ax1.legend(fontsize=7)
    load_ratio = fz[mask, 1] / fz[mask, :2].mean(axis=1)
    force_ratio = fy[mask, 1] / fyf[mask]
    ax2.plot(load_ratio, force_ratio, 'k.', ms=2, label='truth Fy2/Fyf')
    grid = np.linspace(load_ratio.min(), load_ratio.max(), 50)
    ax2.plot(grid, grid, 'C0', label='paper: Fz2/Fzf')
    # Fy2/Fyf for w = Fz^b with Fz1 + Fz2 = 2 Fzf: 2 x^b / (x^b + (2 - x)^b), x = Fz2/Fzf.
    ax2.plot(grid, 2.0 * grid ** split_exponent
             / (grid ** split_exponent + (2.0 - grid) ** split_exponent), 'C1',
             label=f'load-sensitive, exponent {split_exponent:g}')
    ax2.set_xlabel('Fz2 / Fzf')
    ax2.set_ylabel('Fy2 / Fyf')
    ax2.set_title('Relation 2: front right wheel, |ay| < 0.5 g')
    ax2.legend(fontsize=7)
    save_figure(fig, path)
