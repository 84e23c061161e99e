"""Offline engine throughput vs the live graph's replay of the same bag, and their equality.

For each shipped bag (or those given) in one process: the live graph (DDS, as the main job
runs it: ``main_job.run_graph_on_bag``) and then the offline engine (the same processors,
ROS-free, outputs written to a bag) over the same recording, with the same parameters
(the domain's graph and run parameters). Prints per bag the recorded time, both real-time
factors (recorded seconds per wall second), their ratio, the engine's CPU real-time factor
(one core), and whether every output topic agrees (``offline_engine.compare_outputs``: the
same messages and stamps, values to 1e-9 of each field's scale), except the voter's
``/tpms/warning``, whose periodic messages between indications come from the node's timer
(counts given). Bags whose domain's
estimators are not all registered as processors are listed as skipped. ``--breakdown`` adds,
per bag, where the engine's time goes: each processor's own ``process`` calls (their outputs'
downstream processing not included) and the rest (reading and decoding the bag, building,
encoding and writing the outputs); the timers add ~1 us per call, so the shares are measured
in a run of their own, after the timed one.

Run under tools/env.sh:
``python benchmarks/bench_offline_engine.py [--no-live] [--breakdown] [bag ...]``.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
import tempfile
import time
from typing import Any

from vehicle_monitor_common.bag_io import BagError, bag_topics
from vehicle_monitor_common.evaluation import Domain, domain_of_bag, domains
from vehicle_monitor_common.graph_spec import load_graph
from vehicle_monitor_common.offline_engine import (
    OfflineGraph,
    compare_outputs,
    factory_for,
    processor_factories,
    write_outputs,
)
from vehicle_monitor_common.resources import workspace_bags

#: Topics a node also publishes from a timer on its clock (the voter's periodic warning between
#: indications): that part is the node's, not the processor's, so the engine publishes only the
#: warnings that answer an indication; compared by count only.
TIMER_TOPICS = {'/tpms/warning'}


def _ready(domain: Domain) -> list[str]:
    """The estimator nodes of the domain's graph without a registered processor."""
    factories = processor_factories()
    return [n.name or n.plugin for n in load_graph(domain.graph).nodes
            if (n.name or n.plugin) not in (domain.player, domain.recorder)
            and factory_for(n.plugin, factories) is None]


def bench(bag: Path, domain: Domain, scratch: Path, live: bool) -> dict[str, object]:
    """One bag: the live replay (optional), the engine, the comparison."""
    row: dict[str, object] = {'bag': bag.name, 'domain': domain.name}
    recorded = None
    if live:
        from vehicle_monitor_common.main_job import run_graph_on_bag

        recorded, stats = run_graph_on_bag(domain, bag, scratch / 'live', executor=None,
                                           log=lambda line: None)
        row.update(live_rtf=stats.real_time_factor, dropped=stats.dropped)
    graph = OfflineGraph.from_spec(load_graph(domain.graph),
                                   domain.run_parameters(scratch / 'offline'))
    cpu = time.process_time()
    engine = write_outputs(graph, bag, scratch / 'offline' / 'outputs')
    cpu = time.process_time() - cpu
    row.update(data_s=engine.data_s, engine_rtf=engine.real_time_factor,
               engine_cpu_rtf=engine.data_s / cpu if cpu > 0 else float('inf'),
               messages_in=engine.messages_in, messages_out=engine.messages_out)
    if recorded is not None:
        compared = set(engine.published) - TIMER_TOPICS
        problems = compare_outputs(recorded, scratch / 'offline' / 'outputs', compared)
        row['identical'] = 'yes' if not problems else f'NO: {problems[0]}'
        live_topics = bag_topics(recorded)
        for topic in sorted(TIMER_TOPICS & set(engine.published)):
            live_count = live_topics[topic].count if topic in live_topics else 0
            row['identical'] = (f'{row["identical"]}; {topic}: {engine.published[topic]} '
                                f'(live {live_count}, with its timer\'s)')
        row['ratio'] = engine.real_time_factor / float(row['live_rtf'])  # type: ignore[arg-type]
    return row


def breakdown(bag: Path, domain: Domain, scratch: Path) -> str:
    """Where the engine's wall time goes on one bag: per processor, and the rest."""
    graph = OfflineGraph.from_spec(load_graph(domain.graph),
                                   domain.run_parameters(scratch / 'breakdown'))
    spent: dict[str, float] = {}

    def timed(name: str, process: Callable[[str, Any], list[Any]]
              ) -> Callable[[str, Any], list[Any]]:
        def call(topic: str, payload: Any) -> list[Any]:
            started = time.perf_counter()
            try:
                return process(topic, payload)
            finally:
                spent[name] = spent.get(name, 0.0) + time.perf_counter() - started
        return call

    for node in graph.nodes:
        # an instance attribute shadows the method for this graph's run only
        node.processor.process = timed(node.fqn, node.processor.process)  # type: ignore
    stats = write_outputs(graph, bag, scratch / 'breakdown' / 'outputs')
    rest = stats.wall_s - sum(spent.values())
    shares = sorted(spent.items(), key=lambda item: -item[1]) + [('read, encode, write', rest)]
    return ', '.join(f'{name} {100 * s / stats.wall_s:.0f} % ({stats.data_s / s:.0f}x RT)'
                     for name, s in shares)


def _cell(row: dict[str, object], key: str, fmt: str = '{:.1f}') -> str:
    value = row.get(key)
    return '' if value is None else (fmt.format(value) if isinstance(value, float)
                                     else str(value))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('bags', nargs='*', type=Path)
    parser.add_argument('--no-live', action='store_true', help='the engine only')
    parser.add_argument('--breakdown', action='store_true',
                        help='also where the engine\'s time goes, per processor')
    args = parser.parse_args()
    bags = args.bags or sorted(p for p in workspace_bags().iterdir()
                               if (p / 'metadata.yaml').is_file())
    registered = domains()
    print('| bag | domain | data s | live x RT | engine x RT | engine/live | engine CPU x RT '
          '| in | out | dropped live | identical |')
    print('| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |')
    for bag in bags:
        try:
            domain = domain_of_bag(bag, registered)
        except (ValueError, BagError) as exc:
            print(f'| {bag.name} | skipped: {exc} |')
            continue
        missing = _ready(domain)
        if missing:
            print(f'| {bag.name} | {domain.name} | skipped: no processor for '
                  f'{", ".join(missing)} |')
            continue
        with tempfile.TemporaryDirectory(prefix='bench-engine-') as scratch:
            row = bench(bag, domain, Path(scratch), not args.no_live)
            split = breakdown(bag, domain, Path(scratch)) if args.breakdown else ''
        print(f'| {bag.name} | {domain.name} | {_cell(row, "data_s", "{:.0f}")} | '
              f'{_cell(row, "live_rtf")} | {_cell(row, "engine_rtf")} | {_cell(row, "ratio")} | '
              f'{_cell(row, "engine_cpu_rtf")} | {row["messages_in"]} | {row["messages_out"]} | '
              f'{_cell(row, "dropped")} | {_cell(row, "identical")} |', flush=True)
        if split:
            print(f'|  | time: {split} |', flush=True)


if __name__ == '__main__':
    main()
