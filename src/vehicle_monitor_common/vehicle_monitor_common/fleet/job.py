"""The fleet job: one task per recording, chained per vehicle, results as Parquet datasets.

A task (:func:`run_recording`) runs its vehicle's graph (the offline engine: the nodes'
processors, no ROS) over one recording with the vehicle's parameters and the calibration in
force when the drive started, summarises the outputs as they stream out
(:mod:`.summaries`), and returns the rows, the episodes and the calibration in force at the end.
Whatever goes wrong with the recording (missing, not a bag, truncated, another robot's) becomes
the recording's error row; the job goes on.

The driver (:func:`run_fleet`) submits every task at once to an executor: Ray
(:class:`RayExecutor`) or, for tests and one-off runs, this process (:class:`LocalExecutor`).
A vehicle's tasks form a chain in time order, each taking the calibration its predecessor
returns, as the car would carry it from drive to drive; different vehicles run in parallel.
As each task completes, the driver writes its results atomically (temporary file, then
``os.replace``), partitioned by vehicle and date (hive layout, ``vehicle=<id>/date=<day>``)::

    <out>/summary/vehicle=car01/date=2026-11-03/<recording>.parquet   one row per method
    <out>/events/vehicle=car01/date=2026-11-03/<recording>.parquet    one row per episode
    <out>/calibration/vehicle=car01/<recording>.yaml                  calibration after it

The summary file is written last: its presence means the recording is done, so a rerun skips
it (unless ``force``) and continues the vehicle's chain from its stored calibration.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
import contextlib
from dataclasses import dataclass, field
import datetime as dt
import math
import os
from pathlib import Path
import re
import shutil
import tempfile
import time
from typing import Any, Protocol

import pyarrow as pa
import pyarrow.dataset as pads
import pyarrow.parquet as pq
import yaml

from vehicle_monitor_common.bag_io import BagError, bag_topics
from vehicle_monitor_common.calibration_store import load_calibration
from vehicle_monitor_common.fleet.manifest import Manifest, Recording, VehicleConfig, is_uri
from vehicle_monitor_common.fleet.summaries import (
    EVENT_FIELDS,
    SUMMARY_FIELDS,
    RecordingSummary,
)
from vehicle_monitor_common.graph_spec import (
    GraphSpec,
    fully_qualified_name,
    load_graph,
    node_parameter_values,
)
from vehicle_monitor_common.offline_engine import OfflineGraph, factory_for, processor_factories
from vehicle_monitor_common.parameters import ConfigurationError

Calibration = dict[str, dict[str, Any]]
"""A vehicle's calibration: node fully qualified name -> the processor's calibration state."""

#: Columns identifying a recording in both tables (vehicle and date are the partitions).
RECORDING_FIELDS: dict[str, type] = {
    'recording': str, 'path': str, 'time': dt.datetime, 'graph': str, 'error': str,
    'duration_s': float, 'messages_in': int, 'messages_out': int, 'wall_s': float,
    'real_time_factor': float, 'health_level': int, 'health': str, 'inputs_missing': str,
    'calibration_in': str,
}
PARTITIONS = ('vehicle', 'date')
_ARROW = {str: pa.string(), int: pa.int64(), float: pa.float64(), bool: pa.bool_(),
          dt.datetime: pa.timestamp('ns', tz='UTC')}


def _schema(fields: Mapping[str, type]) -> pa.Schema:
    return pa.schema([(name, _ARROW[kind]) for name, kind in fields.items()])


SUMMARY_SCHEMA = _schema({**RECORDING_FIELDS, **SUMMARY_FIELDS})
EVENTS_SCHEMA = _schema({'recording': str, **EVENT_FIELDS})
PARTITIONING = pads.partitioning(pa.schema([(p, pa.string()) for p in PARTITIONS]),
                                 flavor='hive')


@dataclass(frozen=True)
class Task:
    """One recording and how its vehicle is configured (picklable: sent to a Ray worker)."""

    recording: Recording
    vehicle: VehicleConfig


@dataclass
class RecordingResult:
    """What a task returns."""

    recording: Recording
    rows: list[dict[str, Any]]
    events: list[dict[str, Any]]
    calibration: Calibration | None
    error: str = ''
    wall_s: float = 0.0
    data_s: float = 0.0


# ---------------------------------------------------------------------------------------------
# One task


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f'{type(exc).__name__}: {text[0] if text else ""}'.rstrip(': ')


def resolve_graph(vehicle: VehicleConfig, bag: str | os.PathLike[str]) -> tuple[GraphSpec, str]:
    """The vehicle's graph (a domain name, a graph or launch file, or the domain whose input
    topics the bag has) and how to name it in the results."""
    from vehicle_monitor_common.evaluation import domain_of_bag, domains

    if vehicle.graph is not None and (os.sep in vehicle.graph or
                                      vehicle.graph.endswith(('.yaml', '.yml'))):
        return load_graph(vehicle.graph, dict(vehicle.launch_args) or None), vehicle.graph
    registered = domains()
    if vehicle.graph is not None:
        domain = next((d for d in registered if d.name == vehicle.graph), None)
        if domain is None:
            raise ConfigurationError(f'no domain {vehicle.graph!r} (known: '
                                     f'{", ".join(d.name for d in registered)})')
    else:
        try:
            domain = domain_of_bag(bag, registered)
        except ValueError as exc:
            raise BagError(f'foreign recording: {str(exc).split(": ", 1)[-1]}') from None
    return load_graph(domain.graph), domain.name


def vehicle_parameters(spec: GraphSpec, vehicle: VehicleConfig,
                       calibration: Mapping[str, Any] | None = None,
                       ) -> dict[str, dict[str, Any]]:
    """Per node (fully qualified name) the values the vehicle sets over the graph's own: its
    params files (matched to each node as rcl does), then its per-node values. A node whose
    stored calibration is given does not recalibrate at the start (``calibrate_on_start``
    off), as on the car once a calibration is saved."""
    factories = processor_factories()
    given = calibration or {}
    parameters: dict[str, dict[str, Any]] = {}
    for node in spec.nodes:
        if factory_for(node.plugin, factories) is None:
            continue
        name = node.name or node.plugin.split('/')[-1]
        fqn = fully_qualified_name(node.namespace, name)
        values = node_parameter_values(fqn, vehicle.params, {})
        values.update(vehicle.parameters.get(name, {}))
        values.update(vehicle.parameters.get(fqn, {}))
        if fqn in given or name in given:
            graph_values = node_parameter_values(fqn, node.param_files, node.parameters)
            if 'calibrate_on_start' in {**graph_values, **values}:
                values['calibrate_on_start'] = False
        if values:
            parameters[fqn] = values
    return parameters


def read_calibration_file(path: str) -> Calibration:
    """A stored vehicle calibration (node name or fqn -> state).

    Raises:
        ConfigurationError: the file is missing, unreadable or not such a mapping.
    """
    loaded = load_calibration(path)
    if not loaded.exists:
        raise ConfigurationError(f'no calibration file {path}')
    if loaded.state is None:
        raise ConfigurationError(f'calibration {path}: {loaded.problem}')
    if not all(isinstance(v, dict) for v in loaded.state.values()):
        raise ConfigurationError(f'calibration {path}: expected node -> state mappings')
    return {str(k): dict(v) for k, v in loaded.state.items()}


@contextlib.contextmanager
def _local_copy(path: str) -> Iterator[str]:
    """The bag as a local directory: a URI's bag is copied to scratch space (pyarrow.fs)."""
    if not is_uri(path):
        yield path
        return
    from pyarrow import fs

    scratch = tempfile.mkdtemp(prefix='fleet-')
    try:
        local = os.path.join(scratch, path.rstrip('/').rsplit('/', 1)[-1])
        try:
            fs.copy_files(path.rstrip('/'), local)
        except (OSError, pa.ArrowException) as exc:
            raise BagError(f'cannot fetch {path}: {_one_line(exc)}') from None
        yield local
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def _base_row(task: Task) -> dict[str, Any]:
    row: dict[str, Any] = {name: None for name in RECORDING_FIELDS}
    row.update(recording=task.recording.key, path=task.recording.path,
               time=task.recording.time, error='', calibration_in='')
    return row


def run_recording(task: Task, calibration: Calibration | None = None) -> RecordingResult:
    """Screen one recording (see the module docstring); never raises for a bad recording.

    Args:
        task: the recording and its vehicle.
        calibration: the calibration in force at the start (the previous drive's result, or
            the vehicle's stored one); None: the graph's own start-up behaviour.
    """
    started = time.perf_counter()
    base = _base_row(task)
    try:
        with _local_copy(task.recording.path) as bag:
            return _screen(task, bag, calibration, base, started)
    except Exception as exc:  # noqa: BLE001 - any failure is this recording's result row
        return error_result(task, _one_line(exc), calibration, time.perf_counter() - started)


def error_result(task: Task, error: str, calibration: Calibration | None = None,
                 wall_s: float = 0.0) -> RecordingResult:
    """The result of a recording that could not be screened: its row with the error; the
    calibration passes on unchanged."""
    base = _base_row(task)
    base.update(error=error, wall_s=wall_s)
    return RecordingResult(task.recording, [base], [], calibration, error, wall_s)


def _screen(task: Task, bag: str, calibration: Calibration | None, base: dict[str, Any],
            started: float) -> RecordingResult:
    recorded = bag_topics(bag)  # a BagError names what is wrong with it
    spec, graph_name = resolve_graph(task.vehicle, bag)
    base['graph'] = graph_name
    graph = OfflineGraph.from_spec(spec, vehicle_parameters(spec, task.vehicle, calibration))
    present = graph.input_topics & set(recorded)
    if not present:
        raise BagError(f'foreign recording: none of the graph\'s inputs '
                       f'({", ".join(sorted(graph.input_topics))}) is in it')
    base['inputs_missing'] = ','.join(sorted(graph.input_topics - set(recorded)
                                             - _published_topics(graph)))
    notes = []
    for node in graph.nodes:
        load = getattr(node.processor, 'load_calibration_state', None)
        name = node.fqn.rsplit('/', 1)[-1]
        state = (calibration or {}).get(node.fqn, (calibration or {}).get(name))
        if load is None or state is None:
            continue
        try:
            load(state)
            notes.append(f'{name}: loaded')
        except ValueError as exc:
            notes.append(f'{name}: refused ({_one_line(exc)})')
    base['calibration_in'] = '; '.join(notes)
    summary = RecordingSummary()
    stats = graph.run(bag, summary)
    origin = stats.first_ns or 0
    statuses = [(node.fqn, node.processor.status(stats.last_ns or 0)) for node in graph.nodes]
    base.update(
        duration_s=stats.data_s, messages_in=stats.messages_in,
        messages_out=stats.messages_out, wall_s=time.perf_counter() - started,
        real_time_factor=stats.real_time_factor if math.isfinite(stats.real_time_factor)
        else None,
        health_level=max((s.level for _, s in statuses), default=0),
        health='; '.join(f'{fqn}: {s.message}' for fqn, s in statuses if s.level > 0))
    rows = [{**base, **row} for row in summary.rows(origin)] or [{**base, 'method': ''}]
    events = [{'recording': task.recording.key, **event} for event in summary.events(origin)]
    out = dict(calibration or {})
    for node in graph.nodes:
        state_of = getattr(node.processor, 'calibration_state', None)
        if state_of is not None:
            state = state_of()
            if state is not None:
                out[node.fqn] = dict(state)
    return RecordingResult(task.recording, rows, events, out or None, '', base['wall_s'],
                           stats.data_s)


def _published_topics(graph: OfflineGraph) -> set[str]:
    return {node.topic(name) for node in graph.nodes for name in node.processor.outputs}


# ---------------------------------------------------------------------------------------------
# Executors


class Executor(Protocol):
    """Runs tasks; a task's calibration may be the pending calibration of another task."""

    def submit(self, task: Task, calibration: Any) -> tuple[Any, Any]:
        """Start a task; (handle of its result, handle of the calibration it returns)."""

    def next_done(self) -> RecordingResult:
        """Wait for any submitted task to finish; its result."""

    def close(self) -> None:
        """Release what the executor holds."""


class _Later:
    """A local task's result, once it has run."""

    result: RecordingResult | None = None


class LocalExecutor:
    """Runs the tasks one by one in this process, in submission order, so a chained task's
    predecessor has always run (tests, a single machine without Ray)."""

    def __init__(self) -> None:
        self._queue: list[tuple[Task, Any, _Later]] = []

    def submit(self, task: Task, calibration: Any) -> tuple[Any, Any]:
        later = _Later()
        self._queue.append((task, calibration, later))
        return later, later

    def next_done(self) -> RecordingResult:
        task, calibration, later = self._queue.pop(0)
        if isinstance(calibration, _Later):
            assert calibration.result is not None, 'a chained task ran before its predecessor'
            calibration = calibration.result.calibration
        later.result = run_recording(task, calibration)
        return later.result

    def close(self) -> None:
        self._queue.clear()


def _ray_task(task: Task, calibration: Calibration | None,
              ) -> tuple[RecordingResult, Calibration | None]:
    result = run_recording(task, calibration)
    return result, result.calibration


class RayExecutor:
    """One Ray task per recording (``ray.remote``, one CPU each): an embedded local Ray by
    default, an existing cluster with ``address``. A chained task gets its predecessor's
    calibration as an ObjectRef argument, so Ray starts it once that task has finished."""

    def __init__(self, address: str | None = None, num_cpus: int | None = None,
                 runtime_env: Mapping[str, Any] | None = None) -> None:
        import ray

        self._ray = ray
        self._started = not ray.is_initialized()
        if self._started:
            kwargs: dict[str, Any] = {'include_dashboard': False, 'log_to_driver': False,
                                      'logging_level': 'ERROR'}
            if address:
                kwargs['address'] = address
            elif num_cpus:
                kwargs['num_cpus'] = num_cpus
            if runtime_env:
                kwargs['runtime_env'] = dict(runtime_env)
            ray.init(**kwargs)
        self._remote = ray.remote(num_returns=2, num_cpus=1, max_retries=1)(_ray_task)
        self._pending: list[Any] = []
        self._tasks: dict[Any, Task] = {}

    def submit(self, task: Task, calibration: Any) -> tuple[Any, Any]:
        refs: Any = self._remote.remote(task, calibration)  # num_returns=2: two ObjectRefs
        self._pending.append(refs[0])
        self._tasks[refs[0]] = task
        return refs[0], refs[1]

    def next_done(self) -> RecordingResult:
        done, self._pending = self._ray.wait(self._pending, num_returns=1)
        task = self._tasks.pop(done[0])
        try:
            result: RecordingResult = self._ray.get(done[0])
        except self._ray.exceptions.RayError as exc:
            # the worker died (out of memory, killed) even after a retry, or the task it
            # waited for did: this recording's error row, the job goes on
            result = error_result(task, f'task failed: {_one_line(exc)}')
        return result

    def close(self) -> None:
        if self._started:
            self._ray.shutdown()


# ---------------------------------------------------------------------------------------------
# Writing and resuming

_UNSAFE = re.compile(r'[^A-Za-z0-9._-]')


def _safe(name: str) -> str:
    return _UNSAFE.sub('_', name) or '_'


def result_paths(out: Path, recording: Recording) -> dict[str, Path]:
    """Where a recording's summary, events and calibration go."""
    name = _safe(recording.key.split('/', 1)[-1]) + '.parquet'
    vehicle = f'vehicle={_safe(recording.vehicle)}'
    part = Path(vehicle) / f'date={recording.date}'
    return {'summary': out / 'summary' / part / name, 'events': out / 'events' / part / name,
            'calibration': out / 'calibration' / vehicle / (name[:-8] + '.yaml')}


def _atomic(path: Path, write: Callable[[Path], None]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=f'.{path.name}.', dir=path.parent)
    os.close(handle)
    try:
        write(Path(tmp))
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _table(rows: Sequence[Mapping[str, Any]], schema: pa.Schema) -> pa.Table:
    columns = {name: [row.get(name) for row in rows] for name in schema.names}
    for name, values in columns.items():  # NaN is no value in Parquet's eyes: write null
        columns[name] = [None if isinstance(v, float) and math.isnan(v) else v for v in values]
    return pa.Table.from_pydict(columns, schema=schema)


def write_result(out: Path, result: RecordingResult) -> None:
    """Write a task's tables and calibration atomically; the summary last (done marker)."""
    paths = result_paths(out, result.recording)
    events = _table(result.events, EVENTS_SCHEMA)
    _atomic(paths['events'], lambda tmp: pq.write_table(events, tmp))
    if result.calibration is not None:
        text = yaml.safe_dump(_plain(result.calibration), sort_keys=True)
        _atomic(paths['calibration'], lambda tmp: _write_text(tmp, text))
    summary = _table(result.rows, SUMMARY_SCHEMA)
    _atomic(paths['summary'], lambda tmp: pq.write_table(summary, tmp))


def _write_text(path: Path, text: str) -> None:
    path.write_text(text, encoding='utf-8')


def _plain(value: Any) -> Any:
    """Numpy scalars and arrays as plain YAML-able values."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if hasattr(value, 'tolist'):
        return _plain(value.tolist())
    return value


def stored_calibration(out: Path, recording: Recording) -> Calibration | None:
    """The calibration a finished recording left (None: none was learned)."""
    path = result_paths(out, recording)['calibration']
    if not path.is_file():
        return None
    return read_calibration_file(str(path))


def read_table(out: str | os.PathLike[str], name: str) -> pa.Table:
    """A result dataset (``summary`` or ``events``) with its vehicle and date partitions."""
    root = Path(out) / name
    schema = SUMMARY_SCHEMA if name == 'summary' else EVENTS_SCHEMA
    full = schema.append(pa.field('vehicle', pa.string())).append(pa.field('date', pa.string()))
    if not root.is_dir():
        return full.empty_table()
    dataset = pads.dataset(root, format='parquet', partitioning=PARTITIONING, schema=full,
                           exclude_invalid_files=True)
    return dataset.to_table()


# ---------------------------------------------------------------------------------------------
# The job


@dataclass
class FleetRun:
    """What a run of the job did."""

    total: int = 0
    skipped: int = 0
    done: int = 0
    failed: int = 0
    wall_s: float = 0.0
    data_s: float = 0.0
    task_wall_s: float = 0.0
    errors: list[str] = field(default_factory=list)

    @property
    def throughput(self) -> float:
        """Recordings screened per wall second."""
        return self.done / self.wall_s if self.wall_s > 0 else 0.0


def chains(manifest: Manifest) -> list[list[Task]]:
    """Per vehicle its tasks in recording time order (unknown times last, by key)."""
    by_vehicle: dict[str, list[Recording]] = {}
    for recording in manifest.recordings:
        by_vehicle.setdefault(recording.vehicle, []).append(recording)
    far = dt.datetime.max.replace(tzinfo=dt.UTC)
    return [[Task(r, manifest.vehicle(vehicle))
             for r in sorted(recordings, key=lambda r: (r.time or far, r.key))]
            for vehicle, recordings in sorted(by_vehicle.items())]


def run_fleet(manifest: Manifest, out: str | os.PathLike[str], executor: Executor, *,
              force: bool = False, log: Callable[[str], None] = print) -> FleetRun:
    """Screen every recording of the manifest into ``out`` (see the module docstring)."""
    out = Path(out)
    run = FleetRun(total=len(manifest.recordings))
    started = time.perf_counter()
    submitted = 0
    for chain in chains(manifest):
        vehicle = chain[0].vehicle
        calibration: Any = None
        if vehicle.calibration is not None:
            try:
                calibration = read_calibration_file(vehicle.calibration)
            except ConfigurationError as exc:
                log(f'{chain[0].recording.vehicle}: {exc}; starting uncalibrated')
        for task in chain:
            if not force and result_paths(out, task.recording)['summary'].is_file():
                run.skipped += 1
                calibration = stored_calibration(out, task.recording) or calibration
                continue
            _, calibration = executor.submit(task, calibration)
            submitted += 1
    if run.skipped:
        log(f'{run.skipped} of {run.total} recording(s) already screened (--force to redo)')
    for index in range(submitted):
        result = executor.next_done()
        write_result(out, result)
        run.done += 1
        run.data_s += result.data_s
        run.task_wall_s += result.wall_s
        if result.error:
            run.failed += 1
            run.errors.append(f'{result.recording.key}: {result.error}')
        elapsed = time.perf_counter() - started
        rate = (index + 1) / elapsed if elapsed > 0 else 0.0
        eta = (submitted - index - 1) / rate if rate > 0 else 0.0
        what = f'error: {result.error}' if result.error else (
            f'{result.data_s:.0f} s of data in {result.wall_s:.1f} s')
        log(f'[{run.skipped + index + 1}/{run.total}] {result.recording.key}: {what} | '
            f'{rate:.2f} recordings/s, ETA {eta:.0f} s')
    run.wall_s = time.perf_counter() - started
    return run
