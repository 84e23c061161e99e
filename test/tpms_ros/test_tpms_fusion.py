"""End-to-end TPMS fusion on the road simulator (issue 6): cores fed as their nodes feed them.

One seeded 220 s scenario (90 km/h, mild cornering, a speed dip): every method calibrates over
the first 90 s at placard pressure (the stiffness observer learns the encoder rings for 15 s
first), the car then drives 60 s more at nominal pressure (no warning allowed), and at 150 s
the front-left tire loses 25 % in 2 s (a puncture). The fused
voter must warn within 60 s, on that tire only. The replay is the one of
``benchmarks/eval_tpms_fusion.py`` (vibration blocks of 0.1 s, radius on 10 ms means closed at
the IMU stamps with held driver inputs, stiffness chunks of 0.25 s, voters at 10 Hz).
"""

from __future__ import annotations

from pathlib import Path
import sys

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / 'benchmarks'))

from eval_tpms_fusion import (  # noqa: E402
    BASE_SCENARIO,
    ReplayTraces,
    replay_methods,
    steer_amplitude_deg,
)

from tpms_ros.core.wheel_radius_analysis import bin_wheel_speeds, sample_and_hold  # noqa: E402
from tpms_ros.simulation.road_scenario import parse_scenario  # noqa: E402
from tpms_ros.simulation.road_simulator import simulate_scenario  # noqa: E402

CALIBRATION_END_S = 90.0
FAULT_S = 150.0
DURATION_S = 220.0


@pytest.fixture(scope='module')
def replay() -> ReplayTraces:
    """Simulate the puncture scenario once and replay it through the cores and voters."""
    base = yaml.safe_load(BASE_SCENARIO.read_text())
    doc = {key: base[key] for key in ('vehicle', 'tire', 'drive', 'sensors', 'rates')
           if key in base}
    doc.update({
        'name': 'fusion_test', 'seed': 77, 'duration_s': DURATION_S,
        'speed': {'initial_kmh': 90.0, 'segments': [
            {'type': 'hold', 'duration_s': 30.0},
            {'type': 'ramp', 'to_kmh': 76.0, 'duration_s': 10.0},
            {'type': 'ramp', 'to_kmh': 90.0, 'duration_s': 10.0}]},
        'steering': {'segments': [{'type': 'sine', 'duration_s': DURATION_S,
                                   'amplitude_deg': steer_amplitude_deg(90.0),
                                   'frequency_hz': 0.04}]},
        'events': [{'type': 'pressure_step', 'at_s': FAULT_S, 'tires': ['FL'],
                    'drop_percent': 25.0, 'duration_s': 2.0}],
    })
    result = simulate_scenario(parse_scenario(yaml.safe_dump(doc), '<fusion_test>'))
    return replay_methods(result, calibration_end_s=CALIBRATION_END_S)


def test_nominal_driving_gives_no_warning(replay: ReplayTraces) -> None:
    """Between calibration and the puncture (60 s of nominal driving) nothing is warned, and
    every method calibrated and knows all tires by the end of its calibration."""
    assert replay.calibration_errors == {}
    nominal = (replay.t >= CALIBRATION_END_S) & (replay.t < FAULT_S)
    for name, warning in replay.warnings.items():
        assert not warning[nominal].any(), name
    for method in ('vibration', 'wheel_radius'):
        assert replay.known[method][nominal].all(), method


def test_puncture_warned_by_fusion_within_60_s_on_the_right_tire(replay: ReplayTraces) -> None:
    """A 25 % FL puncture is warned by the fused voter within 60 s; only FL is ever warned."""
    after = replay.t >= FAULT_S
    fused = replay.warnings['fused']
    warned = fused[after, 0]
    assert warned.any()
    first = float(replay.t[after][np.argmax(warned)]) - FAULT_S
    assert first <= 60.0
    assert fused[-1].tolist() == [True, False, False, False]
    assert not fused[:, 1:].any()


def test_alignment_helpers_match_the_node_rules() -> None:
    """Bin means cover (previous end, end] at most one bin long and NaN a wheel with a bad
    sample; the hold takes the newest value not newer than the query, NaN when stale."""
    stamps = np.arange(1, 41) * 1e-3                                 # 1 kHz, 1..40 ms
    omega = np.tile(np.arange(1.0, 41.0)[:, None], (1, 4))
    omega[15, 2] = np.nan                                            # bad sample at 16 ms
    ends = np.array([0.010, 0.020, 0.0455])
    means = bin_wheel_speeds(stamps, omega, ends, 0.01, 600.0)
    np.testing.assert_allclose(means[0], 5.5)                       # samples 1..10
    assert np.isnan(means[1, 2]) and means[1, 0] == pytest.approx(15.5)
    np.testing.assert_allclose(means[2], 38.0)                      # (35.5, 45.5] ms: 36..40
    held = sample_and_hold(np.array([0.0, 0.05]), np.array([1.0, 2.0]),
                           np.array([-0.01, 0.04, 0.05, 0.2]), 0.1)
    assert np.isnan(held[0]) and held[1] == 1.0 and held[2] == 2.0 and np.isnan(held[3])
