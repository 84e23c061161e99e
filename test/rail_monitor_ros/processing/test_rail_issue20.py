"""The rail processors in the node and in the offline engine, and issue 20's findings on the rail
nodes (1: time jumps, 2: a frozen body accelerometer and a stale or one-element track, 4:
silence, 5: namespaced parameter files, 7: the time after a fault), each checked as it was
reported: these tests failed before the fix.
"""

from __future__ import annotations

from collections.abc import Callable
import copy
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu
from vehicle_monitor_msgs.msg import RailLateralStates, TrackIrregularity
import yaml

from rail_monitor_ros.nodes.creep_estimator_node import CreepEstimatorNode
from rail_monitor_ros.nodes.suspension_monitor_node import SuspensionMonitorNode
from rail_monitor_ros.processing import creep_estimator, suspension_monitor
from vehicle_monitor_common.bag_io import iter_raw, read_messages
from vehicle_monitor_common.offline_engine import EngineNode, OfflineGraph
from vehicle_monitor_common.processing import WARN, Output

ROOT = Path(__file__).resolve().parents[3]
FAULT_BAG = ROOT / 'bags' / 'rail_imm_spring_damper_fault'
HEALTHY_BAG = ROOT / 'bags' / 'rail_healthy'
CONFIG = ROOT / 'src' / 'rail_monitor_ros' / 'config'
RCLPY_TYPES = {'/rail/bogie/imu': Imu, '/rail/body/imu': Imu,
               '/rail/track_irregularity': TrackIrregularity,
               '/rail/lateral_states': RailLateralStates}
# node name -> (node class, parameter values)
NODES: dict[str, tuple[Any, dict[str, Any]]] = {
    'suspension_monitor': (SuspensionMonitorNode, {}),
    'creep_estimator': (CreepEstimatorNode, {}),
    'creep_estimator_imu': (CreepEstimatorNode, {'pattern': 'D'}),
}


def _make(name: str, values: dict[str, Any] | None = None) -> Any:
    values = {**NODES[name][1], **(values or {})}
    module = suspension_monitor if name == 'suspension_monitor' else creep_estimator
    return module.make_processor(values, f'/{name}')


def _fields_equal(a: dict[str, Any], b: Any, path: str = '') -> None:
    """An output's fields against a published (rosbags) message: equal, floats to 1e-9."""
    for key, value in a.items():
        other = getattr(b, key)
        if isinstance(value, dict):
            _fields_equal(value, other, f'{path}{key}.')
        elif isinstance(value, str) or (isinstance(value, list) and value
                                        and isinstance(value[0], str)):
            assert list(other) == list(value) if isinstance(value, list) else other == value
        else:
            np.testing.assert_allclose(np.asarray(value, dtype=float),
                                       np.asarray(other, dtype=float), rtol=1e-9, atol=1e-12,
                                       err_msg=f'{path}{key}')


@pytest.mark.parametrize('name', list(NODES))
def test_engine_gives_what_the_node_publishes(name: str, make_node: Callable[..., Any]) -> None:
    """The shipped fault recording through the node's adapter (rclpy messages) and through the
    offline engine (rosbags messages): the same outputs, stamps equal, values to 1e-9."""
    cls, values = NODES[name]
    node = make_node(cls, node_name=name, parameter_overrides=[
        Parameter(k, value=v) for k, v in values.items()])
    published: list[Output] = []
    node.publish_output = published.append
    inputs = {f'/{topic}' for topic in node.processor.inputs}
    for topic, _, _, data in iter_raw(FAULT_BAG, sorted(inputs & set(RCLPY_TYPES))):
        node.deliver(topic.lstrip('/'), deserialize_message(data, RCLPY_TYPES[topic]))
    engine: list[tuple[int, Any]] = []
    graph = OfflineGraph([EngineNode(f'/{name}', _make(name))])
    graph.run(FAULT_BAG, lambda topic, msgtype, stamp, msg: engine.append((stamp, msg)))
    assert len(published) == len(engine) == 2001
    for output, (stamp, msg) in zip(published, engine, strict=True):
        assert output.stamp_ns == stamp
        _fields_equal({k: v for k, v in output.fields.items() if k != 'header'}, msg)


def _stream(bag: Path, topics: list[str], seconds: float) -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    first = None
    for topic, _, log_ns, msg in read_messages(bag, topics):
        first = log_ns if first is None else first
        if (log_ns - first) * 1e-9 > seconds:
            break
        out.append((topic.lstrip('/'), msg))
    return out


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 10**9 + int(msg.header.stamp.nanosec)


def _shifted(msg: Any, offset_ns: int) -> Any:
    msg = copy.deepcopy(msg)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(_stamp(msg) + offset_ns, 10**9)
    return msg


IMM_TOPICS = ['/rail/bogie/imu', '/rail/body/imu', '/rail/track_irregularity']


@pytest.mark.parametrize('name', list(NODES))
def test_finding_1_a_future_stamp_does_not_blind_and_a_replay_restarts(name: str) -> None:
    """Finding 1: one message stamped 10 000 s ahead is dropped and counted (the outputs go on
    at the recorded rate, the status names it); a replay from the start (time back by 2 s)
    restarts the filters and they publish again, the status saying 'time jump' (not level
    0)."""
    processor = _make(name)
    driving = 'rail/lateral_states' if name == 'creep_estimator' else 'rail/body/imu'
    topics = [f'/{t}' for t in processor.inputs if t != 'rail/creep_factor']   # not recorded
    stream = _stream(HEALTHY_BAG, topics, 2.0)
    half = len(stream) // 2
    k_future = next(i for i in range(half, len(stream)) if stream[i][0] == driving)
    outputs: list[Output] = []
    statuses = []
    for i, (topic, msg) in enumerate(stream):
        if i == k_future:
            outputs += processor.process(topic, _shifted(msg, 10_000 * 10**9))
            statuses.append(processor.status(_stamp(msg)))
        outputs += processor.process(topic, msg)
    assert any('future_stamp' in s.message and s.level >= WARN for s in statuses)
    assert len(outputs) >= 400 - 2                  # 2 s at 200 Hz: nothing lost but one
    n_first = len(outputs)
    statuses = []
    for topic, msg in stream:                       # the replay: stamps back to the start
        outputs += processor.process(topic, msg)
        statuses.append(processor.status(_stamp(msg)))
    assert len(outputs) - n_first >= 400 - 10       # restarts after 5 confirming samples
    assert any('time jump' in s.message and s.level >= WARN for s in statuses)


def test_finding_2_frozen_body_accelerometer_is_no_suspension_fault() -> None:
    """Finding 2: the body accelerometer frozen for 3 s of a healthy run: never
    fault_detected, the status names the frozen sensor, and the estimate afterwards is the
    clean run's (damper ratio 1, not 0.3)."""
    stream = _stream(HEALTHY_BAG, IMM_TOPICS, 8.0)
    t0 = _stamp(stream[0][1])
    processor = _make('suspension_monitor')
    outputs: list[Output] = []
    statuses = []
    held = None
    for topic, msg in stream:
        if topic == 'rail/body/imu' and 2e9 <= _stamp(msg) - t0 < 5e9:
            msg = copy.deepcopy(msg)
            held = msg.linear_acceleration.y if held is None else held
            msg.linear_acceleration.y = held
        outputs += processor.process(topic, msg)
        statuses.append(processor.status(_stamp(msg)))
    assert not any(o.fields['fault_detected'] for o in outputs)
    assert any('frozen_sensor' in s.message and s.level >= WARN for s in statuses)
    assert abs(outputs[-1].fields['damper_ratio'] - 1.0) < 0.05
    assert abs(outputs[-1].fields['spring_ratio'] - 1.0) < 0.05


@pytest.mark.parametrize('kind', ['stale', 'one_element'])
def test_finding_2_stale_or_short_track_is_no_fault_and_no_creep_error(kind: str) -> None:
    """Finding 2: the track irregularity stale (not published for 2 s) or with one element
    for 2 s: the suspension monitor declares no fault; the creep estimator (C and D) never
    publishes as measured (std_dev < 1) a creep factor off the true 1.0 by more than 0.1."""
    processors = {name: _make(name) for name in NODES}
    topics = ['/rail/bogie/imu', '/rail/body/imu', '/rail/track_irregularity',
              '/rail/lateral_states']
    stream = _stream(HEALTHY_BAG, topics, 8.0)
    t0 = _stamp(stream[0][1])
    outputs: dict[str, list[Output]] = {name: [] for name in NODES}
    for topic, msg in stream:
        if topic == 'rail/track_irregularity' and 3e9 <= _stamp(msg) - t0 < 5e9:
            if kind == 'stale':
                continue
            msg = copy.deepcopy(msg)
            msg.lateral_alignment = np.asarray(msg.lateral_alignment)[:1]
            msg.lateral_alignment_rate = np.asarray(msg.lateral_alignment_rate)[:1]
        for name, processor in processors.items():
            if topic in processor.inputs:
                outputs[name] += processor.process(topic, msg)
    assert not any(o.fields['fault_detected'] for o in outputs['suspension_monitor'])
    for name in ('creep_estimator', 'creep_estimator_imu'):
        c = np.array([o.fields['creep_factor'] for o in outputs[name]])
        std = np.array([o.fields['std_dev'] for o in outputs[name]])
        t = (np.array([o.stamp_ns for o in outputs[name]]) - t0) * 1e-9
        measured = (std < getattr(creep_estimator, 'UNKNOWN_STD', 1.0)) & (t > 2.0)
        assert np.all(np.abs(c[measured] - 1.0) < 0.1), (name, c[measured].min(),
                                                         c[measured].max())
        assert not any(o.fields['low_adhesion'] for o in outputs[name])
        assert measured[-1]


def test_finding_4_silent_body_imu_is_not_suspension_normal() -> None:
    """Finding 4: the body IMU stops for 10 s (bogie IMU and track go on): the status is not
    'suspension normal' (level >= WARN, naming the missing pairs), and returns to OK once the
    body IMU is back and the IMM has settled."""
    stream = _stream(HEALTHY_BAG, IMM_TOPICS, 16.0)
    t0 = _stamp(stream[0][1])
    processor = _make('suspension_monitor')
    during, after = [], []
    for topic, msg in stream:
        t = (_stamp(msg) - t0) * 1e-9
        if topic == 'rail/body/imu' and 2.0 <= t < 12.0:
            continue
        processor.process(topic, msg)
        status = processor.status(_stamp(msg))
        if 4.0 <= t < 12.0:
            during.append(status)
        elif t > 15.0:
            after.append(status)
    assert during and all(s.level >= WARN and s.message != 'suspension normal' for s in during)
    assert any('no IMU pair' in s.message for s in during)
    assert after[-1].message == 'suspension normal' and after[-1].level == 0


@pytest.mark.parametrize('name', ['suspension_monitor', 'creep_estimator'])
def test_finding_5_shipped_yaml_applies_under_any_namespace(
        name: str, make_node: Callable[..., Any], tmp_path: Path) -> None:
    """Finding 5: the shipped config is keyed /** and applies to the node under a namespace
    and another node name (a changed value is taken, not the default)."""
    data = yaml.safe_load((CONFIG / f'{name}.yaml').read_text())
    assert list(data) == ['/**']
    key = 'pair_timeout_s'
    data['/**']['ros__parameters'][key] = 0.042
    path = tmp_path / 'params.yaml'
    path.write_text(yaml.safe_dump(data))
    node = make_node(NODES[name][0], node_name=f'{name}_2', namespace='/train2',
                     cli_args=['--ros-args', '--params-file', str(path)])
    assert node.get_fully_qualified_name() == f'/train2/{name}_2'
    assert node.get_parameter(key).value == pytest.approx(0.042)


@pytest.mark.parametrize('name', ['suspension_monitor', 'creep_estimator'])
def test_finding_7_after_a_fault_the_status_says_recovering(name: str) -> None:
    """Finding 7: after an input fault clears, the status says the estimate is recovering for
    the documented time (not silently off), then returns to OK."""
    processor = _make(name)
    driving = 'rail/lateral_states' if name == 'creep_estimator' else 'rail/body/imu'
    field = 'bogie_lateral' if name == 'creep_estimator' else 'linear_acceleration'
    topics = [f'/{t}' for t in processor.inputs if t != 'rail/creep_factor']   # not recorded
    stream = _stream(HEALTHY_BAG, topics, 8.0)
    t0 = _stamp(stream[0][1])
    recovering, final = [], None
    recovery_s = (processor.node_params.fault_recovery_s if name == 'suspension_monitor'
                  else processor.node_params.recovery_s)
    for topic, msg in stream:
        t = (_stamp(msg) - t0) * 1e-9
        if topic == driving and 2.0 <= t < 3.0:
            msg = copy.deepcopy(msg)
            if name == 'creep_estimator':
                msg.bogie_lateral = np.full(2, np.nan)
            else:
                getattr(msg, field).y = float('nan')
        processor.process(topic, msg)
        final = processor.status(_stamp(msg))
        if 3.05 <= t < 3.0 + recovery_s - 0.05:
            recovering.append(final)
    assert recovering and all('recovering' in s.message and s.level >= WARN
                              for s in recovering), {s.message for s in recovering}
    assert final is not None and final.level == 0, final.message
