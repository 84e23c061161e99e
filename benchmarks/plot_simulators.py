"""The simulators' figures, as in the papers: wheel-speed spectra (Umeno Figs. 1 and 8) and the
rail body acceleration spectra healthy vs faulty (Mori Fig. 4).

Run under tools/env.sh: ``python benchmarks/plot_simulators.py --out DIR`` (writes PNGs).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from rail_monitor_ros.offline.acceleration_spectra import plot_acceleration_psd
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict
from rail_monitor_ros.simulation.rail_simulator import simulate
from tpms_ros.offline.wheel_speed_spectra import plot_wheel_speed_psd
from tpms_ros.simulation.road_scenario import parse_scenario
from tpms_ros.simulation.road_simulator import simulate_scenario

ROAD = '''seed: 11
duration_s: 30
vehicle: {{driven_axle: rear}}
speed: {{initial_kmh: 60}}
road: {{segments: [{{at_s: 0, surface: rough_concrete}}]}}
events:
  - {{type: pressure_step, at_s: 0, tires: [FR, RL], to_kpa: {pressure}, duration_s: 0.01}}
'''


def road_figures(out: Path) -> list[Path]:
    """Umeno Fig. 1 (non-driven FR at 200 vs 120 kPa) and Fig. 8 (driven RL vs RL - RR)."""
    runs = {f'{p} kPa': simulate_scenario(parse_scenario(ROAD.format(pressure=p), f'{p} kPa'))
            for p in (200, 120)}
    return [
        plot_wheel_speed_psd(runs, out / 'umeno_fig1_wheel_speed_psd.png', wheels=(1,),
                             start_s=2.0, title='FR (non-driven) wheel speed: 200 vs 120 kPa'),
        plot_wheel_speed_psd({'200 kPa': runs['200 kPa']}, out / 'umeno_fig8_driven_psd.png',
                             wheels=(2, (2, 3)), start_s=2.0,
                             title='RL (driven) and RL - RR: the in-phase driveline peaks cancel'),
    ]


def rail_figures(out: Path) -> list[Path]:
    """Mori Fig. 4: body lateral acceleration, healthy vs spring 150 % vs damper 50 %."""
    base = {'duration': 60.0, 'seed': 5}
    runs = {
        'healthy': simulate(rail_scenario_from_dict(base)),
        'spring 150 %': simulate(rail_scenario_from_dict(
            {**base, 'events': [{'time': 0.0, 'spring_ratio': 1.5, 'bogie': 'front'}]})),
        'damper 50 %': simulate(rail_scenario_from_dict(
            {**base, 'events': [{'time': 0.0, 'damper_ratio': 0.5, 'bogie': 'front'}]})),
    }
    return [plot_acceleration_psd(runs, out / 'mori_fig4_body_acceleration_psd.png')]


def main() -> None:
    """Write the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--out', type=Path, default=Path('out/simulator_figures'))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for path in [*road_figures(args.out), *rail_figures(args.out)]:
        print(path)


if __name__ == '__main__':
    main()
