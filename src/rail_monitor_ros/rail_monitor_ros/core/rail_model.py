"""Linear lateral rail vehicle models: the one source of the model matrices.

The rail simulator integrates the 14-DOF full car as truth; the IMM suspension monitor
(docs/methods/suspension_monitor.md)
and the creep-factor EKF (docs/methods/creep_estimator.md) build their estimation models from the
same functions with
their own parameters. No ROS import.

Equations (docs/methods/creep_estimator.md, Chonan & Tsunashima, signs restored; x forward, y
left, yaw counter-clockwise
seen from above). Wheelset i under bogie j, leading (s_i = +1) or trailing (s_i = -1)::

    mw y_wi''  = -(2 c f22 / v) y_wi' + 2 c f22 psi_wi - Ky (y_wi - y_bj - s_i a0 psi_bj)
    Iw psi_wi'' = -(2 c f11 l0^2 / v) psi_wi' - (2 c f11 lam l0 / r0)(y_wi - y_ri)
                  - Kp (psi_wi - psi_bj)
    mb y_bj''  = Ky (y_w,lead + y_w,trail - 2 y_bj) - Ksy (y_bj - y_v,j) - Csy (y_bj' - y_v,j')
    Ib psi_bj'' = Ky a0 (y_w,lead - y_w,trail - 2 a0 psi_bj) + Kp (psi_w,lead + psi_w,trail
                  - 2 psi_bj) - Cpsi (psi_bj' - psi_v')

with y_v,j the body's lateral displacement above bogie j: y_v in the half car, y_v + sigma_j lv
psi_v in the full car (sigma = +1 front, -1 rear bogie). The half car has no body yaw, so its
anti-yaw damper acts against the track frame. Ksy = Kylb + Kyrb and Csy = Cylb + Cyrb are
multiplied by the spring and damper ratios (the IMM's fault modes), f11 and f22 by the creep
factor c. Track lateral alignment y_ri enters only through the yaw creep moment, so its rate is
not an input.

Assembly: every spring and damper is written as a connection vector g over the displacement
coordinates q (its elongation is g . q), so K += k g g^T gives the forces on both ends and the
moments from the lever arms consistently; the creep terms are added directly (they are not
symmetric). Then x = [q_1, q_1', q_2, q_2', ...].
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
import math

import numpy as np
import scipy.linalg

from vehicle_monitor_common.parameters import param

# Manchester Benchmarks passenger coach (Iwnicki 1998, Vehicle System Dynamics 30(3-4),
# 295-313): body 32 000 kg with yaw inertia 1.97e6 kg m^2, bogie centres 19 m apart. The paper's
# half car carries mv = 11 000 kg per bogie, so the full car body is 22 000 kg; its yaw inertia
# keeps the benchmark's yaw radius of gyration sqrt(1.97e6 / 32 000) = 7.85 m.
_MANCHESTER_BODY_MASS = 32000.0
_MANCHESTER_BODY_YAW_INERTIA = 1.97e6
_MANCHESTER_BOGIE_PIVOT_SEMI_SPACING = 9.5
# The models' speed range, m/s (vehicle.speed's, and a published speed's: rail/speed).
MAX_SPEED_MPS = 150.0
# Relative speed step of the central differences of a model in speed (dA/dv: the creep EKF's
# and the suspension IMM's transitions stepped to a sample's speed). A is smooth in v (the creep
# coefficients' 1/v, the track's poles, the Pade sections), so the difference's error, ~1e-7 of
# dA/dv, stays below the first-order step's own.
SPEED_DIFFERENCE = 1e-3
_TABLE_1_BODY_MASS = 11000.0     # mv, the paper's body mass per bogie


@dataclass(frozen=True)
class RailVehicleParams:
    """Lateral model parameters of a two-bogie passenger car (docs/methods/creep_estimator.md
    Table 1).

    Defaults: Chonan & Tsunashima Table 1; body yaw inertia and bogie pivot semi-spacing from
    the Manchester Benchmarks passenger coach (Iwnicki 1998), which the paper does not give.
    Each field's symbol, unit and range are its :func:`param` declaration (a node exposes them
    as a parameter group); all are read-only on a running node but the speed. The names keep
    the paper's quantities without unit suffixes (the unit is in each description): the
    simulator's scenario files, the IMM and the estimators share them.
    """

    wheelset_mass: float = param(1250.0, 'mw, wheelset mass, kg', low=1.0, high=1e5,
                                 read_only=True)
    wheelset_yaw_inertia: float = param(700.0, 'Iw, wheelset yaw inertia, kg m^2', low=1.0,
                                        high=1e5, read_only=True)
    bogie_mass: float = param(2500.0, 'mb, bogie mass, kg', low=1.0, high=1e5, read_only=True)
    bogie_yaw_inertia: float = param(2300.0, 'Ib, bogie yaw inertia, kg m^2', low=1.0,
                                     high=1e6, read_only=True)
    body_mass: float = param(_TABLE_1_BODY_MASS, 'mv, body mass carried by one bogie (the half '
                             'car body; the full car body is twice this), kg', low=1.0,
                             high=1e6, read_only=True)
    body_yaw_inertia: float = param(
        _MANCHESTER_BODY_YAW_INERTIA / _MANCHESTER_BODY_MASS * 2.0 * _TABLE_1_BODY_MASS,
        'full car body yaw inertia, kg m^2', low=1.0, high=1e8, read_only=True)
    primary_lateral_stiffness: float = param(4000e3, 'Ky, primary lateral stiffness per '
                                             'wheelset, N/m', low=1.0, high=1e9, read_only=True)
    primary_yaw_stiffness: float = param(2500e3, 'Kp, primary yaw stiffness per wheelset, '
                                         'N m/rad', low=1.0, high=1e9, read_only=True)
    secondary_lateral_stiffness_left: float = param(500e3, 'Kylb, secondary lateral stiffness '
                                                    'per bogie, left, N/m', low=1.0, high=1e9,
                                                    read_only=True)
    secondary_lateral_stiffness_right: float = param(500e3, 'Kyrb, secondary lateral '
                                                     'stiffness per bogie, right, N/m', low=1.0,
                                                     high=1e9, read_only=True)
    secondary_lateral_damping_left: float = param(30e3, 'Cylb, secondary lateral damping per '
                                                  'bogie, left, N s/m', low=0.0, high=1e8,
                                                  read_only=True)
    secondary_lateral_damping_right: float = param(30e3, 'Cyrb, secondary lateral damping per '
                                                   'bogie, right, N s/m', low=0.0, high=1e8,
                                                   read_only=True)
    anti_yaw_damping_left: float = param(500e3, 'anti-yaw damping per bogie, left, N m s/rad',
                                         low=0.0, high=1e8, read_only=True)
    anti_yaw_damping_right: float = param(500e3, 'anti-yaw damping per bogie, right, '
                                          'N m s/rad', low=0.0, high=1e8, read_only=True)
    longitudinal_creep_coefficient: float = param(7.44e6, 'f11, nominal longitudinal creep '
                                                  'coefficient, N', low=1.0, high=1e9,
                                                  read_only=True)
    lateral_creep_coefficient: float = param(6.79e6, 'f22, nominal lateral creep coefficient, '
                                             'N', low=1.0, high=1e9, read_only=True)
    semi_wheelbase: float = param(1.05, 'a0, half the bogie wheelbase, m', low=0.1, high=10.0,
                                  read_only=True)
    half_gauge: float = param(0.75, 'l0, half the contact-point distance, m', low=0.1,
                              high=2.0, read_only=True)
    conicity: float = param(0.15, 'lambda, effective wheel conicity, 1', low=1e-3, high=1.0,
                            read_only=True)
    wheel_radius: float = param(0.37, 'r0, wheel rolling radius, m', low=0.1, high=2.0,
                                read_only=True)
    speed: float = param(40.0, 'v, forward speed, m/s (settable at runtime; the nodes follow '
                         'rail/speed instead when it is published)', low=1.0, high=MAX_SPEED_MPS)
    bogie_pivot_semi_spacing: float = param(_MANCHESTER_BOGIE_PIVOT_SEMI_SPACING,
                                            'lv, body centre to bogie centre, m', low=0.1,
                                            high=50.0, read_only=True)

    # Damping may be zero (a failed or absent damper); everything else must be positive.
    _MAY_BE_ZERO = frozenset({
        'secondary_lateral_damping_left', 'secondary_lateral_damping_right',
        'anti_yaw_damping_left', 'anti_yaw_damping_right'})

    def __post_init__(self) -> None:
        for spec in fields(self):
            value = getattr(self, spec.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f'RailVehicleParams.{spec.name} must be a number, got {value!r}')
            if not math.isfinite(value):
                raise ValueError(f'RailVehicleParams.{spec.name} must be finite, got {value}')
            if spec.name in self._MAY_BE_ZERO:
                if value < 0.0:
                    raise ValueError(f'RailVehicleParams.{spec.name} must be >= 0, got {value}')
            elif value <= 0.0:
                raise ValueError(f'RailVehicleParams.{spec.name} must be > 0, got {value}')

    @property
    def secondary_lateral_stiffness(self) -> float:
        """Ksy = Kylb + Kyrb, nominal, per bogie, N/m."""
        return self.secondary_lateral_stiffness_left + self.secondary_lateral_stiffness_right

    @property
    def secondary_lateral_damping(self) -> float:
        """Csy = Cylb + Cyrb, nominal, per bogie, N s/m."""
        return self.secondary_lateral_damping_left + self.secondary_lateral_damping_right

    @property
    def anti_yaw_damping(self) -> float:
        """Cpsi, both anti-yaw dampers of one bogie, N m s/rad."""
        return self.anti_yaw_damping_left + self.anti_yaw_damping_right

    @property
    def full_body_mass(self) -> float:
        """Full car body mass, 2 mv, kg."""
        return 2.0 * self.body_mass

    @property
    def wheelset_offsets(self) -> np.ndarray:
        """(4,) distance of each full-car wheelset behind the leading one, m (front to rear)."""
        a0, lv = self.semi_wheelbase, self.bogie_pivot_semi_spacing
        return np.array([0.0, 2.0 * a0, 2.0 * lv, 2.0 * lv + 2.0 * a0])

    def with_speed(self, speed: float) -> RailVehicleParams:
        """The same vehicle at another forward speed (validated)."""
        return replace(self, speed=float(speed))


@dataclass(frozen=True)
class StateSpace:
    """Continuous linear model x' = A x + B u, y = C x + D u with named signals.

    Attributes:
        a: (n, n) state matrix.
        b: (n, m) input matrix.
        c: (p, n) output matrix.
        d: (p, m) feedthrough matrix.
        state_names: n names, e.g. ``'y_b'``, ``'dy_b'`` (rate), ``'psi_w1'``.
        input_names: m names.
        output_names: p names.
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]

    def discretize(self, dt: float) -> DiscreteStateSpace:
        """Zero-order-hold discretisation (exact for inputs constant over each step)."""
        f, g = discretize_zoh(self.a, self.b, dt)
        return DiscreteStateSpace(self, f, g, float(dt))

    def state_index(self, name: str) -> int:
        """Index of a named state; ValueError naming it when absent."""
        try:
            return self.state_names.index(name)
        except ValueError:
            raise ValueError(f'unknown state {name!r}; states: {self.state_names}') from None


@dataclass(frozen=True)
class DiscreteStateSpace:
    """x[k+1] = F x[k] + G u[k], y[k] = H x[k] + L u[k] (the papers' notation, eq. 9-10): the
    zero-order-hold discretisation of a continuous model, whose output equation (H = C, L = D)
    and signal names stay those of the continuous model.

    Attributes:
        continuous: the model discretised.
        f: (n, n) transition matrix.
        g: (n, m) input matrix.
        dt: sample period, s.
    """

    continuous: StateSpace
    f: np.ndarray
    g: np.ndarray
    dt: float

    @property
    def h(self) -> np.ndarray:
        """(p, n) output matrix."""
        return self.continuous.c

    @property
    def l(self) -> np.ndarray:  # noqa: E743 - the papers' name for the feedthrough
        """(p, m) feedthrough matrix."""
        return self.continuous.d


def discretize_zoh(a: np.ndarray, b: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Zero-order-hold (F, G) = (e^{A dt}, int_0^dt e^{A s} ds B) from one matrix exponential.

    Args:
        a: (n, n) continuous state matrix.
        b: (n, m) continuous input matrix.
        dt: step, s, > 0.

    Returns:
        F (n, n) and G (n, m).
    """
    a, b = _check_ab(a, b)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be finite and > 0, got {dt}')
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    phi = scipy.linalg.expm(block * dt)
    return phi[:n, :n], phi[:n, n:]


def discretize_zoh_sensitivity(
    a: np.ndarray, b: np.ndarray, da: np.ndarray, db: np.ndarray, dt: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """ZOH (F, G) and their exact derivatives (dF, dG) along a parameter direction (dA, dB).

    For the augmented-state EKF: with A(c) = A0 + c dA and B(c) = c dB (the creep factor enters
    linearly, see :func:`half_car_creep_sensitivity`), dF/dc and dG/dc are the Frechet
    derivative of the matrix exponential, not a finite difference.

    Returns:
        F, G, dF, dG.
    """
    a, b = _check_ab(a, b)
    da, db = _check_ab(da, db)
    if da.shape != a.shape or db.shape != b.shape:
        raise ValueError('da and db must have the shapes of a and b')
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be finite and > 0, got {dt}')
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n] = a
    block[:n, n:] = b
    dblock = np.zeros_like(block)
    dblock[:n, :n] = da
    dblock[:n, n:] = db
    phi, dphi = scipy.linalg.expm_frechet(block * dt, dblock * dt)
    return phi[:n, :n], phi[:n, n:], dphi[:n, :n], dphi[:n, n:]


def _check_ab(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    if a.ndim != 2 or a.shape[0] != a.shape[1]:
        raise ValueError(f'a must be square, got shape {a.shape}')
    if b.ndim != 2 or b.shape[0] != a.shape[0]:
        raise ValueError(f'b must have {a.shape[0]} rows, got shape {b.shape}')
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ValueError('a and b must be finite')
    return a, b


def _check_ratio(name: str, value: float, upper: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and 0.0 < value <= upper):
        raise ValueError(f'{name} must be in (0, {upper}], got {value}')
    return value


# Upper bounds of the sane range of the multipliers (contract: ratios outside a sane range
# refused).
MAX_SUSPENSION_RATIO = 5.0
MAX_CREEP_FACTOR = 2.0


class _Assembly:
    """M q'' + C q' + K q = E u over named displacement coordinates q."""

    def __init__(self, coordinates: Sequence[str], inputs: Sequence[str]) -> None:
        self.coordinates = tuple(coordinates)
        self.inputs = tuple(inputs)
        n = len(self.coordinates)
        self.mass = np.zeros(n)
        self.k = np.zeros((n, n))
        self.c = np.zeros((n, n))
        self.e = np.zeros((n, len(self.inputs)))

    def idx(self, name: str) -> int:
        return self.coordinates.index(name)

    def connection(self, terms: dict[str, float]) -> np.ndarray:
        g = np.zeros(len(self.coordinates))
        for name, coefficient in terms.items():
            g[self.idx(name)] += coefficient
        return g

    def spring(self, stiffness: float, terms: dict[str, float]) -> None:
        g = self.connection(terms)
        self.k += stiffness * np.outer(g, g)

    def damper(self, damping: float, terms: dict[str, float]) -> None:
        g = self.connection(terms)
        self.c += damping * np.outer(g, g)

    def wheelset_creep(self, p: RailVehicleParams, creep_factor: float, wheelset: str,
                       track_input: str) -> None:
        """Linear creep forces of one wheelset (docs/methods/creep_estimator.md eq. for y_wi and
        psi_wi)."""
        v = p.speed
        f11 = creep_factor * p.longitudinal_creep_coefficient
        f22 = creep_factor * p.lateral_creep_coefficient
        y, psi = self.idx(f'y_{wheelset}'), self.idx(f'psi_{wheelset}')
        yaw_creep_stiffness = 2.0 * f11 * p.conicity * p.half_gauge / p.wheel_radius
        self.c[y, y] += 2.0 * f22 / v
        self.k[y, psi] -= 2.0 * f22
        self.c[psi, psi] += 2.0 * f11 * p.half_gauge ** 2 / v
        self.k[psi, y] += yaw_creep_stiffness
        self.e[psi, self.inputs.index(track_input)] += yaw_creep_stiffness

    def state_space(self) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
        """(A, B, state names) with x = [q_1, q_1', q_2, q_2', ...]."""
        n = len(self.coordinates)
        inv_m = 1.0 / self.mass
        a = np.zeros((2 * n, 2 * n))
        b = np.zeros((2 * n, len(self.inputs)))
        pos = np.arange(n) * 2
        vel = pos + 1
        a[pos, vel] = 1.0
        a[np.ix_(vel, pos)] = -inv_m[:, None] * self.k
        a[np.ix_(vel, vel)] = -inv_m[:, None] * self.c
        b[vel, :] = inv_m[:, None] * self.e
        names: list[str] = []
        for name in self.coordinates:
            names += [name, f'd{name}']
        return a, b, tuple(names)


def _wheelset_and_primary(asm: _Assembly, p: RailVehicleParams, creep_factor: float,
                          wheelset: str, bogie: str, lead_sign: float, track: str) -> None:
    asm.mass[asm.idx(f'y_{wheelset}')] = p.wheelset_mass
    asm.mass[asm.idx(f'psi_{wheelset}')] = p.wheelset_yaw_inertia
    asm.wheelset_creep(p, creep_factor, wheelset, track)
    _primary(asm, p, wheelset, bogie, lead_sign)


def _primary(asm: _Assembly, p: RailVehicleParams, wheelset: str, bogie: str,
             lead_sign: float) -> None:
    """Primary lateral and yaw springs of one wheelset (leading: lead_sign = +1)."""
    a0 = p.semi_wheelbase
    asm.spring(p.primary_lateral_stiffness,
               {f'y_{wheelset}': 1.0, f'y_{bogie}': -1.0, f'psi_{bogie}': -lead_sign * a0})
    asm.spring(p.primary_yaw_stiffness, {f'psi_{wheelset}': 1.0, f'psi_{bogie}': -1.0})


def _full_car_bogies_and_body(asm: _Assembly, p: RailVehicleParams, spring_ratio: np.ndarray,
                              damper_ratio: np.ndarray) -> None:
    """Bogie and body inertias, secondary lateral springs and dampers and the anti-yaw
    dampers of the full car (shared by the truth and the IMM's reduced full car)."""
    lv = p.bogie_pivot_semi_spacing
    for j, bogie_sign in enumerate((+1.0, -1.0)):
        bogie = f'b{j + 1}'
        asm.mass[asm.idx(f'y_{bogie}')] = p.bogie_mass
        asm.mass[asm.idx(f'psi_{bogie}')] = p.bogie_yaw_inertia
        secondary = {f'y_{bogie}': 1.0, 'y_v': -1.0, 'psi_v': -bogie_sign * lv}
        asm.spring(spring_ratio[j] * p.secondary_lateral_stiffness, secondary)
        asm.damper(damper_ratio[j] * p.secondary_lateral_damping, secondary)
        asm.damper(p.anti_yaw_damping, {f'psi_{bogie}': 1.0, 'psi_v': -1.0})
    asm.mass[asm.idx('y_v')] = p.full_body_mass
    asm.mass[asm.idx('psi_v')] = p.body_yaw_inertia


def _rows_of_derivative(a: np.ndarray, b: np.ndarray, state_names: tuple[str, ...],
                        coordinate: str) -> tuple[np.ndarray, np.ndarray]:
    """(C row, D row) of the second derivative of a coordinate: the rate's row of (A, B)."""
    i = state_names.index(f'd{coordinate}')
    return a[i].copy(), b[i].copy()


OBSERVATION_PATTERNS = ('A', 'B', 'C', 'D')

# The papers' observation patterns over the half car (Chonan & Tsunashima §4.1; D:
# docs/methods/creep_estimator.md).
_HALF_CAR_PATTERN_STATES = {
    'A': ('y_w1', 'dy_w1', 'psi_w1', 'dpsi_w1', 'y_w2', 'dy_w2', 'psi_w2', 'dpsi_w2',
          'y_b', 'dy_b', 'psi_b', 'dpsi_b', 'y_v', 'dy_v'),
    'B': ('y_b', 'dy_b', 'psi_b', 'dpsi_b', 'y_v', 'dy_v'),
    'C': ('y_b', 'dy_b', 'y_v', 'dy_v'),
}
SENSOR_OUTPUT_NAMES = ('ddy_b', 'dpsi_b', 'ddy_v')


def half_car_state_space(params: RailVehicleParams, creep_factor: float = 1.0,
                         spring_ratio: float = 1.0, damper_ratio: float = 1.0,
                         pattern: str = 'D') -> StateSpace:
    """7-DOF half car (docs/methods/suspension_monitor.md/§6): two wheelsets (lateral, yaw), bogie
    (lateral, yaw), body.

    State x = [y_w1, y_w1', psi_w1, psi_w1', y_w2, y_w2', psi_w2, psi_w2', y_b, y_b', psi_b,
    psi_b', y_v, y_v'] (Chonan & Tsunashima's order); inputs u = [y_r1, y_r2], the track
    lateral alignment at the leading and trailing wheelset, m.

    Args:
        params: vehicle parameters (speed included).
        creep_factor: c, multiplies f11 and f22, in (0, 2].
        spring_ratio: multiplies Ksy, in (0, 5].
        damper_ratio: multiplies Csy, in (0, 5].
        pattern: output set. 'A': wheelset, bogie and body lateral/yaw states; 'B': bogie
            lateral and yaw with rates, body lateral with rate; 'C': bogie and body lateral
            displacement and velocity; 'D': the sensors [bogie lateral acceleration, bogie yaw
            rate, body lateral acceleration] (m/s^2, rad/s, m/s^2).

    Returns:
        The continuous state space with C, D for the chosen pattern.
    """
    c = _check_ratio('creep_factor', creep_factor, MAX_CREEP_FACTOR)
    sr = _check_ratio('spring_ratio', spring_ratio, MAX_SUSPENSION_RATIO)
    dr = _check_ratio('damper_ratio', damper_ratio, MAX_SUSPENSION_RATIO)
    if pattern not in OBSERVATION_PATTERNS:
        raise ValueError(f'pattern must be one of {OBSERVATION_PATTERNS}, got {pattern!r}')
    asm = _Assembly(('y_w1', 'psi_w1', 'y_w2', 'psi_w2', 'y_b', 'psi_b', 'y_v'),
                    ('y_r1', 'y_r2'))
    _wheelset_and_primary(asm, params, c, 'w1', 'b', +1.0, 'y_r1')
    _wheelset_and_primary(asm, params, c, 'w2', 'b', -1.0, 'y_r2')
    asm.mass[asm.idx('y_b')] = params.bogie_mass
    asm.mass[asm.idx('psi_b')] = params.bogie_yaw_inertia
    asm.mass[asm.idx('y_v')] = params.body_mass
    asm.spring(sr * params.secondary_lateral_stiffness, {'y_b': 1.0, 'y_v': -1.0})
    asm.damper(dr * params.secondary_lateral_damping, {'y_b': 1.0, 'y_v': -1.0})
    # No body yaw in the half car: the anti-yaw dampers act against the (non-yawing) body.
    asm.damper(params.anti_yaw_damping, {'psi_b': 1.0})
    a, b, names = asm.state_space()
    c_out, d_out, out_names = _half_car_outputs(a, b, names, pattern)
    return StateSpace(a, b, c_out, d_out, names, asm.inputs, out_names)


def _half_car_outputs(a: np.ndarray, b: np.ndarray, names: tuple[str, ...], pattern: str,
                      ) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    if pattern == 'D':
        rows = [_rows_of_derivative(a, b, names, 'y_b'),
                (np.eye(len(names))[names.index('dpsi_b')], np.zeros(b.shape[1])),
                _rows_of_derivative(a, b, names, 'y_v')]
        return (np.array([r[0] for r in rows]), np.array([r[1] for r in rows]),
                SENSOR_OUTPUT_NAMES)
    selected = _HALF_CAR_PATTERN_STATES[pattern]
    c_out = np.eye(len(names))[[names.index(s) for s in selected]]
    return c_out, np.zeros((len(selected), b.shape[1])), selected


def half_car_creep_sensitivity(params: RailVehicleParams, spring_ratio: float = 1.0,
                               damper_ratio: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(dA/dc, dB/dc) of the half car: A = A(c=0) + c dA/dc and B = c dB/dc exactly.

    The creep forces are linear in c, so the difference of two evaluations is the exact
    derivative; the creep EKF's Jacobian in c is built from it (with
    :func:`discretize_zoh_sensitivity` for the discrete model).
    """
    one = half_car_state_space(params, 1.0, spring_ratio, damper_ratio)
    # c -> 0 is outside the model's valid range, so evaluate at c = 1 and c = 1/2.
    half = half_car_state_space(params, 0.5, spring_ratio, damper_ratio)
    return 2.0 * (one.a - half.a), 2.0 * (one.b - half.b)


FULL_CAR_SENSOR_OUTPUT_NAMES = (
    'ddy_b1', 'dpsi_b1', 'ddy_v_above_b1', 'ddy_b2', 'dpsi_b2', 'ddy_v_above_b2')


def full_car_state_space(params: RailVehicleParams, creep_factor: float = 1.0,
                         spring_ratio: Sequence[float] | np.ndarray = (1.0, 1.0),
                         damper_ratio: Sequence[float] | np.ndarray = (1.0, 1.0),
                         suspension_errors: bool = False) -> StateSpace:
    """14-DOF full car: four wheelsets and two bogies (lateral, yaw), body (lateral, yaw).

    State x = [y_w1, y_w1', psi_w1, psi_w1', ..., y_w4 ..., y_b1, y_b1', psi_b1, psi_b1', y_b2
    ..., y_v, y_v', psi_v, psi_v'] (wheelsets and bogies front to rear); inputs
    u = [y_r1 .. y_r4], the track lateral alignment under each wheelset, m. Outputs: per bogie
    the bogie lateral acceleration, bogie yaw rate and the body lateral acceleration above the
    bogie centre (y_v'' +/- lv psi_v''), front bogie first.

    Args:
        params: vehicle parameters (speed included).
        creep_factor: c, common to all wheelsets, in (0, 2].
        spring_ratio: (2,) Ksy multipliers, front and rear bogie, each in (0, 5].
        damper_ratio: (2,) Csy multipliers, front and rear bogie, each in (0, 5].
        suspension_errors: also inputs [f_b1, m_b1, f_b2, m_b2] after the track's: per bogie
            the secondary suspension's lateral force (N, on the bogie; the body takes it back
            at the pivot) and yaw moment (N m) beyond the modelled springs and dampers.
    """
    c = _check_ratio('creep_factor', creep_factor, MAX_CREEP_FACTOR)
    srs = _check_pair('spring_ratio', spring_ratio)
    drs = _check_pair('damper_ratio', damper_ratio)
    errors = ('f_b1', 'm_b1', 'f_b2', 'm_b2') if suspension_errors else ()
    asm = _Assembly(('y_w1', 'psi_w1', 'y_w2', 'psi_w2', 'y_w3', 'psi_w3', 'y_w4', 'psi_w4',
                     'y_b1', 'psi_b1', 'y_b2', 'psi_b2', 'y_v', 'psi_v'),
                    ('y_r1', 'y_r2', 'y_r3', 'y_r4', *errors))
    lv = params.bogie_pivot_semi_spacing
    for j in range(2):
        for k, lead_sign in enumerate((+1.0, -1.0)):
            i = 2 * j + k + 1
            _wheelset_and_primary(asm, params, c, f'w{i}', f'b{j + 1}', lead_sign, f'y_r{i}')
    _full_car_bogies_and_body(asm, params, srs, drs)
    for j, pivot in enumerate((lv, -lv) if suspension_errors else ()):
        # An internal force pair: on the bogie, and back on the body at the bogie's pivot.
        force, moment = asm.inputs.index(f'f_b{j + 1}'), asm.inputs.index(f'm_b{j + 1}')
        asm.e[asm.idx(f'y_b{j + 1}'), force] = 1.0
        asm.e[asm.idx('y_v'), force] = -1.0
        asm.e[asm.idx('psi_v'), force] = -pivot
        asm.e[asm.idx(f'psi_b{j + 1}'), moment] = 1.0
        asm.e[asm.idx('psi_v'), moment] = -1.0
    a, b, names = asm.state_space()
    rows_c, rows_d = [], []
    eye = np.eye(len(names))
    for j, bogie_sign in enumerate((+1.0, -1.0)):
        bogie = f'b{j + 1}'
        cb, db = _rows_of_derivative(a, b, names, f'y_{bogie}')
        cy, dy = _rows_of_derivative(a, b, names, 'y_v')
        cp, dp = _rows_of_derivative(a, b, names, 'psi_v')
        rows_c += [cb, eye[names.index(f'dpsi_{bogie}')], cy + bogie_sign * lv * cp]
        rows_d += [db, np.zeros(b.shape[1]), dy + bogie_sign * lv * dp]
    return StateSpace(a, b, np.array(rows_c), np.array(rows_d), names, asm.inputs,
                      FULL_CAR_SENSOR_OUTPUT_NAMES)


def _check_pair(name: str, values: Sequence[float] | np.ndarray) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.shape != (2,):
        raise ValueError(f'{name} must have 2 values (front, rear bogie), got shape {arr.shape}')
    for k, value in enumerate(arr):
        _check_ratio(f'{name}[{k}]', value, MAX_SUSPENSION_RATIO)
    return arr


REDUCED_STATE_NAMES = ('y_b', 'dy_b', 'psi_b', 'dpsi_b', 'y_v', 'dy_v')
REDUCED_INPUT_NAMES = ('y_w1', 'y_w2', 'psi_w1', 'psi_w2')


def reduced_bogie_body_model(params: RailVehicleParams, spring_ratio: float = 1.0,
                             damper_ratio: float = 1.0) -> StateSpace:
    """The IMM's estimation model (docs/methods/suspension_monitor.md): the half car with the
    wheelset motion removed.

    State x = [y_b, y_b', psi_b, psi_b', y_v, y_v']; outputs y = [bogie lateral acceleration,
    bogie yaw rate, body lateral acceleration]. The wheelsets act on the bogie only through the
    primary suspension, so their lateral displacements and yaw angles are the inputs
    u = [y_w1, y_w2, psi_w1, psi_w2]: B and D hold Ky and Kp over the inertias. Two ways to use
    them:

    * known input: u from the track alignment, assuming the wheelsets follow it (see
      :func:`wheelset_inputs_from_track`), as in the paper;
    * in service, u unknown: treat it as process noise, Q = G Sigma_u G^T after
      discretisation (and R gains D Sigma_u D^T), with Sigma_u the wheelset motion's
      covariance.

    The creep factor does not appear: it acts only on the removed wheelset equations.
    """
    sr = _check_ratio('spring_ratio', spring_ratio, MAX_SUSPENSION_RATIO)
    dr = _check_ratio('damper_ratio', damper_ratio, MAX_SUSPENSION_RATIO)
    asm = _Assembly(('y_b', 'psi_b', 'y_v', 'y_w1', 'y_w2', 'psi_w1', 'psi_w2'), ())
    a0 = params.semi_wheelbase
    for wheelset, lead_sign in (('w1', +1.0), ('w2', -1.0)):
        asm.spring(params.primary_lateral_stiffness,
                   {f'y_{wheelset}': 1.0, 'y_b': -1.0, 'psi_b': -lead_sign * a0})
        asm.spring(params.primary_yaw_stiffness, {f'psi_{wheelset}': 1.0, 'psi_b': -1.0})
    asm.spring(sr * params.secondary_lateral_stiffness, {'y_b': 1.0, 'y_v': -1.0})
    asm.damper(dr * params.secondary_lateral_damping, {'y_b': 1.0, 'y_v': -1.0})
    asm.damper(params.anti_yaw_damping, {'psi_b': 1.0})
    asm.mass[[asm.idx(n) for n in ('y_b', 'psi_b', 'y_v')]] = (
        params.bogie_mass, params.bogie_yaw_inertia, params.body_mass)
    a, b = _wheelsets_as_inputs(asm, ('y_b', 'psi_b', 'y_v'), REDUCED_INPUT_NAMES)
    c_out, d_out, _ = _half_car_outputs(a, b, REDUCED_STATE_NAMES, 'D')
    return StateSpace(a, b, c_out, d_out, REDUCED_STATE_NAMES, REDUCED_INPUT_NAMES,
                      SENSOR_OUTPUT_NAMES)


def _wheelsets_as_inputs(asm: _Assembly, kept: Sequence[str], inputs: Sequence[str],
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the kept coordinates' rows, x = [q_1, q_1', ...], with the (wheelset)
    coordinates ``inputs`` as displacement inputs: B holds minus their stiffness columns."""
    body = [asm.idx(n) for n in kept]
    wheel = [asm.idx(n) for n in inputs]
    inv_m = 1.0 / asm.mass[body]
    n = len(body)
    a = np.zeros((2 * n, 2 * n))
    b = np.zeros((2 * n, len(wheel)))
    pos = np.arange(n) * 2
    vel = pos + 1
    a[pos, vel] = 1.0
    a[np.ix_(vel, pos)] = -inv_m[:, None] * asm.k[np.ix_(body, body)]
    a[np.ix_(vel, vel)] = -inv_m[:, None] * asm.c[np.ix_(body, body)]
    b[vel, :] = -inv_m[:, None] * asm.k[np.ix_(body, wheel)]
    return a, b


def wheelset_inputs_from_track(alignment: np.ndarray, alignment_rate: np.ndarray | None,
                               speed: float | np.ndarray) -> np.ndarray:
    """Known inputs of :func:`reduced_bogie_body_model` from the track alignment.

    Assumes the wheelsets follow the track without creepage: y_wi = y_ri and psi_wi = y_ri'/v
    (lateral creepage y'/v - psi = 0). Good below the wheelset's kinematic frequency, which is
    where the body and bogie suspension modes are. Without the rate, psi_wi = 0 (the paper's
    two-input form).

    Args:
        alignment: (N, 2) track alignment at the monitored bogie's leading and trailing
            wheelsets, m.
        alignment_rate: (N, 2) its time derivative, m/s, or None.
        speed: forward speed, m/s, scalar or (N,).

    Returns:
        (N, 4) u = [y_w1, y_w2, psi_w1, psi_w2].
    """
    y = np.asarray(alignment, dtype=float)
    if y.ndim != 2 or y.shape[1] != 2:
        raise ValueError(f'alignment must have shape (N, 2), got {y.shape}')
    v = np.broadcast_to(np.asarray(speed, dtype=float), (y.shape[0],))
    if not np.all(np.isfinite(v) & (v > 0.0)):
        raise ValueError('speed must be finite and > 0')
    u = np.zeros((y.shape[0], 4))
    u[:, :2] = y
    if alignment_rate is not None:
        rate = np.asarray(alignment_rate, dtype=float)
        if rate.shape != y.shape:
            raise ValueError(f'alignment_rate must have shape {y.shape}, got {rate.shape}')
        u[:, 2:] = rate / v[:, None]
    return u


def free_wheelset_state_space(params: RailVehicleParams, creep_factor: float = 1.0) -> StateSpace:
    """A single wheelset on linear creep forces without suspension: x = [y, y', psi, psi'].

    Its oscillatory eigenvalue pair is the kinematic (Klingel) motion, slightly destabilised by
    inertia; see :func:`klingel_frequency`.
    """
    c = _check_ratio('creep_factor', creep_factor, math.inf)
    asm = _Assembly(('y_w', 'psi_w'), ('y_r',))
    asm.mass[:] = (params.wheelset_mass, params.wheelset_yaw_inertia)
    asm.wheelset_creep(params, c, 'w', 'y_r')
    a, b, names = asm.state_space()
    c_out = np.eye(len(names))
    return StateSpace(a, b, c_out, np.zeros((len(names), 1)), names, asm.inputs, names)


def klingel_frequency(params: RailVehicleParams) -> float:
    """Kinematic hunting frequency v / (2 pi) sqrt(lambda / (r0 l0)), Hz (Klingel 1883)."""
    return params.speed / (2.0 * math.pi) * math.sqrt(
        params.conicity / (params.wheel_radius * params.half_gauge))


def modal_frequencies(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Damped frequencies (Hz) and damping ratios of the oscillatory eigenvalue pairs of A.

    Returns:
        (frequency_hz, damping_ratio), one entry per pair with positive imaginary part, sorted
        by frequency.
    """
    eig = np.linalg.eigvals(np.asarray(a, dtype=float))
    osc = eig[eig.imag > 1e-9]
    order = np.argsort(osc.imag)
    osc = osc[order]
    return osc.imag / (2.0 * math.pi), -osc.real / np.abs(osc)


@dataclass(frozen=True)
class VehicleMode:
    """One oscillatory mode of a vehicle model.

    Attributes:
        frequency_hz: damped natural frequency, Hz.
        damping_ratio: 1 (negative: unstable).
        coordinate: the displacement coordinate that dominates the mode shape, e.g. 'y_v'.
    """

    frequency_hz: float
    damping_ratio: float
    coordinate: str


def vehicle_modes(model: StateSpace, params: RailVehicleParams) -> list[VehicleMode]:
    """Oscillatory modes of a model and the coordinate each is dominated by, by frequency.

    Yaw angles are weighed by a lever arm (l0 for wheelsets, a0 for bogies, lv for the body) so
    they compare with lateral displacements in metres.
    """
    values, vectors = np.linalg.eig(model.a)
    names = model.state_names
    coords = [i for i, name in enumerate(names) if not name.startswith('d')]
    arms = np.array([_lever_arm(names[i], params) for i in coords])
    modes = []
    for value, vector in zip(values, vectors.T, strict=True):
        if value.imag <= 1e-9:
            continue
        shape = np.abs(vector[coords]) * arms
        modes.append(VehicleMode(float(value.imag / (2.0 * math.pi)),
                                 float(-value.real / abs(value)),
                                 names[coords[int(np.argmax(shape))]]))
    return sorted(modes, key=lambda mode: mode.frequency_hz)


def _lever_arm(coordinate: str, params: RailVehicleParams) -> float:
    if not coordinate.startswith('psi'):
        return 1.0
    if coordinate.startswith('psi_w'):
        return params.half_gauge
    if coordinate.startswith('psi_b'):
        return params.semi_wheelbase
    return params.bogie_pivot_semi_spacing


def max_real_eigenvalue(params: RailVehicleParams, creep_factor: float = 1.0,
                        model: str = 'half') -> float:
    """Largest real part of the eigenvalues of the half ('half') or full ('full') car, 1/s."""
    if model == 'half':
        a = half_car_state_space(params, creep_factor).a
    elif model == 'full':
        a = full_car_state_space(params, creep_factor).a
    else:
        raise ValueError(f"model must be 'half' or 'full', got {model!r}")
    return float(np.max(np.linalg.eigvals(a).real))


def critical_speed(params: RailVehicleParams, creep_factor: float = 1.0, model: str = 'half',
                   v_min: float = 1.0, v_max: float = 200.0, tolerance: float = 0.01,
                   ) -> float:
    """Lowest speed at which an eigenvalue crosses into the right half plane, m/s.

    Scans a geometric speed grid from v_min to v_max, then bisects the first crossing to the
    given relative tolerance.

    Returns:
        The critical speed, or ``math.inf`` when the model is stable over the whole range.
    """
    if not (0.0 < v_min < v_max and math.isfinite(v_max)):
        raise ValueError(f'need 0 < v_min < v_max, got {v_min}, {v_max}')
    grid = np.geomspace(v_min, v_max, 60)

    def unstable(v: float) -> bool:
        return max_real_eigenvalue(params.with_speed(v), creep_factor, model) > 0.0

    previous = None
    for v in grid:
        if unstable(float(v)):
            if previous is None:
                return float(v)
            lo, hi = previous, float(v)
            while hi - lo > tolerance * lo:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if unstable(mid) else (mid, hi)
            return hi
        previous = float(v)
    return math.inf


# == One end of the full car: the creep EKF's estimation model (docs/methods/creep_estimator.md)
# =========================

CAR_END_COORDINATES = ('y_w1', 'psi_w1', 'y_w2', 'psi_w2', 'y_b', 'psi_b', 'y_v', 'psi_v')
CAR_END_INPUT_NAMES = ('y_r1', 'y_r2', 'f_rear', 'm_rear')


def car_end_state_space(params: RailVehicleParams, creep_factor: float = 1.0,
                        spring_ratio: float = 1.0, damper_ratio: float = 1.0,
                        bogie: str = 'front') -> StateSpace:
    """One end of the full car: a bogie with its two wheelsets, and the whole body.

    Coordinates q = [y_w1, psi_w1, y_w2, psi_w2, y_b, psi_b, y_v, psi_v] (the monitored bogie's
    leading and trailing wheelset, the bogie, the body lateral and yaw at its centre), state
    x = [q_1, q_1', ...] (16). Unlike the half car, the body has its full mass 2 mv and its yaw
    inertia, the secondary suspension acts at the pivot y_v + lv psi_v and the anti-yaw dampers
    against the body's yaw. The other bogie is not modelled: the body rests on the other
    bogie's secondary suspension as if that bogie were still (spring, damper and anti-yaw
    damper to the track frame at the other pivot, so the body modes are those of the car), and
    what that bogie's own motion adds enters as inputs:

    * ``f_rear`` = Ksy y_b2 + Csy y_b2', the lateral force on the body at the other pivot, N;
    * ``m_rear`` = Cpsi psi_b2', the other anti-yaw dampers' yaw moment on the body, N m.

    Inputs u = [y_r1, y_r2, f_rear, m_rear] (y_r: track alignment at the monitored bogie's
    leading and trailing wheelset); outputs the sensors [bogie lateral acceleration, bogie yaw
    rate, body lateral acceleration above the bogie] (pattern D). For the rear bogie (w3, w4
    of the full car) only the lever arm changes sign: its pivot is at -lv, the other at +lv.

    Args:
        params: vehicle parameters (speed included).
        creep_factor: c on the two wheelsets, in (0, 2].
        spring_ratio: multiplies this bogie's Ksy, in (0, 5].
        damper_ratio: multiplies this bogie's Csy, in (0, 5].
        bogie: the monitored bogie, 'front' or 'rear'.
    """
    if bogie not in ('front', 'rear'):
        raise ValueError(f"bogie must be 'front' or 'rear', got {bogie!r}")
    c = _check_ratio('creep_factor', creep_factor, MAX_CREEP_FACTOR)
    sr = _check_ratio('spring_ratio', spring_ratio, MAX_SUSPENSION_RATIO)
    dr = _check_ratio('damper_ratio', damper_ratio, MAX_SUSPENSION_RATIO)
    asm = _Assembly(CAR_END_COORDINATES, CAR_END_INPUT_NAMES)
    _wheelset_and_primary(asm, params, c, 'w1', 'b', +1.0, 'y_r1')
    _wheelset_and_primary(asm, params, c, 'w2', 'b', -1.0, 'y_r2')
    # Signed position of the monitored bogie's pivot ahead of the body centre.
    lv = params.bogie_pivot_semi_spacing * (1.0 if bogie == 'front' else -1.0)
    asm.mass[asm.idx('y_b')] = params.bogie_mass
    asm.mass[asm.idx('psi_b')] = params.bogie_yaw_inertia
    asm.mass[asm.idx('y_v')] = params.full_body_mass
    asm.mass[asm.idx('psi_v')] = params.body_yaw_inertia
    monitored = {'y_b': 1.0, 'y_v': -1.0, 'psi_v': -lv}
    asm.spring(sr * params.secondary_lateral_stiffness, monitored)
    asm.damper(dr * params.secondary_lateral_damping, monitored)
    asm.damper(params.anti_yaw_damping, {'psi_b': 1.0, 'psi_v': -1.0})
    # The other bogie's suspension, as if that bogie were still (its motion: f_rear, m_rear).
    other = {'y_v': 1.0, 'psi_v': -lv}   # its pivot, at -lv
    asm.spring(params.secondary_lateral_stiffness, other)
    asm.damper(params.secondary_lateral_damping, other)
    asm.damper(params.anti_yaw_damping, {'psi_v': 1.0})
    # The other bogie's motion: a lateral force at its pivot (x = -lv) and a yaw moment.
    asm.e[asm.idx('y_v'), asm.inputs.index('f_rear')] = 1.0
    asm.e[asm.idx('psi_v'), asm.inputs.index('f_rear')] = -lv
    asm.e[asm.idx('psi_v'), asm.inputs.index('m_rear')] = 1.0
    a, b, names = asm.state_space()
    cb, db = _rows_of_derivative(a, b, names, 'y_b')
    cy, dy = _rows_of_derivative(a, b, names, 'y_v')
    cp, dp = _rows_of_derivative(a, b, names, 'psi_v')
    c_out = np.array([cb, np.eye(len(names))[names.index('dpsi_b')], cy + lv * cp])
    d_out = np.array([db, np.zeros(b.shape[1]), dy + lv * dp])
    return StateSpace(a, b, c_out, d_out, names, asm.inputs, SENSOR_OUTPUT_NAMES)
