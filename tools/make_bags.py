"""Regenerate the shipped scenario bags in bags/ from the packages' scenario files.

Same scenario file and seed -> the same messages, so the bags can be checked against their
source at any time (test/test_shipped_bags.py). Run: ``python tools/make_bags.py`` under
tools/env.sh.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import time

from rail_monitor_ros.rail_simulator import scenario_topics as rail_topics
from tpms_ros.road_simulator import scenario_topics as road_topics
from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.resources import shipped_file

BAG_DIR = Path(__file__).resolve().parents[1] / 'bags'
# bag name -> (package, scenario, synthesis). Kept small enough to ship (zstd-compressed MCAP).
SHIPPED = {
    'road_kim_huh_lateral': ('tpms_ros', 'kim_huh_lateral', road_topics),
    'road_puncture_15pct_fl': ('tpms_ros', 'puncture_15pct_fl', road_topics),
    'rail_imm_spring_damper_fault': ('rail_monitor_ros', 'rail_imm_spring_damper_fault',
                                     rail_topics),
    'rail_creep_steps': ('rail_monitor_ros', 'rail_creep_steps', rail_topics),
}


def main() -> None:
    """Write every shipped bag (or the named ones)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('names', nargs='*', metavar='NAME',
                        help=f'bags to regenerate (default: all of {", ".join(SHIPPED)})')
    args = parser.parse_args()
    unknown = sorted(set(args.names) - set(SHIPPED))
    if unknown:
        parser.error(f'unknown bag {unknown[0]!r}')
    for name in args.names or SHIPPED:
        package, scenario, synthesis = SHIPPED[name]
        started = time.monotonic()
        series = synthesis(shipped_file(package, 'scenarios', scenario), None)
        write_bag(BAG_DIR / name, series, overwrite=True, compress=True)
        print(f'{name}: {sum(len(s) for s in series.values())} messages in '
              f'{time.monotonic() - started:.1f} s')


if __name__ == '__main__':
    main()
