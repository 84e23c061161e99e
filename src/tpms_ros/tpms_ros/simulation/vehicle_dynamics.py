"""14-DOF road vehicle with combined-slip Magic Formula tires: the handling truth. No ROS import.

Degrees of freedom: body 6 (longitudinal, lateral, yaw of the whole car; heave, roll, pitch of
the sprung mass), 4 unsprung vertical, 4 wheel spins. Plus one transient-slip state per wheel
and direction (tire relaxation), which is what keeps the wheel spin stable at dt = 1 ms down to
low speed. Frames REP 103 (x forward, y left, z up); roll positive left side up, pitch positive
nose down; wheel order FL, FR, RL, RR.

Why written here and not taken from PyPI: ``commonroad-vehicle-models`` (the obvious
candidate, its multi-body model with PAC2002 tires) is not installed and not installable
offline on this machine, and it would not fit anyway: it is scalar Python called through an
ODE solver (far from 5x real time at 1 kHz), has no friction-scale or per-wheel rolling-radius
input, and parameterises suspension by corner rates rather than the per-axle roll stiffness and
damping of docs/methods/lateral_force_observer.md. The equations below are the textbook ones
(Gillespie 1992, ch. 6-9;
Pacejka 2006, ch. 7), arranged so one derivative evaluation per step suffices.

Equations (m, ms include the added mass; a_x = vx' - r vy, a_y = vy' + r vx)::

    m a_x + ms hs q'                  = sum Fx - F_drag                (pitch centre at ground)
    (Iy + ms hs^2) q' + ms hs a_x      = M_pitch,susp + ms g hs theta - hs F_drag
    m a_y - ms e p'                   = sum Fy
    (docs/methods/lateral_force_observer.md form)
    (Ix + ms e^2) p' - ms e a_y        = M_roll,susp + ms g e phi       (roll axis e below CG)
    Iz r'                             = sum (x_i Fy_i - y_i Fx_i)
    ms z''                            = sum F_susp,i
    m_u,i zu_i''                      = (Fz_i - Fz0_i) - F_susp,i - G_i
    Iw omega_i'                       = T_i - Fx_i r_i - f_r Fz_i r_i sgn(omega_i)

Suspension, per axle, in modal form: a heave wheel rate ks (per corner) with damper cs, and the
roll stiffness/damping kphi, cphi of docs/methods/lateral_force_observer.md on the body-to-axle
roll angle. This is the
same as corner springs plus an anti-roll bar, but lets the (light) Ford FC/HVE roll damping stand
apart from a realistic heave damping. Lateral forces reach the sprung mass at the roll centres
(hf, hr): the moment F_link,a h_a plus the unsprung-mass inertia moment is the geometric load
transfer G_i (a vertical force pair on the axle's unsprung masses); the rest goes through the
roll stiffness. The roll axis under the sprung CG is at h - e (contract: 0.07 m, equal within
1 mm to the line through hf and hr at the sprung CG), i.e. h is read as the sprung CG height.

Extra values (not in the Ford FC/HVE data), each a parameter with its reason:
    iy = 2300 kg m^2: sprung pitch inertia; measured passenger cars have pitch inertia
        0.85-0.95 of yaw inertia (Heydinger et al. 1999, SAE 1999-01-1336), 0.9 x 2560.
    unsprung_front_share = 0.52: of m - ms = 153 kg, front corners 39.8 kg, rear 36.7 kg
        (McPherson front corners carry the larger brakes, knuckle and drive-shaft end).
    kt = 200 kN/m, ct = 100 N s/m: passenger-car radial tire vertical stiffness (Gillespie
        1992 ch. 5: 150-250 kN/m) and its small hysteretic damping.
    ks_f = 33.5 kN/m, ks_r = 26.5 kN/m: heave wheel rates for ride frequencies 1.2 Hz front,
        1.35 Hz rear in series with kt (Gillespie ch. 6: 1-1.5 Hz, rear ~10 % higher).
    cs_f = 2500, cs_r = 1800 N s/m: about 30 % of critical damping of those ride modes.
    relax_long = 0.15 m, relax_lat = 0.5 m: tire relaxation lengths of a passenger tire
        (Pacejka 2006 ch. 7: sigma_alpha about 1.5-2 rim radii, sigma_kappa markedly shorter).
    rolling_resistance = 0.012, drag_area = 0.75 m^2, air_density = 1.2: Wong, Theory of
        Ground Vehicles (f_r 0.010-0.015 on asphalt; full-size sedan Cd 0.33 x A 2.3 m^2).
    brake_front_share = 0.6: front/rear brake split of the speed controller (as the paper's
        60/40 N m).

Integration (fixed step dt, one force evaluation per step): semi-implicit (symplectic) Euler.
Forces from the state at t_k update all velocities; the positions and the tire deflections are
then advanced with the new velocities; the relaxation decay term |vx| u / sigma is implicit;
brake and rolling-resistance torques are Coulomb-type and clipped so that they stop a wheel
but never reverse it. The fastest modes are the wheel-spin/tire-deflection oscillation
(sqrt(C_kappa r^2 / (sigma_kappa Iw)) ~ 200-300 rad/s) and wheel hop (~75 rad/s); symplectic
Euler is stable for omega dt < 2 and we refuse dt with omega_max dt > 1 (dt <= ~3 ms with the
defaults). Steady states are the exact steady states of the ODE (no integrator bias); the
transient error is first order in dt and measured in the tests (1 ms against 0.25 ms).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
import math

import numpy as np

from tpms_ros.core.magic_formula import MagicFormulaTire, combined_weights

GRAVITY = 9.81  # m/s^2
_N_WHEELS = 4


@dataclass(frozen=True)
class VehicleParams:
    """Vehicle parameters. Defaults: Ford FC/HVE data of docs/methods/lateral_force_observer.md
    plus documented extras.

    Lengths in m, masses in kg, inertias in kg m^2, roll stiffness N m/rad, roll damping
    N m s/rad. tf, tr are half tracks. See the module docstring for the sources of the extras.
    """

    m: float = 1814.0          # total mass
    ms: float = 1661.0         # sprung mass
    iz: float = 2560.0         # yaw inertia (whole car)
    ix: float = 580.0          # roll inertia of the sprung mass about its CG
    iw: float = 2.0            # wheel spin inertia
    lf: float = 1.076          # CG to front axle
    lr: float = 1.617          # CG to rear axle
    h: float = 0.55            # CG height (of the sprung mass, see module docstring)
    hf: float = 0.114          # front roll-centre height
    hr: float = 0.004          # rear roll-centre height
    e: float = 0.48            # sprung CG above the roll axis
    rw: float = 0.305          # nominal wheel radius
    tf: float = 0.784          # front half track
    tr: float = 0.760          # rear half track
    kphi_f: float = 108205.8   # front roll stiffness
    kphi_r: float = 81436.7    # rear roll stiffness
    cphi_f: float = 826.8      # front roll damping
    cphi_r: float = 658.9      # rear roll damping
    driven_axle: str = 'rear'  # 'front' or 'rear'
    iy: float = 2300.0         # sprung pitch inertia about its CG
    unsprung_front_share: float = 0.52  # share of m - ms on the front axle
    kt: float = 200000.0       # tire vertical stiffness, N/m
    ct: float = 100.0          # tire vertical damping, N s/m
    ks_f: float = 33500.0      # front heave wheel rate per corner, N/m
    ks_r: float = 26500.0      # rear heave wheel rate per corner, N/m
    cs_f: float = 2500.0       # front heave damping per corner, N s/m
    cs_r: float = 1800.0       # rear heave damping per corner, N s/m
    relax_long: float = 0.15   # longitudinal relaxation length, m
    relax_lat: float = 0.5     # lateral relaxation length, m
    relax_min_speed: float = 1.0  # speed floor in the relaxation decay (low-speed damping), m/s
    rolling_resistance: float = 0.012  # rolling resistance coefficient f_r
    drag_area: float = 0.75    # Cd A, m^2
    air_density: float = 1.2   # kg/m^3
    brake_front_share: float = 0.6  # front share of the controller's brake torque
    speed_kp: float = 0.8      # speed controller: commanded accel per speed error, 1/s
    speed_ki: float = 0.2      # speed controller: integral gain, 1/s^2
    max_drive_accel: float = 4.0   # speed controller limit, m/s^2
    max_brake_decel: float = 8.0   # speed controller limit, m/s^2
    tire: MagicFormulaTire = field(default_factory=MagicFormulaTire)

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in ('driven_axle', 'tire'):
                continue
            try:
                value = float(value)
            except (TypeError, ValueError) as exc:
                raise ValueError(f'VehicleParams.{f.name} must be a number, '
                                 f'got {value!r}') from exc
            if not math.isfinite(value):
                raise ValueError(f'VehicleParams.{f.name} must be finite, got {value}')
        positive = ('m', 'ms', 'iz', 'ix', 'iw', 'lf', 'lr', 'h', 'e', 'rw', 'tf', 'tr',
                    'kphi_f', 'kphi_r', 'iy', 'kt', 'ks_f', 'ks_r', 'relax_long', 'relax_lat',
                    'relax_min_speed', 'air_density')
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ValueError(f'VehicleParams.{name} must be > 0, got {getattr(self, name)}')
        non_negative = ('cphi_f', 'cphi_r', 'ct', 'cs_f', 'cs_r', 'rolling_resistance',
                        'drag_area', 'speed_kp', 'speed_ki', 'max_drive_accel',
                        'max_brake_decel')
        for name in non_negative:
            if not getattr(self, name) >= 0.0:
                raise ValueError(f'VehicleParams.{name} must be >= 0, got {getattr(self, name)}')
        if not self.ms < self.m:
            raise ValueError(f'VehicleParams.ms must be < m (unsprung mass > 0), got {self.ms}')
        for name in ('unsprung_front_share', 'brake_front_share'):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f'VehicleParams.{name} must be in [0, 1], '
                                 f'got {getattr(self, name)}')
        if not 0.0 < self.unsprung_front_share < 1.0:
            raise ValueError('VehicleParams.unsprung_front_share must be in (0, 1), '
                             f'got {self.unsprung_front_share}')
        if self.driven_axle not in ('front', 'rear'):
            raise ValueError("VehicleParams.driven_axle must be 'front' or 'rear', "
                             f'got {self.driven_axle!r}')

    @property
    def wheelbase(self) -> float:
        """lf + lr, m."""
        return self.lf + self.lr

    @property
    def unsprung_corner_masses(self) -> np.ndarray:
        """Unsprung mass per wheel FL, FR, RL, RR, kg."""
        mu = self.m - self.ms
        front = 0.5 * mu * self.unsprung_front_share
        rear = 0.5 * mu * (1.0 - self.unsprung_front_share)
        return np.array([front, front, rear, rear])

    def static_wheel_loads(self, added_mass: float = 0.0) -> np.ndarray:
        """Static vertical load per wheel on flat ground, N (added mass at the CG)."""
        weight = (self.m + added_mass) * GRAVITY
        front = 0.5 * weight * self.lr / self.wheelbase
        rear = 0.5 * weight * self.lf / self.wheelbase
        return np.array([front, front, rear, rear])


@dataclass(frozen=True)
class HandlingInputs:
    """Time series driving the simulation, all sampled on the integration grid t.

    Attributes:
        t: (N,) time, s, uniformly spaced (the spacing is the integration step).
        steer: (N,) front road-wheel angle, rad, left positive.
        speed_target: (N,) target speed, m/s, of the built-in PI speed controller acting on
            drive (driven axle) and brake (all wheels) torque; NaN samples switch it off.
        torque_offset: (N, 4) extra wheel torque FL, FR, RL, RR, N m. Positive = drive torque;
            negative = brake torque of that magnitude, which opposes the wheel's rotation and
            stops the wheel but never spins it backwards.
        friction_scale: (N,) road friction scale on the tire peak force (1.1 dry ... 0.2 ice).
        rolling_radius: (N, 4) effective rolling radius per wheel, m (set by the caller).
        added_mass: kg on the sprung mass at the CG.
    """

    t: np.ndarray
    steer: np.ndarray
    speed_target: np.ndarray
    torque_offset: np.ndarray
    friction_scale: np.ndarray
    rolling_radius: np.ndarray
    added_mass: float = 0.0

    def __post_init__(self) -> None:
        # Store float arrays whatever array-likes came in (frozen: bypass __setattr__).
        for name in ('t', 'steer', 'speed_target', 'torque_offset', 'friction_scale',
                     'rolling_radius'):
            try:
                object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))
            except (TypeError, ValueError) as exc:
                raise ValueError(f'HandlingInputs.{name} must be numeric') from exc
        t = self.t
        if t.ndim != 1 or t.size < 2:
            raise ValueError(f'HandlingInputs.t must be 1-D with >= 2 samples, got {t.shape}')
        if not np.all(np.isfinite(t)):
            raise ValueError('HandlingInputs.t must be finite')
        steps = np.diff(t)
        dt = steps[0]
        if not dt > 0.0 or not np.allclose(steps, dt, rtol=1e-6, atol=1e-12):
            raise ValueError('HandlingInputs.t must be strictly increasing and uniformly spaced')
        n = t.size
        expected = {'steer': (n,), 'speed_target': (n,), 'torque_offset': (n, _N_WHEELS),
                    'friction_scale': (n,), 'rolling_radius': (n, _N_WHEELS)}
        for name, shape in expected.items():
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape:
                raise ValueError(f'HandlingInputs.{name} must have shape {shape}, '
                                 f'got {value.shape}')
            if name == 'speed_target':
                if np.any(np.isinf(value)):
                    raise ValueError('HandlingInputs.speed_target must be finite or NaN')
            elif not np.all(np.isfinite(value)):
                raise ValueError(f'HandlingInputs.{name} must be finite')
        if not np.all(np.asarray(self.friction_scale) > 0.0):
            raise ValueError('HandlingInputs.friction_scale must be > 0')
        if not np.all(np.asarray(self.rolling_radius) > 0.0):
            raise ValueError('HandlingInputs.rolling_radius must be > 0')
        if np.any(np.abs(np.asarray(self.steer)) >= 0.5 * math.pi):
            raise ValueError('HandlingInputs.steer must be within (-pi/2, pi/2) rad')
        if not (math.isfinite(self.added_mass) and self.added_mass >= 0.0):
            raise ValueError(f'HandlingInputs.added_mass must be >= 0, got {self.added_mass}')

    @property
    def dt(self) -> float:
        """Integration step, s."""
        return float(self.t[1] - self.t[0])


@dataclass(frozen=True)
class HandlingResult:
    """Simulated truth, every array sampled on inputs.t.

    Attributes:
        t: (N,) s.
        omega: (N, 4) wheel spin, rad/s.
        wheel_torque: (N, 4) total applied drive/brake torque, N m (drive +, brake -).
        steer: (N,) front road-wheel angle, rad.
        vx, vy: (N,) velocity of the CG in the body (yaw) frame, m/s.
        yaw_rate: (N,) rad/s.
        roll, roll_rate: (N,) sprung-mass roll angle (left side up +), rad and rad/s.
        ax, ay: (N,) specific force an IMU fixed to the body at the CG reads, m/s^2 (includes
            the gravity component of roll and pitch and the roll/pitch angular accelerations).
        fx, fy, fz: (N, 4) tire forces in the wheel frame, N.
        mass: total mass including the added mass, kg.
        pitch: (N,) sprung-mass pitch (nose down +), rad.
        yaw: (N,) heading angle, rad.
        slip_ratio: (N, 4) longitudinal slip of the tire (after relaxation), -.
        slip_angle: (N, 4) slip angle of the tire (after relaxation), rad.
    """

    t: np.ndarray
    omega: np.ndarray
    wheel_torque: np.ndarray
    steer: np.ndarray
    vx: np.ndarray
    vy: np.ndarray
    yaw_rate: np.ndarray
    roll: np.ndarray
    roll_rate: np.ndarray
    ax: np.ndarray
    ay: np.ndarray
    fx: np.ndarray
    fy: np.ndarray
    fz: np.ndarray
    mass: float
    pitch: np.ndarray
    yaw: np.ndarray
    slip_ratio: np.ndarray
    slip_angle: np.ndarray


def _suspension_matrices(
    params: VehicleParams, sprung_cg_to_front: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corner geometry T (4x3, [z, phi, theta] -> corner heave) and modal K4, C4 (4x4)."""
    x_front = sprung_cg_to_front
    x_rear = sprung_cg_to_front - params.wheelbase
    geometry = np.array([
        [1.0, params.tf, -x_front],
        [1.0, -params.tf, -x_front],
        [1.0, params.tr, -x_rear],
        [1.0, -params.tr, -x_rear],
    ])
    stiffness = np.zeros((4, 4))
    damping = np.zeros((4, 4))
    heave_pair = np.array([[1.0, 1.0], [1.0, 1.0]])
    roll_pair = np.array([[1.0, -1.0], [-1.0, 1.0]])
    axles = ((slice(0, 2), params.ks_f, params.cs_f, params.kphi_f, params.cphi_f, params.tf),
             (slice(2, 4), params.ks_r, params.cs_r, params.kphi_r, params.cphi_r, params.tr))
    for sl, ks, cs, kphi, cphi, half_track in axles:
        # Heave: both corners see the mean deflection; roll: the body-to-axle roll angle
        # (dL - dR) / (2 t) with moment kphi acting as a force pair over the track.
        stiffness[sl, sl] = 0.5 * ks * heave_pair + kphi / (4.0 * half_track**2) * roll_pair
        damping[sl, sl] = 0.5 * cs * heave_pair + cphi / (4.0 * half_track**2) * roll_pair
    return geometry, stiffness, damping


def max_stable_step(params: VehicleParams, added_mass: float = 0.0) -> float:
    """Largest dt (s) the integrator accepts: omega_max dt <= 1 for the fastest mode.

    The fastest modes are wheel hop and the wheel-spin / tire-deflection oscillation
    (see the module docstring); the latter is taken at twice the static load for margin.
    """
    loads = params.static_wheel_loads(added_mass)
    slip_stiffness = float(np.max(params.tire.slip_stiffness(2.0 * loads)))
    radius = 1.05 * params.rw
    omega_spin = math.sqrt(slip_stiffness * radius**2 / (params.relax_long * params.iw))
    mu_min = float(np.min(params.unsprung_corner_masses))
    omega_hop = math.sqrt((params.kt + max(params.ks_f, params.ks_r)) / mu_min)
    return 1.0 / max(omega_spin, omega_hop)


def simulate_handling(
    params: VehicleParams, inputs: HandlingInputs, initial_speed: float
) -> HandlingResult:
    """Simulate the 14-DOF vehicle over inputs.t, starting in steady straight running.

    At t[0] the car runs straight at initial_speed with static loads, settled suspension and
    the wheels rolling with the slip that holds that speed under the controller's t[0]
    feed-forward (zero slip when the controller is off).

    Args:
        params: vehicle parameters.
        inputs: time series (their spacing is the integration step).
        initial_speed: forward speed at t[0], m/s (>= 0).

    Returns:
        The truth sampled on inputs.t.

    Raises:
        ValueError: if initial_speed is not finite and >= 0, or the step is too large to be
            stable (see max_stable_step).
    """
    if not (math.isfinite(initial_speed) and initial_speed >= 0.0):
        raise ValueError(f'initial_speed must be finite and >= 0, got {initial_speed}')
    dt = inputs.dt
    dt_max = max_stable_step(params, inputs.added_mass)
    if dt > dt_max:
        raise ValueError(f'HandlingInputs.t step {dt:.4g} s is above the stable limit '
                         f'{dt_max:.4g} s of this vehicle')

    p = params
    n = inputs.t.size
    l_base = p.wheelbase
    m_tot = p.m + inputs.added_mass
    ms_tot = p.ms + inputs.added_mass
    mu_corner = p.unsprung_corner_masses
    mu_rear_total = float(mu_corner[2] + mu_corner[3])
    mu_front_total = float(mu_corner[0] + mu_corner[1])
    # Sprung CG from the front axle: the added mass sits at the total CG (lf behind the front).
    a_s = (p.m * p.lf - mu_rear_total * l_base + inputs.added_mass * p.lf) / ms_tot
    geometry, k4, c4 = _suspension_matrices(p, a_s)
    geometry_t = np.ascontiguousarray(geometry.T)
    fz0 = p.static_wheel_loads(inputs.added_mass)

    # Whole-car wheel positions about the total CG.
    x_w = np.array([p.lf, p.lf, -p.lr, -p.lr])
    y_w = np.array([p.tf, -p.tf, p.tr, -p.tr])
    hs = p.h
    e = p.e
    # Mass matrices of the coupled longitudinal/pitch and lateral/roll pairs, inverted once.
    inv_long = np.linalg.inv(np.array([[m_tot, ms_tot * hs],
                                       [ms_tot * hs, p.iy + ms_tot * hs**2]]))
    inv_lat = np.linalg.inv(np.array([[m_tot, -ms_tot * e],
                                      [-ms_tot * e, p.ix + ms_tot * e**2]]))
    il00, il01, il10, il11 = inv_long.ravel().tolist()
    it00, it01, it10, it11 = inv_lat.ravel().tolist()
    # Geometric load transfer: lateral link force at roll centre + unsprung inertia moments.
    half_tracks = (p.tf, p.tr)
    long_pair = np.array([1.0, 1.0, -1.0, -1.0])  # front +, rear -

    if p.driven_axle == 'front':
        driven = np.array([0.5, 0.5, 0.0, 0.0])
    else:
        driven = np.array([0.0, 0.0, 0.5, 0.5])
    brake_split = np.array([0.5 * p.brake_front_share] * 2 + [0.5 * (1 - p.brake_front_share)] * 2)

    tire = p.tire
    sigma_k = p.relax_long
    sigma_a = p.relax_lat
    f_r = p.rolling_resistance
    drag_coef = 0.5 * p.air_density * p.drag_area
    inv_iw = 1.0 / p.iw
    kt = p.kt
    ct = p.ct
    inv_mu = 1.0 / mu_corner
    deg = 180.0 / math.pi

    steer_in = np.asarray(inputs.steer, dtype=float).tolist()
    target_in = np.asarray(inputs.speed_target, dtype=float).tolist()
    mu_in = np.asarray(inputs.friction_scale, dtype=float).tolist()
    offset_in = np.asarray(inputs.torque_offset, dtype=float)
    radius_in = np.asarray(inputs.rolling_radius, dtype=float)
    drive_offset = np.maximum(offset_in, 0.0)
    brake_offset = np.maximum(-offset_in, 0.0)
    radius_mean = radius_in.mean(axis=1).tolist()

    # --- initial steady state -------------------------------------------------------------
    vx = float(initial_speed)
    vy = r = p_roll = q_pitch = w_heave = 0.0
    z = phi = theta = psi = 0.0
    zu = np.zeros(_N_WHEELS)
    zud = np.zeros(_N_WHEELS)
    v_def = np.zeros(_N_WHEELS)
    kappa0 = np.zeros(_N_WHEELS)
    if math.isfinite(target_in[0]) and vx > 0.0:
        # Undriven wheels roll against rolling resistance; driven ones carry drag + that.
        resist = f_r * fz0
        fx_needed = -resist * (driven == 0.0)
        fx_needed += driven * (drag_coef * vx * vx + float(np.sum(resist * (driven == 0.0))))
        kappa0 = fx_needed / tire.slip_stiffness(fz0)
    u_def = sigma_k * kappa0
    omega = vx * (1.0 + kappa0) / radius_in[0]
    integ = 0.0

    # --- outputs ----------------------------------------------------------------------------
    out_scalar = np.empty((n, 10))
    out_omega = np.empty((n, _N_WHEELS))
    out_torque = np.empty((n, _N_WHEELS))
    out_fx = np.empty((n, _N_WHEELS))
    out_fy = np.empty((n, _N_WHEELS))
    out_fz = np.empty((n, _N_WHEELS))
    out_kappa = np.empty((n, _N_WHEELS))
    out_alpha = np.empty((n, _N_WHEELS))

    cos_d = np.ones(_N_WHEELS)
    sin_d = np.zeros(_N_WHEELS)
    body_s = np.zeros(3)
    body_sd = np.zeros(3)
    imu_h = p.h  # IMU at the CG on the sprung body
    h_ra = p.h - p.e

    for k in range(n):
        delta = steer_in[k]
        mu_road = mu_in[k]
        rad = radius_in[k]
        cd = math.cos(delta)
        sd = math.sin(delta)
        cos_d[0] = cos_d[1] = cd
        sin_d[0] = sin_d[1] = sd

        # Slip of the current state from the tire deflection (relaxation) states.
        kappa = u_def / sigma_k
        alpha = np.arctan(v_def / sigma_a)

        # Vertical tire loads (flat road): deflection from the static state, no pull.
        fz = np.maximum(fz0 - kt * zu - ct * zud, 0.0)

        # Combined-slip Magic Formula.
        b_y, c_y, d_y, e_y = tire.lateral_coefficients(fz, mu_road)
        b_x, c_x, d_x, e_x = tire.longitudinal_coefficients(fz, mu_road)
        ba = b_y * (alpha * deg)
        fy0 = d_y * np.sin(c_y * np.arctan(ba - e_y * (ba - np.arctan(ba))))
        bk = b_x * (kappa * 100.0)
        fx0 = d_x * np.sin(c_x * np.arctan(bk - e_x * (bk - np.arctan(bk))))
        g_x, g_y = combined_weights(tire, kappa, alpha, mu_road)
        fx = g_x * fx0
        fy = g_y * fy0

        # Body-frame tire forces and their resultants.
        fxb = fx * cos_d - fy * sin_d
        fyb = fx * sin_d + fy * cos_d
        sum_fx = float(fxb.sum())
        sum_fy = float(fyb.sum())
        mz = float(np.dot(x_w, fyb) - np.dot(y_w, fxb))
        fy_front = float(fyb[0] + fyb[1])
        fy_rear = float(fyb[2] + fyb[3])

        # Speed controller (driver): PI on speed with resistance feed-forward.
        drag = drag_coef * vx * abs(vx)
        target = target_in[k]
        if math.isfinite(target):
            err = target - vx
            integ += err * dt
            i_lim = p.max_drive_accel / p.speed_ki if p.speed_ki > 0.0 else 0.0
            integ = min(max(integ, -i_lim), i_lim)
            a_cmd = p.speed_kp * err + p.speed_ki * integ
            a_cmd = min(max(a_cmd, -p.max_brake_decel), p.max_drive_accel)
            f_cmd = m_tot * a_cmd + drag + f_r * m_tot * GRAVITY
            if f_cmd >= 0.0:
                t_drive = drive_offset[k] + driven * (f_cmd * radius_mean[k])
                t_brake = brake_offset[k]
            else:
                t_drive = drive_offset[k]
                t_brake = brake_offset[k] + brake_split * (-f_cmd * radius_mean[k])
        else:
            integ = 0.0
            t_drive = drive_offset[k]
            t_brake = brake_offset[k]

        # Suspension corner forces on the sprung mass (deviation from static).
        body_s[0] = z
        body_s[1] = phi
        body_s[2] = theta
        body_sd[0] = w_heave
        body_sd[1] = p_roll
        body_sd[2] = q_pitch
        defl = geometry @ body_s - zu
        defl_rate = geometry @ body_sd - zud
        f_susp = -(k4 @ defl) - c4 @ defl_rate
        heave_f, roll_m, pitch_m = (geometry_t @ f_susp).tolist()

        # Body accelerations.
        rhs_x = sum_fx - drag
        rhs_q = pitch_m + ms_tot * GRAVITY * hs * theta - hs * drag
        a_x = il00 * rhs_x + il01 * rhs_q
        q_dot = il10 * rhs_x + il11 * rhs_q
        rhs_y = sum_fy
        rhs_p = roll_m + ms_tot * GRAVITY * e * phi
        a_y = it00 * rhs_y + it01 * rhs_p
        p_dot = it10 * rhs_y + it11 * rhs_p
        r_dot = mz / p.iz
        w_dot = heave_f / ms_tot

        # Geometric load transfer on the unsprung masses (vertical pairs, + = more tire load).
        ay_f = a_y + r_dot * p.lf
        ay_r = a_y - r_dot * p.lr
        m_front = (fy_front - mu_front_total * ay_f) * p.hf + mu_front_total * ay_f * p.rw
        m_rear = (fy_rear - mu_rear_total * ay_r) * p.hr + mu_rear_total * ay_r * p.rw
        lat_f = m_front / (2.0 * half_tracks[0])
        lat_r = m_rear / (2.0 * half_tracks[1])
        long_m = (mu_front_total + mu_rear_total) * a_x * p.rw / (2.0 * l_base)
        geo = -long_pair * long_m
        geo[0] -= lat_f
        geo[1] += lat_f
        geo[2] -= lat_r
        geo[3] += lat_r

        # Record the state at t_k with the forces that act on it.
        wheel_torque = t_drive - t_brake * np.sign(omega)
        out_scalar[k] = (vx, vy, r, phi, p_roll,
                         a_x + imu_h * q_dot - GRAVITY * theta,
                         a_y - (imu_h - h_ra) * p_dot + GRAVITY * phi,
                         theta, psi, delta)
        out_omega[k] = omega
        out_torque[k] = wheel_torque
        out_fx[k] = fx
        out_fy[k] = fy
        out_fz[k] = fz
        out_kappa[k] = kappa
        out_alpha[k] = alpha

        # --- semi-implicit Euler: velocities first ---
        vx, vy = vx + dt * (a_x + r * vy), vy + dt * (a_y - r * vx)
        r += dt * r_dot
        p_roll += dt * p_dot
        q_pitch += dt * q_dot
        w_heave += dt * w_dot
        zud = zud + dt * ((fz - fz0) - f_susp - geo) * inv_mu
        omega_free = omega + dt * inv_iw * (t_drive - fx * rad)
        resist = t_brake + f_r * fz * rad
        omega = np.sign(omega_free) * np.maximum(np.abs(omega_free) - dt * inv_iw * resist, 0.0)

        # --- then positions with the new velocities ---
        z += dt * w_heave
        phi += dt * p_roll
        theta += dt * q_pitch
        psi += dt * r
        zu = zu + dt * zud
        vx_hub = vx - r * y_w
        vy_hub = vy + r * x_w
        vxw = vx_hub * cos_d + vy_hub * sin_d
        vyw = vy_hub * cos_d - vx_hub * sin_d
        speed_w = np.maximum(np.abs(vxw), p.relax_min_speed)
        u_def = (u_def + dt * (omega * rad - vxw)) / (1.0 + dt / sigma_k * speed_w)
        v_def = (v_def - dt * vyw) / (1.0 + dt / sigma_a * speed_w)

    return HandlingResult(
        t=np.asarray(inputs.t, dtype=float).copy(),
        omega=out_omega, wheel_torque=out_torque, steer=out_scalar[:, 9].copy(),
        vx=out_scalar[:, 0].copy(), vy=out_scalar[:, 1].copy(),
        yaw_rate=out_scalar[:, 2].copy(), roll=out_scalar[:, 3].copy(),
        roll_rate=out_scalar[:, 4].copy(), ax=out_scalar[:, 5].copy(),
        ay=out_scalar[:, 6].copy(), fx=out_fx, fy=out_fy, fz=out_fz, mass=m_tot,
        pitch=out_scalar[:, 7].copy(), yaw=out_scalar[:, 8].copy(),
        slip_ratio=out_kappa, slip_angle=out_alpha,
    )
