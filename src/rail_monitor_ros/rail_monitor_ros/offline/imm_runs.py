"""Offline runs of the suspension IMM over a recording, and the paper's mode-probability
figure (Figs. 5-7)."""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path

import numpy as np

from rail_monitor_ros.core.rail_model import RailVehicleParams
from rail_monitor_ros.core.suspension_imm import N_OUTPUTS, SuspensionImm, SuspensionImmParams
from rail_monitor_ros.core.suspension_modes import SuspensionMode
from vehicle_monitor_common.figures import pyplot, save_figure


@dataclass(frozen=True)
class ImmRunResult:
    """An offline run (row k = sample k).

    Attributes:
        time: (N,) s.
        modes: the mode set.
        probability: (N, M).
        smoothed_probability: (N, M).
        mode_spring_ratio: (N, M) spring ratio of each mode (adaptive damper modes move).
        mode_damper_ratio: (M,).
        spring_ratio: (N,) probability-weighted estimate.
        damper_ratio: (N,).
        state: (N, n) combined state of the model (``SuspensionImm.state_names``).
        covariance: (N, n, n) combined covariance, or None (not stored).
        fault_detected: (N,) bool.
        fault_component: (N,) str.
        accepted: (N,) bool, measurement used.
        known_input: whether the known-input model was used.
        truth_spring_ratio: (N,) or None, for plots.
        truth_damper_ratio: (N,) or None.
    """

    time: np.ndarray
    modes: tuple[SuspensionMode, ...]
    probability: np.ndarray
    smoothed_probability: np.ndarray
    mode_spring_ratio: np.ndarray
    mode_damper_ratio: np.ndarray
    spring_ratio: np.ndarray
    damper_ratio: np.ndarray
    state: np.ndarray
    covariance: np.ndarray | None
    fault_detected: np.ndarray
    fault_component: np.ndarray
    accepted: np.ndarray
    known_input: bool
    truth_spring_ratio: np.ndarray | None = field(default=None)
    truth_damper_ratio: np.ndarray | None = field(default=None)

    def mode_index(self, name: str) -> int:
        """Index of a mode by name ('spring_150'); ValueError listing the names."""
        names = [m.name for m in self.modes]
        if name not in names:
            raise ValueError(f'unknown mode {name!r}; modes: {names}')
        return names.index(name)

    def first_time_above(self, name: str, threshold: float, after: float) -> float:
        """First time >= ``after`` at which the mode's smoothed probability exceeds the
        threshold, s (inf if never)."""
        column = self.smoothed_probability[:, self.mode_index(name)]
        hit = np.nonzero((self.time >= after) & (column > threshold))[0]
        return float(self.time[hit[0]]) if hit.size else math.inf

    def first_detection(self, component: str, after: float) -> float:
        """First time >= ``after`` the decision reports this component, s (inf if never)."""
        hit = np.nonzero((self.time >= after) & (self.fault_component == component))[0]
        return float(self.time[hit[0]]) if hit.size else math.inf


def run_suspension_imm(measurements: np.ndarray, known_inputs: np.ndarray | None = None,
                       params: SuspensionImmParams | None = None,
                       vehicle: RailVehicleParams | None = None, time: np.ndarray | None = None,
                       truth_spring_ratio: np.ndarray | None = None,
                       truth_damper_ratio: np.ndarray | None = None,
                       store_covariance: bool = False) -> ImmRunResult:
    """Run the IMM over a recording.

    Args:
        measurements: (N, 3) [bogie lateral accel, bogie yaw rate, body lateral accel].
        known_inputs: (N, k) known inputs per sample (see :meth:`SuspensionImm.step`: full
            car (N, 2) or (N, 4) track alignment; half car (N, 4) wheelset inputs), or None.
        params: the IMM's parameters.
        vehicle: model parameters (default: ``params.vehicle``).
        time: (N,) s; default k / sample_rate_hz.
        truth_spring_ratio, truth_damper_ratio: (N,) ground truth kept for plots.
        store_covariance: also keep the (N, n, n) combined covariance (slower).
    """
    z = np.asarray(measurements, dtype=float)
    if z.ndim != 2 or z.shape[1] != N_OUTPUTS:
        raise ValueError(f'measurements must have shape (N, {N_OUTPUTS}), got {z.shape}')
    imm = SuspensionImm(params, vehicle)
    u = None
    if known_inputs is not None:
        u = np.asarray(known_inputs, dtype=float)
        if u.ndim != 2 or u.shape[0] != z.shape[0] or u.shape[1] not in imm._known_sizes[1:]:
            raise ValueError(f'known_inputs must have shape ({z.shape[0]}, one of '
                             f'{imm._known_sizes[1:]}), got {u.shape}')
    n, m = z.shape[0], imm.n_modes
    t = np.arange(n) / imm.params.sample_rate_hz if time is None else np.asarray(time, float)
    if t.shape != (n,):
        raise ValueError(f'time must have shape ({n},), got {t.shape}')
    prob = np.empty((n, m))
    smooth = np.empty((n, m))
    mode_spring = np.empty((n, m))
    spring = np.empty(n)
    damper = np.empty(n)
    state = np.empty((n, imm.n_states))
    cov = np.empty((n, imm.n_states, imm.n_states)) if store_covariance else None
    detected = np.zeros(n, dtype=bool)
    component = np.empty(n, dtype=object)
    accepted = np.isfinite(z).all(axis=1)
    if u is not None:
        u_ok = np.isfinite(u).all(axis=1)
    for k in range(n):
        zk = z[k] if accepted[k] else None
        uk = u[k] if u is not None and u_ok[k] else None
        imm.advance(zk, uk)
        prob[k] = imm.mu
        smooth[k] = imm.smoothed
        mode_spring[k] = imm._mode_spring_used
        spring[k] = imm.spring_ratio
        damper[k] = imm.damper_ratio
        if cov is not None:
            state[k], cov[k] = imm.combined()
        else:
            state[k] = imm.combined_state()
        detected[k] = imm.fault.detected
        component[k] = imm.fault.component
    return ImmRunResult(t, imm.modes, prob, smooth, mode_spring, imm.mode_damper_ratio.copy(),
                        spring, damper, state, cov, detected, component, accepted,
                        u is not None, truth_spring_ratio, truth_damper_ratio)


def plot_mode_probabilities(result: ImmRunResult, path: str | Path, title: str = '') -> Path:
    """The paper's Figs. 5-7 in one PNG: smoothed mode probabilities, spring and damper ratio.

    Top: smoothed probability of every mode over time (the normal, spring and damper families
    in distinct colour maps); middle: estimated spring ratio with the truth when known;
    bottom: estimated damper ratio with the truth; the decision's fault periods shaded.

    Args:
        result: an offline run (:func:`run_suspension_imm`).
        path: PNG path.
        title: figure title.

    Returns:
        The path written.
    """
    plt = pyplot()

    fig, (ax_p, ax_s, ax_d) = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    t = result.time
    springs = [i for i, m in enumerate(result.modes) if m.kind == 'spring']
    dampers = [i for i, m in enumerate(result.modes) if m.kind == 'damper']
    spring_colours = plt.get_cmap('autumn')(np.linspace(0.0, 0.8, max(len(springs), 1)))
    damper_colours = plt.get_cmap('winter')(np.linspace(0.0, 0.9, max(len(dampers), 1)))
    for index, mode in enumerate(result.modes):
        if mode.kind == 'normal':
            colour = 'black'
        elif mode.kind == 'spring':
            colour = spring_colours[springs.index(index)]
        else:
            colour = damper_colours[dampers.index(index)]
        ax_p.plot(t, result.smoothed_probability[:, index], color=colour, lw=1.0,
                  label=f'{mode.number}: {mode.name}')
    ax_p.set_ylabel('smoothed mode probability')
    ax_p.set_ylim(-0.02, 1.02)
    ax_p.legend(ncol=4, fontsize=7, loc='upper left')
    for axis, estimate, truth, label in (
            (ax_s, result.spring_ratio, result.truth_spring_ratio, 'spring ratio Ksy / nominal'),
            (ax_d, result.damper_ratio, result.truth_damper_ratio,
             'damper ratio Csy / nominal')):
        axis.plot(t, estimate, label='IMM estimate')
        if truth is not None:
            axis.plot(t, truth, 'k--', label='truth')
        axis.set_ylabel(label)
        axis.grid(True, alpha=0.3)
        axis.legend(loc='upper left')
    for axis in (ax_p, ax_s, ax_d):
        axis.fill_between(t, 0, 1, where=result.fault_detected, color='red', alpha=0.08,
                          transform=axis.get_xaxis_transform(), label=None)
    ax_d.set_xlabel('time, s  (shaded: fault declared)')
    mode_label = 'known inputs' if result.known_input else 'inputs as process noise'
    fig.suptitle(title or f'IMM suspension monitor ({mode_label})')
    return save_figure(fig, path, dpi=110)
