from glob import glob

from setuptools import setup

package_name = 'tpms_ros'
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
            'vehicle_simulator = tpms_ros.nodes.vehicle_simulator_node:main',
            'vibration_analyzer = tpms_ros.nodes.vibration_analyzer_node:main',
            'wheel_radius_analyzer = tpms_ros.nodes.wheel_radius_analyzer_node:main',
            'tpms_voter = tpms_ros.nodes.tpms_voter_node:main',
            'tire_stiffness_observer = tpms_ros.nodes.tire_stiffness_observer_node:main',
            'lateral_force_observer = tpms_ros.nodes.lateral_force_observer_node:main',
        ],
        # Node classes for the composed runner (vehicle_monitor_common.runner).
        'vehicle_monitor.nodes': [
            'vehicle_simulator = tpms_ros.nodes.vehicle_simulator_node:VehicleSimulatorNode',
            'vibration_analyzer = tpms_ros.nodes.vibration_analyzer_node:VibrationAnalyzerNode',
            'wheel_radius_analyzer = '
            'tpms_ros.nodes.wheel_radius_analyzer_node:WheelRadiusAnalyzerNode',
            'tpms_voter = tpms_ros.nodes.tpms_voter_node:TpmsVoterNode',
            'tire_stiffness_observer = '
            'tpms_ros.nodes.tire_stiffness_observer_node:TireStiffnessObserverNode',
            'lateral_force_observer = '
            'tpms_ros.nodes.lateral_force_observer_node:LateralForceObserverNode',
        ],
        # Node logic for the offline engine (vehicle_monitor_common.offline_engine).
        'vehicle_monitor.processors': [
            'tpms_voter = tpms_ros.processing.tpms_voter:make_processor',
            'tire_stiffness_observer = '
            'tpms_ros.processing.tire_stiffness_observer:make_processor',
            'vibration_analyzer = tpms_ros.processing.vibration_analyzer:make_processor',
            'wheel_radius_analyzer = tpms_ros.processing.wheel_radius_analyzer:make_processor',
            'lateral_force_observer = '
            'tpms_ros.processing.lateral_force_observer:make_processor',
        ],
        # Scenarios and scoring for monitor_demo / evaluate (vehicle_monitor_common.evaluation).
        'vehicle_monitor.evaluations': [
            'road = tpms_ros.offline.evaluation:domain',
        ],
    },
)
