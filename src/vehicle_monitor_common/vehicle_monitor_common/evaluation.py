"""Scoring a recorded run against ground truth: the vocabulary shared by both domains.

ROS-free (numpy, rosbags through :mod:`bag_io`). A domain package describes itself with a
:class:`Domain` (its graph file, its shipped scenarios, how to synthesise a scenario file and how
to evaluate a recording) and registers a factory under the ``vehicle_monitor.evaluations``
entry-point group of its setup.cfg::

    [options.entry_points]
    vehicle_monitor.evaluations =
        road = tpms_ros.offline.evaluation:domain

The main job (``monitor_demo``) and the evaluation CLI (``evaluate``) discover the domains
through that group, so this package never imports a domain package. An evaluation yields one
:class:`Metric` per method and key figure: the value computed from the run, the docs/targets.md
target
and whether it was met. Without ground truth the metrics carry what the estimators said (first
warning, final estimate) and no target or verdict.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from importlib.metadata import entry_points
import json
import math
import os
from pathlib import Path
import re
from typing import Any

import numpy as np

from vehicle_monitor_common.bag_io import bag_topics, messages_to_series, read_messages
from vehicle_monitor_common.family_results import (
    FAMILY_INTRO,
    FamilyTable,
    render_family_section,
    render_family_text,
)
from vehicle_monitor_common.series import TopicSeries

EVALUATION_GROUP = 'vehicle_monitor.evaluations'


@dataclass(frozen=True)
class Metric:
    """One key figure of one method in one scenario.

    Attributes:
        method: method name as the scoreboard shows it, e.g. ``'tpms fused'``.
        figure: what is measured, e.g. ``'detection time'``.
        value: the measured value; None when the run does not allow it (no truth, no output).
        unit: unit of ``value`` (``'s'``, ``'kPa'``, ``'%'``, ``''``).
        target: the docs/targets.md target as text (``'<= 60 s'``); empty without truth.
        passed: whether the target is met; None when there is no target (no truth).
        detail: one line of evidence (which tires, counts of false warnings, ...).
    """

    method: str
    figure: str
    value: float | None
    unit: str
    target: str = ''
    passed: bool | None = None
    detail: str = ''

    def value_text(self) -> str:
        """The value with its unit, or 'n/a'."""
        if self.value is None or not math.isfinite(self.value):
            return 'n/a'
        magnitude = abs(self.value)
        text = (f'{self.value:.3g}' if magnitude < 10 else f'{self.value:.1f}'
                if magnitude < 1000 else f'{self.value:.0f}')
        return f'{text} {self.unit}'.strip()

    def verdict(self) -> str:
        """PASS, FAIL or '-' (no target)."""
        return '-' if self.passed is None else 'PASS' if self.passed else 'FAIL'


@dataclass(frozen=True)
class Evaluation:
    """Everything an evaluation of one recorded run produced."""

    scenario: str
    has_truth: bool
    metrics: tuple[Metric, ...]
    figures: tuple[str, ...] = ()  # PNG file names, relative to the figure directory


@dataclass(frozen=True)
class Scenario:
    """A shipped scenario the main job replays through a domain's graph.

    Attributes:
        name: scenario name (the shipped bag's directory name).
        bag: the bag to replay.
        description: one line for the report.
        methods: methods the scoreboard shows for this scenario (empty: every method the
            evaluation can score).
    """

    name: str
    bag: Path
    description: str = ''
    methods: tuple[str, ...] = ()


@dataclass(frozen=True)
class Domain:
    """How a domain package plugs into the main job and the evaluation CLI.

    Attributes:
        name: ``'road'`` or ``'rail'``.
        graph: the domain's graph YAML (composed runner format).
        player: name of the node in ``graph`` that replays a bag (its ``bag`` parameter is set).
        recorder: name of the recorder node in ``graph`` (its ``bag`` parameter is set).
        input_topics: topics only this domain's bags carry (a bag with any of them is this
            domain's).
        sync_topics: the estimator outputs that pace the replay (for the graph's player).
        scenarios: what the main job runs.
        evaluate: ``(series, scenario name, figure directory, methods)`` -> Evaluation; series
            as :func:`read_stamped_series` returns them; methods filters the metrics (empty:
            all).
        synthesize: ``(scenario YAML, seed or None)`` -> topics of a simulated run with truth.
        is_scenario: whether a scenario YAML file is this domain's (it loads without error).
        run_parameters: ``(run directory)`` -> per-node parameter overrides for one run (e.g.
            calibration files kept in the run directory, not in ~/.ros).
        read_topics: topics the evaluation reads from a recording (empty: all).
    """

    name: str
    graph: Path
    player: str
    recorder: str
    input_topics: tuple[str, ...]
    sync_topics: tuple[str, ...]
    scenarios: tuple[Scenario, ...]
    evaluate: Callable[[Mapping[str, TopicSeries], str, Path, Sequence[str]], Evaluation]
    synthesize: Callable[[Path, int | None], dict[str, TopicSeries]]
    is_scenario: Callable[[Path], bool]
    run_parameters: Callable[[Path], dict[str, dict[str, Any]]] = field(
        default=lambda run_dir: {})
    read_topics: tuple[str, ...] = ()


def domains() -> list[Domain]:
    """Every domain registered under the ``vehicle_monitor.evaluations`` entry-point group."""
    found = []
    for entry_point in sorted(entry_points(group=EVALUATION_GROUP), key=lambda e: e.name):
        factory = entry_point.load()
        found.append(factory())
    return found


def domain_of_bag(path: str | os.PathLike[str], candidates: Iterable[Domain]) -> Domain:
    """The domain whose input topics the bag carries.

    Raises:
        ValueError: no registered domain recognises the bag.
    """
    topics = set(bag_topics(path))
    candidates = list(candidates)
    for domain in candidates:
        if topics & set(domain.input_topics):
            return domain
    raise ValueError(f'{path}: none of the domains ({", ".join(d.name for d in candidates)}) '
                     f'knows its topics ({", ".join(sorted(topics))})')


# ---------------------------------------------------------------------------------------------
# Reading a recording


def read_stamped_series(path: str | os.PathLike[str], topics: Iterable[str] | None = None,
                        ) -> dict[str, TopicSeries]:
    """Topics of a bag as column-wise series stamped with their ``header.stamp``.

    A recorder logs messages at arrival time; every output of this product is stamped with
    the input sample it answers, so the header stamp is the time to score against truth.
    Messages without a header keep their log time. Topics absent from the bag are skipped.
    """
    available = bag_topics(path)
    wanted = [t for t in (available if topics is None else topics) if t in available]
    collected: dict[str, tuple[str, list[int], list[Any]]] = {}
    for topic, msgtype, log_ns, msg in read_messages(path, wanted):
        header = getattr(msg, 'header', None)
        stamp = (int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)
                 if header is not None else int(log_ns))
        entry = collected.setdefault(topic, (msgtype, [], []))
        entry[1].append(stamp)
        entry[2].append(msg)
    series = {}
    for topic, (msgtype, stamps, messages) in collected.items():
        order = np.argsort(np.asarray(stamps, dtype=np.int64), kind='stable')
        series[topic] = messages_to_series(msgtype, [stamps[i] for i in order],
                                           [messages[i] for i in order])
    return series


def seconds(series: TopicSeries, t0_ns: int = 0) -> np.ndarray:
    """Stamps of a series in seconds from ``t0_ns``."""
    return (np.asarray(series.stamps_ns, dtype=np.int64) - t0_ns) * 1e-9


def selected_methods(methods: Sequence[str], known: Iterable[str]) -> set[str]:
    """The methods a domain's ``evaluate`` scores: ``methods``, or all ``known`` when empty.

    Raises:
        ValueError: a method the domain does not know.
    """
    known = list(known)
    unknown = sorted(set(methods) - set(known))
    if unknown:
        raise ValueError(f'methods: unknown {unknown[0]!r} (known: {", ".join(known)})')
    return set(methods or known)


def start_ns(series: Mapping[str, TopicSeries]) -> int:
    """Earliest stamp over all series (the run's time origin), 0 if there is none."""
    firsts = [int(s.stamps_ns[0]) for s in series.values() if len(s)]
    return min(firsts) if firsts else 0


@dataclass(frozen=True)
class MethodScoring:
    """How a domain scores one of its methods.

    Attributes:
        key: the method's key (what ``evaluate``'s ``methods`` select).
        score: ``(series, t0 ns)`` -> its key figures: a list, one Metric, or None (nothing to
            score in this recording).
        plot: ``(series, PNG path, t0 ns)`` -> the path written.
        figure: the PNG's file name (after the paper's figure it reproduces).
        drawn: whether the figure is drawn, from the series and the key figures found (by
            default: when there are any).
    """

    key: str
    score: Callable[[Mapping[str, TopicSeries], int], Sequence[Metric] | Metric | None]
    plot: Callable[[Mapping[str, TopicSeries], Path, int], Path]
    figure: str
    drawn: Callable[[Mapping[str, TopicSeries], Sequence[Metric]], bool] = (
        lambda series, found: bool(found))


def score_methods(series: Mapping[str, TopicSeries], scenario: str, figure_dir: Path,
                  methods: Sequence[str], scorings: Sequence[MethodScoring],
                  truth_topics: Iterable[str]) -> Evaluation:
    """A domain's ``evaluate``: the key figures and figure of each method selected.

    Args:
        series: recorded topics by name (header stamps).
        scenario: scenario name for the result.
        figure_dir: where the PNGs go.
        methods: keys of the methods to score (empty: all of ``scorings``).
        scorings: the domain's methods, in scoreboard order.
        truth_topics: the ground truth topics (the evaluation has truth when one was recorded).
    """
    wanted = selected_methods(methods, [scoring.key for scoring in scorings])
    t0 = start_ns(series)
    metrics: list[Metric] = []
    figures: list[str] = []
    for scoring in scorings:
        if scoring.key not in wanted:
            continue
        scored = scoring.score(series, t0)
        found = [] if scored is None else [scored] if isinstance(scored, Metric) else list(scored)
        metrics += found
        if scoring.drawn(series, found):
            figures.append(scoring.plot(series, figure_dir / scoring.figure, t0).name)
    has_truth = any(topic in series for topic in truth_topics)
    return Evaluation(scenario, has_truth, tuple(metrics), tuple(figures))


def loads_as_scenario(load: Callable[[Path], Any],
                      refusals: tuple[type[Exception], ...]) -> Callable[[Path], bool]:
    """A domain's ``is_scenario``: whether ``load`` reads the file without one of the
    ``refusals`` it raises for a file that is not its domain's."""

    def is_scenario(path: Path) -> bool:
        try:
            load(path)
        except refusals:
            return False
        return True

    return is_scenario


def stack_column(values: np.ndarray) -> np.ndarray:
    """A variable-length array field (object array of lists) as a 2-D float array."""
    if values.dtype != object:
        return np.asarray(values, dtype=float)
    return np.array([np.asarray(v, dtype=float) for v in values])


def hold_at(t_src: np.ndarray, values: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Sample-and-hold of ``values`` (first axis over ``t_src``) at ``t_query``.

    Before the first source sample the first value is held (truth starts with the run).
    """
    index = np.searchsorted(t_src, t_query, side='right') - 1
    return values[np.clip(index, 0, len(t_src) - 1)]


def rising_edges(flags: np.ndarray) -> np.ndarray:
    """Indices where a boolean series (first axis time) turns True, per column."""
    flags = np.asarray(flags, dtype=bool)
    previous = np.concatenate([np.zeros_like(flags[:1]), flags[:-1]])
    return flags & ~previous


# ---------------------------------------------------------------------------------------------
# Scoreboard, report, results file


@dataclass(frozen=True)
class RunStats:
    """How one graph run went: speed and completeness.

    Attributes:
        scenario: scenario name.
        domain: domain name.
        bag_duration_s: recorded time replayed, s.
        wall_s: wall time of the replay (first message to the last output), s.
        cpu_s: CPU time of the process over the replay (every thread), s.
        published: messages the player published.
        dropped: replayed messages the recorder did not receive.
    """

    scenario: str
    domain: str
    bag_duration_s: float
    wall_s: float
    cpu_s: float
    published: int
    dropped: int

    @property
    def real_time_factor(self) -> float:
        """Bag time / wall time."""
        return self.bag_duration_s / self.wall_s if self.wall_s > 0 else math.inf

    @property
    def cpu_real_time_factor(self) -> float:
        """Bag time / CPU time: the real-time factor on a machine that is not shared."""
        return self.bag_duration_s / self.cpu_s if self.cpu_s > 0 else math.inf


def render_scoreboard(evaluations: Sequence[Evaluation],
                      runs: Sequence[RunStats] = (),
                      families: Sequence[FamilyTable] = ()) -> str:
    """The scoreboard as a fixed-width text table, then one line per graph run, then the
    held-out family tables (committed results, see :mod:`family_results`)."""
    header = ('scenario', 'method', 'key figure', 'value', 'target', 'result')
    rows = [(e.scenario, m.method, m.figure, m.value_text(), m.target or '-', m.verdict())
            for e in evaluations for m in e.metrics]
    widths = [max(len(str(r[i])) for r in [header, *rows]) for i in range(len(header))]
    line = '  '.join('-' * w for w in widths)
    lines = ['  '.join(f'{c:<{w}}' for c, w in zip(header, widths, strict=True)), line]
    lines += ['  '.join(f'{c:<{w}}' for c, w in zip(row, widths, strict=True)) for row in rows]
    scored = [m for e in evaluations for m in e.metrics if m.passed is not None]
    lines.append(line)
    lines.append(f'{sum(m.passed is True for m in scored)} of {len(scored)} targets met')
    for run in runs:
        lines.append(_run_line(run))
    if families:
        lines += ['', f'Held-out family. {FAMILY_INTRO}', render_family_text(families)]
    return '\n'.join(lines)


def _run_line(run: RunStats) -> str:
    return (f'graph {run.domain} on {run.scenario}: {run.bag_duration_s:.0f} s of bag in '
            f'{run.wall_s:.1f} s wall = {run.real_time_factor:.1f}x real time '
            f'({run.cpu_real_time_factor:.1f}x per CPU second; target >= 10x), '
            f'{run.published} messages, {run.dropped} dropped')


def render_markdown_table(evaluations: Sequence[Evaluation]) -> str:
    """The scoreboard as a Markdown table."""
    lines = ['| scenario | method | key figure | value | target (docs/targets.md) | result |',
             '| --- | --- | --- | --- | --- | --- |']
    for evaluation in evaluations:
        for m in evaluation.metrics:
            verdict = {'PASS': '**pass**', 'FAIL': '**FAIL**'}.get(m.verdict(), '-')
            lines.append(f'| {evaluation.scenario} | {m.method} | {m.figure} | '
                         f'{m.value_text()} | {m.target or "-"} | {verdict} |')
    return '\n'.join(lines)


def render_runs_table(runs: Sequence[RunStats]) -> str:
    """Graph speed and completeness as a Markdown table."""
    lines = ['| graph | scenario | bag time | wall time | real-time factor | per CPU second '
             '| messages | dropped |',
             '| --- | --- | --- | --- | --- | --- | --- | --- |']
    for r in runs:
        lines.append(f'| {r.domain} | {r.scenario} | {r.bag_duration_s:.0f} s | {r.wall_s:.1f} s '
                     f'| {r.real_time_factor:.1f}x | {r.cpu_real_time_factor:.1f}x '
                     f'| {r.published} | {r.dropped} |')
    return '\n'.join(lines)


def details_lines(evaluations: Sequence[Evaluation]) -> list[str]:
    """One Markdown bullet per metric with its evidence."""
    return [f'- {e.scenario} / {m.method}: {m.detail}' for e in evaluations for m in e.metrics
            if m.detail]


def write_results(path: str | os.PathLike[str], evaluations: Sequence[Evaluation],
                  runs: Sequence[RunStats] = (), extra: Mapping[str, Any] | None = None,
                  ) -> Path:
    """Write the machine-readable results (JSON): evaluations, metrics, runs."""
    data: dict[str, Any] = dict(extra or {})
    data['evaluations'] = [
        {'scenario': e.scenario, 'has_truth': e.has_truth, 'figures': list(e.figures),
         'metrics': [asdict(m) for m in e.metrics]} for e in evaluations]
    data['runs'] = [{**asdict(r), 'real_time_factor': r.real_time_factor,
                     'cpu_real_time_factor': r.cpu_real_time_factor} for r in runs]
    scored = [m for e in evaluations for m in e.metrics if m.passed is not None]
    data['summary'] = {'targets': len(scored),
                       'met': sum(m.passed is True for m in scored)}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, default=_json_default) + '\n', encoding='utf-8')
    return path


def _json_default(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f'cannot write {type(value).__name__} to JSON')


def _finite_or_none(value: Any) -> float | None:
    return None if value is None else float(value)


def load_results(path: str | os.PathLike[str]) -> tuple[list[Evaluation], list[RunStats]]:
    """Read a results file written by :func:`write_results` back."""
    data = json.loads(Path(path).read_text(encoding='utf-8'))
    evaluations = [Evaluation(
        scenario=e['scenario'], has_truth=bool(e['has_truth']), figures=tuple(e['figures']),
        metrics=tuple(Metric(**{**m, 'value': _finite_or_none(m['value'])})
                      for m in e['metrics'])) for e in data.get('evaluations', [])]
    fields = RunStats.__dataclass_fields__
    runs = [RunStats(**{k: v for k, v in r.items() if k in fields}) for r in data.get('runs', [])]
    return evaluations, runs


def write_report(path: str | os.PathLike[str], evaluations: Sequence[Evaluation],
                 runs: Sequence[RunStats] = (), title: str = 'Monitoring graph report',
                 descriptions: Mapping[str, str] | None = None,
                 families: Sequence[FamilyTable] = ()) -> Path:
    """A short Markdown report: the scoreboard, graph speed, the held-out family tables,
    evidence, embedded figures.

    Figure names in the evaluations are relative to the report's directory.
    """
    lines = [f'# {title}', '', render_markdown_table(evaluations), '']
    if runs:
        lines += ['## Graph runs', '', render_runs_table(runs), '']
    if families:
        lines += [render_family_section(families, '## Held-out family'), '']
    details = details_lines(evaluations)
    if details:
        lines += ['## Evidence', '', *details, '']
    for evaluation in evaluations:
        if not evaluation.figures:
            continue
        lines += [f'## {evaluation.scenario}', '']
        if descriptions and descriptions.get(evaluation.scenario):
            lines += [descriptions[evaluation.scenario], '']
        for figure in evaluation.figures:
            lines += [f'![{Path(figure).stem}]({figure})', '']
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text('\n'.join(lines), encoding='utf-8')
    return path


README_BEGIN = '<!-- scoreboard:begin (generated by `monitor_demo --update-readme`) -->'
README_END = '<!-- scoreboard:end -->'


def update_readme(readme: str | os.PathLike[str], results: str | os.PathLike[str],
                  families: Sequence[FamilyTable] = ()) -> bool:
    """Rewrite the README section between the scoreboard markers from a results file.

    The section holds the scoreboard, the graph runs, links to the figures and the held-out
    family tables (``families``). The figures are
    copied next to the README into ``docs/figures/<scenario>/`` (committed with it, so the links
    work on a fresh clone where no run has written ``out/``). Appended at the end when the
    markers are missing.

    Returns:
        Whether the README (or a figure) changed.
    """
    readme, results = Path(readme), Path(results)
    evaluations, runs = load_results(results)
    figure_root = readme.parent / 'docs' / 'figures'
    figures, copied = [], False
    for e in evaluations:
        for f in e.figures:
            target, source = figure_root / f, results.parent / f
            if not source.is_file() and not target.is_file():
                continue  # neither written by this run nor committed before: nothing to show
            data = source.read_bytes() if source.is_file() else target.read_bytes()
            if not target.exists() or target.read_bytes() != data:
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
                copied = True
            figures.append(f'[{Path(f).stem}]({target.relative_to(readme.parent).as_posix()})')
    block = [README_BEGIN, '', render_markdown_table(evaluations), '']
    if runs:
        block += [render_runs_table(runs), '']
    if figures:
        block += ['Figures of this run (named after the papers\' figures; every run writes them '
                  'with its report into its output folder): ' + ', '.join(figures) + '.', '']
    if families:
        block += [render_family_section(families, '### Held-out family'), '']
    block.append(README_END)
    text = readme.read_text(encoding='utf-8')
    pattern = re.compile(re.escape(README_BEGIN) + '.*?' + re.escape(README_END), re.S)
    section = '\n'.join(block)
    if pattern.search(text):
        updated = pattern.sub(lambda _: section, text)
    else:
        updated = text.rstrip('\n') + '\n\n' + section + '\n'
    if updated == text:
        return copied
    readme.write_text(updated, encoding='utf-8')
    return True
