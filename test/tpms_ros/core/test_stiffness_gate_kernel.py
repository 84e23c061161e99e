"""The tire stiffness observer's compiled validity gates held to their numpy form.

``_gate_chunk`` replaced the numpy gates of ``TireStiffnessObserver._process`` (speed band,
acceleration, wheel torque, cornering, wheel slip, tooth learning, then the driven axles'
partner rule); the reference below is that implementation. The kernel makes the same
comparisons on the same arithmetic, so the codes and counts agree exactly.
"""

from __future__ import annotations

import numpy as np
import pytest

from tpms_ros.core.stiffness_observer import (
    _CODE,
    _EMPTY_1D,
    _EMPTY_2D,
    _STEERING_INVALID,
    _TORQUE_INVALID,
    AXLES,
    N_WHEELS,
    OK,
    REASONS,
    StiffnessObserverParams,
    _gate_chunk,
)


def numpy_gates(p: StiffnessObserverParams, axles: list[tuple[int, int]], lowpass: np.ndarray,
                previous: np.ndarray, good: np.ndarray, code: np.ndarray,
                torque: np.ndarray | None, steering: np.ndarray | None,
                learned: np.ndarray) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """(codes, counts) as the numpy gates set and counted them."""
    counts: dict[str, np.ndarray] = {}
    prev_low = np.concatenate((previous[None], lowpass[:-1]))
    accel = (lowpass - prev_low) * p.sample_rate_hz * p.rolling_radius_m
    speed_kmh = lowpass * p.rolling_radius_m * 3.6
    masked = np.where(good, lowpass, np.nan)
    ordered = np.sort(masked, axis=1)
    count = np.count_nonzero(np.isfinite(masked), axis=1)
    lo = np.clip((count - 1) // 2, 0, None)[:, None]
    hi = np.clip(count // 2, 0, N_WHEELS - 1)[:, None]
    mid = 0.5 * (np.take_along_axis(ordered, lo, axis=1)
                 + np.take_along_axis(ordered, hi, axis=1))[:, 0]
    ref = np.where(count > 0, mid, np.nan)[:, None]
    with np.errstate(invalid='ignore', divide='ignore'):
        slip = np.abs(lowpass / ref - 1.0)
    gates = [(_CODE['speed_band'],
              (speed_kmh < p.speed_band_kmh[0]) | (speed_kmh > p.speed_band_kmh[1])),
             (_CODE['acceleration'], np.abs(accel) > p.max_accel_mps2)]
    if torque is not None:
        torque_ok = np.isfinite(torque)
        counts['torque_invalid'] = (~torque_ok).sum(axis=0)
        gates.append((_CODE['wheel_torque'],
                      torque_ok & (np.abs(np.where(torque_ok, torque, 0.0))
                                   > p.max_wheel_torque_nm)))
    if steering is not None:
        steering_ok = np.isfinite(steering)
        counts['steering_invalid'] = np.full(N_WHEELS, np.count_nonzero(~steering_ok))
        speed_mps = ref[:, 0] * p.rolling_radius_m
        with np.errstate(invalid='ignore'):
            lateral = speed_mps ** 2 * np.abs(np.tan(np.where(steering_ok, steering, 0.0))
                                              ) / p.wheelbase_m
        gates.append((_CODE['cornering'],
                      np.broadcast_to((np.nan_to_num(lateral) > p.max_lateral_accel_mps2)
                                      [:, None], code.shape)))
    gates.append((_CODE['wheel_slip'], np.isfinite(slip) & (slip > p.max_slip)))
    gates.append((_CODE['tooth_learning'], ~learned))
    for gate_code, hit in gates:
        code = np.where((code == OK) & hit, gate_code, code)
    wheel_mask = code == OK
    for left, right in axles:
        both = wheel_mask[:, left] & wheel_mask[:, right]
        for w in (left, right):
            code[:, w] = np.where(wheel_mask[:, w] & ~both, _CODE['axle_partner'], code[:, w])
    for name in REASONS:
        counts[name] = (code == _CODE[name]).sum(axis=0)
    return code, counts


@pytest.mark.parametrize('driven', [('rear',), ('front',), ('front', 'rear')])
@pytest.mark.parametrize('inputs', ['none', 'torque', 'steering', 'both'])
def test_the_compiled_gates_are_the_numpy_gates(driven: tuple[str, ...], inputs: str) -> None:
    """Seeded speeds crossing every limit (the speed band, braking, wheel spin, a dead wheel,
    torque and steering with non-finite samples): the same codes and counts."""
    p = StiffnessObserverParams()
    rng = np.random.default_rng(len(driven) * 10 + len(inputs))
    n = 3000
    base = np.cumsum(rng.normal(0.0, 0.4, n)) + 60.0
    lowpass = base[:, None] * (1.0 + rng.normal(0.0, 0.03, (n, N_WHEELS)))
    lowpass[2000:2200] *= 0.1                         # below the speed band
    lowpass[2500:2600] *= 4.0                         # above it
    lowpass[rng.random((n, N_WHEELS)) < 0.01] = np.nan
    good = rng.random((n, N_WHEELS)) > 0.1
    good[1000:1100] = False                          # no good wheel: no reference
    code = np.where(rng.random((n, N_WHEELS)) < 0.05, _CODE['settling'], OK).astype(np.int64)
    learned = rng.random((n, N_WHEELS)) > 0.05
    torque = (rng.normal(0.0, 800.0, (n, N_WHEELS)) if inputs in ('torque', 'both') else None)
    steering = (rng.normal(0.0, 0.05, n) if inputs in ('steering', 'both') else None)
    if torque is not None:
        torque[rng.random((n, N_WHEELS)) < 0.02] = np.nan
    if steering is not None:
        steering[rng.random(n) < 0.02] = np.inf
    previous = lowpass[0].copy()
    axles = [AXLES[name] for name in driven]
    expected, counts = numpy_gates(p, axles, lowpass, previous, good, code.copy(), torque,
                                   steering, learned)
    tallies = np.zeros((len(REASONS) + 2, N_WHEELS), dtype=np.int64)
    limits = np.array([p.sample_rate_hz, p.rolling_radius_m, p.speed_band_kmh[0],
                       p.speed_band_kmh[1], p.max_accel_mps2, p.max_wheel_torque_nm,
                       p.max_lateral_accel_mps2, p.wheelbase_m, p.max_slip])
    _gate_chunk(lowpass, previous, good, code, _EMPTY_2D if torque is None else torque,
                _EMPTY_1D if steering is None else steering, learned, limits,
                np.array(axles, dtype=np.int64).reshape(-1, 2), tallies)
    np.testing.assert_array_equal(code, expected)
    for name in REASONS:
        np.testing.assert_array_equal(tallies[_CODE[name]], counts[name], err_msg=name)
    if torque is not None:
        np.testing.assert_array_equal(tallies[_TORQUE_INVALID], counts['torque_invalid'])
    if steering is not None:
        np.testing.assert_array_equal(tallies[_STEERING_INVALID], counts['steering_invalid'])
    # every gate fired somewhere
    fired = {REASONS[c] for c in np.unique(code)}
    assert {'speed_band', 'acceleration', 'wheel_slip', 'tooth_learning'} <= fired
    assert ('wheel_torque' in fired) == (torque is not None)
    assert ('cornering' in fired) == (steering is not None)
