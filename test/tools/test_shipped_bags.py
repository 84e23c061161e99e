"""The shipped bags are what their scenario files generate: regenerated, they decode the same.

"The same" is ``compare_bags``: topics, types, order, stamps, integers and strings exactly,
floating-point fields to ``BAG_RTOL`` of each field's peak. Not the bytes: the simulators' BLAS
calls round differently on another CPU (~2e-13 of the signal), so byte identity holds only on
the machine that wrote the bags.
"""

from __future__ import annotations

from collections.abc import Mapping
import dataclasses
import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from vehicle_monitor_common.bag_io import BAG_RTOL, compare_bags, write_bag
from vehicle_monitor_common.resources import shipped_file
from vehicle_monitor_common.series import TopicSeries

ROOT = Path(__file__).resolve().parents[2]
CHECKED = ['road_kim_huh_lateral', 'rail_imm_spring_damper_fault']


def _make_bags() -> ModuleType:
    spec = importlib.util.spec_from_file_location('make_bags', ROOT / 'tools' / 'make_bags.py')
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope='module', params=CHECKED)
def regenerated(request: pytest.FixtureRequest) -> tuple[str, Mapping[str, TopicSeries]]:
    """A shipped bag's name and its topics synthesised again from its scenario file."""
    name: str = request.param
    (package, synthesis), scenario = _make_bags().SHIPPED[name]
    return name, synthesis(shipped_file(package, 'scenarios', scenario), None)


def _scaled(series: Mapping[str, TopicSeries], factors: Mapping[str, np.ndarray],
            ) -> dict[str, TopicSeries]:
    """The series with each floating-point column multiplied by its ``'topic field'`` factor."""
    out = {}
    for topic, s in series.items():
        fields = {}
        for name, values in s.fields.items():
            array = np.asarray(values)
            fields[name] = array * factors[f'{topic} {name}'] if array.dtype.kind == 'f' else array
        out[topic] = dataclasses.replace(s, fields=fields)
    return out


def test_shipped_set_stays_small() -> None:
    """Every shipped bag exists as one plain .mcap file and together they stay under 60 MB."""
    make_bags = _make_bags()
    total = 0
    for name in make_bags.SHIPPED:
        bag = ROOT / 'bags' / name
        assert (bag / 'metadata.yaml').is_file(), f'{name} missing: run tools/make_bags.py'
        assert [f.name for f in bag.glob('*.mcap*')] == [f'{name}.mcap'], name
        total += sum(f.stat().st_size for f in bag.iterdir())
    assert total < 60e6, f'{total / 1e6:.1f} MB'


def test_regenerated_bag_decodes_the_same(
        regenerated: tuple[str, Mapping[str, TopicSeries]], tmp_path: Path) -> None:
    """Regenerating a shipped bag gives the same messages, floats to BAG_RTOL of their peak."""
    name, series = regenerated
    write_bag(tmp_path / name, series)
    assert compare_bags(ROOT / 'bags' / name, tmp_path / name) == []


def test_other_rounding_still_matches(
        regenerated: tuple[str, Mapping[str, TopicSeries]], tmp_path: Path) -> None:
    """A machine whose BLAS rounds differently (every float off by 1e-12 of itself) passes."""
    name, series = regenerated
    rng = np.random.default_rng(20)
    factors = {f'{topic} {field}': 1.0 + 1e-12 * rng.choice([-1.0, 1.0], np.shape(values))
               for topic, s in series.items() for field, values in s.fields.items()}
    write_bag(tmp_path / name, _scaled(series, factors))
    assert compare_bags(ROOT / 'bags' / name, tmp_path / name) == []
    # The check is not vacuous: the perturbed bag is not the shipped one value for value.
    assert compare_bags(ROOT / 'bags' / name, tmp_path / name, rtol=0.0) != []


def test_a_real_change_fails(
        regenerated: tuple[str, Mapping[str, TopicSeries]], tmp_path: Path) -> None:
    """One value changed by 1e-6 of its field's peak is a difference, named by topic and field."""
    name, series = regenerated
    topic, field = next((t, f) for t, s in series.items() for f, v in s.fields.items()
                        if np.asarray(v).dtype.kind == 'f' and np.any(np.asarray(v) != 0))
    fields = dict(series[topic].fields)
    values = np.array(fields[field], dtype=float)
    peak = np.unravel_index(np.argmax(np.abs(values)), values.shape)
    values[peak] *= 1.0 + 1e-6
    fields[field] = values
    changed = {**series, topic: dataclasses.replace(series[topic], fields=fields)}
    write_bag(tmp_path / name, changed)
    (problem,) = compare_bags(ROOT / 'bags' / name, tmp_path / name)
    assert problem.startswith(f'{topic} {field}: message {peak[0]} has'), problem
    assert f'{BAG_RTOL:g}' in problem
