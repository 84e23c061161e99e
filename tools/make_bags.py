"""Regenerate the scenario bags in bags/ from the packages' scenario files.

Same scenario file and seed -> the same messages (to rounding: another CPU's BLAS may differ
by ~1e-13 of a signal, which ``bag_io.compare_bags`` allows). The bags are plain MCAP files with
zstd-compressed chunks, as every MCAP tool opens them. The shipped set (committed, < 60 MB)
covers the main job and the papers' scenarios; ``--all`` also writes the longer ones into
bags/extra/ (not committed). Run under tools/env.sh:
``python tools/make_bags.py [--all] [NAME ...]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from pathlib import Path
import time

from rail_monitor_ros.simulation.rail_simulator import scenario_topics as rail_topics
from tpms_ros.simulation.road_simulator import scenario_topics as road_topics
from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.resources import shipped_file
from vehicle_monitor_common.series import TopicSeries

BAG_DIR = Path(__file__).resolve().parents[1] / 'bags'
Synthesis = Callable[[Path, 'int | None'], Mapping[str, TopicSeries]]
ROAD: tuple[str, Synthesis] = ('tpms_ros', road_topics)
RAIL: tuple[str, Synthesis] = ('rail_monitor_ros', rail_topics)
# bag name -> (package and synthesis, scenario). Road data costs ~62 kB/s compressed (1 kHz
# wheel speeds), rail ~134 kB/s, a quarter of it the MCAP message indexes (uncompressed, 16 bytes
# a message, what indexed readers seek with): the shipped set stays under 60 MB.
SHIPPED = {
    'road_kim_huh_lateral': (ROAD, 'kim_huh_lateral'),
    'road_kim_huh_relation_check': (ROAD, 'kim_huh_relation_check'),
    'road_puncture_15pct_fl': (ROAD, 'puncture_15pct_fl'),
    'road_diffusion_15pct': (ROAD, 'diffusion_15pct'),
    'road_umeno_step_60kmh_rough_concrete': (ROAD, 'umeno_step_60kmh_rough_concrete'),
    'rail_imm_spring_damper_fault': (RAIL, 'rail_imm_spring_damper_fault'),
    'rail_creep_steps': (RAIL, 'rail_creep_steps'),
    'rail_healthy': (RAIL, 'rail_healthy'),
    'rail_speed_change': (RAIL, 'rail_speed_change'),
}
EXTRA = {
    'road_nominal_drive': (ROAD, 'nominal_drive'),
    'road_diffusion_25pct': (ROAD, 'diffusion_25pct'),
    'road_umeno_step_60kmh_smooth_asphalt': (ROAD, 'umeno_step_60kmh_smooth_asphalt'),
    'road_umeno_step_90kmh_smooth_asphalt': (ROAD, 'umeno_step_90kmh_smooth_asphalt'),
    'road_umeno_step_90kmh_rough_concrete': (ROAD, 'umeno_step_90kmh_rough_concrete'),
    'rail_combined_long': (RAIL, 'rail_combined_long'),
}


def main() -> None:
    """Write every shipped bag (or the named ones)."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('names', nargs='*', metavar='NAME',
                        help='bags to regenerate (default: the shipped set)')
    parser.add_argument('--all', action='store_true', help='also the long ones, in bags/extra')
    args = parser.parse_args()
    known = {**SHIPPED, **EXTRA}
    unknown = sorted(set(args.names) - set(known))
    if unknown:
        parser.error(f'unknown bag {unknown[0]!r} (known: {", ".join(known)})')
    names = args.names or [*SHIPPED, *(EXTRA if args.all else ())]
    for name in names:
        (package, synthesis), scenario = known[name]
        started = time.monotonic()
        series = synthesis(shipped_file(package, 'scenarios', scenario), None)
        target = BAG_DIR / name if name in SHIPPED else BAG_DIR / 'extra' / name
        write_bag(target, series, overwrite=True)
        print(f'{name}: {sum(len(s) for s in series.values())} messages in '
              f'{time.monotonic() - started:.1f} s')


if __name__ == '__main__':
    main()
