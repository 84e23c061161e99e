"""The TPMS voter's processor: the node and the offline engine give the same warnings; the
voter's side of issue 20 finding 1 (a future stamp, a replay) on the node."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from rclpy.serialization import deserialize_message
from vehicle_monitor_msgs.msg import TpmsIndication

from tpms_ros.nodes.tpms_voter_node import TpmsVoterNode
from tpms_ros.processing.tpms_voter import WARNING, make_processor
from vehicle_monitor_common.bag_io import BagWriter, default_message, iter_raw
from vehicle_monitor_common.offline_engine import EngineNode, OfflineGraph
from vehicle_monitor_common.processing import Output

METHODS = ('stiffness', 'vibration', 'wheel_radius')
T0_NS = 1_700_000_000 * 10**9
MSGTYPE = 'vehicle_monitor_msgs/msg/TpmsIndication'


def _indication(method: str, stamp_ns: int, low_fr: bool) -> Any:
    msg = default_message(MSGTYPE)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    msg.method = method
    msg.underinflated = np.array([False, low_fr, False, False])
    msg.confidence = np.array([0.05, 0.9 if low_fr else 0.1, 0.05, 0.05])
    msg.known = np.ones(4, dtype=bool)
    return msg


@pytest.fixture(scope='module')
def indications(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """40 s of three methods at 4 Hz; FR low in two of them from 10 s on (a warning), then
    healthy again from 20 s (it clears after set_off_s, 10 s)."""
    path = tmp_path_factory.mktemp('bags') / 'indications'
    with BagWriter(path) as writer:
        for k in range(160):
            for j, method in enumerate(METHODS):
                stamp = T0_NS + k * 250_000_000 + j * 7_000_000
                low = 40 <= k < 80 and method != 'wheel_radius'
                writer.write(f'/tpms/indication/{method}', MSGTYPE, stamp,
                             _indication(method, stamp, low))
    return path


def test_engine_gives_what_the_node_publishes(indications: Path,
                                              make_node: Callable[..., Any]) -> None:
    """The same indications through the node's adapter (rclpy messages) and the offline engine
    (rosbags messages): the same warnings at the same stamps (the node's periodic output is its
    timer's, not part of this)."""
    node = make_node(TpmsVoterNode)
    published: list[Output] = []
    node.publish_output = published.append  # type: ignore[method-assign]
    for topic, _, _, data in iter_raw(indications):
        node.deliver(topic.lstrip('/'), deserialize_message(data, TpmsIndication))
    engine: list[tuple[int, Any]] = []
    graph = OfflineGraph([EngineNode('/tpms_voter', make_processor({}, '/tpms_voter'))])
    graph.run(indications, lambda topic, msgtype, stamp, msg: engine.append((stamp, msg)))
    assert len(published) == len(engine) == 480
    for output, (stamp, msg) in zip(published, engine, strict=True):
        assert output.topic == WARNING and output.stamp_ns == stamp
        assert list(output.fields['warning']) == list(msg.warning)
        np.testing.assert_allclose(output.fields['confidence'], msg.confidence, rtol=1e-9)
        assert list(output.fields['reasons']) == list(msg.reasons)
    assert any(o.fields['warning'][1] for o in published)
    assert not any(o.fields['warning'][1] for o in published[-10:])


def test_future_stamp_and_replay_keep_it_voting(indications: Path,
                                                make_node: Callable[..., Any]) -> None:
    """Finding 1, the voter's side: one indication stamped 10 000 s ahead is dropped (the other
    methods stay fresh); a second replay of the same indications restarts the vote and warns
    again on the replayed low tire."""
    node = make_node(TpmsVoterNode, node_name='voter_replayed')
    published: list[Output] = []
    node.publish_output = published.append  # type: ignore[method-assign]
    messages = [(topic.lstrip('/'), deserialize_message(data, TpmsIndication))
                for topic, _, _, data in iter_raw(indications)]
    for n, (topic, msg) in enumerate(messages):
        if n == 30:
            msg.header.stamp.sec += 10_000
        node.deliver(topic, msg)
        if n == 31:
            status = node.processor.status(0)
            assert 'future_stamp' in status.message and status.level == 1
    assert node.processor.rejected['future_stamp'] == 1
    first = len(published)
    assert all(sorted(o.fields['methods']) == sorted(METHODS) for o in published[40:first])
    for topic, msg in messages:
        node.deliver(topic, msg)
    assert node.processor.time_jumps == 1
    second = published[first:]
    assert any(o.fields['warning'][1] for o in second)
    assert all(sorted(o.fields['methods']) == sorted(METHODS) for o in second[-100:])
    node.processor.status(0)     # the rejections of the replay's first samples are reported
    assert node.processor.status(0).level == 0      # ... and clear when no more come


def test_clock_jump_back_reanchors_the_periodic_output(indications: Path) -> None:
    """A /clock reset between indications (the node's jump callback calls clock_jumped): the
    periodic output goes on extrapolating data time from the reset, so a method that stops
    still ages out after max_age_s instead of the vote freezing until the clock catches up."""
    processor = make_processor({}, '/tpms_voter')
    clock = [10**12]
    processor._clock = lambda: clock[0]
    for topic, _, _, data in iter_raw(indications):
        processor.process(topic.lstrip('/'),
                          deserialize_message(data, TpmsIndication))
    assert processor.tick(clock[0])[0].fields['methods']
    clock[0] = 5 * 10**9                       # the clock went back 995 s
    processor.clock_jumped(clock[0])
    # Every method silent: 3 s of node clock later they are all stale (max_age_s 2 s).
    (output,) = processor.tick(clock[0] + 3 * 10**9)
    assert output.fields['methods'] == []
    assert processor.status(0).message == 'no fresh indication from any enabled method'


def test_periodic_output_does_not_change_the_answers(indications: Path) -> None:
    """The node's timer (``tick``, at node-clock times unrelated to the data) shows the vote
    between indications but does not move it: the warnings answering the indications, their
    reasons and hold timers included, are those of a run without the timer. (When the timer
    moved the hold timers, the live graph's warnings depended on when it happened to run.)"""
    rng = np.random.default_rng(22)
    messages = [(topic.lstrip('/'), deserialize_message(data, TpmsIndication))
                for topic, _, _, data in iter_raw(indications)]
    clock = [0]
    plain, ticked = make_processor({}, '/plain'), make_processor({}, '/ticked')
    plain._clock = ticked._clock = lambda: clock[0]
    answers: dict[str, list[Output]] = {'plain': [], 'ticked': []}
    periodic = []
    for topic, msg in messages:
        clock[0] += int(rng.integers(1, 200_000_000))
        answers['plain'] += plain.process(topic, msg)
        answers['ticked'] += ticked.process(topic, msg)
        for _ in range(int(rng.integers(0, 3))):
            clock[0] += int(rng.integers(1, 300_000_000))
            periodic += ticked.tick(clock[0])
    assert len(periodic) > 100
    assert any(o.fields['warning'][1] for o in answers['plain'])
    for mine, theirs in zip(answers['plain'], answers['ticked'], strict=True):
        assert (mine.stamp_ns, mine.fields) == (theirs.stamp_ns, theirs.fields)
