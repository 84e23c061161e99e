from setuptools import find_packages, setup

package_name = 'vehicle_monitor_common'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='Vehicle monitor maintainers',
    maintainer_email='maintainers@vehicle-monitor.dev',
    description='Bag I/O, scenario player, graph runner and node helpers shared by the monitors.',
    license='Apache-2.0',
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
