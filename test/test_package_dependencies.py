"""Every runtime import of a package is declared in its package.xml with its rosdep key, so
``rosdep install --from-paths src`` on a real ROS 2 install brings everything the nodes import."""

from __future__ import annotations

import ast
from pathlib import Path
import re
import sys
import xml.etree.ElementTree as ET

import pytest

SRC = Path(__file__).resolve().parents[1] / 'src'
PACKAGES = sorted(p.parent.name for p in SRC.glob('*/package.xml'))
# Import name -> rosdep key, for what is not a ROS package of the same name. Keys of PyPI-only
# packages follow rosdep's python.yaml convention (<name>-pip).
ROSDEP_KEYS = {
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'numba': 'python3-numba',
    'yaml': 'python3-yaml',
    'matplotlib': 'python3-matplotlib',
    'rosbags': 'python3-rosbags-pip',
    'mcap': 'python3-mcap-pip',
    'zstandard': 'python3-zstandard',
    'ray': 'python3-ray-pip',
    'pyarrow': 'python3-pyarrow-pip',
    'pandas': 'python3-pandas',
}
ROS_PACKAGES = {'rclpy', 'rcl_interfaces', 'builtin_interfaces', 'std_msgs', 'std_srvs',
                'geometry_msgs', 'sensor_msgs', 'diagnostic_msgs', 'rosgraph_msgs',
                'ament_index_python', 'vehicle_monitor_msgs', 'vehicle_monitor_common',
                'tpms_ros', 'rail_monitor_ros'}
# Runtime dependencies that are not imports: bag_io reads the message definitions from
# vehicle_monitor_msgs' share directory to build the rosbags typestore.
DATA_DEPENDENCIES = {'vehicle_monitor_common': {'vehicle_monitor_msgs'}}


def _imports(package: str) -> set[str]:
    """Top-level modules a package imports, and the message packages it names by type
    (``'sensor_msgs/msg/Imu'``: processors declare their inputs so, the adapter imports them)."""
    names: set[str] = set()
    for path in (SRC / package / package).rglob('*.py'):
        text = path.read_text()
        names |= set(re.findall(r"""['"](\w+)/msg/\w+['"]""", text))
        for node in ast.walk(ast.parse(text, str(path))):
            if isinstance(node, ast.Import):
                names |= {alias.name.split('.')[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.add(node.module.split('.')[0])
    return {n for n in names if n not in sys.stdlib_module_names and n != package}


def _declared(package: str) -> set[str]:
    root = ET.parse(SRC / package / 'package.xml').getroot()
    return {e.text.strip() for e in root if e.tag in ('depend', 'exec_depend') and e.text}


def _key(module: str) -> str:
    if module in ROS_PACKAGES:
        return module
    if module not in ROSDEP_KEYS:
        pytest.fail(f'import {module}: add its rosdep key to ROSDEP_KEYS')
    return ROSDEP_KEYS[module]


@pytest.mark.parametrize('package', PACKAGES)
def test_every_runtime_import_is_declared(package: str) -> None:
    """An imported module without an exec_depend would be missing on a rosdep install."""
    missing = sorted({_key(m) for m in _imports(package)} - _declared(package))
    assert not missing, f'{package}/package.xml lacks <exec_depend> for {missing}'


@pytest.mark.parametrize('package', PACKAGES)
def test_no_dependency_is_declared_for_nothing(package: str) -> None:
    """A declared runtime dependency that nothing imports is stale (ROS message packages the
    nodes use only through their types count as imports too)."""
    needed = {_key(m) for m in _imports(package)} | DATA_DEPENDENCIES.get(package, set())
    stale = sorted(_declared(package) - needed)
    assert not stale, f'{package}/package.xml declares {stale}, which no module imports'
