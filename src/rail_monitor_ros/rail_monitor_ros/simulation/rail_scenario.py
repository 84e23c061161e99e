"""Rail simulator scenarios: YAML schema, validation and the parameter profiles over time.

A scenario fixes the vehicle, the track, the sensors and the events (steps and ramps of the
secondary lateral spring and damper ratios per bogie, the creep factor and the speed). The
schema is documented in ``docs/rail_scenario_schema.md``; every unknown key, non-physical value
or out-of-order event is refused with a ValueError naming the key. No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
import math
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rail_monitor_ros.core.rail_model import (
    MAX_CREEP_FACTOR,
    MAX_SUSPENSION_RATIO,
    RailVehicleParams,
)
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from vehicle_monitor_common.resources import share_dir, shipped_file

MAX_SPEED = 150.0  # m/s; beyond any rail vehicle, and far beyond the linear model's validity
EVENT_QUANTITIES = ('spring_ratio', 'damper_ratio', 'creep_factor', 'speed')
BOGIE_NAMES = {'front': (0,), 'rear': (1,), 'both': (0, 1)}

SCENARIO_DIR = share_dir('rail_monitor_ros', 'scenarios')


@dataclass(frozen=True)
class TrackConfig:
    """Track irregularity settings.

    Attributes:
        spectrum: key of :data:`rail_monitor_ros.core.track_spectra.TRACK_SPECTRA`.
        min_wavelength: shortest wavelength, m.
        max_wavelength: longest wavelength, m.
        scale: amplitude multiplier on the published spectrum.
    """

    spectrum: str = 'german_low'
    min_wavelength: float = 1.0
    max_wavelength: float = 120.0
    scale: float = 1.0


@dataclass(frozen=True)
class SensorConfig:
    """Sensor noise (standard deviation of white Gaussian noise per sample) and constant bias.

    Attributes:
        bogie_accel_noise: bogie lateral accelerometer, m/s^2.
        bogie_accel_bias: m/s^2.
        bogie_gyro_noise: bogie yaw-rate gyro, rad/s.
        bogie_gyro_bias: rad/s.
        body_accel_noise: body lateral accelerometer above the front bogie, m/s^2.
        body_accel_bias: m/s^2.
        displacement_noise: lateral displacements in RailLateralStates, m.
        velocity_noise: lateral velocities, m/s.
        yaw_noise: yaw angles, rad.
        yaw_rate_noise: yaw rates, rad/s.
        track_noise: track alignment on /rail/track_irregularity, m.
        track_rate_noise: its rate, m/s.
    """

    bogie_accel_noise: float = 0.02
    bogie_accel_bias: float = 0.0
    bogie_gyro_noise: float = 1e-3
    bogie_gyro_bias: float = 0.0
    body_accel_noise: float = 0.02
    body_accel_bias: float = 0.0
    displacement_noise: float = 1e-4
    velocity_noise: float = 1e-3
    yaw_noise: float = 1e-4
    yaw_rate_noise: float = 1e-3
    track_noise: float = 0.0
    track_rate_noise: float = 0.0


@dataclass(frozen=True)
class InitialConditions:
    """Values at t = 0 (and during the warm-up).

    Attributes:
        speed: forward speed, m/s.
        creep_factor: c, 1.
        spring_ratio: (front, rear) secondary lateral spring ratio.
        damper_ratio: (front, rear) secondary lateral damper ratio.
    """

    speed: float = 40.0
    creep_factor: float = 1.0
    spring_ratio: tuple[float, float] = (1.0, 1.0)
    damper_ratio: tuple[float, float] = (1.0, 1.0)


@dataclass(frozen=True)
class RailEvent:
    """A change of one quantity: a step (ramp = 0) or a linear ramp from the previous value.

    Attributes:
        time: start, s from the scenario start.
        quantity: one of :data:`EVENT_QUANTITIES`.
        value: target value.
        ramp: ramp duration, s (0 = step).
        bogies: bogie indices the change applies to (suspension ratios only; () otherwise).
    """

    time: float
    quantity: str
    value: float
    ramp: float = 0.0
    bogies: tuple[int, ...] = ()


@dataclass(frozen=True)
class RailScenario:
    """A validated scenario.

    Attributes:
        name: short identifier.
        description: free text.
        duration: simulated time after the warm-up, s.
        seed: seed of every random draw (track and sensor noise).
        output_rate: sample rate of the published signals, Hz.
        internal_rate: integration rate (an integer multiple of output_rate), Hz.
        warm_up: time simulated before t = 0 with the initial values, so the run starts in the
            stationary random response rather than at rest, s.
        vehicle: vehicle parameters (speed = initial speed).
        track: track settings.
        sensors: sensor noise and bias.
        initial: values at t = 0.
        events: changes, in time order.
    """

    name: str
    description: str
    duration: float
    seed: int
    output_rate: float
    internal_rate: float
    warm_up: float
    vehicle: RailVehicleParams
    track: TrackConfig
    sensors: SensorConfig
    initial: InitialConditions
    events: tuple[RailEvent, ...]


@dataclass(frozen=True)
class ParameterProfiles:
    """Piecewise-linear parameter histories evaluated at given times.

    Attributes:
        time: (N,) s.
        speed: (N,) m/s.
        creep_factor: (N,).
        spring_ratio: (N, 2) front, rear.
        damper_ratio: (N, 2) front, rear.
    """

    time: np.ndarray
    speed: np.ndarray
    creep_factor: np.ndarray
    spring_ratio: np.ndarray
    damper_ratio: np.ndarray


_TOP_KEYS = {'name', 'description', 'duration', 'seed', 'output_rate', 'internal_rate',
             'warm_up', 'vehicle', 'track', 'sensors', 'initial', 'events'}
_EVENT_KEYS = {'time', 'ramp', 'bogie', *EVENT_QUANTITIES}


def load_rail_scenario(path: str | Path) -> RailScenario:
    """Read and validate a scenario YAML file."""
    path = Path(path)
    with path.open(encoding='utf-8') as stream:
        data = yaml.safe_load(stream)
    return rail_scenario_from_dict(data)


def shipped_scenario(name: str) -> RailScenario:
    """One of the scenarios the package ships in ``scenarios/`` (name without '.yaml')."""
    try:
        path = shipped_file('rail_monitor_ros', 'scenarios', name)
    except FileNotFoundError as exc:
        raise ValueError(str(exc)) from None
    return load_rail_scenario(path)


def rail_scenario_from_dict(data: Any) -> RailScenario:
    """Validate a parsed scenario mapping (the YAML document) into a :class:`RailScenario`.

    Raises:
        ValueError: naming the offending key.
    """
    top = _mapping(data, 'scenario')
    _no_unknown(top, _TOP_KEYS, '')
    duration = _number(top, 'duration', None, lo=0.0, lo_open=True, hi=24 * 3600.0)
    seed = top.get('seed', 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f'seed must be a non-negative integer, got {seed!r}')
    output_rate = _number(top, 'output_rate', 200.0, lo=0.0, lo_open=True, hi=10000.0)
    internal_rate = _number(top, 'internal_rate', 1000.0, lo=0.0, lo_open=True, hi=100000.0)
    substeps = internal_rate / output_rate
    if abs(substeps - round(substeps)) > 1e-9 or round(substeps) < 1:
        raise ValueError(
            f'internal_rate must be an integer multiple of output_rate, got {internal_rate} and '
            f'{output_rate}')
    warm_up = _number(top, 'warm_up', 5.0, lo=0.0, hi=600.0)
    initial = _initial(top.get('initial', {}))
    vehicle = _vehicle(top.get('vehicle', {}), initial.speed)
    track = _track(top.get('track', {}))
    sensors = _sensors(top.get('sensors', {}))
    events = _events(top.get('events', []), duration)
    name = top.get('name', 'unnamed')
    description = top.get('description', '')
    for key, text in (('name', name), ('description', description)):
        if not isinstance(text, str):
            raise ValueError(f'{key} must be a string, got {text!r}')
    return RailScenario(name, description, duration, seed, output_rate, internal_rate, warm_up,
                        vehicle, track, sensors, initial, events)


def _mapping(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise ValueError(f'{where} must be a mapping, got {type(value).__name__}')
    return value


def _no_unknown(section: Mapping[str, Any], allowed: set[str], prefix: str) -> None:
    unknown = sorted(set(map(str, section)) - allowed)
    if unknown:
        raise ValueError(f"unknown key '{prefix}{unknown[0]}'; allowed: {sorted(allowed)}")


def _as_float(value: Any, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'{key} must be a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f'{key} must be finite, got {value}')
    return value


def _number(section: Mapping[str, Any], key: str, default: float | None, *, lo: float,
            hi: float, lo_open: bool = False, prefix: str = '') -> float:
    if key not in section:
        if default is None:
            raise ValueError(f'missing required key {prefix}{key!r}')
        return default
    value = _as_float(section[key], f'{prefix}{key}')
    if value < lo or (lo_open and value == lo) or value > hi:
        bracket = '(' if lo_open else '['
        raise ValueError(f'{prefix}{key} must be in {bracket}{lo}, {hi}], got {value}')
    return value


def _ratio_pair(value: Any, key: str) -> tuple[float, float]:
    items = list(value) if isinstance(value, (list, tuple)) else [value, value]
    if len(items) != 2:
        raise ValueError(f'{key} must be a number or [front, rear], got {value!r}')
    pair = tuple(_check_range(_as_float(v, key), key, MAX_SUSPENSION_RATIO) for v in items)
    return pair[0], pair[1]


def _check_range(value: float, key: str, upper: float) -> float:
    if not 0.0 < value <= upper:
        raise ValueError(f'{key} must be in (0, {upper}], got {value}')
    return value


def _initial(section: Any) -> InitialConditions:
    section = _mapping(section, 'initial')
    _no_unknown(section, {'speed', 'creep_factor', 'spring_ratio', 'damper_ratio'}, 'initial.')
    speed = _number(section, 'speed', 40.0, lo=0.0, lo_open=True, hi=MAX_SPEED,
                    prefix='initial.')
    creep = _number(section, 'creep_factor', 1.0, lo=0.0, lo_open=True, hi=MAX_CREEP_FACTOR,
                    prefix='initial.')
    spring = _ratio_pair(section.get('spring_ratio', 1.0), 'initial.spring_ratio')
    damper = _ratio_pair(section.get('damper_ratio', 1.0), 'initial.damper_ratio')
    return InitialConditions(speed, creep, spring, damper)


def _vehicle(section: Any, speed: float) -> RailVehicleParams:
    section = _mapping(section, 'vehicle')
    allowed = {f.name for f in fields(RailVehicleParams)} - {'speed'}
    if 'speed' in section:
        raise ValueError('vehicle.speed is not a vehicle key: set initial.speed or speed events')
    _no_unknown(section, allowed, 'vehicle.')
    values = {key: _as_float(value, f'vehicle.{key}') for key, value in section.items()}
    try:
        return RailVehicleParams(**values, speed=speed)
    except ValueError as error:
        raise ValueError(f'vehicle: {error}') from None


def _track(section: Any) -> TrackConfig:
    section = _mapping(section, 'track')
    _no_unknown(section, {f.name for f in fields(TrackConfig)}, 'track.')
    spectrum = section.get('spectrum', 'german_low')
    if spectrum not in TRACK_SPECTRA:
        raise ValueError(f'track.spectrum must be one of {sorted(TRACK_SPECTRA)}, got '
                         f'{spectrum!r}')
    min_wl = _number(section, 'min_wavelength', 1.0, lo=0.1, hi=1000.0, prefix='track.')
    max_wl = _number(section, 'max_wavelength', 120.0, lo=0.1, hi=1000.0, prefix='track.')
    if max_wl <= min_wl:
        raise ValueError(f'track.max_wavelength ({max_wl}) must exceed track.min_wavelength '
                         f'({min_wl})')
    scale = _number(section, 'scale', 1.0, lo=0.0, hi=100.0, prefix='track.')
    return TrackConfig(spectrum, min_wl, max_wl, scale)


def _sensors(section: Any) -> SensorConfig:
    section = _mapping(section, 'sensors')
    defaults = SensorConfig()
    spec = {f.name: float(getattr(defaults, f.name)) for f in fields(SensorConfig)}
    _no_unknown(section, set(spec), 'sensors.')
    values: dict[str, float] = {}
    for key, default in spec.items():
        if key.endswith('_bias'):
            values[key] = _number(section, key, default, lo=-1e3, hi=1e3, prefix='sensors.')
        else:
            values[key] = _number(section, key, default, lo=0.0, hi=1e3, prefix='sensors.')
    return SensorConfig(**values)


def _events(items: Any, duration: float) -> tuple[RailEvent, ...]:
    if not isinstance(items, list):
        raise ValueError(f'events must be a list, got {type(items).__name__}')
    events: list[RailEvent] = []
    for k, item in enumerate(items):
        where = f'events[{k}].'
        item = _mapping(item, f'events[{k}]')
        _no_unknown(item, _EVENT_KEYS, where)
        quantities = [q for q in EVENT_QUANTITIES if q in item]
        if len(quantities) != 1:
            raise ValueError(f'{where[:-1]} must set exactly one of {EVENT_QUANTITIES}, got '
                             f'{quantities}')
        quantity = quantities[0]
        time = _number(item, 'time', None, lo=0.0, hi=duration, prefix=where)
        ramp = _number(item, 'ramp', 0.0, lo=0.0, hi=duration, prefix=where)
        if time + ramp > duration + 1e-9:
            raise ValueError(f'{where}ramp ends at {time + ramp} s, after duration {duration} s')
        value = _as_float(item[quantity], where + quantity)
        upper = {'creep_factor': MAX_CREEP_FACTOR, 'speed': MAX_SPEED}.get(
            quantity, MAX_SUSPENSION_RATIO)
        _check_range(value, where + quantity, upper)
        bogies: tuple[int, ...] = ()
        if quantity in ('spring_ratio', 'damper_ratio'):
            bogie = item.get('bogie', 'both')
            if bogie not in BOGIE_NAMES:
                raise ValueError(f'{where}bogie must be one of {sorted(BOGIE_NAMES)}, got '
                                 f'{bogie!r}')
            bogies = BOGIE_NAMES[bogie]
        elif 'bogie' in item:
            raise ValueError(f'{where}bogie applies only to spring_ratio and damper_ratio')
        if events and time < events[-1].time:
            raise ValueError(f'{where}time {time} s is before the previous event '
                             f'({events[-1].time} s): events must be in time order')
        event = RailEvent(time, quantity, value, ramp, bogies)
        _check_no_overlap(events, event, where)
        events.append(event)
    return tuple(events)


def _check_no_overlap(previous: list[RailEvent], event: RailEvent, where: str) -> None:
    """A change of a quantity must not start while a ramp of the same quantity still runs."""
    for other in previous:
        same_target = other.quantity == event.quantity and (
            not event.bogies or set(other.bogies) & set(event.bogies))
        if same_target and event.time < other.time + other.ramp - 1e-9:
            raise ValueError(
                f'{where}time {event.time} s starts during the ramp of {event.quantity} that '
                f'runs from {other.time} s to {other.time + other.ramp} s')


def evaluate_profiles(scenario: RailScenario, time: np.ndarray) -> ParameterProfiles:
    """Speed, creep factor and suspension ratios at the given times (s from the start).

    Times before 0 (the warm-up) take the initial values. A step at time T applies from T on;
    a ramp goes linearly from the previous target (or the initial value) to its target over
    ``ramp`` seconds. The ordering and no-overlap checks make that previous value a constant.
    """
    t = np.asarray(time, dtype=float)
    init = scenario.initial
    # One column per target: speed, creep, spring front/rear, damper front/rear.
    columns = {('speed', 0): init.speed, ('creep_factor', 0): init.creep_factor,
               ('spring_ratio', 0): init.spring_ratio[0],
               ('spring_ratio', 1): init.spring_ratio[1],
               ('damper_ratio', 0): init.damper_ratio[0],
               ('damper_ratio', 1): init.damper_ratio[1]}
    values = {key: np.full(t.shape, value) for key, value in columns.items()}
    for event in scenario.events:
        for bogie in event.bogies or (0,):
            key = (event.quantity, bogie)
            before = columns[key]
            if event.ramp > 0.0:
                fraction = np.clip((t - event.time) / event.ramp, 0.0, 1.0)
                new = before + (event.value - before) * fraction
            else:
                new = np.full(t.shape, event.value)
            values[key] = np.where(t >= event.time, new, values[key])
            columns[key] = event.value
    return ParameterProfiles(
        t, values[('speed', 0)], values[('creep_factor', 0)],
        np.stack([values[('spring_ratio', 0)], values[('spring_ratio', 1)]], axis=-1),
        np.stack([values[('damper_ratio', 0)], values[('damper_ratio', 1)]], axis=-1))
