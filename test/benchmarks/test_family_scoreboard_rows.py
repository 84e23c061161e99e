"""The family evaluations' scoreboard rows (``--scoreboard``) from small hand-made records:
pass counts, worst cases and verdicts against the issues' targets."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
from pathlib import Path
import pickle
import sys
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from vehicle_monitor_common.family_results import load_family_results

BENCHMARKS = Path(__file__).resolve().parents[2] / 'benchmarks'


def _load(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f'{name}.py')
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


tpms = _load('eval_tpms_family')
rail = _load('eval_rail_family')

NAN = math.nan


def _record(seed: int, case: str, **figures: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        'seed': seed, 'case': case, 'drive': 'rural', 'tires': ['FL'],
        'nominal_mean_err_kpa': [1.0, -2.0, 3.0, 0.5], 'nominal_std_kpa': [1.0, 1.0, 1.0, 1.0],
        'end_truth_kpa': [160.0] * 4, 'end_reading_kpa': [NAN] * 4, 'fused_detect_s': 10.0,
        'stiffness_detect_s': None, 'false_warning_tires': [], 'nominal_s': 60.0,
        'speed_corr_fl': 0.1, 'confidence': {m: {'nominal_max_conf': 0.3, 'healthy_max_conf': 0.2,
                                                  'threshold': 0.8, 'margin': 0.5}
                                              for m in tpms.METHODS}}
    return base | figures


RECORDS = [
    _record(21000, 'diffusion20', tires=['FL', 'FR', 'RL', 'RR'],
            nominal_mean_err_kpa=[1.0, NAN, 2.0, -3.0],
            end_reading_kpa=[165.0, 172.0, NAN, 158.0], fused_detect_s=-20.0,
            stiffness_detect_s=-20.0),
    _record(21000, 'puncture25', fused_detect_s=None),
    _record(21001, 'puncture25', fused_detect_s=12.5,
            nominal_mean_err_kpa=[-14.0, 0.0, 0.0, 0.0]),
    _record(21001, 'puncture15', fused_detect_s=30.0, false_warning_tires=['RL', 'RR']),
]


def _rows(rows: list[Any]) -> dict[str, Any]:
    return {row.target: row for row in rows}


def test_tpms_rows() -> None:
    """Unknown tires pass the nominal row only as unknown; a miss is the worst detection;
    readings are judged per tire against that tire's truth."""
    rows = _rows(tpms.scoreboard_rows(RECORDS))
    nominal = rows['stiffness at placard']
    assert (nominal.passed, nominal.cases) == (2, 4)  # the unknown FR and the -14 kPa fail
    assert nominal.worst_value == 14.0 and '21001 puncture25 rural FL' in nominal.worst_case
    assert '1 runs with a tire unknown' in nominal.detail and '1 tires read more' in nominal.detail
    assert not nominal.met
    reading = rows['stiffness reads -20 %']
    assert (reading.passed, reading.cases, reading.worst_value) == (2, 4, 12.0)
    assert reading.detail == '1 tires unknown'
    puncture = rows['fused: 25 % puncture']
    assert (puncture.passed, puncture.cases, puncture.worst_value) == (1, 2, None)
    assert puncture.worst_case == 'missed: 21000 puncture25 rural' and not puncture.met
    assert rows['fused: 20 % diffusion'].met and rows['fused: 15 % on 1-2 tires'].met
    false = rows['no false warning']
    assert (false.passed, false.cases, false.worst_value) == (3, 4, 2.0)
    assert false.worst_case == '21001 puncture15 rural: RL,RR' and not false.met
    assert '4 min of nominal driving, 2 min at most per car' in false.detail


def test_tpms_scoreboard_from_saved_runs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                         ) -> None:
    """``--report RUNS --scoreboard`` writes the file the main job reads, with the commit
    given and the date of the saved runs."""
    runs = tmp_path / 'runs.json'
    runs.write_text(json.dumps({'settings': {'fault_s': 150.0}, 'date': '2026-11-28',
                                'records': RECORDS}))
    out = tmp_path / 'tpms_family.json'
    monkeypatch.setattr(sys, 'argv', ['eval_tpms_family.py', '--report', str(runs),
                                      '--scoreboard', str(out), '--commit', 'abc1234'])
    tpms.main()
    results = load_family_results(out)
    assert (results.commit, results.date, results.seeds) == ('abc1234', '2026-11-28',
                                                             (21000, 21001))
    assert results.held_out and results.settings == {'fault_s': 150.0}
    assert [row.target for row in results.rows] == [row.target for row in
                                                    tpms.scoreboard_rows(RECORDS)]


def test_rail_rows() -> None:
    """Creep rows judge each config by its own band; a case that never settles is the worst;
    the healthy row is not met on fewer than 30 minutes per car even without a declaration."""
    creep = [rail.CreepCase(190001, 30.0, 'D/none', settle_10=[0.5, 1.5, 0.2]),
             rail.CreepCase(190002, 40.0, 'D/none', settle_10=[0.5, math.inf, 0.2]),
             rail.CreepCase(190001, 30.0, 'C-spec/exact', settle_5=[0.3, 0.4, 0.9])]
    imm = [rail.ImmCase(190001, 35.0, 'spring', 1.4, delay=0.1, end_component='spring'),
           rail.ImmCase(190001, 35.0, 'damper', 0.5, delay=1.2, end_component='none'),
           rail.ImmCase(190001, 35.0, 'healthy', 1.0),
           rail.ImmCase(190002, 45.0, 'healthy', 1.0)]
    rows = _rows(rail.scoreboard_rows(creep, imm, 60.0))
    assert list(rows) == ['creep D/none', 'creep C-spec/exact', 'IMM spring', 'IMM damper',
                          'IMM healthy', 'IMM component at the end']
    d_none = rows['creep D/none']
    assert (d_none.passed, d_none.cases, d_none.worst_value) == (1, 2, None)
    assert d_none.worst_case == 'never stays within the band: 190002 at 40.0 m/s'
    assert rows['creep C-spec/exact'].met and rows['creep C-spec/exact'].worst_value == 0.9
    damper = rows['IMM damper']
    assert (damper.passed, damper.worst_value, damper.met) == (0, 1.2, False)
    healthy = rows['IMM healthy']
    assert (healthy.passed, healthy.cases, healthy.met) == (2, 2, False)
    assert 'judged on 1 healthy min per car' in healthy.detail
    end = rows['IMM component at the end']
    assert (end.passed, end.cases) == (1, 2)
    assert end.worst_case == 'damper at 190001 at 35.0 m/s: ended none'


def test_scoreboard_of_files_run_with_other_settings_keeps_each(tmp_path: Path) -> None:
    """Fault runs and long nominal drives run with other timing: the merged header keeps each
    file's settings by the cases it ran (not the last file's for all), without the settings
    that only say where files were kept."""
    faults = tmp_path / 'faults.json'
    faults.write_text(json.dumps({'settings': {'fault_s': 150.0, 'sim_cache': '/tmp/x'},
                                  'commit': 'aaa', 'date': '2026-12-01', 'records': RECORDS}))
    nominal = tmp_path / 'nominal.json'
    nominal.write_text(json.dumps({'settings': {'fault_s': 1890.0}, 'commit': 'bbb',
                                   'date': '2026-12-02',
                                   'records': [_record(21002, 'nominal', nominal_s=1800.0)]}))
    records, header = tpms.load_records([faults, nominal])
    assert len(records) == 5 and (header['commit'], header['date']) == ('bbb', '2026-12-02')
    assert header['settings'] == {
        'diffusion20,puncture15,puncture25': {'fault_s': 150.0, 'sim_cache': '/tmp/x'},
        'nominal': {'fault_s': 1890.0}}
    out = tmp_path / 'tpms_family.json'
    tpms.write_scoreboard(out, records, header['commit'], header['date'], header['settings'])
    assert load_family_results(out).settings == {
        'diffusion20,puncture15,puncture25': {'fault_s': 150.0}, 'nominal': {'fault_s': 1890.0}}
    same = tpms.load_records([faults, faults])[1]['settings']
    assert same == {'fault_s': 150.0, 'sim_cache': '/tmp/x'}


def test_ring_scale_changes_only_the_ring() -> None:
    """``--ring-scale 0``: the same car and drive with a perfect ring (every other draw where it
    was); the default scale leaves the car as drawn."""
    settings = tpms.Settings(ring_scale=0.0)
    job = tpms.Job(21500, 'nominal', 'rural', settings)
    car, perfect = tpms.sample_car(21500), tpms.family_car(job)
    assert car.sensors.tooth_error_rms > 0.0 and perfect.sensors.tooth_error_rms == 0.0
    assert dataclasses.replace(perfect, sensors=car.sensors) == car
    assert tpms.family_car(tpms.Job(21500, 'nominal', 'rural', tpms.Settings())) == car
    runs = [tpms.simulate_scenario(tpms.car_scenario(c, 'rural', 1.0, [], seed=7, name='ring'))
            for c in (car, perfect)]
    assert np.abs(runs[0].tooth_error).max() > 0.0 and not runs[1].tooth_error.any()
    np.testing.assert_array_equal(runs[0].rim_speed, runs[1].rim_speed)
    assert not np.array_equal(runs[0].wheel_speed, runs[1].wheel_speed)


def test_each_case_is_observed_for_its_targets_window() -> None:
    """A run ends no sooner after its loss than its detection target allows (the diffusion's
    2 minutes: a warning at 90 s must be seen, not counted a miss); nominal drives and
    punctures drive on for the settings' time."""
    settings = tpms.Settings(observe_s=60.0)
    assert tpms.observed_s(tpms.Job(21500, 'diffusion20', 'rural', settings)) == 120.0
    assert tpms.observed_s(tpms.Job(21500, 'puncture15', 'rural', settings)) == 60.0
    assert tpms.observed_s(tpms.Job(21500, 'nominal', 'rural',
                                    tpms.Settings(observe_s=0.0))) == 0.0
    rows = _rows(tpms.scoreboard_rows(RECORDS))
    assert rows['fused: 20 % diffusion'].text.endswith('within 2 min of reaching it')
    assert tpms.DETECTION_LIMIT_S['diffusion20'] == 120.0


def test_method_settings_reach_the_observer_and_the_analyzer() -> None:
    """``--stiffness-set`` and ``--vibration-set`` values are the stiffness observer's and the
    vibration analyzer's parameters in every run, and change nothing else."""
    car = tpms.sample_car(21500)
    settings = tpms.Settings(stiffness_set={'forgetting_factor': 0.99, 'tooth_learning_s': 60.0},
                             vibration_set={'rel_noise_floor': 0.01})
    vibration, radius, stiffness = tpms.method_params(car, settings)
    assert (stiffness.forgetting_factor, stiffness.tooth_learning_s) == (0.99, 60.0)
    assert vibration.rel_noise_floor == 0.01
    default_vibration, default_radius, default = tpms.method_params(car, tpms.Settings())
    assert dataclasses.replace(stiffness, forgetting_factor=default.forgetting_factor,
                               tooth_learning_s=default.tooth_learning_s) == default
    assert dataclasses.replace(
        vibration, rel_noise_floor=default_vibration.rel_noise_floor) == default_vibration
    assert radius == default_radius


def test_beat_table_counts_held_period_cars_by_edge_beat(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    """``--beat-table``: healthy tires after calibration on cars with held tooth periods, by
    |e - round(e)| fs. A hand-made trace of tuning car 21500 (held periods): 10 ticks whose
    speed puts 1.005 edges in a sample (beat 5 Hz), FR confident on 4 of them, and 10 ticks at
    1.09 (90 Hz) with no confidence; FL is the faulty tire (left out), ticks before the
    calibration are left out. A window-average car's trace is skipped."""
    settings = tpms.Settings()
    held = tpms.family_car(tpms.Job(21500, 'puncture15', 'rural', settings))
    assert held.sensors.speed_method == 'tooth_period'
    radius = held.user_parameters()['nominal_radius_m']
    per_edge_rate = 2.0 * np.pi * 1000.0 / held.sensors.teeth * radius   # m/s at 1 edge/sample
    t = np.concatenate([np.full(5, 10.0), np.linspace(100.0, 140.0, 20)])
    speed = np.concatenate([np.full(5, 1.005), np.full(10, 1.005), np.full(10, 1.09)]) \
        * per_edge_rate
    conf = np.zeros((t.size, 4))
    conf[:5] = 1.0                       # before the calibration: not counted
    conf[5:9, 1] = 0.6                   # FR confident on 4 of the 10 ticks at a 5 Hz beat
    conf[5:, 0] = 1.0                    # FL, the faulty tire: not counted
    for seed, name in ((21500, 'held'), (21501, 'window')):
        job = tpms.Job(seed, 'puncture15', 'rural', settings)
        saved = {'job': dataclasses.asdict(job), 'tires': (0,), 'reached_s': 150.0,
                 'trace': {'t': t, 'speed': speed, 'conf': {'vibration': conf}}}
        (tmp_path / f'{name}.pkl').write_bytes(pickle.dumps(saved))
    assert tpms.family_car(tpms.Job(21501, 'puncture15', 'rural', settings)
                           ).sensors.speed_method == 'window_average'
    tpms.beat_table([tmp_path])
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith('1 runs with held tooth periods')
    ticks = lines[3].split('|')[2:-1]
    shares = lines[4].split('|')[2:-1]
    # 3 healthy tires x 10 ticks in the 0-10 Hz band and in the 80-100 Hz band
    assert [int(n) for n in ticks] == [30, 0, 0, 0, 0, 0, 0, 30, 0, 0]
    assert shares[0].strip() == '13.3 %' and shares[7].strip() == '0.0 %'


lateral = _load('eval_lateral_force_family')


def test_lateral_force_rows_count_cars_within_ten_percent(tmp_path: Path) -> None:
    """One row per case with rows: the cars whose worst wheel is under 10 %, the worst car; the
    row is met only when every car is; the file the main job reads round-trips."""
    rows = [{'seed': 21000, 'body': 'passenger', 'case': 'kim_huh', 'worst_percent': 9.9},
            {'seed': 21001, 'body': 'light_truck', 'case': 'kim_huh', 'worst_percent': 10.4},
            {'seed': 21000, 'body': 'passenger', 'case': 'rural', 'worst_percent': 3.0},
            {'seed': 21001, 'body': 'light_truck', 'case': 'rural', 'worst_percent': 6.8}]
    made = {row.target: row for row in lateral.scoreboard_rows(rows)}
    assert set(made) == {'lateral force kim_huh', 'lateral force rural'}
    kim = made['lateral force kim_huh']
    assert (kim.passed, kim.cases, kim.met) == (1, 2, False)
    assert kim.worst_value == 10.4 and kim.worst_case == '21001 light_truck'
    assert made['lateral force rural'].met
    path = tmp_path / 'lateral_force_family.json'
    lateral.write_scoreboard(path, {'seeds': [21000, 21001], 'split': 'tire', 'overrides': {},
                                    'date': '2026-12-06', 'rows': rows}, 'abc123')
    loaded = load_family_results(path)
    assert loaded.held_out and loaded.met_count() == 1 and loaded.commit == 'abc123'


def test_lateral_force_user_parameters() -> None:
    """The measured body is the car's; the data sheet keeps the defaults for what a data sheet
    does not give; the tire's split is its cornering stiffness exponent at the car's load."""
    car = lateral.car_family.sample_car(21500)
    measured = lateral.user_parameters(car, 'tire', 'measured')
    datasheet = lateral.user_parameters(car, '0.6', 'datasheet')
    default = lateral.ObserverVehicleParams()
    assert measured.iz == pytest.approx(car.vehicle.iz) and measured.m == pytest.approx(
        car.vehicle.m)
    assert datasheet.iz == default.iz and datasheet.kphi_f == default.kphi_f
    assert datasheet.m == pytest.approx(car.vehicle.m) and datasheet.split_exponent == 0.6
    assert measured.split_exponent == pytest.approx(lateral.split_exponent_from_tire(
        car.vehicle.tire.a4, car.vehicle.tire.a5, car.vehicle.m * 9.81 / 4.0))
