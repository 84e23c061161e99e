"""Which recordings to screen and each vehicle's configuration: the fleet manifest.

A manifest is a YAML file (paths relative to it)::

    defaults:                       # for every vehicle (each key may be overridden per vehicle)
      graph: road                   # a domain (road, rail) or a graph / YAML launch file;
                                    # default: the domain whose input topics the recording has
    vehicles:
      car0042:
        params: [params/car0042.yaml]   # ROS params files, as the nodes take them (--params-file)
        parameters:                     # and/or values by node name or fully qualified name
          tire_stiffness_observer: {driven_axle: front}
        calibration: calib/car0042.yaml # stored calibration: node (name or fqn) -> state
        launch_args: {namespace: car0042}
    recordings:
      - {path: drives/car0042/2026-11-03, vehicle: car0042, time: 2026-11-03T07:12:00Z}
      - drives/car0042/2026-11-04       # vehicle: its parent directory's name; time: the bag's

Instead of a manifest, the ``fleet`` command takes bag directories, a directory holding bags
(``<root>/<vehicle>/<bag>``: vehicle = the first directory below the root; bags directly in the
root are each their own vehicle) or glob patterns; every vehicle then has the defaults.
A recording may be a URI (``s3://...``, ``gs://...``, anything ``pyarrow.fs`` opens): the task
copies the bag directory to local scratch space first (rosbags reads local files).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
import datetime as dt
import glob
import os
from pathlib import Path
import re
from typing import Any

import yaml

from vehicle_monitor_common.graph_spec import read_yaml_file
from vehicle_monitor_common.parameters import ConfigurationError

_URI = re.compile(r'^[a-zA-Z][a-zA-Z0-9+.-]*://')


def is_uri(path: str) -> bool:
    """Whether ``path`` is a URI (``scheme://...``) rather than a local path."""
    return bool(_URI.match(path)) and not path.startswith('file://')


@dataclass(frozen=True)
class VehicleConfig:
    """How one vehicle's recordings are run."""

    vehicle: str
    graph: str | None = None
    launch_args: Mapping[str, str] = field(default_factory=dict)
    params: tuple[str, ...] = ()
    parameters: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    calibration: str | None = None


@dataclass(frozen=True)
class Recording:
    """One recording to screen.

    Attributes:
        key: unique name of the recording in the results (``<vehicle>/<bag name>``).
        path: the bag directory (local path or URI).
        vehicle: vehicle id.
        time: when it was recorded (UTC), None when unknown: from the manifest, else the bag's
            first message.
    """

    key: str
    path: str
    vehicle: str
    time: dt.datetime | None = None

    @property
    def date(self) -> str:
        """The partition date, ``YYYY-MM-DD`` (``unknown`` without a time)."""
        return self.time.date().isoformat() if self.time is not None else 'unknown'


@dataclass(frozen=True)
class Manifest:
    """Recordings and vehicle configurations."""

    recordings: tuple[Recording, ...]
    vehicles: Mapping[str, VehicleConfig]
    defaults: VehicleConfig = field(default_factory=lambda: VehicleConfig(''))

    def vehicle(self, vehicle: str) -> VehicleConfig:
        """The configuration of a vehicle (the defaults for one not listed)."""
        return self.vehicles.get(vehicle) or VehicleConfig(
            vehicle, self.defaults.graph, self.defaults.launch_args, self.defaults.params,
            self.defaults.parameters, self.defaults.calibration)


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (holds metadata.yaml)."""
    return path.is_dir() and (path / 'metadata.yaml').is_file()


def bag_start_time(path: str) -> dt.datetime | None:
    """The first message's log time of a local bag from its metadata (None if unreadable)."""
    try:
        with open(Path(path) / 'metadata.yaml', encoding='utf-8') as stream:
            info = yaml.safe_load(stream)['rosbag2_bagfile_information']
        start = int(info['starting_time']['nanoseconds_since_epoch'])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError):
        return None
    return dt.datetime.fromtimestamp(start * 1e-9, dt.UTC)


def _resolve(base: Path, path: str) -> str:
    if is_uri(path) or os.path.isabs(path):
        return path
    return str(base / path)


def _time(value: Any, where: str) -> dt.datetime | None:
    if value is None:
        return None
    if isinstance(value, dt.datetime):
        moment = value
    elif isinstance(value, dt.date):
        moment = dt.datetime(value.year, value.month, value.day)
    else:
        try:
            moment = dt.datetime.fromisoformat(str(value).replace('Z', '+00:00'))
        except ValueError:
            raise ConfigurationError(f'{where}: time {value!r} is not an ISO date/time') from None
    return moment if moment.tzinfo else moment.replace(tzinfo=dt.UTC)


def _vehicle_config(vehicle: str, entry: Any, base: Path, defaults: VehicleConfig,
                    where: str) -> VehicleConfig:
    if entry is None:
        entry = {}
    if not isinstance(entry, dict):
        raise ConfigurationError(f'{where}: expected a mapping')
    unknown = set(entry) - {'graph', 'launch_args', 'params', 'parameters', 'calibration'}
    if unknown:
        raise ConfigurationError(f'{where}: unknown key {sorted(unknown)[0]!r}')
    params = entry.get('params', list(defaults.params))
    params = [params] if isinstance(params, str) else list(params or [])
    parameters = entry.get('parameters', defaults.parameters) or {}
    if not isinstance(parameters, dict) or not all(
            isinstance(v, dict) for v in parameters.values()):
        raise ConfigurationError(f'{where}: parameters must map node names to values')
    graph = entry.get('graph', defaults.graph)
    if graph is not None and ('/' in str(graph) or str(graph).endswith(('.yaml', '.yml'))):
        graph = _resolve(base, str(graph))
    calibration = entry.get('calibration', defaults.calibration)
    return VehicleConfig(
        vehicle=vehicle, graph=None if graph is None else str(graph),
        launch_args={str(k): str(v) for k, v in
                     (entry.get('launch_args', defaults.launch_args) or {}).items()},
        params=tuple(_resolve(base, str(p)) for p in params),
        parameters={str(k): dict(v) for k, v in parameters.items()},
        calibration=None if calibration is None else _resolve(base, str(calibration)))


def read_manifest(path: str | os.PathLike[str]) -> Manifest:
    """Read and check a manifest file (see the module docstring).

    Raises:
        ConfigurationError: unreadable, malformed, or naming a vehicle twice.
    """
    base = Path(path).resolve().parent
    data = read_yaml_file(path, 'manifest')
    if not isinstance(data, dict) or 'recordings' not in data:
        raise ConfigurationError(f'{path}: not a fleet manifest (no recordings list)')
    unknown = set(data) - {'defaults', 'vehicles', 'recordings'}
    if unknown:
        raise ConfigurationError(f'{path}: unknown key {sorted(unknown)[0]!r}')
    defaults = _vehicle_config('', data.get('defaults'), base, VehicleConfig(''),
                               f'{path}: defaults')
    vehicles = {str(v): _vehicle_config(str(v), entry, base, defaults, f'{path}: vehicle {v}')
                for v, entry in (data.get('vehicles') or {}).items()}
    entries = []
    for index, entry in enumerate(data.get('recordings') or []):
        where = f'{path}: recordings[{index}]'
        if isinstance(entry, str):
            entry = {'path': entry}
        if not isinstance(entry, dict) or 'path' not in entry:
            raise ConfigurationError(f'{where}: needs a path')
        bad = set(entry) - {'path', 'vehicle', 'time'}
        if bad:
            raise ConfigurationError(f'{where}: unknown key {sorted(bad)[0]!r}')
        location = _resolve(base, str(entry['path']))
        vehicle = str(entry.get('vehicle') or Path(location.rstrip('/')).parent.name)
        entries.append((location, vehicle, _time(entry.get('time'), where)))
    return Manifest(_recordings(entries), vehicles, defaults)


def _recordings(entries: Iterable[tuple[str, str, dt.datetime | None]],
                ) -> tuple[Recording, ...]:
    """Recordings with unique keys; times from the bags where not given."""
    recordings = []
    used: set[str] = set()
    for location, vehicle, time in entries:
        if time is None and not is_uri(location):
            time = bag_start_time(location)
        name = Path(location.rstrip('/')).name or 'recording'
        key, n = f'{vehicle}/{name}', 1
        while key in used:
            n += 1
            key = f'{vehicle}/{name}_{n}'
        used.add(key)
        recordings.append(Recording(key, location, vehicle, time))
    return tuple(recordings)


def find_recordings(inputs: Sequence[str]) -> Manifest:
    """Recordings from bag directories, directories of bags or glob patterns (defaults only).

    Raises:
        ConfigurationError: an input matches nothing, or a directory holds no bag.
    """
    entries: list[tuple[str, str, dt.datetime | None]] = []
    for item in inputs:
        if is_uri(item):
            entries.append((item, Path(item.rstrip('/')).name, None))
            continue
        matches = sorted(glob.glob(item)) if glob.has_magic(item) else [item]
        if not matches:
            raise ConfigurationError(f'{item}: no recording matches')
        for match in matches:
            root = Path(match)
            if is_bag(root):
                entries.append((str(root), root.name, None))
                continue
            if not root.exists():
                raise ConfigurationError(f'{item}: no such file or directory')
            if not root.is_dir():
                if glob.has_magic(item):
                    continue  # a pattern may match other files beside the bags
                raise ConfigurationError(f'{item}: not a bag directory, a directory of bags, '
                                         'a glob pattern or a manifest')
            bags = sorted(p.parent for p in root.rglob('metadata.yaml'))
            if not bags:
                raise ConfigurationError(f'{item}: holds no recording (no rosbag2 directory)')
            for bag in bags:
                below = bag.relative_to(root).parts
                vehicle = below[0] if len(below) > 1 else bag.name
                entries.append((str(bag), vehicle, None))
    return Manifest(_recordings(entries), {})


def load_inputs(inputs: Sequence[str]) -> Manifest:
    """A manifest file (one input ending in .yaml/.yml) or the recordings the inputs name."""
    if len(inputs) == 1 and inputs[0].endswith(('.yaml', '.yml')) and os.path.isfile(inputs[0]):
        return read_manifest(inputs[0])
    return find_recordings(inputs)
