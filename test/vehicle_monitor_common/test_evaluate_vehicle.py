"""``evaluate`` takes the vehicle: its params file, per-node values and stored calibration (or a
fleet manifest's entry) reach the graph's estimator nodes."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from vehicle_monitor_common.calibration_store import load_calibration
from vehicle_monitor_common.evaluate_cli import Vehicle, main, read_vehicle
from vehicle_monitor_common.evaluation import domains
from vehicle_monitor_common.parameters import ConfigurationError


def _road():
    return next(d for d in domains() if d.name == 'road')


def test_params_file_and_calibration_reach_the_nodes(tmp_path: Path) -> None:
    """A /** params file applies to every estimator node (not the player or recorder); a
    stored calibration is written to the node's calibration file and put in force at start."""
    params = tmp_path / 'car.yaml'
    params.write_text(yaml.safe_dump({
        '/**': {'ros__parameters': {'driven_axle': 'front'}},
        '/tire_stiffness_observer': {'ros__parameters': {
            'nominal_pressure_kpa': [230.0, 230.0, 240.0, 240.0]}}}))
    calibration = tmp_path / 'calib.yaml'
    calibration.write_text(yaml.safe_dump({'tire_stiffness_observer': {'k_nominal': [1, 2]}}))
    vehicle = read_vehicle([str(params)], str(calibration))
    run = vehicle.run_parameters(_road(), tmp_path / 'run')
    stiffness = run['tire_stiffness_observer']
    assert stiffness['nominal_pressure_kpa'] == [230.0, 230.0, 240.0, 240.0]
    assert stiffness['driven_axle'] == 'front'
    assert stiffness['calibrate_on_start'] is False
    assert load_calibration(stiffness['calibration_file']).state == {'k_nominal': [1, 2]}
    assert run['vibration_analyzer']['driven_axle'] == 'front'
    assert 'calibrate_on_start' not in run['vibration_analyzer']
    assert 'vehicle_simulator' not in run and 'road_recorder' not in run
    assert run['vibration_analyzer']['calibration_file'] == str(
        tmp_path / 'run' / 'vibration_analyzer_calibration.yaml')


def test_vehicle_from_a_fleet_manifest(tmp_path: Path) -> None:
    """--manifest/--vehicle: the entry's params files, per-node values and calibration."""
    (tmp_path / 'p.yaml').write_text(yaml.safe_dump({'/**': {'ros__parameters': {'x': 1}}}))
    (tmp_path / 'c.yaml').write_text(yaml.safe_dump({'wheel_radius_analyzer': {'a': 1.0}}))
    manifest = tmp_path / 'fleet.yaml'
    manifest.write_text(yaml.safe_dump({
        'vehicles': {'car7': {'params': 'p.yaml', 'calibration': 'c.yaml',
                              'parameters': {'tpms_voter': {'h0': 0.7}}}},
        'recordings': []}))
    vehicle = read_vehicle(manifest=str(manifest), vehicle_id='car7')
    assert vehicle == Vehicle((str(tmp_path / 'p.yaml'),), {'tpms_voter': {'h0': 0.7}},
                              {'wheel_radius_analyzer': {'a': 1.0}})
    with pytest.raises(ConfigurationError, match="no vehicle 'car8'"):
        read_vehicle(manifest=str(manifest), vehicle_id='car8')


def test_bad_vehicle_options_are_one_line_errors(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A missing params or calibration file, --manifest without --vehicle."""
    with pytest.raises(ConfigurationError, match='no params file'):
        read_vehicle([str(tmp_path / 'missing.yaml')])
    with pytest.raises(ConfigurationError, match='no such file'):
        read_vehicle(calibration=str(tmp_path / 'missing.yaml'))
    assert main(['bags/rail_healthy', '--calibration', str(tmp_path / 'none.yaml'),
                 '--out', str(tmp_path / 'out')]) == 2
    assert 'error: calibration' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(['bags/rail_healthy', '--manifest', 'm.yaml'])


@pytest.mark.timeout(300)
def test_offline_evaluation_scores_every_message(tmp_path: Path) -> None:
    """--offline: the graph's processors over the bag in the offline engine, nothing dropped,
    scored as a live recording is (the IMM bag's two fault onsets within target)."""
    from vehicle_monitor_common.evaluate_cli import Task, run_task

    bag = Path(__file__).resolve().parents[2] / 'bags' / 'rail_imm_spring_damper_fault'
    evaluation, stats = run_task(Task('imm', 'rail', bag, 'bag', offline=True), tmp_path,
                                 quiet=True)
    assert stats is not None and stats.dropped == 0 and stats.published == 8205
    imm = [m for m in evaluation.metrics if m.method == 'IMM' and m.passed is not None]
    assert imm and all(m.passed for m in imm)
