"""Held-out family results: one row per target, committed, shown under the main job's scoreboard.

The family evaluations (``benchmarks/eval_tpms_family.py``, ``benchmarks/eval_rail_family.py``,
``benchmarks/eval_lateral_force_family.py``) take 10-40 minutes each, too long for the main
job. Each writes its figures against the issue's
targets into a small JSON file committed under ``docs/results/`` (``--scoreboard PATH``); the
main job reads those files and prints them as a second table, headed with the commit and date
they were measured at. This module is the one definition of that file: the row, the file, where
the main job finds it, and how the table is rendered. ROS-free.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
import datetime
import json
import math
import os
from pathlib import Path
import subprocess
from typing import Any

RESULTS_SUBDIR = Path('docs') / 'results'
SCHEMA_VERSION = 1


@dataclass(frozen=True)
class FamilyFile:
    """One family evaluation's committed result file.

    Attributes:
        title: what the table's heading calls it.
        name: file name under ``docs/results/``.
        command: the command that regenerates the file (a full run of the evaluation).
        analysis: the page that explains the figures: per car, why a target is missed, what
            was tried ('' for none).
    """

    title: str
    name: str
    command: str
    analysis: str = ''


FAMILY_FILES = (
    # The fault cases and the 30-minute nominal drives run with other timing, then merge.
    FamilyFile('TPMS methods on the held-out cars (issue 21)', 'tpms_family.json',
               'python benchmarks/eval_tpms_family.py --out /tmp/tpms_family.json && '
               'python benchmarks/eval_tpms_family.py --cases nominal --fault-s 1890 '
               '--observe-s 0 --out /tmp/tpms_nominal.json && '
               'python benchmarks/eval_tpms_family.py --report /tmp/tpms_family.json '
               '/tmp/tpms_nominal.json --scoreboard docs/results/tpms_family.json',
               'docs/methods/tpms_family_evaluation.md'),
    FamilyFile('Rail estimators on the held-out cars and tracks (issue 19)', 'rail_family.json',
               'python benchmarks/eval_rail_family.py --creep-track-model spectrum '
               '--healthy-s 900 --json /tmp/rail_family.json '
               '--scoreboard docs/results/rail_family.json',
               'docs/methods/rail_family_evaluation.md'),
    FamilyFile('Lateral force observer on the held-out cars (the family of issue 21)',
               'lateral_force_family.json',
               'python benchmarks/eval_lateral_force_family.py --seeds held-out '
               '--json /tmp/lateral_force_family.json '
               '--scoreboard docs/results/lateral_force_family.json',
               'docs/methods/lateral_force_observer.md'),
)


@dataclass(frozen=True)
class FamilyRow:
    """One target of an issue, judged over the held-out family.

    Attributes:
        target: short name, e.g. ``'fused: 25 % puncture'``.
        text: the target as the issue states it.
        passed: cases that meet the target.
        cases: cases judged.
        case_unit: what a case is (``'runs'``, ``'tires'``, ``'cars'``).
        required_share: share of the cases that must pass (1.0: every case).
        worst_value: the worst case's figure; None when it has none (a missed detection, a
            wrong component).
        worst_unit: unit of ``worst_value``.
        worst_case: which car and case the worst is, and what happened when there is no value.
        met: whether the target is met (the share, and any further condition in ``detail``).
        detail: further evidence (unknown readings, minutes judged, ...).
    """

    target: str
    text: str
    passed: int
    cases: int
    case_unit: str
    required_share: float
    worst_value: float | None
    worst_unit: str
    worst_case: str
    met: bool
    detail: str = ''

    def share_met(self) -> bool:
        """Whether the share of passing cases reaches the required share (no case: no)."""
        return self.cases > 0 and self.passed >= self.required_share * self.cases - 1e-9

    def pass_text(self) -> str:
        """``'40 / 72 runs (56 %)'``."""
        share = f' ({100 * self.passed / self.cases:.0f} %)' if self.cases else ''
        return f'{self.passed} / {self.cases} {self.case_unit}{share}'

    def required_text(self) -> str:
        """``'>= 95 %'`` or ``'every'``."""
        return 'every' if self.required_share >= 1.0 else f'>= {100 * self.required_share:.0f} %'

    def worst_text(self) -> str:
        """The worst case's figure and where it is."""
        if self.worst_value is None or not math.isfinite(self.worst_value):
            return self.worst_case or '-'
        value = f'{self.worst_value:.3g}' if abs(self.worst_value) < 10 else \
            f'{self.worst_value:.1f}'
        return f'{value} {self.worst_unit}'.strip() + f' ({self.worst_case})'


@dataclass(frozen=True)
class FamilyResults:
    """One family evaluation's results against its issue's targets.

    Attributes:
        evaluation: the script that measured them (``benchmarks/eval_tpms_family.py``).
        commit: the commit the evaluation ran on.
        date: the date of the run (ISO, UTC).
        seeds: the car seeds judged.
        held_out: whether every seed is of the held-out set (nothing tuned on them).
        rows: one per target.
        settings: the run's settings (durations, options), for the record.
    """

    evaluation: str
    commit: str
    date: str
    seeds: tuple[int, ...]
    held_out: bool
    rows: tuple[FamilyRow, ...]
    settings: dict[str, Any] = field(default_factory=dict)

    def met_count(self) -> int:
        """Targets met."""
        return sum(row.met for row in self.rows)


def write_family_results(path: str | os.PathLike[str], results: FamilyResults) -> Path:
    """Write the result file (JSON, stable key order, one row per target)."""
    data = {'schema': SCHEMA_VERSION, **asdict(results)}
    data['seeds'] = list(results.seeds)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=1, allow_nan=False, default=_finite) + '\n',
                    encoding='utf-8')
    return path


def _finite(value: Any) -> Any:
    if hasattr(value, 'item'):  # numpy scalars
        return value.item()
    raise TypeError(f'cannot write {type(value).__name__} to JSON')


def load_family_results(path: str | os.PathLike[str]) -> FamilyResults:
    """Read a result file.

    Raises:
        FileNotFoundError: no such file.
        ValueError: not a result file of this schema.
    """
    data = json.loads(Path(path).read_text(encoding='utf-8'))
    if not isinstance(data, dict) or data.get('schema') != SCHEMA_VERSION:
        raise ValueError(f'{path}: not a family result file of schema {SCHEMA_VERSION}')
    try:
        return FamilyResults(
            evaluation=data['evaluation'], commit=data['commit'], date=data['date'],
            seeds=tuple(int(s) for s in data['seeds']), held_out=bool(data['held_out']),
            rows=tuple(FamilyRow(**row) for row in data['rows']),
            settings=dict(data.get('settings', {})))
    except (KeyError, TypeError) as exc:
        raise ValueError(f'{path}: malformed family result file ({exc})') from exc


def results_dir() -> Path:
    """``docs/results`` of the workspace, whether the code runs from the source tree or from the
    colcon install space inside it; else ``./docs/results``."""
    for parent in Path(__file__).resolve().parents:
        if (parent / RESULTS_SUBDIR).is_dir():
            return parent / RESULTS_SUBDIR
    return RESULTS_SUBDIR


@dataclass(frozen=True)
class FamilyTable:
    """A family file as the scoreboard shows it: its results, or why there are none."""

    source: FamilyFile
    results: FamilyResults | None
    problem: str = ''


def load_family_tables(directory: Path | None = None,
                       files: Iterable[FamilyFile] = FAMILY_FILES) -> list[FamilyTable]:
    """Every family file from ``directory`` (default :func:`results_dir`); a missing or unreadable
    file gives a table saying so instead of an error."""
    directory = results_dir() if directory is None else directory
    tables = []
    for source in files:
        path = directory / source.name
        try:
            tables.append(FamilyTable(source, load_family_results(path)))
        except FileNotFoundError:
            tables.append(FamilyTable(source, None, f'not measured yet: no {_shown(path)}'))
        except ValueError as exc:  # json.JSONDecodeError is a ValueError
            tables.append(FamilyTable(source, None, f'unreadable: {exc}'))
    return tables


def _shown(path: Path) -> Path:
    """The path relative to the working directory when inside it (the README shows
    ``docs/results/...``, not this machine's workspace path)."""
    try:
        return path.resolve().relative_to(Path.cwd().resolve())
    except ValueError:
        return path


def seeds_text(seeds: Sequence[int]) -> str:
    """``'21000-21023 (24 cars)'``; runs of consecutive seeds joined."""
    ordered = sorted(set(seeds))
    parts: list[str] = []
    start = previous = None
    for seed in [*ordered, None]:
        if seed is not None and previous is not None and seed == previous + 1:
            previous = seed
            continue
        if start is not None:
            parts.append(str(start) if start == previous else f'{start}-{previous}')
        start = previous = seed
    return f'{", ".join(parts)} ({len(ordered)} car{"s" if len(ordered) != 1 else ""})'


def heading_text(table: FamilyTable) -> str:
    """The line above a family's rows: what, on which cars, measured when, where it is
    explained, regenerated how."""
    source = table.source
    results = table.results
    analysis = f' Why, per car: {source.analysis}.' if source.analysis else ''
    if results is None:
        return f'{source.title}: {table.problem}.{analysis} Regenerate: `{source.command}`'
    cars = ('held-out cars' if results.held_out else 'cars (not all held out)')
    return (f'{source.title}: {cars} {seeds_text(results.seeds)}, measured at commit '
            f'{results.commit[:7]} on {results.date}; {results.met_count()} of '
            f'{len(results.rows)} targets met.{analysis} Regenerate: `{source.command}`')


def _cell(text: str) -> str:
    return text.replace('|', '\\|')


def render_family_markdown(tables: Sequence[FamilyTable]) -> str:
    """The held-out family tables in Markdown, one per family file."""
    lines: list[str] = []
    for table in tables:
        lines += [heading_text(table), '']
        if table.results is None:
            continue
        lines += ['| target | required | passed | worst case | result | evidence |',
                  '| --- | --- | --- | --- | --- | --- |']
        for row in table.results.rows:
            verdict = '**pass**' if row.met else '**FAIL**'
            lines.append(f'| {_cell(row.text)} | {row.required_text()} | {row.pass_text()} | '
                         f'{_cell(row.worst_text())} | {verdict} | {_cell(row.detail) or "-"} |')
        lines.append('')
    return '\n'.join(lines).rstrip('\n')


FAMILY_INTRO = ('Measured by the family evaluations (too long for the main job) on cars nothing '
                'was tuned on, committed under docs/results/ and read from there, not run here.')


def render_family_section(tables: Sequence[FamilyTable], heading: str) -> str:
    """A Markdown section: ``heading``, what the tables are, the tables."""
    return '\n\n'.join([heading, FAMILY_INTRO, render_family_markdown(tables)])


def render_family_text(tables: Sequence[FamilyTable]) -> str:
    """The held-out family tables as fixed-width text (the printed scoreboard)."""
    lines: list[str] = []
    for table in tables:
        lines.append(heading_text(table))
        if table.results is None:
            continue
        header = ('target', 'required', 'passed', 'worst case', 'result')
        rows = [(row.target, row.required_text(), row.pass_text(), row.worst_text(),
                 'PASS' if row.met else 'FAIL') for row in table.results.rows]
        widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
        lines.append('  '.join(f'{c:<{w}}' for c, w in zip(header, widths, strict=True)))
        lines.append('  '.join('-' * w for w in widths))
        lines += ['  '.join(f'{c:<{w}}' for c, w in zip(r, widths, strict=True)).rstrip()
                  for r in rows]
    return '\n'.join(lines)


def current_commit(directory: str | os.PathLike[str] = '.') -> str:
    """HEAD of the git checkout at ``directory``; 'unknown' outside one."""
    try:
        out = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=directory, capture_output=True,
                             text=True, check=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return 'unknown'
    return out.stdout.strip()


def today() -> str:
    """Today's date, ISO, UTC."""
    return datetime.datetime.now(datetime.UTC).date().isoformat()
