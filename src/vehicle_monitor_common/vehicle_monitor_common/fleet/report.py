"""The fleet report: vehicles ranked by concern, per-vehicle trends, fleet-wide histograms.

Read from the job's Parquet datasets (so a report can be redrawn without screening again):
``report.md`` beside them, its figures in ``figures/``.

Concern, per vehicle, from its latest recording of each method and its trends:
a tire warned by the voter (3 per tire), a suspension fault declared (3), spring or damper
ratio drifting away from 1 over its recordings (the drift x 10), time of low adhesion
(1 per 10 s), a recording that could not be screened (1). The score only orders the list;
the columns say why.
"""

from __future__ import annotations

from collections.abc import Sequence
import math
import os
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from vehicle_monitor_common.fleet.job import read_table  # noqa: E402
from vehicle_monitor_common.fleet.summaries import TIRES  # noqa: E402

#: What the fleet-wide histogram of each method shows.
HISTOGRAM_FIGURES = {
    'tpms_warning': ('warnings_raised', 'warnings raised per recording'),
    'suspension': ('spring_ratio_mean', 'mean spring ratio per recording'),
    'creep_factor': ('min_creep_factor', 'lowest creep factor per recording'),
    'creep_factor_imu': ('min_creep_factor', 'lowest creep factor per recording'),
}


def _latest(rows: pd.DataFrame) -> pd.Series | None:
    if rows.empty:
        return None
    return rows.sort_values('time', na_position='first').iloc[-1]


def _drift(rows: pd.DataFrame, column: str) -> float:
    """Last minus first value of a per-recording figure (NaN with fewer than two)."""
    values = rows.sort_values('time')[column].dropna()
    return float(values.iloc[-1] - values.iloc[0]) if len(values) >= 2 else math.nan


def vehicle_concern(summary: pd.DataFrame) -> pd.DataFrame:
    """One row per vehicle: what concerns it and a score to rank by (see module docstring)."""
    rows = []
    for vehicle, own in summary.groupby('vehicle', sort=True):
        recordings = own['recording'].nunique()
        errors = own.loc[own['error'].fillna('') != '', 'recording'].nunique()
        ok = own[own['error'].fillna('') == '']
        warned: list[str] = []
        latest = _latest(ok[ok['method'] == 'tpms_warning'])
        if latest is not None:
            warned = [t.upper() for t in TIRES
                      if not pd.isna(latest[f'first_warning_s_{t}'])]
        suspension = ok[ok['method'] == 'suspension']
        last_suspension = _latest(suspension)
        faults = '' if last_suspension is None else str(last_suspension['fault_modes'] or '')
        spring_drift = _drift(suspension, 'spring_ratio_mean')
        damper_drift = _drift(suspension, 'damper_ratio_mean')
        creep = ok[ok['method'].str.startswith('creep_factor')]
        low_s = float(creep['low_adhesion_s'].fillna(0).max()) if not creep.empty else 0.0
        min_creep = float(creep['min_creep_factor'].min()) if not creep.empty else math.nan
        drift = max(abs(np.nan_to_num(spring_drift)), abs(np.nan_to_num(damper_drift)))
        score = (3 * len(warned) + 3 * bool(faults) + 10 * drift + low_s / 10 + errors)
        rows.append({'vehicle': vehicle, 'score': score, 'recordings': recordings,
                     'last_date': str(own['date'].max()), 'tires_warned': ','.join(warned),
                     'suspension_fault': faults, 'spring_drift': spring_drift,
                     'damper_drift': damper_drift, 'min_creep_factor': min_creep,
                     'low_adhesion_s': low_s, 'errors': errors})
    table = pd.DataFrame(rows)
    if table.empty:
        return table
    return table.sort_values(['score', 'vehicle'], ascending=[False, True]).reset_index(
        drop=True)


def _cell(value: Any) -> str:
    if isinstance(value, float):
        return '' if math.isnan(value) else f'{value:.3g}'
    return str(value)


def markdown_table(table: pd.DataFrame) -> list[str]:
    """A table as Markdown lines (floats to 3 significant digits, NaN empty)."""
    if table.empty:
        return ['(none)']
    lines = ['| ' + ' | '.join(table.columns) + ' |', '|' + ' --- |' * len(table.columns)]
    lines += ['| ' + ' | '.join(_cell(v) for v in row) + ' |'
              for row in table.itertuples(index=False)]
    return lines


# One panel of a trend figure: the summary column, its axis label, and the value a recording
# without one is drawn at (None: left as a gap).
Panel = tuple[str, str, float | None]
SUSPENSION_PANELS: tuple[Panel, ...] = (
    ('spring_ratio_mean', 'spring ratio (mean of drive)', None),
    ('damper_ratio_mean', 'damper ratio (mean of drive)', None))
WARNING_PANELS: tuple[Panel, ...] = (('max_confidence', 'peak warning confidence', 0.0),)


def _trend_figure(summary: pd.DataFrame, path: Path, method: str, panels: Sequence[Panel],
                  height: float) -> bool:
    """One line per vehicle over recording time in each panel, for the summaries of ``method``;
    False (nothing drawn) when it has none with a time."""
    rows = summary[(summary['method'] == method) & summary['time'].notna()]
    if rows.empty:
        return False
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, height), sharex=True, squeeze=False)
    for vehicle, own in rows.groupby('vehicle', sort=True):
        own = own.sort_values('time')
        for ax, (column, _, missing) in zip(axes[:, 0], panels, strict=True):
            values = own[column] if missing is None else own[column].fillna(missing)
            ax.plot(own['time'], values, marker='o', label=vehicle)
    for ax, (_, label, _) in zip(axes[:, 0], panels, strict=True):
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel('recording time')
    axes[0, 0].legend(fontsize='small', ncol=4)
    fig.autofmt_xdate()
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def _histograms(summary: pd.DataFrame, path: Path) -> bool:
    methods = [m for m in sorted(summary['method'].dropna().unique()) if m]
    if not methods:
        return False
    fig, axes = plt.subplots(len(methods), 1, figsize=(7, 2.2 * len(methods)), squeeze=False)
    for ax, method in zip(axes[:, 0], methods, strict=True):
        column, label = HISTOGRAM_FIGURES.get(method, ('max_confidence',
                                                       'peak confidence per recording'))
        values = summary.loc[summary['method'] == method, column].dropna().astype(float)
        if column == 'max_confidence':
            values = values.fillna(0)
        ax.hist(values, bins=20)
        ax.set_title(f'{method}: {label}', fontsize='small')
        ax.set_ylabel('recordings')
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return True


def write_report(out: str | os.PathLike[str]) -> Path:
    """Write ``report.md`` and its figures from the results in ``out``; its path."""
    out = Path(out)
    summary = read_table(out, 'summary').to_pandas()
    events = read_table(out, 'events').to_pandas()
    figures = out / 'figures'
    figures.mkdir(parents=True, exist_ok=True)
    concern = vehicle_concern(summary)
    lines = ['# Fleet report', '',
             f'{summary["recording"].nunique()} recording(s) of {summary["vehicle"].nunique()} '
             f'vehicle(s), {len(events)} episode(s).', '',
             '## Vehicles ranked by concern', '', *markdown_table(concern), '']
    worth = concern[concern['score'] > 0] if not concern.empty else concern
    if not worth.empty:
        lines += ['## Recordings worth a look', '']
        for vehicle in worth['vehicle']:
            own = summary[(summary['vehicle'] == vehicle)]
            flagged = own[(own['warnings_raised'].fillna(0) > 0)
                          | (own['fault_episodes'].fillna(0) > 0)
                          | (own['low_adhesion_s'].fillna(0) > 0)
                          | (own['error'].fillna('') != '')]
            for recording in sorted(flagged['recording'].unique()):
                what = flagged[flagged['recording'] == recording]
                reasons = sorted({r.error or r.method for r in what.itertuples()})
                lines.append(f'- `{recording}`: {", ".join(reasons)}')
        lines.append('')
    errors = summary[summary['error'].fillna('') != ''].drop_duplicates('recording')
    if not errors.empty:
        lines += ['## Recordings that could not be screened', '']
        lines += [f'- `{r.recording}` ({r.path}): {r.error}' for r in errors.itertuples()]
        lines.append('')
    lines += ['## Trends', '']
    if _trend_figure(summary, figures / 'suspension_trend.png', 'suspension', SUSPENSION_PANELS,
                     6.0):
        lines += ['![suspension trend](figures/suspension_trend.png)', '']
    if _trend_figure(summary, figures / 'tpms_trend.png', 'tpms_warning', WARNING_PANELS, 3.5):
        lines += ['![TPMS trend](figures/tpms_trend.png)', '']
    lines += ['## Fleet-wide, per method', '']
    if _histograms(summary, figures / 'histograms.png'):
        lines += ['![histograms](figures/histograms.png)', '']
    path = out / 'report.md'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return path
