"""The offline engine's outputs equal what the live graph records, on every shipped bag
(issue 22: "identical outputs on every shipped bag").

Per bag: the domain's live graph (DDS, the main job's ``run_graph_on_bag``, its default
executor) replays the bag and records every output; the offline engine runs the same graph file
with the same run parameters over the same bag. Every topic the engine publishes is compared
per topic in header-stamp order (``offline_engine.compare_outputs``: same messages, same
stamps, values to 1e-9 of each field's scale). The voter's ``/tpms/warning`` is the one topic
the node also publishes from a timer (the periodic warning between indications, in extrapolated
data time), which the engine has no clock for: there, every warning the engine publishes must
be among the live ones, at its stamp and with its values.

A live replay takes the bag's time over the graph's real-time factor (road ~3x, rail ~2x
here): about 6 minutes for the eight shipped bags.

The live replay runs as fast as it can, so it assumes a machine that is not overloaded. Seen
once (2026-11-29, the suite run beside two other test processes on 2 cores): rail_healthy's
creep factor differed from message 21 on; alone, the same test passed. The likely cause (not
confirmed): the rail nodes pair the bogie and body IMU samples in data time and give a bogie
sample up as unpaired (missing) once the other stream is ``pair_timeout_s`` ahead (0.1 s of
data, ~50 ms of wall time at this replay speed); the engine pairs in log-time order.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from vehicle_monitor_common.bag_io import BagWriter, compare_bags, iter_raw, typestore
from vehicle_monitor_common.evaluation import domain_of_bag, domains
from vehicle_monitor_common.graph_spec import load_graph
from vehicle_monitor_common.main_job import run_graph_on_bag
from vehicle_monitor_common.offline_engine import OfflineGraph, compare_outputs, write_outputs
from vehicle_monitor_common.processing import header_stamp_ns
from vehicle_monitor_common.resources import workspace_bags

BAGS = sorted(p for p in workspace_bags().iterdir() if (p / 'metadata.yaml').is_file())
#: Published by a node's timer as well as in answer to its inputs (see the module docstring).
TIMER_TOPICS = {'/tpms/warning'}


def _answers_among_live(live: Path, engine: Path, topic: str, scratch: Path) -> list[str]:
    """What differs between the engine's messages on ``topic`` and the live messages at the
    same header stamps (the live ones in between, from the node's timer, left out)."""
    store = typestore()
    live_by_stamp: dict[int, tuple[str, bytes]] = {}
    for _, msgtype, _, data in iter_raw(live, [topic]):
        stamp = header_stamp_ns(store.deserialize_cdr(data, msgtype))
        live_by_stamp.setdefault(stamp, (msgtype, bytes(data)))
    missing = []
    with BagWriter(scratch / 'live') as live_answers, \
            BagWriter(scratch / 'engine') as engine_answers:
        for _, msgtype, _, data in iter_raw(engine, [topic]):
            stamp = header_stamp_ns(store.deserialize_cdr(data, msgtype))
            engine_answers.write_raw(topic, msgtype, stamp, data)
            if stamp not in live_by_stamp:
                missing.append(stamp)
                continue
            live_type, live_data = live_by_stamp[stamp]
            live_answers.write_raw(topic, live_type, stamp, live_data)
    if missing:
        return [f'{topic}: {len(missing)} engine messages have no live one at their stamp '
                f'(first {missing[0]} ns)']
    return compare_bags(scratch / 'live', scratch / 'engine')


@pytest.mark.parametrize('bag', BAGS, ids=[b.name for b in BAGS])
def test_engine_outputs_equal_the_live_graph_recording(bag: Path, tmp_path: Path) -> None:
    domain = domain_of_bag(bag, domains())
    recorded, stats = run_graph_on_bag(domain, bag, tmp_path / 'live', log=lambda line: None)
    assert stats.dropped == 0
    graph = OfflineGraph.from_spec(load_graph(domain.graph),
                                   domain.run_parameters(tmp_path / 'offline'))
    engine_bag = tmp_path / 'offline' / 'outputs'
    engine = write_outputs(graph, bag, engine_bag)
    assert engine.messages_out > 0
    compared = set(engine.published) - TIMER_TOPICS
    assert compare_outputs(recorded, engine_bag, compared) == []
    for topic in sorted(TIMER_TOPICS & set(engine.published)):
        scratch = tmp_path / topic.strip('/').replace('/', '_')
        scratch.mkdir()
        assert _answers_among_live(recorded, engine_bag, topic, scratch) == []
