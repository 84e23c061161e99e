"""A synthetic fleet with known faults, and the check that the fleet job finds exactly them.

``generate`` writes N cars and N trains x M drives from the shipped scenario files (road:
``diffusion_15pct.yaml``'s drive without its event; rail: ``rail_healthy.yaml``), each drive
its own seed, each vehicle its own parameters drawn from the fleet seed:

* cars: placard pressure (the tires' nominal pressure, given to the vehicle's stiffness
  observer as ``nominal_pressure_kpa`` in the manifest), added mass, tire resonance at placard,
  and the car's own tires and rings (the road simulator's ``vehicle_seed``: tire-to-tire
  radius and stiffness spread, tooth errors, the same in every drive); drives ``car_days``
  apart. **Planted: a slow leak** on one tire of the leaking cars, from
  placard at the first drive (where the TPMS methods calibrate; the calibration is carried to
  the next drives by the fleet job) down by ``leak_fraction`` at the last drive.
* trains: sensor noise; drives ``train_days`` apart. **Planted: a degrading damper** on the
  front (monitored) bogie of the degrading trains, its secondary lateral damping falling
  linearly from nominal at the first drive to ``damper_last`` at the last.

Drives are written as the vehicles would record them (inputs only, no ``/truth/*``; stamps at
the drive's date), with ``manifest.yaml`` (recordings, vehicle parameters) and ``truth.yaml``
(the planted faults). ``score`` reads the job's summary table and gives, per method, the
planted vehicles found, those missed and the vehicles flagged without a fault::

    python -m vehicle_monitor_common.fleet.synthetic out/fleet_data --cars 6 --trains 6
    fleet out/fleet_data/manifest.yaml --out out/fleet_run
    python -m vehicle_monitor_common.fleet.synthetic out/fleet_data --score out/fleet_run
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, replace
import datetime as dt
import math
from pathlib import Path
import sys
import tempfile
from typing import Any

import numpy as np
import pandas as pd
import yaml

from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.resources import share_dir
from vehicle_monitor_common.series import TopicSeries

TIRES = ('FL', 'FR', 'RL', 'RR')
ROAD_METHODS = ('tpms_warning',)
RAIL_METHODS = ('suspension', 'creep_factor', 'creep_factor_imu')


@dataclass(frozen=True)
class FleetPlan:
    """What to generate."""

    cars: int = 4
    trains: int = 4
    drives: int = 4
    leaking_cars: int = 1
    degrading_trains: int = 1
    car_drive_s: float = 150.0
    train_drive_s: float = 30.0
    car_days: int = 2
    train_days: int = 7
    leak_fraction: float = 0.25
    damper_last: float = 0.5
    seed: int = 1
    start: dt.datetime = dt.datetime(2026, 11, 2, 7, 0, tzinfo=dt.UTC)


def _scenario(package: str, name: str) -> dict[str, Any]:
    path = share_dir(package, 'scenarios') / name
    with open(path, encoding='utf-8') as stream:
        data: dict[str, Any] = yaml.safe_load(stream)
    return data


def _car_scenario(base: Mapping[str, Any], plan: FleetPlan, car: Mapping[str, Any],
                  pressures: list[float], seed: int) -> dict[str, Any]:
    scenario = {key: value for key, value in base.items() if key not in ('events', 'tire')}
    # the car's tires and rings (vehicle_seed) are the same in every drive; the road is not
    scenario.update(name=f'{car["id"]}_drive', description='synthetic fleet drive', seed=seed,
                    vehicle_seed=car['vehicle_seed'], duration_s=plan.car_drive_s,
                    added_mass_kg=car['added_mass_kg'])
    scenario['steering'] = {'segments': [
        {'type': 'sine', 'amplitude_deg': 0.5, 'frequency_hz': 0.05,
         'duration_s': plan.car_drive_s}]}
    scenario['tire'] = {'nominal_pressure_kpa': car['placard_kpa'],
                        'nominal_resonance_hz': car['resonance_hz'],
                        'initial_pressure_kpa': pressures}
    return scenario


def _train_scenario(base: Mapping[str, Any], plan: FleetPlan, train: Mapping[str, Any],
                    damper: float, seed: int) -> dict[str, Any]:
    scenario = dict(base)
    scenario.update(name=f'{train["id"]}_drive', description='synthetic fleet drive',
                    seed=seed, duration=plan.train_drive_s, events=[])
    scenario['initial'] = {**base.get('initial', {}), 'damper_ratio': [damper, 1.0]}
    noise = train['noise_scale']
    scenario['sensors'] = {key: value * noise for key, value in base.get('sensors', {}).items()}
    return scenario


def _shifted(topics: Mapping[str, TopicSeries], start: dt.datetime) -> dict[str, TopicSeries]:
    """The vehicle's recording: inputs only, stamped from the drive's start."""
    offset = int(start.timestamp()) * 1_000_000_000
    return {topic: replace(series, stamps_ns=np.asarray(series.stamps_ns) + offset)
            for topic, series in topics.items() if not topic.startswith('/truth/')}


def _drives(plan: FleetPlan, rng: np.random.Generator, index: int,
            days_apart: int) -> Iterator[tuple[str, float, int, dt.datetime]]:
    """Each drive of the vehicle ``index``: its name, how far into the planted fault it is (0 at
    the first drive, 1 at the last), the seed of its scenario (drawn here, one per drive), and
    its start (``days_apart`` between drives, an hour of day per vehicle)."""
    for drive in range(plan.drives):
        seed = int(rng.integers(1_000_000))
        start = plan.start + dt.timedelta(days=drive * days_apart, hours=index % 12)
        yield f'drive{drive + 1:02d}', drive / max(1, plan.drives - 1), seed, start


def generate(out: str | Path, plan: FleetPlan = FleetPlan(),
             log: Callable[[str], None] = print) -> Path:
    """Write the fleet (see the module docstring); the manifest's path."""
    from vehicle_monitor_common.evaluation import domains

    # each domain's simulator, through its registration (this package depends on no domain)
    synthesizers = {domain.name: domain.synthesize for domain in domains()}
    road_topics, rail_topics = synthesizers.get('road'), synthesizers.get('rail')
    out = Path(out)
    rng = np.random.default_rng(plan.seed)
    road_base = _scenario('tpms_ros', 'diffusion_15pct.yaml')
    rail_base = _scenario('rail_monitor_ros', 'rail_healthy.yaml')
    vehicles: dict[str, Any] = {}
    truth: dict[str, Any] = {}
    recordings: list[dict[str, Any]] = []
    jobs: list[tuple[str, str, dict[str, Any], dt.datetime, Callable[..., Any] | None]] = []
    leaking = set(rng.choice(plan.cars, plan.leaking_cars, replace=False).tolist())
    degrading = set(rng.choice(plan.trains, plan.degrading_trains, replace=False).tolist())
    for index in range(plan.cars):
        car: dict[str, Any] = {'id': f'car{index + 1:02d}',
               'placard_kpa': float(rng.choice([200.0, 220.0, 230.0, 240.0, 250.0])),
               'added_mass_kg': float(np.round(rng.uniform(0.0, 150.0))),
               'resonance_hz': float(np.round(rng.uniform(39.0, 41.0), 2)),
               'vehicle_seed': int(rng.integers(1_000_000))}
        tire = int(rng.integers(4)) if index in leaking else None
        vehicles[car['id']] = {'graph': 'road', 'parameters': {'tire_stiffness_observer': {
            'nominal_pressure_kpa': [car['placard_kpa']] * 4}}}
        truth[car['id']] = {'domain': 'road', 'fault': 'leak' if tire is not None else None,
                            'tire': TIRES[tire] if tire is not None else None,
                            'pressures_kpa': []}
        for drive, share, seed, start in _drives(plan, rng, index, plan.car_days):
            pressures: list[float] = [car['placard_kpa']] * 4
            if tire is not None:
                pressures[tire] = round(car['placard_kpa'] * (1 - plan.leak_fraction * share), 1)
            truth[car['id']]['pressures_kpa'].append(pressures)
            jobs.append((car['id'], drive, _car_scenario(road_base, plan, car, pressures, seed),
                         start, road_topics))
    for index in range(plan.trains):
        train: dict[str, Any] = {'id': f'train{index + 1:02d}',
                 'noise_scale': float(np.round(rng.uniform(0.8, 1.2), 2))}
        vehicles[train['id']] = {'graph': 'rail'}
        planted = index in degrading
        truth[train['id']] = {'domain': 'rail', 'fault': 'damper' if planted else None,
                              'damper_ratios': []}
        for drive, share, seed, start in _drives(plan, rng, index, plan.train_days):
            damper = round(1.0 - (1.0 - plan.damper_last) * share, 3) if planted else 1.0
            truth[train['id']]['damper_ratios'].append(damper)
            jobs.append((train['id'], drive, _train_scenario(rail_base, plan, train, damper, seed),
                         start, rail_topics))
    with tempfile.TemporaryDirectory(prefix='fleet-scenarios-') as scratch:
        for number, (vehicle, drive_name, scenario, start, synthesize) in enumerate(jobs, 1):
            if synthesize is None:
                raise RuntimeError(f'{vehicle}: its domain is not installed')
            path = Path(scratch) / f'{vehicle}_{drive_name}.yaml'
            path.write_text(yaml.safe_dump(scenario, sort_keys=False), encoding='utf-8')
            bag = out / 'drives' / vehicle / drive_name
            write_bag(bag, _shifted(synthesize(path, None), start), overwrite=True)
            recordings.append({'path': str(bag.relative_to(out)), 'vehicle': vehicle,
                               'time': start.isoformat()})
            log(f'[{number}/{len(jobs)}] {vehicle}/{drive_name}')
    manifest = out / 'manifest.yaml'
    manifest.write_text(yaml.safe_dump({'vehicles': vehicles, 'recordings': recordings},
                                       sort_keys=False), encoding='utf-8')
    (out / 'truth.yaml').write_text(yaml.safe_dump(truth, sort_keys=False), encoding='utf-8')
    return manifest


#: A TPMS method alone makes the voter warn when its flag comes with a confidence above h_i,
#: the voter's single-method threshold (its default, docs/methods/tpms_voter.md); below it a
#: method's flag is evidence the voter weighs, not a warning, so that is what a method is scored
#: on. (This package depends on no domain, hence the value and not the voter's parameter.)
INDICATION_THRESHOLD = 0.8


def _flagged(summary: pd.DataFrame, events: pd.DataFrame, method: str,
             indication_threshold: float) -> dict[str, set[str]]:
    """Per vehicle what the method flagged over its recordings: tires (the voter's warnings; a
    TPMS method's indications above ``indication_threshold``), fault components (suspension),
    ``low_adhesion`` (creep)."""
    found: dict[str, set[str]] = {}
    if method.startswith('indication_'):
        strong = events[(events['method'] == method) & (events['peak'] >= indication_threshold)]
        for vehicle, subject in zip(strong['vehicle'], strong['subject'], strict=True):
            found.setdefault(str(vehicle), set()).add(str(subject).upper())
        return found
    rows = summary[(summary['method'] == method) & (summary['error'].fillna('') == '')]
    for row in rows.itertuples():
        flags = found.setdefault(str(row.vehicle), set())
        if method == 'suspension':
            flags |= {c for c in str(row.fault_modes or '').split(',') if c}
        elif method.startswith('creep_factor'):
            if (row.low_adhesion_s or 0) > 0:
                flags.add('low_adhesion')
        else:
            flags |= {t.upper() for t in ('fl', 'fr', 'rl', 'rr')
                      if not pd.isna(getattr(row, f'first_warning_s_{t}'))}
    return found


def score(results: str | Path, truth: str | Path | Mapping[str, Any],
          indication_threshold: float = INDICATION_THRESHOLD) -> pd.DataFrame:
    """Per method: vehicles with a planted fault, found, missed, flagged without a fault
    (false positives: a healthy vehicle flagged, or a faulty one flagged on another tire or
    component), recall. A leak is found by a warning on its tire (the voter's, or one TPMS
    method's indication with a confidence above ``indication_threshold``: what would make the
    voter warn on that method alone); a damper by a fault with a damper component; creep
    methods have nothing planted."""
    from vehicle_monitor_common.fleet.job import read_table

    if not isinstance(truth, Mapping):
        with open(truth, encoding='utf-8') as stream:
            truth = yaml.safe_load(stream)
    assert isinstance(truth, Mapping)
    summary = read_table(results, 'summary').to_pandas()
    events = read_table(results, 'events').to_pandas()
    rows = []
    indications = tuple(sorted(m for m in summary['method'].dropna().unique()
                               if str(m).startswith('indication_')))
    for domain, methods in (('road', ROAD_METHODS + indications), ('rail', RAIL_METHODS)):
        vehicles = {v: t for v, t in truth.items() if t['domain'] == domain}
        if not vehicles:
            continue
        for method in methods:
            flagged = _flagged(summary, events, method, indication_threshold)
            planted = found = 0
            missed, false_positives = [], []
            for vehicle, fact in sorted(vehicles.items()):
                flags = flagged.get(vehicle, set())
                if method.startswith('creep_factor'):
                    expected: set[str] = set()
                elif fact['fault'] == 'leak':
                    expected = {fact['tire']}
                elif fact['fault'] == 'damper':
                    expected = {'damper', 'spring+damper'}
                else:
                    expected = set()
                if expected:
                    planted += 1
                    if flags & expected:
                        found += 1
                    else:
                        missed.append(vehicle)
                if flags - expected:
                    false_positives.append(vehicle)
            rows.append({'method': method, 'vehicles': len(vehicles), 'planted': planted,
                         'found': found, 'missed': ','.join(missed),
                         'false_positives': ','.join(false_positives),
                         'recall': found / planted if planted else math.nan})
    return pd.DataFrame(rows)


def main(argv: list[str] | None = None) -> int:
    """Generate a synthetic fleet, or score a fleet run against its truth."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('out', type=Path, help='folder of the fleet (drives, manifest, truth)')
    parser.add_argument('--score', type=Path, default=None, metavar='RESULTS',
                        help='score the fleet job\'s results in RESULTS instead of generating')
    defaults = FleetPlan()
    for name in ('cars', 'trains', 'drives', 'leaking_cars', 'degrading_trains', 'seed'):
        parser.add_argument(f'--{name.replace("_", "-")}', type=int,
                            default=getattr(defaults, name))
    for name in ('car_drive_s', 'train_drive_s'):
        parser.add_argument(f'--{name.replace("_", "-")}', type=float,
                            default=getattr(defaults, name))
    args = parser.parse_args(argv)
    if args.score is not None:
        table = score(args.score, args.out / 'truth.yaml')
        from vehicle_monitor_common.fleet.report import markdown_table

        print('\n'.join(markdown_table(table)))
        return 0
    plan = FleetPlan(cars=args.cars, trains=args.trains, drives=args.drives,
                     leaking_cars=min(args.leaking_cars, args.cars),
                     degrading_trains=min(args.degrading_trains, args.trains), seed=args.seed,
                     car_drive_s=args.car_drive_s, train_drive_s=args.train_drive_s)
    manifest = generate(args.out, plan)
    print(f'manifest: {manifest}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
