"""False alarms of the TPMS methods and the voting fusion on nominal mixed driving
(docs/targets.md).

Per surface, 30 minutes of evaluated driving at placard pressure, simulated in segments with
their own seeds (each segment is a fresh drive: the cores calibrate over its first
``CALIBRATION_S`` of gentle cruising, as after the driver's "reset", then ``EVALUATE_S`` of
mixed driving: city stop-and-go, acceleration, hard braking, highway cruise at 50-130 km/h,
lane changes and turns up to ~3 m/s^2). The cores are fed exactly as in
``eval_tpms_fusion.py`` (the nodes' feed).

Reported per method and surface: the highest confidence any tire reached after calibration, the
method's own threshold h_i and the margin h_i - max; the highest fused (agreement) evidence,
i.e. the mean confidence of the tires where all counted methods flag, against h0; and every
warning (any signal) with its time. Thresholds may be set from these margins (that is how a
production system is calibrated), never from the fault scenarios.

Run: ``PYTHONPATH=src/tpms_ros:src/vehicle_monitor_common:benchmarks python
benchmarks/eval_tpms_false_alarms.py --out /tmp/tpms_eval [--minutes 30]``
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
from pathlib import Path
import time

from eval_tpms_fusion import (
    BASE_SCENARIO,
    METHODS,
    ReplayTraces,
    replay_methods,
    steer_amplitude_deg,
)
import numpy as np
import yaml

from tpms_ros.core.tpms_voting import VoterParams
from tpms_ros.simulation.road_scenario import Scenario, parse_scenario
from tpms_ros.simulation.road_simulator import simulate_scenario

CALIBRATION_S = 90.0
EVALUATE_S = 300.0
SURFACES = ('smooth_asphalt', 'rough_concrete')
CRUISE_KMH = (90.0, 50.0, 130.0, 70.0, 110.0, 60.0)


def segment_scenario(surface: str, index: int, seed: int,
                     base_path: Path = BASE_SCENARIO) -> Scenario:
    """One nominal segment: gentle calibration cruise, then mixed driving."""
    base = yaml.safe_load(base_path.read_text())
    cruise = CRUISE_KMH[index % len(CRUISE_KMH)]
    amp = round(steer_amplitude_deg(cruise, 0.8), 3)
    speed = [
        {'type': 'hold', 'duration_s': CALIBRATION_S},
        {'type': 'ramp', 'to_kmh': 30.0, 'duration_s': 8.0},               # braking ~2 m/s^2
        {'type': 'stop_and_go', 'low_kmh': 5.0, 'period_s': 20.0, 'duration_s': 60.0},
        {'type': 'ramp', 'to_kmh': cruise, 'duration_s': 15.0},
        {'type': 'hold', 'duration_s': 60.0},
        {'type': 'ramp', 'to_kmh': 0.6 * cruise, 'duration_s': 5.0},       # hard braking
        {'type': 'hold', 'duration_s': 20.0},
        {'type': 'ramp', 'to_kmh': cruise, 'duration_s': 12.0},
        {'type': 'hold', 'duration_s': 60.0},
        {'type': 'ramp', 'to_kmh': 0.8 * cruise, 'duration_s': 10.0},
        {'type': 'hold', 'duration_s': 50.0},
    ]
    # turns are sized for ~2.5 m/s^2 at the speed they are driven at
    v_turn = 0.8 * cruise / 3.6
    radius = max(20.0, round(v_turn * v_turn / 2.5, 0))
    steering = [
        {'type': 'sine', 'amplitude_deg': amp, 'frequency_hz': 0.05,
         'duration_s': CALIBRATION_S},
        {'type': 'straight', 'rise_s': 1.0, 'duration_s': 10.0},
        {'type': 'sine', 'amplitude_deg': 3.0, 'frequency_hz': 0.1, 'duration_s': 60.0},
        {'type': 'straight', 'rise_s': 1.0, 'duration_s': 30.0},
        {'type': 'lane_change', 'amplitude_deg': round(steer_amplitude_deg(cruise, 3.0), 3),
         'period_s': 4.0, 'duration_s': 20.0},
        {'type': 'hold', 'duration_s': 60.0},
        {'type': 'straight', 'rise_s': 1.0, 'duration_s': 62.0},
        {'type': 'turn', 'radius_m': radius, 'rise_s': 2.0, 'duration_s': 25.0},
        {'type': 'straight', 'rise_s': 2.0, 'duration_s': 10.0},
        {'type': 'turn', 'radius_m': -radius, 'rise_s': 2.0, 'duration_s': 20.0},
        {'type': 'straight', 'rise_s': 2.0, 'duration_s': 3.0},
    ]
    doc = {key: base[key] for key in ('vehicle', 'tire', 'drive', 'sensors', 'rates')
           if key in base}
    doc.update({
        'name': f'nominal_{surface}_{index}', 'seed': seed,
        'duration_s': CALIBRATION_S + EVALUATE_S,
        'speed': {'initial_kmh': cruise, 'segments': speed},
        'steering': {'segments': steering},
        'road': {'segments': [{'at_s': 0.0, 'surface': surface}]},
    })
    return parse_scenario(yaml.safe_dump(doc, sort_keys=False), f'<{doc["name"]}>')


def fused_evidence(traces: ReplayTraces, methods: tuple[str, ...]) -> np.ndarray:
    """(T,) the largest mean confidence over tires where all counted methods flag (>= 2)."""
    flags = np.array([traces.flags[m] for m in methods])
    known = np.array([traces.known[m] for m in methods])
    conf = np.array([traces.confidence[m] for m in methods])
    counted = known.sum(axis=0)
    agree = (counted >= 2) & ((flags & known).sum(axis=0) == counted)
    mean = np.where(known, conf, 0.0).sum(axis=0) / np.maximum(counted, 1)
    return np.where(agree, mean, 0.0).max(axis=1)


def run_segment(job: tuple[str, int, int]) -> dict:
    """Simulate and replay one segment (worker)."""
    surface, index, seed = job
    t0 = time.perf_counter()
    result = simulate_scenario(segment_scenario(surface, index, seed))
    traces = replay_methods(result, calibration_end_s=CALIBRATION_S)
    after = traces.t >= CALIBRATION_S
    record: dict = {'surface': surface, 'index': index, 'seed': seed,
                    'wall_s': time.perf_counter() - t0,
                    'calibration_errors': traces.calibration_errors, 'max_confidence': {},
                    'known_fraction': {}, 'warnings': {}}
    for m in METHODS:
        conf = traces.confidence[m][after]
        record['max_confidence'][m] = float(conf.max()) if conf.size else 0.0
        record['known_fraction'][m] = float(traces.known[m][after].mean())
    for name, methods in (('fused', METHODS), ('fused_no_stiffness', METHODS[:2])):
        ev = fused_evidence(traces, methods)[after]
        record['max_confidence'][name + '_agreement'] = float(ev.max()) if ev.size else 0.0
    for name, warning in traces.warnings.items():
        hit = warning[after].any(axis=1)
        record['warnings'][name] = [round(float(t), 1) for t in traces.t[after][hit][:1]]
    return record


def main() -> None:
    """Run the segments of every surface and print the margins."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--minutes', type=float, default=30.0, help='evaluated per surface')
    parser.add_argument('--workers', type=int, default=2)
    parser.add_argument('--out', type=Path, default=Path('/tmp/tpms_eval'))
    args = parser.parse_args()
    n_seg = max(1, math.ceil(args.minutes * 60.0 / EVALUATE_S))
    jobs = [(surface, i, 5000 + 100 * s + i) for s, surface in enumerate(SURFACES)
            for i in range(n_seg)]
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    records = []
    with multiprocessing.get_context('fork').Pool(max(1, min(args.workers, 2)),
                                                  maxtasksperchild=4) as pool:
        for rec in pool.imap_unordered(run_segment, jobs):
            records.append(rec)
            print(f'[{len(records)}/{len(jobs)} {time.perf_counter() - t0:5.0f} s] '
                  f'{rec["surface"]} #{rec["index"]}: max conf '
                  + ', '.join(f'{k} {v:.2f}' for k, v in rec['max_confidence'].items())
                  + f'; warnings {rec["warnings"]}', flush=True)
    voter = VoterParams()
    summary = {}
    for surface in SURFACES:
        recs = [r for r in records if r['surface'] == surface]
        rows = {}
        for key in recs[0]['max_confidence']:
            peak = max(r['max_confidence'][key] for r in recs)
            threshold = voter.h0 if key.endswith('_agreement') else \
                voter.method_thresholds[key]
            rows[key] = {'max_confidence': peak, 'threshold': threshold,
                         'margin': threshold - peak}
        warned = {name: sum(bool(r['warnings'][name]) for r in recs)
                  for name in recs[0]['warnings']}
        summary[surface] = {'minutes': len(recs) * EVALUATE_S / 60.0, 'margins': rows,
                            'segments_with_warning': warned,
                            'known_fraction': {m: float(np.mean([r['known_fraction'][m]
                                                                 for r in recs]))
                                               for m in METHODS}}
        print(f'\n{surface}: {summary[surface]["minutes"]:.0f} min evaluated')
        for key, row in rows.items():
            print(f'  {key:28s} max {row["max_confidence"]:.3f}  threshold '
                  f'{row["threshold"]:.2f}  margin {row["margin"]:+.3f}')
        print(f'  segments with a warning: {warned}')
    (args.out / 'false_alarms.json').write_text(json.dumps(
        {'segments': records, 'summary': summary}, indent=1))
    print(f'wrote {args.out / "false_alarms.json"}; {time.perf_counter() - t0:.0f} s wall')


if __name__ == '__main__':
    main()
