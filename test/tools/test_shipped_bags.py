"""The shipped bags are what their scenario files generate: regenerated, they come out the same."""

from __future__ import annotations

import hashlib
import importlib.util
from pathlib import Path
from types import ModuleType

import pytest

from vehicle_monitor_common.bag_io import iter_raw, write_bag
from vehicle_monitor_common.resources import shipped_file

ROOT = Path(__file__).resolve().parents[2]


def _make_bags() -> ModuleType:
    spec = importlib.util.spec_from_file_location('make_bags', ROOT / 'tools' / 'make_bags.py')
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _content(bag: Path) -> str:
    digest = hashlib.sha256()
    for topic, msgtype, stamp, data in iter_raw(bag):
        digest.update(f'{topic}|{msgtype}|{stamp}|'.encode())
        digest.update(bytes(data))
    return digest.hexdigest()


def test_shipped_set_stays_small() -> None:
    """Every shipped bag exists and together they stay under 50 MB."""
    make_bags = _make_bags()
    total = 0
    for name in make_bags.SHIPPED:
        bag = ROOT / 'bags' / name
        assert (bag / 'metadata.yaml').is_file(), f'{name} missing: run tools/make_bags.py'
        total += sum(f.stat().st_size for f in bag.iterdir())
    assert total < 50e6, f'{total / 1e6:.1f} MB'


@pytest.mark.parametrize('name', ['road_kim_huh_lateral', 'rail_imm_spring_damper_fault'])
def test_regenerated_bag_is_identical(name: str, tmp_path: Path) -> None:
    """Regenerating a shipped bag gives the same messages and the same storage file bytes."""
    make_bags = _make_bags()
    (package, synthesis), scenario = make_bags.SHIPPED[name]
    series = synthesis(shipped_file(package, 'scenarios', scenario), None)
    write_bag(tmp_path / name, series, compress=True)
    shipped = ROOT / 'bags' / name
    assert _content(tmp_path / name) == _content(shipped)
    (regenerated,) = (tmp_path / name).glob('*.zstd')
    assert regenerated.read_bytes() == (shipped / regenerated.name).read_bytes()
