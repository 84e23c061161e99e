"""Road-vehicle scenario files: schema, loading, validation, and the time profiles they define.

A scenario is a YAML file (documented in ``docs/road_scenario_schema.md``) that says what the
simulated car is, where and how it is driven, what happens to its tires and the road over time,
and how its sensors behave. :func:`load_scenario` turns it into a frozen :class:`Scenario`;
anything it does not understand (an unknown key, a negative pressure, a surface that does not
exist, events out of time order, a step too coarse for the models) is refused with a
``ValueError`` that names the file, the line and the key path, so nothing is simulated from a
half-understood file.

The profile functions at the end (:func:`speed_target`, :func:`steering_angle`,
:func:`tire_pressure`, :func:`friction_multiplier`, :func:`road_surface`) sample the scenario on
any time grid; the simulator (``road_simulator``) calls them. No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping
import dataclasses
from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any

import numpy as np

from tpms_ros.core.tire_model import TorsionalTire
from tpms_ros.core.wheel_encoder import SPEED_METHODS
from tpms_ros.simulation.vehicle_dynamics import VehicleParams, max_stable_step
from vehicle_monitor_common.scenario_yaml import MappingNode as _Node
from vehicle_monitor_common.scenario_yaml import read_mapping

WHEEL_NAMES: tuple[str, ...] = ('FL', 'FR', 'RL', 'RR')

# The torsional filter is discretised exactly (zero-order hold), so it never goes unstable, but
# white road torque held over a step is only white well below the step rate: ask for at least
# this many samples per period of the fastest modelled resonance.
MIN_TORSION_SAMPLES_PER_PERIOD = 20.0

# Fitted to the paper's car (Umeno 1997, Fig. 1): f = 40 Hz at 200 kPa, 35 Hz at 120 kPa.
# With f ~ sqrt(K) and K/K0 = 1 - s (1 - p/p0): s = (1 - (35/40)^2) / (1 - 120/200).
DEFAULT_STIFFNESS_PRESSURE_SLOPE = (1.0 - (35.0 / 40.0) ** 2) / (1.0 - 120.0 / 200.0)

STIFFNESS_LAWS = ('linear', 'power')
DRIVELINE_WHEELS = ('driven', 'all')


@dataclass(frozen=True)
class Surface:
    """Road surface class.

    Attributes:
        roughness_psd: one-sided PSD of the road-roughness torque on the tire belt at the
            reference speed, N^2 m^2 / Hz (white over the band the tire responds in).
        friction: friction scale of the surface relative to the tire model's dry asphalt.
    """

    roughness_psd: float
    friction: float


# Levels chosen so that smooth asphalt at 60 km/h gives a rim-speed resonance of a few
# hundredths of rad/s rms, rough concrete about twice that (Umeno's two test surfaces), gravel
# more; friction scales are textbook peak-mu ratios (dry 1.0, wet ~0.7, gravel ~0.6, snow ~0.3).
SURFACES: Mapping[str, Surface] = {
    'smooth_asphalt': Surface(roughness_psd=0.5, friction=1.0),
    'rough_concrete': Surface(roughness_psd=2.0, friction=1.0),
    'gravel': Surface(roughness_psd=6.0, friction=0.6),
    'wet': Surface(roughness_psd=0.5, friction=0.7),
    'snow': Surface(roughness_psd=1.0, friction=0.3),
}


@dataclass(frozen=True)
class Rates:
    """Sample rates of the simulation grids and the published topics, Hz.

    ``parameter_chunk_s`` is the length of the pieces in which the torsional and driveline
    filters run with their parameters (K, D, mode frequencies) held constant; the state is
    carried across pieces. Pressure changes over seconds, so 50 ms pieces are exact enough.
    """

    handling_hz: float = 1000.0
    torsion_hz: float = 5000.0
    wheel_speed_hz: float = 1000.0
    imu_hz: float = 100.0
    driver_inputs_hz: float = 100.0
    truth_hz: float = 100.0
    pressure_hz: float = 10.0
    parameter_chunk_s: float = 0.05


@dataclass(frozen=True)
class TireSpec:
    """Torsional tire of docs/methods/tire_stiffness_observer.md and how it follows inflation
    pressure (same for all tires).

    Attributes:
        j1: rim-side inertia, kg m^2.
        j2: belt-side inertia, kg m^2.
        nominal_resonance_hz: torsional resonance at nominal pressure (sets K0).
        nominal_damping: torsional damping D0 at nominal pressure, N m s/rad.
        nominal_pressure_kpa: p0, kPa (gauge).
        initial_pressure_kpa: pressure of FL, FR, RL, RR at t = 0, kPa.
        stiffness_pressure_slope: s in K/K0 = 1 - s (1 - p/p0) (``stiffness_law`` linear).
        stiffness_law: ``linear`` (the line above, the paper's) or ``power``
            (K/K0 = (p/p0)^n with n = ``stiffness_pressure_exponent``).
        stiffness_pressure_exponent: n of the power law.
        stiffness_spread: standard deviation of each tire's relative K0 offset (tire-to-tire
            spread of the same model), drawn once per run from the seed; 0: identical tires.
        damping_spread: the same for D0.
        damping_pressure_slope: s_d in D/D0 = 1 - s_d (1 - p/p0).
        radius_loss_at_30pct: relative rolling-radius drop at 30 % pressure loss (linear).
        radius_spread: standard deviation of the tire-to-tire relative radius offset (wear,
            manufacturing), drawn once per run from the seed.
        rigid_mode_corner_hz: the rigid (common-spin) mode of the vibration filter leaks back
            at this corner instead of integrating, so the zero-mean road torque cannot make it
            drift; the wheel's mean spin comes from the handling model.
    """

    j1: float = TorsionalTire().j1
    j2: float = TorsionalTire().j2
    nominal_resonance_hz: float = 40.0
    nominal_damping: float = TorsionalTire().d
    nominal_pressure_kpa: float = 200.0
    initial_pressure_kpa: tuple[float, float, float, float] = (200.0, 200.0, 200.0, 200.0)
    stiffness_pressure_slope: float = DEFAULT_STIFFNESS_PRESSURE_SLOPE
    stiffness_law: str = 'linear'
    stiffness_pressure_exponent: float = 0.5
    stiffness_spread: float = 0.0
    damping_spread: float = 0.0
    damping_pressure_slope: float = 0.0
    radius_loss_at_30pct: float = 0.003
    radius_spread: float = 0.001
    rigid_mode_corner_hz: float = 1.0

    @property
    def nominal_tire(self) -> TorsionalTire:
        """The torsional tire at nominal pressure."""
        return TorsionalTire(self.j1, self.j2, 1.0, self.nominal_damping).with_resonance(
            self.nominal_resonance_hz)

    def stiffness(self, pressure_kpa: np.ndarray) -> np.ndarray:
        """Torsional stiffness K at the given pressures, N m/rad."""
        ratio = np.asarray(pressure_kpa, dtype=float) / self.nominal_pressure_kpa
        if self.stiffness_law == 'power':
            return self.nominal_tire.k * np.maximum(ratio, 0.0) ** self.stiffness_pressure_exponent
        return self.nominal_tire.k * (1.0 - self.stiffness_pressure_slope * (1.0 - ratio))

    def damping(self, pressure_kpa: np.ndarray) -> np.ndarray:
        """Torsional damping D at the given pressures, N m s/rad."""
        ratio = np.asarray(pressure_kpa, dtype=float) / self.nominal_pressure_kpa
        return self.nominal_damping * (1.0 - self.damping_pressure_slope * (1.0 - ratio))

    def resonance_hz(self, pressure_kpa: np.ndarray) -> np.ndarray:
        """Undamped torsional resonance at the given pressures, Hz."""
        reduced = self.j1 * self.j2 / (self.j1 + self.j2)
        return np.sqrt(self.stiffness(pressure_kpa) / reduced) / (2.0 * np.pi)

    def radius_factor(self, pressure_kpa: np.ndarray) -> np.ndarray:
        """Rolling radius relative to the nominal-pressure radius (1 at p0)."""
        ratio = np.asarray(pressure_kpa, dtype=float) / self.nominal_pressure_kpa
        return 1.0 - (self.radius_loss_at_30pct / 0.3) * (1.0 - ratio)


@dataclass(frozen=True)
class DrivelineMode:
    """One driveline/suspension-member resonance felt in phase by both driven wheels.

    Attributes:
        name: label (e.g. ``fore_aft``, ``pitch``).
        frequency_hz: centre frequency; the instantaneous one wanders around it.
        damping_ratio: modal damping ratio.
        torque_rms_nm: rms of the mode's torque on each driven rim at the roughness reference
            speed (scaled with speed like the road torque).
    """

    name: str
    frequency_hz: float
    damping_ratio: float
    torque_rms_nm: float


@dataclass(frozen=True)
class DrivelineSpec:
    """Driveline resonances on the driven axle (Umeno 1997 §3.1).

    The paper finds suspension-member and differential fore-aft and pitch resonances on both
    sides of the tire resonance, their frequencies varying over a 5-6 Hz range with driving
    conditions. Here each mode's frequency is
    ``f0 + span/2 * tanh((v - v_ref)/v_scale + n(t))`` with ``n`` a seeded Ornstein-Uhlenbeck
    wander, so it moves with speed and drifts on its own.

    ``wheels``: ``driven`` (the vehicle's driven axle, both rims in phase) or ``all``
    (all-wheel drive: each axle gets its own independent realisation of the modes, in phase
    on its two rims; the handling model still drives the vehicle's ``driven_axle``).
    """

    modes: tuple[DrivelineMode, ...] = (
        DrivelineMode('fore_aft', 25.0, 0.08, 20.0),
        DrivelineMode('pitch', 52.0, 0.06, 10.0),
    )
    wander_span_hz: float = 5.5
    wander_reference_speed_kmh: float = 70.0
    wander_speed_scale_kmh: float = 30.0
    wander_random_std: float = 0.5
    wander_time_constant_s: float = 10.0
    wheels: str = 'driven'


@dataclass(frozen=True)
class SpeedSegment:
    """One piece of the speed profile; starts where the previous one ended.

    Kinds: ``hold`` (keep speed), ``ramp`` (linear to ``to_kmh``), ``stop_and_go`` (cosine
    cycles between the current speed and ``low_kmh`` with period ``period_s``), ``coast`` (no
    speed control: only the fixed wheel torques act; must be last).
    """

    kind: str
    duration_s: float
    to_kmh: float = math.nan
    low_kmh: float = math.nan
    period_s: float = math.nan


@dataclass(frozen=True)
class SteerSegment:
    """One piece of the front road-wheel steer profile; starts where the previous one ended.

    Kinds: ``hold``; ``straight`` (back to 0 over ``rise_s``); ``step`` (to ``to_deg`` over
    ``rise_s``, then hold); ``ramp`` (linear to ``to_deg`` over the segment); ``sine``
    (``amplitude_deg`` at ``frequency_hz`` around the current angle); ``turn`` (kinematic angle
    atan(L/R) of a constant-radius turn, ``radius_m`` > 0 left, < 0 right, reached over
    ``rise_s``); ``lane_change`` (one full sine period ``period_s`` of ``amplitude_deg``).
    """

    kind: str
    duration_s: float
    to_deg: float = math.nan
    amplitude_deg: float = math.nan
    frequency_hz: float = math.nan
    period_s: float = math.nan
    radius_m: float = math.nan
    rise_s: float = 0.2


@dataclass(frozen=True)
class RoadSegment:
    """Road surface from ``at_s`` until the next segment."""

    at_s: float
    surface: str
    roughness_scale: float = 1.0
    friction: float = math.nan      # NaN: the surface's own friction


@dataclass(frozen=True)
class ScenarioEvent:
    """Something that happens at ``at_s``.

    Kinds: ``pressure_step`` (``tires`` go to ``to_kpa``, or down by ``drop_percent``, over
    ``duration_s``), ``slow_leak`` (``tires`` lose ``rate_kpa_per_min`` until ``to_kpa``),
    ``diffusion`` (all tires lose ``rate_kpa_per_min`` until ``to_kpa`` or ``drop_percent``),
    ``friction`` (road friction multiplier becomes ``scale`` over ``duration_s``). A new
    pressure event on a tire replaces whatever change was going on in it.
    """

    kind: str
    at_s: float
    tires: tuple[int, ...] = ()
    to_kpa: float = math.nan
    drop_percent: float = math.nan
    rate_kpa_per_min: float = math.nan
    duration_s: float = 0.0
    scale: float = math.nan


@dataclass(frozen=True)
class SensorSpec:
    """ABS encoder and IMU imperfections.

    Attributes:
        teeth: encoder teeth per wheel revolution.
        tooth_error_rms: rms tooth-spacing error as a fraction of the tooth pitch (fixed per
            tooth and wheel, drawn from the seed).
        timer_resolution_s: resolution of the ECU timer that stamps tooth edges.
        speed_method: how the ECU forms the speed from the edges: ``tooth_period`` (pitch /
            last tooth period, held until the next edge) or ``window_average`` (teeth passed
            over the edge-to-edge time spanning the last ``speed_window_s``: an average of the
            tooth periods in the window).
        speed_window_s: averaging window of ``window_average``, s.
        gyro_yaw_offset_rad_s, gyro_roll_offset_rad_s: constant gyro offsets.
        gyro_noise_rad_s: white gyro noise, rms per sample.
        accel_noise_m_s2: white accelerometer noise, rms per sample.
    """

    teeth: int = 48
    tooth_error_rms: float = 0.001
    timer_resolution_s: float = 1.0e-6
    speed_method: str = 'tooth_period'
    speed_window_s: float = 0.005
    gyro_yaw_offset_rad_s: float = 0.004
    gyro_roll_offset_rad_s: float = 0.0
    gyro_noise_rad_s: float = 0.002
    accel_noise_m_s2: float = 0.05


@dataclass(frozen=True)
class Scenario:
    """A validated road scenario (see ``docs/road_scenario_schema.md``)."""

    name: str
    seed: int
    duration_s: float
    vehicle: VehicleParams
    description: str = ''
    #: seeds what belongs to the car, not the drive (tire-to-tire radius, K0 and D0 spread, the
    #: rings' tooth errors): drives of one car share it; None = drawn from ``seed``
    vehicle_seed: int | None = None
    added_mass_kg: float = 0.0
    rates: Rates = field(default_factory=Rates)
    tire: TireSpec = field(default_factory=TireSpec)
    torque_offset_nm: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    driveline: DrivelineSpec = field(default_factory=DrivelineSpec)
    initial_speed_kmh: float = 60.0
    speed_segments: tuple[SpeedSegment, ...] = ()
    initial_steer_deg: float = 0.0
    steer_segments: tuple[SteerSegment, ...] = ()
    road_segments: tuple[RoadSegment, ...] = (RoadSegment(0.0, 'smooth_asphalt'),)
    roughness_reference_kmh: float = 60.0
    roughness_speed_exponent: float = 0.5
    events: tuple[ScenarioEvent, ...] = ()
    sensors: SensorSpec = field(default_factory=SensorSpec)
    source: str = '<scenario>'


# ----------------------------------------------------------------------------------------------
# Loading and validation


def _tire_indices(node: _Node, key: str) -> tuple[int, ...]:
    raw = node.raw(key)
    names = [raw] if isinstance(raw, str) else raw
    if not isinstance(names, list) or not names:
        raise node.error(key, 'must be a tire name or a non-empty list of them')
    if names == ['all']:
        return (0, 1, 2, 3)
    indices = []
    for name in names:
        if name not in WHEEL_NAMES:
            raise node.error(key, f'unknown tire {name!r}; expected FL, FR, RL, RR or all')
        indices.append(WHEEL_NAMES.index(name))
    return tuple(sorted(set(indices)))


def _four(node: _Node, key: str, default: tuple[float, float, float, float], *,
          low: float | None = None, low_open: bool = False
          ) -> tuple[float, float, float, float]:
    """A number for all four wheels, or a list of four (FL, FR, RL, RR)."""
    fl, fr, rl, rr = node.numbers(key, default, WHEEL_NAMES, low=low, low_open=low_open)
    return fl, fr, rl, rr


def _parse_rates(node: _Node) -> Rates:
    defaults = Rates()
    values = {}
    for name in ('torsion_hz', 'wheel_speed_hz', 'imu_hz', 'driver_inputs_hz', 'truth_hz',
                 'pressure_hz', 'parameter_chunk_s'):
        values[name] = node.number(name, getattr(defaults, name), low=0.0, low_open=True)
    handling_hz = node.number('handling_hz', defaults.handling_hz, low=0.0, low_open=True)
    rates = Rates(handling_hz=handling_hz, **values)
    for name in ('wheel_speed_hz', 'imu_hz', 'driver_inputs_hz', 'truth_hz', 'pressure_hz'):
        if getattr(rates, name) > rates.torsion_hz:
            raise node.error(name, f'must not exceed torsion_hz ({rates.torsion_hz:g} Hz)')
    if rates.parameter_chunk_s * rates.torsion_hz < 1.0:
        raise node.error('parameter_chunk_s', 'must span at least one torsion_hz sample')
    node.finish()
    return rates


def _parse_tire(node: _Node) -> TireSpec:
    d = TireSpec()
    tire = TireSpec(
        j1=node.number('j1', d.j1, low=0.0, low_open=True),
        j2=node.number('j2', d.j2, low=0.0, low_open=True),
        nominal_resonance_hz=node.number('nominal_resonance_hz', d.nominal_resonance_hz,
                                         low=0.0, low_open=True),
        nominal_damping=node.number('nominal_damping', d.nominal_damping, low=0.0),
        nominal_pressure_kpa=node.number('nominal_pressure_kpa', d.nominal_pressure_kpa,
                                         low=0.0, low_open=True),
        initial_pressure_kpa=_four(node, 'initial_pressure_kpa', d.initial_pressure_kpa,
                                   low=0.0, low_open=True),
        stiffness_pressure_slope=node.number('stiffness_pressure_slope',
                                             d.stiffness_pressure_slope, low=0.0, high=1.0),
        stiffness_law=node.text('stiffness_law', d.stiffness_law, choices=STIFFNESS_LAWS),
        stiffness_pressure_exponent=node.number('stiffness_pressure_exponent',
                                                d.stiffness_pressure_exponent, low=0.0,
                                                high=3.0),
        stiffness_spread=node.number('stiffness_spread', d.stiffness_spread, low=0.0,
                                     high=0.2),
        damping_spread=node.number('damping_spread', d.damping_spread, low=0.0, high=0.5),
        damping_pressure_slope=node.number('damping_pressure_slope', d.damping_pressure_slope,
                                           low=0.0, high=1.0),
        radius_loss_at_30pct=node.number('radius_loss_at_30pct', d.radius_loss_at_30pct,
                                         low=0.0, high=0.05),
        radius_spread=node.number('radius_spread', d.radius_spread, low=0.0, high=0.02),
        rigid_mode_corner_hz=node.number('rigid_mode_corner_hz', d.rigid_mode_corner_hz,
                                         low=0.0, low_open=True, high=5.0),
    )
    if not node.has('initial_pressure_kpa'):
        tire = dataclasses.replace(tire, initial_pressure_kpa=(tire.nominal_pressure_kpa,) * 4)
    node.finish()
    return tire


def _parse_driveline(node: _Node) -> DrivelineSpec:
    d = DrivelineSpec()
    modes = d.modes
    if node.has('modes'):
        parsed: list[DrivelineMode] = []
        for item in node.items('modes'):
            parsed.append(DrivelineMode(
                name=item.text('name', f'mode{len(parsed)}'),
                frequency_hz=item.number('frequency_hz', low=0.0, low_open=True),
                damping_ratio=item.number('damping_ratio', 0.08, low=0.0, low_open=True,
                                          high=1.0),
                torque_rms_nm=item.number('torque_rms_nm', low=0.0)))
            item.finish()
        modes = tuple(parsed)
    spec = DrivelineSpec(
        modes=modes,
        wander_span_hz=node.number('wander_span_hz', d.wander_span_hz, low=0.0),
        wander_reference_speed_kmh=node.number('wander_reference_speed_kmh',
                                               d.wander_reference_speed_kmh, low=0.0),
        wander_speed_scale_kmh=node.number('wander_speed_scale_kmh', d.wander_speed_scale_kmh,
                                           low=0.0, low_open=True),
        wander_random_std=node.number('wander_random_std', d.wander_random_std, low=0.0),
        wander_time_constant_s=node.number('wander_time_constant_s', d.wander_time_constant_s,
                                           low=0.0, low_open=True),
        wheels=node.text('wheels', d.wheels, choices=DRIVELINE_WHEELS))
    for index, mode in enumerate(spec.modes):
        if mode.frequency_hz - spec.wander_span_hz / 2.0 <= 0.0:
            raise node.error(f'modes[{index}].frequency_hz',
                             'minus half the wander span must stay above 0 Hz')
    node.finish()
    return spec


_SPEED_KINDS = ('hold', 'ramp', 'stop_and_go', 'coast')
_STEER_KINDS = ('hold', 'straight', 'step', 'ramp', 'sine', 'turn', 'lane_change')


def _parse_speed(node: _Node) -> tuple[float, tuple[SpeedSegment, ...]]:
    initial = node.number('initial_kmh', 60.0, low=0.0)
    segments = []
    items = node.items('segments')
    for index, item in enumerate(items):
        kind = item.text('type', choices=_SPEED_KINDS)
        duration = item.number('duration_s', low=0.0, low_open=True)
        if kind == 'hold' or kind == 'coast':
            segment = SpeedSegment(kind, duration)
        elif kind == 'ramp':
            segment = SpeedSegment(kind, duration, to_kmh=item.number('to_kmh', low=0.0))
        else:
            segment = SpeedSegment(kind, duration, low_kmh=item.number('low_kmh', low=0.0),
                                   period_s=item.number('period_s', low=0.0, low_open=True))
        if kind == 'coast' and index != len(items) - 1:
            raise item.error('type', 'coast must be the last speed segment (without speed '
                                     'control the speed it ends at is not known in advance)')
        item.finish()
        segments.append(segment)
    node.finish()
    return initial, tuple(segments)


def _parse_steering(node: _Node, wheelbase_m: float) -> tuple[float, tuple[SteerSegment, ...]]:
    initial = node.number('initial_deg', 0.0, low=-45.0, high=45.0)
    segments = []
    for item in node.items('segments'):
        kind = item.text('type', choices=_STEER_KINDS)
        duration = item.number('duration_s', low=0.0, low_open=True)
        rise = item.number('rise_s', 0.2, low=0.0) if kind in ('straight', 'step', 'turn') \
            else 0.2
        if kind in ('hold',):
            segment = SteerSegment(kind, duration)
        elif kind == 'straight':
            segment = SteerSegment(kind, duration, to_deg=0.0, rise_s=rise)
        elif kind in ('step', 'ramp'):
            segment = SteerSegment(kind, duration, rise_s=rise,
                                   to_deg=item.number('to_deg', low=-45.0, high=45.0))
        elif kind == 'sine':
            segment = SteerSegment(
                kind, duration, amplitude_deg=item.number('amplitude_deg', low=0.0, high=45.0),
                frequency_hz=item.number('frequency_hz', low=0.0, low_open=True))
        elif kind == 'turn':
            radius = item.number('radius_m')
            if abs(radius) < wheelbase_m:
                raise item.error('radius_m', f'|radius| must be >= the wheelbase '
                                             f'({wheelbase_m:g} m), got {radius:g}')
            segment = SteerSegment(kind, duration, radius_m=radius, rise_s=rise)
        else:
            segment = SteerSegment(
                kind, duration, amplitude_deg=item.number('amplitude_deg', low=0.0, high=45.0),
                period_s=item.number('period_s', low=0.0, low_open=True))
            if segment.period_s > duration:
                raise item.error('period_s', 'must not exceed the segment duration_s')
        if rise > duration:
            raise item.error('rise_s', 'must not exceed the segment duration_s')
        item.finish()
        segments.append(segment)
    node.finish()
    return initial, tuple(segments)


def _parse_road(node: _Node) -> tuple[tuple[RoadSegment, ...], float, float]:
    reference = node.number('reference_speed_kmh', 60.0, low=0.0, low_open=True)
    exponent = node.number('speed_exponent', 0.5, low=0.0, high=3.0)
    segments: list[RoadSegment] = []
    for item in node.items('segments'):
        segment = RoadSegment(
            at_s=item.number('at_s', low=0.0),
            surface=item.text('surface', choices=tuple(SURFACES)),
            roughness_scale=item.number('roughness_scale', 1.0, low=0.0),
            friction=item.number('friction', math.nan, low=0.0, low_open=True, high=2.0))
        if not segments and segment.at_s != 0.0:
            raise item.error('at_s', 'the first road segment must start at 0')
        if segments and segment.at_s <= segments[-1].at_s:
            raise item.error('at_s', f'road segments must be in time order: {segment.at_s:g} '
                                     f'after {segments[-1].at_s:g}')
        item.finish()
        segments.append(segment)
    node.finish()
    if not segments:
        segments = [RoadSegment(0.0, 'smooth_asphalt')]
    return tuple(segments), reference, exponent


_EVENT_KINDS = ('pressure_step', 'slow_leak', 'diffusion', 'friction')


def _parse_event(item: _Node) -> ScenarioEvent:
    kind = item.text('type', choices=_EVENT_KINDS)
    at = item.number('at_s', low=0.0)
    if kind == 'friction':
        event = ScenarioEvent(kind, at, scale=item.number('scale', low=0.0, low_open=True,
                                                          high=2.0),
                              duration_s=item.number('duration_s', 0.0, low=0.0))
    else:
        tires = (0, 1, 2, 3) if kind == 'diffusion' else _tire_indices(item, 'tires')
        to_kpa = item.number('to_kpa', math.nan, low=0.0, low_open=True) \
            if item.has('to_kpa') else math.nan
        drop = item.number('drop_percent', math.nan, low=0.0, high=90.0) \
            if item.has('drop_percent') else math.nan
        if kind == 'slow_leak' and not item.has('to_kpa'):
            raise item.error('to_kpa', 'is required: the pressure a slow leak stops at')
        if kind != 'slow_leak' and math.isnan(to_kpa) == math.isnan(drop):
            raise item.error(None, 'give exactly one of to_kpa or drop_percent')
        rate = math.nan
        duration = 0.0
        if kind == 'pressure_step':
            duration = item.number('duration_s', 0.0, low=0.0)
        else:
            rate = item.number('rate_kpa_per_min', low=0.0, low_open=True)
        event = ScenarioEvent(kind, at, tires=tires, to_kpa=to_kpa, drop_percent=drop,
                              rate_kpa_per_min=rate, duration_s=duration)
    item.finish()
    return event


def _parse_sensors(node: _Node) -> SensorSpec:
    d = SensorSpec()
    encoder = node.child('encoder')
    gyro = node.child('gyro')
    accel = node.child('accelerometer')
    spec = SensorSpec(
        teeth=encoder.integer('teeth', d.teeth, low=4),
        # Beyond a quarter pitch the edges could swap order; real rings are far better.
        tooth_error_rms=encoder.number('tooth_error_rms', d.tooth_error_rms, low=0.0,
                                       high=0.05),
        timer_resolution_s=encoder.number('timer_resolution_s', d.timer_resolution_s,
                                          low=0.0, high=1e-3),
        speed_method=encoder.text('speed_method', d.speed_method, choices=SPEED_METHODS),
        speed_window_s=encoder.number('speed_window_s', d.speed_window_s, low=0.0,
                                      low_open=True, high=0.1),
        gyro_yaw_offset_rad_s=gyro.number('yaw_offset_rad_s', d.gyro_yaw_offset_rad_s),
        gyro_roll_offset_rad_s=gyro.number('roll_offset_rad_s', d.gyro_roll_offset_rad_s),
        gyro_noise_rad_s=gyro.number('noise_rad_s', d.gyro_noise_rad_s, low=0.0),
        accel_noise_m_s2=accel.number('noise_m_s2', d.accel_noise_m_s2, low=0.0))
    for sub in (encoder, gyro, accel):
        sub.finish()
    node.finish()
    return spec


def _parse_vehicle(node: _Node) -> VehicleParams:
    defaults = VehicleParams()
    # Numeric and text fields only: nested parameter objects (the Magic Formula tire) keep
    # their documented coefficient set.
    names = {f.name for f in dataclasses.fields(VehicleParams)
             if isinstance(getattr(defaults, f.name), (int, float, str))}
    overrides: dict[str, Any] = {}
    for key in node.values:
        if key not in names:
            raise node.error(str(key), f'unknown key (settable VehicleParams fields: '
                                       f'{sorted(names)})')
        if isinstance(getattr(defaults, key), str):
            overrides[key] = node.text(key)
        else:
            overrides[key] = node.number(key)
    try:
        return dataclasses.replace(defaults, **overrides)
    except (TypeError, ValueError) as error:
        raise node.error(None, str(error)) from error


def parse_scenario(text: str, source: str = '<scenario>') -> Scenario:
    """Parse and validate scenario YAML text.

    Args:
        text: the YAML document.
        source: file name used in error messages.

    Returns:
        The validated scenario.

    Raises:
        ValueError: on any invalid, unknown or inconsistent entry; the message names
            ``source:line: key.path``.
    """
    root = read_mapping(text, source)

    name = root.text('name', Path(source).stem)
    description = root.text('description', '')
    seed = root.integer('seed', 0, low=0)
    vehicle_seed = root.integer('vehicle_seed', 0, low=0) if root.has('vehicle_seed') else None
    duration = root.number('duration_s', low=0.0, low_open=True)
    rates = _parse_rates(root.child('rates'))
    vehicle = _parse_vehicle(root.child('vehicle'))
    added_mass = root.number('added_mass_kg', 0.0, low=0.0)
    tire = _parse_tire(root.child('tire'))
    drive = root.child('drive')
    torque_offset = _four(drive, 'torque_offset_nm', (0.0, 0.0, 0.0, 0.0))
    driveline = _parse_driveline(drive.child('driveline'))
    drive.finish()
    initial_speed, speed_segments = _parse_speed(root.child('speed'))
    wheelbase = float(vehicle.lf + vehicle.lr)
    initial_steer, steer_segments = _parse_steering(root.child('steering'), wheelbase)
    road_segments, reference_kmh, exponent = _parse_road(root.child('road'))
    events: list[ScenarioEvent] = []
    for item in root.items('events'):
        event = _parse_event(item)
        if events and event.at_s < events[-1].at_s:
            raise item.error('at_s', f'events must be in time order: {event.at_s:g} s after '
                                     f'{events[-1].at_s:g} s')
        if event.at_s > duration:
            raise item.error('at_s', f'is after the end of the run ({duration:g} s)')
        events.append(event)
    sensors = _parse_sensors(root.child('sensors'))
    root.finish()

    scenario = Scenario(
        name=name, description=description, seed=seed, vehicle_seed=vehicle_seed,
        duration_s=duration, vehicle=vehicle, added_mass_kg=added_mass, rates=rates, tire=tire,
        torque_offset_nm=torque_offset,
        driveline=driveline, initial_speed_kmh=initial_speed, speed_segments=speed_segments,
        initial_steer_deg=initial_steer, steer_segments=steer_segments,
        road_segments=road_segments, roughness_reference_kmh=reference_kmh,
        roughness_speed_exponent=exponent, events=tuple(events), sensors=sensors,
        source=source)
    _check_consistency(scenario, root)
    return scenario


def _check_consistency(scenario: Scenario, root: _Node) -> None:
    """Checks that need the whole scenario: step sizes against the fastest dynamics."""
    limit = max_stable_step(scenario.vehicle, scenario.added_mass_kg)
    if 1.0 / scenario.rates.handling_hz > limit:
        raise root.error('rates.handling_hz',
                         f'{scenario.rates.handling_hz:g} Hz gives an unstable handling step '
                         f'(1/handling_hz must be <= {limit * 1e3:.2f} ms, i.e. >= '
                         f'{1.0 / limit:.0f} Hz)')
    tire = scenario.tire
    highest = max(tire.initial_pressure_kpa + (tire.nominal_pressure_kpa,)
                  + tuple(e.to_kpa for e in scenario.events if math.isfinite(e.to_kpa)))
    fastest = float(tire.resonance_hz(np.array(highest)))
    if tire.stiffness_law == 'linear' and tire.stiffness_pressure_slope > 0.0:
        lowest_ok = tire.nominal_pressure_kpa * (1.0 - 1.0 / tire.stiffness_pressure_slope)
        for index, event in enumerate(scenario.events):
            if math.isfinite(event.to_kpa) and event.to_kpa <= lowest_ok:
                raise root.error(f'events[{index}].to_kpa',
                                 'gives a non-positive torsional stiffness')
    fastest = max([fastest] + [m.frequency_hz + scenario.driveline.wander_span_hz / 2.0
                               for m in scenario.driveline.modes])
    needed = MIN_TORSION_SAMPLES_PER_PERIOD * fastest
    if scenario.rates.torsion_hz < needed:
        raise root.error('rates.torsion_hz',
                         f'{scenario.rates.torsion_hz:g} Hz is too coarse (unstable/aliased) a '
                         f'step for a {fastest:.1f} Hz resonance: need >= {needed:.0f} Hz')


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file (see :func:`parse_scenario`)."""
    path = Path(path)
    return parse_scenario(path.read_text(encoding='utf-8'), source=str(path))


# ----------------------------------------------------------------------------------------------
# Profiles on a time grid


def speed_target(scenario: Scenario, t: np.ndarray) -> np.ndarray:
    """Target speed of the speed controller, m/s; NaN where the car coasts (no control)."""
    t = np.asarray(t, dtype=float)
    current = scenario.initial_speed_kmh
    out = np.full(t.shape, current)
    start = 0.0
    for segment in scenario.speed_segments:
        tau = t - start
        inside = tau >= 0.0
        if segment.kind == 'hold':
            values = np.full(t.shape, current)
            end_value = current
        elif segment.kind == 'ramp':
            frac = np.clip(tau / segment.duration_s, 0.0, 1.0)
            values = current + (segment.to_kmh - current) * frac
            end_value = segment.to_kmh
        elif segment.kind == 'stop_and_go':
            def cycle(x: np.ndarray, high: float = current, seg: SpeedSegment = segment
                      ) -> np.ndarray:
                phase = 2.0 * np.pi * np.clip(x, 0.0, seg.duration_s) / seg.period_s
                return seg.low_kmh + (high - seg.low_kmh) * 0.5 * (1.0 + np.cos(phase))
            values = cycle(tau)
            end_value = float(cycle(np.array(segment.duration_s)))
        else:   # coast: last segment, lasts to the end of the run
            values = np.full(t.shape, np.nan)
            end_value = math.nan
        out = np.where(inside, values, out)
        current = end_value
        start += segment.duration_s
    return out / 3.6


def steering_angle(scenario: Scenario, t: np.ndarray) -> np.ndarray:
    """Front road-wheel steer angle, rad, left positive."""
    t = np.asarray(t, dtype=float)
    wheelbase = float(scenario.vehicle.lf + scenario.vehicle.lr)
    current = scenario.initial_steer_deg
    out = np.full(t.shape, current)
    start = 0.0

    def blend(tau: np.ndarray, rise: float) -> np.ndarray:
        # Smooth (half-cosine) transition: a driver does not step a wheel in zero time.
        if rise <= 0.0:
            return (tau >= 0.0).astype(float)
        x = np.clip(tau / rise, 0.0, 1.0)
        return 0.5 * (1.0 - np.cos(np.pi * x))

    for segment in scenario.steer_segments:
        tau = t - start
        inside = tau >= 0.0
        kind = segment.kind
        if kind == 'hold':
            values = np.full(t.shape, current)
            end_value = current
        elif kind in ('straight', 'step', 'turn'):
            target = segment.to_deg if kind != 'turn' else math.degrees(
                math.atan(wheelbase / segment.radius_m))
            values = current + (target - current) * blend(tau, segment.rise_s)
            end_value = target
        elif kind == 'ramp':
            values = current + (segment.to_deg - current) * np.clip(
                tau / segment.duration_s, 0.0, 1.0)
            end_value = segment.to_deg
        elif kind == 'sine':
            phase = 2.0 * np.pi * segment.frequency_hz * np.clip(tau, 0.0, segment.duration_s)
            values = current + segment.amplitude_deg * np.sin(phase)
            end_value = current + segment.amplitude_deg * math.sin(
                2.0 * math.pi * segment.frequency_hz * segment.duration_s)
        else:   # lane_change: one full period, then back on the current angle
            phase = 2.0 * np.pi * np.clip(tau, 0.0, segment.period_s) / segment.period_s
            values = current + segment.amplitude_deg * np.sin(phase)
            end_value = current
        out = np.where(inside, values, out)
        current = end_value
        start += segment.duration_s
    return np.radians(out)


def tire_pressure(scenario: Scenario, t: np.ndarray) -> np.ndarray:
    """Inflation pressure of FL, FR, RL, RR, kPa, shape (N, 4).

    Each tire's pressure is piecewise linear: every event on a tire starts, at its time, from
    the pressure the tire has then and moves linearly to its target (a step over
    ``duration_s``, a leak at its rate) and stays there, unless a later event takes over.
    """
    t = np.asarray(t, dtype=float)
    out = np.empty(t.shape + (4,))
    for wheel in range(4):
        times = [0.0]
        values = [scenario.tire.initial_pressure_kpa[wheel]]
        for event in scenario.events:
            if event.kind == 'friction' or wheel not in event.tires:
                continue
            p_at = float(np.interp(event.at_s, times, values))
            keep = [i for i, time in enumerate(times) if time < event.at_s]
            times = [times[i] for i in keep] + [event.at_s]
            values = [values[i] for i in keep] + [p_at]
            target = event.to_kpa if math.isfinite(event.to_kpa) \
                else p_at * (1.0 - event.drop_percent / 100.0)
            if event.kind == 'pressure_step':
                duration = event.duration_s
            else:
                # A leak only loses pressure; a target above the present one is a no-op.
                target = min(target, p_at)
                duration = (p_at - target) / event.rate_kpa_per_min * 60.0
            times.append(event.at_s + duration)
            values.append(target)
        out[..., wheel] = np.interp(t, times, values)
    return out


def friction_multiplier(scenario: Scenario, t: np.ndarray) -> np.ndarray:
    """Friction multiplier set by ``friction`` events (1 until the first), shape (N,)."""
    t = np.asarray(t, dtype=float)
    times = [0.0]
    values = [1.0]
    for event in scenario.events:
        if event.kind != 'friction':
            continue
        now = float(np.interp(event.at_s, times, values))
        keep = [i for i, time in enumerate(times) if time < event.at_s]
        times = [times[i] for i in keep] + [event.at_s, event.at_s + event.duration_s]
        values = [values[i] for i in keep] + [now, event.scale]
    return np.interp(t, times, values)


def road_surface(scenario: Scenario, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Road-roughness torque PSD at the reference speed (N^2 m^2/Hz) and surface friction.

    Returns:
        (roughness_psd, friction), each of shape (N,).
    """
    t = np.asarray(t, dtype=float)
    starts = np.array([segment.at_s for segment in scenario.road_segments])
    index = np.searchsorted(starts, t, side='right') - 1
    index = np.clip(index, 0, len(starts) - 1)
    psd = np.array([SURFACES[s.surface].roughness_psd * s.roughness_scale
                    for s in scenario.road_segments])
    friction = np.array([s.friction if math.isfinite(s.friction)
                         else SURFACES[s.surface].friction for s in scenario.road_segments])
    return psd[index], friction[index]
