"""Magic Formula tire forces, pure and combined slip, vectorised over wheels. No ROS import.

Pure slip (Bakker, Nyborg & Pacejka 1987, "Tyre modelling for use in vehicle dynamics
studies", SAE 870421)::

    y(x) = D sin(C atan(B x - E (B x - atan(B x))))

with the load-dependent coefficients of that paper (Fz in kN, slip angle in degrees, slip
ratio in percent, force in N)::

    lateral:      D = a1 Fz^2 + a2 Fz, BCD = a3 sin(a4 atan(a5 Fz)),     E = a6 Fz^2 + a7 Fz + a8
    longitudinal: D = b1 Fz^2 + b2 Fz, BCD = (b3 Fz^2 + b4 Fz) e^-b5Fz, E = b6 Fz^2 + b7 Fz + b8

The default coefficients are the passenger-car tire set published in that paper (the set widely
reproduced as "Michelin MXV8"; C_y = 1.30, a1..a8 = -22.1, 1011, 1078, 1.82, 0.208, 0, -0.354,
0.707; C_x = 1.65, b1..b8 = -21.3, 1144, 49.6, 226, 0.069, -0.006, 0.056, 0.486). Camber and
the shifts S_h, S_v are zero: the road simulator has no camber and the tire is symmetric, so
the curves are odd in slip.

Combined slip: the cosine weighting functions of the Pacejka 2002 model (Pacejka, "Tire and
Vehicle Dynamics", 2nd ed. 2006, section 4.3.2), without shifts::

    Fx = G_xa Fx0(kappa),  G_xa = cos(C_xa atan(B_xa a - E_xa (B_xa a - atan(B_xa a))))
    Fy = G_yk Fy0(alpha),  G_yk = cos(C_yk atan(B_yk k - E_yk (B_yk k - atan(B_yk k))))
    B_xa = r_bx1 cos(atan(r_bx2 kappa)), B_yk = r_by1 cos(atan(r_by2 alpha)), C = r_cx1 / r_cy1,
    E = r_ex1 / r_ey1   (a = alpha, k = kappa)

(alpha in rad, kappa dimensionless). The weighting coefficients are the PAC2002 passenger-car
set of the CommonRoad vehicle models (Althoff et al., "CommonRoad: Vehicle Models",
parameters_vehicle1/2, from the MSC ADAMS tire handbook): r_bx1 13.276, r_bx2 -13.778,
r_cx1 1.2568, r_ex1 0.65225, r_by1 7.1433, r_by2 9.1916, r_cy1 1.0719, r_ey1 -0.27572.
The weights are clipped at 0 (with C > 1 the cosine would turn negative at very large
combined slip, a force reversal outside the model's fitted range), so |F| <= |F0| always.
Why the 2002 weighting and not the 1989 "similarity" rule: it needs no extra fit between the
two pure-slip curves, is the standard of today's MF-Tyre, and keeps combined <= pure by
construction.

Friction scale lambda (road surface, 1.1 dry ... 0.2 ice) multiplies D and leaves the slip
stiffness BCD unchanged (B = BCD / (C lambda D)), as the lambda_mu scaling of MF-Tyre:
a slippery road lowers the peak and moves it to smaller slip, not the initial slope. The
combined-slip weights are evaluated at kappa / lambda and alpha / lambda: their coefficients
were fitted on a dry road (lambda = 1), and the brush model (Pacejka 2006, ch. 3) says the
interaction of the two slips scales with slip relative to the sliding limit mu Fz / C. Without
this, on ice (peak slip five times smaller) both forces would reach their peaks at once and
the resultant would exceed the friction limit by up to ~40 %.

Signs (ISO/Pacejka): kappa = (omega r - vx) / |vx| (drive positive), alpha = -atan(vy / |vx|)
of the wheel-centre velocity in the wheel frame; Fx and Fy then have the sign of kappa and alpha.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
import math

import numpy as np

_DEG_PER_RAD = 180.0 / math.pi


@dataclass(frozen=True)
class MagicFormulaTire:
    """Coefficients of the pure-slip (BNP 1987) and combined-slip (PAC2002 weights) model.

    Pure-slip coefficients take Fz in kN, slip angle in degrees and slip ratio in percent,
    as in Bakker, Nyborg & Pacejka (1987); the combined weights take radians and ratio.
    """

    c_y: float = 1.30       # lateral shape factor C
    a1: float = -22.1       # lateral peak D = a1 Fz^2 + a2 Fz, N/kN^2
    a2: float = 1011.0      # N/kN
    a3: float = 1078.0      # cornering stiffness BCD = a3 sin(a4 atan(a5 Fz)), N/deg
    a4: float = 1.82        # -
    a5: float = 0.208       # 1/kN
    a6: float = 0.0         # lateral curvature E = a6 Fz^2 + a7 Fz + a8, 1/kN^2
    a7: float = -0.354      # 1/kN
    a8: float = 0.707       # -
    c_x: float = 1.65       # longitudinal shape factor C
    b1: float = -21.3       # longitudinal peak D = b1 Fz^2 + b2 Fz, N/kN^2
    b2: float = 1144.0      # N/kN
    b3: float = 49.6        # slip stiffness BCD = (b3 Fz^2 + b4 Fz) exp(-b5 Fz), N/%/kN^2
    b4: float = 226.0       # N/%/kN
    b5: float = 0.069       # 1/kN
    b6: float = -0.006      # longitudinal curvature E = b6 Fz^2 + b7 Fz + b8, 1/kN^2
    b7: float = 0.056       # 1/kN
    b8: float = 0.486       # -
    r_bx1: float = 13.276   # combined: Fx weight slope factor
    r_bx2: float = -13.778  # combined: variation of that slope with kappa
    r_cx1: float = 1.2568   # combined: Fx weight shape factor
    r_ex1: float = 0.65225  # combined: Fx weight curvature
    r_by1: float = 7.1433   # combined: Fy weight slope factor
    r_by2: float = 9.1916   # combined: variation of that slope with alpha
    r_cy1: float = 1.0719   # combined: Fy weight shape factor
    r_ey1: float = -0.27572  # combined: Fy weight curvature

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if not math.isfinite(value):
                raise ValueError(f'MagicFormulaTire.{f.name} must be finite, got {value}')
        for name in ('c_y', 'c_x', 'r_cx1', 'r_cy1'):
            value = getattr(self, name)
            if not 0.0 < value < 2.0:
                # C >= 2 makes sin(C atan(.)) change sign inside the slip range: no tire does.
                raise ValueError(f'MagicFormulaTire.{name} must be in (0, 2), got {value}')
        for name in ('a2', 'a3', 'b2', 'b4', 'r_bx1', 'r_by1'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'MagicFormulaTire.{name} must be > 0, got {getattr(self, name)}')
        for name in ('r_ex1', 'r_ey1'):
            if not getattr(self, name) < 1.0:
                raise ValueError(f'MagicFormulaTire.{name} must be < 1, got {getattr(self, name)}')

    def lateral_coefficients(
        self, fz: np.ndarray, friction_scale: np.ndarray | float = 1.0
    ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """(B, C, D, E) of the pure lateral curve at load fz (N), for alpha in degrees."""
        fz_kn = np.maximum(np.asarray(fz, dtype=float), 0.0) * 1e-3
        d = (self.a1 * fz_kn + self.a2) * fz_kn * friction_scale
        bcd = self.a3 * np.sin(self.a4 * np.arctan(self.a5 * fz_kn))
        e = (self.a6 * fz_kn + self.a7) * fz_kn + self.a8
        # Zero load gives D = BCD = 0; the floor keeps B finite (B D = 0 then anyway).
        b = bcd / (self.c_y * np.maximum(d, 1e-9))
        return b, self.c_y, d, e

    def longitudinal_coefficients(
        self, fz: np.ndarray, friction_scale: np.ndarray | float = 1.0
    ) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
        """(B, C, D, E) of the pure longitudinal curve at load fz (N), for kappa in percent."""
        fz_kn = np.maximum(np.asarray(fz, dtype=float), 0.0) * 1e-3
        d = (self.b1 * fz_kn + self.b2) * fz_kn * friction_scale
        bcd = (self.b3 * fz_kn + self.b4) * fz_kn * np.exp(-self.b5 * fz_kn)
        e = (self.b6 * fz_kn + self.b7) * fz_kn + self.b8
        b = bcd / (self.c_x * np.maximum(d, 1e-9))
        return b, self.c_x, d, e

    def cornering_stiffness(self, fz: np.ndarray | float) -> np.ndarray:
        """dFy/dalpha at alpha = 0, N/rad (independent of the friction scale)."""
        fz_kn = np.maximum(np.asarray(fz, dtype=float), 0.0) * 1e-3
        return self.a3 * np.sin(self.a4 * np.arctan(self.a5 * fz_kn)) * _DEG_PER_RAD

    def slip_stiffness(self, fz: np.ndarray | float) -> np.ndarray:
        """dFx/dkappa at kappa = 0, N per unit slip ratio (independent of the friction scale)."""
        fz_kn = np.maximum(np.asarray(fz, dtype=float), 0.0) * 1e-3
        return (self.b3 * fz_kn + self.b4) * fz_kn * np.exp(-self.b5 * fz_kn) * 100.0


def magic_formula(
    x: np.ndarray, b: np.ndarray | float, c: np.ndarray | float, d: np.ndarray | float,
    e: np.ndarray | float,
) -> np.ndarray:
    """The Magic Formula y = D sin(C atan(B x - E (B x - atan(B x))))."""
    bx = b * np.asarray(x, dtype=float)
    return d * np.sin(c * np.arctan(bx - e * (bx - np.arctan(bx))))


def pure_lateral_force(
    tire: MagicFormulaTire, alpha: np.ndarray, fz: np.ndarray,
    friction_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Pure-slip lateral force Fy0 (N) at slip angle alpha (rad) and load fz (N)."""
    b, c, d, e = tire.lateral_coefficients(fz, friction_scale)
    return magic_formula(np.asarray(alpha, dtype=float) * _DEG_PER_RAD, b, c, d, e)


def pure_longitudinal_force(
    tire: MagicFormulaTire, kappa: np.ndarray, fz: np.ndarray,
    friction_scale: np.ndarray | float = 1.0,
) -> np.ndarray:
    """Pure-slip longitudinal force Fx0 (N) at slip ratio kappa (-) and load fz (N)."""
    b, c, d, e = tire.longitudinal_coefficients(fz, friction_scale)
    return magic_formula(np.asarray(kappa, dtype=float) * 100.0, b, c, d, e)


def combined_weights(
    tire: MagicFormulaTire, kappa: np.ndarray, alpha: np.ndarray,
    friction_scale: np.ndarray | float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Cosine weights (G_xa on Fx0, G_yk on Fy0) of the PAC2002 combined-slip model, in [0, 1].

    The slips enter divided by the friction scale (see the module docstring).
    """
    kappa = np.asarray(kappa, dtype=float) / friction_scale
    alpha = np.asarray(alpha, dtype=float) / friction_scale
    # cos(atan(u)) = 1 / sqrt(1 + u^2): one ufunc fewer on the simulator's hot path.
    b_xa = tire.r_bx1 / np.sqrt(1.0 + (tire.r_bx2 * kappa) ** 2)
    b_yk = tire.r_by1 / np.sqrt(1.0 + (tire.r_by2 * alpha) ** 2)
    ba = b_xa * alpha
    bk = b_yk * kappa
    g_x = np.cos(tire.r_cx1 * np.arctan(ba - tire.r_ex1 * (ba - np.arctan(ba))))
    g_y = np.cos(tire.r_cy1 * np.arctan(bk - tire.r_ey1 * (bk - np.arctan(bk))))
    return np.maximum(g_x, 0.0), np.maximum(g_y, 0.0)


def combined_forces(
    tire: MagicFormulaTire, kappa: np.ndarray, alpha: np.ndarray, fz: np.ndarray,
    friction_scale: np.ndarray | float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Combined-slip (Fx, Fy) in the wheel frame, N, at slip ratio kappa and slip angle alpha.

    Args:
        tire: coefficient set.
        kappa: slip ratio, any shape broadcastable with the others.
        alpha: slip angle, rad.
        fz: vertical load, N (<= 0 gives zero force: wheel lifted).
        friction_scale: road friction scale on the peak force.

    Returns:
        (Fx, Fy), each of the broadcast shape.
    """
    g_x, g_y = combined_weights(tire, kappa, alpha, friction_scale)
    fx0 = pure_longitudinal_force(tire, kappa, fz, friction_scale)
    fy0 = pure_lateral_force(tire, alpha, fz, friction_scale)
    return g_x * fx0, g_y * fy0
