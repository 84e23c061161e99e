"""``evaluate``: score the monitoring graph on any bag or scenario file, or a Monte Carlo batch.

Inputs, any mix of:

- a rosbag2 directory: replayed through its domain's graph (recognised by its input topics),
  recorded, scored. With ``--as-recorded`` the bag is scored as it is (it already holds the
  estimators' outputs, e.g. recorded on a vehicle). A bag without ground truth gets the
  estimates, warnings and plots, without error columns or verdicts.
- a scenario YAML file (road or rail, see docs/*_scenario_schema.md): simulated by its domain's
  simulator (same synthesis as the simulator nodes), written to a bag, then as above. With
  ``--seeds N`` it is simulated N times with seeds ``--seed-start`` ... (Monte Carlo).

The vehicle: ``--params FILE`` (a ROS params file, as the nodes take it: keys ``/**`` or a
node's name) and ``--calibration FILE`` (a stored calibration, node name -> state, as the fleet
job keeps it) configure the graph's estimator nodes, or ``--manifest M --vehicle ID`` takes a
fleet manifest's vehicle entry (its params files, per-node values and calibration). Without
them the graph runs with the shipped parameters and calibrates on the recording itself. A
stored calibration is put in force from the start (the node's calibration file in the run
folder, ``calibrate_on_start`` off), as on a car that calibrated on an earlier drive.

With ``--offline`` the graph's processors run over the bag in the offline engine instead of
the live graph (the same node logic without DDS: no message can be dropped, whoever wrote the
bag, and several times faster); the recording scored is the bag's messages plus the outputs.

Runs go in parallel over the machine's cores (``--jobs``), one process each (a graph is one
process). Writes ``results.json`` (every run's metrics, plus per scenario and metric the mean,
min, max and pass rate over the seeds), ``report.md`` and per run its recording and figures into
the output folder (default ``out/evaluate``)::

    evaluate bags/rail_creep_steps
    evaluate src/rail_monitor_ros/scenarios/rail_imm_spring_damper_fault.yaml --seeds 8
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
import math
import multiprocessing
import os
from pathlib import Path
import shutil
import sys
import time
from typing import Any

from vehicle_monitor_common.bag_io import BagError, write_bag
from vehicle_monitor_common.calibration_store import load_calibration, save_calibration
from vehicle_monitor_common.cli import run_cli
from vehicle_monitor_common.evaluation import (
    Domain,
    Evaluation,
    Metric,
    RunStats,
    domain_of_bag,
    domains,
    render_scoreboard,
    write_report,
    write_results,
)
from vehicle_monitor_common.graph_spec import (
    fully_qualified_name,
    load_graph,
    node_parameter_values,
)
from vehicle_monitor_common.parameters import ConfigurationError

DEFAULT_OUT = Path('out/evaluate')


@dataclass(frozen=True)
class Vehicle:
    """The vehicle a run is configured for (empty: the graph's shipped parameters).

    Attributes:
        params: ROS params files applied to every estimator node of the graph (rcl's
            matching: ``/**``, ``/**/<name>``, the node's fully qualified name).
        parameters: values by node name on top of them.
        calibration: stored calibration, node name (or fully qualified name) -> state.
    """

    params: tuple[str, ...] = ()
    parameters: dict[str, dict[str, Any]] = field(default_factory=dict)
    calibration: dict[str, dict[str, Any]] = field(default_factory=dict)

    def run_parameters(self, domain: Domain, run_dir: Path) -> dict[str, dict[str, Any]]:
        """Per node name of the domain's graph: its run parameters with the vehicle's values,
        and the stored calibration written to the node's calibration file in ``run_dir``."""
        spec = load_graph(domain.graph)
        result = {node: dict(values) for node, values in domain.run_parameters(run_dir).items()}
        for node in spec.nodes:
            name = node.name or node.plugin.split('/')[-1]
            if name in (domain.player, domain.recorder):
                continue
            fqn = fully_qualified_name(node.namespace, name)
            values = node_parameter_values(fqn, self.params, {}) if self.params else {}
            values.update(self.parameters.get(name, {}))
            values.update(self.parameters.get(fqn, {}))
            state = self.calibration.get(name, self.calibration.get(fqn))
            if state is not None:
                file = result.get(name, {}).get('calibration_file') or str(
                    run_dir / f'{name}_calibration.yaml')
                problem = save_calibration(file, state, comment='stored vehicle calibration')
                if problem:
                    raise ConfigurationError(f'{name}: {problem}')
                values['calibration_file'] = file
                values['calibrate_on_start'] = False
            if values:
                result.setdefault(name, {}).update(values)
        return result


def read_vehicle(params: Sequence[str] = (), calibration: str | None = None,
                 manifest: str | None = None, vehicle_id: str | None = None) -> Vehicle:
    """The vehicle from params files and a calibration file, or a fleet manifest's entry.

    Raises:
        ConfigurationError: a file that cannot be read, a vehicle the manifest lacks.
    """
    parameters: dict[str, dict[str, Any]] = {}
    files = list(params)
    if manifest is not None:
        from vehicle_monitor_common.fleet.manifest import read_manifest

        fleet = read_manifest(manifest)
        if vehicle_id not in fleet.vehicles:
            raise ConfigurationError(f'{manifest}: no vehicle {vehicle_id!r}')
        entry = fleet.vehicle(str(vehicle_id))
        files = [*entry.params, *files]
        parameters = {k: dict(v) for k, v in entry.parameters.items()}
        calibration = calibration or entry.calibration
    for path in files:
        if not os.path.isfile(path):
            raise ConfigurationError(f'no params file {path}')
    states: dict[str, dict[str, Any]] = {}
    if calibration is not None:
        loaded = load_calibration(calibration)
        if loaded.state is None:
            raise ConfigurationError(f'calibration {calibration}: '
                                     f'{loaded.problem or "no such file"}')
        if not all(isinstance(v, dict) for v in loaded.state.values()):
            raise ConfigurationError(f'calibration {calibration}: expected node -> state')
        states = {str(k): dict(v) for k, v in loaded.state.items()}
    return Vehicle(tuple(files), parameters, states)


@dataclass(frozen=True)
class Task:
    """One run: a bag to replay (or score as recorded) or a scenario to simulate first."""

    name: str
    domain: str
    source: Path
    kind: str               # 'bag', 'recorded' or 'scenario'
    seed: int | None = None
    base: str = ''          # scenario the run belongs to (Monte Carlo groups by it)
    vehicle: Vehicle = field(default_factory=Vehicle)
    offline: bool = False   # the offline engine instead of the live graph


def _is_bag(path: Path) -> bool:
    return path.is_dir() and (path / 'metadata.yaml').is_file()


def plan(inputs: Sequence[Path], registered: Sequence[Domain], seeds: int | None,
         seed_start: int, as_recorded: bool) -> list[Task]:
    """The runs for the inputs.

    Raises:
        ConfigurationError: an input is neither a bag nor a scenario of a registered domain.
    """
    tasks = []
    for path in inputs:
        if _is_bag(path):
            try:
                domain = domain_of_bag(path, registered)
            except (ValueError, BagError) as exc:
                raise ConfigurationError(str(exc)) from None
            tasks.append(Task(path.name, domain.name, path,
                              'recorded' if as_recorded else 'bag', base=path.name))
            continue
        if not path.is_file():
            raise ConfigurationError(f'{path}: neither a bag directory nor a scenario file')
        owner = next((d for d in registered if d.is_scenario(path)), None)
        if owner is None:
            known = ', '.join(d.name for d in registered)
            raise ConfigurationError(f'{path}: not a valid scenario of any domain ({known}); '
                                     'check it against docs/*_scenario_schema.md')
        if seeds is None:
            tasks.append(Task(path.stem, owner.name, path, 'scenario', base=path.stem))
        else:
            tasks += [Task(f'{path.stem}_seed{seed}', owner.name, path, 'scenario', seed,
                           path.stem) for seed in range(seed_start, seed_start + seeds)]
    names = [t.name for t in tasks]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate:
        raise ConfigurationError(f'two inputs would both write {duplicate!r}')
    return tasks


def run_task(task: Task, out_dir: Path, executor: str | None = None,
             quiet: bool = False) -> tuple[Evaluation, RunStats | None]:
    """Do one run (in this process) and score it; figures and recording in out_dir/name."""
    # Imported here: worker processes bring rclpy up themselves.
    from vehicle_monitor_common.main_job import evaluate_recording, run_graph_on_bag

    domain = next(d for d in domains() if d.name == task.domain)
    vehicle = task.vehicle
    if vehicle != Vehicle():
        shipped = domain
        domain = replace(domain, run_parameters=lambda run_dir: vehicle.run_parameters(
            shipped, run_dir))
    run_dir = out_dir / task.name
    if run_dir.exists():
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True)

    def log(line: str) -> None:
        if not quiet:
            print(line, flush=True)

    stats = None
    if task.kind == 'recorded':
        recorded = task.source
    else:
        bag = task.source
        if task.kind == 'scenario':
            bag = write_bag(run_dir / 'input', domain.synthesize(task.source, task.seed),
                            overwrite=True)
        if task.offline:
            recorded, stats = run_offline(domain, bag, run_dir, label=task.name)
        else:
            recorded, stats = run_graph_on_bag(domain, bag, run_dir, label=task.name,
                                               executor=executor, log=log)
    evaluation = evaluate_recording(domain, recorded, task.name, run_dir,
                                    relative_to=out_dir)
    return evaluation, stats


def run_offline(domain: Domain, bag: Path, run_dir: Path, *, label: str = '',
                ) -> tuple[Path, RunStats]:
    """Run the domain graph's processors over ``bag`` with the offline engine (no DDS, so no
    message can be dropped) and write ``run_dir/recorded``: the bag's messages and the
    outputs, merged in log-time order (outputs logged at their header stamps), as the
    evaluation reads a live recording."""
    from contextlib import closing
    import heapq

    from vehicle_monitor_common.bag_io import BagWriter, iter_raw
    from vehicle_monitor_common.offline_engine import OfflineGraph, write_outputs

    graph = OfflineGraph.from_spec(load_graph(domain.graph), domain.run_parameters(run_dir))
    cpu = time.process_time()
    engine = write_outputs(graph, bag, run_dir / 'outputs')
    cpu = time.process_time() - cpu
    recorded = run_dir / 'recorded'
    with BagWriter(recorded, overwrite=True) as writer, \
            closing(iter_raw(bag)) as inputs, closing(iter_raw(run_dir / 'outputs')) as outputs:
        for topic, msgtype, stamp, data in heapq.merge(inputs, outputs, key=lambda m: m[2]):
            writer.write_raw(topic, msgtype, stamp, data)
    shutil.rmtree(run_dir / 'outputs')
    return recorded, RunStats(scenario=label or bag.name, domain=domain.name,
                              bag_duration_s=engine.data_s, wall_s=engine.wall_s, cpu_s=cpu,
                              published=engine.messages_in, dropped=0)


def _init_worker(counter: Any, parent_pid: int) -> None:
    """Give each worker process a DDS domain of its own: parallel replays must not mix."""
    from vehicle_monitor_common.main_job import use_private_domain

    with counter.get_lock():
        counter.value += 1
        index = counter.value
    use_private_domain(offset=parent_pid + index - os.getpid())  # id from parent pid + index


def _worker(args: tuple[Task, Path, str | None]) -> tuple[Evaluation, RunStats | None]:
    task, out_dir, executor = args
    started = time.monotonic()
    result = run_task(task, out_dir, executor, quiet=True)
    print(f'  {task.name}: done in {time.monotonic() - started:.1f} s', flush=True)
    return result


def batch_summary(tasks: Sequence[Task], evaluations: Sequence[Evaluation],
                  ) -> list[dict[str, Any]]:
    """Per scenario (over its seeds) and metric: count, mean/min/max of the value, pass rate."""
    groups: dict[tuple[str, str, str], list[Metric]] = defaultdict(list)
    for task, evaluation in zip(tasks, evaluations, strict=True):
        for metric in evaluation.metrics:
            groups[(task.base, metric.method, metric.figure)].append(metric)
    summary = []
    for (base, method, figure), metrics in groups.items():
        values = [m.value for m in metrics if m.value is not None and math.isfinite(m.value)]
        verdicts = [m.passed for m in metrics if m.passed is not None]
        summary.append({
            'scenario': base, 'method': method, 'figure': figure, 'runs': len(metrics),
            'unit': metrics[0].unit, 'target': metrics[0].target,
            'mean': sum(values) / len(values) if values else None,
            'min': min(values) if values else None, 'max': max(values) if values else None,
            'valid_runs': len(values),
            'pass_rate': sum(verdicts) / len(verdicts) if verdicts else None})
    return summary


def render_batch_summary(summary: Sequence[Mapping[str, Any]]) -> str:
    """Monte Carlo summary lines (scenarios with more than one run)."""
    lines = []
    for row in summary:
        if row['runs'] == 1:
            continue
        value = ('n/a' if row['mean'] is None else
                 f'mean {row["mean"]:.3g}, min {row["min"]:.3g}, max {row["max"]:.3g} '
                 f'{row["unit"]} over {row["valid_runs"]}/{row["runs"]} runs')
        rate = '' if row['pass_rate'] is None else f'; pass rate {100 * row["pass_rate"]:.0f} %'
        lines.append(f'{row["scenario"]} / {row["method"]} / {row["figure"]}: {value}{rate}')
    return '\n'.join(lines)


def main(argv: list[str] | None = None) -> int:
    """``evaluate``: run, score and plot the given bags and scenario files."""
    parser = argparse.ArgumentParser(
        prog='evaluate', description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='\n'.join(__doc__.split('\n')[2:]))
    parser.add_argument('inputs', nargs='+', type=Path, metavar='BAG_OR_SCENARIO')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT,
                        help=f'output folder (default: {DEFAULT_OUT})')
    parser.add_argument('--seeds', type=int, default=None, metavar='N',
                        help='simulate each scenario file N times with different seeds')
    parser.add_argument('--seed-start', type=int, default=1, help='first seed (default 1)')
    parser.add_argument('--jobs', type=int, default=None,
                        help='parallel runs (default: the number of cores)')
    parser.add_argument('--as-recorded', action='store_true',
                        help='score bags as they are, without replaying them through a graph')
    parser.add_argument('--executor', choices=('events', 'single', 'multi'), default=None)
    parser.add_argument('--offline', action='store_true',
                        help="run the graph's processors with the offline engine (no DDS: no "
                             'message dropped, several times faster) instead of the live graph')
    parser.add_argument('--params', action='append', default=[], metavar='PARAMS_FILE',
                        help="the vehicle's ROS params file (repeatable; later wins)")
    parser.add_argument('--calibration', default=None, metavar='FILE',
                        help="the vehicle's stored calibration (node name -> state)")
    parser.add_argument('--manifest', default=None,
                        help='fleet manifest to take the vehicle from (with --vehicle)')
    parser.add_argument('--vehicle', default=None, metavar='ID',
                        help="the manifest's vehicle whose parameters and calibration to use")
    args = parser.parse_args(argv)
    if args.seeds is not None and args.seeds < 1:
        parser.error('--seeds must be at least 1')
    if (args.manifest is None) != (args.vehicle is None):
        parser.error('--manifest and --vehicle go together')
    def run() -> int:
        registered = domains()
        vehicle = read_vehicle(args.params, args.calibration, args.manifest, args.vehicle)
        if vehicle != Vehicle() and args.as_recorded:
            raise ConfigurationError('--as-recorded scores outputs already recorded: the '
                                     'vehicle options do not apply')
        tasks = [replace(t, vehicle=vehicle, offline=args.offline) for t in
                 plan(args.inputs, registered, args.seeds, args.seed_start, args.as_recorded)]
        jobs = max(1, min(args.jobs or os.cpu_count() or 1, len(tasks)))
        started = time.monotonic()
        print(f'{len(tasks)} run(s) on {jobs} process(es) into {args.out}/', flush=True)
        args.out.mkdir(parents=True, exist_ok=True)
        if jobs == 1:
            from vehicle_monitor_common.main_job import use_private_domain

            use_private_domain()
            results = []
            for task in tasks:
                print(f'- {task.name}', flush=True)
                results.append(run_task(task, args.out, args.executor))
        else:
            # spawn: a forked process would inherit the parent's DDS state.
            spawn = multiprocessing.get_context('spawn')
            counter = spawn.Value('i', 0)
            with spawn.Pool(jobs, initializer=_init_worker,
                            initargs=(counter, os.getpid())) as pool:
                results = pool.map(_worker, [(t, args.out, args.executor) for t in tasks],
                                   chunksize=1)
        evaluations = [e for e, _ in results]
        runs = [r for _, r in results if r is not None]
        summary = batch_summary(tasks, evaluations)
        write_results(args.out / 'results.json', evaluations, runs,
                      extra={'inputs': [str(p) for p in args.inputs], 'seeds': args.seeds,
                             'batch': summary})
        write_report(args.out / 'report.md', evaluations, runs, title='Evaluation report')
        print()
        print(render_scoreboard(evaluations, runs))
        batch = render_batch_summary(summary)
        if batch:
            print('\nover the seeds:\n' + batch)
        print(f'\n{time.monotonic() - started:.0f} s wall; results.json, report.md and figures '
              f'in {args.out}/')
        return 0

    return run_cli(run, (ConfigurationError, BagError, RuntimeError, FileNotFoundError,
                                ValueError))


if __name__ == '__main__':
    sys.exit(main())

