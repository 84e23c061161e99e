"""Creep-factor EKF core (docs/methods/creep_estimator.md): Jacobians, tracking of the paper's
run, robustness."""

from __future__ import annotations

from dataclasses import replace
import math

import numpy as np
import pytest

from rail_monitor_ros.core import creep_ekf
from rail_monitor_ros.core.creep_ekf import (
    CreepEkf,
    CreepEkfParams,
    CreepRun,
    lateral_states_measurement,
    measurement_channels,
    pattern_fields,
    track_wheelsets,
)
from rail_monitor_ros.core.rail_model import car_end_state_space, full_car_state_space
from rail_monitor_ros.offline.creep_runs import (
    run_on_simulation,
    simulation_inputs,
    step_metrics,
)
from rail_monitor_ros.simulation.rail_scenario import rail_scenario_from_dict, shipped_scenario
from rail_monitor_ros.simulation.rail_simulator import (
    RailSimulationResult,
    lateral_states_fields,
    simulate,
)

# docs/targets.md: within 5 % (A-C) / 10 % (D) of the true c from 1 s after each step. Measured on
# the seeded run (known input, surveyed track), largest error after 1 s, steps to 40 % / 60 %:
# the full model (default) A 1.3 / 1.4 %, B 1.8 / 2.0 %, C 1.8 / 1.9 %, D 1.7 / 1.5 %; the end
# model A 1.4 / 1.2 %, B 1.5 / 2.5 %, C 1.7 / 2.8 %, D 3.4 / 1.2 %.
SPEC_TARGET = {'A': 0.05, 'B': 0.05, 'C': 0.05, 'D': 0.10}


@pytest.fixture(scope='module')
def creep_steps() -> RailSimulationResult:
    """The paper's run: 144 km/h, 15 s, c 1.0 -> 0.4 at 5 s -> 0.6 at 10 s (seeded)."""
    return simulate(shipped_scenario('rail_creep_steps'))


# The shipped bags publish the true track alignment (an exact survey; 0.01 mm stands for
# exact), and the estimator is told so; the default track_map_error_m (0.3 mm, a map in
# service) costs these runs up to 4 points of error (B: 5.3 % instead of 1.5 % from 1 s
# after the first step).
SURVEYED_TRACK = {'track_map_error_m': 1e-5}


@pytest.fixture(scope='module')
def known_runs(creep_steps: RailSimulationResult) -> dict[tuple[str, str], CreepRun]:
    """One run per model and pattern with the measured track alignment as known input."""
    return {(model, p): run_on_simulation(creep_steps, CreepEkfParams(pattern=p, model=model,
                                                                      **SURVEYED_TRACK))
            for model in ('full', 'end') for p in 'ABCD'}


def _state(ekf: CreepEkf, rng: np.random.Generator, creep_factor: float) -> np.ndarray:
    """A plausible augmented state: mm displacements, cm/s rates, mrad yaw (the other bogie's
    forces in units of its motion)."""
    x = np.zeros(ekf.dim_x)
    n_q, n_u = ekf.n_model, ekf.n_track
    x[:n_q] = rng.normal(size=n_q) * np.tile([2e-3, 2e-2, 1e-3, 1e-2], n_q // 4 + 1)[:n_q]
    x[n_q:n_q + n_u] = rng.normal(size=n_u) * 2e-3
    x[n_q + n_u:n_q + 2 * n_u] = rng.normal(size=n_u) * 5e-2
    # The other bogie's forces (3 mm) or the suspension ratio errors (3e-3), the track map's
    # error (0.3 mm, its rate 3 mm/s) and the sensor offsets (0.1 mm).
    rest = ekf.i_theta - n_q - 2 * n_u
    spread = np.concatenate([np.full(ekf.n_disturbances, 3e-3),
                             np.repeat([3e-4, 3e-3], ekf.n_map_error // 2),
                             np.full(ekf.n_offsets, 1e-4)])
    x[n_q + 2 * n_u:ekf.i_theta] = rng.normal(size=rest) * spread
    x[ekf.i_theta] = math.log(creep_factor)
    return x


@pytest.mark.parametrize('model, creep_factor, trend', [
    ('end', 0.3, 0.0), ('end', 0.73, 0.0), ('end', 1.4, 0.0), ('half', 0.73, 0.0),
    ('full', 0.73, 0.0), ('full', 0.73, 0.003)])
def test_jacobian_matches_finite_differences(model: str, creep_factor: float,
                                             trend: float) -> None:
    """The exact Jacobian (Frechet derivative of e^{A dt}) equals central finite differences,
    with and without the rate of ln c as a state."""
    ekf = CreepEkf(CreepEkfParams(pattern='A', model=model, creep_trend_walk_std=trend))
    x = _state(ekf, np.random.default_rng(3), creep_factor)
    if ekf.i_trend is not None:
        x[ekf.i_trend] = -0.05           # c falling by 5 % a second
        next_x, _ = ekf.transition(x, exact=True)
        assert next_x[ekf.i_theta] == pytest.approx(x[ekf.i_theta] - 0.05 * ekf.params.dt)
    _, jac = ekf.transition(x, exact=True)
    dim_x, i_theta = ekf.dim_x, ekf.i_theta
    numeric = np.zeros((dim_x, dim_x))
    for i in range(dim_x):
        step = 1e-5 if i == i_theta else 1e-6 * max(1.0, abs(x[i]))
        dx = np.zeros(dim_x)
        dx[i] = step
        plus, _ = ekf.transition(x + dx, exact=True)
        minus, _ = ekf.transition(x - dx, exact=True)
        numeric[:, i] = (plus - minus) / (2.0 * step)
    scale = np.abs(numeric).max(axis=0) + 1e-12
    assert np.max(np.abs(jac - numeric) / scale) < 1e-6
    # The c column is not trivially zero: c acts on the wheelset rows.
    assert np.abs(jac[:ekf.n_model, i_theta]).max() > 1e-6


def test_car_end_model_exact_for_the_full_car(creep_steps: RailSimulationResult) -> None:
    """Given the other bogie's forces, the end model's derivatives equal the full car's: the
    estimation model is the truth's front end, built from the same assembly code."""
    p = creep_steps.scenario.vehicle
    full = full_car_state_space(p, 0.7)
    end = car_end_state_space(p, 0.7)
    k = 777
    x_full = creep_steps.state[k]
    names = full.state_names

    def full_name(name: str) -> str:
        return name.replace('_b', '_b1') if '_b' in name else name

    x_end = np.array([x_full[names.index(full_name(n))] for n in end.state_names])
    col = dict(zip(names, x_full, strict=True))
    disturbance = [p.secondary_lateral_stiffness * col['y_b2']
                   + p.secondary_lateral_damping * col['dy_b2'],
                   p.anti_yaw_damping * col['dpsi_b2']]
    u_full = creep_steps.track_alignment[k]
    xdot_full = full.a @ x_full + full.b @ u_full
    xdot_end = end.a @ x_end + end.b @ np.concatenate([u_full[:2], disturbance])
    expected = np.array([xdot_full[names.index(full_name(n))] for n in end.state_names])
    np.testing.assert_allclose(xdot_end, expected, rtol=1e-9, atol=1e-12)
    # Sensors (pattern D): the same three outputs as the full car's front bogie.
    np.testing.assert_allclose(
        end.c @ x_end + end.d @ np.concatenate([u_full[:2], disturbance]),
        (full.c @ x_full + full.d @ u_full)[:3], rtol=1e-9, atol=1e-12)
    # The rear bogie mirrors the lever arm: its pivot is at -lv, so body yaw pulls it the
    # other way.
    rear = car_end_state_space(p, 0.7, bogie='rear')
    row, column = end.state_names.index('dy_b'), end.state_names.index('psi_v')
    assert end.a[row, column] > 0.0
    assert rear.a[row, column] == pytest.approx(-end.a[row, column])
    with pytest.raises(ValueError, match='bogie'):
        car_end_state_space(p, bogie='middle')


def test_cached_discretisation_close_to_exact() -> None:
    """Grid + first-order Taylor step: transition and the x, u Jacobian blocks within 2e-5 of
    the exact ones (second-order error); the c column within 1.5 % (its derivative is taken at
    the grid point, a first-order error of the 1 % grid)."""
    ekf = CreepEkf(CreepEkfParams(pattern='C'))
    rng = np.random.default_rng(4)
    i_theta = ekf.i_theta
    for c in rng.uniform(0.1, 1.9, size=20):
        x = _state(ekf, rng, float(c))
        cached, jac_cached = ekf.transition(x)
        exact, jac_exact = ekf.transition(x, exact=True)
        # Measured worst 1.03e-5 relative (spectrum track model; 0.72e-5 with slope_walk).
        assert np.max(np.abs(cached - exact)[:ekf.n_model]) < 2e-5 * np.max(
            np.abs(exact[:ekf.n_model]))
        block = np.s_[:ekf.n_model, :ekf.n_model]
        assert np.max(np.abs(jac_cached[block] - jac_exact[block])) < 1e-5 * np.max(
            np.abs(jac_exact[block]))
        column_cached, column_exact = jac_cached[:i_theta, i_theta], jac_exact[:i_theta, i_theta]
        # Measured worst 1.002 % (spectrum track model): of the order of the 1 % grid.
        assert (np.linalg.norm(column_cached - column_exact)
                < 0.015 * np.linalg.norm(column_exact))
    # A second call near the same c is served from the cache (no matrix exponential).
    before = ekf.discretizations
    x[i_theta] += 1e-4
    ekf.transition(x)
    assert ekf.discretizations == before


@pytest.mark.parametrize('model', ['full', 'end'])
@pytest.mark.parametrize('pattern', 'ABCD')
def test_spec_target(known_runs: dict[tuple[str, str], CreepRun], model: str,
                     pattern: str) -> None:
    """docs/targets.md: within 5 % (A-C) / 10 % (D) of the truth from 1 s after each step on, no
    steady bias, and each step detected (not just drifted to)."""
    run = known_runs[model, pattern]
    metrics = step_metrics(run, tolerance=0.05, window_s=1.0)
    assert [m.value for m in metrics] == pytest.approx([0.4, 0.6])
    for m in metrics:
        assert m.max_error_after_window <= SPEC_TARGET[pattern], m
        # Measured steady errors: full within 0.3 %; end A-C within 1.4 %, D +1.5 % / -0.3 %.
        assert abs(m.steady_error) < (0.03 if pattern == 'D' else 0.02), m
    # The drop to 40 % is seen within 1 s by every pattern (estimate below 60 % of nominal).
    k = np.searchsorted(run.time, 6.0)
    assert run.creep_factor[k] < 0.6
    assert run.rejected == {} and run.resets == {}


def test_half_car_model_mismatch_biases_pattern_d(creep_steps: RailSimulationResult) -> None:
    """The paper's 7-DOF half car on the 14-DOF truth: pattern D is biased high (its body is
    too heavy seen from the bogie, no yaw, no other bogie); the end and full models remove the
    bias."""
    half = run_on_simulation(creep_steps, CreepEkfParams(pattern='D', model='half'))
    half_bias = [m.steady_error for m in step_metrics(half)]
    assert min(half_bias) > 0.05                       # measured +9.6 % and +17.5 %
    # Measured: end +1.5 % and -0.3 %, full +0.1 % and +0.2 %.
    for model, limit in (('end', 0.03), ('full', 0.01)):
        run = run_on_simulation(creep_steps, CreepEkfParams(pattern='D', model=model,
                                                            **SURVEYED_TRACK))
        assert max(abs(m.steady_error) for m in step_metrics(run)) < limit, model


def test_yaw_measurement_helps_little(known_runs: dict[tuple[str, str], CreepRun]) -> None:
    """Paper: B (with bogie yaw) vs C (without) differ little; so they do here."""
    def mean_error(run: CreepRun) -> float:
        assert run.true_creep_factor is not None
        settled = np.zeros(run.time.size, dtype=bool)
        for t0 in (5.0, 10.0):
            settled |= (run.time >= t0 + 1.0) & (run.time < t0 + 5.0)
        rel = run.creep_factor / run.true_creep_factor - 1.0
        return float(np.mean(np.abs(rel[settled])))

    b, c = mean_error(known_runs['full', 'B']), mean_error(known_runs['full', 'C'])
    assert max(b, c) < 0.02     # measured 0.53 % (B) and 0.40 % (C); the end model 0.98, 1.01 %
    assert abs(c - b) < 0.005   # "little": a twentieth of a per cent here


def test_unknown_input_pattern_a(creep_steps: RailSimulationResult) -> None:
    """Without the track input (process noise), pattern A still follows the steps; B-D do
    not (the track's yaw creep moment is then unknown: c drifts, see the issue report)."""
    run = run_on_simulation(creep_steps, CreepEkfParams(pattern='A'), known_input=False)
    for m in step_metrics(run):
        assert m.max_error_after_window < 0.06, m     # measured 4.2 % and 2.7 %


def test_covariance_spd_and_ramps_on_long_run() -> None:
    """rail_combined_long (180 s, ramps, speed changes, faults): P stays SPD, c follows."""
    result = simulate(shipped_scenario('rail_combined_long'))
    y, track, speed = simulation_inputs(result, 'A')
    ekf = CreepEkf(CreepEkfParams(pattern='A'))
    estimate = np.empty(y.shape[0])
    min_eig = math.inf
    asym = 0.0
    for k in range(y.shape[0]):
        estimate[k] = ekf.step(y[k], track[k], float(speed[k])).creep_factor
        if k % 100 == 0:
            # Eigenvalues of the correlation matrix: P itself spans many decades.
            scale = 1.0 / np.sqrt(np.diag(ekf.P))
            min_eig = min(min_eig, float(np.linalg.eigvalsh(ekf.P * np.outer(scale, scale))[0]))
            asym = max(asym, float(np.abs(ekf.P - ekf.P.T).max()))
    assert min_eig > 0.0 and asym == 0.0
    assert ekf.resets == {}
    rel = estimate / result.creep_factor - 1.0
    # Outside the first second, the mean |error| stays small through ramps, speed changes and
    # the suspension faults the model does not know of (measured bias and spread in report).
    settled = result.time > 1.0
    assert np.mean(np.abs(rel[settled])) < 0.08


def test_bad_samples_rejected_and_counted(creep_steps: RailSimulationResult) -> None:
    """NaN, wrong size and spikes are rejected and counted; the estimate stays as clean."""
    y, track, _ = simulation_inputs(creep_steps, 'C')
    clean = CreepEkf(CreepEkfParams(pattern='C')).run(y, track)
    ekf = CreepEkf(CreepEkfParams(pattern='C'))
    rng = np.random.default_rng(11)
    bad = rng.choice(np.arange(100, y.shape[0] - 10), size=30, replace=False)
    estimates = []
    for k in range(y.shape[0]):
        sample: np.ndarray | None = y[k]
        u = track[k]
        if k in bad[:10]:
            sample = np.full(y.shape[1], np.nan)
        elif k in bad[10:20]:
            sample = y[k][:3]
        elif k in bad[20:25]:
            sample = y[k] + np.eye(y.shape[1])[0] * 0.5      # 0.5 m jump
        elif k in bad[25:]:
            u = np.array([np.inf, 0.0])
        estimates.append(ekf.step(sample, u).creep_factor)
    assert ekf.rejected == {'non_finite': 10, 'wrong_shape': 10, 'outlier': 5,
                            'track_non_finite': 5}
    assert ekf.resets == {}
    diff = np.abs(np.array(estimates) / clean.creep_factor - 1.0)
    # A step's alarm may come a sample later or earlier than in the clean run (measured: one
    # sample 27 % apart, at the second step's alarm); every other within 5 %.
    assert diff[-1] < 0.01 and np.count_nonzero(diff > 0.05) <= 2


def test_divergence_detected_and_reset(creep_steps: RailSimulationResult) -> None:
    """Garbage for a while (measurements of another vehicle) resets the filter and reports it;
    afterwards it tracks again and c never leaves its bounds."""
    y, track, _ = simulation_inputs(creep_steps, 'C')
    params = CreepEkfParams(pattern='C')
    ekf = CreepEkf(params)
    garbage = slice(400, 800)
    corrupted = y.copy()
    corrupted[garbage] = y[garbage] * 8.0     # consistently wrong scale for 2 s
    run = ekf.run(corrupted, track, time=creep_steps.time,
                  true_creep_factor=creep_steps.creep_factor)
    assert sum(run.resets.values()) >= 1
    assert np.all((run.creep_factor >= params.min_creep_factor)
                  & (run.creep_factor <= params.max_creep_factor))
    metrics = step_metrics(run)
    assert metrics[0].steady_error == pytest.approx(0.0, abs=0.08)


def test_rewinding_without_widening_reproduces_the_first_pass(
        creep_steps: RailSimulationResult) -> None:
    """Going back to the change's onset keeps the whole filter state: with the widening all
    but off (1e-4), the run that goes back at the first alarm and filters again (over a gap
    of missing samples between the step and the alarm) gives the estimates of the run that
    does not, up to its second alarm (after which a threshold crossing may move by a
    sample). The onsets are tried ``change_confirm_s`` after the alarm; the alarm is kept
    whatever the onset's gain (without a widening it has none)."""
    y, track, _ = simulation_inputs(creep_steps, 'C')
    period = round(1e9 / 200.0)
    missing = set(range(1010, 1014))      # the step is at sample 1000, the alarm after 1020
    runs = {}
    for rewind in (2.0, 0.0):
        ekf = CreepEkf(CreepEkfParams(pattern='C', change_log_std=1e-4, change_rewind_s=rewind,
                                      change_confirm_gain=-1e9, **SURVEYED_TRACK))
        estimates, alarms, rewinds = [], [], []
        for k in range(1200):
            if k in missing:
                continue
            ekf.advance_to(k * period)
            before = ekf.changes_detected
            estimates.append(ekf.step(y[k], track[k]).creep_factor)
            if ekf.changes_detected > before:
                alarms.append(len(estimates) - 1)
            rewinds.append(ekf.rewinds)
        runs[rewind] = (np.array(estimates), alarms, rewinds)
    (with_rewind, alarms, rewinds), (plain, plain_alarms, _) = runs[2.0], runs[0.0]
    confirm = round(CreepEkfParams().change_confirm_s * 200.0)
    assert alarms[0] == plain_alarms[0]
    assert rewinds[alarms[0] + confirm - 1] == 0 and rewinds[alarms[0] + confirm] == 1
    until = plain_alarms[1]
    np.testing.assert_allclose(with_rewind[:until], plain[:until], rtol=1e-5)


@pytest.mark.parametrize('pattern', 'ABCD')
def test_a_change_begins_at_its_most_likely_onset(creep_steps: RailSimulationResult,
                                                  pattern: str) -> None:
    """The onset kept on an alarm is the step's sample (5 s, 10 s), 0.065-0.185 s before the
    alarm (measured), and trying the onsets costs a few hundred samples filtered again."""
    y, track, _ = simulation_inputs(creep_steps, pattern)
    ekf = CreepEkf(CreepEkfParams(pattern=pattern, **SURVEYED_TRACK))
    onsets = []
    for k in range(y.shape[0]):
        rewinds = ekf.rewinds
        ekf.step(y[k], track[k])
        if ekf.rewinds > rewinds:
            onsets.append(k * ekf.params.dt - ekf.last_change_lead_s)
    np.testing.assert_allclose(onsets, [5.0, 10.0], atol=1e-9)
    assert ekf.rewinds == 2 and ekf.refiltered < 1000


@pytest.mark.parametrize('pattern', 'ABCD')
def test_onsets_ranked_on_cached_grid_points(creep_steps: RailSimulationResult, pattern: str,
                                            monkeypatch: pytest.MonkeyPatch) -> None:
    """Ranking the onsets on the grid points already cached (ONSET_SEARCH_GRID_REACH) keeps
    the onset and every estimate of ranking on new ones, with half the discretisations
    (measured: 52-66 against 114-142 over the run)."""
    y, track, _ = simulation_inputs(creep_steps, pattern)
    runs = {}
    for reach in (0, creep_ekf.ONSET_SEARCH_GRID_REACH):
        monkeypatch.setattr(creep_ekf, 'ONSET_SEARCH_GRID_REACH', reach)
        ekf = CreepEkf(CreepEkfParams(pattern=pattern, **SURVEYED_TRACK))
        estimates = [ekf.step(y[k], track[k]).creep_factor for k in range(y.shape[0])]
        runs[reach] = (np.array(estimates), ekf.discretizations, ekf.rewinds)
    (exact, exact_count, exact_rewinds), (ranked, ranked_count, rewinds) = runs.values()
    np.testing.assert_allclose(ranked, exact, rtol=1e-12)
    assert rewinds == exact_rewinds == 2
    assert ranked_count < 0.6 * exact_count


def test_an_onset_the_filter_diverges_from_is_not_kept(creep_steps: RailSimulationResult,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """A divergence while the onsets are tried does not reset the filter (that would drop the
    kept samples and the track history): the onset is out, and when every onset is, the
    change is widened where they were tried, as without going back but change_confirm_s
    later."""
    reason = CreepEkf._divergence_reason                       # noqa: SLF001

    def diverged_while_replaying(ekf: CreepEkf) -> str:
        return 'innovation_inconsistent' if ekf._replaying else reason(ekf)  # noqa: SLF001

    monkeypatch.setattr(CreepEkf, '_divergence_reason', diverged_while_replaying)
    y, track, _ = simulation_inputs(creep_steps, 'C')
    runs = {}
    for rewind, confirm in ((2.0, 0.0), (0.0, 0.0), (2.0, 0.05)):
        ekf = CreepEkf(CreepEkfParams(pattern='C', change_rewind_s=rewind,
                                      change_confirm_s=confirm, **SURVEYED_TRACK))
        estimates = [ekf.step(y[k], track[k]).creep_factor for k in range(y.shape[0])]
        runs[rewind, confirm] = (np.array(estimates), ekf.changes_detected, ekf.rewinds,
                                 ekf.resets)
    (tried, alarms, rewinds, resets), (at_alarm, plain_alarms, _, _), confirmed = runs.values()
    # Two steps; widened at the alarm, the first step raises a second alarm (measured: 3).
    assert alarms == plain_alarms >= 2 and rewinds == 0 and resets == {}
    np.testing.assert_allclose(tried, at_alarm, rtol=1e-12)
    later, later_alarms, later_rewinds, later_resets = confirmed
    assert later_alarms >= 2 and later_rewinds == 0 and later_resets == {}
    assert np.all(np.abs(later[-200:] / creep_steps.creep_factor[-200:] - 1.0) < 0.05)


def test_low_adhesion_hysteresis() -> None:
    """The flag turns on below the threshold and off only above threshold + hysteresis."""
    ekf = CreepEkf(CreepEkfParams(pattern='C', low_adhesion_threshold=0.5,
                                  low_adhesion_hysteresis=0.05))
    flags = []
    for c in (0.9, 0.49, 0.53, 0.549, 0.56, 0.52):
        ekf.x[ekf.i_theta] = math.log(c)
        flags.append(ekf.step(None).low_adhesion)
    assert flags == [False, True, True, True, False, False]


def test_outputs_scale_nominal_coefficients() -> None:
    """f11 = c f11_nom, f22 = c f22_nom; std_dev = c sqrt(P_theta)."""
    params = CreepEkfParams(pattern='D')
    ekf = CreepEkf(params)
    ekf.x[ekf.i_theta] = math.log(0.6)
    est = ekf.step(None)
    assert est.f11 == pytest.approx(0.6 * params.vehicle.longitudinal_creep_coefficient)
    assert est.f22 == pytest.approx(0.6 * params.vehicle.lateral_creep_coefficient)
    assert est.std_dev == pytest.approx(0.6 * params.initial_log_creep_std)
    assert est.status == 'predicted' and math.isnan(est.nis)


@pytest.mark.parametrize('kwargs, match', [
    ({'pattern': 'E'}, 'pattern'),
    ({'min_creep_factor': 1.5, 'max_creep_factor': 1.0}, 'min_creep_factor'),
    ({'max_creep_factor': 3.0}, 'max_creep_factor'),
    ({'displacement_noise_m': -1.0}, 'displacement_noise_m'),
    ({'creep_walk_std_per_sqrt_s': math.nan}, 'creep_walk_std_per_sqrt_s'),
    ({'initial_creep_factor': 0.01}, 'initial_creep_factor'),
    ({'track_delay_min_wavelength_m': 5.0, 'model': 'end'}, 'track_delay_min_wavelength_m'),
    ({'track_delay_min_wavelength_m': 5.0, 'track_model': 'slope_walk'},
     'track_delay_min_wavelength_m'),
    ({'track_delay_min_wavelength_m': -1.0}, 'track_delay_min_wavelength_m'),
])
def test_bad_parameters_refused(kwargs: dict[str, object], match: str) -> None:
    """Non-physical settings raise ValueError naming the parameter."""
    with pytest.raises(ValueError, match=match):
        CreepEkfParams(**kwargs)  # type: ignore[arg-type]


def test_run_checks_shapes() -> None:
    """run() refuses measurement arrays of the wrong width for the pattern."""
    with pytest.raises(ValueError, match='measurements'):
        CreepEkf(CreepEkfParams(pattern='B')).run(np.zeros((10, 4)))


def test_lateral_states_measurement_body_channels() -> None:
    """End model: body lateral and yaw at the centre; half car: above the bogie, y_v + lv psi_v
    (front), y_v - lv psi_v (rear)."""
    n = 3
    rng = np.random.default_rng(5)
    fields = {name: rng.normal(size=(n, 4)) for name in
              ('wheelset_lateral', 'wheelset_lateral_rate', 'wheelset_yaw', 'wheelset_yaw_rate')}
    fields |= {name: rng.normal(size=(n, 2)) for name in
               ('bogie_lateral', 'bogie_lateral_rate', 'bogie_yaw', 'bogie_yaw_rate')}
    fields |= {name: rng.normal(size=n) for name in
               ('body_lateral', 'body_lateral_rate', 'body_yaw', 'body_yaw_rate')}
    for pattern in 'ABC':
        for model in ('end', 'half'):
            assert lateral_states_measurement(fields, pattern, model=model).shape == (
                n, len(measurement_channels(pattern, model)))
    # End model, pattern A: the body's lateral displacement and yaw at its centre, as the
    # message has them; B and C (docs/methods/creep_estimator.md): the body's lateral displacement
    # and velocity only.
    assert measurement_channels('A')[-4:] == ('y_v', 'psi_v', 'dy_v', 'dpsi_v')
    end = lateral_states_measurement(fields, 'C')
    assert measurement_channels('C') == ('y_b', 'dy_b', 'y_v', 'dy_v')
    assert measurement_channels('B') == ('y_b', 'dy_b', 'psi_b', 'dpsi_b', 'y_v', 'dy_v')
    np.testing.assert_allclose(end[:, 2:], np.column_stack([
        fields['body_lateral'], fields['body_lateral_rate']]))
    # The fields a pattern does not use are ignored: NaN there, or absent, changes nothing.
    spec_only = {name: (values if name in ('bogie_lateral', 'bogie_lateral_rate',
                                           'body_lateral', 'body_lateral_rate')
                        else np.full_like(values, np.nan)) for name, values in fields.items()}
    np.testing.assert_array_equal(lateral_states_measurement(spec_only, 'C'), end)
    minimal = {name: fields[name] for name in ('bogie_lateral', 'bogie_lateral_rate',
                                               'body_lateral', 'body_lateral_rate')}
    np.testing.assert_array_equal(lateral_states_measurement(minimal, 'C'), end)
    # Half car: the body above the bogie.
    front = lateral_states_measurement(fields, 'C', 'front', 10.0, model='half')
    rear = lateral_states_measurement(fields, 'C', 'rear', 10.0, model='half')
    np.testing.assert_allclose(front[:, 0], fields['bogie_lateral'][:, 0])
    np.testing.assert_allclose(rear[:, 1], fields['bogie_lateral_rate'][:, 1])
    np.testing.assert_allclose(front[:, 2], fields['body_lateral'] + 10.0 * fields['body_yaw'])
    np.testing.assert_allclose(rear[:, 3],
                               fields['body_lateral_rate'] - 10.0 * fields['body_yaw_rate'])
    a = lateral_states_measurement(fields, 'A', 'rear', model='half')
    np.testing.assert_allclose(a[:, 0], fields['wheelset_lateral'][:, 2])
    np.testing.assert_allclose(a[:, 7], fields['wheelset_yaw_rate'][:, 3])


def test_predict_through_gap_is_prediction_steps(creep_steps: RailSimulationResult) -> None:
    """Data time in the core: stamped samples with 7 missing ones give the same state,
    covariance and estimates as prediction-only steps in their place; a gap beyond max_gap_s
    resets; both counted."""
    z, track, _ = simulation_inputs(creep_steps, 'C')
    period = 5_000_000
    stepped, stamped = CreepEkf(CreepEkfParams()), CreepEkf(CreepEkfParams())
    for k in range(300):
        missing = 150 <= k < 157
        a = stepped.step(None if missing else z[k], None if missing else track[k])
        if missing:
            continue
        stamped.advance_to(k * period)
        b = stamped.step(z[k], track[k])
        assert a.creep_factor == b.creep_factor and a.low_adhesion == b.low_adhesion
    np.testing.assert_array_equal(stepped.x, stamped.x)
    np.testing.assert_array_equal(stepped.P, stamped.P)
    assert stamped.predicted_missing == 7 and stamped.gap_resets == 0
    stamped.x[stamped.i_theta] = math.log(0.5)
    stamped.advance_to(300 * period + 10**9)
    assert stamped.gap_resets == 1 and stamped.creep_factor == pytest.approx(1.0)


def test_pattern_c_reads_only_the_spec_fields(creep_steps: RailSimulationResult) -> None:
    """Issue 19: pattern C is the bogie and body lateral displacement and velocity only; with
    every other RailLateralStates field NaN no sample is rejected and the contract target (the
    exact track) holds (measured on the seeded run: settled 0.16 / 0.105 s, largest error
    after 1 s 1.8 / 1.9 %; told the default map accuracy, 0.3 mm, instead: 0.21 / 0.47 s,
    2.8 / 3.3 %)."""
    fields = lateral_states_fields(creep_steps.measured_state, creep_steps.state_names)
    spec = ('bogie_lateral', 'bogie_lateral_rate', 'body_lateral', 'body_lateral_rate')
    fields = {name: (values if name in spec else np.full_like(values, np.nan))
              for name, values in fields.items()}
    z = lateral_states_measurement(fields, 'C')
    _, track, _ = simulation_inputs(creep_steps, 'C')
    run = CreepEkf(CreepEkfParams(pattern='C', **SURVEYED_TRACK)).run(
        z, track, time=creep_steps.time, true_creep_factor=creep_steps.creep_factor)
    assert run.rejected == {}
    for m in step_metrics(run):
        assert m.settling_time < 1.0 and m.max_error_after_window < 0.05, m


def test_track_map_weighted_by_its_stated_accuracy(creep_steps: RailSimulationResult) -> None:
    """A published track map with 0.3 mm rms error (the spectrum's shape) over the simulated
    band: the spectrum track model told the map's accuracy and band has less than half the
    worst error of one that takes the map as exact (measured, largest error from 1 s after
    the 0.4 -> 0.6 step: 13.0 % against 42.9 %; with the force and moment suspension errors
    before 2026-12-05, 20.5 % against 59.1 %, and 32.5 % when the stated rms was taken as the
    whole spectrum's; the issue's +/-5 % is not reached, see
    docs/methods/rail_family_evaluation.md)."""
    scenario = creep_steps.scenario
    mapped = simulate(replace(scenario, track=replace(scenario.track, map_error_rms=3e-4)))
    worst = {}
    for stated in (1e-5, 3e-4):
        run = run_on_simulation(mapped, CreepEkfParams(
            pattern='C', track_map_error_m=stated,
            track_map_max_wavelength_m=scenario.track.max_wavelength))
        worst[stated] = step_metrics(run)[-1].max_error_after_window
    assert worst[3e-4] < 0.5 * worst[1e-5]


def test_sensor_offsets_estimated(creep_steps: RailSimulationResult) -> None:
    """Constant offsets on the measured lateral states are states of the filter: the estimate
    of the bogie displacement's offset approaches the true 0.5 mm."""
    scenario = creep_steps.scenario
    biased = simulate(replace(scenario, sensors=replace(scenario.sensors,
                                                        displacement_bias=5e-4)))
    params = CreepEkfParams(pattern='C', **SURVEYED_TRACK)
    ekf = CreepEkf(params)
    y, track, _ = simulation_inputs(biased, 'C')
    ekf.run(y, track)
    offsets = ekf.x[ekf.i_theta - ekf.n_offsets:ekf.i_theta]
    assert measurement_channels('C')[0] == 'y_b'
    assert offsets[0] == pytest.approx(5e-4, rel=0.3)


@pytest.mark.parametrize('model', ['end', 'half', 'full'])
@pytest.mark.parametrize('bogie', ['front', 'rear'])
def test_pattern_fields_are_what_the_measurement_reads(model: str, bogie: str) -> None:
    """pattern_fields names exactly the entries lateral_states_measurement reads: NaN in any
    of them reaches the measurement, NaN everywhere else does not."""
    rng = np.random.default_rng(9)
    shapes = {'wheelset_lateral': 4, 'wheelset_lateral_rate': 4, 'wheelset_yaw': 4,
              'wheelset_yaw_rate': 4, 'bogie_lateral': 2, 'bogie_lateral_rate': 2,
              'bogie_yaw': 2, 'bogie_yaw_rate': 2, 'body_lateral': None,
              'body_lateral_rate': None, 'body_yaw': None, 'body_yaw_rate': None}
    fields = {name: rng.normal(size=(1, size) if size else 1) for name, size in shapes.items()}
    for pattern in 'ABC':
        used = pattern_fields(pattern, bogie, model)
        only_used = {name: np.full_like(values, np.nan) for name, values in fields.items()}
        for name, index in used:
            if index is None:
                only_used[name] = fields[name].copy()
            else:
                only_used[name][:, index] = fields[name][:, index]
        z = lateral_states_measurement(only_used, pattern, bogie, 9.5, model)
        assert np.isfinite(z).all(), (pattern, used)
        for name, index in used:
            probe = {key: value.copy() for key, value in fields.items()}
            if index is None:
                probe[name][:] = np.nan
            else:
                probe[name][:, index] = np.nan
            z = lateral_states_measurement(probe, pattern, bogie, 9.5, model)
            assert not np.isfinite(z).all(), (pattern, name, index)


def test_full_model_knows_the_rear_track_from_the_front(creep_steps: RailSimulationResult) -> None:
    """The full model's rear wheelsets run on the published front track a wheelbase later
    (core.track_history): after 10 s its rear track states are the true alignment within a
    few hundredths of a millimetre (measured 0.0004 and 0.015 mm, std 0.08 mm). Kept no
    longer than the wheelbase takes, they are the spectrum's guess (measured 0.005 and 0.59 mm
    off, std 2.0 and 3.8 mm)."""
    samples = 2000
    rear = {}
    for history_s in (5.0, 0.1):
        params = CreepEkfParams(pattern='C', track_history_s=history_s, **SURVEYED_TRACK)
        y, track, speed = simulation_inputs(creep_steps, 'C', model=params.model)
        ekf = CreepEkf(params)
        ekf.run(y[:samples], track[:samples], speed[:samples])
        states = slice(ekf.n_model + 2, ekf.n_model + 4)    # y_r3, y_r4 (predicted to k)
        rear[history_s] = (np.abs(ekf.x[states] - creep_steps.track_alignment[samples, 2:4]),
                           np.sqrt(np.diag(ekf.P)[states]))
    error, std = rear[5.0]
    assert np.all(error < 5e-5) and np.all(std < 2e-4)
    assert np.all(rear[0.1][1] > 1e-3)


def test_measurement_model_with_the_rear_rows(creep_steps: RailSimulationResult) -> None:
    """measurement_model(rear=True) is the update a full-model sample makes once the front
    track is kept a wheelbase's time: the same rows (the front and rear pairs' alignment and
    rate) as the filter's own sample; without ``rear``, the front pair's only."""
    params = CreepEkfParams(pattern='C', **SURVEYED_TRACK)
    y, track, speed = simulation_inputs(creep_steps, 'C', model=params.model)
    ekf = CreepEkf(params)
    ekf.run(y[:400], track[:400], speed[:400])
    rows, _ = ekf._track_sample(track[400])                 # noqa: SLF001
    h_rear, r_rear = ekf.measurement_model(4, rear=True)
    expected = ekf._observation(rows)                       # noqa: SLF001
    np.testing.assert_array_equal(h_rear, expected.h)
    np.testing.assert_array_equal(r_rear, expected.r)
    h_front, _ = ekf.measurement_model(4)
    assert h_front.shape[0] == h_rear.shape[0] - 4          # the rear pair's two rows each
    end = CreepEkf(CreepEkfParams(pattern='C', model='end'))
    np.testing.assert_array_equal(end.measurement_model(4, rear=True)[0],
                                  end.measurement_model(4)[0])


def test_track_delays_carry_the_front_track_to_the_rear(
        creep_steps: RailSimulationResult) -> None:
    """With the track's delays in the model (track_delay_min_wavelength_m), the rear
    wheelsets' alignment is the front one's through Pade cascades, not a kept history: after
    10 s of the paper's run with the front pair's track published, pattern C's rear alignment
    is the true one within 0.25 and 0.08 mm (measured; the filter states 0.04 mm: the
    cascades' error at wavelengths below 5 m is not in its model), where independent rear
    processes without the history have a spread of 1.8-3.8 mm. A sample then observes the
    front pair's rows only."""
    samples = 2000
    y, track, speed = simulation_inputs(creep_steps, 'C', model='full')
    rear = {}
    for delays, history_s in ((5.0, 5.0), (0.0, 0.1)):
        ekf = CreepEkf(CreepEkfParams(pattern='C', track_delay_min_wavelength_m=delays,
                                      track_history_s=history_s, **SURVEYED_TRACK))
        ekf.run(y[:samples], track[:samples], speed[:samples])
        rows = ekf._h_track_rows[2:4]                       # noqa: SLF001 (y_r3, y_r4)
        rear[delays] = (np.abs(rows @ ekf.x - creep_steps.track_alignment[samples, 2:4]),
                        np.sqrt(np.diag(rows @ ekf.P @ rows.T)))
        if delays:
            assert ekf._track_sample(track[samples])[0] == (0, 1, 4, 5)   # noqa: SLF001
            np.testing.assert_array_equal(ekf.measurement_model(4, rear=True)[0],
                                          ekf.measurement_model(4)[0])
    error, std = rear[5.0]
    assert np.all(error < 4e-4) and np.all(std < 1e-4)
    assert np.all(rear[0.0][1] > 1e-3)


def test_the_full_model_takes_the_front_pair_track() -> None:
    """Whichever bogie it monitors, the full model takes the front pair's published track
    (the rear runs on it later); the others the monitored bogie's."""
    assert track_wheelsets('rear', 'full') == slice(0, 2)
    assert track_wheelsets('rear', 'end') == slice(2, 4)
    assert track_wheelsets('front', 'end') == slice(0, 2)


def test_a_suspension_fault_is_no_low_adhesion() -> None:
    """The full model carries each bogie's secondary spring and damper ratio as states
    (pattern D: a force and a moment as Gauss-Markov states), so a failed spring or damper is
    not read as a creep change: on the fault recording's run (spring 150 % at 3 s, damper 50 %
    at 6 s, c = 1 throughout) pattern C stays within 0.945-1.055 and D within 0.90-1.04
    (measured), and low adhesion is never flagged; D with the track's delays and no track
    published (the shipped IMU estimator in service) 0.916-1.111 (without the delays
    0.68-1.32). With the ratios held at 1 (std 1e-6) C ran 0.36-1.57 and flagged low
    adhesion."""
    fault = simulate(shipped_scenario('rail_imm_spring_damper_fault'))
    after = fault.time > 1.0
    for pattern, delays, known, (low, high) in (('C', 0.0, True, (0.9, 1.1)),
                                                 ('D', 0.0, True, (0.8, 1.1)),
                                                 ('D', 5.0, False, (0.85, 1.15))):
        run = run_on_simulation(fault, CreepEkfParams(
            pattern=pattern, track_delay_min_wavelength_m=delays), known_input=known)
        assert low < run.creep_factor[after].min() and run.creep_factor[after].max() < high
        assert not run.low_adhesion.any()
    bare = run_on_simulation(fault, CreepEkfParams(pattern='C', suspension_ratio_std=1e-6,
                                                   suspension_ratio_walk_std_per_sqrt_s=1e-6))
    assert bare.creep_factor[after].min() < 0.5 and bare.low_adhesion.any()


@pytest.mark.parametrize('pattern, delays, share', [('C', 0.0, 0.015), ('D', 5.0, 0.03)])
def test_a_sample_at_another_speed_steps_the_transition_to_it(
        pattern: str, delays: float, share: float) -> None:
    """Within ``speed_tolerance_mps`` the model is kept and its transition stepped to the
    sample's speed by dF/dv (exact at the model's speed). 0.5 m/s from a model at 30 m/s the
    stepped Jacobian is off the exact one at 30.5 m/s by 0.9 % (C) and 2.0 % (D with the
    track's delays) of what the model at 30 m/s is off (measured)."""
    rng = np.random.default_rng(11)
    params = CreepEkfParams(pattern=pattern, model='full', track_delay_min_wavelength_m=delays,
                            **SURVEYED_TRACK)
    stepped, exact = CreepEkf(params), CreepEkf(params)
    stepped.set_speed(30.0)
    x = rng.normal(size=stepped.dim_x) * 1e-3      # mm, mm/s, mrad: the state's scale
    x[stepped.i_theta] = math.log(0.8)
    kept = stepped.transition(x, exact=True)[1]
    stepped.set_speed(30.5)
    exact.set_speed(30.5)
    assert stepped.speed == exact.speed == 30.5
    truth = exact.transition(x, exact=True)[1]
    error = np.linalg.norm(stepped.transition(x, exact=True)[1] - truth)
    assert error < share * np.linalg.norm(kept - truth)


def test_an_accelerating_car_reads_c_as_a_steady_one() -> None:
    """A car accelerating from 20 to 30 m/s over 20 s (0.5 m/s^2), c 1 -> 0.5 at 12 s, pattern
    C with the exact track: over 4-12 s the estimate's mean error is +0.6 % and its largest
    3.7 %; from 14 s 0.5 % rms (measured). The rear bogie's track is the front pair's where
    the car stood a wheelbase earlier, and the transition is at each sample's speed; with the
    delay from the present speed and the model rebuilt every 0.05 m/s (the code before) the
    same run read +1.6 %, 5.8 % and 0.7 %."""
    scenario = rail_scenario_from_dict({
        'name': 'creep_accelerating', 'duration': 24.0, 'seed': 5,
        'initial': {'speed': 20.0, 'creep_factor': 1.0},
        'events': [{'time': 2.0, 'speed': 30.0, 'ramp': 20.0},
                   {'time': 12.0, 'creep_factor': 0.5}]})
    result = simulate(scenario)
    run = run_on_simulation(result, CreepEkfParams(pattern='C', **SURVEYED_TRACK))
    error = run.creep_factor / result.creep_factor - 1.0
    before = (result.time > 4.0) & (result.time < 12.0)
    after = result.time > 14.0
    assert abs(np.mean(error[before])) < 0.01
    assert np.max(np.abs(error[before])) < 0.045
    assert np.sqrt(np.mean(error[after] ** 2)) < 0.01
