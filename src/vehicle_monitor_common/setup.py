from glob import glob
import os

from setuptools import setup

package_name = 'vehicle_monitor_common'
BAGS = os.path.join('..', '..', 'bags')  # relative to this package folder, as colcon wants


def shipped_bags() -> list[tuple[str, list[str]]]:
    """The workspace's scenario bags, installed to share/<package>/bags/<bag>/, so a
    simulator's `-p bag:=<name>` finds them from any directory."""
    if not os.path.isdir(BAGS):  # a package built outside this workspace ships none
        return []
    return [('share/' + package_name + '/bags/' + name,
             sorted(glob(os.path.join(BAGS, name, '*'))))
            for name in sorted(os.listdir(BAGS)) if os.path.isdir(os.path.join(BAGS, name))]

setup(
    name=package_name,
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        *shipped_bags(),
    ],
    entry_points={
        'console_scripts': [
            'run_graph = vehicle_monitor_common.runner:main',
            'monitor_demo = vehicle_monitor_common.main_job:main',
            'evaluate = vehicle_monitor_common.evaluate_cli:main',
            'parameter_docs = vehicle_monitor_common.parameter_docs:main',
            'fleet = vehicle_monitor_common.fleet.cli:main',
        ],
        # Node classes for the composed runner (vehicle_monitor_common.runner).
        'vehicle_monitor.nodes': [
            'scenario_player = vehicle_monitor_common.player:ScenarioPlayer',
            'graph_recorder = vehicle_monitor_common.recorder:GraphRecorder',
        ],
    },
)
