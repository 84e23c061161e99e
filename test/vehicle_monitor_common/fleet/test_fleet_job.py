"""The fleet job with small stand-in processors (fleet_fakes): tables, calibration chain,
resuming, bad recordings, vehicle parameters, Ray."""

from __future__ import annotations

import datetime as dt
import os
from pathlib import Path
import shutil
import sys

import numpy as np
import pytest
import yaml

from vehicle_monitor_common.bag_io import write_bag
from vehicle_monitor_common.fleet.cli import main as fleet_main
from vehicle_monitor_common.fleet.job import (
    LocalExecutor,
    RayExecutor,
    read_table,
    result_paths,
    run_fleet,
)
from vehicle_monitor_common.fleet.manifest import find_recordings, read_manifest
from vehicle_monitor_common.parameters import ConfigurationError
from vehicle_monitor_common.series import TopicSeries

HERE = Path(__file__).resolve().parent
DAY_NS = 86_400 * 1_000_000_000
EPOCH_NS = int(dt.datetime(2026, 11, 1, 8, tzinfo=dt.UTC).timestamp()) * 1_000_000_000


@pytest.fixture(autouse=True)
def fakes_importable(monkeypatch: pytest.MonkeyPatch) -> None:
    """The graph names its processors by import path (fleet_fakes:make_...)."""
    monkeypatch.syspath_prepend(str(HERE))


def drive(path: Path, day: int, ay: np.ndarray, creep: float = 1.0,
          spring: float = 1.0) -> Path:
    """A 10 Hz IMU recording on day ``day`` of the month: lateral acceleration ``ay``,
    yaw rate = creep factor, roll rate = spring ratio."""
    n = len(ay)
    stamps = EPOCH_NS + day * DAY_NS + np.arange(n, dtype=np.int64) * 100_000_000
    write_bag(path, {'/vehicle/imu': TopicSeries('sensor_msgs/msg/Imu', stamps, {
        'linear_acceleration.y': np.asarray(ay, float),
        'angular_velocity.z': np.full(n, creep), 'angular_velocity.x': np.full(n, spring)})})
    return path


def graph_file(tmp_path: Path) -> Path:
    path = tmp_path / 'graph.yaml'
    path.write_text(yaml.safe_dump({'nodes': [
        {'plugin': 'fleet_fakes:make_tire_warner', 'name': 'warner'},
        {'plugin': 'fleet_fakes:make_creep', 'name': 'creep'},
        {'plugin': 'fleet_fakes:make_suspension', 'name': 'suspension'}]}))
    return path


def small_fleet(tmp_path: Path) -> Path:
    """car1: healthy, then its FL tire low for the whole second drive (a leak since the first);
    car2: healthy twice, low adhesion for 2 s and a spring fault in its second drive."""
    root = tmp_path / 'drives'
    healthy = np.full(40, 1.0)
    drive(root / 'car1' / 'd1', 1, healthy)
    drive(root / 'car1' / 'd2', 3, np.full(40, -1.0))
    drive(root / 'car2' / 'd1', 2, healthy)
    drive(root / 'car2' / 'd2', 4, healthy, creep=0.4, spring=1.5)
    manifest = tmp_path / 'manifest.yaml'
    manifest.write_text(yaml.safe_dump({
        'defaults': {'graph': str(graph_file(tmp_path))},
        'recordings': [str(p.relative_to(tmp_path)) for p in sorted(root.glob('*/*'))]}))
    return manifest


def test_tables_and_the_calibration_chain(tmp_path: Path) -> None:
    """One row per recording x method, episodes with start/end/peak, partitioned by vehicle and
    date; the low tire of car1's second drive is warned from its start because the calibration
    learned in the first drive is carried over (recalibrating would learn the low tire)."""
    out = tmp_path / 'out'
    run = run_fleet(read_manifest(small_fleet(tmp_path)), out, LocalExecutor(), log=lambda _: None)
    assert (run.done, run.failed, run.skipped) == (4, 0, 0)
    summary = read_table(out, 'summary').to_pandas()
    assert sorted(summary['method'].unique()) == ['creep_factor', 'suspension', 'tpms_warning']
    assert len(summary) == 12
    warn = summary[summary['method'] == 'tpms_warning'].set_index('recording')
    assert warn.loc['car1/d2', 'warnings_raised'] == 1
    assert warn.loc['car1/d2', 'first_warning_s_fl'] == 0.0
    assert warn.loc['car1/d2', 'date'] == '2026-11-04'
    assert warn.loc['car1/d2', 'calibration_in'] == 'warner: loaded'
    assert warn.loc['car1/d1', 'warnings_raised'] == 0
    assert np.isnan(warn.loc['car1/d2', 'first_warning_s_fr'])
    creep = summary[summary['method'] == 'creep_factor'].set_index('recording')
    assert creep.loc['car2/d2', 'min_creep_factor'] == pytest.approx(0.4)
    assert creep.loc['car2/d2', 'low_adhesion_s'] == pytest.approx(3.9)
    assert creep.loc['car2/d1', 'low_adhesion_s'] == 0.0
    suspension = summary[summary['method'] == 'suspension'].set_index('recording')
    assert suspension.loc['car2/d2', 'fault_modes'] == 'spring'
    assert suspension.loc['car2/d2', 'spring_ratio_mean'] == pytest.approx(1.5)
    events = read_table(out, 'events').to_pandas()
    assert sorted(events['kind']) == ['low_adhesion', 'suspension_fault', 'tire_warning']
    tire = events[events['kind'] == 'tire_warning'].iloc[0]
    assert (tire['recording'], tire['subject'], tire['peak']) == ('car1/d2', 'fl', 0.9)
    assert tire['open_at_end'] and tire['end_s'] == pytest.approx(3.9)
    assert (out / 'summary' / 'vehicle=car2' / 'date=2026-11-05' / 'd2.parquet').is_file()
    assert yaml.safe_load((out / 'calibration' / 'vehicle=car1' / 'd2.yaml').read_text()) == {
        '/warner': {'baseline': 1.0}}


def test_rerun_skips_done_recordings_and_force_redoes_them(tmp_path: Path) -> None:
    """A rerun screens only what has no result yet, continuing the chain from the stored
    calibration; --force screens everything again."""
    manifest = read_manifest(small_fleet(tmp_path))
    out = tmp_path / 'out'
    run_fleet(manifest, out, LocalExecutor(), log=lambda _: None)
    gone = result_paths(out, manifest.recordings[1])['summary']
    assert manifest.recordings[1].key == 'car1/d2'
    gone.unlink()
    rerun = run_fleet(manifest, out, LocalExecutor(), log=lambda _: None)
    assert (rerun.done, rerun.skipped) == (1, 3)
    warn = read_table(out, 'summary').to_pandas().query("method == 'tpms_warning'")
    assert warn.set_index('recording').loc['car1/d2', 'warnings_raised'] == 1
    forced = run_fleet(manifest, out, LocalExecutor(), force=True, log=lambda _: None)
    assert (forced.done, forced.skipped) == (4, 0)
    assert len(read_table(out, 'summary')) == 12


def test_bad_recordings_become_error_rows(tmp_path: Path) -> None:
    """A missing path, a non-bag file, a truncated MCAP and another robot's bag each give a
    one-line error row; the good recording's results are intact."""
    drive(tmp_path / 'good', 1, np.full(20, 1.0))
    truncated = drive(tmp_path / 'truncated', 1, np.full(2000, 1.0))
    mcap = next(truncated.glob('*.mcap'))
    with open(mcap, 'r+b') as stream:
        stream.truncate(mcap.stat().st_size // 2)
    (tmp_path / 'notes.txt').write_text('not a bag')
    foreign = tmp_path / 'foreign'
    write_bag(foreign, {'/scan': TopicSeries('sensor_msgs/msg/Imu',
                                             np.arange(3, dtype=np.int64), {})})
    manifest = tmp_path / 'manifest.yaml'
    manifest.write_text(yaml.safe_dump({
        'defaults': {'graph': str(graph_file(tmp_path))},
        'recordings': [{'path': p, 'vehicle': 'v'} for p in
                       ('good', 'missing', 'notes.txt', 'truncated', 'foreign')]}))
    run = run_fleet(read_manifest(manifest), tmp_path / 'out', LocalExecutor(),
                    log=lambda _: None)
    assert (run.done, run.failed) == (5, 4)
    summary = read_table(tmp_path / 'out', 'summary').to_pandas()
    errors = summary.drop_duplicates('recording').set_index('recording')['error']
    assert errors['v/good'] == ''
    assert errors['v/missing'].startswith('BagError: no such bag')
    assert 'not a rosbag2 bag' in errors['v/notes.txt']
    assert 'cannot read bag' in errors['v/truncated']
    assert errors['v/foreign'].startswith('BagError: foreign recording')
    assert all('\n' not in e for e in errors)
    assert len(summary[summary['recording'] == 'v/good']) == 3


def test_vehicle_parameters_from_params_file_and_manifest(tmp_path: Path) -> None:
    """A vehicle's params file (keyed /** as the nodes take it) and its per-node values reach
    its processors: a larger warning threshold silences car1's warning."""
    manifest_path = small_fleet(tmp_path)
    params = tmp_path / 'car1.yaml'
    params.write_text(yaml.safe_dump({'/**': {'ros__parameters': {'drop': 5.0}}}))
    data = yaml.safe_load(manifest_path.read_text())
    data['vehicles'] = {'car1': {'params': ['car1.yaml']},
                        'car2': {'parameters': {'warner': {'calibration_samples': 2}}}}
    manifest_path.write_text(yaml.safe_dump(data))
    manifest = read_manifest(manifest_path)
    assert manifest.vehicle('car1').params == (str(params),)
    assert manifest.vehicle('car1').graph == str(graph_file(tmp_path))
    out = tmp_path / 'out'
    run_fleet(manifest, out, LocalExecutor(), log=lambda _: None)
    warn = read_table(out, 'summary').to_pandas().query("method == 'tpms_warning'")
    assert warn.set_index('recording').loc['car1/d2', 'warnings_raised'] == 0


def test_stored_calibration_starts_the_chain(tmp_path: Path) -> None:
    """A vehicle's stored calibration is in force from its first recording (a refused one is
    reported and the processor calibrates itself)."""
    manifest_path = small_fleet(tmp_path)
    (tmp_path / 'calib.yaml').write_text(yaml.safe_dump({'warner': {'baseline': 3.0}}))
    (tmp_path / 'bad.yaml').write_text(yaml.safe_dump({'warner': {'offset': 3.0}}))
    data = yaml.safe_load(manifest_path.read_text())
    data['vehicles'] = {'car1': {'calibration': 'calib.yaml'},
                        'car2': {'calibration': 'bad.yaml'}}
    manifest_path.write_text(yaml.safe_dump(data))
    out = tmp_path / 'out'
    run_fleet(read_manifest(manifest_path), out, LocalExecutor(), log=lambda _: None)
    warn = read_table(out, 'summary').to_pandas().query("method == 'tpms_warning'")
    warn = warn.set_index('recording')
    assert warn.loc['car1/d1', 'warnings_raised'] == 1  # 1.0 is low against a baseline of 3
    assert warn.loc['car2/d1', 'calibration_in'].startswith('warner: refused (ValueError')


def test_finding_recordings(tmp_path: Path) -> None:
    """A directory of vehicles' bags, a glob; an empty directory is a one-line error."""
    small_fleet(tmp_path)
    found = find_recordings([str(tmp_path / 'drives')])
    assert [(r.key, r.date) for r in found.recordings] == [
        ('car1/d1', '2026-11-02'), ('car1/d2', '2026-11-04'), ('car2/d1', '2026-11-03'),
        ('car2/d2', '2026-11-05')]
    assert len(find_recordings([str(tmp_path / 'drives' / '*' / 'd1')]).recordings) == 2
    (tmp_path / 'empty').mkdir()
    with pytest.raises(ConfigurationError, match='holds no recording'):
        find_recordings([str(tmp_path / 'empty')])


def test_cli_writes_tables_and_report(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``fleet --local`` prints progress and writes the report ranking car1 and car2 above
    nobody (both have a concern); an empty directory is exit code 2 with one line."""
    out = tmp_path / 'out'
    assert fleet_main([str(small_fleet(tmp_path)), '--local', '--out', str(out)]) == 0
    printed = capsys.readouterr().out
    assert '[4/4]' in printed and 'ETA' in printed
    report = (out / 'report.md').read_text()
    assert '| car1 |' in report and '| car2 |' in report
    assert (out / 'figures' / 'histograms.png').is_file()
    (tmp_path / 'empty').mkdir()
    assert fleet_main([str(tmp_path / 'empty'), '--local', '--out', str(out)]) == 2
    assert capsys.readouterr().err.strip().count('\n') == 0


@pytest.mark.timeout(240)
def test_on_a_local_ray_the_results_are_the_local_ones(tmp_path: Path) -> None:
    """A real embedded Ray (one CPU) gives the same tables as running in this process,
    with the calibration chain carried between tasks; a task whose worker dies is its
    recording's error row."""
    manifest_path = small_fleet(tmp_path)
    manifest = read_manifest(manifest_path)
    run_fleet(manifest, tmp_path / 'local', LocalExecutor(), log=lambda _: None)
    crash_graph = tmp_path / 'crash.yaml'
    crash_graph.write_text(yaml.safe_dump({'nodes': [
        {'plugin': 'fleet_fakes:make_crasher', 'name': 'crasher'}]}))
    drive(tmp_path / 'drives' / 'car3' / 'd1', 1, np.full(5, 1.0))
    data = yaml.safe_load(manifest_path.read_text())
    data['vehicles'] = {'car3': {'graph': str(crash_graph)}}
    data['recordings'].append('drives/car3/d1')
    manifest_path.write_text(yaml.safe_dump(data))
    path = os.pathsep.join([str(HERE), *sys.path])
    executor = RayExecutor(num_cpus=1, runtime_env={'env_vars': {'PYTHONPATH': path}})
    try:
        run = run_fleet(read_manifest(manifest_path), tmp_path / 'ray', executor,
                        log=lambda _: None)
    finally:
        executor.close()
    assert (run.done, run.failed) == (5, 1)
    assert run.errors[0].startswith('car3/d1: task failed: ')
    shutil.rmtree(tmp_path / 'ray' / 'summary' / 'vehicle=car3')

    def table(out: Path) -> object:
        frame = read_table(out, 'summary').to_pandas().drop(
            columns=['wall_s', 'real_time_factor'])
        return frame.sort_values(['recording', 'method']).reset_index(drop=True)

    expected, got = table(tmp_path / 'local'), table(tmp_path / 'ray')
    assert expected.equals(got)
    shutil.rmtree(tmp_path / 'ray')
