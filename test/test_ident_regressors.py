"""Regressors, filters and solvers of multirotor_ros.ident on hand-computed cases."""

import math

import numpy as np
import pytest
from scipy.signal import savgol_filter

from multirotor_ros.ident.fit import newey_west, solve_bounded
from multirotor_ros.ident.parameters import parameter_facts
from multirotor_ros.ident.regressors import ForceRegressor, linear_refs, parameter_value, with_values
from multirotor_ros.ident.samples import MeasurementChain, lag_filter
from multirotor_ros.io.derive import SavitzkyGolay
from multirotor_ros.model.airframe import GRAVITY_M_S2, load_airframe
from multirotor_ros.model.effects import EFFECTS, TRANSLATIONAL_EFFECTS
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import euler_to_matrix
from multirotor_ros.model.state import StateBatch

X8 = load_airframe("x8_octorotor")
HEXA = load_airframe("hexarotor_f550")

# A non-neutral value for every linear parameter (used to make data the regressor must reproduce).
TRUE_VALUES = {
    "c_x": 0.3,
    "c_y": 0.2,
    "c_z": 0.1,
    "k_h": 1e-4,
    "k_f1": 3e-9,
    "eta_lower": 0.8,
    "k_v": 4e-4,
    "dm_kg": 0.12,
    "f_x": 0.4,
    "f_y": -0.3,
    "f_z": 0.2,
    "rotor_radius_m": 0.12,
    "tau_s": 0.03,
    "motor": 2.0,
    "effectiveness": 0.6,
    "t_fault_s": 0.05,
    **{f"e_{i}": 1.0 - 0.05 * i for i in range(1, 9)},
}


def batch(airframe, n=7, seed=0):
    rng = np.random.default_rng(seed)
    euler = rng.normal(0.0, 0.2, (n, 3))
    return dict(
        t=np.linspace(0.0, 0.1, n),
        p=np.column_stack([rng.normal(0, 2, n), rng.normal(0, 2, n), rng.uniform(0.2, 3, n)]),
        v=rng.normal(0.0, 2.0, (n, 3)),
        R=euler_to_matrix(euler),
        w=rng.normal(0.0, 0.5, (n, 3)),
        omega=rng.uniform(250.0, 450.0, (n, airframe.n_rotors)),
    )


def hand_level_state(airframe):
    """Level attitude, known velocity and speeds: columns computable by hand."""
    n_rotors = airframe.n_rotors
    return dict(
        t=np.zeros(1),
        p=np.array([[0.0, 0.0, 5.0]]),
        v=np.array([[2.0, -1.0, 0.5]]),
        R=np.eye(3)[None],
        w=np.zeros((1, 3)),
        omega=np.full((1, n_rotors), 300.0),
    )


def test_columns_match_the_formulas_of_effects_md_on_a_level_vehicle():
    model = Model(
        X8,
        [
            {"id": "quadratic_drag", "c_x": 0, "c_y": 0, "c_z": 0},
            {"id": "rotor_drag", "k_h": 0},
            {"id": "mass_offset", "dm_kg": 0.0},
            {"id": "constant_force", "f_x": 0, "f_y": 0, "f_z": 0},
        ],
    )
    refs = linear_refs(
        model, ["quadratic_drag", "rotor_drag", "mass_offset", "constant_force"], include_k_f=True
    )
    s = hand_level_state(X8)
    a = np.array([[0.5, 0.2, -0.3]])
    states = StateBatch(s["t"], s["p"], s["v"], s["R"], s["w"], s["omega"], a)
    y, Phi = ForceRegressor(model, refs).from_states(states)
    columns = dict(zip([name for _, name in refs], np.moveaxis(Phi[0], 1, 0), strict=True))
    np.testing.assert_allclose(columns["k_f_N_s2"], [0, 0, 8 * 300.0**2])
    np.testing.assert_allclose(columns["c_x"], [-2.0 * 2.0, 0, 0])
    np.testing.assert_allclose(columns["c_y"], [0, 1.0 * 1.0, 0])
    np.testing.assert_allclose(columns["c_z"], [0, 0, -0.5 * 0.5])
    # rotor drag: -k_h * sum(omega) * (body-horizontal velocity); level, so (v_x, v_y, 0).
    np.testing.assert_allclose(columns["k_h"], [-8 * 300.0 * 2.0, 8 * 300.0 * 1.0, 0.0])
    np.testing.assert_allclose(columns["dm_kg"], [-0.5, -0.2, 0.3 - GRAVITY_M_S2])
    np.testing.assert_allclose(columns["f_x"], [1, 0, 0])
    # Every parameter of the list is free, so y is the measured side m (a + g e_z) alone.
    np.testing.assert_allclose(y[0], X8.mass_kg * (a[0] + [0, 0, GRAVITY_M_S2]))


@pytest.mark.parametrize("airframe", [X8, HEXA], ids=["x8", "hexa"])
@pytest.mark.parametrize("effect_id", TRANSLATIONAL_EFFECTS)
def test_y_equals_phi_theta_for_data_made_by_the_model(airframe, effect_id):
    """The contract of ForceRegressor for every translational effect: the model's own force is reproduced."""
    why_not = EFFECTS[effect_id].not_applicable(airframe)
    if why_not is not None:
        pytest.skip(why_not)
    parameters = EFFECTS[effect_id].parameter_list(airframe.n_rotors)
    truth = Model(airframe, [{"id": effect_id, **{p.name: TRUE_VALUES[p.name] for p in parameters}}])
    s = batch(airframe)
    ctx = truth.context(StateBatch(s["t"], s["p"], s["v"], s["R"], s["w"], s["omega"]))
    a_true = truth.accelerations(ctx)[0]
    # k_f times a thrust factor on every rotor is one product: with both free the data fix only that, so the
    # per-rotor effect is regressed with k_f known.
    refs = linear_refs(truth, [effect_id], include_k_f=EFFECTS[effect_id].PER_ROTOR_PARAMETER is None)
    if effect_id == "actuator_fault":
        refs.append(("actuator_fault", "effectiveness"))
    start = with_values(truth, {r: parameter_facts(r).neutral if r[0] != "airframe" else 1e-5 for r in refs})
    regressor = ForceRegressor(start, refs)
    theta = np.array([parameter_value(truth, r) for r in refs])
    y, Phi = regressor(ctx, a_true)
    if regressor.bilinear:
        # k_f x eta: Gauss-Newton steps from the start converge to the truth.
        for _ in range(20):
            estimate = np.linalg.lstsq(Phi.reshape(-1, len(refs)), y.reshape(-1), rcond=None)[0]
            regressor.relinearise(estimate)
            y, Phi = regressor(ctx, a_true)
    np.testing.assert_allclose(y, Phi @ theta, rtol=1e-9, atol=1e-9 * np.abs(y).max())


def test_nonlinear_parameters_are_refused_with_the_reason():
    model = Model(X8, [{"id": "ground_effect", "rotor_radius_m": 0.1}])
    with pytest.raises(ValueError, match="rotor_radius_m enters the force non-linearly"):
        ForceRegressor(model, [("ground_effect", "rotor_radius_m")])
    with pytest.raises(ValueError, match="has no effect 'rotor_drag'"):
        ForceRegressor(model, [("rotor_drag", "k_h")])


def test_neutral_effects_change_nothing():
    s = batch(X8)
    base = Model(X8, [])
    ctx = base.context(StateBatch(s["t"], s["p"], s["v"], s["R"], s["w"], s["omega"]))
    reference = base.wrench(ctx)[0]
    for effect_id in TRANSLATIONAL_EFFECTS:
        if effect_id == "motor_lag":
            continue  # acts on the rotor speeds themselves: see test_lag_filter_*
        model = Model(X8, [{"id": effect_id, **EFFECTS[effect_id].neutral_parameters(X8.n_rotors)}])
        np.testing.assert_allclose(model.wrench(ctx)[0], reference, rtol=1e-9, err_msg=effect_id)


def test_lag_filter_is_the_exact_solution_for_a_ramp_and_identity_without_lag():
    t = np.arange(0.0, 1.0, 0.01)
    omega = (300.0 + 100.0 * t)[:, None]  # a ramp: linear between samples, so the discretisation is exact
    tau = 0.05
    lagged = lag_filter(t, omega, tau)
    # d(w)/dt = (300 + 100 t - w)/tau, w(0) = 300: w = 300 + 100 (t - tau (1 - exp(-t/tau))).
    exact = 300.0 + 100.0 * (t - tau * (1.0 - np.exp(-t / tau)))
    np.testing.assert_allclose(lagged[:, 0], exact, rtol=1e-12)
    np.testing.assert_allclose(lag_filter(t, omega, 1e-9), omega, rtol=1e-9)
    jittered = t + np.where(np.arange(t.size) > 50, 1e-4, 0.0)
    np.testing.assert_allclose(lag_filter(jittered, omega, tau)[:40], lagged[:40], rtol=1e-12)
    with pytest.raises(ValueError, match="tau_s must be > 0"):
        lag_filter(t, omega, 0.0)


def test_measurement_chain_reproduces_the_filter_applied_to_the_log():
    dt = 0.01
    t = np.arange(0.0, 5.0, dt)
    position = np.sin(3 * t) + 0.2 * t**2
    acceleration = -9 * np.sin(3 * t) + 0.4
    flt = SavitzkyGolay()
    window = flt.window_samples(dt)
    logged = savgol_filter(position, window, flt.polyorder, deriv=2, delta=dt, mode="interp")
    chained = MeasurementChain(2, flt, dt).apply(t, acceleration[:, None], [(0, t.size)])[:, 0]
    inner = slice(window, -window)
    # Both are the same filter of the same signal: equal up to the trapezoid rule's error.
    assert np.max(np.abs(chained[inner] - logged[inner])) < 2e-3
    # ...while the raw acceleration differs from the filtered one by the filter's smoothing.
    assert np.max(np.abs(acceleration[inner] - logged[inner])) > 5 * np.max(
        np.abs(chained[inner] - logged[inner])
    )
    np.testing.assert_array_equal(MeasurementChain(0, flt, dt).apply(t, acceleration, []), acceleration)


def test_bounded_solve_respects_physical_bounds():
    rng = np.random.default_rng(1)
    A = rng.normal(size=(200, 2))
    b = A @ np.array([-0.5, 2.0]) + rng.normal(0, 0.01, 200)
    free = solve_bounded(A, b, np.array([-np.inf, -np.inf]), np.array([np.inf, np.inf]))
    np.testing.assert_allclose(free, [-0.5, 2.0], atol=0.01)
    bounded = solve_bounded(A, b, np.array([0.0, -np.inf]), np.array([np.inf, np.inf]))
    assert bounded[0] == pytest.approx(0.0, abs=1e-12)
    # The remaining parameter is the least-squares answer given the bound.
    expected = np.linalg.lstsq(A[:, 1:], b, rcond=None)[0][0]
    assert bounded[1] == pytest.approx(expected, rel=1e-6)


def test_newey_west_inflates_the_std_of_autocorrelated_residuals_only():
    rng = np.random.default_rng(2)
    n = 4000
    X = np.zeros((n, 3, 1))
    X[:, 2, 0] = 1.0  # a constant force on z: the mean of the residual
    weights = np.ones(3)
    white = rng.normal(size=(n, 3))
    cov, cov_white, _ = newey_west(X, white, weights)
    assert math.sqrt(cov[0, 0]) == pytest.approx(math.sqrt(cov_white[0, 0]), rel=0.25)
    ar = np.zeros((n, 3))
    noise = rng.normal(size=(n, 3))
    for k in range(1, n):
        ar[k] = 0.9 * ar[k - 1] + noise[k]
    cov, cov_white, bandwidth = newey_west(X, ar, weights)
    # AR(1) with 0.9: the long-run std of a mean is sqrt((1 + 0.9)/(1 - 0.9)) = 4.4 times the white one.
    assert math.sqrt(cov[0, 0] / cov_white[0, 0]) > 2.5
    assert bandwidth > 5
