from setuptools import setup

package_name = 'vehicle_monitor_common'

setup(
    name=package_name,
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
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
