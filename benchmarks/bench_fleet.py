"""Fleet job scaling: the same recordings screened on an embedded Ray with 1 and 2 workers.

Generates a synthetic rail fleet (``fleet.synthetic``: ``--trains`` x ``--drives`` recordings of
``--drive-s`` seconds, one degrading damper) unless ``--fleet`` names one already generated, then
screens it with ``num_cpus`` = each of ``--workers`` (fresh output each time, Ray started and
stopped around each run; its start-up is timed apart). Prints per run the wall time, the
recordings per second, the mean per-recording task cost (wall, in the worker) and the speed-up
over one worker; then the projection for ``--project`` recordings on a cluster of
``--cluster-cpus`` CPUs, as arithmetic from the measured per-recording cost.

Run under tools/env.sh: ``python benchmarks/bench_fleet.py [--trains 10 --drives 4]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import tempfile
import time

from vehicle_monitor_common.fleet.job import RayExecutor, run_fleet
from vehicle_monitor_common.fleet.manifest import read_manifest
from vehicle_monitor_common.fleet.synthetic import FleetPlan, generate, score


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--fleet', type=Path, default=None,
                        help='a generated fleet folder (default: generate one)')
    parser.add_argument('--trains', type=int, default=10)
    parser.add_argument('--drives', type=int, default=4)
    parser.add_argument('--drive-s', type=float, default=20.0)
    parser.add_argument('--workers', type=int, nargs='+', default=[1, 2])
    parser.add_argument('--project', type=int, default=10_000)
    parser.add_argument('--cluster-cpus', type=int, default=256)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix='bench-fleet-') as scratch:
        fleet = args.fleet
        if fleet is None:
            fleet = Path(scratch) / 'fleet'
            started = time.perf_counter()
            generate(fleet, FleetPlan(cars=0, trains=args.trains, drives=args.drives,
                                      leaking_cars=0, degrading_trains=1,
                                      train_drive_s=args.drive_s), log=lambda _: None)
            print(f'generated {args.trains} x {args.drives} recordings of {args.drive_s:.0f} s '
                  f'in {time.perf_counter() - started:.0f} s')
        manifest = read_manifest(fleet / 'manifest.yaml')
        count = len(manifest.recordings)
        print(f'{count} recordings\n')
        print('| workers | Ray start s | wall s | recordings/s | task cost s (mean) '
              '| data x RT per task | speed-up |')
        print('| --- | --- | --- | --- | --- | --- | --- |')
        base = None
        cost = 0.0
        for workers in args.workers:
            out = Path(scratch) / f'out{workers}'
            started = time.perf_counter()
            executor = RayExecutor(num_cpus=workers)
            start_s = time.perf_counter() - started
            try:
                run = run_fleet(manifest, out, executor, force=True, log=lambda _: None)
            finally:
                executor.close()
            cost = run.task_wall_s / max(1, run.done)
            base = base or run.wall_s
            print(f'| {workers} | {start_s:.1f} | {run.wall_s:.1f} | {run.throughput:.2f} | '
                  f'{cost:.2f} | {run.data_s / max(run.task_wall_s, 1e-9):.1f} | '
                  f'{base / run.wall_s:.2f} |', flush=True)
            if run.errors:
                print(f'  {run.failed} recording(s) failed, e.g. {run.errors[0]}', flush=True)
        if (fleet / 'truth.yaml').is_file():
            table = score(out, fleet / 'truth.yaml')
            print('\n' + table.to_string(index=False))
        hours = args.project * cost / args.cluster_cpus / 3600
        print(f'\nprojection: {args.project} recordings x {cost:.2f} s per recording '
              f'(of {args.drive_s:.0f} s each) / {args.cluster_cpus} CPUs = {hours:.2f} h '
              f'(+ Ray start-up; per-recording cost scales with the recording length)')


if __name__ == '__main__':
    main()
