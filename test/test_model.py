"""The rigid body and the integrator: free fall, hover, energy, ground, batching, bad input."""

from __future__ import annotations

import numpy as np
import pytest

from multirotor_ros.model import state as S
from multirotor_ros.model.airframe import GRAVITY_M_S2, load_airframe
from multirotor_ros.model.integrator import Integrator
from multirotor_ros.model.model import Model

BACKENDS = ["numpy", "compiled"]


@pytest.fixture(scope="module")
def x8() -> Model:
    return Model(load_airframe("x8_octorotor"))


@pytest.mark.parametrize("backend", BACKENDS)
def test_free_fall_is_exact(x8: Model, backend: str) -> None:
    """With no thrust and no drag, z(t) = z0 - g t^2 / 2 (RK4 is exact on this polynomial)."""
    model = x8.with_effects([])
    integrator = Integrator(model, 1e-3, ground_height_m=None, backend=backend)
    x = integrator.advance(0.0, S.make_state(8, position_m=(1.0, 2.0, 50.0)), np.zeros(8), 1000)
    assert x[0, 2] == pytest.approx(50.0 - GRAVITY_M_S2 / 2, abs=1e-9)
    assert x[0, 5] == pytest.approx(-GRAVITY_M_S2, abs=1e-9)
    np.testing.assert_allclose(x[0, :2], [1.0, 2.0], atol=1e-12)


@pytest.mark.parametrize("name", ["x8_octorotor", "hexarotor_f550", "quad_x"])
def test_hover_is_an_equilibrium(name: str) -> None:
    model = Model(load_airframe(name))
    omega = np.full(model.n_rotors, model.hover_speed_rad_s())
    x0 = S.make_state(model.n_rotors, position_m=(0, 0, 2.0), rotor_speed_rad_s=omega)
    x = Integrator(model, 1e-3).advance(0.0, x0, omega, 2000)
    np.testing.assert_allclose(x[0, :13], x0[0, :13], atol=1e-7)


@pytest.mark.parametrize("backend", BACKENDS)
def test_energy_is_conserved_without_input_or_dissipation(x8: Model, backend: str) -> None:
    """A tumbling, drifting vehicle in free flight keeps its mechanical energy (seed 2's Hamiltonian)."""
    model = x8.with_effects([])
    x0 = S.make_state(
        8,
        position_m=(0, 0, 100.0),
        velocity_m_s=(3.0, -2.0, 5.0),
        euler_rad=(0.4, -0.3, 1.0),
        body_rate_rad_s=(2.0, -1.5, 3.0),
    )
    x = Integrator(model, 1e-3, ground_height_m=None, backend=backend).advance(0.0, x0, np.zeros(8), 5000)
    e0, e1 = model.mechanical_energy(x0)[0], model.mechanical_energy(x)[0]
    assert abs(e1 - e0) / abs(e0) < 1e-10
    # Angular momentum in world axes is conserved too (torque-free rigid body).
    from multirotor_ros.model.rotation import quat_to_matrix

    def momentum_W(state: np.ndarray) -> np.ndarray:
        return quat_to_matrix(state[0, S.QUATERNION]) @ (model.inertia_kg_m2 @ state[0, S.BODY_RATE])

    np.testing.assert_allclose(momentum_W(x), momentum_W(x0), rtol=1e-9)


def test_vehicle_rests_on_the_ground_and_takes_off(x8: Model) -> None:
    integrator = Integrator(x8, 1e-3)
    hover = x8.hover_speed_rad_s()
    x = integrator.advance(0.0, S.make_state(8), np.full(8, 0.9 * hover), 500)
    assert x[0, 2] == 0.0 and np.all(x[0, 3:6] == 0.0)
    x = integrator.advance(0.5, x, np.full(8, 1.1 * hover), 1000)
    assert x[0, 2] > 0.1 and x[0, 5] > 0.0


def test_batch_steps_equal_separate_runs() -> None:
    """Three parameter sets in one batch give the same states as three separate models."""
    airframe = load_airframe("x8_octorotor")
    c_values = np.array([0.1, 0.5, 1.0])
    batched = Model(airframe, [{"id": "quadratic_drag", "c_x": c_values, "c_y": 0.2, "c_z": 0.0}])
    x0 = S.make_state(
        8, batch=3, position_m=(0, 0, 10), velocity_m_s=(5.0, 1.0, 0.0), euler_rad=(0.05, 0.1, 0.0)
    )
    u = np.full((3, 8), 345.0)
    for backend in BACKENDS:
        x = Integrator(batched, 1e-3, backend=backend).advance(0.0, x0, u, 300)
        for b, c in enumerate(c_values):
            single = Model(airframe, [{"id": "quadratic_drag", "c_x": c, "c_y": 0.2, "c_z": 0.0}])
            xs = Integrator(single, 1e-3, backend=backend).advance(0.0, x0[b : b + 1], u[b], 300)
            np.testing.assert_allclose(x[b], xs[0], rtol=1e-12, atol=1e-12)


def test_backends_agree_on_a_full_effect_flight() -> None:
    airframe = load_airframe("x8_octorotor")
    model = Model(
        airframe,
        [
            {"id": "quadratic_drag", "c_x": 0.47, "c_y": 0.47, "c_z": 0.2},
            {"id": "rotor_drag", "k_h": 2e-4},
            {"id": "motor_lag", "tau_s": 0.03},
            {"id": "actuator_fault", "motor": 3, "effectiveness": 0.4, "t_fault_s": 0.1},
            {"id": "ground_effect", "rotor_radius_m": 0.127},
        ],
    )
    x0 = S.make_state(
        8,
        position_m=(0, 0, 0.3),
        velocity_m_s=(1, -1, 0.5),
        euler_rad=(0.1, -0.1, 0.3),
        rotor_speed_rad_s=340,
    )
    u = np.linspace(320, 360, 8)
    numpy_x = Integrator(model, 1e-3, backend="numpy").advance(0.0, x0, u, 300)
    compiled_x = Integrator(model, 1e-3, backend="compiled").advance(0.0, x0, u, 300)
    np.testing.assert_allclose(compiled_x, numpy_x, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("backend", BACKENDS)
def test_non_finite_command_is_refused_with_the_rotor_named(x8: Model, bad: float, backend: str) -> None:
    u = np.full(8, 340.0)
    u[4] = bad
    with pytest.raises(ValueError, match="rotor_5"):
        Integrator(x8, 1e-3, backend=backend).step(0.0, S.make_state(8), u)


def test_wrong_rotor_count_is_refused(x8: Model) -> None:
    with pytest.raises(ValueError, match="8 rotors"):
        Integrator(x8, 1e-3).step(0.0, S.make_state(8), np.full(6, 340.0))


@pytest.mark.parametrize("backend", BACKENDS)
def test_state_never_becomes_nan_silently(x8: Model, backend: str) -> None:
    x = S.make_state(8, position_m=(0, 0, 5))
    x[0, S.BODY_RATE] = np.nan
    with pytest.raises(FloatingPointError, match="vehicle 0"):
        Integrator(x8, 1e-3, backend=backend).step(0.0, x, np.full(8, 340.0))


def test_bad_step_and_duplicate_effects_are_refused(x8: Model) -> None:
    with pytest.raises(ValueError, match="positive"):
        Integrator(x8, 0.0)
    with pytest.raises(ValueError, match="listed twice"):
        x8.with_effects([{"id": "rotor_drag", "k_h": 1e-4}, {"id": "rotor_drag", "k_h": 2e-4}])
    with pytest.raises(ValueError, match="8 rotors"):
        x8.with_effects([{"id": "actuator_fault", "motor": 9, "effectiveness": 0.5, "t_fault_s": 0.0}])


def test_integration_is_deterministic(x8: Model) -> None:
    x0 = S.make_state(8, position_m=(0, 0, 5), velocity_m_s=(1, 2, 3))
    runs = [Integrator(x8, 1e-3).advance(0.0, x0, np.linspace(300, 380, 8), 200) for _ in range(2)]
    assert np.array_equal(runs[0], runs[1])
