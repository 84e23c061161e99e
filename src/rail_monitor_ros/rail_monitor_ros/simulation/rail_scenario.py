"""Rail simulator scenarios: YAML schema, validation and the parameter profiles over time.

A scenario fixes the vehicle, the track, the sensors and the events (steps and ramps of the
secondary lateral spring and damper ratios per bogie, the creep factor and the speed). The
schema is documented in ``docs/rail_scenario_schema.md``; every unknown key, non-physical value
or out-of-order event is refused with a ValueError naming ``file:line: key.path``
(:mod:`vehicle_monitor_common.scenario_yaml`, the reader both domains share). No ROS import.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from rail_monitor_ros.core.rail_model import (
    MAX_CREEP_FACTOR,
    MAX_SUSPENSION_RATIO,
    RailVehicleParams,
)
from rail_monitor_ros.core.track_spectra import TRACK_SPECTRA
from vehicle_monitor_common.resources import share_dir, shipped_file
from vehicle_monitor_common.scenario_yaml import MappingNode, mapping_from_data, read_mapping

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
        map_error_rms: rms error of the published track map, m (0 = the published alignment is
            the true track plus ``sensors.track_noise``). Otherwise /rail/track_irregularity is
            the true track plus a seeded error profile with the spectrum's shape in the same
            wavelength band, scaled to this rms (a track known as in service, from a survey).
    """

    spectrum: str = 'german_low'
    min_wavelength: float = 1.0
    max_wavelength: float = 120.0
    scale: float = 1.0
    map_error_rms: float = 0.0


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
        displacement_bias: constant offset of the lateral displacements in RailLateralStates, m.
        velocity_bias: of the lateral velocities, m/s.
        yaw_bias: of the yaw angles, rad.
        yaw_rate_bias: of the yaw rates, rad/s.
        speed_noise: the forward speed on /rail/speed, m/s.
        speed_scale_bias: its relative scale error, 1 (a tachometer on a wheel 0.2 % smaller
            than it assumes reads 0.002 high).
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
    displacement_bias: float = 0.0
    velocity_bias: float = 0.0
    yaw_bias: float = 0.0
    yaw_rate_bias: float = 0.0
    speed_noise: float = 0.0
    speed_scale_bias: float = 0.0


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


def load_rail_scenario(path: str | Path) -> RailScenario:
    """Read and validate a scenario YAML file (errors name ``file:line: key.path``)."""
    path = Path(path)
    return parse_rail_scenario(path.read_text(encoding='utf-8'), str(path))


def shipped_scenario(name: str) -> RailScenario:
    """One of the scenarios the package ships in ``scenarios/`` (name without '.yaml')."""
    try:
        path = shipped_file('rail_monitor_ros', 'scenarios', name)
    except FileNotFoundError as exc:
        raise ValueError(str(exc)) from None
    return load_rail_scenario(path)


def parse_rail_scenario(text: str, source: str = '<scenario>') -> RailScenario:
    """Validate scenario YAML text into a :class:`RailScenario`.

    Raises:
        ValueError: naming ``source:line: key.path`` of the offending entry.
    """
    return _scenario(read_mapping(text, source))


def rail_scenario_from_dict(data: Any) -> RailScenario:
    """Validate a parsed scenario mapping (e.g. built in code) into a :class:`RailScenario`.

    Raises:
        ValueError: naming the offending key path.
    """
    return _scenario(mapping_from_data(data))


def _scenario(top: MappingNode) -> RailScenario:
    duration = top.number('duration', low=0.0, low_open=True, high=24 * 3600.0)
    seed = top.integer('seed', 0, low=0)
    output_rate = top.number('output_rate', 200.0, low=0.0, low_open=True, high=10000.0)
    internal_rate = top.number('internal_rate', 1000.0, low=0.0, low_open=True, high=100000.0)
    substeps = internal_rate / output_rate
    if abs(substeps - round(substeps)) > 1e-9 or round(substeps) < 1:
        raise top.error('internal_rate', f'must be an integer multiple of output_rate, got '
                                         f'{internal_rate:g} and {output_rate:g}')
    warm_up = top.number('warm_up', 5.0, low=0.0, high=600.0)
    initial = _initial(top.child('initial'))
    vehicle = _vehicle(top.child('vehicle'), initial.speed)
    track = _track(top.child('track'))
    sensors = _sensors(top.child('sensors'))
    events = _events(top.items('events'), duration)
    name = top.text('name', 'unnamed')
    description = top.text('description', '')
    top.finish()
    return RailScenario(name, description, duration, seed, output_rate, internal_rate, warm_up,
                        vehicle, track, sensors, initial, events)


def _ratio_pair(node: MappingNode, key: str) -> tuple[float, float]:
    """A suspension ratio for both bogies, or [front, rear], each in (0, MAX_SUSPENSION_RATIO]."""
    front, rear = node.numbers(key, (1.0, 1.0), ('front', 'rear'), low=0.0, low_open=True,
                               high=MAX_SUSPENSION_RATIO)
    return front, rear


def _initial(node: MappingNode) -> InitialConditions:
    speed = node.number('speed', 40.0, low=0.0, low_open=True, high=MAX_SPEED)
    creep = node.number('creep_factor', 1.0, low=0.0, low_open=True, high=MAX_CREEP_FACTOR)
    spring = _ratio_pair(node, 'spring_ratio')
    damper = _ratio_pair(node, 'damper_ratio')
    node.finish()
    return InitialConditions(speed, creep, spring, damper)


def _vehicle(node: MappingNode, speed: float) -> RailVehicleParams:
    if node.has('speed'):
        raise node.error('speed', 'is not a vehicle key: set initial.speed or speed events')
    names = [f.name for f in fields(RailVehicleParams) if f.name != 'speed']
    values = {name: node.number(name) for name in names if node.has(name)}
    node.finish()
    try:
        return RailVehicleParams(**values, speed=speed)
    except ValueError as error:
        # The model's own rules (positive masses ...): located at the key they name.
        key = next((k for k in values if f'.{k} ' in str(error)), None)
        raise node.error(key, str(error)) from None


def _track(node: MappingNode) -> TrackConfig:
    spectrum = node.text('spectrum', 'german_low', choices=sorted(TRACK_SPECTRA))
    min_wl = node.number('min_wavelength', 1.0, low=0.1, high=1000.0)
    max_wl = node.number('max_wavelength', 120.0, low=0.1, high=1000.0)
    if max_wl <= min_wl:
        raise node.error('max_wavelength', f'({max_wl:g}) must exceed min_wavelength '
                                           f'({min_wl:g})')
    scale = node.number('scale', 1.0, low=0.0, high=100.0)
    map_error = node.number('map_error_rms', 0.0, low=0.0, high=0.1)
    node.finish()
    return TrackConfig(spectrum, min_wl, max_wl, scale, map_error)


def _sensors(node: MappingNode) -> SensorConfig:
    defaults = SensorConfig()
    values: dict[str, float] = {}
    for f in fields(SensorConfig):
        default = float(getattr(defaults, f.name))
        low = -1e3 if f.name.endswith('_bias') else 0.0
        values[f.name] = node.number(f.name, default, low=low, high=1e3)
    node.finish()
    return SensorConfig(**values)


def _events(items: list[MappingNode], duration: float) -> tuple[RailEvent, ...]:
    events: list[RailEvent] = []
    for item in items:
        quantities = [q for q in EVENT_QUANTITIES if item.has(q)]
        if len(quantities) != 1:
            raise item.error(None, f'must set exactly one of {EVENT_QUANTITIES}, got '
                                   f'{quantities}')
        quantity = quantities[0]
        time = item.number('time', low=0.0, high=duration)
        ramp = item.number('ramp', 0.0, low=0.0, high=duration)
        if time + ramp > duration + 1e-9:
            raise item.error('ramp', f'ends at {time + ramp:g} s, after duration {duration:g} s')
        upper = {'creep_factor': MAX_CREEP_FACTOR, 'speed': MAX_SPEED}.get(
            quantity, MAX_SUSPENSION_RATIO)
        value = item.number(quantity, low=0.0, low_open=True, high=upper)
        bogies: tuple[int, ...] = ()
        if quantity in ('spring_ratio', 'damper_ratio'):
            bogies = BOGIE_NAMES[item.text('bogie', 'both', choices=sorted(BOGIE_NAMES))]
        elif item.has('bogie'):
            raise item.error('bogie', 'applies only to spring_ratio and damper_ratio')
        if events and time < events[-1].time:
            raise item.error('time', f'{time:g} s is before the previous event '
                                     f'({events[-1].time:g} s): events must be in time order')
        event = RailEvent(time, quantity, value, ramp, bogies)
        _check_no_overlap(events, event, item)
        item.finish()
        events.append(event)
    return tuple(events)


def _check_no_overlap(previous: list[RailEvent], event: RailEvent, item: MappingNode) -> None:
    """A change of a quantity must not start while a ramp of the same quantity still runs."""
    for other in previous:
        same_target = other.quantity == event.quantity and (
            not event.bogies or set(other.bogies) & set(event.bogies))
        if same_target and event.time < other.time + other.ramp - 1e-9:
            raise item.error('time', f'{event.time:g} s starts during the ramp of '
                                     f'{event.quantity} that runs from {other.time:g} s to '
                                     f'{other.time + other.ramp:g} s')


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
