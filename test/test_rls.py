"""Recursive least squares and the identifier's online estimator (window, refit, identifiability)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from multirotor_ros.ident.rls import OnlineIdentifier, OnlineSettings, RecursiveLeastSquares, RlsError
from multirotor_ros.model.airframe import load_airframe
from multirotor_ros.model.model import Model
from multirotor_ros.model.rotation import euler_to_matrix
from multirotor_ros.model.state import StateBatch


def _linear_data(rng: np.random.Generator, theta: np.ndarray, n: int, noise: float):
    phi = rng.normal(size=(n, 3, theta.size))
    return phi @ theta + noise * rng.normal(size=(n, 3)), phi


def test_recovers_parameters_with_consistent_standard_deviations():
    rng = np.random.default_rng(1)
    theta = np.array([0.3, -1.2, 2.0, 0.05])
    y, phi = _linear_data(rng, theta, 3000, noise=0.1)
    rls = RecursiveLeastSquares(["a", "b", "c", "d"], forgetting=1.0)
    for k in range(y.shape[0]):
        rls.update(y[k], phi[k])
    error = rls.theta - theta
    assert np.all(np.abs(error) < 4 * rls.std)
    assert np.all(rls.std < 0.01)
    assert rls.noise_variance == pytest.approx(0.01, rel=0.1)


def test_forgetting_follows_a_parameter_that_changes():
    rng = np.random.default_rng(2)
    rls = RecursiveLeastSquares(["k"], forgetting=0.98)
    for k in range(2000):
        value = 1.0 if k < 1000 else 2.0
        phi = rng.normal(size=(3, 1))
        rls.update(phi[:, 0] * value + 0.01 * rng.normal(size=3), phi)
        if k == 999:
            assert rls.theta[0] == pytest.approx(1.0, abs=0.01)
    # Memory 1/(1 - 0.98) = 50 samples: 1000 samples after the change the old value is forgotten.
    assert rls.theta[0] == pytest.approx(2.0, abs=0.01)


def test_covariance_of_an_unexcited_parameter_does_not_wind_up():
    rls = RecursiveLeastSquares(["seen", "unseen"], forgetting=0.95, initial_std=[10.0, 2.0])
    for _ in range(5000):
        rls.update([1.0, 1.0, 1.0], [[1.0, 0.0], [1.0, 0.0], [1.0, 0.0]])
    assert rls.covariance[1, 1] <= 4.0 + 1e-12
    assert np.all(np.linalg.eigvalsh(rls.covariance) >= -1e-12)
    assert rls.theta[0] == pytest.approx(1.0)


def test_refuses_non_finite_rows_and_wrong_shapes_without_changing_the_estimate():
    rls = RecursiveLeastSquares(["a", "b"])
    rls.update([1.0], [[1.0, 0.0]])
    before = (rls.theta.copy(), rls.covariance.copy())
    with pytest.raises(RlsError, match="measurement row 1 is nan"):
        rls.update([1.0, float("nan")], np.ones((2, 2)))
    with pytest.raises(RlsError, match="regressor row 0, parameter b is inf"):
        rls.update([1.0], [[1.0, float("inf")]])
    with pytest.raises(RlsError, match="does not match"):
        rls.update([1.0, 2.0], [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(rls.theta, before[0])
    np.testing.assert_array_equal(rls.covariance, before[1])


def test_state_round_trip_and_refusal_of_a_broken_state():
    rng = np.random.default_rng(3)
    rls = RecursiveLeastSquares(["a", "b"], forgetting=0.99)
    y, phi = _linear_data(rng, np.array([1.0, 2.0]), 50, 0.1)
    for k in range(50):
        rls.update(y[k], phi[k])
    copy = RecursiveLeastSquares.from_state(rls.state())
    np.testing.assert_array_equal(copy.theta, rls.theta)
    np.testing.assert_array_equal(copy.std, rls.std)
    assert copy.n_updates == 50
    broken = rls.state()
    broken["covariance"] = np.zeros((3, 3))
    with pytest.raises(RlsError, match="inconsistent shapes"):
        RecursiveLeastSquares.from_state(broken)
    with pytest.raises(RlsError, match="incomplete"):
        RecursiveLeastSquares.from_state({"theta": np.zeros(2)})


def _random_flight(truth: Model, rng: np.random.Generator, n: int, vertical_speed: float = 2.0) -> StateBatch:
    v = rng.normal(0.0, 2.0, (n, 3))
    v[:, 2] *= vertical_speed / 2.0
    flight = StateBatch(
        t=np.arange(n) * 0.01,
        p_WB_W=np.zeros((n, 3)),
        v_WB_W=v,
        R_WB=euler_to_matrix(rng.normal(0.0, 0.1, (n, 3))),
        w_WB_B=rng.normal(0.0, 0.3, (n, 3)),
        omega=rng.uniform(300.0, 380.0, (n, truth.n_rotors)),
    )
    a, _ = truth.accelerations(truth.context(flight))
    return dataclasses.replace(flight, a_WB_W=a + rng.normal(0.0, 0.3, a.shape))


def _add_one_by_one(identifier: OnlineIdentifier, flight: StateBatch) -> None:
    """As the identifier node does: sample after sample."""
    for k in range(flight.size):
        identifier.add(flight.select(slice(k, k + 1)))


def test_online_identifier_recovers_thrust_constant_and_drag():
    airframe = load_airframe("x8_octorotor")
    truth = Model(
        dataclasses.replace(airframe, k_f_N_s2=1.05 * airframe.k_f_N_s2),
        [{"id": "quadratic_drag", "c_x": 0.3, "c_y": 0.5, "c_z": 0.1}],
    )
    flight = _random_flight(truth, np.random.default_rng(4), 3000)
    identifier = OnlineIdentifier(airframe, ["quadratic_drag"], OnlineSettings(window_s=20.0))
    _add_one_by_one(identifier, flight)
    running = {e.name: e for e in identifier.estimates()}
    assert running["k_f_N_s2"].value == pytest.approx(1.05 * airframe.k_f_N_s2, rel=0.01)
    assert running["c_x"].value == pytest.approx(0.3, abs=0.02)
    refit = identifier.refit()
    assert refit is not None
    assert refit.n_samples in (2000, 2001)  # the last 20 s at 100 Hz (the ends are a rounding apart)
    fitted = {e.name: e for e in refit.estimates}
    for name, value in (("c_x", 0.3), ("c_y", 0.5), ("c_z", 0.1)):
        assert fitted[name].value == pytest.approx(value, abs=0.02)
        assert abs(fitted[name].value - value) < 5 * fitted[name].std
    drag = identifier.model().effect("quadratic_drag")
    assert float(drag["c_y"]) == pytest.approx(0.5, abs=0.02)


def test_refit_holds_what_the_window_cannot_see():
    airframe = load_airframe("x8_octorotor")
    truth = Model(airframe, [{"id": "quadratic_drag", "c_x": 0.4688, "c_y": 0.4688, "c_z": 0.3}])
    # No vertical speed at all: c_z has no column; it keeps the configured value (0 for the X8).
    flight = _random_flight(truth, np.random.default_rng(5), 1000, vertical_speed=0.0)
    identifier = OnlineIdentifier(airframe, ["quadratic_drag"], OnlineSettings(window_s=60.0))
    _add_one_by_one(identifier, flight)
    refit = identifier.refit()
    assert refit is not None
    fitted = {e.name: e for e in refit.estimates}
    assert not fitted["c_z"].identifiable
    assert fitted["c_z"].value == 0.0
    assert fitted["c_x"].identifiable and fitted["c_x"].value == pytest.approx(0.4688, abs=0.03)


def test_online_identifier_refuses_effects_it_cannot_fit_and_stale_samples():
    airframe = load_airframe("x8_octorotor")
    with pytest.raises(ValueError, match="motor_lag.*no parameter that enters the force linearly"):
        OnlineIdentifier(airframe, ["motor_lag"])
    with pytest.raises(ValueError, match="unknown effect 'drag'"):
        OnlineIdentifier(airframe, ["drag"])
    identifier = OnlineIdentifier(airframe, [])
    sample = StateBatch(
        [1.0], np.zeros((1, 3)), np.zeros((1, 3)), np.eye(3)[None], np.zeros((1, 3)), np.full((1, 8), 340.0)
    )
    with pytest.raises(ValueError, match="measured acceleration"):
        identifier.add(sample)
    sample = dataclasses.replace(sample, a_WB_W=np.zeros((1, 3)))
    identifier.add(sample)
    with pytest.raises(ValueError, match="not newer"):
        identifier.add(sample)


def test_window_keeps_only_the_last_window_s():
    airframe = load_airframe("quad_x")
    identifier = OnlineIdentifier(airframe, [], OnlineSettings(window_s=2.0, min_refit_samples=10))
    n = 1000
    hover = StateBatch(
        t=0.01 * np.arange(n),
        p_WB_W=np.zeros((n, 3)),
        v_WB_W=np.zeros((n, 3)),
        R_WB=np.broadcast_to(np.eye(3), (n, 3, 3)),
        w_WB_B=np.zeros((n, 3)),
        omega=np.full((n, airframe.n_rotors), 400.0),
        a_WB_W=np.zeros((n, 3)),
    )
    _add_one_by_one(identifier, hover)
    identifier.flush()
    times = identifier.window.arrays()["t"]
    assert times[0] == pytest.approx(7.99) and times[-1] == pytest.approx(9.99)
