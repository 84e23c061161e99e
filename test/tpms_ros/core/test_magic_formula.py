"""Tests of the Magic Formula tire (pure and combined slip) against the published coefficients."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from tpms_ros.core.magic_formula import (
    MagicFormulaTire,
    combined_forces,
    combined_weights,
    magic_formula,
    pure_lateral_force,
    pure_longitudinal_force,
)

TIRE = MagicFormulaTire()

# Bakker, Nyborg & Pacejka (1987) passenger-car set, typed in again here so the test does not
# trust the module's defaults: lateral (Fz kN, alpha deg) and longitudinal (Fz kN, kappa %).
C_Y, A = 1.30, (-22.1, 1011.0, 1078.0, 1.82, 0.208, 0.0, -0.354, 0.707)
C_X, B = 1.65, (-21.3, 1144.0, 49.6, 226.0, 0.069, -0.006, 0.056, 0.486)
# PAC2002 combined-slip weights (CommonRoad / ADAMS set).
R_BX1, R_BX2, R_CX1, R_EX1 = 13.276, -13.778, 1.2568, 0.65225
R_BY1, R_BY2, R_CY1, R_EY1 = 7.1433, 9.1916, 1.0719, -0.27572


def _ref_fy0(alpha_rad: float, fz_n: float, lam: float = 1.0) -> float:
    """Scalar reference lateral force from the 1987 formulas."""
    fz = fz_n / 1000.0
    a1, a2, a3, a4, a5, a6, a7, a8 = A
    d = (a1 * fz**2 + a2 * fz) * lam
    bcd = a3 * math.sin(a4 * math.atan(a5 * fz))
    b = bcd / (C_Y * d)
    e = a6 * fz**2 + a7 * fz + a8
    x = math.degrees(alpha_rad)
    phi = (1.0 - e) * x + (e / b) * math.atan(b * x)  # the paper's own form of the formula
    return d * math.sin(C_Y * math.atan(b * phi))


def _ref_fx0(kappa: float, fz_n: float, lam: float = 1.0) -> float:
    """Scalar reference longitudinal force from the 1987 formulas."""
    fz = fz_n / 1000.0
    b1, b2, b3, b4, b5, b6, b7, b8 = B
    d = (b1 * fz**2 + b2 * fz) * lam
    bcd = (b3 * fz**2 + b4 * fz) * math.exp(-b5 * fz)
    b = bcd / (C_X * d)
    e = b6 * fz**2 + b7 * fz + b8
    x = 100.0 * kappa
    phi = (1.0 - e) * x + (e / b) * math.atan(b * x)
    return d * math.sin(C_X * math.atan(b * phi))


def _ref_weight(slip: float, other: float, b1: float, b2: float, c: float, e: float) -> float:
    """Scalar PAC2002 cosine weight (no shifts), clipped at 0."""
    b = b1 * math.cos(math.atan(b2 * other))
    bs = b * slip
    return max(math.cos(c * math.atan(bs - e * (bs - math.atan(bs)))), 0.0)


@pytest.mark.parametrize('fz', [2000.0, 4000.0, 6500.0])
@pytest.mark.parametrize('alpha_deg', [0.5, 2.0, 6.0, 15.0])
def test_pure_lateral_matches_reference(fz: float, alpha_deg: float) -> None:
    """Fy0 equals the 1987 formula with the published coefficients at reference points."""
    alpha = math.radians(alpha_deg)
    got = float(pure_lateral_force(TIRE, np.array([alpha]), np.array([fz]))[0])
    assert got == pytest.approx(_ref_fy0(alpha, fz), rel=1e-12)


@pytest.mark.parametrize('fz', [2000.0, 4000.0, 6500.0])
@pytest.mark.parametrize('kappa', [0.005, 0.03, 0.12, 0.6])
def test_pure_longitudinal_matches_reference(fz: float, kappa: float) -> None:
    """Fx0 equals the 1987 formula with the published coefficients at reference points."""
    got = float(pure_longitudinal_force(TIRE, np.array([kappa]), np.array([fz]))[0])
    assert got == pytest.approx(_ref_fx0(kappa, fz), rel=1e-12)


def test_reference_point_values() -> None:
    """A hand-checked anchor: at 4 kN the lateral peak D is 3689.6 N and the slip stiffness
    BCD is 1288 N/% (values computed by hand from the 1987 table)."""
    _, _, d_y, _ = TIRE.lateral_coefficients(np.array([4000.0]))
    assert float(d_y[0]) == pytest.approx(-22.1 * 16 + 1011 * 4, rel=1e-12)
    assert float(TIRE.slip_stiffness(4000.0)) == pytest.approx(
        (49.6 * 16 + 226 * 4) * math.exp(-0.069 * 4) * 100, rel=1e-12)
    assert float(TIRE.slip_stiffness(4000.0)) == pytest.approx(128_800, rel=1e-3)


@pytest.mark.parametrize('kappa, alpha_deg, fz', [
    (0.02, 2.0, 4000.0), (0.1, 5.0, 3000.0), (-0.05, -3.0, 6000.0), (0.3, 8.0, 4500.0),
    (-0.6, 1.0, 5000.0),
])
def test_combined_matches_reference(kappa: float, alpha_deg: float, fz: float) -> None:
    """Combined Fx, Fy equal the cosine-weighted pure forces computed independently here."""
    alpha = math.radians(alpha_deg)
    fx, fy = combined_forces(TIRE, np.array([kappa]), np.array([alpha]), np.array([fz]))
    gx = _ref_weight(alpha, kappa, R_BX1, R_BX2, R_CX1, R_EX1)
    gy = _ref_weight(kappa, alpha, R_BY1, R_BY2, R_CY1, R_EY1)
    assert float(fx[0]) == pytest.approx(gx * _ref_fx0(kappa, fz), rel=1e-12)
    assert float(fy[0]) == pytest.approx(gy * _ref_fy0(alpha, fz), rel=1e-12)
    assert 0.0 < gx < 1.0 and 0.0 < gy < 1.0


def test_odd_symmetry() -> None:
    """Pure and combined forces are odd in their own slip (symmetric tire, no shifts)."""
    rng = np.random.default_rng(3)
    kappa = rng.uniform(-0.5, 0.5, 200)
    alpha = rng.uniform(-0.3, 0.3, 200)
    fz = rng.uniform(1000.0, 8000.0, 200)
    fx, fy = combined_forces(TIRE, kappa, alpha, fz)
    fx_m, fy_m = combined_forces(TIRE, -kappa, -alpha, fz)
    np.testing.assert_allclose(fx_m, -fx, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(fy_m, -fy, rtol=1e-12, atol=1e-9)
    fx_k, fy_k = combined_forces(TIRE, kappa, -alpha, fz)  # flipping only alpha flips only Fy
    np.testing.assert_allclose(fx_k, fx, rtol=1e-12)
    np.testing.assert_allclose(fy_k, -fy, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize('fz', [3000.0, 5000.0])
def test_peak_position_and_height(fz: float) -> None:
    """The force peaks at D where C atan(B x - E(B x - atan B x)) = pi/2, inside the usual
    passenger-car ranges (lateral 4-12 deg, longitudinal 8-25 %)."""
    for coeffs, scale, lo, hi, force in (
        (TIRE.lateral_coefficients(fz), 180.0 / math.pi, 4.0, 12.0, pure_lateral_force),
        (TIRE.longitudinal_coefficients(fz), 100.0, 8.0, 25.0, pure_longitudinal_force),
    ):
        b, c, d, e = (float(np.asarray(v)) for v in coeffs)
        def shape(x: float, b: float = b, c: float = c, e: float = e) -> float:
            return c * math.atan(b * x - e * (b * x - math.atan(b * x))) - math.pi / 2

        x_peak = brentq(shape, 1e-6, 100.0)
        assert lo < x_peak < hi
        grid = np.linspace(0.0, 2.0 * x_peak, 20001) / scale
        values = force(TIRE, grid, np.full(grid.shape, fz))
        assert grid[np.argmax(values)] * scale == pytest.approx(x_peak, abs=2e-3 * x_peak)
        assert values.max() == pytest.approx(d, rel=1e-9)


def test_combined_never_exceeds_pure() -> None:
    """|Fx| <= |Fx0| and |Fy| <= |Fy0| on a grid of slips, loads and friction scales, and the
    resultant stays within 6 % of the larger pure peak (no friction-circle violation)."""
    kappa, alpha = np.meshgrid(np.linspace(-1.0, 1.0, 161), np.linspace(-0.5, 0.5, 161))
    for lam in (1.1, 0.6, 0.2):
        for fz in (1500.0, 4000.0, 7500.0):
            fx, fy = combined_forces(TIRE, kappa, alpha, fz, lam)
            fx0 = pure_longitudinal_force(TIRE, kappa, fz, lam)
            fy0 = pure_lateral_force(TIRE, alpha, fz, lam)
            assert np.all(np.abs(fx) <= np.abs(fx0) + 1e-9)
            assert np.all(np.abs(fy) <= np.abs(fy0) + 1e-9)
            d_max = max(float(TIRE.longitudinal_coefficients(fz, lam)[2]),
                        float(TIRE.lateral_coefficients(fz, lam)[2]))
            assert np.hypot(fx, fy).max() <= 1.06 * d_max


def test_friction_scale_scales_peak_not_stiffness() -> None:
    """The friction scale multiplies the peak and keeps the slope at zero slip."""
    fz = np.array([4000.0])
    small = 1e-6
    for lam in (1.1, 0.2):
        slope_y = pure_lateral_force(TIRE, np.array([small]), fz, lam)[0] / small
        slope_x = pure_longitudinal_force(TIRE, np.array([small]), fz, lam)[0] / small
        assert slope_y == pytest.approx(float(TIRE.cornering_stiffness(4000.0)), rel=1e-6)
        assert slope_x == pytest.approx(float(TIRE.slip_stiffness(4000.0)), rel=1e-6)
        peak = pure_lateral_force(TIRE, np.linspace(0, 0.4, 4001), np.full(4001, 4000.0), lam)
        assert peak.max() == pytest.approx(lam * (-22.1 * 16 + 1011 * 4), rel=1e-6)


def test_weights_use_slip_relative_to_friction() -> None:
    """On a road with scale lambda the weights equal the dry-road weights at slip / lambda."""
    gx, gy = combined_weights(TIRE, np.array([0.01]), np.array([0.02]), 0.2)
    gx1, gy1 = combined_weights(TIRE, np.array([0.05]), np.array([0.1]), 1.0)
    assert float(gx[0]) == pytest.approx(float(gx1[0]), rel=1e-12)
    assert float(gy[0]) == pytest.approx(float(gy1[0]), rel=1e-12)


def test_zero_and_negative_load_give_zero_force() -> None:
    """A lifted wheel (Fz <= 0) transmits nothing and yields no NaN."""
    fx, fy = combined_forces(TIRE, np.array([0.1, 0.1]), np.array([0.05, 0.05]),
                             np.array([0.0, -500.0]))
    assert np.all(fx == 0.0) and np.all(fy == 0.0)


def test_magic_formula_generic_is_the_formula() -> None:
    """The generic y(x) equals D sin(C atan(Bx - E(Bx - atan Bx))) for scalar inputs."""
    x, b, c, d, e = 0.7, 1.3, 1.5, 2.0, -0.4
    expected = d * math.sin(c * math.atan(b * x - e * (b * x - math.atan(b * x))))
    assert float(magic_formula(np.array(x), b, c, d, e)) == pytest.approx(expected, rel=1e-14)


@pytest.mark.parametrize('field_name, value', [
    ('c_y', 2.5), ('c_x', 0.0), ('a2', -1.0), ('b4', 0.0), ('r_ex1', 1.0), ('a3', float('nan')),
])
def test_invalid_coefficients_raise(field_name: str, value: float) -> None:
    """Non-physical coefficients are refused with the field's name."""
    with pytest.raises(ValueError, match=field_name):
        MagicFormulaTire(**{field_name: value})
