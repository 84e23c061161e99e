"""Lateral acceleration spectra of rail simulations and their figure (Mori et al., Fig. 4).

Offline analysis of :mod:`rail_monitor_ros.simulation.rail_simulator` results: how a weakened
or stiffened secondary suspension shows in the bogie and body accelerations. Kept out of the
simulator, which synthesises data and draws nothing.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import scipy.signal

from rail_monitor_ros.core.rail_model import full_car_state_space, vehicle_modes
from rail_monitor_ros.simulation.rail_simulator import RailSimulationResult
from vehicle_monitor_common.figures import pyplot, save_figure

ACCELERATION_SIGNALS = ('body', 'bogie')


def acceleration_psd(result: RailSimulationResult, signal: str = 'body',
                     t_min: float = 0.0, t_max: float | None = None,
                     segment_seconds: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """Welch PSD of the measured lateral acceleration over a time window.

    Args:
        result: a simulation result.
        signal: 'body' (above the front bogie) or 'bogie' (front bogie).
        t_min: window start, s.
        t_max: window end, s (None: the end of the run).
        segment_seconds: Welch segment length, s (sets the resolution, 1/segment Hz).

    Returns:
        (frequency Hz, PSD (m/s^2)^2/Hz).
    """
    if signal not in ACCELERATION_SIGNALS:
        raise ValueError(f'signal must be one of {ACCELERATION_SIGNALS}, got {signal!r}')
    data = result.body_lateral_accel if signal == 'body' else result.bogie_lateral_accel
    end = result.time[-1] if t_max is None else t_max
    window = (result.time >= t_min) & (result.time <= end)
    fs = result.scenario.output_rate
    nperseg = int(round(segment_seconds * fs))
    if window.sum() < nperseg:
        raise ValueError(f'window [{t_min}, {end}] s is shorter than one segment '
                         f'({segment_seconds} s)')
    freq, psd = scipy.signal.welch(data[window], fs=fs, nperseg=nperseg)
    return freq, psd


def plot_acceleration_psd(results: Mapping[str, RailSimulationResult], path: str | Path,
                          signal: str = 'body', t_min: float = 0.0, t_max: float | None = None,
                          max_frequency: float = 20.0) -> Path:
    """Paper Fig. 4 style: the time signals look alike, their PSDs do not.

    Top: a 5 s excerpt of the measured lateral acceleration of each run; bottom: its Welch
    PSD (log scale) with the nominal body suspension modes marked. Writes a PNG.

    Args:
        results: label -> result, e.g. {'healthy': ..., 'spring 150 %': ...}.
        path: PNG path.
        signal: 'body' or 'bogie'.
        t_min: PSD window start, s.
        t_max: PSD window end, s.
        max_frequency: upper limit of the PSD axis, Hz.

    Returns:
        The path written.
    """
    plt = pyplot()

    if not results:
        raise ValueError('results must not be empty')
    fig, (ax_time, ax_psd) = plt.subplots(2, 1, figsize=(8, 7))
    for label, result in results.items():
        data = result.body_lateral_accel if signal == 'body' else result.bogie_lateral_accel
        excerpt = (result.time >= t_min) & (result.time <= t_min + 5.0)
        ax_time.plot(result.time[excerpt], data[excerpt], lw=0.8, label=label)
        freq, psd = acceleration_psd(result, signal, t_min, t_max)
        band = (freq > 0.0) & (freq <= max_frequency)
        ax_psd.semilogy(freq[band], psd[band], label=label)
    first = next(iter(results.values()))
    params = first.scenario.vehicle
    for mode in vehicle_modes(full_car_state_space(params), params):
        if mode.coordinate in ('y_v', 'psi_v'):
            ax_psd.axvline(mode.frequency_hz, color='grey', ls=':', lw=0.8)
    ax_time.set_xlabel('time, s')
    ax_time.set_ylabel(f'{signal} lateral accel, m/s$^2$')
    ax_time.legend(loc='upper right')
    ax_psd.set_xlabel('frequency, Hz  (dotted: nominal body lateral and yaw modes)')
    ax_psd.set_ylabel('PSD, (m/s$^2$)$^2$/Hz')
    ax_psd.legend(loc='upper right')
    ax_psd.grid(True, which='both', alpha=0.3)
    return save_figure(fig, path, dpi=120)
