"""The synthetic fleet: planted faults as written, and the fleet job finds exactly them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from vehicle_monitor_common.bag_io import bag_topics
from vehicle_monitor_common.fleet.job import RECORDING_FIELDS, LocalExecutor, run_fleet
from vehicle_monitor_common.fleet.manifest import read_manifest
from vehicle_monitor_common.fleet.synthetic import FleetPlan, generate, score


def test_generated_fleet_recordings_and_truth(tmp_path: Path) -> None:
    """N x M recordings with inputs only at their drive dates; the damper of the degrading
    train falls linearly to damper_last; the manifest names every recording."""
    plan = FleetPlan(cars=0, trains=2, drives=3, leaking_cars=0, degrading_trains=1,
                     train_drive_s=2.0, seed=7)
    manifest = read_manifest(generate(tmp_path, plan, log=lambda _: None))
    assert len(manifest.recordings) == 6
    assert [r.date for r in manifest.recordings[:3]] == ['2026-11-02', '2026-11-09',
                                                         '2026-11-16']
    topics = bag_topics(manifest.recordings[0].path)
    assert '/rail/bogie/imu' in topics and not any(t.startswith('/truth') for t in topics)
    truth = yaml.safe_load((tmp_path / 'truth.yaml').read_text())
    faulty = [v for v, t in truth.items() if t['fault'] == 'damper']
    assert len(faulty) == 1
    assert truth[faulty[0]]['damper_ratios'] == [1.0, 0.75, 0.5]


def test_score_counts_found_missed_and_false_positives(tmp_path: Path) -> None:
    """A leak is found by a warning on its tire; a warning elsewhere is a false positive."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from vehicle_monitor_common.fleet.job import SUMMARY_SCHEMA

    def row(vehicle: str, fl: float = np.nan, fr: float = np.nan) -> dict[str, object]:
        values = {name: None for name in SUMMARY_SCHEMA.names}
        values.update(recording=f'{vehicle}/d1', error='', method='tpms_warning',
                      first_warning_s_fl=fl, first_warning_s_fr=fr)
        return values

    for vehicle, values in (('a', row('a', fl=3.0)), ('b', row('b', fr=1.0)), ('c', row('c'))):
        folder = tmp_path / 'summary' / f'vehicle={vehicle}' / 'date=2026-11-02'
        folder.mkdir(parents=True)
        pq.write_table(pa.Table.from_pylist([values], schema=SUMMARY_SCHEMA),
                       folder / 'd1.parquet')
    truth = {'a': {'domain': 'road', 'fault': 'leak', 'tire': 'FL'},
             'b': {'domain': 'road', 'fault': 'leak', 'tire': 'RR'},
             'c': {'domain': 'road', 'fault': None}}
    table = score(tmp_path, truth).set_index('method')
    assert table.loc['tpms_warning', 'planted'] == 2
    assert table.loc['tpms_warning', 'found'] == 1
    assert table.loc['tpms_warning', 'missed'] == 'b'
    assert table.loc['tpms_warning', 'false_positives'] == 'b'
    assert table.loc['tpms_warning', 'recall'] == 0.5
    assert 'recording' in RECORDING_FIELDS


def test_score_judges_a_tpms_method_by_what_would_make_the_voter_warn(tmp_path: Path) -> None:
    """A method's indication counts when its confidence passes the voter's single-method
    threshold: a weak flag on a healthy tire is evidence, not a false positive."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from vehicle_monitor_common.fleet.job import EVENTS_SCHEMA, SUMMARY_SCHEMA

    for vehicle, tire, peak in (('a', 'fl', 0.95), ('b', 'rr', 0.6)):
        summary = {name: None for name in SUMMARY_SCHEMA.names}
        summary.update(recording=f'{vehicle}/d1', error='', method='indication_vibration')
        event = {name: None for name in EVENTS_SCHEMA.names}
        event.update(recording=f'{vehicle}/d1', method='indication_vibration',
                     kind='tire_indication', subject=tire, peak=peak)
        for name, values, schema in (('summary', summary, SUMMARY_SCHEMA),
                                     ('events', event, EVENTS_SCHEMA)):
            folder = tmp_path / name / f'vehicle={vehicle}' / 'date=2026-11-02'
            folder.mkdir(parents=True)
            pq.write_table(pa.Table.from_pylist([values], schema=schema), folder / 'd1.parquet')
    truth = {'a': {'domain': 'road', 'fault': 'leak', 'tire': 'FL'},
             'b': {'domain': 'road', 'fault': None}}
    row = score(tmp_path, truth).set_index('method').loc['indication_vibration']
    assert (row['found'], row['false_positives']) == (1, '')
    strict = score(tmp_path, truth, indication_threshold=0.5).set_index('method')
    assert strict.loc['indication_vibration', 'false_positives'] == 'b'


@pytest.mark.timeout(300)
def test_fleet_job_finds_the_degrading_damper_and_nothing_else(tmp_path: Path) -> None:
    """Two trains x two weekly drives, the front damper of one down to half by its second
    drive: the suspension monitor flags that train only; no low adhesion anywhere."""
    plan = FleetPlan(cars=0, trains=2, drives=2, leaking_cars=0, degrading_trains=1,
                     train_drive_s=15.0, seed=3)
    manifest = generate(tmp_path / 'fleet', plan, log=lambda _: None)
    run = run_fleet(read_manifest(manifest), tmp_path / 'out', LocalExecutor(),
                    log=lambda _: None)
    assert (run.done, run.failed) == (4, 0)
    table = score(tmp_path / 'out', tmp_path / 'fleet' / 'truth.yaml').set_index('method')
    assert table.loc['suspension', 'found'] == table.loc['suspension', 'planted'] == 1
    assert (table['false_positives'] == '').all()
