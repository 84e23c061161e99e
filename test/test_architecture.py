"""The layering of docs/architecture.md, checked on the source: cores stay free of ROS, plots,
simulators and evaluation code."""

from __future__ import annotations

import ast
from pathlib import Path
import subprocess
import sys

import pytest

SRC = Path(__file__).resolve().parents[1] / 'src'
DOMAINS = ('tpms_ros', 'rail_monitor_ros')
# What a core may import from the common package: its ROS-free modules.
COMMON_ROS_FREE = ('parameters', 'validation', 'input_health', 'calibration_store')


def _core_modules() -> list[Path]:
    return sorted(p for d in DOMAINS for p in (SRC / d / d / 'core').glob('*.py'))


def _forbidden(module: str, domain: str) -> str | None:
    """Why a core may not import ``module`` (None: it may)."""
    top = module.split('.')[0]
    if top in ('rclpy', 'rosbags', 'matplotlib', 'builtin_interfaces', 'std_srvs', 'std_msgs',
               'rcl_interfaces') or top.endswith('_msgs'):
        return 'ROS, bags or plotting'
    if top == domain and module.split('.')[1:2] and module.split('.')[1] != 'core':
        return 'only cores of its own domain'
    if top in DOMAINS and top != domain:
        return 'another domain'
    if top == 'vehicle_monitor_common':
        parts = module.split('.')
        if len(parts) < 2 or parts[1] not in COMMON_ROS_FREE:
            return f'common modules other than {", ".join(COMMON_ROS_FREE)}'
    return None


def _imports(path: Path) -> list[str]:
    tree = ast.parse(path.read_text(), str(path))
    names: list[str] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def test_every_domain_has_cores() -> None:
    """Both domain packages keep their methods under core/ (the check below is not vacuous)."""
    for domain in DOMAINS:
        assert len(list((SRC / domain / domain / 'core').glob('*.py'))) >= 3, domain


@pytest.mark.parametrize('path', _core_modules(), ids=lambda p: f'{p.parent.parent.name}.{p.stem}')
def test_core_imports_are_allowed(path: Path) -> None:
    """A core module imports no ROS, message, plotting, simulator or evaluation module
    (statically: every import statement, including those inside functions)."""
    domain = path.parent.parent.name
    problems = [f'{m} ({why})' for m in _imports(path)
                if (why := _forbidden(m, domain)) is not None]
    assert not problems, f'{path.relative_to(SRC)} imports ' + '; '.join(problems)


def test_importing_every_core_loads_no_ros_or_matplotlib() -> None:
    """Importing all cores in a fresh interpreter pulls in neither rclpy nor matplotlib
    (transitively, through whatever they import)."""
    modules = [f'{p.parent.parent.name}.core.{p.stem}' for p in _core_modules()
               if p.stem != '__init__']
    code = ('import importlib, sys\n'
            f'for m in {modules!r}:\n'
            '    importlib.import_module(m)\n'
            "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
            "('rclpy', 'matplotlib', 'rosbags'))\n"
            'print(",".join(bad))\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=300, check=True)
    assert out.stdout.strip() == '', f'cores load: {out.stdout.strip()[:300]}'


def test_forbidden_rule_catches_a_violation() -> None:
    """The rule itself refuses what it must (a check that could not fail would prove nothing)."""
    assert _forbidden('rclpy.node', 'tpms_ros')
    assert _forbidden('matplotlib.pyplot', 'rail_monitor_ros')
    assert _forbidden('tpms_ros.simulation.road_simulator', 'tpms_ros')
    assert _forbidden('tpms_ros.offline.evaluation', 'tpms_ros')
    assert _forbidden('vehicle_monitor_common.figures', 'tpms_ros')
    assert _forbidden('rail_monitor_ros.core.rail_model', 'tpms_ros')
    assert _forbidden('vehicle_monitor_msgs.msg', 'tpms_ros')
    assert _forbidden('tpms_ros.core.tires', 'tpms_ros') is None
    assert _forbidden('vehicle_monitor_common.parameters', 'rail_monitor_ros') is None
    assert _forbidden('numpy', 'rail_monitor_ros') is None
