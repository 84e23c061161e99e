"""``monitor_demo``: the main job. Every registered scenario through its monitoring graph, scored.

For each domain registered under ``vehicle_monitor.evaluations`` (road: ``tpms_ros``, rail:
``rail_monitor_ros``) and each of its shipped scenarios, the domain's graph (simulator in replay
mode, every estimator node, a recorder) is brought up in this process as real rclpy nodes over
real topics; the bag is replayed as fast as the graph keeps up (paced by the estimators' outputs,
no message dropped); the recording is evaluated against its ground truth. Then it prints the
scoreboard (one row per scenario and method: key figure, docs/targets.md target, pass/fail),
each graph's real-time factor and the held-out family tables (one row per target of the family
evaluations, read from the committed ``docs/results/*_family.json``: those runs take too long
for the main job), and writes into the output folder (default ``out/demo``):

- ``results.json``: every metric and run figure, machine-readable;
- ``report.md``: the scoreboard, the runs and the figures (PNG, named after the papers');
- ``<scenario>/recorded``: the recording of each run (inputs, truth, outputs), and the
  calibration files the TPMS nodes learned.

``monitor_demo --update-readme`` also rewrites the README's scoreboard section from the results;
``monitor_demo --from-results out/demo/results.json --update-readme`` does only that.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
import os
from pathlib import Path
import shutil
import threading
import time
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.task import Future

from vehicle_monitor_common.bag_io import open_reader
from vehicle_monitor_common.cli import run_cli
from vehicle_monitor_common.evaluation import (
    Domain,
    Evaluation,
    RunStats,
    domains,
    read_stamped_series,
    render_scoreboard,
    update_readme,
    write_report,
    write_results,
)
from vehicle_monitor_common.family_results import FamilyTable, load_family_tables
from vehicle_monitor_common.graph_spec import GraphSpec, load_graph
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.player import ScenarioPlayer
from vehicle_monitor_common.recorder import GraphRecorder
from vehicle_monitor_common.runner import EXECUTORS, Graph

DEFAULT_OUT = Path('out/demo')
# Printed progress lines are this far apart (wall time, s).
PROGRESS_PERIOD_S = 5.0


def use_private_domain(offset: int = 0) -> int:
    """Put this process's ROS graph in a DDS domain of its own (before any rclpy context).

    A replay publishes the same topics as a vehicle (``/vehicle/wheel_speeds``, ``/clock``):
    in the default domain it would feed a live graph on this machine, and two replays would
    feed each other. The domain id (200-231: Linux allows up to 232; the test suite uses
    100-199) is derived from the process id plus ``offset``, distinct per worker of a batch.

    Returns:
        The domain id now in ``ROS_DOMAIN_ID``.
    """
    domain_id = 200 + (os.getpid() + offset) % 32
    os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    return domain_id


def with_parameters(spec: GraphSpec, parameters: Mapping[str, Mapping[str, Any]],
                    executor: str | None = None) -> GraphSpec:
    """The graph with node parameters overridden, by node name.

    Raises:
        ConfigurationError: a named node is not in the graph.
    """
    names = {node.name or node.plugin.split('/')[-1] for node in spec.nodes}
    unknown = sorted(set(parameters) - names)
    if unknown:
        raise ConfigurationError(f'graph has no node {unknown[0]!r} (it has: '
                                 f'{", ".join(sorted(names))})')
    nodes = tuple(
        replace(node, parameters={**node.parameters,
                                  **parameters.get(node.name or node.plugin.split('/')[-1], {})})
        for node in spec.nodes)
    return replace(spec, nodes=nodes, executor=executor or spec.executor)


def bag_duration_s(bag: str | os.PathLike[str]) -> float:
    """Recorded time span of a bag, s."""
    reader = open_reader(bag)
    try:
        return float(reader.duration) * 1e-9
    finally:
        reader.close()


class _ReplayWatch:
    """Times a replay and reports its progress from a thread of its own.

    The replay's wall time runs from the player's first message to the moment the recorder has
    received every message the player published (not to the player's end, which may include a
    wait for a sync topic that publishes no more). CPU time is the process's over that span.
    """

    def __init__(self, player: ScenarioPlayer, recorder: GraphRecorder, duration_s: float,
                 label: str, log: Callable[[str], None]) -> None:
        self.finished: Future = Future()
        self._player, self._recorder = player, recorder
        self._duration_s, self._label, self._log = duration_s, label, log
        self._total = sum(player.topic_counts.values())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f'{label}_watch', daemon=True)
        self._first: tuple[float, float] | None = None
        self._last: tuple[float, float] | None = None

    def start(self) -> None:
        """Start watching."""
        self._thread.start()

    def stop(self) -> None:
        """Stop watching (after the replay)."""
        self._stop.set()
        self._thread.join()

    def elapsed(self) -> tuple[float, float]:
        """(wall, CPU) seconds of the replay; 0 if it never started."""
        if self._first is None:
            return 0.0, 0.0
        last = self._last or (time.monotonic(), time.process_time())
        return last[0] - self._first[0], last[1] - self._first[1]

    def _received_all(self) -> bool:
        stats = self._recorder.stats
        return all(topic in stats and stats[topic].count >= count
                   for topic, count in list(self._player.published.items()))

    def _run(self) -> None:
        started = time.monotonic()
        next_report = started + PROGRESS_PERIOD_S
        while not self._stop.wait(0.02):
            now = time.monotonic()
            published = sum(self._player.published.values())
            if self._first is None and published:
                self._first = (now, time.process_time())
            if (self._last is None and published >= self._total
                    and self._received_all()):
                self._last = (now, time.process_time())
            if now >= next_report and self._total:
                self._log(f'  {self._label}: {published / self._total * self._duration_s:6.1f}'
                          f' / {self._duration_s:.0f} s of bag '
                          f'({100 * published / self._total:3.0f} %), '
                          f'{now - started:5.1f} s elapsed')
                next_report = now + PROGRESS_PERIOD_S
            if self._player.done.is_set() and not self.finished.done():
                self.finished.set_result(True)


def run_graph_on_bag(domain: Domain, bag: Path, run_dir: Path, *, label: str = '',
                     executor: str | None = None, timeout_s: float | None = None,
                     log: Callable[[str], None] = print,
                     on_graph: Callable[[Graph], None] | None = None,
                     ) -> tuple[Path, RunStats]:
    """Replay ``bag`` through the domain's graph, recording everything into ``run_dir``.

    A fresh rclpy context per run, so nodes of one run never hear another's. Progress lines
    go to ``log`` every few seconds. ``on_graph`` sees the graph once it is up, before the
    replay (the benchmarks instrument its callbacks there).

    Returns:
        The recorded bag and the run's speed and completeness.

    Raises:
        RuntimeError: the replay failed or did not finish within ``timeout_s``.
    """
    run_dir.mkdir(parents=True, exist_ok=True)
    recorded = run_dir / 'recorded'
    duration = bag_duration_s(bag)
    parameters: dict[str, dict[str, Any]] = {
        domain.player: {'bag': str(bag)}, domain.recorder: {'bag': str(recorded)}}
    for node, values in domain.run_parameters(run_dir).items():
        parameters.setdefault(node, {}).update(values)
    spec = with_parameters(load_graph(domain.graph), parameters, executor)
    label = label or bag.name
    timeout_s = timeout_s if timeout_s is not None else 60.0 + 20.0 * duration
    context = rclpy.Context()
    rclpy.init(context=context)
    graph: Graph | None = None
    try:
        graph = Graph(spec, context)
        if on_graph is not None:
            on_graph(graph)
        player = graph.of_type(ScenarioPlayer)[0]
        recorder = graph.of_type(GraphRecorder)[0]
        watch = _ReplayWatch(player, recorder, duration, label, log)
        watch.start()
        started = time.monotonic()
        while not player.done.is_set():
            if graph.spec.executor == 'events':
                # The C++ loop of the EventsExecutor, no Python between events; the watch
                # completes the future when the replay is done.
                graph.executor.spin_until_future_complete(watch.finished, timeout_sec=1.0)
            else:
                graph.executor.spin_once(timeout_sec=0.05)
            if time.monotonic() - started > timeout_s:
                raise RuntimeError(f'{label}: replay did not finish within {timeout_s:.0f} s')
        watch.stop()
        if player.error:
            raise RuntimeError(f'{label}: {player.error}')
        published_counts = dict(player.published)
        graph.drain(expected=published_counts)
        dropped = sum(max(0, count - (recorder.stats[topic].count
                                      if topic in recorder.stats else 0))
                      for topic, count in published_counts.items())
        wall, cpu = watch.elapsed()
    finally:
        if graph is not None:
            graph.destroy()  # closes the recorder's bag
        rclpy.try_shutdown(context=context)
    stats = RunStats(scenario=label, domain=domain.name, bag_duration_s=duration, wall_s=wall,
                     cpu_s=cpu, published=sum(published_counts.values()), dropped=dropped)
    return recorded, stats


def evaluate_recording(domain: Domain, recorded: Path, scenario: str, figure_dir: Path,
                       methods: Sequence[str] = (), relative_to: Path | None = None,
                       ) -> Evaluation:
    """Read a recording (header stamps) and score it with the domain's evaluation.

    Figures go to ``figure_dir``; their names in the result are relative to ``relative_to``
    (default: ``figure_dir``), where the report and results file are.
    """
    series = read_stamped_series(recorded, domain.read_topics or None)
    figure_dir.mkdir(parents=True, exist_ok=True)
    evaluation = domain.evaluate(series, scenario, figure_dir, methods)
    base = relative_to or figure_dir
    return replace(evaluation, figures=tuple(
        Path(os.path.relpath(figure_dir / name, base)).as_posix()
        for name in evaluation.figures))


def run_demo(out_dir: Path, only: Sequence[str] = (), executor: str | None = None,
             log: Callable[[str], None] = print, families: Sequence[FamilyTable] = (),
             ) -> tuple[list[Evaluation], list[RunStats]]:
    """Run every registered scenario (or those named in ``only``) and write the outputs; the
    report also shows the held-out family tables ``families``."""
    registered = domains()
    if not registered:
        raise ConfigurationError('no domain registered under vehicle_monitor.evaluations '
                                 '(is the workspace built and sourced?)')
    selected = [(d, s) for d in registered for s in d.scenarios if not only or s.name in only]
    unknown = sorted(set(only) - {s.name for _, s in selected})
    if unknown:
        names = ', '.join(s.name for d in registered for s in d.scenarios)
        raise ConfigurationError(f'unknown scenario {unknown[0]!r} (registered: {names})')
    out_dir.mkdir(parents=True, exist_ok=True)
    evaluations: list[Evaluation] = []
    runs: list[RunStats] = []
    for index, (domain, scenario) in enumerate(selected, start=1):
        log(f'[{index}/{len(selected)}] {domain.name} graph on {scenario.name}: '
            f'{scenario.description}')
        run_dir = out_dir / scenario.name
        if run_dir.exists():
            shutil.rmtree(run_dir)  # a rerun starts fresh: no calibration from a previous run
        started = time.monotonic()
        recorded, stats = run_graph_on_bag(domain, scenario.bag, run_dir, label=scenario.name,
                                           executor=executor, log=log)
        runs.append(stats)
        evaluation = evaluate_recording(domain, recorded, scenario.name, run_dir,
                                        scenario.methods, relative_to=out_dir)
        evaluations.append(evaluation)
        log(f'  {scenario.name}: done in {time.monotonic() - started:.1f} s '
            f'({stats.real_time_factor:.1f}x real time, {stats.dropped} dropped), '
            f'{sum(m.passed is True for m in evaluation.metrics)} of '
            f'{sum(m.passed is not None for m in evaluation.metrics)} targets met')
    descriptions = {s.name: s.description for _, s in selected}
    write_results(out_dir / 'results.json', evaluations, runs)
    write_report(out_dir / 'report.md', evaluations, runs, descriptions=descriptions,
                 families=families)
    return evaluations, runs


def _find_readme() -> Path:
    return Path.cwd() / 'README.md'


def main(argv: list[str] | None = None) -> int:
    """``monitor_demo``: run the scenarios, print the scoreboard, write figures and report."""
    parser = argparse.ArgumentParser(prog='monitor_demo', description=__doc__.split('\n')[0])
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT,
                        help=f'output folder (default: {DEFAULT_OUT})')
    parser.add_argument('--only', action='append', default=[], metavar='SCENARIO',
                        help='run only this scenario (repeatable)')
    parser.add_argument('--executor', choices=sorted(EXECUTORS), default=None,
                        help="executor of every graph (default: the graph file's)")
    parser.add_argument('--shared-domain', action='store_true',
                        help='run in the ROS_DOMAIN_ID of the environment (default: a private '
                             'domain, so the replay cannot reach a live graph)')
    parser.add_argument('--update-readme', action='store_true',
                        help="rewrite the README's scoreboard section from the results")
    parser.add_argument('--readme', type=Path, default=None,
                        help='README to update (default: ./README.md)')
    parser.add_argument('--from-results', type=Path, default=None, metavar='RESULTS_JSON',
                        help='do not run: use this results file (with --update-readme)')
    args = parser.parse_args(argv)
    readme = args.readme or _find_readme()
    if not args.shared_domain:
        use_private_domain()
    def run() -> int:
        families = load_family_tables()
        if args.from_results is not None:
            if not args.update_readme:
                parser.error('--from-results only makes sense with --update-readme')
            changed = update_readme(readme, args.from_results, families)
            print(f'{readme}: {"updated" if changed else "already up to date"}')
            return 0
        started = time.monotonic()
        evaluations, runs = run_demo(args.out, args.only, args.executor, families=families)
        print()
        print(render_scoreboard(evaluations, runs, families))
        print(f'\nmain job: {time.monotonic() - started:.0f} s wall; figures, report.md and '
              f'results.json in {args.out}/')
        if args.update_readme:
            changed = update_readme(readme, args.out / 'results.json', families)
            print(f'{readme}: {"updated" if changed else "already up to date"}')
        # Missed targets are the product's state, not an error: exit 0. A run that dropped
        # messages is one (the scores would not be the graph's).
        return 1 if any(r.dropped for r in runs) else 0

    return run_cli(run, (ConfigurationError, RuntimeError, FileNotFoundError),
                   (KeyboardInterrupt, ExternalShutdownException))
