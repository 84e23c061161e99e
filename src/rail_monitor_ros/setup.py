from glob import glob

from setuptools import setup

package_name = 'rail_monitor_ros'
setup(
    name=package_name,
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', glob('config/*.yaml')),
        ('share/' + package_name + '/launch', glob('launch/*.launch.yaml')),
        ('share/' + package_name + '/scenarios', glob('scenarios/*.yaml')),
    ],
    entry_points={
        'console_scripts': [
            'rail_simulator = rail_monitor_ros.nodes.rail_simulator_node:main',
            'creep_estimator = rail_monitor_ros.nodes.creep_estimator_node:main',
            'suspension_monitor = rail_monitor_ros.nodes.suspension_monitor_node:main',
        ],
        # Node classes for the composed runner (vehicle_monitor_common.runner).
        'vehicle_monitor.nodes': [
            'rail_simulator = rail_monitor_ros.nodes.rail_simulator_node:RailSimulatorNode',
            'creep_estimator = rail_monitor_ros.nodes.creep_estimator_node:CreepEstimatorNode',
            'suspension_monitor = '
            'rail_monitor_ros.nodes.suspension_monitor_node:SuspensionMonitorNode',
        ],
        # Node logic for the offline engine (vehicle_monitor_common.offline_engine):
        # make_processor(values, fqn) per node.
        'vehicle_monitor.processors': [
            'creep_estimator = rail_monitor_ros.processing.creep_estimator:make_processor',
            'suspension_monitor = '
            'rail_monitor_ros.processing.suspension_monitor:make_processor',
        ],
        # Scenarios and scoring for monitor_demo / evaluate (vehicle_monitor_common.evaluation).
        'vehicle_monitor.evaluations': [
            'rail = rail_monitor_ros.offline.evaluation:domain',
        ],
    },
)
