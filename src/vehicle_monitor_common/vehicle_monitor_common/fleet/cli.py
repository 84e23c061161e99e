"""``fleet``: screen a fleet's recordings on Ray; Parquet tables and a report.

Inputs: bag directories, a directory holding bags (``<root>/<vehicle>/<bag>``), glob patterns,
URIs, or one manifest YAML naming the recordings and each vehicle's graph, parameters and
stored calibration (docs/fleet.md). One Ray task per recording on an embedded local Ray
(``--num-cpus`` workers) or an existing cluster (``--address``); ``--local`` runs the tasks in
this process instead. Results in ``--out`` (default ``out/fleet``): ``summary/`` and
``events/`` Parquet datasets partitioned by vehicle and date, ``calibration/``, and
``report.md`` with its figures. A rerun skips the recordings already screened (``--force``
redoes them)::

    fleet bags/
    fleet fleet/manifest.yaml --address ray://head:10001 --out /data/screening/2026-11-25
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys

from vehicle_monitor_common.bag_io import BagError
from vehicle_monitor_common.cli import run_cli
from vehicle_monitor_common.parameters import ConfigurationError

DEFAULT_OUT = Path('out/fleet')


def main(argv: list[str] | None = None) -> int:
    """``fleet``: see the module docstring."""
    parser = argparse.ArgumentParser(
        prog='fleet', description=__doc__.split('\n')[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog='\n'.join(__doc__.split('\n')[2:]))
    parser.add_argument('inputs', nargs='+', metavar='RECORDINGS_OR_MANIFEST')
    parser.add_argument('--out', type=Path, default=DEFAULT_OUT,
                        help=f'output folder (default: {DEFAULT_OUT})')
    parser.add_argument('--address', default=None,
                        help='Ray cluster to use (default: start an embedded local Ray)')
    parser.add_argument('--num-cpus', type=int, default=None,
                        help='CPUs of the embedded Ray (default: all of this machine)')
    parser.add_argument('--local', action='store_true',
                        help='run the tasks one by one in this process, without Ray')
    parser.add_argument('--force', action='store_true',
                        help='screen again recordings whose results exist')
    parser.add_argument('--graph', default=None,
                        help='graph for vehicles the manifest does not give one: a domain '
                             '(road, rail) or a graph / launch file (default: by the topics)')
    parser.add_argument('--params', action='append', default=None, metavar='PARAMS_FILE',
                        help='ROS params file for every vehicle (repeatable)')
    parser.add_argument('--calibration', default=None,
                        help='stored calibration for vehicles without their own')
    parser.add_argument('--no-report', action='store_true', help='write the tables only')
    args = parser.parse_args(argv)
    if args.local and args.address:
        parser.error('--local and --address exclude each other')
    from dataclasses import replace

    from vehicle_monitor_common.fleet.job import LocalExecutor, RayExecutor, run_fleet
    from vehicle_monitor_common.fleet.manifest import load_inputs
    from vehicle_monitor_common.fleet.report import write_report

    def run() -> int:
        manifest = load_inputs(args.inputs)
        defaults = manifest.defaults
        if args.graph is not None:
            defaults = replace(defaults, graph=args.graph)
        if args.params:
            defaults = replace(defaults, params=tuple(args.params))
        if args.calibration is not None:
            defaults = replace(defaults, calibration=args.calibration)
        manifest = replace(manifest, defaults=defaults)
        if not manifest.recordings:
            raise ConfigurationError('no recording to screen')
        where = 'this process' if args.local else (
            f'Ray at {args.address}' if args.address else 'an embedded Ray')
        print(f'{len(manifest.recordings)} recording(s) of '
              f'{len({r.vehicle for r in manifest.recordings})} vehicle(s) on {where} '
              f'into {args.out}/', flush=True)
        executor = LocalExecutor() if args.local else RayExecutor(args.address, args.num_cpus)
        try:
            run = run_fleet(manifest, args.out, executor, force=args.force,
                            log=lambda line: print(line, flush=True))
        finally:
            executor.close()
        print(f'{run.done} screened ({run.failed} with an error), {run.skipped} skipped in '
              f'{run.wall_s:.1f} s', flush=True)
        for error in run.errors:
            print(f'  {error}')
        if not args.no_report:
            report = write_report(args.out)
            print(f'report: {report}')
        return 0

    return run_cli(run, (ConfigurationError, BagError, FileNotFoundError))


if __name__ == '__main__':
    sys.exit(main())
