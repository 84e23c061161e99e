"""The offline engine gives what the node publishes, for vibration_analyzer,
wheel_radius_analyzer and lateral_force_observer (issue 22 item 1).

The first seconds of a shipped bag are copied into a short bag; the offline engine
(``OfflineGraph`` of one ``EngineNode`` with the registered ``make_processor``) runs it, and the
node, created in-process with the same parameter values, gets the same messages in the same
order through :meth:`ProcessorNode.deliver` (the CDR bytes for a raw input, rclpy messages
otherwise, as its subscriptions hand them over); its publishers are tapped. Same topics, same
stamps, every field equal to 1e-9 of its scale. The calibrating nodes calibrate within the
seconds used, so the calibration wiring is covered too.
"""

from __future__ import annotations

from collections.abc import Callable
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message

from tpms_ros.nodes.lateral_force_observer_node import LateralForceObserverNode
from tpms_ros.nodes.vibration_analyzer_node import VibrationAnalyzerNode
from tpms_ros.nodes.wheel_radius_analyzer_node import WheelRadiusAnalyzerNode
from vehicle_monitor_common.bag_io import BagWriter, iter_raw
from vehicle_monitor_common.offline_engine import EngineNode, OfflineGraph, processor_factories
from vehicle_monitor_common.processor_node import message_class

ROOT = Path(__file__).resolve().parents[3]
PUNCTURE = ROOT / 'bags' / 'road_puncture_15pct_fl'
LATERAL = ROOT / 'bags' / 'road_kim_huh_lateral'
RTOL = 1e-9
CASES: dict[str, tuple[Any, Path, float, dict[str, Any]]] = {
    'vibration_analyzer': (VibrationAnalyzerNode, PUNCTURE, 20.0, {
        'calibrate_on_start': True, 'calibration_duration_s': 12.0,
        'calibration_settle_s': 2.0, 'min_calibration_s': 5.0,
        'driveline_compensation': 'rear', 'output_phase_s': 0.03}),
    'wheel_radius_analyzer': (WheelRadiusAnalyzerNode, PUNCTURE, 25.0, {
        'calibrate_on_start': True, 'calibration_duration_s': 15.0,
        'calibration_settle_s': 2.0, 'min_calibration_s': 5.0, 'driven_axle': 'rear',
        'nominal_radius_m': 0.305, 'output_phase_s': 0.05}),
    'lateral_force_observer': (LateralForceObserverNode, LATERAL, 10.0, {}),
}


def _short_bag(source: Path, seconds: float, topics: list[str], out: Path) -> Path:
    with BagWriter(out, overwrite=True) as writer:
        first = None
        for topic, msgtype, log_ns, data in iter_raw(source, topics):
            first = log_ns if first is None else first
            if log_ns - first > seconds * 1e9:
                break
            writer.write_raw(topic, msgtype, log_ns, data)
    return out


def _leaves(msg: Any, prefix: str = '') -> dict[str, Any]:
    """Field path -> value of an rclpy message."""
    out: dict[str, Any] = {}
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, 'get_fields_and_field_types'):
            out.update(_leaves(value, f'{prefix}{name}.'))
        else:
            out[f'{prefix}{name}'] = value
    return out


def _get(msg: Any, path: str) -> Any:
    for part in path.split('.'):
        msg = getattr(msg, part)
    return msg


@pytest.mark.parametrize('plugin', list(CASES))
def test_engine_gives_what_the_node_publishes(plugin: str, tmp_path: Path,
                                              make_node: Callable[..., Any]) -> None:
    """Same messages, stamps and values from the node in-process and from the engine."""
    cls, source, seconds, values = CASES[plugin]
    values = {**values, 'calibration_file': 'none'}
    factory = processor_factories()[f'tpms_ros/{plugin}']
    fqn = f'/{plugin}'
    processor = factory(values, fqn)
    topics = ['/' + t for t in processor.inputs]
    bag = _short_bag(source, seconds, topics, tmp_path / 'short')

    engine: list[tuple[str, int, Any]] = []
    OfflineGraph([EngineNode(fqn, processor)]).run(
        bag, lambda topic, msgtype, stamp, msg: engine.append((topic, stamp, msg)))

    node = make_node(cls, parameter_overrides=[Parameter(k, value=v) for k, v in
                                               values.items()])
    live: list[tuple[str, int, Any]] = []
    for topic, publisher in node._publishers_by_topic.items():
        publisher.publish = (lambda msg, topic=topic: live.append(
            ('/' + topic, msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec,
             msg)))
    for topic, msgtype, _, data in iter_raw(bag, topics):
        relative = topic.lstrip('/')
        spec = node.processor.inputs[relative]
        node.deliver(relative, bytes(data) if spec.raw
                     else deserialize_message(bytes(data), message_class(msgtype)))

    assert len(engine) > 50 and [(t, s) for t, s, _ in live] == [(t, s) for t, s, _ in engine]
    calibrated = [m for t, _, m in live if hasattr(m, 'calibrated') and m.calibrated]
    if plugin != 'lateral_force_observer':
        assert calibrated, f'{plugin} did not calibrate within {seconds} s'
    scale: dict[tuple[str, str], float] = {}
    for topic, _, msg in live:
        for path, value in _leaves(msg).items():
            if isinstance(value, str):
                continue
            finite = np.asarray(value, dtype=float)
            finite = finite[np.isfinite(finite)]
            key = (topic, path)
            scale[key] = max(scale.get(key, 0.0), float(np.abs(finite).max(initial=0.0)))
    for (topic, _, mine), (_, _, theirs) in zip(live, engine, strict=True):
        for path, value in _leaves(mine).items():
            other = _get(theirs, path)
            if isinstance(value, str):
                assert value == other, (topic, path)
                continue
            a, b = np.asarray(value, dtype=float), np.asarray(other, dtype=float)
            assert a.shape == b.shape, (topic, path)
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b), err_msg=f'{topic} {path}')
            tolerance = RTOL * max(scale[(topic, path)], math.ulp(1.0))
            np.testing.assert_allclose(np.nan_to_num(a), np.nan_to_num(b), rtol=0,
                                       atol=tolerance, err_msg=f'{topic} {path}')
