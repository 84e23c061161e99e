"""Wheel-speed spectra of road simulations and their figure (Umeno 1997, Figs. 1 and 8).

Offline analysis of :mod:`tpms_ros.simulation.road_simulator` results: how the torsional tire
mode and the driveline show in the simulated wheel speeds. Kept out of the simulator, which
synthesises data and draws nothing.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from scipy.signal import welch

from tpms_ros.simulation.road_simulator import RoadSimulationResult
from vehicle_monitor_common.figures import pyplot, save_figure


def wheel_speed_psd(result: RoadSimulationResult, wheel: int | tuple[int, int], *,
                    start_s: float = 0.0, stop_s: float | None = None,
                    segment_s: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Welch PSD of a measured wheel speed, or of the difference of two wheels' speeds.

    Args:
        result: a simulation result.
        wheel: wheel index, or a pair (a, b) for the difference w_a - w_b.
        start_s, stop_s: time window, s.
        segment_s: Welch segment length (sets the resolution 1/segment_s Hz).

    Returns:
        (frequency Hz, PSD (rad/s)^2/Hz).
    """
    fs = result.scenario.rates.wheel_speed_hz
    t = result.wheel_speed_t
    window = (t >= start_s) & (t <= (t[-1] if stop_s is None else stop_s))
    speeds = result.wheel_speed[window]
    signal = speeds[:, wheel] if isinstance(wheel, int) \
        else speeds[:, wheel[0]] - speeds[:, wheel[1]]
    nperseg = min(signal.size, int(round(segment_s * fs)))
    frequency, psd = welch(signal, fs=fs, nperseg=nperseg, detrend='linear')
    return frequency, psd


def plot_wheel_speed_psd(results: Mapping[str, RoadSimulationResult], path: str | Path, *,
                         wheels: Sequence[int | tuple[int, int]] = (1,), start_s: float = 0.0,
                         stop_s: float | None = None, max_hz: float = 80.0,
                         title: str | None = None) -> Path:
    """Plot wheel-speed PSDs of several runs on one axis (Umeno 1997, Fig. 1 style), as PNG.

    Args:
        results: label -> result (e.g. ``{'200 kPa': ..., '120 kPa': ...}``).
        path: PNG file to write.
        wheels: wheels to plot for each run: an index, or (a, b) for the difference
            w_a - w_b (e.g. ``(2, (2, 3))`` shows a driven wheel and the rear left-right
            difference, the Fig. 8 effect).
        start_s, stop_s: time window of each run, s.
        max_hz: upper frequency limit of the plot.
        title: figure title.

    Returns:
        The written path.
    """
    plt = pyplot()

    names = ('FL', 'FR', 'RL', 'RR')
    figure, axis = plt.subplots(figsize=(7.0, 4.5))
    for label, result in results.items():
        for wheel in wheels:
            frequency, psd = wheel_speed_psd(result, wheel, start_s=start_s, stop_s=stop_s)
            keep = frequency <= max_hz
            which = names[wheel] if isinstance(wheel, int) \
                else f'{names[wheel[0]]} - {names[wheel[1]]}'
            axis.semilogy(frequency[keep], psd[keep], label=f'{label}, {which}')
    axis.set_xlabel('frequency (Hz)')
    axis.set_ylabel('wheel speed PSD ((rad/s)$^2$/Hz)')
    axis.set_title(title or 'Wheel speed power spectrum')
    axis.grid(True, which='both', alpha=0.3)
    axis.legend()
    return save_figure(figure, path, dpi=120)
