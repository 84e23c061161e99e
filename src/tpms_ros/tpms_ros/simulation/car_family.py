"""A family of cars for the road simulator: one scenario, many cars drawn from seeded ranges.

Issue 21: the TPMS methods must hold on cars they have never seen, not on the one car of the
shipped scenarios. :func:`sample_car` draws a car (passenger car or light truck) from a seed:

* tire torsional resonance 32-52 Hz at placard, rim/belt inertia split and total inertia,
  damping ratio of the torsional mode, a stiffness-pressure law that is a power law
  (exponent 0.4-1.0) on most cars and the paper's straight line with another slope on the
  rest, a damping-pressure slope, tire-to-tire spread of K0 and D0;
* placard 180-350 kPa, radius sensitivity to pressure, tire-to-tire radius spread;
* front, rear or all-wheel drive with driveline resonances at other frequencies, levels and
  damping than the shipped car's;
* an encoder ring (teeth, tooth-spacing error 0-0.3 % rms of the pitch, timer resolution) and
  the way the ECU forms the speed (``tooth_period``: held last tooth period, as the shipped
  scenarios; ``window_average``: teeth over edge-to-edge time across a window of 2-10 ms);
* body (mass, wheelbase, tracks, CG height, radius) and the road roughness level of its roads.

:func:`drive_profile` draws a drive with continuous speed variation: ``urban`` (30-60 km/h
stop-and-go, corners), ``rural`` (60-100 km/h, a curve every ~40 s), ``motorway`` (100-140
km/h, lane changes, long bends), with the road surface changing along it.

:func:`car_scenario` builds a runnable :class:`Scenario` for a car, a drive and pressure
events; :func:`apply_car` puts a car into an existing scenario (its drive and events kept).

Held-out seeds: :data:`HELD_OUT_SEEDS` (24 cars) are for reporting only; no parameter of any
method may be tuned on them (tune on :data:`TUNING_SEEDS`). Both are fixed here so every
evaluation reports on the same cars. The family is opt-in: the shipped scenarios and bags do
not use it and stay bit-identical. No ROS import.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
import dataclasses
from dataclasses import dataclass
import math
from typing import Any

import numpy as np

from tpms_ros.simulation.road_scenario import (
    DrivelineMode,
    DrivelineSpec,
    RoadSegment,
    Scenario,
    ScenarioEvent,
    SensorSpec,
    SpeedSegment,
    SteerSegment,
    TireSpec,
)
from tpms_ros.simulation.vehicle_dynamics import VehicleParams, max_stable_step

# Cars nothing is ever tuned on (reported in docs/methods/tpms_family_evaluation.md).
HELD_OUT_SEEDS: tuple[int, ...] = tuple(range(21_000, 21_024))
# Cars a method may be tuned or studied on.
TUNING_SEEDS: tuple[int, ...] = tuple(range(21_500, 21_532))
DRIVE_KINDS: tuple[str, ...] = ('urban', 'rural', 'motorway')
LAYOUTS: tuple[str, ...] = ('front', 'rear', 'all')
GRAVITY = 9.80665


@dataclass(frozen=True)
class FamilyCar:
    """One car of the family (everything the simulator needs, and its truth).

    Attributes:
        seed: the seed it was drawn from.
        body: ``passenger`` or ``light_truck``.
        layout: driven wheels, ``front``, ``rear`` or ``all``.
        vehicle: handling-model parameters (``driven_axle`` rear for all-wheel drive).
        tire: torsional tire and its pressure relations (placard = ``nominal_pressure_kpa``).
        driveline: driveline resonances (``wheels='all'`` for all-wheel drive).
        sensors: encoder and IMU.
        roughness_scale: road roughness of this car's roads relative to the surface classes.
        damping_ratio: damping ratio of the torsional mode at placard (truth, for reports).
    """

    seed: int
    body: str
    layout: str
    vehicle: VehicleParams
    tire: TireSpec
    driveline: DrivelineSpec
    sensors: SensorSpec
    roughness_scale: float
    damping_ratio: float

    @property
    def placard_kpa(self) -> float:
        """Placard (nominal cold) pressure, kPa."""
        return self.tire.nominal_pressure_kpa

    def describe(self) -> str:
        """One line: the car's main truths."""
        t, s = self.tire, self.sensors
        law = (f'K~p^{t.stiffness_pressure_exponent:.2f}' if t.stiffness_law == 'power'
               else f'K lin s={t.stiffness_pressure_slope:.2f}')
        return (f'car {self.seed}: {self.body:<11} {self.layout:<5} placard '
                f'{self.placard_kpa:5.0f} kPa, f0 {t.nominal_resonance_hz:4.1f} Hz '
                f'(J1/J {t.j1 / (t.j1 + t.j2):.2f}, zeta {self.damping_ratio:.3f}), {law}, '
                f'ring {s.teeth} teeth {100 * s.tooth_error_rms:.2f} % {s.speed_method}'
                + (f' {1e3 * s.speed_window_s:.0f} ms' if s.speed_method == 'window_average'
                   else '')
                + f', rough x{self.roughness_scale:.2f}')

    def user_parameters(self) -> dict[str, Any]:
        """What a user of this car can know and set (placard, layout, radius, geometry, the
        encoder ring's teeth)."""
        v = self.vehicle
        wheelbase = v.lf + v.lr
        front = v.m * GRAVITY * v.lr / wheelbase / 2.0
        rear = v.m * GRAVITY * v.lf / wheelbase / 2.0
        return {'nominal_pressure_kpa': self.placard_kpa, 'driven_axle': self.layout,
                'nominal_radius_m': v.rw, 'wheelbase_m': wheelbase,
                'track_front_m': 2.0 * v.tf, 'track_rear_m': 2.0 * v.tr,
                'static_load_n': (front, front, rear, rear), 'encoder_teeth': self.sensors.teeth,
                'wheel_inertia_kgm2': v.iw, 'cg_height_m': v.h}

    def ecu_parameters(self) -> dict[str, Any]:
        """How the ABS ECU forms the wheel speed, as the stiffness observer's ``encoder_*``
        parameters: ECU data a supplier has, not part of :meth:`user_parameters` (the observer
        reads the timer from held tooth periods itself)."""
        s = self.sensors
        return {'encoder_timer_s': s.timer_resolution_s, 'encoder_speed_method': s.speed_method,
                'encoder_window_s': s.speed_window_s}

    def tire_law_parameters(self) -> dict[str, Any]:
        """The tire's stiffness-pressure law as the stiffness observer's ``pressure_relation``
        parameters: tire data a user may have (a stiffness or resonance measured at two
        pressures), not part of :meth:`user_parameters`."""
        t = self.tire
        if t.stiffness_law == 'power':
            return {'law': 'power', 'exponent': t.stiffness_pressure_exponent}
        return {'law': 'line', 'slope': t.stiffness_pressure_slope}


def _uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


def sample_car(seed: int) -> FamilyCar:
    """Draw one car from the family (same seed, same car)."""
    rng = np.random.default_rng(np.random.SeedSequence([21, int(seed)]))
    body = 'light_truck' if rng.uniform() < 0.3 else 'passenger'
    truck = body == 'light_truck'
    layout = str(rng.choice(LAYOUTS, p=[0.45, 0.35, 0.2]))

    # Body.
    base = VehicleParams()
    m = _uniform(rng, 2000.0, 2700.0) if truck else _uniform(rng, 1150.0, 1850.0)
    wheelbase = _uniform(rng, 2.95, 3.4) if truck else _uniform(rng, 2.45, 2.95)
    lf = wheelbase * _uniform(rng, 0.38, 0.5)
    half_track = _uniform(rng, 0.8, 0.87) if truck else _uniform(rng, 0.74, 0.81)
    rw = _uniform(rng, 0.33, 0.38) if truck else _uniform(rng, 0.28, 0.33)
    h = _uniform(rng, 0.62, 0.75) if truck else _uniform(rng, 0.48, 0.58)
    mass_ratio = m / base.m
    iw = base.iw * (rw / base.rw) ** 2 * (1.5 if truck else 1.0)
    vehicle = dataclasses.replace(
        base, m=m, ms=0.9 * m, iz=base.iz * mass_ratio * (wheelbase / base.wheelbase) ** 2,
        ix=base.ix * mass_ratio, iy=base.iy * mass_ratio * (wheelbase / base.wheelbase) ** 2,
        iw=iw, lf=lf, lr=wheelbase - lf, h=h, rw=rw, tf=half_track,
        tr=half_track - _uniform(rng, 0.0, 0.03), kphi_f=base.kphi_f * mass_ratio,
        kphi_r=base.kphi_r * mass_ratio, cphi_f=base.cphi_f * mass_ratio,
        cphi_r=base.cphi_r * mass_ratio, ks_f=base.ks_f * mass_ratio,
        ks_r=base.ks_r * mass_ratio, kt=base.kt * (1.3 if truck else 1.0),
        driven_axle='front' if layout == 'front' else 'rear')

    # Tire.
    placard = _uniform(rng, 250.0, 350.0) if truck else _uniform(rng, 180.0, 280.0)
    resonance = _uniform(rng, 32.0, 52.0)
    inertia = _uniform(rng, 1.4, 2.4) if truck else _uniform(rng, 1.0, 1.8)
    rim_share = _uniform(rng, 0.45, 0.72)
    j1, j2 = inertia * rim_share, inertia * (1.0 - rim_share)
    zeta = _uniform(rng, 0.02, 0.08)
    reduced = j1 * j2 / (j1 + j2)
    damping = 2.0 * zeta * reduced * 2.0 * math.pi * resonance
    if rng.uniform() < 0.75:
        law, exponent = 'power', _uniform(rng, 0.4, 1.0)
        slope = TireSpec().stiffness_pressure_slope
    else:
        law, exponent, slope = 'linear', TireSpec().stiffness_pressure_exponent, \
            _uniform(rng, 0.3, 0.9)
    tire = TireSpec(
        j1=j1, j2=j2, nominal_resonance_hz=resonance, nominal_damping=damping,
        nominal_pressure_kpa=placard, initial_pressure_kpa=(placard,) * 4,
        stiffness_pressure_slope=slope, stiffness_law=law, stiffness_pressure_exponent=exponent,
        stiffness_spread=_uniform(rng, 0.005, 0.04), damping_spread=_uniform(rng, 0.03, 0.15),
        damping_pressure_slope=_uniform(rng, 0.0, 0.3),
        radius_loss_at_30pct=_uniform(rng, 0.0015, 0.006),
        radius_spread=_uniform(rng, 0.0005, 0.002))

    # Driveline: two member/differential modes, elsewhere than the shipped 25 / 52 Hz.
    scale = 1.4 if truck else 1.0
    driveline = DrivelineSpec(
        modes=(DrivelineMode('fore_aft', _uniform(rng, 16.0, 30.0), _uniform(rng, 0.05, 0.12),
                             scale * _uniform(rng, 8.0, 25.0)),
               DrivelineMode('pitch', _uniform(rng, 46.0, 64.0), _uniform(rng, 0.04, 0.1),
                             scale * _uniform(rng, 4.0, 14.0))),
        wander_span_hz=_uniform(rng, 3.0, 6.5),
        wander_reference_speed_kmh=_uniform(rng, 50.0, 90.0),
        wheels='all' if layout == 'all' else 'driven')

    # Encoder ring and ECU.
    method = 'window_average' if rng.uniform() < 0.5 else 'tooth_period'
    sensors = SensorSpec(
        teeth=int(rng.choice([43, 44, 48, 48, 48, 50, 60])),
        tooth_error_rms=_uniform(rng, 0.0, 0.003),
        timer_resolution_s=float(rng.choice([1e-6, 2e-6, 4e-6])),
        speed_method=method, speed_window_s=_uniform(rng, 0.002, 0.01),
        gyro_yaw_offset_rad_s=_uniform(rng, -0.006, 0.006),
        gyro_noise_rad_s=_uniform(rng, 0.001, 0.004),
        accel_noise_m_s2=_uniform(rng, 0.03, 0.08))
    roughness = float(math.exp(rng.uniform(math.log(0.5), math.log(3.0))))
    if max_stable_step(vehicle) < 1e-3:
        raise ValueError(f'car {seed}: the handling model is unstable at 1 kHz')
    return FamilyCar(seed=int(seed), body=body, layout=layout, vehicle=vehicle, tire=tire,
                     driveline=driveline, sensors=sensors, roughness_scale=roughness,
                     damping_ratio=zeta)


def held_out_cars() -> list[FamilyCar]:
    """The held-out cars (:data:`HELD_OUT_SEEDS`)."""
    return [sample_car(seed) for seed in HELD_OUT_SEEDS]


@dataclass(frozen=True)
class Drive:
    """A drive: speed, steering and road along it."""

    kind: str
    initial_kmh: float
    speed: tuple[SpeedSegment, ...]
    steering: tuple[SteerSegment, ...]
    road: tuple[RoadSegment, ...]


#: Corners of the urban and rural drives: straight length, corner radius (either side) and
#: corner duration ranges (s, m, s) and the steering rise time, s.
_Range = tuple[float, float]
_CORNERS: dict[str, tuple[_Range, _Range, _Range, float]] = {
    'urban': ((8.0, 25.0), (40.0, 120.0), (3.0, 7.0), 1.0),
    'rural': ((20.0, 40.0), (150.0, 500.0), (5.0, 15.0), 2.0),
}


def _steer_deg(wheelbase: float, speed_kmh: float, lateral_acc: float) -> float:
    """Kinematic road-wheel angle for a lateral acceleration at a speed, degrees."""
    v = max(speed_kmh, 10.0) / 3.6
    return math.degrees(math.atan(wheelbase * lateral_acc / (v * v)))


def drive_profile(kind: str, duration_s: float, seed: int, wheelbase_m: float = 2.7,
                  roughness_scale: float = 1.0) -> Drive:
    """Draw a drive of the given kind lasting at least ``duration_s``.

    ``urban``: 30-60 km/h with speed changes every few seconds, a stop-and-go cycle (down to
    5-15 km/h) about once a minute, corners of 40-120 m radius. ``rural``: 60-100 km/h ramps,
    a curve of 150-500 m radius (left or right) every 30-50 s. ``motorway``: 100-140 km/h,
    a lane change every 15-40 s, bends of 800-2000 m. Roads switch between smooth asphalt and
    rough concrete every 30-90 s, each stretch with its own roughness around
    ``roughness_scale``.
    """
    if kind not in DRIVE_KINDS:
        raise ValueError(f'unknown drive kind {kind!r}; expected one of {DRIVE_KINDS}')
    rng = np.random.default_rng(np.random.SeedSequence([22, int(seed), DRIVE_KINDS.index(kind)]))
    low, high = {'urban': (30.0, 60.0), 'rural': (60.0, 100.0),
                 'motorway': (100.0, 140.0)}[kind]
    initial = _uniform(rng, low, high)
    speed: list[SpeedSegment] = []
    elapsed = 0.0
    current = initial
    next_stop = _uniform(rng, 40.0, 70.0)
    while elapsed < duration_s:
        if kind == 'urban' and elapsed >= next_stop:
            period = _uniform(rng, 15.0, 30.0)
            seg = SpeedSegment('stop_and_go', period, low_kmh=_uniform(rng, 5.0, 15.0),
                               period_s=period)
            next_stop = elapsed + _uniform(rng, 50.0, 80.0)
        elif rng.uniform() < 0.35:
            seg = SpeedSegment('hold', _uniform(rng, 3.0, 12.0))
        else:
            target = _uniform(rng, low, high)
            accel = _uniform(rng, 0.3, 1.2)     # m/s^2
            seg = SpeedSegment('ramp', max(2.0, abs(target - current) / 3.6 / accel),
                               to_kmh=target)
            current = target
        speed.append(seg)
        elapsed += seg.duration_s

    steering: list[SteerSegment] = []
    elapsed = 0.0
    typical = 0.5 * (low + high)
    while elapsed < duration_s:
        if kind in _CORNERS:
            straights, radii, turns, rise_s = _CORNERS[kind]
            straight = _uniform(rng, *straights)
            radius = _uniform(rng, *radii) * (1 if rng.uniform() < 0.5 else -1)
            turn = _uniform(rng, *turns)
            steering += [SteerSegment('straight', straight, to_deg=0.0, rise_s=rise_s),
                         SteerSegment('turn', turn, radius_m=radius, rise_s=rise_s)]
            elapsed += straight + turn
        else:
            straight = _uniform(rng, 10.0, 35.0)
            period = _uniform(rng, 4.0, 7.0)
            amplitude = _steer_deg(wheelbase_m, typical, _uniform(rng, 0.8, 2.0))
            steering += [SteerSegment('straight', straight, to_deg=0.0, rise_s=2.0),
                         SteerSegment('lane_change', period, amplitude_deg=round(amplitude, 4),
                                      period_s=period)]
            elapsed += straight + period
            if rng.uniform() < 0.3:
                bend = _uniform(rng, 10.0, 25.0)
                steering.append(SteerSegment(
                    'turn', bend, rise_s=3.0,
                    radius_m=_uniform(rng, 800.0, 2000.0) * (1 if rng.uniform() < 0.5 else -1)))
                elapsed += bend

    road: list[RoadSegment] = []
    at = 0.0
    while at < duration_s:
        surface = 'rough_concrete' if rng.uniform() < 0.35 else 'smooth_asphalt'
        road.append(RoadSegment(at, surface, roughness_scale=roughness_scale
                                * _uniform(rng, 0.7, 1.3)))
        at += _uniform(rng, 30.0, 90.0)
    return Drive(kind, initial, tuple(speed), tuple(steering), tuple(road))


def _scaled_event(event: ScenarioEvent, ratio: float) -> ScenarioEvent:
    """An event moved to another placard: absolute pressures and leak rates scale with it."""
    if event.kind == 'friction':
        return event
    return dataclasses.replace(event, to_kpa=event.to_kpa * ratio,
                               rate_kpa_per_min=event.rate_kpa_per_min * ratio)


def apply_car(scenario: Scenario, car: FamilyCar) -> Scenario:
    """The scenario driven by another car: its drive, road and events kept.

    The car's vehicle, tire, driveline and sensors replace the scenario's; absolute pressures
    and leak rates of the events scale with the placard ratio (a 200 -> 170 kPa step becomes
    the same 15 % on the car's placard); the car's roughness level scales the road; the
    scenario's initial pressures are scaled likewise.
    """
    ratio = car.placard_kpa / scenario.tire.nominal_pressure_kpa
    p = scenario.tire.initial_pressure_kpa
    initial = (p[0] * ratio, p[1] * ratio, p[2] * ratio, p[3] * ratio)
    tire = dataclasses.replace(car.tire, initial_pressure_kpa=initial)
    road = tuple(dataclasses.replace(s, roughness_scale=s.roughness_scale * car.roughness_scale)
                 for s in scenario.road_segments)
    return dataclasses.replace(
        scenario, name=f'{scenario.name}_car{car.seed}', vehicle=car.vehicle, tire=tire,
        driveline=car.driveline, sensors=car.sensors, road_segments=road,
        events=tuple(_scaled_event(e, ratio) for e in scenario.events))


def car_scenario(car: FamilyCar, drive: str | Drive, duration_s: float,
                 events: Sequence[ScenarioEvent] = (), seed: int | None = None,
                 name: str | None = None) -> Scenario:
    """A runnable scenario: the car on a drive (kind or :class:`Drive`) with pressure events.

    Events are in the car's terms (use ``drop_percent`` for placard-relative losses).
    ``seed`` seeds the simulation's noise streams and, for a drive kind, the drive (default:
    the car's seed).
    """
    run_seed = car.seed if seed is None else int(seed)
    wheelbase = float(car.vehicle.lf + car.vehicle.lr)
    if isinstance(drive, str):
        drive = drive_profile(drive, duration_s, run_seed, wheelbase, car.roughness_scale)
    scenario = Scenario(
        name=name or f'car{car.seed}_{drive.kind}', seed=run_seed, duration_s=float(duration_s),
        vehicle=car.vehicle, description=car.describe(), tire=car.tire,
        driveline=car.driveline, initial_speed_kmh=drive.initial_kmh,
        speed_segments=drive.speed, steer_segments=drive.steering, road_segments=drive.road,
        events=tuple(events), sensors=car.sensors, source=f'<car_family {car.seed}>')
    check_scenario(scenario)
    return scenario


def check_scenario(scenario: Scenario) -> None:
    """The consistency checks of a scenario file, for one built in code (raises ValueError)."""
    limit = max_stable_step(scenario.vehicle, scenario.added_mass_kg)
    if 1.0 / scenario.rates.handling_hz > limit:
        raise ValueError(f'{scenario.name}: unstable handling step')
    tire = scenario.tire
    fastest = float(tire.resonance_hz(np.array(max(tire.initial_pressure_kpa))))
    fastest *= 1.0 + 3.0 * tire.stiffness_spread
    fastest = max([fastest] + [m.frequency_hz + scenario.driveline.wander_span_hz / 2.0
                               for m in scenario.driveline.modes])
    if scenario.rates.torsion_hz < 20.0 * fastest:
        raise ValueError(f'{scenario.name}: torsion_hz too coarse for {fastest:.1f} Hz')


def pressure_event(kind: str, at_s: float, tires: Sequence[int] = (0, 1, 2, 3),
                   drop_percent: float = 20.0, duration_s: float = 2.0,
                   rate_kpa_per_min: float = 30.0) -> ScenarioEvent:
    """A placard-relative pressure event (``pressure_step``, ``slow_leak``-like ``diffusion``)."""
    if kind == 'pressure_step':
        return ScenarioEvent('pressure_step', at_s, tires=tuple(tires),
                             drop_percent=drop_percent, duration_s=duration_s)
    if kind == 'diffusion':
        return ScenarioEvent('diffusion', at_s, tires=(0, 1, 2, 3), drop_percent=drop_percent,
                             rate_kpa_per_min=rate_kpa_per_min)
    raise ValueError(f'unknown event kind {kind!r}')


def family_table(cars: Sequence[FamilyCar]) -> list[Mapping[str, Any]]:
    """One row of truths per car (for reports)."""
    return [{'seed': c.seed, 'body': c.body, 'layout': c.layout, 'placard_kpa': c.placard_kpa,
             'resonance_hz': c.tire.nominal_resonance_hz,
             'rim_share': c.tire.j1 / (c.tire.j1 + c.tire.j2), 'damping_ratio': c.damping_ratio,
             'law': c.tire.stiffness_law,
             'exponent_or_slope': (c.tire.stiffness_pressure_exponent
                                   if c.tire.stiffness_law == 'power'
                                   else c.tire.stiffness_pressure_slope),
             'teeth': c.sensors.teeth, 'tooth_error_pct': 100.0 * c.sensors.tooth_error_rms,
             'speed_method': c.sensors.speed_method, 'roughness': c.roughness_scale,
             'driveline_hz': tuple(round(m.frequency_hz, 1) for m in c.driveline.modes)}
            for c in cars]


def main() -> None:
    """Print the held-out cars."""
    for car in held_out_cars():
        print(car.describe())


__all__ = ['HELD_OUT_SEEDS', 'TUNING_SEEDS', 'DRIVE_KINDS', 'FamilyCar', 'Drive',
           'sample_car', 'held_out_cars', 'drive_profile', 'apply_car', 'car_scenario',
           'pressure_event', 'family_table', 'check_scenario']

if __name__ == '__main__':
    main()
